//! Eight-lane force and curvature kernels over the sliced springs: AVX2 with FMA (with AVX-512
//! for the f64 half on request) when the CPU has them (checked at run time), otherwise a
//! portable path with bit-identical results.
//!
//! Both paths run the same generic code over a [`Lanes`] implementation, lane by lane the same
//! IEEE operations in the same order, so the results do not depend on the CPU; and they are
//! the operations of the plain per-vertex loop over CSR springs, so they do not depend on the
//! layout either. Products that feed a sum are fused with it (`fma`, one rounding: the dot
//! products, the trial point `x + a d`, the force and energy accumulations); the portable path
//! takes the same fused operations from `f32::mul_add` and `f64::mul_add`, which round once on
//! every target (in software, and much slower, on a CPU without FMA). Fusing them cut a
//! relaxation iteration's instructions by 7.5 % and its time by 12-17 % (session 15,
//! `benches/README.md`). No approximate reciprocals.
#![expect(
    unsafe_code,
    reason = "AVX2 intrinsics and gathers from raw pointers behind a run-time CPU check; every \
              gathered index is below the vertex count, asserted per chunk"
)]

use std::mem::size_of;

use glam::Vec3;

use super::kernels::Sums;
use super::sell::{LANES, PAIR_LANES, Refs, Sell};
use super::team::{Chunked, Par};
use super::{STEP_BLOCK, VertexAnchor, fused};

/// Eight lanes of f32 (and f64) arithmetic.
pub(crate) trait Lanes: Copy {
    /// Eight f32.
    type F: Copy;
    /// Eight u32 indices.
    type I: Copy;
    /// Eight lane flags.
    type M: Copy;
    /// Eight f64.
    type D: Copy;
    fn splat(self, v: f32) -> Self::F;
    fn load(self, p: &[f32]) -> Self::F;
    fn load_i(self, p: &[u32]) -> Self::I;
    /// `base + p[l]` per lane (16-bit offsets, sign-extended).
    fn load_near(self, p: &[i16], base: u32) -> Self::I;
    /// `base[idx[l]]` per lane.
    ///
    /// # Safety
    /// Every `base + idx[l]` must be in bounds of one allocation.
    unsafe fn gather(self, base: *const f32, idx: Self::I) -> Self::F;
    /// Eight consecutive `Vec3` at `p` (24 floats) as their x, y and z lanes.
    ///
    /// # Safety
    /// 24 floats from `p` must be readable.
    unsafe fn load3(self, p: *const f32) -> [Self::F; 3];
    /// Eight consecutive floats at `p`.
    ///
    /// # Safety
    /// 8 floats from `p` must be readable.
    unsafe fn load_at(self, p: *const f32) -> Self::F;
    /// Writes eight floats at `p`.
    ///
    /// # Safety
    /// 8 floats from `p` must be writable.
    unsafe fn store_at(self, p: *mut f32, a: Self::F);
    /// The x, y and z lanes of eight `Vec3` held as their 24 floats in order (as
    /// [`load3`](Self::load3) from registers).
    fn deinterleave(self, v: [Self::F; 3]) -> [Self::F; 3];
    /// Eight per-vertex values spread over the 24 floats of eight `Vec3` (each value three
    /// times in a row, in the layout [`load_at`](Self::load_at) reads them).
    fn spread3(self, w: Self::F) -> [Self::F; 3];
    /// `v[i]` per lane as x, y and z lanes, for `v` the `n` vectors at `p`, `i` the indices
    /// `j` and `rows` the same indices as float offsets.
    ///
    /// # Safety
    /// `p` points to `3 n` readable floats and every index is below `n`.
    unsafe fn vec3s(self, p: *const f32, n: usize, rows: &Rows, j: Self::I) -> [Self::F; 3];
    /// [`vec3s`](Self::vec3s) of `x` (at `p`) and of `d` (at `dp`) at the same rows.
    ///
    /// # Safety
    /// As [`vec3s`](Self::vec3s), for both `p` and `dp`.
    #[inline(always)]
    unsafe fn vec3s_pair(
        self,
        p: *const f32,
        dp: *const f32,
        n: usize,
        rows: &Rows,
        j: Self::I,
    ) -> ([Self::F; 3], [Self::F; 3]) {
        // SAFETY: the caller's contract.
        unsafe { (self.vec3s(p, n, rows, j), self.vec3s(dp, n, rows, j)) }
    }
    /// Writes eight `Vec3` (24 floats) at `p` from their x, y and z lanes.
    ///
    /// # Safety
    /// 24 floats from `p` must be writable.
    unsafe fn store3(self, p: *mut f32, v: [Self::F; 3]);
    /// The eight `(k, rest)` pairs of one upper slot at `p` (16 floats, the pairs in the lane
    /// order [`PAIR_LANES`]) as the lanes `(k, rest)`.
    ///
    /// # Safety
    /// 16 floats from `p` must be readable.
    unsafe fn pairs(self, p: *const f32) -> (Self::F, Self::F);
    /// The pairs `p[2 i]`, `p[2 i + 1]` for the pair indices `i` in `idx`, which lists them
    /// in the lane order [`PAIR_LANES`] (lane `l`'s index in position `PAIR_LANES[l]`), as the
    /// lanes `(k, rest)`.
    ///
    /// # Safety
    /// The two floats at every `p + 2 i` must be readable.
    unsafe fn pairs_at(self, p: *const f32, idx: Self::I) -> (Self::F, Self::F);
    /// [`pairs_at`](Self::pairs_at) for the pair indices `base + refs[m]` (in the lane order
    /// [`PAIR_LANES`]).
    ///
    /// # Safety
    /// Eight references readable; the two floats at every `p + 2 (base + refs[m])` readable.
    #[inline(always)]
    unsafe fn pairs_near(self, p: *const f32, refs: &[i16], base: isize) -> (Self::F, Self::F) {
        // SAFETY: the caller's contract.
        unsafe { self.pairs_at(p, self.load_near(refs, base as u32)) }
    }
    /// Lanes whose sign bit is set (`-0.0` included).
    fn negative(self, a: Self::F) -> Self::M;
    /// Whether `a` and `b` hold the same bits in every lane.
    fn same_bits(self, a: Self::F, b: Self::F) -> bool;
    /// Eight f64 from an array.
    fn dfrom(self, a: [f64; 8]) -> Self::D;
    /// `3 i` per lane.
    fn times3(self, i: Self::I) -> Self::I;
    fn add(self, a: Self::F, b: Self::F) -> Self::F;
    fn sub(self, a: Self::F, b: Self::F) -> Self::F;
    fn mul(self, a: Self::F, b: Self::F) -> Self::F;
    /// `a·b + c` per lane, rounded once (a fused multiply-add).
    fn fma(self, a: Self::F, b: Self::F, c: Self::F) -> Self::F;
    /// `c − a·b` per lane, rounded once.
    fn fnma(self, a: Self::F, b: Self::F, c: Self::F) -> Self::F;
    fn div(self, a: Self::F, b: Self::F) -> Self::F;
    fn sqrt(self, a: Self::F) -> Self::F;
    /// `a > b ? a : b` (the second operand when either is NaN).
    fn max(self, a: Self::F, b: Self::F) -> Self::F;
    fn gt(self, a: Self::F, b: Self::F) -> Self::M;
    fn le(self, a: Self::F, b: Self::F) -> Self::M;
    /// `|a|` per lane (the sign bit cleared).
    fn abs(self, a: Self::F) -> Self::F;
    /// `m ? a : b` per lane.
    fn select(self, m: Self::M, a: Self::F, b: Self::F) -> Self::F;
    /// `m ? a : +0` per lane, for a mask `m` from a comparison ([`gt`](Self::gt),
    /// [`le`](Self::le); not [`negative`](Self::negative)).
    fn keep(self, m: Self::M, a: Self::F) -> Self::F;
    /// `base + l` in lane `l`.
    fn iota(self, base: u32) -> Self::I;
    fn store(self, a: Self::F) -> [f32; 8];
    fn widen(self, a: Self::F) -> Self::D;
    fn dsplat(self, v: f64) -> Self::D;
    fn dadd(self, a: Self::D, b: Self::D) -> Self::D;
    fn dsub(self, a: Self::D, b: Self::D) -> Self::D;
    fn dmul(self, a: Self::D, b: Self::D) -> Self::D;
    /// `a·b + c` per lane, rounded once.
    fn dfma(self, a: Self::D, b: Self::D, c: Self::D) -> Self::D;
    /// `c − a·b` per lane, rounded once.
    fn dfnma(self, a: Self::D, b: Self::D, c: Self::D) -> Self::D;
    fn dstore(self, a: Self::D) -> [f64; 8];
}

/// The portable lanes: plain arrays.
#[derive(Clone, Copy)]
pub(crate) struct Scalar;

impl Lanes for Scalar {
    type F = [f32; 8];
    type I = [u32; 8];
    type M = [bool; 8];
    type D = [f64; 8];
    #[inline(always)]
    fn splat(self, v: f32) -> Self::F {
        [v; 8]
    }
    #[inline(always)]
    fn load(self, p: &[f32]) -> Self::F {
        std::array::from_fn(|l| p[l])
    }
    #[inline(always)]
    fn load_i(self, p: &[u32]) -> Self::I {
        std::array::from_fn(|l| p[l])
    }
    #[inline(always)]
    fn load_near(self, p: &[i16], base: u32) -> Self::I {
        std::array::from_fn(|l| base.wrapping_add(p[l] as i32 as u32))
    }
    #[inline(always)]
    unsafe fn gather(self, base: *const f32, idx: Self::I) -> Self::F {
        // SAFETY: the caller guarantees every index is in bounds.
        std::array::from_fn(|l| unsafe { *base.add(idx[l] as usize) })
    }
    #[inline(always)]
    unsafe fn load3(self, p: *const f32) -> [Self::F; 3] {
        // SAFETY: the caller guarantees 24 readable floats.
        std::array::from_fn(|c| std::array::from_fn(|l| unsafe { *p.add(3 * l + c) }))
    }
    #[inline(always)]
    unsafe fn load_at(self, p: *const f32) -> Self::F {
        // SAFETY: the caller guarantees 8 readable floats.
        std::array::from_fn(|l| unsafe { *p.add(l) })
    }
    #[inline(always)]
    unsafe fn store_at(self, p: *mut f32, a: Self::F) {
        for (l, a) in a.iter().enumerate() {
            // SAFETY: the caller guarantees 8 writable floats.
            unsafe { *p.add(l) = *a };
        }
    }
    #[inline(always)]
    fn deinterleave(self, v: [Self::F; 3]) -> [Self::F; 3] {
        std::array::from_fn(|c| std::array::from_fn(|l| v[(3 * l + c) / 8][(3 * l + c) % 8]))
    }
    #[inline(always)]
    fn spread3(self, w: Self::F) -> [Self::F; 3] {
        std::array::from_fn(|k| std::array::from_fn(|l| w[(8 * k + l) / 3]))
    }
    #[inline(always)]
    unsafe fn vec3s(self, p: *const f32, _n: usize, rows: &Rows, _j: Self::I) -> [Self::F; 3] {
        // SAFETY: the caller guarantees the indices are in bounds.
        let p = unsafe { p.add(3 * rows.shift) };
        std::array::from_fn(|c| std::array::from_fn(|l| unsafe { *p.offset(rows.o[l]).add(c) }))
    }
    #[inline(always)]
    unsafe fn store3(self, p: *mut f32, v: [Self::F; 3]) {
        for l in 0..8 {
            for (c, v) in v.iter().enumerate() {
                // SAFETY: the caller guarantees 24 writable floats.
                unsafe { *p.add(3 * l + c) = v[l] };
            }
        }
    }
    #[inline(always)]
    unsafe fn pairs(self, p: *const f32) -> (Self::F, Self::F) {
        // SAFETY: the caller guarantees 16 readable floats.
        let at = |l: usize, c: usize| unsafe { *p.add(2 * PAIR_LANES[l] + c) };
        (
            std::array::from_fn(|l| at(l, 0)),
            std::array::from_fn(|l| at(l, 1)),
        )
    }
    #[inline(always)]
    unsafe fn pairs_at(self, p: *const f32, idx: Self::I) -> (Self::F, Self::F) {
        // SAFETY: the caller guarantees every pair is readable.
        let at = |l: usize, c: usize| unsafe { *p.add(2 * idx[PAIR_LANES[l]] as usize + c) };
        (
            std::array::from_fn(|l| at(l, 0)),
            std::array::from_fn(|l| at(l, 1)),
        )
    }
    #[inline(always)]
    fn negative(self, a: Self::F) -> Self::M {
        a.map(f32::is_sign_negative)
    }
    #[inline(always)]
    fn same_bits(self, a: Self::F, b: Self::F) -> bool {
        a.iter().zip(&b).all(|(a, b)| a.to_bits() == b.to_bits())
    }
    #[inline(always)]
    fn dfrom(self, a: [f64; 8]) -> Self::D {
        a
    }
    #[inline(always)]
    fn times3(self, i: Self::I) -> Self::I {
        i.map(|i| i.wrapping_mul(3))
    }
    #[inline(always)]
    fn add(self, a: Self::F, b: Self::F) -> Self::F {
        std::array::from_fn(|l| a[l] + b[l])
    }
    #[inline(always)]
    fn sub(self, a: Self::F, b: Self::F) -> Self::F {
        std::array::from_fn(|l| a[l] - b[l])
    }
    #[inline(always)]
    fn mul(self, a: Self::F, b: Self::F) -> Self::F {
        std::array::from_fn(|l| a[l] * b[l])
    }
    #[inline(always)]
    fn fma(self, a: Self::F, b: Self::F, c: Self::F) -> Self::F {
        std::array::from_fn(|l| a[l].mul_add(b[l], c[l]))
    }
    #[inline(always)]
    fn fnma(self, a: Self::F, b: Self::F, c: Self::F) -> Self::F {
        std::array::from_fn(|l| (-a[l]).mul_add(b[l], c[l]))
    }
    #[inline(always)]
    fn div(self, a: Self::F, b: Self::F) -> Self::F {
        std::array::from_fn(|l| a[l] / b[l])
    }
    #[inline(always)]
    fn sqrt(self, a: Self::F) -> Self::F {
        a.map(f32::sqrt)
    }
    #[inline(always)]
    fn max(self, a: Self::F, b: Self::F) -> Self::F {
        std::array::from_fn(|l| if a[l] > b[l] { a[l] } else { b[l] })
    }
    #[inline(always)]
    fn gt(self, a: Self::F, b: Self::F) -> Self::M {
        std::array::from_fn(|l| a[l] > b[l])
    }
    #[inline(always)]
    fn le(self, a: Self::F, b: Self::F) -> Self::M {
        std::array::from_fn(|l| a[l] <= b[l])
    }
    #[inline(always)]
    fn abs(self, a: Self::F) -> Self::F {
        a.map(f32::abs)
    }
    #[inline(always)]
    fn select(self, m: Self::M, a: Self::F, b: Self::F) -> Self::F {
        std::array::from_fn(|l| if m[l] { a[l] } else { b[l] })
    }
    #[inline(always)]
    fn keep(self, m: Self::M, a: Self::F) -> Self::F {
        std::array::from_fn(|l| if m[l] { a[l] } else { 0.0 })
    }
    #[inline(always)]
    fn iota(self, base: u32) -> Self::I {
        std::array::from_fn(|l| base.wrapping_add(l as u32))
    }
    #[inline(always)]
    fn store(self, a: Self::F) -> [f32; 8] {
        a
    }
    #[inline(always)]
    fn widen(self, a: Self::F) -> Self::D {
        a.map(f64::from)
    }
    #[inline(always)]
    fn dsplat(self, v: f64) -> Self::D {
        [v; 8]
    }
    #[inline(always)]
    fn dadd(self, a: Self::D, b: Self::D) -> Self::D {
        std::array::from_fn(|l| a[l] + b[l])
    }
    #[inline(always)]
    fn dsub(self, a: Self::D, b: Self::D) -> Self::D {
        std::array::from_fn(|l| a[l] - b[l])
    }
    #[inline(always)]
    fn dmul(self, a: Self::D, b: Self::D) -> Self::D {
        std::array::from_fn(|l| a[l] * b[l])
    }
    #[inline(always)]
    fn dfma(self, a: Self::D, b: Self::D, c: Self::D) -> Self::D {
        std::array::from_fn(|l| a[l].mul_add(b[l], c[l]))
    }
    #[inline(always)]
    fn dfnma(self, a: Self::D, b: Self::D, c: Self::D) -> Self::D {
        std::array::from_fn(|l| (-a[l]).mul_add(b[l], c[l]))
    }
    #[inline(always)]
    fn dstore(self, a: Self::D) -> [f64; 8] {
        a
    }
}

