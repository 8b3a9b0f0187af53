//! Unit tests of the export geometry, validation and checkpoints.

use std::path::Path;

use approx::assert_relative_eq;
use glam::{Quat, Vec3};

use super::*;

/// Unit cube `[-1, 1]³`, each face split into two triangles, all outward and counter-clockwise.
fn cube() -> (Vec<Vec3>, Vec<[u32; 3]>) {
    let p: Vec<Vec3> = (0..8)
        .map(|i| {
            Vec3::new(
                if i & 1 == 0 { -1.0 } else { 1.0 },
                if i & 2 == 0 { -1.0 } else { 1.0 },
                if i & 4 == 0 { -1.0 } else { 1.0 },
            )
        })
        .collect();
    let faces = [
        [0, 2, 3, 1],
        [4, 5, 7, 6],
        [0, 1, 5, 4],
        [2, 6, 7, 3],
        [0, 4, 6, 2],
        [1, 3, 7, 5],
    ];
    let mut t = Vec::new();
    for f in faces {
        for tri in [[f[0], f[1], f[2]], [f[0], f[2], f[3]]] {
            // Orient outward: the face normal must point away from the centre.
            let [a, b, c] = tri.map(|v: u32| p[v as usize]);
            let outward = (b - a).cross(c - a).dot(a + b + c) > 0.0;
            t.push(if outward {
                tri
            } else {
                [tri[0], tri[2], tri[1]]
            });
        }
    }
    (p, t)
}

/// A flat `n × n` grid in the xy plane with spacing 1.
fn grid(n: u32) -> (Vec<Vec3>, Vec<[u32; 3]>) {
    let p = (0..n * n)
        .map(|i| Vec3::new((i % n) as f32, (i / n) as f32, 0.0))
        .collect();
    (p, crate::mesh::shapes::grid_triangles(n, n))
}

#[test]
fn angle_weighted_normals_of_a_cube_point_along_the_diagonals() {
    // Each corner touches one or two triangles of each face, so area weighting would tilt the
    // normal; angle weighting gives each face the same π/2 and the exact diagonal.
    let (p, t) = cube();
    for (v, n) in p.iter().zip(vertex_normals(&t, &p)) {
        let expected = v.normalize();
        assert!(
            (n - expected).length() < 1e-6,
            "vertex {v}: {n} vs {expected}"
        );
    }
}

#[test]
fn normals_of_a_flat_grid_are_plus_z_and_isolated_vertices_fall_back() {
    let (mut p, t) = grid(4);
    p.push(Vec3::new(9.0, 9.0, 9.0)); // in no triangle
    let n = vertex_normals(&t, &p);
    assert!(n.iter().all(|n| (*n - Vec3::Z).length() < 1e-6));
}

#[test]
fn strain_of_uniform_scaling_is_the_scale_factor() {
    let (p, t) = cube();
    let scaled: Vec<Vec3> = p.iter().map(|v| 1.1 * *v).collect();
    for s in vertex_strain(&t, &p, &scaled, StrainMeasure::MaxPrincipalStretch) {
        assert_relative_eq!(s, 1.1, max_relative = 1e-6);
    }
    for s in vertex_strain(&t, &p, &scaled, StrainMeasure::AreaStretch) {
        assert_relative_eq!(s, 1.21, max_relative = 1e-6);
    }
}

#[test]
fn strain_is_one_under_rigid_motion() {
    let (p, t) = cube();
    let q = Quat::from_axis_angle(Vec3::new(1.0, 2.0, 3.0).normalize(), 0.7);
    let moved: Vec<Vec3> = p
        .iter()
        .map(|v| q * *v + Vec3::new(5.0, -2.0, 1.0))
        .collect();
    for m in [
        StrainMeasure::MaxPrincipalStretch,
        StrainMeasure::AreaStretch,
    ] {
        for s in vertex_strain(&t, &p, &moved, m) {
            assert_relative_eq!(s, 1.0, max_relative = 1e-5);
        }
    }
}

