//! Particle-steps per second of a free muscle lattice of about 10k particles (springs, pressure
//! cells, velocity Verlet with drag), at activation 0.5; and the cost of one ECS frame of the
//! jaw scene (`spawn_jaw` in a `World` + dermis `Schedule`: inputs, steps, collider outputs)
//! against the same steps on the bare `AnatomySystem`, and with a skin sleeve relaxed over it.
//!
//! Run with `cargo bench --bench muscle`.

use bevy_ecs::prelude::*;
use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use dermis::anatomy::dynamics::{AnatomySystem, DynamicsConfig};
use dermis::anatomy::lattice::{MuscleConfig, MuscleLattice};
use dermis::anatomy::scenes::tube_mesh;
use dermis::anatomy::scenes::{JawConfig, jaw};
use dermis::ecs::{DermisPlugin, JawSkinConfig, MuscleActivation, spawn_jaw};
use glam::Vec3;

fn muscle_system() -> (AnatomySystem, usize) {
    let surface = tube_mesh(Vec3::ZERO, Vec3::new(0.0, 0.0, 0.1), 0.01, 48, 20).expect("tube");
    let line = [Vec3::new(0.0, 0.0, 0.001), Vec3::new(0.0, 0.0, 0.099)];
    let config = MuscleConfig {
        sections: 40,
        cell_area_m2: 6e-7,
        ..MuscleConfig::default()
    };
    let lattice = MuscleLattice::build(&surface, &line, config).expect("lattice");
    let mut system = AnatomySystem::new(DynamicsConfig {
        dt_s: 1e-4,
        substeps: 1,
        drag: 0.01,
        gravity: Vec3::ZERO,
    })
    .expect("system");
    let m = system.add_muscle(&lattice).expect("muscle");
    system.set_activation(m, 0.5).expect("activation");
    (system, m)
}

fn bench_muscle(c: &mut Criterion) {
    let (mut system, _) = muscle_system();
    let particles = system.positions().len();
    let mut group = c.benchmark_group("muscle");
    group.throughput(Throughput::Elements(particles as u64));
    group.bench_function(format!("step_{particles}_particles"), |b| {
        b.iter(|| system.step().expect("step"));
    });
    group.finish();
}

/// Steps per frame of the jaw comparison: 1 isolates the per-frame ECS overhead, 40 is the
/// `dermis anatomy jaw` default.
const JAW_STEPS: [u32; 2] = [1, 40];

fn bench_jaw_ecs(c: &mut Criterion) {
    let mut group = c.benchmark_group("jaw_frame");
    for steps in JAW_STEPS {
        let mut scene = jaw(&JawConfig::default()).expect("jaw");
        scene
            .system
            .set_activation(scene.muscle, 0.5)
            .expect("activation");
        group.bench_function(format!("bare_{steps}_steps"), |b| {
            b.iter(|| {
                for _ in 0..steps {
                    scene.system.step().expect("step");
                }
            });
        });
        for skin in [None, Some(JawSkinConfig::default())] {
            if skin.is_some() && steps == 1 {
                continue;
            }
            let mut world = World::new();
            let mut schedule = DermisPlugin.build_schedule(&mut world);
            let spawned =
                spawn_jaw(&mut world, &JawConfig::default(), steps, skin.as_ref()).expect("spawn");
            world
                .get_mut::<MuscleActivation>(spawned.muscle)
                .expect("muscle")
                .0 = 0.5;
            let name = if skin.is_some() {
                "ecs_with_skin"
            } else {
                "ecs"
            };
            group.bench_function(format!("{name}_{steps}_steps"), |b| {
                b.iter(|| schedule.run(&mut world));
            });
        }
    }
    group.finish();
}

criterion_group!(benches, bench_muscle, bench_jaw_ecs);
criterion_main!(benches);
