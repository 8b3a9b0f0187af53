//! Writes chosen frames of the bench's tube-10k elbow clip as text files, for offline analysis
//! of the relaxation (`benches/analysis/iterations.py` studies why a frame takes the iterations
//! it takes).
//!
//! `cargo run --release --example frame_dump -- [vertices] [frames] [out_dir]`
//!
//! `frames` is a comma-separated list of frame numbers counted from the start of the run, as in
//! `examples/tube_profile` (default `1,59`); `out_dir` defaults to `target/frame_dump`. Writes
//! `edges.txt` (`i j k_N_per_m rest_m` per spring) and, per frame `f`: `f{f}_anchors.txt`
//! (`target normal k_normal k_tangent`), `f{f}_x0.txt` (the warm start), `f{f}_x1.txt` (the
//! solved positions), `f{f}_contacts.txt` (the vertices, in the caller's order, that ended
//! the frame on a collider) and `f{f}_meta.txt` (`iterations substeps residual force_scale
//! tolerance`).

use std::fmt::Write as _;
use std::path::Path;

use dermis::bench::arm::{ArmRun, ArmWorkload, CLIP_FRAMES};
use dermis::collision::predict_from_anchors;
use dermis::solver::Projection;
use glam::Vec3;

fn write(path: &Path, text: &str) {
    std::fs::write(path, text).unwrap_or_else(|e| panic!("writing {}: {e}", path.display()));
}

fn points(x: &[Vec3]) -> String {
    x.iter().fold(String::new(), |mut s, p| {
        let _ = writeln!(s, "{} {} {}", p.x, p.y, p.z);
        s
    })
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let vertices: usize = args.first().and_then(|a| a.parse().ok()).unwrap_or(10_000);
    let wanted: Vec<usize> = args
        .get(1)
        .map_or("1,59", String::as_str)
        .split(',')
        .map(|f| {
            f.parse()
                .expect("frames: a comma-separated list of numbers")
        })
        .collect();
    let out = Path::new(args.get(2).map_or("target/frame_dump", String::as_str));
    std::fs::create_dir_all(out).expect("creating the output directory");

    let work = ArmWorkload::new("tube", vertices, (126, 200), CLIP_FRAMES);
    let mut run = ArmRun::new(&work, 12, 500).expect("the bench's own workload");
    let mesh = &work.tube.mesh;
    let mut edges = String::new();
    for ((e, k), l) in mesh
        .topology()
        .edges()
        .iter()
        .zip(&work.tube.stiffness)
        .zip(mesh.edge_lengths())
    {
        let _ = writeln!(edges, "{} {} {k} {l}", e[0], e[1]);
    }
    write(&out.join("edges.txt"), &edges);

    let last = wanted.iter().copied().max().unwrap_or(0);
    for f in 0..=last {
        let keep = wanted.contains(&f);
        if keep {
            let anchors = work.anchors(run.frame + 1);
            let mut x0 = run.x.clone();
            predict_from_anchors(&mut x0, &work.anchors(run.frame), &anchors);
            let text = anchors.iter().fold(String::new(), |mut s, a| {
                let (t, n) = (a.target, a.normal);
                let _ = writeln!(
                    s,
                    "{} {} {} {} {} {} {} {}",
                    t.x, t.y, t.z, n.x, n.y, n.z, a.k_normal, a.k_tangent
                );
                s
            });
            write(&out.join(format!("f{f}_anchors.txt")), &text);
            write(&out.join(format!("f{f}_x0.txt")), &points(&x0));
        }
        let times = run.step(&work).expect("the bench's own workload");
        if keep {
            write(&out.join(format!("f{f}_x1.txt")), &points(&run.x));
            let order = work.tube.system.order();
            let contacts = run
                .contact
                .active_contacts()
                .iter()
                .fold(String::new(), |mut s, c| {
                    let _ = writeln!(s, "{}", order[c.vertex as usize]);
                    s
                });
            write(&out.join(format!("f{f}_contacts.txt")), &contacts);
            let report = run.last.as_ref().expect("a frame ran");
            let meta = format!(
                "{} {} {} {} {}\n",
                times.iterations,
                times.substeps,
                report.residual,
                report.force_scale,
                work.relax_config().tolerance
            );
            write(&out.join(format!("f{f}_meta.txt")), &meta);
            println!(
                "frame {f}: {} iterations, {} substeps, residual {:.3e}, {} contacts",
                times.iterations,
                times.substeps,
                report.residual,
                run.contact.active_contacts().len()
            );
        }
    }
}