#[test]
fn strain_of_biaxial_stretch_and_shear_match_closed_forms() {
    let (p, t) = grid(5);
    let pulled: Vec<Vec3> = p
        .iter()
        .map(|v| Vec3::new(1.5 * v.x, 0.8 * v.y, 0.0))
        .collect();
    for s in vertex_strain(&t, &p, &pulled, StrainMeasure::MaxPrincipalStretch) {
        assert_relative_eq!(s, 1.5, max_relative = 1e-6);
    }
    for s in vertex_strain(&t, &p, &pulled, StrainMeasure::AreaStretch) {
        assert_relative_eq!(s, 1.2, max_relative = 1e-6);
    }
    // Simple shear x += γ y preserves area; λ_max = γ/2 + sqrt(1 + γ²/4).
    let gamma = 0.5f32;
    let sheared: Vec<Vec3> = p
        .iter()
        .map(|v| Vec3::new(v.x + gamma * v.y, v.y, 0.0))
        .collect();
    let expected = gamma / 2.0 + (1.0 + gamma * gamma / 4.0).sqrt();
    for s in vertex_strain(&t, &p, &sheared, StrainMeasure::MaxPrincipalStretch) {
        assert_relative_eq!(s, expected, max_relative = 1e-6);
    }
    for s in vertex_strain(&t, &p, &sheared, StrainMeasure::AreaStretch) {
        assert_relative_eq!(s, 1.0, max_relative = 1e-6);
    }
}

#[test]
fn color_map_is_linear_between_blue_white_red() {
    let map = StrainColorMap {
        measure: StrainMeasure::AreaStretch,
        range: 0.5,
    };
    assert_eq!(map.color(1.25), [1.0, 0.5, 0.5]);
    assert_eq!(map.color(0.75), [0.5, 0.5, 1.0]);
    assert_eq!(map.color(f32::NAN), [1.0, 1.0, 1.0]);
    assert_eq!(geometry::to_u8([1.0, 0.5, 0.0]), [255, 128, 0]);
}

fn meta() -> ExportMeta {
    let (p, t) = grid(3);
    let (bp, bt) = cube();
    ExportMeta::new(
        vec![
            MeshMeta::new("sheet", MeshRole::Skin, t, p),
            MeshMeta::new("ulna", MeshRole::Bone, bt, bp),
        ],
        30.0,
    )
}

#[test]
fn staging_selects_skin_unless_colliders_are_wanted() {
    let m = meta();
    let skin_only = Staged::new(&m, &ExportOptions::default()).unwrap();
    assert_eq!(skin_only.selected, vec![0]);
    let all = ExportOptions {
        with_colliders: true,
        ..ExportOptions::default()
    };
    assert_eq!(Staged::new(&m, &all).unwrap().selected, vec![0, 1]);
    let bones_only = ExportMeta::new(vec![m.meshes[1].clone()], 30.0);
    assert!(matches!(
        Staged::new(&bones_only, &ExportOptions::default()),
        Err(ExportError::NoMeshes { .. })
    ));
}

#[test]
fn staging_rejects_bad_metadata_naming_the_item() {
    let mut m = meta();
    m.fps = 0.0;
    assert!(matches!(
        Staged::new(&m, &ExportOptions::default()),
        Err(ExportError::InvalidFps { .. })
    ));
    let mut m = meta();
    m.meshes[0].triangles[3] = [0, 1, 99];
    let err = Staged::new(&m, &ExportOptions::default()).unwrap_err();
    assert!(matches!(
        &err,
        ExportError::IndexOutOfRange { mesh, triangle: 3, index: 99, vertex_count: 9 } if mesh == "sheet"
    ));
    assert!(err.to_string().contains("triangle 3"), "{err}");
    let mut m = meta();
    m.meshes[0].rest_positions[4].y = f32::NAN;
    let err = Staged::new(&m, &ExportOptions::default()).unwrap_err();
    assert!(matches!(
        err,
        ExportError::NonFinite {
            frame: None,
            vertex: 4,
            ..
        }
    ));
    assert!(err.to_string().contains("rest pose"), "{err}");
}

#[test]
fn frames_are_checked_for_count_order_and_finiteness() {
    let m = meta();
    let mut s = Staged::new(&m, &ExportOptions::default()).unwrap();
    let skin = m.meshes[0].rest_positions.clone();
    let bone = m.meshes[1].rest_positions.clone();
    assert!(matches!(
        s.frame(0, &[&skin]),
        Err(ExportError::MeshCount {
            frame: 0,
            expected: 2,
            found: 1
        })
    ));
    let short = &skin[..5];
    assert!(matches!(
        s.frame(0, &[short, &bone]),
        Err(ExportError::VertexCount {
            frame: 0,
            expected: 9,
            found: 5,
            ..
        })
    ));
    let mut inf = skin.clone();
    inf[7].x = f32::INFINITY;
    let err = s.frame(0, &[&inf, &bone]).unwrap_err();
    assert!(matches!(
        err,
        ExportError::NonFinite {
            frame: Some(0),
            vertex: 7,
            ..
        }
    ));
    assert!(err.to_string().contains("frame 0") && err.to_string().contains("sheet"));
    // A collider that is not exported is still counted but not checked for finiteness.
    let mut bad_bone = bone.clone();
    bad_bone[0].z = f32::NAN;
    assert_eq!(s.frame(3, &[&skin, &bad_bone]).unwrap().len(), 1);
    assert!(matches!(
        s.frame(3, &[&skin, &bone]),
        Err(ExportError::FrameOrder {
            frame: 3,
            previous: 3
        })
    ));
}

