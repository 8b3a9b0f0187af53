//! Sliding contact of the skin on deforming muscles and rigid bones: thickness, friction, no tunnelling.
#![doc = include_str!("README.md")]

pub mod bench_support;
mod cache;
mod collider;
mod frame;
mod plan;
mod project;
pub mod shapes;

pub use collider::{ColliderMesh, RefitStats, SurfaceProjection};
pub use frame::{
    FrameError, FrameRelax, FrameSchedule, MotionHistory, MotionPrediction, SUBSTEP_ITERATIONS,
    predict_from_anchors, predict_from_motion, relax_frame,
};

use glam::Vec3;
use parry3d::bounding_volume::Aabb;
use parry3d::math::Pose;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::mesh::TopologyError;
use crate::solver::{ActiveContact, Projection, Step};
use cache::{Answer, Patch, Slot};
use collider::{NONE, Prism};
use plan::{Batch, LANES, Motion};

/// Vertices per parallel work item (fixed, so results never depend on the thread count).
const CHUNK: usize = 256;

/// Why a collider or a contact set-up was rejected.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum CollisionError {
    /// The collider mesh failed basic validation (indices, repeated or non-finite vertices,
    /// zero-area triangles, non-manifold edges). Repair it in the modelling tool.
    #[error("collider mesh: {0}")]
    Topology(#[from] TopologyError),
    /// An edge has only one triangle: the surface has a hole, so inside and outside are
    /// undefined. Close the hole (fill it with triangles) before using the mesh as a collider.
    #[error(
        "collider mesh has a hole: edge ({a}, {b}) of triangle {triangle} has no triangle on its other side"
    )]
    Hole {
        /// First vertex of the open edge.
        a: u32,
        /// Second vertex of the open edge.
        b: u32,
        /// The only triangle on that edge.
        triangle: usize,
    },
    /// Two triangles run their shared edge in the same direction: one of them is flipped.
    /// Re-orient the mesh consistently (e.g. "recalculate normals" in the modelling tool).
    #[error(
        "collider mesh triangles {first} and {second} wind their shared edge ({a}, {b}) the same way: one of them is flipped"
    )]
    InconsistentWinding {
        /// First vertex of the edge.
        a: u32,
        /// Second vertex of the edge.
        b: u32,
        /// One triangle.
        first: usize,
        /// The other triangle.
        second: usize,
    },
    /// The mesh encloses a negative volume: every triangle winds clockwise seen from outside.
    /// Reverse each triangle (swap its second and third index). Such meshes are rejected rather
    /// than flipped silently, because the exporter's convention is then wrong everywhere.
    #[error(
        "collider mesh is inside out (signed volume {volume_m3} m³): reverse every triangle (swap its 2nd and 3rd index)"
    )]
    InsideOut {
        /// Signed volume, m³ (≤ 0).
        volume_m3: f64,
    },
    /// A primitive has a non-finite or non-positive dimension.
    #[error("bad {what}: {detail}; dimensions must be finite and radii positive")]
    BadShape {
        /// Which primitive.
        what: &'static str,
        /// What was given.
        detail: String,
    },
    /// A position, pose or thickness is NaN or infinite.
    #[error("{what} {index} is not finite")]
    NonFinite {
        /// Which input.
        what: &'static str,
        /// Its index.
        index: usize,
    },
    /// An input array has the wrong number of entries.
    #[error("{what} has {given} entries, expected {expected}")]
    Length {
        /// Which input.
        what: &'static str,
        /// Entries given.
        given: usize,
        /// Entries expected.
        expected: usize,
    },
    /// A thickness is negative, NaN or infinite. Thicknesses are in metres, ≥ 0.
    #[error("thickness of vertex {vertex} is {value}; it must be finite and >= 0")]
    BadThickness {
        /// The vertex (caller's index).
        vertex: usize,
        /// The value given.
        value: f32,
    },
    /// A configuration field is out of range; the message names the field and its range.
    #[error("contact config: {field} = {value} is out of range ({range})")]
    BadConfig {
        /// The field.
        field: &'static str,
        /// The value given.
        value: f32,
        /// The allowed range.
        range: &'static str,
    },
    /// [`ColliderMesh::set_vertices`] on a primitive: move primitives with
    /// [`ColliderMesh::set_pose`].
    #[error("set_vertices needs a mesh collider; move primitives with set_pose")]
    NotAMesh,
    /// A [`ColliderId`] that this contact set never handed out.
    #[error("no collider {0}")]
    UnknownCollider(u32),
    /// parry rejected the mesh (should not happen after the checks above).
    #[error("parry rejected the collider mesh: {0}")]
    Parry(String),
}

/// Index of a collider in a [`SkinCollision`], in the order they were added (which is also the
/// order contacts are resolved in).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub struct ColliderId(pub u32);

/// How the skin touches its colliders.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct ContactConfig {
    /// Default skin thickness: the distance kept between a skin vertex and every collider
    /// surface, m. Overridden per vertex by [`SkinCollision::set_thickness`].
    pub thickness_m: f32,
    /// Friction in `[0, 1]`: the fraction of a touching vertex's tangential slip, relative to
    /// the collider surface point it touched at the start of the frame (which moves with the
    /// collider), removed at each projection. 0: free sliding; 1: the skin sticks.
    pub friction: f32,
    /// Gauss-Seidel rounds over the colliders per vertex (creases); a vertex still pushed in
    /// the last round is reported in [`ContactDiagnostics::unresolved`].
    pub max_rounds: u32,
    /// A vertex closer than `thickness − tolerance_m` is pushed out, m.
    pub tolerance_m: f32,
    /// A vertex within `thickness × (1 + contact_band)` counts as touching (friction applies).
    pub contact_band: f32,
    /// At most this many substeps when colliders or vertices move more than half a thickness
    /// in one frame ([`ContactDiagnostics::substeps_capped`] says when it was not enough).
    pub max_substeps: u32,
}

impl ContactConfig {
    /// 2 mm of skin, frictionless, 4 rounds, 1 µm tolerance, 10 % band, 256 substeps.
    pub const DEFAULT: Self = Self {
        thickness_m: 0.002,
        friction: 0.0,
        max_rounds: 4,
        tolerance_m: 1e-6,
        contact_band: 0.1,
        max_substeps: 256,
    };

    fn validate(&self) -> Result<(), CollisionError> {
        let bad = |field, value: f32, range| {
            Err(CollisionError::BadConfig {
                field,
                value,
                range,
            })
        };
        if !(self.thickness_m.is_finite() && self.thickness_m >= 0.0) {
            return bad("thickness_m", self.thickness_m, "finite, >= 0");
        }
        if !(0.0..=1.0).contains(&self.friction) {
            return bad("friction", self.friction, "0 to 1");
        }
        if self.max_rounds == 0 {
            return bad("max_rounds", 0.0, ">= 1");
        }
        if !(self.tolerance_m.is_finite() && self.tolerance_m >= 0.0) {
            return bad("tolerance_m", self.tolerance_m, "finite, >= 0");
        }
        if !(self.contact_band.is_finite() && self.contact_band >= 0.0) {
            return bad("contact_band", self.contact_band, "finite, >= 0");
        }
        if self.max_substeps == 0 {
            return bad("max_substeps", 0.0, ">= 1");
        }
        Ok(())
    }
}

impl Default for ContactConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// What the contact passes did: the last pass's unresolved vertices, and counters summed
/// since the last [`SkinCollision::begin_frame`].
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct ContactDiagnostics {
    /// Vertices (caller's indices, increasing) still too close to or inside some collider after
    /// [`ContactConfig::max_rounds`] rounds in the last pass: typically wedged in a crease
    /// narrower than twice the skin thickness.
    pub unresolved: Vec<u32>,
    /// Vertices touching a collider after the last pass.
    pub contacts: u64,
    /// Contact passes (substeps and projections) since the frame began.
    pub passes: u64,
    /// Vertices moved, summed over passes.
    pub moved: u64,
    /// Exact closest-point queries, summed over passes.
    pub exact_queries: u64,
    /// Exact queries whose closest triangle was the cached one.
    pub cache_hits: u64,
    /// Closest-point queries answered exactly from the vertex's cached patch of triangles,
    /// without a BVH search (not counted in `exact_queries`).
    pub certified_queries: u64,
    /// Vertex–collider pairs skipped because the vertex lies outside the collider's bounding box
    /// inflated by the thickness.
    pub skipped_aabb: u64,
    /// Vertex–collider pairs skipped because the cached distance bound proves no contact
    /// (counting every collider of a vertex skipped whole).
    pub skipped_bound: u64,
    /// Vertices skipped whole, summed over passes: their motion since they were last resolved,
    /// plus every collider's travel, stayed within the distance that proves them outside every
    /// contact band, so the pass did not read their per-collider state at all.
    pub skipped_vertices: u64,
    /// Of those, the ones in blocks of [`STEP_BLOCK`](crate::solver::STEP_BLOCK) vertices
    /// that a pass right after a solver's step ([`Projection::project_step`]) skipped without
    /// reading them: the step's bound on their motion since the block was last tested stayed
    /// within what its vertices' tests allow.
    pub skipped_in_blocks: u64,
    /// Vertices stopped by the swept test (a step that would have crossed a collider).
    pub swept_hits: u64,
    /// Substeps used by the last [`SkinCollision::begin_frame`].
    pub substeps: u32,
    /// `true` when the last frame needed more than [`ContactConfig::max_substeps`] substeps.
    pub substeps_capped: bool,
    /// `true` when a pass was handed positions of the wrong length, or a projection an order
    /// that is not a permutation of the vertices (it then did nothing).
    pub length_mismatch: bool,
}

