//! Probe: run tube-10k arm frames for profiling.
//!
//! `cargo run --release --example tube_profile -- [vertices] [frames] [steady passes]`: per
//! frame the plan's time (on a copy), the frame's time, iterations and contact counters; then
//! `steady passes` (default 200; 0: none) projections of the last state, timed. The last line
//! before them gives two hashes: `hash` (positions and contact counters: same work, same
//! answers) and `answers` (positions, contacts and unresolved vertices only: same answers).
//! Profile the frames' projections with 0 steady passes: the steady ones repeat the same
//! positions.
use std::time::Instant;

use dermis::bench::arm::{ArmRun, ArmWorkload};
use dermis::solver::Projection;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let n: usize = args.get(1).and_then(|a| a.parse().ok()).unwrap_or(10_000);
    let frames: usize = args.get(2).and_then(|a| a.parse().ok()).unwrap_or(10);
    let reps: usize = args.get(3).and_then(|a| a.parse().ok()).unwrap_or(200);
    // A hash of every frame's positions and contact counters: two builds answer identically
    // when their hashes agree (FNV-1a over the bits). A second hash takes the positions, the
    // unresolved vertices and the contact count only: it agrees between builds that give the
    // same answers with different work (fewer queries, say).
    let fnv = |h: &mut u64, v: u64| *h = (*h ^ v).wrapping_mul(0x100_0000_01b3);
    let (mut hash, mut answers) = (0xcbf2_9ce4_8422_2325u64, 0xcbf2_9ce4_8422_2325u64);
    let mut iterations = 0u64;
    let work = ArmWorkload::new("tube", n, (126, 200), dermis::bench::arm::CLIP_FRAMES);
    let mut run = ArmRun::new(&work, 12, 500).unwrap();
    for _ in 0..frames {
        // The frame plan on its own (on a copy), to split the contact time.
        let mut c = run.contact.clone();
        let mut xp = run.x.clone();
        let f = run.frame + 1;
        c.collider_mut(run.ids.muscle)
            .unwrap()
            .set_vertices(&work.muscle_vertices(f))
            .unwrap();
        c.collider_mut(run.ids.ulna)
            .unwrap()
            .set_pose(work.forearm_pose(f))
            .unwrap();
        c.clear_frame_state();
        let tp = Instant::now();
        rayon::scope(|_| c.begin_frame(&mut xp).unwrap());
        print!("plan {:.2} ms | ", tp.elapsed().as_secs_f64() * 1e3);
        let t0 = Instant::now();
        let t = run.step(&work).unwrap();
        let d = run.contact.diagnostics().clone();
        iterations += t.iterations as u64;
        for c in run.x.iter().flat_map(|p| p.to_array()) {
            fnv(&mut hash, u64::from(c.to_bits()));
            fnv(&mut answers, u64::from(c.to_bits()));
        }
        fnv(&mut answers, d.contacts);
        d.unresolved
            .iter()
            .for_each(|&u| fnv(&mut answers, u64::from(u)));
        for c in [
            d.contacts,
            d.exact_queries,
            d.certified_queries,
            d.skipped_bound,
            d.skipped_aabb,
            d.moved,
            d.passes,
        ] {
            fnv(&mut hash, c);
        }
        d.unresolved
            .iter()
            .for_each(|&u| fnv(&mut hash, u64::from(u)));
        println!(
            "{:.1} ms its {} sub {} passes {} coll {:.1} ms conv {} | contacts {} exact {} cert {} skipbound {} skipaabb {} moved {}",
            t0.elapsed().as_secs_f64() * 1e3,
            t.iterations,
            t.substeps,
            t.passes,
            t.collision_s() * 1e3,
            t.converged,
            d.contacts,
            d.exact_queries,
            d.certified_queries,
            d.skipped_bound,
            d.skipped_aabb,
            d.moved
        );
    }
    println!("frames {frames}: iterations {iterations}, hash {hash:016x}, answers {answers:016x}");
    if reps == 0 {
        return;
    }
    // One projection pass on the last frame's state, in the solver's order, repeated.
    let order = work.tube.system.order().to_vec();
    let mut x: Vec<_> = order.iter().map(|&o| run.x[o as usize]).collect();
    let mut contact = run.contact.clone();
    contact.project(&mut x, &order);
    let t0 = Instant::now();
    rayon::scope(|_| {
        for _ in 0..reps {
            contact.project(&mut x, &order);
        }
    });
    println!(
        "steady: {:.1} us",
        t0.elapsed().as_secs_f64() * 1e6 / reps as f64
    );
    let mut junk = vec![1.0f32; 1 << 20];
    let mut spent = 0.0;
    rayon::scope(|_| {
        for r in 0..reps {
            for (i, j) in junk.iter_mut().enumerate() {
                *j += (i + r) as f32;
            }
            for p in x.iter_mut() {
                p.x += 1e-7;
            }
            let t = Instant::now();
            contact.project(&mut x, &order);
            spent += t.elapsed().as_secs_f64();
        }
    });
    println!(
        "moving + cache thrashed: {:.1} us ({})",
        spent * 1e6 / reps as f64,
        junk[7]
    );
    let t0 = Instant::now();
    println!(
        "projection pass: {:.1} us ({} vertices, {} active contacts)",
        t0.elapsed().as_secs_f64() * 1e6 / reps as f64,
        x.len(),
        contact.active_contacts().len()
    );
}
