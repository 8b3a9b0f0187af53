//! One animation frame of a skin in contact: substeps, contact passes and the relaxation, shared by the ECS and the bench.

use std::time::{Duration, Instant};

use glam::{Vec3, Vec3A};
use rayon::prelude::*;
use thiserror::Error;

use super::bench_support::Timed;
use super::{CollisionError, SkinCollision};
use crate::solver::{Loads, RelaxConfig, RelaxReport, SolverError, SpringSystem, VertexAnchor};

/// Relaxation iterations each intermediate substep of a frame gets by default
/// ([`FrameSchedule::DEFAULT`]): none, the intermediate substeps run their contact pass only (no
/// tunnelling needs no equilibrium there) and the last substep gets the whole budget. Measured
/// on the bench's arm (tube-10k, 20 frames from frame 12, `examples/tube_profile`-style runs):
/// 4,750 iterations and 15 frames converged, against 5,601 and 14 when half the budget was
/// spread over the intermediate substeps (they never converged in their share).
pub const SUBSTEP_ITERATIONS: u32 = 0;

/// How a frame spends its work.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameSchedule {
    /// Relaxation iterations of each intermediate substep, at most
    /// `max(max_iterations / (2 · substeps), 1)` (the last substep gets the rest of
    /// [`RelaxConfig::max_iterations`]); 0: contact passes only.
    pub substep_iterations: u32,
}

impl FrameSchedule {
    /// [`SUBSTEP_ITERATIONS`] per intermediate substep.
    pub const DEFAULT: Self = Self {
        substep_iterations: SUBSTEP_ITERATIONS,
    };
}

impl Default for FrameSchedule {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// What [`relax_frame`] did.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameRelax {
    /// The last substep's relaxation, with `iterations` summed over all substeps.
    pub report: RelaxReport,
    /// Substeps run.
    pub substeps: u32,
    /// The frame plan ([`SkinCollision::begin_frame`]).
    pub plan_time: Duration,
    /// The substeps' contact passes ([`SkinCollision::substep`]).
    pub pass_time: Duration,
    /// The projections inside the relaxations.
    pub projection_time: Duration,
}

impl FrameRelax {
    /// Time spent in contact: the frame plan, the substep passes and the projections inside
    /// the solves.
    pub fn contact_time(&self) -> Duration {
        self.plan_time + self.pass_time + self.projection_time
    }
}

/// Why a frame could not be relaxed.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum FrameError {
    /// The contact rejected an input (positions of the wrong length or not finite); fix the
    /// input it names.
    #[error(transparent)]
    Collision(#[from] CollisionError),
    /// The solver rejected an input (loads of the wrong length or not finite); fix the input it
    /// names.
    #[error(transparent)]
    Solver(#[from] SolverError),
}

/// Moves each anchored vertex by its anchor target's motion since the last frame
/// (`next.target − prev.target`): the skin is carried along by the skinning that drives its
/// anchors, a far better start for the frame's solve than where it was. Vertices with a zero
/// anchor stiffness are left. Does nothing when the lengths differ from `x`'s.
pub fn predict_from_anchors(x: &mut [Vec3], prev: &[VertexAnchor], next: &[VertexAnchor]) {
    if prev.len() != x.len() || next.len() != x.len() {
        return;
    }
    for ((p, a), b) in x.iter_mut().zip(prev).zip(next) {
        if a.k_normal > 0.0 || a.k_tangent > 0.0 {
            let d = b.target - a.target;
            if d.is_finite() {
                *p += d;
            }
        }
    }
}

/// How [`predict_from_motion`] extrapolates the skin's deviation from its anchors.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MotionPrediction {
    /// Fraction of the last frame's change of the tangential deviation carried into the next
    /// frame (scaled by how the anchors' motion continues): 0 is [`predict_from_anchors`], 1 a
    /// linear extrapolation.
    pub gain: f32,
    /// Jacobi sweeps over the mesh's edges that smooth the extrapolated correction (each
    /// vertex averaged with its neighbours): the deviation's frame-to-frame change carries
    /// vertex-scale noise (the last solve's leftover error), which extrapolated costs
    /// iterations, most at fine resolutions.
    pub smoothing_sweeps: u32,
}

impl MotionPrediction {
    /// Gain 1, 2 smoothing sweeps. Measured paired (each frame of the bench's elbow clip, 60
    /// frames, from the same state) against [`predict_from_anchors`]: 9.8 % fewer iterations
    /// at tube-10k (better in 46 frames, worse in 11; 4 sweeps 7.4 %, none 12.1 %), 2.8 % at
    /// tube-100k (31 / 21, within that size's noise; 4 sweeps 0.9 %, none 8.6 % more); see
    /// `benches/README.md`, sessions 7 and 9.
    pub const DEFAULT: Self = Self {
        gain: 1.0,
        smoothing_sweeps: 2,
    };
}

