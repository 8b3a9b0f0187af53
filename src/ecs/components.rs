//! The components of a skin entity, its config types and its diagnostics.

use std::ops::{Deref, DerefMut};
use std::sync::Arc;

use bevy_ecs::prelude::*;
use glam::Vec3;
use serde::{Deserialize, Serialize};

use super::SkinError;
use crate::collision::{ColliderId, ContactDiagnostics, SkinCollision};
use crate::mesh::{TriMesh, TriMeshTopology};
use crate::solver::{SpringSystem, StopReason, VertexAnchor};
use crate::stiffness::{Modulus, StiffnessRule};

/// Connectivity of a skin: triangles, unique edges, CSR adjacency. Fixed after spawn.
///
/// Shared (`Arc`) so systems that only need connectivity (export, collision) can hold it
/// cheaply.
#[derive(Component, Debug, Clone)]
pub struct SkinTopology(pub(crate) Arc<TriMeshTopology>);

impl Deref for SkinTopology {
    type Target = TriMeshTopology;
    fn deref(&self) -> &TriMeshTopology {
        &self.0
    }
}

/// The rest shape of a skin and the lengths and areas derived from it.
///
/// Changing it (through [`set_positions`](Self::set_positions)) makes the stiffness system
/// recompute [`EdgeStiffness`] for this skin on the next frame.
#[derive(Component, Debug, Clone)]
pub struct RestGeometry {
    mesh: TriMesh,
    edge_lengths_m: Vec<f32>,
    triangle_areas_m2: Vec<f32>,
}

impl RestGeometry {
    /// The rest geometry of a validated mesh.
    pub fn new(mesh: TriMesh) -> Self {
        let edge_lengths_m = mesh.edge_lengths();
        let triangle_areas_m2 = (0..mesh.triangles().len())
            .map(|t| mesh.triangle_area(t))
            .collect();
        Self {
            mesh,
            edge_lengths_m,
            triangle_areas_m2,
        }
    }
    /// The rest mesh (positions and topology).
    pub fn mesh(&self) -> &TriMesh {
        &self.mesh
    }
    /// Rest positions, m.
    pub fn positions(&self) -> &[Vec3] {
        self.mesh.positions()
    }
    /// Rest length of every edge in [`TriMeshTopology::edges`] order, m.
    pub fn edge_lengths_m(&self) -> &[f32] {
        &self.edge_lengths_m
    }
    /// Rest area of every triangle, m².
    pub fn triangle_areas_m2(&self) -> &[f32] {
        &self.triangle_areas_m2
    }
    /// Mean rest edge length, m.
    pub fn mean_edge_length_m(&self) -> f32 {
        let sum: f64 = self.edge_lengths_m.iter().map(|&l| f64::from(l)).sum();
        (sum / self.edge_lengths_m.len().max(1) as f64) as f32
    }

    /// Replaces the rest positions (same vertex count, same triangles), re-validating the mesh.
    pub fn set_positions(&mut self, positions: Vec<Vec3>) -> Result<(), SkinError> {
        let expected = self.mesh.positions().len();
        if positions.len() != expected {
            return Err(SkinError::Length {
                what: "rest positions",
                given: positions.len(),
                expected,
            });
        }
        let mesh = TriMesh::new(positions, self.mesh.triangles().to_vec())?;
        *self = Self::new(mesh);
        Ok(())
    }
}

/// What the skin is made of.
///
/// ```
/// use dermis::ecs::SkinMaterial;
/// use dermis::stiffness::{Modulus, StiffnessRule};
/// let m = SkinMaterial::default()
///     .with_youngs_2d(Modulus::Uniform(2000.0))
///     .with_stiffness_rule(StiffnessRule::poisson(0.3));
/// assert_eq!(m.poisson_ratio, 0.3);
/// ```
#[derive(Component, Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SkinMaterial {
    /// 2D Young's modulus `E2` (N/m), uniform or one value per triangle.
    pub youngs_2d_n_per_m: Modulus,
    /// How edge stiffness is derived from the rest geometry and `E2`.
    pub stiffness_rule: StiffnessRule,
    /// Poisson ratio ν. [`with_stiffness_rule`](Self::with_stiffness_rule) and
    /// [`with_poisson_ratio`](Self::with_poisson_ratio) keep it equal to the `nu` of a
    /// [`StiffnessRule::Poisson`] rule; the other rules ignore it.
    pub poisson_ratio: f32,
    /// Skin thickness, m (used by collision as the contact offset).
    pub thickness_m: f32,
    /// Volumetric density, kg/m³.
    pub density_kg_per_m3: f32,
}

