//! Mesh colliders in BVH parts answer exactly as one parry mesh over every triangle.

use glam::Vec3;
use parry3d::math::Pose;
use parry3d::query::{Ray, RayCast};
use parry3d::shape::{CompositeShapeRef, TriMesh as ParryMesh};

use super::*;
use crate::collision::cache::{Answer, Patch, Slot};
use crate::collision::shapes::ellipsoid;

/// A small deterministic generator (64-bit LCG; also used by the eight-lane distances' tests).
pub(super) struct Lcg(pub(super) u64);

impl Lcg {
    /// Uniform in [0, 1).
    pub(super) fn next(&mut self) -> f32 {
        self.0 = self
            .0
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        (self.0 >> 40) as f32 / (1u64 << 24) as f32
    }

    /// Uniform in the cube [-s, s]³.
    pub(super) fn point(&mut self, s: f32) -> Vec3 {
        Vec3::new(self.next(), self.next(), self.next()) * (2.0 * s) - Vec3::splat(s)
    }
}

/// The bench muscle's shape, coarser.
fn muscle(n_lat: u32, n_lon: u32) -> (Vec<Vec3>, Vec<[u32; 3]>) {
    ellipsoid(Vec3::ZERO, Vec3::new(0.04, 0.035, 0.15), n_lat, n_lon).unwrap()
}

/// A smooth deformation of the rest shape (a travelling bulge and a twist).
fn deform(rest: &[Vec3], phase: f32) -> Vec<Vec3> {
    rest.iter()
        .map(|p| {
            let bulge = 1.0 + 0.12 * (30.0 * p.z + phase).sin() * (3.0 * p.y.atan2(p.x)).cos();
            let twist = glam::Quat::from_rotation_z(2.0 * p.z * phase.cos());
            twist * Vec3::new(p.x * bulge, p.y * bulge, p.z * (1.0 + 0.05 * phase.sin()))
        })
        .collect()
}

fn mesh(c: &ColliderMesh) -> &MeshShape {
    match &c.shape {
        Shape::Mesh(m) => m,
        _ => unreachable!("a mesh collider"),
    }
}

/// The parts of `m` fitted to its live vertices (see `Parts::fingerprint`).
fn fingerprint(m: &MeshShape) -> Vec<(Vec<[u32; 3]>, Vec<parts::Visited>)> {
    m.parts.fingerprint(&m.live)
}

fn bits(p: &SurfaceProjection) -> [u32; 11] {
    let [a, b, c] = p.point.to_array().map(f32::to_bits);
    let [d, e, f] = p.normal.to_array().map(f32::to_bits);
    let [g, h, i] = p.coords.to_array().map(f32::to_bits);
    [
        a,
        b,
        c,
        d,
        e,
        f,
        p.signed_distance.to_bits(),
        p.part,
        g,
        h,
        i,
    ]
}

fn aabb_bits(a: &Aabb) -> [u32; 6] {
    let [a0, a1, a2] = a.mins.to_array().map(f32::to_bits);
    let [b0, b1, b2] = a.maxs.to_array().map(f32::to_bits);
    [a0, a1, a2, b0, b1, b2]
}

/// Query points around the surface of `c`: deep inside, outside, within a few mm, on the
/// vertices, and out from the vertices along their normals (their closest feature is the
/// vertex itself, an exact tie between the triangles around it).
fn probes(c: &ColliderMesh, rng: &mut Lcg) -> Vec<Vec3> {
    let m = mesh(c);
    let v = &m.live;
    let mut out = Vec::new();
    for k in 0..1200 {
        let p = v[(k * 7919) % v.len()];
        out.push(match k % 6 {
            0 => p * (0.1 + 0.85 * rng.next()),
            1 => p * (1.1 + 1.5 * rng.next()) + rng.point(0.01),
            2 | 3 => p + rng.point(0.003),
            4 => p,
            _ => p + m.vertex_normal(((k * 7919) % v.len()) as u32) * (0.01 * rng.next()),
        });
    }
    out
}

