//! Projections in the solver's order: one sequential skip test per vertex, and only the
//! vertices that may be near a collider resolved.
//!
//! A relaxation projects its positions after every iteration, and between two of them almost
//! every vertex stays provably outside every contact band ([`Reach::skips`]). Reading each
//! vertex's [`Reach`] in the caller's order through the solver's permutation cost a gather and
//! a scatter per vertex per pass. Instead, the skip test of every vertex is kept here in the
//! solver's order (`[at, limit²]`, 16 bytes, for the colliders' travel of the relaxation, which
//! is constant while it runs), together with the positions of the last pass. A pass reads them
//! sequentially next to the positions and lists the few vertices that fail; only those are
//! resolved, in parallel over the caller's chunks of state they own.
//!
//! The test is conservative (it implies [`Reach::skips`]), so a pass resolves a superset of the
//! vertices the caller-order pass resolves, and resolving a vertex the reserve would have
//! skipped finds exactly nothing to do: the positions and contacts are the same either way.
//! The one exception is a vertex held on a face ([`Reach::hold`]): touching, the caller-order
//! pass resolves it, but the test here may skip it, and the pass then reports it as touching
//! with the contact it had, which is what resolving it would find (see `hold_of`).

use glam::Vec3;
use rayon::prelude::*;

use super::{CHUNK, ChunkPass, Counters, Ctx, NONE, Reach, SkinCollision, VertexState};
use crate::solver::team::{Chunked, Par};

/// The skip tests and last positions in the solver's order (see the module docs).
#[derive(Debug, Clone, Default)]
pub(super) struct View {
    /// Whether `test` is up to date with the caller-order [`Reach`]es for the colliders'
    /// identities and travels in `key`.
    valid: bool,
    key: Vec<(u64, f64)>,
    /// Per internal vertex: where it was resolved last...
    at: Vec<Vec3>,
    /// ... and how far, squared, it may move from there before a pass must resolve it
    /// (negative: every pass resolves it).
    limit2: Vec<f32>,
    /// Each vertex's position after the last pass, in the solver's order, while `holds_last`.
    prev: Vec<Vec3>,
    /// Whether `prev` holds the last positions (then [`SkinCollision::last`] is stale).
    holds_last: bool,
    /// The vertices held on a face ([`Reach::hold`]), by increasing internal index: their
    /// skip test is [`Holder::keeps`] instead (their `limit2` fails every pass), and they are
    /// reported as touching when it passes.
    holders: Vec<Holder>,
    /// The vertices (internal indices) the last pass moved.
    pub(super) moved: Vec<u32>,
}

/// A vertex held on a face: where it was resolved, its contact normal, the range of its
/// offset along the normal and the radius within which resolving it changes nothing the
/// solver sees (see `hold_of`).
#[derive(Debug, Clone, Copy)]
struct Holder {
    /// Internal index.
    i: u32,
    at: Vec3,
    normal: Vec3,
    slab: [f32; 2],
    radius2: f32,
}

impl Holder {
    /// The hold of a vertex (internal index `i`) whose reach is `r` and state `state`, the
    /// colliders' summed travel `travel`: none if a collider moved since it was resolved.
    fn of(i: u32, r: &Reach, state: &VertexState, travel: f64) -> Option<Self> {
        (r.hold > 0.0
            && travel == r.travel_at
            && r.at.is_finite()
            && state.touches[0].collider != NONE
            && state.touches[1].collider == NONE)
            .then(|| Self {
                i,
                at: r.at,
                normal: state.touches[0].normal,
                slab: state.slab,
                // The relative margin covers the f32 rounding of the squared distance.
                radius2: (f64::from(r.hold) * (1.0 - 4e-6)).powi(2) as f32,
            })
    }

    /// Whether the vertex, now at `p`, is still held: resolving it would find what the last
    /// resolution did.
    #[inline]
    fn keeps(&self, p: Vec3) -> bool {
        let d = p - self.at;
        let along = self.normal.dot(d);
        d.length_squared() <= self.radius2 && along >= self.slab[0] && along <= self.slab[1]
    }
}

impl View {
    /// Forgets the view, the last positions included (the caller's state was reset).
    pub(super) fn discard(&mut self) {
        self.valid = false;
        self.holds_last = false;
    }
}

