//! A headless Bevy app running [`DermisPlugin`] for a fixed number of frames: a skin anchored to
//! a body that breathes (its anchor targets swell and shrink), with the diagnostics printed every
//! frame. No window, no renderer: just `bevy_app` and the dermis systems in `Update`.
//!
//! Run it with `cargo run --example bevy_app --features bevy_app`.

use bevy_app::{App, Update};
use bevy_ecs::prelude::*;
use bevy_ecs::schedule::{LogLevel, ScheduleBuildSettings};
use dermis::ecs::*;
use dermis::mesh::TriMesh;
use glam::Vec3;

/// Frame counter driving the animation (fixed timestep: one frame per update).
#[derive(Resource, Default)]
struct Breath(u32);

/// Swells the anchor targets radially from the sheet's centre, a few millimetres per frame.
fn breathe(mut breath: ResMut<Breath>, mut skins: Query<(&RestGeometry, &mut SkinAnchors)>) {
    breath.0 += 1;
    let s = 1.0 + 0.05 * (breath.0 as f32 * 0.3).sin();
    let centre = Vec3::new(0.5, 0.5, 0.0);
    for (rest, mut anchors) in &mut skins {
        for (a, &p) in anchors.iter_mut().zip(rest.positions()) {
            a.target = centre + (p - centre) * s;
        }
    }
}

fn print_diagnostics(skins: Query<(Entity, &RelaxDiagnostics)>) {
    for (skin, d) in &skins {
        println!(
            "frame {:3} skin {skin}: {:3} iterations, residual {:.2e} of {:.3} N, energy {:.3e} J, {:?}",
            d.frames, d.iterations, d.residual, d.force_scale_n, d.energy_j, d.stop
        );
    }
}

fn grid(n: u32) -> TriMesh {
    let p = (0..n * n)
        .map(|v| Vec3::new((v % n) as f32, (v / n) as f32, 0.0) / (n - 1) as f32)
        .collect();
    let mut t = Vec::new();
    for j in 0..n - 1 {
        for i in 0..n - 1 {
            let a = j * n + i;
            t.push([a, a + 1, a + n + 1]);
            t.push([a, a + n + 1, a + n]);
        }
    }
    TriMesh::new(p, t).expect("the grid is a valid mesh")
}

/// Builds the app, runs `frames` updates and returns the skin's final diagnostics.
pub fn run(frames: u32) -> RelaxDiagnostics {
    let mut app = App::new();
    app.add_plugins(DermisPlugin)
        .init_resource::<Breath>()
        .add_systems(
            Update,
            (
                breathe.in_set(DermisSystems::Animate),
                print_diagnostics.in_set(DermisSystems::Export),
            ),
        )
        // Our systems must be ordered: make any ambiguity in `Update` an error.
        .edit_schedule(Update, |schedule| {
            schedule.set_build_settings(ScheduleBuildSettings {
                ambiguity_detection: LogLevel::Error,
                ..Default::default()
            });
        });
    let skin = SkinBuilder::new(grid(12), SkinMaterial::default())
        .with_rest_anchors(50.0, 5.0)
        .spawn(app.world_mut())
        .expect("valid skin");
    for _ in 0..frames {
        app.update();
    }
    app.world()
        .get::<RelaxDiagnostics>(skin)
        .expect("the skin exists")
        .clone()
}

fn main() {
    let d = run(30);
    println!("done after {} frames", d.frames);
}