/// Triangles around mesh vertex `vertex` whose parry distance to `p` equals the best one's
/// exactly.
fn tied(m: &MeshShape, vertex: usize, p: Vec3) -> usize {
    let around = &m.vt[m.vt_offsets[vertex] as usize..m.vt_offsets[vertex + 1] as usize];
    let d: Vec<f32> = around
        .iter()
        .map(|&t| m.triangle_projection(t, p).0)
        .collect();
    let best = d.iter().copied().fold(f32::INFINITY, f32::min);
    d.iter().filter(|&&x| x == best).count()
}

/// Checks every query of `split` against one parry mesh over all triangles (`reference`, in
/// the same shape, built at rest and refitted like the collider) and against `whole` (the
/// same collider in one part); returns how many vertex probes were exact ties of two or more
/// triangles.
fn assert_same_answers(
    split: &ColliderMesh,
    whole: &ColliderMesh,
    reference: &ParryMesh,
    points: &[Vec3],
    rng: &mut Lcg,
    what: &str,
) -> usize {
    let (ms, mw) = (mesh(split), mesh(whole));
    assert_eq!(
        aabb_bits(split.local_aabb()),
        aabb_bits(&reference.local_aabb()),
        "{what}: box"
    );
    assert_eq!(ms.live, reference.vertices(), "{what}: vertices");
    let mut ties = 0;
    for (k, &p) in points.iter().enumerate() {
        // parry's search over the whole mesh: same triangle, same point, same feature.
        let got = ms.search(p, f32::MAX).unwrap();
        let want = CompositeShapeRef(reference)
            .project_local_point_and_get_location(p, f32::MAX, false)
            .unwrap();
        assert_eq!(got.0, want.0, "{what}: triangle at probe {k} {p}");
        assert_eq!(got.1.point, want.1.point, "{what}: point at probe {k}");
        assert_eq!(
            format!("{:?}", got.2),
            format!("{:?}", want.2),
            "{what}: feature at probe {k}"
        );
        let plain = CompositeShapeRef(reference)
            .project_local_point(p, f32::MAX, false)
            .unwrap();
        assert_eq!(
            ms.search_point(p),
            Some(plain.0),
            "{what}: plain search {k}"
        );
        if k % 6 == 5 {
            let vertex = (k * 7919) % ms.live.len();
            if tied(ms, vertex, p) >= 2 {
                ties += 1;
            }
        }
        // The collider's answers, with and without a hint, capped or not.
        let hint = (k as u32 * 31) % ms.indices.len() as u32;
        for h in [NONE, hint, got.0] {
            assert_eq!(
                bits(&split.project_local(p, h)),
                bits(&whole.project_local(p, h)),
                "{what}: projection at probe {k}, hint {h}"
            );
        }
        assert_eq!(split.project_local(p, NONE).part, want.0);
        for cap in [0.001, 0.02, f32::MAX] {
            assert_eq!(
                split.distance_local_capped(p, cap).to_bits(),
                whole.distance_local_capped(p, cap).to_bits(),
                "{what}: capped distance at probe {k}"
            );
        }
        // Rays: the first hit of a segment, as parry's ray cast on the whole mesh.
        let delta = rng.point(0.05) + (Vec3::ZERO - p) * rng.next();
        let ray = Ray::new(p, delta);
        let hit = ms.cast_ray(&ray, 1.0);
        let want_hit = reference.cast_local_ray_and_get_normal(&ray, 1.0, false);
        assert_eq!(
            format!("{hit:?}"),
            format!("{want_hit:?}"),
            "{what}: ray from probe {k}"
        );
        assert_eq!(
            format!("{:?}", split.cast_local_segment(p, delta)),
            format!("{:?}", whole.cast_local_segment(p, delta)),
            "{what}: segment from probe {k}"
        );
    }
    assert_eq!(mw.parts.len(), 1);
    ties
}