/// The skip test of a vertex whose reach is `r`, the colliders' summed travel `travel`:
/// `(at, limit²)` such that `|p − at|² ≤ limit²` in f32 implies `r.skips(p, travel)`.
fn test_of(r: &Reach, travel: f64) -> (Vec3, f32) {
    let limit = r.reserve as f64 / (1.0 + 1e-5) - (travel - r.travel_at);
    // The relative margin (4e-6) covers the f32 rounding of the squared distance, of its
    // square root in `skips` and of `limit²` itself (a few 1e-7 together).
    let limit2 = if limit > 0.0 && r.at.is_finite() {
        (limit * (1.0 - 4e-6)).powi(2) as f32
    } else {
        -1.0
    };
    (r.at, limit2)
}

/// One resolved vertex.
#[derive(Clone, Copy)]
struct Resolved {
    /// Place among the pass's resolved vertices in the solver's order.
    j: u32,
    /// Internal index.
    i: u32,
    /// Caller's index.
    o: u32,
    p: Vec3,
    moved: bool,
    unresolved: bool,
    touching: bool,
    /// Its hold, if any.
    holder: Option<Holder>,
    test: (Vec3, f32),
}

impl SkinCollision {
    /// Hands the last positions held in the solver's order back to the caller's order and
    /// marks the view stale: every caller-order use of `reach` or `last` starts with this.
    pub(super) fn leave_view(&mut self) {
        if self.view.holds_last {
            let (prev, rank) = (&self.view.prev, &self.rank);
            self.last
                .par_chunks_mut(CHUNK)
                .zip(rank.par_chunks(CHUNK))
                .for_each(|(last, rank)| {
                    for (l, &r) in last.iter_mut().zip(rank) {
                        *l = prev[r as usize];
                    }
                });
        }
        self.view.discard();
    }

    /// A projection pass over `x` in the solver's order (`self.rank_of`, already checked to be
    /// a permutation), with the swept test: what it did, and the `(internal, caller's)` index
    /// of every vertex touching a collider after it, by increasing internal index; `None` when
    /// there is nothing to collide with. Its loops run on the team of the solve that calls it,
    /// if any ([`Par::current`]): its helpers are awake, where rayon's may sleep.
    pub(super) fn project_pass(&mut self, x: &mut [Vec3]) -> Option<(ChunkPass, Vec<(u32, u32)>)> {
        let nc = self.colliders.len();
        let n = x.len();
        if nc == 0 || n == 0 {
            return None;
        }
        let travel = self.collider_travel();
        let travel_sum: f64 = travel.iter().sum();
        if !(self.view.valid && self.view.key == self.travel_seen) {
            self.rebuild_view(travel_sum);
        }
        Par::current(|par| Some(self.pass_on(par, x, &travel, travel_sum)))
    }

