//! The `equilibrium` and `paper fig4` commands, run as a user would.

use crate::common::dermis;

use dermis::io::{MeshFile, obj_text, read_mesh};
use dermis::mesh::shapes::sheet;
use dermis::solver::{Loads, RelaxConfig, SpringSystem};
use dermis::stiffness::{Modulus, StiffnessRule};

/// A sheet pinned along one side and pulled along the other: the command's answer must be the
/// library's, the summary must say so, and the output must be a readable mesh.
#[test]
fn equilibrium_command_relaxes_and_reports() {
    let dir = tempfile::tempdir().unwrap();
    let mesh = sheet(6, 1.0);
    std::fs::write(
        dir.path().join("m.obj"),
        obj_text(mesh.positions(), mesh.triangles()),
    )
    .unwrap();
    // Left column pinned, right column pulled +x with 1 N in total (consistent nodal loads of a
    // uniform 1 N/m traction: corners get half).
    let pinned: Vec<u32> = (0..6).map(|j| j * 6).collect();
    let share = |j: u32| if j == 0 || j == 5 { 0.1 } else { 0.2 };
    let forces: Vec<String> = (0..6)
        .map(|j| {
            format!(
                r#"{{"vertex": {}, "force": [{}, 0, 0]}}"#,
                j * 6 + 5,
                share(j)
            )
        })
        .collect();
    let loads = format!(
        r#"{{"forces": [{}], "pinned": {:?}}}"#,
        forces.join(","),
        pinned
    );
    std::fs::write(dir.path().join("l.json"), loads).unwrap();
    let out = dir.path().join("out.obj");
    let output = crate::common::run_ok(
        dermis()
            .args(["equilibrium", "--mesh"])
            .arg(dir.path().join("m.obj"))
            .arg("--loads")
            .arg(dir.path().join("l.json"))
            .args(["--stiffness", "area-len2", "--e2", "100", "--json", "--out"])
            .arg(&out),
    );
    let summary: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap();
    assert_eq!(summary["rule"], "area-len2");
    assert_eq!(summary["vertices"], 36);
    assert_eq!(summary["stop"], "converged");
    let MeshFile::Surface(result) = read_mesh(&out).unwrap() else {
        panic!("surface")
    };
    // The command's answer is the library's, bit for bit.
    let k = StiffnessRule::AreaOverLengthSquared
        .edge_stiffness(&mesh, &Modulus::Uniform(100.0))
        .unwrap();
    let system = SpringSystem::from_mesh(&mesh, &k).unwrap();
    let mut x = mesh.positions().to_vec();
    let mut f = vec![glam::Vec3::ZERO; 36];
    let mut pins = vec![false; 36];
    for j in 0..6 {
        f[(j * 6 + 5) as usize].x = share(j);
        pins[(j * 6) as usize] = true;
    }
    let loads = Loads {
        forces: Some(&f),
        pinned: Some(&pins),
        ..Default::default()
    };
    system
        .relax(&mut x, &loads, &RelaxConfig::default())
        .unwrap();
    assert_eq!(result.positions(), &x[..]);
    // Physically: a 1 m square of E2 = 100 N/m under 1 N/m stretches by about 1 % (the spring
    // mesh's own Poisson effect and the clamped edge make it differ by a few tens of %).
    let right: f32 = (0..6)
        .map(|j| result.positions()[j * 6 + 5].x - 0.5)
        .sum::<f32>()
        / 6.0;
    assert!((right - 0.01).abs() < 0.003, "right edge moved {right}");
    for p in &pinned {
        assert_eq!(
            result.positions()[*p as usize],
            mesh.positions()[*p as usize]
        );
    }
}

#[test]
fn equilibrium_command_rejects_bad_loads_and_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let mesh = sheet(3, 1.0);
    std::fs::write(
        dir.path().join("m.obj"),
        obj_text(mesh.positions(), mesh.triangles()),
    )
    .unwrap();
    std::fs::write(dir.path().join("l.json"), r#"{"pinned": [99]}"#).unwrap();
    let out = dir.path().join("out.obj");
    let output = dermis()
        .args(["equilibrium", "--mesh"])
        .arg(dir.path().join("m.obj"))
        .arg("--loads")
        .arg(dir.path().join("l.json"))
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert_eq!(output.status.code(), Some(1));
    let err = String::from_utf8_lossy(&output.stderr);
    assert!(err.contains("pinned[0] names vertex 99"), "{err}");
    assert!(!out.exists());
}

#[test]
fn fig4_command_prints_the_documented_json() {
    let dir = tempfile::tempdir().unwrap();
    let output = crate::common::run_ok(
        dermis()
            .args(["paper", "fig4", "--seeds", "2", "--json", "--out"])
            .arg(dir.path()),
    );
    let v: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap();
    let runs = v["runs"].as_array().unwrap();
    assert_eq!(runs.len(), 2);
    for run in runs {
        assert!(run["vertices"].as_u64().unwrap() > 100);
        for rule in ["constant", "inverse-length", "area-len2", "poisson", "fem"] {
            assert!(run["deviation"][rule].as_f64().unwrap() >= 0.0, "{rule}");
        }
    }
    for seed in 0..2 {
        let png = std::fs::read(dir.path().join(format!("fig4-seed{seed}.png"))).unwrap();
        assert_eq!(&png[1..4], b"PNG");
    }
}
