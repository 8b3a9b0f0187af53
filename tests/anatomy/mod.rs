//! Acceptance tests of the muscles-and-bones engine (issue 7): each checks the engine against a
//! closed form or a conservation law.

mod ecs;

use dermis::anatomy::AnatomyError;
use dermis::anatomy::dynamics::{AnatomySystem, DynamicsConfig};
use dermis::anatomy::lattice::{MuscleConfig, MuscleLattice};
use dermis::anatomy::pressure::PressureCell;
use dermis::anatomy::rigid::{BoneDesc, BoneKind};
use dermis::anatomy::scenes::{JawConfig, box_mesh, jaw, tube_mesh};
use glam::{Quat, Vec3};

fn undamped(dt_s: f32) -> AnatomySystem {
    AnatomySystem::new(DynamicsConfig {
        dt_s,
        substeps: 1,
        drag: 0.0,
        gravity: Vec3::ZERO,
    })
    .unwrap()
}

/// Two 1 kg particles on a 100 N/m spring: angular frequency sqrt(2k/m).
#[test]
fn verlet_conserves_oscillator_energy_and_matches_the_analytic_period() {
    let (m, k, amplitude) = (1.0f32, 100.0f32, 0.01f32);
    let omega = (2.0 * k / m).sqrt();
    let period = std::f64::consts::TAU / f64::from(omega);
    let steps_per_period = 200;
    let h = (period / f64::from(steps_per_period)) as f32;
    let mut sys = undamped(h);
    let a = sys.add_particle(Vec3::ZERO, m).unwrap();
    // Short spring near the origin: f32 positions keep ~1e-9 m resolution, so rounding does not
    // random-walk the energy over the 200k steps.
    let rest = 0.02;
    let b = sys
        .add_particle(Vec3::new(rest + amplitude, 0.0, 0.0), m)
        .unwrap();
    sys.add_spring(a, b, k, rest).unwrap();
    let e0 = 0.5 * k * amplitude * amplitude;
    assert!((sys.total_energy() - e0).abs() < 1e-6 * e0.max(1.0));
    let extension = |s: &AnatomySystem| s.positions()[b].x - s.positions()[a].x - rest;
    let mut crossings = Vec::new();
    let mut prev = extension(&sys);
    let mut worst = 0.0f32;
    for step in 1..=1000 * steps_per_period {
        sys.step().unwrap();
        let e = extension(&sys);
        if prev < 0.0 && e >= 0.0 {
            // Linear interpolation of the upward zero crossing.
            let t = (f64::from(step) - 1.0 + f64::from(-prev / (e - prev))) * f64::from(h);
            crossings.push(t);
        }
        prev = e;
        if step % 97 == 0 {
            worst = worst.max((sys.total_energy() - e0).abs() / e0);
        }
    }
    assert!(worst < 1e-3, "relative energy error {worst}");
    assert!(crossings.len() >= 999, "{} crossings", crossings.len());
    let measured = (crossings.last().unwrap() - crossings[0]) / (crossings.len() - 1) as f64;
    assert!(
        (measured / period - 1.0).abs() < 1e-3,
        "period {measured} s vs analytic {period} s"
    );
}

/// Boyle's law on a cube of side 1 cm, and the force on the moving face is P A.
#[test]
fn pressure_cell_squeezed_to_half_volume_doubles_its_pressure() {
    let side = 0.01f32;
    let x: Vec<Vec3> = (0..8)
        .map(|i| side * Vec3::new((i & 1) as f32, ((i >> 1) & 1) as f32, ((i >> 2) & 1) as f32))
        .collect();
    let faces = vec![
        [0, 2, 1],
        [1, 2, 3],
        [4, 5, 6],
        [5, 7, 6],
        [0, 1, 4],
        [1, 5, 4],
        [2, 6, 3],
        [3, 6, 7],
        [0, 4, 2],
        [2, 4, 6],
        [1, 3, 5],
        [3, 7, 5],
    ];
    let p0 = 1.0e5;
    let cell = PressureCell::new(faces, &x, p0, 0.0).unwrap();
    let half: Vec<Vec3> = x.iter().map(|p| *p * Vec3::new(1.0, 1.0, 0.5)).collect();
    assert!((cell.volume_m3(&half) / cell.rest_volume_m3() - 0.5).abs() < 1e-5);
    assert!((cell.pressure_pa(&half) / (2.0 * p0) - 1.0).abs() < 1e-5);
    // Force on the top face (z = side / 2, vertices 4..8) is 2 P0 * side² along +z.
    let mut forces = vec![Vec3::ZERO; 8];
    cell.add_forces(&half, &mut forces);
    let top: Vec3 = forces[4..].iter().sum();
    let expected = 2.0 * p0 * side * side;
    assert!((top.z / expected - 1.0).abs() < 1e-4 && top.truncate().length() < 1e-4 * expected);
    // The same cell inside a system reports the same pressure.
    let mut sys = undamped(1e-4);
    for p in &half {
        sys.add_particle(*p, 1e-3).unwrap();
    }
    let cell_in_sys = PressureCell::new(cell.faces().to_vec(), &x, p0, 0.0).unwrap();
    let c = sys.add_pressure_cell(&cell_in_sys).unwrap();
    assert!((sys.cell_pressure_pa(c) / (2.0 * p0) - 1.0).abs() < 1e-5);
}

