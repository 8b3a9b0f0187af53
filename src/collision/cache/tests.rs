use glam::{Quat, Vec3};
use parry3d::math::Pose;
use parry3d::query::PointQuery;

use super::*;
use crate::collision::shapes::ellipsoid;
use crate::collision::tests::Lcg;
use crate::collision::{ColliderId, ContactConfig, SkinCollision};

/// A lumpy closed surface: an ellipsoid with a crease-like dent (non-convex, so nearest
/// triangles jump between distant parts of the mesh for some points).
fn lumpy(phase: f32, v: &[Vec3]) -> Vec<Vec3> {
    v.iter()
        .map(|p| {
            let bulge = 1.0 + 0.2 * (5.0 * p.z + phase).sin() * (4.0 * p.x).cos();
            let dent = 1.0 - 0.5 * (-(p.y * p.y) * 60.0).exp();
            Vec3::new(p.x * bulge * dent, p.y * bulge, p.z)
        })
        .collect()
}

/// Points scattered around the surface: most within a few thicknesses of it, some inside.
fn near_surface(v: &[Vec3], rng: &mut Lcg, count: usize, spread: f32) -> Vec<Vec3> {
    (0..count)
        .map(|k| {
            let p = v[(k * 7919) % v.len()];
            p + p.normalize_or_zero() * spread * (rng.next() * 2.0 - 0.6)
                + rng.point(1.0) * 0.3 * spread
        })
        .collect()
}

/// Compares one cached answer with parry's full search (and the uncached reference for the
/// inside flag, which parry's non-oriented mesh does not give).
fn assert_same(col: &ColliderMesh, local: Vec3, got: &SurfaceProjection, what: &str) {
    let parry = col.parry_mesh().unwrap();
    let naive = parry.project_point(&Pose::IDENTITY, local, false);
    let reference = col.project_local(local, NONE);
    let dist = naive.point.distance(local);
    assert!(
        (got.signed_distance.abs() - dist).abs() <= 1e-6 * (1.0 + dist),
        "{what}: distance {} vs parry {dist} at {local}",
        got.signed_distance
    );
    // The same point, or (far from the surface, where two triangles' feet can be within
    // rounding of the same distance) another surface point exactly as close.
    let on_surface = parry
        .project_point(&Pose::IDENTITY, got.point, false)
        .point
        .distance(got.point);
    assert!(
        got.point.distance(naive.point) < 1e-6
            || (on_surface < 1e-6
                && (got.point.distance(local) - dist).abs() <= 1e-6 * (1.0 + dist)),
        "{what}: point {} vs parry {} at {local}",
        got.point,
        naive.point
    );
    assert_eq!(
        got.signed_distance < 0.0,
        reference.signed_distance < 0.0,
        "{what}: inside flag at {local}"
    );
}

/// Many passes per frame with small motion, over deforming frames: every answer, certified or
/// searched, is parry's closest point; and most answers come from certificates.
#[test]
fn certified_answers_equal_parry_over_deforming_frames_and_passes() {
    let (v, t) = ellipsoid(Vec3::ZERO, Vec3::new(0.3, 0.2, 0.25), 24, 36).unwrap();
    let mut col = ColliderMesh::from_mesh(lumpy(0.0, &v), t).unwrap();
    let mut rng = Lcg(5);
    let mut points = near_surface(&v, &mut rng, 1500, 0.03);
    let mut slots = vec![(Slot::NEW, Patch::NEW); points.len()];
    let (mut certified, mut searched) = (0u32, 0u32);
    for frame in 0..6 {
        col.set_vertices(&lumpy(0.15 * frame as f32, &v)).unwrap();
        let travel = col.travel_m();
        for pass in 0..20 {
            // A converging relaxation: steps shrink pass after pass.
            let step = 0.004 * 0.8f32.powi(pass);
            for (i, (p, slot)) in points.iter_mut().zip(&mut slots).enumerate() {
                *p += rng.point(1.0) * step;
                let (got, answer) = slot.0.project(&mut slot.1, &col, *p, travel, 0.02);
                match answer {
                    Answer::Certified => certified += 1,
                    Answer::Searched { .. } => searched += 1,
                }
                assert_same(
                    &col,
                    *p,
                    &got,
                    &format!("frame {frame} pass {pass} point {i}"),
                );
            }
        }
    }
    assert!(
        certified > 3 * searched,
        "certified {certified}, searched {searched}"
    );
}

