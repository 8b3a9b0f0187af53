//! Mesh topology: unique edges, incident triangles per edge, CSR vertex adjacency, boundary,
//! tetrahedral topology and a quality report, all validated with [`TopologyError`].

mod quality;
pub mod shapes;
mod tet;

pub use quality::{MeshQuality, NEAR_DEGENERATE_ANGLE_DEG};
pub use tet::TetMesh;

use glam::Vec3;
use thiserror::Error;

/// Marker in [`TriMeshTopology::edge_triangles`] for "no second triangle" (a boundary edge).
pub const NO_TRIANGLE: u32 = u32::MAX;

/// Why a mesh was rejected. Every variant names the offending element so it can be fixed in the
/// modelling tool that produced the mesh.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum TopologyError {
    /// The mesh has no triangles (or tetrahedra) at all.
    #[error("the mesh has no elements")]
    Empty,
    /// A vertex position is NaN or infinite. Fix the exporter or the simulation that produced it.
    #[error("vertex {vertex} has a non-finite coordinate {position:?}")]
    NonFinite {
        /// Index of the vertex.
        vertex: usize,
        /// Its position as read.
        position: [f32; 3],
    },
    /// An element refers to a vertex index that does not exist.
    #[error(
        "element {element} refers to vertex {index}, but the mesh has only {vertex_count} vertices"
    )]
    IndexOutOfRange {
        /// Index of the triangle or tetrahedron.
        element: usize,
        /// The bad vertex index.
        index: u32,
        /// Number of vertices in the mesh.
        vertex_count: usize,
    },
    /// An element uses the same vertex twice. Remove the degenerate element.
    #[error("element {element} has two identical vertices ({index})")]
    RepeatedVertex {
        /// Index of the triangle or tetrahedron.
        element: usize,
        /// The repeated vertex index.
        index: u32,
    },
    /// A triangle has (numerically) zero area, or a tetrahedron zero volume: its stiffness and
    /// normals are undefined. Collapse it in the modelling tool.
    #[error("element {element} is degenerate (zero area or volume)")]
    Degenerate {
        /// Index of the triangle or tetrahedron.
        element: usize,
    },
    /// More than two triangles share an edge, so the surface is not a 2-manifold.
    #[error(
        "edge ({a}, {b}) is shared by more than two triangles (triangle {element} is the third)"
    )]
    NonManifoldEdge {
        /// First vertex of the edge.
        a: u32,
        /// Second vertex of the edge.
        b: u32,
        /// The first triangle found beyond the second.
        element: usize,
    },
    /// New positions do not have one entry per vertex of the mesh.
    #[error("{given} positions given for a mesh of {expected} vertices")]
    VertexCount {
        /// Positions given.
        given: usize,
        /// Vertices in the mesh.
        expected: usize,
    },
    /// The mesh has more vertices or elements than 32-bit indices can address.
    #[error("the mesh is too large for 32-bit indices")]
    TooLarge,
}

/// Relative area threshold under which a triangle counts as degenerate: `area < DEGENERATE *
/// longest_edge²`.
pub const DEGENERATE_AREA_RATIO: f32 = 1e-7;

/// Validated triangle-mesh connectivity.
///
/// Edges are unique, stored with `a < b`, in lexicographic order, so the same triangles always
/// give the same edge numbering. The adjacency is CSR: the neighbours of vertex `v` are
/// `adjacency[offsets[v]..offsets[v + 1]]`, in increasing vertex order, each with the edge that
/// joins them.
///
/// ```
/// use dermis::mesh::TriMeshTopology;
/// // Two triangles sharing the diagonal of a unit square.
/// let topo = TriMeshTopology::new(4, &[[0, 1, 2], [0, 2, 3]]).unwrap();
/// assert_eq!(topo.edges().len(), 5);
/// assert_eq!(topo.boundary_edges().count(), 4);
/// assert_eq!(topo.neighbors(0).len(), 3);
/// ```
#[derive(Debug, Clone, PartialEq)]
pub struct TriMeshTopology {
    vertex_count: usize,
    triangles: Vec<[u32; 3]>,
    edges: Vec<[u32; 2]>,
    edge_triangles: Vec<[u32; 2]>,
    triangle_edges: Vec<[u32; 3]>,
    offsets: Vec<u32>,
    adjacency: Vec<Neighbor>,
}

/// One entry of the CSR vertex adjacency: a neighbouring vertex and the edge that joins them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Neighbor {
    /// The neighbouring vertex.
    pub vertex: u32,
    /// Index into [`TriMeshTopology::edges`].
    pub edge: u32,
}

