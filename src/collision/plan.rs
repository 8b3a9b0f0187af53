//! The frame plan's per-pair tests eight vertices at a time, as a conservative filter.
//!
//! [`SkinCollision::begin_frame`](super::SkinCollision::begin_frame) bounds, for every pair of a
//! skin vertex and a collider, how far the vertex moves relative to the collider over the frame
//! and whether it can come within its contact band (see `reaching_motion`). Most pairs are
//! settled by a few cheap tests: the pair moves less than the substeps already asked for cover,
//! its cached distance bound keeps it out of reach, or both ends of its path are farther from
//! the collider's box than the path can dip. Those tests are arithmetic on each pair's own data,
//! so here they run on eight vertices' lanes at once, in f32, with a rounding allowance that
//! makes each of them stricter than the exact test it stands for: a pair they drop is one the
//! exact tests drop too. The pairs they keep go through the exact tests one by one, which decide
//! everything; so the plan's substep count is the same with or without this filter.

use glam::{Mat3, Vec3};
use parry3d::bounding_volume::Aabb;
use parry3d::math::Pose;

use super::cache::Slot;

/// Vertices per batch.
pub(super) const LANES: usize = 8;

/// What the plan knows of one collider's motion over the frame.
pub(super) struct Motion {
    pub(super) prev: Pose,
    pub(super) pose: Pose,
    /// `prev.lerp(pose, k / PATH_STEPS)` for every `k`: the bisection only evaluates the path
    /// at these times, the same for every vertex.
    pub(super) path: Vec<Pose>,
    /// The slerp's angular velocity over the frame (world frame), rad.
    pub(super) omega: Vec3,
    /// The pose did not change over the frame.
    pub(super) still: bool,
    /// The path's speed at its ends, `|w′ − ω × wₖ|`, is `|(p₁ − p₀) + cₖ − ω × pₖ|` with
    /// `cₖ = t₀ − t₁ + ω × tₖ`...
    pub(super) ends: [Vec3; 2],
    /// ... and the relative pose carries `p₀` by `|(M − I) p₀ + b|` (`M = R₁ R₀ᵀ`,
    /// `b = t₁ − M t₀`).
    pub(super) carry: (Mat3, Vec3),
    /// How far the collider's shape moved any of its points over the frame (a deforming
    /// mesh's largest vertex displacement), m.
    pub(super) deform: f32,
    /// Bound on how far any point of its surface moved over the frame (the deformation and the
    /// pose's motion), m.
    pub(super) global: f32,
    /// Its travel so far, the clock of the slots' distance bounds, m.
    pub(super) travel: f64,
    /// The path's end poses as rotation matrices of their inverses and translations, for the
    /// filter's box distances (`path[0]` and `pose`).
    inverse_ends: [(Mat3, Vec3); 2],
    /// The collider's rest-frame box.
    aabb: Aabb,
}

impl Motion {
    /// The motion of a collider from `prev` to `pose` over the frame, its shape deforming by
    /// `deform` (its global bound `global`), travelled `travel` so far, its box `aabb`.
    /// `path_steps`: the pieces the path is cut into.
    pub(super) fn new(
        (prev, pose): (Pose, Pose),
        (deform, global, travel): (f32, f32, f64),
        aabb: Aabb,
        path_steps: usize,
    ) -> Self {
        // The slerp turns about the axis of `R₁ R₀⁻¹` by its angle along the shorter way (the
        // quaternion with `w >= 0`). The angle from `atan2(|xyz|, w)`, not from `acos(w)`,
        // which loses small turns to the rounding of `w` near 1.
        let turn = pose.rotation * prev.rotation.inverse();
        let mut delta = turn.normalize();
        if delta.w < 0.0 {
            delta = -delta;
        }
        let xyz = delta.xyz();
        let sin_half = xyz.length();
        let omega = if sin_half > 0.0 {
            xyz * (2.0 * sin_half.atan2(delta.w) / sin_half)
        } else {
            Vec3::ZERO
        };
        let path: Vec<Pose> = (0..=path_steps)
            .map(|k| prev.lerp(&pose, k as f32 / path_steps as f32))
            .collect();
        let inverse = |p: &Pose| (Mat3::from_quat(p.rotation.inverse()), p.translation);
        let inverse_ends = [inverse(&path[0]), inverse(&pose)];
        Self {
            prev,
            pose,
            path,
            omega,
            still: prev == pose,
            ends: [prev.translation, pose.translation]
                .map(|t| prev.translation - pose.translation + omega.cross(t)),
            carry: {
                let m = Mat3::from_quat(turn);
                (m - Mat3::IDENTITY, pose.translation - m * prev.translation)
            },
            deform,
            global,
            travel,
            inverse_ends,
            aabb,
        }
    }
}

