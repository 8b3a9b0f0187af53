use approx::assert_relative_eq;

use super::*;

/// Eq. 11 and Eq. 12 written out exactly as in the paper, for vertices p, q, r.
fn paper_blocks(p: DVec2, q: DVec2, r: DVec2, e2: f64, nu: f64) -> ([[f64; 2]; 2], [[f64; 2]; 2]) {
    let area = 0.5 * (q - p).perp_dot(r - p);
    let s = e2 / (4.0 * area * (1.0 - nu * nu));
    let g = (1.0 - nu) / 2.0;
    let h = (1.0 + nu) / 2.0;
    let (xrq, yrq) = (r.x - q.x, r.y - q.y);
    let (xpr, ypr) = (p.x - r.x, p.y - r.y);
    let kpp = [
        [s * (yrq * yrq + g * xrq * xrq), -s * h * yrq * xrq],
        [-s * h * yrq * xrq, s * (xrq * xrq + g * yrq * yrq)],
    ];
    let kpq = [
        [
            s * (yrq * ypr + g * xrq * xpr),
            s * (-nu * yrq * xpr - g * ypr * xrq),
        ],
        [
            s * (-nu * xrq * ypr - g * xpr * yrq),
            s * (xrq * xpr + g * yrq * ypr),
        ],
    ];
    (kpp, kpq)
}

#[test]
fn element_matrix_is_the_papers_eq_11_and_12() {
    let (p, q, r) = (
        DVec2::new(0.1, -0.2),
        DVec2::new(1.3, 0.4),
        DVec2::new(0.2, 0.9),
    );
    let (e2, nu) = (250.0, 0.3);
    let k = cst_stiffness([p, q, r], e2, nu);
    let (kpp, kpq) = paper_blocks(p, q, r, e2, nu);
    for i in 0..2 {
        for j in 0..2 {
            assert_relative_eq!(k[i][j], kpp[i][j], max_relative = 1e-12);
            assert_relative_eq!(k[i][2 + j], kpq[i][j], max_relative = 1e-12);
        }
    }
    // Rows sum to zero (translations), and a rotation gives no force.
    let rot: Vec<f64> = [p, q, r].iter().flat_map(|v| [-v.y, v.x]).collect();
    for row in &k {
        assert!(row.iter().step_by(2).sum::<f64>().abs() < 1e-10);
        let f: f64 = row.iter().zip(&rot).map(|(a, b)| a * b).sum();
        assert!(f.abs() < 1e-10);
    }
}

fn square_mesh(n: u32) -> TriMesh {
    let mut p = Vec::new();
    for j in 0..n {
        for i in 0..n {
            let jitter = if i % (n - 1) != 0 && j % (n - 1) != 0 {
                0.02 * ((i * 7 + j * 3) % 5) as f32
            } else {
                0.0
            };
            p.push(Vec3::new(
                i as f32 / (n - 1) as f32 + jitter,
                j as f32 / (n - 1) as f32 - jitter,
                0.0,
            ));
        }
    }
    TriMesh::new(p, crate::mesh::shapes::grid_triangles(n, n)).unwrap()
}

/// A square pulled uniformly on two opposite sides stretches uniformly, with the Poisson
/// contraction of plane stress: `ε_x = σ/E2`, `ε_y = −ν σ/E2` (the patch test).
#[test]
fn uniaxial_tension_gives_the_plane_stress_answer() {
    let n = 7;
    let mesh = square_mesh(n);
    let (e2, nu, sigma) = (1000.0, 0.3, 2.0);
    let mut f = vec![Vec3::ZERO; mesh.positions().len()];
    let h = 1.0 / (n - 1) as f32;
    for j in 0..n {
        let w = if j == 0 || j == n - 1 { 0.5 } else { 1.0 };
        f[(j * n + n - 1) as usize].x += sigma * h * w;
        f[(j * n) as usize].x -= sigma * h * w;
    }
    let pinned = vec![false; f.len()];
    let sol = solve_membrane(&mesh, &Modulus::Uniform(e2), nu, &f, &pinned).unwrap();
    // Fit the displacement gradient G by least squares; its symmetric part is the strain (the
    // antisymmetric part is a rigid rotation, which the loads leave undetermined).
    let c = mesh.positions().iter().map(|p| p.as_dvec3()).sum::<DVec3>() / f.len() as f64;
    let (mut dq, mut qq) = (glam::DMat2::ZERO, glam::DMat2::ZERO);
    for (p, d) in mesh.positions().iter().zip(&sol.displacement) {
        let q = (p.as_dvec3() - c).truncate();
        dq += glam::DMat2::from_cols(d.truncate() * q.x, d.truncate() * q.y);
        qq += glam::DMat2::from_cols(q * q.x, q * q.y);
    }
    let g = dq * qq.inverse();
    let strain = (g + g.transpose()) * 0.5;
    assert_relative_eq!(
        strain.x_axis.x,
        sigma as f64 / e2 as f64,
        max_relative = 1e-6
    );
    assert_relative_eq!(
        strain.y_axis.y,
        -nu * sigma as f64 / e2 as f64,
        max_relative = 1e-6
    );
    assert!(strain.x_axis.y.abs() < 1e-9);
}

#[test]
fn one_spring_linear_solve_is_f_over_k() {
    let mesh = TriMesh::new(vec![Vec3::ZERO, Vec3::X, Vec3::Y], vec![[0, 1, 2]]).unwrap();
    let k = [10.0, 20.0, 30.0];
    let mut f = vec![Vec3::ZERO; 3];
    f[1] = Vec3::new(0.5, 0.0, 0.0);
    let pinned = [true, false, true];
    let sol = solve_linear_springs(&mesh, &k, &f, &pinned).unwrap();
    // Vertex 1 is held by edge (0,1), k=10, along x, and edge (1,2), k=30, at 45 degrees:
    // K = [[10 + 15, -15], [-15, 15]] so d = K⁻¹ f.
    let (a, b, c) = (25.0f64, -15.0f64, 15.0f64);
    let det = a * c - b * b;
    let d = DVec2::new(c * 0.5 / det, -b * 0.5 / det);
    let got = sol.displacement[1];
    assert_relative_eq!(got.length(), d.length(), max_relative = 1e-9);
    assert_eq!(sol.displacement[0], DVec3::ZERO);
}

#[test]
fn unbalanced_free_loads_and_bent_meshes_are_errors() {
    let mesh = square_mesh(3);
    let mut f = vec![Vec3::ZERO; 9];
    f[4] = Vec3::X;
    let pinned = vec![false; 9];
    assert!(matches!(
        solve_membrane(&mesh, &Modulus::Uniform(1.0), 0.2, &f, &pinned),
        Err(FemError::Unbalanced(_))
    ));
    let mut p = mesh.positions().to_vec();
    p[4].z = 0.3;
    let bent = TriMesh::new(p, mesh.triangles().to_vec()).unwrap();
    assert!(matches!(
        solve_membrane(
            &bent,
            &Modulus::Uniform(1.0),
            0.2,
            &[Vec3::ZERO; 9],
            &pinned
        ),
        Err(FemError::NotPlanar { vertex: 4, .. })
    ));
}
