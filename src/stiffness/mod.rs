//! Per-edge spring stiffness from rest geometry: Van Gelder's rules (Eq. 27, 29, 30) and the
//! constant and 1/length baselines.
#![doc = include_str!("README.md")]

use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::mesh::{TetMesh, TriMesh};

/// Default floor of the [`StiffnessRule::Poisson`] policy for obtuse triangles, as a fraction of
/// the triangle's Eq. 29 contribution.
pub const DEFAULT_OBTUSE_FLOOR: f32 = 0.1;

/// Young's modulus of the material, uniform or one value per element.
///
/// For surfaces this is the 2D modulus `E2` (N/m) per triangle; for tetrahedral meshes the 3D
/// modulus `E` (N/m²) per tetrahedron.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum Modulus {
    /// The same value for every element.
    Uniform(f32),
    /// One value per element, in element order (non-uniform skin).
    PerElement(Vec<f32>),
}

impl Modulus {
    /// The modulus of element `e`.
    #[inline]
    pub fn at(&self, e: usize) -> f32 {
        match self {
            Modulus::Uniform(v) => *v,
            Modulus::PerElement(v) => v[e],
        }
    }

    fn validate(&self, elements: usize) -> Result<(), StiffnessError> {
        match self {
            Modulus::Uniform(v) if !(v.is_finite() && *v > 0.0) => {
                Err(StiffnessError::BadModulus {
                    element: None,
                    value: *v,
                })
            }
            Modulus::Uniform(_) => Ok(()),
            Modulus::PerElement(v) if v.len() != elements => Err(StiffnessError::ModulusCount {
                given: v.len(),
                elements,
            }),
            Modulus::PerElement(v) => match v.iter().position(|x| !(x.is_finite() && *x > 0.0)) {
                Some(e) => Err(StiffnessError::BadModulus {
                    element: Some(e),
                    value: v[e],
                }),
                None => Ok(()),
            },
        }
    }
}

/// How spring stiffness is derived from the rest geometry.
///
/// ```
/// use dermis::mesh::TriMesh;
/// use dermis::stiffness::{Modulus, StiffnessRule};
/// use glam::Vec3;
/// // A right isosceles triangle of area 1/2 with legs of length 1.
/// let mesh = TriMesh::new(vec![Vec3::ZERO, Vec3::X, Vec3::Y], vec![[0, 1, 2]]).unwrap();
/// let k = StiffnessRule::AreaOverLengthSquared
///     .edge_stiffness(&mesh, &Modulus::Uniform(100.0))
///     .unwrap();
/// // Edges (0,1) and (0,2): k = E2 * 0.5 / 1² = 50 N/m; the hypotenuse (1,2): 100 * 0.5 / 2.
/// assert_eq!(k, vec![50.0, 50.0, 25.0]);
/// ```
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "rule", rename_all = "kebab-case")]
pub enum StiffnessRule {
    /// Baseline: the same stiffness `k` (N/m) for every edge, whatever its geometry.
    Constant {
        /// Spring stiffness, N/m.
        k_n_per_m: f32,
    },
    /// Baseline: the same 1D Young's modulus `E1` (N) for every edge, so `k = E1 / |c|`.
    InverseLength {
        /// One-dimensional Young's modulus, N.
        e1_n: f32,
    },
    /// Van Gelder Eq. 29: `k_c = E2 * Σ area(T) / |c|²` over the triangles incident to `c`.
    AreaOverLengthSquared,
    /// Van Gelder Eq. 27 with Poisson ratio `nu` (areas from Eq. 28), summed over incident
    /// triangles. Each triangle's contribution is clamped from below at `obtuse_floor` times its
    /// Eq. 29 contribution, because Eq. 27 goes negative on the long edge of an obtuse triangle.
    Poisson {
        /// Poisson ratio, in `[0, 0.5)`.
        nu: f32,
        /// Floor per triangle, as a fraction of its Eq. 29 contribution (see
        /// [`DEFAULT_OBTUSE_FLOOR`]); must be positive.
        obtuse_floor: f32,
    },
    /// Van Gelder Eq. 30: `k_c = E * Σ vol(T) / |c|²` over the tetrahedra incident to `c`
    /// ([`tetrahedral_stiffness`]).
    Tetrahedral,
}

impl StiffnessRule {
    /// Eq. 27 with the default obtuse policy.
    pub fn poisson(nu: f32) -> Self {
        StiffnessRule::Poisson {
            nu,
            obtuse_floor: DEFAULT_OBTUSE_FLOOR,
        }
    }