impl Motion {
    /// The path's speed bound from its raw value (see `reaching_motion`), with room for the
    /// rounding of the products and of the slerp; exactly 0 for a still pair. The exact tests
    /// and the filter share it, operation for operation.
    #[inline(always)]
    pub(super) fn speed(raw: f32) -> f32 {
        if raw > 0.0 {
            raw * (1.0 + 1e-4) + 1e-6
        } else {
            0.0
        }
    }

    /// How far a pair of the contact band `band` moving at `speed` may come in before its
    /// path reaches: the band, the deformation and the rounding of the transforms and queries.
    #[inline(always)]
    pub(super) fn margin(&self, band: f32, speed: f32) -> f32 {
        band + self.deform + 1e-4 * (speed + band) + 1e-6
    }

    /// How far the frame's relative pose carries a point it moves by `carried` (plus the
    /// deformation, at most the collider's whole motion).
    #[inline(always)]
    pub(super) fn moved(&self, carried: f32) -> f32 {
        (carried * (1.0 + 1e-4) + 1e-6 + self.deform).min(self.global)
    }
}

/// Eight skin vertices' data, lane `l` for vertex `l` of the batch.
pub(super) struct Batch {
    /// Where each vertex was at the last pass (its warm start if none), and its warm start.
    p0: [[f32; LANES]; 3],
    p1: [[f32; LANES]; 3],
    /// `|p₁ − p₀|` and the contact band, as the exact tests compute them.
    pub(super) v: [f32; LANES],
    pub(super) band: [f32; LANES],
}

impl Batch {
    /// The batch of the vertices at `x` (warm starts) with last positions `last` and
    /// thicknesses `h` (eight of each), for a contact band `contact_band`.
    #[inline]
    pub(super) fn new(x: &[Vec3], last: &[Vec3], h: &[f32], contact_band: f32) -> Self {
        let mut b = Self {
            p0: [[0.0; LANES]; 3],
            p1: [[0.0; LANES]; 3],
            v: [0.0; LANES],
            band: [0.0; LANES],
        };
        for l in 0..LANES {
            let p1 = x[l];
            let p0 = if last[l].is_finite() { last[l] } else { p1 };
            for k in 0..3 {
                b.p0[k][l] = p0[k];
                b.p1[k][l] = p1[k];
            }
            b.v[l] = p0.distance(p1);
            b.band[l] = h[l] * (1.0 + contact_band);
        }
        b
    }

    /// Vertex `l`'s last and current positions.
    #[inline]
    pub(super) fn ends(&self, l: usize) -> (Vec3, Vec3) {
        let at = |p: &[[f32; LANES]; 3]| Vec3::new(p[0][l], p[1][l], p[2][l]);
        (at(&self.p0), at(&self.p1))
    }

