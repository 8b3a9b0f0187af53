//! Vertex–collider queries against a deforming 50k-triangle muscle, with and without the contact
//! cache, next to one parry `project_point` per vertex in the same run; and whole frames (the
//! muscle deforms once, then `PASSES` relaxation-like contact passes) for the amortised cost per
//! skin vertex per frame.
//!
//! Run with `nice cargo bench --bench collision` (figures in benches/README.md: with the patch
//! certificates a 30-pass frame is 4-5x faster than 30 naive passes under `decaying` motion,
//! 3.5x under `steady`, 1.5x under `old_jiggle`). Criterion
//! times the kernels (`collider_refit`, `collision_pass/*` one pass after the muscle moved,
//! `collision_frame/*` one whole frame); a summary printed at the end times frames and naive
//! passes side by side in the same run (median of `SUMMARY_FRAMES` frames) with the cache's
//! counters, through `dermis::collision::bench_support`.
//!
//! Motion between passes: each skin vertex moves by `amplitude × u` with `u` a fixed
//! pseudo-random vector per vertex and pass (|u| ≤ 1). `decaying`: amplitude 5 % of the
//! thickness at the first pass, × 0.85 per pass (a converging relaxation: 0.33 thickness in
//! all); `steady`: 5 % of the thickness at every pass (1.5 thicknesses in all, a worst case for
//! the certificates); `old_jiggle`: the motion of the first version of this bench, up to 30 %
//! of the thickness per pass.

use std::hint::black_box;
use std::time::{Duration, Instant};

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use dermis::collision::bench_support::{frame_cost, naive_pass_seconds};
use dermis::collision::{
    ColliderId, ColliderMesh, ContactConfig, SkinCollision, shapes::ellipsoid,
};
use glam::Vec3;

const THICKNESS_M: f32 = 0.002;
const PHASES: usize = 8;
/// Contact passes per frame: a relaxation projects after every accepted step (20-60).
const PASSES: usize = 30;
const SUMMARY_FRAMES: usize = 5;

#[derive(Clone, Copy, PartialEq, Eq, Debug)]
enum Motion {
    Decaying,
    Steady,
    OldJiggle,
}

impl Motion {
    fn name(self) -> &'static str {
        match self {
            Motion::Decaying => "decaying",
            Motion::Steady => "steady",
            Motion::OldJiggle => "old_jiggle",
        }
    }

    /// Moves every skin vertex before pass `pass` (≥ 1) of a frame.
    fn apply(self, x: &mut [Vec3], pass: usize) {
        let amplitude = match self {
            Motion::Decaying => 0.05 * THICKNESS_M * 0.85f32.powi(pass as i32 - 1),
            Motion::Steady => 0.05 * THICKNESS_M,
            Motion::OldJiggle => {
                for (i, p) in x.iter_mut().enumerate() {
                    let s = ((i * 31 + pass * 17) % 97) as f32 / 97.0 - 0.5;
                    *p += Vec3::new(s, -s, 0.5 * s) * (0.4 * THICKNESS_M);
                }
                return;
            }
        };
        for (i, p) in x.iter_mut().enumerate() {
            let h = |k: usize| ((i * 7919 + pass * 104_729 + k * 1_299_709) % 1000) as f32 / 1000.0;
            let u = Vec3::new(h(0) - 0.5, h(1) - 0.5, h(2) - 0.5) * (2.0 / 3f32.sqrt());
            *p += u * amplitude;
        }
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

fn setup(n: usize, rest: &[Vec3], tris: &[[u32; 3]]) -> (SkinCollision, ColliderId) {
    let config = ContactConfig {
        thickness_m: THICKNESS_M,
        ..ContactConfig::DEFAULT
    };
    let mut contact = SkinCollision::new(n, config).expect("valid config");
    let muscle = contact
        .add_collider(ColliderMesh::from_mesh(rest.to_vec(), tris.to_vec()).expect("closed mesh"));
    (contact, muscle)
}

/// One frame: the muscle moves to `phase`, the skin restarts from `base`, `PASSES` contact
/// passes with `motion` between them. Returns the contact time (the refit is not included).
fn frame(
    contact: &mut SkinCollision,
    muscle: ColliderId,
    vertices: &[Vec3],
    base: &[Vec3],
    x: &mut [Vec3],
    motion: Motion,
) -> Duration {
    set_phase(contact, muscle, vertices);
    x.copy_from_slice(base);
    // Diagnostics count from here; the substep plan is not used (the passes are the frame,
    // on a copy so `x` stays as it is).
    contact
        .begin_frame(&mut x.to_vec())
        .expect("finite positions");
    let mut total = Duration::ZERO;
    for pass in 0..PASSES {
        if pass > 0 {
            motion.apply(x, pass);
        }
        let start = Instant::now();
        black_box(contact.contact_pass(x).expect("right length"));
        total += start.elapsed();
    }
    total
}

fn collision(c: &mut Criterion) {
    let (rest, tris) = muscle();
    let frames = phases(&rest);

    let mut refit = ColliderMesh::from_mesh(rest.clone(), tris.clone()).expect("closed mesh");
    let mut k = 0;
    // The whole refit (`set_vertices`, then every part refitted in parallel), and
    // `set_vertices` alone (the parts then wait for the queries that reach them).
    c.bench_function("collider_refit/50k_triangles", |b| {
        b.iter(|| {
            k = (k + 1) % PHASES;
            refit.set_vertices(&frames[k]).expect("same vertex count");
            refit.refit_all();
        })
    });
    c.bench_function("collider_refit/50k_triangles_deferred", |b| {
        b.iter(|| {
            k = (k + 1) % PHASES;
            refit.set_vertices(&frames[k]).expect("same vertex count");
        })
    });

    let mut group = c.benchmark_group("collision_pass");
    group
        .sample_size(10)
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(3));
    for n in [10_000usize, 100_000] {
        let base = skin(n);
        group.throughput(Throughput::Elements(n as u64));
        for variant in ["naive_parry", "uncached", "cached"] {
            let (mut contact, muscle) = setup(n, &rest, &tris);
            let mut x = base.clone();
            let mut phase = 0;
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
                        total += if variant == "naive_parry" {
                            Duration::from_secs_f64(naive_pass_seconds(&contact, &x))
                        } else {
                            let start = Instant::now();
                            black_box(contact.contact_pass(&mut x).expect("right length"));
                            start.elapsed()
                        };
                    }
                    total
                })
            });
        }
    }
    group.finish();

    let mut group = c.benchmark_group("collision_frame");
    group
        .sample_size(10)
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(4));
    for n in [10_000usize, 100_000] {
        let base = skin(n);
        // Throughput per skin vertex per frame.
        group.throughput(Throughput::Elements(n as u64));
        for motion in [Motion::Decaying, Motion::Steady] {
            let (mut contact, muscle) = setup(n, &rest, &tris);
            let mut x = base.clone();
            let mut phase = 0;
            group.bench_function(BenchmarkId::new(motion.name(), n), |b| {
                b.iter_custom(|iters| {
                    (0..iters)
                        .map(|_| {
                            phase = (phase + 1) % PHASES;
                            frame(&mut contact, muscle, &frames[phase], &base, &mut x, motion)
                        })
                        .sum()
                })
            });
        }
    }
    group.finish();

    summary(&rest, &tris, &frames);
}

