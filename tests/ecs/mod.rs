//! The ECS layer driven through a `Schedule`: equilibrium, change detection, quarantine,
//! determinism, and the Bevy app example.

mod determinism;
mod equilibrium;
mod frame;

use bevy_ecs::prelude::*;
use dermis::ecs::*;
use dermis::mesh::TriMesh;
use glam::Vec3;

/// A flat `n` x `n` grid sheet over the unit square (z = 0), two triangles per cell.
pub fn sheet(n: u32) -> TriMesh {
    let mut p = Vec::new();
    for j in 0..n {
        for i in 0..n {
            p.push(Vec3::new(
                i as f32 / (n - 1) as f32,
                j as f32 / (n - 1) as f32,
                0.0,
            ));
        }
    }
    TriMesh::new(p, dermis::mesh::shapes::grid_triangles(n, n)).unwrap()
}

/// The frame counter the test animation reads.
#[derive(Resource, Default)]
pub struct Frame(pub u32);

/// Where the anchor of a vertex at rest position `p` goes at frame `f`.
pub type AnchorPath = fn(Vec3, u32) -> Vec3;

/// The animation of a test scene: which path the anchors follow.
#[derive(Resource)]
pub struct Animation(pub AnchorPath);

/// Moves every skin's anchor targets along the scene's path (runs in `DermisSystems::Animate`).
pub fn animate_anchors(
    mut frame: ResMut<Frame>,
    animation: Res<Animation>,
    mut skins: Query<(&RestGeometry, &mut SkinAnchors)>,
) {
    frame.0 += 1;
    for (rest, mut anchors) in &mut skins {
        for (a, &p) in anchors.iter_mut().zip(rest.positions()) {
            a.target = (animation.0)(p, frame.0);
        }
    }
}

/// A world and a dermis schedule with the anchor animation in `Animate`.
pub fn world_with(path: AnchorPath) -> (World, Schedule) {
    let mut world = World::new();
    let mut schedule = DermisPlugin.build_schedule(&mut world);
    world.insert_resource(Frame(0));
    world.insert_resource(Animation(path));
    schedule.add_systems(animate_anchors.in_set(DermisSystems::Animate));
    (world, schedule)
}

#[test]
fn the_dermis_schedule_has_no_ambiguous_system_order() {
    // `build_schedule` reports ambiguities as errors: building must succeed.
    let (mut world, mut schedule) = world_with(|p, _| p);
    SkinBuilder::new(sheet(4), SkinMaterial::default())
        .spawn(&mut world)
        .unwrap();
    schedule.initialize(&mut world).unwrap();
}

#[cfg(feature = "bevy_app")]
#[path = "../../examples/bevy_app.rs"]
#[expect(dead_code, reason = "the example's `main` is not called by the test")]
mod bevy_app_example;

#[cfg(feature = "bevy_app")]
#[test]
fn the_bevy_app_example_runs_and_relaxes() {
    let frames = 12;
    let diagnostics = bevy_app_example::run(frames);
    assert_eq!(diagnostics.frames, frames as u64);
    assert!(diagnostics.stop.is_some(), "the solve ran: {diagnostics:?}");
    assert!(
        diagnostics.residual <= RelaxSettings::DEFAULT.tolerance,
        "{diagnostics:?}"
    );
    assert!(diagnostics.quarantined.is_empty());
}