    /// The lanes (bits) whose pair with the collider of motion `m` the exact tests might not
    /// drop, given each lane's slot for that collider (`slot(l)`) and the motion `skip` that
    /// the substeps asked for so far cover. A lane left out is a pair that moves no more than
    /// `skip`, or provably stays out of its band over the frame.
    #[cfg_attr(
        target_arch = "x86_64",
        expect(
            unsafe_code,
            reason = "the AVX2 build of the same code, behind its CPU check"
        )
    )]
    #[inline]
    pub(super) fn survivors<'a>(
        &self,
        m: &Motion,
        slot: impl Fn(usize) -> &'a Slot,
        skip: f32,
    ) -> u32 {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU has AVX2.
            return unsafe { self.survivors_avx2(m, slot, skip) };
        }
        self.survivors_in(m, slot, skip)
    }

    /// [`survivors`](Self::survivors) compiled for AVX2 (eight lanes per instruction; no
    /// fused multiply-adds, so the same values).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn survivors_avx2<'a>(&self, m: &Motion, slot: impl Fn(usize) -> &'a Slot, skip: f32) -> u32 {
        self.survivors_in(m, slot, skip)
    }

    #[inline(always)]
    fn survivors_in<'a>(&self, m: &Motion, slot: impl Fn(usize) -> &'a Slot, skip: f32) -> u32 {
        // Each test flags the lanes it settles (a NaN settles none). First a still collider
        // under a vertex that moves less than `skip`, the usual case, in one test per lane
        // (the exact test's own arithmetic).
        let mut settled = [0u32; LANES];
        for (s, &v) in settled.iter_mut().zip(&self.v) {
            *s = u32::from(m.global + v <= skip);
        }
        let mut alive = !bits(&settled) & ((1 << LANES) - 1);
        if alive == 0 {
            return 0;
        }
        let [p0x, p0y, p0z] = &self.p0;
        let [p1x, p1y, p1z] = &self.p1;
        let mut raw = self.v;
        if !m.still {
            let (ox, oy, oz) = (m.omega.x, m.omega.y, m.omega.z);
            let [e0, e1] = m.ends;
            for l in 0..LANES {
                // `(p₁ − p₀) + cₖ − ω × pₖ` at both ends, the exact test's vectors bit for bit.
                let (sx, sy, sz) = (p1x[l] - p0x[l], p1y[l] - p0y[l], p1z[l] - p0z[l]);
                let (ax, ay, az) = (p0x[l], p0y[l], p0z[l]);
                let (bx, by, bz) = (p1x[l], p1y[l], p1z[l]);
                let (t0x, t0y, t0z) = (oy * az - ay * oz, oz * ax - az * ox, ox * ay - ax * oy);
                let (t1x, t1y, t1z) = (oy * bz - by * oz, oz * bx - bz * ox, ox * by - bx * oy);
                let (u0x, u0y, u0z) = (sx + e0.x - t0x, sy + e0.y - t0y, sz + e0.z - t0z);
                let (u1x, u1y, u1z) = (sx + e1.x - t1x, sy + e1.y - t1y, sz + e1.z - t1z);
                let r0 = (u0x * u0x + u0y * u0y + u0z * u0z).sqrt();
                let r1 = (u1x * u1x + u1y * u1y + u1z * u1z).sqrt();
                raw[l] = r0.max(r1);
            }
        }
        let mut speed = [0.0f32; LANES];
        let mut motion = [0.0f32; LANES];
        for l in 0..LANES {
            speed[l] = Motion::speed(raw[l]);
            motion[l] = (speed[l] + m.deform).min(m.global + self.v[l]);
        }
        // The substeps asked for so far cover the pair's motion (with room for rounding).
        for (s, &motion) in settled.iter_mut().zip(&motion) {
            *s = u32::from(motion * (1.0 + 1e-6) <= skip);
        }
        alive &= !bits(&settled);
        if alive == 0 {
            return 0;
        }
        // The cached bound: the slot's reserve `clearance − (travel − travel_at)` rounded down
        // to f32, less how far each end is from the slot's reference point.
        let mut reserve = [0.0f32; LANES];
        let mut refs = [[0.0f32; LANES]; 3];
        for l in 0..LANES {
            let (r, at) = slot(l).reserve_f32(m.travel);
            reserve[l] = r;
            for k in 0..3 {
                refs[k][l] = at[k];
            }
        }
        let (c, b) = m.carry;
        let mut cap = [0.0f32; LANES];
        for l in 0..LANES {
            let dist = |px: f32, py: f32, pz: f32| {
                let (dx, dy, dz) = (px - refs[0][l], py - refs[1][l], pz - refs[2][l]);
                (dx * dx + dy * dy + dz * dz).sqrt()
            };
            let d1 = dist(p1x[l], p1y[l], p1z[l]);
            let d0 = dist(p0x[l], p0y[l], p0z[l]);
            let now = reserve[l] - d1;
            let moved = if m.still {
                m.deform
            } else {
                let (x, y, z) = (p0x[l], p0y[l], p0z[l]);
                let cx = c.x_axis.x * x + c.y_axis.x * y + c.z_axis.x * z + b.x;
                let cy = c.x_axis.y * x + c.y_axis.y * y + c.z_axis.y * z + b.y;
                let cz = c.x_axis.z * x + c.y_axis.z * y + c.z_axis.z * z + b.z;
                let carried = (cx * cx + cy * cy + cz * cz).sqrt();
                m.moved(carried)
            };
            let before = reserve[l] - d0 - moved;
            let band = self.band[l];
            let margin = m.margin(band, speed[l]);
            let needed = margin + 0.5 * speed[l];
            cap[l] = needed;
            let scale = p1x[l].abs().max(p1y[l].abs()).max(p1z[l].abs());
            // The exact test's allowance, plus the rounding of these f32 sums against its f64
            // ones (a few 1e-7 of the terms).
            let rounding = 1e-6 * (reserve[l].abs() + d0 + d1 + moved + needed + scale) + 1e-12;
            let bound = now.min(before);
            settled[l] = u32::from(bound - 1e-4 * (scale + needed) - 1e-6 - rounding >= needed);
        }
        alive &= !bits(&settled);
        if alive == 0 {
            return 0;
        }
        // Both ends of the path farther from the collider's box than the path can dip: the
        // bisection's first test settles the pair.
        let (lo, hi) = (m.aabb.mins, m.aabb.maxs);
        let outside = |(r, t): &(Mat3, Vec3), px: f32, py: f32, pz: f32, cap: f32| {
            let (x, y, z) = (px - t.x, py - t.y, pz - t.z);
            let lx = r.x_axis.x * x + r.y_axis.x * y + r.z_axis.x * z;
            let ly = r.x_axis.y * x + r.y_axis.y * y + r.z_axis.y * z;
            let lz = r.x_axis.z * x + r.y_axis.z * y + r.z_axis.z * z;
            let gx = (lo.x - lx).max(lx - hi.x).max(0.0);
            let gy = (lo.y - ly).max(ly - hi.y).max(0.0);
            let gz = (lo.z - lz).max(lz - hi.z).max(0.0);
            let d = (gx * gx + gy * gy + gz * gz).sqrt();
            // The rounding of the rotation and of the box distance (relative to the
            // coordinates).
            let slack = 1e-5 * (cap + x.abs() + y.abs() + z.abs()) + 1e-9;
            d - slack >= cap * (1.0 + 1e-5)
        };
        for l in 0..LANES {
            let out0 = outside(&m.inverse_ends[0], p0x[l], p0y[l], p0z[l], cap[l]);
            let out1 = outside(&m.inverse_ends[1], p1x[l], p1y[l], p1z[l], cap[l]);
            settled[l] = u32::from(out0 && out1);
        }
        alive & !bits(&settled)
    }
}

