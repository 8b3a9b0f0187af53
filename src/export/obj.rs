//! Wavefront OBJ sequence: one file per frame, each mesh its own `o <role>:<name>` object.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use glam::Vec3;

use super::geometry::vertex_normals;
use super::text::push_vec3;
use super::{ExportError, ExportMeta, ExportOptions, FrameSink, Sequence, Staged};

/// Writes one OBJ per frame (`arm_000012.obj` for `out = arm.obj`): per mesh an object
/// `o <role>:<name>`, vertices `v x y z r g b` (strain colour, if enabled), angle-weighted
/// normals `vn`, and faces `f a//a b//b c//c`. Floats are written in shortest round-trip form,
/// so positions read back bit-exactly.
#[derive(Debug)]
pub struct ObjSink(Sequence);

impl ObjSink {
    /// A sink for the sequence named by `out` (see [`super::Format::sink`]).
    pub fn new(out: &Path, options: ExportOptions) -> Self {
        Self(Sequence::new(out, options, "obj"))
    }
}

impl FrameSink for ObjSink {
    fn begin(&mut self, meta: &ExportMeta) -> Result<(), ExportError> {
        self.0.begin(meta)
    }

    fn write_frame(&mut self, frame: u32, positions: &[&[Vec3]]) -> Result<(), ExportError> {
        self.0.write_frame(frame, positions, frame_text)
    }

    fn finish(&mut self) -> Result<Vec<PathBuf>, ExportError> {
        self.0.finish()
    }
}

fn frame_text(staged: &Staged, options: &ExportOptions, frame: u32, meshes: &[&[Vec3]]) -> Vec<u8> {
    let vertices: usize = meshes.iter().map(|m| m.len()).sum();
    let mut s = String::with_capacity(vertices * 100);
    let _ = writeln!(s, "# dermis frame {frame}");
    let mut base = 1usize;
    for ((mesh, rest), &p) in staged.meshes.iter().zip(&staged.rest).zip(meshes) {
        let _ = writeln!(s, "o {}", mesh.qualified_name());
        let colors = options
            .strain_colors
            .map(|map| (map, rest.vertex_strain(p, map.measure)));
        for (i, v) in p.iter().enumerate() {
            s.push_str("v ");
            push_vec3(&mut s, v.to_array(), " ");
            if let Some((map, strain)) = &colors {
                s.push(' ');
                push_vec3(&mut s, map.color(strain[i]), " ");
            }
            s.push('\n');
        }
        for n in vertex_normals(&mesh.triangles, p) {
            s.push_str("vn ");
            push_vec3(&mut s, n.to_array(), " ");
            s.push('\n');
        }
        for t in &mesh.triangles {
            let [a, b, c] = t.map(|v| v as usize + base);
            let _ = writeln!(s, "f {a}//{a} {b}//{b} {c}//{c}");
        }
        base += p.len();
    }
    s.into_bytes()
}
