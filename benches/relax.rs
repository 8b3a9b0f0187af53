//! Relaxation benchmarks: one NCG iteration and a warm-started frame on skin tubes of 10k and
//! 100k vertices, plus stiffness assembly. See `benches/README.md`.

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use dermis::mesh::shapes::tube;
use dermis::solver::{Loads, RelaxConfig, SpringSystem, VertexAnchor};
use dermis::stiffness::{Modulus, StiffnessRule};
use glam::Vec3;

fn relax(c: &mut Criterion) {
    let mut group = c.benchmark_group("relax");
    group.sample_size(10);
    for (around, along) in [(100u32, 100u32), (316, 316)] {
        let mesh = tube(around, along, 0.05, 0.4);
        let n = mesh.positions().len();
        let k = StiffnessRule::AreaOverLengthSquared
            .edge_stiffness(&mesh, &Modulus::Uniform(1000.0))
            .unwrap();
        let system = SpringSystem::from_mesh(&mesh, &k).unwrap();
        // Anchors pulled 1 cm outwards along the normal, as a deforming body would.
        let anchors: Vec<VertexAnchor> = mesh
            .positions()
            .iter()
            .map(|p| {
                let normal = Vec3::new(p.x, p.y, 0.0).normalize();
                let bulge = 0.01 * (p.z * 20.0).sin();
                VertexAnchor {
                    target: *p + normal * bulge,
                    normal,
                    k_normal: 200.0,
                    k_tangent: 20.0,
                }
            })
            .collect();
        let loads = Loads {
            anchors: Some(&anchors),
            ..Default::default()
        };
        group.throughput(Throughput::Elements(n as u64 * 30));
        group.bench_with_input(BenchmarkId::new("30-iterations", n), &n, |b, _| {
            let config = RelaxConfig {
                max_iterations: 30,
                tolerance: 0.0,
                stagnation_window: 0,
                ..RelaxConfig::DEFAULT
            };
            b.iter(|| {
                let mut x = mesh.positions().to_vec();
                system.relax(&mut x, &loads, &config).unwrap()
            })
        });
        group.throughput(Throughput::Elements(mesh.topology().edges().len() as u64));
        group.bench_with_input(BenchmarkId::new("stiffness-area-len2", n), &n, |b, _| {
            b.iter(|| {
                StiffnessRule::AreaOverLengthSquared
                    .edge_stiffness(&mesh, &Modulus::Uniform(1000.0))
                    .unwrap()
            })
        });
    }
    group.finish();
}

criterion_group!(benches, relax);
criterion_main!(benches);
