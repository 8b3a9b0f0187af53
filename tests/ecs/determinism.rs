//! Determinism golden test: positions after 200 frames of a fixed scene hash to a committed
//! constant, whatever the thread count (run with `RAYON_NUM_THREADS=1` and `=2`).

use dermis::ecs::*;
use dermis::stiffness::{Modulus, StiffnessRule};
use glam::Vec3;

use super::{sheet, world_with};

/// The committed hash. If a change to the solver or the systems alters the result on purpose,
/// run `cargo test --test main ecs::determinism -- --nocapture`, check the new behaviour is
/// right, and paste the hash it prints here (and say so in the commit message).
const GOLDEN: u64 = 0x42b3_c71a_c3ed_9ed3;

/// 64-bit FNV-1a over the little-endian bits of every coordinate.
fn fnv1a(positions: &[Vec3]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for p in positions {
        for c in p.to_array() {
            for byte in c.to_bits().to_le_bytes() {
                h ^= u64::from(byte);
                h = h.wrapping_mul(0x0000_0100_0000_01b3);
            }
        }
    }
    h
}

fn ripple(p: Vec3, frame: u32) -> Vec3 {
    let t = frame as f32 * 0.05;
    p + Vec3::new(
        0.05 * (t + 3.0 * p.y).sin() * p.x,
        0.0,
        0.04 * (2.0 * t + 5.0 * p.x).sin(),
    )
}

#[test]
fn positions_after_200_frames_match_the_golden_hash() {
    let (mut world, mut schedule) = world_with(ripple);
    let mut skins = Vec::new();
    // An anchored skin following the ripple.
    skins.push(
        SkinBuilder::new(sheet(16), SkinMaterial::default())
            .with_rest_anchors(60.0, 6.0)
            .spawn(&mut world)
            .unwrap(),
    );
    // A hanging skin: top row pinned, a downward load on every vertex, Poisson rule,
    // per-triangle modulus.
    let n = 12;
    let mesh = sheet(n);
    let e2 = (0..mesh.triangles().len())
        .map(|t| 800.0 + 10.0 * (t % 7) as f32)
        .collect();
    skins.push(
        SkinBuilder::new(
            mesh,
            SkinMaterial::default().with_youngs_2d(Modulus::PerElement(e2)),
        )
        .with_stiffness_rule(StiffnessRule::poisson(0.3))
        .with_pinned((0..n).map(|i| (n - 1) * n + i))
        .with_forces(vec![Vec3::new(0.0, -0.05, -0.02); (n * n) as usize])
        .spawn(&mut world)
        .unwrap(),
    );
    for _ in 0..200 {
        schedule.run(&mut world);
    }
    let mut all = Vec::new();
    for &s in &skins {
        let d = world.get::<RelaxDiagnostics>(s).unwrap();
        assert!(d.quarantined.is_empty() && d.stop.is_some(), "{d:?}");
        all.extend_from_slice(skin_positions(&world, s).unwrap());
    }
    let hash = fnv1a(&all);
    println!("determinism hash: {hash:#018x}");
    assert_eq!(
        hash, GOLDEN,
        "positions after 200 frames changed (hash {hash:#018x}). If that is intended, update \
         GOLDEN in tests/ecs/determinism.rs (see its doc comment)"
    );
}
