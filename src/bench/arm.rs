//! The real frame of `dermis bench`: a skin tube over a deforming muscle and two capsule bones, an elbow-flexion clip.
//!
//! The arm lies along +z: shoulder at `z = 0`, elbow at [`ELBOW_Z_M`], wrist at 0.4 m; the skin
//! is the bench's 10 cm tube. The forearm flexes towards +y about the x axis through the
//! elbow, following `θ(f) = θmax (1 − cos 2πf/F) / 2` over a clip of `F` frames (one flexion and
//! extension). Under the skin:
//!
//! - a biceps on the +y side of the upper arm: an ellipsoid mesh (50k triangles in the
//!   standard workloads) that thickens and shortens with the flexion, refitted every frame with
//!   [`ColliderMesh::set_vertices`]; at full flexion it stands 3 mm proud of the rest skin, so
//!   the skin must slide over it;
//! - a humerus (static capsule) and an ulna (capsule moved with the forearm's pose) whose
//!   olecranon end pokes through the linear-blend-skinned skin at the back of the elbow.
//!
//! The skin's anchors follow a linear blend of the upper-arm and forearm transforms (weights
//! ramping over 6 cm around the elbow), so without contact the skin would sink into both the
//! muscle and the ulna.

use std::time::Instant;

use glam::{Quat, Vec3};
use parry3d::math::Pose;
use parry3d::query::PointQuery;
use parry3d::shape::Capsule;
use rayon::prelude::*;

use super::TubeWorkload;
use crate::collision::shapes::ellipsoid;
use crate::collision::{
    ColliderId, ColliderMesh, CollisionError, ContactConfig, FrameError, FrameSchedule,
    MotionHistory, MotionPrediction, RefitStats, SkinCollision, predict_from_anchors,
    predict_from_motion, relax_frame,
};
use crate::solver::{Loads, RelaxConfig, RelaxReport, SolverError, VertexAnchor};

/// Height of the elbow's flexion axis along the tube, m.
pub const ELBOW_Z_M: f32 = 0.2;
/// Largest flexion of the clip, rad (60°).
pub const MAX_FLEXION_RAD: f32 = std::f32::consts::FRAC_PI_3;
/// Frames of the standard clip (one flexion and extension, two seconds at 30 fps).
pub const CLIP_FRAMES: usize = 60;
/// Skin thickness kept from every collider, m.
pub const THICKNESS_M: f32 = 0.002;
/// Stiffness of the anchors along the skin's normal, N/m.
pub const ANCHOR_K_NORMAL: f32 = 200.0;
/// Stiffness of the anchors along the skin, N/m.
pub const ANCHOR_K_TANGENT: f32 = 20.0;

/// A bone: a capsule around the segment `a`–`b` (rest pose, m) of radius `radius_m`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Bone {
    /// One end, m.
    pub a: Vec3,
    /// The other end, m.
    pub b: Vec3,
    /// Radius, m.
    pub radius_m: f32,
}

/// The upper-arm bone (never moves).
pub const HUMERUS: Bone = Bone {
    a: Vec3::new(0.0, -0.01, 0.02),
    b: Vec3::new(0.0, -0.01, 0.19),
    radius_m: 0.015,
};

/// The forearm bone in its rest pose; its elbow end lies 3 mm under the rest skin (with the
/// thickness) at the back of the elbow.
pub const ULNA: Bone = Bone {
    a: Vec3::new(0.0, -0.025, ELBOW_Z_M),
    b: Vec3::new(0.0, -0.015, 0.38),
    radius_m: 0.02,
};

/// The biceps as an analytic ellipsoid at flexion fraction `s ∈ [0, 1]`: (centre, semi-axes),
/// m. The muscle mesh has its vertices on this ellipsoid.
pub fn muscle_ellipsoid(s: f32) -> (Vec3, Vec3) {
    let centre = Vec3::new(0.0, 0.018, 0.1);
    let radii = Vec3::new(
        0.025 * (1.0 + 0.4 * s),
        0.025 * (1.0 + 0.4 * s),
        0.075 * (1.0 - 0.15 * s),
    );
    (centre, radii)
}

