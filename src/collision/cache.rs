//! Per vertex and collider contact cache: distance bounds that skip queries, and patch certificates that answer exact queries from a few triangles.
//!
//! A query at a reference point `p₀` (collider travel `T₀`) keeps the [`PATCH`] triangles
//! nearest to `p₀`, their distances `dᵢ`, and a lower bound `G` of the distance from `p₀` to
//! every other triangle. Distances to triangles are 1-Lipschitz in the point and in the
//! triangle's vertices, so after the point moved by `δ` and the surface by at most `τ` (the
//! collider's travel since `T₀`), with `σ = δ + τ`, triangle `i` is at least `dᵢ − σ` away and
//! every triangle outside the patch at least `G − σ`. Projecting the point on the patch
//! triangles (in order of `dᵢ`, stopping when `dᵢ − σ` exceeds the best found) gives the
//! closest triangle of the whole mesh whenever the best distance is below `G − σ`: the answer
//! of the full BVH search, at the cost of one or two triangle projections. Otherwise the BVH is
//! searched again and the patch rebuilt around the new point.

use glam::Vec3;

use super::collider::{ColliderMesh, NONE, SurfaceProjection};

/// Triangles kept per patch: more widen the gap `G − d` (fewer BVH searches per frame) but cost
/// 8 bytes each per vertex and collider; 12 halved the searches of 6 in the collision bench.
pub(crate) const PATCH: usize = 12;

/// Rounding allowance of a triangle distance relative to the coordinates' magnitude: f32
/// distances carry errors of a few ulps (~1e-7 relative); the allowance is a hundred times that.
const ROUNDING: f32 = 1e-5;

/// The triangles nearest a reference point and a bound on all the others (see the module
/// documentation). `len == 0`: no certificate.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Patch {
    /// Nearest triangles at `at`, by increasing distance.
    pub(crate) tris: [u32; PATCH],
    /// Their distances at `at`, m.
    pub(crate) dist: [f32; PATCH],
    /// Lower bound of the distance at `at` to every triangle not in `tris`, m.
    pub(crate) gap: f32,
    /// Triangles in use.
    pub(crate) len: u8,
    /// Index in `tris` of the last answer.
    pub(crate) best: u8,
    /// Reference point, collider rest frame.
    at: Vec3,
    /// The collider's travel when the patch was built, m.
    travel_at: f64,
    /// After a certified answer: how much farther than the answer's triangle every other
    /// triangle was at the query point, less the rounding of both distances, m (0: unknown).
    pub(crate) margin: f32,
}

const _: () = assert!(size_of::<Patch>() == 128);

impl Patch {
    pub(crate) const NEW: Self = Self {
        tris: [NONE; PATCH],
        dist: [0.0; PATCH],
        gap: 0.0,
        len: 0,
        best: 0,
        at: Vec3::ZERO,
        travel_at: 0.0,
        margin: 0.0,
    };

    pub(crate) fn clear(&mut self) {
        self.len = 0;
        self.margin = 0.0;
    }

    /// Bound on how far the point `p` (rest frame) and the surface moved since the patch was
    /// built, plus the rounding allowance of the distances compared against it; `None`
    /// without a patch.
    #[inline]
    pub(crate) fn slack(&self, p: Vec3, travel: f64) -> Option<f32> {
        if self.len == 0 {
            return None;
        }
        let moved = p.distance(self.at) as f64 + (travel - self.travel_at);
        let scale = p.abs().max_element() + self.at.abs().max_element() + self.gap.abs();
        Some((moved * (1.0 + 1e-6)) as f32 + ROUNDING * scale + f32::MIN_POSITIVE)
    }
}

/// Per vertex and collider: the closest-feature cache and a distance bound, 32 bytes (two per
/// cache line), with its patch certificate kept apart (a [`Patch`] at the same index of a
/// parallel array: 128 bytes read only when the vertex is near the collider). The frame plan
/// and every pass read the bound of each vertex they do not skip whole; with the patch inline
/// (a 160-byte slot) each bound cost a cache line of its own, and the plan stalled on them.
#[derive(Debug, Clone, Copy)]
#[repr(C, align(32))]
pub(crate) struct Slot {
    /// Triangle found last time ([`NONE`]: none).
    pub(crate) part: u32,
    /// Lower bound of the signed distance at `p_ref` when the collider had travelled
    /// `travel_at`, m.
    pub(crate) clearance: f32,
    travel_at: f64,
    p_ref: Vec3,
}

/// What one cached query did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Answer {
    /// The patch certificate held: no BVH search.
    Certified,
    /// A BVH search (the patch was rebuilt or cleared); `hit`: it ended on the cached
    /// triangle.
    Searched {
        /// The closest triangle was the cached one.
        hit: bool,
    },
}

impl Slot {
    pub(crate) const NEW: Self = Self {
        part: NONE,
        clearance: 0.0,
        travel_at: 0.0,
        p_ref: Vec3::ZERO,
    };

    /// Lower bound of the signed distance at `p`: the surface moved at most `travel −
    /// travel_at`, the point at most `|p − p_ref|`.
    #[inline]
    pub(crate) fn lower_bound(&self, p: Vec3, travel: f64) -> f64 {
        self.clearance as f64 - (travel - self.travel_at) - p.distance(self.p_ref) as f64
    }

    /// The terms of [`lower_bound`](Self::lower_bound) for a filter in f32: the reserve
    /// `clearance − (travel − travel_at)` rounded down to f32 (at most the exact one), and the
    /// reference point.
    #[inline]
    pub(crate) fn reserve_f32(&self, travel: f64) -> (f32, Vec3) {
        let r = self.clearance as f64 - (travel - self.travel_at);
        let down = r as f32;
        let down = if down as f64 > r {
            down.next_down()
        } else {
            down
        };
        (down, self.p_ref)
    }

    #[inline]
    pub(crate) fn set(&mut self, clearance: f32, p: Vec3, travel: f64) {
        self.clearance = clearance;
        self.p_ref = p;
        self.travel_at = travel;
    }

    /// The exact projection of the rest-frame point `local` on `collider` (the answer of
    /// [`ColliderMesh::project_point`]), from `patch` (this slot's) when its certificate holds,
    /// else from a BVH search that rebuilds the patch with triangles up to `margin_m` farther
    /// than the nearest. `travel`: the collider's travel now.
    #[inline]
    pub(crate) fn project(
        &mut self,
        patch: &mut Patch,
        collider: &ColliderMesh,
        local: Vec3,
        travel: f64,
        margin_m: f32,
    ) -> (SurfaceProjection, Answer) {
        let slack = patch.slack(local, travel);
        let hint = self.part;
        // A search builds a patch only when the collider stayed still since this slot's last
        // search (the passes of a relaxation share one collider state); the first search after
        // the collider moved is a plain one, since a single pass per state (substeps) would
        // never use the patch.
        let margin = (patch.travel_at == travel).then_some(margin_m);
        let (proj, certified) = collider.project_patched(local, hint, patch, slack, margin);
        self.part = proj.part;
        if certified {
            (proj, Answer::Certified)
        } else {
            patch.at = local;
            patch.travel_at = travel;
            (
                proj,
                Answer::Searched {
                    hit: proj.part == hint,
                },
            )
        }
    }
}

#[cfg(test)]
mod tests;