/// A mesh cut into many parts (four levels above them) answers every query bit for bit as
/// one parry mesh over all its triangles, ties included, at rest, after `set_vertices` and
/// at an interpolated substep shape; and the contact cache's patches (which hold triangle
/// ids) give the same answers and certificates as in one part.
#[test]
fn split_mesh_answers_like_one_parry_mesh() {
    let (v, t) = muscle(40, 64);
    let mut split = ColliderMesh::from_mesh_in_parts(v.clone(), t.clone(), 300).unwrap();
    let mut whole = ColliderMesh::from_mesh_in_parts(v.clone(), t.clone(), usize::MAX).unwrap();
    let mut reference = ParryMesh::new(v.clone(), t.clone()).unwrap();
    let parts = &mesh(&split).parts;
    assert!(parts.len() >= 16, "{:?}", parts.sizes());
    assert!(parts.top_depth() >= 4);
    assert!(parts.sizes().iter().all(|&s| s <= 300));
    assert_eq!(parts.sizes().iter().sum::<usize>(), t.len());

    let mut rng = Lcg(17);
    let mut ties = 0;
    let shapes = [v.clone(), deform(&v, 0.7), deform(&v, 2.9)];
    for (i, shape) in shapes.iter().enumerate() {
        if i > 0 {
            split.set_vertices(shape).unwrap();
            whole.set_vertices(shape).unwrap();
            reference.set_vertices(shape);
        }
        let points = probes(&split, &mut rng);
        ties += assert_same_answers(
            &split,
            &whole,
            &reference,
            &points,
            &mut rng,
            &format!("shape {i}"),
        );
    }
    // Half way between the last two shapes, as a substep puts it.
    for c in [&mut split, &mut whole] {
        c.commit_frame();
        c.set_vertices(&shapes[1]).unwrap();
        c.enter_substep(0.5, &Pose::IDENTITY, true);
    }
    let halfway: Vec<Vec3> = shapes[2]
        .iter()
        .zip(&shapes[1])
        .map(|(a, b)| a.lerp(*b, 0.5))
        .collect();
    reference.set_vertices(&halfway);
    let points = probes(&split, &mut rng);
    ties += assert_same_answers(&split, &whole, &reference, &points, &mut rng, "substep");
    assert!(ties > 100, "only {ties} exact ties exercised");

    // Cached answers: patches hold mesh triangle ids, certificates hold as in one part.
    split.enter_substep(1.0, &Pose::IDENTITY, true);
    whole.enter_substep(1.0, &Pose::IDENTITY, true);
    let mut points = probes(&split, &mut rng);
    let new = (Slot::NEW, Patch::NEW);
    let mut slots = vec![(new, new); points.len()];
    let mut certified = 0;
    for pass in 0..8 {
        let step = 0.0005 * 0.7f32.powi(pass);
        for (k, (p, (a, b))) in points.iter_mut().zip(&mut slots).enumerate() {
            *p += rng.point(step);
            let got = a.0.project(&mut a.1, &split, *p, split.travel_m(), 0.004);
            let want = b.0.project(&mut b.1, &whole, *p, whole.travel_m(), 0.004);
            assert_eq!(bits(&got.0), bits(&want.0), "pass {pass} probe {k}");
            assert_eq!(got.1, want.1, "pass {pass} probe {k}");
            certified += usize::from(got.1 == Answer::Certified);
        }
    }
    assert!(certified > points.len(), "{certified} certified answers");
}

/// Parts refitted on one rayon thread or two (by queries after the moves) are the same parts,
/// bit for bit, and so give the same answers.
#[test]
fn refit_is_the_same_on_one_and_two_threads() {
    let (v, t) = muscle(48, 80);
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let two = rayon::ThreadPoolBuilder::new()
        .num_threads(2)
        .build()
        .unwrap();
    let base = ColliderMesh::from_mesh_in_parts(v.clone(), t, 1000).unwrap();
    assert!(mesh(&base).parts.len() >= 4);
    let (mut a, mut b) = (base.clone(), base);
    for (pool, c) in [(&one, &mut a), (&two, &mut b)] {
        pool.install(|| {
            c.set_vertices(&deform(&v, 1.3)).unwrap();
            c.commit_frame();
            c.set_vertices(&deform(&v, 2.1)).unwrap();
            c.enter_substep(0.25, &Pose::IDENTITY, true);
            // The parts are refitted by the queries that reach them, from the pool's threads.
            let points = probes(c, &mut Lcg(5));
            let c = &*c;
            points.par_iter().for_each(|p| {
                c.project_local(*p, NONE);
            });
        });
    }
    assert_eq!(fingerprint(mesh(&a)), fingerprint(mesh(&b)), "parts");
    assert_eq!(aabb_bits(a.local_aabb()), aabb_bits(b.local_aabb()));
    assert_eq!(a.travel_m().to_bits(), b.travel_m().to_bits());
    let mut rng = Lcg(3);
    for p in probes(&a, &mut rng) {
        assert_eq!(
            bits(&a.project_local(p, NONE)),
            bits(&b.project_local(p, NONE))
        );
    }
}