/// Where a skin vertex last touched a collider: the surface point friction anchors it to at
/// the start of the next frame (it moves with the collider). See
/// [`SkinCollision::friction_anchors`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FrictionAnchor {
    /// The collider's index ([`ColliderId`]`.0`).
    pub collider: u32,
    /// The triangle (0 for primitives).
    pub part: u32,
    /// Barycentric coordinates on the triangle, or the rest-frame point for primitives.
    pub coords: Vec3,
}

/// A point of a collider's surface: `coords` on `part`, as in [`SurfaceProjection`].
#[derive(Debug, Clone, Copy, PartialEq)]
struct Contact {
    collider: u32,
    part: u32,
    coords: Vec3,
}

impl Contact {
    const NONE: Self = Self {
        collider: NONE,
        part: NONE,
        coords: Vec3::ZERO,
    };
}

/// A collider whose surface a vertex lies on after a pass (within `tolerance_m` of the
/// thickness): a contact the solver may hold.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Touch {
    /// The collider ([`NONE`]: no contact in this slot).
    collider: u32,
    /// Outward unit normal of the contact plane, world frame.
    normal: Vec3,
}

impl Touch {
    const NONE: Self = Self {
        collider: NONE,
        normal: Vec3::ZERO,
    };
}

/// Contacts per vertex reported to the solver (two colliders meeting in a crease).
const TOUCHES: usize = 2;

/// How far a vertex may go before it can come near a collider: the hot part of the per-vertex
/// state, read by every caller-order pass for every vertex (32 bytes, two per cache line), so a
/// vertex far from every collider costs one distance, one compare and the store of its
/// position. Projections read a conservative copy of the test in the solver's order instead
/// (`project::View`).
#[derive(Debug, Clone, Copy)]
#[repr(C, align(32))]
struct Reach {
    /// Where the vertex was resolved last (NaN: never).
    at: Vec3,
    /// How far the vertex may move from `at`, plus the colliders' travel since `travel_at`,
    /// before it can come within its contact band of any collider, m, with the rounding
    /// allowance taken off; `-∞` when it touched something (then every pass resolves it).
    reserve: f32,
    /// The colliders' summed travel ([`ColliderMesh::travel_m`]) when the vertex was resolved,
    /// m.
    travel_at: f64,
    /// Lower bound of the distance from `at` to every collider surface then, m (0: none).
    safe: f32,
    /// For a vertex touching one mesh collider inside a face (`reserve` is `-∞`): how far it
    /// may move from `at`, no collider moving, and its triangle stay the closest (so its
    /// contact's face and normal stay) and every other collider beyond the band, m; 0
    /// otherwise. Within it, resolving the vertex changes nothing the solver sees as long as
    /// its signed distance stays within the tolerance of the thickness
    /// ([`VertexState::slab`]). See [`hold_of`].
    hold: f32,
}

impl Reach {
    const NEW: Self = Self {
        at: Vec3::NAN,
        reserve: f32::NEG_INFINITY,
        travel_at: 0.0,
        safe: 0.0,
        hold: 0.0,
    };

    /// Whether a vertex now at `p`, the colliders' summed travel now `travel`, is provably
    /// outside every contact band (what resolving it would find, without the slots).
    #[inline]
    fn skips(&self, p: Vec3, travel: f64) -> bool {
        let moved = p.distance(self.at) as f64 + (travel - self.travel_at);
        moved * (1.0 + 1e-5) <= self.reserve as f64
    }

    /// Lower bound of the distance from `p` to every collider surface, the colliders' summed
    /// travel now `travel` (negative: none known).
    #[inline]
    fn clearance(&self, p: Vec3, travel: f64) -> f64 {
        self.safe as f64 - p.distance(self.at) as f64 - (travel - self.travel_at)
    }
}

/// Per-vertex state.
#[derive(Debug, Clone, Copy)]
struct VertexState {
    /// The surface point touched in the last pass.
    contact: Contact,
    /// The surface point touched at the start of the frame (friction).
    anchor: Contact,
    /// The colliders touched after the last pass, in resolution order.
    touches: [Touch; TOUCHES],
    /// Colliders the solver holds this vertex against ([`Projection::hold`]): the next
    /// projection keeps it at the thickness from them, from outside as well.
    held: [u32; TOUCHES],
    /// With a hold ([`Reach::hold`]): the range of `n · (p − at)` (`n` the touch's normal)
    /// over which its signed distance stays within the tolerance of the thickness, m.
    slab: [f32; 2],
}

impl VertexState {
    const NEW: Self = Self {
        contact: Contact::NONE,
        anchor: Contact::NONE,
        touches: [Touch::NONE; TOUCHES],
        held: [NONE; TOUCHES],
        slab: [0.0; 2],
    };
}

#[derive(Debug, Clone, Copy, Default)]
struct Counters {
    contacts: u64,
    moved: u64,
    exact_queries: u64,
    cache_hits: u64,
    certified: u64,
    skipped_aabb: u64,
    skipped_bound: u64,
    skipped_vertices: u64,
    skipped_in_blocks: u64,
    swept_hits: u64,
}

/// What a pass (or one chunk of it) did.
#[derive(Debug, Default)]
struct ChunkPass {
    counters: Counters,
    /// Vertices still too close after the last round (caller's indices, increasing).
    unresolved: Vec<u32>,
}

impl Counters {
    fn add(&mut self, o: &Self) {
        self.contacts += o.contacts;
        self.moved += o.moved;
        self.exact_queries += o.exact_queries;
        self.cache_hits += o.cache_hits;
        self.certified += o.certified;
        self.skipped_aabb += o.skipped_aabb;
        self.skipped_bound += o.skipped_bound;
        self.skipped_vertices += o.skipped_vertices;
        self.skipped_in_blocks += o.skipped_in_blocks;
        self.swept_hits += o.swept_hits;
    }
}

