//! USD text stage: one `Mesh` prim per exported mesh with time-sampled points, normals, extent
//! and strain colours.

use std::fmt::Write as _;
use std::io::Write as _;
use std::path::{Path, PathBuf};

use glam::Vec3;

use super::atomic::write_atomic;
use super::geometry::vertex_normals;
use super::text::{push_f32, push_vec3};
use super::{ExportError, ExportMeta, ExportOptions, FrameSink, Lifecycle, Staged};

/// Writes one USD text stage (`.usda`). The root prim `/dermis` (an `Xform`, the default prim)
/// holds one `Mesh` per exported mesh, named `<role>_<name>` (made a valid identifier, with a
/// numeric suffix if two names collide; the original name and role are kept in `customData`).
/// Each mesh has `faceVertexCounts` and `faceVertexIndices`, and time samples at time code
/// `frame` of `points`, `normals` (angle-weighted, `vertex` interpolation), `extent` and, with
/// strain colours, `primvars:displayColor` (`vertex` interpolation). The stage metadata sets
/// `timeCodesPerSecond` and `framesPerSecond` to the frame rate, `startTimeCode` and
/// `endTimeCode` to the first and last frame, `metersPerUnit = 1` and `upAxis = "Y"` (as glTF).
///
/// Samples are formatted as each frame arrives; the stage is written atomically at
/// [`FrameSink::finish`].
#[derive(Debug)]
pub struct UsdaSink {
    out: PathBuf,
    options: ExportOptions,
    life: Lifecycle,
    /// Per exported mesh: the text of its time samples so far.
    samples: Vec<MeshSamples>,
    first_last: Option<(u32, u32)>,
}

#[derive(Debug, Default)]
struct MeshSamples {
    points: String,
    normals: String,
    extent: String,
    colors: String,
}

impl UsdaSink {
    /// A sink writing the stage `out`.
    pub fn new(out: &Path, options: ExportOptions) -> Self {
        Self {
            out: out.to_owned(),
            options,
            life: Lifecycle::default(),
            samples: Vec::new(),
            first_last: None,
        }
    }
}

impl FrameSink for UsdaSink {
    fn begin(&mut self, meta: &ExportMeta) -> Result<(), ExportError> {
        let staged = self.life.begin(meta, &self.options, &self.out)?;
        self.samples = staged
            .meshes
            .iter()
            .map(|_| MeshSamples::default())
            .collect();
        Ok(())
    }

    fn write_frame(&mut self, frame: u32, positions: &[&[Vec3]]) -> Result<(), ExportError> {
        let (staged, meshes) = self.life.frame(frame, positions)?;
        for (((mesh, rest), p), s) in staged
            .meshes
            .iter()
            .zip(&staged.rest)
            .zip(&meshes)
            .zip(&mut self.samples)
        {
            push_sample(&mut s.points, frame, p.iter().map(|v| v.to_array()));
            let normals = vertex_normals(&mesh.triangles, p);
            push_sample(&mut s.normals, frame, normals.iter().map(|v| v.to_array()));
            let (lo, hi) = p.iter().fold(
                (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
                |(lo, hi), v| (lo.min(*v), hi.max(*v)),
            );
            push_sample(
                &mut s.extent,
                frame,
                [lo.to_array(), hi.to_array()].into_iter(),
            );
            if let Some(map) = self.options.strain_colors {
                let strain = rest.vertex_strain(p, map.measure);
                push_sample(&mut s.colors, frame, strain.iter().map(|&x| map.color(x)));
            }
        }
        self.first_last = Some((self.first_last.map_or(frame, |(f, _)| f), frame));
        Ok(())
    }

    fn finish(&mut self) -> Result<Vec<PathBuf>, ExportError> {
        let staged = self.life.finish()?;
        let Some((first, last)) = self.first_last else {
            return Err(ExportError::NoFrames {
                path: self.out.clone(),
            });
        };
        let text = stage_text(
            staged,
            &self.samples,
            first,
            last,
            self.options.strain_colors.is_some(),
        );
        write_atomic(&self.out, |w| w.write_all(text.as_bytes()))?;
        self.samples = Vec::new();
        Ok(vec![self.out.clone()])
    }
}

/// Appends `        <frame>: [(x, y, z), ...],\n`.
fn push_sample(out: &mut String, frame: u32, values: impl Iterator<Item = [f32; 3]>) {
    let _ = write!(out, "            {frame}: [");
    for (i, v) in values.enumerate() {
        if i > 0 {
            out.push_str(", ");
        }
        out.push('(');
        push_vec3(out, v, ", ");
        out.push(')');
    }
    out.push_str("],\n");
}

/// A valid USD identifier from `raw`: `[A-Za-z_][A-Za-z0-9_]*`.
fn identifier(raw: &str) -> String {
    let mut s: String = raw
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '_' {
                c
            } else {
                '_'
            }
        })
        .collect();
    if s.is_empty() || s.starts_with(|c: char| c.is_ascii_digit()) {
        s.insert(0, '_');
    }
    s
}