    /// [`project_pass`](Self::project_pass) once the view is up to date, its loops on `par`.
    #[expect(unsafe_code, reason = "disjoint chunks written by one parallel loop")]
    fn pass_on(
        &mut self,
        par: Par<'_>,
        x: &mut [Vec3],
        travel: &[f64],
        travel_sum: f64,
    ) -> (ChunkPass, Vec<(u32, u32)>) {
        let nc = self.colliders.len();
        let n = x.len();
        // The skip test of every vertex, in order; the ones that fail are listed with their
        // last position, and the others' last positions become their positions.
        let view = &mut self.view;
        let groups = n.div_ceil(GROUP);
        let mut per_group: Vec<(Vec<(u32, Vec3)>, u64)> = vec![(Vec::new(), 0); groups];
        {
            let (xs, prevs) = (Chunked::new(x, GROUP), Chunked::new(&mut view.prev, GROUP));
            let out = Chunked::new(&mut per_group, 1);
            let (at, limit2) = (&view.at, &view.limit2);
            par.for_each_min(groups, SKIP_TASK_GROUPS, |g| {
                // SAFETY: each group index once per loop.
                let (xs, prevs, out) = unsafe { (xs.chunk(g), prevs.chunk(g), out.chunk(g)) };
                let range = g * GROUP..g * GROUP + xs.len();
                // The blocks' failures first, so that the list is allocated once (a group
                // with none allocates nothing).
                let mut masks = [0u64; GROUP / BLOCK];
                for (mask, ((xs, at), limit2)) in masks.iter_mut().zip(
                    xs.chunks(BLOCK)
                        .zip(at[range.clone()].chunks(BLOCK))
                        .zip(limit2[range].chunks(BLOCK)),
                ) {
                    *mask = failures(xs, at, limit2);
                }
                let failing: u32 = masks.iter().map(|m| m.count_ones()).sum();
                let mut listed = Vec::with_capacity(failing as usize);
                for (block, ((mut bits, prevs), xs)) in masks
                    .into_iter()
                    .zip(prevs.chunks_mut(BLOCK))
                    .zip(xs.chunks(BLOCK))
                    .enumerate()
                {
                    while bits != 0 {
                        let k = bits.trailing_zeros() as usize;
                        bits &= bits - 1;
                        listed.push(((g * GROUP + block * BLOCK + k) as u32, prevs[k]));
                    }
                    // Block by block, while in cache (and below the size from which `memcpy`
                    // switches to `rep movsb`, which callgrind counts byte by byte).
                    prevs.copy_from_slice(xs);
                }
                let skipped = (xs.len() - listed.len()) as u64;
                out[0] = (listed, skipped);
            });
        }
        let mut counters = Counters::default();
        // The failing vertices in the solver's order (`i` increasing), then grouped by the
        // caller's chunk that owns their state: a stable counting sort (no comparisons), each
        // entry keeping its place `j` in the solver's order. Within a chunk they are resolved
        // in the solver's order: a resolution reads and writes only its own vertex's state
        // (the counters are sums), so the order changes nothing.
        let mut listed: Vec<(u32, u32, Vec3)> =
            Vec::with_capacity(per_group.iter().map(|(l, _)| l.len()).sum());
        for (l, skipped) in per_group {
            counters.skipped_vertices += skipped;
            counters.skipped_bound += skipped * nc as u64;
            listed.extend(
                l.into_iter()
                    .map(|(i, last)| (i, self.rank_of[i as usize], last)),
            );
        }
        // The held vertices (all listed: their `limit2` fails) that their hold keeps: not
        // resolved, still touching as the last pass left them. `listed` and `holders` are
        // both by increasing internal index.
        let mut skipped_holders: Vec<Holder> = Vec::new();
        if !self.view.holders.is_empty() {
            let mut holders = self.view.holders.iter().peekable();
            listed.retain(|&(i, _, _)| {
                while holders.next_if(|h| h.i < i).is_some() {}
                match holders.peek() {
                    Some(h) if h.i == i && h.keeps(x[i as usize]) => {
                        skipped_holders.push(**h);
                        false
                    }
                    _ => true,
                }
            });
        }
        counters.contacts += skipped_holders.len() as u64;
        counters.skipped_vertices += skipped_holders.len() as u64;
        let chunks = n.div_ceil(CHUNK);
        let mut bounds = vec![0usize; chunks + 1];
        for &(_, o, _) in &listed {
            bounds[o as usize / CHUNK + 1] += 1;
        }
        for c in 0..chunks {
            bounds[c + 1] += bounds[c];
        }
        let mut fill = bounds.clone();
        let mut grouped = vec![(0u32, 0u32, 0u32, Vec3::ZERO); listed.len()];
        for (j, &(i, o, last)) in listed.iter().enumerate() {
            let at = &mut fill[o as usize / CHUNK];
            grouped[*at] = (j as u32, i, o, last);
            *at += 1;
        }
        // The chunks with something to resolve, each resolved by one thread.
        let busy: Vec<usize> = (0..chunks).filter(|&c| bounds[c + 1] > bounds[c]).collect();
        let ctx = Ctx {
            colliders: &self.colliders,
            travel,
            travel_sum,
            config: &self.config,
            swept: true,
            face_holds: self.face_holds,
        };
        let xs = &*x;
        let mut resolved = vec![(Vec::new(), Counters::default()); busy.len()];
        {
            let (reach, states) = (
                Chunked::new(&mut self.reach, CHUNK),
                Chunked::new(&mut self.states, CHUNK),
            );
            let slots = Chunked::new(&mut self.slots, CHUNK * nc);
            let patches = Chunked::new(&mut self.patches, CHUNK * nc);
            let out = Chunked::new(&mut resolved, 1);
            let thickness = &self.thickness;
            let resolve = |b: usize| {
                let chunk = busy[b];
                // SAFETY: each busy chunk once per loop (`busy` has no repeats).
                let (reach, states, slots, patches, out) = unsafe {
                    (
                        reach.chunk(chunk),
                        states.chunk(chunk),
                        slots.chunk(chunk),
                        patches.chunk(chunk),
                        out.chunk(b),
                    )
                };
                let hs = &thickness[chunk * CHUNK..];
                let mut counters = Counters::default();
                let done = grouped[bounds[chunk]..bounds[chunk + 1]]
                    .iter()
                    .map(|&(j, i, o, last)| {
                        let k = o as usize - chunk * CHUNK;
                        let (mut p, mut last) = (xs[i as usize], last);
                        let (moved, unresolved) = ctx.resolve(
                            &mut p,
                            hs[k],
                            (&mut reach[k], &mut last),
                            &mut states[k],
                            (
                                &mut slots[k * nc..(k + 1) * nc],
                                &mut patches[k * nc..(k + 1) * nc],
                            ),
                            &mut counters,
                        );
                        Resolved {
                            j,
                            i,
                            o,
                            p,
                            moved,
                            unresolved,
                            touching: states[k].touches[0].collider != NONE,
                            holder: Holder::of(i, &reach[k], &states[k], travel_sum),
                            test: test_of(&reach[k], travel_sum),
                        }
                    })
                    .collect();
                out[0] = (done, counters);
            };
            if listed.len() < PARALLEL_RESOLUTIONS {
                (0..busy.len()).for_each(resolve);
            } else {
                par.for_each(busy.len(), resolve);
            }
        }

        let mut pass = ChunkPass {
            counters,
            unresolved: Vec::new(),
        };
        // The touching vertices go back to the solver's order through their places `j`, so do
        // the new holders.
        let mut touches = vec![None; listed.len()];
        let mut held = vec![None; listed.len()];
        let view = &mut self.view;
        for (done, counters) in resolved {
            pass.counters.add(&counters);
            for r in done {
                let i = r.i as usize;
                if r.moved {
                    x[i] = r.p;
                    pass.counters.moved += 1;
                    view.moved.push(r.i);
                }
                view.prev[i] = r.p;
                (view.at[i], view.limit2[i]) = r.test;
                if r.unresolved {
                    pass.unresolved.push(r.o);
                }
                if r.touching {
                    touches[r.j as usize] = Some((r.i, r.o));
                }
                held[r.j as usize] = r.holder;
            }
        }
        // Rare: a sort only when some vertex stayed unresolved.
        pass.unresolved.sort_unstable();
        // The resolved and the skipped holders, and the touching ones, by internal index.
        let rank_of = &self.rank_of;
        let touched: Vec<(u32, u32)> = touches.into_iter().flatten().collect();
        let kept: Vec<(u32, u32)> = skipped_holders
            .iter()
            .map(|h| (h.i, rank_of[h.i as usize]))
            .collect();
        let touching = merged(&touched, &kept, |t| t.0);
        let resolved_holders: Vec<Holder> = held.into_iter().flatten().collect();
        view.holders = merged(&resolved_holders, &skipped_holders, |h| h.i);
        (pass, touching)
    }