/// The skin's contact with its colliders: a [`Projection`] for
/// [`SpringSystem::relax_projected`](crate::solver::SpringSystem::relax_projected).
///
/// Per frame: move the colliders ([`ColliderMesh::set_pose`], [`ColliderMesh::set_vertices`]
/// through [`collider_mut`](Self::collider_mut)), call [`begin_frame`](Self::begin_frame) with
/// the warm-start skin positions: it splits the motion into substeps short enough that nothing
/// tunnels; run each with [`substep`](Self::substep) followed by a relaxation with `self` as
/// the projection.
///
/// ```
/// use dermis::collision::{ColliderMesh, ContactConfig, SkinCollision};
/// use dermis::solver::Projection;
/// use glam::Vec3;
/// let config = ContactConfig { thickness_m: 0.01, ..ContactConfig::DEFAULT };
/// let mut skin = SkinCollision::new(2, config).unwrap();
/// skin.add_collider(ColliderMesh::ball(1.0).unwrap());
/// // One vertex inside the ball, one far away.
/// let mut x = vec![Vec3::new(0.0, 0.0, 0.5), Vec3::new(0.0, 0.0, 3.0)];
/// skin.advance_frame(&mut x).unwrap();
/// assert!((x[0].z - 1.01).abs() < 1e-6); // pushed to the surface plus the thickness
/// assert_eq!(x[1], Vec3::new(0.0, 0.0, 3.0));
/// // As a solver projection (internal order given by `order`): nothing left to do.
/// assert!(!skin.project(&mut x, &[0, 1]));
/// ```
#[derive(Debug, Clone)]
pub struct SkinCollision {
    config: ContactConfig,
    colliders: Vec<ColliderMesh>,
    thickness: Vec<f32>,
    reach: Vec<Reach>,
    /// Each vertex's position after the last pass, resolved or skipped (NaN: none yet).
    last: Vec<Vec3>,
    states: Vec<VertexState>,
    /// `vertex_count × colliders` slots, vertex-major...
    slots: Vec<Slot>,
    /// ... and their patch certificates (cold: apart, see [`Slot`]).
    patches: Vec<Patch>,
    /// The skip tests and last positions in the solver's order, for projections.
    view: project::View,
    diagnostics: ContactDiagnostics,
    plan: Option<Plan>,
    /// Contacts after the last projection, internal order ([`Projection::active_contacts`]).
    active: Vec<ActiveContact>,
    /// `(caller's vertex, collider)` of each entry of `active`.
    active_owner: Vec<(u32, u32)>,
    /// Caller's vertices with a held contact.
    held_vertices: Vec<u32>,
    /// Inverse of `rank_of`, the solver's order of the last projection: `rank[o]` is the
    /// internal index of caller's vertex `o`.
    rank: Vec<u32>,
    rank_of: Vec<u32>,
    /// The address and length of the order `rank_of` holds while [`relax_frame`] vouches for it
    /// (its system is borrowed for the whole frame, so the order cannot change): projections
    /// given that slice skip comparing it with `rank_of`, an O(n) read per pass (~27 µs of a
    /// ~200 µs tube-100k pass). Cleared when the frame ends and whenever `rank_of` changes.
    trusted_order: Option<(usize, usize)>,
    /// Each collider's identity and travel at the last pass (another identity or a smaller
    /// travel means it was replaced).
    travel_seen: Vec<(u64, f64)>,
    /// Whether vertices touching inside a face may be held ([`Reach::hold`]); off only in tests
    /// that compare against resolving every touching vertex.
    face_holds: bool,
    /// CPU time of the passes run alongside a solver's force gather
    /// ([`Projection::project_step_deferred`]), summed over the threads that ran their groups:
    /// a timer around such a pass times the gather too (see [`relax_frame`]).
    pub(super) alongside: std::time::Duration,
}

/// The substeps of the frame in progress.
#[derive(Debug, Clone)]
struct Plan {
    substeps: u32,
    next: u32,
    poses: Vec<Pose>,
    /// Per collider: whether a deforming mesh passes through its interpolated shapes.
    interpolate: Vec<bool>,
    increments: Vec<Vec3>,
}

/// How [`SkinCollision::begin_frame`] split the frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct FramePlan {
    /// Substeps to run with [`SkinCollision::substep`].
    pub substeps: u32,
    /// `true` when more than [`ContactConfig::max_substeps`] were needed.
    pub capped: bool,
}

impl SkinCollision {
    /// Contact for a skin of `vertex_count` vertices, all `config.thickness_m` thick, with no
    /// colliders yet.
    pub fn new(vertex_count: usize, config: ContactConfig) -> Result<Self, CollisionError> {
        config.validate()?;
        Ok(Self {
            config,
            colliders: Vec::new(),
            thickness: vec![config.thickness_m; vertex_count],
            reach: vec![Reach::NEW; vertex_count],
            last: vec![Vec3::NAN; vertex_count],
            rank: Vec::new(),
            rank_of: Vec::new(),
            trusted_order: None,
            travel_seen: Vec::new(),
            states: vec![VertexState::NEW; vertex_count],
            slots: Vec::new(),
            patches: Vec::new(),
            view: project::View::default(),
            diagnostics: ContactDiagnostics::default(),
            plan: None,
            active: Vec::new(),
            active_owner: Vec::new(),
            held_vertices: Vec::new(),
            face_holds: true,
            alongside: std::time::Duration::ZERO,
        })
    }

    /// Per-vertex skin thickness, m (caller's order).
    pub fn set_thickness(&mut self, thickness_m: &[f32]) -> Result<(), CollisionError> {
        if thickness_m.len() != self.thickness.len() {
            return Err(CollisionError::Length {
                what: "thickness",
                given: thickness_m.len(),
                expected: self.thickness.len(),
            });
        }
        if let Some(v) = thickness_m
            .iter()
            .position(|t| !(t.is_finite() && *t >= 0.0))
        {
            return Err(CollisionError::BadThickness {
                vertex: v,
                value: thickness_m[v],
            });
        }
        self.thickness.copy_from_slice(thickness_m);
        self.leave_view();
        // The contact bands changed: no vertex may skip a pass on its old reserve.
        for r in &mut self.reach {
            r.reserve = f32::NEG_INFINITY;
        }
        Ok(())
    }

    /// Builder form of [`set_thickness`](Self::set_thickness).
    pub fn with_thickness(mut self, thickness_m: &[f32]) -> Result<Self, CollisionError> {
        self.set_thickness(thickness_m)?;
        Ok(self)
    }

    /// Adds a collider; contacts are resolved in the order colliders were added.
    pub fn add_collider(&mut self, collider: ColliderMesh) -> ColliderId {
        self.colliders.push(collider);
        self.clear_cache();
        ColliderId(self.colliders.len() as u32 - 1)
    }

    /// A collider.
    pub fn collider(&self, id: ColliderId) -> Result<&ColliderMesh, CollisionError> {
        self.colliders
            .get(id.0 as usize)
            .ok_or(CollisionError::UnknownCollider(id.0))
    }

    /// A collider, to move it for the next frame.
    pub fn collider_mut(&mut self, id: ColliderId) -> Result<&mut ColliderMesh, CollisionError> {
        self.colliders
            .get_mut(id.0 as usize)
            .ok_or(CollisionError::UnknownCollider(id.0))
    }

    /// All colliders, in resolution order.
    pub fn colliders(&self) -> &[ColliderMesh] {
        &self.colliders
    }

    /// Number of skin vertices.
    pub fn vertex_count(&self) -> usize {
        self.thickness.len()
    }

    /// The configuration.
    pub fn config(&self) -> &ContactConfig {
        &self.config
    }

    /// What the last passes did.
    pub fn diagnostics(&self) -> &ContactDiagnostics {
        &self.diagnostics
    }

    /// Forgets every cached contact, distance bound and friction anchor (the next pass runs
    /// exact queries everywhere; results are the same).
    pub fn clear_cache(&mut self) {
        self.view.discard();
        let n = self.thickness.len();
        self.states = vec![VertexState::NEW; n];
        self.reach = vec![Reach::NEW; n];
        self.last = vec![Vec3::NAN; n];
        self.slots = vec![Slot::NEW; n * self.colliders.len()];
        self.patches = vec![Patch::NEW; n * self.colliders.len()];
    }

    /// Forgets the query cache (closest triangles, distance bounds, last positions) but keeps
    /// each vertex's last contact, the friction anchor of the next frame: what a frame that
    /// must depend only on checkpointed state starts from (see
    /// [`friction_anchors`](Self::friction_anchors)).
    pub fn clear_query_cache(&mut self) {
        self.clear_frame_state();
        self.reach.fill(Reach::NEW);
        self.slots = vec![Slot::NEW; self.states.len() * self.colliders.len()];
        self.patches = vec![Patch::NEW; self.states.len() * self.colliders.len()];
    }

    /// Forgets what only the last frame's passes need (each vertex's last position, touches and
    /// held contacts) but keeps the query cache (closest triangles and distance bounds) and the
    /// last contacts: a frame starts from this with the same plan as from
    /// [`clear_query_cache`](Self::clear_query_cache) and the same answers (up to which of two
    /// surface features at exactly the same distance is named), only its first pass needs far
    /// fewer exact searches.
    pub fn clear_frame_state(&mut self) {
        self.view.discard();
        for s in &mut self.states {
            *s = VertexState {
                contact: s.contact,
                ..VertexState::NEW
            };
        }
        // A vertex that touched something resolves again on the next pass anyway.
        self.last.fill(Vec3::NAN);
        self.held_vertices.clear();
        self.active.clear();
        self.active_owner.clear();
    }

    /// Each vertex's last contact (caller's order; `None`: not touching): where friction
    /// anchors it at the start of the next frame. Part of a checkpoint when friction is on.
    pub fn friction_anchors(&self) -> Vec<Option<FrictionAnchor>> {
        self.states
            .iter()
            .map(|s| {
                (s.contact.collider != NONE).then_some(FrictionAnchor {
                    collider: s.contact.collider,
                    part: s.contact.part,
                    coords: s.contact.coords,
                })
            })
            .collect()
    }

