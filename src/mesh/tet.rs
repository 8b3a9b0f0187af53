//! Tetrahedral meshes: unique edges and the tetrahedra incident to each.

use glam::Vec3;

use super::{TopologyError, check_element, check_finite};

/// A validated tetrahedral mesh, for the 3D stiffness rule (Van Gelder Eq. 30).
///
/// Edges are unique with `a < b` in lexicographic order; `edge_tets(e)` lists the tetrahedra
/// sharing edge `e` (any number).
///
/// ```
/// use dermis::mesh::TetMesh;
/// use glam::Vec3;
/// let tet = TetMesh::new(vec![Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::Z], vec![[0, 1, 2, 3]]).unwrap();
/// assert_eq!(tet.edges().len(), 6);
/// assert!((tet.volume(0) - 1.0 / 6.0).abs() < 1e-6);
/// ```
#[derive(Debug, Clone, PartialEq)]
pub struct TetMesh {
    positions: Vec<Vec3>,
    tets: Vec<[u32; 4]>,
    edges: Vec<[u32; 2]>,
    edge_tet_offsets: Vec<u32>,
    edge_tet_list: Vec<u32>,
}

impl TetMesh {
    /// Validates and builds a tetrahedral mesh (finite positions, indices in range, no repeated
    /// vertex, no zero-volume tetrahedron).
    pub fn new(positions: Vec<Vec3>, tets: Vec<[u32; 4]>) -> Result<Self, TopologyError> {
        if tets.is_empty() {
            return Err(TopologyError::Empty);
        }
        if positions.len() >= u32::MAX as usize || tets.len() >= u32::MAX as usize / 6 {
            return Err(TopologyError::TooLarge);
        }
        check_finite(&positions)?;
        for (t, tet) in tets.iter().enumerate() {
            check_element(t, tet, positions.len())?;
            let [a, b, c, d] = tet.map(|i| positions[i as usize]);
            let vol = (b - a).cross(c - a).dot(d - a).abs() / 6.0;
            let longest = [b - a, c - a, d - a, c - b, d - b, d - c]
                .iter()
                .map(|e| e.length())
                .fold(0.0f32, f32::max);
            if vol.is_nan() || vol <= super::DEGENERATE_AREA_RATIO * longest.powi(3) {
                return Err(TopologyError::Degenerate { element: t });
            }
        }
        const PAIRS: [(usize, usize); 6] = [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)];
        let mut half: Vec<(u32, u32, u32)> = Vec::with_capacity(tets.len() * 6);
        for (t, tet) in tets.iter().enumerate() {
            for (i, j) in PAIRS {
                let (a, b) = (tet[i].min(tet[j]), tet[i].max(tet[j]));
                half.push((a, b, t as u32));
            }
        }
        half.sort_unstable();
        let mut edges: Vec<[u32; 2]> = Vec::new();
        let mut edge_tet_offsets = vec![0u32];
        let mut edge_tet_list = Vec::with_capacity(half.len());
        for (a, b, t) in half {
            if edges.last() != Some(&[a, b]) {
                if !edges.is_empty() {
                    edge_tet_offsets.push(edge_tet_list.len() as u32);
                }
                edges.push([a, b]);
            }
            edge_tet_list.push(t);
        }
        edge_tet_offsets.push(edge_tet_list.len() as u32);
        Ok(Self {
            positions,
            tets,
            edges,
            edge_tet_offsets,
            edge_tet_list,
        })
    }

    /// Rest positions.
    pub fn positions(&self) -> &[Vec3] {
        &self.positions
    }
    /// The tetrahedra.
    pub fn tets(&self) -> &[[u32; 4]] {
        &self.tets
    }
    /// Unique edges.
    pub fn edges(&self) -> &[[u32; 2]] {
        &self.edges
    }
    /// The tetrahedra incident to edge `e`, in increasing order.
    pub fn edge_tets(&self, e: usize) -> &[u32] {
        &self.edge_tet_list
            [self.edge_tet_offsets[e] as usize..self.edge_tet_offsets[e + 1] as usize]
    }
    /// Unsigned volume of tetrahedron `t` at rest.
    pub fn volume(&self, t: usize) -> f32 {
        let [a, b, c, d] = self.tets[t].map(|i| self.positions[i as usize]);
        (b - a).cross(c - a).dot(d - a).abs() / 6.0
    }
    /// Rest length of every edge.
    pub fn edge_lengths(&self) -> Vec<f32> {
        self.edges
            .iter()
            .map(|&[a, b]| (self.positions[a as usize] - self.positions[b as usize]).length())
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn two_tets_share_a_face() {
        let p = vec![
            Vec3::ZERO,
            Vec3::X,
            Vec3::Y,
            Vec3::Z,
            Vec3::new(1.0, 1.0, 1.0),
        ];
        let m = TetMesh::new(p, vec![[0, 1, 2, 3], [1, 2, 3, 4]]).unwrap();
        assert_eq!(m.edges().len(), 9);
        let shared = m.edges().iter().position(|&e| e == [1, 2]).unwrap();
        assert_eq!(m.edge_tets(shared), &[0, 1]);
        let only_first = m.edges().iter().position(|&e| e == [0, 1]).unwrap();
        assert_eq!(m.edge_tets(only_first), &[0]);
    }

    #[test]
    fn flat_tet_is_rejected() {
        let p = vec![Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::new(1.0, 1.0, 0.0)];
        assert_eq!(
            TetMesh::new(p, vec![[0, 1, 2, 3]]).unwrap_err(),
            TopologyError::Degenerate { element: 0 }
        );
    }
}