    /// Rebuilds the skip tests in the solver's order for the colliders' summed travel
    /// `travel_sum`, and takes the last positions over from the caller's order.
    fn rebuild_view(&mut self, travel_sum: f64) {
        let n = self.rank_of.len();
        let view = &mut self.view;
        view.at.resize(n, Vec3::ZERO);
        view.limit2.resize(n, 0.0);
        let (order, reach) = (&self.rank_of, &self.reach);
        view.at
            .par_chunks_mut(CHUNK)
            .zip(view.limit2.par_chunks_mut(CHUNK))
            .zip(order.par_chunks(CHUNK))
            .for_each(|((at, limit2), order)| {
                for ((a, l), &o) in at.iter_mut().zip(limit2).zip(order) {
                    (*a, *l) = test_of(&reach[o as usize], travel_sum);
                }
            });
        if !view.holds_last {
            view.prev.resize(n, Vec3::ZERO);
            let last = &self.last;
            view.prev
                .par_chunks_mut(CHUNK)
                .zip(order.par_chunks(CHUNK))
                .for_each(|(prevs, order)| {
                    for (p, &o) in prevs.iter_mut().zip(order) {
                        *p = last[o as usize];
                    }
                });
            view.holds_last = true;
        }
        let states = &self.states;
        view.holders = order
            .par_chunks(CHUNK)
            .enumerate()
            .map(|(c, order)| {
                (c * CHUNK..)
                    .zip(order)
                    .filter_map(|(i, &o)| {
                        let o = o as usize;
                        Holder::of(i as u32, &reach[o], &states[o], travel_sum)
                    })
                    .collect::<Vec<Holder>>()
            })
            .flatten_iter()
            .collect();
        view.key.clone_from(&self.travel_seen);
        view.valid = true;
    }
}