impl TriMeshTopology {
    /// Builds the topology of `triangles` over `vertex_count` vertices.
    ///
    /// Checks indices, repeated vertices and manifold edges (at most two triangles per edge);
    /// geometry checks (non-finite, zero area) are in [`TriMesh::new`].
    pub fn new(vertex_count: usize, triangles: &[[u32; 3]]) -> Result<Self, TopologyError> {
        if triangles.is_empty() {
            return Err(TopologyError::Empty);
        }
        if vertex_count >= u32::MAX as usize || triangles.len() >= u32::MAX as usize / 3 {
            return Err(TopologyError::TooLarge);
        }
        for (t, tri) in triangles.iter().enumerate() {
            check_element(t, tri, vertex_count)?;
        }
        // Half-edges (min, max, triangle, local edge), sorted: the unique edges in lexicographic
        // order fall out, each with its incident triangles in increasing triangle order.
        let mut half: Vec<(u32, u32, u32, u8)> = Vec::with_capacity(triangles.len() * 3);
        for (t, tri) in triangles.iter().enumerate() {
            for local in 0..3u8 {
                // Local edge `local` is opposite vertex `local`.
                let a = tri[(local as usize + 1) % 3];
                let b = tri[(local as usize + 2) % 3];
                half.push((a.min(b), a.max(b), t as u32, local));
            }
        }
        half.sort_unstable();
        let mut edges = Vec::with_capacity(half.len() / 2 + 1);
        let mut edge_triangles: Vec<[u32; 2]> = Vec::with_capacity(half.len() / 2 + 1);
        let mut triangle_edges = vec![[0u32; 3]; triangles.len()];
        for &(a, b, t, local) in &half {
            let same = edges.last().is_some_and(|e: &[u32; 2]| *e == [a, b]);
            if same {
                let et = edge_triangles
                    .last_mut()
                    .expect("edge pushed with its triangles");
                if et[1] != NO_TRIANGLE {
                    return Err(TopologyError::NonManifoldEdge {
                        a,
                        b,
                        element: t as usize,
                    });
                }
                et[1] = t;
            } else {
                edges.push([a, b]);
                edge_triangles.push([t, NO_TRIANGLE]);
            }
            triangle_edges[t as usize][local as usize] = (edges.len() - 1) as u32;
        }
        let (offsets, adjacency) = build_csr(vertex_count, &edges);
        Ok(Self {
            vertex_count,
            triangles: triangles.to_vec(),
            edges,
            edge_triangles,
            triangle_edges,
            offsets,
            adjacency,
        })
    }

    /// Number of vertices (including any not used by a triangle).
    pub fn vertex_count(&self) -> usize {
        self.vertex_count
    }
    /// The triangles, as given.
    pub fn triangles(&self) -> &[[u32; 3]] {
        &self.triangles
    }
    /// Unique edges, `a < b`, in lexicographic order.
    pub fn edges(&self) -> &[[u32; 2]] {
        &self.edges
    }
    /// For each edge, its one or two incident triangles; the second is [`NO_TRIANGLE`] on the
    /// boundary.
    pub fn edge_triangles(&self) -> &[[u32; 2]] {
        &self.edge_triangles
    }
    /// For each triangle, its three edges; entry `i` is the edge opposite vertex `i`.
    pub fn triangle_edges(&self) -> &[[u32; 3]] {
        &self.triangle_edges
    }
    /// CSR offsets: `vertex_count + 1` entries.
    pub fn offsets(&self) -> &[u32] {
        &self.offsets
    }
    /// CSR adjacency entries (each edge appears twice, once from each end).
    pub fn adjacency(&self) -> &[Neighbor] {
        &self.adjacency
    }
    /// Neighbours of vertex `v`, in increasing vertex order.
    pub fn neighbors(&self, v: usize) -> &[Neighbor] {
        &self.adjacency[self.offsets[v] as usize..self.offsets[v + 1] as usize]
    }
    /// Indices of the edges with a single incident triangle.
    pub fn boundary_edges(&self) -> impl Iterator<Item = usize> + '_ {
        self.edge_triangles
            .iter()
            .enumerate()
            .filter(|(_, t)| t[1] == NO_TRIANGLE)
            .map(|(e, _)| e)
    }
    /// `true` for every vertex on a boundary edge.
    pub fn boundary_vertices(&self) -> Vec<bool> {
        let mut on = vec![false; self.vertex_count];
        for e in self.boundary_edges() {
            let [a, b] = self.edges[e];
            on[a as usize] = true;
            on[b as usize] = true;
        }
        on
    }
    /// `true` when every edge has two triangles (a closed surface).
    pub fn is_closed(&self) -> bool {
        self.boundary_edges().next().is_none()
    }
}