/// The bench's 50k-triangle muscle (four parts, 25k vertices: several of `set_vertices`'
/// checks) refitted inside a pool of one thread, of two, and from a thread outside any pool
/// (the bench's and the ECS's case: the caller works next to the pool's threads): the same
/// parts bit for bit, the answers of parry's own mesh refitted to the same shapes, and the
/// motion and deformation bounds of a serial read of the shapes.
#[test]
fn bench_muscle_refits_alike_in_and_out_of_pools() {
    let (v, t) = muscle(126, 200);
    assert!(v.len() > 4 * CHECK_CHUNK, "{} vertices", v.len());
    let shapes = [deform(&v, 0.6), deform(&v, 1.9)];
    let base = ColliderMesh::from_mesh(v.clone(), t.clone()).unwrap();
    assert!(
        mesh(&base).parts.len() >= 4,
        "{:?}",
        mesh(&base).parts.sizes()
    );
    let run = |c: &mut ColliderMesh| {
        c.set_vertices(&shapes[0]).unwrap();
        c.commit_frame();
        c.set_vertices(&shapes[1]).unwrap();
    };
    let mut runs = vec![base.clone(), base.clone(), base];
    crate::test_support::in_pool(1, || run(&mut runs[0]));
    crate::test_support::in_pool(2, || run(&mut runs[1]));
    run(&mut runs[2]);
    for c in &runs[1..] {
        assert_eq!(fingerprint(mesh(c)), fingerprint(mesh(&runs[0])));
    }
    // The bounds: the largest displacements, read serially.
    let largest = |a: &[Vec3], b: &[Vec3]| {
        a.iter()
            .zip(b)
            .map(|(a, b)| a.distance_squared(*b))
            .fold(0.0f32, f32::max)
            .sqrt()
    };
    let travel = f64::from(largest(&v, &shapes[0])) + f64::from(largest(&shapes[0], &shapes[1]));
    let deform_m = largest(&shapes[0], &shapes[1]);
    for c in &runs {
        assert_eq!(c.travel_m().to_bits(), travel.to_bits());
        assert_eq!(c.frame_deform_m().to_bits(), deform_m.to_bits());
    }
    let mut reference = ParryMesh::new(v.clone(), t.clone()).unwrap();
    reference.set_vertices(&shapes[1]);
    let mut whole = ColliderMesh::from_mesh_in_parts(v.clone(), t, usize::MAX).unwrap();
    whole.set_vertices(&shapes[1]).unwrap();
    let mut rng = Lcg(29);
    let points: Vec<Vec3> = probes(&runs[1], &mut rng).into_iter().step_by(4).collect();
    assert_same_answers(
        &runs[1],
        &whole,
        &reference,
        &points,
        &mut rng,
        "two threads",
    );

    // A non-finite vertex in a late check and another in the last: the first is named, the
    // collider is left exactly as it was, on any pool.
    let mut bad = deform(&v, 2.7);
    let (first, last) = (3 * CHECK_CHUNK + 11, v.len() - 2);
    bad[first].z = f32::NAN;
    bad[last].x = f32::NEG_INFINITY;
    for (k, c) in runs.iter_mut().enumerate() {
        let before = fingerprint(mesh(c));
        let aabb = aabb_bits(c.local_aabb());
        let mut refresh = || c.set_vertices(&bad);
        let result = match k {
            0 => crate::test_support::in_pool(1, refresh),
            1 => crate::test_support::in_pool(2, refresh),
            _ => refresh(),
        };
        match result {
            Err(CollisionError::NonFinite { index, .. }) => assert_eq!(index, first),
            other => panic!("expected NonFinite, got {other:?}"),
        }
        assert_eq!(fingerprint(mesh(c)), before);
        assert_eq!(aabb_bits(c.local_aabb()), aabb);
        assert_eq!(mesh(c).live, shapes[1]);
        assert_eq!(mesh(c).current, shapes[1]);
        assert_eq!(c.travel_m().to_bits(), travel.to_bits());
        assert_eq!(c.frame_deform_m().to_bits(), deform_m.to_bits());
    }
}

