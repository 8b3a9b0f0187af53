//! Vertex–collider queries per second against a deforming 50k-triangle muscle, with and without
//! the contact cache, next to one parry `project_point` per vertex in the same run.
//!
//! Run with `cargo bench --bench collision`. Each timed iteration is one contact pass over the
//! whole skin after the muscle moved to its next deformation phase (the refit is untimed here
//! and measured on its own as `collider_refit`).
//!
//! Measured 2026-11-22 00:12 UTC on the shared 2-core machine while others were building
//! (absolute times drift by ±30 % or more between runs; compare the ratios within one run),
//! 2 threads, `cargo bench --bench collision`:
//!
//! | variant | 10k vertices | 100k vertices |
//! |---|---|---|
//! | parry `project_point` per vertex, 1 pass | 30.8 ms (324 k/s) | 265 ms (378 k/s) |
//! | contact pass, cache cleared | 37.3 ms (268 k/s), 0.83x | 207 ms (484 k/s), 1.28x |
//! | contact pass, cached | 23.7 ms (422 k/s), 1.30x | 202 ms (496 k/s), 1.31x |
//! | parry, 10 passes per muscle frame | 218 ms (459 k/s) | 2.52 s (397 k/s) |
//! | contact, 10 passes per muscle frame, cached | 125 ms (800 k/s), 1.74x | 1.52 s (657 k/s), 1.66x |
//!
//! Refit of the 50k-triangle muscle: 1.06 ms. A contact pass does more than the naive query
//! (signs from feature normals, pushes, a re-check of every pushed vertex: about 1.2-1.3 BVH
//! queries per vertex in the contact band); the cache bounds the BVH search with the cached
//! triangle's distance (75 % of searches end on it) and skips vertices whose distance bound
//! clears the band (19 % per frame, 43 % between relaxation passes).

use std::hint::black_box;
use std::time::{Duration, Instant};

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use dermis::collision::{
    ColliderId, ColliderMesh, ContactConfig, SkinCollision, shapes::ellipsoid,
};
use glam::Vec3;
use parry3d::math::Pose;
use parry3d::query::PointQuery;
use rayon::prelude::*;

const THICKNESS_M: f32 = 0.002;
const PHASES: usize = 8;
const RELAX_PASSES: usize = 10;

/// Moves every skin vertex by up to a fifth of a thickness, as a relaxation step might.
fn jiggle(x: &mut [Vec3], pass: usize) {
    for (i, p) in x.iter_mut().enumerate() {
        let s = ((i * 31 + pass * 17) % 97) as f32 / 97.0 - 0.5;
        *p += Vec3::new(s, -s, 0.5 * s) * (0.4 * THICKNESS_M);
    }
}

/// A biceps-sized ellipsoid of 2 × 200 × 125 = 50,000 triangles.
fn muscle() -> (Vec<Vec3>, Vec<[u32; 3]>) {
    ellipsoid(Vec3::ZERO, Vec3::new(0.04, 0.035, 0.15), 126, 200).expect("valid resolution")
}

/// A contraction cycle: the belly bulges and shortens, a little per frame.
fn phases(rest: &[Vec3]) -> Vec<Vec<Vec3>> {
    (0..PHASES)
        .map(|k| {
            let a = 0.02 * (std::f32::consts::TAU * k as f32 / PHASES as f32).sin();
            rest.iter()
                .map(|p| {
                    let belly = 1.0 + a * (1.0 - (p.z / 0.15).powi(2));
                    Vec3::new(p.x * belly, p.y * belly, p.z * (1.0 - 0.5 * a))
                })
                .collect()
        })
        .collect()
}

