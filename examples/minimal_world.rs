//! The smallest dermis program: a standalone `bevy_ecs` `World` and a `Schedule` from
//! [`DermisPlugin::build_schedule`], one skin (a 16 x 16 sheet) whose anchors are pulled
//! sideways and lifted over 20 frames and then held, and the relaxation diagnostics printed
//! every frame. No Bevy app, no window.
//!
//! Run it with `cargo run --example minimal_world`.

use bevy_ecs::prelude::*;
use dermis::ecs::*;
use dermis::mesh::TriMesh;
use glam::Vec3;

/// Frames so far (animation advances by a fixed step per frame, never by the wall clock).
#[derive(Resource, Default)]
struct FrameCount(u32);

/// Moves the anchor targets: the right edge of the sheet slides +x, the middle rises.
fn pull_anchors(
    mut frame: ResMut<FrameCount>,
    mut skins: Query<(&RestGeometry, &mut SkinAnchors)>,
) {
    frame.0 += 1;
    let s = (frame.0 as f32 / 20.0).min(1.0);
    for (rest, mut anchors) in &mut skins {
        for (a, &p) in anchors.iter_mut().zip(rest.positions()) {
            let lift =
                0.1 * (std::f32::consts::PI * p.x).sin() * (std::f32::consts::PI * p.y).sin();
            a.target = p + s * Vec3::new(0.15 * p.x, 0.0, lift);
        }
    }
}

fn sheet(n: u32) -> TriMesh {
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

fn main() -> Result<(), SkinError> {
    let mut world = World::new();
    let mut schedule = DermisPlugin.build_schedule(&mut world);
    world.init_resource::<FrameCount>();
    schedule.add_systems(pull_anchors.in_set(DermisSystems::Animate));

    // Skin slides along the body (tangential anchors 10x softer than normal ones).
    let skin = SkinBuilder::new(sheet(16), SkinMaterial::HUMAN_SKIN)
        .with_rest_anchors(50.0, 5.0)
        .spawn(&mut world)?;

    for _ in 0..30 {
        schedule.run(&mut world);
        let d = world.get::<RelaxDiagnostics>(skin).expect("skin exists");
        println!(
            "frame {:2}: {:3} iterations, residual {:.1e} of {:.2} N, energy {:.4} J, {:?}",
            d.frames, d.iterations, d.residual, d.force_scale_n, d.energy_j, d.stop
        );
    }
    let x = skin_positions(&world, skin)?;
    let centre = x[8 * 16 + 8];
    println!("centre vertex now at {centre:.4}");
    Ok(())
}
