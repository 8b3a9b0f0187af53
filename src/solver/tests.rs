use glam::{Quat, Vec3};

use super::*;
use crate::stiffness::{Modulus, StiffnessRule};

/// A bumpy 3D grid sheet, `n` x `n` vertices.
pub(crate) fn sheet(n: u32) -> TriMesh {
    let mut p = Vec::new();
    for j in 0..n {
        for i in 0..n {
            let (x, y) = (i as f32 / (n - 1) as f32, j as f32 / (n - 1) as f32);
            p.push(Vec3::new(
                x + 0.01 * (7.0 * y).sin(),
                y,
                0.05 * (3.0 * x).sin(),
            ));
        }
    }
    TriMesh::new(p, crate::mesh::shapes::grid_triangles(n, n)).unwrap()
}

fn system(mesh: &TriMesh) -> SpringSystem {
    let k = StiffnessRule::AreaOverLengthSquared
        .edge_stiffness(mesh, &Modulus::Uniform(1000.0))
        .unwrap();
    SpringSystem::from_mesh(mesh, &k).unwrap()
}

#[test]
fn rigid_motion_of_rest_mesh_gives_zero_force() {
    let mesh = sheet(12);
    let s = system(&mesh);
    let q = Quat::from_axis_angle(Vec3::new(1.0, 2.0, -0.5).normalize(), 1.1);
    let moved: Vec<Vec3> = mesh
        .positions()
        .iter()
        .map(|p| q * *p + Vec3::new(3.0, -1.0, 2.0))
        .collect();
    let f = s.spring_forces(&moved).unwrap();
    let max = f.iter().map(|f| f.length()).fold(0.0, f32::max);
    // Compare against the force a 1% stretch produces.
    let stretched: Vec<Vec3> = mesh.positions().iter().map(|p| *p * 1.01).collect();
    let typical = s
        .spring_forces(&stretched)
        .unwrap()
        .iter()
        .map(|f| f.length())
        .fold(0.0, f32::max);
    assert!(
        max < 1e-3 * typical,
        "rigid motion force {max} vs 1% stretch {typical}"
    );
    assert!(s.spring_energy(&moved).unwrap() < 1e-6 * s.spring_energy(&stretched).unwrap());
}

#[test]
fn energy_never_rises_during_relaxation() {
    let mesh = sheet(16);
    let s = system(&mesh);
    // A large, messy deformation with a few pins and anchors.
    let mut x: Vec<Vec3> = mesh
        .positions()
        .iter()
        .enumerate()
        .map(|(i, p)| *p * 1.3 + Vec3::new(0.0, 0.0, 0.2 * ((i * 37 % 11) as f32 / 11.0 - 0.5)))
        .collect();
    let mut pinned = vec![false; x.len()];
    pinned[0] = true;
    pinned[15] = true;
    let anchors: Vec<VertexAnchor> = mesh
        .positions()
        .iter()
        .map(|p| VertexAnchor {
            target: *p,
            normal: Vec3::Z,
            k_normal: 50.0,
            k_tangent: 5.0,
        })
        .collect();
    let forces = vec![Vec3::new(0.0, 0.0, -0.01); x.len()];
    let loads = Loads {
        forces: Some(&forces),
        pinned: Some(&pinned),
        anchors: Some(&anchors),
    };
    let cfg = RelaxConfig {
        max_iterations: 300,
        tolerance: 1e-6,
        record_energy: true,
        ..RelaxConfig::DEFAULT
    };
    let report = s.relax(&mut x, &loads, &cfg).unwrap();
    assert!(report.energy_history.len() > 20);
    for w in report.energy_history.windows(2) {
        assert!(w[1] <= w[0], "energy rose from {} to {}", w[0], w[1]);
    }
    assert!(report.energy_history[0] > 10.0 * report.energy);
    // Pinned vertices did not move.
    assert_eq!(
        x[0],
        mesh.positions()[0] * 1.3 + Vec3::new(0.0, 0.0, 0.2 * (0.0 / 11.0 - 0.5))
    );
}

#[test]
fn chain_under_load_matches_series_springs() {
    // Five springs in series along x, pinned at 0, pulled at the end: each stretches by f/k_i.
    let rest: Vec<Vec3> = (0..6)
        .map(|i| Vec3::new(i as f32 * 0.1, 0.0, 0.0))
        .collect();
    let edges: Vec<[u32; 2]> = (0..5).map(|i| [i, i + 1]).collect();
    let k = [100.0, 200.0, 50.0, 400.0, 80.0];
    let s = SpringSystem::new(&rest, &edges, &k, &[0.1; 5]).unwrap();
    let mut x = rest.clone();
    let mut f = vec![Vec3::ZERO; 6];
    f[5] = Vec3::new(1.5, 0.0, 0.0);
    let mut pinned = vec![false; 6];
    pinned[0] = true;
    let loads = Loads {
        forces: Some(&f),
        pinned: Some(&pinned),
        ..Default::default()
    };
    let report = s
        .relax(
            &mut x,
            &loads,
            &RelaxConfig {
                tolerance: 1e-5,
                ..Default::default()
            },
        )
        .unwrap();
    assert!(report.converged(), "{report:?}");
    let expected: f32 = 0.5 + k.iter().map(|k| 1.5 / k).sum::<f32>();
    assert!((x[5].x - expected).abs() < 1e-5, "{} vs {expected}", x[5].x);
}