fn free_muscle(drag: f32, cell_area_m2: f32) -> (AnatomySystem, usize) {
    let surface = tube_mesh(Vec3::ZERO, Vec3::new(0.0, 0.0, 0.1), 0.01, 32, 10).unwrap();
    let line = [Vec3::new(0.0, 0.0, 0.001), Vec3::new(0.0, 0.0, 0.099)];
    let cfg = MuscleConfig {
        sections: 11,
        cell_area_m2,
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
    let (mut sys, m) = free_muscle(0.02, 4e-6);
    let last = sys.muscle(m).unwrap().sections() - 1;
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
    // At rest the lattice is in equilibrium: nothing moves.
    for _ in 0..20 {
        sys.step().unwrap();
    }
    assert!((length(&sys) / l0 - 1.0).abs() < 1e-4);
    sys.set_activation(m, 1.0).unwrap();
    for _ in 0..400 {
        sys.step().unwrap();
    }
    let (v1, l1, a1) = (
        sys.muscle_volume_m3(m).unwrap(),
        length(&sys),
        sys.muscle_section_area_m2(m, mid).unwrap(),
    );
    assert!((v1 / v0 - 1.0).abs() < 0.05, "volume ratio {}", v1 / v0);
    assert!(l1 / l0 < 0.8, "length ratio {}", l1 / l0);
    assert!(a1 > 1.2 * a0, "mid cross-section ratio {}", a1 / a0);
    sys.set_activation(m, 0.0).unwrap();
    for _ in 0..400 {
        sys.step().unwrap();
    }
    // Relaxing again lets the muscle lengthen back (slowly: only the soft in-section springs
    // drive the cross-section back against the drag).
    assert!(
        length(&sys) / l0 > 0.9,
        "released length ratio {}",
        length(&sys) / l0
    );
}

#[test]
fn muscle_steps_are_bit_identical_for_any_thread_count() {
    let run = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| {
                let (mut sys, m) = free_muscle(0.02, 4e-7);
                assert!(sys.positions().len() > 2048, "needs several chunks");
                sys.set_activation(m, 0.7).unwrap();
                for _ in 0..5 {
                    sys.step().unwrap();
                }
                sys.positions().to_vec()
            })
    };
    let one = run(1);
    let two = run(2);
    let three = run(3);
    let bits = |v: &[Vec3]| {
        v.iter()
            .flat_map(|p| p.to_array().map(f32::to_bits))
            .collect::<Vec<_>>()
    };
    assert_eq!(bits(&one), bits(&two));
    assert_eq!(bits(&one), bits(&three));
}

/// An asymmetric bone (box plus an off-centre attachment).
fn bone() -> BoneDesc {
    BoneDesc::new(
        box_mesh(
            Vec3::new(-0.03, -0.01, -0.02),
            Vec3::new(0.05, 0.01, 0.02),
            2,
        )
        .unwrap(),
        0.01,
    )
    .with_attachments(vec![Vec3::new(0.02, 0.03, 0.01)])
}

fn pairwise(x: &[Vec3]) -> Vec<f32> {
    let mut d = Vec::new();
    for i in 0..x.len() {
        for j in i + 1..x.len() {
            d.push((x[i] - x[j]).length());
        }
    }
    d
}

/// Angular momentum of particles about `centre`: sum m r x v.
fn particle_momentum(sys: &AnatomySystem, range: std::ops::Range<usize>, centre: Vec3) -> Vec3 {
    range
        .map(|p| sys.masses()[p] * (sys.positions()[p] - centre).cross(sys.velocities()[p]))
        .sum()
}

