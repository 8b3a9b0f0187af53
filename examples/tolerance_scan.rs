//! Probe: what the relaxation tolerance buys on the bench's elbow clip.
//!
//! `cargo run --release --example tolerance_scan -- [vertices] [frames]`: every frame of the
//! tube's chain (from frame 12, as `dermis bench`) is solved from the same state at several
//! tolerances and at a tight reference (1e-6, which stops at the f32 floor); prints each one's
//! iterations and its distance to the reference (max and rms over the vertices), then the
//! sums. The chain itself advances at the default tolerance. See `benches/analysis/README.md`.
use dermis::bench::arm::{ArmRun, ArmWorkload, CLIP_FRAMES};
use dermis::solver::RelaxConfig;
use glam::Vec3;

/// The tight reference first, then the default (1e-4) and looser ones.
const TOLERANCES: [f32; 5] = [1e-6, 1e-4, 3e-4, 1e-3, 3e-3];

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let n: usize = args.get(1).and_then(|a| a.parse().ok()).unwrap_or(10_000);
    let frames: usize = args.get(2).and_then(|a| a.parse().ok()).unwrap_or(30);
    let work = ArmWorkload::new("tube", n, (126, 200), CLIP_FRAMES);
    let mut run = ArmRun::new(&work, 12, 500).expect("the bench's own inputs are valid");
    let k = TOLERANCES.len();
    let (mut iterations, mut worst, mut rms_sum) = (vec![0u64; k], vec![0f32; k], vec![0f64; k]);
    for _ in 0..frames {
        let f = run.frame + 1;
        // Each tolerance from the same state: a copy of the run steps the frame with it.
        let solved: Vec<(Vec<Vec3>, u32)> = TOLERANCES
            .iter()
            .map(|&tolerance| {
                let config = RelaxConfig {
                    tolerance,
                    max_iterations: if tolerance < 1e-5 { 3000 } else { 500 },
                    ..work.relax_config()
                };
                let mut copy = run.clone();
                let times = copy
                    .step_with(&work, &config)
                    .expect("the bench's own inputs are valid");
                (copy.x, times.iterations)
            })
            .collect();
        print!("frame {f}: reference {} its |", solved[0].1);
        for (j, (x, its)) in solved.iter().enumerate() {
            let (mut max, mut sq) = (0f32, 0f64);
            for (a, b) in x.iter().zip(&solved[0].0) {
                let d = a.distance(*b);
                max = max.max(d);
                sq += f64::from(d) * f64::from(d);
            }
            let rms = (sq / x.len() as f64).sqrt();
            iterations[j] += u64::from(*its);
            worst[j] = worst[j].max(max);
            rms_sum[j] += rms;
            if j > 0 {
                let (max_um, rms_um) = (max * 1e6, rms * 1e6);
                print!(
                    " {:.0e}: {its} its, max {max_um:.0} um, rms {rms_um:.1} um |",
                    TOLERANCES[j]
                );
            }
        }
        println!();
        run.step(&work).expect("the bench's own inputs are valid");
    }
    for (j, t) in TOLERANCES.iter().enumerate() {
        println!(
            "tolerance {t:.0e}: {} iterations, max distance to the reference {:.0} um, mean rms {:.1} um",
            iterations[j],
            worst[j] * 1e6,
            rms_sum[j] / frames as f64 * 1e6
        );
    }
}
