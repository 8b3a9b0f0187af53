//! Sliding contact of the skin on deforming muscles and rigid bones: thickness, friction, no tunnelling.
#![doc = include_str!("README.md")]

pub mod bench_support;
mod cache;
mod collider;
pub mod shapes;

pub use collider::{ColliderMesh, SurfaceProjection};

use glam::Vec3;
use parry3d::bounding_volume::Aabb;
use parry3d::math::Pose;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::mesh::TopologyError;
use crate::solver::Projection;
use cache::{Answer, Slot};
use collider::NONE;

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
    /// Vertex–collider pairs skipped because the cached distance bound proves no contact.
    pub skipped_bound: u64,
    /// Vertices stopped by the swept test (a step that would have crossed a collider).
    pub swept_hits: u64,
    /// Substeps used by the last [`SkinCollision::begin_frame`].
    pub substeps: u32,
    /// `true` when the last frame needed more than [`ContactConfig::max_substeps`] substeps.
    pub substeps_capped: bool,
    /// `true` when a pass was handed positions of the wrong length (it then did nothing).
    pub length_mismatch: bool,
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

/// Per-vertex state.
#[derive(Debug, Clone, Copy)]
struct VertexState {
    /// Position after the last pass (NaN: none yet).
    last: Vec3,
    /// How far `last` may move before it can reach any collider surface, m.
    safe: f32,
    /// The surface point touched in the last pass.
    contact: Contact,
    /// The surface point touched at the start of the frame (friction).
    anchor: Contact,
}

impl VertexState {
    const NEW: Self = Self {
        last: Vec3::NAN,
        safe: 0.0,
        contact: Contact::NONE,
        anchor: Contact::NONE,
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
    swept_hits: u64,
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
    states: Vec<VertexState>,
    /// `vertex_count × colliders` slots, vertex-major.
    slots: Vec<Slot>,
    scratch: Vec<Vec3>,
    diagnostics: ContactDiagnostics,
    plan: Option<Plan>,
}

/// The substeps of the frame in progress.
#[derive(Debug, Clone)]
struct Plan {
    substeps: u32,
    next: u32,
    poses: Vec<Pose>,
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
            states: vec![VertexState::NEW; vertex_count],
            slots: Vec::new(),
            scratch: Vec::new(),
            diagnostics: ContactDiagnostics::default(),
            plan: None,
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
        let n = self.thickness.len();
        self.states = vec![VertexState::NEW; n];
        self.slots = vec![Slot::NEW; n * self.colliders.len()];
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
        if let Some(i) = x.iter().position(|p| !p.is_finite()) {
            return Err(CollisionError::NonFinite {
                what: "skin vertex",
                index: i,
            });
        }
        self.diagnostics = ContactDiagnostics::default();
        for s in &mut self.states {
            s.anchor = s.contact;
        }
        let vertex_motion = x
            .iter()
            .zip(&self.states)
            .filter(|(_, s)| s.last.is_finite())
            .map(|(p, s)| p.distance(s.last))
            .fold(0.0f32, f32::max);
        let collider_motion = self
            .colliders
            .iter()
            .map(ColliderMesh::frame_motion_m)
            .fold(0.0f32, f32::max);
        let h_min = self.thickness.iter().copied().fold(f32::INFINITY, f32::min);
        let wanted = if h_min > 0.0 {
            ((vertex_motion + collider_motion) / (0.5 * h_min)).ceil()
        } else {
            1.0
        };
        let substeps = (wanted.max(1.0) as u64).min(self.config.max_substeps as u64) as u32;
        let capped = wanted > self.config.max_substeps as f32;
        self.diagnostics.substeps_capped = capped;
        self.diagnostics.substeps = substeps;
        let mut increments = Vec::new();
        if substeps > 1 {
            increments = x
                .iter_mut()
                .zip(&self.states)
                .map(|(p, s)| {
                    let target = *p;
                    if s.last.is_finite() {
                        *p = s.last;
                    }
                    (target - *p) / substeps as f32
                })
                .collect();
        }
        self.plan = Some(Plan {
            substeps,
            next: 1,
            poses: self.colliders.iter().map(ColliderMesh::pose).collect(),
            increments,
        });
        Ok(FramePlan { substeps, capped })
    }

