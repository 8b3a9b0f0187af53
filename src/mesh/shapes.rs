//! Procedural meshes for examples, tests and benchmarks.

use glam::Vec3;

use super::TriMesh;

/// An open cylindrical tube along +z: `around` vertices per ring, `along` rings, radius and
/// length in metres. Vertices ring by ring; triangles wound so normals point outwards.
///
/// ```
/// let tube = dermis::mesh::shapes::tube(32, 10, 0.05, 0.3);
/// assert_eq!(tube.positions().len(), 320);
/// assert_eq!(tube.topology().boundary_edges().count(), 64);
/// ```
pub fn tube(around: u32, along: u32, radius: f32, length: f32) -> TriMesh {
    assert!(
        around >= 3 && along >= 2,
        "a tube needs at least 3 x 2 vertices"
    );
    let mut positions = Vec::with_capacity((around * along) as usize);
    for j in 0..along {
        let z = length * j as f32 / (along - 1) as f32;
        for i in 0..around {
            let a = std::f32::consts::TAU * i as f32 / around as f32;
            positions.push(Vec3::new(radius * a.cos(), radius * a.sin(), z));
        }
    }
    let mut triangles = Vec::with_capacity((2 * around * (along - 1)) as usize);
    for j in 0..along - 1 {
        for i in 0..around {
            let a = j * around + i;
            let b = j * around + (i + 1) % around;
            let (c, d) = (a + around, b + around);
            triangles.push([a, b, d]);
            triangles.push([a, d, c]);
        }
    }
    TriMesh::new(positions, triangles).expect("the tube is a valid mesh")
}

/// A square sheet in the `z = 0` plane, `n` x `n` vertices over `size` metres, centred on the
/// origin, rows along +x.
///
/// ```
/// let sheet = dermis::mesh::shapes::sheet(11, 1.0);
/// assert_eq!(sheet.triangles().len(), 200);
/// ```
pub fn sheet(n: u32, size: f32) -> TriMesh {
    assert!(n >= 2, "a sheet needs at least 2 x 2 vertices");
    let mut positions = Vec::with_capacity((n * n) as usize);
    for j in 0..n {
        for i in 0..n {
            let u = i as f32 / (n - 1) as f32 - 0.5;
            let v = j as f32 / (n - 1) as f32 - 0.5;
            positions.push(Vec3::new(u * size, v * size, 0.0));
        }
    }
    TriMesh::new(positions, grid_triangles(n, n)).expect("the sheet is a valid mesh")
}

/// The triangles of an `nx × ny`-vertex grid whose vertices are numbered row by row
/// (`j * nx + i`): two triangles per cell, counter-clockwise when `i` runs along +x and `j`
/// along +y. Pair it with your own vertex positions for any flat or curved grid.
///
/// ```
/// let t = dermis::mesh::shapes::grid_triangles(3, 2);
/// assert_eq!(t, vec![[0, 1, 4], [0, 4, 3], [1, 2, 5], [1, 5, 4]]);
/// ```
pub fn grid_triangles(nx: u32, ny: u32) -> Vec<[u32; 3]> {
    let mut triangles =
        Vec::with_capacity((2 * nx.saturating_sub(1) * ny.saturating_sub(1)) as usize);
    for j in 0..ny.saturating_sub(1) {
        for i in 0..nx.saturating_sub(1) {
            let a = j * nx + i;
            triangles.push([a, a + 1, a + nx + 1]);
            triangles.push([a, a + nx + 1, a + nx]);
        }
    }
    triangles
}