impl Default for MotionPrediction {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// The skin at its last solve, relative to its anchors: per vertex the anchor target and the
/// deviation `x − target` (m), what [`predict_from_motion`] extrapolates from. Empty (the
/// default) until a first prediction records it; [`clear`](Self::clear) it after a jump (a
/// teleport, a rollback, a still frame) so the next prediction falls back to
/// [`predict_from_anchors`]. Part of a checkpoint ([`targets`](Self::targets),
/// [`deviations`](Self::deviations), [`from_parts`](Self::from_parts)).
///
/// It also keeps what the prediction reuses from frame to frame: the mesh's vertex adjacency
/// (built on the first prediction with edges, rebuilt when the vertex or edge count changes)
/// and the prediction's buffers (no allocation per frame).
#[derive(Debug, Clone, Default)]
pub struct MotionHistory {
    targets: Vec<Vec3>,
    deviations: Vec<Vec3>,
    adjacency: Adjacency,
    /// The correction field and its smoothed copy.
    field: Vec<Vec3A>,
    spare: Vec<Vec3A>,
    /// Per vertex: anchored at the last prediction.
    anchored: Vec<bool>,
    /// Per chunk: the sums of `Δ·Δ₋` and `|Δ₋|²`, added in chunk order.
    sums: Vec<[f64; 2]>,
}

/// Two histories are equal when they record the same solve (caches and buffers aside).
impl PartialEq for MotionHistory {
    fn eq(&self, other: &Self) -> bool {
        self.targets == other.targets && self.deviations == other.deviations
    }
}

impl MotionHistory {
    /// A history of `targets` and `deviations` (one per vertex, m), as
    /// [`targets`](Self::targets) and [`deviations`](Self::deviations) gave them. `None` when
    /// the lengths differ.
    pub fn from_parts(targets: Vec<Vec3>, deviations: Vec<Vec3>) -> Option<Self> {
        (targets.len() == deviations.len()).then(|| Self {
            targets,
            deviations,
            ..Self::default()
        })
    }

    /// Anchor targets at the last recorded solve, m (empty: no history).
    pub fn targets(&self) -> &[Vec3] {
        &self.targets
    }

    /// Deviations `x − target` at the last recorded solve, m.
    pub fn deviations(&self) -> &[Vec3] {
        &self.deviations
    }

    /// `true` when nothing is recorded.
    pub fn is_empty(&self) -> bool {
        self.targets.is_empty()
    }

    /// Forgets the recorded solve: the next prediction falls back to [`predict_from_anchors`].
    pub fn clear(&mut self) {
        self.targets.clear();
        self.deviations.clear();
    }
}

/// Neighbours a vertex keeps in its row of [`Adjacency`] (a regular triangle mesh's interior
/// vertices have six); a vertex with more keeps the rest in the overflow list.
const ROW: usize = 6;

/// A mesh's vertex adjacency laid out for the smoothing sweeps: per vertex a fixed row of
/// [`ROW`] neighbours (padded with the index `n`, where the fields keep a zero), the rest of
/// a vertex's neighbours in an overflow list by vertex, and the mean's weight `1 / (1 +
/// degree)`. Neighbours in the order of the edges.
#[derive(Debug, Clone, Default)]
struct Adjacency {
    rows: Vec<[u32; ROW]>,
    weights: Vec<f32>,
    /// `(vertex, neighbour)` pairs past a full row, by vertex.
    overflow: Vec<[u32; 2]>,
    /// Per chunk of [`MOTION_CHUNK`] vertices its first pair in `overflow`, and the end.
    overflow_starts: Vec<u32>,
    /// The vertex and edge counts it was built for.
    key: (usize, usize),
}

impl Adjacency {
    /// Rebuilds the rows for `n` vertices and `edges` unless they were built for the same
    /// counts. Edges naming a vertex past `n` are left out.
    fn update(&mut self, n: usize, edges: &[[u32; 2]]) {
        if self.key == (n, edges.len()) && self.rows.len() == n {
            return;
        }
        let sentinel = u32::try_from(n).unwrap_or(u32::MAX);
        let mut rows = vec![[sentinel; ROW]; n];
        let mut degree = vec![0usize; n];
        let mut overflow = Vec::new();
        let inside = |&&[a, b]: &&[u32; 2]| (a as usize) < n && (b as usize) < n;
        for &[a, b] in edges.iter().filter(inside) {
            for (v, w) in [(a, b), (b, a)] {
                let d = &mut degree[v as usize];
                match rows[v as usize].get_mut(*d) {
                    Some(slot) => *slot = w,
                    None => overflow.push([v, w]),
                }
                *d += 1;
            }
        }
        // By vertex, each vertex's pairs still in the order of the edges.
        overflow.sort_by_key(|&[v, _]| v);
        let chunks = n.div_ceil(MOTION_CHUNK);
        let overflow_starts = (0..=chunks)
            .map(|c| {
                let first = (c * MOTION_CHUNK) as u64;
                overflow.partition_point(|&[v, _]| u64::from(v) < first) as u32
            })
            .collect();
        *self = Self {
            rows,
            weights: degree.iter().map(|&d| 1.0 / (1 + d) as f32).collect(),
            overflow,
            overflow_starts,
            key: (n, edges.len()),
        };
    }

    /// Chunk `c`'s rows, weights and overflow pairs.
    fn chunk(&self, c: usize) -> (&[[u32; ROW]], &[f32], &[[u32; 2]]) {
        let range = c * MOTION_CHUNK..((c + 1) * MOTION_CHUNK).min(self.rows.len());
        let overflow =
            &self.overflow[self.overflow_starts[c] as usize..self.overflow_starts[c + 1] as usize];
        (&self.rows[range.clone()], &self.weights[range], overflow)
    }

