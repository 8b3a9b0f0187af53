use glam::{Quat, Vec3};
use parry3d::math::Pose;
use parry3d::query::PointQuery;
use parry3d::shape::{TriMesh as ParryMesh, TriMeshFlags};

use super::*;
use crate::mesh::TriMesh;
use crate::solver::{Loads, RelaxConfig, RelaxReport, SpringSystem, StopReason, VertexAnchor};
use crate::stiffness::{Modulus, StiffnessRule};

/// A flat `n` x `n` sheet of side `size` centred on (0, 0, z).
fn sheet(n: u32, size: f32, z: f32) -> TriMesh {
    let mut p = Vec::new();
    for j in 0..n {
        for i in 0..n {
            let u = i as f32 / (n - 1) as f32 - 0.5;
            let v = j as f32 / (n - 1) as f32 - 0.5;
            p.push(Vec3::new(u * size, v * size, z));
        }
    }
    TriMesh::new(p, crate::mesh::shapes::grid_triangles(n, n)).unwrap()
}

/// An open tube along x: `rings` rings of `around` vertices, from `x0` to `x1`.
fn tube(around: u32, rings: u32, radius: f32, x0: f32, x1: f32) -> TriMesh {
    let mut p = Vec::new();
    for j in 0..rings {
        let x = x0 + (x1 - x0) * j as f32 / (rings - 1) as f32;
        for i in 0..around {
            let a = std::f32::consts::TAU * i as f32 / around as f32;
            p.push(Vec3::new(x, radius * a.cos(), radius * a.sin()));
        }
    }
    let mut t = Vec::new();
    for j in 0..rings - 1 {
        for i in 0..around {
            let (a, b) = (j * around + i, j * around + (i + 1) % around);
            let (c, d) = (a + around, b + around);
            t.push([a, b, d]);
            t.push([a, d, c]);
        }
    }
    TriMesh::new(p, t).unwrap()
}

fn springs(mesh: &TriMesh) -> SpringSystem {
    let k = StiffnessRule::AreaOverLengthSquared
        .edge_stiffness(mesh, &Modulus::Uniform(1000.0))
        .unwrap();
    SpringSystem::from_mesh(mesh, &k).unwrap()
}

/// One frame: the contact's substeps, each followed by `iterations` of relaxation.
fn frame(
    contact: &mut SkinCollision,
    system: &SpringSystem,
    x: &mut [Vec3],
    loads: &Loads<'_>,
    iterations: u32,
) {
    let plan = contact.begin_frame(x).unwrap();
    for _ in 0..plan.substeps {
        contact.substep(x).unwrap();
        system
            .relax_projected(x, loads, &budget(iterations), Some(&mut *contact))
            .unwrap();
        assert!(contact.diagnostics().unresolved.is_empty());
    }
}

fn budget(iterations: u32) -> RelaxConfig {
    RelaxConfig {
        max_iterations: iterations,
        tolerance: 1e-7,
        ..RelaxConfig::DEFAULT
    }
}

/// Deterministic pseudo-random numbers in [0, 1) (also used by the cache's tests).
pub(super) struct Lcg(pub(super) u64);
impl Lcg {
    pub(super) fn next(&mut self) -> f32 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (self.0 >> 40) as f32 / (1u64 << 24) as f32
    }
    /// A point of the cube `[-half, half]³`.
    pub(super) fn point(&mut self, half: f32) -> Vec3 {
        Vec3::new(self.next(), self.next(), self.next()) * (2.0 * half) - Vec3::splat(half)
    }
}

fn blob(n_lat: u32, n_lon: u32) -> (Vec<Vec3>, Vec<[u32; 3]>) {
    shapes::ellipsoid(
        Vec3::new(0.01, -0.02, 0.03),
        Vec3::new(0.3, 0.2, 0.25),
        n_lat,
        n_lon,
    )
    .unwrap()
}

/// A smooth non-convex deformation of the blob: a travelling bulge and a dent.
fn deform(v: &[Vec3], phase: f32) -> Vec<Vec3> {
    v.iter()
        .map(|p| {
            let bulge = 1.0 + 0.15 * (4.0 * p.x + phase).sin() * (3.0 * p.y).cos();
            Vec3::new(
                p.x,
                p.y * bulge,
                p.z * (1.0 - 0.3 * (-(p.x * p.x) * 40.0).exp()),
            )
        })
        .collect()
}

#[test]
fn holes_flips_and_inside_out_meshes_are_rejected_with_the_culprit_named() {
    let (v, t) = blob(6, 8);
    let mut holed = t.clone();
    let removed = holed.remove(5);
    let err = ColliderMesh::from_mesh(v.clone(), holed).unwrap_err();
    let CollisionError::Hole { a, b, .. } = err else {
        panic!("expected a hole, got {err}");
    };
    assert!(removed.contains(&a) && removed.contains(&b));
    assert!(err.to_string().contains("hole"));

    let mut flipped = t.clone();
    flipped[7].swap(1, 2);
    let err = ColliderMesh::from_mesh(v.clone(), flipped).unwrap_err();
    let CollisionError::InconsistentWinding { first, second, .. } = err else {
        panic!("expected inconsistent winding, got {err}");
    };
    assert!(first == 7 || second == 7, "{err}");

    let inside_out: Vec<[u32; 3]> = t.iter().map(|&[a, b, c]| [a, c, b]).collect();
    let err = ColliderMesh::from_mesh(v.clone(), inside_out).unwrap_err();
    let CollisionError::InsideOut { volume_m3 } = err else {
        panic!("expected inside out, got {err}");
    };
    // The ellipsoid's volume, 4/3 π abc, up to the polyhedral approximation.
    let exact = 4.0 / 3.0 * std::f64::consts::PI * 0.3 * 0.2 * 0.25;
    assert!(
        volume_m3 < -0.5 * exact && volume_m3 > -exact,
        "{volume_m3}"
    );
    assert!(err.to_string().contains("swap"));

    assert!(ColliderMesh::capsule(Vec3::ZERO, Vec3::X, -1.0).is_err());
    assert!(ColliderMesh::from_mesh(v, t).is_ok());
}

/// The sign from feature normals matches parry's own pseudo-normal test on an `ORIENTED` mesh
/// (an independent implementation), and distances and closest points match parry's.
#[test]
fn signed_distance_matches_parry_oriented_mesh_before_and_after_deformation() {
    let (v, t) = blob(14, 20);
    let mut collider = ColliderMesh::from_mesh(v.clone(), t.clone()).unwrap();
    let mut rng = Lcg(7);
    for phase in [None, Some(0.4), Some(2.0)] {
        let verts = match phase {
            None => v.clone(),
            Some(ph) => {
                let d = deform(&v, ph);
                collider.set_vertices(&d).unwrap();
                d
            }
        };
        let oriented = ParryMesh::with_flags(verts, t.clone(), TriMeshFlags::ORIENTED).unwrap();
        let mut inside = 0;
        for _ in 0..3000 {
            let p = rng.point(0.4);
            let ours = collider.project_point(p);
            let theirs = oriented.project_point(&Pose::IDENTITY, p, false);
            let dist = theirs.point.distance(p);
            assert!(
                (ours.signed_distance.abs() - dist).abs() < 1e-6,
                "{p} {phase:?}"
            );
            // Near-ties may pick another closest point at the same distance.
            assert!(ours.point.distance(theirs.point) < 1e-4, "{p} {phase:?}");
            if dist > 1e-5 {
                assert_eq!(ours.signed_distance < 0.0, theirs.is_inside, "{p}");
            }
            inside += theirs.is_inside as u32;
        }
        assert!(
            inside > 300,
            "the sample must probe the inside too ({inside})"
        );
    }
}

