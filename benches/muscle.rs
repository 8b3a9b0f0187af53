//! Particle-steps per second of a free muscle lattice of about 10k particles (springs, pressure
//! cells, velocity Verlet with drag), at activation 0.5.
//!
//! Run with `cargo bench --bench muscle`.

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use dermis::anatomy::dynamics::{AnatomySystem, DynamicsConfig};
use dermis::anatomy::lattice::{MuscleConfig, MuscleLattice};
use dermis::anatomy::scenes::tube_mesh;
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

criterion_group!(benches, bench_muscle);
criterion_main!(benches);
