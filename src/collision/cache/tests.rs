use glam::Vec3;

use super::*;
use crate::collision::shapes::ellipsoid;

#[test]
#[ignore = "timing probe"]
fn probe_search_cost() {
    let (v, t) = ellipsoid(Vec3::ZERO, Vec3::new(0.04, 0.035, 0.15), 126, 200).unwrap();
    let col = ColliderMesh::from_mesh(v.clone(), t).unwrap();
    let pts: Vec<Vec3> = v.iter().skip(1).step_by(5).map(|p| *p + p.normalize() * 0.003).collect();
    let start = std::time::Instant::now();
    for p in &pts {
        std::hint::black_box(col.project_point(*p));
    }
    let naive = start.elapsed().as_secs_f64() / pts.len() as f64;
    let mut slots = vec![Slot::NEW; pts.len()];
    let start = std::time::Instant::now();
    for (p, s) in pts.iter().zip(&mut slots) {
        std::hint::black_box(s.project(&col, *p, 0.0, 0.0022));
    }
    let first = start.elapsed().as_secs_f64() / pts.len() as f64;
    let start = std::time::Instant::now();
    for (p, s) in pts.iter().zip(&mut slots) {
        s.patch.len = 0;
        std::hint::black_box(s.project(&col, *p + Vec3::splat(1e-4), 0.0, 0.0022));
    }
    let hinted = start.elapsed().as_secs_f64() / pts.len() as f64;
    let start = std::time::Instant::now();
    let mut cert = 0;
    for (p, s) in pts.iter().zip(&mut slots) {
        cert += (s.project(&col, *p + Vec3::splat(1.2e-4), 0.0, 0.0022).1 == Answer::Certified) as u32;
    }
    let patched = start.elapsed().as_secs_f64() / pts.len() as f64;
    let gaps: f32 = slots.iter().map(|s| s.patch.gap - s.patch.dist[0]).sum::<f32>() / slots.len() as f32;
    eprintln!("naive {:.3} us, first {:.3} us, hinted search {:.3} us, patch {:.3} us ({cert} of {} certified), mean gap {gaps}", naive * 1e6, first * 1e6, hinted * 1e6, patched * 1e6, pts.len());
}
