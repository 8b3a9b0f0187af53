//! The relaxation as it was before the fused kernels of issue 8, kept only as the in-run
//! baseline of `dermis bench` (anchors only: no pins, no external forces, no projection).
//!
//! Per iteration it ran a curvature gather, a trial-position pass, a force gather that took
//! the energy from f64 square roots of both ends of every spring, four separate dot products, a
//! preconditioner pass (allocating a new vector) and the direction update.

use glam::Vec3;
use rayon::prelude::*;

use crate::solver::{Spring, SpringSystem, VertexAnchor};

const CHUNK: usize = 2048;

struct Frame<'a> {
    offsets: &'a [u32],
    springs: &'a [Spring],
    anchors: &'a [VertexAnchor],
}

fn anchor_force_energy(a: &VertexAnchor, x: Vec3) -> (Vec3, f64) {
    let d = x - a.target;
    let dn = d.dot(a.normal);
    let dt = d - a.normal * dn;
    let force = -(a.normal * (a.k_normal * dn) + dt * a.k_tangent);
    let d64 = x.as_dvec3() - a.target.as_dvec3();
    let n64 = a.normal.as_dvec3();
    let dn64 = d64.dot(n64);
    let energy = 0.5 * a.k_normal as f64 * dn64 * dn64
        + 0.5 * a.k_tangent as f64 * (d64 - n64 * dn64).length_squared();
    (force, energy)
}

fn anchor_curvature(a: &VertexAnchor, u: Vec3) -> f32 {
    let un = u.dot(a.normal);
    a.k_normal * un * un + a.k_tangent * (u.length_squared() - un * un).max(0.0)
}

impl Frame<'_> {
    fn force_energy(&self, x: &[Vec3], out: &mut [Vec3]) -> f64 {
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
                        let st = (x[s.other as usize].as_dvec3() - xi.as_dvec3()).length()
                            - s.rest as f64;
                        energy += 0.25 * s.k as f64 * st * st;
                    }
                    let (fa, ea) = anchor_force_energy(&self.anchors[i], xi);
                    *f = force + fa;
                    energy += ea;
                }
                energy
            })
            .collect();
        partial.iter().sum()
    }

    fn curvature(&self, x: &[Vec3], d: &[Vec3]) -> f64 {
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
                    sum += 0.5 * vertex as f64;
                    sum += anchor_curvature(&self.anchors[i], di) as f64;
                }
                sum
            })
            .collect();
        partial.iter().sum()
    }

    fn inverse_diagonal(&self, n: usize) -> Vec<f32> {
        (0..n)
            .into_par_iter()
            .with_min_len(CHUNK)
            .map(|i| {
                let range = self.offsets[i] as usize..self.offsets[i + 1] as usize;
                let mut diag: f32 = self.springs[range].iter().map(|s| s.k).sum();
                let a = &self.anchors[i];
                diag += a.k_normal.max(a.k_tangent);
                if diag > 0.0 { 1.0 / diag } else { 0.0 }
            })
            .collect()
    }
}

fn dot(a: &[Vec3], b: &[Vec3]) -> f64 {
    let partial: Vec<f64> = a
        .par_chunks(CHUNK)
        .zip(b.par_chunks(CHUNK))
        .map(|(a, b)| a.iter().zip(b).map(|(a, b)| a.dot(*b) as f64).sum::<f64>())
        .collect();
    partial.iter().sum()
}

fn weighted_dot(a: &[Vec3], b: &[Vec3], w: &[f32]) -> f64 {
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

/// `iterations` iterations of the previous solver from `x` (caller's order) under `anchors`
/// (caller's order); returns the final energy, J.
pub fn relax(system: &SpringSystem, x: &[Vec3], anchors: &[VertexAnchor], iterations: u32) -> f64 {
    let order = system.order();
    let n = order.len();
    let (offsets, springs) = system.csr();
    let anchors: Vec<VertexAnchor> = order.iter().map(|&o| anchors[o as usize]).collect();
    let frame = Frame {
        offsets: &offsets,
        springs: &springs,
        anchors: &anchors,
    };
    let mut xi: Vec<Vec3> = order.iter().map(|&o| x[o as usize]).collect();
    let inv_diag = frame.inverse_diagonal(n);
    let mut r = vec![Vec3::ZERO; n];
    let mut energy = frame.force_energy(&xi, &mut r);
    let precondition = |r: &[Vec3], z: &mut [Vec3]| {
        z.par_chunks_mut(CHUNK).enumerate().for_each(|(c, chunk)| {
            for (o, z) in chunk.iter_mut().enumerate() {
                let i = c * CHUNK + o;
                *z = r[i] * inv_diag[i];
            }
        });
    };
    let mut z = vec![Vec3::ZERO; n];
    precondition(&r, &mut z);
    let mut d = z.clone();
    let mut rz = weighted_dot(&r, &r, &inv_diag);
    let mut trial = vec![Vec3::ZERO; n];
    let mut r_trial = vec![Vec3::ZERO; n];
    let mut done = 0;
    while done < iterations {
        let slope = dot(&r, &d);
        if slope <= 0.0 {
            d.copy_from_slice(&z);
            if rz <= 0.0 {
                break;
            }
            continue;
        }
        let curvature = frame.curvature(&xi, &d);
        let mut alpha = if curvature > 0.0 {
            slope / curvature
        } else {
            1.0
        };
        let mut accepted = false;
        for _ in 0..30 {
            let a = alpha as f32;
            trial
                .par_chunks_mut(CHUNK)
                .enumerate()
                .for_each(|(c, chunk)| {
                    for (o, t) in chunk.iter_mut().enumerate() {
                        let i = c * CHUNK + o;
                        *t = xi[i] + d[i] * a;
                    }
                });
            let e = frame.force_energy(&trial, &mut r_trial);
            if e < energy {
                energy = e;
                accepted = true;
                break;
            }
            alpha *= 0.5;
        }
        if !accepted {
            break;
        }
        std::mem::swap(&mut xi, &mut trial);
        std::mem::swap(&mut r, &mut r_trial);
        done += 1;
        let z_old = std::mem::take(&mut z);
        z = vec![Vec3::ZERO; n];
        precondition(&r, &mut z);
        let rz_new = weighted_dot(&r, &r, &inv_diag);
        let beta = if rz <= 0.0 {
            0.0
        } else {
            ((rz_new - dot(&r, &z_old)) / rz).max(0.0)
        };
        rz = rz_new;
        let b = beta as f32;
        d.par_chunks_mut(CHUNK).enumerate().for_each(|(c, chunk)| {
            for (o, d) in chunk.iter_mut().enumerate() {
                let i = c * CHUNK + o;
                *d = z[i] + *d * b;
            }
        });
    }
    energy
}