/// The elbow-flexion scene around one skin tube.
///
/// ```
/// use dermis::bench::arm::{ArmRun, ArmWorkload, THICKNESS_M, analytic_clearance};
/// // A small arm: 600 skin vertices, a 1,200-triangle muscle, a 12-frame clip.
/// let work = ArmWorkload::new("small", 600, (16, 40), 12);
/// assert_eq!(work.muscle_triangle_count(), 2 * 40 * 15);
/// let mut run = ArmRun::new(&work, 4, 100).unwrap();
/// let times = run.step(&work).unwrap();
/// assert!(times.iterations > 0 && times.collision_s() > 0.0);
/// // The skin keeps (about) its thickness from the muscle and the bones.
/// assert!(analytic_clearance(&work, run.frame, &run.x) > 0.5 * THICKNESS_M);
/// ```
#[derive(Debug, Clone)]
pub struct ArmWorkload {
    /// The skin and its springs.
    pub tube: TubeWorkload,
    /// Frames of one flexion-extension cycle.
    pub clip_frames: usize,
    /// Unit-sphere directions of the muscle's vertices (scaled by [`muscle_ellipsoid`]).
    muscle_unit: Vec<Vec3>,
    muscle_triangles: Vec<[u32; 3]>,
    /// The ECS's absolute force scale for this skin, N (see [`crate::ecs::force_scale_n`]).
    force_scale_n: f32,
}

impl ArmWorkload {
    /// A skin tube of about `vertices` vertices over a muscle of `2 · n_lon · (n_lat − 1)`
    /// triangles (126 × 200: 50,000), with a clip of `clip_frames` frames.
    pub fn new(
        name: &'static str,
        vertices: usize,
        (n_lat, n_lon): (u32, u32),
        clip_frames: usize,
    ) -> Self {
        let tube = TubeWorkload::new(name, vertices);
        let (muscle_unit, muscle_triangles) =
            ellipsoid(Vec3::ZERO, Vec3::ONE, n_lat.max(2), n_lon.max(3)).expect("valid resolution");
        let force_scale_n = ecs_force_scale(&tube, RelaxConfig::DEFAULT.tolerance);
        Self {
            tube,
            clip_frames: clip_frames.max(2),
            muscle_unit,
            muscle_triangles,
            force_scale_n,
        }
    }

    /// Muscle triangles.
    pub fn muscle_triangle_count(&self) -> usize {
        self.muscle_triangles.len()
    }

    /// The muscle mesh's triangles (counter-clockwise seen from outside).
    pub fn muscle_triangles(&self) -> &[[u32; 3]] {
        &self.muscle_triangles
    }

    /// Flexion fraction `s ∈ [0, 1]` at `frame` (the clip loops).
    pub fn flexion(&self, frame: usize) -> f32 {
        let t = (frame % self.clip_frames) as f32 / self.clip_frames as f32;
        0.5 * (1.0 - (std::f32::consts::TAU * t).cos())
    }

    /// The forearm's rigid transform at `frame`: a rotation about the x axis through the elbow,
    /// folding the forearm towards +y.
    pub fn forearm_pose(&self, frame: usize) -> Pose {
        let q = Quat::from_rotation_x(-MAX_FLEXION_RAD * self.flexion(frame));
        let elbow = Vec3::new(0.0, 0.0, ELBOW_Z_M);
        Pose::from_parts(elbow - q * elbow, q)
    }

    /// The muscle's vertices at `frame` (rest frame = world).
    pub fn muscle_vertices(&self, frame: usize) -> Vec<Vec3> {
        let (c, r) = muscle_ellipsoid(self.flexion(frame));
        self.muscle_unit.iter().map(|u| c + *u * r).collect()
    }