/// Skin vertices on a lat-long grid around the muscle, from half a thickness to three
/// thicknesses off its surface (some pushed, some touching, some clear).
fn skin(n: usize) -> Vec<Vec3> {
    let side = (n as f32).sqrt().ceil() as usize;
    let mut out = Vec::with_capacity(n);
    for k in 0..n {
        let (i, j) = (k % side, k / side);
        let theta = std::f32::consts::PI * (j as f32 + 0.5) / side as f32;
        let phi = std::f32::consts::TAU * i as f32 / side as f32;
        let unit = Vec3::new(
            theta.sin() * phi.cos(),
            theta.sin() * phi.sin(),
            theta.cos(),
        );
        let offset = THICKNESS_M * (0.5 + 2.5 * ((k * 7919) % 101) as f32 / 100.0);
        let on = unit * Vec3::new(0.04, 0.035, 0.15);
        out.push(on + on.normalize() * offset);
    }
    out
}

fn collision(c: &mut Criterion) {
    let (rest, tris) = muscle();
    let frames = phases(&rest);
    let config = ContactConfig {
        thickness_m: THICKNESS_M,
        ..ContactConfig::DEFAULT
    };

    let mut refit = ColliderMesh::from_mesh(rest.clone(), tris.clone()).expect("closed mesh");
    let mut k = 0;
    c.bench_function("collider_refit/50k_triangles", |b| {
        b.iter(|| {
            k = (k + 1) % PHASES;
            refit.set_vertices(&frames[k]).expect("same vertex count");
        })
    });

    let mut group = c.benchmark_group("collision_pass");
    group
        .sample_size(10)
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(4));
    for n in [10_000usize, 100_000] {
        let base = skin(n);
        // (name, passes per muscle frame): one pass per frame, or a relaxation-like frame of
        // `RELAX_PASSES` passes with the skin moving a little between them.
        let variants = [
            ("naive_parry", 1),
            ("uncached", 1),
            ("cached", 1),
            ("naive_parry_relax", RELAX_PASSES),
            ("cached_relax", RELAX_PASSES),
        ];
        for (variant, passes) in variants {
            group.throughput(Throughput::Elements((n * passes) as u64));
            let mut contact = SkinCollision::new(n, config).expect("valid config");
            let muscle = contact.add_collider(
                ColliderMesh::from_mesh(rest.clone(), tris.clone()).expect("closed mesh"),
            );
            let mut x = base.clone();
            let mut phase = 0;
            let naive = variant.starts_with("naive");
            group.bench_function(BenchmarkId::new(variant, n), |b| {
                b.iter_custom(|iters| {
                    let mut total = Duration::ZERO;
                    for _ in 0..iters {
                        phase = (phase + 1) % PHASES;
                        set_phase(&mut contact, muscle, &frames[phase]);
                        x.copy_from_slice(&base);
                        if variant == "uncached" {
                            contact.clear_cache();
                        }
                        for pass in 0..passes {
                            if pass > 0 {
                                jiggle(&mut x, pass);
                            }
                            let start = Instant::now();
                            if naive {
                                let mesh = contact
                                    .collider(muscle)
                                    .expect("added")
                                    .parry_mesh()
                                    .expect("a mesh");
                                let d: f32 = x
                                    .par_iter()
                                    .map(|p| mesh.project_point(&Pose::IDENTITY, *p, false).point.x)
                                    .sum();
                                black_box(d);
                            } else {
                                black_box(contact.contact_pass(&mut x).expect("right length"));
                            }
                            total += start.elapsed();
                        }
                    }
                    total
                })
            });
            if !naive {
                let d = contact.diagnostics();
                let per = |v: u64| v as f64 / d.passes.max(1) as f64;
                eprintln!(
                    "{variant} {n}: per pass {:.0} BVH queries ({:.0} hinted hits), {:.0} bound skips, {:.0} box skips",
                    per(d.exact_queries),
                    per(d.cache_hits),
                    per(d.skipped_bound),
                    per(d.skipped_aabb)
                );
            }
        }
    }
    group.finish();
}

fn set_phase(contact: &mut SkinCollision, muscle: ColliderId, vertices: &[Vec3]) {
    contact
        .collider_mut(muscle)
        .expect("added")
        .set_vertices(vertices)
        .expect("same vertex count");
}

criterion_group!(benches, collision);
criterion_main!(benches);
