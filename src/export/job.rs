//! The headless export job behind `dermis export`: load a rigged model, play a clip frame by
//! frame through the ECS pipeline (skinning, colliders, relaxation), hand every frame to a
//! [`FrameSink`], checkpoint as it goes and resume from the last checkpoint.

use std::path::{Path, PathBuf};
use std::time::Instant;

use bevy_ecs::prelude::*;
use serde::{Deserialize, Serialize};
use thiserror::Error;

use super::{
    ExportConfig, ExportError, ExportMeta, ExportOptions, Format, FrameSink, MeshMeta, MeshRole,
};
use crate::collision::ContactConfig;
use crate::ecs::{
    DermisPlugin, RelaxSettings, SceneError, SceneOptions, SceneState, SkinMaterial, SpawnedScene,
    Tissue, capture_state, collider_geometry, restore_state, scene_diagnostics,
    scene_skin_positions, spawn_scene,
};
use crate::gltf::{GltfError, LoadOptions, Scene};
use crate::io::{IoError, write_atomic};
use crate::stiffness::Modulus;

/// Which frames to export.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum FrameRange {
    /// The whole clip, `0 ..= duration` (one frame without a clip).
    Clip,
    /// The first `n` frames from time 0.
    Count(u32),
    /// Frames from `start_s` to `end_s` inclusive (the simulation still runs from time 0, so
    /// the skin has settled by `start_s`).
    Span {
        /// First exported time, s.
        start_s: f64,
        /// Last exported time, s.
        end_s: f64,
    },
}

/// An export to run.
#[derive(Debug, Clone)]
pub struct ExportJob {
    /// The rigged model (`.gltf` or `.glb`).
    pub model: PathBuf,
    /// Clip name or index; `None`: the first.
    pub clip: Option<String>,
    /// Which frames.
    pub frames: FrameRange,
    /// Output path (a file; sequences number it `stem_000012.ext`).
    pub out: PathBuf,
    /// Output format.
    pub format: Format,
    /// Settings.
    pub config: ExportConfig,
    /// Continue from the checkpoint next to `out`, if there is one.
    pub resume: bool,
}

/// What an export did: the JSON summary of `dermis export`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ExportSummary {
    /// Frames written.
    pub frames: u32,
    /// Skin vertices (all skins, as exported).
    pub vertices: usize,
    /// Mean solver iterations per frame (summed over skins and substeps).
    pub iterations_mean: f64,
    /// Largest solver iterations in a frame.
    pub iterations_max: u32,
    /// Largest final relative residual of any skin in any frame.
    pub residual_max: f32,
    /// Skin vertices left inside a collider after their frame, summed over frames.
    pub unresolved_contacts: u64,
    /// Wall-clock seconds of this run (not part of any output file).
    pub seconds: f64,
    /// Frames per second achieved.
    pub frames_per_second: f64,
    /// Frame the run started at (non-zero when resumed).
    pub resumed_from_frame: u32,
    /// Files written.
    pub files: Vec<PathBuf>,
}