/// A cached triangle, however stale, gives the same closest point as the naive query.
#[test]
fn cached_queries_equal_naive_project_point() {
    let (v, t) = blob(20, 30);
    let mut collider = ColliderMesh::from_mesh(v.clone(), t.clone()).unwrap();
    let mut rng = Lcg(11);
    let points: Vec<Vec3> = (0..2000).map(|_| rng.point(0.4)).collect();
    let mut hints: Vec<u32> = points
        .iter()
        .map(|p| collider.project_point(*p).part)
        .collect();
    for frame in 0..6 {
        let d = deform(&v, 0.3 * frame as f32);
        collider.set_vertices(&d).unwrap();
        let parry = collider.parry_mesh().unwrap();
        for (p, hint) in points.iter().zip(&mut hints) {
            let naive = parry.project_point(&Pose::IDENTITY, *p, false);
            let cached = collider.project_local(*p, *hint);
            assert!(
                (cached.signed_distance.abs() - naive.point.distance(*p)).abs() < 1e-7,
                "frame {frame} point {p}"
            );
            assert!(cached.point.distance(naive.point) < 1e-6);
            *hint = cached.part;
        }
        // Stale and even wrong hints must not change the answer.
        let wrong = collider.project_local(points[0], (frame * 97) as u32 % t.len() as u32);
        assert!(
            wrong
                .point
                .distance(collider.project_point(points[0]).point)
                < 1e-6
        );
    }

    // Whole passes: with the cache and bounds, the same positions as with no cache at all.
    let n = points.len();
    let config = ContactConfig {
        thickness_m: 0.01,
        ..ContactConfig::DEFAULT
    };
    let mut cached = SkinCollision::new(n, config).unwrap();
    let mut naive = SkinCollision::new(n, config).unwrap();
    for s in [&mut cached, &mut naive] {
        s.add_collider(ColliderMesh::from_mesh(v.clone(), t.clone()).unwrap());
    }
    // A shuffled solver order: projections run on the solver's order, caller-order passes
    // (the frames) in between must see the same state.
    let mut order: Vec<u32> = (0..n as u32).collect();
    for i in (1..n).rev() {
        let j = (rng.next() * (i + 1) as f32) as usize;
        order.swap(i, j.min(i));
    }
    let to_solver = |x: &[Vec3]| -> Vec<Vec3> { order.iter().map(|&o| x[o as usize]).collect() };
    let (mut xa, mut xb) = (points.clone(), points.clone());
    for frame in 0..5 {
        let d = deform(&v, 0.05 * frame as f32);
        for s in [&mut cached, &mut naive] {
            s.collider_mut(ColliderId(0))
                .unwrap()
                .set_vertices(&d)
                .unwrap();
        }
        cached.advance_frame(&mut xa).unwrap();
        naive.clear_cache();
        naive.advance_frame(&mut xb).unwrap();
        // The frame plan skips pairs on cached bounds: the same split as with exact queries.
        assert_eq!(
            cached.diagnostics().substeps,
            naive.diagnostics().substeps,
            "frame {frame}"
        );
        for k in 0..3 {
            // Jiggle the skin like a solver step would.
            for (i, (a, b)) in xa.iter_mut().zip(&mut xb).enumerate() {
                let step = 0.002 * ((i * 7 + k) as f32).sin();
                *a += Vec3::splat(step);
                *b += Vec3::splat(step);
            }
            let (mut ia, mut ib) = (to_solver(&xa), to_solver(&xb));
            cached.project(&mut ia, &order);
            naive.clear_cache();
            naive.project(&mut ib, &order);
            for (i, &o) in order.iter().enumerate() {
                (xa[o as usize], xb[o as usize]) = (ia[i], ib[i]);
            }
            // Vertices skipped whole on their reserve touch exactly what a full query finds.
            let (ca, cb) = (cached.active_contacts(), naive.active_contacts());
            assert_eq!(ca.len(), cb.len(), "frame {frame} pass {k}");
            for (a, b) in ca.iter().zip(cb) {
                assert_eq!(a.vertex, b.vertex);
                assert!(a.normal.distance(b.normal) < 1e-5);
            }
        }
        let max = xa
            .iter()
            .zip(&xb)
            .map(|(a, b)| a.distance(*b))
            .fold(0.0f32, f32::max);
        assert!(max < 1e-6, "frame {frame}: cached pass differs by {max}");
    }
    let d = cached.diagnostics();
    assert!(
        d.skipped_bound + d.skipped_aabb > 0 && d.cache_hits > 0 && d.skipped_vertices > 0,
        "{d:?}"
    );
}

#[test]
fn sheet_draped_over_a_sphere_rests_at_the_thickness() {
    let (r, centre, h) = (0.3, Vec3::new(0.0, 0.0, -0.2), 0.01);
    let (v, t) = shapes::ellipsoid(centre, Vec3::splat(r), 30, 48).unwrap();
    let oriented = ParryMesh::with_flags(v.clone(), t.clone(), TriMeshFlags::ORIENTED).unwrap();
    let mesh = sheet(21, 1.0, 0.0);
    let system = springs(&mesh);
    let n = mesh.positions().len();
    let pinned: Vec<bool> = mesh
        .positions()
        .iter()
        .map(|p| p.x.abs() > 0.49 || p.y.abs() > 0.49)
        .collect();
    let config = ContactConfig {
        thickness_m: h,
        ..ContactConfig::DEFAULT
    };
    let mut contact = SkinCollision::new(n, config).unwrap();
    contact.add_collider(ColliderMesh::from_mesh(v, t).unwrap());
    let mut x = mesh.positions().to_vec();
    contact.advance_frame(&mut x).unwrap();
    let loads = Loads {
        pinned: Some(&pinned),
        ..Default::default()
    };
    system
        .relax_projected(&mut x, &loads, &budget(600), Some(&mut contact))
        .unwrap();
    assert!(contact.diagnostics().unresolved.is_empty());
    let mut touching = 0;
    for (i, p) in x.iter().enumerate() {
        let proj = oriented.project_point(&Pose::IDENTITY, *p, false);
        let d = proj.point.distance(*p);
        assert!(!proj.is_inside, "vertex {i} inside");
        assert!(d > h - 1e-5, "vertex {i} at {d}, thickness {h}");
        // The sphere's cap pokes 0.1 through the sheet's plane: the middle must lie on it.
        let radial = (p.x * p.x + p.y * p.y).sqrt();
        if radial < 0.1 {
            assert!((d - h).abs() < 1e-4, "central vertex {i} at {d}, not {h}");
            touching += 1;
        }
    }
    assert!(touching >= 9, "{touching}");
}

proptest::proptest! {
    /// A pair the plan skips as covered by the largest motion so far never asks for more
    /// substeps than that motion does, at the boundaries between counts too.
    #[test]
    fn motions_the_plan_skips_ask_for_no_more_substeps(
        step in 1e-6f32..1e-1,
        k in 0u32..40,
        nudge in -1e-5f32..1e-5,
        fraction in 0.0f32..=1.0,
    ) {
        // `worst` near the boundary between `k` and `k + 1` substeps.
        let worst = (k as f32 * step * (1.0 + nudge)).max(0.0);
        let covered = covered_motion(worst, step);
        proptest::prop_assert!(covered >= worst);
        let counts = |m: f32| wanted_substeps(m, step).max(1.0);
        for m in [covered, covered * fraction, worst + (covered - worst) * fraction] {
            proptest::prop_assert!(counts(m) <= counts(worst), "{m} vs {worst}, step {step}");
        }
    }
}

/// The frame plan's preparation (contacts to friction anchors, touching vertices listed) gives
/// the same list and anchors on rayon's pool as serially, with more vertices than one chunk.
#[test]
fn plan_preparation_lists_the_same_touching_vertices_in_parallel_and_serially() {
    let (v, t) = shapes::ellipsoid(Vec3::new(0.0, 0.0, -0.2), Vec3::splat(0.3), 16, 24).unwrap();
    let mesh = sheet(41, 1.0, 0.0);
    let n = mesh.positions().len();
    assert!(n > 4 * CHUNK);
    let mut contact = SkinCollision::new(n, ContactConfig::DEFAULT).unwrap();
    contact.add_collider(ColliderMesh::from_mesh(v, t).unwrap());
    let mut x = mesh.positions().to_vec();
    contact.advance_frame(&mut x).unwrap();
    let (mut serial, mut parallel) = (contact.clone(), contact.clone());
    let (a, b) = (
        serial.anchor_contacts(false),
        parallel.anchor_contacts(true),
    );
    // The ball's cap pokes through the sheet: a patch of its vertices touches it.
    assert!(a.len() > 20, "{} touching", a.len());
    assert_eq!(a, b);
    for set in [&serial, &parallel] {
        let touching = set.states.iter().enumerate();
        let listed: Vec<u32> = touching
            .filter(|(_, s)| s.contact.collider != NONE)
            .map(|(i, _)| i as u32)
            .collect();
        assert_eq!(listed, a);
        assert!(set.states.iter().all(|s| s.anchor == s.contact));
    }
    // Before the preparation some anchors were not the contacts (the frame's start).
    let stale = contact
        .states
        .iter()
        .filter(|s| s.anchor != s.contact)
        .count();
    assert!(stale > 0);
}

/// Sheet over a ball sliding along x by `shift` over `frames` frames; returns the sheet at the
/// end and at the start.
fn slide(friction: f32, shift: f32, frames: u32) -> (Vec<Vec3>, Vec<Vec3>, Vec<Vec3>) {
    slide_with(friction, shift, frames, |_| {})
}

/// [`slide`], calling `between` before every frame.
fn slide_with(
    friction: f32,
    shift: f32,
    frames: u32,
    between: impl Fn(&mut SkinCollision),
) -> (Vec<Vec3>, Vec<Vec3>, Vec<Vec3>) {
    let (r, h) = (0.3, 0.01);
    let start = Vec3::new(-0.5 * shift, 0.0, -0.22);
    let mesh = sheet(11, 1.0, 0.0);
    let system = springs(&mesh);
    let n = mesh.positions().len();
    let pinned: Vec<bool> = mesh
        .positions()
        .iter()
        .map(|p| p.x.abs() > 0.49 || p.y.abs() > 0.49)
        .collect();
    // Tangential anchors hold the sheet in place; normal motion is free.
    let anchors: Vec<VertexAnchor> = mesh
        .positions()
        .iter()
        .map(|p| VertexAnchor {
            target: *p,
            normal: Vec3::Z,
            k_normal: 0.0,
            k_tangent: 200.0,
        })
        .collect();
    let loads = Loads {
        pinned: Some(&pinned),
        anchors: Some(&anchors),
        ..Default::default()
    };
    let config = ContactConfig {
        thickness_m: h,
        friction,
        ..ContactConfig::DEFAULT
    };
    let relax = |contact: &mut SkinCollision, x: &mut Vec<Vec3>| {
        frame(contact, &system, x, &loads, 3000);
    };
    let mut contact = SkinCollision::new(n, config).unwrap();
    let ball = contact.add_collider(
        ColliderMesh::ball(r)
            .unwrap()
            .with_pose(Pose::from_translation(start)),
    );
    let mut x = mesh.positions().to_vec();
    relax(&mut contact, &mut x);
    let initial = x.clone();
    for f in 1..=frames {
        let c = start + Vec3::X * shift * f as f32 / frames as f32;
        contact
            .collider_mut(ball)
            .unwrap()
            .set_pose(Pose::from_translation(c))
            .unwrap();
        between(&mut contact);
        relax(&mut contact, &mut x);
    }
    // A fresh drape over the ball at its final place.
    let mut fresh_contact = SkinCollision::new(n, config).unwrap();
    fresh_contact.add_collider(
        ColliderMesh::ball(r)
            .unwrap()
            .with_pose(Pose::from_translation(start + Vec3::X * shift)),
    );
    let mut fresh = mesh.positions().to_vec();
    relax(&mut fresh_contact, &mut fresh);
    (x, initial, fresh)
}

