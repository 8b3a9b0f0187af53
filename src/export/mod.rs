//! Frame sinks: animated glTF (glb), OBJ/PLY sequences and USD (usda), all written atomically.
//!
//! A simulation hands its frames to a [`FrameSink`]: first [`FrameSink::begin`] with the mesh
//! metadata ([`ExportMeta`]: names, roles, triangles, rest positions, frame rate), then
//! [`FrameSink::write_frame`] once per frame with the current positions of every mesh, then
//! [`FrameSink::finish`]. [`FrameSequence`] is the same data held in memory, handy for tests
//! and for tools that already have all frames.
//!
//! | format | output | motion | strain colour |
//! |---|---|---|---|
//! | [`Format::Glb`] | one `.glb` file | one morph target per frame, STEP weights animation | static `COLOR_0`: peak strain over the clip |
//! | [`Format::Obj`] | one `.obj` per frame | one file per frame | `v x y z r g b` |
//! | [`Format::Ply`] | one binary `.ply` per frame | one file per frame | `red green blue` vertex properties |
//! | [`Format::Usda`] | one `.usda` stage | time-sampled `points`, `normals`, `extent` | time-sampled `primvars:displayColor` |
//!
//! Every file goes to a temporary name in its final directory and is renamed into place only
//! once complete, so an interrupted or failed export never leaves a half-written file: a
//! sequence keeps the frames that completed, a single-file format writes nothing until
//! [`FrameSink::finish`]. Output is a pure function of the input (no timestamps, shortest
//! round-trip float text via `ryu`), so two exports of the same frames are byte-identical.
//!
//! Normals are angle-weighted vertex normals ([`vertex_normals`]); strain is the stretch of the
//! incident triangles relative to rest, averaged to vertices ([`vertex_strain`]) and coloured by
//! [`StrainColorMap`].
//!
//! ```
//! use dermis::export::{ExportMeta, ExportOptions, Format, FrameSequence, MeshMeta, MeshRole};
//! use glam::Vec3;
//!
//! let rest = vec![Vec3::ZERO, Vec3::X, Vec3::Y];
//! let skin = MeshMeta::new("patch", MeshRole::Skin, vec![[0, 1, 2]], rest.clone());
//! let mut seq = FrameSequence::new(ExportMeta::new(vec![skin], 24.0));
//! for f in 0..3 {
//!     let stretched: Vec<Vec3> = rest.iter().map(|p| *p * (1.0 + 0.1 * f as f32)).collect();
//!     seq.push(f, vec![stretched]);
//! }
//! let dir = tempfile::tempdir()?;
//! let mut sink = Format::Obj.sink(&dir.path().join("patch.obj"), &ExportOptions::default());
//! let written = seq.write_to(sink.as_mut())?;
//! assert_eq!(written.len(), 3); // patch_000000.obj, patch_000001.obj, patch_000002.obj
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

mod atomic;
mod checkpoint;
mod config;
mod geometry;
mod glb;
mod job;
mod obj;
mod ply;
mod text;
mod usda;

use std::fmt;
use std::path::{Path, PathBuf};
use std::str::FromStr;

use glam::Vec3;
use thiserror::Error;

pub use atomic::{write_atomic, write_atomic_durable};
pub use checkpoint::{CHECKPOINT_VERSION, Checkpoint, CheckpointArray};
pub use config::{
    AnchorConfig, ContactSettings, ExportConfig, MaterialConfig, OutputConfig, SolverConfig,
};
pub use geometry::{StrainColorMap, StrainMeasure, vertex_normals, vertex_strain};
pub use glb::GlbSink;
pub use job::{ExportJob, ExportJobError, ExportSummary, FrameRange, checkpoint_path, run_export};
pub use obj::ObjSink;
pub use ply::PlySink;
pub use usda::UsdaSink;

