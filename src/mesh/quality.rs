//! Mesh quality figures: triangle angles, obtuse and near-degenerate counts.

use serde::Serialize;

use super::TriMesh;

/// Smallest angle (degrees) under which a triangle counts as near-degenerate.
pub const NEAR_DEGENERATE_ANGLE_DEG: f32 = 5.0;

/// Figures that tell whether a mesh is fit for spring-mesh simulation.
///
/// Obtuse triangles matter for the Poisson stiffness rule (Eq. 27 can go negative opposite an
/// obtuse angle); near-degenerate ones make stiffness and normals ill-conditioned.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MeshQuality {
    /// Number of vertices.
    pub vertices: usize,
    /// Number of triangles.
    pub triangles: usize,
    /// Number of unique edges.
    pub edges: usize,
    /// Number of edges with a single triangle.
    pub boundary_edges: usize,
    /// Triangles with an angle above 90 degrees.
    pub obtuse_triangles: usize,
    /// Triangles with an angle below [`NEAR_DEGENERATE_ANGLE_DEG`].
    pub near_degenerate_triangles: usize,
    /// Smallest triangle angle, degrees.
    pub min_angle_deg: f32,
    /// Median of all triangle angles, degrees.
    pub median_angle_deg: f32,
    /// Largest triangle angle, degrees.
    pub max_angle_deg: f32,
    /// Ratio of the largest to the smallest triangle area.
    pub area_ratio: f32,
}

impl MeshQuality {
    /// Computes the report for `mesh`.
    pub fn of(mesh: &TriMesh) -> Self {
        let p = mesh.positions();
        let mut angles = Vec::with_capacity(mesh.triangles().len() * 3);
        let (mut obtuse, mut degenerate) = (0, 0);
        let (mut amin, mut amax) = (f32::INFINITY, 0.0f32);
        for (t, tri) in mesh.triangles().iter().enumerate() {
            let v = tri.map(|i| p[i as usize]);
            let mut worst_small = f32::INFINITY;
            let mut worst_big = 0.0f32;
            for i in 0..3 {
                let a = v[(i + 1) % 3] - v[i];
                let b = v[(i + 2) % 3] - v[i];
                let angle = a.angle_between(b).to_degrees();
                worst_small = worst_small.min(angle);
                worst_big = worst_big.max(angle);
                angles.push(angle);
            }
            obtuse += usize::from(worst_big > 90.0);
            degenerate += usize::from(worst_small < NEAR_DEGENERATE_ANGLE_DEG);
            let area = mesh.triangle_area(t);
            amin = amin.min(area);
            amax = amax.max(area);
        }
        angles.sort_unstable_by(f32::total_cmp);
        let topo = mesh.topology();
        Self {
            vertices: p.len(),
            triangles: mesh.triangles().len(),
            edges: topo.edges().len(),
            boundary_edges: topo.boundary_edges().count(),
            obtuse_triangles: obtuse,
            near_degenerate_triangles: degenerate,
            min_angle_deg: angles[0],
            median_angle_deg: angles[angles.len() / 2],
            max_angle_deg: angles[angles.len() - 1],
            area_ratio: amax / amin,
        }
    }
}

#[cfg(test)]
mod tests {
    use glam::Vec3;

    use super::*;

    #[test]
    fn counts_obtuse_and_slivers() {
        // Right triangle, an obtuse one (102.7 degrees) and a needle (4.6 degrees).
        let p = vec![
            Vec3::ZERO,
            Vec3::X,
            Vec3::Y,
            Vec3::new(0.5, -0.4, 0.0),
            Vec3::new(11.0, 0.4, 0.0),
            Vec3::new(11.0, -0.4, 0.0),
        ];
        let m = TriMesh::new(p, vec![[0, 1, 2], [0, 3, 1], [1, 4, 5]]).unwrap();
        let q = m.quality();
        assert_eq!(q.triangles, 3);
        assert_eq!(q.obtuse_triangles, 1);
        assert_eq!(q.near_degenerate_triangles, 1);
        assert!(
            (q.max_angle_deg - (180.0 - 2.0 * 38.66)).abs() < 0.1,
            "{}",
            q.max_angle_deg
        );
        assert!((q.min_angle_deg - 2.0 * 0.04f32.atan().to_degrees()).abs() < 0.01);
    }
}
