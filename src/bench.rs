//! Standard performance workloads and an in-run machine calibration, behind `dermis bench`.
//!
//! Every figure comes with the calibration measured in the same process (memory bandwidth and
//! the cost of one spring evaluation), so results from different machines, or from the same
//! noisy machine at different times, compare as ratios.

mod previous;

use std::time::Instant;

use glam::Vec3;
use rayon::prelude::*;
use serde::Serialize;

use crate::mesh::TriMesh;
use crate::mesh::shapes::tube;
use crate::solver::{Loads, RelaxConfig, SpringSystem, VertexAnchor};
use crate::stiffness::{Modulus, StiffnessRule};

/// Bytes the relaxation must stream per vertex and iteration at the least: a position and three
/// springs (other index, stiffness, rest length, and the neighbour's position) — the figure the
/// floor is computed from.
pub const MIN_BYTES_PER_VERTEX_ITERATION: f64 = 72.0;

/// What the machine can do, measured in this process.
#[derive(Debug, Clone, Serialize)]
pub struct Machine {
    /// Rayon threads.
    pub threads: usize,
    /// Triad (`a = b + s·c`, f32) bandwidth over arrays far larger than the caches, GB/s.
    pub bandwidth_gb_s: f64,
    /// Time of one spring force evaluation in a tight, vectorisable loop, ns (all threads).
    pub spring_ns: f64,
}

/// Measures the machine (about a second).
pub fn calibrate(quick: bool) -> Machine {
    let n = if quick { 4 << 20 } else { 16 << 20 };
    let b = vec![1.0f32; n];
    let c = vec![2.0f32; n];
    let mut a = vec![0.0f32; n];
    let mut best = f64::INFINITY;
    for _ in 0..if quick { 3 } else { 6 } {
        let t = Instant::now();
        a.par_chunks_mut(1 << 16)
            .zip(b.par_chunks(1 << 16))
            .zip(c.par_chunks(1 << 16))
            .for_each(|((a, b), c)| {
                for ((a, b), c) in a.iter_mut().zip(b).zip(c) {
                    *a = b + 1.5 * c;
                }
            });
        best = best.min(t.elapsed().as_secs_f64());
    }
    std::hint::black_box(&a);
    let bandwidth_gb_s = 3.0 * 4.0 * n as f64 / best / 1e9;

    // Springs between consecutive points of an array that fits in L2.
    let m = 1 << 14;
    let p: Vec<Vec3> = (0..m)
        .map(|i| Vec3::new(i as f32, (i as f32).sin(), 0.0))
        .collect();
    let rounds = if quick { 64 } else { 256 };
    let t = Instant::now();
    let total: f32 = (0..rounds)
        .into_par_iter()
        .map(|r| {
            let mut f = Vec3::ZERO;
            for i in 0..m - 1 {
                let d = p[i + 1] - p[i];
                let len = d.length();
                f += d * ((len - 1.0 - r as f32 * 1e-6) / len);
            }
            f.x + f.y
        })
        .sum();
    std::hint::black_box(total);
    let spring_ns = t.elapsed().as_secs_f64() * 1e9 / (rounds * (m - 1)) as f64;
    Machine {
        threads: rayon::current_num_threads(),
        bandwidth_gb_s,
        spring_ns,
    }
}

/// A relaxation workload: a skin tube with anchors that a bulging body moves every frame.
#[derive(Debug, Clone)]
pub struct TubeWorkload {
    /// Name in the report (`tube-10k`, ...).
    pub name: &'static str,
    /// The skin.
    pub mesh: TriMesh,
    /// Its springs (Eq. 29, `E2` = 1000 N/m).
    pub system: SpringSystem,
}

impl TubeWorkload {
    /// A tube of about `vertices` vertices, 10 cm across and 40 cm long.
    pub fn new(name: &'static str, vertices: usize) -> Self {
        let around = ((vertices as f64 * 0.25 * std::f64::consts::PI)
            .sqrt()
            .round() as u32)
            .max(8);
        let along = (vertices as u32).div_ceil(around).max(2);
        let mesh = tube(around, along, 0.05, 0.4);
        let k = StiffnessRule::AreaOverLengthSquared
            .edge_stiffness(&mesh, &Modulus::Uniform(1000.0))
            .expect("valid tube");
        let system = SpringSystem::from_mesh(&mesh, &k).expect("valid springs");
        Self { name, mesh, system }
    }

    /// Anchors of frame `frame`: the body under the skin bulges (a travelling radial wave of
    /// up to 1 cm), pulling the skin along its normals.
    pub fn anchors(&self, frame: usize) -> Vec<VertexAnchor> {
        let phase = frame as f32 * 0.05;
        self.mesh
            .positions()
            .iter()
            .map(|p| {
                let normal = Vec3::new(p.x, p.y, 0.0).normalize_or_zero();
                let bulge = 0.01 * (p.z * 15.0 - phase).sin() * (phase * 0.5).sin();
                VertexAnchor {
                    target: *p + normal * bulge,
                    normal,
                    k_normal: 200.0,
                    k_tangent: 20.0,
                }
            })
            .collect()
    }
}

