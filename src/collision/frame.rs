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
    /// Time spent in contact (frame plan, substep passes, projections inside the solves): the
    /// sum of the three below.
    pub contact_time: Duration,
    /// The frame plan ([`SkinCollision::begin_frame`]).
    pub plan_time: Duration,
    /// The substeps' contact passes ([`SkinCollision::substep`]).
    pub pass_time: Duration,
    /// The projections inside the relaxations.
    pub projection_time: Duration,
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
            let mut timed = Timed::new(collision);
            let report = system.relax_projected(x, loads, &sub_config, Some(&mut timed))?;
            projection_time += Duration::from_secs_f64(timed.seconds);
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
            contact_time: plan_time + pass_time + projection_time,
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
}
