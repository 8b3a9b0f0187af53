//! AVX-512 lanes: the f32 half as in AVX2, the f64 half in one 512-bit register instead of two.
//!
//! The f32 operations are those of [`Avx2`] (delegated), and the f64 ones are the same IEEE
//! additions, subtractions and multiplications of the same operands, eight at once: the results
//! are bit-identical to the AVX2 and portable paths.

use std::arch::x86_64::*;

use super::Lanes;
use super::avx2::Avx2;

/// AVX-512 lanes; only constructed after `is_x86_feature_detected!` for AVX-512F, AVX-512VL,
/// FMA and AVX2, and only used inside `#[target_feature(enable = "avx2,fma,avx512f,avx512vl")]`
/// functions (every method is inlined there).
#[derive(Clone, Copy)]
pub(crate) struct Avx512;

const A: Avx2 = Avx2;

impl Lanes for Avx512 {
    type F = <Avx2 as Lanes>::F;
    type I = <Avx2 as Lanes>::I;
    type M = <Avx2 as Lanes>::M;
    type D = __m512d;
    #[inline(always)]
    fn splat(self, v: f32) -> Self::F {
        A.splat(v)
    }
    #[inline(always)]
    fn load(self, p: &[f32]) -> Self::F {
        A.load(p)
    }
    #[inline(always)]
    fn load_i(self, p: &[u32]) -> Self::I {
        A.load_i(p)
    }
    #[inline(always)]
    fn load_near(self, p: &[i16], base: u32) -> Self::I {
        A.load_near(p, base)
    }
    #[inline(always)]
    unsafe fn gather(self, base: *const f32, idx: Self::I) -> Self::F {
        // SAFETY: the caller's contract.
        unsafe { A.gather(base, idx) }
    }
    #[inline(always)]
    unsafe fn pairs(self, p: *const f32) -> (Self::F, Self::F) {
        // SAFETY: the caller's contract.
        unsafe { A.pairs(p) }
    }
    #[inline(always)]
    unsafe fn pairs_at(self, p: *const f32, idx: Self::I) -> (Self::F, Self::F) {
        // SAFETY: the caller guarantees every pair is readable. One gather of eight doubles
        // (the pairs, in memory order), then the shuffles of `pairs`.
        unsafe {
            let v = _mm512_castpd_ps(_mm512_i32gather_pd::<8>(idx, p.cast()));
            let (a, b) = (
                _mm512_castps512_ps256(v),
                _mm256_castpd_ps(_mm512_extractf64x4_pd::<1>(_mm512_castps_pd(v))),
            );
            (
                _mm256_shuffle_ps::<0x88>(a, b),
                _mm256_shuffle_ps::<0xDD>(a, b),
            )
        }
    }
    #[inline(always)]
    unsafe fn pairs_near(self, p: *const f32, refs: &[i16], base: isize) -> (Self::F, Self::F) {
        // SAFETY: the caller guarantees the references and pairs are readable. Each pair is
        // one 8-byte load at its place in the layout `pairs` reads (volatile reads keep the
        // decode of the references scalar), then the same shuffles.
        unsafe {
            let p = p.wrapping_offset(2 * base).cast::<f64>();
            let q = |m: usize| p.wrapping_offset(refs.as_ptr().add(m).read_volatile() as isize);
            let two = |m: usize| _mm_loadh_pd(_mm_load_sd(q(m)), q(m + 1));
            let a = _mm256_insertf128_pd::<1>(_mm256_castpd128_pd256(two(0)), two(2));
            let b = _mm256_insertf128_pd::<1>(_mm256_castpd128_pd256(two(4)), two(6));
            let (a, b) = (_mm256_castpd_ps(a), _mm256_castpd_ps(b));
            (
                _mm256_shuffle_ps::<0x88>(a, b),
                _mm256_shuffle_ps::<0xDD>(a, b),
            )
        }
    }
    #[inline(always)]
    unsafe fn load3(self, p: *const f32) -> [Self::F; 3] {
        // SAFETY: the caller's contract.
        unsafe { A.load3(p) }
    }
    #[inline(always)]
    unsafe fn load_at(self, p: *const f32) -> Self::F {
        // SAFETY: the caller's contract.
        unsafe { A.load_at(p) }
    }
    #[inline(always)]
    unsafe fn store_at(self, p: *mut f32, a: Self::F) {
        // SAFETY: the caller's contract.
        unsafe { A.store_at(p, a) }
    }
    #[inline(always)]
    fn deinterleave(self, v: [Self::F; 3]) -> [Self::F; 3] {
        A.deinterleave(v)
    }
    #[inline(always)]
    fn spread3(self, w: Self::F) -> [Self::F; 3] {
        A.spread3(w)
    }
    #[inline(always)]
    unsafe fn vec3s(self, p: *const f32, n: usize, rows: &super::Rows, j: Self::I) -> [Self::F; 3] {
        // SAFETY: the caller's contract.
        unsafe { A.vec3s(p, n, rows, j) }
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
        // SAFETY: the caller's contract.
        unsafe { A.vec3s_pair(p, dp, n, rows, j) }
    }
    #[inline(always)]
    unsafe fn store3(self, p: *mut f32, v: [Self::F; 3]) {
        // SAFETY: the caller's contract.
        unsafe { A.store3(p, v) }
    }
    #[inline(always)]
    fn negative(self, a: Self::F) -> Self::M {
        A.negative(a)
    }
    #[inline(always)]
    fn same_bits(self, a: Self::F, b: Self::F) -> bool {
        A.same_bits(a, b)
    }
    #[inline(always)]
    fn dfrom(self, a: [f64; 8]) -> Self::D {
        // SAFETY: eight doubles in bounds.
        unsafe { _mm512_loadu_pd(a.as_ptr()) }
    }
    #[inline(always)]
    fn times3(self, i: Self::I) -> Self::I {
        A.times3(i)
    }
    #[inline(always)]
    fn add(self, a: Self::F, b: Self::F) -> Self::F {
        A.add(a, b)
    }
    #[inline(always)]
    fn sub(self, a: Self::F, b: Self::F) -> Self::F {
        A.sub(a, b)
    }
    #[inline(always)]
    fn mul(self, a: Self::F, b: Self::F) -> Self::F {
        A.mul(a, b)
    }
    #[inline(always)]
    fn fma(self, a: Self::F, b: Self::F, c: Self::F) -> Self::F {
        A.fma(a, b, c)
    }
    #[inline(always)]
    fn fnma(self, a: Self::F, b: Self::F, c: Self::F) -> Self::F {
        A.fnma(a, b, c)
    }
    #[inline(always)]
    fn div(self, a: Self::F, b: Self::F) -> Self::F {
        A.div(a, b)
    }
    #[inline(always)]
    fn sqrt(self, a: Self::F) -> Self::F {
        A.sqrt(a)
    }
    #[inline(always)]
    fn max(self, a: Self::F, b: Self::F) -> Self::F {
        A.max(a, b)
    }
    #[inline(always)]
    fn gt(self, a: Self::F, b: Self::F) -> Self::M {
        A.gt(a, b)
    }
    #[inline(always)]
    fn le(self, a: Self::F, b: Self::F) -> Self::M {
        A.le(a, b)
    }
    #[inline(always)]
    fn abs(self, a: Self::F) -> Self::F {
        A.abs(a)
    }
    #[inline(always)]
    fn select(self, m: Self::M, a: Self::F, b: Self::F) -> Self::F {
        A.select(m, a, b)
    }
    #[inline(always)]
    fn keep(self, m: Self::M, a: Self::F) -> Self::F {
        A.keep(m, a)
    }
    #[inline(always)]
    fn iota(self, base: u32) -> Self::I {
        A.iota(base)
    }
    #[inline(always)]
    fn store(self, a: Self::F) -> [f32; 8] {
        A.store(a)
    }
    #[inline(always)]
    fn widen(self, a: Self::F) -> Self::D {
        // Exact: every f32 is an f64.
        unsafe { _mm512_cvtps_pd(a) }
    }
    #[inline(always)]
    fn dsplat(self, v: f64) -> Self::D {
        unsafe { _mm512_set1_pd(v) }
    }
    #[inline(always)]
    fn dadd(self, a: Self::D, b: Self::D) -> Self::D {
        unsafe { _mm512_add_pd(a, b) }
    }
    #[inline(always)]
    fn dsub(self, a: Self::D, b: Self::D) -> Self::D {
        unsafe { _mm512_sub_pd(a, b) }
    }
    #[inline(always)]
    fn dmul(self, a: Self::D, b: Self::D) -> Self::D {
        unsafe { _mm512_mul_pd(a, b) }
    }
    #[inline(always)]
    fn dfma(self, a: Self::D, b: Self::D, c: Self::D) -> Self::D {
        unsafe { _mm512_fmadd_pd(a, b, c) }
    }
    #[inline(always)]
    fn dfnma(self, a: Self::D, b: Self::D, c: Self::D) -> Self::D {
        unsafe { _mm512_fnmadd_pd(a, b, c) }
    }
    #[inline(always)]
    fn dstore(self, a: Self::D) -> [f64; 8] {
        let mut out = [0.0f64; 8];
        // SAFETY: eight doubles of room.
        unsafe { _mm512_storeu_pd(out.as_mut_ptr(), a) };
        out
    }
}
