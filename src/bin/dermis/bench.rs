//! `dermis bench`: the standard workloads, with an in-run calibration.

use std::io::IsTerminal;
use std::path::PathBuf;

use dermis::bench::{Plan, arm_workloads, peers};

use crate::CliResult;

#[derive(clap::Args)]
pub struct Args {
    /// Smaller workloads and fewer frames (seconds instead of a minute or two).
    #[arg(long)]
    quick: bool,
    /// Print the report as JSON.
    #[arg(long)]
    json: bool,
    /// Write the workloads' skin tubes (`tube-10k.obj`, `tube-100k.obj`) and the muscle at full
    /// flexion (`muscle.obj`) into this folder for `benches/peers/`, and exit.
    #[arg(long, value_name = "DIR")]
    write_mesh: Option<PathBuf>,
}

pub fn run(args: Args) -> CliResult {
    if let Some(dir) = &args.write_mesh {
        let plan = if args.quick { Plan::QUICK } else { Plan::FULL };
        for path in peers::write_peer_files(dir, &arm_workloads(&plan))? {
            println!("{}", path.display());
        }
        return Ok(());
    }
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
        "machine: {}; {} threads, triad {:.1} GB/s, spring {:.2} ns, {} kernels; run took {:.0} s",
        m.cpu, m.threads, m.bandwidth_gb_s, m.spring_ns, m.kernels, report.wall_s
    );
    println!(
        "{:<10} {:>8} {:>7} {:>9} {:>9} {:>6} {:>11} {:>6} {:>5} {:>7} {:>7} {:>7} {:>6} {:>6} {:>6} {:>6}",
        "workload",
        "vertices",
        "frames",
        "frame ms",
        "p99 ms",
        "its",
        "Mvert-it/s",
        "floor",
        "2/1",
        "coll us",
        "vs qry",
        "refit",
        "shuf",
        "B/vert",
        "vs nv",
        "vs prv"
    );
    let opt = |v: Option<f64>, digits: usize| {
        v.map_or_else(|| "-".to_owned(), |v| format!("{v:.digits$}"))
    };
    for w in &report.workloads {
        println!(
            "{:<10} {:>8} {:>7} {:>9.1} {:>9.1} {:>6.0} {:>11.1} {:>6.3} {:>5.2} {:>7} {:>7} {:>7} {:>6} {:>6.1} {:>6.2} {:>6.2}",
            w.name,
            w.skin_vertices,
            format!("{}/{}", w.frames_converged, w.frames),
            w.frame_ms_median,
            w.frame_ms_p99,
            w.iterations_per_frame_mean,
            w.relax_vertex_iterations_per_s / 1e6,
            w.relax_fraction_of_floor,
            w.thread_scaling_2_over_1,
            opt(w.collision_us_per_vertex, 2),
            opt(w.collision_speedup_vs_naive, 2),
            opt(w.collider_refresh_ms, 2),
            opt(w.shuffled_over_ordered, 2),
            w.bytes_per_vertex,
            w.relax_speedup_vs_naive_scatter,
            w.relax_speedup_vs_previous
        );
    }
    println!(
        "frames: converged/timed; coll us: contact µs per skin vertex per frame; vs qry: one naive \
         parry query per vertex over a frame's contact; refit: muscle refit ms; shuf: shuffled / \
         ordered time"
    );
    for w in &report.workloads {
        let l = &w.relax_ns_per_vertex_iteration;
        println!(
            "{} relaxation, ns per vertex-iteration: curvature gather {:.2}, force gather {:.2}, \
             step {:.2}, direction {:.2}, other {:.2}",
            w.name, l.curvature_gather, l.force_gather, l.step, l.direction, l.other
        );
    }
    for w in &report.workloads {
        if let (Some(plan), Some(passes), Some(projections)) = (
            w.collision_plan_us_per_vertex,
            w.collision_passes_us_per_vertex,
            w.collision_projections_us_per_vertex,
        ) {
            println!(
                "{} contact, µs per skin vertex per frame: plan {plan:.3}, substep passes \
                 {passes:.3}, projections in the relaxations {projections:.3}",
                w.name
            );
        }
    }
    if !report.targets.is_empty() {
        println!(
            "issue 8 targets (attainment: measured / target for a floor, target / measured for a ceiling):"
        );
        let short = |v: f64| {
            if v.abs() >= 1e4 {
                format!("{v:.3e}")
            } else {
                format!("{v:.3}")
            }
        };
        for t in &report.targets {
            let side = match t.goal {
                dermis::bench::targets::Goal::AtLeast => ">=",
                dermis::bench::targets::Goal::AtMost => "<=",
            };
            println!(
                "  {:<10} {:<31} {side} {:<9} measured {:<9} attainment {:.2} {}",
                t.workload,
                t.metric,
                short(t.target),
                short(t.measured),
                t.attainment,
                if t.met { "met" } else { "not met" }
            );
        }
    }
    Ok(())
}