    /// Runs the next substep of the frame begun by [`begin_frame`](Self::begin_frame): colliders
    /// to their interpolated state (poses slerped, deforming vertices interpolated and the BVH
    /// refitted), the skin's warm-start motion advanced, one contact pass. Returns how many
    /// substeps remain; after the last one the colliders' state becomes their previous-frame
    /// state. Without a frame begun it does nothing and returns 0.
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
            for (c, pose) in self.colliders.iter_mut().zip(&plan.poses) {
                c.enter_substep(s, pose);
            }
            for (p, d) in x.iter_mut().zip(&plan.increments) {
                *p += *d;
            }
        }
        let (counters, unresolved) = self.pass(x, false);
        self.record(counters, unresolved);
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
        let (counters, unresolved) = self.pass(x, false);
        let moved = counters.moved > 0;
        self.record(counters, unresolved);
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
        d.swept_hits += c.swept_hits;
    }

    /// One contact pass over `x` (caller's order), parallel over fixed chunks of vertices.
    fn pass(&mut self, x: &mut [Vec3], swept: bool) -> (Counters, Vec<u32>) {
        let nc = self.colliders.len();
        if nc == 0 || x.is_empty() {
            return (Counters::default(), Vec::new());
        }
        let travel: Vec<f64> = self.colliders.iter().map(ColliderMesh::travel_m).collect();
        let ctx = Ctx {
            colliders: &self.colliders,
            travel: &travel,
            config: &self.config,
            swept,
        };
        let per_chunk: Vec<(Counters, Vec<u32>)> = x
            .par_chunks_mut(CHUNK)
            .zip(self.states.par_chunks_mut(CHUNK))
            .zip(self.slots.par_chunks_mut(CHUNK * nc))
            .zip(self.thickness.par_chunks(CHUNK))
            .enumerate()
            .map(|(chunk, (((xs, states), slots), hs))| {
                let mut counters = Counters::default();
                let mut unresolved = Vec::new();
                for (o, (p, state)) in xs.iter_mut().zip(states.iter_mut()).enumerate() {
                    let slots = &mut slots[o * nc..(o + 1) * nc];
                    let (moved, bad) = ctx.resolve(p, hs[o], state, slots, &mut counters);
                    counters.moved += moved as u64;
                    if bad {
                        unresolved.push((chunk * CHUNK + o) as u32);
                    }
                }
                (counters, unresolved)
            })
            .collect();
        let mut total = Counters::default();
        let mut unresolved = Vec::new();
        for (c, u) in per_chunk {
            total.add(&c);
            unresolved.extend(u);
        }
        (total, unresolved)
    }
}

impl Projection for SkinCollision {
    /// Pushes every vertex closer than its thickness to (or inside) a collider out to the
    /// thickness, after a swept test along its step since the last pass.
    fn project(&mut self, x: &mut [Vec3], order: &[u32]) -> bool {
        let n = self.vertex_count();
        if x.len() != n || order.len() != n {
            self.diagnostics.length_mismatch = true;
            return false;
        }
        let mut xc = std::mem::take(&mut self.scratch);
        xc.resize(n, Vec3::ZERO);
        for (i, &o) in order.iter().enumerate() {
            let Some(slot) = xc.get_mut(o as usize) else {
                self.diagnostics.length_mismatch = true;
                self.scratch = xc;
                return false;
            };
            *slot = x[i];
        }
        let (counters, unresolved) = self.pass(&mut xc, true);
        x.par_iter_mut()
            .zip(order.par_iter())
            .for_each(|(x, &o)| *x = xc[o as usize]);
        self.scratch = xc;
        let moved = counters.moved > 0;
        self.record(counters, unresolved);
        moved
    }
}

struct Ctx<'a> {
    colliders: &'a [ColliderMesh],
    travel: &'a [f64],
    config: &'a ContactConfig,
    swept: bool,
}

impl Ctx<'_> {
    /// Resolves one vertex against every collider. Returns (moved, unresolved).
    fn resolve(
        &self,
        p: &mut Vec3,
        h: f32,
        state: &mut VertexState,
        slots: &mut [Slot],
        counters: &mut Counters,
    ) -> (bool, bool) {
        let start = *p;
        let cfg = self.config;
        let tol = cfg.tolerance_m;
        let band = h * (1.0 + cfg.contact_band);
        if self.swept && state.last.is_finite() && state.safe > 0.0 {
            let delta = *p - state.last;
            if delta.length() > state.safe {
                let mut best: Option<(f32, Vec3, usize)> = None;
                for (c, col) in self.colliders.iter().enumerate() {
                    let pose = col.pose();
                    let from = pose.inverse_transform_point(state.last);
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
        // Rounds 0..max_rounds push; one more round only checks.
        for round in 0..=cfg.max_rounds {
            let check_only = round == cfg.max_rounds;
            let mut pushed = false;
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
                let (proj, answer) = slot.project(col, local, travel, (0.25 * band).max(1e-5));
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
                if state.anchor.collider == NONE {
                    state.anchor = contact;
                }
                let mut q = local;
                let mut moved = false;
                if s < h - tol {
                    if check_only {
                        unresolved = true;
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
        state.safe = if unresolved {
            0.0
        } else {
            slots
                .iter()
                .zip(self.travel)
                .map(|(s, &t)| s.lower_bound(*p, t))
                .fold(f64::INFINITY, f64::min)
                .max(0.0) as f32
        };
        state.last = *p;
        (*p != start, unresolved)
    }
}

/// Distance from `p` to the box (0 inside).
fn aabb_distance(aabb: &Aabb, p: Vec3) -> f32 {
    let d = (aabb.mins - p).max(p - aabb.maxs).max(Vec3::ZERO);
    d.length()
}

#[cfg(test)]
mod tests;