/// Mean x-displacement of the vertices touching the top of the ball initially.
fn carried(x: &[Vec3], initial: &[Vec3]) -> f32 {
    let top: Vec<usize> = (0..x.len())
        .filter(|&i| initial[i].x.abs() < 0.11 && initial[i].y.abs() < 0.11)
        .collect();
    top.iter().map(|&i| x[i].x - initial[i].x).sum::<f32>() / top.len() as f32
}

#[test]
fn frictionless_sliding_ball_carries_no_vertex_and_friction_drags_the_sheet() {
    let shift = 0.1;
    let (free, initial, fresh) = slide(0.0, shift, 5);
    // Frictionless contact has no memory: the sheet is where a fresh drape puts it.
    let max = free
        .iter()
        .zip(&fresh)
        .map(|(a, b)| a.distance(*b))
        .fold(0.0f32, f32::max);
    assert!(
        max < 0.05 * shift,
        "frictionless result differs from a fresh drape by {max}"
    );
    let moved_free = carried(&free, &initial);
    let (stuck, initial_stuck, _) = slide(1.0, shift, 5);
    let moved_stuck = carried(&stuck, &initial_stuck);
    assert!(
        moved_free.abs() < 0.2 * shift,
        "frictionless carried {moved_free}"
    );
    assert!(
        moved_stuck > 0.5 * shift,
        "sticking carried only {moved_stuck}"
    );
}

/// Winding number of a closed polygon around the line through `c` along `axis`.
fn winding(ring: &[Vec3], c: Vec3, axis: Vec3) -> f32 {
    let u = axis.any_orthonormal_vector();
    let w = axis.cross(u);
    let angle = |p: Vec3| {
        let d = p - c;
        d.dot(w).atan2(d.dot(u))
    };
    let mut total = 0.0;
    for k in 0..ring.len() {
        let mut da = angle(ring[(k + 1) % ring.len()]) - angle(ring[k]);
        if da > std::f32::consts::PI {
            da -= std::f32::consts::TAU;
        }
        if da < -std::f32::consts::PI {
            da += std::f32::consts::TAU;
        }
        total += da;
    }
    total / std::f32::consts::TAU
}

fn capsule_distance(p: Vec3, a: Vec3, b: Vec3, r: f32) -> f32 {
    let ab = b - a;
    let t = ((p - a).dot(ab) / ab.length_squared()).clamp(0.0, 1.0);
    p.distance(a + ab * t) - r
}

fn swing(max_substeps: u32) -> (usize, usize) {
    let (around, rings, radius, h, bone_r) = (16, 25, 0.05, 0.004, 0.03);
    let mesh = tube(around, rings, radius, -0.1, 0.3);
    let system = springs(&mesh);
    let n = mesh.positions().len();
    let pinned: Vec<bool> = mesh.positions().iter().map(|p| p.x < -0.099).collect();
    // The bone sticks out of the tube, so the tube cannot just slide off its end.
    let (a, b) = (Vec3::ZERO, Vec3::new(0.45, 0.0, 0.0));
    let config = ContactConfig {
        thickness_m: h,
        max_substeps,
        ..ContactConfig::DEFAULT
    };
    let mut contact = SkinCollision::new(n, config).unwrap();
    let bone = contact.add_collider(ColliderMesh::capsule(a, b, bone_r).unwrap());
    let loads = Loads {
        pinned: Some(&pinned),
        ..Default::default()
    };
    let mut x = mesh.positions().to_vec();
    let (mut inside, mut escaped) = (0, 0);
    for step in 1..=4 {
        // 0.3 rad per frame: the tube's end moves 0.09 m, almost twice the tube radius.
        let q = Quat::from_rotation_z(0.3 * step as f32);
        let pose = Pose::from_rotation(q);
        contact.collider_mut(bone).unwrap().set_pose(pose).unwrap();
        frame(&mut contact, &system, &mut x, &loads, 10);
        let (wa, wb) = (pose.transform_point(a), pose.transform_point(b));
        inside += x
            .iter()
            .filter(|p| capsule_distance(**p, wa, wb, bone_r) < h - 1e-5)
            .count();
        // Rings over the bone must still wrap around it. Over the bone: the ring's centroid
        // projects onto the bone's segment. The tube bends around the pivot, and a ring that
        // slid back off the end cap has no bone to wrap (the winding number about the axis
        // line is then a matter of how the ring tilted, not of tunnelling).
        let axis = (wb - wa).normalize();
        let mut over = 0;
        for j in 5..rings as usize {
            let ring = &x[j * around as usize..(j + 1) * around as usize];
            let centroid = ring.iter().copied().sum::<Vec3>() / ring.len() as f32;
            let t = (centroid - wa).dot(wb - wa) / (wb - wa).length_squared();
            if !(0.0..=1.0).contains(&t) {
                continue;
            }
            over += 1;
            if winding(ring, wa, axis).abs() < 0.5 {
                escaped += 1;
            }
        }
        // Most rings are over the bone (it sticks out of the tube): the check is not vacuous.
        assert!(over >= 15, "only {over} rings over the bone at step {step}");
    }
    (inside, escaped)
}

#[test]
fn fast_swinging_bone_stays_inside_the_skin_tube() {
    let (inside, escaped) = swing(256);
    assert_eq!(inside, 0);
    assert_eq!(escaped, 0, "the bone tunnelled out of {escaped} rings");
}

#[test]
fn without_substeps_the_fast_bone_tunnels() {
    // Guards the test above: the same motion with one substep does tunnel.
    let (_, escaped) = swing(1);
    assert!(escaped > 0);
}

#[test]
fn crease_between_two_capsules_leaves_no_vertex_inside() {
    let (r, h) = (0.03, 0.01);
    // Two overlapping parallel bones: a V-shaped crease along y between them.
    let (a0, a1) = (
        Vec3::new(-0.025, -0.3, -0.04),
        Vec3::new(-0.025, 0.3, -0.04),
    );
    let (b0, b1) = (Vec3::new(0.025, -0.3, -0.04), Vec3::new(0.025, 0.3, -0.04));
    let mesh = sheet(25, 0.4, 0.0);
    let system = springs(&mesh);
    let n = mesh.positions().len();
    let pinned: Vec<bool> = mesh
        .positions()
        .iter()
        .map(|p| p.x.abs() > 0.199 || p.y.abs() > 0.199)
        .collect();
    // Pressed down into the groove.
    let forces = vec![Vec3::new(0.0, 0.0, -2.0); n];
    let loads = Loads {
        pinned: Some(&pinned),
        forces: Some(&forces),
        ..Default::default()
    };
    let config = ContactConfig {
        thickness_m: h,
        ..ContactConfig::DEFAULT
    };
    let mut contact = SkinCollision::new(n, config).unwrap();
    contact.add_collider(ColliderMesh::capsule(a0, a1, r).unwrap());
    contact.add_collider(ColliderMesh::capsule(b0, b1, r).unwrap());
    let mut x = mesh.positions().to_vec();
    contact.advance_frame(&mut x).unwrap();
    system
        .relax_projected(&mut x, &loads, &budget(500), Some(&mut contact))
        .unwrap();
    assert!(contact.diagnostics().unresolved.is_empty());
    let mut touching = 0;
    for (i, p) in x.iter().enumerate() {
        let da = capsule_distance(*p, a0, a1, r);
        let db = capsule_distance(*p, b0, b1, r);
        assert!(da > h - 1e-5 && db > h - 1e-5, "vertex {i}: {da}, {db}");
        if da < 1.1 * h || db < 1.1 * h {
            touching += 1;
        }
    }
    assert!(touching > 20, "{touching}");

    // Points dropped into the notch: pushed out of one bone into the other and back, they must
    // end on the feasible side of both, at the thickness from one, near the notch's apex where
    // both distances are the thickness: x = 0, z = −0.04 + √((r + h)² − 0.025²).
    let z_star = -0.04 + ((r + h) * (r + h) - 0.025f32 * 0.025).sqrt();
    let mut notch: Vec<Vec3> = (0..40)
        .map(|k| {
            Vec3::new(
                0.004 * ((k % 7) as f32 - 3.0) / 3.0,
                -0.2 + 0.01 * k as f32,
                -0.035 + 0.0006 * k as f32,
            )
        })
        .collect();
    let mut contact = SkinCollision::new(notch.len(), config).unwrap();
    contact.add_collider(ColliderMesh::capsule(a0, a1, r).unwrap());
    contact.add_collider(ColliderMesh::capsule(b0, b1, r).unwrap());
    contact.advance_frame(&mut notch).unwrap();
    assert!(contact.diagnostics().unresolved.is_empty());
    for (k, p) in notch.iter().enumerate() {
        let da = capsule_distance(*p, a0, a1, r);
        let db = capsule_distance(*p, b0, b1, r);
        assert!(da > h - 1e-5 && db > h - 1e-5, "point {k}: {da}, {db}");
        assert!((da.min(db) - h).abs() < 1e-4, "point {k}: {da}, {db}");
        assert!(
            p.x.abs() < 3e-3 && (p.z - z_star).abs() < 2e-3,
            "point {k} at {p}, not in the crease at z {z_star}"
        );
    }
}