#[cfg(target_arch = "x86_64")]
mod avx512;

#[cfg(target_arch = "x86_64")]
mod avx2 {
    use std::arch::x86_64::*;

    /// The x, y and z lanes of eight 16-byte rows, paired by 128-bit halves: `v[l]` holds the
    /// rows of lanes `l` and `l + 4`.
    #[inline(always)]
    fn transpose4(v: [__m256; 4]) -> [__m256; 3] {
        // SAFETY: AVX is enabled wherever this is inlined (AVX2 lanes only).
        unsafe {
            let t0 = _mm256_unpacklo_ps(v[0], v[1]);
            let t1 = _mm256_unpackhi_ps(v[0], v[1]);
            let t2 = _mm256_unpacklo_ps(v[2], v[3]);
            let t3 = _mm256_unpackhi_ps(v[2], v[3]);
            [
                _mm256_shuffle_ps::<0x44>(t0, t2),
                _mm256_shuffle_ps::<0xEE>(t0, t2),
                _mm256_shuffle_ps::<0x44>(t1, t3),
            ]
        }
    }

    /// AVX2 lanes; only constructed after `is_x86_feature_detected!` of AVX2 and FMA, and only used
    /// inside `#[target_feature(enable = "avx2,fma")]` functions (every method is inlined there).
    #[derive(Clone, Copy)]
    pub(crate) struct Avx2;

    impl super::Lanes for Avx2 {
        type F = __m256;
        type I = __m256i;
        type M = __m256;
        type D = (__m256d, __m256d);
        #[inline(always)]
        fn splat(self, v: f32) -> Self::F {
            unsafe { _mm256_set1_ps(v) }
        }
        #[inline(always)]
        fn load(self, p: &[f32]) -> Self::F {
            assert!(p.len() >= 8);
            // SAFETY: eight values in bounds (asserted).
            unsafe { _mm256_loadu_ps(p.as_ptr()) }
        }
        #[inline(always)]
        fn load_i(self, p: &[u32]) -> Self::I {
            assert!(p.len() >= 8);
            // SAFETY: eight values in bounds (asserted).
            unsafe { _mm256_loadu_si256(p.as_ptr().cast()) }
        }
        #[inline(always)]
        fn load_near(self, p: &[i16], base: u32) -> Self::I {
            assert!(p.len() >= 8);
            // SAFETY: eight values in bounds (asserted).
            unsafe {
                let wide = _mm256_cvtepi16_epi32(_mm_loadu_si128(p.as_ptr().cast()));
                _mm256_add_epi32(wide, _mm256_set1_epi32(base as i32))
            }
        }
        #[inline(always)]
        unsafe fn gather(self, base: *const f32, idx: Self::I) -> Self::F {
            // SAFETY: the caller guarantees every index is in bounds.
            unsafe { _mm256_i32gather_ps::<4>(base, idx) }
        }
        #[inline(always)]
        unsafe fn load3(self, p: *const f32) -> [Self::F; 3] {
            // SAFETY: the caller guarantees 24 readable floats.
            unsafe {
                self.deinterleave([
                    _mm256_loadu_ps(p),
                    _mm256_loadu_ps(p.add(8)),
                    _mm256_loadu_ps(p.add(16)),
                ])
            }
        }
        #[inline(always)]
        unsafe fn load_at(self, p: *const f32) -> Self::F {
            // SAFETY: the caller guarantees 8 readable floats.
            unsafe { _mm256_loadu_ps(p) }
        }
        #[inline(always)]
        unsafe fn store_at(self, p: *mut f32, a: Self::F) {
            // SAFETY: the caller guarantees 8 writable floats.
            unsafe { _mm256_storeu_ps(p, a) }
        }
        #[inline(always)]
        fn spread3(self, w: Self::F) -> [Self::F; 3] {
            unsafe {
                [
                    _mm256_permutevar8x32_ps(w, _mm256_setr_epi32(0, 0, 0, 1, 1, 1, 2, 2)),
                    _mm256_permutevar8x32_ps(w, _mm256_setr_epi32(2, 3, 3, 3, 4, 4, 4, 5)),
                    _mm256_permutevar8x32_ps(w, _mm256_setr_epi32(5, 5, 6, 6, 6, 7, 7, 7)),
                ]
            }
        }
        #[inline(always)]
        fn deinterleave(self, v: [Self::F; 3]) -> [Self::F; 3] {
            // Float 3m + c is component c of vertex m; two blends gather each component's
            // eight values into one register (out of order), one permutation puts them in
            // vertex order.
            unsafe {
                let [a, b, c] = v;
                let x = _mm256_blend_ps::<0b0010_0100>(_mm256_blend_ps::<0b1001_0010>(a, b), c);
                let y = _mm256_blend_ps::<0b0100_1001>(_mm256_blend_ps::<0b0010_0100>(a, b), c);
                let z = _mm256_blend_ps::<0b1001_0010>(_mm256_blend_ps::<0b0100_1001>(a, b), c);
                [
                    _mm256_permutevar8x32_ps(x, _mm256_setr_epi32(0, 3, 6, 1, 4, 7, 2, 5)),
                    _mm256_permutevar8x32_ps(y, _mm256_setr_epi32(1, 4, 7, 2, 5, 0, 3, 6)),
                    _mm256_permutevar8x32_ps(z, _mm256_setr_epi32(2, 5, 0, 3, 6, 1, 4, 7)),
                ]
            }
        }
        #[inline(always)]
        unsafe fn vec3s(
            self,
            p: *const f32,
            n: usize,
            rows: &super::Rows,
            j: Self::I,
        ) -> [Self::F; 3] {
            // SAFETY: the caller guarantees every index is below n. Each vector is read as 16
            // bytes (x, y, z and the next vector's x) and eight of them are transposed: cheaper
            // than three gathers on CPUs with slow gathers. The last vector has no successor,
            // so a group that names it takes the gathers instead.
            unsafe {
                let last = _mm256_set1_epi32(n as i32 - 1);
                if rows.may_name_last
                    && _mm256_movemask_ps(_mm256_castsi256_ps(_mm256_cmpeq_epi32(j, last))) != 0
                {
                    return super::gather3(self, p, self.times3(j));
                }
                let p = p.add(3 * rows.shift);
                macro_rules! row {
                    ($l:literal) => {
                        _mm_loadu_ps(p.offset(rows.row($l)))
                    };
                }
                let v0 = _mm256_insertf128_ps::<1>(_mm256_castps128_ps256(row!(0)), row!(4));
                let v1 = _mm256_insertf128_ps::<1>(_mm256_castps128_ps256(row!(1)), row!(5));
                let v2 = _mm256_insertf128_ps::<1>(_mm256_castps128_ps256(row!(2)), row!(6));
                let v3 = _mm256_insertf128_ps::<1>(_mm256_castps128_ps256(row!(3)), row!(7));
                let t0 = _mm256_unpacklo_ps(v0, v1);
                let t1 = _mm256_unpackhi_ps(v0, v1);
                let t2 = _mm256_unpacklo_ps(v2, v3);
                let t3 = _mm256_unpackhi_ps(v2, v3);
                [
                    _mm256_shuffle_ps::<0x44>(t0, t2),
                    _mm256_shuffle_ps::<0xEE>(t0, t2),
                    _mm256_shuffle_ps::<0x44>(t1, t3),
                ]
            }
        }
        #[inline(always)]
        unsafe fn vec3s_pair(
            self,
            p: *const f32,
            dp: *const f32,
            n: usize,
            rows: &super::Rows,
            j: Self::I,
        ) -> ([Self::F; 3], [Self::F; 3]) {
            // SAFETY: as in `vec3s`, each lane's row read once for both vectors.
            unsafe {
                let last = _mm256_set1_epi32(n as i32 - 1);
                if rows.may_name_last
                    && _mm256_movemask_ps(_mm256_castsi256_ps(_mm256_cmpeq_epi32(j, last))) != 0
                {
                    let j3 = self.times3(j);
                    return (super::gather3(self, p, j3), super::gather3(self, dp, j3));
                }
                let (p, dp) = (p.add(3 * rows.shift), dp.add(3 * rows.shift));
                let mut v = [_mm256_setzero_ps(); 4];
                let mut u = [_mm256_setzero_ps(); 4];
                for lane in 0..4 {
                    let (lo, hi) = (rows.row(lane), rows.row(lane + 4));
                    v[lane] = _mm256_insertf128_ps::<1>(
                        _mm256_castps128_ps256(_mm_loadu_ps(p.offset(lo))),
                        _mm_loadu_ps(p.offset(hi)),
                    );
                    u[lane] = _mm256_insertf128_ps::<1>(
                        _mm256_castps128_ps256(_mm_loadu_ps(dp.offset(lo))),
                        _mm_loadu_ps(dp.offset(hi)),
                    );
                }
                (transpose4(v), transpose4(u))
            }
        }
        #[inline(always)]
        unsafe fn store3(self, p: *mut f32, v: [Self::F; 3]) {
            // SAFETY: the caller guarantees 24 writable floats. The inverse of `load3`: put each
            // component's values where the three output registers want them, then blend.
            unsafe {
                let x = _mm256_permutevar8x32_ps(v[0], _mm256_setr_epi32(0, 3, 6, 1, 4, 7, 2, 5));
                let y = _mm256_permutevar8x32_ps(v[1], _mm256_setr_epi32(5, 0, 3, 6, 1, 4, 7, 2));
                let z = _mm256_permutevar8x32_ps(v[2], _mm256_setr_epi32(2, 5, 0, 3, 6, 1, 4, 7));
                let a = _mm256_blend_ps::<0b0010_0100>(_mm256_blend_ps::<0b1001_0010>(x, y), z);
                let b = _mm256_blend_ps::<0b0010_0100>(_mm256_blend_ps::<0b1001_0010>(z, x), y);
                let c = _mm256_blend_ps::<0b1001_0010>(_mm256_blend_ps::<0b0010_0100>(y, x), z);
                _mm256_storeu_ps(p, a);
                _mm256_storeu_ps(p.add(8), b);
                _mm256_storeu_ps(p.add(16), c);
            }
        }
        #[inline(always)]
        unsafe fn pairs(self, p: *const f32) -> (Self::F, Self::F) {
            // SAFETY: the caller guarantees 16 readable floats. The pairs of lanes 0, 1, 4, 5
            // then 2, 3, 6, 7: the even floats of each 128-bit half are k in lane order.
            unsafe {
                let (a, b) = (_mm256_loadu_ps(p), _mm256_loadu_ps(p.add(8)));
                (
                    _mm256_shuffle_ps::<0x88>(a, b),
                    _mm256_shuffle_ps::<0xDD>(a, b),
                )
            }
        }
        #[inline(always)]
        unsafe fn pairs_at(self, p: *const f32, idx: Self::I) -> (Self::F, Self::F) {
            // SAFETY: the caller guarantees every pair is readable. Each pair gathered as one
            // double, in the order `pairs` finds them in memory, then the same shuffles.
            unsafe {
                let p = p.cast::<f64>();
                let a = _mm256_i32gather_pd::<8>(p, _mm256_castsi256_si128(idx));
                let b = _mm256_i32gather_pd::<8>(p, _mm256_extracti128_si256::<1>(idx));
                let (a, b) = (_mm256_castpd_ps(a), _mm256_castpd_ps(b));
                (
                    _mm256_shuffle_ps::<0x88>(a, b),
                    _mm256_shuffle_ps::<0xDD>(a, b),
                )
            }
        }
        #[inline(always)]
        fn negative(self, a: Self::F) -> Self::M {
            // Masks only feed `blendv`, which reads the sign bit alone.
            a
        }
        #[inline(always)]
        fn same_bits(self, a: Self::F, b: Self::F) -> bool {
            // SAFETY: AVX2 is enabled where this inlines (see the module documentation).
            unsafe {
                let x = _mm256_xor_si256(_mm256_castps_si256(a), _mm256_castps_si256(b));
                _mm256_testz_si256(x, x) == 1
            }
        }
        #[inline(always)]
        fn dfrom(self, a: [f64; 8]) -> Self::D {
            unsafe {
                (
                    _mm256_loadu_pd(a.as_ptr()),
                    _mm256_loadu_pd(a.as_ptr().add(4)),
                )
            }
        }
        #[inline(always)]
        fn times3(self, i: Self::I) -> Self::I {
            unsafe { _mm256_add_epi32(i, _mm256_add_epi32(i, i)) }
        }
        #[inline(always)]
        fn add(self, a: Self::F, b: Self::F) -> Self::F {
            unsafe { _mm256_add_ps(a, b) }
        }
        #[inline(always)]
        fn sub(self, a: Self::F, b: Self::F) -> Self::F {
            unsafe { _mm256_sub_ps(a, b) }
        }
        #[inline(always)]
        fn mul(self, a: Self::F, b: Self::F) -> Self::F {
            unsafe { _mm256_mul_ps(a, b) }
        }
        #[inline(always)]
        fn fma(self, a: Self::F, b: Self::F, c: Self::F) -> Self::F {
            unsafe { _mm256_fmadd_ps(a, b, c) }
        }
        #[inline(always)]
        fn fnma(self, a: Self::F, b: Self::F, c: Self::F) -> Self::F {
            unsafe { _mm256_fnmadd_ps(a, b, c) }
        }
        #[inline(always)]
        fn div(self, a: Self::F, b: Self::F) -> Self::F {
            unsafe { _mm256_div_ps(a, b) }
        }
        #[inline(always)]
        fn sqrt(self, a: Self::F) -> Self::F {
            unsafe { _mm256_sqrt_ps(a) }
        }
        #[inline(always)]
        fn max(self, a: Self::F, b: Self::F) -> Self::F {
            // maxps returns its second operand unless the first is greater.
            unsafe { _mm256_max_ps(a, b) }
        }
        #[inline(always)]
        fn gt(self, a: Self::F, b: Self::F) -> Self::M {
            unsafe { _mm256_cmp_ps::<_CMP_GT_OQ>(a, b) }
        }
        #[inline(always)]
        fn le(self, a: Self::F, b: Self::F) -> Self::M {
            unsafe { _mm256_cmp_ps::<_CMP_LE_OQ>(a, b) }
        }
        #[inline(always)]
        fn abs(self, a: Self::F) -> Self::F {
            unsafe { _mm256_andnot_ps(_mm256_set1_ps(-0.0), a) }
        }
        #[inline(always)]
        fn select(self, m: Self::M, a: Self::F, b: Self::F) -> Self::F {
            unsafe { _mm256_blendv_ps(b, a, m) }
        }
        #[inline(always)]
        fn keep(self, m: Self::M, a: Self::F) -> Self::F {
            // Comparison masks are all ones or all zeros per lane.
            unsafe { _mm256_and_ps(m, a) }
        }
        #[inline(always)]
        fn iota(self, base: u32) -> Self::I {
            unsafe {
                _mm256_add_epi32(
                    _mm256_set1_epi32(base as i32),
                    _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7),
                )
            }
        }
        #[inline(always)]
        fn store(self, a: Self::F) -> [f32; 8] {
            let mut out = [0.0f32; 8];
            // SAFETY: eight floats of room.
            unsafe { _mm256_storeu_ps(out.as_mut_ptr(), a) };
            out
        }
        #[inline(always)]
        fn widen(self, a: Self::F) -> Self::D {
            unsafe {
                (
                    _mm256_cvtps_pd(_mm256_castps256_ps128(a)),
                    _mm256_cvtps_pd(_mm256_extractf128_ps::<1>(a)),
                )
            }
        }
        #[inline(always)]
        fn dsplat(self, v: f64) -> Self::D {
            unsafe { (_mm256_set1_pd(v), _mm256_set1_pd(v)) }
        }
        #[inline(always)]
        fn dadd(self, a: Self::D, b: Self::D) -> Self::D {
            unsafe { (_mm256_add_pd(a.0, b.0), _mm256_add_pd(a.1, b.1)) }
        }
        #[inline(always)]
        fn dsub(self, a: Self::D, b: Self::D) -> Self::D {
            unsafe { (_mm256_sub_pd(a.0, b.0), _mm256_sub_pd(a.1, b.1)) }
        }
        #[inline(always)]
        fn dmul(self, a: Self::D, b: Self::D) -> Self::D {
            unsafe { (_mm256_mul_pd(a.0, b.0), _mm256_mul_pd(a.1, b.1)) }
        }
        #[inline(always)]
        fn dfma(self, a: Self::D, b: Self::D, c: Self::D) -> Self::D {
            unsafe {
                (
                    _mm256_fmadd_pd(a.0, b.0, c.0),
                    _mm256_fmadd_pd(a.1, b.1, c.1),
                )
            }
        }
        #[inline(always)]
        fn dfnma(self, a: Self::D, b: Self::D, c: Self::D) -> Self::D {
            unsafe {
                (
                    _mm256_fnmadd_pd(a.0, b.0, c.0),
                    _mm256_fnmadd_pd(a.1, b.1, c.1),
                )
            }
        }
        #[inline(always)]
        fn dstore(self, a: Self::D) -> [f64; 8] {
            let mut out = [0.0f64; 8];
            // SAFETY: eight doubles of room.
            unsafe {
                _mm256_storeu_pd(out.as_mut_ptr(), a.0);
                _mm256_storeu_pd(out.as_mut_ptr().add(4), a.1);
            }
            out
        }
    }
}

