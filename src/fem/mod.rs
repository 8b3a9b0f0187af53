//! Constant-strain triangle membrane FEM (Van Gelder Eq. 10-12): the reference answer.
//!
//! Small-displacement, plane-stress linear elasticity on a planar triangle mesh, assembled into a
//! sparse stiffness matrix and solved by conjugate gradients in `f64`, with rigid-body modes
//! projected out when the pins do not remove them. The same machinery solves the linearised
//! spring mesh (`K d = f` assembled from the springs), so the two models can be compared on
//! equal terms.

mod sparse;

use glam::{DVec2, DVec3, Vec3};
use thiserror::Error;

use crate::mesh::TriMesh;
use crate::stiffness::{Modulus, StiffnessError};
pub use sparse::SparseMatrix;

/// Relative residual at which the conjugate gradients stop.
pub const CG_TOLERANCE: f64 = 1e-12;

/// Why a linear reference solve failed.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum FemError {
    /// The membrane FEM works in the plane of the mesh; this vertex is off that plane.
    #[error(
        "vertex {vertex} is {distance} m off the mesh plane; the membrane reference needs a planar mesh"
    )]
    NotPlanar {
        /// Vertex index.
        vertex: usize,
        /// Its distance to the best-fit plane.
        distance: f64,
    },
    /// Bad material parameters.
    #[error(transparent)]
    Material(#[from] StiffnessError),
    /// An input does not have one entry per vertex (or edge).
    #[error("{what} has {given} entries, expected {expected}")]
    Length {
        /// Which input.
        what: &'static str,
        /// Entries given.
        given: usize,
        /// Entries expected.
        expected: usize,
    },
    /// The loads are not balanced although nothing is pinned, so no equilibrium exists.
    #[error("the loads have a net force or torque of {0:e} N (or N·m) and nothing is pinned")]
    Unbalanced(f64),
    /// Conjugate gradients did not reach [`CG_TOLERANCE`].
    #[error(
        "conjugate gradients stopped at relative residual {residual:e} after {iterations} iterations"
    )]
    NotConverged {
        /// Iterations taken.
        iterations: usize,
        /// Relative residual reached.
        residual: f64,
    },
}

/// An orthonormal frame in the plane of a planar mesh.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlaneFrame {
    /// A point of the plane (the centroid of the vertices).
    pub origin: DVec3,
    /// First in-plane axis.
    pub u: DVec3,
    /// Second in-plane axis.
    pub v: DVec3,
}

impl PlaneFrame {
    /// The best-fit plane of `mesh` (Newell normal through the centroid); errors (naming the
    /// furthest vertex) when a vertex is further than `1e-5` of the mesh size from it.
    pub fn of(mesh: &TriMesh) -> Result<Self, FemError> {
        let p: Vec<DVec3> = mesh.positions().iter().map(|p| p.as_dvec3()).collect();
        let origin = p.iter().sum::<DVec3>() / p.len() as f64;
        let mut normal = DVec3::ZERO;
        for t in mesh.triangles() {
            let [a, b, c] = t.map(|i| p[i as usize]);
            normal += (b - a).cross(c - a);
        }
        let normal = normal.normalize();
        let size = p.iter().map(|q| (*q - origin).length()).fold(0.0, f64::max);
        let (vertex, distance) = p
            .iter()
            .map(|q| (*q - origin).dot(normal).abs())
            .enumerate()
            .fold(
                (0, 0.0),
                |worst, (i, d)| if d > worst.1 { (i, d) } else { worst },
            );
        if distance > 1e-5 * size {
            return Err(FemError::NotPlanar { vertex, distance });
        }
        let u = normal.any_orthonormal_vector();
        Ok(Self {
            origin,
            u,
            v: normal.cross(u),
        })
    }

    /// In-plane coordinates of a point.
    pub fn project(&self, p: Vec3) -> DVec2 {
        let d = p.as_dvec3() - self.origin;
        DVec2::new(d.dot(self.u), d.dot(self.v))
    }

    /// In-plane components of a vector.
    pub fn project_vector(&self, v: Vec3) -> DVec2 {
        let v = v.as_dvec3();
        DVec2::new(v.dot(self.u), v.dot(self.v))
    }

    /// The 3D vector of in-plane components `d`.
    pub fn lift(&self, d: DVec2) -> DVec3 {
        self.u * d.x + self.v * d.y
    }
}

/// A linear solve's answer.
#[derive(Debug, Clone, PartialEq)]
pub struct LinearSolution {
    /// Displacement of every vertex (in the mesh plane), m.
    pub displacement: Vec<DVec3>,
    /// CG iterations.
    pub iterations: usize,
    /// Final relative residual.
    pub residual: f64,
}

