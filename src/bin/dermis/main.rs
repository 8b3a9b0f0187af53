//! The `dermis` command line: see `dermis --help`.

use std::process::ExitCode;

use clap::{Parser, Subcommand};

mod inspect;
mod make_arm;
mod pose;

/// Anatomical skin as a spring mesh: relax, inspect, pose, export and benchmark.
#[derive(Parser)]
#[command(name = "dermis", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Write every mesh primitive of a glTF model posed at a time (OBJ or PLY, world space).
    Pose(pose::PoseArgs),
    /// Print a glTF model's meshes with roles and quality, skins and clips.
    Inspect(inspect::InspectArgs),
    /// Regenerate the bundled arm model (assets/arm.glb) byte-for-byte.
    MakeArm(make_arm::MakeArmArgs),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Pose(args) => pose::run(args),
        Command::Inspect(args) => inspect::run(args),
        Command::MakeArm(args) => make_arm::run(args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}
