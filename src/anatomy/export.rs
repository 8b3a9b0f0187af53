//! The jaw animation written to files: the ECS jaw scene played with activation rising 0 → 1, every frame handed to an export `FrameSink`.
//!
//! [`run_jaw_export`] spawns [`spawn_jaw`] (with a skin sleeve over the muscle unless
//! [`JawExportJob::skin`] is off) in a plain `World`, runs the dermis schedule once per frame
//! with the muscle's activation at `frame / (frames - 1)`, and writes the skin, the muscle's
//! outer surface and the three bones through the format's [`FrameSink`](crate::export::FrameSink) (glb, obj, ply or usda; the
//! sinks write a temporary file and rename it, so no half-written file is left). It returns a
//! [`JawExportSummary`] with the jaw angle and muscle volume ratio of every frame. This is
//! `dermis anatomy jaw`.
//!
//! ```no_run
//! use dermis::anatomy::export::{JawExportJob, run_jaw_export};
//! use dermis::export::Format;
//! let job = JawExportJob::new("out/jaw.usda".into(), Format::Usda);
//! let summary = run_jaw_export(&job).unwrap();
//! assert!(summary.final_jaw_angle_deg > 5.0);
//! ```

use std::path::PathBuf;
use std::time::Instant;

use bevy_ecs::prelude::*;
use glam::Vec3;
use serde::Serialize;
use thiserror::Error;

use super::AnatomyError;
use super::scenes::{JawConfig, JawScene};
use crate::ecs::{
    AnatomyDiagnostics, BonePose, ColliderState, DermisPlugin, JawSkinConfig, MuscleActivation,
    MuscleState, RelaxDiagnostics, RestGeometry, RigError, SkinPositions, spawn_jaw,
};
use crate::export::{ExportError, ExportMeta, ExportOptions, Format, MeshMeta, MeshRole};

/// What to export and how.
#[derive(Debug, Clone, PartialEq)]
pub struct JawExportJob {
    /// Output file; sequences (obj, ply) number it `stem_000012.ext`.
    pub out: PathBuf,
    /// File format.
    pub format: Format,
    /// Frames to write (at least 1); the activation rises linearly from 0 at the first frame
    /// to 1 at the last.
    pub frames: u32,
    /// Frame rate written into the file, frames per second.
    pub fps: f32,
    /// Dynamics steps per frame (each of the scene's fixed substeps).
    pub steps_per_frame: u32,
    /// Drape a skin sleeve over the muscle (`None`: write only the muscle and bones).
    pub skin: Option<JawSkinConfig>,
    /// The jaw scene.
    pub scene: JawConfig,
}

impl JawExportJob {
    /// 60 frames at 30 fps, 40 steps of 1 ms per frame, the default skin sleeve and scene.
    pub fn new(out: PathBuf, format: Format) -> Self {
        Self {
            out,
            format,
            frames: 60,
            fps: 30.0,
            steps_per_frame: 40,
            skin: Some(JawSkinConfig::default()),
            scene: JawConfig::default(),
        }
    }
}

impl JawExportJob {
    /// Checks the job's numbers (frames, fps, steps per frame) without touching any file.
    pub fn validate(&self) -> Result<(), JawExportError> {
        if self.frames == 0 {
            return Err(invalid("frames", 0.0, "at least 1"));
        }
        if !(self.fps.is_finite() && self.fps > 0.0) {
            return Err(invalid("fps", f64::from(self.fps), "finite, > 0"));
        }
        if self.steps_per_frame == 0 {
            return Err(invalid("steps_per_frame", 0.0, "at least 1"));
        }
        Ok(())
    }
}

/// What a jaw export did.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct JawExportSummary {
    /// Frames written.
    pub frames: u32,
    /// Format written.
    pub format: String,
    /// Skin vertices (0 without a skin).
    pub skin_vertices: usize,
    /// Muscle surface vertices.
    pub muscle_vertices: usize,
    /// Muscle activation of every frame.
    pub activation: Vec<f32>,
    /// Jaw opening angle of every frame, degrees.
    pub jaw_angle_deg: Vec<f32>,
    /// Jaw opening angle at the last frame, degrees.
    pub final_jaw_angle_deg: f32,
    /// Muscle volume over rest volume, every frame.
    pub muscle_volume_ratio: Vec<f32>,
    /// Muscle length over rest length at the last frame.
    pub final_muscle_length_ratio: f32,
    /// Skin vertices left inside a collider after their frame, summed over frames.
    pub unresolved_contacts: u64,
    /// Wall-clock seconds of the run (not part of any output file).
    pub wall_time_s: f64,
    /// Files written.
    pub files: Vec<PathBuf>,
}

