//! Lean distances from a point to eight mesh triangles at once (AVX2), bit for bit the scalar ones.
//!
//! A certified patch query ([`super::MeshShape::project_on_patch`]) compares the lean distances
//! of its patch triangles (about five per query, ~145 instructions each with the corner
//! gather). Here the corners of eight triangles are gathered and the scalar closest-point
//! arithmetic ([`super::triangle_distance_sq`]) runs on all eight lanes: every Voronoi region's
//! formula, with the same f32 operations in the same order, then the one the scalar branches
//! would take is selected lane by lane (first match in the scalar order), then the same square
//! root. The values are the scalar ones bit for bit, so every decision made from them is too.

use glam::Vec3;

/// Triangles per batch.
pub(super) const LANES: usize = 8;

/// The lean distances (`triangle_distance_sq(..).sqrt()`) from `p` to the triangles `tris` of
/// the mesh `indices` over `live`, eight at once, and a mask of the lanes whose triangle is out
/// of range (their values are meaningless); `None` without AVX2 or when a vertex index is out of
/// range (the caller then takes the scalar path, which reports it).
#[cfg_attr(
    target_arch = "x86_64",
    expect(
        unsafe_code,
        reason = "the AVX2 path, behind its run-time CPU and index checks"
    )
)]
#[inline]
pub(super) fn distances(
    indices: &[[u32; 3]],
    live: &[Vec3],
    tris: &[u32; LANES],
    p: Vec3,
) -> Option<([f32; LANES], u32)> {
    #[cfg(target_arch = "x86_64")]
    if avx2::available()
        && !live.is_empty()
        && !indices.is_empty()
        // The gathers' 32-bit offsets (3 per triangle or vertex) must not overflow.
        && indices.len() <= i32::MAX as usize / 3
        && live.len() <= i32::MAX as usize / 3
    {
        // SAFETY: AVX2 is available and the sizes are as `avx2::distances` needs; it checks
        // every index it gathers with before using it.
        return unsafe { avx2::distances(indices, live, tris, p) };
    }
    let _ = (indices, live, tris, p);
    None
}

/// Whether [`distances`] can answer on this CPU.
#[inline]
pub(super) fn available() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        avx2::available()
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

#[cfg(target_arch = "x86_64")]
#[expect(
    unsafe_code,
    reason = "AVX2 gathers of checked indices behind a run-time CPU check"
)]
mod avx2 {
    use std::arch::x86_64::*;

    use glam::Vec3;

    use super::LANES;

    /// Whether the CPU has AVX2 (cached by the standard library).
    #[inline]
    pub fn available() -> bool {
        std::arch::is_x86_feature_detected!("avx2")
    }

