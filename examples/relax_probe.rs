//! A fixed relaxation workload for profiling and the CI instruction-count guard: a skin tube of
//! about 10k vertices with anchors, relaxed for a fixed number of iterations.
//!
//! `cargo run --release --example relax_probe -- [vertices] [iterations] [frames]`
//!
//! One frame runs exactly `iterations` iterations (tolerance 0); several frames are
//! warm-started and stop at the default tolerance. Frame `f` uses the anchors of the bench's
//! animation frame `f + PROBE_FRAME0` (environment variable, default 10).

use dermis::bench::TubeWorkload;
use dermis::solver::{Loads, RelaxConfig};

fn main() {
    let mut args = std::env::args().skip(1).map(|a| a.parse::<usize>().ok());
    let vertices = args.next().flatten().unwrap_or(10_000);
    let iterations = args.next().flatten().unwrap_or(30);
    let frames = args.next().flatten().unwrap_or(1);
    let work = TubeWorkload::new("probe", vertices);
    let mut x = work.mesh.positions().to_vec();
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
        let report = work
            .system
            .relax(&mut x, &loads, &config)
            .expect("finite inputs");
        println!(
            "frame {frame}: {} iterations, residual {:.3e}, energy {:.12e}, {:?}",
            report.iterations, report.residual, report.energy, report.stop
        );
    }
}