/// Why an export failed. Every variant names the offending path, mesh, frame or vertex.
#[derive(Debug, Error)]
pub enum ExportError {
    /// The output directory does not exist, is not a directory, or refuses new files. Create it
    /// (or pick another `--out`) and check its permissions.
    #[error("cannot write into directory {path}: {source}")]
    UnwritableDirectory {
        /// The directory.
        path: PathBuf,
        /// What the operating system said.
        source: std::io::Error,
    },
    /// Reading or writing a file failed (disk full, file vanished, ...).
    #[error("I/O error on {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// What the operating system said.
        source: std::io::Error,
    },
    /// [`ExportMeta`] holds no mesh that this sink exports (none at all, or only colliders while
    /// [`ExportOptions::with_colliders`] is off). Add a skin mesh.
    #[error("nothing to export: no {what} mesh")]
    NoMeshes {
        /// "skin" or "" depending on the filter.
        what: &'static str,
    },
    /// The frame rate is not a positive finite number. Pass e.g. 24 or 30.
    #[error("frame rate {fps} is not a positive finite number")]
    InvalidFps {
        /// The rejected rate, frames per second.
        fps: f32,
    },
    /// A triangle refers to a vertex the mesh does not have. Fix the mesh metadata.
    #[error(
        "mesh {mesh:?}: triangle {triangle} refers to vertex {index}, but the mesh has {vertex_count} vertices"
    )]
    IndexOutOfRange {
        /// Name of the mesh.
        mesh: String,
        /// Index of the triangle.
        triangle: usize,
        /// The bad vertex index.
        index: u32,
        /// Number of rest positions.
        vertex_count: usize,
    },
    /// A frame holds a different number of meshes than [`ExportMeta`] declared. Pass one
    /// position slice per declared mesh, in declaration order.
    #[error("frame {frame}: {found} meshes given, {expected} declared")]
    MeshCount {
        /// Frame index.
        frame: u32,
        /// Meshes declared in [`ExportMeta`].
        expected: usize,
        /// Position slices given.
        found: usize,
    },
    /// A frame gives a mesh a different number of vertices than its rest positions. The
    /// simulation and the metadata disagree about the mesh.
    #[error("frame {frame}, mesh {mesh:?}: {found} vertices given, the rest mesh has {expected}")]
    VertexCount {
        /// Frame index.
        frame: u32,
        /// Name of the mesh.
        mesh: String,
        /// Number of rest positions.
        expected: usize,
        /// Number of positions given.
        found: usize,
    },
    /// A position is NaN or infinite (the simulation blew up, or the rest mesh is broken).
    /// Nothing of this frame was written; lower the time step or check the rest mesh.
    #[error("{}mesh {mesh:?}: vertex {vertex} has a non-finite position {position:?}", frame_prefix(*frame))]
    NonFinite {
        /// Frame index, or `None` for the rest positions.
        frame: Option<u32>,
        /// Name of the mesh.
        mesh: String,
        /// Index of the vertex.
        vertex: usize,
        /// The position as given.
        position: [f32; 3],
    },
    /// Frame indices must strictly increase (each frame once, in order).
    #[error("frame {frame} given after frame {previous}: frames must strictly increase")]
    FrameOrder {
        /// The rejected frame index.
        frame: u32,
        /// The frame written before it.
        previous: u32,
    },
    /// The sink was used out of order ([`FrameSink::begin`] not called, called twice, or a
    /// call after [`FrameSink::finish`]). This is a bug in the caller.
    #[error("frame sink misused: {0}")]
    State(&'static str),
    /// A single-file format was finished without any frame. Export at least one frame.
    #[error("no frame was written; {path} needs at least one")]
    NoFrames {
        /// The file that would have been written.
        path: PathBuf,
    },
    /// The output would exceed what the format can address (a glb is limited to 4 GiB).
    /// Export fewer frames or split the clip.
    #[error("{path} would be too large for its format ({bytes} bytes)")]
    TooLarge {
        /// The file.
        path: PathBuf,
        /// Its size in bytes.
        bytes: u64,
    },
    /// Serialising the glTF JSON failed.
    #[error("glTF JSON for {path}: {source}")]
    Json {
        /// The file.
        path: PathBuf,
        /// The serialiser's error.
        source: serde_json::Error,
    },
    /// A checkpoint file is not one this version of dermis wrote (wrong magic, unknown version,
    /// truncated or trailing bytes). Delete it and export from the start.
    #[error("checkpoint {path} is unreadable: {reason}")]
    BadCheckpoint {
        /// The checkpoint file.
        path: PathBuf,
        /// What is wrong with it.
        reason: String,
    },
}