/// One workload's figures.
#[derive(Debug, Clone, Serialize)]
pub struct WorkloadReport {
    /// Workload name.
    pub name: &'static str,
    /// Skin vertices.
    pub skin_vertices: usize,
    /// Collider triangles (0 until collision is part of the workload).
    pub collider_triangles: usize,
    /// Median frame time (warm-started relaxation to the default tolerance), ms.
    pub frame_ms_median: f64,
    /// 99th-percentile frame time, ms.
    pub frame_ms_p99: f64,
    /// Mean relaxation iterations per frame.
    pub iterations_per_frame_mean: f64,
    /// Vertex-iterations per second over a fixed 30-iteration relaxation.
    pub relax_vertex_iterations_per_s: f64,
    /// The floor time of those iterations (bandwidth- or compute-bound, from the calibration)
    /// over the measured time: 1 would be at the machine's limit.
    pub relax_fraction_of_floor: f64,
    /// Collision time per skin vertex per frame, µs (`None` until collision is benchmarked).
    pub collision_us_per_vertex: Option<f64>,
    /// Collision speed-up over one naive parry query per vertex (`None` until then).
    pub collision_speedup_vs_naive: Option<f64>,
    /// Bytes of solver state per skin vertex (springs, CSR and the solver's vectors).
    pub bytes_per_vertex: f64,
    /// 30-iteration time on 1 thread over the time on all threads.
    pub thread_scaling_2_over_1: f64,
    /// 30-iteration time of the solver before the issue-8 kernels (kept in the bench as a
    /// baseline) over the time of the current one, both on one thread, measured in this run.
    pub relax_speedup_vs_previous: f64,
    /// Energy after 30 iterations of that previous solver, J (compare with `energy_after_30`).
    pub previous_energy_after_30: f64,
    /// Time of one iteration of [`naive_scatter`] (the plain scalar kernel: edge list,
    /// force scatter, damped Verlet) over the time of one relaxation iteration, both on one
    /// thread, measured in this run.
    pub relax_speedup_vs_naive_scatter: f64,
    /// Total energy after 30 iterations from the same start, J (speed must not be bought by
    /// doing less work).
    pub energy_after_30: f64,
}

/// Runs one workload: `frames` animation frames, then the fixed 30-iteration measurements.
pub fn run_workload(work: &TubeWorkload, machine: &Machine, frames: usize) -> WorkloadReport {
    let n = work.mesh.positions().len();
    let mut x = work.mesh.positions().to_vec();
    let mut times = Vec::with_capacity(frames);
    let mut iterations = 0u64;
    let config = RelaxConfig::default();
    for frame in 0..frames {
        let anchors = work.anchors(frame + 1);
        let loads = Loads {
            anchors: Some(&anchors),
            ..Default::default()
        };
        // Anchors only: the residual is relative to the frame's initial imbalance.
        let t = Instant::now();
        let report = work
            .system
            .relax(&mut x, &loads, &config)
            .expect("benchmark inputs are finite");
        times.push(t.elapsed().as_secs_f64() * 1e3);
        iterations += report.iterations as u64;
    }
    times.sort_by(f64::total_cmp);
    let pct = |q: f64| times[((times.len() - 1) as f64 * q).round() as usize];

    let anchors = work.anchors(10);
    let loads = Loads {
        anchors: Some(&anchors),
        ..Default::default()
    };
    let fixed = RelaxConfig {
        max_iterations: 30,
        tolerance: 0.0,
        stagnation_window: 0,
        ..RelaxConfig::DEFAULT
    };
    let thirty = || {
        let mut x = work.mesh.positions().to_vec();
        let t = Instant::now();
        let r = work.system.relax(&mut x, &loads, &fixed).expect("finite");
        (t.elapsed().as_secs_f64(), r)
    };
    let best = |runs: usize| {
        (0..runs)
            .map(|_| thirty())
            .min_by(|a, b| a.0.total_cmp(&b.0))
            .expect("at least one run")
    };
    let runs = if n > 500_000 { 2 } else { 5 };
    let (t_all, report) = best(runs);
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("a one-thread pool");
    let (t_one, report_one) = one.install(|| best(runs));
    assert_eq!(
        report.energy.to_bits(),
        report_one.energy.to_bits(),
        "results must not depend on the thread count"
    );
    let its = report.iterations.max(1) as f64;
    let per_iteration = t_all / its;
    let floor = (n as f64 * MIN_BYTES_PER_VERTEX_ITERATION / (machine.bandwidth_gb_s * 1e9))
        .max(work.system.edge_count() as f64 * machine.spring_ns * 1e-9);
    let (t_previous, previous_energy) = one.install(|| {
        (0..runs)
            .map(|_| {
                let t = Instant::now();
                let e = previous::relax(&work.system, work.mesh.positions(), &anchors, 30);
                (t.elapsed().as_secs_f64(), e)
            })
            .min_by(|a, b| a.0.total_cmp(&b.0))
            .expect("at least one run")
    });
    let (t_naive, _) = naive_scatter(work, &anchors, if n > 500_000 { 3 } else { 10 });
    // Solver vectors: x, trial, d, r (4 × 12 B), inverse diagonal and pin (5 B).
    let vectors = 4.0 * 12.0 + 5.0;
    WorkloadReport {
        name: work.name,
        skin_vertices: n,
        collider_triangles: 0,
        frame_ms_median: pct(0.5),
        frame_ms_p99: pct(0.99),
        iterations_per_frame_mean: iterations as f64 / frames.max(1) as f64,
        relax_vertex_iterations_per_s: n as f64 / per_iteration,
        relax_fraction_of_floor: floor / per_iteration,
        collision_us_per_vertex: None,
        collision_speedup_vs_naive: None,
        bytes_per_vertex: work.system.bytes_per_vertex() + vectors,
        thread_scaling_2_over_1: t_one / t_all,
        relax_speedup_vs_previous: t_previous / t_one,
        previous_energy_after_30: previous_energy,
        relax_speedup_vs_naive_scatter: t_naive / (t_one / its),
        energy_after_30: report.energy,
    }
}

