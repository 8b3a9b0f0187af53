//! Acceptance tests of the muscles-and-bones engine (issue 7).

use dermis::anatomy::dynamics::{AnatomySystem, DynamicsConfig};
use dermis::anatomy::lattice::{MuscleConfig, MuscleLattice};
use dermis::anatomy::scenes::tube_mesh;
use glam::Vec3;

fn free_muscle(drag: f32) -> (AnatomySystem, usize) {
    let surface = tube_mesh(Vec3::ZERO, Vec3::new(0.0, 0.0, 0.1), 0.01, 32, 10).unwrap();
    let line = [Vec3::new(0.0, 0.0, 0.001), Vec3::new(0.0, 0.0, 0.099)];
    let cfg = MuscleConfig {
        sections: 11,
        cell_area_m2: 4e-6,
        ..MuscleConfig::default()
    };
    let lattice = MuscleLattice::build(&surface, &line, cfg).unwrap();
    let mut sys = AnatomySystem::new(DynamicsConfig {
        dt_s: 1e-3,
        substeps: 10,
        drag,
        gravity: Vec3::ZERO,
    })
    .unwrap();
    let m = sys.add_muscle(&lattice).unwrap();
    (sys, m)
}

#[test]
fn contracted_muscle_keeps_volume_shortens_and_bulges() {
    let (mut sys, m) = free_muscle(0.02);
    let muscle = sys.muscle(m).unwrap().clone();
    let last = muscle.sections() - 1;
    let mid = last / 2;
    let length = |s: &AnatomySystem| {
        (s.muscle_section_centroid(m, last).unwrap() - s.muscle_section_centroid(m, 0).unwrap())
            .length()
    };
    let (v0, l0, a0) = (
        sys.muscle_volume_m3(m).unwrap(),
        length(&sys),
        sys.muscle_section_area_m2(m, mid).unwrap(),
    );
    sys.set_activation(m, 1.0).unwrap();
    for i in 0..400 {
        sys.step().unwrap();
        if i % 50 == 0 {
            eprintln!("{i} v {} l {} a {}", sys.muscle_volume_m3(m).unwrap() / v0, length(&sys) / l0, sys.muscle_section_area_m2(m, mid).unwrap() / a0);
        }
    }
    let (v1, l1, a1) = (
        sys.muscle_volume_m3(m).unwrap(),
        length(&sys),
        sys.muscle_section_area_m2(m, mid).unwrap(),
    );
    eprintln!("volume {} length {} area {}", v1 / v0, l1 / l0, a1 / a0);
    assert!((v1 / v0 - 1.0).abs() < 0.05);
    assert!(l1 / l0 < 0.8);
    assert!(a1 > a0 * 1.1);
}
