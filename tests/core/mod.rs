//! The spring-mesh core against independent answers: the FEM membrane, the linearised spring
//! mesh, and the exact uniform expansion of Van Gelder's Fig. 4.

mod cli;
mod contact_set;

use dermis::fem::{solve_linear_springs, solve_membrane};
use dermis::paper::{
    Fig4Config, deviation_from_uniform_expansion, fig4, graded_hexagon, uniform_traction,
};
use dermis::solver::{Loads, RelaxConfig, SpringSystem};
use dermis::stiffness::{Modulus, StiffnessRule};
use glam::DVec3;

/// The exact membrane answer to uniform traction is a uniform expansion; the FEM must find it
/// (the patch test), with the plane-stress magnitude `t (1 − ν) / E2`.
#[test]
fn fem_gives_uniform_expansion_on_the_hexagon() {
    let config = Fig4Config::default();
    for seed in [0, 1] {
        let mesh = graded_hexagon(seed, &config).unwrap();
        let f = uniform_traction(&mesh, config.traction_n_per_m);
        let pinned = vec![false; f.len()];
        let sol = solve_membrane(
            &mesh,
            &Modulus::Uniform(config.e2_n_per_m),
            config.nu as f64,
            &f,
            &pinned,
        )
        .unwrap();
        let (dev, s) = deviation_from_uniform_expansion(mesh.positions(), &sol.displacement);
        assert!(
            dev < 1e-6,
            "seed {seed}: FEM deviates {dev:e} from uniform expansion"
        );
        let exact =
            config.traction_n_per_m as f64 * (1.0 - config.nu as f64) / config.e2_n_per_m as f64;
        assert!(
            (s / exact - 1.0).abs() < 1e-5,
            "stretch {s} vs exact {exact}"
        );
    }
}

/// Van Gelder's claim (Sec. 6, Fig. 4): on an irregular mesh, area/len² springs deviate from
/// the uniform expansion far less than equal springs or equal 1D moduli.
#[test]
fn area_len2_beats_the_baselines_on_graded_hexagons() {
    for seed in 0..4 {
        let run = fig4(seed, &Fig4Config::default()).unwrap().run;
        let d = &run.deviation;
        assert!(d["area-len2"] < d["constant"], "seed {seed}: {d:?}");
        assert!(d["area-len2"] < d["inverse-length"], "seed {seed}: {d:?}");
        assert!(d["fem"] < 1e-6, "seed {seed}: {d:?}");
    }
}

/// At 1e-4 strain the nonlinear relaxation must agree with the linearised spring mesh
/// (`K d = f` assembled from the same springs, solved by CG in f64) to within 1 %.
#[test]
fn nonlinear_relaxation_matches_linearised_springs_at_small_strain() {
    let config = Fig4Config::default();
    let mesh = graded_hexagon(2, &config).unwrap();
    let e2 = Modulus::Uniform(1000.0);
    // Traction chosen for a strain of about 1e-4.
    let f = uniform_traction(&mesh, 0.1);
    let k = StiffnessRule::AreaOverLengthSquared
        .edge_stiffness(&mesh, &e2)
        .unwrap();
    let pinned = vec![false; f.len()];
    let linear = solve_linear_springs(&mesh, &k, &f, &pinned).unwrap();
    let system = SpringSystem::from_mesh(&mesh, &k).unwrap();
    let mut x = mesh.positions().to_vec();
    let loads = Loads {
        forces: Some(&f),
        ..Default::default()
    };
    let report = system
        .relax(
            &mut x,
            &loads,
            &RelaxConfig {
                tolerance: 1e-5,
                max_iterations: 20_000,
                ..Default::default()
            },
        )
        .unwrap();
    let d: Vec<DVec3> = x
        .iter()
        .zip(mesh.positions())
        .map(|(x, p)| x.as_dvec3() - p.as_dvec3())
        .collect();
    // Remove the rigid motion both answers are free to have, by comparing the fitted strain and
    // the non-uniform remainder.
    let (dev_n, s_n) = deviation_from_uniform_expansion(mesh.positions(), &d);
    let (dev_l, s_l) = deviation_from_uniform_expansion(mesh.positions(), &linear.displacement);
    assert!(
        (s_n / s_l - 1.0).abs() < 0.01,
        "stretch {s_n} vs linear {s_l} ({report:?})"
    );
    assert!(
        (s_l - 1e-4).abs() < 5e-5,
        "the test should run at about 1e-4 strain, got {s_l}"
    );
    let _ = (dev_n, dev_l);
    // Vertex by vertex, once each field's own rigid motion is removed.
    let (a, b) = (
        without_rigid_motion(mesh.positions(), &d),
        without_rigid_motion(mesh.positions(), &linear.displacement),
    );
    let diff: f64 = a
        .iter()
        .zip(&b)
        .map(|(a, b)| (*a - *b).length_squared())
        .sum::<f64>()
        .sqrt();
    let norm: f64 = b.iter().map(|b| b.length_squared()).sum::<f64>().sqrt();
    assert!(
        diff < 0.01 * norm,
        "nonlinear and linear answers differ by {:.3} % ({report:?})",
        100.0 * diff / norm
    );
}

/// `d` minus its least-squares in-plane translation and rotation about the centroid.
fn without_rigid_motion(rest: &[glam::Vec3], d: &[DVec3]) -> Vec<DVec3> {
    let n = rest.len() as f64;
    let c = rest.iter().map(|p| p.as_dvec3()).sum::<DVec3>() / n;
    let mean = d.iter().sum::<DVec3>() / n;
    let (mut num, mut den) = (0.0, 0.0);
    for (p, d) in rest.iter().zip(d) {
        let q = (p.as_dvec3() - c).truncate();
        num += q.perp_dot(d.truncate());
        den += q.length_squared();
    }
    let w = num / den;
    rest.iter()
        .zip(d)
        .map(|(p, d)| {
            let q = (p.as_dvec3() - c).truncate();
            *d - mean - (q.perp() * w).extend(0.0)
        })
        .collect()
}
