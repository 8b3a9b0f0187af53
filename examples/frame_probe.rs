//! Probe: where a tube-10k arm frame's iterations go, per frame schedule, against a tight reference.
use std::time::Instant;

use dermis::bench::arm::{ArmRun, ArmWorkload};
use dermis::collision::FrameSchedule;
use dermis::solver::{Loads, RelaxConfig};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let n: usize = args.get(1).and_then(|a| a.parse().ok()).unwrap_or(10_000);
    let frames: usize = args.get(2).and_then(|a| a.parse().ok()).unwrap_or(10);
    let first: usize = args.get(3).and_then(|a| a.parse().ok()).unwrap_or(12);
    let work = ArmWorkload::new("tube", n, (126, 200), dermis::bench::arm::CLIP_FRAMES);
    for (name, predict, sub) in [
        ("old: no predict, half budget on substeps", false, u32::MAX),
        ("predict, half budget", true, u32::MAX),
        ("no predict, 0 substep its", false, 0),
        ("predict, 0 substep its", true, 0),
    ] {
        let mut run = ArmRun::new(&work, first, 500).unwrap();
        run.predict = predict;
        run.schedule = FrameSchedule {
            substep_iterations: sub,
        };
        let (mut times, mut its, mut subs, mut conv, mut gaps, mut res) =
            (vec![], 0, 0, 0, vec![], 0.0f32);
        for _ in 0..frames {
            let t0 = Instant::now();
            let t = run.step(&work).unwrap();
            times.push(t0.elapsed().as_secs_f64() * 1e3);
            its += t.iterations;
            subs += t.substeps;
            conv += usize::from(t.converged);
            let rep = run.last.clone().unwrap();
            res = res.max(rep.residual);
            // Reference: keep solving this frame's state tightly.
            let mut x = run.x.clone();
            let mut c = run.contact.clone();
            let anchors = work.anchors(run.frame);
            let loads = Loads {
                anchors: Some(&anchors),
                ..Default::default()
            };
            let cfg = RelaxConfig {
                max_iterations: 5000,
                tolerance: 1e-7,
                stagnation_window: 500,
                ..work.relax_config()
            };
            let r = work
                .tube
                .system
                .relax_projected(&mut x, &loads, &cfg, Some(&mut c))
                .unwrap();
            let dx = x
                .iter()
                .zip(&run.x)
                .map(|(a, b)| a.distance(*b))
                .fold(0.0f32, f32::max);
            gaps.push((
                (rep.energy - r.energy) / r.energy.abs(),
                dx,
                r.residual,
                rep.residual,
                t.iterations,
                t.substeps,
                t.unresolved,
            ));
        }
        times.sort_by(f64::total_cmp);
        println!(
            "{name}: median {:.1} ms p99 {:.1} ms, its/frame {:.1}, substeps/frame {:.1}, converged {conv}/{frames}, worst residual {res:.2e}",
            times[times.len() / 2],
            times[times.len() - 1],
            its as f64 / frames as f64,
            subs as f64 / frames as f64
        );
        for g in gaps {
            println!(
                "   dE/E {:.2e}  max|dx| {:.2e} m  ref res {:.1e}  res {:.1e} its {} sub {} unres {}",
                g.0, g.1, g.2, g.3, g.4, g.5, g.6
            );
        }
    }
}