    /// Linear-blend-skinned anchors at `frame`: the rest position and radial normal carried by
    /// the blend of the identity (upper arm) and [`forearm_pose`](Self::forearm_pose).
    pub fn anchors(&self, frame: usize) -> Vec<VertexAnchor> {
        let pose = self.forearm_pose(frame);
        self.tube
            .mesh
            .positions()
            .iter()
            .map(|p| {
                let t = ((p.z - (ELBOW_Z_M - 0.03)) / 0.06).clamp(0.0, 1.0);
                let w = t * t * (3.0 - 2.0 * t);
                let n = Vec3::new(p.x, p.y, 0.0).normalize_or_zero();
                VertexAnchor {
                    target: p.lerp(pose.transform_point(*p), w),
                    normal: n.lerp(pose.transform_vector(n), w).normalize_or_zero(),
                    k_normal: ANCHOR_K_NORMAL,
                    k_tangent: ANCHOR_K_TANGENT,
                }
            })
            .collect()
    }

    /// The colliders at `frame` (as their previous state too): muscle, humerus, ulna.
    pub fn collision(&self, frame: usize) -> Result<(SkinCollision, ArmColliders), CollisionError> {
        let config = ContactConfig {
            thickness_m: THICKNESS_M,
            ..ContactConfig::DEFAULT
        };
        let mut contact = SkinCollision::new(self.tube.mesh.positions().len(), config)?;
        let muscle = contact.add_collider(ColliderMesh::from_mesh(
            self.muscle_vertices(frame),
            self.muscle_triangles.clone(),
        )?);
        let humerus = contact.add_collider(ColliderMesh::capsule(
            HUMERUS.a,
            HUMERUS.b,
            HUMERUS.radius_m,
        )?);
        let ulna = contact.add_collider(
            ColliderMesh::capsule(ULNA.a, ULNA.b, ULNA.radius_m)?
                .with_pose(self.forearm_pose(frame)),
        );
        Ok((
            contact,
            ArmColliders {
                muscle,
                humerus,
                ulna,
            },
        ))
    }

    /// The relaxation settings of a frame: the defaults, with the ECS's absolute force scale.
    pub fn relax_config(&self) -> RelaxConfig {
        RelaxConfig {
            force_scale: Some(self.force_scale_n),
            ..RelaxConfig::DEFAULT
        }
    }
}

/// The ECS's force scale ([`crate::ecs::force_scale_n`]) for the tube with the arm's anchors at
/// rest: `max(0.1 L̄ sqrt(Σk² + Σ max(k_n, k_t)²), ε |x|max |K| / tolerance)`.
fn ecs_force_scale(tube: &TubeWorkload, tolerance: f32) -> f32 {
    let mesh = &tube.mesh;
    let lengths = mesh.edge_lengths();
    let mean_edge =
        lengths.iter().map(|&l| f64::from(l)).sum::<f64>() / lengths.len().max(1) as f64;
    let n = mesh.positions().len();
    let anchor_k = f64::from(ANCHOR_K_NORMAL.max(ANCHOR_K_TANGENT));
    let spring_sq: f64 = tube.stiffness.iter().map(|&k| f64::from(k).powi(2)).sum();
    let primary = f64::from(crate::ecs::REFERENCE_STRAIN)
        * mean_edge
        * (spring_sq + n as f64 * anchor_k * anchor_k).sqrt();
    let mut vertex_k = vec![anchor_k; n];
    for (&[a, b], &k) in mesh.topology().edges().iter().zip(&tube.stiffness) {
        vertex_k[a as usize] += f64::from(k);
        vertex_k[b as usize] += f64::from(k);
    }
    let k_norm = vertex_k.iter().map(|k| k * k).sum::<f64>().sqrt();
    primary.max(crate::ecs::f32_force_floor_n(
        mesh.positions(),
        k_norm,
        tolerance,
    )) as f32
}

/// The colliders of an [`ArmWorkload`] in its [`SkinCollision`].
#[derive(Debug, Clone, Copy)]
pub struct ArmColliders {
    /// The deforming muscle mesh.
    pub muscle: ColliderId,
    /// The static upper-arm capsule.
    pub humerus: ColliderId,
    /// The forearm capsule.
    pub ulna: ColliderId,
}