#[test]
fn sequence_names_are_zero_padded() {
    let p = sequence_path(Path::new("out/arm.obj"), 12, 6, "obj");
    assert_eq!(p, Path::new("out/arm_000012.obj"));
    let p = sequence_path(Path::new("arm.ply"), 1_234_567, 4, "ply");
    assert_eq!(p, Path::new("arm_1234567.ply"));
    assert_eq!(parent_dir(Path::new("arm.glb")), Path::new("."));
    assert_eq!("USDA".parse::<Format>().unwrap(), Format::Usda);
    assert!("fbx".parse::<Format>().is_err());
}

#[test]
fn checkpoint_round_trips_bits_exactly() {
    let mut c = Checkpoint::new(41);
    let odd = [
        f32::from_bits(0x7fc0_1234), // NaN with payload
        -0.0,
        f32::MIN_POSITIVE / 8.0, // subnormal
        f32::INFINITY,
        0.1,
    ];
    c.push("odd", odd.to_vec());
    c.push_vec3("skin/positions", &[Vec3::new(1.0, 2.0, 3.0), Vec3::NEG_ONE]);
    c.push("empty", Vec::new());
    let bytes = c.to_bytes();
    let back = Checkpoint::from_bytes(&bytes, Path::new("c")).unwrap();
    assert_eq!(back.frame, 41);
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(back.get("odd").unwrap()), bits(&odd));
    assert_eq!(
        back.get_vec3("skin/positions").unwrap(),
        vec![Vec3::new(1.0, 2.0, 3.0), Vec3::NEG_ONE]
    );
    assert_eq!(back.get("empty"), Some(&[][..]));

    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("state.ckpt");
    c.write(&path).unwrap();
    assert_eq!(std::fs::read(&path).unwrap(), bytes);
    assert_eq!(
        std::fs::read_dir(dir.path()).unwrap().count(),
        1,
        "no temp file left"
    );
}

#[test]
fn damaged_checkpoints_are_rejected() {
    let mut c = Checkpoint::new(3);
    c.push("x", vec![1.0, 2.0]);
    let good = c.to_bytes();
    let path = Path::new("run/state.ckpt");
    let reason = |bytes: &[u8]| match Checkpoint::from_bytes(bytes, path) {
        Err(ExportError::BadCheckpoint { path: p, reason }) => {
            assert_eq!(p, path);
            reason
        }
        other => panic!("expected BadCheckpoint, got {other:?}"),
    };
    for cut in [0, 7, 12, good.len() - 1] {
        assert!(!reason(&good[..cut]).is_empty());
    }
    let mut trailing = good.clone();
    trailing.push(0);
    assert!(reason(&trailing).contains("trailing"));
    let mut version = good.clone();
    version[8] = 9;
    assert!(reason(&version).contains("version 9"));
    let mut magic = good.clone();
    magic[0] = b'X';
    assert!(reason(&magic).contains("magic"));
    let mut huge = good;
    let at = 8 + 4 + 4 + 4 + 4 + 1; // count of the first array
    huge[at..at + 8].copy_from_slice(&u64::MAX.to_le_bytes());
    assert!(reason(&huge).contains("claims"));
}

#[test]
fn a_failed_atomic_write_leaves_the_old_file_and_no_temporary() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("frame.obj");
    std::fs::write(&path, b"complete old frame").unwrap();
    let err = write_atomic(&path, |w| {
        use std::io::Write as _;
        w.write_all(b"half a fra")?;
        Err(std::io::Error::other("disk full"))
    })
    .unwrap_err();
    assert!(
        matches!(&err, ExportError::Io { path: p, .. } if *p == path),
        "{err:?}"
    );
    assert!(err.to_string().contains("frame.obj"));
    assert_eq!(std::fs::read(&path).unwrap(), b"complete old frame");
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
}
