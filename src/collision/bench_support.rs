//! Timing helpers for `dermis bench` and `benches/collision.rs`: contact cost per skin vertex per frame next to one naive parry query per vertex, measured in the same run.
//!
//! Wrap the contact set in [`Timed`] when handing it to the relaxation (and time the
//! [`SkinCollision::substep`] calls around it), then call [`frame_cost`] with the frame's total
//! contact time: it runs one naive pass over the same positions and returns the per-vertex
//! figures and the speed-up.
//!
//! ```
//! use dermis::collision::bench_support::{Timed, frame_cost};
//! use dermis::collision::{ColliderMesh, ContactConfig, SkinCollision};
//! use dermis::solver::Projection;
//! use glam::Vec3;
//! let mut skin = SkinCollision::new(2, ContactConfig::DEFAULT).unwrap();
//! skin.add_collider(ColliderMesh::ball(1.0).unwrap());
//! let mut x = vec![Vec3::new(0.0, 0.0, 0.9), Vec3::new(0.0, 0.0, 3.0)];
//! skin.begin_frame(&mut x).unwrap();
//! let mut timed = Timed::new(&mut skin);
//! for _ in 0..3 {
//!     timed.project(&mut x, &[0, 1]);
//! }
//! let (seconds, passes) = (timed.seconds, timed.calls);
//! let cost = frame_cost(&skin, &x, seconds, passes);
//! assert_eq!(cost.passes, 3);
//! assert!(cost.us_per_vertex >= 0.0 && cost.naive_us_per_vertex > 0.0);
//! ```

use std::hint::black_box;
use std::time::Instant;

use glam::Vec3;
use parry3d::query::PointQuery;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::{CHUNK, SkinCollision};
use crate::solver::{ActiveContact, Projection, Step};

/// A [`Projection`] that times every call of the one it wraps. It forwards the active contacts
/// and the held set, so a relaxation converges on the contact set exactly as without it
/// ([`relax_frame`](super::relax_frame) times its projections with it).
#[derive(Debug)]
pub struct Timed<'a, P: Projection + ?Sized> {
    /// The wrapped projection.
    pub inner: &'a mut P,
    /// Wall time spent in the projection ([`Projection::project`],
    /// [`Projection::project_step`] and [`Projection::settled`]), s. Passes run alongside the
    /// solver's force gather ([`Projection::project_step_deferred`]) are not timed: a timer
    /// around one times the gather too.
    pub seconds: f64,
    /// Projection passes ([`Projection::project`], [`Projection::project_step`] and
    /// [`Projection::project_step_deferred`]).
    pub calls: u64,
}

impl<'a, P: Projection + ?Sized> Timed<'a, P> {
    /// Wraps `inner`, with zero time and calls.
    pub fn new(inner: &'a mut P) -> Self {
        Self {
            inner,
            seconds: 0.0,
            calls: 0,
        }
    }

    /// Runs `f` on the wrapped projection, its wall time added to `seconds` (and one call to
    /// `calls` for a pass).
    fn time<R>(&mut self, pass: bool, f: impl FnOnce(&mut P) -> R) -> R {
        let start = Instant::now();
        let r = f(self.inner);
        self.seconds += start.elapsed().as_secs_f64();
        self.calls += u64::from(pass);
        r
    }
}

impl<P: Projection + ?Sized> Projection for Timed<'_, P> {
    fn project(&mut self, x: &mut [Vec3], order: &[u32]) -> bool {
        self.time(true, |p| p.project(x, order))
    }

    fn active_contacts(&self) -> &[ActiveContact] {
        self.inner.active_contacts()
    }

    fn moved_vertices(&self) -> Option<&[u32]> {
        self.inner.moved_vertices()
    }

    fn hold(&mut self, held: &[bool]) {
        self.inner.hold(held);
    }

    fn project_step(&mut self, x: &mut [Vec3], order: &[u32], step: &Step<'_>) -> bool {
        self.time(true, |p| p.project_step(x, order, step))
    }

    fn project_step_deferred(
        &mut self,
        x: &[Vec3],
        order: &[u32],
        step: &Step<'_>,
        moves: &mut Vec<(u32, Vec3)>,
    ) -> Option<bool> {
        // Not timed: its wall time is the gather's too (`relax_frame` counts its CPU time).
        self.calls += 1;
        self.inner.project_step_deferred(x, order, step, moves)
    }

    fn settled(&mut self, x: &[Vec3]) {
        self.time(false, |p| p.settled(x));
    }
}

