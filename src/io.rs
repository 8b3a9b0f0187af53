//! Mesh and load files (OBJ via obj-rs, JSON meshes, the loads JSON) and atomic writes.
//!
//! # The loads file
//!
//! `dermis equilibrium --loads L.json` reads per-vertex forces (N) and pinned vertices, indices
//! into the mesh's vertex list (0-based, in file order):
//!
//! ```json
//! {
//!   "forces": [ { "vertex": 12, "force": [0.0, 0.0, -1.5] } ],
//!   "pinned": [0, 1, 2]
//! }
//! ```
//!
//! Both keys are optional; a vertex listed twice in `forces` gets the sum.

use std::io::Write;
use std::path::{Path, PathBuf};

use glam::Vec3;
use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::mesh::{TetMesh, TopologyError, TriMesh};

/// Why a file could not be read or written.
#[derive(Debug, Error)]
pub enum IoError {
    /// The file could not be opened, read or written.
    #[error("{path}: {source}")]
    File {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// The OBJ file could not be parsed.
    #[error("{path}: not a readable OBJ file: {message}")]
    Obj {
        /// The file.
        path: PathBuf,
        /// What the parser said.
        message: String,
    },
    /// The JSON file could not be parsed.
    #[error("{path}: {source}")]
    Json {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        source: serde_json::Error,
    },
    /// The mesh in the file is invalid.
    #[error("{path}: {source}")]
    Mesh {
        /// The file.
        path: PathBuf,
        /// What is wrong with it.
        source: TopologyError,
    },
    /// The loads file names a vertex the mesh does not have, or a non-finite force.
    #[error("{path}: {message}")]
    Loads {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// The file extension is not one this command reads or writes.
    #[error("{0}: unsupported file type (expected {1})")]
    Unsupported(PathBuf, &'static str),
    /// Writing the output failed (unwritable directory, disk full, ...).
    #[error(transparent)]
    Write(#[from] crate::export::ExportError),
    /// Encoding an image failed.
    #[error("could not encode image: {0}")]
    Encode(String),
}

/// Writes `bytes` to `path` through a temporary file in the same directory, renamed into place
/// only when complete and synced: readers never see a half-written file, and a failure leaves
/// nothing (see [`crate::export::write_atomic`], which this wraps).
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), IoError> {
    crate::export::write_atomic_durable(path, |w| w.write_all(bytes))?;
    Ok(())
}

/// A mesh read from disk: a surface or a tetrahedral volume.
#[derive(Debug, Clone)]
pub enum MeshFile {
    /// A triangle mesh.
    Surface(TriMesh),
    /// A tetrahedral mesh.
    Volume(TetMesh),
}

/// JSON mesh layout: `{"positions": [[x, y, z], ...], "triangles": [[a, b, c], ...]}` or with
/// `"tetrahedra": [[a, b, c, d], ...]` instead of triangles.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct JsonMesh {
    /// Vertex positions, m.
    pub positions: Vec<[f32; 3]>,
    /// Triangles (0-based vertex indices).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub triangles: Option<Vec<[u32; 3]>>,
    /// Tetrahedra (0-based vertex indices).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tetrahedra: Option<Vec<[u32; 4]>>,
}

/// Reads a mesh from `.obj` (all objects merged, vertices in file order, polygons fanned into
/// triangles, via obj-rs) or `.json`
/// ([`JsonMesh`]).
pub fn read_mesh(path: &Path) -> Result<MeshFile, IoError> {
    let mesh_err = |source| IoError::Mesh {
        path: path.to_path_buf(),
        source,
    };
    match extension(path).as_deref() {
        Some("obj") => {
            let file = std::fs::File::open(path).map_err(|source| IoError::File {
                path: path.to_path_buf(),
                source,
            })?;
            let raw =
                obj::raw::parse_obj(std::io::BufReader::new(file)).map_err(|e| IoError::Obj {
                    path: path.to_path_buf(),
                    message: e.to_string(),
                })?;
            // Vertices stay in file order (the loads file indexes them); polygons are split
            // into triangle fans.
            let positions: Vec<Vec3> = raw
                .positions
                .iter()
                .map(|&(x, y, z, _)| Vec3::new(x, y, z))
                .collect();
            let mut triangles = Vec::with_capacity(raw.polygons.len());
            for polygon in &raw.polygons {
                let corners: Vec<usize> = match polygon {
                    obj::raw::object::Polygon::P(v) => v.clone(),
                    obj::raw::object::Polygon::PT(v) => v.iter().map(|c| c.0).collect(),
                    obj::raw::object::Polygon::PN(v) => v.iter().map(|c| c.0).collect(),
                    obj::raw::object::Polygon::PTN(v) => v.iter().map(|c| c.0).collect(),
                };
                for i in 1..corners.len().saturating_sub(1) {
                    let t = [corners[0], corners[i], corners[i + 1]];
                    triangles.push(t.map(|v| u32::try_from(v).unwrap_or(u32::MAX)));
                }
            }
            Ok(MeshFile::Surface(
                TriMesh::new(positions, triangles).map_err(mesh_err)?,
            ))
        }
        Some("json") => {
            let text = read_text(path)?;
            let m: JsonMesh = serde_json::from_str(&text).map_err(|source| IoError::Json {
                path: path.to_path_buf(),
                source,
            })?;
            let positions: Vec<Vec3> = m.positions.iter().map(|p| Vec3::from_array(*p)).collect();
            match (m.triangles, m.tetrahedra) {
                (Some(t), None) => Ok(MeshFile::Surface(
                    TriMesh::new(positions, t).map_err(mesh_err)?,
                )),
                (None, Some(t)) => Ok(MeshFile::Volume(
                    TetMesh::new(positions, t).map_err(mesh_err)?,
                )),
                _ => Err(IoError::Loads {
                    path: path.to_path_buf(),
                    message: "a JSON mesh needs exactly one of \"triangles\" or \"tetrahedra\""
                        .into(),
                }),
            }
        }
        _ => Err(IoError::Unsupported(path.to_path_buf(), ".obj or .json")),
    }
}

fn extension(path: &Path) -> Option<String> {
    path.extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
}

fn read_text(path: &Path) -> Result<String, IoError> {
    std::fs::read_to_string(path).map_err(|source| IoError::File {
        path: path.to_path_buf(),
        source,
    })
}

/// One entry of the loads file.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PointForce {
    /// Vertex index.
    pub vertex: u32,
    /// Force, N.
    pub force: [f32; 3],
}

/// The loads file (see the module docs).
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LoadsFile {
    /// Point forces.
    #[serde(default)]
    pub forces: Vec<PointForce>,
    /// Pinned vertices.
    #[serde(default)]
    pub pinned: Vec<u32>,
}

/// Per-vertex forces and pins, validated against a vertex count.
#[derive(Debug, Clone, PartialEq)]
pub struct VertexLoads {
    /// Force per vertex, N.
    pub forces: Vec<Vec3>,
    /// Pinned flag per vertex.
    pub pinned: Vec<bool>,
}

/// Reads the loads JSON for a mesh of `vertex_count` vertices.
pub fn read_loads(path: &Path, vertex_count: usize) -> Result<VertexLoads, IoError> {
    let text = read_text(path)?;
    let file: LoadsFile = serde_json::from_str(&text).map_err(|source| IoError::Json {
        path: path.to_path_buf(),
        source,
    })?;
    let bad = |message: String| IoError::Loads {
        path: path.to_path_buf(),
        message,
    };
    let mut forces = vec![Vec3::ZERO; vertex_count];
    for (i, f) in file.forces.iter().enumerate() {
        let v = f.vertex as usize;
        if v >= vertex_count {
            return Err(bad(format!(
                "forces[{i}] names vertex {v}, but the mesh has {vertex_count} vertices"
            )));
        }
        let force = Vec3::from_array(f.force);
        if !force.is_finite() {
            return Err(bad(format!("forces[{i}] is not finite")));
        }
        forces[v] += force;
    }
    let mut pinned = vec![false; vertex_count];
    for (i, &v) in file.pinned.iter().enumerate() {
        if v as usize >= vertex_count {
            return Err(bad(format!(
                "pinned[{i}] names vertex {v}, but the mesh has {vertex_count} vertices"
            )));
        }
        pinned[v as usize] = true;
    }
    Ok(VertexLoads { forces, pinned })
}

/// OBJ text of a triangle mesh (`v` lines with shortest round-trip floats, then 1-based `f`).
pub fn obj_text(positions: &[Vec3], triangles: &[[u32; 3]]) -> String {
    use std::fmt::Write as _;
    let mut s = String::with_capacity(positions.len() * 40 + triangles.len() * 24);
    for p in positions {
        let _ = writeln!(s, "v {} {} {}", p.x, p.y, p.z);
    }
    for t in triangles {
        let _ = writeln!(s, "f {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1);
    }
    s
}

/// The boundary faces of a tetrahedral mesh (faces used by one tetrahedron), outward-facing.
pub fn tet_boundary(mesh: &TetMesh) -> Vec<[u32; 3]> {
    let mut faces: Vec<([u32; 3], [u32; 3])> = Vec::new();
    let p = mesh.positions();
    for tet in mesh.tets() {
        for skip in 0..4 {
            let mut f = [0u32; 3];
            let mut k = 0;
            for (i, &v) in tet.iter().enumerate() {
                if i != skip {
                    f[k] = v;
                    k += 1;
                }
            }
            // Orient away from the skipped vertex.
            let [a, b, c] = f.map(|i| p[i as usize]);
            if (b - a).cross(c - a).dot(p[tet[skip] as usize] - a) > 0.0 {
                f.swap(1, 2);
            }
            let mut key = f;
            key.sort_unstable();
            faces.push((key, f));
        }
    }
    faces.sort_unstable_by_key(|(k, _)| *k);
    let mut out = Vec::new();
    let mut i = 0;
    while i < faces.len() {
        let mut j = i + 1;
        while j < faces.len() && faces[j].0 == faces[i].0 {
            j += 1;
        }
        if j - i == 1 {
            out.push(faces[i].1);
        }
        i = j;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn atomic_write_replaces_whole_file_and_leaves_no_temp() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.txt");
        write_atomic(&path, b"first").unwrap();
        write_atomic(&path, b"second").unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), b"second");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
        let missing = dir.path().join("no/such/dir/x.txt");
        assert!(matches!(
            write_atomic(&missing, b"x"),
            Err(IoError::Write(_))
        ));
    }

