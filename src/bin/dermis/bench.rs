//! `dermis bench`: the standard workloads, with an in-run calibration.

use std::io::IsTerminal;

use crate::CliResult;

#[derive(clap::Args)]
pub struct Args {
    /// Smaller workloads and fewer frames (seconds instead of a minute or two).
    #[arg(long)]
    quick: bool,
    /// Print the report as JSON.
    #[arg(long)]
    json: bool,
}

pub fn run(args: Args) -> CliResult {
    let chatty = std::io::stderr().is_terminal();
    let report = dermis::bench::run(args.quick, |stage| {
        if chatty {
            eprintln!("bench: {stage}");
        }
    });
    if args.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
        return Ok(());
    }
    let m = &report.machine;
    println!(
        "machine: {} threads, triad {:.1} GB/s, spring {:.2} ns",
        m.threads, m.bandwidth_gb_s, m.spring_ns
    );
    println!(
        "{:<10} {:>9} {:>9} {:>9} {:>7} {:>12} {:>7} {:>7} {:>8} {:>9} {:>8}",
        "workload",
        "vertices",
        "frame ms",
        "p99 ms",
        "its",
        "Mvert-it/s",
        "floor",
        "2/1",
        "B/vert",
        "vs naive",
        "vs prev"
    );
    for w in &report.workloads {
        println!(
            "{:<10} {:>9} {:>9.2} {:>9.2} {:>7.1} {:>12.1} {:>7.3} {:>7.2} {:>8.1} {:>9.2} {:>8.2}",
            w.name,
            w.skin_vertices,
            w.frame_ms_median,
            w.frame_ms_p99,
            w.iterations_per_frame_mean,
            w.relax_vertex_iterations_per_s / 1e6,
            w.relax_fraction_of_floor,
            w.thread_scaling_2_over_1,
            w.bytes_per_vertex,
            w.relax_speedup_vs_naive_scatter,
            w.relax_speedup_vs_previous
        );
    }
    Ok(())
}
