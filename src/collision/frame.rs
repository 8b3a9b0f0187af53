//! One animation frame of a skin in contact: substeps, contact passes and the relaxation, shared by the ECS and the bench.

use std::time::{Duration, Instant};

use glam::Vec3;
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
    /// Time spent in contact (frame plan, substep passes, projections inside the solves).
    pub contact_time: Duration,
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
    /// Gain 1, 4 smoothing sweeps. Measured paired (each frame from the same state) on the
    /// bench's elbow clip against [`predict_from_anchors`]: 7.4 % fewer iterations at tube-10k
    /// (better in 45 frames of 60, worse in 13), 1.6 % at tube-100k (32 / 22); see
    /// `benches/README.md`, session 7.
    pub const DEFAULT: Self = Self {
        gain: 1.0,
        smoothing_sweeps: 4,
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
#[derive(Debug, Clone, Default)]
pub struct MotionHistory {
    targets: Vec<Vec3>,
    deviations: Vec<Vec3>,
    /// The mesh's vertex adjacency (CSR), built on first use for `adjacency_key`.
    offsets: Vec<u32>,
    neighbours: Vec<u32>,
    adjacency_key: (usize, usize),
    /// Buffers reused from frame to frame (no allocation, no fresh pages, per prediction).
    scratch: [Vec<Vec3>; 3],
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

    fn adjacency(&mut self, n: usize, edges: &[[u32; 2]]) -> (&[u32], &[u32]) {
        if self.adjacency_key != (n, edges.len()) || self.offsets.len() != n + 1 {
            let mut degree = vec![0u32; n + 1];
            for &[a, b] in edges {
                if (a as usize) < n && (b as usize) < n {
                    degree[a as usize + 1] += 1;
                    degree[b as usize + 1] += 1;
                }
            }
            for v in 0..n {
                degree[v + 1] += degree[v];
            }
            let mut fill = degree.clone();
            let mut neighbours = vec![0u32; degree[n] as usize];
            for &[a, b] in edges {
                if (a as usize) < n && (b as usize) < n {
                    neighbours[fill[a as usize] as usize] = b;
                    fill[a as usize] += 1;
                    neighbours[fill[b as usize] as usize] = a;
                    fill[b as usize] += 1;
                }
            }
            self.offsets = degree;
            self.neighbours = neighbours;
            self.adjacency_key = (n, edges.len());
        }
        (&self.offsets, &self.neighbours)
    }
}

/// Vertices per parallel chunk of the smoothing sweeps (fixed: the result does not depend on
/// the thread count).
const SMOOTH_CHUNK: usize = 1024;

/// Second-order warm start: [`predict_from_anchors`] plus the extrapolated change of each
/// anchored vertex's tangential deviation from its anchor.
///
/// With `u = x − target` the deviation at a solve and `history` holding the solve before
/// (`u₋`, `target₋`), each anchored vertex moves by
/// `next.target − prev.target + gain · r · P(u − u₋)`, where `P` drops the component along
/// the anchor's normal (the normal deviation is pinned by contacts, whose extrapolation
/// measured no gain), `r = Σ Δ·Δ₋ / Σ |Δ₋|²` (clamped to [−1, 1]) is how the anchors' motion
/// `Δ = next.target − prev.target` continues the last one `Δ₋ = prev.target − target₋`
/// (near 1 for a steady motion, 0 for a still frame, negative when it turns back), and the
/// correction is smoothed over the mesh `edges` by [`MotionPrediction::smoothing_sweeps`]
/// Jacobi sweeps. Vertices with a zero anchor stiffness are left.
///
/// Without a usable history (empty, or recorded for another vertex count) this is
/// [`predict_from_anchors`]. Either way `history` then records this solve's start
/// (`prev.target`, `x − prev.target`), so call it once per frame, before the solve, with `x`
/// the last solve's result. Does nothing (and clears `history`) when `prev` or `next` is not
/// one per vertex.
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
    let anchored = |a: &VertexAnchor| a.k_normal > 0.0 || a.k_tangent > 0.0;
    let [mut deviations, mut delta, mut spare] = std::mem::take(&mut history.scratch);
    deviations.clear();
    deviations.extend(x.iter().zip(prev).map(|(p, a)| *p - a.target));
    let mut ratio = 0.0f32;
    if history.targets.len() == n && history.deviations.len() == n {
        let (mut num, mut den) = (0.0f64, 0.0f64);
        for ((a, b), t0) in prev.iter().zip(next).zip(&history.targets) {
            if anchored(a) {
                let d1 = (b.target - a.target).as_dvec3();
                let d0 = (a.target - *t0).as_dvec3();
                num += d1.dot(d0);
                den += d0.length_squared();
            }
        }
        let r = num / den;
        if den > 0.0 && r.is_finite() {
            ratio = r.clamp(-1.0, 1.0) as f32;
        }
    }
    let s = prediction.gain * ratio;
    if s != 0.0 && s.is_finite() {
        delta.clear();
        delta.extend(
            prev.iter()
                .zip(&deviations)
                .zip(&history.deviations)
                .map(|((a, u), u0)| {
                    if !anchored(a) {
                        return Vec3::ZERO;
                    }
                    let du = *u - *u0;
                    s * (du - a.normal * a.normal.dot(du))
                }),
        );
        if prediction.smoothing_sweeps > 0 && !edges.is_empty() {
            spare.clear();
            spare.resize(n, Vec3::ZERO);
            let (offsets, neighbours) = history.adjacency(n, edges);
            for _ in 0..prediction.smoothing_sweeps {
                smooth_sweep(&delta, &mut spare, offsets, neighbours);
                std::mem::swap(&mut delta, &mut spare);
            }
        }
        for (((p, a), b), d) in x.iter_mut().zip(prev).zip(next).zip(&delta) {
            if anchored(a) {
                let m = b.target - a.target + *d;
                if m.is_finite() {
                    *p += m;
                }
            }
        }
    } else {
        predict_from_anchors(x, prev, next);
    }
    history.targets.clear();
    history.targets.extend(prev.iter().map(|a| a.target));
    std::mem::swap(&mut history.deviations, &mut deviations);
    history.scratch = [deviations, delta, spare];
}