#[test]
fn free_rigid_body_keeps_its_shape_and_angular_momentum() {
    let mut sys = undamped(1e-3);
    let b = sys.add_bone(&bone()).unwrap();
    let l = Vec3::new(1e-5, 3e-5, -2e-5);
    sys.set_body_motion(b, Vec3::new(0.01, 0.0, 0.0), l)
        .unwrap();
    let range = sys.body(b).unwrap().particles();
    let d0 = pairwise(&sys.positions()[range.clone()]);
    for _ in 0..5000 {
        sys.step().unwrap();
    }
    let body = sys.body(b).unwrap();
    // It did tumble (an asymmetric top), yet stayed rigid.
    assert!(body.rotation().angle_between(Quat::IDENTITY) > 0.5);
    let d1 = pairwise(&sys.positions()[range.clone()]);
    let worst = d0
        .iter()
        .zip(&d1)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f32::max);
    assert!(worst < 1e-5, "distance changed by {worst} m");
    // L recomputed from the particles' own positions and velocities.
    let lp = particle_momentum(&sys, range, body.center_of_mass());
    assert!((lp - l).length() < 1e-3 * l.length(), "{lp} vs {l}");
    assert!((body.angular_momentum() - l).length() < 1e-6 * l.length());
}

#[test]
fn spring_torque_changes_angular_momentum_but_conserves_the_total() {
    // Two bones joined off-centre by a stretched spring: each spins up, the sum stays zero.
    let mut sys = undamped(1e-3);
    let b0 = sys.add_bone(&bone()).unwrap();
    let shifted = BoneDesc::new(
        box_mesh(
            Vec3::new(0.07, -0.01, -0.02),
            Vec3::new(0.15, 0.01, 0.02),
            2,
        )
        .unwrap(),
        0.01,
    )
    .with_attachments(vec![Vec3::new(0.09, -0.03, 0.0)]);
    let b1 = sys.add_bone(&shifted).unwrap();
    let (p0, p1) = (
        sys.body(b0).unwrap().particles().end - 1,
        sys.body(b1).unwrap().particles().end - 1,
    );
    sys.add_spring(p0, p1, 50.0, 0.03).unwrap();
    let total = |s: &AnatomySystem| {
        [b0, b1]
            .map(|b| {
                let body = s.body(b).unwrap();
                body.mass_kg() * body.center_of_mass().cross(body.velocity())
                    + body.angular_momentum()
            })
            .iter()
            .sum::<Vec3>()
    };
    let mut spin = 0.0f32;
    for _ in 0..2000 {
        sys.step().unwrap();
        spin = spin.max(sys.body(b0).unwrap().angular_momentum().length());
    }
    assert!(spin > 1e-5, "the spring should spin the bones up ({spin})");
    assert!(total(&sys).length() < 1e-3 * spin, "total {}", total(&sys));
    // And the particles agree with the bodies' momenta.
    let range = 0..sys.positions().len();
    assert!((particle_momentum(&sys, range, Vec3::ZERO) - total(&sys)).length() < 1e-3 * spin);
}

#[test]
fn kinematic_bone_follows_its_pose() {
    let mut sys = undamped(1e-2);
    let b = sys
        .add_bone(&bone().with_kind(BoneKind::Kinematic))
        .unwrap();
    let rest = sys.positions().to_vec();
    let (q, t) = (Quat::from_rotation_z(0.3), Vec3::new(0.0, 0.1, 0.0));
    sys.set_kinematic_pose(b, q, t).unwrap();
    sys.step().unwrap();
    for (p, r) in sys.positions().iter().zip(&rest) {
        assert!((*p - (q * *r + t)).length() < 1e-6);
    }
}

#[test]
fn jaw_opens_monotonically_as_activation_rises() {
    let mut scene = jaw(&JawConfig::default()).unwrap();
    let mut angles = vec![scene.settle(0.0, 50).unwrap()];
    assert!(angles[0].abs() < 1e-3, "jaw moved at rest: {}", angles[0]);
    for k in 1..=5 {
        angles.push(scene.settle(k as f32 * 0.2, 300).unwrap());
    }
    for w in angles.windows(2) {
        assert!(w[1] > w[0] + 0.01, "angles (rad) {angles:?}");
    }
    assert!(angles[5] > 5f32.to_radians(), "angles (rad) {angles:?}");
}