/// Seconds for one naive closest-point query per skin vertex and collider, the reference a
/// contact pass is compared with: parry's `TriMesh::project_point` (full BVH search, no
/// orientation) on mesh colliders, the public [`ColliderMesh::project_point`](super::ColliderMesh::project_point) on primitives,
/// in parallel over the same fixed chunks as a contact pass. `x` in the caller's order.
pub fn naive_pass_seconds(collision: &SkinCollision, x: &[Vec3]) -> f64 {
    // Whole parry meshes are made on demand (ColliderMesh::parry_mesh): before the clock.
    let meshes: Vec<_> = collision
        .colliders()
        .iter()
        .map(|c| c.parry_mesh())
        .collect();
    let start = Instant::now();
    for (collider, mesh) in collision.colliders().iter().zip(meshes) {
        let pose = collider.pose();
        let sum: f32 = match mesh {
            Some(mesh) => x
                .par_chunks(CHUNK)
                .map(|c| {
                    c.iter()
                        .map(|p| mesh.project_point(&pose, *p, false).point.x)
                        .sum::<f32>()
                })
                .collect::<Vec<_>>()
                .iter()
                .sum(),
            None => x
                .par_chunks(CHUNK)
                .map(|c| {
                    c.iter()
                        .map(|p| collider.project_point(*p).signed_distance)
                        .sum::<f32>()
                })
                .collect::<Vec<_>>()
                .iter()
                .sum(),
        };
        black_box(sum);
    }
    start.elapsed().as_secs_f64()
}

/// The contact cost of one frame next to naive queries, from [`frame_cost`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FrameCost {
    /// Contact passes in the frame.
    pub passes: u64,
    /// Contact time of the frame per skin vertex, µs (all passes).
    pub us_per_vertex: f64,
    /// One naive query per vertex and collider in every pass of the frame, per skin vertex, µs.
    pub naive_us_per_vertex: f64,
    /// `naive_us_per_vertex / us_per_vertex`.
    pub speedup_vs_naive: f64,
    /// BVH searches per vertex in the frame (from [`ContactDiagnostics`](super::ContactDiagnostics)).
    pub searches_per_vertex: f64,
    /// Queries answered from a cached patch per vertex in the frame.
    pub certified_per_vertex: f64,
    /// Vertex–collider pairs skipped by a distance bound or a bounding box, per vertex.
    pub skipped_per_vertex: f64,
}

/// Figures for a frame whose contact passes took `seconds` in all, over `passes` passes
/// (counters read from `collision`'s diagnostics, which cover the frame since
/// [`SkinCollision::begin_frame`]). Runs one naive pass over `x` (the frame's final positions,
/// caller's order) to price the same number of naive passes in the same run.
pub fn frame_cost(collision: &SkinCollision, x: &[Vec3], seconds: f64, passes: u64) -> FrameCost {
    let n = collision.vertex_count().max(1) as f64;
    let naive = naive_pass_seconds(collision, x) * passes as f64;
    let d = collision.diagnostics();
    FrameCost {
        passes,
        us_per_vertex: seconds * 1e6 / n,
        naive_us_per_vertex: naive * 1e6 / n,
        speedup_vs_naive: if seconds > 0.0 { naive / seconds } else { 0.0 },
        searches_per_vertex: d.exact_queries as f64 / n,
        certified_per_vertex: d.certified_queries as f64 / n,
        skipped_per_vertex: (d.skipped_bound + d.skipped_aabb) as f64 / n,
    }
}
