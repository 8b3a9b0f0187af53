//! A skin pulled by moving anchors settles where the pure solver (and, for a rigid motion, the
//! closed form) says it should.

use dermis::ecs::*;
use dermis::solver::{Loads, RelaxConfig, SpringSystem, StopReason};
use dermis::stiffness::StiffnessRule;
use glam::Vec3;

use super::{sheet, world_with};

const K_NORMAL: f32 = 40.0;
const K_TANGENT: f32 = 4.0;

/// Anchors stretch the sheet 10 % along x and lift a bump, reached over 10 frames, then hold.
fn stretch(p: Vec3, frame: u32) -> Vec3 {
    let s = (frame as f32 / 10.0).min(1.0);
    let bump = 0.05 * (std::f32::consts::PI * p.x).sin() * (std::f32::consts::PI * p.y).sin();
    p + s * Vec3::new(0.1 * p.x, 0.0, bump)
}

/// Bound on the distance to the exact equilibrium from a residual force norm: the Hessian of
/// springs under tension plus anchors is at least `min(k_normal, k_tangent)` times identity,
/// so `|x − x*| <= |r| / min(k)`.
fn distance_bound(residual: f32, force_scale: f32) -> f32 {
    residual * force_scale / K_NORMAL.min(K_TANGENT)
}

#[test]
fn anchored_skin_settles_to_the_pure_solver_equilibrium() {
    let mesh = sheet(14);
    let material = SkinMaterial::default();
    let (mut world, mut schedule) = world_with(stretch);
    // Below the f32 floor: both solvers iterate to the best f32 answer. The pure solver gets the
    // same tolerance and force scale.
    let tolerance = 1e-6;
    world.resource_mut::<DermisConfig>().relax.tolerance = tolerance;
    let skin = SkinBuilder::new(mesh.clone(), material.clone())
        .with_rest_anchors(K_NORMAL, K_TANGENT)
        .spawn(&mut world)
        .unwrap();
    for _ in 0..40 {
        schedule.run(&mut world);
    }
    let diag = world.get::<RelaxDiagnostics>(skin).unwrap().clone();
    assert!(
        diag.stop.is_some() && diag.quarantined.is_empty(),
        "{diag:?}"
    );
    let ecs = skin_positions(&world, skin).unwrap().to_vec();

    // The pure solver, from rest, same anchors at their final targets, much tighter tolerance.
    let k = material
        .stiffness_rule
        .edge_stiffness(&mesh, &material.youngs_2d_n_per_m)
        .unwrap();
    let system = SpringSystem::from_mesh(&mesh, &k).unwrap();
    let mut anchors = world.get::<SkinAnchors>(skin).unwrap().to_vec();
    for (a, &p) in anchors.iter_mut().zip(mesh.positions()) {
        a.target = stretch(p, 10);
    }
    let mut pure = mesh.positions().to_vec();
    let loads = Loads {
        anchors: Some(&anchors),
        ..Default::default()
    };
    let config = RelaxConfig {
        max_iterations: 20_000,
        tolerance,
        force_scale: Some(diag.force_scale_n),
        ..Default::default()
    };
    let report = system.relax(&mut pure, &loads, &config).unwrap();

    let bound = distance_bound(diag.residual, diag.force_scale_n)
        + distance_bound(report.residual, report.force_scale);
    let worst = ecs
        .iter()
        .zip(&pure)
        .map(|(a, b)| a.distance(*b))
        .fold(0.0, f32::max);
    // The skin really moved (so agreeing is not trivial), and agrees within the bound.
    let moved = ecs
        .iter()
        .zip(mesh.positions())
        .map(|(a, b)| a.distance(*b))
        .fold(0.0, f32::max);
    assert!(moved > 0.05, "the skin barely moved: {moved}");
    assert!(
        worst <= bound,
        "ECS and pure solver differ by {worst} m (bound {bound} m); {diag:?}"
    );
    // The bound is loose (it uses the softest anchor direction); the answer is much closer.
    assert!(worst < 1e-4, "{worst} m is more than 0.1 % of an edge");
}