    /// Restores [`friction_anchors`](Self::friction_anchors) (one per vertex).
    pub fn set_friction_anchors(
        &mut self,
        anchors: &[Option<FrictionAnchor>],
    ) -> Result<(), CollisionError> {
        if anchors.len() != self.states.len() {
            return Err(CollisionError::Length {
                what: "friction anchors",
                given: anchors.len(),
                expected: self.states.len(),
            });
        }
        for (v, a) in anchors.iter().enumerate() {
            if let Some(a) = a {
                if a.collider as usize >= self.colliders.len() {
                    return Err(CollisionError::UnknownCollider(a.collider));
                }
                if !a.coords.is_finite() {
                    return Err(CollisionError::NonFinite {
                        what: "friction anchor of vertex",
                        index: v,
                    });
                }
            }
        }
        self.leave_view();
        for ((s, r), a) in self.states.iter_mut().zip(&mut self.reach).zip(anchors) {
            s.contact = a.map_or(Contact::NONE, |a| Contact {
                collider: a.collider,
                part: a.part,
                coords: a.coords,
            });
            // The next pass must resolve the vertex to replace the contact if it is gone.
            r.reserve = f32::NEG_INFINITY;
        }
        Ok(())
    }

    /// Starts a frame after the colliders were moved: `x` (caller's order) holds the skin's
    /// warm start. Friction anchors are taken from the last contacts, and the motion since the
    /// last pass, of the colliders and of `x` itself, is split into substeps of at most half a
    /// thickness (at most [`ContactConfig::max_substeps`]).
    ///
    /// Then call [`substep`](Self::substep) that many times, each followed by a relaxation (the
    /// springs hold the skin together while a bone plows through it), or use
    /// [`advance_frame`](Self::advance_frame) to run the substeps with contact passes only.
    /// With more than one substep, `x` is reset to the positions of the last pass and moved
    /// back to the warm start by the substeps.
    pub fn begin_frame(&mut self, x: &mut [Vec3]) -> Result<FramePlan, CollisionError> {
        let n = self.vertex_count();
        if x.len() != n {
            return Err(CollisionError::Length {
                what: "positions",
                given: x.len(),
                expected: n,
            });
        }
        // Serial below `PARALLEL_PLAN_PREP` vertices, where waking rayon's workers would cost
        // more than these passes (~40 µs at 10k vertices; ~0.9 ms serial at 100k).
        let parallel = n >= PARALLEL_PLAN_PREP;
        let bad = |c: &[Vec3]| c.iter().any(|p| !p.is_finite());
        if (parallel && x.par_chunks(CHUNK).any(bad)) || (!parallel && bad(x)) {
            let i = x.iter().position(|p| !p.is_finite()).unwrap_or_default();
            return Err(CollisionError::NonFinite {
                what: "skin vertex",
                index: i,
            });
        }
        self.leave_view();
        self.diagnostics = ContactDiagnostics::default();
        let touched = self.anchor_contacts(parallel);
        // The plan reads the cached bounds: none may survive a collider replaced in place.
        self.collider_travel();
        let h_min = self.thickness.iter().copied().fold(f32::INFINITY, f32::min);
        // Each substep may move half the thinnest skin.
        let per_substep = 0.5 * h_min;
        let motion = self.reaching_motion(x, &touched, per_substep);
        let wanted = wanted_substeps(motion, per_substep);
        let substeps = (wanted.max(1.0) as u64).min(self.config.max_substeps as u64) as u32;
        let capped = wanted > self.config.max_substeps as f32;
        self.diagnostics.substeps_capped = capped;
        self.diagnostics.substeps = substeps;
        let mut increments: Vec<Vec3> = Vec::new();
        if substeps > 1 {
            increments = x
                .iter_mut()
                .zip(&self.last)
                .map(|(p, last)| {
                    let target = *p;
                    if last.is_finite() {
                        *p = *last;
                    }
                    (target - *p) / substeps as f32
                })
                .collect();
        }
        // A deforming mesh whose whole frame motion, plus a substep of the skin's, is within
        // the half thickness a substep may move needs no substeps of its own: it takes its
        // current shape at the first substep, which spares a BVH refit per substep.
        let step = increments.iter().map(|d| d.length()).fold(0.0f32, f32::max);
        let interpolate = self
            .colliders
            .iter()
            .map(|c| substeps > 1 && c.frame_motion_m() + step >= 0.5 * h_min)
            .collect();
        self.plan = Some(Plan {
            substeps,
            next: 1,
            poses: self.colliders.iter().map(ColliderMesh::pose).collect(),
            interpolate,
            increments,
        });
        Ok(FramePlan { substeps, capped })
    }

    /// Each vertex's contact becomes its friction anchor; returns the vertices touching a
    /// collider, in order, for the plan (the same list either way; `parallel` on rayon's pool).
    fn anchor_contacts(&mut self, parallel: bool) -> Vec<u32> {
        if parallel {
            let chunks = self.states.par_chunks_mut(CHUNK).enumerate();
            chunks.flat_map_iter(|(c, s)| anchor_chunk(c, s)).collect()
        } else {
            let chunks = self.states.chunks_mut(CHUNK).enumerate();
            chunks.flat_map(|(c, s)| anchor_chunk(c, s)).collect()
        }
    }

    /// The largest relative motion, over the frame, between a skin vertex and a collider it
    /// can come within its contact band of, m: what the substeps must split.
    ///
    /// In a rigid collider's rest frame, a vertex moving from its last pass `p₀` to its warm
    /// start `p₁` (`v = |p₁ − p₀|`) while the pose goes from the previous frame's `(R₀, t₀)`
    /// to the current one `(R₁, t₁)` (translation lerped, rotation slerped: a constant angular
    /// velocity `ω` in the world frame) follows the path `l(t) = R(t)ᵀ w(t)`, `w(t) = p(t) −
    /// t(t)`, whose speed `|l′(t)| = |w′ − ω × w(t)|` is linear in `t` under the norm: it is
    /// at most `L = max(|w′ − ω × w₀|, |w′ − ω × w₁|)`, exact for a vertex carried with the
    /// collider or turned about a far pivot. A deforming mesh's surface moves at most `δ` (its
    /// largest vertex displacement) on top.
    /// The signed distance is 1-Lipschitz, so over `[t_a, t_b]` it stays above
    /// `min(s(t_a), s(t_b)) − L (t_b − t_a) / 2 − δ`: the path is bisected (exact queries at
    /// the ends of each piece, up to 64 pieces) until every piece is proven to stay out of the
    /// band, or one cannot be. The pair then needs `min(L + δ, M + v)` split, `M` the
    /// collider's global motion bound. Far colliders, however fast, cost no substep.
    /// `touched`: the vertices touching a collider after the last pass, in order (visited
    /// first, see below).
    ///
    /// Only the substep count the motion asks for is exact, `max(1, ⌈motion / step⌉)` for
    /// `step` half the thinnest skin (what [`begin_frame`](Self::begin_frame) makes of it): a
    /// pair whose motion stays within the count the largest reaching motion found so far asks
    /// for changes nothing, and is not tested.
    fn reaching_motion(&self, x: &[Vec3], touched: &[u32], step: f32) -> f32 {
        self.reaching_motion_with(x, touched, step, true)
    }

    /// [`reaching_motion`](Self::reaching_motion), its pairs filtered eight vertices at a time
    /// when `wide` ([`plan`]: the same substep count either way).
    fn reaching_motion_with(&self, x: &[Vec3], touched: &[u32], step: f32, wide: bool) -> f32 {
        let nc = self.colliders.len();
        if nc == 0 {
            return 0.0;
        }
        let motions = self.plan_motions();
        let cfg = &self.config;
        let covered = |worst: f32| covered_motion(worst, step);
        let pair = |c, ends, slot: &Slot, ws| self.reach_pair(&motions, step, c, ends, slot, ws);
        let vertex = |p1: Vec3, last: Vec3, h: f32, slots: &[Slot], mut ws: (f32, f32)| {
            let p0 = if last.is_finite() { last } else { p1 };
            let ends = (p0, p1, p0.distance(p1), h * (1.0 + cfg.contact_band));
            for (c, slot) in slots.iter().enumerate() {
                ws = pair(c, ends, slot, ws);
            }
            ws
        };
        // Eight vertices: the pairs the filter keeps, collider by collider, each through the
        // exact tests (the result is a maximum: any order of pairs gives it).
        let batch =
            |xs: &[Vec3], lasts: &[Vec3], hs: &[f32], slots: &[Slot], mut ws: (f32, f32)| {
                let b = Batch::new(xs, lasts, hs, cfg.contact_band);
                for (c, m) in motions.iter().enumerate() {
                    let mut alive = b.survivors(m, |l| &slots[l * nc + c], ws.1);
                    while alive != 0 {
                        let l = alive.trailing_zeros() as usize;
                        alive &= alive - 1;
                        let (p0, p1) = b.ends(l);
                        ws = pair(c, (p0, p1, b.v[l], b.band[l]), &slots[l * nc + c], ws);
                    }
                }
                ws
            };
        // The result is a maximum, whatever order the pairs are visited in, and pairs that
        // move less than the largest reaching one found so far need no query. Vertices that
        // touched a collider last (their friction anchors) most likely reach it again: visiting
        // them first lets the whole skin skip the queries of a deforming collider, whose motion
        // bound is the same for every vertex.
        let touched = touched.iter().fold((0.0f32, covered(0.0)), |worst, &i| {
            let i = i as usize;
            let slots = &self.slots[i * nc..(i + 1) * nc];
            vertex(x[i], self.last[i], self.thickness[i], slots, worst)
        });
        let per_chunk: Vec<f32> = x
            .par_chunks(CHUNK)
            .zip(self.last.par_chunks(CHUNK))
            .zip(self.thickness.par_chunks(CHUNK))
            .zip(self.slots.par_chunks(CHUNK * nc))
            .map(|(((xs, lasts), hs), slots)| {
                let mut worst = touched;
                let mut k = 0;
                if wide {
                    while k + LANES <= xs.len() {
                        let r = k..k + LANES;
                        let s = &slots[k * nc..(k + LANES) * nc];
                        worst = batch(&xs[r.clone()], &lasts[r.clone()], &hs[r], s, worst);
                        k += LANES;
                    }
                }
                for k in k..xs.len() {
                    let s = &slots[k * nc..(k + 1) * nc];
                    worst = vertex(xs[k], lasts[k], hs[k], s, worst);
                }
                worst.0
            })
            .collect();
        per_chunk.into_iter().fold(0.0f32, f32::max)
    }

