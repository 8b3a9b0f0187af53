//! Colliders: closed deforming triangle meshes and rigid primitives, queried in their own frame.

use glam::Vec3;
use parry3d::bounding_volume::Aabb;
use parry3d::math::Pose;
use parry3d::query::PointQuery;
use parry3d::query::{Ray, RayCast};
use parry3d::shape::{
    Ball, Capsule, CompositeShapeRef, TriMesh as ParryMesh, Triangle, TrianglePointLocation,
};
use rayon::prelude::*;
use std::sync::OnceLock;

use super::CollisionError;
use super::cache::{PATCH, Patch};
use crate::mesh::TriMesh;
use parts::Parts;

mod lean;
mod parts;
#[cfg(test)]
mod tests;

/// Marks "no triangle" in neighbour tables and caches.
pub(crate) const NONE: u32 = u32::MAX;

/// Vertices per job of [`ColliderMesh::set_vertices`]'s check of its input (a few
/// microseconds each: the checks spread over the threads that refit the parts).
const CHECK_CHUNK: usize = 4096;

/// One chunk of [`ColliderMesh::set_vertices`]'s check: whether its input is finite, and its
/// largest squared displacements from the fitted vertices and from the previous frame's, m².
struct Check {
    finite: bool,
    moved_sq: f32,
    deform_sq: f32,
}

/// Refits of a mesh collider's BVH parts since it was built ([`ColliderMesh::refit_stats`]).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct RefitStats {
    /// Parts refitted (a mesh in one part: once per move; a split mesh: once per part a
    /// query reached after a move).
    pub parts_refitted: u64,
    /// Time the refits took, s, summed over the threads that ran them.
    pub seconds: f64,
}

/// The closest point of a collider's surface to a query point, in the collider's local frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfaceProjection {
    /// The closest surface point, m.
    pub point: Vec3,
    /// Unit direction along which the query point leaves the surface: away from the surface
    /// for an outside point, towards it for an inside one (the outward feature normal when the
    /// point lies on the surface). When the closest point lies inside a mesh face, that face's
    /// outward normal itself, bit for bit the same wherever over the face the point is.
    pub normal: Vec3,
    /// Distance to the surface, negative inside, m.
    pub signed_distance: f32,
    /// The triangle the point projected on (0 for primitives).
    pub part: u32,
    /// Where on `part`: barycentric coordinates on a triangle; the local surface point itself
    /// for primitives. Carried by the surface as it moves (friction anchors).
    pub coords: Vec3,
}

#[derive(Debug, Clone)]
enum Shape {
    Mesh(Box<MeshShape>),
    Capsule { a: Vec3, b: Vec3, radius: f32 },
    Ball { radius: f32 },
}

#[derive(Debug, Clone)]
struct MeshShape {
    /// The triangles as subtrees of one parry BVH, searched as the whole mesh's BVH and each
    /// refitted when a search first reaches it after a move (see [`parts`]). Parry meshes
    /// built without `ORIENTED`: refits cost only the BVH.
    parts: Parts,
    /// Triangles (mesh vertex ids), as built.
    indices: Vec<[u32; 3]>,
    /// The vertices the parts are fitted to: `current`, or interpolated ones during substeps.
    live: Vec<Vec3>,
    /// The vertices as built (the BVH's structure was built over them).
    rest: Vec<Vec3>,
    /// Vertices at the end of the previous frame.
    prev: Vec<Vec3>,
    /// Vertices of the current frame.
    current: Vec<Vec3>,
    /// Largest displacement from `prev` to `current`, m (kept with them: the frame plan reads
    /// it several times, and `set_vertices` measures it in its check of the input).
    deform_m: f32,
    /// Triangle across each of a triangle's edges, in parry's local edge numbering (0: AB,
    /// 1: BC, 2: AC).
    across: Vec<[u32; 3]>,
    /// CSR vertex → incident triangles.
    vt_offsets: Vec<u32>,
    vt: Vec<u32>,
    /// The whole mesh as one parry mesh at `live`, made on demand by
    /// [`ColliderMesh::parry_mesh`] and dropped when `live` changes.
    whole: OnceLock<ParryMesh>,
}

/// A closed surface the skin slides over: a deforming muscle mesh, or a rigid bone (a capsule,
/// a ball, or a closed mesh moved only by its pose).
///
/// Every shape is stored in its rest frame with a [`Pose`]; queries transform the skin vertex
/// into that frame, so moving a rigid bone is one [`set_pose`](Self::set_pose) and no refit. A
/// deforming mesh is refreshed with [`set_vertices`](Self::set_vertices), a BVH refit (the
/// mesh is never parry-`ORIENTED`, which would recompute pseudo-normals on every refit):
/// inside/outside comes from the normal of the feature the point projects on, face normals
/// for faces, the sum of the two face normals for edges, angle-weighted normals for vertices.
///
/// ```
/// use dermis::collision::ColliderMesh;
/// use glam::Vec3;
/// // A tetrahedron, wound counter-clockwise seen from outside.
/// let v = vec![Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::Z];
/// let t = vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]];
/// let tet = ColliderMesh::from_mesh(v, t).unwrap();
/// let inside = tet.project_point(Vec3::splat(0.1));
/// assert!(inside.signed_distance < 0.0);
/// let outside = tet.project_point(Vec3::new(0.2, 0.2, -0.5));
/// assert!((outside.signed_distance - 0.5).abs() < 1e-6);
///
/// // Holes are rejected with the offending edge named.
/// let open = ColliderMesh::from_mesh(
///     vec![Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::Z],
///     vec![[0, 2, 1], [0, 1, 3], [0, 3, 2]],
/// );
/// assert!(open.unwrap_err().to_string().contains("hole"));
/// ```
#[derive(Debug, Clone)]
pub struct ColliderMesh {
    shape: Shape,
    pose: Pose,
    prev_pose: Pose,
    /// Sum of surface-motion bounds over every state change, m (distance-bound cache).
    travel_m: f64,
    local_aabb: Aabb,
    /// Which construction this is (clones share it): a contact cache measured against one
    /// collider must not be trusted for another put in its place.
    uid: u64,
}