/// A split mesh refits a part when a query first reaches it, or at the move after one did:
/// after a move with no query since the last, no part is fitted; queries at one tip of the
/// bench's muscle fit a few of its parts and answer as parry's mesh over all the triangles
/// refitted to the new shape; a clone taken while every part waits answers every probe bit
/// for bit alike with its queries run from two threads at once, each part it needs refitted
/// once; the next move refits the parts queries entered, and only those.
#[test]
fn parts_are_refitted_when_a_query_first_reaches_them() {
    let (v, t) = muscle(126, 200);
    let mut c = ColliderMesh::from_mesh(v.clone(), t.clone()).unwrap();
    let n = c.part_count();
    assert!(n >= 8, "{n} parts");
    assert_eq!(mesh(&c).parts.fitted(), n);
    let shape = deform(&v, 1.1);
    let before = c.refit_stats();
    c.set_vertices(&shape).unwrap();
    assert_eq!(mesh(&c).parts.fitted(), 0);
    assert_eq!(c.refit_stats(), before);
    let clone = c.clone();

    // Just outside the muscle's tip (its largest z), where few parts are.
    let mut reference = ParryMesh::new(v.clone(), t.clone()).unwrap();
    reference.set_vertices(&shape);
    let tip = shape
        .iter()
        .copied()
        .max_by(|a, b| a.z.total_cmp(&b.z))
        .unwrap();
    let tip_points: Vec<Vec3> = (0..20)
        .map(|k| tip + Vec3::new(0.0005 * k as f32, -0.0003 * k as f32, 0.002))
        .collect();
    for (k, &p) in tip_points.iter().enumerate() {
        let got = c.project_local(p, NONE);
        let want = CompositeShapeRef(&reference)
            .project_local_point(p, f32::MAX, false)
            .unwrap();
        assert_eq!(got.part, want.0, "probe {k}");
        assert_eq!(got.point, want.1.point, "probe {k}");
    }
    let fitted = mesh(&c).parts.fitted();
    assert!(
        fitted >= 1 && fitted <= n / 4,
        "{fitted} of {n} parts refitted"
    );
    let stats = c.refit_stats();
    assert_eq!(stats.parts_refitted - before.parts_refitted, fitted as u64);
    assert!(stats.seconds > before.seconds);

    // Every probe, on the original (some parts fitted) and on the clone (none) from two
    // threads at once.
    let points = probes(&c, &mut Lcg(41));
    let serial: Vec<_> = points
        .iter()
        .map(|p| bits(&c.project_local(*p, NONE)))
        .collect();
    let refitted = clone.refit_stats().parts_refitted;
    let parallel: Vec<_> = crate::test_support::in_pool(2, || {
        points
            .par_iter()
            .map(|p| bits(&clone.project_local(*p, NONE)))
            .collect()
    });
    assert_eq!(serial, parallel);
    let fitted = mesh(&clone).parts.fitted();
    assert!(fitted > n / 2, "{fitted} of {n}");
    assert_eq!(
        clone.refit_stats().parts_refitted - refitted,
        fitted as u64,
        "each part refitted once"
    );
    assert_eq!(fingerprint(mesh(&clone)), fingerprint(mesh(&c)));

    // The next move refits at once, in parallel, the parts that searches entered since the
    // last one (the skin most likely reaches them again): here every part. After searches at
    // the tip only, the move after refits only theirs; `refit_all` fits the others now, each
    // part once in all.
    c.set_vertices(&v).unwrap();
    assert_eq!(mesh(&c).parts.fitted(), n);
    for &p in &tip_points {
        c.project_local(p, NONE);
    }
    let before = c.refit_stats().parts_refitted;
    c.set_vertices(&shape).unwrap();
    let used = mesh(&c).parts.fitted();
    assert!(used >= 1 && used <= n / 4, "{used} of {n}");
    assert_eq!(c.refit_stats().parts_refitted - before, used as u64);
    c.refit_all();
    assert_eq!(mesh(&c).parts.fitted(), n);
    assert_eq!(c.refit_stats().parts_refitted - before, n as u64);
    c.refit_all();
    assert_eq!(c.refit_stats().parts_refitted - before, n as u64);
    // `refit_all` is no search: a move with no search since the last refits no part.
    c.set_vertices(&v).unwrap();
    assert_eq!(mesh(&c).parts.fitted(), 0);
}

