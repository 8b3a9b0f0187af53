//! Vertex-centric gather kernels over the sliced springs: forces, energy and curvature.
//!
//! Every kernel reads the neighbours of a vertex and writes only that vertex, over fixed-size
//! chunks (eight vertices at a time, see [`super::simd`]). Partial sums are per chunk and added
//! in chunk order, so the results are bit-identical for any number of threads. The dot products
//! the conjugate-gradient update needs are taken inside the passes that produce their operands.
//! One iteration streams the vertices four times: the curvature gather, the step to the trial
//! point (in place: the solver keeps no trial vector and no copy of the last point), the force
//! gather there, and the direction update.

use glam::Vec3;

use super::STEP_BLOCK;
use super::sell::{LANES, Sell};
use super::simd::{self, ForceInputs, Isa, SlicedAnchors};
use super::team::{Chunked, Par};

/// Vertices per parallel chunk; fixed so reductions do not depend on the thread count.
pub(crate) const CHUNK: usize = 1024;

/// Inputs that stay fixed during one relaxation, in internal order.
pub(crate) struct Frame<'a> {
    pub sell: &'a Sell,
    /// Each vertex's stiffness summed over its springs ([`Sell::stiffness_diagonal`]).
    pub spring_diagonal: &'a [f32],
    pub isa: Isa,
    pub external: Option<&'a [Vec3]>,
    pub anchors: Option<&'a SlicedAnchors>,
    /// Where the parallel loops run.
    pub par: Par<'a>,
}

/// The reductions of one force gather (each summed per chunk, then over chunks in order).
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct Sums {
    /// Total energy, J.
    pub energy: f64,
    /// `Σ r·r` of the new net force.
    pub rr: f64,
    /// `Σ w r·r` (preconditioned).
    pub rzr: f64,
    /// `Σ w r·r_old`, with `r_old` what the force buffer held before the gather.
    pub rz_old: f64,
    /// `Σ r·d` of the new force and the step's direction `d` (0 for a gather without a
    /// step): with the slope before the step, how much the slope along `d` changed over it.
    pub rd: f64,
}

impl std::ops::AddAssign for Sums {
    fn add_assign(&mut self, o: Self) {
        self.energy += o.energy;
        self.rr += o.rr;
        self.rzr += o.rzr;
        self.rz_old += o.rz_old;
        self.rd += o.rd;
    }
}

/// Number of chunks of `n` vertices.
pub(crate) fn chunks(n: usize) -> usize {
    n.div_ceil(CHUNK)
}

/// Sums per-chunk partials in chunk order.
fn total<T: Copy + Default + std::ops::AddAssign>(partial: &[T]) -> T {
    let mut sum = T::default();
    for p in partial {
        sum += *p;
    }
    sum
}