impl ColliderMesh {
    /// A closed, consistently wound triangle mesh (counter-clockwise seen from outside), at the
    /// identity pose.
    ///
    /// Rejected: invalid topology or geometry, holes (an edge with one triangle), edges whose two
    /// triangles wind the same way, and inside-out meshes (negative signed volume). An
    /// inside-out mesh is rejected rather than flipped: it usually means an exporter used the
    /// opposite convention, which the caller should know about.
    pub fn from_mesh(
        vertices: Vec<Vec3>,
        triangles: Vec<[u32; 3]>,
    ) -> Result<Self, CollisionError> {
        Self::from_mesh_in_parts(vertices, triangles, parts::PART_TRIANGLES)
    }

    /// [`from_mesh`](Self::from_mesh) with BVH parts of at most `max_part` triangles where the
    /// BVH allows.
    pub(crate) fn from_mesh_in_parts(
        vertices: Vec<Vec3>,
        triangles: Vec<[u32; 3]>,
        max_part: usize,
    ) -> Result<Self, CollisionError> {
        let checked = TriMesh::new(vertices, triangles)?;
        let topo = checked.topology();
        let tris = topo.triangles();
        let pos = checked.positions();
        let mut across = vec![[NONE; 3]; tris.len()];
        for (&[a, b], &[t0, t1]) in topo.edges().iter().zip(topo.edge_triangles()) {
            if t1 == crate::mesh::NO_TRIANGLE {
                return Err(CollisionError::Hole {
                    a,
                    b,
                    triangle: t0 as usize,
                });
            }
            let (l0, f0) = directed_edge(tris[t0 as usize], a, b);
            let (l1, f1) = directed_edge(tris[t1 as usize], a, b);
            if f0 == f1 {
                return Err(CollisionError::InconsistentWinding {
                    a,
                    b,
                    first: t0 as usize,
                    second: t1 as usize,
                });
            }
            across[t0 as usize][l0] = t1;
            across[t1 as usize][l1] = t0;
        }
        let volume: f64 = tris
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| pos[i as usize].as_dvec3());
                a.dot(b.cross(c)) / 6.0
            })
            .sum();
        if volume <= 0.0 {
            return Err(CollisionError::InsideOut { volume_m3: volume });
        }
        let n = pos.len();
        let mut vt_offsets = vec![0u32; n + 1];
        for t in tris {
            for &v in t {
                vt_offsets[v as usize + 1] += 1;
            }
        }
        for i in 0..n {
            vt_offsets[i + 1] += vt_offsets[i];
        }
        let mut fill = vt_offsets.clone();
        let mut vt = vec![0u32; tris.len() * 3];
        for (ti, t) in tris.iter().enumerate() {
            for &v in t {
                vt[fill[v as usize] as usize] = ti as u32;
                fill[v as usize] += 1;
            }
        }
        let vertices = pos.to_vec();
        let whole = ParryMesh::new(vertices.clone(), tris.to_vec())
            .map_err(|e| CollisionError::Parry(e.to_string()))?;
        let local_aabb = whole.local_aabb();
        let parts = Parts::new(whole, max_part);
        Ok(Self::with_shape(
            Shape::Mesh(Box::new(MeshShape {
                parts,
                indices: tris.to_vec(),
                live: vertices.clone(),
                rest: vertices.clone(),
                prev: vertices.clone(),
                current: vertices,
                deform_m: 0.0,
                across,
                vt_offsets,
                vt,
                whole: OnceLock::new(),
            })),
            local_aabb,
        ))
    }

    /// A capsule (a bone) around the segment `a`–`b` of its rest frame, `radius_m` thick.
    pub fn capsule(a: Vec3, b: Vec3, radius_m: f32) -> Result<Self, CollisionError> {
        if !(a.is_finite() && b.is_finite() && radius_m.is_finite() && radius_m > 0.0) {
            return Err(CollisionError::BadShape {
                what: "capsule",
                detail: format!("a {a}, b {b}, radius {radius_m}"),
            });
        }
        let aabb = Aabb::new(
            a.min(b) - Vec3::splat(radius_m),
            a.max(b) + Vec3::splat(radius_m),
        );
        Ok(Self::with_shape(
            Shape::Capsule {
                a,
                b,
                radius: radius_m,
            },
            aabb,
        ))
    }

    /// A ball of `radius_m` centred on its rest frame's origin.
    pub fn ball(radius_m: f32) -> Result<Self, CollisionError> {
        if !(radius_m.is_finite() && radius_m > 0.0) {
            return Err(CollisionError::BadShape {
                what: "ball",
                detail: format!("radius {radius_m}"),
            });
        }
        let r = Vec3::splat(radius_m);
        Ok(Self::with_shape(
            Shape::Ball { radius: radius_m },
            Aabb::new(-r, r),
        ))
    }

    fn with_shape(shape: Shape, local_aabb: Aabb) -> Self {
        Self {
            shape,
            pose: Pose::IDENTITY,
            prev_pose: Pose::IDENTITY,
            travel_m: 0.0,
            local_aabb,
            uid: {
                static NEXT: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
                NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed)
            },
        }
    }

    /// Builder: the same collider at `pose` (also its previous-frame pose).
    pub fn with_pose(mut self, pose: Pose) -> Self {
        self.pose = pose;
        self.prev_pose = pose;
        self
    }

    /// The current pose (rest frame → world).
    pub fn pose(&self) -> Pose {
        self.pose
    }

    /// Moves the collider rigidly. No refit: queries happen in the rest frame.
    pub fn set_pose(&mut self, pose: Pose) -> Result<(), CollisionError> {
        if !pose.is_finite() {
            return Err(CollisionError::NonFinite {
                what: "pose",
                index: 0,
            });
        }
        self.travel_m += pose_motion(&self.local_aabb, &self.pose, &pose) as f64;
        self.pose = pose;
        Ok(())
    }

    /// Deforms a mesh collider (rest-frame positions, same count and order as built): a BVH
    /// refit, no pseudo-normal recomputation. A mesh of more than 1,024 triangles holds its
    /// BVH in subtrees of at most that many, which answer every query exactly as one BVH over
    /// the whole mesh: this call checks the input, recomputes the boxes above the subtrees and
    /// refits (in parallel) the subtrees queries reached since the last move, and each other
    /// subtree is refitted when a query first reaches it (see
    /// [`refit_stats`](Self::refit_stats)). A non-finite or wrongly sized input is an error
    /// and leaves the collider as it was.
    pub fn set_vertices(&mut self, vertices: &[Vec3]) -> Result<(), CollisionError> {
        let Shape::Mesh(m) = &mut self.shape else {
            return Err(CollisionError::NotAMesh);
        };
        if vertices.len() != m.current.len() {
            return Err(CollisionError::Length {
                what: "collider vertices",
                given: vertices.len(),
                expected: m.current.len(),
            });
        }
        // The checks, in parallel chunks: the input finite, and its largest displacements from
        // the fitted vertices and from the previous frame's. Nothing changes before they pass.
        let checked: Vec<Check> = vertices
            .par_chunks(CHECK_CHUNK)
            .zip(m.live.par_chunks(CHECK_CHUNK))
            .zip(m.prev.par_chunks(CHECK_CHUNK))
            .map(|((v, live), prev)| Check {
                finite: v.iter().all(|v| v.is_finite()),
                moved_sq: max_distance_sq(live, v),
                deform_sq: max_distance_sq(prev, v),
            })
            .collect();
        if !checked.iter().all(|c| c.finite) {
            return Err(CollisionError::NonFinite {
                what: "collider vertex",
                index: vertices.iter().position(|v| !v.is_finite()).unwrap_or(0),
            });
        }
        m.live.copy_from_slice(vertices);
        m.current.copy_from_slice(vertices);
        m.parts.move_to(&m.live);
        // Maxima: the same whatever the order.
        let (moved_sq, deform_sq) = checked.iter().fold((0.0f32, 0.0f32), |(m, d), c| {
            (m.max(c.moved_sq), d.max(c.deform_sq))
        });
        let moved = moved_sq.sqrt();
        m.deform_m = deform_sq.sqrt();
        m.whole = OnceLock::new();
        self.local_aabb = m.parts.local_aabb();
        self.travel_m += moved as f64;
        Ok(())
    }

    /// Number of triangles (0 for primitives).
    pub fn triangle_count(&self) -> usize {
        match &self.shape {
            Shape::Mesh(m) => m.indices.len(),
            _ => 0,
        }
    }

    /// The whole mesh of a mesh collider as one parry mesh, in its rest frame and its current
    /// shape (for comparisons and debugging): built over the shape the collider was built
    /// with and refitted to the current one, as parry's own deforming mesh would be, so its
    /// answers are the collider's, ties between triangles included. The collider holds its
    /// BVH in parts (see [`set_vertices`](Self::set_vertices)): this mesh is made on the first
    /// call after the shape changed (a full BVH build, about 15 ms for 50k triangles) and kept
    /// until the next change.
    pub fn parry_mesh(&self) -> Option<&ParryMesh> {
        match &self.shape {
            Shape::Mesh(m) => Some(m.whole.get_or_init(|| {
                let mut whole = ParryMesh::new(m.rest.clone(), m.indices.clone())
                    .expect("the triangles were accepted by parry when the collider was built");
                whole.set_vertices(&m.live);
                whole
            })),
            _ => None,
        }
    }

    /// How much of a mesh collider's BVH has been refitted since it was built (zero for
    /// primitives, which are never refitted).
    ///
    /// A mesh of more than 1,024 triangles holds its BVH in parts (subtrees of at most that
    /// many triangles): [`set_vertices`](Self::set_vertices) recomputes the boxes above them
    /// and refits the parts queries reached since the last move; every other part is refitted
    /// when a query first reaches it, so a skin that touches a small region of a large
    /// deforming mesh refits only that region. These counts show how much that was.
    ///
    /// ```
    /// use dermis::collision::ColliderMesh;
    /// use glam::Vec3;
    /// let v = vec![Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::Z];
    /// let t = vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]];
    /// let mut tet = ColliderMesh::from_mesh(v.clone(), t).unwrap();
    /// let moved: Vec<Vec3> = v.iter().map(|p| *p * 1.1).collect();
    /// tet.set_vertices(&moved).unwrap();
    /// // A small mesh is one part, refitted by `set_vertices` itself.
    /// assert_eq!(tet.refit_stats().parts_refitted, 1);
    /// assert_eq!(tet.part_count(), 1);
    /// ```
    pub fn refit_stats(&self) -> RefitStats {
        match &self.shape {
            Shape::Mesh(m) => {
                let (parts_refitted, nanos) = m.parts.refits();
                RefitStats {
                    parts_refitted,
                    seconds: nanos as f64 * 1e-9,
                }
            }
            _ => RefitStats::default(),
        }
    }

    /// Refits every part of a mesh collider's BVH that waits for its refit, now, in parallel
    /// (rayon), instead of when queries first reach them (see
    /// [`refit_stats`](Self::refit_stats)): for a caller that wants the whole cost up front,
    /// say to time queries alone. Answers are the same either way. Nothing for primitives.
    pub fn refit_all(&self) {
        if let Shape::Mesh(m) = &self.shape {
            m.parts.refit_all(&m.live);
        }
    }

    /// The number of parts a mesh collider's BVH is held in (see
    /// [`refit_stats`](Self::refit_stats)); 0 for primitives.
    pub fn part_count(&self) -> usize {
        match &self.shape {
            Shape::Mesh(m) => m.parts.count(),
            _ => 0,
        }
    }

    pub(crate) fn travel_m(&self) -> f64 {
        self.travel_m
    }

    /// Identifies this collider's construction (see the field).
    pub(crate) fn uid(&self) -> u64 {
        self.uid
    }

    pub(crate) fn local_aabb(&self) -> &Aabb {
        &self.local_aabb
    }

    /// The pose at the end of the previous frame.
    pub(crate) fn prev_pose(&self) -> Pose {
        self.prev_pose
    }

    /// Largest rest-frame vertex displacement of a deforming mesh since the previous frame, m
    /// (0 for rigid colliders).
    pub(crate) fn frame_deform_m(&self) -> f32 {
        match &self.shape {
            Shape::Mesh(m) => m.deform_m,
            _ => 0.0,
        }
    }

    /// Bound on how far any surface point moved since the previous frame, m.
    pub(crate) fn frame_motion_m(&self) -> f32 {
        self.frame_deform_m() + self.frame_pose_motion_m()
    }

    /// Bound on how far the pose change since the previous frame moved any surface point, m.
    pub(crate) fn frame_pose_motion_m(&self) -> f32 {
        pose_motion(&self.local_aabb, &self.prev_pose, &self.pose)
    }

    /// Puts the collider in the state a fraction `s` of the way from the previous frame to the
    /// current one (`s == 1`: exactly the current state); with `shape == false` a deforming
    /// mesh keeps its current shape (only the pose is interpolated).
    pub(crate) fn enter_substep(&mut self, s: f32, current_pose: &Pose, shape: bool) {
        let pose = if s >= 1.0 {
            *current_pose
        } else {
            self.prev_pose.lerp(current_pose, s)
        };
        self.travel_m += pose_motion(&self.local_aabb, &self.pose, &pose) as f64;
        self.pose = pose;
        if let Shape::Mesh(m) = &mut self.shape
            && shape
            && m.prev != m.current
        {
            let (prev, current) = (&m.prev, &m.current);
            let at = |g: usize| {
                if s >= 1.0 {
                    current[g]
                } else {
                    prev[g].lerp(current[g], s)
                }
            };
            let moved_sq = move_to(&mut m.live, (0..prev.len()).map(at));
            m.parts.move_to(&m.live);
            m.whole = OnceLock::new();
            self.travel_m += moved_sq.sqrt() as f64;
            self.local_aabb = m.parts.local_aabb();
        }
    }

    /// The current state becomes the previous frame's.
    pub(crate) fn commit_frame(&mut self) {
        self.prev_pose = self.pose;
        if let Shape::Mesh(m) = &mut self.shape {
            m.prev.copy_from_slice(&m.current);
            m.deform_m = 0.0;
        }
    }

    /// Projects a world point on the surface (no cache; the reference answer). The result is in
    /// world coordinates.
    pub fn project_point(&self, p: Vec3) -> SurfaceProjection {
        let mut r = self.project_local(self.pose.inverse_transform_point(p), NONE);
        r.point = self.pose.transform_point(r.point);
        r.normal = self.pose.transform_vector(r.normal);
        r
    }

    /// Projects a rest-frame point, testing triangle `hint` first: its distance bounds the BVH
    /// search, so the answer is the same as without a hint.
    pub(crate) fn project_local(&self, p: Vec3, hint: u32) -> SurfaceProjection {
        match &self.shape {
            Shape::Mesh(m) => m.project(p, hint),
            Shape::Capsule { a, b, radius } => {
                let ab = *b - *a;
                let len2 = ab.length_squared();
                let t = if len2 > 0.0 {
                    ((p - *a).dot(ab) / len2).clamp(0.0, 1.0)
                } else {
                    0.0
                };
                round_projection(p, *a + ab * t, *radius, ab)
            }
            Shape::Ball { radius } => round_projection(p, Vec3::ZERO, *radius, Vec3::X),
        }
    }

    /// The signed distance from rest-frame point `p` to the surface, as
    /// [`project_local`](Self::project_local) gives it, except that a point outside the
    /// collider's box and at least `cap` from the surface may get `cap` instead: the search of a
    /// mesh stops at `cap`, so far points cost a few box tests instead of a full search.
    pub(crate) fn distance_local_capped(&self, p: Vec3, cap: f32) -> f32 {
        match &self.shape {
            // Outside the box the point is outside the (closed) surface: the distance is the
            // unsigned one, and a search bounded by `cap` finds it if it is below.
            Shape::Mesh(m) if !self.local_aabb.contains_local_point(p) => m
                .search(p, cap)
                .map_or(cap, |(_, proj, _)| p.distance(proj.point)),
            _ => self.project_local(p, NONE).signed_distance,
        }
    }

    /// Projects a rest-frame point with the help of a vertex's `patch` (see [`Patch`]): from
    /// the patch alone while its certificate holds (`slack_m`: a bound on how far the point
    /// and the surface moved in total since it was built), else by an exact search around
    /// `hint` that rebuilds the patch with triangles up to `margin_m` farther than the nearest
    /// (`None`: a plain search, and no patch). Returns the projection and whether the patch answered; the
    /// projection is the exact one either way. Primitives need no patch.
    pub(crate) fn project_patched(
        &self,
        p: Vec3,
        hint: u32,
        patch: &mut Patch,
        slack_m: Option<f32>,
        margin_m: Option<f32>,
    ) -> (SurfaceProjection, bool) {
        match &self.shape {
            Shape::Mesh(m) => {
                if let Some(slack) = slack_m
                    && patch.len > 0
                    && let Some(r) = m.project_on_patch(p, patch, slack)
                {
                    return (r, true);
                }
                match margin_m {
                    Some(margin) => (m.project_and_certify(p, hint, margin, patch), false),
                    None => {
                        patch.clear();
                        (m.project(p, hint), false)
                    }
                }
            }
            _ => (self.project_local(p, hint), false),
        }
    }

    /// The [`Prism`] of the rest-frame point `p` over face `t` of this mesh, from the patch
    /// that just certified `t` as its closest triangle (`slack`: that certificate's, see
    /// `Patch::slack`); `allowance`: the corner tests' `τ`, the clearance from the face's
    /// edges a hold needs, and the distances' rounding `δ` (see `hold_of` in the collision
    /// module). `None` for a primitive, a degenerate face, or a point too near an edge.
    pub(crate) fn face_prism(
        &self,
        p: Vec3,
        t: u32,
        patch: &Patch,
        slack: f32,
        allowance: (f32, f32, f32),
    ) -> Option<Prism> {
        match &self.shape {
            Shape::Mesh(m) => m.face_prism(p, t, patch, slack, allowance),
            _ => None,
        }
    }

    /// The current rest-frame position of a surface point given by `part` and `coords` (see
    /// [`SurfaceProjection`]).
    pub(crate) fn local_surface_point(&self, part: u32, coords: Vec3) -> Vec3 {
        match &self.shape {
            Shape::Mesh(m) => {
                let [a, b, c] = m.corners(part);
                a * coords.x + b * coords.y + c * coords.z
            }
            _ => coords,
        }
    }

    /// First crossing of the rest-frame segment `from → from + delta` into the solid, as the
    /// entry point and the outward unit normal there.
    pub(crate) fn cast_local_segment(&self, from: Vec3, delta: Vec3) -> Option<(Vec3, Vec3)> {
        let ray = Ray::new(from, delta);
        let hit = match &self.shape {
            Shape::Mesh(m) => m.cast_ray(&ray, 1.0),
            Shape::Capsule { a, b, radius } => {
                Capsule::new(*a, *b, *radius).cast_local_ray_and_get_normal(&ray, 1.0, true)
            }
            Shape::Ball { radius } => {
                Ball::new(*radius).cast_local_ray_and_get_normal(&ray, 1.0, true)
            }
        }?;
        if hit.time_of_impact <= 0.0 {
            return None; // Started inside: not a crossing, the projection handles it.
        }
        let mut n = hit.normal.normalize_or_zero();
        if n.dot(delta) > 0.0 {
            n = -n;
        }
        Some((ray.point_at(hit.time_of_impact), n))
    }
}

