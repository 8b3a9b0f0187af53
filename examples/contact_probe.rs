//! A fixed contact workload for profiling and the CI instruction-count guard: the bench's
//! tube-10k skin over its 50k-triangle deforming muscle and two capsule bones, contact passes
//! only (no relaxation, so the count does not move when the solver changes).
//!
//! `cargo run --release --example contact_probe -- [vertices] [frames] [passes]`
//!
//! Per frame of the elbow clip (from frame 12): the muscle refitted and the forearm posed, the
//! skin put at its skinned anchors, the frame plan and its substeps
//! ([`SkinCollision::advance_frame`](dermis::collision::SkinCollision::advance_frame)), then
//! `passes` projections in the solver's order with the skin nudged between them as solver
//! steps would. Prints the contact counters and the wall time per pass. The CI guard counts
//! the instructions of `SkinCollision::pass` and the frame plan only (callgrind
//! `--toggle-collect`), not the workload's set-up.

use std::time::Instant;

use dermis::bench::arm::{ArmWorkload, CLIP_FRAMES};
use dermis::solver::Projection;

fn main() {
    let mut args = std::env::args().skip(1).map(|a| a.parse::<usize>().ok());
    let vertices = args.next().flatten().unwrap_or(10_000);
    let frames = args.next().flatten().unwrap_or(3);
    let passes = args.next().flatten().unwrap_or(100);
    let work = ArmWorkload::new("probe", vertices, (126, 200), CLIP_FRAMES);
    let first = 12;
    let (mut contact, ids) = work.collision(first).expect("valid workload");
    let order = work.tube.system.order().to_vec();
    let mut spent = 0.0;
    // One job on the rayon pool, as the solver runs (see `SpringSystem::relax_projected`).
    rayon::scope(|_| {
        for frame in first + 1..=first + frames {
            let muscle = work.muscle_vertices(frame);
            let mut x: Vec<_> = work.anchors(frame).iter().map(|a| a.target).collect();
            let c = contact.collider_mut(ids.muscle).expect("muscle");
            c.set_vertices(&muscle).expect("finite muscle");
            let c = contact.collider_mut(ids.ulna).expect("ulna");
            c.set_pose(work.forearm_pose(frame)).expect("finite pose");
            let t = Instant::now();
            contact.clear_frame_state();
            contact.advance_frame(&mut x).expect("valid skin");
            spent += t.elapsed().as_secs_f64();
            let mut xi: Vec<_> = order.iter().map(|&o| x[o as usize]).collect();
            for k in 0..passes {
                for (i, p) in xi.iter_mut().enumerate() {
                    // A small smooth drift, like the steps of a converging solve.
                    let s = 2e-5 / (1.0 + k as f32);
                    *p += glam::Vec3::new(
                        (i as f32 * 0.37 + k as f32).sin(),
                        (i as f32 * 0.11).cos(),
                        0.5,
                    ) * s;
                }
                let t = Instant::now();
                contact.project(&mut xi, &order);
                spent += t.elapsed().as_secs_f64();
            }
            let d = contact.diagnostics();
            println!(
                "frame {frame}: substeps {}, passes {}, contacts {}, exact {}, certified {}, skipped vertices {}, moved {}",
                d.substeps,
                d.passes,
                d.contacts,
                d.exact_queries,
                d.certified_queries,
                d.skipped_vertices,
                d.moved
            );
        }
    });
    println!(
        "{:.1} us per pass ({} vertices)",
        spent * 1e6 / (frames * (passes + 1)).max(1) as f64,
        order.len()
    );
}