#[test]
fn chain_along_its_axis_takes_the_iterations_of_linear_pcg() {
    // A chain along x, anchored and loaded along x, is an exactly quadratic problem while its
    // vertices keep their order: each spring's energy is ½ k (x_{i+1} − x_i − L)², each
    // anchor's ½ k_a (x_i − t_i)², and the Gauss-Newton curvature along x is exact, so every
    // step is an exact line search. The nonlinear conjugate gradients must then take the
    // iterations of linear Jacobi-preconditioned CG, computed here independently in f64.
    // Directions that lost their conjugacy (steepest descent needs several times more) or a
    // wrong β would not.
    let n = 30;
    let rest_len = 0.01f32;
    let rest: Vec<Vec3> = (0..n)
        .map(|i| Vec3::new(i as f32 * rest_len, 0.0, 0.0))
        .collect();
    let edges: Vec<[u32; 2]> = (0..n as u32 - 1).map(|i| [i, i + 1]).collect();
    let k: Vec<f32> = (0..n - 1)
        .map(|i| 50.0 + ((i * 37) % 29) as f32 * 15.0)
        .collect();
    let k_anchor = 100.0f32;
    let anchors: Vec<VertexAnchor> = (0..n)
        .map(|i| VertexAnchor {
            target: Vec3::new(i as f32 * rest_len * 1.2, 0.0, 0.0),
            normal: Vec3::X,
            k_normal: k_anchor,
            k_tangent: k_anchor,
        })
        .collect();
    let f: Vec<Vec3> = (0..n)
        .map(|i| Vec3::new(0.1 * ((i * 13) % 7) as f32 - 0.3, 0.0, 0.0))
        .collect();
    let mut pinned = vec![false; n];
    pinned[0] = true;
    let s = SpringSystem::new(&rest, &edges, &k, &vec![rest_len; n - 1]).unwrap();
    // Loads of ~0.2 N keep the f32 force noise (~2e-4 N) well under the threshold (~1e-3 N).
    let tolerance = 1e-3;
    // Start at the anchors' targets (springs stretched by 20 %).
    let mut x: Vec<Vec3> = anchors.iter().map(|a| a.target).collect();
    let report = s
        .relax(
            &mut x,
            &Loads {
                forces: Some(&f),
                pinned: Some(&pinned),
                anchors: Some(&anchors),
            },
            &RelaxConfig {
                tolerance,
                max_iterations: 1000,
                stagnation_window: 0,
                ..Default::default()
            },
        )
        .unwrap();
    assert!(report.converged(), "{report:?}");
    assert!(
        x.windows(2).all(|p| p[1].x > p[0].x),
        "the chain kept its order: {x:?}"
    );

    // Linear PCG in f64 on the free vertices 1..n from the same start.
    let (kk, ka) = (
        k.iter().map(|&k| f64::from(k)).collect::<Vec<_>>(),
        f64::from(k_anchor),
    );
    let xs: Vec<f64> = anchors.iter().map(|a| f64::from(a.target.x)).collect();
    let m = n - 1; // free unknowns: vertex i + 1
    // (A u)_i for the free vertices, u[i] the displacement of vertex i + 1 (vertex 0 pinned).
    let apply = |u: &[f64]| -> Vec<f64> {
        (0..m)
            .map(|i| {
                let left = if i == 0 { 0.0 } else { u[i - 1] };
                let mut v = ka * u[i] + kk[i] * (u[i] - left);
                if i + 1 < m {
                    v -= kk[i + 1] * (u[i + 1] - u[i]);
                }
                v
            })
            .collect()
    };
    // The net force at the start: springs, anchors and loads.
    let mut r: Vec<f64> = (1..n)
        .map(|v| {
            let mut r = f64::from(f[v].x) - ka * (xs[v] - f64::from(anchors[v].target.x));
            r -= kk[v - 1] * (xs[v] - xs[v - 1] - f64::from(rest_len));
            if v + 1 < n {
                r += kk[v] * (xs[v + 1] - xs[v] - f64::from(rest_len));
            }
            r
        })
        .collect();
    let w: Vec<f64> = (0..m)
        .map(|i| 1.0 / (ka + kk[i] + kk.get(i + 1).copied().unwrap_or(0.0)))
        .collect();
    let norm = |v: &[f64]| v.iter().map(|v| v * v).sum::<f64>().sqrt();
    let dotp = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(a, b)| a * b).sum::<f64>();
    let scale = norm(&f[1..].iter().map(|f| f64::from(f.x)).collect::<Vec<_>>());
    let mut z: Vec<f64> = r.iter().zip(&w).map(|(r, w)| r * w).collect();
    let mut d = z.clone();
    let mut rz = dotp(&r, &z);
    let mut reference = 0;
    while norm(&r) > f64::from(tolerance) * scale {
        let hd = apply(&d);
        let a = rz / dotp(&d, &hd);
        for i in 0..m {
            r[i] -= a * hd[i];
        }
        z = r.iter().zip(&w).map(|(r, w)| r * w).collect();
        let rz_new = dotp(&r, &z);
        for i in 0..m {
            d[i] = z[i] + rz_new / rz * d[i];
        }
        rz = rz_new;
        reference += 1;
    }
    assert!(
        (reference - 1..=reference + 1).contains(&(report.iterations as i32)),
        "{} iterations, linear PCG {reference}",
        report.iterations
    );
}