/// How far a point above a mesh face may move and keep that face its closest triangle by a
/// margin, from where the face lies among its patch's other triangles (see `hold_of` in the
/// collision module): each triangle of the patch is either *beyond* one of the face's edges
/// (its corners on the far side of that edge's line, seen along the face's normal, and none
/// above the face's plane: a convex neighbour across an edge or most of those around a
/// corner) or among the *rest*.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Prism {
    /// The point's distance to the nearest of the face's edge lines, in the face's plane, less
    /// what keeps the triangles beyond an edge farther than the face, m.
    pub inside: f32,
    /// How much farther than the face the rest of the triangles are, the ones outside the
    /// patch included (by its gap), at least, m; those too far to matter (over
    /// `2 inside + δ`) left out.
    pub rest: f32,
}

impl MeshShape {
    /// See [`ColliderMesh::face_prism`].
    fn face_prism(
        &self,
        p: Vec3,
        t: u32,
        patch: &Patch,
        slack: f32,
        (tau, need, delta): (f32, f32, f32),
    ) -> Option<Prism> {
        let [a, b, c] = self.corners(t);
        let n = self.face_normal(t);
        // Each edge's point and its outward normal in the face's plane.
        let mut edges = [(Vec3::ZERO, Vec3::ZERO); 3];
        for (e, (p0, p1, other)) in edges.iter_mut().zip([(a, b, c), (b, c, a), (c, a, b)]) {
            let m = (p1 - p0).cross(n).normalize_or_zero();
            *e = (p0, if m.dot(other - p0) > 0.0 { -m } else { m });
        }
        if n == Vec3::ZERO || edges.iter().any(|e| e.1 == Vec3::ZERO) {
            return None;
        }
        let inside = edges
            .iter()
            .map(|&(p0, m)| -m.dot(p - p0))
            .fold(f32::INFINITY, f32::min)
            - need;
        // Most vertices the skin presses onto a mesh sit near an edge: no prism (a NaN too).
        if inside.is_nan() || inside <= 0.0 {
            return None;
        }
        let own = self.triangle_distance(t, p);
        let mut rest = patch.gap - slack - own;
        // A triangle whose bound alone keeps it this much farther than the face cannot make the
        // radius shorter than `inside` (`hold_of` takes half of `rest − δ`): left out.
        let enough = 2.0 * inside + delta;
        for (&u, &dist) in patch.tris.iter().zip(&patch.dist).take(patch.len as usize) {
            if u == t || dist - slack - own >= enough {
                continue;
            }
            let corners = self.corners(u);
            let below = corners.iter().all(|&q| n.dot(q - a) <= tau);
            let beyond = below
                && edges
                    .iter()
                    .any(|&(p0, m)| corners.iter().all(|&q| m.dot(q - p0) >= -tau));
            if !beyond {
                rest = rest.min(self.triangle_distance(u, p) - own);
            }
        }
        Some(Prism { inside, rest })
    }

