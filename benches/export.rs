//! Cost of exporting one frame of a 10 000-vertex skin (100 × 100 grid, 19 602 triangles) in
//! each format, strain colours on: `begin` (validation, rest metric), one `write_frame`
//! (normals, strain, formatting) and `finish` (the atomic write), into a temporary directory.
//!
//! Run: `cargo bench --bench export`.

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use dermis::export::{ExportMeta, ExportOptions, Format, MeshMeta, MeshRole};
use glam::Vec3;

fn skin(n: u32) -> (Vec<Vec3>, Vec<[u32; 3]>, Vec<Vec3>) {
    let rest: Vec<Vec3> = (0..n * n)
        .map(|i| Vec3::new(0.01 * (i % n) as f32, 0.01 * (i / n) as f32, 0.0))
        .collect();
    let mut t = Vec::new();
    for y in 0..n - 1 {
        for x in 0..n - 1 {
            let v = y * n + x;
            t.push([v, v + 1, v + n + 1]);
            t.push([v, v + n + 1, v + n]);
        }
    }
    let moved = rest
        .iter()
        .map(|p| {
            Vec3::new(
                1.05 * p.x,
                p.y,
                0.02 * (20.0 * p.x).sin() * (15.0 * p.y).cos(),
            )
        })
        .collect();
    (rest, t, moved)
}

fn export_one_frame(c: &mut Criterion) {
    let (rest, triangles, moved) = skin(100);
    let meta = ExportMeta::new(
        vec![MeshMeta::new("skin", MeshRole::Skin, triangles, rest)],
        30.0,
    );
    let dir = tempfile::tempdir().unwrap();
    let options = ExportOptions::default();
    let mut group = c.benchmark_group("export_one_frame_10k");
    group.sample_size(20);
    for format in Format::ALL {
        let out = dir.path().join(format!("bench.{format}"));
        group.bench_function(format.extension(), |b| {
            b.iter(|| {
                let mut sink = format.sink(&out, &options);
                sink.begin(&meta).unwrap();
                sink.write_frame(0, &[&moved]).unwrap();
                black_box(sink.finish().unwrap());
            });
        });
    }
    group.finish();
}

criterion_group!(benches, export_one_frame);
criterion_main!(benches);
