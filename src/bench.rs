//! Standard performance workloads and an in-run machine calibration, behind `dermis bench`.
//!
//! Every figure comes with the calibration measured in the same process (memory bandwidth and
//! the cost of one spring evaluation), so results from different machines, or from the same
//! noisy machine at different times, compare as ratios.

pub mod arm;
pub mod peers;
mod previous;
pub mod targets;

use std::time::Instant;

use glam::Vec3;
use rayon::prelude::*;
use serde::Serialize;

use crate::mesh::TriMesh;
use crate::mesh::shapes::tube;
use crate::solver::{Loads, LoopTimes, RelaxConfig, RelaxReport, SpringSystem, VertexAnchor};
use crate::stiffness::{Modulus, StiffnessRule};
use arm::{ArmRun, ArmWorkload, CLIP_FRAMES};

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
    /// The SIMD path of the relaxation kernels ([`crate::solver::kernel_path`]).
    pub kernels: &'static str,
    /// The CPU, from CPUID: brand, vendor, family and model (`unknown` off x86-64). Which
    /// kernel path is fastest, and every figure, depends on it.
    pub cpu: String,
    /// The CPUs the global pool's workers are pinned to, worker `i` to the `i`-th
    /// ([`crate::threads::build_global_pool`]; empty: not pinned).
    pub pinned_cpus: Vec<usize>,
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

    // Springs between consecutive points of SoA arrays that fit in L2, every spring's force
    // factor stored (no reduction chain, so the loop vectorises at the baseline target): the
    // throughput of spring math, not its latency. Each thread sweeps its own output buffer
    // (allocated outside the timing), over slices rather than indices (no bounds checks, which
    // kept the loop scalar until session 16 and read 1.3-2.5 ns instead of 0.35-0.6); the best
    // of several repetitions, like the triad.
    let m = 1 << 14;
    let xs: Vec<f32> = (0..m).map(|i| i as f32).collect();
    let ys: Vec<f32> = (0..m).map(|i| (i as f32).sin()).collect();
    let zs: Vec<f32> = (0..m).map(|i| (i as f32 * 0.5).cos()).collect();
    let threads = rayon::current_num_threads().max(1);
    let rounds = if quick { 64 } else { 256 };
    let mut outs = vec![vec![0.0f32; m - 1]; threads];
    let mut best = f64::INFINITY;
    for _ in 0..if quick { 3 } else { 6 } {
        let t = Instant::now();
        outs.par_iter_mut().enumerate().for_each(|(w, out)| {
            for r in (w..rounds).step_by(threads) {
                spring_factors(&xs, &ys, &zs, 1.0 + r as f32 * 1e-6, out);
                std::hint::black_box(&mut *out);
            }
        });
        best = best.min(t.elapsed().as_secs_f64());
    }
    let spring_ns = best * 1e9 / (rounds * (m - 1)) as f64;
    Machine {
        threads,
        bandwidth_gb_s,
        spring_ns,
        kernels: crate::solver::kernel_path(),
        cpu: crate::cpu::description(),
        pinned_cpus: crate::threads::pinned_cpus().to_vec(),
    }
}

/// `out[i] = (|p_{i+1} − p_i| − rest) / |p_{i+1} − p_i|` for the points `(xs, ys, zs)`: the
/// calibration's spring math.
fn spring_factors(xs: &[f32], ys: &[f32], zs: &[f32], rest: f32, out: &mut [f32]) {
    fn pairs(v: &[f32]) -> impl Iterator<Item = (&f32, &f32)> {
        let n = v.len().saturating_sub(1);
        v[..n].iter().zip(&v[1..])
    }
    for (((o, (x0, x1)), (y0, y1)), (z0, z1)) in
        out.iter_mut().zip(pairs(xs)).zip(pairs(ys)).zip(pairs(zs))
    {
        let (dx, dy, dz) = (x1 - x0, y1 - y0, z1 - z0);
        let len = (dx * dx + dy * dy + dz * dz).sqrt();
        *o = (len - rest) / len;
    }
}