/// The lanes whose flag is 1, as bits.
#[inline(always)]
fn bits(flags: &[u32; LANES]) -> u32 {
    let mut b = 0;
    for (l, &f) in flags.iter().enumerate() {
        b |= f << l;
    }
    b
}

#[cfg(test)]
mod tests {
    use glam::{Quat, Vec3};
    use parry3d::math::Pose;

    use super::{Batch, LANES};
    use crate::collision::{
        ColliderMesh, ContactConfig, SkinCollision, covered_motion, shapes, wanted_substeps,
    };

    /// A skin tube (radius 5 cm, 5 mm thick) round a capsule bone and over a deforming
    /// ellipsoid, a ball beside it, after one frame at rest; then the bone turns by `turn` about
    /// its joint, the ellipsoid swells by `swell` and every skin vertex moves by up to
    /// `jitter` (a fixed pseudo-random pattern), and the ball, grazing the tube's top, moves by
    /// `sweep` along it. Returns the contact state and the warm start.
    fn scene((turn, swell, jitter, sweep): (f32, f32, f32, f32)) -> (SkinCollision, Vec<Vec3>) {
        let (around, rings) = (32u32, 21u32);
        let mut x = Vec::new();
        for j in 0..rings {
            for i in 0..around {
                let a = std::f32::consts::TAU * i as f32 / around as f32;
                let along = -0.2 + 0.4 * j as f32 / (rings - 1) as f32;
                x.push(Vec3::new(along, 0.05 * a.cos(), 0.05 * a.sin()));
            }
        }
        let config = ContactConfig {
            thickness_m: 0.005,
            ..ContactConfig::DEFAULT
        };
        let mut contact = SkinCollision::new(x.len(), config).unwrap();
        let joint = Vec3::new(-0.15, 0.0, 0.0);
        let bone = contact
            .add_collider(ColliderMesh::capsule(joint, Vec3::new(0.3, 0.0, 0.0), 0.03).unwrap());
        let (v, t) = shapes::ellipsoid(Vec3::ZERO, Vec3::new(0.15, 0.04, 0.04), 12, 16).unwrap();
        let belly = contact.add_collider(ColliderMesh::from_mesh(v.clone(), t).unwrap());
        // 4 mm above the skin at the tube's top: within the contact band.
        let ball_at = |dx: f32| Pose::from_translation(Vec3::new(dx - 0.5 * sweep, 0.084, 0.0));
        let ball = contact.add_collider(ColliderMesh::ball(0.03).unwrap().with_pose(ball_at(0.0)));
        contact.advance_frame(&mut x).unwrap();
        let q = Quat::from_rotation_z(turn);
        let pose = Pose::from_parts(joint - q * joint, q);
        contact.collider_mut(bone).unwrap().set_pose(pose).unwrap();
        contact
            .collider_mut(ball)
            .unwrap()
            .set_pose(ball_at(sweep))
            .unwrap();
        let swollen: Vec<Vec3> = v
            .iter()
            .map(|p| Vec3::new(p.x, p.y * (1.0 + swell), p.z * (1.0 + swell)))
            .collect();
        contact
            .collider_mut(belly)
            .unwrap()
            .set_vertices(&swollen)
            .unwrap();
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = || {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            (state >> 40) as f32 / (1u64 << 24) as f32 - 0.5
        };
        for p in &mut x {
            *p += Vec3::new(next(), next(), next()) * (2.0 * jitter);
        }
        (contact, x)
    }

