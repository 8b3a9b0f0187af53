//! Vertex-centric gather kernels over the CSR springs: forces, energy and curvature.
//!
//! Every kernel reads the neighbours of a vertex and writes only that vertex, over fixed-size
//! chunks. Partial sums are per chunk and added in chunk order, so the results are bit-identical
//! for any number of threads.

use glam::Vec3;
use rayon::prelude::*;

use super::{Spring, VertexAnchor};

/// Vertices per parallel chunk; fixed so reductions do not depend on the thread count.
pub(crate) const CHUNK: usize = 2048;

/// Inputs that stay fixed during one relaxation, in internal order.
pub(crate) struct Frame<'a> {
    pub offsets: &'a [u32],
    pub springs: &'a [Spring],
    pub external: Option<&'a [Vec3]>,
    pub pinned: &'a [bool],
    pub anchors: Option<&'a [VertexAnchor]>,
}

impl Frame<'_> {
    /// Net force on every vertex (zero on pinned ones) into `out`, and the total energy.
    pub fn force_energy(&self, x: &[Vec3], out: &mut [Vec3]) -> f64 {
        let partial: Vec<f64> = out
            .par_chunks_mut(CHUNK)
            .enumerate()
            .map(|(c, chunk)| {
                let base = c * CHUNK;
                let mut energy = 0.0f64;
                for (o, f) in chunk.iter_mut().enumerate() {
                    let i = base + o;
                    let xi = x[i];
                    let mut force = Vec3::ZERO;
                    let range = self.offsets[i] as usize..self.offsets[i + 1] as usize;
                    for s in &self.springs[range] {
                        let d = x[s.other as usize] - xi;
                        let len = d.length();
                        let stretch = len - s.rest;
                        if len > f32::MIN_POSITIVE {
                            force += d * (s.k * stretch / len);
                        }
                        // Each spring is seen from both ends: a quarter here, a quarter there.
                        // In f64 from exact differences, so the line search can still see energy
                        // changes far below the f32 rounding of the length.
                        let st = (x[s.other as usize].as_dvec3() - xi.as_dvec3()).length()
                            - s.rest as f64;
                        energy += 0.25 * s.k as f64 * st * st;
                    }
                    if let Some(a) = self.anchors {
                        let (fa, ea) = a[i].force_energy(xi);
                        force += fa;
                        energy += ea;
                    }
                    if let Some(ext) = self.external {
                        force += ext[i];
                        energy -= ext[i].as_dvec3().dot(xi.as_dvec3());
                    }
                    *f = if self.pinned[i] { Vec3::ZERO } else { force };
                }
                energy
            })
            .collect();
        partial.iter().sum()
    }

    /// `dᵀ H d` for the spring Hessian at `x`, with the transverse term clamped at zero for
    /// compressed springs (a Gauss-Newton curvature, never negative).
    pub fn curvature(&self, x: &[Vec3], d: &[Vec3]) -> f64 {
        let partial: Vec<f64> = (0..x.len().div_ceil(CHUNK))
            .into_par_iter()
            .map(|c| {
                let mut sum = 0.0f64;
                for i in c * CHUNK..((c + 1) * CHUNK).min(x.len()) {
                    let (xi, di) = (x[i], d[i]);
                    let range = self.offsets[i] as usize..self.offsets[i + 1] as usize;
                    let mut vertex = 0.0f32;
                    for s in &self.springs[range] {
                        let e = x[s.other as usize] - xi;
                        let u = d[s.other as usize] - di;
                        let len = e.length();
                        if len <= f32::MIN_POSITIVE {
                            vertex += s.k * u.length_squared();
                            continue;
                        }
                        let along = e.dot(u) / len;
                        let transverse = (u.length_squared() - along * along).max(0.0);
                        vertex +=
                            s.k * (along * along + (1.0 - s.rest / len).max(0.0) * transverse);
                    }
                    // Springs are counted from both ends.
                    sum += 0.5 * vertex as f64;
                    if let Some(a) = self.anchors {
                        sum += a[i].curvature(di) as f64;
                    }
                }
                sum
            })
            .collect();
        partial.iter().sum()
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

/// Deterministic dot product of two vector fields (f64 accumulation, chunked).
pub(crate) fn dot(a: &[Vec3], b: &[Vec3]) -> f64 {
    let partial: Vec<f64> = a
        .par_chunks(CHUNK)
        .zip(b.par_chunks(CHUNK))
        .map(|(a, b)| a.iter().zip(b).map(|(a, b)| a.dot(*b) as f64).sum::<f64>())
        .collect();
    partial.iter().sum()
}

/// Deterministic `Σ w_i (a_i · b_i)`.
pub(crate) fn weighted_dot(a: &[Vec3], b: &[Vec3], w: &[f32]) -> f64 {
    let partial: Vec<f64> = a
        .par_chunks(CHUNK)
        .zip(b.par_chunks(CHUNK))
        .zip(w.par_chunks(CHUNK))
        .map(|((a, b), w)| {
            a.iter()
                .zip(b)
                .zip(w)
                .map(|((a, b), w)| (*w * a.dot(*b)) as f64)
                .sum::<f64>()
        })
        .collect();
    partial.iter().sum()
}