/// Which lanes the kernels run on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub(crate) enum Isa {
    /// Portable arrays.
    Scalar,
    /// AVX2 and FMA (x86-64 only, detected at run time).
    Avx2,
    /// AVX2 for the f32 half (with the 32 registers of AVX-512VL), AVX-512F for the f64 half
    /// (x86-64 only, detected at run time). The default wherever the CPU has AVX-512F and VL:
    /// it executes fewer instructions, and it ran faster on both machines measured since
    /// session 23: an EPYC Zen 4 (session 23, `relax_probe` 1.27-1.32x at 10k, 1.19-1.23x
    /// at 100k and 1M) and an Intel Xeon with 2 MiB of L2 per core (session 26, alternated:
    /// 1.02-1.03x at 10k on two threads, 1.08-1.12x on one, 1.05-1.10x at 100k and 1M).
    /// On the project's first, Sapphire-Rapids-class machine it ran slower (session 13:
    /// 0.91-0.93x at 10k): there `DERMIS_SIMD=avx2` is the faster choice.
    Avx512,
}

impl Isa {
    /// The path for `n` vertices (gather offsets must fit in i32): the fastest the CPU has
    /// (AVX-512, else AVX2, else the portable one). The environment variable `DERMIS_SIMD`
    /// (`scalar`, `avx2` or `avx512`) picks another, falling back to the best the CPU has
    /// below it (for measurements: every path gives the same bits).
    pub fn detect(n: usize) -> Self {
        static BEST: std::sync::OnceLock<Isa> = std::sync::OnceLock::new();
        let best = *BEST.get_or_init(|| {
            let cap = match std::env::var("DERMIS_SIMD").ok().as_deref() {
                Some("scalar") => Isa::Scalar,
                Some("avx2") => Isa::Avx2,
                Some("avx512") => Isa::Avx512,
                _ => Isa::Avx512,
            };
            Isa::available(0)
                .into_iter()
                .rfind(|&isa| isa <= cap)
                .unwrap_or(Isa::Scalar)
        });
        if n < (1 << 27) { best } else { Self::Scalar }
    }

    /// Every path this CPU can run for `n` vertices, slowest first.
    pub fn available(n: usize) -> Vec<Self> {
        let mut all = vec![Self::Scalar];
        #[cfg(target_arch = "x86_64")]
        if n < (1 << 27)
            && std::arch::is_x86_feature_detected!("avx2")
            && std::arch::is_x86_feature_detected!("fma")
        {
            all.push(Self::Avx2);
            if std::arch::is_x86_feature_detected!("avx512f")
                && std::arch::is_x86_feature_detected!("avx512vl")
            {
                all.push(Self::Avx512);
            }
        }
        let _ = n;
        all
    }
}

// Gathers index positions as three floats.
const _: () = assert!(size_of::<Vec3>() == 12);
// The eight floats of an anchor, in the rows of a slice of [`SlicedAnchors`].
const TARGET: usize = 0;
const NORMAL: usize = 3;
const K_NORMAL: usize = 6;
const K_TANGENT: usize = 7;
/// Floats per anchor, and rows per slice of [`SlicedAnchors`].
const ANCHOR_FLOATS: usize = 8;

/// A solve's anchors in internal order, laid out for the kernels' lanes: per slice of eight
/// vertices, each of an anchor's eight floats (target, normal, `k_normal`, `k_tangent`) for
/// the eight lanes in turn, the last slice padded with zero anchors. The force and curvature
/// gathers read a slice's anchors with eight plain loads, where eight [`VertexAnchor`]s in a
/// row would take a transpose (24 shuffles) per slice and gather: 3-4 % of a relaxation
/// iteration at tube-10k and tube-100k (session 13). Built once per solve, in the pass that
/// puts the anchors in internal order anyway.
#[derive(Debug, Clone, Default)]
pub(crate) struct SlicedAnchors {
    floats: Vec<f32>,
    n: usize,
}

/// Writes the anchors `anchors[order[l]]` into the rows of one slice (lane `l`); whether every
/// float was finite.
fn slice_anchors(rows: &mut [f32], anchors: &[VertexAnchor], order: &[u32]) -> bool {
    let mut finite = true;
    for (lane, &o) in order.iter().enumerate() {
        let a = &anchors[o as usize];
        let values = [
            (TARGET, a.target.x),
            (TARGET + 1, a.target.y),
            (TARGET + 2, a.target.z),
            (NORMAL, a.normal.x),
            (NORMAL + 1, a.normal.y),
            (NORMAL + 2, a.normal.z),
            (K_NORMAL, a.k_normal),
            (K_TANGENT, a.k_tangent),
        ];
        for (row, v) in values {
            rows[row * LANES + lane] = v;
            finite &= v.is_finite();
        }
    }
    finite
}

impl SlicedAnchors {
    /// The anchors of internal vertex `i` at `anchors[order[i]]` (`order` a permutation of
    /// `anchors`' indices), laid out on `par` in chunks of [`kernels::CHUNK`](super::kernels::CHUNK)
    /// vertices and checked finite as they are: `None` if a float is not.
    #[expect(unsafe_code, reason = "disjoint chunks written by one parallel loop")]
    pub(crate) fn finite(anchors: &[VertexAnchor], order: &[u32], par: Par<'_>) -> Option<Self> {
        let n = order.len();
        let chunk = super::kernels::CHUNK;
        let mut floats = vec![0.0f32; n.div_ceil(LANES) * LANES * ANCHOR_FLOATS];
        let mut finite = vec![true; n.div_ceil(chunk)];
        {
            let (rows, oks) = (
                Chunked::new(&mut floats, chunk * ANCHOR_FLOATS),
                Chunked::new(&mut finite, 1),
            );
            par.for_each(oks.chunks(), |c| {
                // SAFETY: each chunk index once per loop.
                let (rows, ok) = unsafe { (rows.chunk(c), oks.chunk(c)) };
                let order = &order[c * chunk..((c + 1) * chunk).min(n)];
                ok[0] = rows
                    .chunks_mut(LANES * ANCHOR_FLOATS)
                    .zip(order.chunks(LANES))
                    .fold(true, |ok, (rows, order)| {
                        ok & slice_anchors(rows, anchors, order)
                    });
            });
        }
        finite.iter().all(|&ok| ok).then_some(Self { floats, n })
    }

    /// Vertices.
    pub fn len(&self) -> usize {
        self.n
    }

    /// The anchor of internal vertex `i < len()`.
    pub fn get(&self, i: usize) -> VertexAnchor {
        let rows = &self.floats[(i / LANES) * LANES * ANCHOR_FLOATS..][..LANES * ANCHOR_FLOATS];
        let at = |row: usize| rows[row * LANES + i % LANES];
        VertexAnchor {
            target: Vec3::new(at(TARGET), at(TARGET + 1), at(TARGET + 2)),
            normal: Vec3::new(at(NORMAL), at(NORMAL + 1), at(NORMAL + 2)),
            k_normal: at(K_NORMAL),
            k_tangent: at(K_TANGENT),
        }
    }