#[test]
fn impossible_slot_is_reported_not_oscillating() {
    // Two balls whose surfaces are half a thickness apart: no point between them is at the
    // thickness from both, and the symmetric vertex is pushed back and forth along x.
    let h = 0.01;
    let gap = 0.5 * h;
    let mut contact = SkinCollision::new(
        1,
        ContactConfig {
            thickness_m: h,
            ..ContactConfig::DEFAULT
        },
    )
    .unwrap();
    for side in [-1.0, 1.0] {
        contact.add_collider(
            ColliderMesh::ball(1.0)
                .unwrap()
                .with_pose(Pose::from_translation(Vec3::X * side * (1.0 + gap / 2.0))),
        );
    }
    let mut x = vec![Vec3::ZERO];
    let d = contact.advance_frame(&mut x).unwrap();
    assert_eq!(d.unresolved, vec![0]);
    let first = x[0];
    assert!(first.is_finite());
    // Deterministic: the same answer again from the same start.
    let mut y = vec![Vec3::ZERO];
    contact.clear_cache();
    contact.advance_frame(&mut y).unwrap();
    assert_eq!(first, y[0]);
}

#[test]
fn per_vertex_thickness_and_results_independent_of_thread_count() {
    let (v, t) = blob(16, 24);
    let mut rng = Lcg(3);
    let n = 3000;
    let points: Vec<Vec3> = (0..n).map(|_| rng.point(0.35)).collect();
    let thickness: Vec<f32> = (0..n).map(|i| 0.002 + 0.01 * (i % 5) as f32).collect();
    let run = |threads: usize| {
        crate::test_support::in_pool(threads, || {
            let mut c = SkinCollision::new(n, ContactConfig::DEFAULT)
                .unwrap()
                .with_thickness(&thickness)
                .unwrap();
            c.add_collider(ColliderMesh::from_mesh(v.clone(), t.clone()).unwrap());
            let mut x = points.clone();
            c.advance_frame(&mut x).unwrap();
            (x, c.diagnostics().clone())
        })
    };
    let (one, d1) = run(1);
    let (two, d2) = run(2);
    assert_eq!(one, two);
    assert_eq!(d1, d2);
    let oriented = ParryMesh::with_flags(v, t, TriMeshFlags::ORIENTED).unwrap();
    for (i, p) in one.iter().enumerate() {
        let proj = oriented.project_point(&Pose::IDENTITY, *p, false);
        assert!(!proj.is_inside, "vertex {i}");
        assert!(proj.point.distance(*p) > thickness[i] - 1e-5, "vertex {i}");
    }
    assert!(
        SkinCollision::new(2, ContactConfig::DEFAULT)
            .unwrap()
            .set_thickness(&[0.1, f32::NAN])
            .unwrap_err()
            .to_string()
            .contains("vertex 1")
    );
}

/// The old behaviour, for comparison: the same projection without its contact set (the
/// trait's default methods), so the contact forces stay in the residual.
struct Blind<'a>(&'a mut SkinCollision);

impl Projection for Blind<'_> {
    fn project(&mut self, x: &mut [Vec3], order: &[u32]) -> bool {
        self.0.project(x, order)
    }
}

/// A sheet pinned at its border draped over a ball poking through it, relaxed with
/// `projection`.
struct Drape {
    system: SpringSystem,
    pinned: Vec<bool>,
    x: Vec<Vec3>,
    centre: Vec3,
    radius: f32,
    h: f32,
}

impl Drape {
    fn new(n: u32) -> (Self, SkinCollision) {
        let (radius, centre, h) = (0.3, Vec3::new(0.0, 0.0, -0.2), 0.01);
        let mesh = sheet(n, 1.0, 0.0);
        let system = springs(&mesh);
        let pinned: Vec<bool> = mesh
            .positions()
            .iter()
            .map(|p| p.x.abs() > 0.49 || p.y.abs() > 0.49)
            .collect();
        let config = ContactConfig {
            thickness_m: h,
            ..ContactConfig::DEFAULT
        };
        let mut contact = SkinCollision::new(mesh.positions().len(), config).unwrap();
        contact.add_collider(
            ColliderMesh::ball(radius)
                .unwrap()
                .with_pose(Pose::from_translation(centre)),
        );
        let mut x = mesh.positions().to_vec();
        contact.advance_frame(&mut x).unwrap();
        let drape = Self {
            system,
            pinned,
            x,
            centre,
            radius,
            h,
        };
        (drape, contact)
    }

    fn relax(&mut self, config: &RelaxConfig, projection: &mut dyn Projection) -> RelaxReport {
        let loads = Loads {
            pinned: Some(&self.pinned),
            ..Default::default()
        };
        self.system
            .relax_projected(&mut self.x, &loads, config, Some(projection))
            .unwrap()
    }

    /// Checks the KKT conditions of the contact problem independently of the solver: no vertex
    /// inside the ball (parry's query), every free vertex force-free except contact vertices
    /// (at the thickness), whose net force is along the outward normal and pushes into the
    /// ball (the contact pushes back), within `tol_n` per vertex. Returns the number of
    /// contact vertices.
    fn check_kkt(&self, tol_n: f32) -> usize {
        let ball = parry3d::shape::Ball::new(self.radius);
        let pose = Pose::from_translation(self.centre);
        let f = self.system.spring_forces(&self.x).unwrap();
        let mut contacts = 0;
        for (i, p) in self.x.iter().enumerate() {
            let proj = ball.project_point(&pose, *p, false);
            assert!(!proj.is_inside, "vertex {i} inside");
            let gap = proj.point.distance(*p) - self.h;
            assert!(
                gap > -1e-5,
                "vertex {i} closer than the thickness by {}",
                -gap
            );
            if self.pinned[i] {
                continue;
            }
            let n = (*p - self.centre).normalize();
            if gap < 1e-5 {
                contacts += 1;
                let push = f[i].dot(n);
                let tangential = (f[i] - n * push).length();
                assert!(push < tol_n, "contact {i} pulled off by {push} N");
                assert!(
                    tangential < tol_n,
                    "contact {i}: tangential force {tangential} N"
                );
            } else {
                assert!(
                    f[i].length() < tol_n,
                    "free vertex {i} (gap {gap}): force {} N",
                    f[i].length()
                );
            }
        }
        contacts
    }
}

#[test]
fn draped_sheet_converges_to_the_kkt_point_of_the_contact_problem() {
    let config = RelaxConfig {
        max_iterations: 2000,
        tolerance: 1e-5,
        ..RelaxConfig::DEFAULT
    };
    let (mut drape, mut contact) = Drape::new(21);
    let report = drape.relax(&config, &mut contact);
    assert_eq!(report.stop, StopReason::Converged, "{report:?}");
    assert!(contact.diagnostics().unresolved.is_empty());
    // Per-vertex force tolerance: the residual bound, from the force scale the report names.
    let tol_n = 2.0 * config.tolerance * report.force_scale;
    let contacts = drape.check_kkt(tol_n);
    // The cap pokes 0.1 m through the sheet: a disc of radius ~0.24 m of the sheet lies on it.
    assert!(contacts >= 9, "{contacts} contacts");
    eprintln!("drape: {report:?}, {contacts} contacts");

    // Without the contact set the same solve cannot meet the tolerance in 5x the iterations.
    let (mut blind, mut blind_contact) = Drape::new(21);
    let budget = 5 * report.iterations.max(20);
    let old = blind.relax(
        &RelaxConfig {
            max_iterations: budget,
            stagnation_window: 0,
            ..config
        },
        &mut Blind(&mut blind_contact),
    );
    eprintln!("blind drape: {old:?}");
    assert_ne!(old.stop, StopReason::Converged, "{old:?}");
}

#[test]
fn far_fast_colliders_cost_no_substep_near_ones_do() {
    let h = 0.01;
    let mesh = sheet(11, 1.0, 0.0);
    let config = ContactConfig {
        thickness_m: h,
        ..ContactConfig::DEFAULT
    };
    let mut contact = SkinCollision::new(mesh.positions().len(), config).unwrap();
    let far = contact.add_collider(
        ColliderMesh::ball(0.1)
            .unwrap()
            .with_pose(Pose::from_translation(Vec3::new(5.0, 0.0, 0.0))),
    );
    let near = contact.add_collider(
        ColliderMesh::ball(0.1)
            .unwrap()
            .with_pose(Pose::from_translation(Vec3::new(0.0, 0.0, -0.2))),
    );
    let mut x = mesh.positions().to_vec();
    contact.advance_frame(&mut x).unwrap();
    // 3 m in one frame, 300 thicknesses, but never within 4 m of the sheet.
    let moved = Pose::from_translation(Vec3::new(5.0, 3.0, 0.0));
    contact.collider_mut(far).unwrap().set_pose(moved).unwrap();
    assert_eq!(contact.begin_frame(&mut x).unwrap().substeps, 1);
    while contact.substep(&mut x).unwrap() > 0 {}
    // The near ball rises 0.15 m, through the sheet's plane: the relative motion must be split
    // into steps of at most half a thickness.
    let rise = Pose::from_translation(Vec3::new(0.0, 0.0, -0.05));
    contact.collider_mut(near).unwrap().set_pose(rise).unwrap();
    let plan = contact.begin_frame(&mut x).unwrap();
    assert!(plan.substeps >= 30, "{plan:?}");
    while contact.substep(&mut x).unwrap() > 0 {}
    // Both at once: the near one decides.
    contact
        .collider_mut(far)
        .unwrap()
        .set_pose(Pose::from_translation(Vec3::new(5.0, 0.0, 0.0)))
        .unwrap();
    contact
        .collider_mut(near)
        .unwrap()
        .set_pose(Pose::from_translation(Vec3::new(0.0, 0.0, -0.2)))
        .unwrap();
    let both = contact.begin_frame(&mut x).unwrap();
    assert!(both.substeps >= 30 && both.substeps < 300, "{both:?}");
}