    /// Short name used on the command line (`area-len2`, `poisson`, ...).
    pub fn name(&self) -> &'static str {
        match self {
            StiffnessRule::Constant { .. } => "constant",
            StiffnessRule::InverseLength { .. } => "inverse-length",
            StiffnessRule::AreaOverLengthSquared => "area-len2",
            StiffnessRule::Poisson { .. } => "poisson",
            StiffnessRule::Tetrahedral => "tetrahedral",
        }
    }

    /// Stiffness of every edge of a triangle mesh, in the order of
    /// [`TriMeshTopology::edges`](crate::mesh::TriMeshTopology::edges). `modulus` is `E2` per
    /// triangle; the baselines ignore it.
    pub fn edge_stiffness(
        &self,
        mesh: &TriMesh,
        modulus: &Modulus,
    ) -> Result<Vec<f32>, StiffnessError> {
        let topo = mesh.topology();
        let lengths = mesh.edge_lengths();
        let k: Vec<f64> = match *self {
            StiffnessRule::Constant { k_n_per_m } => {
                positive("k_n_per_m", k_n_per_m)?;
                vec![k_n_per_m as f64; lengths.len()]
            }
            StiffnessRule::InverseLength { e1_n } => {
                positive("e1_n", e1_n)?;
                lengths.iter().map(|&l| e1_n as f64 / l as f64).collect()
            }
            StiffnessRule::AreaOverLengthSquared => {
                modulus.validate(mesh.triangles().len())?;
                let mut k = vec![0.0f64; lengths.len()];
                for (t, edges) in topo.triangle_edges().iter().enumerate() {
                    let ea = modulus.at(t) as f64 * mesh.triangle_area(t) as f64;
                    for &e in edges {
                        let l = lengths[e as usize] as f64;
                        k[e as usize] += ea / (l * l);
                    }
                }
                k
            }
            StiffnessRule::Poisson { nu, obtuse_floor } => {
                if !(0.0..0.5).contains(&nu) {
                    return Err(StiffnessError::BadPoisson(nu));
                }
                positive("obtuse_floor", obtuse_floor)?;
                modulus.validate(mesh.triangles().len())?;
                let mut k = vec![0.0f64; lengths.len()];
                for (t, edges) in topo.triangle_edges().iter().enumerate() {
                    let l = edges.map(|e| lengths[e as usize] as f64);
                    let e2 = modulus.at(t) as f64;
                    for i in 0..3 {
                        let (c, a, b) = (l[i], l[(i + 1) % 3], l[(i + 2) % 3]);
                        let contribution = poisson_contribution(e2, nu as f64, a, b, c);
                        let floor = obtuse_floor as f64 * e2 * heron_area(a, b, c) / (c * c);
                        k[edges[i] as usize] += contribution.max(floor);
                    }
                }
                k
            }
            StiffnessRule::Tetrahedral => return Err(StiffnessError::NeedsTetrahedra),
        };
        Ok(k.into_iter().map(|k| k as f32).collect())
    }
}

impl Default for StiffnessRule {
    /// Eq. 29, the rule the paper recommends.
    fn default() -> Self {
        StiffnessRule::AreaOverLengthSquared
    }
}

/// One triangle's Eq. 27 contribution to edge `c`, with `a`, `b` the other two edge lengths.
pub fn poisson_contribution(e2: f64, nu: f64, a: f64, b: f64, c: f64) -> f64 {
    let area = heron_area(a, b, c);
    e2 / (1.0 + nu) * area / (c * c)
        + e2 * nu / (1.0 - nu * nu) * (a * a + b * b - c * c) / (8.0 * area)
}

/// Triangle area from its edge lengths (Eq. 28), in the numerically stable ordering of Kahan.
pub fn heron_area(a: f64, b: f64, c: f64) -> f64 {
    let mut s = [a, b, c];
    s.sort_by(|x, y| y.total_cmp(x));
    let [a, b, c] = s;
    let p = (a + (b + c)) * (c - (a - b)) * (c + (a - b)) * (a + (b - c));
    0.25 * p.max(0.0).sqrt()
}

/// Van Gelder Eq. 30 on a tetrahedral mesh: `k_c = E * Σ vol(T) / |c|²` over the tetrahedra
/// sharing edge `c`, in the order of [`TetMesh::edges`]. `modulus` is the 3D Young's modulus
/// per tetrahedron (N/m²).
///
/// Unlike the 2D rule, this one is not scale invariant: doubling the mesh doubles `k`.
pub fn tetrahedral_stiffness(
    mesh: &TetMesh,
    modulus: &Modulus,
) -> Result<Vec<f32>, StiffnessError> {
    modulus.validate(mesh.tets().len())?;
    let lengths = mesh.edge_lengths();
    Ok((0..mesh.edges().len())
        .map(|e| {
            let l = lengths[e] as f64;
            let sum: f64 = mesh
                .edge_tets(e)
                .iter()
                .map(|&t| modulus.at(t as usize) as f64 * mesh.volume(t as usize) as f64)
                .sum();
            (sum / (l * l)) as f32
        })
        .collect())
}