/// Points sweeping steadily across and through the surface (their certificates must expire),
/// and a rigid mesh moved by its pose (travel from pose changes): still parry's answers.
#[test]
fn certificates_expire_under_sweeping_motion_and_pose_changes() {
    let (v, t) = ellipsoid(Vec3::ZERO, Vec3::new(0.3, 0.2, 0.25), 16, 24).unwrap();
    let mut col = ColliderMesh::from_mesh(lumpy(0.4, &v), t).unwrap();
    let mut rng = Lcg(9);
    let starts = near_surface(&v, &mut rng, 400, 0.05);
    let dirs: Vec<Vec3> = starts.iter().map(|_| rng.point(1.0) * 0.01).collect();
    let mut slots = vec![(Slot::NEW, Patch::NEW); starts.len()];
    let mut searched_later = 0;
    for step in 0..60 {
        let angle = 0.01 * step as f32;
        let pose = Pose::from_parts(
            Vec3::new(0.001 * step as f32, 0.0, 0.0),
            Quat::from_rotation_z(angle),
        );
        col.set_pose(pose).unwrap();
        let travel = col.travel_m();
        for (i, ((s, d), slot)) in starts.iter().zip(&dirs).zip(&mut slots).enumerate() {
            let world = *s + *d * step as f32;
            let local = pose.inverse_transform_point(world);
            let (got, answer) = slot.0.project(&mut slot.1, &col, local, travel, 0.01);
            if step > 0 && matches!(answer, Answer::Searched { .. }) {
                searched_later += 1;
            }
            assert_same(&col, local, &got, &format!("step {step} point {i}"));
        }
    }
    // 1 cm per step sweeps every point across many triangles: certificates must have failed.
    assert!(searched_later > 1000, "{searched_later}");
}

/// Whole contact passes with certificates give the positions of passes that search every
/// query afresh, over deforming frames of a relaxation-like sequence of passes.
#[test]
fn cached_frames_equal_fresh_searches_and_use_certificates() {
    let (v, t) = ellipsoid(Vec3::ZERO, Vec3::new(0.3, 0.2, 0.25), 20, 30).unwrap();
    let mut rng = Lcg(3);
    let points = near_surface(&v, &mut rng, 1200, 0.02);
    let n = points.len();
    let config = ContactConfig {
        thickness_m: 0.01,
        ..ContactConfig::DEFAULT
    };
    let mut cached = SkinCollision::new(n, config).unwrap();
    let mut fresh = SkinCollision::new(n, config).unwrap();
    for s in [&mut cached, &mut fresh] {
        s.add_collider(ColliderMesh::from_mesh(lumpy(0.0, &v), t.clone()).unwrap());
    }
    let (mut xa, mut xb) = (points.clone(), points);
    let mut certified = 0;
    for frame in 0..4 {
        let d = lumpy(0.1 * frame as f32, &v);
        for s in [&mut cached, &mut fresh] {
            s.collider_mut(ColliderId(0))
                .unwrap()
                .set_vertices(&d)
                .unwrap();
        }
        cached.begin_frame(&mut xa.clone()).unwrap();
        for pass in 0..25 {
            let step = 0.002 * 0.85f32.powi(pass);
            for (i, (a, b)) in xa.iter_mut().zip(&mut xb).enumerate() {
                let m = Vec3::new(
                    ((i * 13 + pass as usize) as f32).sin(),
                    ((i * 7 + 3 * pass as usize) as f32).cos(),
                    ((i + 5 * pass as usize) as f32).sin(),
                ) * step;
                *a += m;
                *b += m;
            }
            cached.contact_pass(&mut xa).unwrap();
            fresh.clear_cache();
            fresh.contact_pass(&mut xb).unwrap();
            let max = xa
                .iter()
                .zip(&xb)
                .map(|(a, b)| a.distance(*b))
                .fold(0.0f32, f32::max);
            assert!(max < 1e-6, "frame {frame} pass {pass}: differs by {max}");
        }
        certified += cached.diagnostics().certified_queries;
        let d = cached.diagnostics();
        assert!(d.passes == 25, "{d:?}");
    }
    // A cleared cache only certifies the re-checks of vertices pushed in the same pass.
    assert!(certified > 10 * fresh.diagnostics().certified_queries.max(1));
}

#[test]
fn slots_pack_two_per_cache_line() {
    // The bound read by every pass is the whole slot (its patch lives apart): 32 bytes, 32-byte
    // aligned, so two slots share each 64-byte line of a Vec and none straddles two.
    assert_eq!(std::mem::align_of::<Slot>(), 32);
    assert_eq!(std::mem::size_of::<Slot>(), 32);
}