    /// The corners of triangle `t` now.
    #[inline]
    fn corners(&self, t: u32) -> [Vec3; 3] {
        self.indices[t as usize].map(|i| self.live[i as usize])
    }

    /// Triangle `t` now, as parry's mesh gives it.
    #[inline]
    fn triangle(&self, t: u32) -> Triangle {
        let [a, b, c] = self.corners(t);
        Triangle::new(a, b, c)
    }

    /// parry's closest-point search of the whole mesh (`CompositeShapeRef::
    /// project_local_point_and_get_location`, non-solid), limited to `max_dist`; the triangle
    /// is a mesh triangle id.
    fn search(
        &self,
        p: Vec3,
        max_dist: f32,
    ) -> Option<(u32, parry3d::query::PointProjection, TrianglePointLocation)> {
        self.parts
            .find_best(
                max_dist,
                |aabb, _| aabb.distance_to_local_point(p, true),
                |part, bound| {
                    CompositeShapeRef(self.part_mesh(part))
                        .project_local_point_and_get_location(p, bound, false)
                        .map(|(t, proj, location)| {
                            ((proj.point - p).length(), (part.global(t), proj, location))
                        })
                },
            )
            .map(|(_, found)| found)
    }

    /// Part `part`'s parry mesh for a search entering it, fitted to the live vertices (see
    /// [`parts::Part::mesh`]).
    #[inline]
    fn part_mesh<'a>(&'a self, part: &'a parts::Part) -> &'a ParryMesh {
        part.mesh(&self.live, self.parts.refit_counter())
    }