impl Frame<'_> {
    /// Net force at `x` into `r`, with the energy and the dot products of the
    /// conjugate-gradient update (weights `w`: the [inverse diagonal](Self::inverse_diagonal),
    /// whose sign marks the pinned vertices; `None`: nothing pinned, no dot products).
    /// `partial` is scratch with one entry per chunk.
    pub fn gather(
        &self,
        x: &[Vec3],
        w: Option<&[f32]>,
        r: &mut [Vec3],
        partial: &mut [Sums],
    ) -> Sums {
        self.gather_inputs(x, None, w, r, partial, None)
    }

    /// [`gather`](Self::gather) again after some vertices moved since the last gather (whose
    /// per-chunk sums `partial` holds): only the chunks `stale` (sorted, every chunk whose
    /// forces read a moved vertex) are recomputed. The others keep their forces and sums, as a
    /// whole gather would compute them again bit for bit, except the two products it takes
    /// against the old force and the direction: `Σ w r·r_old` is `Σ w r·r` there (the force
    /// did not change, and both are summed with the same operations) and `Σ r·d` is 0 (no
    /// direction). The result equals [`gather`](Self::gather)'s to the bit.
    pub fn regather(
        &self,
        x: &[Vec3],
        w: Option<&[f32]>,
        r: &mut [Vec3],
        partial: &mut [Sums],
        stale: &[u32],
    ) -> Sums {
        for p in partial.iter_mut() {
            p.rz_old = p.rzr;
            p.rd = 0.0;
        }
        self.gather_inputs(x, None, w, r, partial, Some(stale))
    }

    /// [`gather`](Self::gather) after a step along `d`, with `Σ r·d` ([`Sums::rd`]).
    pub fn gather_along(
        &self,
        x: &[Vec3],
        d: &[Vec3],
        w: Option<&[f32]>,
        r: &mut [Vec3],
        partial: &mut [Sums],
    ) -> Sums {
        self.gather_inputs(x, Some(d), w, r, partial, None)
    }

    /// [`gather_along`](Self::gather_along) with `body` run alongside (see
    /// [`Par::with_rider`]): its first parallel loop on the solve's team shares the gather's.
    /// `body` must not write `x`, `d`, `w` or `r`.
    pub fn gather_along_with<R>(
        &self,
        (x, d, w): (&[Vec3], &[Vec3], Option<&[f32]>),
        r: &mut [Vec3],
        partial: &mut [Sums],
        body: impl FnOnce() -> R,
    ) -> (Sums, R) {
        self.gather_inputs_with(x, Some(d), w, (r, partial), None, body)
    }

    /// The force gather over the chunks `only` (sorted, no repeats; `None`: every chunk).
    fn gather_inputs(
        &self,
        x: &[Vec3],
        dir: Option<&[Vec3]>,
        w: Option<&[f32]>,
        r: &mut [Vec3],
        partial: &mut [Sums],
        only: Option<&[u32]>,
    ) -> Sums {
        self.gather_inputs_with(x, dir, w, (r, partial), only, || ())
            .0
    }

    /// [`gather_inputs`](Self::gather_inputs) with `body` run alongside ([`Par::with_rider`]).
    #[expect(unsafe_code, reason = "disjoint chunks written by one parallel loop")]
    fn gather_inputs_with<R>(
        &self,
        x: &[Vec3],
        dir: Option<&[Vec3]>,
        w: Option<&[f32]>,
        (r, partial): (&mut [Vec3], &mut [Sums]),
        only: Option<&[u32]>,
        body: impl FnOnce() -> R,
    ) -> (Sums, R) {
        let inputs = ForceInputs {
            sell: self.sell,
            x,
            dir,
            anchors: self.anchors,
            external: self.external,
            w,
        };
        let (rs, ps) = (Chunked::new(r, CHUNK), Chunked::new(partial, 1));
        let count = only.map_or(ps.chunks(), <[u32]>::len);
        let chunk = |k: usize| {
            let c = only.map_or(k, |only| only[k] as usize);
            // SAFETY: each chunk index once per loop (`only` has no repeats).
            let (r, p) = unsafe { (rs.chunk(c), ps.chunk(c)) };
            p[0] = inputs.chunk(self.isa, c * CHUNK, r);
        };
        let out = self.par.with_rider(count, &chunk, body);
        (total(partial), out)
    }

    /// `dᵀ H d` for the spring Hessian at `x`, with the transverse term clamped at zero for
    /// compressed springs (a Gauss-Newton curvature, never negative). Each spring is visited
    /// once, from its lower-numbered end.
    #[expect(unsafe_code, reason = "disjoint chunks written by one parallel loop")]
    pub fn curvature(&self, x: &[Vec3], d: &[Vec3], partial: &mut [f64]) -> f64 {
        let slices = self.sell.slices();
        let ps = Chunked::new(partial, 1);
        self.par.for_each(ps.chunks(), |c| {
            let range = c * (CHUNK / LANES)..((c + 1) * (CHUNK / LANES)).min(slices);
            // SAFETY: each chunk index once per loop.
            let p = unsafe { ps.chunk(c) };
            p[0] = simd::curvature(self.isa, self.sell, x, d, self.anchors, range);
        });
        total(partial)
    }

    /// Jacobi preconditioner: the diagonal stiffness of each vertex, inverted (`+0.0` when
    /// there is none), `-0.0` for a `pinned` vertex: the sign is the pin flag the force gather
    /// reads, and the weight is zero either way.
    #[expect(unsafe_code, reason = "disjoint chunks written by one parallel loop")]
    pub fn inverse_diagonal(&self, pinned: &[bool]) -> Vec<f32> {
        let mut inv = vec![0.0f32; pinned.len()];
        let invs = Chunked::new(&mut inv, CHUNK);
        self.par.for_each(invs.chunks(), |c| {
            // SAFETY: each chunk index once per loop.
            let inv = unsafe { invs.chunk(c) };
            let first = c * CHUNK;
            let springs = &self.spring_diagonal[first..first + inv.len()];
            for (o, (w, &springs)) in inv.iter_mut().zip(springs).enumerate() {
                let i = first + o;
                *w = if pinned[i] {
                    -0.0
                } else {
                    let mut diag = springs;
                    if let Some(a) = self.anchors {
                        let a = a.get(i);
                        diag += a.k_normal.max(a.k_tangent);
                    }
                    if diag > 0.0 { 1.0 / diag } else { 0.0 }
                };
            }
        });
        inv
    }
}