/// A bone turning by `theta` about a joint at `joint_x` on its frame's x axis (far from the
/// origin: a forearm about the elbow), the skin wrapped round it at the thickness `h`: the substeps planned for skin
/// carried with the bone and for still skin, the least the still skin's motion relative to the
/// bone needs (`θ` times the far ring's distance from the joint, in steps of `h / 2`), and the
/// still skin's least clearance from the turned bone after its substeps.
fn turning_bone(h: f32, theta: f32, joint_x: f32) -> (u32, u32, u32, f32) {
    let r = 0.03;
    // The bone runs 0.3 m along x from the joint at `joint_x`.
    let (joint, end) = (
        Vec3::new(joint_x, 0.0, 0.0),
        Vec3::new(joint_x + 0.3, 0.0, 0.0),
    );
    let mesh = tube(12, 7, r + h, joint_x, joint_x + 0.3);
    let q = Quat::from_rotation_z(theta);
    let pose = Pose::from_parts(joint - q * joint, q);
    let config = ContactConfig {
        thickness_m: h,
        ..ContactConfig::DEFAULT
    };
    let start = |x: &mut Vec<Vec3>| {
        let mut contact = SkinCollision::new(x.len(), config).unwrap();
        let bone = contact.add_collider(ColliderMesh::capsule(joint, end, r).unwrap());
        contact.advance_frame(x).unwrap();
        contact.collider_mut(bone).unwrap().set_pose(pose).unwrap();
        contact
    };
    let mut x = mesh.positions().to_vec();
    let mut contact = start(&mut x);
    x.iter_mut().for_each(|p| *p = pose.transform_point(*p));
    let carried = contact.begin_frame(&mut x).unwrap().substeps;
    let mut x = mesh.positions().to_vec();
    let mut contact = start(&mut x);
    let far = mesh
        .positions()
        .iter()
        .map(|p| p.distance(joint))
        .fold(0.0, f32::max);
    let least = (theta * far / (0.5 * h)).ceil() as u32;
    let still = contact.begin_frame(&mut x).unwrap().substeps;
    while contact.substep(&mut x).unwrap() > 0 {}
    let (a, b) = (pose.transform_point(joint), pose.transform_point(end));
    let clearance = x
        .iter()
        .map(|p| capsule_distance(*p, a, b, r))
        .fold(f32::INFINITY, f32::min);
    (carried, still, least, clearance)
}

/// The substeps split the skin's motion relative to a turning bone, not the bone's motion
/// through its frame's origin: skin carried with the bone needs none, still skin the motion of
/// the bone's far end under it, and no more; the substeps keep it outside.
#[test]
fn substeps_follow_the_motion_relative_to_a_turning_bone() {
    let (h, theta) = (0.01, 0.05);
    let (carried, still, least, clearance) = turning_bone(h, theta, 1.0);
    assert_eq!(carried, 1);
    assert!((least..=least + 1).contains(&still), "{still} for {least}");
    assert!(clearance > h - 1e-4, "{clearance}");
}

/// A turn too small for `acos` of the quaternion's `w` in f32 (`w` rounds to 1) still counts:
/// a 0.1 mm skin over a bone turning by 2e-4 rad about its frame's origin (no translation to
/// carry the motion), whose far end moves 6e-5 m.
#[test]
fn a_small_turn_still_splits_into_substeps() {
    let (_, still, least, _) = turning_bone(1e-4, 2e-4, 0.0);
    assert!(least >= 2);
    assert!(still >= least, "{still} for {least}");
}

#[test]
fn contact_solve_is_bit_identical_for_any_thread_count() {
    let run = |threads: usize| {
        crate::test_support::in_pool(threads, || {
            let (mut drape, mut contact) = Drape::new(33);
            let report = drape.relax(&budget(300), &mut contact);
            (drape.x, report)
        })
    };
    let (x1, r1) = run(1);
    let (x2, r2) = run(2);
    let bits = |x: &[Vec3]| {
        x.iter()
            .flat_map(|p| p.to_array().map(f32::to_bits))
            .collect::<Vec<_>>()
    };
    assert_eq!(bits(&x1), bits(&x2));
    assert_eq!(r1.iterations, r2.iterations);
    assert_eq!(r1.energy.to_bits(), r2.energy.to_bits());
}

/// Friction across frames as the ECS runs it: the query cache cleared before every frame (exact
/// checkpoints) keeps each vertex's last contact, so a ball sliding over ten frames with
/// `friction == 1` carries the sheet along, and without friction it does not. Clearing
/// everything (the anchors too) loses the grip at every frame.
#[test]
fn friction_carries_the_sheet_across_frames_with_the_query_cache_cleared() {
    let shift = 0.1;
    let (stuck, initial, _) = slide_with(1.0, shift, 10, SkinCollision::clear_query_cache);
    let carried_stuck = carried(&stuck, &initial);
    assert!(
        carried_stuck > 0.5 * shift,
        "sticking carried only {carried_stuck}"
    );
    let (free, initial_free, _) = slide_with(0.0, shift, 10, SkinCollision::clear_query_cache);
    let carried_free = carried(&free, &initial_free);
    assert!(
        carried_free.abs() < 0.2 * shift,
        "frictionless carried {carried_free}"
    );
    let (lost, initial_lost, _) = slide_with(1.0, shift, 10, SkinCollision::clear_cache);
    let carried_lost = carried(&lost, &initial_lost);
    assert!(
        carried_lost < carried_stuck,
        "{carried_lost} >= {carried_stuck}"
    );
    // The anchors round-trip through their public form.
    let mut contact = SkinCollision::new(2, ContactConfig::DEFAULT).unwrap();
    contact.add_collider(ColliderMesh::ball(1.0).unwrap());
    let mut x = vec![Vec3::new(0.0, 0.0, 0.5), Vec3::new(0.0, 0.0, 3.0)];
    contact.advance_frame(&mut x).unwrap();
    let anchors = contact.friction_anchors();
    assert!(anchors[0].is_some() && anchors[1].is_none());
    let mut other = SkinCollision::new(2, ContactConfig::DEFAULT).unwrap();
    assert!(other.set_friction_anchors(&anchors).is_err()); // no collider 0 there
    other.add_collider(ColliderMesh::ball(1.0).unwrap());
    other.set_friction_anchors(&anchors).unwrap();
    assert_eq!(other.friction_anchors(), anchors);
}

#[test]
fn a_projection_order_that_is_not_a_permutation_is_refused_untouched() {
    let mut skin = SkinCollision::new(3, ContactConfig::DEFAULT).unwrap();
    skin.add_collider(ColliderMesh::ball(1.0).unwrap());
    // Vertex 0 inside the ball: a real pass would move it.
    let inside = vec![
        Vec3::new(0.0, 0.0, 0.5),
        Vec3::new(0.0, 0.0, 3.0),
        Vec3::X * 4.0,
    ];
    for order in [vec![0, 0, 2], vec![0, 1, 7]] {
        let mut x = inside.clone();
        assert!(!skin.project(&mut x, &order));
        assert_eq!(x, inside);
        assert!(skin.diagnostics().length_mismatch);
    }
    // A permutation works: `x` is in its order, so the vertex inside is internal vertex 0.
    let mut x = inside.clone();
    assert!(skin.project(&mut x, &[2, 0, 1]));
    assert!((x[0].length() - 1.002).abs() < 1e-5, "{}", x[0]);
    assert_eq!(&x[1..], &inside[1..]);
}

/// Contact of a 1 cm thick skin.
const ONE_CM: ContactConfig = ContactConfig {
    thickness_m: 0.01,
    ..ContactConfig::DEFAULT
};

/// A one-vertex skin of 1 cm thickness and a ball of radius 0.1 at the origin.
fn one_vertex_by_a_small_ball() -> (SkinCollision, ColliderId) {
    let mut skin = SkinCollision::new(1, ONE_CM).unwrap();
    let id = skin.add_collider(ColliderMesh::ball(0.1).unwrap());
    (skin, id)
}

#[test]
fn a_collider_replaced_in_place_is_seen_by_the_next_pass() {
    // A vertex far from a small ball is skipped by its cached bounds; replacing the ball with a
    // big one through `collider_mut` (its travel restarts) must not let the stale bounds hide it.
    let (mut skin, id) = one_vertex_by_a_small_ball();
    let order = [0u32];
    let mut x = vec![Vec3::new(0.0, 0.0, 0.5)];
    for _ in 0..3 {
        assert!(!skin.project(&mut x, &order));
    }
    *skin.collider_mut(id).unwrap() = ColliderMesh::ball(1.0).unwrap();
    assert!(skin.project(&mut x, &order));
    assert!((x[0].z - 1.01).abs() < 1e-5, "{}", x[0]);
}

