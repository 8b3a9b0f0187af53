//! `dermis paper`: the source papers' experiments.

use std::path::PathBuf;

use dermis::paper::{FIG4_RULES, Fig4Config, fig4, render_fig4};

use crate::CliResult;

#[derive(clap::Subcommand)]
pub enum Experiment {
    /// Van Gelder Fig. 4: graded hexagon under uniform traction, each stiffness rule's deviation
    /// from the exact uniform expansion; writes `fig4-seed<N>.png` per seed.
    Fig4 {
        /// Output directory (created if missing).
        #[arg(long)]
        out: PathBuf,
        /// Number of mesh seeds to run (0, 1, ...).
        #[arg(long, default_value_t = 5)]
        seeds: u64,
        /// Print the results as JSON.
        #[arg(long)]
        json: bool,
    },
}

pub fn run(experiment: Experiment) -> CliResult {
    match experiment {
        Experiment::Fig4 { out, seeds, json } => {
            std::fs::create_dir_all(&out).map_err(|e| format!("{}: {e}", out.display()))?;
            let config = Fig4Config::default();
            let mut runs = Vec::new();
            for seed in 0..seeds {
                let result = fig4(seed, &config)?;
                render_fig4(&result, &out.join(format!("fig4-seed{seed}.png")))?;
                runs.push(result.run);
            }
            if json {
                println!(
                    "{}",
                    serde_json::to_string_pretty(
                        &serde_json::json!({ "config": config, "runs": runs })
                    )?
                );
            } else {
                println!("deviation from uniform expansion |d - sX| / |sX| (rigid motion removed)");
                print!("{:>5} {:>8}", "seed", "vertices");
                for r in FIG4_RULES {
                    print!(" {r:>14}");
                }
                println!();
                for run in &runs {
                    print!("{:>5} {:>8}", run.seed, run.vertices);
                    for r in FIG4_RULES {
                        print!(" {:>14.3e}", run.deviation[r]);
                    }
                    println!();
                }
                println!(
                    "figures: {}/fig4-seed<N>.png (rest, constant, inverse-length, area-len2, poisson)",
                    out.display()
                );
            }
            Ok(())
        }
    }
}