    /// The closest triangle to `p` by parry's search of the whole mesh
    /// (`CompositeShapeRef::project_local_point`, non-solid).
    fn search_point(&self, p: Vec3) -> Option<u32> {
        self.parts
            .find_best(
                f32::MAX,
                |aabb, _| aabb.distance_to_local_point(p, true),
                |part, bound| {
                    CompositeShapeRef(self.part_mesh(part))
                        .project_local_point(p, bound, false)
                        .map(|(t, proj)| ((proj.point - p).length(), part.global(t)))
                },
            )
            .map(|(_, t)| t)
    }

    /// The first hit of `ray` within `max_toi` on the (hollow) mesh, as parry's
    /// `TriMesh::cast_local_ray_and_get_normal` finds it.
    fn cast_ray(&self, ray: &Ray, max_toi: f32) -> Option<parry3d::query::RayIntersection> {
        self.parts
            .find_best(
                max_toi,
                |aabb, best| aabb.cast_local_ray(ray, best, true).unwrap_or(f32::MAX),
                |part, best| {
                    CompositeShapeRef(self.part_mesh(part))
                        .cast_local_ray_and_get_normal(ray, best, false)
                        .map(|(t, hit)| (hit.time_of_impact, hit.with_subshape(part.global(t))))
                },
            )
            .map(|(_, hit)| hit)
    }

    fn face_normal(&self, t: u32) -> Vec3 {
        let [a, b, c] = self.corners(t);
        (b - a).cross(c - a).normalize_or_zero()
    }

    fn vertex_normal(&self, vertex: u32) -> Vec3 {
        let v = &self.live;
        let range = self.vt_offsets[vertex as usize] as usize
            ..self.vt_offsets[vertex as usize + 1] as usize;
        let mut sum = Vec3::ZERO;
        for &t in &self.vt[range] {
            let idx = self.indices[t as usize];
            let k = idx.iter().position(|&i| i == vertex).unwrap_or(0);
            let p = v[idx[k] as usize];
            let e1 = (v[idx[(k + 1) % 3] as usize] - p).normalize_or_zero();
            let e2 = (v[idx[(k + 2) % 3] as usize] - p).normalize_or_zero();
            let angle = e1.dot(e2).clamp(-1.0, 1.0).acos();
            sum += self.face_normal(t) * angle;
        }
        sum.normalize_or_zero()
    }