#[test]
fn bad_input_is_a_typed_error() {
    let (mut sys, m) = free_muscle(0.02, 1e-5);
    assert_eq!(
        sys.set_activation(m, 1.5),
        Err(AnatomyError::ActivationOutOfRange {
            muscle: m,
            activation: 1.5
        })
    );
    assert!(matches!(
        sys.set_activation(m, f32::NAN),
        Err(AnatomyError::ActivationOutOfRange { .. })
    ));
    assert!(matches!(
        sys.set_activation(7, 0.5),
        Err(AnatomyError::IndexOutOfRange { what: "muscle", .. })
    ));
    assert!(matches!(
        sys.add_particle(Vec3::new(f32::NAN, 0.0, 0.0), 1.0),
        Err(AnatomyError::NonFinite { .. })
    ));
    assert!(matches!(
        sys.add_particle(Vec3::ZERO, -1.0),
        Err(AnatomyError::InvalidParameter {
            name: "mass_kg",
            ..
        })
    ));
    assert!(matches!(
        sys.add_spring(0, 1_000_000, 1.0, 1.0),
        Err(AnatomyError::IndexOutOfRange {
            what: "particle",
            ..
        })
    ));
    let b = sys.add_bone(&bone()).unwrap();
    assert_eq!(
        sys.set_kinematic_pose(b, Quat::IDENTITY, Vec3::ZERO),
        Err(AnatomyError::NotKinematic { body: b })
    );
    assert!(
        AnatomySystem::new(DynamicsConfig {
            drag: 1.0,
            ..Default::default()
        })
        .is_err()
    );
    assert!(
        AnatomySystem::new(DynamicsConfig {
            substeps: 0,
            ..Default::default()
        })
        .is_err()
    );
}

#[test]
fn a_diverging_step_is_rolled_back() {
    // Absurdly stiff spring for the time step.
    let mut sys = undamped(1.0);
    let a = sys.add_particle(Vec3::ZERO, 1e-6).unwrap();
    let b = sys.add_particle(Vec3::new(2.0, 0.0, 0.0), 1e-6).unwrap();
    sys.add_spring(a, b, 1e30, 1.0).unwrap();
    let before = sys.positions().to_vec();
    let mut err = None;
    for _ in 0..100 {
        if let Err(e) = sys.step() {
            err = Some(e);
            break;
        }
    }
    assert!(matches!(err, Some(AnatomyError::Diverged { .. })));
    assert!(sys.positions().iter().all(|p| p.is_finite()));
    let _ = before;
}

#[test]
fn muscle_particles_do_not_pass_through_a_bone() {
    let (mut sys, m) = free_muscle(0.05, 4e-6);
    // A kinematic slab pushed sideways into the middle of the muscle (radius 1 cm along z).
    let (lo, hi) = (Vec3::new(0.012, -0.03, 0.04), Vec3::new(0.03, 0.03, 0.06));
    let slab = sys
        .add_bone(&BoneDesc::new(box_mesh(lo, hi, 2).unwrap(), 0.01).with_kind(BoneKind::Kinematic))
        .unwrap();
    sys.add_bone_contact(m, slab).unwrap();
    let muscle = sys.muscle(m).unwrap().particles();
    let push = 0.008;
    let inside_final = |x: Vec3| {
        let (blo, bhi) = (
            lo - Vec3::new(push, 0.0, 0.0),
            hi - Vec3::new(push, 0.0, 0.0),
        );
        (x - blo).min(bhi - x).min_element() > 0.0
    };
    // At rest, some muscle particles sit where the slab will end up.
    let in_the_way = muscle
        .clone()
        .filter(|&p| inside_final(sys.positions()[p]))
        .count();
    assert!(in_the_way > 5, "{in_the_way} particles in the slab's way");
    for step in 1..=200 {
        let dx = push * (step as f32 / 100.0).min(1.0);
        sys.set_kinematic_pose(slab, Quat::IDENTITY, Vec3::new(-dx, 0.0, 0.0))
            .unwrap();
        sys.step().unwrap();
        let (blo, bhi) = (lo - Vec3::new(dx, 0.0, 0.0), hi - Vec3::new(dx, 0.0, 0.0));
        for p in muscle.clone() {
            let x = sys.positions()[p];
            let depth = (x - blo).min(bhi - x).min_element();
            assert!(
                depth < 1e-6,
                "step {step}: particle {p} is {depth} m inside the bone"
            );
        }
    }
}