    /// The mean of `field` over vertex `v` (its `row` and `weight`) and its neighbours,
    /// taking `v`'s pairs off the front of `overflow`. `field` holds a zero at index `n`.
    #[inline(always)]
    fn mean(
        field: &[Vec3A],
        v: usize,
        row: &[u32; ROW],
        weight: f32,
        overflow: &mut &[[u32; 2]],
    ) -> Vec3A {
        let f = |w: u32| field[w as usize];
        let mut sum = (field[v] + f(row[0]))
            + (f(row[1]) + f(row[2]))
            + ((f(row[3]) + f(row[4])) + f(row[5]));
        while let [[u, w], rest @ ..] = *overflow
            && *u as usize == v
        {
            sum += f(*w);
            *overflow = rest;
        }
        sum * weight
    }

    /// One Jacobi sweep: each vertex's value of `from` averaged with its neighbours', into
    /// `to` (both with the zero at index `n`).
    fn smooth(&self, from: &[Vec3A], to: &mut [Vec3A]) {
        let n = self.rows.len();
        to[..n]
            .par_chunks_mut(MOTION_CHUNK)
            .enumerate()
            .for_each(|(c, chunk)| {
                let (rows, weights, mut overflow) = self.chunk(c);
                for (k, ((out, row), &weight)) in
                    chunk.iter_mut().zip(rows).zip(weights).enumerate()
                {
                    *out = Self::mean(from, c * MOTION_CHUNK + k, row, weight, &mut overflow);
                }
            });
    }
}

/// Vertices per parallel chunk of [`predict_from_motion`] (fixed, and its sums added in chunk
/// order: the result does not depend on the thread count).
const MOTION_CHUNK: usize = 1024;

/// Second-order warm start: [`predict_from_anchors`] plus the extrapolated change of each
/// anchored vertex's tangential deviation from its anchor.
///
/// With `u = x − target` the deviation at a solve and `history` holding the solve before
/// (`u₋`, `target₋`), each anchored vertex moves by
/// `next.target − prev.target + gain · r · S(P(u − u₋))`, where `P` drops the component along
/// the anchor's normal (the normal deviation is pinned by contacts, whose extrapolation
/// measured no gain), `r = Σ Δ·Δ₋ / Σ |Δ₋|²` (clamped to [−1, 1]) is how the anchors' motion
/// `Δ = next.target − prev.target` continues the last one `Δ₋ = prev.target − target₋`
/// (near 1 for a steady motion, 0 for a still frame, negative when it turns back), and `S` is
/// [`MotionPrediction::smoothing_sweeps`] Jacobi sweeps over the mesh `edges` (each vertex
/// averaged with its neighbours). Vertices with a zero anchor stiffness are left; a move that
/// is not finite is skipped.
///
/// Without a usable history (empty, or recorded for another vertex count) this is
/// [`predict_from_anchors`]. Either way `history` then records this solve's start
/// (`prev.target`, `x − prev.target`), so call it once per frame, before the solve, with `x`
/// the last solve's result. Does nothing (and clears `history`) when `prev` or `next` is not
/// one per vertex.
///
/// Cost: one pass over the vertices (the deviation's change, `r`'s sums, the history and the
/// anchors' carry), then the sweeps (the last one applying the correction), each parallel
/// over fixed chunks: bit-identical for any thread count, no allocation after the first frame.
/// About 0.1 ms per tube-10k frame at 2 threads (the anchors' carry alone: ~0.02 ms).
///
/// ```
/// use dermis::collision::{MotionHistory, MotionPrediction, predict_from_motion};
/// use dermis::solver::VertexAnchor;
/// use glam::Vec3;
/// let anchor = |x: f32| VertexAnchor { target: Vec3::new(x, 0.0, 0.0), normal: Vec3::Z, k_normal: 1.0, k_tangent: 1.0 };
/// let mut history = MotionHistory::default();
/// // Frame 1: the anchor moves 0 -> 1, the skin lags 0.1 behind it.
/// let mut x = [Vec3::new(-0.1, 0.0, 0.0)];
/// predict_from_motion(&mut x, &mut history, &[anchor(0.0)], &[anchor(1.0)], &[], &MotionPrediction::DEFAULT);
/// assert_eq!(x[0], Vec3::new(0.9, 0.0, 0.0)); // no history yet: carried by the anchor
/// // The solve lands 0.2 behind; frame 2 (1 -> 2) extrapolates the lag: 0.3 behind.
/// let mut x = [Vec3::new(0.8, 0.0, 0.0)];
/// predict_from_motion(&mut x, &mut history, &[anchor(1.0)], &[anchor(2.0)], &[], &MotionPrediction::DEFAULT);
/// assert!((x[0].x - 1.7).abs() < 1e-6);
/// ```
pub fn predict_from_motion(
    x: &mut [Vec3],
    history: &mut MotionHistory,
    prev: &[VertexAnchor],
    next: &[VertexAnchor],
    edges: &[[u32; 2]],
    prediction: &MotionPrediction,
) {
    let n = x.len();
    if prev.len() != n || next.len() != n {
        history.clear();
        return;
    }
    let MotionHistory {
        targets,
        deviations,
        adjacency,
        field,
        spare,
        anchored,
        sums,
    } = history;
    let recorded = targets.len() == n && deviations.len() == n;
    if !recorded {
        targets.clear();
        targets.resize(n, Vec3::ZERO);
        deviations.clear();
        deviations.resize(n, Vec3::ZERO);
    }
    // The fields keep a zero past the last vertex, where the rows' padding points.
    field.resize(n + 1, Vec3A::ZERO);
    field[n] = Vec3A::ZERO;
    anchored.resize(n, false);
    sums.clear();
    sums.resize(n.div_ceil(MOTION_CHUNK), [0.0; 2]);

    // One pass: the tangential change of the deviation (zero where there is nothing to
    // extrapolate from), the sums of `r` per chunk, this start recorded, the anchors' carry.
    (
        x.par_chunks_mut(MOTION_CHUNK),
        prev.par_chunks(MOTION_CHUNK),
        next.par_chunks(MOTION_CHUNK),
        targets.par_chunks_mut(MOTION_CHUNK),
        deviations.par_chunks_mut(MOTION_CHUNK),
        field[..n].par_chunks_mut(MOTION_CHUNK),
        anchored.par_chunks_mut(MOTION_CHUNK),
        sums.par_iter_mut(),
    )
        .into_par_iter()
        .for_each(
            |(x, prev, next, targets, deviations, field, anchored, sums)| {
                let (mut num, mut den) = (Vec3A::ZERO, Vec3A::ZERO);
                let vertices = x
                    .iter_mut()
                    .zip(prev.iter().zip(next))
                    .zip(targets.iter_mut().zip(deviations.iter_mut()))
                    .zip(field.iter_mut().zip(anchored.iter_mut()));
                for (((p, (a, b)), (target, deviation)), (change, on)) in vertices {
                    let anchored = a.k_normal > 0.0 || a.k_tangent > 0.0;
                    let u = *p - a.target;
                    let carry = b.target - a.target;
                    *change = Vec3A::ZERO;
                    if recorded && anchored {
                        let last = Vec3A::from(a.target - *target);
                        num += Vec3A::from(carry) * last;
                        den += last * last;
                        let du = u - *deviation;
                        *change = Vec3A::from(du - a.normal * a.normal.dot(du));
                    }
                    *target = a.target;
                    *deviation = u;
                    *on = anchored;
                    if anchored && carry.is_finite() {
                        *p += carry;
                    }
                }
                *sums = [f64::from(num.element_sum()), f64::from(den.element_sum())];
            },
        );

    let (num, den) = sums
        .iter()
        .fold((0.0, 0.0), |(n, d), [a, b]| (n + a, d + b));
    let r = num / den;
    if !(den > 0.0 && r.is_finite()) {
        return;
    }
    let s = prediction.gain * r.clamp(-1.0, 1.0) as f32;
    if s == 0.0 || !s.is_finite() {
        return;
    }
    // The sweeps but the last, then the last one fused with the correction's application.
    let sweeps = if edges.is_empty() {
        0
    } else {
        adjacency.update(n, edges);
        prediction.smoothing_sweeps
    };
    if sweeps > 1 {
        spare.resize(n + 1, Vec3A::ZERO);
        spare[n] = Vec3A::ZERO;
        for _ in 1..sweeps {
            adjacency.smooth(field, spare);
            std::mem::swap(field, spare);
        }
    }
    let (field, adjacency) = (&*field, &*adjacency);
    x.par_chunks_mut(MOTION_CHUNK)
        .zip(anchored.par_chunks(MOTION_CHUNK))
        .enumerate()
        .for_each(|(c, (x, anchored))| {
            let apply = |p: &mut Vec3, d: Vec3A| {
                let m = Vec3::from(s * d);
                if m.is_finite() {
                    *p += m;
                }
            };
            let first = c * MOTION_CHUNK;
            if sweeps == 0 {
                for (k, (p, _)) in x
                    .iter_mut()
                    .zip(anchored)
                    .enumerate()
                    .filter(|(_, (_, on))| **on)
                {
                    apply(p, field[first + k]);
                }
                return;
            }
            let (rows, weights, mut overflow) = adjacency.chunk(c);
            let vertices = x.iter_mut().zip(anchored).zip(rows.iter().zip(weights));
            for (k, ((p, &on), (row, &weight))) in vertices.enumerate() {
                let v = first + k;
                // Every vertex's overflow pairs are taken, anchored or not.
                let d = Adjacency::mean(field, v, row, weight, &mut overflow);
                if on {
                    apply(p, d);
                }
            }
        });
}

/// A skin collision that trusts a solver order (see `SkinCollision::trust_order`) until it is
/// dropped, however the frame ends.
struct TrustedOrder<'a>(&'a mut SkinCollision);