fn frame_prefix(frame: Option<u32>) -> String {
    match frame {
        Some(f) => format!("frame {f}, "),
        None => "rest pose, ".to_owned(),
    }
}

/// What a mesh is in the anatomical model. Colliders (muscle, bone) are exported only with
/// [`ExportOptions::with_colliders`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum MeshRole {
    /// The simulated skin.
    Skin,
    /// A muscle collider.
    Muscle,
    /// A bone collider.
    Bone,
}

impl MeshRole {
    /// The lower-case name used in object names (`skin`, `muscle`, `bone`).
    pub fn as_str(self) -> &'static str {
        match self {
            MeshRole::Skin => "skin",
            MeshRole::Muscle => "muscle",
            MeshRole::Bone => "bone",
        }
    }
}

impl fmt::Display for MeshRole {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// One mesh of the export: name, role, connectivity and rest positions (metres). Strain is
/// measured against the rest positions; glb also uses them as the base of its morph targets.
#[derive(Debug, Clone, PartialEq)]
pub struct MeshMeta {
    /// Node name in the source model (used in object names: `skin:<name>`).
    pub name: String,
    /// Skin or collider.
    pub role: MeshRole,
    /// Counter-clockwise triangles (outward normals), indices into the positions.
    pub triangles: Vec<[u32; 3]>,
    /// Rest positions, metres.
    pub rest_positions: Vec<Vec3>,
}

impl MeshMeta {
    /// Bundles the fields.
    pub fn new(
        name: impl Into<String>,
        role: MeshRole,
        triangles: Vec<[u32; 3]>,
        rest_positions: Vec<Vec3>,
    ) -> Self {
        Self {
            name: name.into(),
            role,
            triangles,
            rest_positions,
        }
    }

    /// `<role>:<name>`, the object name in OBJ and PLY comments; whitespace and control
    /// characters in the name become `_` so the name stays one token.
    pub fn qualified_name(&self) -> String {
        let name: String = self
            .name
            .chars()
            .map(|c| {
                if c.is_whitespace() || c.is_control() {
                    '_'
                } else {
                    c
                }
            })
            .collect();
        format!("{}:{name}", self.role)
    }
}

/// Everything a sink needs before the first frame.
#[derive(Debug, Clone, PartialEq)]
pub struct ExportMeta {
    /// The meshes, in the order every frame gives their positions.
    pub meshes: Vec<MeshMeta>,
    /// Frames per second: frame `f` is shown at time `f / fps` seconds.
    pub fps: f32,
}

impl ExportMeta {
    /// Bundles the fields.
    pub fn new(meshes: Vec<MeshMeta>, fps: f32) -> Self {
        Self { meshes, fps }
    }
}

/// Options shared by all formats.
#[derive(Debug, Clone, PartialEq)]
pub struct ExportOptions {
    /// Also export muscle and bone meshes (default: skin only).
    pub with_colliders: bool,
    /// Colour vertices by strain (default: on).
    pub strain_colors: Option<StrainColorMap>,
    /// Digits of the zero-padded frame number in sequence file names (default 6:
    /// `arm_000012.obj`). Larger frame numbers get more digits.
    pub frame_digits: usize,
}

impl Default for ExportOptions {
    fn default() -> Self {
        Self {
            with_colliders: false,
            strain_colors: Some(StrainColorMap::default()),
            frame_digits: 6,
        }
    }
}

/// Receives a simulation frame by frame. Call [`begin`](Self::begin) once, then
/// [`write_frame`](Self::write_frame) for strictly increasing frame indices, then
/// [`finish`](Self::finish). After an error the sink must not be used again; files completed
/// before the error stay, no partial file is left.
///
/// Sinks are `Send + Sync` so a `Box<dyn FrameSink>` can live in an ECS resource.
pub trait FrameSink: Send + Sync {
    /// Validates the metadata and the output directory.
    fn begin(&mut self, meta: &ExportMeta) -> Result<(), ExportError>;
    /// Records frame `frame`: `positions[m]` are the current positions (metres) of mesh `m` of
    /// [`ExportMeta::meshes`]. Sequence formats write the frame's file now.
    fn write_frame(&mut self, frame: u32, positions: &[&[Vec3]]) -> Result<(), ExportError>;
    /// Completes the export and returns every file written, in order.
    fn finish(&mut self) -> Result<Vec<PathBuf>, ExportError>;
}

/// An output format.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Format {
    /// One binary glTF with morph-target animation.
    Glb,
    /// A sequence of Wavefront OBJ files.
    Obj,
    /// A sequence of binary little-endian PLY files.
    Ply,
    /// One USD text stage.
    Usda,
}