#[test]
fn result_does_not_depend_on_input_vertex_order() {
    let mesh = sheet(10);
    let n = mesh.positions().len() as u32;
    // The same mesh with vertices listed in a scrambled order.
    let perm: Vec<u32> = (0..n).map(|i| (i * 37 + 11) % n).collect();
    let mut inv = vec![0u32; n as usize];
    for (new, &old) in perm.iter().enumerate() {
        inv[old as usize] = new as u32;
    }
    let p2: Vec<Vec3> = perm.iter().map(|&o| mesh.positions()[o as usize]).collect();
    let t2: Vec<[u32; 3]> = mesh
        .triangles()
        .iter()
        .map(|t| t.map(|v| inv[v as usize]))
        .collect();
    let shuffled = TriMesh::new(p2, t2).unwrap();
    let run = |m: &TriMesh| {
        let s = system(m);
        let mut x: Vec<Vec3> = m.positions().iter().map(|p| *p * 1.1).collect();
        let mut pinned = vec![false; x.len()];
        let corner = m
            .positions()
            .iter()
            .position(|p| *p == mesh.positions()[0])
            .unwrap();
        pinned[corner] = true;
        let loads = Loads {
            pinned: Some(&pinned),
            ..Default::default()
        };
        s.relax(
            &mut x,
            &loads,
            &RelaxConfig {
                tolerance: 1e-5,
                ..Default::default()
            },
        )
        .unwrap();
        x
    };
    let a = run(&mesh);
    let b = run(&shuffled);
    // The internal order depends on the mesh, not on its numbering: the same bits.
    for (new, &old) in perm.iter().enumerate() {
        assert_eq!(a[old as usize], b[new], "vertex {old}");
    }
}

#[test]
fn with_stiffness_gives_what_new_gives() {
    // A sheet pinned along one side and sagging under a load, relaxed with per-edge stiffness
    // that a system built with uniform stiffness is given afterwards.
    let mesh = sheet(14);
    let uniform = system(&mesh);
    let edges = mesh.topology().edges();
    let rest: Vec<f32> = edges
        .iter()
        .map(|&[a, b]| mesh.positions()[a as usize].distance(mesh.positions()[b as usize]))
        .collect();
    let varied: Vec<f32> = (0..edges.len())
        .map(|e| 300.0 + 50.0 * (e % 11) as f32)
        .collect();
    let run = |s: &SpringSystem| {
        let mut x = mesh.positions().to_vec();
        let pinned: Vec<bool> = mesh.positions().iter().map(|p| p.y < 1e-3).collect();
        let forces = vec![Vec3::new(0.0, 0.0, -0.02); x.len()];
        let loads = Loads {
            forces: Some(&forces),
            pinned: Some(&pinned),
            ..Default::default()
        };
        s.relax(&mut x, &loads, &RelaxConfig::default()).unwrap();
        x
    };
    let restiffened = run(&uniform.with_stiffness(edges, &varied, &rest).unwrap());
    let fresh = run(&SpringSystem::new(mesh.positions(), edges, &varied, &rest).unwrap());
    assert_eq!(restiffened, fresh);
    // The new stiffness is the one relaxed with.
    assert_ne!(run(&uniform), fresh);
    // Its inputs are checked as `new` checks them.
    assert!(matches!(
        uniform.with_stiffness(edges, &varied[1..], &rest),
        Err(SolverError::Length { .. })
    ));
    let mut bad = varied.clone();
    bad[7] = -1.0;
    assert!(matches!(
        uniform.with_stiffness(edges, &bad, &rest),
        Err(SolverError::BadSpring { edge: 7, .. })
    ));
    assert!(matches!(
        uniform.with_stiffness(&[[0, 196]], &[1.0], &[1.0]),
        Err(SolverError::BadEdge { edge: 0, .. })
    ));
}

