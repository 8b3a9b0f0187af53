//! What one frame does and does not touch: stiffness only where inputs changed, and the
//! non-finite quarantine of one skin leaving the others alone.

use bevy_ecs::prelude::*;
use dermis::ecs::*;
use dermis::stiffness::Modulus;
use glam::Vec3;

use super::{sheet, world_with};

fn wave(p: Vec3, frame: u32) -> Vec3 {
    p + Vec3::new(0.0, 0.0, 0.02 * (0.3 * frame as f32 + 4.0 * p.x).sin())
}

fn two_skins(world: &mut World) -> (Entity, Entity) {
    let spawn = |world: &mut World| {
        SkinBuilder::new(sheet(10), SkinMaterial::default())
            .with_rest_anchors(40.0, 4.0)
            .spawn(world)
            .unwrap()
    };
    (spawn(world), spawn(world))
}

fn diagnostics(world: &World, skin: Entity) -> RelaxDiagnostics {
    world.get::<RelaxDiagnostics>(skin).unwrap().clone()
}

#[test]
fn changing_one_material_recomputes_only_that_skins_stiffness() {
    let (mut world, mut schedule) = world_with(wave);
    let (a, b) = two_skins(&mut world);
    schedule.run(&mut world);
    // The first frame computes every skin's stiffness and springs once.
    for s in [a, b] {
        let d = diagnostics(&world, s);
        assert_eq!((d.stiffness_updates, d.spring_rebuilds), (1, 1));
    }
    // Frames that change no material or rest geometry do not recompute anything.
    let k_a = world.get::<EdgeStiffness>(a).unwrap().k_n_per_m.clone();
    let tick_b = world
        .entity(b)
        .get_ref::<EdgeStiffness>()
        .unwrap()
        .last_changed();
    for _ in 0..3 {
        schedule.run(&mut world);
    }
    for s in [a, b] {
        let d = diagnostics(&world, s);
        assert_eq!((d.stiffness_updates, d.spring_rebuilds), (1, 1));
    }

    world.get_mut::<SkinMaterial>(a).unwrap().youngs_2d_n_per_m = Modulus::Uniform(3000.0);
    schedule.run(&mut world);
    let (da, db) = (diagnostics(&world, a), diagnostics(&world, b));
    assert_eq!((da.stiffness_updates, da.spring_rebuilds), (2, 2));
    assert_eq!((db.stiffness_updates, db.spring_rebuilds), (1, 1));
    // Eq. 29 is linear in E2: tripling E2 triples every edge stiffness.
    let k_a3 = &world.get::<EdgeStiffness>(a).unwrap().k_n_per_m;
    for (k1, k3) in k_a.iter().zip(k_a3) {
        approx::assert_relative_eq!(*k3, 3.0 * k1, max_relative = 1e-6);
    }
    // B's stiffness was not even written.
    let b_ref = world.entity(b).get_ref::<EdgeStiffness>().unwrap();
    assert_eq!(b_ref.last_changed(), tick_b);
}

/// Asserts that skin `a`'s springs relax a loaded sheet to the same bits as a system built
/// afresh from its rest geometry and stiffness.
fn assert_springs_as_built_afresh(world: &World, a: Entity) {
    let rest = world.get::<RestGeometry>(a).unwrap();
    let k = &world.get::<EdgeStiffness>(a).unwrap().k_n_per_m;
    let fresh = dermis::solver::SpringSystem::new(
        rest.positions(),
        rest.mesh().topology().edges(),
        k,
        rest.edge_lengths_m(),
    )
    .unwrap();
    let rebuilt = world.get::<SkinSprings>(a).unwrap().system().unwrap();
    let forces: Vec<Vec3> = rest
        .positions()
        .iter()
        .map(|p| Vec3::new(0.0, 0.0, -0.01 * (1.0 + p.x)))
        .collect();
    // The side with the least y pinned.
    let low = rest
        .positions()
        .iter()
        .map(|p| p.y)
        .fold(f32::INFINITY, f32::min);
    let pinned: Vec<bool> = rest.positions().iter().map(|p| p.y < low + 1e-3).collect();
    assert!(pinned.iter().filter(|&&p| p).count() < pinned.len() / 4);
    let loads = dermis::solver::Loads {
        forces: Some(&forces),
        pinned: Some(&pinned),
        ..Default::default()
    };
    let relaxed = |s: &dermis::solver::SpringSystem| {
        let mut x = rest.positions().to_vec();
        s.relax(&mut x, &loads, &dermis::solver::RelaxConfig::default())
            .unwrap();
        x
    };
    assert_eq!(relaxed(rebuilt), relaxed(&fresh));
}