/// What one frame cost and did.
#[derive(Debug, Clone, Copy, Default)]
pub struct FrameTimes {
    /// The whole frame: collider refresh, contact frame plan, substeps and relaxations, s.
    pub total_s: f64,
    /// [`ColliderMesh::set_vertices`] of the muscle, s.
    pub refresh_s: f64,
    /// The muscle's parts refitted after `set_vertices`, when a query first reached them (see
    /// [`ColliderMesh::refit_stats`]): their refit time, s, summed over threads. It is spent
    /// inside the frame plan, the substep passes and the projections, and counted in their
    /// times too.
    pub deferred_refit_s: f64,
    /// The muscle's parts refitted after `set_vertices` (when a query first reached them).
    pub parts_refitted: u64,
    /// The contact frame plan, s.
    pub plan_s: f64,
    /// The substeps' contact passes, s.
    pub passes_s: f64,
    /// The projections inside the relaxations, s.
    pub projections_s: f64,
    /// Relaxation iterations, summed over substeps.
    pub iterations: u32,
    /// Substeps.
    pub substeps: u32,
    /// Contact passes.
    pub passes: u64,
    /// Vertices left unresolved by the last pass.
    pub unresolved: usize,
    /// The last substep's relaxation converged to the tolerance (rather than spending its
    /// budget or stalling).
    pub converged: bool,
}

impl FrameTimes {
    /// Contact work: frame plan, substep passes and the projections inside the relaxations, s.
    pub fn collision_s(&self) -> f64 {
        self.plan_s + self.passes_s + self.projections_s
    }
}

/// A running clip: the skin's positions and contact state, frame after frame.
#[derive(Debug, Clone)]
pub struct ArmRun {
    /// Skin positions after the last frame (caller's order).
    pub x: Vec<Vec3>,
    /// The contact.
    pub contact: SkinCollision,
    /// Its colliders.
    pub ids: ArmColliders,
    /// The last frame run.
    pub frame: usize,
    /// Warm-start each frame from the anchors' motion ([`predict_from_anchors`]).
    pub predict: bool,
    /// With [`predict`](Self::predict): extrapolate the skin's deviation from its anchors too
    /// ([`predict_from_motion`], the ECS's warm start); `None`: the anchors' motion alone.
    pub motion: Option<MotionPrediction>,
    /// The last solve's deviation from its anchors, for [`motion`](Self::motion).
    pub history: MotionHistory,
    /// How a frame spends its iterations over its substeps.
    pub schedule: FrameSchedule,
    /// The last frame's relaxation.
    pub last: Option<RelaxReport>,
}

