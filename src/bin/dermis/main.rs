//! The `dermis` command line: see `dermis --help`.

mod anatomy;
mod bench;
mod equilibrium;
mod export;
mod inspect;
mod make_arm;
mod paper;
mod pose;

use std::process::ExitCode;

use clap::{Parser, Subcommand};

/// Anatomical skin as a spring mesh: relax, inspect, pose, export and benchmark.
#[derive(Parser)]
#[command(name = "dermis", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Play a rigged model's clip, settle the skin every frame, write the frames (glb, obj, ply, usda).
    Export(export::Args),
    /// Print a glTF model's meshes with roles and quality, skins and clips.
    Inspect(inspect::InspectArgs),
    /// Write every mesh primitive of a glTF model posed at a time (OBJ or PLY, world space).
    Pose(pose::PoseArgs),
    /// Equilibrium of a spring mesh (or the FEM membrane) under point forces and pins.
    Equilibrium(equilibrium::Args),
    /// Standard performance workloads with an in-run machine calibration.
    Bench(bench::Args),
    /// Reproduce the source papers' experiments.
    #[command(subcommand)]
    Paper(paper::Experiment),
    /// Simulate a muscles-and-bones scene through the ECS and write its frames (glb, obj, ply, usda).
    #[command(subcommand)]
    Anatomy(anatomy::Scene),
    /// Regenerate the bundled arm model (assets/arm.glb) byte-for-byte.
    MakeArm(make_arm::MakeArmArgs),
}

/// A command's failure: printed as `error: ...`, exit code 1.
type CliResult = Result<(), Box<dyn std::error::Error>>;

/// Lists the first few files a command wrote, and how many there are in all.
fn print_written(files: &[std::path::PathBuf]) {
    for f in files.iter().take(3) {
        println!("  {}", f.display());
    }
    if files.len() > 3 {
        println!("  ... {} files in all", files.len());
    }
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    // The solves' teams spin between their loops: one worker per CPU, pinned, unless
    // `DERMIS_PIN=0` (see `dermis::threads`).
    let pin = std::env::var("DERMIS_PIN").map_or(true, |v| v.trim() != "0");
    if let Err(e) = dermis::threads::build_global_pool(pin) {
        eprintln!("error: {e}");
        return ExitCode::FAILURE;
    }
    let result: CliResult = match cli.command {
        Command::Export(args) => export::run(args),
        Command::Inspect(args) => inspect::run(args),
        Command::Pose(args) => pose::run(args),
        Command::Equilibrium(args) => equilibrium::run(args),
        Command::Bench(args) => bench::run(args),
        Command::Paper(experiment) => paper::run(experiment),
        Command::MakeArm(args) => make_arm::run(args),
        Command::Anatomy(scene) => anatomy::run(scene),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}