/// Frames and naive passes timed side by side in one run.
fn summary(rest: &[Vec3], tris: &[[u32; 3]], frames: &[Vec<Vec3>]) {
    eprintln!(
        "\nsummary: {PASSES} passes per frame, {} muscle triangles, medians of {SUMMARY_FRAMES} frames",
        tris.len()
    );
    eprintln!(
        "{:>7} {:>10} | {:>10} {:>10} {:>10} | {:>9} {:>9} | {:>8} {:>8} {:>8}",
        "skin",
        "motion",
        "naive/pass",
        "us/v/pass",
        "us/v/frame",
        "naive/frm",
        "speed-up",
        "search/v",
        "cert/v",
        "skip/v"
    );
    // `COLLISION_SUMMARY_ONLY_10K=1`: the 10k skin only (quick tuning runs).
    let sizes: &[usize] = if std::env::var_os("COLLISION_SUMMARY_ONLY_10K").is_some() {
        &[10_000]
    } else {
        &[10_000, 100_000]
    };
    for &n in sizes {
        let base = skin(n);
        for motion in [Motion::Decaying, Motion::Steady, Motion::OldJiggle] {
            let (mut contact, muscle) = setup(n, rest, tris);
            let mut x = base.clone();
            // Warm-up frames fill the cache as a running animation would.
            for vertices in &frames[..2] {
                frame(&mut contact, muscle, vertices, &base, &mut x, motion);
            }
            let mut costs = Vec::new();
            for k in 0..SUMMARY_FRAMES {
                let phase = (k + 2) % PHASES;
                let t = frame(&mut contact, muscle, &frames[phase], &base, &mut x, motion);
                costs.push(frame_cost(&contact, &x, t.as_secs_f64(), PASSES as u64));
            }
            costs.sort_by(|a, b| a.us_per_vertex.total_cmp(&b.us_per_vertex));
            let mut naive: Vec<f64> = costs.iter().map(|c| c.naive_us_per_vertex).collect();
            naive.sort_by(f64::total_cmp);
            let (c, naive_frame) = (costs[SUMMARY_FRAMES / 2], naive[SUMMARY_FRAMES / 2]);
            eprintln!(
                "{n:>7} {:>10} | {:>10.3} {:>10.4} {:>10.3} | {:>9.2} {:>8.1}x | {:>8.2} {:>8.2} {:>8.2}",
                motion.name(),
                naive_frame / PASSES as f64,
                c.us_per_vertex / PASSES as f64,
                c.us_per_vertex,
                naive_frame,
                naive_frame / c.us_per_vertex,
                c.searches_per_vertex,
                c.certified_per_vertex,
                c.skipped_per_vertex
            );
        }
    }
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
