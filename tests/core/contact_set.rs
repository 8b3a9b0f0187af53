//! A contact solve on the bench's arm: the held set settles instead of flickering, and the
//! answer meets the contact problem's conditions, checked on the analytic colliders.

use std::collections::HashMap;

use dermis::bench::arm::{ArmWorkload, HUMERUS, THICKNESS_M, ULNA, analytic_clearance};
use dermis::collision::SkinCollision;
use dermis::solver::{ActiveContact, Loads, Projection, RelaxConfig, StopReason};
use glam::Vec3;

/// The arm's contact, counting how often each vertex becomes held again after a release.
struct Counting<'a> {
    inner: &'a mut SkinCollision,
    held: HashMap<u32, bool>,
    rehold: HashMap<u32, u32>,
}

impl Projection for Counting<'_> {
    fn project(&mut self, x: &mut [Vec3], order: &[u32]) -> bool {
        self.inner.project(x, order)
    }

    fn active_contacts(&self) -> &[ActiveContact] {
        self.inner.active_contacts()
    }

    fn hold(&mut self, held: &[bool]) {
        let mut now: HashMap<u32, bool> = HashMap::new();
        for (c, &h) in self.inner.active_contacts().iter().zip(held) {
            *now.entry(c.vertex).or_default() |= h;
        }
        for (&v, &h) in &now {
            let before = self.held.get(&v).copied();
            if h && before == Some(false) {
                *self.rehold.entry(v).or_default() += 1;
            }
        }
        for (v, h) in self.held.iter_mut() {
            if !now.contains_key(v) {
                *h = false;
            }
        }
        self.held.extend(now);
        self.inner.hold(held);
    }
}

/// Distance from `p` to the segment `a`–`b`, and the outward unit normal there.
fn segment(p: Vec3, a: Vec3, b: Vec3) -> (f32, Vec3) {
    let ab = b - a;
    let t = ((p - a).dot(ab) / ab.length_squared()).clamp(0.0, 1.0);
    let q = p - (a + ab * t);
    (q.length(), q.normalize_or_zero())
}

/// One settling solve of the small arm at full flexion (the skin starts at its skinned anchors,
/// deep in the muscle and the ulna). With the proportioning release the contacts at the rim
/// of the patches stop flickering: measured 164 iterations and 44 re-holds (at most 11 of one
/// vertex), against 306 iterations and 195 re-holds (42) with the previous policy (each
/// contact released as soon as its force turned), at the same energy to 3e-7. The answer is
/// checked on the analytic shapes: no vertex inside, the vertices clear of every collider
/// force-free, and the vertices on the (exact) bone capsules pushed straight into them.
#[test]
fn arm_contacts_settle_and_meet_the_contact_conditions() {
    let work = ArmWorkload::new("arm-contact", 2_000, (26, 40), 12);
    let frame = 6;
    let (mut contact, _) = work.collision(frame).unwrap();
    let anchors = work.anchors(frame);
    let mut x: Vec<Vec3> = anchors.iter().map(|a| a.target).collect();
    contact.contact_pass(&mut x).unwrap();
    let loads = Loads {
        anchors: Some(&anchors),
        ..Default::default()
    };
    let config = RelaxConfig {
        max_iterations: 2000,
        stagnation_window: 0,
        ..work.relax_config()
    };
    let mut counting = Counting {
        inner: &mut contact,
        held: HashMap::new(),
        rehold: HashMap::new(),
    };
    let report = work
        .tube
        .system
        .relax_projected(&mut x, &loads, &config, Some(&mut counting))
        .unwrap();
    let most = counting.rehold.values().copied().max().unwrap_or(0);
    let total: u32 = counting.rehold.values().sum();
    eprintln!("{report:?}; re-held: {total} in all, at most {most} per vertex");
    assert_eq!(report.stop, StopReason::Converged, "{report:?}");
    assert!(report.iterations <= 250, "{report:?}");
    assert!(
        total <= 120,
        "contacts held again {total} times (at most {most} per vertex)"
    );

    // Net force per vertex: springs plus anchors (the anchor's energy written out here).
    let springs = work.tube.system.spring_forces(&x).unwrap();
    let tol = 2.0 * config.tolerance * report.force_scale;
    let pose = work.forearm_pose(frame);
    let (ua, ub) = (pose.transform_point(ULNA.a), pose.transform_point(ULNA.b));
    let band = THICKNESS_M * 1.1;
    let (mut free_rr, mut free, mut on_bone) = (0.0f64, 0, 0);
    for (i, (p, a)) in x.iter().zip(&anchors).enumerate() {
        let d = *p - a.target;
        let dn = d.dot(a.normal);
        let f = springs[i] - (a.normal * (a.k_normal * dn) + (d - a.normal * dn) * a.k_tangent);
        let clearance = analytic_clearance(&work, frame, std::slice::from_ref(p));
        assert!(clearance > 0.5 * THICKNESS_M, "vertex {i} at {clearance} m");
        // The muscle mesh is inscribed in its ellipsoid (sagitta < 0.3 mm): clear of the
        // analytic shape by the band plus that, a vertex touches nothing.
        if clearance > band + 3e-4 {
            free += 1;
            free_rr += f64::from(f.length_squared());
            continue;
        }
        for (a, b, r) in [
            (HUMERUS.a, HUMERUS.b, HUMERUS.radius_m),
            (ua, ub, ULNA.radius_m),
        ] {
            let (dist, n) = segment(*p, a, b);
            // On a bone, and no other collider near: the bone alone takes the force.
            if dist - r < THICKNESS_M + 1e-5 && clearance > dist - r - 1e-6 {
                on_bone += 1;
                let push = f.dot(n);
                assert!(push < tol, "vertex {i} pulled off the bone by {push} N");
                let tangential = (f - n * push).length();
                assert!(
                    tangential < tol,
                    "vertex {i}: {tangential} N along the bone"
                );
            }
        }
    }
    assert!(
        free_rr.sqrt() < f64::from(tol),
        "free vertices: {} N",
        free_rr.sqrt()
    );
    assert!(
        free > 1000 && on_bone > 0,
        "{free} free, {on_bone} on a bone"
    );
    eprintln!("{free} free vertices, {on_bone} on a bone");
}