pub(crate) fn check_element(
    element: usize,
    indices: &[u32],
    vertex_count: usize,
) -> Result<(), TopologyError> {
    for (i, &index) in indices.iter().enumerate() {
        if index as usize >= vertex_count {
            return Err(TopologyError::IndexOutOfRange {
                element,
                index,
                vertex_count,
            });
        }
        if indices[..i].contains(&index) {
            return Err(TopologyError::RepeatedVertex { element, index });
        }
    }
    Ok(())
}

pub(crate) fn check_finite(positions: &[Vec3]) -> Result<(), TopologyError> {
    match positions.iter().position(|p| !p.is_finite()) {
        Some(vertex) => Err(TopologyError::NonFinite {
            vertex,
            position: positions[vertex].to_array(),
        }),
        None => Ok(()),
    }
}

/// CSR adjacency from unique edges; neighbours sorted by vertex index.
pub(crate) fn build_csr(vertex_count: usize, edges: &[[u32; 2]]) -> (Vec<u32>, Vec<Neighbor>) {
    let mut degree = vec![0u32; vertex_count + 1];
    for &[a, b] in edges {
        degree[a as usize + 1] += 1;
        degree[b as usize + 1] += 1;
    }
    for v in 0..vertex_count {
        degree[v + 1] += degree[v];
    }
    let offsets = degree;
    let mut fill = offsets.clone();
    let mut adjacency = vec![Neighbor { vertex: 0, edge: 0 }; edges.len() * 2];
    for (e, &[a, b]) in edges.iter().enumerate() {
        let slot = &mut fill[a as usize];
        adjacency[*slot as usize] = Neighbor {
            vertex: b,
            edge: e as u32,
        };
        *slot += 1;
        let slot = &mut fill[b as usize];
        adjacency[*slot as usize] = Neighbor {
            vertex: a,
            edge: e as u32,
        };
        *slot += 1;
    }
    for v in 0..vertex_count {
        adjacency[offsets[v] as usize..offsets[v + 1] as usize].sort_unstable_by_key(|n| n.vertex);
    }
    (offsets, adjacency)
}

/// A validated triangle mesh: rest positions plus topology.
///
/// ```
/// use dermis::mesh::TriMesh;
/// use glam::Vec3;
/// let mesh = TriMesh::new(
///     vec![Vec3::ZERO, Vec3::X, Vec3::Y],
///     vec![[0, 1, 2]],
/// ).unwrap();
/// assert!((mesh.triangle_area(0) - 0.5).abs() < 1e-6);
///
/// // Bad input is a typed error naming the culprit, never a panic.
/// let err = TriMesh::new(vec![Vec3::ZERO, Vec3::X], vec![[0, 1, 2]]).unwrap_err();
/// assert_eq!(err.to_string(), "element 0 refers to vertex 2, but the mesh has only 2 vertices");
/// ```
#[derive(Debug, Clone, PartialEq)]
pub struct TriMesh {
    positions: Vec<Vec3>,
    topology: TriMeshTopology,
}

impl TriMesh {
    /// Validates and builds a mesh: finite coordinates, indices in range, no repeated vertex in a
    /// triangle, no zero-area triangle, at most two triangles per edge.
    pub fn new(positions: Vec<Vec3>, triangles: Vec<[u32; 3]>) -> Result<Self, TopologyError> {
        check_finite(&positions)?;
        let topology = TriMeshTopology::new(positions.len(), &triangles)?;
        for (t, tri) in triangles.iter().enumerate() {
            let [a, b, c] = tri.map(|i| positions[i as usize]);
            let area2 = (b - a).cross(c - a).length();
            let longest = (b - a)
                .length_squared()
                .max((c - b).length_squared())
                .max((a - c).length_squared());
            if area2.is_nan() || area2 * 0.5 <= DEGENERATE_AREA_RATIO * longest {
                return Err(TopologyError::Degenerate { element: t });
            }
        }
        Ok(Self {
            positions,
            topology,
        })
    }