impl SkinMaterial {
    /// Human skin, order of magnitude: `E ≈ 0.5 MPa` over `2 mm` gives `E2 = 1000 N/m`,
    /// ν = 0.45, density 1100 kg/m³, Van Gelder's Eq. 29 rule.
    pub const HUMAN_SKIN: Self = Self {
        youngs_2d_n_per_m: Modulus::Uniform(1000.0),
        stiffness_rule: StiffnessRule::AreaOverLengthSquared,
        poisson_ratio: 0.45,
        thickness_m: 0.002,
        density_kg_per_m3: 1100.0,
    };

    /// Sets `E2` (N/m), uniform or per triangle.
    pub fn with_youngs_2d(mut self, e2: Modulus) -> Self {
        self.youngs_2d_n_per_m = e2;
        self
    }
    /// Sets the stiffness rule (and [`poisson_ratio`](Self::poisson_ratio) from a Poisson rule).
    pub fn with_stiffness_rule(mut self, rule: StiffnessRule) -> Self {
        if let StiffnessRule::Poisson { nu, .. } = rule {
            self.poisson_ratio = nu;
        }
        self.stiffness_rule = rule;
        self
    }
    /// Sets ν (and the `nu` of a Poisson rule).
    pub fn with_poisson_ratio(mut self, nu: f32) -> Self {
        self.poisson_ratio = nu;
        if let StiffnessRule::Poisson { nu: rule_nu, .. } = &mut self.stiffness_rule {
            *rule_nu = nu;
        }
        self
    }
    /// Sets the thickness, m.
    pub fn with_thickness_m(mut self, thickness_m: f32) -> Self {
        self.thickness_m = thickness_m;
        self
    }
    /// Sets the density, kg/m³.
    pub fn with_density(mut self, density_kg_per_m3: f32) -> Self {
        self.density_kg_per_m3 = density_kg_per_m3;
        self
    }
}

impl Default for SkinMaterial {
    fn default() -> Self {
        Self::HUMAN_SKIN
    }
}

/// Spring stiffness of every edge (N/m), in [`TriMeshTopology::edges`] order. Written by
/// [`compute_edge_stiffness`](super::compute_edge_stiffness); you may also write it yourself,
/// and the springs are rebuilt from it.
#[derive(Component, Debug, Clone, Default, PartialEq)]
pub struct EdgeStiffness {
    /// N/m per edge.
    pub k_n_per_m: Vec<f32>,
}

/// The solver-ready spring system of a skin (vertices in bandwidth order, sliced springs),
/// rebuilt by [`rebuild_springs`](super::rebuild_springs) whenever [`EdgeStiffness`] changes.
#[derive(Component, Debug, Clone, Default)]
pub struct SkinSprings {
    pub(crate) system: Option<SpringSystem>,
    /// `Σ k²` over edges, N²/m².
    pub(crate) spring_scale_sq: f64,
    /// Summed stiffness of the springs at each vertex, N/m.
    pub(crate) vertex_k: Vec<f64>,
    /// Whether `system`'s vertex order is the one the current [`RestGeometry`] gives, so a
    /// stiffness change may keep it.
    pub(crate) order_is_current: bool,
}

impl SkinSprings {
    /// The spring system, if the stiffness has been computed successfully.
    pub fn system(&self) -> Option<&SpringSystem> {
        self.system.as_ref()
    }
}

/// Current vertex positions (m) in the caller's vertex order: the relaxed skin after
/// [`DermisSystems::Relax`](super::DermisSystems::Relax), and the warm start of the next frame.
///
/// Dereferences to a slice: values can be edited, the vertex count cannot.
#[derive(Component, Debug, Clone, PartialEq)]
pub struct SkinPositions(pub(crate) Vec<Vec3>);

impl Deref for SkinPositions {
    type Target = [Vec3];
    fn deref(&self) -> &[Vec3] {
        &self.0
    }
}
impl DerefMut for SkinPositions {
    fn deref_mut(&mut self) -> &mut [Vec3] {
        &mut self.0
    }
}

/// The last positions that passed the non-finite guard: what a quarantined skin is rolled back
/// to. Maintained by [`relax_skins`](super::relax_skins).
#[derive(Component, Debug, Clone, PartialEq)]
pub struct LastValidPositions(pub(crate) Vec<Vec3>);

