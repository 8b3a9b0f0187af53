//! Linear blend skinning on the CPU: 10k and 100k vertices, 4 influences each, 64 joints.
//!
//! Run with `cargo bench --bench skinning`.

use std::hint::black_box;

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use dermis::animation::{Influences, skin_positions};
use glam::{Mat4, Quat, Vec3};

const JOINTS: u32 = 64;

fn setup(n: usize) -> (Vec<Vec3>, Influences, Vec<Mat4>) {
    let positions: Vec<Vec3> = (0..n)
        .map(|i| {
            let t = i as f32 / n as f32;
            Vec3::new(t, (t * 37.0).sin() * 0.1, (t * 37.0).cos() * 0.1)
        })
        .collect();
    let joints: Vec<u32> = (0..n)
        .flat_map(|i| {
            let j = (i as u32 * JOINTS / n as u32).min(JOINTS - 4);
            [j, j + 1, j + 2, j + 3]
        })
        .collect();
    let weights: Vec<f32> = (0..n).flat_map(|_| [0.4, 0.3, 0.2, 0.1]).collect();
    let influences = Influences::new(4, joints, weights).expect("consistent lengths");
    let matrices = (0..JOINTS)
        .map(|j| {
            Mat4::from_rotation_translation(
                Quat::from_rotation_z(j as f32 * 0.05),
                Vec3::new(j as f32 * 0.01, 0.0, 0.0),
            )
        })
        .collect();
    (positions, influences, matrices)
}

fn lbs(c: &mut Criterion) {
    let mut group = c.benchmark_group("lbs_4_influences");
    for n in [10_000usize, 100_000] {
        let (positions, influences, matrices) = setup(n);
        group.throughput(Throughput::Elements(n as u64));
        group.bench_with_input(BenchmarkId::from_parameter(n), &n, |b, _| {
            b.iter(|| skin_positions(black_box(&positions), &influences, &matrices));
        });
    }
    group.finish();
}

criterion_group!(benches, lbs);
criterion_main!(benches);