/// A collider cloned while another thread's queries refit its parts is whole: every clone
/// answers as the original.
#[test]
fn clones_taken_during_refits_answer_alike() {
    let (v, t) = muscle(126, 200);
    let mut c = ColliderMesh::from_mesh(v.clone(), t).unwrap();
    let points = probes(&c, &mut Lcg(7));
    let want: Vec<_> = points
        .iter()
        .map(|p| bits(&c.project_local(*p, NONE)))
        .collect();
    for round in 0..3 {
        c.set_vertices(&v).unwrap();
        let c = &c;
        let clones = crate::test_support::in_pool(2, || {
            let (_, clones) = rayon::join(
                || {
                    points.par_iter().for_each(|p| {
                        c.project_local(*p, NONE);
                    })
                },
                || (0..40).map(|_| c.clone()).collect::<Vec<_>>(),
            );
            clones
        });
        for (k, clone) in clones.iter().enumerate() {
            let p = (k * 31 + round) % points.len();
            assert_eq!(bits(&clone.project_local(points[p], NONE)), want[p]);
        }
    }
}

/// The part rule: the bench's 50k-triangle muscle is held in parts of at most
/// [`parts::PART_TRIANGLES`] (more than one), a small mesh in one; `parry_mesh` is the whole
/// mesh in its current shape either way.
#[test]
fn part_rule_and_whole_parry_mesh() {
    let (v, t) = muscle(126, 200);
    assert_eq!(t.len(), 50_000);
    let mut big = ColliderMesh::from_mesh(v.clone(), t.clone()).unwrap();
    let sizes = mesh(&big).parts.sizes();
    assert!(sizes.len() >= 2, "{sizes:?}");
    assert!(
        sizes.iter().all(|&s| s <= parts::PART_TRIANGLES),
        "{sizes:?}"
    );
    assert_eq!(sizes.iter().sum::<usize>(), t.len());
    let shape = deform(&v, 0.4);
    big.set_vertices(&shape).unwrap();
    let parry = big.parry_mesh().unwrap();
    assert_eq!(parry.vertices(), &shape[..]);
    assert_eq!(parry.indices(), &t[..]);
    let (v, t) = muscle(12, 20);
    assert!(t.len() <= parts::PART_TRIANGLES);
    let small = ColliderMesh::from_mesh(v, t).unwrap();
    assert_eq!(mesh(&small).parts.len(), 1);
}