    #[test]
    fn obj_round_trips_in_file_order() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("m.obj");
        let p = vec![
            Vec3::ZERO,
            Vec3::new(1.5, 0.0, 0.25),
            Vec3::new(0.1, 1.0 / 3.0, 0.0),
        ];
        write_atomic(&path, obj_text(&p, &[[0, 1, 2]]).as_bytes()).unwrap();
        let MeshFile::Surface(m) = read_mesh(&path).unwrap() else {
            panic!("surface expected")
        };
        assert_eq!(m.positions(), &p[..]);
        assert_eq!(m.triangles(), &[[0, 1, 2]]);
    }

    /// Faces that use vertices out of order, and a quad: vertices keep their file order (the
    /// loads file indexes them), the quad becomes two triangles.
    #[test]
    fn obj_keeps_file_vertex_order() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("q.obj");
        std::fs::write(
            &path,
            "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 2 0 0\nf 5 3 2\nf 1 2 3 4\n",
        )
        .unwrap();
        let MeshFile::Surface(m) = read_mesh(&path).unwrap() else {
            panic!("surface expected")
        };
        assert_eq!(m.positions()[4], Vec3::new(2.0, 0.0, 0.0));
        assert_eq!(m.positions()[2], Vec3::new(1.0, 1.0, 0.0));
        assert_eq!(m.triangles(), &[[4, 2, 1], [0, 1, 2], [0, 2, 3]]);
        std::fs::write(&path, "v 0 0 0\nf 1 2 3\n").unwrap();
        assert!(matches!(
            read_mesh(&path),
            Err(IoError::Obj { .. }) | Err(IoError::Mesh { .. })
        ));
    }

    #[test]
    fn loads_are_validated() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("l.json");
        std::fs::write(&path, r#"{"forces": [{"vertex": 1, "force": [0, 2, 0]}, {"vertex": 1, "force": [1, 0, 0]}], "pinned": [0]}"#).unwrap();
        let l = read_loads(&path, 3).unwrap();
        assert_eq!(l.forces[1], Vec3::new(1.0, 2.0, 0.0));
        assert_eq!(l.pinned, vec![true, false, false]);
        let e = read_loads(&path, 1).unwrap_err().to_string();
        assert!(
            e.contains("forces[0] names vertex 1, but the mesh has 1 vertices"),
            "{e}"
        );
        std::fs::write(&path, r#"{"force": []}"#).unwrap();
        assert!(matches!(read_loads(&path, 3), Err(IoError::Json { .. })));
    }

    #[test]
    fn tet_boundary_of_two_tets_has_six_outward_faces() {
        let p = vec![
            Vec3::ZERO,
            Vec3::X,
            Vec3::Y,
            Vec3::Z,
            Vec3::new(1.0, 1.0, 1.0),
        ];
        let m = TetMesh::new(p.clone(), vec![[0, 1, 2, 3], [1, 2, 3, 4]]).unwrap();
        let faces = tet_boundary(&m);
        assert_eq!(faces.len(), 6);
        let centroid = p.iter().sum::<Vec3>() / 5.0;
        for f in faces {
            let [a, b, c] = f.map(|i| p[i as usize]);
            assert!((b - a).cross(c - a).dot((a + b + c) / 3.0 - centroid) > 0.0);
        }
    }
}
