//! Vertex-centric gather kernels over the CSR springs: forces, energy and curvature.
//!
//! Every kernel reads the neighbours of a vertex and writes only that vertex, over fixed-size
//! chunks. Partial sums are per chunk and added in chunk order, so the results are bit-identical
//! for any number of threads. The dot products the conjugate-gradient update needs are taken
//! inside the passes that produce their operands, so one iteration streams the vertices three
//! times: the force gather, the direction update and the curvature gather.

use glam::Vec3;
use rayon::prelude::*;

use super::{Spring, VertexAnchor};

/// Vertices per parallel chunk; fixed so reductions do not depend on the thread count.
pub(crate) const CHUNK: usize = 1024;

/// Inputs that stay fixed during one relaxation, in internal order.
pub(crate) struct Frame<'a> {
    pub offsets: &'a [u32],
    pub springs: &'a [Spring],
    pub external: Option<&'a [Vec3]>,
    pub pinned: &'a [bool],
    pub anchors: Option<&'a [VertexAnchor]>,
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
}

impl std::ops::AddAssign for Sums {
    fn add_assign(&mut self, o: Self) {
        self.energy += o.energy;
        self.rr += o.rr;
        self.rzr += o.rzr;
        self.rz_old += o.rz_old;
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

/// The spring stretch `|e| − rest` in f64, from the exact f64 edge vector `e64` and its f32
/// length `len` (with `inv_len = 1/len`): one Newton step on the square root, so the result is
/// accurate to ~1e-14 of the length without an f64 square root.
#[inline(always)]
fn stretch64(e64: glam::DVec3, len: f32, inv_len: f32, rest: f32) -> f64 {
    let l2 = e64.length_squared();
    if len > f32::MIN_POSITIVE {
        let len64 = len as f64;
        (len64 - rest as f64) + (l2 - len64 * len64) * (0.5 * inv_len) as f64
    } else {
        l2.sqrt() - rest as f64
    }
}

impl Frame<'_> {
    /// Net force (zero on pinned vertices) and energy of vertex `i` at positions `pos(j)`;
    /// springs to higher-numbered vertices carry the spring energy (each spring once).
    #[inline(always)]
    fn vertex(&self, i: usize, pos: impl Fn(usize) -> Vec3) -> (Vec3, f64) {
        let yi = pos(i);
        let mut force = Vec3::ZERO;
        let mut energy = 0.0f64;
        let range = self.offsets[i] as usize..self.offsets[i + 1] as usize;
        for s in &self.springs[range] {
            let j = s.other as usize;
            let yj = pos(j);
            let e = yj - yi;
            let len = e.length();
            let inv_len = 1.0 / len;
            if len > f32::MIN_POSITIVE {
                force += e * (s.k * (len - s.rest) * inv_len);
            }
            if j > i {
                // In f64 from exact differences, so the line search can still see energy
                // changes far below the f32 rounding of the length. Each spring once.
                let st = stretch64(yj.as_dvec3() - yi.as_dvec3(), len, inv_len, s.rest);
                energy += 0.5 * s.k as f64 * st * st;
            }
        }
        if let Some(a) = self.anchors {
            let (fa, ea) = a[i].force_energy(yi);
            force += fa;
            energy += ea;
        }
        if let Some(ext) = self.external {
            force += ext[i];
            energy -= ext[i].as_dvec3().dot(yi.as_dvec3());
        }
        let force = if self.pinned[i] { Vec3::ZERO } else { force };
        (force, energy)
    }

    /// Net force at `x` into `r`, with the energy and the dot
    /// products of the conjugate-gradient update (weights `w`: the inverse diagonal).
    /// `partial` is scratch with one entry per chunk.
    pub fn gather(
        &self,
        x: &[Vec3],
        w: Option<&[f32]>,
        r: &mut [Vec3],
        partial: &mut [Sums],
    ) -> Sums {
        r.par_chunks_mut(CHUNK)
            .zip(partial.par_iter_mut())
            .enumerate()
            .for_each(|(c, (chunk, p))| *p = body_at(self, c, chunk, w, |j| x[j]));
        total(partial)
    }

    /// `dᵀ H d` for the spring Hessian at `x`, with the transverse term clamped at zero for
    /// compressed springs (a Gauss-Newton curvature, never negative). Each spring is visited
    /// once, from its lower-numbered end.
    pub fn curvature(&self, x: &[Vec3], d: &[Vec3], partial: &mut [f64]) -> f64 {
        partial.par_iter_mut().enumerate().for_each(|(c, p)| {
            let mut sum = 0.0f64;
            for i in c * CHUNK..((c + 1) * CHUNK).min(x.len()) {
                let (xi, di) = (x[i], d[i]);
                let springs = &self.springs[self.offsets[i] as usize..self.offsets[i + 1] as usize];
                let upper = springs.partition_point(|s| (s.other as usize) < i);
                let mut vertex = 0.0f32;
                for s in &springs[upper..] {
                    let e = x[s.other as usize] - xi;
                    let u = d[s.other as usize] - di;
                    let l2 = e.length_squared();
                    if l2 <= f32::MIN_POSITIVE * f32::MIN_POSITIVE {
                        vertex += s.k * u.length_squared();
                        continue;
                    }
                    let inv_len = 1.0 / l2.sqrt();
                    let along = e.dot(u) * inv_len;
                    let transverse = (u.length_squared() - along * along).max(0.0);
                    vertex +=
                        s.k * (along * along + (1.0 - s.rest * inv_len).max(0.0) * transverse);
                }
                sum += vertex as f64;
                if let Some(a) = self.anchors {
                    sum += a[i].curvature(di) as f64;
                }
            }
            *p = sum;
        });
        total(partial)
    }

    /// Jacobi preconditioner: the diagonal stiffness of each vertex (inverse, zero when pinned).
    pub fn inverse_diagonal(&self, n: usize) -> Vec<f32> {
        (0..n)
            .into_par_iter()
            .with_min_len(CHUNK)
            .map(|i| {
                if self.pinned[i] {
                    return 0.0;
                }
                let range = self.offsets[i] as usize..self.offsets[i + 1] as usize;
                let mut diag: f32 = self.springs[range].iter().map(|s| s.k).sum();
                if let Some(a) = self.anchors {
                    diag += a[i].k_normal.max(a[i].k_tangent);
                }
                if diag > 0.0 { 1.0 / diag } else { 0.0 }
            })
            .collect()
    }
}

/// One chunk of [`Frame::gather`], monomorphised per position function.
#[inline(always)]
fn body_at(
    frame: &Frame<'_>,
    c: usize,
    chunk: &mut [Vec3],
    w: Option<&[f32]>,
    pos: impl Fn(usize) -> Vec3 + Copy,
) -> Sums {
    let base = c * CHUNK;
    let mut sums = Sums::default();
    for (o, slot) in chunk.iter_mut().enumerate() {
        let i = base + o;
        let (f, e) = frame.vertex(i, pos);
        sums.energy += e;
        let ff = f.dot(f);
        sums.rr += ff as f64;
        if let Some(w) = w {
            sums.rzr += (w[i] * ff) as f64;
            sums.rz_old += (w[i] * f.dot(*slot)) as f64;
        }
        *slot = f;
    }
    sums
}

/// The direction update `d = w·r + β d`; returns `Σ r·d` (the slope along the new direction).
pub(crate) fn update_direction(
    d: &mut [Vec3],
    r: &[Vec3],
    w: &[f32],
    beta: f32,
    partial: &mut [f64],
) -> f64 {
    d.par_chunks_mut(CHUNK)
        .zip(partial.par_iter_mut())
        .enumerate()
        .for_each(|(c, (d, p))| {
            let base = c * CHUNK;
            let mut slope = 0.0f64;
            for (o, d) in d.iter_mut().enumerate() {
                let i = base + o;
                *d = r[i] * w[i] + *d * beta;
                slope += r[i].dot(*d) as f64;
            }
            *p = slope;
        });
    total(partial)
}

/// Deterministic dot product of two vector fields (f64 accumulation, chunked).
pub(crate) fn dot(a: &[Vec3], b: &[Vec3]) -> f64 {
    let partial: Vec<f64> = a
        .par_chunks(CHUNK)
        .zip(b.par_chunks(CHUNK))
        .map(|(a, b)| a.iter().zip(b).map(|(a, b)| a.dot(*b) as f64).sum::<f64>())
        .collect();
    partial.iter().sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stretch_matches_the_f64_square_root() {
        let mut worst = 0.0f64;
        for i in 0..2000u32 {
            let t = i as f32;
            let e = Vec3::new(
                (t * 0.37).sin() * 0.01,
                (t * 1.13).cos() * 0.003,
                (t * 0.71).sin() * 0.02 + 1e-4,
            );
            let rest = e.length() * (1.0 + 1e-6 * (t * 0.1).sin());
            let len = e.length();
            let exact = e.as_dvec3().length() - rest as f64;
            let got = stretch64(e.as_dvec3(), len, 1.0 / len, rest);
            worst = worst.max((got - exact).abs() / len as f64);
        }
        // An f32 length alone would be off by up to ~6e-8 of the length.
        assert!(worst < 1e-13, "relative error {worst}");
        let zero = stretch64(glam::DVec3::ZERO, 0.0, f32::INFINITY, 0.5);
        assert_eq!(zero, -0.5);
    }
}