    /// The frame's motion of every collider, as the plan takes it.
    fn plan_motions(&self) -> Vec<Motion> {
        self.colliders
            .iter()
            .map(|c| {
                let deform = c.frame_deform_m();
                Motion::new(
                    (c.prev_pose(), c.pose()),
                    (deform, deform + c.frame_pose_motion_m(), c.travel_m()),
                    *c.local_aabb(),
                    PATH_STEPS,
                )
            })
            .collect()
    }

    /// The exact tests of [`reaching_motion`](Self::reaching_motion) for one pair: the largest
    /// motion, above `worst`, of the pair of a vertex (last at `p0`, now at `p1`,
    /// `v = |p₁ − p₀|`, contact band `band`) and collider `c` (its slot `slot`, its frame's
    /// motion `motions[c]`), when it can reach the collider and asks for more substeps than
    /// `worst`; else `worst`; with `skip = covered(worst)` for substeps of `step`.
    fn reach_pair(
        &self,
        motions: &[Motion],
        step: f32,
        c: usize,
        (p0, p1, v, band): (Vec3, Vec3, f32, f32),
        slot: &Slot,
        (worst, skip): (f32, f32),
    ) -> (f32, f32) {
        let (col, m) = (&self.colliders[c], &motions[c]);
        // `motion` below is at most `m.global + v` (a still pair: 0), and `worst >= 0`.
        if m.global + v <= skip {
            return (worst, skip);
        }
        // The path's speed bound (see above; `Motion::speed`): 0 for a still pair (a still
        // bone under still skin), which then costs nothing below.
        let raw = if m.still {
            v
        } else {
            // (A vertex still over the frame, the usual case, turns once.)
            let turn0 = m.omega.cross(p0);
            let turn1 = if p0 == p1 { turn0 } else { m.omega.cross(p1) };
            let step = p1 - p0;
            (step + m.ends[0] - turn0)
                .length()
                .max((step + m.ends[1] - turn1).length())
        };
        let speed = Motion::speed(raw);
        let motion = (speed + m.deform).min(m.global + v);
        if motion <= skip {
            return (worst, skip);
        }
        let margin = m.margin(band, speed);
        // The cached distance bound (now, and at the previous pose: at most the frame's
        // surface motion less) proves what the first test of `reaches` would: both ends at
        // least `margin + speed / 2` away (with room for the rounding of the distances it
        // computes).
        // (A vertex with no last pass this frame has `p0 == p1`: one bound.)
        let now = slot.lower_bound(p1, m.travel);
        let before = if p0 == p1 {
            now
        } else {
            slot.lower_bound(p0, m.travel)
        };
        // At the previous pose `p₀` was as far from the surface as `P₁ P₀⁻¹ p₀` is now, less
        // the deformation: the bound now, less how far that relative pose carries `p₀` (at
        // most the collider's whole motion `m.global`).
        let moved = if m.still {
            m.deform
        } else {
            let carried = (m.carry.0 * p0 + m.carry.1).length();
            m.moved(carried)
        };
        let bound = now.min(before - moved as f64);
        let needed = (margin + 0.5 * speed) as f64;
        if bound - 1e-4 * (p1.abs().max_element() as f64 + needed) - 1e-6 >= needed {
            return (worst, skip);
        }
        let distance = |t: f32| {
            let k = t * PATH_STEPS as f32;
            let pose = if t >= 1.0 {
                m.pose
            } else if k.fract() == 0.0 && k >= 0.0 {
                m.path[k as usize]
            } else {
                m.prev.lerp(&m.pose, t)
            };
            let local = pose.inverse_transform_point(p0.lerp(p1, t));
            // A distance of at least `margin + speed / 2` proves any piece out of reach: a
            // cheaper bound (the box, or a search stopped there) answers the same as the
            // exact distance.
            let cap = margin + 0.5 * speed;
            let d = aabb_distance(col.local_aabb(), local);
            if d >= cap {
                d
            } else {
                col.distance_local_capped(local, cap)
            }
        };
        if reaches(&distance, speed, margin) {
            (motion, covered_motion(motion, step))
        } else {
            (worst, skip)
        }
    }

    /// Runs the next substep of the frame begun by [`begin_frame`](Self::begin_frame): colliders
    /// to their interpolated state (poses slerped; a deforming mesh's vertices interpolated and
    /// its BVH refitted, unless its whole frame motion fits in one substep), the skin's
    /// warm-start motion advanced, one contact pass. Returns how many substeps remain; after
    /// the last one the colliders' state becomes their previous-frame state. Without a frame
    /// begun it does nothing and returns 0.
    pub fn substep(&mut self, x: &mut [Vec3]) -> Result<u32, CollisionError> {
        let n = self.vertex_count();
        if x.len() != n {
            return Err(CollisionError::Length {
                what: "positions",
                given: x.len(),
                expected: n,
            });
        }
        let Some(plan) = self.plan.take() else {
            return Ok(0);
        };
        if plan.substeps > 1 {
            let s = plan.next as f32 / plan.substeps as f32;
            for ((c, pose), &shape) in self
                .colliders
                .iter_mut()
                .zip(&plan.poses)
                .zip(&plan.interpolate)
            {
                c.enter_substep(s, pose, shape);
            }
            for (p, d) in x.iter_mut().zip(&plan.increments) {
                *p += *d;
            }
        }
        let done = self.pass(x);
        self.record(done.counters, done.unresolved);
        let remaining = plan.substeps - plan.next;
        if remaining == 0 {
            for c in &mut self.colliders {
                c.commit_frame();
            }
        } else {
            self.plan = Some(Plan {
                next: plan.next + 1,
                ..plan
            });
        }
        Ok(remaining)
    }

    /// [`begin_frame`](Self::begin_frame) and all its substeps, with contact passes only.
    pub fn advance_frame(&mut self, x: &mut [Vec3]) -> Result<&ContactDiagnostics, CollisionError> {
        self.begin_frame(x)?;
        while self.substep(x)? > 0 {}
        Ok(&self.diagnostics)
    }

    /// One contact pass over `x` (caller's order) against the colliders as they are, without the
    /// swept test: every vertex closer than its thickness is pushed out (after skinning, say).
    /// Returns `true` if any vertex moved.
    pub fn contact_pass(&mut self, x: &mut [Vec3]) -> Result<bool, CollisionError> {
        if x.len() != self.vertex_count() {
            return Err(CollisionError::Length {
                what: "positions",
                given: x.len(),
                expected: self.vertex_count(),
            });
        }
        let done = self.pass(x);
        let moved = done.counters.moved > 0;
        self.record(done.counters, done.unresolved);
        Ok(moved)
    }

    fn record(&mut self, c: Counters, unresolved: Vec<u32>) {
        let d = &mut self.diagnostics;
        d.unresolved = unresolved;
        d.contacts = c.contacts;
        d.passes += 1;
        d.moved += c.moved;
        d.exact_queries += c.exact_queries;
        d.cache_hits += c.cache_hits;
        d.certified_queries += c.certified;
        d.skipped_aabb += c.skipped_aabb;
        d.skipped_bound += c.skipped_bound;
        d.skipped_vertices += c.skipped_vertices;
        d.skipped_in_blocks += c.skipped_in_blocks;
        d.swept_hits += c.swept_hits;
    }

