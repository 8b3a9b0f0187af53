//! `dermis export`: play a rigged model's clip, let the skin settle every frame, write frames.

use std::io::IsTerminal;
use std::path::PathBuf;

use dermis::export::{ExportConfig, ExportJob, Format, FrameRange, run_export};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

use crate::CliResult;

#[derive(clap::Args)]
pub struct Args {
    /// The rigged model (`.gltf` or `.glb`).
    model: PathBuf,
    /// Clip name or index (default: the first clip).
    #[arg(long)]
    clip: Option<String>,
    /// Frames per second (overrides the settings file; default 30).
    #[arg(long)]
    fps: Option<f32>,
    /// First exported time, s (the simulation still starts at 0).
    #[arg(long, requires = "end", conflicts_with = "frames")]
    start: Option<f64>,
    /// Last exported time, s.
    #[arg(long, requires = "start")]
    end: Option<f64>,
    /// Export this many frames from time 0 (default: the whole clip).
    #[arg(long)]
    frames: Option<u32>,
    /// Output file; sequences (obj, ply) number it `stem_000012.ext`.
    #[arg(long)]
    out: PathBuf,
    /// Output format (default: from the settings file, else from the extension of --out, else glb).
    #[arg(long)]
    format: Option<String>,
    /// Settings file (TOML; every field optional, see `dermis::export::ExportConfig`).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Also write the muscle and bone meshes as they moved.
    #[arg(long)]
    with_colliders: bool,
    /// Continue an interrupted export from its checkpoint (`OUT.dermis-checkpoint.json`).
    #[arg(long)]
    resume: bool,
    /// Print the summary as JSON.
    #[arg(long)]
    json: bool,
}

pub fn run(args: Args) -> CliResult {
    let mut config = match &args.config {
        Some(path) => ExportConfig::read(path)?,
        None => ExportConfig::default(),
    };
    if let Some(fps) = args.fps {
        config.fps = fps;
    }
    if args.with_colliders {
        config.output.with_colliders = true;
    }
    let format_name = match (&args.format, args.config.is_some()) {
        (Some(f), _) => f.clone(),
        (None, true) => config.output.format.clone(),
        (None, false) => args
            .out
            .extension()
            .map(|e| e.to_string_lossy().to_ascii_lowercase())
            .filter(|e| ["glb", "obj", "ply", "usda"].contains(&e.as_str()))
            .unwrap_or_else(|| config.output.format.clone()),
    };
    let format: Format = format_name.parse()?;
    config.output.format = format_name;
    let frames = match (args.start, args.end, args.frames) {
        (Some(start_s), Some(end_s), _) => FrameRange::Span { start_s, end_s },
        (_, _, Some(n)) => FrameRange::Count(n),
        _ => FrameRange::Clip,
    };
    // A missing output directory is created; one that cannot be is reported by the export.
    if let Some(dir) = args.out.parent().filter(|d| !d.as_os_str().is_empty()) {
        let _ = std::fs::create_dir_all(dir);
    }
    let job = ExportJob {
        model: args.model,
        clip: args.clip,
        frames,
        out: args.out,
        format,
        config,
        resume: args.resume,
    };
    let bar = ProgressBar::with_draw_target(Some(0), ProgressDrawTarget::hidden());
    if std::io::stderr().is_terminal() {
        bar.set_draw_target(ProgressDrawTarget::stderr());
        bar.set_style(
            ProgressStyle::with_template("{bar:40} {pos}/{len} frames  {per_sec}  eta {eta}")
                .expect("a valid template"),
        );
    }
    let summary = run_export(&job, |done, total| {
        bar.set_length(u64::from(total));
        bar.set_position(u64::from(done));
    })?;
    bar.finish_and_clear();
    if args.json {
        println!("{}", serde_json::to_string_pretty(&summary)?);
    } else {
        println!(
            "{} frames of {} skin vertices in {:.1} s ({:.1} frames/s): mean {:.1} iterations/frame, max residual {:.2e}, {} unresolved contacts",
            summary.frames,
            summary.vertices,
            summary.seconds,
            summary.frames_per_second,
            summary.iterations_mean,
            summary.residual_max,
            summary.unresolved_contacts
        );
        crate::print_written(&summary.files);
    }
    Ok(())
}