impl<'a> TrustedOrder<'a> {
    /// `collision` trusting `order`, which the caller keeps borrowed while this lives.
    fn new(collision: &'a mut SkinCollision, order: &'a [u32]) -> Self {
        collision.trust_order(order);
        Self(collision)
    }
}

impl std::ops::Deref for TrustedOrder<'_> {
    type Target = SkinCollision;
    fn deref(&self) -> &SkinCollision {
        self.0
    }
}

impl std::ops::DerefMut for TrustedOrder<'_> {
    fn deref_mut(&mut self) -> &mut SkinCollision {
        self.0
    }
}

impl Drop for TrustedOrder<'_> {
    fn drop(&mut self) {
        self.0.distrust_order();
    }
}

/// Relaxes one frame of `system` in contact: `collision`'s last frame's pass state forgotten
/// ([`SkinCollision::clear_frame_state`]; its query cache carries over), the frame plan
/// ([`SkinCollision::begin_frame`]), and per substep a contact pass
/// ([`SkinCollision::substep`]) followed, on the intermediate substeps, by
/// `schedule.substep_iterations` of relaxation and, on the last, by the rest of the budget
/// with the contact as the projection. `x` (caller's order) holds the warm start (see
/// [`predict_from_anchors`]).
pub fn relax_frame(
    system: &SpringSystem,
    collision: &mut SkinCollision,
    x: &mut [Vec3],
    loads: &Loads<'_>,
    config: &RelaxConfig,
    schedule: &FrameSchedule,
) -> Result<FrameRelax, FrameError> {
    // One job on the rayon pool for the whole frame (see `SpringSystem::relax_projected`).
    rayon::scope(|_| {
        // `system` is borrowed for the whole frame, so its order cannot change: the
        // projections need not compare it pass by pass.
        let mut collision = TrustedOrder::new(collision, system.order());
        let t = Instant::now();
        collision.clear_frame_state();
        let plan = collision.begin_frame(x)?;
        let plan_time = t.elapsed();
        let (mut pass_time, mut projection_time) = (Duration::ZERO, Duration::ZERO);
        let substeps = plan.substeps.max(1);
        let intermediate = schedule
            .substep_iterations
            .min((config.max_iterations / (2 * substeps)).max(1));
        let last = config
            .max_iterations
            .saturating_sub(intermediate * (substeps - 1))
            .max(1);
        let mut iterations = 0;
        let mut last_report = None;
        for s in 0..substeps {
            let t = Instant::now();
            collision.substep(x)?;
            pass_time += t.elapsed();
            let max_iterations = if s + 1 == substeps {
                last
            } else {
                intermediate
            };
            if max_iterations == 0 {
                continue;
            }
            let sub_config = RelaxConfig {
                max_iterations,
                ..*config
            };
            let alongside = collision.alongside;
            let mut timed = Timed::new(&mut *collision);
            let report = system.relax_projected(x, loads, &sub_config, Some(&mut timed))?;
            projection_time += Duration::from_secs_f64(timed.seconds);
            // The passes run alongside the force gather share its loop's wall time: theirs is
            // their CPU time over the solve's team.
            let members = crate::solver::team_size(x.len());
            projection_time += (collision.alongside - alongside) / members as u32;
            iterations += report.iterations;
            last_report = Some(report);
        }
        let report = last_report.expect("the last substep always relaxes");
        Ok(FrameRelax {
            report: RelaxReport {
                iterations,
                ..report
            },
            substeps,
            plan_time,
            pass_time,
            projection_time,
        })
    })
}