/// Bad input to a split mesh's refresh: a typed error naming the first non-finite vertex, or
/// the wrong length, and the collider left exactly as it was.
#[test]
fn split_refresh_rejects_bad_vertices_unchanged() {
    let (v, t) = muscle(40, 64);
    let mut c = ColliderMesh::from_mesh_in_parts(v.clone(), t, 500).unwrap();
    assert!(mesh(&c).parts.len() > 1);
    c.set_vertices(&deform(&v, 0.5)).unwrap();
    let before = (
        fingerprint(mesh(&c)),
        c.travel_m(),
        c.project_local(Vec3::X, NONE),
    );
    let mut bad = deform(&v, 0.9);
    bad[1234].y = f32::NAN;
    bad[2345].x = f32::INFINITY;
    match c.set_vertices(&bad) {
        Err(CollisionError::NonFinite { index, .. }) => assert_eq!(index, 1234),
        other => panic!("expected NonFinite, got {other:?}"),
    }
    match c.set_vertices(&bad[..100]) {
        Err(CollisionError::Length {
            given, expected, ..
        }) => assert_eq!((given, expected), (100, v.len())),
        other => panic!("expected Length, got {other:?}"),
    }
    let after = (
        fingerprint(mesh(&c)),
        c.travel_m(),
        c.project_local(Vec3::X, NONE),
    );
    assert_eq!(before.0, after.0);
    assert_eq!(before.1.to_bits(), after.1.to_bits());
    assert_eq!(bits(&before.2), bits(&after.2));
    assert_eq!(mesh(&c).current, deform(&v, 0.5));
}

/// The certified patch query with its lean distances eight at a time (AVX2) answers bit for bit
/// as with them one at a time, and as parry's search of the whole mesh: over a deforming
/// muscle, for points near the surface that moved from where their patch was built by up to
/// a few millimetres (slack large enough that triangles past the first eight are compared), and
/// for points whose certificate fails (both paths fall back to a search: `None`).
#[test]
fn patch_answers_eight_at_a_time_equal_one_at_a_time_and_parry() {
    let (rest, t) = muscle(24, 40);
    let mut col = ColliderMesh::from_mesh(rest.clone(), t).unwrap();
    col.set_vertices(&deform(&rest, 0.7)).unwrap();
    let m = mesh(&col);
    let parry = col.parry_mesh().unwrap();
    let mut rng = Lcg(23);
    let (mut certified, mut failed, mut second_batch) = (0, 0, 0);
    for k in 0..3000 {
        let v = m.live[(k * 7919) % m.live.len()];
        let at = v + v.normalize_or_zero() * 0.002 + rng.point(0.002);
        let mut built = Patch::NEW;
        m.project_and_certify(at, NONE, 0.01, &mut built);
        assert_eq!(built.len as usize, PATCH, "probe {k}: a full patch");
        let moved = [1e-5, 3e-4, 2e-3, 8e-3][k % 4];
        let p = at + rng.point(moved);
        let slack = p.distance(at) * (1.0 + 1e-6) + 1e-5 * (p.abs().max_element() + 0.1);
        let (mut wide, mut narrow) = (built, built);
        let a = m.project_on_patch_with(p, &mut wide, slack, true);
        let b = m.project_on_patch_with(p, &mut narrow, slack, false);
        assert_eq!(a.map(|r| bits(&r)), b.map(|r| bits(&r)), "probe {k}");
        assert_eq!(wide.best, narrow.best, "probe {k}");
        let Some(got) = a else {
            failed += 1;
            continue;
        };
        certified += 1;
        // The answer's triangle is (one of) the closest of the whole mesh: parry's distance,
        // and parry's point on that triangle.
        let want = parry.project_local_point(p, false);
        let dist = want.point.distance(p);
        assert!(
            (got.signed_distance.abs() - dist).abs() <= 1e-6 * (1.0 + dist),
            "probe {k}: {} against parry {dist}",
            got.signed_distance
        );
        let (_, own, _) = m.triangle_projection(got.part, p);
        assert_eq!(got.point, own.point, "probe {k}");
        // Triangles past the first eight were within the slack of the answer.
        if built.dist[lean::LANES] - slack <= dist {
            second_batch += 1;
        }
    }
    assert!(certified > 1000 && failed > 100, "{certified} / {failed}");
    assert!(second_batch > 100, "{second_batch}");
}