fn positive(name: &'static str, v: f32) -> Result<(), StiffnessError> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(StiffnessError::NotPositive { name, value: v })
    }
}

/// Why stiffness could not be computed.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum StiffnessError {
    /// A Young's modulus is zero, negative or not finite.
    #[error("Young's modulus {value} {} must be finite and positive", match element { Some(e) => format!("of element {e}"), None => String::new() })]
    BadModulus {
        /// The element, or `None` for a uniform modulus.
        element: Option<usize>,
        /// The value given.
        value: f32,
    },
    /// A per-element modulus list does not have one entry per element.
    #[error("{given} per-element moduli given for {elements} elements")]
    ModulusCount {
        /// Entries given.
        given: usize,
        /// Elements in the mesh.
        elements: usize,
    },
    /// The Poisson ratio is outside `[0, 0.5)`.
    #[error("Poisson ratio {0} is outside [0, 0.5)")]
    BadPoisson(f32),
    /// A rule parameter is zero, negative or not finite.
    #[error("{name} = {value} must be finite and positive")]
    NotPositive {
        /// Parameter name.
        name: &'static str,
        /// The value given.
        value: f32,
    },
    /// [`StiffnessRule::Tetrahedral`] was asked of a triangle mesh; use
    /// [`tetrahedral_stiffness`] on a [`TetMesh`].
    #[error("the tetrahedral rule needs a tetrahedral mesh")]
    NeedsTetrahedra,
}

#[cfg(test)]
mod tests {
    use approx::assert_relative_eq;
    use glam::Vec3;

    use super::*;

    fn tri(p: [Vec3; 3]) -> TriMesh {
        TriMesh::new(p.to_vec(), vec![[0, 1, 2]]).unwrap()
    }

    /// Sec. 5.1: the 2D stiffness depends only on shape, the 3D one on scale too.
    #[test]
    fn triangle_stiffness_is_scale_invariant_tetrahedral_is_not() {
        let p = [
            Vec3::ZERO,
            Vec3::new(1.3, 0.1, 0.0),
            Vec3::new(0.4, 0.9, 0.2),
        ];
        for rule in [
            StiffnessRule::AreaOverLengthSquared,
            StiffnessRule::poisson(0.3),
        ] {
            let k1 = rule
                .edge_stiffness(&tri(p), &Modulus::Uniform(7.0))
                .unwrap();
            let k3 = rule
                .edge_stiffness(&tri(p.map(|v| v * 3.0)), &Modulus::Uniform(7.0))
                .unwrap();
            for (a, b) in k1.iter().zip(&k3) {
                assert_relative_eq!(a, b, max_relative = 1e-5);
            }
        }
        let q = vec![
            Vec3::ZERO,
            Vec3::X,
            Vec3::new(0.2, 1.1, 0.0),
            Vec3::new(0.3, 0.2, 0.8),
        ];
        let t1 = TetMesh::new(q.clone(), vec![[0, 1, 2, 3]]).unwrap();
        let t3 = TetMesh::new(q.iter().map(|v| *v * 3.0).collect(), vec![[0, 1, 2, 3]]).unwrap();
        let k1 = tetrahedral_stiffness(&t1, &Modulus::Uniform(5.0)).unwrap();
        let k3 = tetrahedral_stiffness(&t3, &Modulus::Uniform(5.0)).unwrap();
        for (a, b) in k1.iter().zip(&k3) {
            // vol scales by 27, |c|² by 9.
            assert_relative_eq!(*b, 3.0 * a, max_relative = 1e-5);
        }
    }

    #[test]
    fn tetrahedral_sums_over_incident_tets() {
        let p = vec![
            Vec3::ZERO,
            Vec3::X,
            Vec3::Y,
            Vec3::Z,
            Vec3::new(1.0, 1.0, 1.0),
        ];
        let m = TetMesh::new(p, vec![[0, 1, 2, 3], [1, 2, 3, 4]]).unwrap();
        let k = tetrahedral_stiffness(&m, &Modulus::PerElement(vec![2.0, 3.0])).unwrap();
        let e12 = m.edges().iter().position(|&e| e == [1, 2]).unwrap();
        let expect = (2.0 * m.volume(0) + 3.0 * m.volume(1)) / 2.0; // |c|² = 2
        assert_relative_eq!(k[e12], expect, max_relative = 1e-6);
    }

    /// With nu = 0, Eq. 27 is Eq. 29 exactly; Eq. 28 agrees with the cross-product area.
    #[test]
    fn poisson_with_zero_nu_is_area_over_length_squared() {
        let m = tri([
            Vec3::ZERO,
            Vec3::new(2.0, 0.3, 0.0),
            Vec3::new(0.7, 1.5, 0.0),
        ]);
        let a = StiffnessRule::AreaOverLengthSquared
            .edge_stiffness(&m, &Modulus::Uniform(3.0))
            .unwrap();
        let b = StiffnessRule::poisson(0.0)
            .edge_stiffness(&m, &Modulus::Uniform(3.0))
            .unwrap();
        for (x, y) in a.iter().zip(&b) {
            assert_relative_eq!(x, y, max_relative = 1e-5);
        }
    }