/// Why an export failed. Nothing half-written is left behind in any case.
#[derive(Debug, Error)]
pub enum ExportJobError {
    /// The model could not be loaded.
    #[error(transparent)]
    Gltf(#[from] GltfError),
    /// The model could not be spawned or played (unknown clip, ...).
    #[error(transparent)]
    Scene(#[from] SceneError),
    /// Writing failed.
    #[error(transparent)]
    Export(#[from] ExportError),
    /// Reading or writing a checkpoint failed.
    #[error(transparent)]
    Io(#[from] IoError),
    /// The model has no skin to simulate. Mark a mesh as skin in glTF extras
    /// (`{"dermis": {"role": "skin"}}`) or give it a name containing "skin".
    #[error("{0}: the model has no skin mesh to simulate")]
    NoSkin(PathBuf),
    /// A setting is invalid.
    #[error("invalid setting: {0}")]
    Setting(String),
    /// The checkpoint was written by a different job (model, clip, range, format or settings).
    #[error(
        "{path}: the checkpoint belongs to a different export ({reason}); delete it or drop --resume"
    )]
    CheckpointMismatch {
        /// The checkpoint file.
        path: PathBuf,
        /// What differs.
        reason: String,
    },
}

/// Where the checkpoint of an export to `out` lives.
pub fn checkpoint_path(out: &Path) -> PathBuf {
    let mut name = out
        .file_name()
        .map(|n| n.to_os_string())
        .unwrap_or_default();
    name.push(".dermis-checkpoint.json");
    out.with_file_name(name)
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct CheckpointFile {
    version: u32,
    fingerprint: String,
    /// Frames already handed to the sink (and stored below).
    frames_done: u32,
    state: SceneState,
    /// Every written frame, per mesh, so single-file formats can be rebuilt identically.
    frames: Vec<Vec<Vec<[f32; 3]>>>,
    stats: Stats,
}

#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
struct Stats {
    iterations_sum: u64,
    iterations_max: u32,
    residual_max: f32,
    unresolved: u64,
}

fn scene_options(job: &ExportJob) -> Result<SceneOptions, ExportJobError> {
    let c = &job.config;
    if !(c.fps.is_finite() && c.fps > 0.0) {
        return Err(ExportJobError::Setting(format!(
            "fps = {} must be positive",
            c.fps
        )));
    }
    let rule = c
        .material
        .stiffness_rule()
        .map_err(ExportJobError::Setting)?;
    let contact = c.contact.enabled.then(|| ContactConfig {
        thickness_m: c.contact.thickness_m,
        friction: c.contact.friction,
        ..SceneOptions::DEFAULT
            .contact
            .unwrap_or(ContactConfig::DEFAULT)
    });
    Ok(SceneOptions {
        clip: job.clip.clone(),
        dt_s: 1.0 / f64::from(c.fps),
        looping: false,
        material: SkinMaterial {
            youngs_2d_n_per_m: Modulus::Uniform(c.material.youngs_2d_n_per_m),
            stiffness_rule: rule,
            poisson_ratio: c.material.poisson_ratio,
            thickness_m: c.contact.thickness_m,
            ..SkinMaterial::HUMAN_SKIN
        },
        anchor_k_normal_n_per_m: c.anchors.k_normal_n_per_m,
        anchor_k_tangent_n_per_m: c.anchors.k_tangent_n_per_m,
        contact,
        relax: RelaxSettings {
            max_iterations: c.solver.max_iterations,
            tolerance: c.solver.tolerance,
            ..RelaxSettings::DEFAULT
        },
    })
}

/// Frames to simulate and the first one to write: `(first_written, last)` as frame numbers
/// from time 0.
fn frame_span(range: FrameRange, fps: f64, duration_s: f32) -> Result<(u32, u32), ExportJobError> {
    match range {
        FrameRange::Clip => Ok((0, (f64::from(duration_s) * fps).round() as u32)),
        FrameRange::Count(0) => Err(ExportJobError::Setting(
            "--frames must be at least 1".into(),
        )),
        FrameRange::Count(n) => Ok((0, n - 1)),
        FrameRange::Span { start_s, end_s } => {
            if !(start_s.is_finite() && end_s.is_finite() && 0.0 <= start_s && start_s <= end_s) {
                return Err(ExportJobError::Setting(format!(
                    "--start {start_s} --end {end_s}: need 0 <= start <= end"
                )));
            }
            Ok(((start_s * fps).round() as u32, (end_s * fps).round() as u32))
        }
    }
}

struct Pipeline {
    world: World,
    schedule: Schedule,
    spawned: SpawnedScene,
}

impl Pipeline {
    fn new(scene: &Scene, options: &SceneOptions) -> Result<Self, ExportJobError> {
        let mut world = World::new();
        let schedule = DermisPlugin.build_schedule(&mut world);
        let spawned = spawn_scene(&mut world, scene, options)?;
        Ok(Self {
            world,
            schedule,
            spawned,
        })
    }

    /// Positions of every exported mesh, in [`ExportMeta`] order.
    fn frame(&self, with_colliders: bool) -> Result<Vec<Vec<glam::Vec3>>, ExportJobError> {
        let mut meshes = Vec::new();
        for skin in &self.spawned.skins {
            meshes.push(scene_skin_positions(&self.world, skin.entity)?);
        }
        if with_colliders {
            for c in &self.spawned.colliders {
                meshes.push(collider_geometry(&self.world, c.entity)?.0);
            }
        }
        Ok(meshes)
    }

    fn meta(
        &self,
        scene: &Scene,
        with_colliders: bool,
        fps: f32,
    ) -> Result<ExportMeta, ExportJobError> {
        let mut meshes = Vec::new();
        for skin in &self.spawned.skins {
            let node = &scene.nodes[skin.node as usize];
            let mesh = node.mesh.map(|m| &scene.meshes[m as usize]);
            let prim = mesh
                .and_then(|m| m.primitives.get(skin.primitive as usize))
                .ok_or_else(|| {
                    ExportJobError::Setting(format!("skin {} has no primitive", skin.name))
                })?;
            meshes.push(MeshMeta::new(
                skin.name.clone(),
                MeshRole::Skin,
                prim.triangles.clone(),
                prim.positions.clone(),
            ));
        }
        if with_colliders {
            for c in &self.spawned.colliders {
                let (vertices, triangles) = collider_geometry(&self.world, c.entity)?;
                let role = match c.tissue {
                    Tissue::Muscle => MeshRole::Muscle,
                    Tissue::Bone => MeshRole::Bone,
                };
                meshes.push(MeshMeta::new(c.name.clone(), role, triangles, vertices));
            }
        }
        Ok(ExportMeta::new(meshes, fps))
    }
}

fn fingerprint(job: &ExportJob, model_bytes: &[u8]) -> String {
    // FNV-1a of the model plus everything that shapes the output.
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    let mut eat = |bytes: &[u8]| {
        for b in bytes {
            h ^= u64::from(*b);
            h = h.wrapping_mul(0x0000_0100_0000_01b3);
        }
    };
    eat(model_bytes);
    let shape = serde_json::json!({
        "clip": job.clip, "frames": job.frames, "format": job.format.extension(), "config": job.config,
    });
    eat(shape.to_string().as_bytes());
    format!("{h:016x}")
}

/// Runs an export. `progress(done, total)` is called after every frame.
pub fn run_export(
    job: &ExportJob,
    mut progress: impl FnMut(u32, u32),
) -> Result<ExportSummary, ExportJobError> {
    let started = Instant::now();
    let model_bytes = std::fs::read(&job.model).map_err(|source| IoError::File {
        path: job.model.clone(),
        source,
    })?;
    let scene = crate::gltf::load(&job.model, &LoadOptions::default())?;
    let options = scene_options(job)?;
    let mut pipeline = Pipeline::new(&scene, &options)?;
    if pipeline.spawned.skins.is_empty() {
        return Err(ExportJobError::NoSkin(job.model.clone()));
    }
    let fps = f64::from(job.config.fps);
    let (first, last) = frame_span(job.frames, fps, pipeline.spawned.clip_duration_s)?;
    let total = last - first + 1;
    let with_colliders = job.config.output.with_colliders;
    let meta = pipeline.meta(&scene, with_colliders, job.config.fps)?;
    let vertices = pipeline
        .spawned
        .skins
        .iter()
        .map(|s| meta_vertices(&meta, &s.name))
        .sum();
    let export_options = ExportOptions {
        with_colliders,
        strain_colors: job
            .config
            .output
            .strain_colors
            .then(super::StrainColorMap::default),
        ..ExportOptions::default()
    };
    // Fail on a bad --out before any simulation work.
    super::atomic::check_writable(&job.out)?;
    let mut sink: Box<dyn FrameSink> = job.format.sink(&job.out, &export_options);
    sink.begin(&meta)?;

    let fingerprint = fingerprint(job, &model_bytes);
    let ck_path = checkpoint_path(&job.out);
    let mut stored: Vec<Vec<Vec<[f32; 3]>>> = Vec::new();
    let mut stats = Stats::default();
    let mut frame = 0u32; // simulated frames since time 0
    let mut written = 0u32;
    let mut resumed_from = 0;
    if job.resume && ck_path.exists() {
        let text = std::fs::read_to_string(&ck_path).map_err(|source| IoError::File {
            path: ck_path.clone(),
            source,
        })?;
        let ck: CheckpointFile = serde_json::from_str(&text).map_err(|source| IoError::Json {
            path: ck_path.clone(),
            source,
        })?;
        if ck.fingerprint != fingerprint || ck.version != 1 {
            return Err(ExportJobError::CheckpointMismatch {
                path: ck_path,
                reason: "model, clip, range, format or settings changed".into(),
            });
        }
        restore_state(&mut pipeline.world, &ck.state)?;
        for (i, f) in ck.frames.iter().enumerate() {
            let positions: Vec<Vec<glam::Vec3>> = f
                .iter()
                .map(|m| m.iter().map(|p| glam::Vec3::from_array(*p)).collect())
                .collect();
            let refs: Vec<&[glam::Vec3]> = positions.iter().map(Vec::as_slice).collect();
            sink.write_frame(i as u32, &refs)?;
        }
        written = ck.frames_done;
        frame = first + written;
        stats = ck.stats;
        stored = ck.frames;
        resumed_from = written;
    }
    // Frame 0 is the spawn state (the skinned pose at time 0); every schedule run advances the
    // clock by one frame.
    while frame <= last {
        if frame > 0 {
            pipeline.schedule.run(&mut pipeline.world);
            let d = scene_diagnostics(&pipeline.world)?;
            let its: u32 = d.skins.iter().map(|s| s.iterations).sum();
            if frame >= first {
                stats.iterations_sum += u64::from(its);
                stats.iterations_max = stats.iterations_max.max(its);
                for s in &d.skins {
                    stats.residual_max = stats.residual_max.max(s.residual);
                    stats.unresolved += s.contact.as_ref().map_or(0, |c| c.unresolved.len() as u64);
                }
            }
        }
        if frame >= first {
            let positions = pipeline.frame(with_colliders)?;
            let refs: Vec<&[glam::Vec3]> = positions.iter().map(Vec::as_slice).collect();
            sink.write_frame(written, &refs)?;
            stored.push(
                positions
                    .iter()
                    .map(|m| m.iter().map(|p| p.to_array()).collect())
                    .collect(),
            );
            written += 1;
            progress(written, total);
            let every = job.config.output.checkpoint_every;
            if every > 0 && written.is_multiple_of(every) && frame < last {
                let ck = CheckpointFile {
                    version: 1,
                    fingerprint: fingerprint.clone(),
                    frames_done: written,
                    state: capture_state(&mut pipeline.world)?,
                    frames: stored.clone(),
                    stats: stats.clone(),
                };
                let json = serde_json::to_vec(&ck).map_err(|source| IoError::Json {
                    path: ck_path.clone(),
                    source,
                })?;
                write_atomic(&ck_path, &json)?;
            }
        }
        frame += 1;
    }
    let files = sink.finish()?;
    if ck_path.exists() {
        let _ = std::fs::remove_file(&ck_path);
    }
    let seconds = started.elapsed().as_secs_f64();
    let simulated = (written - resumed_from).max(1);
    Ok(ExportSummary {
        frames: written,
        vertices,
        iterations_mean: stats.iterations_sum as f64 / f64::from(written.max(1)),
        iterations_max: stats.iterations_max,
        residual_max: stats.residual_max,
        unresolved_contacts: stats.unresolved,
        seconds,
        frames_per_second: f64::from(simulated) / seconds.max(1e-9),
        resumed_from_frame: resumed_from,
        files,
    })
}

fn meta_vertices(meta: &ExportMeta, name: &str) -> usize {
    meta.meshes
        .iter()
        .find(|m| m.name == name)
        .map_or(0, |m| m.rest_positions.len())
}