#[cfg(test)]
mod tests {
    use glam::Vec3;

    use super::*;
    use crate::collision::ContactConfig;
    use crate::mesh::TriMesh;
    use crate::stiffness::{Modulus, StiffnessRule};

    /// A flat `n` x `n` sheet of side `size` in the z = 0 plane.
    fn sheet(n: u32, size: f32) -> TriMesh {
        crate::mesh::shapes::sheet(n, size)
    }

    fn springs(mesh: &TriMesh) -> SpringSystem {
        let k = StiffnessRule::AreaOverLengthSquared
            .edge_stiffness(mesh, &Modulus::Uniform(1000.0))
            .unwrap();
        SpringSystem::from_mesh(mesh, &k).unwrap()
    }

    fn anchors(mesh: &TriMesh, shift: Vec3) -> Vec<VertexAnchor> {
        // Anchored to a stretched, bulged copy: an equilibrium with stressed springs.
        mesh.positions()
            .iter()
            .map(|p| VertexAnchor {
                target: Vec3::new(1.2 * p.x, p.y, 0.02 * (8.0 * p.x).sin()) + shift,
                normal: Vec3::Z,
                k_normal: 50.0,
                k_tangent: 5.0,
            })
            .collect()
    }

    #[test]
    fn anchor_prediction_carries_a_rigidly_moved_equilibrium() {
        // Translation invariance: when every anchor moves by d, the equilibrium moves by d, so
        // the predicted start is already converged while last frame's positions are not.
        let mesh = sheet(12, 0.2);
        let system = springs(&mesh);
        let n = mesh.positions().len();
        let config = RelaxConfig {
            max_iterations: 2000,
            tolerance: 1e-3,
            force_scale: Some(1.0),
            ..RelaxConfig::DEFAULT
        };
        let mut contact = SkinCollision::new(n, ContactConfig::DEFAULT).unwrap();
        let before = anchors(&mesh, Vec3::ZERO);
        let mut x = mesh.positions().to_vec();
        let tight = RelaxConfig {
            tolerance: 1e-4,
            stagnation_window: 0,
            ..config
        };
        let loads = Loads {
            anchors: Some(&before),
            ..Default::default()
        };
        let settle = system.relax(&mut x, &loads, &tight).unwrap();
        assert!(settle.converged(), "{settle:?}");
        let d = Vec3::new(0.01, -0.02, 0.005);
        let after = anchors(&mesh, d);
        let loads = Loads {
            anchors: Some(&after),
            ..Default::default()
        };
        let mut stale = x.clone();
        let stale_run = relax_frame(
            &system,
            &mut contact.clone(),
            &mut stale,
            &loads,
            &config,
            &FrameSchedule::DEFAULT,
        )
        .unwrap();
        assert!(stale_run.report.iterations > 0);
        let expected: Vec<Vec3> = x.iter().map(|p| *p + d).collect();
        predict_from_anchors(&mut x, &before, &after);
        let run = relax_frame(
            &system,
            &mut contact,
            &mut x,
            &loads,
            &config,
            &FrameSchedule::DEFAULT,
        )
        .unwrap();
        assert!(run.report.converged());
        assert_eq!(run.report.iterations, 0);
        for (p, e) in x.iter().zip(&expected) {
            assert!(p.distance(*e) < 1e-6);
        }
        // The stale start converges to the same equilibrium, the long way.
        for (p, e) in stale.iter().zip(&expected) {
            assert!(p.distance(*e) < 1e-3, "{p} vs {e}");
        }
    }

