//! Vertex normals and per-vertex strain for export, and the strain colour map.

use glam::{DVec3, Vec3};

/// Angle-weighted vertex normals (Thürmer and Wüthrich): each triangle adds its unit normal
/// times its interior angle at the vertex, the sum is normalised. Unlike area weighting the
/// result does not depend on how a flat region is triangulated. Vertices touched by no
/// non-degenerate triangle get `+Z`.
///
/// Indices must be in range (the sinks check this before calling).
///
/// ```
/// use dermis::export::vertex_normals;
/// use glam::Vec3;
/// let n = vertex_normals(&[[0, 1, 2]], &[Vec3::ZERO, Vec3::X, Vec3::Y]);
/// assert_eq!(n, vec![Vec3::Z; 3]);
/// ```
pub fn vertex_normals(triangles: &[[u32; 3]], positions: &[Vec3]) -> Vec<Vec3> {
    let mut acc = vec![DVec3::ZERO; positions.len()];
    for tri in triangles {
        let p = tri.map(|v| positions[v as usize].as_dvec3());
        let face = (p[1] - p[0]).cross(p[2] - p[0]);
        let Some(unit) = face.try_normalize() else {
            continue;
        };
        for k in 0..3 {
            let e1 = p[(k + 1) % 3] - p[k];
            let e2 = p[(k + 2) % 3] - p[k];
            let angle = e1.cross(e2).length().atan2(e1.dot(e2));
            acc[tri[k] as usize] += unit * angle;
        }
    }
    acc.into_iter()
        .map(|n| n.try_normalize().map_or(Vec3::Z, |n| n.as_vec3()))
        .collect()
}

/// How the stretch of a triangle relative to its rest shape is measured. Both are 1 at rest.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum StrainMeasure {
    /// Largest principal stretch `λ₁` of the triangle's deformation (`sqrt` of the largest
    /// eigenvalue of the right Cauchy–Green tensor): shows stretching in any one direction,
    /// even when the area is preserved.
    #[default]
    MaxPrincipalStretch,
    /// Area ratio `J = A / A_rest = λ₁ λ₂`.
    AreaStretch,
}

/// Rest metric of each triangle, for strain.
#[derive(Debug, Clone)]
pub(super) struct RestShape {
    triangles: Vec<[u32; 3]>,
    /// Inverse rest metric `G⁻¹` as (a, b, c) of `[[a, b], [b, c]]`, or `None` if degenerate.
    inv_metric: Vec<Option<[f64; 3]>>,
    /// Rest area of each triangle (weight of its strain at its vertices), m².
    area: Vec<f64>,
    /// Sum of incident rest areas per vertex.
    vertex_area: Vec<f64>,
}

fn metric(p: [DVec3; 3]) -> [f64; 3] {
    let e1 = p[1] - p[0];
    let e2 = p[2] - p[0];
    [e1.dot(e1), e1.dot(e2), e2.dot(e2)]
}

impl RestShape {
    pub(super) fn new(triangles: &[[u32; 3]], rest: &[Vec3]) -> Self {
        let mut inv_metric = Vec::with_capacity(triangles.len());
        let mut area = Vec::with_capacity(triangles.len());
        let mut vertex_area = vec![0.0; rest.len()];
        for tri in triangles {
            let [a, b, c] = metric(tri.map(|v| rest[v as usize].as_dvec3()));
            let det = a * c - b * b;
            // Same relative threshold as the mesh module's degenerate-triangle test (area²).
            if det > 1e-14 * (a.max(c) * a.max(c)) && det.is_finite() {
                inv_metric.push(Some([c / det, -b / det, a / det]));
                let tri_area = 0.5 * det.sqrt();
                area.push(tri_area);
                for &v in tri {
                    vertex_area[v as usize] += tri_area;
                }
            } else {
                inv_metric.push(None);
                area.push(0.0);
            }
        }
        Self {
            triangles: triangles.to_vec(),
            inv_metric,
            area,
            vertex_area,
        }
    }