#[test]
fn springs_rebuilt_for_new_stiffness_are_those_a_fresh_build_gives() {
    let (mut world, mut schedule) = world_with(wave);
    let (a, _) = two_skins(&mut world);
    schedule.run(&mut world);
    // After a material change only the stiffness changes: the rebuilt system keeps its vertex
    // order, and relaxes to the same bits as one built from scratch.
    world.get_mut::<SkinMaterial>(a).unwrap().youngs_2d_n_per_m = Modulus::Uniform(2500.0);
    schedule.run(&mut world);
    assert_eq!(diagnostics(&world, a).spring_rebuilds, 2);
    assert_springs_as_built_afresh(&world, a);
    // A new rest shape (the sheet turned a quarter turn in its plane, which gives another
    // vertex order) with another material in the same frame: the system is ordered afresh.
    let turned: Vec<Vec3> = world
        .get::<RestGeometry>(a)
        .unwrap()
        .positions()
        .iter()
        .map(|p| Vec3::new(p.y, -p.x, p.z))
        .collect();
    world
        .get_mut::<RestGeometry>(a)
        .unwrap()
        .set_positions(turned)
        .unwrap();
    world.get_mut::<SkinMaterial>(a).unwrap().youngs_2d_n_per_m = Modulus::Uniform(1800.0);
    schedule.run(&mut world);
    assert_eq!(diagnostics(&world, a).spring_rebuilds, 3);
    assert_springs_as_built_afresh(&world, a);
}

#[test]
fn a_bad_material_is_reported_and_the_old_stiffness_kept() {
    let (mut world, mut schedule) = world_with(wave);
    let (a, _) = two_skins(&mut world);
    schedule.run(&mut world);
    let before = world.get::<EdgeStiffness>(a).unwrap().clone();
    world.get_mut::<SkinMaterial>(a).unwrap().youngs_2d_n_per_m = Modulus::Uniform(-1.0);
    schedule.run(&mut world);
    let d = diagnostics(&world, a);
    assert!(
        matches!(d.stiffness_error, Some(SkinError::Stiffness(_))),
        "{d:?}"
    );
    assert_eq!(world.get::<EdgeStiffness>(a).unwrap(), &before);
    assert!(
        d.stop.is_some(),
        "the skin keeps relaxing with its old springs"
    );
}

/// Runs two identical skins for `frames` frames; before frame `at`, `inject` may corrupt skin A.
fn run_with(
    frames: u32,
    at: u32,
    inject: impl Fn(&mut World, Entity),
) -> (World, Schedule, Entity, Entity, Vec<Vec3>) {
    let (mut world, mut schedule) = world_with(wave);
    let (a, b) = two_skins(&mut world);
    let mut a_before = Vec::new();
    for f in 0..frames {
        if f == at {
            a_before = skin_positions(&world, a).unwrap().to_vec();
            inject(&mut world, a);
        }
        schedule.run(&mut world);
    }
    (world, schedule, a, b, a_before)
}

fn quarantine_messages(world: &World) -> Vec<SkinQuarantined> {
    world
        .resource::<Messages<SkinQuarantined>>()
        .iter_current_update_messages()
        .copied()
        .collect()
}

#[test]
fn nan_position_is_quarantined_without_touching_the_other_skin() {
    let (control, _, ca, cb, _) = run_with(8, 99, |_, _| {});
    let (world, _, a, b, _) = run_with(8, 7, |world, a| {
        world.get_mut::<SkinPositions>(a).unwrap()[7] = Vec3::NAN;
    });
    let d = diagnostics(&world, a);
    let expected = SkinQuarantined {
        skin: a,
        vertex: 7,
        input: NonFiniteInput::Position,
        frame: 8,
    };
    assert_eq!(d.quarantined, vec![expected]);
    assert_eq!(quarantine_messages(&world), vec![expected]);
    // Rolled back to the last valid state and solved from there: exactly what the skin does
    // without the NaN. The other skin is bit-identical to the control run.
    assert_eq!(
        skin_positions(&world, a).unwrap(),
        skin_positions(&control, ca).unwrap()
    );
    assert_eq!(
        skin_positions(&world, b).unwrap(),
        skin_positions(&control, cb).unwrap()
    );
    assert!(diagnostics(&world, b).quarantined.is_empty());
}