/// `raw` as a USD string literal body (quotes and backslashes escaped, control characters
/// replaced by spaces).
fn quoted(raw: &str) -> String {
    let mut s = String::with_capacity(raw.len() + 2);
    s.push('"');
    for c in raw.chars() {
        match c {
            '"' => s.push_str("\\\""),
            '\\' => s.push_str("\\\\"),
            c if c.is_control() => s.push(' '),
            c => s.push(c),
        }
    }
    s.push('"');
    s
}

fn stage_text(
    staged: &Staged,
    samples: &[MeshSamples],
    first: u32,
    last: u32,
    colors: bool,
) -> String {
    let size: usize = samples
        .iter()
        .map(|s| s.points.len() + s.normals.len() + s.colors.len() + s.extent.len())
        .sum();
    let mut t = String::with_capacity(size + 4096);
    let mut fps = String::new();
    push_f32(&mut fps, staged.fps);
    let _ = write!(
        t,
        "#usda 1.0\n(\n    defaultPrim = \"dermis\"\n    doc = \"Skin animation exported by dermis\"\n    \
         endTimeCode = {last}\n    framesPerSecond = {fps}\n    metersPerUnit = 1\n    \
         startTimeCode = {first}\n    timeCodesPerSecond = {fps}\n    upAxis = \"Y\"\n)\n\n\
         def Xform \"dermis\"\n{{\n"
    );
    let mut used: Vec<String> = Vec::new();
    for (mesh, s) in staged.meshes.iter().zip(samples) {
        let base = identifier(&format!("{}_{}", mesh.role, mesh.name));
        let mut name = base.clone();
        let mut k = 1;
        while used.contains(&name) {
            name = format!("{base}_{k}");
            k += 1;
        }
        used.push(name.clone());
        let _ = write!(
            t,
            "    def Mesh \"{name}\" (\n        customData = {{\n            string dermisName = {}\n            \
             string dermisRole = \"{}\"\n        }}\n    )\n    {{\n",
            quoted(&mesh.name),
            mesh.role
        );
        let _ = write!(
            t,
            "        float3[] extent.timeSamples = {{\n{}        }}\n",
            s.extent
        );
        t.push_str("        int[] faceVertexCounts = [");
        for i in 0..mesh.triangles.len() {
            t.push_str(if i == 0 { "3" } else { ", 3" });
        }
        t.push_str("]\n        int[] faceVertexIndices = [");
        for (i, v) in mesh.triangles.iter().flatten().enumerate() {
            if i > 0 {
                t.push_str(", ");
            }
            let _ = write!(t, "{v}");
        }
        t.push_str("]\n");
        let _ = write!(
            t,
            "        normal3f[] normals (\n            interpolation = \"vertex\"\n        )\n        \
             normal3f[] normals.timeSamples = {{\n{}        }}\n",
            s.normals
        );
        let _ = write!(
            t,
            "        point3f[] points.timeSamples = {{\n{}        }}\n",
            s.points
        );
        if colors {
            let _ = write!(
                t,
                "        color3f[] primvars:displayColor (\n            interpolation = \"vertex\"\n        )\n        \
                 color3f[] primvars:displayColor.timeSamples = {{\n{}        }}\n",
                s.colors
            );
        }
        t.push_str("        uniform token subdivisionScheme = \"none\"\n    }\n");
    }
    t.push_str("}\n");
    t
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn identifiers_are_valid_usd_names() {
        assert_eq!(identifier("skin_left arm"), "skin_left_arm");
        assert_eq!(identifier("3d"), "_3d");
        assert_eq!(identifier(""), "_");
        assert_eq!(quoted("a\"b\\c\nd"), "\"a\\\"b\\\\c d\"");
    }
}