    /// The projection of `p` on triangle `t` exactly as parry's BVH search computes it for a
    /// leaf, with its distance (the search's cost).
    #[inline]
    fn triangle_projection(
        &self,
        t: u32,
        p: Vec3,
    ) -> (f32, parry3d::query::PointProjection, TrianglePointLocation) {
        use parry3d::query::PointQueryWithLocation;
        let (proj, location) = self
            .triangle(t)
            .project_local_point_and_get_location(p, false);
        ((proj.point - p).length(), proj, location)
    }

    fn project(&self, p: Vec3, hint: u32) -> SurfaceProjection {
        let mut bound = f32::MAX;
        if hint != NONE && (hint as usize) < self.indices.len() {
            let (d, _, _) = self.triangle_projection(hint, p);
            // Strictly above the hint's own distance: the hint (or a closer triangle) is found.
            bound = d * (1.0 + 1e-5) + f32::MIN_POSITIVE;
        }
        let found = self.search(p, bound).or_else(|| self.search(p, f32::MAX));
        let Some((t, proj, location)) = found else {
            // Only for non-finite input.
            return SurfaceProjection {
                point: p,
                normal: Vec3::Z,
                signed_distance: 0.0,
                part: 0,
                coords: Vec3::new(1.0, 0.0, 0.0),
            };
        };
        self.finish(p, t, proj.point, location)
    }

    /// The oriented projection of `p` once its closest triangle `t` is known.
    fn finish(
        &self,
        p: Vec3,
        t: u32,
        point: Vec3,
        location: TrianglePointLocation,
    ) -> SurfaceProjection {
        let idx = self.indices[t as usize];
        let on_face = matches!(location, TrianglePointLocation::OnFace(..));
        let feature_normal = match location {
            TrianglePointLocation::OnEdge(i, _) => {
                let other = self.across[t as usize][i as usize];
                (self.face_normal(t) + self.face_normal(other)).normalize_or_zero()
            }
            TrianglePointLocation::OnVertex(i) => self.vertex_normal(idx[i as usize]),
            _ => self.face_normal(t),
        };
        let coords = location
            .barycentric_coordinates()
            .map_or(Vec3::splat(1.0 / 3.0), Vec3::from_array);
        // Off a face's edges the closest point's direction is the face normal itself: taken
        // as is, not from the rounded difference `p − point` (a nonzero normal: the triangle
        // is not degenerate).
        let exact = on_face && feature_normal != Vec3::ZERO;
        oriented(p, point, feature_normal, exact, t, coords)
    }

    /// Distance from `p` to triangle `t` (lean closest-point arithmetic, without parry's
    /// robustness checks; equal to parry's distance up to rounding).
    #[inline]
    fn triangle_distance(&self, t: u32, p: Vec3) -> f32 {
        let [a, b, c] = self.corners(t);
        triangle_distance_sq(p, a, b, c).sqrt()
    }

    /// Among `candidates` (lean distance, triangle), those within rounding of the smallest lean
    /// distance are ranked by parry's own distance, as parry's search ranks them: the answer
    /// is the triangle parry would pick, not one that lean rounding happened to favour.
    fn parry_choice(
        &self,
        p: Vec3,
        candidates: impl Iterator<Item = (f32, u32)> + Clone,
    ) -> Option<(u32, Vec3, TrianglePointLocation)> {
        let lean_min = candidates
            .clone()
            .map(|c| c.0)
            .fold(f32::INFINITY, f32::min);
        let eps = TIE_ROUNDING * (p.abs().max_element() + lean_min);
        let mut best: Option<(f32, u32, Vec3, TrianglePointLocation)> = None;
        for (d, t) in candidates {
            if d <= lean_min + eps {
                let (dp, proj, location) = self.triangle_projection(t, p);
                if best.as_ref().is_none_or(|b| dp < b.0) {
                    best = Some((dp, t, proj.point, location));
                }
            }
        }
        best.map(|(_, t, point, location)| (t, point, location))
    }

    /// An exact projection that also fills `patch` with the [`PATCH`] triangles nearest to `p`
    /// and a lower bound of the distance from `p` to every other triangle (see [`Patch`]).
    /// Triangles farther than the hint's distance plus `margin_m` are not collected.
    fn project_and_certify(
        &self,
        p: Vec3,
        hint: u32,
        margin_m: f32,
        patch: &mut Patch,
    ) -> SurfaceProjection {
        patch.clear();
        let triangles = self.indices.len();
        let hint = if hint != NONE && (hint as usize) < triangles {
            hint
        } else {
            // No usable hint: one plain search finds the nearest triangle first.
            match self.search_point(p) {
                Some(t) => t,
                None => return self.project(p, NONE),
            }
        };
        // Best-first search for the PATCH + 1 nearest triangles: each leaf reports the
        // distance of the (PATCH + 1)-th nearest seen so far, which prunes every box farther.
        let bound = self.triangle_distance(hint, p) + margin_m.max(0.0);
        if !bound.is_finite() {
            return self.project(p, hint);
        }
        let near = std::cell::RefCell::new(([(f32::INFINITY, NONE); PATCH + 1], 0usize));
        let node_cost = |aabb: &Aabb, _| aabb.distance_to_local_point(p, true);
        let leaf_cost = |t: u32| {
            let d = self.triangle_distance(t, p);
            let mut guard = near.borrow_mut();
            let (list, len) = &mut *guard;
            if d < bound {
                // Sorted insertion, keeping the first of equal distances first.
                let mut i = (*len).min(PATCH);
                if i < PATCH || d < list[PATCH].0 {
                    while i > 0 && list[i - 1].0 > d {
                        list[i] = list[i - 1];
                        i -= 1;
                    }
                    list[i] = (d, t);
                    *len = (*len + 1).min(PATCH + 1);
                }
            }
            if *len == PATCH + 1 {
                list[PATCH].0
            } else {
                bound
            }
        };
        // parry's best-first search over the whole mesh, part by part (see `parts`).
        let _ = self.parts.find_best(bound, node_cost, |part, best| {
            self.part_mesh(part)
                .bvh()
                .find_best(
                    best,
                    |node, _| node_cost(&node.aabb(), 0.0),
                    |t, _| Some(leaf_cost(part.global(t))),
                )
                .map(|(_, cost)| (cost, ()))
        });
        let (list, len) = near.into_inner();
        if len == 0 {
            return self.project(p, hint);
        }
        let kept = len.min(PATCH);
        for (k, &(d, t)) in list[..kept].iter().enumerate() {
            patch.tris[k] = t;
            patch.dist[k] = d;
        }
        patch.len = kept as u8;
        patch.best = 0;
        // Every triangle not kept is at least as far as the last one listed, or was pruned
        // (farther than the bound in force, which only fell).
        patch.gap = if len == PATCH + 1 {
            list[PATCH].0
        } else {
            bound
        };
        let Some((t, point, location)) = self.parry_choice(p, list[..kept].iter().copied()) else {
            return self.project(p, hint);
        };
        patch.best = list[..kept].iter().position(|c| c.1 == t).unwrap_or(0) as u8;
        self.finish(p, t, point, location)
    }