#[test]
fn a_collider_replaced_in_place_is_seen_by_the_next_frame_plan() {
    // The plan skips pairs on cached distance bounds, which are measured against each
    // collider's travel: a replacement whose travel restarted below the old one's must not
    // inherit them. The vertex then needs substeps, as for a skin that never saw the old ball.
    let (mut skin, id) = one_vertex_by_a_small_ball();
    let mut x = vec![Vec3::new(0.0, 0.0, 0.5)];
    // The old ball wanders far to the side (a long travel) and comes back.
    for k in 0..20 {
        let side = if k % 2 == 0 { 5.0 } else { 0.0 };
        let pose = Pose::from_translation(Vec3::new(side, 0.0, 0.0));
        skin.collider_mut(id).unwrap().set_pose(pose).unwrap();
        skin.clear_frame_state();
        skin.advance_frame(&mut x).unwrap();
    }
    let moved = |mut ball: ColliderMesh| {
        let pose = Pose::from_translation(Vec3::new(0.0, 0.0, 0.395));
        ball.set_pose(pose).unwrap();
        ball
    };
    *skin.collider_mut(id).unwrap() = moved(ColliderMesh::ball(0.1).unwrap());
    skin.clear_frame_state();
    let plan = skin.begin_frame(&mut x.clone()).unwrap();
    // A skin that never saw the old ball: the moved one added afresh.
    let mut fresh = SkinCollision::new(1, ONE_CM).unwrap();
    fresh.add_collider(moved(ColliderMesh::ball(0.1).unwrap()));
    let expected = fresh.begin_frame(&mut x.clone()).unwrap();
    assert!(expected.substeps > 1, "{expected:?}");
    assert_eq!(plan, expected);
}

#[test]
fn projections_in_a_shuffled_order_keep_the_last_positions_of_every_pass() {
    // The swept test of a projection needs each vertex's position after the previous pass,
    // whichever order that pass ran in; so does the next frame's plan.
    let config = ContactConfig {
        thickness_m: 0.01,
        ..ContactConfig::DEFAULT
    };
    let mut skin = SkinCollision::new(3, config).unwrap();
    skin.add_collider(ColliderMesh::ball(0.1).unwrap());
    let order = [2u32, 0, 1];
    let caller = [
        Vec3::new(0.0, 0.0, 0.5),
        Vec3::new(3.0, 0.0, 0.0),
        Vec3::new(-3.0, 0.0, 0.0),
    ];
    let mut x = caller.to_vec();
    assert!(!skin.contact_pass(&mut x).unwrap());
    // Caller's vertex 0 is the solver's vertex 1. It jumps through the ball in one step, on
    // the first projection after the caller-order pass: caught on the side it came from.
    let mut xi: Vec<Vec3> = order.iter().map(|&o| caller[o as usize]).collect();
    xi[1] = Vec3::new(0.0, 0.0, -0.5);
    assert!(skin.project(&mut xi, &order));
    assert!((xi[1].z - 0.11).abs() < 1e-4, "{}", xi[1]);
    // Again after idle projections and a step back up.
    for _ in 0..3 {
        assert!(!skin.project(&mut xi, &order));
    }
    xi[1] = Vec3::new(0.0, 0.0, 0.4);
    assert!(!skin.project(&mut xi, &order));
    xi[1] = Vec3::new(0.0, 0.0, -0.4);
    assert!(skin.project(&mut xi, &order));
    assert!((xi[1].z - 0.11).abs() < 1e-4, "{}", xi[1]);
    // Back in the caller's order: the frame plan starts from the projected positions (no
    // motion, a still ball: one substep), not from the caller-order pass's (0.39 m away).
    let mut x: Vec<Vec3> = vec![Vec3::ZERO; 3];
    for (i, &o) in order.iter().enumerate() {
        x[o as usize] = xi[i];
    }
    assert_eq!(skin.begin_frame(&mut x).unwrap().substeps, 1);
    // And the projections' positions are where a moving vertex's substeps start from.
    let mut y = x.clone();
    y[0] = Vec3::new(0.0, 0.0, 0.3);
    assert!(skin.begin_frame(&mut y).unwrap().substeps > 1);
    assert_eq!(y[0], x[0], "substeps restart from the last pass's position");
}

#[test]
fn the_query_cache_carried_over_a_frame_skips_far_vertices_with_the_same_answers() {
    // A sheet over a ball that moves a little each frame: from the carried-over cache the
    // frame's pass skips the vertices far from the ball whole; from a cleared one it resolves
    // every vertex. The positions and contacts are the same.
    let mesh = sheet(24, 2.0, 0.3);
    let config = ContactConfig {
        thickness_m: 0.01,
        ..ContactConfig::DEFAULT
    };
    let mut warm = SkinCollision::new(mesh.positions().len(), config).unwrap();
    let id = warm.add_collider(ColliderMesh::ball(0.3).unwrap());
    // The sheet rests on the ball's top.
    let mut xa = mesh.positions().to_vec();
    warm.advance_frame(&mut xa).unwrap();
    let mut cold = warm.clone();
    let mut xb = xa.clone();
    for frame in 1..5 {
        // A substep per frame (the ball moves less than half the thickness).
        let pose = Pose::from_translation(Vec3::new(0.002 * frame as f32, 0.0, 0.0));
        for s in [&mut warm, &mut cold] {
            s.collider_mut(id).unwrap().set_pose(pose).unwrap();
        }
        warm.clear_frame_state();
        cold.clear_query_cache();
        warm.advance_frame(&mut xa).unwrap();
        cold.advance_frame(&mut xb).unwrap();
        assert_eq!(xa, xb, "frame {frame}");
        let (w, c) = (warm.diagnostics(), cold.diagnostics());
        assert_eq!(w.contacts, c.contacts);
        assert!(c.contacts > 0, "frame {frame}: {c:?}");
        assert_eq!((w.substeps, c.substeps), (1, 1));
        assert_eq!(c.skipped_vertices, 0);
        assert!(w.skipped_vertices > 0, "frame {frame}: {w:?}");
    }
}

/// Only contacts on the surface go to the solver. A vertex in the contact band but off the
/// surface is not reported: held, it would be snapped onto the surface from up to a band away
/// (its springs then pull it off, the solver releases it, it settles back into the band and
/// is held again: a cycle that ran for hundreds of iterations at the rim of a contact patch).
#[test]
fn only_vertices_on_the_surface_are_reported_as_active_contacts() {
    let (r, h) = (0.3f32, 0.01f32);
    let config = ContactConfig {
        thickness_m: h,
        ..ContactConfig::DEFAULT
    };
    let band = h * (1.0 + config.contact_band);
    let mut skin = SkinCollision::new(4, config).unwrap();
    skin.add_collider(ColliderMesh::ball(r).unwrap());
    let start = vec![
        // Inside the thickness: pushed out to it, on the surface.
        Vec3::Z * (r + 0.5 * h),
        // In the band, off the surface.
        Vec3::X * (r + 0.5 * (h + band)),
        // Lying at the thickness already (within the tolerance).
        Vec3::NEG_Y * (r + h + 0.2 * config.tolerance_m),
        // Out of the band.
        Vec3::Y * (r + 2.0 * band),
    ];
    let mut x = start.clone();
    assert!(skin.project(&mut x, &[0, 1, 2, 3]));
    assert!((x[0].length() - (r + h)).abs() < 1e-6, "{}", x[0]);
    assert_eq!(&x[1..], &start[1..]);
    let active = skin.active_contacts();
    let reported: Vec<u32> = active.iter().map(|c| c.vertex).collect();
    assert_eq!(reported, [0, 2]);
    assert!(active[0].normal.distance(Vec3::Z) < 1e-5);
    assert!(active[1].normal.distance(Vec3::NEG_Y) < 1e-5);
    // The band vertex still counts as touching (friction anchors, the contact count).
    assert_eq!(skin.diagnostics().contacts, 3);
}