/// The 6x6 stiffness of one constant-strain triangle in plane stress (Eq. 10-12), for in-plane
/// vertex coordinates `p` (any orientation), 2D modulus `e2` and Poisson ratio `nu`. Rows and
/// columns are `(x0, y0, x1, y1, x2, y2)`.
pub fn cst_stiffness(p: [DVec2; 3], e2: f64, nu: f64) -> [[f64; 6]; 6] {
    let area = 0.5 * (p[1] - p[0]).perp_dot(p[2] - p[0]);
    // Shape-function gradients: b_i = y_jk / 2A, c_i = x_kj / 2A.
    let mut b = [0.0; 3];
    let mut c = [0.0; 3];
    for i in 0..3 {
        let (j, k) = ((i + 1) % 3, (i + 2) % 3);
        b[i] = (p[j].y - p[k].y) / (2.0 * area);
        c[i] = (p[k].x - p[j].x) / (2.0 * area);
    }
    let d = e2 / (1.0 - nu * nu);
    let g = 0.5 * (1.0 - nu);
    let a = area.abs();
    let mut k = [[0.0; 6]; 6];
    for i in 0..3 {
        for j in 0..3 {
            k[2 * i][2 * j] = a * d * (b[i] * b[j] + g * c[i] * c[j]);
            k[2 * i][2 * j + 1] = a * d * (nu * b[i] * c[j] + g * c[i] * b[j]);
            k[2 * i + 1][2 * j] = a * d * (nu * c[i] * b[j] + g * b[i] * c[j]);
            k[2 * i + 1][2 * j + 1] = a * d * (c[i] * c[j] + g * b[i] * b[j]);
        }
    }
    k
}

/// Solves the constant-strain membrane under `forces` with `pinned` vertices held: the
/// reference the spring mesh is measured against. `e2` is the 2D Young's modulus per triangle.
pub fn solve_membrane(
    mesh: &TriMesh,
    e2: &Modulus,
    nu: f64,
    forces: &[Vec3],
    pinned: &[bool],
) -> Result<LinearSolution, FemError> {
    if !(0.0..0.5).contains(&nu) {
        return Err(StiffnessError::BadPoisson(nu as f32).into());
    }
    // Reuse the stiffness module's checks of the modulus.
    crate::stiffness::StiffnessRule::AreaOverLengthSquared.edge_stiffness(mesh, e2)?;
    let frame = PlaneFrame::of(mesh)?;
    let p: Vec<DVec2> = mesh.positions().iter().map(|&q| frame.project(q)).collect();
    let mut triplets = Vec::with_capacity(mesh.triangles().len() * 36);
    for (t, tri) in mesh.triangles().iter().enumerate() {
        let k = cst_stiffness(tri.map(|i| p[i as usize]), e2.at(t) as f64, nu);
        for i in 0..6 {
            for j in 0..6 {
                let row = 2 * tri[i / 2] as usize + i % 2;
                let col = 2 * tri[j / 2] as usize + j % 2;
                triplets.push((row as u32, col as u32, k[i][j]));
            }
        }
    }
    let k = SparseMatrix::from_triplets(2 * p.len(), triplets);
    solve_planar(&k, &frame, &p, forces, pinned)
}

/// Solves the linearised spring mesh `K d = f`, `K = Σ k ê êᵀ` at rest, for a planar mesh
/// with per-edge `stiffness` (in the order of the topology's edges).
pub fn solve_linear_springs(
    mesh: &TriMesh,
    stiffness: &[f32],
    forces: &[Vec3],
    pinned: &[bool],
) -> Result<LinearSolution, FemError> {
    let edges = mesh.topology().edges();
    check_len("stiffness", stiffness.len(), edges.len())?;
    let frame = PlaneFrame::of(mesh)?;
    let p: Vec<DVec2> = mesh.positions().iter().map(|&q| frame.project(q)).collect();
    let mut triplets = Vec::with_capacity(edges.len() * 16);
    for (e, &[a, b]) in edges.iter().enumerate() {
        let dir = (p[b as usize] - p[a as usize]).normalize();
        let dir = [dir.x, dir.y];
        let k = stiffness[e] as f64;
        for (va, vb, sign) in [(a, a, 1.0), (b, b, 1.0), (a, b, -1.0), (b, a, -1.0)] {
            for (i, di) in dir.iter().enumerate() {
                for (j, dj) in dir.iter().enumerate() {
                    triplets.push((
                        (2 * va as usize + i) as u32,
                        (2 * vb as usize + j) as u32,
                        sign * k * di * dj,
                    ));
                }
            }
        }
    }
    let k = SparseMatrix::from_triplets(2 * p.len(), triplets);
    solve_planar(&k, &frame, &p, forces, pinned)
}

fn check_len(what: &'static str, given: usize, expected: usize) -> Result<(), FemError> {
    if given == expected {
        Ok(())
    } else {
        Err(FemError::Length {
            what,
            given,
            expected,
        })
    }
}