/// Two lists each sorted by `key` (no key in both), merged in that order.
fn merged<T: Copy>(a: &[T], b: &[T], key: impl Fn(&T) -> u32) -> Vec<T> {
    if b.is_empty() {
        return a.to_vec();
    }
    let mut out = Vec::with_capacity(a.len() + b.len());
    let (mut i, mut j) = (0, 0);
    while i < a.len() && j < b.len() {
        if key(&a[i]) < key(&b[j]) {
            out.push(a[i]);
            i += 1;
        } else {
            out.push(b[j]);
            j += 1;
        }
    }
    out.extend_from_slice(&a[i..]);
    out.extend_from_slice(&b[j..]);
    out
}

/// Vertices per work item of the skip test (a whole number of blocks).
const GROUP: usize = 1024;
const _: () = assert!(GROUP.is_multiple_of(BLOCK));

/// Groups per task of the skip test on rayon's pool: ~8k vertices (the test costs ~1 ns per
/// vertex, less than waking another thread for a smaller task; session 7 measured a tube-10k
/// frame's projections ~15 % faster with the skip test on one thread). A solve's team ignores
/// it: its helpers are awake.
const SKIP_TASK_GROUPS: usize = 8;

/// Resolutions below which a pass resolves its failing vertices on one thread (~1 µs each:
/// fewer are not worth a parallel loop, and they cluster in a few chunks anyway).
const PARALLEL_RESOLUTIONS: usize = 32;

/// Vertices per block of the skip test (one bit each in a `u64`); a whole number of blocks
/// makes a chunk.
const BLOCK: usize = 64;
const _: () = assert!(CHUNK.is_multiple_of(BLOCK));

/// Bit `k` set for each vertex `k` of a block (at most [`BLOCK`]) at `xs` that fails its skip
/// test `|x − at|² ≤ limit²` (NaN fails).
#[cfg_attr(
    target_arch = "x86_64",
    expect(unsafe_code, reason = "the AVX2 path, behind its run-time CPU check")
)]
fn failures(xs: &[Vec3], at: &[Vec3], limit2: &[f32]) -> u64 {
    #[cfg(target_arch = "x86_64")]
    if xs.len() == BLOCK && at.len() == BLOCK && limit2.len() == BLOCK && avx2::available() {
        // SAFETY: AVX2 is available and the three slices hold a whole block.
        return unsafe { avx2::failures(xs, at, limit2) };
    }
    failures_portable(xs, at, limit2)
}

/// [`failures`] one vertex at a time.
fn failures_portable(xs: &[Vec3], at: &[Vec3], limit2: &[f32]) -> u64 {
    let mut fail = 0u64;
    for (k, ((p, a), l)) in xs.iter().zip(at).zip(limit2).enumerate() {
        let (dx, dy, dz) = (p.x - a.x, p.y - a.y, p.z - a.z);
        let near = dx * dx + dy * dy + dz * dz <= *l;
        fail |= u64::from(!near) << k;
    }
    fail
}

#[cfg(target_arch = "x86_64")]
#[expect(
    unsafe_code,
    reason = "AVX2 loads of whole blocks behind a run-time CPU check"
)]
mod avx2 {
    use std::arch::x86_64::*;

    use glam::Vec3;

    use super::BLOCK;

    /// Whether the CPU has AVX2 (cached by the standard library).
    pub fn available() -> bool {
        std::arch::is_x86_feature_detected!("avx2")
    }