/// A projection resolves each failing vertex in the group of the solver's order that tests it,
/// reading and writing its state at its caller's index, and hands back the touching ones in
/// the solver's order: over several groups and a shuffled order, the active contacts and the
/// unresolved vertices are exactly those the balls' closed-form distances give, sorted
/// (solver's order for the contacts, caller's for the unresolved), on every pass.
#[test]
fn projections_over_many_chunks_report_contacts_and_unresolved_vertices_in_order() {
    let (r, h) = (0.2f32, 0.01f32);
    let config = ContactConfig {
        thickness_m: h,
        ..ContactConfig::DEFAULT
    };
    let tol = config.tolerance_m;
    // Two balls whose surfaces are one thickness apart at x = 0: a vertex there cannot be a
    // thickness from both (unresolved); elsewhere vertices end on a surface or away from both.
    let centres = [Vec3::X * -(r + 0.5 * h), Vec3::X * (r + 0.5 * h)];
    // Several groups of the pass and several chunks of the caller's state.
    let n = 3 * project::GROUP.max(CHUNK) + 17;
    let mut skin = SkinCollision::new(n, config).unwrap();
    for c in centres {
        skin.add_collider(
            ColliderMesh::ball(r)
                .unwrap()
                .with_pose(Pose::from_translation(c)),
        );
    }
    let mut rng = Lcg(11);
    let caller: Vec<Vec3> = (0..n)
        .map(|i| match i % 5 {
            // In the slit between the balls.
            0 => Vec3::new(0.0, 0.01 * rng.next(), 0.01 * rng.next()),
            // Far away.
            1 => Vec3::new(0.0, 1.0 + rng.next(), 0.0),
            // Near a ball's surface (inside or out).
            _ => {
                let c = centres[i % 2];
                let dir = (rng.point(1.0) + Vec3::splat(1e-3)).normalize();
                c + dir * (r + h * (2.0 * rng.next() - 0.5))
            }
        })
        .collect();
    let mut order: Vec<u32> = (0..n as u32).collect();
    for i in (1..n).rev() {
        let j = (rng.next() * (i + 1) as f32) as usize;
        order.swap(i, j.min(i));
    }
    let mut x: Vec<Vec3> = order.iter().map(|&o| caller[o as usize]).collect();
    for pass in 0..3 {
        skin.project(&mut x, &order);
        // Independent answer: the signed distances to the two balls.
        let s = |p: Vec3, c: Vec3| p.distance(c) - r;
        let mut expected = Vec::new();
        for (i, &p) in x.iter().enumerate() {
            for (k, &c) in centres.iter().enumerate() {
                let d = s(p, c);
                if d <= h + tol {
                    expected.push((i as u32, k));
                }
            }
        }
        let active = skin.active_contacts();
        let got: Vec<u32> = active.iter().map(|a| a.vertex).collect();
        assert!(
            got.windows(2).all(|w| w[0] <= w[1]),
            "pass {pass}: unsorted"
        );
        let want: Vec<u32> = expected.iter().map(|e| e.0).collect();
        assert_eq!(got, want, "pass {pass}");
        for (a, &(i, k)) in active.iter().zip(&expected) {
            let outward = (x[i as usize] - centres[k]).normalize();
            assert!(a.normal.distance(outward) < 1e-4, "pass {pass} vertex {i}");
        }
        // The slit vertices stay unresolved, listed by caller's index, increasing.
        let unresolved = &skin.diagnostics().unresolved;
        let want: Vec<u32> = (0..n as u32)
            .filter(|&o| {
                let p = x[order.iter().position(|&q| q == o).unwrap()];
                centres.iter().any(|&c| s(p, c) < h - tol)
            })
            .collect();
        assert!(want.len() >= n / 5, "pass {pass}: {}", want.len());
        assert_eq!(unresolved, &want, "pass {pass}");
    }
}

/// The frame plan's bisection evaluates a path only at multiples of `1 / PATH_STEPS` (where
/// the plan keeps each rigid collider's poses, computed once), and answers as a direct check
/// of the pieces would: a path that dips below the margin anywhere is found, a path that stays
/// above it by more than the Lipschitz slack of the finest piece is cleared.
#[test]
fn reaching_bisection_evaluates_the_path_only_at_the_kept_times() {
    use std::cell::RefCell;
    let speed = 1.0f32;
    for (dip_at, dip, margin) in [
        (0.3f32, 0.2f32, 0.05f32),
        (0.71, 0.0, 0.05),
        (0.5, 0.45, 0.05),
        (0.9, 0.6, 0.01),
    ] {
        // 1-Lipschitz at `speed`: a V of slope `speed` bottoming at `dip` at `dip_at`.
        let times = RefCell::new(Vec::new());
        let distance = |t: f32| {
            times.borrow_mut().push(t);
            dip + speed * (t - dip_at).abs()
        };
        let found = reaches(&distance, speed, margin);
        for &t in times.borrow().iter() {
            let k = t * PATH_STEPS as f32;
            assert!(
                k.fract() == 0.0 && (0.0..=PATH_STEPS as f32).contains(&k),
                "t = {t}"
            );
        }
        // The path's true minimum is `dip`: below the margin it must be found; above the
        // margin plus the finest piece's slack it must be cleared.
        if dip < margin {
            assert!(found, "dip {dip} at {dip_at} below {margin} not found");
        }
        if dip > margin + 0.5 * speed / PATH_STEPS as f32 {
            assert!(!found, "dip {dip} at {dip_at} above {margin} not cleared");
        }
    }
}

#[test]
fn a_trusted_order_is_compared_again_once_another_order_was_used() {
    // The frame loop vouches for its solver's order, and projections given that very slice
    // skip comparing it. Once a projection adopts another order, the trusted slice must be
    // compared (and adopted) again, or its vertices would take the other order's states: here
    // their thicknesses, 1 cm for caller's vertex 0 and 5 cm for the others.
    let thickness = [0.01, 0.05, 0.05];
    let mut skin = SkinCollision::new(3, ONE_CM).unwrap();
    skin.add_collider(ColliderMesh::ball(1.0).unwrap());
    skin.set_thickness(&thickness).unwrap();
    // Every vertex inside the ball, on its own axis.
    let caller = [Vec3::Z * 0.5, Vec3::X * 0.5, Vec3::Y * 0.5];
    let trusted: Vec<u32> = vec![2, 0, 1];
    let other: Vec<u32> = vec![1, 2, 0];
    let in_order = |order: &[u32]| {
        order
            .iter()
            .map(|&o| caller[o as usize])
            .collect::<Vec<_>>()
    };
    let pushed_to = |x: &[Vec3], order: &[u32]| {
        for (p, &o) in x.iter().zip(order) {
            let want = 1.0 + thickness[o as usize];
            assert!(
                (p.length() - want).abs() < 1e-5,
                "caller's {o} at {p}, not {want}"
            );
        }
    };
    skin.trust_order(&trusted);
    for order in [&trusted, &other, &trusted] {
        let mut x = in_order(order);
        assert!(skin.project(&mut x, order));
        pushed_to(&x, order);
        // A pass that finds them on the surface leaves them there.
        assert!(!skin.project(&mut x, order));
        pushed_to(&x, order);
    }
    skin.distrust_order();
    assert_eq!(skin.trusted_order, None);
}

#[test]
fn vertices_held_on_a_face_report_what_resolving_them_finds() {
    // Skin lying on a closed mesh at the thickness above its faces' centres, nudged by steps
    // around the tolerance as a converging relaxation does, now and then by a larger one: the
    // passes that skip the vertices held inside a face leave the positions and the active
    // contacts bit for bit as passes that resolve every touching vertex.
    let (v, t) = blob(20, 30);
    let collider = ColliderMesh::from_mesh(v.clone(), t.clone()).unwrap();
    let h = 0.01;
    let config = ContactConfig {
        thickness_m: h,
        ..ContactConfig::DEFAULT
    };
    let mut rng = Lcg(5);
    let n = 600;
    let x: Vec<Vec3> = (0..n)
        .map(|k| {
            let [a, b, c] = t[(k * 7) % t.len()].map(|i| v[i as usize]);
            (a + b + c) / 3.0 + (b - a).cross(c - a).normalize() * h
        })
        .collect();
    let order: Vec<u32> = (0..n as u32).rev().collect();
    // Steps of 0.05 to 2 µm, one in ten of 0.1 mm.
    let (skipped, contacts) = holds_match_resolving(&collider, config, x, &order, 40, |a| {
        a.iter()
            .map(|p| {
                let size = if rng.next() < 0.1 {
                    1e-4
                } else {
                    2e-6 * rng.next().powi(3)
                };
                *p + Vec3::new(rng.next() - 0.5, rng.next() - 0.5, rng.next() - 0.5) * size
            })
            .collect()
    });
    // Every vertex touches the blob: only holds can skip one.
    assert!(
        contacts == n && skipped > (n as u64) * 10,
        "{contacts} contacts, {skipped} skipped"
    );
}

/// Projects `x` (in the solver's `order`) `passes` times with face holds and without, moving
/// the positions by `step` after each pass (held as a solver holds them: lifted back when they
/// drift outward); both give the same positions and contacts bit for bit. Returns the vertices
/// the holds skipped and the contacts after the last pass.
fn holds_match_resolving(
    collider: &ColliderMesh,
    config: ContactConfig,
    mut x: Vec<Vec3>,
    order: &[u32],
    passes: u32,
    mut step: impl FnMut(&[Vec3]) -> Vec<Vec3>,
) -> (u64, usize) {
    let n = x.len();
    let mut held = SkinCollision::new(n, config).unwrap();
    let mut fresh = SkinCollision::new(n, config).unwrap();
    for s in [&mut held, &mut fresh] {
        s.add_collider(collider.clone());
    }
    fresh.face_holds = false;
    for pass in 0..passes {
        let (mut a, mut b) = (x.clone(), x.clone());
        for (s, x) in [(&mut held, &mut a), (&mut fresh, &mut b)] {
            s.project(x, order);
            let all = vec![true; s.active_contacts().len()];
            s.hold(&all);
        }
        assert_eq!(a, b, "pass {pass}: positions");
        assert_eq!(
            held.active_contacts(),
            fresh.active_contacts(),
            "pass {pass}: contacts"
        );
        assert_eq!(held.diagnostics().contacts, fresh.diagnostics().contacts);
        x = step(&a);
    }
    assert_eq!(fresh.diagnostics().skipped_vertices, 0);
    (
        held.diagnostics().skipped_vertices,
        fresh.active_contacts().len(),
    )
}