/// Lanes past a short patch may hold stale or missing triangles (out of range): they are never
/// read, and the distances of the patch's own triangles are the scalar ones.
#[test]
fn short_patches_ignore_the_lanes_past_their_end() {
    let (rest, t) = muscle(12, 16);
    let col = ColliderMesh::from_mesh(rest, t).unwrap();
    let m = mesh(&col);
    let mut patch = Patch::NEW;
    let p = m.live[5] * 1.05;
    m.project_and_certify(p, NONE, 0.01, &mut patch);
    patch.len = 3;
    for (k, t) in patch.tris.iter_mut().enumerate().skip(3) {
        *t = if k % 2 == 0 {
            NONE
        } else {
            m.indices.len() as u32 + k as u32
        };
    }
    let mut batches = Batches::new(m, &patch, p, true);
    for k in 0..3 {
        assert_eq!(
            batches.get(k).to_bits(),
            m.triangle_distance(patch.tris[k], p).to_bits(),
            "triangle {k}"
        );
    }
    // The wide path stayed on when the CPU has it (the bad lanes were past the end).
    assert_eq!(batches.wide, lean::available());
}

/// The frame deformation the plan reads ([`ColliderMesh::frame_deform_m`]), kept by
/// `set_vertices` and `commit_frame`, is the largest vertex displacement since the last
/// committed frame, computed here from the shapes given: across two refreshes in one frame,
/// after a commit (none), and unchanged by a refresh rejected for a non-finite vertex.
#[test]
fn frame_deformation_is_the_largest_displacement_since_the_last_frame() {
    let (v, t) = muscle(20, 32);
    let largest = |a: &[Vec3], b: &[Vec3]| {
        a.iter()
            .zip(b)
            .map(|(a, b)| f64::from(a.distance(*b)))
            .fold(0.0f64, f64::max)
    };
    let mut c = ColliderMesh::from_mesh(v.clone(), t).unwrap();
    assert_eq!(c.frame_deform_m(), 0.0);
    let (one, two) = (deform(&v, 0.4), deform(&v, 1.1));
    c.set_vertices(&one).unwrap();
    let expected = largest(&v, &one);
    assert!(expected > 1e-3);
    assert!((f64::from(c.frame_deform_m()) - expected).abs() <= 1e-6 * expected);
    // A second refresh in the same frame: measured from the last frame's shape, not `one`.
    c.set_vertices(&two).unwrap();
    let expected = largest(&v, &two);
    assert!((f64::from(c.frame_deform_m()) - expected).abs() <= 1e-6 * expected);
    assert_eq!(c.frame_motion_m(), c.frame_deform_m());
    let kept = c.frame_deform_m();
    let mut bad = deform(&v, 2.0);
    bad[7].z = f32::NAN;
    assert!(c.set_vertices(&bad).is_err());
    assert_eq!(c.frame_deform_m().to_bits(), kept.to_bits());
    c.commit_frame();
    assert_eq!(c.frame_deform_m(), 0.0);
    let three = deform(&v, 1.5);
    c.set_vertices(&three).unwrap();
    let expected = largest(&two, &three);
    assert!((f64::from(c.frame_deform_m()) - expected).abs() <= 1e-6 * expected);
}

#[test]
fn a_point_over_a_face_leaves_along_the_face_normal_exactly() {
    // Inside a face the closest point's direction is the face's normal: the projection gives
    // it bit for bit, from outside and from inside (outward both ways), not the rounded
    // direction of `p − point`.
    let (v, t) = muscle(12, 16);
    let c = ColliderMesh::from_mesh(v.clone(), t.clone()).unwrap();
    let mut faces = 0;
    for (k, tri) in t.iter().enumerate().step_by(7) {
        let [a, b, cc] = tri.map(|i| v[i as usize]);
        let n = (b - a).cross(cc - a).normalize_or_zero();
        let centre = (a + b + cc) / 3.0;
        for offset in [2e-3, -1e-4] {
            let p = c.project_point(centre + n * offset);
            if p.part != k as u32 {
                continue; // Another triangle is closer (a concave spot).
            }
            faces += 1;
            assert_eq!(p.normal, n, "triangle {k}, offset {offset}");
            assert_eq!(p.signed_distance > 0.0, offset > 0.0);
        }
    }
    assert!(faces > t.len() / 8, "{faces} faces checked");
}