    /// Forgets the contacts the solver held ([`Projection::hold`]): only projections within
    /// one relaxation keep vertices on the surface.
    fn release_held(&mut self) {
        self.unhold();
        self.active.clear();
        self.active_owner.clear();
    }

    /// Clears the held colliders of every vertex held so far.
    fn unhold(&mut self) {
        for &v in &self.held_vertices {
            if let Some(s) = self.states.get_mut(v as usize) {
                s.held = [NONE; TOUCHES];
            }
        }
        self.held_vertices.clear();
    }

    /// The colliders' travel ([`ColliderMesh::travel_m`]) now. A collider's travel only grows,
    /// unless the collider was replaced in place (through `collider_mut`): then no cached bound
    /// measured against the old one holds, and every one is dropped.
    fn collider_travel(&mut self) -> Vec<f64> {
        let nc = self.colliders.len();
        let replaced = self.travel_seen.len() == nc
            && self
                .colliders
                .iter()
                .zip(&self.travel_seen)
                .any(|(c, &(uid, t))| c.uid() != uid || c.travel_m() < t);
        if replaced {
            self.leave_view();
            self.reach.fill(Reach::NEW);
            self.slots.fill(Slot::NEW);
            self.patches.fill(Patch::NEW);
        }
        self.travel_seen.clear();
        self.travel_seen
            .extend(self.colliders.iter().map(|c| (c.uid(), c.travel_m())));
        self.colliders.iter().map(ColliderMesh::travel_m).collect()
    }

    /// One contact pass over `x` (caller's order), parallel over fixed chunks of vertices,
    /// without the swept test; the held contacts are released first.
    fn pass(&mut self, x: &mut [Vec3]) -> ChunkPass {
        self.leave_view();
        self.release_held();
        let nc = self.colliders.len();
        if nc == 0 || x.is_empty() {
            return ChunkPass::default();
        }
        let travel = self.collider_travel();
        let ctx = Ctx {
            colliders: &self.colliders,
            travel: &travel,
            travel_sum: travel.iter().sum(),
            config: &self.config,
            swept: false,
            face_holds: self.face_holds,
        };
        let per_chunk: Vec<ChunkPass> = x
            .par_chunks_mut(CHUNK)
            .zip(self.reach.par_chunks_mut(CHUNK))
            .zip(self.last.par_chunks_mut(CHUNK))
            .zip(self.states.par_chunks_mut(CHUNK))
            .zip(self.slots.par_chunks_mut(CHUNK * nc))
            .zip(self.patches.par_chunks_mut(CHUNK * nc))
            .zip(self.thickness.par_chunks(CHUNK))
            .enumerate()
            .map(
                |(chunk, ((((((xs, reach), last), states), slots), patches), hs))| {
                    let mut done = ChunkPass::default();
                    let mut skipped = 0u64;
                    for (o, (((p, reach), last), state)) in xs
                        .iter_mut()
                        .zip(reach.iter_mut())
                        .zip(last.iter_mut())
                        .zip(states)
                        .enumerate()
                    {
                        if reach.skips(*p, ctx.travel_sum) {
                            // Provably outside every contact band: what resolving would find,
                            // without reading the collider slots.
                            *last = *p;
                            skipped += 1;
                            continue;
                        }
                        let cache = (
                            &mut slots[o * nc..(o + 1) * nc],
                            &mut patches[o * nc..(o + 1) * nc],
                        );
                        let (moved, bad) =
                            ctx.resolve(p, hs[o], (reach, last), state, cache, &mut done.counters);
                        done.counters.moved += u64::from(moved);
                        if bad {
                            done.unresolved.push((chunk * CHUNK + o) as u32);
                        }
                    }
                    done.counters.skipped_bound += skipped * nc as u64;
                    done.counters.skipped_vertices += skipped;
                    done
                },
            )
            .collect();
        let mut total = ChunkPass::default();
        for c in per_chunk {
            total.counters.add(&c.counters);
            total.unresolved.extend(c.unresolved);
        }
        total
    }

    /// Adopts `order` as the solver's order (as the next projection would) and trusts it until
    /// [`distrust_order`](Self::distrust_order): projections given this very slice skip
    /// comparing it. The caller must keep `order` borrowed, unchanged, until then (see
    /// [`relax_frame`]).
    pub(crate) fn trust_order(&mut self, order: &[u32]) {
        // Not a permutation: no trust, and every projection will say so.
        if self.adopt_order(order) {
            self.trusted_order = Some((order.as_ptr() as usize, order.len()));
        }
    }

    /// Makes `order` the solver's order unless it already is; `false` when it is not a
    /// permutation of the vertices.
    fn adopt_order(&mut self, order: &[u32]) -> bool {
        if self.rank_of == order {
            return true;
        }
        // The last positions held in the old order go back to the caller's order first.
        self.leave_view();
        self.rank_for(order)
    }

    /// Ends [`trust_order`](Self::trust_order).
    pub(crate) fn distrust_order(&mut self) {
        self.trusted_order = None;
    }

    /// Makes `rank` the inverse of a new `order`; `false` when `order` is not a permutation
    /// of the vertices.
    fn rank_for(&mut self, order: &[u32]) -> bool {
        self.trusted_order = None;
        self.rank_of.clear();
        self.rank = vec![u32::MAX; order.len()];
        for (i, &o) in order.iter().enumerate() {
            match self.rank.get_mut(o as usize) {
                Some(r) if *r == u32::MAX => *r = i as u32,
                _ => return false,
            }
        }
        self.rank_of = order.to_vec();
        true
    }
}

impl SkinCollision {
    /// A projection pass ([`Projection::project`]), after the solver's `step` if given.
    fn project_after(&mut self, x: &mut [Vec3], order: &[u32], step: Option<&Step<'_>>) -> bool {
        let moved = self.pass_after(x, order, step, false);
        for (&i, &p) in self.view.moved.iter().zip(&self.view.moves) {
            x[i as usize] = p;
        }
        moved
    }

    /// [`project_after`](Self::project_after) leaving `x` as it is: the moved vertices and
    /// their new positions are `self.view.moved` and `self.view.moves`.
    /// The pass's groups are timed into `alongside` when `alongside` holds.
    fn pass_after(
        &mut self,
        x: &[Vec3],
        order: &[u32],
        step: Option<&Step<'_>>,
        alongside: bool,
    ) -> bool {
        let n = self.vertex_count();
        self.active.clear();
        self.active_owner.clear();
        self.view.moved.clear();
        self.view.moves.clear();
        if x.len() != n || order.len() != n {
            self.diagnostics.length_mismatch = true;
            return false;
        }
        // One comparison of the order per pass (an O(n) read; the solver's order rarely
        // changes), unless the frame loop vouches for it.
        let trusted = self.trusted_order == Some((order.as_ptr() as usize, order.len()));
        if !trusted && !self.adopt_order(order) {
            self.diagnostics.length_mismatch = true;
            return false;
        }
        // The touching vertices come in the solver's order; each with its contacts in
        // resolution order below.
        let Some((done, touching)) = self.project_pass(x, step, alongside) else {
            return false;
        };
        let moved = done.counters.moved > 0;
        self.record(done.counters, done.unresolved);
        let stick = self.config.friction >= 1.0;
        for &(i, o) in &touching {
            let state = &self.states[o as usize];
            for t in state.touches.iter().take_while(|t| t.collider != NONE) {
                self.active.push(ActiveContact {
                    vertex: i,
                    normal: t.normal,
                    stick: stick && state.anchor.collider == t.collider,
                });
                self.active_owner.push((o, t.collider));
            }
        }
        // The list's buffer serves the next pass.
        self.view.touching = touching;
        moved
    }
}

impl Projection for SkinCollision {
    /// Pushes every vertex closer than its thickness to (or inside) a collider out to the
    /// thickness, after a swept test along its step since the last pass.
    fn project(&mut self, x: &mut [Vec3], order: &[u32]) -> bool {
        self.project_after(x, order, None)
    }

    /// [`project`](Self::project) after a solver's step: blocks of vertices whose motion,
    /// bounded by the step, keeps them provably outside every contact band are not read at
    /// all, and the swept test takes each vertex's last position from the step. Same
    /// answers.
    fn project_step(&mut self, x: &mut [Vec3], order: &[u32], step: &Step<'_>) -> bool {
        self.project_after(x, order, Some(step))
    }