#[test]
fn vertices_held_near_a_face_s_edge_report_what_resolving_them_finds() {
    // Skin a thickness above points a fraction of a millimetre inside a face's edge, on a
    // blob bent into bulges and a dent (convex and concave edges both): over a 1 cm skin the
    // neighbour across that edge is farther than the face by only `e² / 2h` (~5-50 µm), so
    // the holds that let such vertices slide tens of microns come from the prism (`Prism`):
    // the vertices beyond an edge and below the face. Passes with holds leave the positions
    // and contacts bit for bit as passes that resolve every touching vertex.
    let (v, t) = blob(20, 30);
    let v = deform(&v, 0.3);
    let collider = ColliderMesh::from_mesh(v.clone(), t.clone()).unwrap();
    let h = 0.01;
    let config = ContactConfig {
        thickness_m: h,
        ..ContactConfig::DEFAULT
    };
    let mut rng = Lcg(17);
    let n = 600;
    let normals: Vec<Vec3> = (0..n)
        .map(|k| {
            let [a, b, c] = t[(k * 7) % t.len()].map(|i| v[i as usize]);
            (b - a).cross(c - a).normalize()
        })
        .collect();
    let x: Vec<Vec3> = (0..n)
        .map(|k| {
            let [a, b, c] = t[(k * 7) % t.len()].map(|i| v[i as usize]);
            // Near edge `ab` (0.2-0.6 mm inside), a random way along it.
            let (along, inside) = (0.2 + 0.6 * rng.next(), 0.004 + 0.012 * rng.next());
            let p = a * (1.0 - along) * (1.0 - inside) + b * along * (1.0 - inside) + c * inside;
            p + normals[k] * h
        })
        .collect();
    let order: Vec<u32> = (0..n as u32).collect();
    // Sliding steps of 10-40 µm (more than the distance margins allow), now and then 1 mm
    // (across the edge, or off it).
    let (skipped, _) = holds_match_resolving(&collider, config, x, &order, 60, |a| {
        a.iter()
            .zip(&normals)
            .map(|(p, n)| {
                let step = Vec3::new(rng.next() - 0.5, rng.next() - 0.5, rng.next() - 0.5);
                if rng.next() < 0.05 {
                    *p + step * 1e-3
                } else {
                    // Along the face the vertex started on.
                    *p + (step - *n * n.dot(step)).normalize_or_zero() * (1e-5 + 3e-5 * rng.next())
                }
            })
            .collect()
    });
    // Holds by the distance margins alone skip ~2,300 vertices here (their radii, a few
    // microns, are shorter than the steps); the prism's skip several times as many.
    assert!(skipped > (n as u64) * 10, "{skipped} skipped");
}

/// The solver gathers the forces again only around the vertices a projection names as moved
/// (`Projection::moved_vertices`): every vertex whose position changed must be named.
#[test]
fn a_projection_names_every_vertex_it_moves() {
    let (v, t) = blob(20, 30);
    let h = 0.01;
    let config = ContactConfig {
        thickness_m: h,
        ..ContactConfig::DEFAULT
    };
    let mut skin = SkinCollision::new(400, config).unwrap();
    skin.add_collider(ColliderMesh::from_mesh(v.clone(), t.clone()).unwrap());
    let mut rng = Lcg(11);
    // Around the blob's faces, from inside it to beyond the band.
    let mut x: Vec<Vec3> = (0..400)
        .map(|k| {
            let [a, b, c] = t[(k * 13) % t.len()].map(|i| v[i as usize]);
            (a + b + c) / 3.0 + (b - a).cross(c - a).normalize() * h * (4.0 * rng.next() - 1.5)
        })
        .collect();
    let order: Vec<u32> = (0..400).rev().collect();
    let mut named_any = 0;
    for pass in 0..20 {
        let before = x.clone();
        skin.project(&mut x, &order);
        let mut named = skin.moved_vertices().expect("the skin names them").to_vec();
        named.sort_unstable();
        let changed: Vec<u32> = (0..x.len() as u32)
            .filter(|&i| {
                let i = i as usize;
                x[i].to_array().map(f32::to_bits) != before[i].to_array().map(f32::to_bits)
            })
            .collect();
        assert!(
            changed.iter().all(|i| named.binary_search(i).is_ok()),
            "pass {pass}: moved {changed:?}, named {named:?}"
        );
        named_any += named.len();
        let all = vec![true; skin.active_contacts().len()];
        skin.hold(&all);
        for p in &mut x {
            *p += Vec3::new(rng.next() - 0.5, rng.next() - 0.5, rng.next() - 0.5) * 2e-3;
        }
    }
    assert!(named_any > 400, "projections moved vertices: {named_any}");
}

/// The same projection without `project_step_deferred`, so that its passes after a step run
/// after the solver's force gather (not alongside it) and write the positions themselves;
/// without `project_step` too when `steps` is false (the trait's default: a whole pass after
/// every step, the last positions copied), for comparison.
struct AfterTheGather<'a> {
    inner: &'a mut SkinCollision,
    steps: bool,
}

impl Projection for AfterTheGather<'_> {
    fn project(&mut self, x: &mut [Vec3], order: &[u32]) -> bool {
        self.inner.project(x, order)
    }

    fn project_step(&mut self, x: &mut [Vec3], order: &[u32], step: &Step<'_>) -> bool {
        if self.steps {
            self.inner.project_step(x, order, step)
        } else {
            self.inner.project(x, order)
        }
    }

    fn settled(&mut self, x: &[Vec3]) {
        if self.steps {
            self.inner.settled(x);
        }
    }

    fn active_contacts(&self) -> &[ActiveContact] {
        self.inner.active_contacts()
    }

    fn moved_vertices(&self) -> Option<&[u32]> {
        self.inner.moved_vertices()
    }

    fn hold(&mut self, held: &[bool]) {
        self.inner.hold(held);
    }
}

/// After a solver's step a pass skips whole blocks of vertices that the step's motion bound
/// keeps clear, and takes the swept test's last positions from the step: the answers and
/// every counter but the blocks' must be those of whole passes, solve after solve, whether
/// the pass runs alongside the solver's force gather (as `SkinCollision` does) or after it.
#[test]
fn passes_after_a_step_skip_blocks_and_answer_as_whole_passes() {
    let config = RelaxConfig {
        max_iterations: 400,
        tolerance: 1e-5,
        ..RelaxConfig::DEFAULT
    };
    let (mut stepped, mut with_steps) = Drape::new(41);
    let (mut whole, mut without) = Drape::new(41);
    let (mut after, mut after_gather) = Drape::new(41);
    let bits = |x: &[Vec3]| -> Vec<[u32; 3]> {
        x.iter().map(|p| p.to_array().map(f32::to_bits)).collect()
    };
    for solve in 0..3 {
        let a = stepped.relax(&config, &mut with_steps);
        let b = whole.relax(
            &config,
            &mut AfterTheGather {
                inner: &mut without,
                steps: false,
            },
        );
        let c = after.relax(
            &config,
            &mut AfterTheGather {
                inner: &mut after_gather,
                steps: true,
            },
        );
        assert_eq!(format!("{a:?}"), format!("{b:?}"), "solve {solve}");
        assert_eq!(format!("{a:?}"), format!("{c:?}"), "solve {solve}");
        assert_eq!(bits(&stepped.x), bits(&whole.x), "solve {solve}");
        assert_eq!(bits(&stepped.x), bits(&after.x), "solve {solve}");
        assert_eq!(with_steps.active_contacts(), after_gather.active_contacts());
        assert_eq!(with_steps.active_contacts(), without.active_contacts());
        let (s, w) = (with_steps.diagnostics(), without.diagnostics());
        let counters = |d: &ContactDiagnostics| {
            (
                d.contacts,
                d.passes,
                d.moved,
                d.exact_queries,
                d.certified_queries,
                d.skipped_aabb,
                d.skipped_bound,
                d.skipped_vertices,
                d.swept_hits,
                d.unresolved.clone(),
            )
        };
        let g = after_gather.diagnostics();
        assert_eq!(counters(g), counters(w), "solve {solve}");
        // Alongside the gather: the same work, but for the trial steps the solve rejected
        // after such a pass (solves 1 and 2 have some): one more pass for each, at most two
        // a solve (a rejection-prone solve then projects after the gather).
        if solve == 0 {
            assert_eq!(counters(s), counters(w), "solve {solve}");
            assert_eq!(s.skipped_in_blocks, g.skipped_in_blocks, "solve {solve}");
        } else {
            assert!(
                s.passes > w.passes && s.passes <= w.passes + 2 * solve,
                "solve {solve}"
            );
        }
        assert_eq!(w.skipped_in_blocks, 0);
        // From the second solve on, the sweeps have something to stop.
        assert!(solve == 0 || s.swept_hits > 0, "solve {solve}: no sweep");
        // Most of the sheet hangs clear of the ball: most of its skips come in whole blocks.
        assert!(
            s.skipped_in_blocks > s.skipped_vertices / 2,
            "solve {solve}: {s:?}"
        );
        eprintln!("solve {solve}: {a:?} {s:?}");
        // The next solve starts from the sheet pushed 3 cm down into the ball and sideways:
        // its first pass sweeps from the last positions the solve reported
        // (`Projection::settled`), and stops the vertices that crossed the surface.
        for x in [&mut stepped.x, &mut whole.x, &mut after.x] {
            for p in x.iter_mut() {
                *p += Vec3::new(0.004, -0.002, -0.03);
            }
        }
    }
}