/// The direction update `d = w·r + β d`; returns `Σ r·d` (the slope along the new direction).
/// `reach` (one entry per [`STEP_BLOCK`] vertices) receives each block's largest `|d|`
/// component.
#[expect(unsafe_code, reason = "disjoint chunks written by one parallel loop")]
pub(crate) fn update_direction(
    par: Par<'_>,
    d: &mut [Vec3],
    r: &[Vec3],
    w: &[f32],
    beta: f32,
    (partial, reach): (&mut [f64], &mut [f32]),
) -> f64 {
    let isa = Isa::detect(0);
    assert_eq!(reach.len(), d.len().div_ceil(STEP_BLOCK));
    let (ds, ps) = (Chunked::new(d, CHUNK), Chunked::new(partial, 1));
    let reaches = Chunked::new(reach, CHUNK / STEP_BLOCK);
    par.for_each(ps.chunks(), |c| {
        let range = c * CHUNK..((c + 1) * CHUNK).min(r.len());
        // SAFETY: each chunk index once per loop.
        let (d, p, reach) = unsafe { (ds.chunk(c), ps.chunk(c), reaches.chunk(c)) };
        p[0] = simd::direction(isa, d, &r[range.clone()], &w[range], beta, reach);
    });
    total(partial)
}

/// Floats an [`advance`] noted per chunk so that [`retreat`] can undo it bit for bit.
pub(crate) type Spills = Vec<Vec<simd::Spilled>>;

/// The step `x += a d`, in place; `spills` (one list per chunk) receives what [`retreat`]
/// needs to undo it exactly.
#[expect(unsafe_code, reason = "disjoint chunks written by one parallel loop")]
pub(crate) fn advance(par: Par<'_>, x: &mut [Vec3], d: &[Vec3], a: f32, spills: &mut Spills) {
    let isa = Isa::detect(0);
    spills.resize_with(chunks(d.len()), Vec::new);
    let (xs, ss) = (Chunked::new(x, CHUNK), Chunked::new(spills, 1));
    par.for_each(chunks(d.len()), |c| {
        let range = c * CHUNK..((c + 1) * CHUNK).min(d.len());
        // SAFETY: each chunk index once per loop.
        let (x, s) = unsafe { (xs.chunk(c), ss.chunk(c)) };
        simd::advance(isa, x, &d[range], a, &mut s[0]);
    });
}

/// Undoes the last [`advance`] (the same `d`, `a` and `spills`): `x` is back to its bits
/// before it.
#[expect(unsafe_code, reason = "disjoint chunks written by one parallel loop")]
pub(crate) fn retreat(par: Par<'_>, x: &mut [Vec3], d: &[Vec3], a: f32, spills: &Spills) {
    let isa = Isa::detect(0);
    let xs = Chunked::new(x, CHUNK);
    par.for_each(chunks(d.len()), |c| {
        let range = c * CHUNK..((c + 1) * CHUNK).min(d.len());
        // SAFETY: each chunk index once per loop.
        let x = unsafe { xs.chunk(c) };
        simd::retreat(isa, x, &d[range], a, &spills[c]);
    });
}

/// Deterministic dot product of two vector fields (f64 accumulation, chunked); `partial` is
/// scratch with one entry per chunk.
#[expect(unsafe_code, reason = "disjoint chunks written by one parallel loop")]
pub(crate) fn dot(par: Par<'_>, a: &[Vec3], b: &[Vec3], partial: &mut [f64]) -> f64 {
    let ps = Chunked::new(partial, 1);
    par.for_each(ps.chunks(), |c| {
        let range = c * CHUNK..((c + 1) * CHUNK).min(a.len());
        let (a, b) = (&a[range.clone()], &b[range]);
        // SAFETY: each chunk index once per loop.
        let p = unsafe { ps.chunk(c) };
        p[0] = a.iter().zip(b).map(|(a, b)| a.dot(*b) as f64).sum::<f64>();
    });
    partial.iter().sum()
}