    /// Stretch per vertex: rest-area-weighted mean of the incident triangles' stretch; 1 for
    /// vertices without a non-degenerate triangle.
    pub(super) fn vertex_strain(&self, current: &[Vec3], measure: StrainMeasure) -> Vec<f32> {
        let mut acc = vec![0.0f64; self.vertex_area.len()];
        for ((tri, inv), &w) in self.triangles.iter().zip(&self.inv_metric).zip(&self.area) {
            let Some([ia, ib, ic]) = *inv else {
                continue;
            };
            let [a, b, c] = metric(tri.map(|v| current[v as usize].as_dvec3()));
            // Eigenvalues of C = G⁻¹ G' (the right Cauchy–Green tensor in the rest frame).
            let (c11, c12, c21, c22) = (
                ia * a + ib * b,
                ia * b + ib * c,
                ib * a + ic * b,
                ib * b + ic * c,
            );
            let det = (c11 * c22 - c12 * c21).max(0.0);
            let s = match measure {
                StrainMeasure::AreaStretch => det.sqrt(),
                StrainMeasure::MaxPrincipalStretch => {
                    let half_tr = 0.5 * (c11 + c22);
                    let disc = (half_tr * half_tr - det).max(0.0).sqrt();
                    (half_tr + disc).max(0.0).sqrt()
                }
            };
            for &v in tri {
                acc[v as usize] += w * s;
            }
        }
        acc.iter()
            .zip(&self.vertex_area)
            .map(|(&s, &w)| if w > 0.0 { (s / w) as f32 } else { 1.0 })
            .collect()
    }
}

/// Per-vertex stretch of `current` relative to `rest` (1 = unstrained): each triangle's stretch
/// by `measure`, averaged to its vertices weighted by rest area. Vertices touched by no
/// non-degenerate triangle get 1.
///
/// ```
/// use dermis::export::{StrainMeasure, vertex_strain};
/// use glam::Vec3;
/// let rest = [Vec3::ZERO, Vec3::X, Vec3::Y];
/// let pulled = [Vec3::ZERO, 1.5 * Vec3::X, Vec3::Y]; // 50 % longer along x
/// let s = vertex_strain(&[[0, 1, 2]], &rest, &pulled, StrainMeasure::MaxPrincipalStretch);
/// assert!((s[0] - 1.5).abs() < 1e-6);
/// ```
pub fn vertex_strain(
    triangles: &[[u32; 3]],
    rest: &[Vec3],
    current: &[Vec3],
    measure: StrainMeasure,
) -> Vec<f32> {
    RestShape::new(triangles, rest).vertex_strain(current, measure)
}

/// Diverging colour map for stretch `s` (linear RGB in 0..=1):
/// `s ≤ 1 − range` is blue `(0, 0, 1)` (compressed), `s = 1` white `(1, 1, 1)` (rest),
/// `s ≥ 1 + range` red `(1, 0, 0)` (stretched), linear in between.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StrainColorMap {
    /// Which stretch is shown.
    pub measure: StrainMeasure,
    /// Relative stretch at which the colour saturates (default 0.25: 25 %).
    pub range: f32,
}

impl Default for StrainColorMap {
    fn default() -> Self {
        Self {
            measure: StrainMeasure::default(),
            range: 0.25,
        }
    }
}

impl StrainColorMap {
    /// The colour of stretch `s`.
    ///
    /// ```
    /// use dermis::export::StrainColorMap;
    /// let map = StrainColorMap::default();
    /// assert_eq!(map.color(1.0), [1.0, 1.0, 1.0]);
    /// assert_eq!(map.color(2.0), [1.0, 0.0, 0.0]);
    /// assert_eq!(map.color(0.5), [0.0, 0.0, 1.0]);
    /// ```
    pub fn color(&self, s: f32) -> [f32; 3] {
        let t = ((s - 1.0) / self.range).clamp(-1.0, 1.0);
        let t = if t.is_nan() { 0.0 } else { t };
        if t >= 0.0 {
            [1.0, 1.0 - t, 1.0 - t]
        } else {
            [1.0 + t, 1.0 + t, 1.0]
        }
    }
}

/// Colour as 8-bit, rounded.
pub(super) fn to_u8(c: [f32; 3]) -> [u8; 3] {
    c.map(|x| (x.clamp(0.0, 1.0) * 255.0).round() as u8)
}