impl Format {
    /// All formats.
    pub const ALL: [Format; 4] = [Format::Glb, Format::Obj, Format::Ply, Format::Usda];

    /// The file extension, without dot.
    pub fn extension(self) -> &'static str {
        match self {
            Format::Glb => "glb",
            Format::Obj => "obj",
            Format::Ply => "ply",
            Format::Usda => "usda",
        }
    }

    /// A sink writing to `out`. For glb and usda `out` is the file; for obj and ply it names
    /// the sequence: `out/dir/arm.obj` gives `out/dir/arm_000000.obj`, `arm_000001.obj`, ...
    pub fn sink(self, out: &Path, options: &ExportOptions) -> Box<dyn FrameSink> {
        match self {
            Format::Glb => Box::new(GlbSink::new(out, options.clone())),
            Format::Obj => Box::new(ObjSink::new(out, options.clone())),
            Format::Ply => Box::new(PlySink::new(out, options.clone())),
            Format::Usda => Box::new(UsdaSink::new(out, options.clone())),
        }
    }
}

impl fmt::Display for Format {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.extension())
    }
}

/// An unknown format name.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
#[error("unknown export format {0:?}: expected glb, obj, ply or usda")]
pub struct UnknownFormat(pub String);

impl FromStr for Format {
    type Err = UnknownFormat;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Format::ALL
            .into_iter()
            .find(|f| f.extension().eq_ignore_ascii_case(s))
            .ok_or_else(|| UnknownFormat(s.to_owned()))
    }
}

/// One frame held in memory.
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    /// Frame index (time `index / fps`).
    pub index: u32,
    /// Positions per mesh, in [`ExportMeta::meshes`] order, metres.
    pub positions: Vec<Vec<Vec3>>,
}

/// A whole export held in memory: metadata plus frames.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameSequence {
    /// Meshes and frame rate.
    pub meta: ExportMeta,
    /// Frames, in increasing index order.
    pub frames: Vec<Frame>,
}

impl FrameSequence {
    /// An empty sequence.
    pub fn new(meta: ExportMeta) -> Self {
        Self {
            meta,
            frames: Vec::new(),
        }
    }

    /// Appends a frame.
    pub fn push(&mut self, index: u32, positions: Vec<Vec<Vec3>>) {
        self.frames.push(Frame { index, positions });
    }

    /// Feeds the whole sequence to `sink` and returns the files written.
    pub fn write_to(&self, sink: &mut dyn FrameSink) -> Result<Vec<PathBuf>, ExportError> {
        sink.begin(&self.meta)?;
        for frame in &self.frames {
            let slices: Vec<&[Vec3]> = frame.positions.iter().map(Vec::as_slice).collect();
            sink.write_frame(frame.index, &slices)?;
        }
        sink.finish()
    }
}