/// The baseline: a plain scalar kernel over an edge list in the mesh's own vertex
/// order (force scatter, anchors, damped Verlet with unit mass), `iterations` iterations on the
/// calling thread from the rest shape. Returns the best time of one iteration over three runs, s,
/// and the final positions.
pub fn naive_scatter(
    work: &TubeWorkload,
    anchors: &[VertexAnchor],
    iterations: usize,
) -> (f64, Vec<Vec3>) {
    let mesh = &work.mesh;
    let k = StiffnessRule::AreaOverLengthSquared
        .edge_stiffness(mesh, &Modulus::Uniform(1000.0))
        .expect("valid tube");
    let rest = mesh.edge_lengths();
    let edges: Vec<(u32, u32, f32, f32)> = mesh
        .topology()
        .edges()
        .iter()
        .zip(k.iter().zip(&rest))
        .map(|(&[a, b], (&k, &l))| (a, b, k, l))
        .collect();
    let n = mesh.positions().len();
    let mut best = f64::INFINITY;
    let mut out = Vec::new();
    for _ in 0..3 {
        let mut x = mesh.positions().to_vec();
        let mut v = vec![Vec3::ZERO; n];
        let mut f = vec![Vec3::ZERO; n];
        let t = Instant::now();
        for _ in 0..iterations {
            f.fill(Vec3::ZERO);
            for &(a, b, k, l) in &edges {
                let d = x[b as usize] - x[a as usize];
                let len = d.length();
                if len > f32::MIN_POSITIVE {
                    let fe = d * (k * (len - l) / len);
                    f[a as usize] += fe;
                    f[b as usize] -= fe;
                }
            }
            for ((x, v), (f, a)) in x.iter_mut().zip(&mut v).zip(f.iter().zip(anchors)) {
                let d = *x - a.target;
                let dn = d.dot(a.normal);
                let fa = -(a.normal * (a.k_normal * dn) + (d - a.normal * dn) * a.k_tangent);
                *v = *v * 0.98 + (*f + fa) * 1e-5;
                *x += *v;
            }
        }
        best = best.min(t.elapsed().as_secs_f64() / iterations.max(1) as f64);
        out = std::hint::black_box(x);
    }
    (best, out)
}

/// The whole report of `dermis bench`.
#[derive(Debug, Clone, Serialize)]
pub struct BenchReport {
    /// The calibration.
    pub machine: Machine,
    /// One entry per workload.
    pub workloads: Vec<WorkloadReport>,
}

/// Runs the standard workloads (`tube-10k`, `tube-100k`, `relax-1m`); `quick` shrinks frame
/// counts and sizes so CI can run it in seconds.
pub fn run(quick: bool, mut progress: impl FnMut(&str)) -> BenchReport {
    progress("calibrating");
    let machine = calibrate(quick);
    let sizes: [(&'static str, usize, usize); 3] = if quick {
        [
            ("tube-10k", 10_000, 10),
            ("tube-100k", 100_000, 3),
            ("relax-1m", 200_000, 1),
        ]
    } else {
        [
            ("tube-10k", 10_000, 60),
            ("tube-100k", 100_000, 20),
            ("relax-1m", 1_000_000, 3),
        ]
    };
    let mut workloads = Vec::new();
    for (name, vertices, frames) in sizes {
        progress(name);
        let work = TubeWorkload::new(name, vertices);
        workloads.push(run_workload(&work, &machine, frames));
    }
    BenchReport { machine, workloads }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tube_workload_has_the_requested_size() {
        let w = TubeWorkload::new("t", 10_000);
        let n = w.mesh.positions().len();
        assert!((9_500..10_500).contains(&n), "{n}");
        // The anchors move between frames, and lie on the body's normals.
        let (a, b) = (w.anchors(3), w.anchors(4));
        assert!(a.iter().zip(&b).any(|(a, b)| a.target != b.target));
        for (a, p) in a.iter().zip(w.mesh.positions()) {
            assert!((a.target - *p).cross(a.normal).length() < 1e-5);
        }
    }
}