/// A relaxation workload: a skin tube with anchors that a bulging body moves every frame.
#[derive(Debug, Clone)]
pub struct TubeWorkload {
    /// Name in the report (`tube-10k`, ...).
    pub name: &'static str,
    /// The skin.
    pub mesh: TriMesh,
    /// Stiffness of each mesh edge (Eq. 29, `E2` = 1000 N/m), N/m.
    pub stiffness: Vec<f32>,
    /// Its springs.
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
        Self::from_mesh(name, tube(around, along, 0.05, 0.4))
    }

    /// The workload of any skin mesh (same material).
    pub fn from_mesh(name: &'static str, mesh: TriMesh) -> Self {
        let stiffness = StiffnessRule::AreaOverLengthSquared
            .edge_stiffness(&mesh, &Modulus::Uniform(1000.0))
            .expect("a valid mesh");
        let system = SpringSystem::from_mesh(&mesh, &stiffness).expect("valid springs");
        Self {
            name,
            mesh,
            stiffness,
            system,
        }
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

/// One workload's figures. Fields that only the arm workloads have (collision, shuffling) are
/// `null` for `relax-1m`.
#[derive(Debug, Clone, Serialize)]
pub struct WorkloadReport {
    /// Workload name.
    pub name: &'static str,
    /// Skin vertices.
    pub skin_vertices: usize,
    /// Collider triangles (the muscle mesh; the capsule bones have none; 0 without collision).
    pub collider_triangles: usize,
    /// Frames timed.
    pub frames: usize,
    /// Each timed frame's time, ms, in the clip's order (the median and p99 below are taken
    /// over these).
    pub frame_ms: Vec<f64>,
    /// Each timed frame's relaxation iterations (summed over its substeps), in the same order.
    pub frame_iterations: Vec<u32>,
    /// Timed frames whose (last) relaxation converged to the default tolerance; the others
    /// spent the 500-iteration budget or stalled.
    pub frames_converged: usize,
    /// Median whole-frame time, ms: for the arm, collider refresh, contact plan, substeps and
    /// the relaxations in contact to the default tolerance (the ECS's frame); for `relax-1m`,
    /// a warm-started relaxation under moving anchors.
    pub frame_ms_median: f64,
    /// 99th-percentile frame time (the nearest-rank sample; the maximum below 100 frames), ms.
    pub frame_ms_p99: f64,
    /// Mean relaxation iterations per frame (summed over substeps).
    pub iterations_per_frame_mean: f64,
    /// Mean contact substeps per frame (`null` without collision).
    pub substeps_per_frame_mean: Option<f64>,
    /// Mean contact passes per frame: one per substep plus one per accepted relaxation step
    /// (`null` without collision).
    pub collision_passes_per_frame_mean: Option<f64>,
    /// Vertex-iterations per second over a fixed 30-iteration relaxation (no projection).
    pub relax_vertex_iterations_per_s: f64,
    /// The floor time of those iterations (bandwidth- or compute-bound, from the calibration)
    /// over the measured time: 1 would be at the machine's limit.
    pub relax_fraction_of_floor: f64,
    /// Where that relaxation's time goes, ns per vertex-iteration (its best run, all threads):
    /// its parallel loops, and the rest.
    pub relax_ns_per_vertex_iteration: RelaxLoops,
    /// The part of that relaxation's time that is not its iterations, ms: a solve's set-up
    /// (input checks, the copies to the internal order, the preconditioner, the first force
    /// gather) and its copy back, timed as the best of the same relaxations stopped after 0
    /// iterations.
    pub relax_setup_ms: f64,
    /// Contact time per skin vertex per frame, µs: frame plan, substep passes and the
    /// projections inside the relaxations, averaged over the timed frames (`null` without
    /// collision).
    pub collision_us_per_vertex: Option<f64>,
    /// The part of `collision_us_per_vertex` spent in the frame plans, µs per skin vertex per
    /// frame (`null` without collision).
    pub collision_plan_us_per_vertex: Option<f64>,
    /// The part spent in the substeps' contact passes (`null` without collision).
    pub collision_passes_us_per_vertex: Option<f64>,
    /// The part spent in the projections inside the relaxations (`null` without collision).
    pub collision_projections_us_per_vertex: Option<f64>,
    /// One naive pass (a parry `project_point` per skin vertex on every collider, parallel),
    /// µs per vertex, measured on the skin of sampled frames (`null` without collision).
    pub collision_naive_us_per_vertex_pass: Option<f64>,
    /// One naive pass over a whole frame's contact work, both on the same sampled frames:
    /// above 1, the whole frame's contact costs less than one plain query per vertex (`null`
    /// without collision).
    pub collision_speedup_vs_naive: Option<f64>,
    /// Median over the timed frames of the muscle's refit, ms: its
    /// [`set_vertices`](crate::collision::ColliderMesh::set_vertices) (which refits the parts
    /// searched the frame before) plus the refits of the parts the frame's queries reached
    /// first, summed over threads (see
    /// [`refit_stats`](crate::collision::ColliderMesh::refit_stats); those refits run inside
    /// the contact work and are in its times too) (`null` without collision).
    pub collider_refresh_ms: Option<f64>,
    /// Mean time per frame of the refits of the muscle's parts that the frame's queries
    /// reached first (after `set_vertices`, which refits the parts searched the frame before),
    /// ms, summed over threads: part of `collider_refresh_ms`, and spent inside the contact
    /// work, so also part of `collision_us_per_vertex` (`null` without collision).
    pub collider_deferred_refit_ms: Option<f64>,
    /// Mean number of the muscle's BVH parts refitted per frame after `set_vertices`, of
    /// `collider_parts` (`null` without collision).
    pub collider_parts_refitted_per_frame: Option<f64>,
    /// Parts the muscle's BVH is held in (`null` without collision).
    pub collider_parts: Option<usize>,
    /// Smallest clearance of the skin from the analytic colliders after any timed frame, m
    /// (the skin thickness when contact holds; `null` without collision).
    pub min_clearance_m: Option<f64>,
    /// Most vertices left unresolved by a frame's last contact pass (`null` without collision).
    pub unresolved_max: Option<usize>,
    /// Bytes of solver state per skin vertex (springs, CSR and the solver's vectors).
    pub bytes_per_vertex: f64,
    /// 30-iteration time on 1 thread over the time on all threads.
    pub thread_scaling_2_over_1: f64,
    /// 30-iteration time of the same tube with its vertices shuffled before the system was
    /// built, over the time of the ordered one, all threads (`null` for `relax-1m`).
    pub shuffled_over_ordered: Option<f64>,
    /// Energy after those 30 iterations of the shuffled system, J (equal to
    /// `energy_after_30` up to summation order).
    pub shuffled_energy_after_30: Option<f64>,
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

/// Where the fixed 30-iteration relaxation spends its time, ns per vertex-iteration: wall time
/// of each of its parallel loops over all iterations, divided by iterations and vertices.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct RelaxLoops {
    /// The curvature gather (`dᵀ H d` along the search direction; each spring once).
    pub curvature_gather: f64,
    /// The force gather at the trial point (forces, energy and the sums of the next
    /// direction), with the solve's first gather.
    pub force_gather: f64,
    /// The step to the trial point (`x += a d`, in place).
    pub step: f64,
    /// The direction update (`d = w r + β d`).
    pub direction: f64,
    /// The rest of the solve: its set-up (input checks, the copies to the internal order, the
    /// preconditioner), the serial work between the loops and the copy back.
    pub other: f64,
}

/// Figures of the fixed 30-iteration relaxation (no projection) of a workload.
#[derive(Debug, Clone)]
struct RelaxFigures {
    loops: RelaxLoops,
    vertex_iterations_per_s: f64,
    fraction_of_floor: f64,
    setup_ms: f64,
    bytes_per_vertex: f64,
    thread_scaling: f64,
    speedup_vs_previous: f64,
    previous_energy: f64,
    speedup_vs_naive_scatter: f64,
    energy: f64,
}

/// Best time of `runs` fixed 30-iteration relaxations from the rest shape, s, and the report.
fn thirty(
    system: &SpringSystem,
    rest: &[Vec3],
    anchors: &[VertexAnchor],
    runs: usize,
) -> (f64, RelaxReport) {
    let (t, report, _) = fixed(system, rest, anchors, runs, 30);
    (t, report)
}

/// Best time of `runs` relaxations from the rest shape stopped after `iterations`, s, the
/// report, and the times of the best run's loops.
fn fixed(
    system: &SpringSystem,
    rest: &[Vec3],
    anchors: &[VertexAnchor],
    runs: usize,
    iterations: u32,
) -> (f64, RelaxReport, LoopTimes) {
    let loads = Loads {
        anchors: Some(anchors),
        ..Default::default()
    };
    let config = RelaxConfig {
        max_iterations: iterations,
        tolerance: 0.0,
        stagnation_window: 0,
        ..RelaxConfig::DEFAULT
    };
    (0..runs.max(1))
        .map(|_| {
            let mut x = rest.to_vec();
            let mut loops = LoopTimes::default();
            let t = Instant::now();
            let r = system
                .relax_timed(&mut x, &loads, &config, &mut loops)
                .expect("finite");
            (t.elapsed().as_secs_f64(), r, loops)
        })
        .min_by(|a, b| a.0.total_cmp(&b.0))
        .expect("at least one run")
}

fn relax_figures(
    work: &TubeWorkload,
    anchors: &[VertexAnchor],
    machine: &Machine,
    runs: usize,
) -> RelaxFigures {
    let n = work.mesh.positions().len();
    let rest = work.mesh.positions();
    let (t_all, report, loops) = fixed(&work.system, rest, anchors, runs, 30);
    let (t_setup, _, _) = fixed(&work.system, rest, anchors, runs, 0);
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("a one-thread pool");
    let (t_one, report_one) = one.install(|| thirty(&work.system, rest, anchors, runs));
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
        (0..runs.max(1))
            .map(|_| {
                let t = Instant::now();
                let e = previous::relax(&work.system, rest, anchors, 30);
                (t.elapsed().as_secs_f64(), e)
            })
            .min_by(|a, b| a.0.total_cmp(&b.0))
            .expect("at least one run")
    });
    let (t_naive, _) = naive_scatter(work, anchors, if n > 500_000 { 3 } else { 10 });
    // Solver vectors: x, d, r and the inverse diagonal (with the pin flag).
    let vectors = SpringSystem::VECTOR_BYTES_PER_VERTEX as f64;
    // ns per vertex-iteration.
    let ns = |s: f64| s * 1e9 / (n as f64 * its);
    let looped = loops.curvature + loops.force + loops.step + loops.direction + loops.projection;
    RelaxFigures {
        loops: RelaxLoops {
            curvature_gather: ns(loops.curvature),
            force_gather: ns(loops.force),
            step: ns(loops.step),
            direction: ns(loops.direction),
            other: ns(loops.total - looped),
        },
        vertex_iterations_per_s: n as f64 / per_iteration,
        fraction_of_floor: floor / per_iteration,
        setup_ms: t_setup * 1e3,
        bytes_per_vertex: work.system.bytes_per_vertex() + vectors,
        thread_scaling: t_one / t_all,
        speedup_vs_previous: t_previous / t_one,
        previous_energy,
        speedup_vs_naive_scatter: t_naive / (t_one / its),
        energy: report.energy,
    }
}