#[test]
fn bad_inputs_are_errors() {
    let rest = vec![Vec3::ZERO, Vec3::X];
    assert!(matches!(
        SpringSystem::new(&rest, &[[0, 2]], &[1.0], &[1.0]),
        Err(SolverError::BadEdge { edge: 0, .. })
    ));
    assert!(matches!(
        SpringSystem::new(&rest, &[[0, 1]], &[f32::NAN], &[1.0]),
        Err(SolverError::BadSpring { edge: 0, .. })
    ));
    let s = SpringSystem::new(&rest, &[[0, 1]], &[1.0], &[1.0]).unwrap();
    let mut x = vec![Vec3::ZERO, Vec3::new(f32::NAN, 0.0, 0.0)];
    assert_eq!(
        s.relax(&mut x, &Loads::default(), &RelaxConfig::default()),
        Err(SolverError::NonFinite {
            what: "position",
            vertex: 1
        })
    );
    // Over several chunks: the first non-finite position, then the first non-finite anchor
    // (the caller's index), whichever float of it.
    let rest: Vec<Vec3> = (0..3000)
        .map(|i| Vec3::new(i as f32 * 0.01, 0.0, 0.0))
        .collect();
    let edges: Vec<[u32; 2]> = (0..2999).map(|i| [i, i + 1]).collect();
    let s = SpringSystem::new(&rest, &edges, &[1.0; 2999], &[0.01; 2999]).unwrap();
    let mut x = rest.clone();
    x[2900].z = f32::INFINITY;
    x[1800].y = f32::NAN;
    let anchor = VertexAnchor {
        target: Vec3::ZERO,
        normal: Vec3::Z,
        k_normal: 1.0,
        k_tangent: 1.0,
    };
    let mut anchors = vec![anchor; 3000];
    let loads = Loads {
        anchors: Some(&anchors),
        ..Default::default()
    };
    let cfg = RelaxConfig::default();
    let err = s.relax(&mut x, &loads, &cfg).unwrap_err();
    assert_eq!(
        err,
        SolverError::NonFinite {
            what: "position",
            vertex: 1800
        }
    );
    let mut x = rest.clone();
    anchors[2600].target.x = f32::NAN;
    anchors[2500].k_tangent = f32::NEG_INFINITY;
    let loads = Loads {
        anchors: Some(&anchors),
        ..Default::default()
    };
    let err = s.relax(&mut x, &loads, &cfg).unwrap_err();
    assert_eq!(
        err,
        SolverError::NonFinite {
            what: "anchor",
            vertex: 2500
        }
    );
    assert_eq!(x, rest, "nothing moved");
}

/// The total energy at `x` in f64 straight from the definition (independent of the kernels).
fn reference_energy(
    mesh: &TriMesh,
    k: &[f32],
    x: &[Vec3],
    anchors: &[VertexAnchor],
    forces: &[Vec3],
) -> f64 {
    let rest = mesh.edge_lengths();
    let mut e = 0.0f64;
    for (i, &[a, b]) in mesh.topology().edges().iter().enumerate() {
        let l = (x[a as usize].as_dvec3() - x[b as usize].as_dvec3()).length();
        e += 0.5 * k[i] as f64 * (l - rest[i] as f64).powi(2);
    }
    for (p, a) in x.iter().zip(anchors) {
        let d = p.as_dvec3() - a.target.as_dvec3();
        let n = a.normal.as_dvec3();
        let dn = d.dot(n);
        e += 0.5 * a.k_normal as f64 * dn * dn
            + 0.5 * a.k_tangent as f64 * (d - n * dn).length_squared();
    }
    for (p, f) in x.iter().zip(forces) {
        e -= p.as_dvec3().dot(f.as_dvec3());
    }
    e
}

fn loaded_sheet(n: u32) -> (TriMesh, Vec<f32>, Vec<Vec3>, Vec<VertexAnchor>, Vec<Vec3>) {
    let mesh = sheet(n);
    let k = StiffnessRule::AreaOverLengthSquared
        .edge_stiffness(&mesh, &Modulus::Uniform(1000.0))
        .unwrap();
    let x: Vec<Vec3> = mesh
        .positions()
        .iter()
        .enumerate()
        .map(|(i, p)| *p * 1.2 + Vec3::new(0.0, 0.0, 0.01 * ((i * 37 % 11) as f32 - 5.0)))
        .collect();
    let anchors: Vec<VertexAnchor> = mesh
        .positions()
        .iter()
        .map(|p| VertexAnchor {
            target: *p + Vec3::Z * 0.01 * (p.x * 9.0).sin(),
            normal: Vec3::Z,
            k_normal: 200.0,
            k_tangent: 20.0,
        })
        .collect();
    let forces = vec![Vec3::new(0.001, 0.0, -0.002); x.len()];
    (mesh, k, x, anchors, forces)
}

#[test]
fn reported_energy_matches_the_definition() {
    let (mesh, k, mut x, anchors, forces) = loaded_sheet(20);
    let s = SpringSystem::from_mesh(&mesh, &k).unwrap();
    let loads = Loads {
        forces: Some(&forces),
        anchors: Some(&anchors),
        ..Default::default()
    };
    let start = reference_energy(&mesh, &k, &x, &anchors, &forces);
    let cfg = RelaxConfig {
        max_iterations: 40,
        tolerance: 0.0,
        record_energy: true,
        ..RelaxConfig::DEFAULT
    };
    let report = s.relax(&mut x, &loads, &cfg).unwrap();
    let end = reference_energy(&mesh, &k, &x, &anchors, &forces);
    let tol = |e: f64| 1e-9 * e.abs().max(1e-6);
    let first = report.energy_history[0];
    assert!((first - start).abs() < tol(start), "{first} vs {start}");
    assert!(
        (report.energy - end).abs() < tol(end),
        "{} vs {end}",
        report.energy
    );
    assert!(end < start);
    // Springs alone: the closed form of one stretched spring.
    // (0.75, 1, 0) is 1.25 long, exactly; stretch 0.5 against a rest length of 0.75.
    let one = SpringSystem::new(&[Vec3::ZERO, Vec3::X], &[[0, 1]], &[300.0], &[0.75]).unwrap();
    let e = one
        .spring_energy(&[Vec3::ZERO, Vec3::new(0.75, 1.0, 0.0)])
        .unwrap();
    assert!((e - 0.5 * 300.0 * 0.25).abs() < 1e-12, "{e}");
}