/// Why an arm frame failed (never with the bench's own inputs).
#[derive(Debug, thiserror::Error)]
pub enum ArmError {
    /// The contact rejected an input.
    #[error(transparent)]
    Collision(#[from] CollisionError),
    /// The solver rejected an input.
    #[error(transparent)]
    Solver(#[from] SolverError),
    /// A frame's relaxation in contact failed.
    #[error(transparent)]
    Frame(#[from] FrameError),
}

impl ArmRun {
    /// Starts the clip at `frame`: colliders there, the skin at its skinned anchors pushed out
    /// of the colliders and relaxed in contact for at most `settle_iterations` (untimed).
    pub fn new(work: &ArmWorkload, frame: usize, settle_iterations: u32) -> Result<Self, ArmError> {
        let (mut contact, ids) = work.collision(frame)?;
        let anchors = work.anchors(frame);
        let mut x: Vec<Vec3> = anchors.iter().map(|a| a.target).collect();
        contact.contact_pass(&mut x)?;
        let loads = Loads {
            anchors: Some(&anchors),
            ..Default::default()
        };
        let config = RelaxConfig {
            max_iterations: settle_iterations,
            ..work.relax_config()
        };
        if settle_iterations > 0 {
            work.tube
                .system
                .relax_projected(&mut x, &loads, &config, Some(&mut contact))?;
        }
        Ok(Self {
            x,
            contact,
            ids,
            frame,
            predict: true,
            motion: Some(MotionPrediction::DEFAULT),
            history: MotionHistory::default(),
            schedule: FrameSchedule::DEFAULT,
            last: None,
        })
    }

    /// Runs the next frame of the clip, as the ECS does (`relax_with_contact`): muscle refit
    /// and forearm pose, the last frame's pass state forgotten (the query cache carries over),
    /// the frame plan, and per substep a contact pass and a relaxation with the contact as the
    /// projection (half the iteration budget spread over the intermediate substeps, the rest
    /// for the last).
    pub fn step(&mut self, work: &ArmWorkload) -> Result<FrameTimes, ArmError> {
        self.step_with(work, &work.relax_config())
    }

    /// [`step`](Self::step) with other relaxation settings (a tolerance study, say).
    pub fn step_with(
        &mut self,
        work: &ArmWorkload,
        config: &RelaxConfig,
    ) -> Result<FrameTimes, ArmError> {
        let frame = self.frame + 1;
        // The animation (not timed): the muscle's new shape, the skinned anchors.
        let muscle = work.muscle_vertices(frame);
        let anchors = work.anchors(frame);
        let pose = work.forearm_pose(frame);
        let loads = Loads {
            anchors: Some(&anchors),
            ..Default::default()
        };
        let system = &work.tube.system;
        // The warm start (timed with the frame: the ECS pays it too): each vertex carried by its
        // anchor's motion since the last frame (and its deviation from the anchor extrapolated).
        let prev = self.predict.then(|| work.anchors(self.frame));
        let start = Instant::now();
        if let Some(prev) = prev {
            match &self.motion {
                Some(motion) => predict_from_motion(
                    &mut self.x,
                    &mut self.history,
                    &prev,
                    &anchors,
                    work.tube.mesh.topology().edges(),
                    motion,
                ),
                None => predict_from_anchors(&mut self.x, &prev, &anchors),
            }
        }

        let refresh = Instant::now();
        self.contact
            .collider_mut(self.ids.muscle)?
            .set_vertices(&muscle)?;
        let refresh_s = refresh.elapsed().as_secs_f64();
        // The parts refitted from here on are the ones the frame's queries reached first
        // (`set_vertices` refitted those searched last frame, inside `refresh_s`).
        let refits = self.muscle_refits();
        self.contact.collider_mut(self.ids.ulna)?.set_pose(pose)?;
        let frame_relax = relax_frame(
            system,
            &mut self.contact,
            &mut self.x,
            &loads,
            config,
            &self.schedule,
        )?;
        let (iterations, substeps, converged) = (
            frame_relax.report.iterations,
            frame_relax.substeps,
            frame_relax.report.converged(),
        );
        self.last = Some(frame_relax.report);
        let total_s = start.elapsed().as_secs_f64();
        let refitted = self.muscle_refits();
        self.frame = frame;
        let d = self.contact.diagnostics();
        Ok(FrameTimes {
            total_s,
            refresh_s,
            deferred_refit_s: refitted.seconds - refits.seconds,
            parts_refitted: refitted.parts_refitted - refits.parts_refitted,
            plan_s: frame_relax.plan_time.as_secs_f64(),
            passes_s: frame_relax.pass_time.as_secs_f64(),
            projections_s: frame_relax.projection_time.as_secs_f64(),
            iterations,
            substeps,
            passes: d.passes,
            unresolved: d.unresolved.len(),
            converged,
        })
    }

    /// The muscle collider's refits so far.
    fn muscle_refits(&self) -> RefitStats {
        self.contact.colliders()[self.ids.muscle.0 as usize].refit_stats()
    }

    /// One naive contact query pass over the current skin: a parry `project_point` per vertex
    /// on each collider (the muscle's BVH, the two capsules), parallel over vertices. Returns
    /// the time, s.
    pub fn naive_pass(&self) -> f64 {
        let colliders = self.contact.colliders();
        let muscle = &colliders[self.ids.muscle.0 as usize];
        let mesh = muscle.parry_mesh().expect("the muscle is a mesh");
        let muscle_pose = muscle.pose();
        let humerus = Capsule::new(HUMERUS.a, HUMERUS.b, HUMERUS.radius_m);
        let humerus_pose = colliders[self.ids.humerus.0 as usize].pose();
        let ulna = Capsule::new(ULNA.a, ULNA.b, ULNA.radius_m);
        let ulna_pose = colliders[self.ids.ulna.0 as usize].pose();
        let t = Instant::now();
        let sum: f32 = self
            .x
            .par_iter()
            .map(|p| {
                mesh.project_point(&muscle_pose, *p, false).point.x
                    + humerus.project_point(&humerus_pose, *p, false).point.x
                    + ulna.project_point(&ulna_pose, *p, false).point.x
            })
            .sum();
        let elapsed = t.elapsed().as_secs_f64();
        std::hint::black_box(sum);
        elapsed
    }
}

/// Smallest clearance of `x` from the arm's colliders at `frame`, measured on the analytic
/// shapes (the ellipsoid the muscle mesh is inscribed in, the capsules' segments), m; negative
/// means a vertex is inside a collider. Independent of the contact code.
pub fn analytic_clearance(work: &ArmWorkload, frame: usize, x: &[Vec3]) -> f32 {
    let (c, r) = muscle_ellipsoid(work.flexion(frame));
    let pose = work.forearm_pose(frame);
    let ulna = (pose.transform_point(ULNA.a), pose.transform_point(ULNA.b));
    let segment = |p: Vec3, a: Vec3, b: Vec3, radius: f32| {
        let ab = b - a;
        let t = ((p - a).dot(ab) / ab.length_squared()).clamp(0.0, 1.0);
        p.distance(a + ab * t) - radius
    };
    x.iter()
        .map(|&p| {
            // Outside the ellipsoid by at least (|q| − 1) · min radius, with q = (p − c) / r.
            let q = (p - c) / r;
            let muscle = (q.length() - 1.0) * r.min_element();
            muscle
                .min(segment(p, HUMERUS.a, HUMERUS.b, HUMERUS.radius_m))
                .min(segment(p, ulna.0, ulna.1, ULNA.radius_m))
        })
        .fold(f32::INFINITY, f32::min)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A small arm: 2k skin vertices, a 2k-triangle muscle, a 12-frame clip.
    fn small() -> ArmWorkload {
        ArmWorkload::new("arm-test", 2_000, (26, 40), 12)
    }

    #[test]
    fn skinned_anchors_sink_into_the_colliders_but_the_relaxed_skin_stays_outside() {
        let work = small();
        let mut run = ArmRun::new(&work, 0, 0).unwrap();
        let mut deepest = f32::INFINITY;
        let mut touched = 0;
        for _ in 0..6 {
            let times = run.step(&work).unwrap();
            assert!(times.substeps >= 1 && times.passes >= 1);
            let targets: Vec<Vec3> = work.anchors(run.frame).iter().map(|a| a.target).collect();
            deepest = deepest.min(analytic_clearance(&work, run.frame, &targets));
            // Every vertex keeps (nearly) the skin thickness from every collider.
            let clearance = analytic_clearance(&work, run.frame, &run.x);
            assert!(
                clearance > 0.5 * THICKNESS_M,
                "frame {}: clearance {clearance}",
                run.frame
            );
            touched += run.contact.diagnostics().contacts;
        }
        // Without contact the skin would be inside: the workload really exercises collision.
        assert!(deepest < -0.002, "{deepest}");
        assert!(touched > 0);
    }

    #[test]
    fn the_clip_loops_and_the_forearm_turns_about_the_elbow() {
        let work = small();
        assert_eq!(work.flexion(0), 0.0);
        assert!((work.flexion(6) - 1.0).abs() < 1e-6);
        assert_eq!(work.flexion(12), 0.0);
        let pose = work.forearm_pose(6);
        let elbow = Vec3::new(0.0, 0.0, ELBOW_Z_M);
        assert!(pose.transform_point(elbow).distance(elbow) < 1e-6);
        // The wrist (on the axis, 0.2 m beyond the elbow) ends 60° up towards +y.
        let wrist = pose.transform_point(Vec3::new(0.0, 0.0, 0.4));
        let expected = elbow + 0.2 * Vec3::new(0.0, MAX_FLEXION_RAD.sin(), MAX_FLEXION_RAD.cos());
        assert!(wrist.distance(expected) < 1e-5, "{wrist}");
        // The muscle mesh lies on its analytic ellipsoid.
        let (c, r) = muscle_ellipsoid(work.flexion(3));
        for v in work.muscle_vertices(3) {
            assert!((((v - c) / r).length() - 1.0).abs() < 1e-5);
        }
    }
}