    /// [`project_step`](Self::project_step) leaving `x` as it is (its pass runs alongside the
    /// solver's force gather): the same answers, the moves handed to the solver.
    fn project_step_deferred(
        &mut self,
        x: &[Vec3],
        order: &[u32],
        step: &Step<'_>,
        moves: &mut Vec<(u32, Vec3)>,
    ) -> Option<bool> {
        let moved = self.pass_after(x, order, Some(step), true);
        moves.clear();
        moves.extend(
            self.view
                .moved
                .iter()
                .copied()
                .zip(self.view.moves.iter().copied()),
        );
        Some(moved)
    }

    fn settled(&mut self, x: &[Vec3]) {
        self.settle_view(x);
    }

    /// Every vertex on a collider's surface (within `tolerance_m` of the thickness, or inside
    /// it when unresolved) after the last projection, one entry per collider (at most two),
    /// with the outward normal at its closest surface point. Sticks with `friction == 1` on
    /// the collider the vertex is anchored to. A vertex in the contact band but off the
    /// surface is not reported: a hold would snap it onto the surface.
    fn active_contacts(&self) -> &[ActiveContact] {
        &self.active
    }

    /// The vertices the last projection resolved to a new position, in no particular order.
    fn moved_vertices(&self) -> Option<&[u32]> {
        Some(&self.view.moved)
    }

    /// Held contacts are kept at exactly the thickness by the next projection: a vertex that
    /// drifted outward (a tangent step over a convex surface) is put back on it.
    fn hold(&mut self, held: &[bool]) {
        self.unhold();
        for (&(v, c), _) in self.active_owner.iter().zip(held).filter(|(_, h)| **h) {
            let Some(state) = self.states.get_mut(v as usize) else {
                continue;
            };
            if let Some(slot) = state.held.iter_mut().find(|s| **s == NONE) {
                *slot = c;
            }
            self.held_vertices.push(v);
        }
    }
}

struct Ctx<'a> {
    colliders: &'a [ColliderMesh],
    travel: &'a [f64],
    /// `travel` summed: a bound on how far any collider surface moved since a vertex's last
    /// pass, with the sum at that pass ([`Reach::travel_at`]).
    travel_sum: f64,
    config: &'a ContactConfig,
    swept: bool,
    /// Whether a touching vertex may get a hold.
    face_holds: bool,
}

impl Ctx<'_> {
    /// Resolves one vertex against every collider. Returns (moved, unresolved).
    fn resolve(
        &self,
        p: &mut Vec3,
        h: f32,
        (reach, last): (&mut Reach, &mut Vec3),
        state: &mut VertexState,
        (slots, patches): (&mut [Slot], &mut [Patch]),
        counters: &mut Counters,
    ) -> (bool, bool) {
        let start = *p;
        let cfg = self.config;
        let tol = cfg.tolerance_m;
        let band = h * (1.0 + cfg.contact_band);
        if self.swept && last.is_finite() && reach.safe > 0.0 {
            let delta = *p - *last;
            // A step shorter than the distance from its start to every surface cannot cross
            // one (a looser bound only costs casts that find nothing).
            if delta.length() as f64 > reach.clearance(*last, self.travel_sum) {
                let mut best: Option<(f32, Vec3, usize)> = None;
                for (c, col) in self.colliders.iter().enumerate() {
                    let pose = col.pose();
                    let from = pose.inverse_transform_point(*last);
                    let d = pose.inverse_transform_vector(delta);
                    if let Some((hit, normal)) = col.cast_local_segment(from, d) {
                        let t = hit.distance_squared(from);
                        if best.is_none_or(|b| t < b.0) {
                            best = Some((t, pose.transform_point(hit + normal * h), c));
                        }
                    }
                }
                if let Some((_, q, c)) = best {
                    *p = q;
                    slots[c].clearance = 0.0;
                    counters.swept_hits += 1;
                }
            }
        }
        let mut touching = Contact::NONE;
        let mut unresolved = false;
        // The last round's touch inside a mesh face, certified: (collider, signed distance,
        // margin of its triangle over every other, rest-frame point, triangle).
        let mut face: Option<(usize, f32, f32, Vec3, u32)> = None;
        // Rounds 0..max_rounds push; one more round only checks.
        for round in 0..=cfg.max_rounds {
            let check_only = round == cfg.max_rounds;
            let mut pushed = false;
            // The contacts of the last round, which saw the final position.
            state.touches = [Touch::NONE; TOUCHES];
            let mut touches = 0;
            face = None;
            for (c, col) in self.colliders.iter().enumerate() {
                let slot = &mut slots[c];
                let travel = self.travel[c];
                if slot.lower_bound(*p, travel) >= band as f64 {
                    counters.skipped_bound += 1;
                    continue;
                }
                let pose = col.pose();
                let local = pose.inverse_transform_point(*p);
                let box_distance = aabb_distance(col.local_aabb(), local);
                if box_distance >= band {
                    slot.set(box_distance, *p, travel);
                    counters.skipped_aabb += 1;
                    continue;
                }
                let margin = (0.25 * band).max(1e-5);
                let (proj, answer) = slot.project(&mut patches[c], col, local, travel, margin);
                let certified = answer == Answer::Certified;
                match answer {
                    Answer::Certified => counters.certified += 1,
                    Answer::Searched { hit } => {
                        counters.exact_queries += 1;
                        counters.cache_hits += hit as u64;
                    }
                }
                let s = proj.signed_distance;
                if s >= band {
                    slot.set(s, *p, travel);
                    continue;
                }
                let contact = Contact {
                    collider: c as u32,
                    part: proj.part,
                    coords: proj.coords,
                };
                touching = contact;
                // Only a contact at the surface goes to the solver: one in the band but off the
                // surface would be held there and snapped onto it by the next projection (the
                // lift below), a pull that the next iteration releases and the one after holds
                // again.
                if touches < TOUCHES && s <= h + tol {
                    state.touches[touches] = Touch {
                        collider: c as u32,
                        normal: pose.transform_vector(proj.normal),
                    };
                    touches += 1;
                    // Inside a face (no barycentric coordinate zero) the normal is the face's.
                    face = (certified && proj.coords.min_element() > 0.0)
                        .then(|| (c, s, patches[c].margin, local, proj.part));
                }
                if state.anchor.collider == NONE {
                    state.anchor = contact;
                }
                let mut q = local;
                let mut moved = false;
                // Held contacts are kept at the thickness from outside too (surface drift).
                let lifted = s > h + tol && state.held.contains(&(c as u32));
                if s < h - tol || lifted {
                    if check_only {
                        unresolved |= s < h - tol;
                        slot.set(s.max(0.0), *p, travel);
                        continue;
                    }
                    q = proj.point + proj.normal * h;
                    moved = true;
                }
                if round == 0 && cfg.friction > 0.0 && state.anchor.collider == c as u32 {
                    let a = col.local_surface_point(state.anchor.part, state.anchor.coords);
                    let rel = q - a;
                    let slip = rel - proj.normal * rel.dot(proj.normal);
                    if slip.length() > tol {
                        q -= slip * cfg.friction;
                        moved = true;
                    }
                }
                if moved {
                    *p = pose.transform_point(q);
                    slot.set(0.0, *p, travel);
                    pushed = true;
                } else {
                    slot.set(s.max(0.0), *p, travel);
                }
            }
            if !pushed {
                break;
            }
        }
        state.contact = touching;
        counters.contacts += (touching.collider != NONE) as u64;
        // The lower bound of the distance to every collider, and to every other than the one
        // touched inside a face (for its hold), from the slots in one pass.
        let face_c = face.map(|f| f.0);
        let (safe, others) = if unresolved {
            (0.0, f64::INFINITY)
        } else {
            let (all, others) = slots.iter().zip(self.travel).enumerate().fold(
                (f64::INFINITY, f64::INFINITY),
                |(all, others), (k, (s, &t))| {
                    let b = s.lower_bound(*p, t);
                    (
                        all.min(b),
                        if face_c == Some(k) {
                            others
                        } else {
                            others.min(b)
                        },
                    )
                },
            );
            (all.max(0.0), others)
        };
        // A vertex that touched something is resolved again by the next pass (its contact and
        // touches must be recomputed even if it leaves), unless it is held on a face: then the
        // solver-order passes skip it within its hold (see `project`). The rounding allowance
        // covers the f32 distances of the skip test and the bound's own rounding to f32.
        let reserve = safe - band as f64 - 1e-5 * (p.abs().max_element() as f64 + safe) - 1e-9;
        let hold = match face {
            Some((c, s, margin, local, part))
                if self.face_holds
                    && cfg.friction == 0.0
                    && !unresolved
                    && touching.collider == c as u32
                    && state.touches[0].collider == c as u32
                    && state.touches[1].collider == NONE =>
            {
                let scale = p.abs().max_element().max(local.abs().max_element()) + s.abs();
                let patch = &patches[c];
                let prism = patch.slack(local, self.travel[c]).and_then(|slack| {
                    let allowance = prism_allowance(scale, h + tol);
                    self.colliders[c].face_prism(local, part, patch, slack, allowance)
                });
                hold_of(scale, (h, tol, band), s, (margin, prism), others)
            }
            _ => None,
        };
        state.slab = hold.map_or([0.0; 2], |h| h.1);
        *reach = Reach {
            at: *p,
            reserve: if touching.collider == NONE && !unresolved && reserve > 0.0 {
                reserve as f32
            } else {
                f32::NEG_INFINITY
            },
            travel_at: self.travel_sum,
            safe: safe as f32,
            hold: hold.map_or(0.0, |h| h.0),
        };
        *last = *p;
        (*p != start, unresolved)
    }
}