/// The monotone-energy invariant against an independent f64 energy: the solve is
/// deterministic, so the solve stopped after `m` iterations is the first `m` iterations of a
/// longer one; the energy from the definition at each of those stops never rises, down to the
/// tiny steps at the f32 floor, and the reported energy is that total.
#[test]
fn energy_from_the_definition_never_rises_iteration_by_iteration() {
    let (mesh, k, x0, anchors, forces) = loaded_sheet(10);
    let s = SpringSystem::from_mesh(&mesh, &k).unwrap();
    let loads = Loads {
        forces: Some(&forces),
        anchors: Some(&anchors),
        ..Default::default()
    };
    let mut previous = reference_energy(&mesh, &k, &x0, &anchors, &forces);
    let mut smallest_drop = f64::INFINITY;
    let mut last_iterations = 0;
    for m in 1..=160 {
        let cfg = RelaxConfig {
            max_iterations: m,
            tolerance: 0.0,
            stagnation_window: 0,
            ..RelaxConfig::DEFAULT
        };
        let mut x = x0.clone();
        let report = s.relax(&mut x, &loads, &cfg).unwrap();
        let e = reference_energy(&mesh, &k, &x, &anchors, &forces);
        // The reference's own rounding: ~1e-16 per term of a sum of a few hundred.
        let slack = 1e-13 * e.abs();
        assert!(e <= previous + slack, "iteration {m}: {previous} -> {e}");
        assert!(
            (report.energy - e).abs() <= 1e-9 * e.abs(),
            "iteration {m}: reported {} vs {e}",
            report.energy
        );
        if report.iterations > last_iterations {
            smallest_drop = smallest_drop.min(previous - e);
        }
        (previous, last_iterations) = (e, report.iterations);
        if report.stop == StopReason::Stalled {
            break;
        }
    }
    // The run reached steps whose energy change is tiny next to the total.
    assert!(
        smallest_drop < 1e-9 * previous.abs(),
        "{smallest_drop} vs {previous}"
    );
}

#[test]
fn results_are_bit_identical_for_any_thread_count() {
    // 60 x 60 = 3600 vertices: two parallel chunks, so the chunked reductions matter.
    let (mesh, k, x0, anchors, forces) = loaded_sheet(60);
    let s = SpringSystem::from_mesh(&mesh, &k).unwrap();
    let mut pinned = vec![false; x0.len()];
    pinned[7] = true;
    let loads = Loads {
        forces: Some(&forces),
        pinned: Some(&pinned),
        anchors: Some(&anchors),
    };
    let cfg = RelaxConfig {
        max_iterations: 60,
        tolerance: 0.0,
        record_energy: true,
        ..RelaxConfig::DEFAULT
    };
    let run = |threads: usize| {
        crate::test_support::in_pool(threads, || {
            let mut x = x0.clone();
            let report = s.relax(&mut x, &loads, &cfg).unwrap();
            (x, report)
        })
    };
    let (x1, r1) = run(1);
    for threads in [2, 3] {
        let (x, r) = run(threads);
        assert!(
            x.iter()
                .zip(&x1)
                .all(|(a, b)| a.to_array().map(f32::to_bits) == b.to_array().map(f32::to_bits))
        );
        assert_eq!(r.energy.to_bits(), r1.energy.to_bits());
        assert_eq!(r.iterations, r1.iterations);
        assert_eq!(r.energy_history, r1.energy_history);
    }
    for w in r1.energy_history.windows(2) {
        assert!(w[1] <= w[0], "energy rose from {} to {}", w[0], w[1]);
    }
}

/// Keeps every vertex at or above a floor.
struct Floor(f32);

impl Projection for Floor {
    fn project(&mut self, x: &mut [Vec3], _order: &[u32]) -> bool {
        let mut moved = false;
        for p in x {
            if p.z < self.0 {
                p.z = self.0;
                moved = true;
            }
        }
        moved
    }
}

#[test]
fn projection_holds_and_energy_falls_between_projections() {
    // A sheet pinned at two corners sags under a load onto a floor just below it.
    let mesh = sheet(12);
    let s = system(&mesh);
    let n = mesh.positions().len();
    let mut x = mesh.positions().to_vec();
    let mut pinned = vec![false; n];
    pinned[0] = true;
    pinned[n - 1] = true;
    let forces = vec![Vec3::new(0.0, 0.0, -0.5); n];
    let loads = Loads {
        forces: Some(&forces),
        pinned: Some(&pinned),
        ..Default::default()
    };
    let floor = -0.06;
    let cfg = RelaxConfig {
        max_iterations: 200,
        tolerance: 1e-5,
        ..RelaxConfig::DEFAULT
    };
    let report = s
        .relax_projected(&mut x, &loads, &cfg, Some(&mut Floor(floor)))
        .unwrap();
    assert!(report.iterations > 1);
    assert!(x.iter().all(|p| p.z >= floor));
    // The load is strong enough that the sheet reaches the floor somewhere.
    assert!(x.iter().any(|p| p.z == floor));
    // Without the floor, the same sheet sags lower.
    let mut free = mesh.positions().to_vec();
    s.relax(&mut free, &loads, &cfg).unwrap();
    assert!(free.iter().any(|p| p.z < floor));
}