    /// The exact projection from the patch alone, when its certificate still holds for a
    /// point and surface that moved at most `slack_m` in total since it was built; `None`
    /// otherwise.
    fn project_on_patch(
        &self,
        p: Vec3,
        patch: &mut Patch,
        slack_m: f32,
    ) -> Option<SurfaceProjection> {
        self.project_on_patch_with(p, patch, slack_m, lean::available())
    }

    /// [`project_on_patch`](Self::project_on_patch), with the lean distances eight at a time
    /// when `wide` (and AVX2 is there), else one at a time: the same answer either way.
    #[inline]
    fn project_on_patch_with(
        &self,
        p: Vec3,
        patch: &mut Patch,
        slack_m: f32,
        wide: bool,
    ) -> Option<SurfaceProjection> {
        let len = patch.len as usize;
        // Lean distances of the patch at `p`, each evaluated at most once (NaN: not yet; the
        // ones never evaluated are farther than the answer). With AVX2 they come eight at a
        // time, the same values bit for bit ([`lean`]), so every decision below is the same.
        let mut lean = [f32::NAN; PATCH];
        let mut batches = Batches::new(self, &*patch, p, wide);
        // The last answer first: often it alone is provably the closest.
        let b = patch.best as usize;
        lean[b] = batches.get(b);
        let mut best = (lean[b], b);
        let others = if b == 0 {
            patch.dist.get(1).copied().filter(|_| len > 1)
        } else {
            Some(patch.dist[0])
        }
        .unwrap_or(f32::INFINITY);
        // Entries past `evaluated` (other than `b`) are never evaluated.
        let mut evaluated = 0;
        if best.0 >= others - slack_m {
            evaluated = len;
            for (k, l) in lean.iter_mut().enumerate().take(len) {
                // Sorted by their distance when built: no later triangle can come closer.
                if patch.dist[k] - slack_m > best.0 {
                    evaluated = k;
                    break;
                }
                if k == b {
                    continue;
                }
                *l = batches.get(k);
                if *l < best.0 {
                    best = (*l, k);
                }
            }
        }
        // Every triangle outside the patch is at least `gap − slack` away now (a NaN fails).
        let certified = best.0 < patch.gap - slack_m;
        if !certified {
            return None;
        }
        // The ties within rounding of the answer need their lean distance: those whose bound
        // is within `reach`, a prefix of the patch (sorted by bound). The others, unevaluated
        // (NaN), are farther than `reach` and never candidates below, as if infinitely far;
        // nor are the evaluated ones past the prefix that `parry_choice` skips (`hi`): every
        // entry from `hi` on is NaN.
        let reach = best.0 + TIE_ROUNDING * (p.abs().max_element() + best.0);
        let mut within = 0;
        while within < len && patch.dist[within] - slack_m <= reach {
            if lean[within].is_nan() {
                lean[within] = batches.get(within);
            }
            within += 1;
        }
        let hi = within.max(evaluated).max(b + 1);
        let (t, point, location) =
            self.parry_choice(p, (0..hi).map(|k| (lean[k], patch.tris[k])))?;
        let kt = (0..len).position(|k| patch.tris[k] == t).unwrap_or(0);
        // How much farther every other triangle is (its lean distance where computed, its
        // bound otherwise; the rest of the mesh by the gap), before any rounding allowance
        // (see `hold_of`).
        let second = (0..len)
            .filter(|&k| k != kt)
            .map(|k| {
                if lean[k].is_nan() {
                    batches.known(k).unwrap_or(patch.dist[k] - slack_m)
                } else {
                    lean[k]
                }
            })
            .fold(patch.gap - slack_m, f32::min);
        let margin = second - lean[kt];
        patch.best = kt as u8;
        patch.margin = if margin > 0.0 { margin } else { 0.0 };
        Some(self.finish(p, t, point, location))
    }
}

/// The lean distances of a patch's triangles at one point, computed on first use: eight at a
/// time with AVX2 ([`lean::distances`]), else one at a time. Either way each is
/// [`MeshShape::triangle_distance`] bit for bit.
struct Batches<'a> {
    mesh: &'a MeshShape,
    patch: &'a Patch,
    p: Vec3,
    /// Whether the eight-lane path is available.
    wide: bool,
    /// Bit `i` set: batch `i` (triangles `LANES i ..`) is in `values`.
    done: u8,
    values: [f32; PATCH.next_multiple_of(lean::LANES)],
}

impl<'a> Batches<'a> {
    /// `wide`: use the eight-lane path where the CPU has it.
    #[inline]
    fn new(mesh: &'a MeshShape, patch: &'a Patch, p: Vec3, wide: bool) -> Self {
        Self {
            mesh,
            patch,
            p,
            wide,
            done: 0,
            values: [f32::NAN; PATCH.next_multiple_of(lean::LANES)],
        }
    }

    /// The lean distance to the patch's triangle `k` (`k < len`).
    #[inline(always)]
    fn get(&mut self, k: usize) -> f32 {
        if self.done >> (k / lean::LANES) & 1 == 0 {
            return self.fill(k);
        }
        self.values[k]
    }

    /// The lean distance to the patch's triangle `k` if its batch was computed.
    #[inline]
    fn known(&self, k: usize) -> Option<f32> {
        (self.done >> (k / lean::LANES) & 1 == 1).then(|| self.values[k])
    }