/// CG on the free degrees of freedom, with the rigid modes the pins leave projected out.
fn solve_planar(
    k: &SparseMatrix,
    frame: &PlaneFrame,
    p: &[DVec2],
    forces: &[Vec3],
    pinned: &[bool],
) -> Result<LinearSolution, FemError> {
    let n = p.len();
    check_len("forces", forces.len(), n)?;
    check_len("pinned", pinned.len(), n)?;
    let free: Vec<f64> = (0..2 * n)
        .map(|d| if pinned[d / 2] { 0.0 } else { 1.0 })
        .collect();
    let mut f: Vec<f64> = Vec::with_capacity(2 * n);
    for (i, force) in forces.iter().enumerate() {
        let q = frame.project_vector(*force);
        f.push(q.x * free[2 * i]);
        f.push(q.y * free[2 * i + 1]);
    }
    let modes = rigid_modes(p, pinned);
    let f_norm = norm(&f);
    let leak = modes.iter().map(|m| dot(m, &f).abs()).fold(0.0, f64::max);
    if leak > 1e-6 * f_norm {
        return Err(FemError::Unbalanced(leak));
    }
    let apply = |x: &[f64], out: &mut [f64]| {
        k.multiply(x, out);
        for (o, m) in out.iter_mut().zip(&free) {
            *o *= m;
        }
        project_out(out, &modes);
    };
    let diag = k.diagonal();
    let inv: Vec<f64> = diag
        .iter()
        .zip(&free)
        .map(|(d, m)| if *d > 0.0 { m / d } else { 0.0 })
        .collect();
    let (x, iterations, residual) = conjugate_gradients(apply, &inv, &f, &modes, 20 * n + 100);
    if residual > CG_TOLERANCE * 10.0 {
        return Err(FemError::NotConverged {
            iterations,
            residual,
        });
    }
    let displacement = (0..n)
        .map(|i| frame.lift(DVec2::new(x[2 * i], x[2 * i + 1])))
        .collect();
    Ok(LinearSolution {
        displacement,
        iterations,
        residual,
    })
}

/// Orthonormal rigid modes (translations, rotation) left free by the pins.
fn rigid_modes(p: &[DVec2], pinned: &[bool]) -> Vec<Vec<f64>> {
    let pins: Vec<usize> = (0..p.len()).filter(|&i| pinned[i]).collect();
    let mut raw: Vec<Vec<f64>> = Vec::new();
    if pins.is_empty() {
        raw.push(p.iter().flat_map(|_| [1.0, 0.0]).collect());
        raw.push(p.iter().flat_map(|_| [0.0, 1.0]).collect());
        let c = p.iter().sum::<DVec2>() / p.len() as f64;
        raw.push(p.iter().flat_map(|q| [-(q.y - c.y), q.x - c.x]).collect());
    } else if pins.iter().all(|&i| p[i] == p[pins[0]]) {
        let c = p[pins[0]];
        raw.push(
            p.iter()
                .zip(pinned)
                .flat_map(|(q, &pin)| {
                    if pin {
                        [0.0, 0.0]
                    } else {
                        [-(q.y - c.y), q.x - c.x]
                    }
                })
                .collect(),
        );
    }
    // Gram-Schmidt.
    let mut modes: Vec<Vec<f64>> = Vec::new();
    for mut m in raw {
        project_out(&mut m, &modes);
        let l = norm(&m);
        if l > 0.0 {
            m.iter_mut().for_each(|v| *v /= l);
            modes.push(m);
        }
    }
    modes
}

fn project_out(x: &mut [f64], modes: &[Vec<f64>]) {
    for m in modes {
        let c = dot(x, m);
        x.iter_mut().zip(m).for_each(|(x, m)| *x -= c * m);
    }
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(a, b)| a * b).sum()
}

fn norm(a: &[f64]) -> f64 {
    dot(a, a).sqrt()
}

/// Jacobi-preconditioned CG, iterates kept orthogonal to `modes`.
fn conjugate_gradients(
    apply: impl Fn(&[f64], &mut [f64]),
    inv_diag: &[f64],
    b: &[f64],
    modes: &[Vec<f64>],
    max_iterations: usize,
) -> (Vec<f64>, usize, f64) {
    let n = b.len();
    let mut b = b.to_vec();
    project_out(&mut b, modes);
    let b_norm = norm(&b);
    let mut x = vec![0.0; n];
    if b_norm == 0.0 {
        return (x, 0, 0.0);
    }
    let mut r = b.clone();
    let precondition = |r: &[f64]| {
        let mut z: Vec<f64> = r.iter().zip(inv_diag).map(|(r, d)| r * d).collect();
        project_out(&mut z, modes);
        z
    };
    let mut z = precondition(&r);
    let mut d = z.clone();
    let mut rz = dot(&r, &z);
    let mut q = vec![0.0; n];
    let mut it = 0;
    while it < max_iterations && norm(&r) > CG_TOLERANCE * b_norm {
        apply(&d, &mut q);
        let alpha = rz / dot(&d, &q);
        x.iter_mut().zip(&d).for_each(|(x, d)| *x += alpha * d);
        r.iter_mut().zip(&q).for_each(|(r, q)| *r -= alpha * q);
        z = precondition(&r);
        let rz_new = dot(&r, &z);
        let beta = rz_new / rz;
        rz = rz_new;
        d.iter_mut().zip(&z).for_each(|(d, z)| *d = z + beta * *d);
        it += 1;
    }
    // True residual, not the recurrence.
    let mut ax = vec![0.0; n];
    apply(&x, &mut ax);
    let res: Vec<f64> = b.iter().zip(&ax).map(|(b, a)| b - a).collect();
    (x, it, norm(&res) / b_norm)
}

#[cfg(test)]
mod tests;