#[test]
fn nan_anchor_rolls_the_skin_back_and_the_next_frames_recover() {
    let (control, _, _, cb, _) = run_with(6, 99, |_, _| {});
    let (mut world, mut schedule, a, b, a_before) = run_with(6, 5, |world, a| {
        world.get_mut::<SkinAnchors>(a).unwrap()[3].k_normal = f32::INFINITY;
    });
    let d = diagnostics(&world, a);
    assert_eq!(d.quarantined.len(), 1, "{d:?}");
    assert_eq!(d.quarantined[0].vertex, 3);
    assert_eq!(d.quarantined[0].input, NonFiniteInput::Anchor);
    assert_eq!(d.stop, None, "no solve ran on bad anchors");
    assert_eq!(skin_positions(&world, a).unwrap(), &a_before[..]);
    assert_eq!(
        skin_positions(&world, b).unwrap(),
        skin_positions(&control, cb).unwrap()
    );

    // The animation rewrites the anchor targets but not k_normal: fix it, and the skin goes on.
    world.get_mut::<SkinAnchors>(a).unwrap()[3].k_normal = 40.0;
    schedule.run(&mut world);
    let d = diagnostics(&world, a);
    assert!(d.quarantined.is_empty() && d.stop.is_some(), "{d:?}");
    assert_eq!(d.quarantine_total, 1);
}

#[test]
fn non_finite_force_is_quarantined() {
    let (mut world, mut schedule) = world_with(wave);
    let mut forces = vec![Vec3::ZERO; 100];
    forces[99] = Vec3::X;
    let skin = SkinBuilder::new(sheet(10), SkinMaterial::default())
        .with_rest_anchors(40.0, 4.0)
        .with_forces(forces)
        .spawn(&mut world)
        .unwrap();
    schedule.run(&mut world);
    world.get_mut::<ExternalLoads>(skin).unwrap().forces_n[42] = Vec3::new(0.0, f32::NAN, 0.0);
    schedule.run(&mut world);
    let d = diagnostics(&world, skin);
    assert_eq!(d.quarantined.len(), 1);
    assert_eq!(
        (d.quarantined[0].vertex, d.quarantined[0].input),
        (42, NonFiniteInput::Force)
    );
}

#[test]
fn builder_rejects_bad_input_with_typed_errors() {
    let err = SkinBuilder::new(sheet(4), SkinMaterial::default())
        .with_pinned([16])
        .build()
        .unwrap_err();
    assert_eq!(
        err.to_string(),
        "pinned vertex 16 is out of range: the mesh has 16 vertices"
    );
    let err = SkinBuilder::new(sheet(4), SkinMaterial::default())
        .with_forces(vec![Vec3::ZERO; 3])
        .build()
        .unwrap_err();
    assert!(matches!(
        err,
        SkinError::Length {
            given: 3,
            expected: 16,
            ..
        }
    ));
    let err = SkinBuilder::new(
        sheet(4),
        SkinMaterial::default().with_youngs_2d(Modulus::PerElement(vec![1.0; 5])),
    )
    .build()
    .unwrap_err();
    assert!(matches!(err, SkinError::Stiffness(_)), "{err}");
}

#[test]
fn still_frames_skip_the_solve_until_an_input_changes() {
    // Anchors stretch the sheet over 5 frames, then hold.
    let (mut world, mut schedule) =
        world_with(|p, f| p + Vec3::new(0.2 * p.x * (f.min(5) as f32 / 5.0), 0.0, 0.0));
    let skin = SkinBuilder::new(sheet(8), SkinMaterial::default())
        .with_rest_anchors(40.0, 4.0)
        .spawn(&mut world)
        .unwrap();
    for _ in 0..8 {
        schedule.run(&mut world);
    }
    // The test animation rewrites the anchors every frame; go on without it.
    let mut still = Schedule::default();
    DermisPlugin.configure(&mut still);
    still.run(&mut world); // first run: every input counts as new
    let tick = world
        .entity(skin)
        .get_ref::<SkinPositions>()
        .unwrap()
        .last_changed();
    let before = diagnostics(&world, skin);
    for _ in 0..3 {
        still.run(&mut world);
    }
    let d = diagnostics(&world, skin);
    assert_eq!(d.iterations, 0);
    assert_eq!(d.frames, before.frames + 3);
    assert_eq!(d.stop, Some(dermis::solver::StopReason::Converged));
    assert_eq!(
        world
            .entity(skin)
            .get_ref::<SkinPositions>()
            .unwrap()
            .last_changed(),
        tick
    );

    // Removing the anchors is a change too: the stretched sheet springs back towards rest.
    world.entity_mut(skin).remove::<SkinAnchors>();
    still.run(&mut world);
    let d = diagnostics(&world, skin);
    assert!(d.iterations > 0, "{d:?}");
}
