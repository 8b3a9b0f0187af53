//! The `dermis` command line: see `dermis --help`.

mod bench;
mod equilibrium;
mod paper;

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
    /// Equilibrium of a spring mesh (or the FEM membrane) under point forces and pins.
    Equilibrium(equilibrium::Args),
    /// Standard performance workloads with an in-run machine calibration.
    Bench(bench::Args),
    /// Reproduce the source papers' experiments.
    #[command(subcommand)]
    Paper(paper::Experiment),
}

/// A command's failure: printed as `error: ...`, exit code 1.
type CliResult = Result<(), Box<dyn std::error::Error>>;

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Bench(args) => bench::run(args),
        Command::Equilibrium(args) => equilibrium::run(args),
        Command::Paper(experiment) => paper::run(experiment),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}