    /// `(turn, swell, jitter, sweep)` of [`scene`].
    const SCENES: [(f32, f32, f32, f32); 7] = [
        (0.0, 0.0, 0.0, 0.0),
        (0.02, 0.0, 0.0005, 0.0),
        (0.2, 0.0, 0.0, 0.0),
        (0.0, 0.3, 0.001, 0.0),
        (0.1, 0.2, 0.003, 0.0),
        (0.0, 0.0, 0.0, 0.1),
        (0.0, 0.0, 0.002, 0.3),
    ];

    /// Every pair the filter drops is one the exact tests drop too: its exact test leaves the
    /// largest motion and the covered motion as they were, whatever the covered motion (from
    /// none to twenty substeps). The AVX2 build drops the same pairs as the portable one, and the
    /// filter drops most pairs while the scenes have pairs that reach.
    #[test]
    fn pairs_the_filter_drops_are_pairs_the_exact_tests_drop() {
        let (mut dropped, mut pairs, mut reaching) = (0usize, 0usize, 0usize);
        for s in SCENES {
            let (mut contact, x) = scene(s);
            contact.collider_travel();
            let motions = contact.plan_motions();
            let nc = motions.len();
            let step = 0.5 * contact.config.thickness_m;
            for worst in [0.0, 0.3 * step, 1.5 * step, 4.0 * step, 20.0 * step] {
                let ws = (worst, covered_motion(worst, step));
                for first in (0..x.len() - LANES + 1).step_by(LANES) {
                    let r = first..first + LANES;
                    let band = contact.config.contact_band;
                    let b = Batch::new(
                        &x[r.clone()],
                        &contact.last[r.clone()],
                        &contact.thickness[r],
                        band,
                    );
                    for (c, m) in motions.iter().enumerate() {
                        let slot = |l: usize| &contact.slots[(first + l) * nc + c];
                        let kept = b.survivors(m, slot, ws.1);
                        assert_eq!(kept, b.survivors_in(m, slot, ws.1));
                        for l in 0..LANES {
                            let (p0, p1) = b.ends(l);
                            let ends = (p0, p1, b.v[l], b.band[l]);
                            let out = contact.reach_pair(&motions, step, c, ends, slot(l), ws);
                            let reaches = out != ws;
                            pairs += 1;
                            reaching += usize::from(reaches);
                            if kept >> l & 1 == 0 {
                                dropped += 1;
                                assert!(
                                    !reaches,
                                    "vertex {} collider {c}: {ws:?} -> {out:?}",
                                    first + l
                                );
                            }
                        }
                    }
                }
            }
        }
        eprintln!("{dropped} of {pairs} pairs dropped, {reaching} reach");
        assert!(reaching > 100, "{reaching} of {pairs} pairs reach");
        assert!(dropped > pairs / 2, "{dropped} of {pairs} pairs dropped");
    }

    /// The plan asks for the same substeps with the filter as without it.
    #[test]
    fn the_filtered_plan_asks_for_the_same_substeps() {
        let mut counts = Vec::new();
        for s in SCENES {
            let (mut contact, x) = scene(s);
            contact.collider_travel();
            let touched = contact.anchor_contacts(false);
            let step = 0.5 * contact.config.thickness_m;
            let [wide, narrow] = [true, false].map(|wide| {
                wanted_substeps(contact.reaching_motion_with(&x, &touched, step, wide), step)
            });
            assert_eq!(wide, narrow, "scene {s:?}");
            counts.push(wide);
        }
        // From one substep (a still bone) to many (a fast turn).
        assert!(
            counts.contains(&0.0) && counts.iter().any(|&c| c > 10.0),
            "{counts:?}"
        );
    }
}