/// The nearest-rank `q`-quantile of sorted `times`.
fn quantile(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let rank = (q * sorted.len() as f64).ceil() as usize;
    sorted[rank.clamp(1, sorted.len()) - 1]
}

fn sorted(mut v: Vec<f64>) -> Vec<f64> {
    v.sort_by(f64::total_cmp);
    v
}

/// The tube with its vertices shuffled (a fixed pseudo-random permutation) before the system
/// is built, and `perm` with `shuffled[i] = original[perm[i]]`.
pub fn shuffled(work: &TubeWorkload) -> (TubeWorkload, Vec<u32>) {
    let n = work.mesh.positions().len();
    let mut perm: Vec<u32> = (0..n as u32).collect();
    // Fisher-Yates with a splitmix64 stream (fixed seed: the same shuffle every run).
    let mut state = 0x9E37_79B9_7F4A_7C15u64;
    let mut next = || {
        state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    };
    for i in (1..n).rev() {
        perm.swap(i, (next() % (i as u64 + 1)) as usize);
    }
    let mut rank = vec![0u32; n];
    for (i, &p) in perm.iter().enumerate() {
        rank[p as usize] = i as u32;
    }
    let positions = perm
        .iter()
        .map(|&p| work.mesh.positions()[p as usize])
        .collect();
    let triangles = work
        .mesh
        .triangles()
        .iter()
        .map(|t| t.map(|v| rank[v as usize]))
        .collect();
    let mesh = TriMesh::new(positions, triangles).expect("a permuted valid mesh");
    (TubeWorkload::from_mesh(work.name, mesh), perm)
}