/// An unreachable tolerance: the residual hits the f32 floor, and the stagnation stop ends the
/// solve there (as `Stalled`, long before the budget) with the answer already accurate.
#[test]
fn stagnation_stops_at_the_f32_floor_instead_of_spending_the_budget() {
    let rest: Vec<Vec3> = (0..6)
        .map(|i| Vec3::new(i as f32 * 0.1, 0.0, 0.0))
        .collect();
    let edges: Vec<[u32; 2]> = (0..5).map(|i| [i, i + 1]).collect();
    let k = [100.0, 200.0, 50.0, 400.0, 80.0];
    let s = SpringSystem::new(&rest, &edges, &k, &[0.1; 5]).unwrap();
    let mut f = vec![Vec3::ZERO; 6];
    f[5] = Vec3::new(1.5, 0.0, 0.0);
    let mut pinned = vec![false; 6];
    pinned[0] = true;
    let loads = Loads {
        forces: Some(&f),
        pinned: Some(&pinned),
        ..Default::default()
    };
    let cfg = RelaxConfig {
        tolerance: 1e-12,
        max_iterations: 10_000,
        ..Default::default()
    };
    let mut x = rest.clone();
    let report = s.relax(&mut x, &loads, &cfg).unwrap();
    assert_eq!(report.stop, StopReason::Stalled, "{report:?}");
    assert!(report.iterations < 200, "{report:?}");
    let expected: f32 = 0.5 + k.iter().map(|k| 1.5 / k).sum::<f32>();
    assert!((x[5].x - expected).abs() < 1e-5);
    // Switched off, the same solve runs on (it may still stop when no step lowers the energy).
    let mut y = rest.clone();
    let off = RelaxConfig {
        stagnation_window: 0,
        ..cfg
    };
    let report_off = s.relax(&mut y, &loads, &off).unwrap();
    assert!(report_off.iterations >= report.iterations);
}

/// A floor that reports its contacts: every vertex on it (within `band`), normal +z, and keeps
/// held vertices on it.
struct ContactFloor {
    z: f32,
    band: f32,
    active: Vec<ActiveContact>,
    held: Vec<u32>,
}

impl ContactFloor {
    fn new(z: f32) -> Self {
        Self {
            z,
            band: 1e-3,
            active: Vec::new(),
            held: Vec::new(),
        }
    }
}

impl Projection for ContactFloor {
    fn project(&mut self, x: &mut [Vec3], _order: &[u32]) -> bool {
        let mut moved = false;
        for &v in &self.held {
            let p = &mut x[v as usize];
            if p.z != self.z && p.z < self.z + self.band {
                p.z = self.z;
                moved = true;
            }
        }
        self.active.clear();
        for (i, p) in x.iter_mut().enumerate() {
            if p.z < self.z {
                p.z = self.z;
                moved = true;
            }
            if p.z < self.z + self.band {
                self.active.push(ActiveContact {
                    vertex: i as u32,
                    normal: Vec3::Z,
                    stick: false,
                });
            }
        }
        moved
    }

    fn active_contacts(&self) -> &[ActiveContact] {
        &self.active
    }

    fn hold(&mut self, held: &[bool]) {
        self.held = self
            .active
            .iter()
            .zip(held)
            .filter(|(_, h)| **h)
            .map(|(c, _)| c.vertex)
            .collect();
    }
}

/// The sheet of `projection_holds_...` pressed onto the floor converges with the contact set,
/// to a point that satisfies the contact problem's KKT conditions, checked from the spring
/// forces alone: free vertices above the floor are force-free, vertices on it are pushed
/// straight down (the floor pushes back), none is below. The floor without its contact set
/// (the old behaviour) cannot converge in ten times the iterations.
#[test]
fn contact_set_converges_to_the_kkt_point_on_a_floor() {
    let mesh = sheet(12);
    let s = system(&mesh);
    let n = mesh.positions().len();
    let mut pinned = vec![false; n];
    pinned[0] = true;
    pinned[n - 1] = true;
    let forces = vec![Vec3::new(0.0, 0.0, -0.5); n];
    let loads = Loads {
        forces: Some(&forces),
        pinned: Some(&pinned),
        ..Default::default()
    };
    let floor = -0.06;
    let cfg = RelaxConfig {
        max_iterations: 2000,
        // Above the f32 floor of this sheet (~1e-4 of the load).
        tolerance: 3e-4,
        ..RelaxConfig::DEFAULT
    };
    let mut x = mesh.positions().to_vec();
    let report = s
        .relax_projected(&mut x, &loads, &cfg, Some(&mut ContactFloor::new(floor)))
        .unwrap();
    assert_eq!(report.stop, StopReason::Converged, "{report:?}");
    let f = s.spring_forces(&x).unwrap();
    let tol = 2.0 * cfg.tolerance * report.force_scale;
    let mut on_floor = 0;
    for i in (0..n).filter(|&i| !pinned[i]) {
        let net = f[i] + forces[i];
        assert!(x[i].z >= floor, "vertex {i} below the floor");
        if x[i].z <= floor + 1e-6 {
            on_floor += 1;
            assert!(
                net.z < tol,
                "vertex {i} on the floor pulled up by {}",
                net.z
            );
            assert!(net.truncate().length() < tol, "vertex {i}: {net}");
        } else {
            assert!(net.length() < tol, "free vertex {i}: {net}");
        }
    }
    assert!(on_floor > 5, "{on_floor}");

    let mut old = mesh.positions().to_vec();
    let blind = RelaxConfig {
        max_iterations: 10 * report.iterations,
        stagnation_window: 0,
        ..cfg
    };
    let old_report = s
        .relax_projected(&mut old, &loads, &blind, Some(&mut Floor(floor)))
        .unwrap();
    assert_ne!(old_report.stop, StopReason::Converged, "{old_report:?}");
    eprintln!(
        "floor: {} iterations; without the contact set {old_report:?}",
        report.iterations
    );
}