    /// Computes the batch holding triangle `k` (or `k` alone without the wide path) and
    /// returns its distance.
    #[inline(never)]
    fn fill(&mut self, k: usize) -> f32 {
        let (tris, len) = (&self.patch.tris, self.patch.len as usize);
        if self.wide {
            let batch = k / lean::LANES;
            let start = batch * lean::LANES;
            // Lanes past the patch hold stale or missing triangles: their values are never
            // read, and they may be out of range (reported in `bad`).
            let mut lanes = [tris[k]; lean::LANES];
            if start + lean::LANES <= PATCH {
                lanes = tris[start..start + lean::LANES]
                    .try_into()
                    .expect("a whole batch");
            } else {
                for (l, &t) in lanes.iter_mut().zip(&tris[start..]) {
                    *l = t;
                }
            }
            let used = (len - start).min(lean::LANES);
            if let Some((d, bad)) =
                lean::distances(&self.mesh.indices, &self.mesh.live, &lanes, self.p)
                && bad & ((1 << used) - 1) == 0
            {
                let values: &mut [f32; lean::LANES] = (&mut self.values
                    [start..start + lean::LANES])
                    .try_into()
                    .expect("whole batches");
                *values = d;
                self.done |= 1 << batch;
                return d[k - start];
            }
            // An index out of range: the scalar path (which reports it).
            self.wide = false;
        }
        self.mesh.triangle_distance(tris[k], self.p)
    }
}

/// Lean and parry distances agree to well within this, relative to the coordinates' magnitude.
const TIE_ROUNDING: f32 = 1e-5;

/// Squared distance from `p` to triangle `abc` (Ericson, Real-Time Collision Detection, 5.1.5).
#[inline]
fn triangle_distance_sq(p: Vec3, a: Vec3, b: Vec3, c: Vec3) -> f32 {
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(ap), ac.dot(ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return ap.length_squared();
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(bp), ac.dot(bp));
    if d3 >= 0.0 && d4 <= d3 {
        return bp.length_squared();
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        let v = d1 / (d1 - d3);
        return (ap - ab * v).length_squared();
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(cp), ac.dot(cp));
    if d6 >= 0.0 && d5 <= d6 {
        return cp.length_squared();
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let w = d2 / (d2 - d6);
        return (ap - ac * w).length_squared();
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && d4 - d3 >= 0.0 && d5 - d6 >= 0.0 {
        let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return (bp - (c - b) * w).length_squared();
    }
    let denom = 1.0 / (va + vb + vc);
    (ap - ab * (vb * denom) - ac * (vc * denom)).length_squared()
}

/// Signed distance and push direction from the feature normal; `exact`: the point projects
/// inside a face, whose (outward, unit) normal is then the push direction, inside or out.
fn oriented(
    p: Vec3,
    point: Vec3,
    feature_normal: Vec3,
    exact: bool,
    part: u32,
    coords: Vec3,
) -> SurfaceProjection {
    let d = p - point;
    let dist = d.length();
    let inside = d.dot(feature_normal) < 0.0;
    let normal = if exact {
        feature_normal
    } else if dist > 1e-12 {
        if inside { -d / dist } else { d / dist }
    } else {
        feature_normal
    };
    SurfaceProjection {
        point,
        normal,
        signed_distance: if inside { -dist } else { dist },
        part,
        coords,
    }
}

fn round_projection(p: Vec3, centre: Vec3, radius: f32, axis: Vec3) -> SurfaceProjection {
    let v = p - centre;
    let len = v.length();
    let n = if len > 1e-12 {
        v / len
    } else {
        axis.any_orthonormal_vector()
    };
    let point = centre + n * radius;
    SurfaceProjection {
        point,
        normal: n,
        signed_distance: len - radius,
        part: 0,
        coords: point,
    }
}

/// Local edge index (parry's: 0 AB, 1 BC, 2 AC) of edge {a, b} in `tri`, and whether `tri`
/// runs it a → b.
fn directed_edge(tri: [u32; 3], a: u32, b: u32) -> (usize, bool) {
    for (local, (i, j)) in [(0usize, 1usize), (1, 2), (0, 2)].into_iter().enumerate() {
        let (u, v) = (tri[i], tri[j]);
        if (u, v) == (a, b) || (u, v) == (b, a) {
            // Winding order of the pair within the triangle: (0,1), (1,2) forward, (0,2) backward.
            let forward = if local == 2 { v == a } else { u == a };
            return (local, forward);
        }
    }
    (0, false)
}

/// Largest squared distance between matching points of `a` and `b`, in eight running maxima
/// (one chain of dependent comparisons would wait on each), m². The maximum of the same
/// distances whatever their order.
fn max_distance_sq(a: &[Vec3], b: &[Vec3]) -> f32 {
    let (a8, b8) = (a.chunks_exact(8), b.chunks_exact(8));
    let mut lanes = [0.0f32; 8];
    for (a, b) in a8.remainder().iter().zip(b8.remainder()) {
        lanes[0] = lanes[0].max(a.distance_squared(*b));
    }
    for (a, b) in a8.zip(b8) {
        for (k, lane) in lanes.iter_mut().enumerate() {
            *lane = lane.max(a[k].distance_squared(b[k]));
        }
    }
    lanes.into_iter().fold(0.0, f32::max)
}

/// Moves `live` to `target`, returning the largest squared displacement, m² (a maximum: the
/// same in any order of chunks).
fn move_to(live: &mut [Vec3], target: impl Iterator<Item = Vec3>) -> f32 {
    let mut moved_sq = 0.0f32;
    for (l, t) in live.iter_mut().zip(target) {
        moved_sq = moved_sq.max(l.distance_squared(t));
        *l = t;
    }
    moved_sq
}

/// Bound on the displacement of any point of `aabb` (rest frame) between two poses: the largest
/// corner displacement (the displacement is affine in the point, its length convex).
fn pose_motion(aabb: &Aabb, from: &Pose, to: &Pose) -> f32 {
    if from == to {
        return 0.0;
    }
    let (lo, hi) = (aabb.mins, aabb.maxs);
    let mut m = 0.0f32;
    for k in 0..8 {
        let c = Vec3::new(
            if k & 1 == 0 { lo.x } else { hi.x },
            if k & 2 == 0 { lo.y } else { hi.y },
            if k & 4 == 0 { lo.z } else { hi.z },
        );
        m = m.max(from.transform_point(c).distance(to.transform_point(c)));
    }
    // Rounding of the transforms.
    m * (1.0 + 1e-5) + 1e-7 * (lo.abs().max(hi.abs()).max_element() + to.translation.length())
}