/// Runs the arm workload: `frames` timed frames of the clip after `first_frame` (where the
/// skin is settled untimed for at most `settle_iterations`), with a naive query pass on every `naive_stride`-th frame, then
/// the fixed 30-iteration measurements and the shuffled-order comparison.
pub fn run_arm_workload(
    work: &ArmWorkload,
    machine: &Machine,
    first_frame: usize,
    settle_iterations: u32,
    frames: usize,
    naive_stride: usize,
    runs: usize,
) -> WorkloadReport {
    let n = work.tube.mesh.positions().len();
    let mut run =
        ArmRun::new(work, first_frame, settle_iterations).expect("the bench's inputs are valid");
    let mut times = Vec::with_capacity(frames);
    let mut frame_iterations = Vec::with_capacity(frames);
    let mut refresh = Vec::with_capacity(frames);
    let (mut parts_refitted, mut deferred_s) = (0u64, 0.0f64);
    let (mut substeps, mut passes) = (0u64, 0u64);
    let (mut naive_s, mut sampled_collision_s) = (0.0, 0.0);
    let (mut plan_s, mut passes_s, mut projections_s) = (0.0, 0.0, 0.0);
    let mut sampled = 0usize;
    let mut min_clearance = f32::INFINITY;
    let mut unresolved_max = 0;
    let mut converged = 0;
    for f in 0..frames {
        let t = run.step(work).expect("the bench's inputs are valid");
        times.push(t.total_s * 1e3);
        frame_iterations.push(t.iterations);
        refresh.push((t.refresh_s + t.deferred_refit_s) * 1e3);
        parts_refitted += t.parts_refitted;
        deferred_s += t.deferred_refit_s;
        substeps += u64::from(t.substeps);
        passes += t.passes;
        (plan_s, passes_s, projections_s) = (
            plan_s + t.plan_s,
            passes_s + t.passes_s,
            projections_s + t.projections_s,
        );
        unresolved_max = unresolved_max.max(t.unresolved);
        converged += usize::from(t.converged);
        min_clearance = min_clearance.min(arm::analytic_clearance(work, run.frame, &run.x));
        if f % naive_stride.max(1) == 0 {
            naive_s += run.naive_pass();
            sampled_collision_s += t.collision_s();
            sampled += 1;
        }
    }
    let iterations: u64 = frame_iterations.iter().map(|&i| u64::from(i)).sum();
    let frame_ms = times.clone();
    let times = sorted(times);
    let per_frame = |v: u64| v as f64 / frames.max(1) as f64;
    let per_vertex = |s: f64| s * 1e6 / (frames.max(1) * n) as f64;

    let anchors = work.anchors(work.clip_frames / 2);
    let relax = relax_figures(&work.tube, &anchors, machine, runs);
    let (shuffled_tube, perm) = shuffled(&work.tube);
    let shuffled_anchors: Vec<VertexAnchor> = perm.iter().map(|&p| anchors[p as usize]).collect();
    // Interleaved, best of each: the machine's drift hits both alike.
    let (mut t_ordered, mut t_shuffled) = (f64::INFINITY, f64::INFINITY);
    let mut shuffled_report = None;
    for _ in 0..runs.max(3) {
        let (t, _) = thirty(&work.tube.system, work.tube.mesh.positions(), &anchors, 1);
        t_ordered = t_ordered.min(t);
        let (t, r) = thirty(
            &shuffled_tube.system,
            shuffled_tube.mesh.positions(),
            &shuffled_anchors,
            1,
        );
        t_shuffled = t_shuffled.min(t);
        shuffled_report = Some(r);
    }
    let shuffled_report = shuffled_report.expect("at least one run");
    WorkloadReport {
        name: work.tube.name,
        skin_vertices: n,
        collider_triangles: work.muscle_triangle_count(),
        frames,
        frame_ms,
        frame_iterations,
        frames_converged: converged,
        frame_ms_median: quantile(&times, 0.5),
        frame_ms_p99: quantile(&times, 0.99),
        iterations_per_frame_mean: per_frame(iterations),
        substeps_per_frame_mean: Some(per_frame(substeps)),
        collision_passes_per_frame_mean: Some(per_frame(passes)),
        relax_vertex_iterations_per_s: relax.vertex_iterations_per_s,
        relax_fraction_of_floor: relax.fraction_of_floor,
        relax_setup_ms: relax.setup_ms,
        relax_ns_per_vertex_iteration: relax.loops,
        collision_us_per_vertex: Some(per_vertex(plan_s + passes_s + projections_s)),
        collision_plan_us_per_vertex: Some(per_vertex(plan_s)),
        collision_passes_us_per_vertex: Some(per_vertex(passes_s)),
        collision_projections_us_per_vertex: Some(per_vertex(projections_s)),
        collision_naive_us_per_vertex_pass: Some(naive_s * 1e6 / (sampled.max(1) * n) as f64),
        collision_speedup_vs_naive: Some(naive_s / sampled_collision_s),
        collider_refresh_ms: Some(quantile(&sorted(refresh), 0.5)),
        collider_deferred_refit_ms: Some(deferred_s * 1e3 / frames.max(1) as f64),
        collider_parts_refitted_per_frame: Some(per_frame(parts_refitted)),
        collider_parts: Some(run.contact.colliders()[run.ids.muscle.0 as usize].part_count()),
        min_clearance_m: Some(f64::from(min_clearance)),
        unresolved_max: Some(unresolved_max),
        bytes_per_vertex: relax.bytes_per_vertex,
        thread_scaling_2_over_1: relax.thread_scaling,
        shuffled_over_ordered: Some(t_shuffled / t_ordered),
        shuffled_energy_after_30: Some(shuffled_report.energy),
        relax_speedup_vs_previous: relax.speedup_vs_previous,
        previous_energy_after_30: relax.previous_energy,
        relax_speedup_vs_naive_scatter: relax.speedup_vs_naive_scatter,
        energy_after_30: relax.energy,
    }
}