/// The `begin` → `write_frame`* → `finish` order every sink enforces, holding the validated
/// metadata in between.
#[derive(Debug, Default)]
struct Lifecycle {
    staged: Option<Staged>,
    finished: bool,
}

impl Lifecycle {
    /// Validates `meta` and the output directory; errors if already begun.
    fn begin(
        &mut self,
        meta: &ExportMeta,
        options: &ExportOptions,
        out: &Path,
    ) -> Result<&mut Staged, ExportError> {
        if self.staged.is_some() || self.finished {
            return Err(ExportError::State("begin called twice"));
        }
        let staged = Staged::new(meta, options)?;
        atomic::check_writable(out)?;
        Ok(self.staged.insert(staged))
    }

    /// Validates a frame; returns the metadata and the exported meshes' positions.
    fn frame<'a>(
        &mut self,
        frame: u32,
        positions: &[&'a [Vec3]],
    ) -> Result<(&mut Staged, Vec<&'a [Vec3]>), ExportError> {
        if self.finished {
            return Err(ExportError::State("write_frame after finish"));
        }
        let staged = self
            .staged
            .as_mut()
            .ok_or(ExportError::State("write_frame before begin"))?;
        let meshes = staged.frame(frame, positions)?;
        Ok((staged, meshes))
    }

    /// Marks the sink finished; errors before `begin` or on a second call.
    fn finish(&mut self) -> Result<&Staged, ExportError> {
        if self.finished {
            return Err(ExportError::State("finish called twice"));
        }
        let staged = self
            .staged
            .as_ref()
            .ok_or(ExportError::State("finish before begin"))?;
        self.finished = true;
        Ok(staged)
    }
}

/// What the one-file-per-frame sinks (OBJ, PLY) share: the lifecycle, the output name and the
/// files written so far. Each sink supplies only its frame encoder.
#[derive(Debug)]
struct Sequence {
    out: PathBuf,
    options: ExportOptions,
    life: Lifecycle,
    written: Vec<PathBuf>,
    ext: &'static str,
}

/// Encodes one frame of the exported meshes as a whole file.
type FrameEncoder = fn(&Staged, &ExportOptions, u32, &[&[Vec3]]) -> Vec<u8>;

impl Sequence {
    fn new(out: &Path, options: ExportOptions, ext: &'static str) -> Self {
        Self {
            out: out.to_owned(),
            options,
            life: Lifecycle::default(),
            written: Vec::new(),
            ext,
        }
    }

    fn begin(&mut self, meta: &ExportMeta) -> Result<(), ExportError> {
        self.life.begin(meta, &self.options, &self.out)?;
        Ok(())
    }

    /// Validates the frame, encodes it and writes it atomically to its numbered file.
    fn write_frame(
        &mut self,
        frame: u32,
        positions: &[&[Vec3]],
        encode: FrameEncoder,
    ) -> Result<(), ExportError> {
        use std::io::Write as _;
        let (staged, meshes) = self.life.frame(frame, positions)?;
        let bytes = encode(staged, &self.options, frame, &meshes);
        let path = sequence_path(&self.out, frame, self.options.frame_digits, self.ext);
        write_atomic(&path, |w| w.write_all(&bytes))?;
        self.written.push(path);
        Ok(())
    }

    fn finish(&mut self) -> Result<Vec<PathBuf>, ExportError> {
        self.life.finish()?;
        Ok(std::mem::take(&mut self.written))
    }
}

/// The validated part of [`ExportMeta`] a sink keeps: the selected meshes and their rest data.
#[derive(Debug)]
struct Staged {
    /// Indices into [`ExportMeta::meshes`] of the exported meshes.
    selected: Vec<usize>,
    /// The exported meshes.
    meshes: Vec<MeshMeta>,
    /// Rest data for strain, per exported mesh.
    rest: Vec<geometry::RestShape>,
    fps: f32,
    /// Total number of meshes declared (every frame must give this many).
    declared: usize,
    last_frame: Option<u32>,
}

