//! Probe: run tube-10k arm frames for profiling.
use std::time::Instant;

use dermis::bench::arm::{ArmRun, ArmWorkload};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let n: usize = args.get(1).and_then(|a| a.parse().ok()).unwrap_or(10_000);
    let frames: usize = args.get(2).and_then(|a| a.parse().ok()).unwrap_or(10);
    let work = ArmWorkload::new("tube", n, (126, 200), dermis::bench::arm::CLIP_FRAMES);
    let mut run = ArmRun::new(&work, 12, 500).unwrap();
    for _ in 0..frames {
        let t0 = Instant::now();
        let t = run.step(&work).unwrap();
        let d = run.contact.diagnostics().clone();
        println!(
            "{:.1} ms its {} sub {} passes {} coll {:.1} ms conv {} | contacts {} exact {} cert {} skipbound {} skipaabb {} moved {}",
            t0.elapsed().as_secs_f64() * 1e3,
            t.iterations,
            t.substeps,
            t.passes,
            t.collision_s * 1e3,
            t.converged,
            d.contacts,
            d.exact_queries,
            d.certified_queries,
            d.skipped_bound,
            d.skipped_aabb,
            d.moved
        );
    }
}