impl Deref for LastValidPositions {
    type Target = [Vec3];
    fn deref(&self) -> &[Vec3] {
        &self.0
    }
}

/// Per-vertex anchor springs pulling the skin towards the body (targets from skinning), stiffer
/// along the body normal than across it. A vertex with `k_normal == k_tangent == 0` is free.
#[derive(Component, Debug, Clone, PartialEq)]
pub struct SkinAnchors(pub(crate) Vec<VertexAnchor>);

impl SkinAnchors {
    /// Anchors at `targets` with normals `normals` and the same stiffness for every vertex.
    pub fn uniform(targets: &[Vec3], normals: &[Vec3], k_normal: f32, k_tangent: f32) -> Self {
        Self(
            targets
                .iter()
                .zip(normals)
                .map(|(&target, &normal)| VertexAnchor {
                    target,
                    normal,
                    k_normal,
                    k_tangent,
                })
                .collect(),
        )
    }
}

impl Deref for SkinAnchors {
    type Target = [VertexAnchor];
    fn deref(&self) -> &[VertexAnchor] {
        &self.0
    }
}
impl DerefMut for SkinAnchors {
    fn deref_mut(&mut self) -> &mut [VertexAnchor] {
        &mut self.0
    }
}

/// The anchors the skin's last relaxation solved for (at spawn: the spawned ones), and the
/// skin's deviation from its anchors at the solve before
/// ([`MotionHistory`](crate::collision::MotionHistory)). The next relaxation starts each
/// anchored vertex moved by its anchor target's motion since then, plus the extrapolated
/// change of its tangential deviation from the anchor
/// ([`predict_from_motion`](crate::collision::predict_from_motion) with
/// [`MotionPrediction::DEFAULT`](crate::collision::MotionPrediction::DEFAULT)): the skin carried
/// along by the skinning that drives its anchors, a far better warm start than last frame's
/// positions when the body moves (on the bench's elbow clip, about 10 % fewer iterations
/// again than the anchors' motion alone). The deviation history is forgotten on a still
/// frame, a frame whose anchors did not move and a non-finite result rolled back (the next
/// start is the anchors' motion alone); checkpoints keep it. Part of every
/// [`SkinBuilder`](super::SkinBuilder) skin; a skin spawned without it is warm-started from
/// its positions alone. Maintained by
/// [`relax_skins`](super::relax_skins).
#[derive(Component, Debug, Clone, Default, PartialEq)]
pub struct SolvedAnchors(
    pub(crate) Vec<VertexAnchor>,
    pub(crate) crate::collision::MotionHistory,
);

impl Deref for SolvedAnchors {
    type Target = [VertexAnchor];
    fn deref(&self) -> &[VertexAnchor] {
        &self.0
    }
}

/// External forces and pins, per vertex in the caller's order. An empty `Vec` means none.
#[derive(Component, Debug, Clone, Default, PartialEq)]
pub struct ExternalLoads {
    /// Force per vertex, N (empty: no external force).
    pub forces_n: Vec<Vec3>,
    /// `true` for vertices held where they are (empty: nothing pinned).
    pub pinned: Vec<bool>,
}

/// Iteration budget and tolerance of the per-frame relaxation.
///
/// The global default lives in [`DermisConfig::relax`]; the same type inserted on a skin entity
/// overrides it for that skin. (In `bevy_ecs` 0.20 a resource is itself a component stored on a
/// resource entity, so one type cannot be both; the resource wraps this component type instead.)
#[derive(Component, Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct RelaxSettings {
    /// Stop after this many iterations per frame even if not converged.
    pub max_iterations: u32,
    /// Converged when `|net force| <= tolerance * force_scale`.
    pub tolerance: f32,
    /// The force (N) the residual is measured against. `None`: the external force norm, or for
    /// skins without external force their characteristic force, never under the f32 floor (see
    /// [`force_scale_n`](super::force_scale_n)).
    pub force_scale_n: Option<f32>,
}

impl RelaxSettings {
    /// 200 iterations per frame, relative residual 1e-4: for anchored skins, the leftover force
    /// of a strain of about 1e-5 (see [`force_scale_n`](super::force_scale_n)).
    pub const DEFAULT: Self = Self {
        max_iterations: 200,
        tolerance: 1e-4,
        force_scale_n: None,
    };
}