    /// The eight rows of slice `s` (lane `l` of row `c`: float `c` of vertex `8 s + l`'s
    /// anchor; zero past the last vertex).
    ///
    /// # Safety
    /// `s` below the slice count of `len()` vertices.
    #[inline(always)]
    unsafe fn rows<S: Lanes>(&self, l: S, s: usize) -> [S::F; ANCHOR_FLOATS] {
        debug_assert!(s < self.n.div_ceil(LANES));
        let p = self.floats.as_ptr();
        // SAFETY: 64 floats per slice, `s` a slice (the caller's contract).
        std::array::from_fn(|row| unsafe { l.load_at(p.add((s * ANCHOR_FLOATS + row) * LANES)) })
    }
}

/// Inputs of a force gather, in internal order (all of length `sell.n`).
pub(crate) struct ForceInputs<'a> {
    pub sell: &'a Sell,
    pub x: &'a [Vec3],
    /// `Some(d)`: the direction of the step that led to `x`, for `Σ r·d` ([`Sums::rd`]).
    pub dir: Option<&'a [Vec3]>,
    pub anchors: Option<&'a SlicedAnchors>,
    pub external: Option<&'a [Vec3]>,
    /// The preconditioner weights (inverse diagonal) for the dot products; a negative weight
    /// (`-0.0`) marks a pinned vertex, whose force is zeroed. `None`: no pins, no dot products.
    pub w: Option<&'a [f32]>,
}

/// The other ends `j` of one entry's eight springs, decoded once for every array read at them:
/// as float offsets `3 (j − shift)` (one per lane) from the floats of vertex `shift`, so that a
/// 16-bit offset needs no addition per lane.
pub(crate) struct Rows {
    o: [isize; 8],
    shift: usize,
    /// Some lane may name the last vertex (whose 16-byte row would read past the end);
    /// `false` for near slices, which never do (see [`Sell`]).
    may_name_last: bool,
}

impl Rows {
    /// The row of lane `l`.
    #[inline(always)]
    fn row(&self, l: usize) -> isize {
        self.o[l]
    }
}

/// `v[e..e + 8]` without a bounds check.
///
/// # Safety
/// `e + 8 <= v.len()`.
#[inline(always)]
unsafe fn eight<T>(v: &[T], e: usize) -> &[T] {
    debug_assert!(e + LANES <= v.len());
    // SAFETY: the caller's contract.
    unsafe { v.get_unchecked(e..e + LANES) }
}

/// Checks the per-entry arrays of `sell` cover every slice's entries (`start` rises, by
/// construction), so that `eight(.., e)` is in bounds for any entry `e` of any slice.
#[inline(always)]
fn assert_entries(sell: &Sell) {
    let total = sell.start.last().map_or(0, |&t| t as usize);
    let lower = sell.low.last().map_or(0, |&t| t as usize);
    assert!(sell.near.len() == total && sell.kr.len() == total - lower && sell.refs.len() == lower);
}

/// Where the other ends of one slice's springs are stored (see [`Sell`]).
trait Ends: Copy {
    /// The other ends of entry `e` (of this slice) as lanes and as rows.
    fn at<S: Lanes>(self, l: S, e: usize) -> (S::I, Rows);
}

/// A slice whose other ends are 16-bit offsets from its first vertex `base` (times three with
/// `TRIPLE`).
#[derive(Clone, Copy)]
struct Near<'a, const TRIPLE: bool> {
    near: &'a [i16],
    base: u32,
}

impl<const TRIPLE: bool> Ends for Near<'_, TRIPLE> {
    #[inline(always)]
    fn at<S: Lanes>(self, l: S, e: usize) -> (S::I, Rows) {
        // SAFETY: `e` is an entry of this slice (the caller's arrays checked).
        let p = unsafe { eight(self.near, e) };
        // Volatile reads keep the decode scalar (a sign-extending load and a multiply-by-3
        // address per lane): vectorised, the compiler turns it into 64-bit vector arithmetic
        // and extractions, which cost more (and a vector decode stored and read back as
        // addresses is fewer instructions but slower). `opaque` keeps the row `3 j` in a
        // register, so each read of x or d at it scales it by 4 in the address instead of the
        // decode computing the byte offset `12 j` (one instruction fewer per lane).
        // A tripled slice stores the rows themselves.
        let o = std::array::from_fn(|k| {
            // SAFETY: eight offsets in bounds (sliced above).
            let v = unsafe { p.as_ptr().add(k).read_volatile() } as isize;
            opaque(if TRIPLE { v } else { 3 * v })
        });
        let rows = Rows {
            o,
            shift: self.base as usize,
            may_name_last: false,
        };
        let base = if TRIPLE { 3 * self.base } else { self.base };
        (l.load_near(p, base), rows)
    }
}

/// `v`, unknown to the optimiser (no instruction: the value stays where it is).
#[inline(always)]
fn opaque(v: isize) -> isize {
    #[cfg(target_arch = "x86_64")]
    {
        let mut v = v;
        // SAFETY: an empty assembly block that claims to change a register; it reads and
        // writes nothing else.
        unsafe {
            std::arch::asm!(
                "/* {0} */",
                inout(reg) v,
                options(pure, nomem, nostack, preserves_flags)
            )
        };
        v
    }
    #[cfg(not(target_arch = "x86_64"))]
    v
}

/// A wide slice: full indices, `far[e - begin]` for entry `e`.
#[derive(Clone, Copy)]
struct Far<'a> {
    far: &'a [u32],
    begin: usize,
}

impl Ends for Far<'_> {
    #[inline(always)]
    fn at<S: Lanes>(self, l: S, e: usize) -> (S::I, Rows) {
        let p = &self.far[e - self.begin..e - self.begin + LANES];
        let rows = Rows {
            o: std::array::from_fn(|k| 3 * p[k] as isize),
            shift: 0,
            may_name_last: true,
        };
        (l.load_i(p), rows)
    }
}

/// Runs `$body` with `$ends` the [`Ends`] of slice `$s` (one instance per storage).
macro_rules! with_ends {
    ($sell:expr, $s:expr, $ends:ident => $body:expr) => {
        match $sell.far_of($s) {
            None if $sell.tripled($s) => {
                let $ends = Near::<true> {
                    near: &$sell.near,
                    base: ($s * LANES) as u32,
                };
                $body
            }
            None => {
                let $ends = Near::<false> {
                    near: &$sell.near,
                    base: ($s * LANES) as u32,
                };
                $body
            }
            Some(far) => {
                let $ends = Far {
                    far,
                    begin: $sell.start[$s] as usize,
                };
                $body
            }
        }
    };
}

/// The vertices of slice `s` (clamped to the last vertex past the end).
#[inline(always)]
fn own_lanes<S: Lanes>(l: S, sell: &Sell, s: usize) -> S::I {
    if (s + 1) * LANES <= sell.n {
        return l.iota((s * LANES) as u32);
    }
    let last = sell.n - 1;
    let own: [u32; 8] = std::array::from_fn(|lane| (s * LANES + lane).min(last) as u32);
    l.load_i(&own)
}

/// `(p[i], p[i + 1], p[i + 2])` per lane.
///
/// # Safety
/// Every `p + i + 2` in bounds.
#[inline(always)]
pub(crate) unsafe fn gather3<S: Lanes>(l: S, p: *const f32, i: S::I) -> [S::F; 3] {
    // SAFETY: the caller's contract.
    unsafe { [l.gather(p, i), l.gather(p.add(1), i), l.gather(p.add(2), i)] }
}

/// Components of `v[i]` for the vertices `i` of slice `s` (`own`: their clamped indices).
///
/// # Safety
/// `v` has `sell.n` entries.
#[inline(always)]
unsafe fn own_vec3<S: Lanes>(l: S, sell: &Sell, s: usize, own: S::I, v: &[Vec3]) -> [S::F; 3] {
    let p = v.as_ptr().cast::<f32>();
    // SAFETY: a full slice reads v[8s..8s + 8]; otherwise indices are clamped below n.
    unsafe {
        if (s + 1) * LANES <= sell.n {
            l.load3(p.add(3 * LANES * s))
        } else {
            gather3(l, p, l.times3(own))
        }
    }
}

/// The first entry of each slot of `entries` (a whole number of slots): a plain counted loop,
/// cheaper than `step_by` in the kernels' inner loops.
#[inline(always)]
fn slots(entries: &std::ops::Range<usize>) -> impl Iterator<Item = usize> + use<> {
    let start = entries.start;
    (0..(entries.end - start) / LANES).map(move |k| start + k * LANES)
}

/// Net force (before pinning) and twice the energy of the vertices of slice `s`, at `x`.
/// Twice: every term without its factor ½, halved once per chunk
/// (scaling by 2 is exact, so the halved sum has the bits of the sum of the halved terms).
///
/// # Safety
/// All arrays of `f` have `f.sell.n` entries and every spring index is below it.
#[inline(always)]
unsafe fn force_slice<S: Lanes, E: Ends>(
    l: S,
    f: &ForceInputs<'_>,
    s: usize,
    ends: E,
) -> ([S::F; 3], S::D) {
    let sell = f.sell;
    let own = own_lanes(l, sell, s);
    let xp = f.x.as_ptr().cast::<f32>();
    // SAFETY: `x` has n entries (the caller's contract).
    let [yx, yy, yz] = unsafe { own_vec3(l, sell, s, own, f.x) };
    let (yx64, yy64, yz64) = (l.widen(yx), l.widen(yy), l.widen(yz));
    let zero = l.splat(0.0);
    let (one, half) = (l.splat(1.0), l.splat(0.5));
    let (mut fx, mut fy, mut fz) = (zero, zero, zero);
    let mut energy = l.dsplat(0.0);
    // The force of one spring of every lane (entry `e`), with what the energy needs (a macro:
    // a closure would not inherit the target features, and its lane operations would not
    // inline).
    macro_rules! spring {
        ($e:expr, $k:expr) => {{
            let e = $e;
            let (j, rows) = ends.at(l, e);
            let (k, rest) = $k;
            // SAFETY: spring indices are below n, x has n entries.
            let z = unsafe { l.vec3s(xp, sell.n, &rows, j) };
            let (ex, ey, ez) = (l.sub(z[0], yx), l.sub(z[1], yy), l.sub(z[2], yz));
            let l2 = l.fma(ez, ez, l.fma(ey, ey, l.mul(ex, ex)));
            // `len > MIN_POSITIVE` exactly when `l2 > 0`: a positive f32 `l2` is at least the
            // smallest subnormal, whose root is ~3.7e-23 (tested against zero, the test needs
            // no constant of its own nor waits for the root).
            let ok = l.gt(l2, zero);
            let len = l.sqrt(l2);
            let inv = l.div(one, len);
            // A degenerate spring (no direction) adds nothing: its coefficient is zeroed, and
            // `f + e·0` is `f` bit for bit (`e` is finite there, and a sum that starts at +0 is
            // never −0), as if the spring were skipped.
            let c = l.keep(ok, l.mul(l.mul(k, l.sub(len, rest)), inv));
            fx = l.fma(ex, c, fx);
            fy = l.fma(ey, c, fy);
            fz = l.fma(ez, c, fz);
            (j, z, len, inv, ok, k, rest)
        }};
    }
    // Force always, energy from the upper entries on (springs to higher vertices only): two
    // loops, no test per entry. The lower entries take their pairs from their references, the
    // upper ones hold them.
    let kr = sell.kr.as_ptr().cast::<f32>();
    let parts = sell.parts(s);
    let (lower, upper) = (parts.lower, parts.upper);
    match parts.refs {
        Refs::Near { refs, base } => {
            for e in slots(&lower) {
                // SAFETY: a reference per lower entry of the slice, each naming a pair in
                // bounds (by construction).
                spring!(e, unsafe {
                    l.pairs_near(kr, eight(refs, e - lower.start), base)
                });
            }
        }
        Refs::Far { refs } => {
            for e in slots(&lower) {
                let idx = l.load_i(&refs[e - lower.start..e - lower.start + LANES]);
                // SAFETY: every reference names a pair in bounds (by construction).
                spring!(e, unsafe { l.pairs_at(kr, idx) });
            }
        }
    }
    for e in slots(&upper) {
        // SAFETY: the slot's eight pairs are in bounds (checked by the caller).
        let (k, rest) = unsafe { l.pairs(kr.add(2 * (parts.pairs + e - upper.start))) };
        // A negative stiffness marks a spring to a lower vertex (see `Sell::kr`).
        let (_, [zx, zy, zz], len, inv, ok, _, rest) = spring!(e, (l.abs(k), rest));
        // Energy in f64 from exact differences, each spring once (from its lower end): the
        // stretch `|e| − rest` with one Newton step on the f32 length.
        let (ex64, ey64, ez64) = (
            l.dsub(l.widen(zx), yx64),
            l.dsub(l.widen(zy), yy64),
            l.dsub(l.widen(zz), yz64),
        );
        let l2_64 = l.dfma(ez64, ez64, l.dfma(ey64, ey64, l.dmul(ex64, ex64)));
        // Masks applied in f32 (cheaper than on the f64 halves), with the same results: a
        // degenerate spring gets no Newton step (`linear + 0`), and a spring to a lower vertex
        // (negative stiffness) or padding adds `0·st² = +0` to an energy that starts at +0.
        // Twice the energy: `k st²`.
        let len64 = l.widen(len);
        let linear = l.dsub(len64, l.widen(rest));
        let half_inv = l.keep(ok, l.mul(half, inv));
        let stretch = l.dfma(l.dfnma(len64, len64, l2_64), l.widen(half_inv), linear);
        energy = l.dfma(l.dmul(l.widen(l.max(k, zero)), stretch), stretch, energy);
    }
    if let Some(a) = f.anchors {
        // SAFETY: `s` is a slice of the n vertices the anchors have (the caller's contract).
        let rows = unsafe { a.rows(l, s) };
        let (tx, ty, tz) = (rows[TARGET], rows[TARGET + 1], rows[TARGET + 2]);
        let (nx, ny, nz) = (rows[NORMAL], rows[NORMAL + 1], rows[NORMAL + 2]);
        let (kn, kt) = (rows[K_NORMAL], rows[K_TANGENT]);
        let (dx, dy, dz) = (l.sub(yx, tx), l.sub(yy, ty), l.sub(yz, tz));
        let dn = l.fma(dz, nz, l.fma(dy, ny, l.mul(dx, nx)));
        let (tx_, ty_, tz_) = (l.fnma(nx, dn, dx), l.fnma(ny, dn, dy), l.fnma(nz, dn, dz));
        let kdn = l.mul(kn, dn);
        fx = l.sub(fx, l.fma(nx, kdn, l.mul(tx_, kt)));
        fy = l.sub(fy, l.fma(ny, kdn, l.mul(ty_, kt)));
        fz = l.sub(fz, l.fma(nz, kdn, l.mul(tz_, kt)));
        let (dx, dy, dz) = (
            l.dsub(yx64, l.widen(tx)),
            l.dsub(yy64, l.widen(ty)),
            l.dsub(yz64, l.widen(tz)),
        );
        let (nx, ny, nz) = (l.widen(nx), l.widen(ny), l.widen(nz));
        let dn = l.dfma(dz, nz, l.dfma(dy, ny, l.dmul(dx, nx)));
        let (px, py, pz) = (
            l.dfnma(nx, dn, dx),
            l.dfnma(ny, dn, dy),
            l.dfnma(nz, dn, dz),
        );
        let lt = l.dfma(pz, pz, l.dfma(py, py, l.dmul(px, px)));
        let tangent = l.dmul(l.widen(kt), lt);
        energy = l.dadd(energy, l.dfma(l.dmul(l.widen(kn), dn), dn, tangent));
    }
    if let Some(ext) = f.external {
        // SAFETY: `ext` has n entries (the caller's contract); a full slice is read as 24
        // floats and deinterleaved, a partial one gathered at its clamped indices.
        let [gx, gy, gz] = unsafe { own_vec3(l, sell, s, own, ext) };
        fx = l.add(fx, gx);
        fy = l.add(fy, gy);
        fz = l.add(fz, gz);
        let work = l.dfma(
            l.widen(gz),
            yz64,
            l.dfma(l.widen(gy), yy64, l.dmul(l.widen(gx), yx64)),
        );
        energy = l.dsub(energy, l.dadd(work, work));
    }
    ([fx, fy, fz], energy)
}

