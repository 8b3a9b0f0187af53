//! A fixed relaxation workload for profiling and the CI instruction-count guard: a skin tube of
//! about 10k vertices with anchors, relaxed for a fixed number of iterations.
//!
//! `cargo run --release --example relax_probe -- [vertices] [iterations] [frames]`
//!
//! One frame runs exactly `iterations` iterations (tolerance 0); several frames are
//! warm-started and stop at the default tolerance. Frame `f` uses the anchors of the bench's
//! animation frame `f + PROBE_FRAME0` (environment variable, default 10). Prints the exact
//! final energy, the wall time of each frame's relaxation and its vertex-iterations per second.

use dermis::bench::TubeWorkload;
use dermis::solver::{Loads, RelaxConfig};

fn main() {
    let mut args = std::env::args().skip(1).map(|a| a.parse::<usize>().ok());
    let vertices = args.next().flatten().unwrap_or(10_000);
    let iterations = args.next().flatten().unwrap_or(30);
    let frames = args.next().flatten().unwrap_or(1);
    let work = TubeWorkload::new("probe", vertices);
    let mut x = work.mesh.positions().to_vec();
    println!(
        "{} vertices, {} springs, {:.1} B of springs per vertex",
        x.len(),
        work.system.edge_count(),
        work.system.bytes_per_vertex()
    );
    for frame in 0..frames {
        let first: usize = std::env::var("PROBE_FRAME0")
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(10);
        let anchors = work.anchors(frame + first);
        let loads = Loads {
            anchors: Some(&anchors),
            ..Default::default()
        };
        let config = RelaxConfig {
            max_iterations: iterations as u32,
            tolerance: if frames > 1 { 1e-4 } else { 0.0 },
            // A fixed amount of work: no early stop on stagnation.
            stagnation_window: if frames > 1 { 50 } else { 0 },
            ..RelaxConfig::DEFAULT
        };
        // PROBE_REPEAT (default 1): solve the frame that many times from the same start and
        // report the fastest (the machine's speed drifts).
        let repeat: usize = std::env::var("PROBE_REPEAT")
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(1);
        let start_x = x.clone();
        let mut seconds = f64::INFINITY;
        let mut report = None;
        for _ in 0..repeat.max(1) {
            x.copy_from_slice(&start_x);
            let start = std::time::Instant::now();
            let r = work
                .system
                .relax(&mut x, &loads, &config)
                .expect("finite inputs");
            seconds = seconds.min(start.elapsed().as_secs_f64());
            report = Some(r);
        }
        let report = report.expect("at least one run");
        // The exact energy (shortest round-trip form) shows any change of result.
        println!(
            "frame {frame}: {} iterations, residual {:.3e}, energy {:e}, {:?}, {:.3} ms, \
             {:.1} M vertex-iterations/s",
            report.iterations,
            report.residual,
            report.energy,
            report.stop,
            seconds * 1e3,
            (work.mesh.positions().len() as f64 * report.iterations as f64) / seconds / 1e6
        );
    }
}