    #[test]
    fn motion_prediction_starts_a_linearly_drifting_equilibrium_converged() {
        // Anchors at the rest sheet moving at a constant velocity V, isotropic anchor springs k
        // and the same in-plane force F(t) = F0 + t·F1 on every vertex: the springs stay at rest
        // length, so the equilibrium is exactly x*(t) = rest + t·V + F(t)/k. Its deviation from
        // the anchors changes linearly (in the tangent plane): the second-order start is
        // x*(t+1) and needs no iteration; the first-order one lags by F1/k.
        let mesh = sheet(10, 0.2);
        let system = springs(&mesh);
        let n = mesh.positions().len();
        let k = 40.0;
        let v = Vec3::new(0.01, -0.005, 0.002);
        let (f0, f1) = (Vec3::new(0.2, -0.1, 0.0), Vec3::new(0.05, 0.08, 0.0));
        let anchors = |t: f32| -> Vec<VertexAnchor> {
            mesh.positions()
                .iter()
                .map(|p| VertexAnchor {
                    target: *p + t * v,
                    normal: Vec3::Z,
                    k_normal: k,
                    k_tangent: k,
                })
                .collect()
        };
        let force = |t: f32| f0 + t * f1;
        let equilibrium =
            |t: f32| -> Vec<Vec3> { anchors(t).iter().map(|a| a.target + force(t) / k).collect() };
        let config = RelaxConfig {
            max_iterations: 500,
            tolerance: 1e-4,
            force_scale: Some(1.0),
            ..RelaxConfig::DEFAULT
        };
        let forces = vec![force(2.0); n];
        let loads = Loads {
            forces: Some(&forces),
            anchors: Some(&anchors(2.0)),
            ..Default::default()
        };
        let edges = mesh.topology().edges();
        let contact = SkinCollision::new(n, ContactConfig::DEFAULT).unwrap();
        let mut history = MotionHistory::default();
        // Frame 1 (from the solve at t = 0): no history, the anchors' motion alone.
        let mut x = equilibrium(0.0);
        let mut first = x.clone();
        predict_from_anchors(&mut first, &anchors(0.0), &anchors(1.0));
        predict_from_motion(
            &mut x,
            &mut history,
            &anchors(0.0),
            &anchors(1.0),
            edges,
            &MotionPrediction::DEFAULT,
        );
        assert_eq!(x, first);
        assert_eq!(history.targets().len(), n);
        // Frame 2 (from the solve at t = 1): extrapolated.
        let mut x = equilibrium(1.0);
        let mut first = x.clone();
        predict_from_anchors(&mut first, &anchors(1.0), &anchors(2.0));
        predict_from_motion(
            &mut x,
            &mut history,
            &anchors(1.0),
            &anchors(2.0),
            edges,
            &MotionPrediction::DEFAULT,
        );
        let exact = equilibrium(2.0);
        for (p, e) in x.iter().zip(&exact) {
            assert!(p.distance(*e) < 1e-6, "{p} vs {e}");
        }
        let run = |x: &mut Vec<Vec3>| {
            relax_frame(
                &system,
                &mut contact.clone(),
                x,
                &loads,
                &config,
                &FrameSchedule::DEFAULT,
            )
            .unwrap()
            .report
        };
        let second_order = run(&mut x);
        assert!(second_order.converged() && second_order.iterations == 0);
        let first_order = run(&mut first);
        assert!(first_order.iterations > 0, "{first_order:?}");
        for (p, e) in first.iter().zip(&exact) {
            assert!(p.distance(*e) < 1e-3, "{p} vs {e}");
        }
    }