/// Runs the relaxation-only workload: `frames` warm-started relaxations under the bulging
/// anchors, then the fixed 30-iteration measurements.
pub fn run_workload(
    work: &TubeWorkload,
    machine: &Machine,
    frames: usize,
    runs: usize,
) -> WorkloadReport {
    let n = work.mesh.positions().len();
    let mut x = work.mesh.positions().to_vec();
    let mut times = Vec::with_capacity(frames);
    let mut frame_iterations = Vec::with_capacity(frames);
    let mut converged = 0;
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
        frame_iterations.push(report.iterations);
        converged += usize::from(report.converged());
    }
    let iterations: u64 = frame_iterations.iter().map(|&i| u64::from(i)).sum();
    let frame_ms = times.clone();
    let times = sorted(times);
    let relax = relax_figures(work, &work.anchors(10), machine, runs);
    WorkloadReport {
        name: work.name,
        skin_vertices: n,
        collider_triangles: 0,
        frames,
        frame_ms,
        frame_iterations,
        frames_converged: converged,
        frame_ms_median: quantile(&times, 0.5),
        frame_ms_p99: quantile(&times, 0.99),
        iterations_per_frame_mean: iterations as f64 / frames.max(1) as f64,
        substeps_per_frame_mean: None,
        collision_passes_per_frame_mean: None,
        relax_vertex_iterations_per_s: relax.vertex_iterations_per_s,
        relax_fraction_of_floor: relax.fraction_of_floor,
        relax_setup_ms: relax.setup_ms,
        relax_ns_per_vertex_iteration: relax.loops,
        collision_us_per_vertex: None,
        collision_plan_us_per_vertex: None,
        collision_passes_us_per_vertex: None,
        collision_projections_us_per_vertex: None,
        collision_naive_us_per_vertex_pass: None,
        collision_speedup_vs_naive: None,
        collider_refresh_ms: None,
        collider_deferred_refit_ms: None,
        collider_parts_refitted_per_frame: None,
        collider_parts: None,
        min_clearance_m: None,
        unresolved_max: None,
        bytes_per_vertex: relax.bytes_per_vertex,
        thread_scaling_2_over_1: relax.thread_scaling,
        shuffled_over_ordered: None,
        shuffled_energy_after_30: None,
        relax_speedup_vs_previous: relax.speedup_vs_previous,
        previous_energy_after_30: relax.previous_energy,
        relax_speedup_vs_naive_scatter: relax.speedup_vs_naive_scatter,
        energy_after_30: relax.energy,
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
    let k = &work.stiffness;
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
    /// Wall time of the whole run, s.
    pub wall_s: f64,
    /// One entry per workload.
    pub workloads: Vec<WorkloadReport>,
    /// Issue 8's targets checked against this run ([`targets::TARGETS`]); empty for any plan
    /// but [`Plan::FULL`] (the targets are for the full workloads' sizes).
    pub targets: Vec<targets::TargetCheck>,
}

