//! `dermis anatomy`: the muscles-and-bones scenes, simulated through the ECS and exported.

use std::path::PathBuf;

use dermis::anatomy::export::{JawExportJob, run_jaw_export};
use dermis::export::Format;

use crate::CliResult;

/// The anatomy scenes.
#[derive(clap::Subcommand)]
pub enum Scene {
    /// The paper's Fig. 1: contracting a platysma-like muscle opens a hinged jaw (activation
    /// 0 -> 1 over the clip); writes the skin sleeve, the muscle surface and the bones.
    Jaw(JawArgs),
}

#[derive(clap::Args)]
pub struct JawArgs {
    /// Output file; sequences (obj, ply) number it `stem_000012.ext`.
    #[arg(long)]
    out: PathBuf,
    /// Output format: glb, obj, ply or usda (default: from the extension of --out, else glb).
    #[arg(long)]
    format: Option<String>,
    /// Frames to write (at least 1).
    #[arg(long, default_value_t = 60)]
    frames: u32,
    /// Frame rate written into the file.
    #[arg(long, default_value_t = 30.0)]
    fps: f32,
    /// Dynamics steps of 1 ms per frame (at least 1).
    #[arg(long, default_value_t = 40)]
    steps_per_frame: u32,
    /// Write only the muscle and bones, no skin sleeve.
    #[arg(long)]
    no_skin: bool,
    /// Print the summary as JSON.
    #[arg(long)]
    json: bool,
}

pub fn run(scene: Scene) -> CliResult {
    match scene {
        Scene::Jaw(args) => jaw(args),
    }
}

fn jaw(args: JawArgs) -> CliResult {
    let format: Format = match &args.format {
        Some(f) => f.parse()?,
        None => args
            .out
            .extension()
            .and_then(|e| e.to_str()?.parse().ok())
            .unwrap_or(Format::Glb),
    };
    let mut job = JawExportJob::new(args.out, format);
    job.frames = args.frames;
    job.fps = args.fps;
    job.steps_per_frame = args.steps_per_frame;
    if args.no_skin {
        job.skin = None;
    }
    job.validate()?;
    // A missing output directory is created; one that cannot be is reported by the export.
    if let Some(dir) = job.out.parent().filter(|d| !d.as_os_str().is_empty()) {
        let _ = std::fs::create_dir_all(dir);
    }
    let summary = run_jaw_export(&job)?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&summary)?);
    } else {
        println!(
            "{} frames in {:.1} s: jaw opened {:.2} deg, muscle length x{:.3}, volume x{:.4} (worst {:.4}), {} unresolved contacts",
            summary.frames,
            summary.wall_time_s,
            summary.final_jaw_angle_deg,
            summary.final_muscle_length_ratio,
            summary.muscle_volume_ratio.last().copied().unwrap_or(1.0),
            summary
                .muscle_volume_ratio
                .iter()
                .copied()
                .fold(1.0f32, |w, r| if (r - 1.0).abs() > (w - 1.0).abs() {
                    r
                } else {
                    w
                }),
            summary.unresolved_contacts
        );
        crate::print_written(&summary.files);
    }
    Ok(())
}
