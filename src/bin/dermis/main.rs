//! The `dermis` command line: see `dermis --help`.

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
enum Command {}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match cli.command {}
}