/// After a projection moved a few vertices, the solver gathers the forces again only in the
/// chunks that read a moved vertex: forces and every sum must be those of a whole gather, bit
/// for bit, including a move at a chunk boundary (whose readers lie in two chunks).
#[test]
fn a_gather_after_a_few_vertices_moved_equals_a_whole_one_bit_for_bit() {
    // 6,400 vertices: seven chunks.
    let (mesh, k, x, anchors, forces) = loaded_sheet(80);
    let s = SpringSystem::from_mesh(&mesh, &k).unwrap();
    let n = s.vertex_count();
    let chunks = kernels::chunks(n);
    assert!(chunks >= 5);
    let (xi, ext) = (s.to_internal(&x), s.to_internal(&forces));
    let sliced = SlicedAnchors::finite(&anchors, &s.order, Par::Pool).unwrap();
    let frame = s.frame(Some(&ext), Some(&sliced), Par::Pool);
    let w = frame.inverse_diagonal(&vec![false; n]);
    let d: Vec<Vec3> = (0..n)
        .map(|i| Vec3::new((i as f32 * 0.3).sin(), 0.2, (i as f32 * 0.7).cos()) * 1e-3)
        .collect();
    // The trial gather the solver did at `xi` (after some older force in `r`).
    let mut r: Vec<Vec3> = (0..n).map(|i| Vec3::splat((i % 5) as f32 * 0.1)).collect();
    let mut partial = vec![Sums::default(); chunks];
    frame.gather_along(&xi, &d, Some(&w), &mut r, &mut partial);
    // The projection moves a vertex at the end of chunk 1 and two inside chunk 3.
    let moved = [
        kernels::CHUNK as u32 * 2 - 1,
        kernels::CHUNK as u32 * 3 + 17,
        kernels::CHUNK as u32 * 3 + 400,
    ];
    let mut x1 = xi.clone();
    for &v in &moved {
        x1[v as usize] += Vec3::new(2e-3, -1e-3, 3e-3);
    }
    let (mut r_whole, mut p_whole) = (r.clone(), partial.clone());
    let whole = frame.gather(&x1, Some(&w), &mut r_whole, &mut p_whole);
    let mut stale = Vec::new();
    s.readers_of(&moved, &mut stale);
    assert!(stale.len() < chunks, "some chunk is kept: {stale:?}");
    assert!(
        stale.contains(&2),
        "chunk 2 reads the vertex at the end of chunk 1"
    );
    let again = frame.regather(&x1, Some(&w), &mut r, &mut partial, &stale);
    let differs = r
        .iter()
        .zip(&r_whole)
        .position(|(a, b)| a.to_array().map(f32::to_bits) != b.to_array().map(f32::to_bits));
    assert_eq!(differs, None, "the first vertex whose force differs");
    for (got, want) in [
        (again.energy, whole.energy),
        (again.rr, whole.rr),
        (again.rzr, whole.rzr),
        (again.rz_old, whole.rz_old),
        (again.rd, whole.rd),
    ] {
        assert_eq!(got.to_bits(), want.to_bits(), "{again:?} vs {whole:?}");
    }
}

/// The bench's timed solve answers as the plain one, bit for bit, and its loop times lie
/// within the solve's: each loop ran, and together they leave the set-up and the serial work.
#[test]
fn a_timed_solve_gives_the_same_answer_and_its_loops_fit_in_its_time() {
    let (mesh, k, x0, anchors, forces) = loaded_sheet(40);
    let s = SpringSystem::from_mesh(&mesh, &k).unwrap();
    let loads = Loads {
        forces: Some(&forces),
        anchors: Some(&anchors),
        ..Default::default()
    };
    let cfg = RelaxConfig {
        max_iterations: 25,
        tolerance: 0.0,
        ..RelaxConfig::DEFAULT
    };
    let (mut plain, mut timed) = (x0.clone(), x0);
    let want = s.relax(&mut plain, &loads, &cfg).unwrap();
    let mut times = LoopTimes::default();
    let wall = std::time::Instant::now();
    let got = s.relax_timed(&mut timed, &loads, &cfg, &mut times).unwrap();
    let wall = wall.elapsed().as_secs_f64();
    assert_eq!(got, want);
    assert!(got.iterations > 0);
    let bits = |x: &[Vec3]| -> Vec<u32> {
        x.iter()
            .flat_map(|p| p.to_array())
            .map(f32::to_bits)
            .collect()
    };
    assert_eq!(bits(&timed), bits(&plain));
    let loops = [times.curvature, times.force, times.step, times.direction];
    assert!(loops.iter().all(|&t| t > 0.0), "{times:?}");
    // No projection: nothing timed there.
    assert_eq!(times.projection, 0.0);
    let looped: f64 = loops.iter().sum();
    assert!(
        looped < times.total && times.total <= wall,
        "{times:?} in {wall} s"
    );
    // A second solve adds to the same times.
    let before = times;
    let mut again = plain.clone();
    s.relax_timed(&mut again, &loads, &cfg, &mut times).unwrap();
    assert!(times.total > before.total && times.force > before.force);
}