impl Default for RelaxSettings {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// Global defaults of the dermis systems.
#[derive(Resource, Debug, Clone, Copy, PartialEq, Default)]
pub struct DermisConfig {
    /// Relaxation settings for every skin without its own [`RelaxSettings`] component.
    pub relax: RelaxSettings,
}

/// Which input of a skin was not finite.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum NonFiniteInput {
    /// A current position (written by another system before the solve).
    Position,
    /// An anchor's target, normal or stiffness.
    Anchor,
    /// An external force.
    Force,
    /// The solver's output (positions after the solve).
    Result,
}

/// A skin was quarantined: something non-finite was found, the skin was rolled back to its last
/// valid positions, and the other skins kept going. Also written as a [`Message`].
#[derive(Message, Debug, Clone, Copy, PartialEq, Eq)]
pub struct SkinQuarantined {
    /// The skin entity.
    pub skin: Entity,
    /// The first offending vertex, in the caller's order.
    pub vertex: usize,
    /// What was not finite.
    pub input: NonFiniteInput,
    /// The skin's relaxation frame ([`RelaxDiagnostics::frames`]) it happened on.
    pub frame: u64,
}

/// What the dermis systems did to a skin, updated every frame.
#[derive(Component, Debug, Clone, Default, PartialEq)]
pub struct RelaxDiagnostics {
    /// Frames the relaxation system has processed this skin.
    pub frames: u64,
    /// Iterations taken this frame.
    pub iterations: u32,
    /// Final relative residual this frame (`|net force| / force_scale`).
    pub residual: f32,
    /// Force scale the residual was measured against, N.
    pub force_scale_n: f32,
    /// Total energy after the solve (springs + anchors − work of external forces), J.
    pub energy_j: f64,
    /// Why the solve stopped; `None` when it did not run this frame.
    pub stop: Option<StopReason>,
    /// How many times the edge stiffness has been recomputed since spawn.
    pub stiffness_updates: u64,
    /// How many times the spring system has been rebuilt since spawn.
    pub spring_rebuilds: u64,
    /// Quarantine events of this frame (cleared at the start of each relaxation).
    pub quarantined: Vec<SkinQuarantined>,
    /// Quarantine events since spawn.
    pub quarantine_total: u64,
    /// Why the last stiffness computation failed (cleared by the next success); the previous
    /// stiffness stays in use.
    pub stiffness_error: Option<SkinError>,
    /// Why the last spring rebuild failed (cleared by the next success); the previous springs
    /// stay in use.
    pub springs_error: Option<SkinError>,
    /// Why the last solve failed for a reason other than a quarantine (cleared by the next
    /// successful solve).
    pub solve_error: Option<SkinError>,
    /// What the contact passes did this frame, for a skin with a [`SkinContact`] (frame plan,
    /// substeps, unresolved vertices, query counters).
    pub contact: Option<ContactDiagnostics>,
    /// Whether anchors, loads and a settings override were present at the last solve.
    pub(crate) present: [bool; 3],
}

/// The contact of a skin with its colliders: a [`SkinCollision`] (the projection
/// [`relax_skins`](super::relax_skins) passes to the solver) and, for each of its colliders, the
/// collider entity that drives it ([`refresh_colliders`](super::refresh_colliders) copies the
/// entity's [`ColliderState`](super::ColliderState) into it every frame).
///
/// With this component, [`relax_skins`](super::relax_skins) runs the collision frame plan: per
/// substep a contact pass, then a relaxation projected onto the colliders, the frame's
/// iteration budget shared by the substeps.
///
/// The query cache (each vertex's nearest triangles and distance bounds) carries over from
/// frame to frame, so most vertices' first pass of a frame needs no search; only each
/// vertex's last position, touches and held contacts are forgotten
/// ([`SkinCollision::clear_frame_state`]). Its answers are exact, but on an exact tie between
/// two surface features a cached and a fresh search may report either, so for checkpoints
/// [`capture_state`](super::capture_state) clears the cache of the running world, as a restored
/// world starts without one: the two continue bit for bit. A checkpoint holds the skin
/// positions, each vertex's last contact (its friction anchor, kept across frames so friction
/// carries the skin over many frames) and the clock the colliders' states follow from.
#[derive(Component, Debug, Clone)]
pub struct SkinContact {
    /// The contact state.
    pub collision: SkinCollision,
    /// `(collider entity, its id in collision)`, in resolution order.
    pub colliders: Vec<(Entity, ColliderId)>,
}