    /// [`super::distances`] on eight lanes.
    ///
    /// # Safety
    /// AVX2 must be available, `indices` and `live` must hold at least one and at most
    /// `i32::MAX / 3` entries.
    #[target_feature(enable = "avx2")]
    pub unsafe fn distances(
        indices: &[[u32; 3]],
        live: &[Vec3],
        tris: &[u32; LANES],
        p: Vec3,
    ) -> Option<([f32; LANES], u32)> {
        let zero = _mm256_setzero_ps();
        let sub = |a, b| _mm256_sub_ps(a, b);
        let mul = |a, b| _mm256_mul_ps(a, b);
        let add = |a, b| _mm256_add_ps(a, b);
        let le = |a, b| _mm256_cmp_ps::<_CMP_LE_OQ>(a, b);
        let ge = |a, b| _mm256_cmp_ps::<_CMP_GE_OQ>(a, b);
        let and = |a, b| _mm256_and_ps(a, b);
        type V = [__m256; 3];
        let vsub = |a: V, b: V| [sub(a[0], b[0]), sub(a[1], b[1]), sub(a[2], b[2])];
        let vscale = |a: V, s| [mul(a[0], s), mul(a[1], s), mul(a[2], s)];
        // glam's `dot`: (x·x' + y·y') + z·z'.
        let dot = |a: V, b: V| add(add(mul(a[0], b[0]), mul(a[1], b[1])), mul(a[2], b[2]));
        let len2 = |a: V| dot(a, a);

        // Unsigned `i < len` as `max(i, len − 1) == len − 1`.
        let below = |i, len: usize| {
            let last = _mm256_set1_epi32((len - 1) as i32);
            _mm256_cmpeq_epi32(_mm256_max_epu32(i, last), last)
        };
        // SAFETY: eight readable u32.
        let t = unsafe { _mm256_loadu_si256(tris.as_ptr().cast()) };
        // Triangles out of range read triangle 0 instead, and are reported.
        let valid = below(t, indices.len());
        let bad = !_mm256_movemask_ps(_mm256_castsi256_ps(valid)) as u32 & 0xff;
        let t = _mm256_and_si256(t, valid);
        let three = _mm256_set1_epi32(3);
        let t3 = _mm256_mullo_epi32(t, three);
        let ip = indices.as_ptr().cast::<i32>();
        // SAFETY: `3 t + j` (j < 3) indexes the flattened `indices` for every lane.
        let corner = |j: usize| unsafe { _mm256_i32gather_epi32::<4>(ip.add(j), t3) };
        let (ia, ib, ic) = (corner(0), corner(1), corner(2));
        // Every vertex index below `live.len()`.
        let inside = |i| below(i, live.len());
        let ok = _mm256_and_si256(_mm256_and_si256(inside(ia), inside(ib)), inside(ic));
        if _mm256_movemask_epi8(ok) != -1 {
            return None;
        }
        let vp = live.as_ptr().cast::<f32>();
        // SAFETY: `3 i + c` (c < 3) indexes the flattened `live` for every checked lane.
        let vertex = |i: __m256i| -> V {
            let i3 = _mm256_mullo_epi32(i, three);
            unsafe {
                [
                    _mm256_i32gather_ps::<4>(vp, i3),
                    _mm256_i32gather_ps::<4>(vp.add(1), i3),
                    _mm256_i32gather_ps::<4>(vp.add(2), i3),
                ]
            }
        };
        let (a, b, c) = (vertex(ia), vertex(ib), vertex(ic));
        let p = [
            _mm256_set1_ps(p.x),
            _mm256_set1_ps(p.y),
            _mm256_set1_ps(p.z),
        ];

        // `triangle_distance_sq`, every region on every lane.
        let (ab, ac, ap) = (vsub(b, a), vsub(c, a), vsub(p, a));
        let (d1, d2) = (dot(ab, ap), dot(ac, ap));
        let in_a = and(le(d1, zero), le(d2, zero));
        let r_a = len2(ap);
        let bp = vsub(p, b);
        let (d3, d4) = (dot(ab, bp), dot(ac, bp));
        let in_b = and(ge(d3, zero), le(d4, d3));
        let r_b = len2(bp);
        let vc = sub(mul(d1, d4), mul(d3, d2));
        let in_ab = and(and(le(vc, zero), ge(d1, zero)), le(d3, zero));
        let v = _mm256_div_ps(d1, sub(d1, d3));
        let r_ab = len2(vsub(ap, vscale(ab, v)));
        let cp = vsub(p, c);
        let (d5, d6) = (dot(ab, cp), dot(ac, cp));
        let in_c = and(ge(d6, zero), le(d5, d6));
        let r_c = len2(cp);
        let vb = sub(mul(d5, d2), mul(d1, d6));
        let in_ac = and(and(le(vb, zero), ge(d2, zero)), le(d6, zero));
        let w = _mm256_div_ps(d2, sub(d2, d6));
        let r_ac = len2(vsub(ap, vscale(ac, w)));
        let va = sub(mul(d3, d6), mul(d5, d4));
        let (e43, e56) = (sub(d4, d3), sub(d5, d6));
        let in_bc = and(and(le(va, zero), ge(e43, zero)), ge(e56, zero));
        let w = _mm256_div_ps(e43, add(e43, e56));
        let r_bc = len2(vsub(bp, vscale(vsub(c, b), w)));
        let denom = _mm256_div_ps(_mm256_set1_ps(1.0), add(add(va, vb), vc));
        let r_face = len2(vsub(
            vsub(ap, vscale(ab, mul(vb, denom))),
            vscale(ac, mul(vc, denom)),
        ));
        // The first region in the scalar order wins: select from the last to the first.
        let mut r = r_face;
        for (inside, value) in [
            (in_bc, r_bc),
            (in_ac, r_ac),
            (in_c, r_c),
            (in_ab, r_ab),
            (in_b, r_b),
            (in_a, r_a),
        ] {
            r = _mm256_blendv_ps(r, value, inside);
        }
        let mut out = [0.0f32; LANES];
        // SAFETY: eight writable f32.
        unsafe { _mm256_storeu_ps(out.as_mut_ptr(), _mm256_sqrt_ps(r)) };
        Some((out, bad))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::collision::collider::tests::Lcg;
    use crate::collision::collider::triangle_distance_sq;

    /// Every lane equals the scalar lean distance bit for bit, in every Voronoi region
    /// (points far around small triangles, on their planes, at their corners and edges),
    /// for slivers, and for a degenerate (collinear) triangle whose scalar answer is NaN.
    #[test]
    fn eight_lanes_equal_the_scalar_distances_bit_for_bit() {
        if !available() {
            return;
        }
        let mut rng = Lcg(11);
        let mut live: Vec<Vec3> = (0..60).map(|_| rng.point(1.0)).collect();
        // A sliver and a collinear triple.
        live.extend([
            Vec3::ZERO,
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(0.5, 1e-6, 0.0),
            Vec3::new(0.0, 0.0, 1.0),
            Vec3::new(0.0, 0.0, 2.0),
            Vec3::new(0.0, 0.0, 3.0),
        ]);
        let mut indices: Vec<[u32; 3]> = (0..40u32)
            .map(|k| [(3 * k) % 60, (3 * k + 7) % 60, (3 * k + 19) % 60])
            .collect();
        indices.push([60, 61, 62]);
        indices.push([63, 64, 65]);
        let mut regions = [0usize; 2];
        for round in 0..4000 {
            let tris: [u32; LANES] =
                std::array::from_fn(|_| (rng.next() * indices.len() as f32) as u32);
            let t0 = indices[tris[0] as usize].map(|i| live[i as usize]);
            let p = match round % 4 {
                0 => rng.point(2.0),
                // On a triangle's plane, often inside it or on an edge's line.
                1 => t0[0] + (t0[1] - t0[0]) * rng.next() + (t0[2] - t0[0]) * rng.next(),
                // A corner exactly.
                2 => t0[round / 4 % 3],
                _ => t0[0].lerp(t0[1], rng.next()) + rng.point(1e-3),
            };
            let (lanes, bad) = distances(&indices, &live, &tris, p).expect("valid indices");
            assert_eq!(bad, 0);
            for (l, &t) in tris.iter().enumerate() {
                let [a, b, c] = indices[t as usize].map(|i| live[i as usize]);
                let scalar = triangle_distance_sq(p, a, b, c).sqrt();
                assert_eq!(
                    lanes[l].to_bits(),
                    scalar.to_bits(),
                    "round {round} lane {l}: {} against {scalar}",
                    lanes[l]
                );
                // An independent check that it is a distance: at most the corners' distances.
                if scalar.is_finite() {
                    let nearest = [a, b, c]
                        .map(|v| p.distance(v))
                        .into_iter()
                        .fold(f32::MAX, f32::min);
                    assert!(scalar <= nearest * (1.0 + 1e-5) + 1e-6, "round {round}");
                    regions[(scalar < nearest * (1.0 - 1e-4)) as usize] += 1;
                }
            }
        }
        // Both corner answers and edge/face answers were exercised.
        assert!(regions[0] > 1000 && regions[1] > 1000, "{regions:?}");
        // Out-of-range indices are refused or reported, not read.
        let bad = vec![[0u32, 1, 99]];
        assert!(distances(&bad, &live[..10], &[0; LANES], Vec3::ZERO).is_none());
        let mut tris = [1u32; LANES];
        (tris[2], tris[5]) = (u32::MAX, indices.len() as u32);
        let (d, bad) = distances(&indices, &live, &tris, Vec3::ZERO).expect("valid vertices");
        assert_eq!(bad, 0b10_0100);
        assert_eq!(d[0].to_bits(), d[7].to_bits());
    }
}
