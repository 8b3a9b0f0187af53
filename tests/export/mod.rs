//! Export writers: files read back with independent readers (gltf crate, tobj, a PLY header
//! parser, USD text and optionally Pixar's USD) match the frames given.

mod failures;
mod formats;
mod job;

use std::path::{Path, PathBuf};

use dermis::export::{ExportMeta, FrameSequence, MeshMeta, MeshRole};
use glam::Vec3;

/// Frame rate of the test clip.
const FPS: f32 = 30.0;
/// First frame index (not 0, so time codes and names are checked against the real index).
const FIRST: u32 = 10;
/// Flat frames: frame `FIRST + k` for k < FLAT is the rest sheet scaled by `1 + 0.1 k` in x and
/// y, so its normals are +Z and its principal stretch is exactly `1 + 0.1 k`.
const FLAT: u32 = 4;
/// Total frames.
const FRAMES: u32 = 7;

/// Scale of flat frame `k` (relative to `FIRST`).
fn flat_scale(k: u32) -> f32 {
    1.0 + 0.1 * k as f32
}

/// Flat `nx × ny` grid in the xy plane, spacing 0.1 m, counter-clockwise seen from +Z.
fn sheet(nx: u32, ny: u32) -> (Vec<Vec3>, Vec<[u32; 3]>) {
    let p = (0..nx * ny)
        .map(|i| Vec3::new(0.1 * (i % nx) as f32, 0.1 * (i / nx) as f32, 0.0))
        .collect();
    (p, dermis::mesh::shapes::grid_triangles(nx, ny))
}

/// A closed tetrahedron standing in for a bone.
fn bone() -> (Vec<Vec3>, Vec<[u32; 3]>) {
    let p = vec![
        Vec3::new(0.0, 0.0, -0.2),
        Vec3::new(0.3, 0.0, -0.2),
        Vec3::new(0.0, 0.3, -0.2),
        Vec3::new(0.0, 0.0, 0.1),
    ];
    (p, vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
}

/// The test clip: a 6 × 5 skin sheet (flat scaled frames, then a travelling wave) and a bone
/// that translates.
fn clip() -> FrameSequence {
    let (skin, skin_t) = sheet(6, 5);
    let (bone, bone_t) = bone();
    let mut seq = FrameSequence::new(ExportMeta::new(
        vec![
            MeshMeta::new("sheet", MeshRole::Skin, skin_t, skin.clone()),
            MeshMeta::new("ulna", MeshRole::Bone, bone_t, bone.clone()),
        ],
        FPS,
    ));
    for k in 0..FRAMES {
        let s: Vec<Vec3> = if k < FLAT {
            skin.iter()
                .map(|p| Vec3::new(flat_scale(k) * p.x, flat_scale(k) * p.y, 0.0))
                .collect()
        } else {
            skin.iter()
                .map(|p| Vec3::new(p.x, p.y, 0.05 * (10.0 * p.x + k as f32).sin()))
                .collect()
        };
        let b = bone
            .iter()
            .map(|p| *p + Vec3::new(0.01 * k as f32, 0.0, 0.0))
            .collect();
        seq.push(FIRST + k, vec![s, b]);
    }
    seq
}

/// Files in `dir`, sorted by name.
fn listing(dir: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    v.sort();
    v
}

/// Asserts `got` equals `want` up to the rounding of `base + (want - base)` in f32.
fn assert_reconstructed(got: Vec3, want: Vec3, base: Vec3, what: &str) {
    for c in 0..3 {
        let tol = 2.0 * f32::EPSILON * (want[c].abs() + base[c].abs()) + f32::MIN_POSITIVE;
        assert!(
            (got[c] - want[c]).abs() <= tol,
            "{what}: component {c}: {} vs {} (tolerance {tol})",
            got[c],
            want[c]
        );
    }
}