    /// Rest positions.
    pub fn positions(&self) -> &[Vec3] {
        &self.positions
    }
    /// Connectivity.
    pub fn topology(&self) -> &TriMeshTopology {
        &self.topology
    }
    /// The triangles.
    pub fn triangles(&self) -> &[[u32; 3]] {
        self.topology.triangles()
    }
    /// Area of triangle `t` at rest.
    pub fn triangle_area(&self, t: usize) -> f32 {
        let [a, b, c] = self.topology.triangles[t].map(|i| self.positions[i as usize]);
        0.5 * (b - a).cross(c - a).length()
    }
    /// Rest length of every edge, in edge order.
    pub fn edge_lengths(&self) -> Vec<f32> {
        self.topology
            .edges
            .iter()
            .map(|&[a, b]| (self.positions[a as usize] - self.positions[b as usize]).length())
            .collect()
    }
    /// Angles, triangle counts and other figures to judge the mesh by.
    pub fn quality(&self) -> MeshQuality {
        MeshQuality::of(self)
    }
    /// Replaces the positions (same count), keeping the topology; validates the count and
    /// finiteness only.
    pub fn with_positions(mut self, positions: Vec<Vec3>) -> Result<Self, TopologyError> {
        if positions.len() != self.positions.len() {
            return Err(TopologyError::VertexCount {
                given: positions.len(),
                expected: self.positions.len(),
            });
        }
        check_finite(&positions)?;
        self.positions = positions;
        Ok(self)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn square() -> (Vec<Vec3>, Vec<[u32; 3]>) {
        (
            vec![Vec3::ZERO, Vec3::X, Vec3::new(1.0, 1.0, 0.0), Vec3::Y],
            vec![[0, 1, 2], [0, 2, 3]],
        )
    }

    #[test]
    fn edges_are_unique_and_know_their_triangles() {
        let (p, t) = square();
        let m = TriMesh::new(p, t).unwrap();
        let topo = m.topology();
        assert_eq!(topo.edges(), &[[0, 1], [0, 2], [0, 3], [1, 2], [2, 3]]);
        // The diagonal (0, 2) is shared by both triangles; the others are boundary.
        assert_eq!(topo.edge_triangles()[1], [0, 1]);
        assert_eq!(topo.boundary_edges().collect::<Vec<_>>(), vec![0, 2, 3, 4]);
        assert!(!topo.is_closed());
        // Edge opposite vertex 0 of triangle 0 is (1, 2).
        assert_eq!(topo.edges()[topo.triangle_edges()[0][0] as usize], [1, 2]);
        let n: Vec<u32> = topo.neighbors(2).iter().map(|n| n.vertex).collect();
        assert_eq!(n, vec![0, 1, 3]);
        for v in 0..4 {
            for nb in topo.neighbors(v) {
                let [a, b] = topo.edges()[nb.edge as usize];
                assert!((a as usize == v && b == nb.vertex) || (b as usize == v && a == nb.vertex));
            }
        }
    }

    #[test]
    fn closed_tetrahedron_surface_is_closed() {
        let t = [[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]];
        let topo = TriMeshTopology::new(4, &t).unwrap();
        assert!(topo.is_closed());
        assert_eq!(topo.edges().len(), 6);
    }

    #[test]
    fn bad_meshes_give_typed_errors_naming_the_element() {
        let (p, _) = square();
        let e = TriMesh::new(p.clone(), vec![[0, 1, 2], [0, 2, 9]]).unwrap_err();
        assert_eq!(
            e,
            TopologyError::IndexOutOfRange {
                element: 1,
                index: 9,
                vertex_count: 4
            }
        );
        let e = TriMesh::new(p.clone(), vec![[0, 1, 1]]).unwrap_err();
        assert_eq!(
            e,
            TopologyError::RepeatedVertex {
                element: 0,
                index: 1
            }
        );
        let mut collinear = p.clone();
        collinear[2] = Vec3::new(2.0, 0.0, 0.0);
        let e = TriMesh::new(collinear, vec![[0, 2, 3], [0, 1, 2]]).unwrap_err();
        assert_eq!(e, TopologyError::Degenerate { element: 1 });
        let mut nan = p.clone();
        nan[3].y = f32::NAN;
        assert!(matches!(
            TriMesh::new(nan, vec![[0, 1, 2]]),
            Err(TopologyError::NonFinite { vertex: 3, .. })
        ));
        let mut five = p.clone();
        five.push(Vec3::new(0.5, 0.5, 1.0));
        let fan = vec![[0, 1, 2], [0, 2, 3], [0, 2, 4]];
        assert_eq!(
            TriMesh::new(five, fan).unwrap_err(),
            TopologyError::NonManifoldEdge {
                a: 0,
                b: 2,
                element: 2
            }
        );
        assert_eq!(TriMesh::new(p, vec![]).unwrap_err(), TopologyError::Empty);
    }
}