/// Sizes and frame counts of one `dermis bench` run.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Plan {
    /// Skin vertices of `tube-10k`, `tube-100k` and `relax-1m`.
    pub vertices: [usize; 3],
    /// The clip frame the skin is settled at before the timed frames (`tube-10k`,
    /// `tube-100k`; the clip has [`CLIP_FRAMES`] frames, full flexion at half of them).
    pub first_frame: [usize; 2],
    /// Most relaxation iterations of the untimed settling at `first_frame`.
    pub settle_iterations: [u32; 2],
    /// Timed frames of each.
    pub frames: [usize; 3],
    /// A naive query pass every this many frames (`tube-10k`, `tube-100k`).
    pub naive_stride: [usize; 2],
    /// Repetitions of the fixed 30-iteration measurements (the best counts).
    pub runs: [usize; 3],
    /// Muscle resolution (latitude bands, longitude sectors): 126 × 200 is 50,000 triangles.
    pub muscle: (u32, u32),
}

impl Plan {
    /// The full run (under two minutes on the 2-core reference machine): `tube-10k` times the
    /// whole clip once round (60 frames from frame 12, through full flexion and back),
    /// `tube-100k` 4 frames of the flexion.
    pub const FULL: Self = Self {
        vertices: [10_000, 100_000, 1_000_000],
        first_frame: [12, 14],
        settle_iterations: [500, 100],
        frames: [CLIP_FRAMES, 4, 1],
        naive_stride: [6, 4],
        runs: [5, 2, 1],
        muscle: (126, 200),
    };
    /// The CI run: the same tube-10k scene over a shorter stretch of the clip, smaller others.
    pub const QUICK: Self = Self {
        vertices: [10_000, 30_000, 200_000],
        first_frame: [18, 18],
        settle_iterations: [200, 100],
        frames: [4, 1, 1],
        naive_stride: [2, 1],
        runs: [3, 2, 1],
        muscle: (126, 200),
    };
}

/// The arm workloads of `plan` (`tube-10k`, `tube-100k`), built but not run.
pub fn arm_workloads(plan: &Plan) -> Vec<ArmWorkload> {
    ["tube-10k", "tube-100k"]
        .into_iter()
        .zip(plan.vertices)
        .map(|(name, n)| ArmWorkload::new(name, n, plan.muscle, CLIP_FRAMES))
        .collect()
}

/// Runs the standard workloads (`tube-10k`, `tube-100k`, `relax-1m`); `quick` runs
/// [`Plan::QUICK`] (CI, seconds) instead of [`Plan::FULL`].
pub fn run(quick: bool, progress: impl FnMut(&str)) -> BenchReport {
    run_plan(
        if quick { &Plan::QUICK } else { &Plan::FULL },
        quick,
        progress,
    )
}