/// The hold of a vertex touching one mesh collider inside a face, no collider moving: the
/// radius within which its triangle stays the closest (so it projects inside that face, and its
/// normal is the contact's) and every other collider (lower bound `others`) stays beyond the
/// band `band`; and the range of `n · (p − at)` (`n` the face normal) over which its signed
/// distance, `s` now, stays within the tolerance `tol` of the thickness `h` (there the
/// distance to the face's plane, linear along `n`): no push, no lift, still touching. `None`:
/// no hold.
///
/// The triangle stays the closest within the larger of two radii (each sound alone):
/// - half its `margin` over every other triangle: any edge or corner of a closed mesh is
///   shared with a triangle as close, so it also projects inside the face;
/// - with a [`Prism`] (`prism`), the smaller of half its margin over the triangles not beyond
///   one of the face's edges, and its clearance from those edges less what keeps a triangle
///   beyond an edge farther than the face (`prism_allowance`): at height `s′ ≤ h + tol` above
///   the face and `e′` inside an edge, a triangle beyond that edge and below the face's plane
///   (both within `τ`) is at least `√((e′ − τ)² + (s′ − τ)²)` away, more than `s′` by over
///   `δ` once `(e′ − τ)² > 2 (h + tol) (δ + τ) + (δ + τ)²`.
///
/// Over a thick skin the first is tiny (`e′² / 2s′` for a neighbour across an edge `e′` away:
/// ~1 µm on the bench's muscle, less than a solver step moves a sliding vertex) and the second
/// is most of the distance to the face's edges.
///
/// Each bound less its rounding allowance relative to `scale` (the largest coordinate, world
/// or rest frame, plus the distance): the f32 distances a few ulps (allowed 1e-6 each), the tie
/// rounding of the patch answers (1e-5), the reserve's own (1e-5), the prism's corner tests
/// ([`PRISM_TAU`]), and the normal's rounding along the step (1e-5 of the radius).
fn hold_of(
    scale: f32,
    (h, tol, band): (f32, f32, f32),
    s: f32,
    (margin, prism): (f32, Option<Prism>),
    others: f64,
) -> Option<(f32, [f32; 2])> {
    let scale = f64::from(scale);
    let delta = HOLD_ROUNDING * scale;
    let closest = 0.5 * (f64::from(margin) - delta);
    let closest = match prism {
        Some(prism) => {
            let (inside, rest) = (
                f64::from(prism.inside),
                0.5 * (f64::from(prism.rest) - delta),
            );
            // A NaN anywhere leaves the first radius (`max` skips a NaN).
            if inside.is_nan() || rest.is_nan() {
                closest
            } else {
                closest.max(inside.min(rest))
            }
        }
        None => closest,
    };
    // No other collider: nothing to clear.
    let clear = if others.is_finite() {
        others - f64::from(band) - 1e-5 * (scale + others.abs()) - 1e-9
    } else {
        f64::INFINITY
    };
    let radius = closest.min(clear);
    if radius.is_nan() || radius <= 0.0 {
        return None;
    }
    // The resolution's own thresholds, `h ∓ tol` in f32.
    let allow = 2e-6 * scale + 1e-5 * radius;
    let lo = f64::from(h - tol) - f64::from(s) + allow;
    let hi = f64::from(h + tol) - f64::from(s) - allow;
    (lo <= 0.0 && hi >= 0.0).then_some((radius as f32, [lo as f32, hi as f32]))
}

/// The rounding allowance `δ` of two f32 distances compared in a hold (see `hold_of`),
/// relative to the coordinates' magnitude.
const HOLD_ROUNDING: f64 = 4e-6;

/// The allowance `τ` of a [`Prism`]'s corner and edge tests, relative to the coordinates'
/// magnitude: far over their f32 rounding (a few 1e-7).
const PRISM_TAU: f64 = 5e-7;

/// A prism's allowances for coordinates of magnitude `scale` (see `hold_of`): its corner
/// tests' `τ`; how far inside its face's edges a point at most `top` above the face must be
/// for every triangle beyond an edge and below the face to stay farther than the face by over
/// the rounding allowance, plus `τ`; and that allowance `δ`.
fn prism_allowance(scale: f32, top: f32) -> (f32, f32, f32) {
    let scale = f64::from(scale);
    let (delta, tau) = (HOLD_ROUNDING * scale, PRISM_TAU * scale);
    let dt = delta + tau;
    let need = tau + (2.0 * f64::from(top) * dt + dt * dt).sqrt();
    (tau as f32, need as f32, delta as f32)
}

/// The substeps a largest reaching motion `motion` asks for, before the clamp to
/// `1..=max_substeps`: `⌈motion / step⌉` (f32), `step` half the thinnest skin (none: 1).
fn wanted_substeps(motion: f32, step: f32) -> f32 {
    if step > 0.0 {
        (motion / step).ceil()
    } else {
        1.0
    }
}

/// The motion up to which a pair asks for no more substeps than `worst` does (at least
/// `worst`): within the count `k = max(1, ⌈worst / step⌉)`, less a relative 1e-5, so that the f32
/// division of [`wanted_substeps`] cannot round a motion below it up to `k + 1`.
fn covered_motion(worst: f32, step: f32) -> f32 {
    if step > 0.0 {
        let k = wanted_substeps(worst, step).max(1.0);
        (k * step * (1.0 - 1e-5)).max(worst)
    } else {
        worst
    }
}

/// Chunk `c` of the states (`CHUNK` vertices each): every vertex's contact becomes its friction
/// anchor; yields the vertices touching a collider.
fn anchor_chunk(c: usize, states: &mut [VertexState]) -> impl Iterator<Item = u32> + '_ {
    states.iter_mut().enumerate().filter_map(move |(k, s)| {
        s.anchor = s.contact;
        (s.contact.collider != NONE).then_some((c * CHUNK + k) as u32)
    })
}

/// Skin vertices from which [`SkinCollision::begin_frame`] checks the positions and lists the
/// touching vertices in parallel.
const PARALLEL_PLAN_PREP: usize = 65_536;

/// The finest piece of [`reaches`]' bisection is `1 / PATH_STEPS` of the path: it evaluates the
/// path only at multiples of that.
const PATH_STEPS: usize = 64;

/// Whether a path along which `distance(t)` (`t ∈ [0, 1]`) is 1-Lipschitz at `speed` can come
/// below `margin`: bisection with exact ends, up to 64 pieces (`true` when not disproved).
fn reaches(distance: &impl Fn(f32) -> f32, speed: f32, margin: f32) -> bool {
    if speed == 0.0 {
        // A still path (a deforming collider's own motion is in the margin): one query.
        return distance(1.0) < margin;
    }
    // Depth-first over halvings down to 1/64: at most one pending piece per level (no heap).
    let mut stack = [(0.0f32, 0.0f32, 0.0f32, 0.0f32); 8];
    stack[0] = (0.0, distance(0.0), 1.0, distance(1.0));
    let mut len = 1;
    while len > 0 {
        len -= 1;
        let (ta, sa, tb, sb) = stack[len];
        if sa.min(sb) < margin {
            return true;
        }
        let dip = 0.5 * speed * (tb - ta);
        if sa.min(sb) - dip >= margin {
            continue;
        }
        if tb - ta <= 1.0 / PATH_STEPS as f32 {
            return true;
        }
        let tm = 0.5 * (ta + tb);
        let sm = distance(tm);
        stack[len] = (tm, sm, tb, sb);
        stack[len + 1] = (ta, sa, tm, sm);
        len += 2;
    }
    false
}

/// Distance from `p` to the box (0 inside).
fn aabb_distance(aabb: &Aabb, p: Vec3) -> f32 {
    let d = (aabb.mins - p).max(p - aabb.maxs).max(Vec3::ZERO);
    d.length()
}

#[cfg(test)]
mod tests;