#[test]
fn rigidly_translated_anchors_carry_the_skin_rigidly() {
    // Closed form: with every anchor translated by d, rest + d has zero spring and anchor force.
    const D: Vec3 = Vec3::new(0.03, -0.02, 0.05);
    let d = D;
    let (mut world, mut schedule) = world_with(|p, f| p + (f.min(5) as f32 / 5.0) * D);
    let mesh = sheet(12);
    let skin = SkinBuilder::new(mesh.clone(), SkinMaterial::default())
        .with_stiffness_rule(StiffnessRule::poisson(0.3))
        .with_rest_anchors(K_NORMAL, K_TANGENT)
        .spawn(&mut world)
        .unwrap();
    for _ in 0..25 {
        schedule.run(&mut world);
    }
    let diag = world.get::<RelaxDiagnostics>(skin).unwrap();
    let bound = distance_bound(diag.residual, diag.force_scale_n).max(1e-6);
    for (i, (x, p)) in skin_positions(&world, skin)
        .unwrap()
        .iter()
        .zip(mesh.positions())
        .enumerate()
    {
        let err = x.distance(*p + d);
        assert!(err <= bound, "vertex {i} off by {err} m (bound {bound})");
    }
}

#[test]
fn per_entity_relax_settings_override_the_global_config() {
    let (mut world, mut schedule) = world_with(stretch);
    world.resource_mut::<DermisConfig>().relax.max_iterations = 3;
    let capped = SkinBuilder::new(sheet(10), SkinMaterial::default())
        .with_rest_anchors(K_NORMAL, K_TANGENT)
        .spawn(&mut world)
        .unwrap();
    let free = SkinBuilder::new(sheet(10), SkinMaterial::default())
        .with_rest_anchors(K_NORMAL, K_TANGENT)
        .with_relax_settings(RelaxSettings {
            max_iterations: 1000,
            ..RelaxSettings::DEFAULT
        })
        .spawn(&mut world)
        .unwrap();
    schedule.run(&mut world);
    let capped = world.get::<RelaxDiagnostics>(capped).unwrap();
    let free = world.get::<RelaxDiagnostics>(free).unwrap();
    assert_eq!(capped.iterations, 3);
    assert_eq!(capped.stop, Some(dermis::solver::StopReason::Budget));
    assert!(free.iterations > 3, "{free:?}");
    assert_ne!(free.stop, Some(dermis::solver::StopReason::Budget));
}

#[test]
fn the_anchors_motion_warm_starts_the_next_frame() {
    // Translation invariance: an equilibrium under anchors moved by d is the old one moved by d.
    // Each frame starts from the skin carried by its anchors' motion since the last solve (since
    // the spawn for the first), so a rigid translation of the anchors costs no iteration at all,
    // where a start from last frame's positions needs many.
    const D: Vec3 = Vec3::new(0.01, -0.004, 0.02);
    let (mut world, mut schedule) = world_with(|p, f| p + f as f32 * D);
    let skin = SkinBuilder::new(sheet(10), SkinMaterial::default())
        .with_stiffness_rule(StiffnessRule::poisson(0.3))
        .with_rest_anchors(K_NORMAL, K_TANGENT)
        .spawn(&mut world)
        .unwrap();
    let rest = sheet(10);
    let mut stale = rest.positions().to_vec();
    for frame in 1..6 {
        let before = skin_positions(&world, skin).unwrap().to_vec();
        schedule.run(&mut world);
        let diag = world.get::<RelaxDiagnostics>(skin).unwrap();
        assert_eq!(diag.iterations, 0, "frame {frame}: {diag:?}");
        assert_eq!(diag.stop, Some(StopReason::Converged));
        for (x, b) in skin_positions(&world, skin).unwrap().iter().zip(&before) {
            assert!(
                x.distance(*b + D) < 1e-6,
                "frame {frame}: {x} vs {}",
                *b + D
            );
        }
        // The same frame started from last frame's positions: the pure solver needs iterations.
        let system = world
            .get::<SkinSprings>(skin)
            .unwrap()
            .system()
            .unwrap()
            .clone();
        let anchors = world.get::<SkinAnchors>(skin).unwrap().to_vec();
        let loads = Loads {
            anchors: Some(&anchors),
            ..Default::default()
        };
        let config = RelaxConfig {
            force_scale: Some(diag.force_scale_n),
            ..RelaxConfig::DEFAULT
        };
        let report = system.relax(&mut stale, &loads, &config).unwrap();
        assert!(report.iterations > 5, "frame {frame}: {report:?}");
    }
}