    /// [`super::failures`] of a whole block, eight vertices per step, with the same f32
    /// operations in the same order (so the same bits).
    ///
    /// # Safety
    /// AVX2 must be available and the slices must hold [`BLOCK`] entries.
    #[target_feature(enable = "avx2")]
    pub unsafe fn failures(xs: &[Vec3], at: &[Vec3], limit2: &[f32]) -> u64 {
        // Float 3m + c of eight vertices is component c of vertex m: two blends gather each
        // component into one register, its lanes in the vertex order below, which one
        // permutation per component brings back to 0..8.
        let to_order = |lanes: [i32; 8]| {
            let mut inv = [0i32; 8];
            for (l, &m) in lanes.iter().enumerate() {
                inv[m as usize] = l as i32;
            }
            // SAFETY: eight readable i32.
            unsafe { _mm256_loadu_si256(inv.as_ptr().cast()) }
        };
        let (px, py, pz) = (
            to_order([0, 3, 6, 1, 4, 7, 2, 5]),
            to_order([5, 0, 3, 6, 1, 4, 7, 2]),
            to_order([2, 5, 0, 3, 6, 1, 4, 7]),
        );
        let (x, a, l) = (
            xs.as_ptr().cast::<f32>(),
            at.as_ptr().cast::<f32>(),
            limit2.as_ptr(),
        );
        let mut fail = 0u64;
        for step in 0..BLOCK / 8 {
            // SAFETY: 24 floats of `xs` and `at` and 8 of `limit2` from vertex 8 step on are in
            // the block.
            unsafe {
                let o = 24 * step;
                let sq = |i: usize| {
                    let d =
                        _mm256_sub_ps(_mm256_loadu_ps(x.add(o + i)), _mm256_loadu_ps(a.add(o + i)));
                    _mm256_mul_ps(d, d)
                };
                let (s0, s1, s2) = (sq(0), sq(8), sq(16));
                let cx = _mm256_blend_ps::<0b0010_0100>(_mm256_blend_ps::<0b1001_0010>(s0, s1), s2);
                let cy = _mm256_blend_ps::<0b0100_1001>(_mm256_blend_ps::<0b0010_0100>(s0, s1), s2);
                let cz = _mm256_blend_ps::<0b1001_0010>(_mm256_blend_ps::<0b0100_1001>(s0, s1), s2);
                let sum = _mm256_add_ps(
                    _mm256_add_ps(
                        _mm256_permutevar8x32_ps(cx, px),
                        _mm256_permutevar8x32_ps(cy, py),
                    ),
                    _mm256_permutevar8x32_ps(cz, pz),
                );
                // Ordered, non-signalling: NaN compares false, so it fails.
                let near = _mm256_cmp_ps::<_CMP_LE_OQ>(sum, _mm256_loadu_ps(l.add(8 * step)));
                let bits = !_mm256_movemask_ps(near) as u64 & 0xff;
                fail |= bits << (8 * step);
            }
        }
        fail
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::collision::tests::Lcg;

    #[test]
    fn block_skip_tests_match_the_per_vertex_test_bit_for_bit() {
        let mut rng = Lcg(5);
        for round in 0..200 {
            let xs: Vec<Vec3> = (0..BLOCK).map(|_| rng.point(1.0)).collect();
            let mut at: Vec<Vec3> = (0..BLOCK).map(|_| rng.point(1.0)).collect();
            let mut limit2: Vec<f32> = (0..BLOCK).map(|_| 4.0 * rng.next() - 1.0).collect();
            // Never resolved (NaN), and exactly on the limit.
            at[round % BLOCK] = Vec3::NAN;
            let k = (round * 7 + 3) % BLOCK;
            limit2[k] = (xs[k] - at[k]).length_squared();
            let bits = failures(&xs, &at, &limit2);
            assert_eq!(bits, failures_portable(&xs, &at, &limit2), "round {round}");
            for v in 0..BLOCK {
                let fails = bits >> v & 1 == 1;
                // An independent answer, in f64, away from the rounding of the boundary.
                let d2 = xs[v].as_dvec3().distance_squared(at[v].as_dvec3());
                let l = f64::from(limit2[v]);
                if v == round % BLOCK {
                    assert!(fails, "NaN must fail");
                } else if v == k {
                    assert!(!fails, "on the limit passes");
                } else if (d2 - l).abs() > 1e-5 {
                    assert_eq!(fails, d2 > l, "round {round} vertex {v}");
                }
            }
        }
        // A short block (the end of the skin) takes the per-vertex path.
        let xs = vec![Vec3::ZERO; 5];
        let at = vec![Vec3::X; 5];
        assert_eq!(failures(&xs, &at, &[2.0, 0.5, 1.0, -1.0, 1.5]), 0b01010);
    }
}