    #[test]
    fn motion_prediction_extrapolates_only_the_tangential_deviation_scaled_by_the_motion() {
        // One anchored vertex with normal z: deviation change (0.1, 0, 0.3) over the last frame.
        let anchor = |x: f32| VertexAnchor {
            target: Vec3::new(x, 0.0, 0.0),
            normal: Vec3::Z,
            k_normal: 1.0,
            k_tangent: 1.0,
        };
        let prediction = MotionPrediction {
            gain: 1.0,
            smoothing_sweeps: 0,
        };
        let step = |history: &mut MotionHistory, x: Vec3, a: f32, b: f32| {
            let mut x = [x];
            predict_from_motion(
                &mut x,
                history,
                &[anchor(a)],
                &[anchor(b)],
                &[],
                &prediction,
            );
            x[0]
        };
        let u0 = Vec3::new(0.0, 0.0, 0.1);
        let u1 = u0 + Vec3::new(0.1, 0.0, 0.3);
        // Steady motion (ratio 1): the tangential change carried, the normal one not.
        let mut h = MotionHistory::default();
        step(&mut h, anchor(0.0).target + u0, 0.0, 1.0);
        let x = step(&mut h, anchor(1.0).target + u1, 1.0, 2.0);
        assert!(x.distance(anchor(2.0).target + u1 + Vec3::new(0.1, 0.0, 0.0)) < 1e-6);
        // The motion turns back (ratio −1): the change is undone.
        let mut h = MotionHistory::default();
        step(&mut h, anchor(0.0).target + u0, 0.0, 1.0);
        let x = step(&mut h, anchor(1.0).target + u1, 1.0, 0.0);
        assert!(x.distance(anchor(0.0).target + u1 - Vec3::new(0.1, 0.0, 0.0)) < 1e-6);
        // Half the speed: half the change.
        let mut h = MotionHistory::default();
        step(&mut h, anchor(0.0).target + u0, 0.0, 1.0);
        let x = step(&mut h, anchor(1.0).target + u1, 1.0, 1.5);
        assert!(x.distance(anchor(1.5).target + u1 + Vec3::new(0.05, 0.0, 0.0)) < 1e-6);
        // A cleared history (a jump): the anchors' motion alone.
        h.clear();
        let x = step(&mut h, anchor(1.5).target + u1, 1.5, 2.5);
        assert_eq!(x, anchor(2.5).target + u1);
        // Mismatched lengths: nothing moves and the history is dropped.
        let mut x = [Vec3::ONE, Vec3::ONE];
        predict_from_motion(
            &mut x,
            &mut h,
            &[anchor(0.0)],
            &[anchor(1.0)],
            &[],
            &prediction,
        );
        assert_eq!(x, [Vec3::ONE; 2]);
        assert!(h.is_empty());
    }

    #[test]
    fn smoothing_keeps_a_uniform_correction_and_spreads_a_spike_to_the_edges_neighbours() {
        // The averaging sweep leaves a constant field unchanged and spreads a spike to the
        // vertices sharing an edge with it, each with weight 1/(1 + its own degree), the
        // degrees counted from the edge list.
        let mesh = sheet(40, 1.0);
        let n = mesh.positions().len();
        let edges = mesh.topology().edges();
        let mut adjacency = Adjacency::default();
        adjacency.update(n, edges);
        // The fields hold a zero past the last vertex (where the rows' padding points).
        let mut uniform = vec![Vec3A::new(0.25, -0.5, 1.0); n + 1];
        uniform[n] = Vec3A::ZERO;
        let mut out = vec![Vec3A::ZERO; n + 1];
        adjacency.smooth(&uniform, &mut out);
        assert_eq!(out[..n], uniform[..n]);
        let mut degree = vec![0usize; n];
        for &[a, b] in edges {
            degree[a as usize] += 1;
            degree[b as usize] += 1;
        }
        let c = n / 2;
        let spike: Vec<Vec3A> = (0..=n)
            .map(|i| if i == c { Vec3A::X } else { Vec3A::ZERO })
            .collect();
        adjacency.smooth(&spike, &mut out);
        for (w, p) in out[..n].iter().enumerate() {
            let touches = w == c
                || edges.iter().any(|&[a, b]| {
                    (a as usize, b as usize) == (w, c) || (b as usize, a as usize) == (w, c)
                });
            let expected = if touches {
                Vec3A::X / (1 + degree[w]) as f32
            } else {
                Vec3A::ZERO
            };
            assert_eq!(*p, expected, "vertex {w}");
        }
    }

    #[test]
    fn smoothing_over_vertices_of_any_degree_is_the_neighbourhood_mean() {
        // A graph over three chunks with hubs of degree 20+ (their neighbours past the row go
        // to the overflow list, some across chunk boundaries), isolated vertices and edges
        // naming a missing vertex (left out): each output is the plain mean over the vertex
        // and its neighbours, counted from the edge list.
        let n = 3 * MOTION_CHUNK + 100;
        let mut edges: Vec<[u32; 2]> = (0..n as u32 - 2)
            .filter(|v| v % 97 != 5)
            .flat_map(|v| [[v, v + 1], [v, v + 2]])
            .collect();
        for hub in (0..n as u32).step_by(500) {
            edges.extend((1..=20).map(|k| [hub, (hub + 37 * k) % n as u32]));
        }
        edges.push([3, n as u32 + 4]);
        let mut around = vec![vec![]; n];
        for &[a, b] in edges.iter().filter(|e| e[1] < n as u32) {
            around[a as usize].push(b as usize);
            around[b as usize].push(a as usize);
        }
        assert!(around.iter().any(|a| a.len() > 2 * ROW));
        let mut adjacency = Adjacency::default();
        adjacency.update(n, &edges);
        let mut field: Vec<Vec3A> = (0..n)
            .map(|i| Vec3A::new((i % 13) as f32, -((i % 7) as f32), (i * i % 11) as f32))
            .collect();
        field.push(Vec3A::ZERO);
        let mut out = vec![Vec3A::ZERO; n + 1];
        adjacency.smooth(&field, &mut out);
        for (v, p) in out[..n].iter().enumerate() {
            let sum = around[v].iter().fold(field[v], |s, &w| s + field[w]);
            let mean = sum / (1 + around[v].len()) as f32;
            assert!(p.distance(mean) < 1e-5, "vertex {v}: {p} vs {mean}");
        }
    }