impl Staged {
    fn new(meta: &ExportMeta, options: &ExportOptions) -> Result<Self, ExportError> {
        if !(meta.fps.is_finite() && meta.fps > 0.0) {
            return Err(ExportError::InvalidFps { fps: meta.fps });
        }
        let selected: Vec<usize> = meta
            .meshes
            .iter()
            .enumerate()
            .filter(|(_, m)| options.with_colliders || m.role == MeshRole::Skin)
            .map(|(i, _)| i)
            .collect();
        if selected.is_empty() {
            return Err(ExportError::NoMeshes {
                what: if options.with_colliders { "" } else { "skin" },
            });
        }
        let mut meshes = Vec::with_capacity(selected.len());
        let mut rest = Vec::with_capacity(selected.len());
        for &i in &selected {
            let mesh = &meta.meshes[i];
            let n = mesh.rest_positions.len();
            for (t, tri) in mesh.triangles.iter().enumerate() {
                if let Some(&index) = tri.iter().find(|&&v| v as usize >= n) {
                    return Err(ExportError::IndexOutOfRange {
                        mesh: mesh.name.clone(),
                        triangle: t,
                        index,
                        vertex_count: n,
                    });
                }
            }
            check_finite(None, &mesh.name, &mesh.rest_positions)?;
            rest.push(geometry::RestShape::new(
                &mesh.triangles,
                &mesh.rest_positions,
            ));
            meshes.push(mesh.clone());
        }
        Ok(Self {
            selected,
            meshes,
            rest,
            fps: meta.fps,
            declared: meta.meshes.len(),
            last_frame: None,
        })
    }

    /// Validates a frame and returns the positions of the exported meshes.
    fn frame<'a>(
        &mut self,
        frame: u32,
        positions: &[&'a [Vec3]],
    ) -> Result<Vec<&'a [Vec3]>, ExportError> {
        if let Some(previous) = self.last_frame
            && frame <= previous
        {
            return Err(ExportError::FrameOrder { frame, previous });
        }
        if positions.len() != self.declared {
            return Err(ExportError::MeshCount {
                frame,
                expected: self.declared,
                found: positions.len(),
            });
        }
        let mut out = Vec::with_capacity(self.selected.len());
        for (mesh, &i) in self.meshes.iter().zip(&self.selected) {
            let p = positions[i];
            if p.len() != mesh.rest_positions.len() {
                return Err(ExportError::VertexCount {
                    frame,
                    mesh: mesh.name.clone(),
                    expected: mesh.rest_positions.len(),
                    found: p.len(),
                });
            }
            check_finite(Some(frame), &mesh.name, p)?;
            out.push(p);
        }
        self.last_frame = Some(frame);
        Ok(out)
    }
}

fn check_finite(frame: Option<u32>, mesh: &str, positions: &[Vec3]) -> Result<(), ExportError> {
    match positions.iter().position(|p| !p.is_finite()) {
        None => Ok(()),
        Some(vertex) => Err(ExportError::NonFinite {
            frame,
            mesh: mesh.to_owned(),
            vertex,
            position: positions[vertex].to_array(),
        }),
    }
}

/// `dir/stem_000012.ext` for a sequence named by `out = dir/stem.ext`.
fn sequence_path(out: &Path, frame: u32, digits: usize, ext: &str) -> PathBuf {
    let stem = out
        .file_stem()
        .map_or_else(|| "frame".into(), |s| s.to_string_lossy().into_owned());
    out.with_file_name(format!("{stem}_{frame:0digits$}.{ext}"))
}

/// The directory a file of `out` goes to (`.` for a bare file name).
fn parent_dir(out: &Path) -> &Path {
    match out.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    }
}

#[cfg(test)]
mod tests;