/// One Jacobi sweep: each vertex's value averaged with its neighbours'.
fn smooth_sweep(from: &[Vec3], to: &mut [Vec3], offsets: &[u32], neighbours: &[u32]) {
    use rayon::prelude::*;
    to.par_chunks_mut(SMOOTH_CHUNK)
        .enumerate()
        .for_each(|(c, chunk)| {
            for (k, out) in chunk.iter_mut().enumerate() {
                let v = c * SMOOTH_CHUNK + k;
                let (lo, hi) = (offsets[v] as usize, offsets[v + 1] as usize);
                let mut sum = from[v];
                for &w in &neighbours[lo..hi] {
                    sum += from[w as usize];
                }
                *out = sum / (1 + hi - lo) as f32;
            }
        });
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
        let t = Instant::now();
        collision.clear_frame_state();
        let plan = collision.begin_frame(x)?;
        let mut contact_time = t.elapsed();
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
            contact_time += t.elapsed();
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
            let mut timed = Timed::new(collision);
            let report = system.relax_projected(x, loads, &sub_config, Some(&mut timed))?;
            contact_time += Duration::from_secs_f64(timed.seconds);
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
            contact_time,
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
    fn smoothing_keeps_a_uniform_correction_and_is_thread_count_independent() {
        // The averaging sweep leaves a constant field unchanged and spreads a spike to the
        // neighbours, each with weight 1/(1 + its degree); the same bits on 1 and 2 threads.
        let mesh = sheet(40, 1.0);
        let n = mesh.positions().len();
        let mut h = MotionHistory::default();
        let (offsets, neighbours) = {
            let (o, nb) = h.adjacency(n, mesh.topology().edges());
            (o.to_vec(), nb.to_vec())
        };
        let uniform = vec![Vec3::new(0.25, -0.5, 1.0); n];
        let mut out = vec![Vec3::ZERO; n];
        smooth_sweep(&uniform, &mut out, &offsets, &neighbours);
        assert_eq!(out, uniform);
        let spike: Vec<Vec3> = (0..n)
            .map(|i| if i == n / 2 { Vec3::X } else { Vec3::ZERO })
            .collect();
        smooth_sweep(&spike, &mut out, &offsets, &neighbours);
        let degree = (offsets[n / 2 + 1] - offsets[n / 2]) as usize;
        assert_eq!(out[n / 2], Vec3::X / (1 + degree) as f32);
        let spike_neighbours = &neighbours[offsets[n / 2] as usize..offsets[n / 2 + 1] as usize];
        for (w, p) in out.iter().enumerate() {
            let dw = (offsets[w + 1] - offsets[w]) as f32;
            if spike_neighbours.contains(&(w as u32)) {
                assert_eq!(*p, Vec3::X / (1.0 + dw));
            } else if w != n / 2 {
                assert_eq!(*p, Vec3::ZERO);
            }
        }
        let run = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            let noisy: Vec<Vec3> = (0..n)
                .map(|i| Vec3::splat(((i * 7919) % 113) as f32 * 1e-3))
                .collect();
            pool.install(|| {
                let mut a = noisy.clone();
                let mut b = vec![Vec3::ZERO; n];
                for _ in 0..8 {
                    smooth_sweep(&a, &mut b, &offsets, &neighbours);
                    std::mem::swap(&mut a, &mut b);
                }
                a
            })
        };
        assert_eq!(run(1), run(2));
    }
}