/// A floor that projects alongside the solver's force gather (`project_step_deferred`), its
/// moves found in a parallel loop on the solve's team; it counts how the solver drives it.
#[derive(Default)]
struct FloorAlongside {
    z: f32,
    /// Passes run alongside the gather.
    alongside: usize,
    /// Whole passes (`project`) right after a `settled` in the middle of a solve.
    whole_after_settled: usize,
    /// `settled` calls.
    settled: usize,
    waiting: bool,
}

impl Projection for FloorAlongside {
    fn project(&mut self, x: &mut [Vec3], order: &[u32]) -> bool {
        if std::mem::take(&mut self.waiting) {
            self.whole_after_settled += 1;
        }
        Floor(self.z).project(x, order)
    }

    fn project_step_deferred(
        &mut self,
        x: &[Vec3],
        _order: &[u32],
        _step: &Step<'_>,
        moves: &mut Vec<(u32, Vec3)>,
    ) -> Option<bool> {
        self.alongside += 1;
        let chunks = x.len().div_ceil(256);
        let found: Vec<std::sync::Mutex<Vec<(u32, Vec3)>>> =
            (0..chunks).map(|_| Default::default()).collect();
        team::Par::current(|par| {
            par.for_each(chunks, |c| {
                let low = (c * 256..((c + 1) * 256).min(x.len()))
                    .filter(|&i| x[i].z < self.z)
                    .map(|i| (i as u32, Vec3::new(x[i].x, x[i].y, self.z)));
                found[c].lock().unwrap().extend(low);
            });
        });
        moves.clear();
        moves.extend(found.into_iter().flat_map(|f| f.into_inner().unwrap()));
        Some(!moves.is_empty())
    }

    fn settled(&mut self, _x: &[Vec3]) {
        self.settled += 1;
        self.waiting = true;
    }
}

/// The projection run alongside the force gather, its moves applied after it, gives the bits
/// of the projection run after the gather, on any number of threads: on a sheet sagging onto
/// a floor, and through rejected trial steps (the first trial from rest raises the energy: the
/// solver then reports the point it went back to and projects the step it accepts whole; after
/// two such rejections it projects after the gather).
#[test]
fn a_projection_alongside_the_gather_gives_the_same_bits_through_rejected_steps() {
    let bits = |x: &[Vec3]| -> Vec<[u32; 3]> {
        x.iter().map(|p| p.to_array().map(f32::to_bits)).collect()
    };
    // (sheet size, pinned corners, load, floor)
    for (size, corners, load, z) in [(12, 2, -0.5, -0.06), (40, 1, -100.0, -0.2)] {
        let mesh = sheet(size);
        let s = system(&mesh);
        let n = mesh.positions().len();
        let mut pinned = vec![false; n];
        pinned[0] = true;
        pinned[n - 1] = corners == 2;
        let forces = vec![Vec3::new(0.0, 0.0, load); n];
        let loads = Loads {
            pinned: Some(&pinned),
            forces: Some(&forces),
            ..Default::default()
        };
        let cfg = RelaxConfig {
            max_iterations: 80,
            tolerance: 1e-5,
            ..RelaxConfig::DEFAULT
        };
        let mut after = mesh.positions().to_vec();
        let plain = crate::test_support::in_pool(2, || {
            s.relax_projected(&mut after, &loads, &cfg, Some(&mut Floor(z)))
                .unwrap()
        });
        for threads in [1, 2, 3] {
            let mut x = mesh.positions().to_vec();
            let mut floor = FloorAlongside {
                z,
                ..Default::default()
            };
            let report = crate::test_support::in_pool(threads, || {
                s.relax_projected(&mut x, &loads, &cfg, Some(&mut floor))
                    .unwrap()
            });
            let case = format!("load {load}, {threads} threads");
            assert_eq!(bits(&x), bits(&after), "{case}");
            assert_eq!(report.iterations, plain.iterations, "{case}");
            assert_eq!(report.energy.to_bits(), plain.energy.to_bits(), "{case}");
            assert!(x.iter().any(|p| p.z == z) && x.iter().all(|p| p.z >= z));
            // Each rejected trial after a pass alongside the gather was reported, and the step
            // accepted after it projected whole; the end of the solve was reported too.
            let (alongside, whole) = (floor.alongside, floor.whole_after_settled);
            assert_eq!(floor.settled, whole + 1, "{case}");
            let its = report.iterations as usize;
            if corners == 2 {
                // One rejection (the first trial): every later step projected alongside.
                assert!(
                    whole >= 1 && alongside == its,
                    "{case}: {alongside} {whole}"
                );
            } else {
                // Many: after the second, the projections follow the gather.
                assert_eq!(whole, ALONGSIDE_MISSES as usize, "{case}");
                assert!(alongside < its / 2, "{case}: {alongside} of {its}");
            }
        }
    }
}