/// Runs the workloads of `plan` (`quick` shortens the calibration).
pub fn run_plan(plan: &Plan, quick: bool, mut progress: impl FnMut(&str)) -> BenchReport {
    let start = Instant::now();
    progress("calibrating");
    let machine = calibrate(quick);
    let mut workloads = Vec::new();
    for (i, work) in arm_workloads(plan).iter().enumerate() {
        progress(work.tube.name);
        workloads.push(run_arm_workload(
            work,
            &machine,
            plan.first_frame[i],
            plan.settle_iterations[i],
            plan.frames[i],
            plan.naive_stride[i],
            plan.runs[i],
        ));
    }
    progress("relax-1m");
    let work = TubeWorkload::new("relax-1m", plan.vertices[2]);
    workloads.push(run_workload(&work, &machine, plan.frames[2], plan.runs[2]));
    let targets = if *plan == Plan::FULL {
        targets::check(&targets::TARGETS, &workloads)
    } else {
        Vec::new()
    };
    BenchReport {
        machine,
        wall_s: start.elapsed().as_secs_f64(),
        workloads,
        targets,
    }
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

    #[test]
    fn nearest_rank_quantiles() {
        let hundred: Vec<f64> = (1..=100).map(f64::from).collect();
        assert_eq!(quantile(&hundred, 0.99), 99.0);
        assert_eq!(quantile(&hundred, 0.5), 50.0);
        assert_eq!(quantile(&[1.0, 2.0, 3.0], 0.5), 2.0);
        assert_eq!(quantile(&[7.0], 0.99), 7.0);
        assert!(quantile(&[], 0.5).is_nan());
    }

    #[test]
    fn a_shuffled_tube_relaxes_to_the_same_answer() {
        let work = TubeWorkload::new("t", 3_000);
        let (shuffled_work, perm) = shuffled(&work);
        // A true permutation that moved most vertices.
        let mut seen = vec![false; perm.len()];
        perm.iter().for_each(|&p| seen[p as usize] = true);
        assert!(seen.iter().all(|&s| s));
        assert!(
            perm.iter()
                .enumerate()
                .filter(|&(i, &p)| i as u32 != p)
                .count()
                > perm.len() / 2
        );
        let anchors = work.anchors(20);
        let moved: Vec<VertexAnchor> = perm.iter().map(|&p| anchors[p as usize]).collect();
        let config = RelaxConfig {
            max_iterations: 30,
            tolerance: 0.0,
            stagnation_window: 0,
            ..RelaxConfig::DEFAULT
        };
        let relax = |w: &TubeWorkload, a: &[VertexAnchor]| {
            let mut x = w.mesh.positions().to_vec();
            let loads = Loads {
                anchors: Some(a),
                ..Default::default()
            };
            let r = w.system.relax(&mut x, &loads, &config).unwrap();
            (x, r.energy)
        };
        let (x, e) = relax(&work, &anchors);
        let (xs, es) = relax(&shuffled_work, &moved);
        assert!((e - es).abs() <= 1e-6 * e.abs(), "{e} vs {es}");
        for (i, &p) in perm.iter().enumerate() {
            assert!(xs[i].distance(x[p as usize]) < 1e-6, "vertex {p}");
        }
    }

    #[test]
    fn the_report_has_every_field_finite_and_the_skin_outside_the_colliders() {
        let plan = Plan {
            vertices: [800, 1_200, 1_500],
            first_frame: [14, 14],
            settle_iterations: [100, 100],
            frames: [3, 1, 1],
            naive_stride: [1, 1],
            runs: [1, 1, 1],
            muscle: (20, 32),
        };
        let mut stages = Vec::new();
        let report = run_plan(&plan, true, |s| stages.push(s.to_owned()));
        assert_eq!(stages, ["calibrating", "tube-10k", "tube-100k", "relax-1m"]);
        let json = serde_json::to_value(&report).unwrap();
        let m = &json["machine"];
        assert!(m["threads"].as_u64().unwrap() >= 1);
        assert!(m["bandwidth_gb_s"].as_f64().unwrap() > 0.0);
        assert!(m["spring_ns"].as_f64().unwrap() > 0.0);
        assert!(json["wall_s"].as_f64().unwrap() > 0.0);
        let workloads = json["workloads"].as_array().unwrap();
        let names: Vec<&str> = workloads
            .iter()
            .map(|w| w["name"].as_str().unwrap())
            .collect();
        assert_eq!(names, ["tube-10k", "tube-100k", "relax-1m"]);
        // Not the full plan: no targets checked.
        assert_eq!(json["targets"], serde_json::json!([]));
        let always = [
            "skin_vertices",
            "collider_triangles",
            "frames",
            "frames_converged",
            "frame_ms_median",
            "frame_ms_p99",
            "iterations_per_frame_mean",
            "relax_vertex_iterations_per_s",
            "relax_fraction_of_floor",
            "relax_setup_ms",
            "bytes_per_vertex",
            "thread_scaling_2_over_1",
            "relax_speedup_vs_previous",
            "previous_energy_after_30",
            "relax_speedup_vs_naive_scatter",
            "energy_after_30",
        ];
        let contact = [
            "substeps_per_frame_mean",
            "collision_passes_per_frame_mean",
            "collision_us_per_vertex",
            "collision_plan_us_per_vertex",
            "collision_passes_us_per_vertex",
            "collision_projections_us_per_vertex",
            "collision_naive_us_per_vertex_pass",
            "collision_speedup_vs_naive",
            "collider_refresh_ms",
            "collider_deferred_refit_ms",
            "collider_parts_refitted_per_frame",
            "collider_parts",
            "min_clearance_m",
            "unresolved_max",
            "shuffled_over_ordered",
            "shuffled_energy_after_30",
        ];
        for (w, vertices) in workloads.iter().zip(plan.vertices) {
            let arm = w["name"] != "relax-1m";
            let n = w["skin_vertices"].as_u64().unwrap() as usize;
            assert!(n.abs_diff(vertices) < vertices / 10, "{n} for {vertices}");
            for key in always
                .iter()
                .chain(arm.then_some(&contact).into_iter().flatten())
            {
                let v = w[key].as_f64().unwrap_or(f64::NAN);
                assert!(
                    v.is_finite() && v >= 0.0,
                    "{}: {key} = {}",
                    w["name"],
                    w[key]
                );
            }
            // The relaxation's loops and the rest: each measured, and together the time per
            // vertex-iteration the rate reports (the same best run, timed inside the solve).
            let loops = &w["relax_ns_per_vertex_iteration"];
            let parts = [
                "curvature_gather",
                "force_gather",
                "step",
                "direction",
                "other",
            ];
            for key in parts {
                let v = loops[key].as_f64().unwrap_or(f64::NAN);
                assert!(v.is_finite() && v > 0.0, "{}: {key} = {v}", w["name"]);
            }
            let sum: f64 = parts.iter().map(|k| loops[k].as_f64().unwrap()).sum();
            let per = 1e9 / w["relax_vertex_iterations_per_s"].as_f64().unwrap();
            assert!(
                sum <= per * (1.0 + 1e-9) && sum >= 0.5 * per,
                "{}: {sum} ns of {per}",
                w["name"]
            );
            // The per-frame lists: one entry per timed frame, and the summaries are theirs.
            let frames = w["frames"].as_u64().unwrap() as usize;
            let ms: Vec<f64> = serde_json::from_value(w["frame_ms"].clone()).unwrap();
            let its: Vec<u32> = serde_json::from_value(w["frame_iterations"].clone()).unwrap();
            assert_eq!((ms.len(), its.len()), (frames, frames), "{}", w["name"]);
            let slowest = ms.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            assert_eq!(w["frame_ms_p99"].as_f64().unwrap(), slowest);
            assert!(ms.contains(&w["frame_ms_median"].as_f64().unwrap()));
            let mean = its.iter().map(|&i| f64::from(i)).sum::<f64>() / frames as f64;
            assert_eq!(w["iterations_per_frame_mean"].as_f64().unwrap(), mean);
            if !arm {
                assert!(contact.iter().all(|k| w[k].is_null()));
                continue;
            }
            assert_eq!(w["collider_triangles"], 2 * 32 * 19);
            // The muscle is in parts; each is refitted at most once per move of the muscle
            // (its `set_vertices` and one per substep).
            let parts = w["collider_parts"].as_u64().unwrap() as f64;
            let refitted = w["collider_parts_refitted_per_frame"].as_f64().unwrap();
            let substeps = w["substeps_per_frame_mean"].as_f64().unwrap();
            assert!(
                parts >= 2.0 && refitted <= parts * (1.0 + substeps),
                "{parts} parts, {refitted} refitted"
            );
            // The contact time's three parts make up the whole.
            let part = |k: &str| w[k].as_f64().unwrap();
            let parts = part("collision_plan_us_per_vertex")
                + part("collision_passes_us_per_vertex")
                + part("collision_projections_us_per_vertex");
            let whole = part("collision_us_per_vertex");
            assert!((parts - whole).abs() <= 1e-9 * whole, "{parts} for {whole}");
            assert!(part("collision_projections_us_per_vertex") > 0.0);
            // Contact held: every vertex kept (nearly) the thickness from the analytic shapes.
            assert!(w["min_clearance_m"].as_f64().unwrap() > 0.5 * f64::from(arm::THICKNESS_M));
            // Each substep is one pass, each relaxation iteration one more.
            let passes = w["collision_passes_per_frame_mean"].as_f64().unwrap();
            let its = w["iterations_per_frame_mean"].as_f64().unwrap();
            let substeps = w["substeps_per_frame_mean"].as_f64().unwrap();
            assert!(
                passes >= its + substeps - 1e-9,
                "{passes} < {its} + {substeps}"
            );
            // The shuffled system reaches the same energy.
            let (e, es) = (
                w["energy_after_30"].as_f64().unwrap(),
                w["shuffled_energy_after_30"].as_f64().unwrap(),
            );
            assert!((e - es).abs() <= 1e-6 * e, "{e} vs {es}");
        }
    }
}
