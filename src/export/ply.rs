//! Binary little-endian PLY sequence: one file per frame, all exported meshes in one file.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use glam::Vec3;

use super::geometry::{to_u8, vertex_normals};
use super::{ExportError, ExportMeta, ExportOptions, FrameSink, Sequence, Staged};

/// Writes one binary little-endian PLY per frame (`arm_000012.ply` for `out = arm.ply`).
/// Vertices carry `float x y z nx ny nz` (angle-weighted normals) and, with strain colours,
/// `uchar red green blue`; faces are `list uchar uint vertex_indices`. All exported meshes are
/// concatenated in one file; a `comment mesh <role>:<name> vertices <first> <count> faces
/// <first> <count>` header line per mesh tells them apart.
#[derive(Debug)]
pub struct PlySink(Sequence);

impl PlySink {
    /// A sink for the sequence named by `out` (see [`super::Format::sink`]).
    pub fn new(out: &Path, options: ExportOptions) -> Self {
        Self(Sequence::new(out, options, "ply"))
    }
}

impl FrameSink for PlySink {
    fn begin(&mut self, meta: &ExportMeta) -> Result<(), ExportError> {
        self.0.begin(meta)
    }

    fn write_frame(&mut self, frame: u32, positions: &[&[Vec3]]) -> Result<(), ExportError> {
        self.0.write_frame(frame, positions, frame_bytes)
    }

    fn finish(&mut self) -> Result<Vec<PathBuf>, ExportError> {
        self.0.finish()
    }
}

fn frame_bytes(
    staged: &Staged,
    options: &ExportOptions,
    frame: u32,
    meshes: &[&[Vec3]],
) -> Vec<u8> {
    let vertices: usize = meshes.iter().map(|m| m.len()).sum();
    let faces: usize = staged.meshes.iter().map(|m| m.triangles.len()).sum();
    let mut header = String::new();
    header.push_str("ply\nformat binary_little_endian 1.0\n");
    let _ = writeln!(header, "comment dermis frame {frame}");
    let (mut v0, mut f0) = (0, 0);
    for (mesh, p) in staged.meshes.iter().zip(meshes) {
        let _ = writeln!(
            header,
            "comment mesh {} vertices {v0} {} faces {f0} {}",
            mesh.qualified_name(),
            p.len(),
            mesh.triangles.len()
        );
        v0 += p.len();
        f0 += mesh.triangles.len();
    }
    let _ = writeln!(header, "element vertex {vertices}");
    for name in ["x", "y", "z", "nx", "ny", "nz"] {
        let _ = writeln!(header, "property float {name}");
    }
    if options.strain_colors.is_some() {
        for name in ["red", "green", "blue"] {
            let _ = writeln!(header, "property uchar {name}");
        }
    }
    let _ = writeln!(header, "element face {faces}");
    header.push_str("property list uchar uint vertex_indices\nend_header\n");

    let mut b = Vec::with_capacity(header.len() + vertices * 27 + faces * 13);
    b.extend_from_slice(header.as_bytes());
    for ((mesh, rest), &p) in staged.meshes.iter().zip(&staged.rest).zip(meshes) {
        let normals = vertex_normals(&mesh.triangles, p);
        let colors = options
            .strain_colors
            .map(|map| (map, rest.vertex_strain(p, map.measure)));
        for (i, (v, n)) in p.iter().zip(&normals).enumerate() {
            for x in v.to_array().into_iter().chain(n.to_array()) {
                b.extend_from_slice(&x.to_le_bytes());
            }
            if let Some((map, strain)) = &colors {
                b.extend_from_slice(&to_u8(map.color(strain[i])));
            }
        }
    }
    let mut base = 0u32;
    for (mesh, p) in staged.meshes.iter().zip(meshes) {
        for t in &mesh.triangles {
            b.push(3);
            for v in t {
                b.extend_from_slice(&(v + base).to_le_bytes());
            }
        }
        base += p.len() as u32;
    }
    b
}