/// Why a jaw export failed. Nothing half-written is left behind.
#[derive(Debug, Error)]
pub enum JawExportError {
    /// A job parameter is out of range; the message names it. Fix the argument.
    #[error("invalid job: {name} = {value} ({expected})")]
    InvalidJob {
        /// The parameter.
        name: &'static str,
        /// The value given.
        value: f64,
        /// What is allowed.
        expected: &'static str,
    },
    /// The scene could not be built (bad [`JawConfig`] or skin configuration).
    #[error(transparent)]
    Rig(#[from] RigError),
    /// The dynamics diverged at a frame; lower the time step or raise the drag.
    #[error("frame {frame}: {source}")]
    Simulation {
        /// The frame.
        frame: u32,
        /// The reason.
        source: AnatomyError,
    },
    /// The sink could not write (unwritable directory, disk full, ...).
    #[error(transparent)]
    Export(#[from] ExportError),
}

fn invalid(name: &'static str, value: f64, expected: &'static str) -> JawExportError {
    JawExportError::InvalidJob {
        name,
        value,
        expected,
    }
}

/// Plays and writes the jaw animation (see the [module docs](self)).
pub fn run_jaw_export(job: &JawExportJob) -> Result<JawExportSummary, JawExportError> {
    let started = Instant::now();
    job.validate()?;
    let mut world = World::new();
    let mut schedule = DermisPlugin.build_schedule(&mut world);
    let jaw = spawn_jaw(
        &mut world,
        &job.scene,
        job.steps_per_frame,
        job.skin.as_ref(),
    )?;
    let bones = [("skull", jaw.skull), ("jaw", jaw.jaw), ("spine", jaw.spine)];
    let collider = |world: &World, e: Entity| world.get::<ColliderState>(e).cloned();
    let mut meshes = Vec::new();
    if let Some(skin) = jaw.skin
        && let Some(rest) = world.get::<RestGeometry>(skin)
    {
        meshes.push(MeshMeta::new(
            "sleeve",
            MeshRole::Skin,
            rest.mesh().triangles().to_vec(),
            rest.positions().to_vec(),
        ));
    }
    let muscle_state = collider(&world, jaw.muscle).ok_or(RigError::NotARig(jaw.muscle))?;
    let muscle_vertices = muscle_state.local_vertices.len();
    meshes.push(MeshMeta::new(
        "platysma",
        MeshRole::Muscle,
        muscle_state.triangles.as_ref().clone(),
        muscle_state.local_vertices.clone(),
    ));
    for (name, e) in bones {
        let state = collider(&world, e).ok_or(RigError::NotARig(e))?;
        meshes.push(MeshMeta::new(
            name,
            MeshRole::Bone,
            state.triangles.as_ref().clone(),
            state.local_vertices.clone(),
        ));
    }
    let meta = ExportMeta::new(meshes, job.fps);
    let options = ExportOptions {
        with_colliders: true,
        ..ExportOptions::default()
    };
    let mut sink = job.format.sink(&job.out, &options);
    sink.begin(&meta)?;
    let mut summary = JawExportSummary {
        frames: job.frames,
        format: job.format.to_string(),
        skin_vertices: jaw
            .skin
            .and_then(|s| world.get::<SkinPositions>(s))
            .map_or(0, |p| p.len()),
        muscle_vertices,
        activation: Vec::new(),
        jaw_angle_deg: Vec::new(),
        final_jaw_angle_deg: 0.0,
        muscle_volume_ratio: Vec::new(),
        final_muscle_length_ratio: 1.0,
        unresolved_contacts: 0,
        wall_time_s: 0.0,
        files: Vec::new(),
    };
    for frame in 0..job.frames {
        let activation = if job.frames == 1 {
            1.0
        } else {
            frame as f32 / (job.frames - 1) as f32
        };
        if let Some(mut a) = world.get_mut::<MuscleActivation>(jaw.muscle) {
            a.0 = activation;
        }
        schedule.run(&mut world);
        if let Some(e) = world
            .get::<AnatomyDiagnostics>(jaw.anatomy.rig)
            .and_then(|d| d.error.clone())
        {
            return Err(JawExportError::Simulation { frame, source: e });
        }
        let mut positions: Vec<Vec<Vec3>> = Vec::new();
        if let Some(skin) = jaw.skin {
            if let Some(p) = world.get::<SkinPositions>(skin) {
                positions.push(p.to_vec());
            }
            if let Some(c) = world
                .get::<RelaxDiagnostics>(skin)
                .and_then(|d| d.contact.as_ref())
            {
                summary.unresolved_contacts += c.unresolved.len() as u64;
            }
        }
        let muscle = collider(&world, jaw.muscle).ok_or(RigError::NotARig(jaw.muscle))?;
        positions.push(muscle.local_vertices);
        for (_, e) in bones {
            let pose = *world.get::<BonePose>(e).ok_or(RigError::NotARig(e))?;
            let state = collider(&world, e).ok_or(RigError::NotARig(e))?;
            positions.push(
                state
                    .local_vertices
                    .iter()
                    .map(|&p| pose.transform_point(p))
                    .collect(),
            );
        }
        let slices: Vec<&[Vec3]> = positions.iter().map(Vec::as_slice).collect();
        sink.write_frame(frame, &slices)?;
        let angle = world
            .get::<BonePose>(jaw.jaw)
            .map_or(0.0, |p| p.angle_about(JawScene::HINGE_AXIS).to_degrees());
        let state = world
            .get::<MuscleState>(jaw.muscle)
            .copied()
            .unwrap_or_default();
        summary.activation.push(activation);
        summary.jaw_angle_deg.push(angle);
        summary.muscle_volume_ratio.push(state.volume_ratio());
        summary.final_jaw_angle_deg = angle;
        summary.final_muscle_length_ratio = state.length_m / state.rest_length_m;
    }
    summary.files = sink.finish()?;
    summary.wall_time_s = started.elapsed().as_secs_f64();
    Ok(summary)
}