    /// Eq. 27 matches its trigonometric form Eq. 26 on an acute triangle.
    #[test]
    fn poisson_matches_trigonometric_form() {
        let p = [
            Vec3::ZERO,
            Vec3::new(2.0, 0.0, 0.0),
            Vec3::new(0.8, 1.4, 0.0),
        ];
        let m = tri(p);
        let nu = 0.3f64;
        let k = StiffnessRule::poisson(nu as f32)
            .edge_stiffness(&m, &Modulus::Uniform(1.0))
            .unwrap();
        // Edge c = (0,1); alpha at vertex 0 is opposite edge (1,2)... use the angles at the
        // ends of c: the formula is symmetric in alpha, beta.
        let ang = |o: Vec3, u: Vec3, v: Vec3| (u - o).angle_between(v - o) as f64;
        let alpha = ang(p[0], p[1], p[2]);
        let beta = ang(p[1], p[0], p[2]);
        let gamma = ang(p[2], p[0], p[1]);
        let eq26 = 1.0 / (1.0 - nu * nu)
            * (alpha.sin() * beta.sin() - nu * alpha.cos() * beta.cos())
            / (2.0 * gamma.sin());
        let e01 = m
            .topology()
            .edges()
            .iter()
            .position(|&e| e == [0, 1])
            .unwrap();
        assert_relative_eq!(k[e01] as f64, eq26, max_relative = 1e-5);
    }

    /// The obtuse policy: no edge ends up with k <= 0, even on very obtuse triangles where raw
    /// Eq. 27 is negative.
    #[test]
    fn poisson_never_gives_non_positive_stiffness() {
        let m = tri([
            Vec3::ZERO,
            Vec3::new(4.0, 0.0, 0.0),
            Vec3::new(2.0, 0.1, 0.0),
        ]);
        let l = m.edge_lengths();
        let long = l.iter().cloned().fold(0.0, f32::max) as f64;
        let short = l.iter().cloned().fold(f32::MAX, f32::min) as f64;
        let raw = poisson_contribution(1.0, 0.45, short, short, long);
        assert!(
            raw < 0.0,
            "the test triangle must make raw Eq. 27 negative, got {raw}"
        );
        for nu in [0.0, 0.25, 0.45, 0.499] {
            let k = StiffnessRule::poisson(nu)
                .edge_stiffness(&m, &Modulus::Uniform(1.0))
                .unwrap();
            assert!(k.iter().all(|&k| k > 0.0), "nu {nu}: {k:?}");
        }
    }

    #[test]
    fn per_triangle_modulus_weights_each_side() {
        let p = vec![Vec3::ZERO, Vec3::X, Vec3::new(1.0, 1.0, 0.0), Vec3::Y];
        let m = TriMesh::new(p, vec![[0, 1, 2], [0, 2, 3]]).unwrap();
        let k = StiffnessRule::AreaOverLengthSquared
            .edge_stiffness(&m, &Modulus::PerElement(vec![1.0, 3.0]))
            .unwrap();
        // Diagonal (0,2): (1*0.5 + 3*0.5) / 2 = 1.
        assert_relative_eq!(k[1], 1.0, max_relative = 1e-6);
        assert_eq!(
            StiffnessRule::AreaOverLengthSquared
                .edge_stiffness(&m, &Modulus::PerElement(vec![1.0])),
            Err(StiffnessError::ModulusCount {
                given: 1,
                elements: 2
            })
        );
        assert!(matches!(
            StiffnessRule::AreaOverLengthSquared
                .edge_stiffness(&m, &Modulus::PerElement(vec![1.0, f32::NAN])),
            Err(StiffnessError::BadModulus {
                element: Some(1),
                ..
            })
        ));
    }

    #[test]
    fn baselines_ignore_geometry_as_documented() {
        let m = tri([
            Vec3::ZERO,
            Vec3::new(2.0, 0.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
        ]);
        let k = StiffnessRule::Constant { k_n_per_m: 4.0 }
            .edge_stiffness(&m, &Modulus::Uniform(1.0))
            .unwrap();
        assert_eq!(k, vec![4.0; 3]);
        let k = StiffnessRule::InverseLength { e1_n: 4.0 }
            .edge_stiffness(&m, &Modulus::Uniform(1.0))
            .unwrap();
        let l = m.edge_lengths();
        for (k, l) in k.iter().zip(l) {
            assert_relative_eq!(k * l, 4.0, max_relative = 1e-6);
        }
    }
}