/// One chunk of the force gather: vertices `first..first + r.len()` (a multiple of [`LANES`]
/// apart from the last chunk), forces into `r`, partial sums returned.
#[inline(always)]
fn force_chunk<S: Lanes>(l: S, f: &ForceInputs<'_>, first: usize, r: &mut [Vec3]) -> Sums {
    let n = f.sell.n;
    let w = f.w;
    assert_entries(f.sell);
    assert!(
        f.x.len() == n
            && f.dir.is_none_or(|d| d.len() == n)
            && f.anchors.is_none_or(|a| a.len() == n)
            && f.external.is_none_or(|e| e.len() == n)
            && w.is_none_or(|w| w.len() == n)
            && first.is_multiple_of(LANES)
            && first + r.len() <= n
    );
    // Per-lane sums (lane = vertex mod 8), added across lanes in order at the end (the
    // energy's twice).
    let zero = l.splat(0.0);
    let (mut energy_acc, mut rr, mut rzr, mut rz_old, mut rd) = (
        l.dsplat(0.0),
        l.dsplat(0.0),
        l.dsplat(0.0),
        l.dsplat(0.0),
        l.dsplat(0.0),
    );
    // The step's direction, for `Σ r·d`.
    let step_dir = f.dir;
    for (s, out) in (first / LANES..).zip(r.chunks_mut(LANES)) {
        // SAFETY: lengths asserted above; spring indices are below n by construction.
        let ([fx, fy, fz], energy) =
            with_ends!(f.sell, s, ends => unsafe { force_slice::<S, _>(l, f, s, ends) });
        let base = s * LANES;
        if out.len() == LANES {
            energy_acc = l.dadd(energy_acc, energy);
            let p = out.as_mut_ptr().cast::<f32>();
            let (fx, fy, fz) = if let Some(w) = w {
                let w = l.load(&w[base..base + LANES]);
                let pinned = l.negative(w);
                let (fx, fy, fz) = (
                    l.select(pinned, zero, fx),
                    l.select(pinned, zero, fy),
                    l.select(pinned, zero, fz),
                );
                let ff = l.fma(fz, fz, l.fma(fy, fy, l.mul(fx, fx)));
                rr = l.dadd(rr, l.widen(ff));
                // SAFETY: `out` holds eight vectors.
                let [ox, oy, oz] = unsafe { l.load3(p) };
                let fo = l.fma(fz, oz, l.fma(fy, oy, l.mul(fx, ox)));
                rzr = l.dadd(rzr, l.widen(l.mul(w, ff)));
                rz_old = l.dadd(rz_old, l.widen(l.mul(w, fo)));
                if let Some(d) = step_dir {
                    // SAFETY: `d` has `n` vectors (asserted above); this slice's eight are
                    // in bounds.
                    let [dx, dy, dz] = unsafe { l.load3(d.as_ptr().add(base).cast::<f32>()) };
                    let fd = l.fma(fz, dz, l.fma(fy, dy, l.mul(fx, dx)));
                    rd = l.dadd(rd, l.widen(fd));
                }
                (fx, fy, fz)
            } else {
                let ff = l.fma(fz, fz, l.fma(fy, fy, l.mul(fx, fx)));
                rr = l.dadd(rr, l.widen(ff));
                (fx, fy, fz)
            };
            // SAFETY: `out` holds eight vectors.
            unsafe { l.store3(p, [fx, fy, fz]) };
            continue;
        }
        // The last, partial slice: the same per-lane values, lane by lane.
        let ([fx, fy, fz], energy) = ([l.store(fx), l.store(fy), l.store(fz)], l.dstore(energy));
        let (mut e8, mut rr8, mut rzr8, mut rzo8, mut rd8) =
            ([0.0f64; 8], [0.0f64; 8], [0.0; 8], [0.0; 8], [0.0; 8]);
        for (lane, slot) in out.iter_mut().enumerate() {
            let i = base + lane;
            let force = if w.is_some_and(|w| w[i].is_sign_negative()) {
                Vec3::ZERO
            } else {
                Vec3::new(fx[lane], fy[lane], fz[lane])
            };
            e8[lane] = energy[lane];
            let ff = fused::dot(force, force);
            rr8[lane] = ff as f64;
            if let Some(w) = w {
                rzr8[lane] = (w[i] * ff) as f64;
                rzo8[lane] = (w[i] * fused::dot(force, *slot)) as f64;
                if let Some(d) = step_dir {
                    rd8[lane] = fused::dot(force, d[i]) as f64;
                }
            }
            *slot = force;
        }
        energy_acc = l.dadd(energy_acc, l.dfrom(e8));
        rr = l.dadd(rr, l.dfrom(rr8));
        if w.is_some() {
            rzr = l.dadd(rzr, l.dfrom(rzr8));
            rz_old = l.dadd(rz_old, l.dfrom(rzo8));
            rd = l.dadd(rd, l.dfrom(rd8));
        }
    }
    let sum = |d: S::D| l.dstore(d).iter().fold(0.0f64, |a, b| a + b);
    Sums {
        energy: 0.5 * sum(energy_acc),
        rr: sum(rr),
        rzr: sum(rzr),
        rz_old: sum(rz_old),
        rd: sum(rd),
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn force_chunk_avx2(f: &ForceInputs<'_>, first: usize, r: &mut [Vec3]) -> Sums {
    force_chunk(avx2::Avx2, f, first, r)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma,avx512f,avx512vl")]
fn force_chunk_avx512(f: &ForceInputs<'_>, first: usize, r: &mut [Vec3]) -> Sums {
    force_chunk(avx512::Avx512, f, first, r)
}

impl ForceInputs<'_> {
    /// Forces of vertices `first..first + r.len()` into `r`, with the chunk's partial sums.
    pub fn chunk(&self, isa: Isa, first: usize, r: &mut [Vec3]) -> Sums {
        match isa {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `Isa::Avx2` is only returned after the CPU check.
            Isa::Avx2 => unsafe { force_chunk_avx2(self, first, r) },
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `Isa::Avx512` is only returned after the CPU checks (AVX2, AVX-512F and VL).
            Isa::Avx512 => unsafe { force_chunk_avx512(self, first, r) },
            _ => force_chunk(Scalar, self, first, r),
        }
    }
}

/// The direction update `d = w·r + β d` of one chunk; returns `Σ r·d`, each vertex's product
/// in f32 (the plain loop's operations) summed in f64 per lane (lane = vertex mod 8), the lanes
/// added in order at the end: eight independent sums, not one chain of dependent additions.
/// `reach[b]` receives the largest `|d|` component of the new direction over the vertices
/// `STEP_BLOCK b..STEP_BLOCK (b + 1)` of the chunk (see [`super::Step`]).
#[inline(always)]
fn direction_chunk<S: Lanes>(
    l: S,
    d: &mut [Vec3],
    r: &[Vec3],
    w: &[f32],
    beta: f32,
    reach: &mut [f32],
) -> f64 {
    assert!(
        r.len() == d.len() && w.len() == d.len() && reach.len() == d.len().div_ceil(STEP_BLOCK)
    );
    let full = d.len() / LANES * LANES;
    let b = l.splat(beta);
    let mut acc = l.dsplat(0.0);
    let mut largest = l.splat(0.0);
    // Elementwise on the floats as stored (no transposes): eight vertices are three registers
    // of eight floats; only the products `r·d` are regrouped per component for the dot. The
    // largest component is a max over the floats, whatever their component.
    for o in (0..full).step_by(LANES) {
        let (rp, dp) = (
            r[o..].as_ptr().cast::<f32>(),
            d[o..].as_mut_ptr().cast::<f32>(),
        );
        // SAFETY: eight vectors (24 floats) from `o < full` are in bounds of `r` and `d`.
        let (rv, dv) = unsafe {
            (
                [0, 8, 16].map(|f| l.load_at(rp.add(f))),
                [0, 8, 16].map(|f| l.load_at(dp.add(f))),
            )
        };
        let wv = l.spread3(l.load(&w[o..o + LANES]));
        let nv: [S::F; 3] = std::array::from_fn(|k| l.fma(dv[k], b, l.mul(rv[k], wv[k])));
        for (k, nv) in nv.iter().enumerate() {
            // SAFETY: as above.
            unsafe { l.store_at(dp.add(8 * k), *nv) };
        }
        let [px, py, pz] = l.deinterleave(std::array::from_fn(|k| l.mul(rv[k], nv[k])));
        acc = l.dadd(acc, l.widen(l.add(l.add(px, py), pz)));
        largest = l.max(
            largest,
            l.max(l.abs(nv[0]), l.max(l.abs(nv[1]), l.abs(nv[2]))),
        );
        if (o + LANES).is_multiple_of(STEP_BLOCK) || o + LANES == full {
            reach[o / STEP_BLOCK] = l.store(largest).into_iter().fold(0.0, f32::max);
            largest = l.splat(0.0);
        }
    }
    if full < d.len() {
        let mut tail = [0.0f64; LANES];
        let mut largest = if full.is_multiple_of(STEP_BLOCK) {
            0.0f32
        } else {
            reach[full / STEP_BLOCK]
        };
        for i in full..d.len() {
            d[i] = d[i].mul_add(Vec3::splat(beta), r[i] * w[i]);
            tail[i - full] = r[i].dot(d[i]) as f64;
            largest = largest.max(d[i].abs().max_element());
        }
        reach[full / STEP_BLOCK] = largest;
        acc = l.dadd(acc, l.dfrom(tail));
    }
    l.dstore(acc).iter().fold(0.0f64, |a, b| a + b)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn direction_chunk_avx2(
    d: &mut [Vec3],
    r: &[Vec3],
    w: &[f32],
    beta: f32,
    reach: &mut [f32],
) -> f64 {
    direction_chunk(avx2::Avx2, d, r, w, beta, reach)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma,avx512f,avx512vl")]
fn direction_chunk_avx512(
    d: &mut [Vec3],
    r: &[Vec3],
    w: &[f32],
    beta: f32,
    reach: &mut [f32],
) -> f64 {
    direction_chunk(avx512::Avx512, d, r, w, beta, reach)
}

/// `d = w·r + β d` over one chunk, returning `Σ r·d` in vertex order (see
/// [`super::kernels::update_direction`]).
pub(crate) fn direction(
    isa: Isa,
    d: &mut [Vec3],
    r: &[Vec3],
    w: &[f32],
    beta: f32,
    reach: &mut [f32],
) -> f64 {
    match isa {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `Isa::Avx2` is only returned after the AVX2 check.
        Isa::Avx2 => unsafe { direction_chunk_avx2(d, r, w, beta, reach) },
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `Isa::Avx512` is only returned after the AVX-512F and VL check.
        Isa::Avx512 => unsafe { direction_chunk_avx512(d, r, w, beta, reach) },
        _ => direction_chunk(Scalar, d, r, w, beta, reach),
    }
}

/// A float a step overwrote that `x − a d` does not give back: its index among the chunk's
/// floats and its value before the step.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Spilled {
    /// Its index among the chunk's floats (`3 i + axis`).
    pub at: u32,
    /// Its value before the step.
    pub old: f32,
}

/// `x += a d` over one chunk, noting in `spill` (cleared first) each float whose old value
/// `x − a d` would not give back bit for bit (its index in the chunk's floats, and the value):
/// with them, [`retreat`] restores the chunk exactly. Rounding makes `x + a d − a d` differ from
/// `x` only where the sum crossed into a wider binade or the rounding tied: rarely.
#[inline(always)]
fn advance_chunk<S: Lanes>(l: S, x: &mut [Vec3], d: &[Vec3], a: f32, spill: &mut Vec<Spilled>) {
    assert!(x.len() == d.len());
    spill.clear();
    // Elementwise on the floats as stored.
    let floats = 3 * x.len();
    let full = floats / LANES * LANES;
    let (xp, dp) = (x.as_mut_ptr().cast::<f32>(), d.as_ptr().cast::<f32>());
    let (av, back) = (l.splat(a), l.splat(-a));
    for f in (0..full).step_by(LANES) {
        // SAFETY: eight floats from `f < full <= floats` are in bounds of `x` and `d`.
        unsafe {
            let (old, dv) = (l.load_at(xp.add(f)), l.load_at(dp.add(f)));
            let moved = l.fma(dv, av, old);
            l.store_at(xp.add(f), moved);
            let undone = l.fma(dv, back, moved);
            if !l.same_bits(undone, old) {
                let (old, undone) = (l.store(old), l.store(undone));
                for k in 0..LANES {
                    if old[k].to_bits() != undone[k].to_bits() {
                        spill.push(Spilled {
                            at: (f + k) as u32,
                            old: old[k],
                        });
                    }
                }
            }
        }
    }
    advance_tail(x, d, a, full, spill);
}

/// [`advance_chunk`]'s floats from `from` on, one by one (the tail after its groups of eight).
#[inline(always)]
fn advance_tail(x: &mut [Vec3], d: &[Vec3], a: f32, from: usize, spill: &mut Vec<Spilled>) {
    for f in from..3 * x.len() {
        let (i, axis) = (f / 3, f % 3);
        let old = x[i][axis];
        let moved = d[i][axis].mul_add(a, old);
        x[i][axis] = moved;
        if d[i][axis].mul_add(-a, moved).to_bits() != old.to_bits() {
            spill.push(Spilled { at: f as u32, old });
        }
    }
}

/// [`advance_chunk`] on the AVX-512 path: the same floats and the same spills, in the same
/// order. A group of eight floats with spills compresses them (a mask compare, two compresses
/// and one 64-byte store of the pairs) instead of testing its lanes one by one. A solve's
/// first steps, large against the coordinates, spill often: on the bench's tube at its
/// mid-clip pose solved from rest up to 668 of a chunk's 3,072 floats, 451 a step on average
/// over 30 steps (session 27); lane by lane those groups took half the step's time and
/// unbalanced the threads' shares of the loops after it.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma,avx512f,avx512vl")]
fn advance_chunk_avx512(x: &mut [Vec3], d: &[Vec3], a: f32, spill: &mut Vec<Spilled>) {
    use std::arch::x86_64::*;
    assert!(x.len() == d.len());
    spill.clear();
    let floats = 3 * x.len();
    let full = floats / LANES * LANES;
    let (xp, dp) = (x.as_mut_ptr().cast::<f32>(), d.as_ptr().cast::<f32>());
    let (av, back) = (_mm256_set1_ps(a), _mm256_set1_ps(-a));
    let lane = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
    // `[indices | values]` to `(index, value)` pairs.
    let zip = _mm512_setr_epi32(0, 8, 1, 9, 2, 10, 3, 11, 4, 12, 5, 13, 6, 14, 7, 15);
    let mut len = 0usize;
    let mut out = spill.as_mut_ptr();
    let mut room = spill.capacity();
    for f in (0..full).step_by(LANES) {
        // SAFETY: eight floats from `f < full <= floats` are in bounds of `x` and `d`; the
        // 64-byte store goes to the spill list's spare capacity (at least eight pairs, checked
        // just before), and the length covers only the pairs written.
        unsafe {
            let (old, dv) = (_mm256_loadu_ps(xp.add(f)), _mm256_loadu_ps(dp.add(f)));
            let moved = _mm256_fmadd_ps(dv, av, old);
            _mm256_storeu_ps(xp.add(f), moved);
            let undone = _mm256_fmadd_ps(dv, back, moved);
            let differ =
                _mm256_cmpneq_epi32_mask(_mm256_castps_si256(undone), _mm256_castps_si256(old));
            if differ != 0 {
                if room < len + LANES {
                    spill.set_len(len);
                    spill.reserve(LANES.max(len));
                    (out, room) = (spill.as_mut_ptr(), spill.capacity());
                }
                let at = _mm256_add_epi32(lane, _mm256_set1_epi32(f as i32));
                let at = _mm256_maskz_compress_epi32(differ, at);
                let old = _mm256_maskz_compress_epi32(differ, _mm256_castps_si256(old));
                let both = _mm512_inserti64x4::<1>(_mm512_castsi256_si512(at), old);
                _mm512_storeu_si512(out.add(len).cast(), _mm512_permutexvar_epi32(zip, both));
                len += differ.count_ones() as usize;
            }
        }
    }
    // SAFETY: the first `len` pairs were written above, within the capacity.
    unsafe { spill.set_len(len) };
    advance_tail(x, d, a, full, spill);
}

/// Undoes [`advance_chunk`] with the same `d`, `a` and `spill`: `x − a d`, then the spilled
/// floats put back.
#[inline(always)]
fn retreat_chunk<S: Lanes>(l: S, x: &mut [Vec3], d: &[Vec3], a: f32, spill: &[Spilled]) {
    assert!(x.len() == d.len());
    let floats = 3 * x.len();
    let full = floats / LANES * LANES;
    let (xp, dp) = (x.as_mut_ptr().cast::<f32>(), d.as_ptr().cast::<f32>());
    let back = l.splat(-a);
    for f in (0..full).step_by(LANES) {
        // SAFETY: eight floats from `f < full <= floats` are in bounds of `x` and `d`.
        unsafe {
            let undone = l.fma(l.load_at(dp.add(f)), back, l.load_at(xp.add(f)));
            l.store_at(xp.add(f), undone);
        }
    }
    for f in full..floats {
        // SAFETY: `f < floats`, in bounds of both.
        unsafe { *xp.add(f) = (*dp.add(f)).mul_add(-a, *xp.add(f)) };
    }
    for &Spilled { at, old } in spill {
        let at = at as usize;
        x[at / 3][at % 3] = old;
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn advance_chunk_avx2(x: &mut [Vec3], d: &[Vec3], a: f32, spill: &mut Vec<Spilled>) {
    advance_chunk(avx2::Avx2, x, d, a, spill)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn retreat_chunk_avx2(x: &mut [Vec3], d: &[Vec3], a: f32, spill: &[Spilled]) {
    retreat_chunk(avx2::Avx2, x, d, a, spill)
}

/// `x += a d` over one chunk, with what [`retreat`] needs to undo it exactly in `spill`.
pub(crate) fn advance(isa: Isa, x: &mut [Vec3], d: &[Vec3], a: f32, spill: &mut Vec<Spilled>) {
    match isa {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `Isa::Avx2` and `Isa::Avx512` are only returned after the AVX2 check.
        Isa::Avx2 => unsafe { advance_chunk_avx2(x, d, a, spill) },
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `Isa::Avx512` is only returned after the AVX-512F and VL checks.
        Isa::Avx512 => unsafe { advance_chunk_avx512(x, d, a, spill) },
        _ => advance_chunk(Scalar, x, d, a, spill),
    }
}

/// Undoes [`advance`] (the same `d`, `a` and `spill`) bit for bit.
pub(crate) fn retreat(isa: Isa, x: &mut [Vec3], d: &[Vec3], a: f32, spill: &[Spilled]) {
    match isa {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: as in `advance`.
        Isa::Avx2 | Isa::Avx512 => unsafe { retreat_chunk_avx2(x, d, a, spill) },
        _ => retreat_chunk(Scalar, x, d, a, spill),
    }
}

/// Per-vertex `Σ_{j > i} dᵀ H_ij d` over the slices `slices`, in f32 per vertex.
#[inline(always)]
fn curvature_chunk<S: Lanes>(
    l: S,
    sell: &Sell,
    x: &[Vec3],
    d: &[Vec3],
    anchors: Option<&SlicedAnchors>,
    slices: std::ops::Range<usize>,
) -> f64 {
    let n = sell.n;
    assert_entries(sell);
    assert!(
        x.len() == n
            && d.len() == n
            && anchors.is_none_or(|a| a.len() == n)
            && slices.end <= sell.slices()
    );
    let xp = x.as_ptr().cast::<f32>();
    let dp = d.as_ptr().cast::<f32>();
    let zero = l.splat(0.0);
    let one = l.splat(1.0);
    let tiny2 = l.splat(f32::MIN_POSITIVE * f32::MIN_POSITIVE);
    // Per-lane sums (lane = vertex mod 8), added across lanes in order at the end.
    let mut acc = l.dsplat(0.0);
    for s in slices {
        let own = own_lanes(l, sell, s);
        // SAFETY (all gathers): indices below n, x and d of n entries (asserted).
        let [xx, xy, xz] = unsafe { own_vec3(l, sell, s, own, x) };
        let [dx, dy, dz] = unsafe { own_vec3(l, sell, s, own, d) };
        let vertex = with_ends!(sell, s, ends => {
            let mut vertex = zero;
        let (upper, pairs) = sell.upper_pairs(s);
        let kr = sell.kr.as_ptr().cast::<f32>();
        for e in slots(&upper) {
            let (j, rows) = ends.at(l, e);
            // SAFETY: `e` is an upper entry of slice `s`: its slot's pairs are in bounds
            // (the arrays checked above).
            let (k, rest) = unsafe { l.pairs(kr.add(2 * (pairs + e - upper.start))) };
            // SAFETY: spring indices are below n, x and d have n entries.
            let ([zx, zy, zz], [vx, vy, vz]) = unsafe { l.vec3s_pair(xp, dp, n, &rows, j) };
            let (ex, ey, ez) = (l.sub(zx, xx), l.sub(zy, xy), l.sub(zz, xz));
            let (ux, uy, uz) = (l.sub(vx, dx), l.sub(vy, dy), l.sub(vz, dz));
            let l2 = l.fma(ez, ez, l.fma(ey, ey, l.mul(ex, ex)));
            let uu = l.fma(uz, uz, l.fma(uy, uy, l.mul(ux, ux)));
            let eu = l.fma(ez, uz, l.fma(ey, uy, l.mul(ex, ux)));
            let inv = l.div(one, l.sqrt(l2));
            let along = l.mul(eu, inv);
            let along2 = l.mul(along, along);
            let transverse = l.max(l.fnma(along, along, uu), zero);
            let taut = l.max(l.fnma(rest, inv, one), zero);
            // A spring to a lower vertex (negative stiffness) or padding adds `+0` (every
            // term is finite and `vertex` is never `-0`).
            let k = l.max(k, zero);
            let inner = l.select(l.le(l2, tiny2), uu, l.fma(taut, transverse, along2));
            vertex = l.fma(k, inner, vertex);
        }
            vertex
        });
        let valid = (s + 1) * LANES <= n;
        if valid {
            acc = l.dadd(acc, l.widen(vertex));
        } else {
            let v = l.store(vertex);
            acc = l.dadd(
                acc,
                l.dfrom(std::array::from_fn(|lane| {
                    if s * LANES + lane < n {
                        v[lane] as f64
                    } else {
                        0.0
                    }
                })),
            );
        }
        if let Some(a) = anchors {
            let term = if valid {
                // SAFETY: `s` is a slice of the n vertices the anchors have (asserted).
                let rows = unsafe { a.rows(l, s) };
                let (nx, ny, nz) = (rows[NORMAL], rows[NORMAL + 1], rows[NORMAL + 2]);
                let (kn, kt) = (rows[K_NORMAL], rows[K_TANGENT]);
                let un = l.fma(dz, nz, l.fma(dy, ny, l.mul(dx, nx)));
                let uu = l.fma(dz, dz, l.fma(dy, dy, l.mul(dx, dx)));
                let t = l.fma(
                    l.mul(kn, un),
                    un,
                    l.mul(kt, l.max(l.fnma(un, un, uu), zero)),
                );
                l.widen(t)
            } else {
                l.dfrom(std::array::from_fn(|lane| {
                    let i = s * LANES + lane;
                    if i < n {
                        a.get(i).curvature(d[i]) as f64
                    } else {
                        0.0
                    }
                }))
            };
            acc = l.dadd(acc, term);
        }
    }
    l.dstore(acc).iter().fold(0.0f64, |a, b| a + b)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn curvature_chunk_avx2(
    sell: &Sell,
    x: &[Vec3],
    d: &[Vec3],
    anchors: Option<&SlicedAnchors>,
    slices: std::ops::Range<usize>,
) -> f64 {
    curvature_chunk(avx2::Avx2, sell, x, d, anchors, slices)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma,avx512f,avx512vl")]
fn curvature_chunk_avx512(
    sell: &Sell,
    x: &[Vec3],
    d: &[Vec3],
    anchors: Option<&SlicedAnchors>,
    slices: std::ops::Range<usize>,
) -> f64 {
    curvature_chunk(avx512::Avx512, sell, x, d, anchors, slices)
}

/// `Σ dᵀ H d` contributions of the vertices in `slices` (see [`Frame::curvature`]).
///
/// [`Frame::curvature`]: super::kernels::Frame::curvature
pub(crate) fn curvature(
    isa: Isa,
    sell: &Sell,
    x: &[Vec3],
    d: &[Vec3],
    anchors: Option<&SlicedAnchors>,
    slices: std::ops::Range<usize>,
) -> f64 {
    match isa {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `Isa::Avx2` is only returned after the CPU check.
        Isa::Avx2 => unsafe { curvature_chunk_avx2(sell, x, d, anchors, slices) },
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `Isa::Avx512` is only returned after the CPU checks (AVX2, AVX-512F and VL).
        Isa::Avx512 => unsafe { curvature_chunk_avx512(sell, x, d, anchors, slices) },
        _ => curvature_chunk(Scalar, sell, x, d, anchors, slices),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::solver::SpringSystem;

    /// A shuffled, irregular spring net (a 23 x 19 grid with diagonals and some long springs,
    /// listed in a scrambled vertex order), anchors, external forces and a few pins.
    fn net() -> (
        SpringSystem,
        Vec<Vec3>,
        Vec<VertexAnchor>,
        Vec<Vec3>,
        Vec<bool>,
    ) {
        let (w, h) = (23u32, 19u32);
        let n = (w * h) as usize;
        let scramble = |v: u32| (v * 211) % (w * h);
        let mut rest_pos = vec![Vec3::ZERO; n];
        for y in 0..h {
            for x in 0..w {
                let p = Vec3::new(x as f32 * 0.01, y as f32 * 0.01, 0.002 * (x as f32).sin());
                rest_pos[scramble(y * w + x) as usize] = p;
            }
        }
        let mut edges = Vec::new();
        for y in 0..h {
            for x in 0..w {
                let v = y * w + x;
                if x + 1 < w {
                    edges.push([scramble(v), scramble(v + 1)]);
                }
                if y + 1 < h {
                    edges.push([scramble(v), scramble(v + w)]);
                }
                if x + 1 < w && y + 1 < h && (x + y) % 3 != 0 {
                    edges.push([scramble(v + w + 1), scramble(v)]);
                }
                if v % 17 == 0 {
                    edges.push([scramble(v), scramble((v * 7 + 5) % (w * h))]);
                }
            }
        }
        edges.retain(|[a, b]| a != b);
        let k: Vec<f32> = (0..edges.len()).map(|e| 50.0 + (e % 13) as f32).collect();
        let rest: Vec<f32> = edges
            .iter()
            .map(|&[a, b]| rest_pos[a as usize].distance(rest_pos[b as usize]) * 0.97)
            .collect();
        let system = SpringSystem::new(&rest_pos, &edges, &k, &rest).unwrap();
        assert_springs_are(&system, &edges, &k, &rest);
        // Uneven degrees: padding, and slots where some lanes' springs go down and others' up.
        let sell = &system.sell;
        let degree = |i: usize| sell.springs_of(i).count();
        assert!((0..sell.slices()).any(|s| {
            let d: Vec<usize> = (s * LANES..((s + 1) * LANES).min(n)).map(degree).collect();
            d.iter().min() != d.iter().max()
        }));
        assert!((0..sell.slices()).any(|s| !sell.lower_entries(s).is_empty()));
        let x: Vec<Vec3> = rest_pos
            .iter()
            .enumerate()
            .map(|(i, p)| *p + 0.001 * Vec3::new((i as f32).sin(), (i as f32 * 1.3).cos(), 0.5))
            .collect();
        // A degenerate spring: two vertices at the same place.
        let mut x = x;
        let [a, b] = edges[5];
        x[b as usize] = x[a as usize];
        let anchors = (0..n)
            .map(|i| VertexAnchor {
                target: rest_pos[i],
                normal: Vec3::new(0.0, (i as f32).sin(), (i as f32).cos()).normalize(),
                k_normal: 20.0 + i as f32 * 0.01,
                k_tangent: 2.0,
            })
            .collect();
        let ext = (0..n)
            .map(|i| Vec3::new(0.0, 0.0, -0.01 * (i % 5) as f32))
            .collect();
        let pinned = (0..n).map(|i| i % 31 == 4).collect();
        (system, x, anchors, ext, pinned)
    }

    /// Checks the system's springs (stored once per spring, in slices) read back as the
    /// half-springs of `edges` at both ends, in internal order, sorted by their other end.
    fn assert_springs_are(system: &SpringSystem, edges: &[[u32; 2]], k: &[f32], rest: &[f32]) {
        let order = system.order();
        let mut rank = vec![0u32; order.len()];
        for (i, &o) in order.iter().enumerate() {
            rank[o as usize] = i as u32;
        }
        let internal: Vec<[u32; 2]> = edges
            .iter()
            .map(|&[a, b]| [rank[a as usize], rank[b as usize]])
            .collect();
        let expected =
            crate::solver::sell::tests::csr(order.len(), &internal, |e| k[e], |e| rest[e]);
        assert_eq!(system.csr(), expected);
    }

    /// The plain per-vertex loop over CSR springs the kernels must reproduce bit for bit.
    fn reference(
        sell: &Sell,
        x: &[Vec3],
        anchors: &[VertexAnchor],
        ext: &[Vec3],
        pinned: &[bool],
    ) -> (Vec<Vec3>, f64) {
        // Energy summed per lane (vertex mod 8), then across lanes in order.
        let mut lanes = [0.0f64; 8];
        let forces = (0..sell.n)
            .map(|i| {
                let yi = x[i];
                let (mut force, mut energy) = (Vec3::ZERO, 0.0f64);
                for s in sell.springs_of(i) {
                    let j = s.other as usize;
                    let e = x[j] - yi;
                    let len = fused::dot(e, e).sqrt();
                    let inv_len = 1.0 / len;
                    if len > f32::MIN_POSITIVE {
                        force = e.mul_add(Vec3::splat(s.k * (len - s.rest) * inv_len), force);
                    }
                    if j > i {
                        let e64 = x[j].as_dvec3() - yi.as_dvec3();
                        let l2 = fused::dot64(e64, e64);
                        let len64 = len as f64;
                        let linear = len64 - s.rest as f64;
                        let st = if len > f32::MIN_POSITIVE {
                            (-len64)
                                .mul_add(len64, l2)
                                .mul_add((0.5 * inv_len) as f64, linear)
                        } else {
                            linear
                        };
                        energy = (0.5 * s.k as f64 * st).mul_add(st, energy);
                    }
                }
                let (fa, ea) = anchors[i].force_energy(yi);
                force += fa;
                energy += ea;
                force += ext[i];
                energy -= fused::dot64(ext[i].as_dvec3(), yi.as_dvec3());
                lanes[i % 8] += energy;
                if pinned[i] { Vec3::ZERO } else { force }
            })
            .collect();
        (forces, lanes.iter().fold(0.0, |a, b| a + b))
    }

    fn isas() -> Vec<Isa> {
        Isa::available(1000)
    }

    #[test]
    fn the_default_path_is_the_widest_this_cpu_has() {
        if std::env::var_os("DERMIS_SIMD").is_none() {
            assert_eq!(Some(&Isa::detect(0)), Isa::available(0).last());
        }
        // Whatever the default, it is a path this CPU runs.
        assert!(Isa::available(0).contains(&Isa::detect(0)));
    }

    #[test]
    fn forces_and_energy_match_the_plain_loop_bit_for_bit() {
        let (system, x, anchors, ext, pinned) = net();
        let sell = &system.sell;
        let xi = system.to_internal(&x);
        let (ai, ei, pi) = (
            system.to_internal(&anchors),
            system.to_internal(&ext),
            system.to_internal(&pinned),
        );
        let sliced = SlicedAnchors::finite(&anchors, &system.order, Par::Pool).unwrap();
        let w = weights(&pi);
        // The gather with and without a step's direction `d` must both reproduce the reference;
        // with it, `Σ r·d` too.
        let d: Vec<Vec3> = (0..sell.n)
            .map(|i| Vec3::new((i as f32 * 0.7).sin(), (i as f32 * 0.3).cos(), 0.2) * 1e-3)
            .collect();
        let (want, want_energy) = reference(sell, &xi, &ai, &ei, &pi);
        for dir in [None, Some(d.as_slice())] {
            // `Σ r·d` with the step's direction (none without a step), summed plainly.
            let want_rd: f64 = dir.map_or(0.0, |d| {
                want.iter()
                    .zip(d)
                    .map(|(f, d)| f64::from(fused::dot(*f, *d)))
                    .sum()
            });
            let mut rd_bits = None;
            for isa in isas() {
                let inputs = ForceInputs {
                    sell,
                    x: &xi,
                    dir,
                    anchors: Some(&sliced),
                    external: Some(&ei),
                    w: Some(&w),
                };
                let mut r = vec![Vec3::ZERO; sell.n];
                let sums = inputs.chunk(isa, 0, &mut r);
                let bits = |v: &Vec3| v.to_array().map(f32::to_bits);
                for (i, (got, want)) in r.iter().zip(&want).enumerate() {
                    assert_eq!(bits(got), bits(want), "{isa:?}: force of vertex {i}");
                }
                assert_eq!(sums.energy.to_bits(), want_energy.to_bits(), "{isa:?}");
                assert!(r.iter().zip(&pi).all(|(f, p)| !p || *f == Vec3::ZERO));
                assert!(pi.iter().any(|p| *p));
                // The same per-lane order on every path; the plain sum up to its order.
                assert!(
                    (sums.rd - want_rd).abs() <= 1e-12 * want_rd.abs().max(1e-30),
                    "{isa:?}: Σ r·d {} vs {want_rd}",
                    sums.rd
                );
                assert_eq!(dir.is_some(), want_rd != 0.0);
                assert_eq!(*rd_bits.get_or_insert(sums.rd.to_bits()), sums.rd.to_bits());
            }
        }
    }

    /// Inverse-diagonal-like weights with the pin flags as their sign.
    fn weights(pinned: &[bool]) -> Vec<f32> {
        (0..pinned.len())
            .map(|i| {
                if pinned[i] {
                    -0.0
                } else {
                    1.0 / (3.0 + i as f32)
                }
            })
            .collect()
    }

    #[test]
    fn wide_slices_match_the_plain_loop_bit_for_bit() {
        // A zigzag strip of 80 000 vertices plus long springs: the slices they touch keep full
        // indices (beyond a 16-bit offset), the others 16-bit offsets.
        let n = 80_000u32;
        let pos: Vec<Vec3> = (0..n)
            .map(|i| Vec3::new(i as f32 * 1e-3, (i % 2) as f32 * 1e-3, 0.0))
            .collect();
        let mut edges: Vec<[u32; 2]> = (0..n - 1).map(|i| [i, i + 1]).collect();
        edges.extend((0..n - 2).step_by(2).map(|i| [i, i + 2]));
        edges.extend((0..40).map(|i| [i * 7, n - 1 - i * 997]));
        // Springs 20 000 vertices long: 16-bit offsets, but too long to store times three.
        edges.extend((0..30).map(|i| [1000 + i * 13, 21_000 + i * 13]));
        // Springs 30 000 vertices long: 16-bit offsets, but their pairs more than 65 535 pairs
        // back from their upper end (two or three per vertex): full pair indices.
        edges.extend((0..30).map(|i| [40_000 + i * 17, 70_000 + i * 17]));
        let k: Vec<f32> = (0..edges.len()).map(|e| 10.0 + (e % 7) as f32).collect();
        let rest: Vec<f32> = edges
            .iter()
            .map(|&[a, b]| pos[a as usize].distance(pos[b as usize]) * 0.9)
            .collect();
        // In Morton order, which keeps the long springs long (the bandwidth order would not).
        let system =
            SpringSystem::in_order(crate::solver::morton_order(&pos), &edges, &k, &rest).unwrap();
        assert_springs_are(&system, &edges, &k, &rest);
        let sell = &system.sell;
        assert!(!sell.wide.is_empty() && sell.wide.len() < sell.slices() / 10);
        // All three storages of the other ends occur, and both of the references to the pairs
        // (with near and with far other ends).
        let near = |s: &usize| sell.far_of(*s).is_none();
        assert!((0..sell.slices()).any(|s| near(&s) && !sell.tripled(s)));
        assert!((0..sell.slices()).any(|s| near(&s) && sell.tripled(s)));
        assert!((0..sell.slices()).any(|s| near(&s) && sell.has_far_refs(s)));
        assert!((0..sell.slices()).any(|s| !near(&s) && sell.has_far_refs(s)));
        assert!((0..sell.slices()).any(|s| near(&s) && !sell.has_far_refs(s)));
        let x: Vec<Vec3> = (0..n as usize)
            .map(|i| system.to_internal(&pos)[i] + Vec3::splat((i as f32).sin() * 1e-4))
            .collect();
        let d: Vec<Vec3> = (0..n as usize)
            .map(|i| Vec3::new((i as f32 * 0.7).sin(), 0.1, (i as f32 * 0.3).cos()) * 1e-3)
            .collect();
        let none = vec![false; n as usize];
        let zero = vec![Vec3::ZERO; n as usize];
        let free = vec![VertexAnchor::default(); n as usize];
        let (want, want_energy) = reference(sell, &x, &free, &zero, &none);
        for isa in isas() {
            let inputs = ForceInputs {
                sell,
                x: &x,
                dir: None,
                anchors: None,
                external: None,
                w: None,
            };
            let mut r = vec![Vec3::ZERO; sell.n];
            let sums = inputs.chunk(isa, 0, &mut r);
            let bits = |v: &Vec3| v.to_array().map(f32::to_bits);
            for (i, (got, want)) in r.iter().zip(&want).enumerate() {
                assert_eq!(bits(got), bits(want), "{isa:?}: force of vertex {i}");
            }
            assert_eq!(sums.energy.to_bits(), want_energy.to_bits(), "{isa:?}");
            let got = curvature(isa, sell, &x, &d, None, 0..sell.slices());
            let scalar = curvature(Isa::Scalar, sell, &x, &d, None, 0..sell.slices());
            assert_eq!(got.to_bits(), scalar.to_bits(), "{isa:?}");
        }
        // The curvature against the plain loop over the springs.
        let mut lanes = [0.0f64; 8];
        for i in 0..sell.n {
            let mut vertex = 0.0f32;
            for s in sell.springs_of(i).filter(|s| s.other as usize > i) {
                let (e, u) = (x[s.other as usize] - x[i], d[s.other as usize] - d[i]);
                vertex = s.k.mul_add(spring_curvature(&s, e, u), vertex);
            }
            lanes[i % 8] += vertex as f64;
        }
        let want = lanes.iter().fold(0.0f64, |a, b| a + b);
        let got = curvature(Isa::Scalar, sell, &x, &d, None, 0..sell.slices());
        assert_eq!(got.to_bits(), want.to_bits());
    }

    /// `dᵀ H d / k` of one spring along `e` for the relative displacement `u`, the plain way
    /// (the caller adds `k` times it to its sum with one rounding, as the kernels do).
    fn spring_curvature(s: &crate::solver::Spring, e: Vec3, u: Vec3) -> f32 {
        let (l2, uu) = (fused::dot(e, e), fused::dot(u, u));
        if l2 <= f32::MIN_POSITIVE * f32::MIN_POSITIVE {
            return uu;
        }
        let inv_len = 1.0 / l2.sqrt();
        let along = fused::dot(e, u) * inv_len;
        let transverse = (-along).mul_add(along, uu).max(0.0);
        let taut = (-s.rest).mul_add(inv_len, 1.0).max(0.0);
        taut.mul_add(transverse, along * along)
    }

    #[test]
    fn direction_update_matches_the_plain_loop_bit_for_bit() {
        // 1003 vertices: full slices and a partial tail; values spanning many magnitudes so
        // any change of operation order would show in the low bits.
        let n = 1003;
        let v = |i: usize, a: f32| {
            let t = i as f32 * a;
            Vec3::new(t.sin() * 1e3, (t * 1.7).cos() * 1e-3, (t * 0.3).sin() + 0.1)
        };
        // Directions from 1e-6 to 1e6 (every third vertex, across the lanes): products `r·d`
        // from ~1 to ~1e12, whose f64 sum rounds differently in another order.
        let r: Vec<Vec3> = (0..n).map(|i| v(i, 0.37)).collect();
        let d0: Vec<Vec3> = (0..n)
            .map(|i| v(i, 1.91) * [1.0, 1e-6, 1e6][i % 3])
            .collect();
        let w: Vec<f32> = (0..n).map(|i| 1e-9 / (3.0 + i as f32)).collect();
        let beta = 0.618_034f32;
        // The plain loop, `Σ r·d` summed per lane (vertex mod 8), the lanes in order.
        let mut want_d = d0.clone();
        let (mut lanes, mut in_order) = ([0.0f64; LANES], 0.0f64);
        for i in 0..n {
            want_d[i] = want_d[i].mul_add(Vec3::splat(beta), r[i] * w[i]);
            lanes[i % LANES] += r[i].dot(want_d[i]) as f64;
            in_order += r[i].dot(want_d[i]) as f64;
        }
        let want = lanes.iter().fold(0.0f64, |a, b| a + b);
        // The data tells the two orders apart.
        assert_ne!(want.to_bits(), in_order.to_bits());
        let x0: Vec<Vec3> = (0..n).map(|i| v(i, 0.53)).collect();
        let a = 0.0371f32;
        let want_x: Vec<Vec3> = x0
            .iter()
            .zip(&d0)
            .map(|(x, d)| d.mul_add(Vec3::splat(a), *x))
            .collect();
        let bits = |v: &Vec3| v.to_array().map(f32::to_bits);
        // Each block's largest component (the last block partial, its SIMD part ending
        // inside it).
        let want_reach: Vec<f32> = want_d
            .chunks(STEP_BLOCK)
            .map(|b| b.iter().map(|v| v.abs().max_element()).fold(0.0, f32::max))
            .collect();
        assert_eq!(want_reach.len(), 16);
        for isa in isas() {
            let mut d = d0.clone();
            let mut reach = vec![-1.0f32; n.div_ceil(STEP_BLOCK)];
            let got = direction(isa, &mut d, &r, &w, beta, &mut reach);
            assert_eq!(got.to_bits(), want.to_bits(), "{isa:?}");
            for (a, b) in d.iter().zip(&want_d) {
                assert_eq!(bits(a), bits(b));
            }
            assert_eq!(reach, want_reach, "{isa:?}");
            let mut x = x0.clone();
            advance(isa, &mut x, &d0, a, &mut Vec::new());
            for (a, b) in x.iter().zip(&want_x) {
                assert_eq!(bits(a), bits(b), "{isa:?}");
            }
        }
    }

    /// The solver steps `x` to its trial point in place and undoes a rejected trial: the undo
    /// must give back every bit, also where `x + a d − a d` rounds to another float.
    #[test]
    fn a_step_is_undone_bit_for_bit() {
        // 1003 vertices (full blocks and a tail), magnitudes from 1e-3 to 1e3 of both signs,
        // and steps large enough that some sums cross into another binade.
        let n = 1003;
        let x0: Vec<Vec3> = (0..n)
            .map(|i| {
                let t = i as f32;
                Vec3::new(
                    (t * 0.37).sin() * 1e3,
                    (t * 1.3).cos() * 1e-3,
                    (t * 0.71).sin(),
                )
            })
            .collect();
        let d: Vec<Vec3> = (0..n)
            .map(|i| {
                let t = i as f32;
                Vec3::new(
                    (t * 2.1).cos() * 40.0,
                    (t * 0.9).sin() * 1e-4,
                    (t * 0.13).cos(),
                )
            })
            .collect();
        let a = 0.0371f32;
        // Whole groups of eight floats that all spill (floats 16..24), and groups with three
        // and with seven (40..43, 48..55): values just below 1 stepped across it, kept where
        // the plain undo misses.
        let spilling: Vec<(f32, f32)> = (0..4000)
            .map(|k| (0.99 + k as f32 * 2.5e-6, 0.31f32))
            .filter(|&(x, d)| d.mul_add(-a, d.mul_add(a, x)).to_bits() != x.to_bits())
            .take(18)
            .collect();
        assert_eq!(spilling.len(), 18);
        let (mut x0, mut d) = (x0, d);
        for (&(xs, ds), f) in spilling.iter().zip((16..24).chain(40..43).chain(48..55)) {
            x0[f / 3][f % 3] = xs;
            d[f / 3][f % 3] = ds;
        }
        let bits = |v: &[Vec3]| {
            v.iter()
                .flat_map(|v| v.to_array())
                .map(f32::to_bits)
                .collect::<Vec<_>>()
        };
        // The plain undo `x + a d − a d` misses some floats: the spill path is exercised.
        let plain: Vec<Vec3> = x0
            .iter()
            .zip(&d)
            .map(|(x, d)| d.mul_add(Vec3::splat(-a), d.mul_add(Vec3::splat(a), *x)))
            .collect();
        assert_ne!(bits(&plain), bits(&x0));
        // Exactly the floats the plain undo misses, in order, with their old values.
        let floats = |v: &[Vec3]| v.iter().flat_map(|v| v.to_array()).collect::<Vec<_>>();
        let missed: Vec<Spilled> = floats(&x0)
            .into_iter()
            .zip(floats(&plain))
            .enumerate()
            .filter(|(_, (old, undone))| old.to_bits() != undone.to_bits())
            .map(|(at, (old, _))| Spilled { at: at as u32, old })
            .collect();
        // Groups of eight with several misses (the AVX-512 path packs them in one store),
        // and more misses than a first allocation holds.
        let groups = |s: &[Spilled]| s.iter().map(|s| s.at / 8).collect::<Vec<_>>();
        let g = groups(&missed);
        for (group, count) in [(2, 8), (5, 3), (6, 7)] {
            assert!(g.iter().filter(|&&x| x == group).count() >= count);
        }
        assert!(missed.len() > 64);
        for isa in isas() {
            let mut x = x0.clone();
            let mut spill = Vec::new();
            advance(isa, &mut x, &d, a, &mut spill);
            assert_eq!(spill, missed, "{isa:?}");
            assert!(spill.len() < 3 * n / 10, "{isa:?}: {} spilled", spill.len());
            // A list reused from another step is cleared first.
            let mut again = x0.clone();
            let mut reused = vec![
                Spilled {
                    at: 7,
                    old: f32::NAN
                };
                5
            ];
            advance(isa, &mut again, &d, a, &mut reused);
            assert_eq!(reused, missed, "{isa:?}");
            assert_eq!(bits(&again), bits(&x), "{isa:?}");
            // What a projection learns from the step: each vertex's position before it, bit
            // for bit, and a bound on each block's motion.
            let spills = vec![spill];
            let mut reach = vec![0.0f32; n.div_ceil(STEP_BLOCK)];
            crate::solver::block_reach(&d, &mut reach);
            let step = crate::solver::Step {
                d: &d,
                a,
                spills: &spills,
                reach: &reach,
            };
            let before: Vec<Vec3> = (0..n).map(|i| step.before(i, x[i])).collect();
            assert_eq!(bits(&before), bits(&x0), "{isa:?}");
            for (b, (x, x0)) in x.chunks(STEP_BLOCK).zip(x0.chunks(STEP_BLOCK)).enumerate() {
                let magnitude = x0.iter().map(|p| p.abs().max_element()).fold(0.0, f32::max);
                let bound = step.motion(b, magnitude);
                let moved = x
                    .iter()
                    .zip(x0)
                    .map(|(x, x0)| x.as_dvec3().distance(x0.as_dvec3()))
                    .fold(0.0, f64::max);
                assert!(moved <= bound, "{isa:?} block {b}: {moved} > {bound}");
                // Not loose by more than the component-to-length factor.
                assert!(
                    bound < 1.8 * moved,
                    "{isa:?} block {b}: {bound} for {moved}"
                );
            }
            retreat(isa, &mut x, &d, a, &spills[0]);
            assert_eq!(bits(&x), bits(&x0), "{isa:?}");
        }
    }

    #[test]
    fn sliced_anchors_hold_each_vertex_s_anchor_in_internal_order_and_zeros_past_the_end() {
        let (system, _, anchors, _, _) = net();
        let n = system.sell.n;
        assert!(n % LANES != 0, "the test wants a partial last slice");
        let sliced = SlicedAnchors::finite(&anchors, &system.order, Par::Pool).unwrap();
        assert_eq!(sliced.len(), n);
        for (i, &o) in system.order.iter().enumerate() {
            assert_eq!(sliced.get(i), anchors[o as usize], "internal vertex {i}");
        }
        // The lanes the kernels read: each row's value is the caller's anchor's field, and the
        // lanes past the last vertex hold zero anchors.
        let s = n / LANES;
        // SAFETY: `s` is the last slice of the n vertices.
        let rows = unsafe { sliced.rows(Scalar, s) };
        for lane in 0..LANES {
            let i = s * LANES + lane;
            let want = if i < n {
                anchors[system.order[i] as usize]
            } else {
                VertexAnchor::default()
            };
            let got = rows.map(|row| row[lane]);
            let mut fields = [0.0f32; ANCHOR_FLOATS];
            fields[TARGET..TARGET + 3].copy_from_slice(&want.target.to_array());
            fields[NORMAL..NORMAL + 3].copy_from_slice(&want.normal.to_array());
            fields[K_NORMAL] = want.k_normal;
            fields[K_TANGENT] = want.k_tangent;
            assert_eq!(got, fields, "lane {lane}");
        }
    }

    #[test]
    fn curvature_matches_the_plain_loop_bit_for_bit() {
        let (system, x, anchors, _, _) = net();
        let sell = &system.sell;
        let xi = system.to_internal(&x);
        let ai = system.to_internal(&anchors);
        let sliced = SlicedAnchors::finite(&anchors, &system.order, Par::Pool).unwrap();
        let d: Vec<Vec3> = (0..sell.n)
            .map(|i| Vec3::new((i as f32 * 0.7).sin(), (i as f32 * 0.3).cos(), 0.2) * 1e-3)
            .collect();
        let mut lanes = [0.0f64; 8];
        for i in 0..sell.n {
            let mut vertex = 0.0f32;
            for s in sell.springs_of(i).filter(|s| s.other as usize > i) {
                let (e, u) = (xi[s.other as usize] - xi[i], d[s.other as usize] - d[i]);
                vertex = s.k.mul_add(spring_curvature(&s, e, u), vertex);
            }
            lanes[i % 8] += vertex as f64;
            lanes[i % 8] += ai[i].curvature(d[i]) as f64;
        }
        let want = lanes.iter().fold(0.0f64, |a, b| a + b);
        for isa in isas() {
            let got = curvature(isa, sell, &xi, &d, Some(&sliced), 0..sell.slices());
            assert_eq!(got.to_bits(), want.to_bits(), "{isa:?}");
        }
    }

    #[test]
    fn energy_of_nearly_relaxed_springs_is_exact_to_f64_precision() {
        // 2000 separate springs stretched by ~1e-6 of their length: an f32 length alone would
        // be off by up to ~6e-8 of the length, i.e. ~10% of each spring's energy.
        let mut positions = Vec::new();
        let (mut edges, mut k, mut rest) = (Vec::new(), Vec::new(), Vec::new());
        let mut exact = 0.0f64;
        for i in 0..2000u32 {
            let t = i as f32;
            let a = Vec3::new(t * 0.1, (t * 0.3).cos(), 0.5);
            let e = Vec3::new(
                (t * 0.37).sin() * 0.01,
                (t * 1.13).cos() * 0.003,
                (t * 0.71).sin() * 0.02 + 1e-4,
            );
            let b = a + e;
            let e64 = b.as_dvec3() - a.as_dvec3();
            let r = (e64.length() * (1.0 + 1e-6 * (t * 0.1).sin() as f64)) as f32;
            let kk = 100.0 + t;
            let st = e64.length() - r as f64;
            exact += 0.5 * kk as f64 * st * st;
            positions.extend([a, b]);
            edges.push([2 * i, 2 * i + 1]);
            k.push(kk);
            rest.push(r);
        }
        let system = SpringSystem::new(&positions, &edges, &k, &rest).unwrap();
        let got = system.spring_energy(&positions).unwrap();
        assert!(((got - exact) / exact).abs() < 1e-6, "{got} vs {exact}");
    }
}