    /// A direct serial reading of [`predict_from_motion`]'s formula (f64, neighbour lists from
    /// the edges): `x + Δ + gain · r · S(P(u − u₋))`.
    fn reference_prediction(
        x: &[Vec3],
        history: (&[Vec3], &[Vec3]),
        prev: &[VertexAnchor],
        next: &[VertexAnchor],
        edges: &[[u32; 2]],
        prediction: &MotionPrediction,
    ) -> Vec<Vec3> {
        use glam::DVec3;
        let n = x.len();
        let on = |a: &VertexAnchor| a.k_normal > 0.0 || a.k_tangent > 0.0;
        let (mut num, mut den) = (0.0, 0.0);
        for v in (0..n).filter(|&v| on(&prev[v])) {
            let d1 = (next[v].target - prev[v].target).as_dvec3();
            let d0 = (prev[v].target - history.0[v]).as_dvec3();
            num += d1.dot(d0);
            den += d0.length_squared();
        }
        let r = (num / den).clamp(-1.0, 1.0);
        let mut field: Vec<DVec3> = (0..n)
            .map(|v| {
                if !on(&prev[v]) {
                    return DVec3::ZERO;
                }
                let du = (x[v] - prev[v].target - history.1[v]).as_dvec3();
                let normal = prev[v].normal.as_dvec3();
                du - normal * normal.dot(du)
            })
            .collect();
        let mut around = vec![vec![]; n];
        for &[a, b] in edges {
            around[a as usize].push(b as usize);
            around[b as usize].push(a as usize);
        }
        for _ in 0..prediction.smoothing_sweeps {
            field = (0..n)
                .map(|v| {
                    let sum = around[v].iter().fold(field[v], |s, &w| s + field[w]);
                    sum / (1 + around[v].len()) as f64
                })
                .collect();
        }
        (0..n)
            .map(|v| {
                if !on(&prev[v]) {
                    return x[v];
                }
                let carry = (next[v].target - prev[v].target).as_dvec3();
                (x[v].as_dvec3() + carry + f64::from(prediction.gain) * r * field[v]).as_vec3()
            })
            .collect()
    }

    #[test]
    fn motion_prediction_follows_its_formula_with_the_same_bits_on_any_thread_count() {
        // A 3,721-vertex sheet (several chunks), anchors wandering along a smooth but
        // non-uniform path with every seventh vertex unanchored, a skin off its anchors by a
        // varying amount: three predictions in a row, on 1, 2 and 3 threads. Each matches the
        // direct f64 reading of the formula, and the three runs agree bit for bit (positions
        // and the recorded history).
        let mesh = sheet(60, 1.0);
        let n = mesh.positions().len();
        assert!(n > 3 * MOTION_CHUNK);
        let edges = mesh.topology().edges();
        let anchors = |t: f32| -> Vec<VertexAnchor> {
            mesh.positions()
                .iter()
                .enumerate()
                .map(|(i, p)| {
                    let phase = 3.0 * p.x + 2.0 * p.y + t;
                    let normal = Vec3::new(0.2 * phase.sin(), 0.1, 1.0).normalize();
                    let free = i % 7 == 3;
                    VertexAnchor {
                        target: *p + Vec3::new(0.01 * t * t, 0.02 * phase.sin(), 0.01 * t),
                        normal,
                        k_normal: if free { 0.0 } else { 10.0 },
                        k_tangent: if free { 0.0 } else { 1.0 },
                    }
                })
                .collect()
        };
        let skin = |t: f32| -> Vec<Vec3> {
            anchors(t)
                .iter()
                .enumerate()
                .map(|(i, a)| {
                    let wobble = ((i * 7919) % 113) as f32 * 1e-5;
                    a.target + Vec3::new(0.003 * t + wobble, -0.002 * t * t, 0.001 - wobble)
                })
                .collect()
        };
        let prediction = MotionPrediction::DEFAULT;
        let run = |threads: usize| {
            crate::test_support::in_pool(threads, || {
                let mut history = MotionHistory::default();
                let mut out = vec![];
                for t in 0..3 {
                    let (prev, next) = (anchors(t as f32), anchors(t as f32 + 1.0));
                    let mut x = skin(t as f32);
                    let before = (history.targets().to_vec(), history.deviations().to_vec());
                    predict_from_motion(&mut x, &mut history, &prev, &next, edges, &prediction);
                    if t > 0 {
                        let expected = reference_prediction(
                            &skin(t as f32),
                            (&before.0, &before.1),
                            &prev,
                            &next,
                            edges,
                            &prediction,
                        );
                        let moved = expected
                            .iter()
                            .zip(skin(t as f32))
                            .map(|(e, s)| e.distance(s))
                            .fold(0.0, f32::max);
                        for (p, e) in x.iter().zip(&expected) {
                            assert!(p.distance(*e) < 1e-6 * moved.max(1.0), "{p} vs {e}");
                        }
                        // The extrapolation took part (not the anchors' carry alone).
                        let mut carried = skin(t as f32);
                        predict_from_anchors(&mut carried, &prev, &next);
                        assert!(x.iter().zip(&carried).any(|(p, c)| p.distance(*c) > 1e-4));
                    }
                    out.push((x, history.clone()));
                }
                out
            })
        };
        let one = run(1);
        for threads in [2, 3] {
            for ((x1, h1), (x2, h2)) in one.iter().zip(&run(threads)) {
                let bits = |x: &[Vec3]| {
                    x.iter()
                        .map(|p| p.to_array().map(f32::to_bits))
                        .collect::<Vec<_>>()
                };
                assert_eq!(bits(x1), bits(x2));
                assert_eq!(bits(h1.targets()), bits(h2.targets()));
                assert_eq!(bits(h1.deviations()), bits(h2.deviations()));
            }
        }
    }
}
