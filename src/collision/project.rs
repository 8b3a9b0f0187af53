//! Projections in the solver's order: one sequential skip test per vertex, and only the
//! vertices that may be near a collider resolved.
//!
//! A relaxation projects its positions after every iteration, and between two of them almost
//! every vertex stays provably outside every contact band ([`Reach::skips`]). Reading each
//! vertex's [`Reach`] in the caller's order through the solver's permutation cost a gather and
//! a scatter per vertex per pass. Instead, the skip test of every vertex is kept here in the
//! solver's order (`[at, limit²]`, 16 bytes, for the colliders' travel of the relaxation, which
//! is constant while it runs), together with the positions of the last pass. A pass reads them
//! sequentially next to the positions, and resolves the few vertices that fail right there: one
//! parallel loop over groups of the solver's order, each vertex's state read and written at
//! its caller's index (a permutation, so the groups touch disjoint state).
//!
//! Inside a relaxation the solver names its step
//! ([`Projection::project_step`](crate::solver::Projection::project_step)): each block of
//! [`BLOCK`] vertices then keeps how far its vertices may still move and pass their tests (its
//! *slack*, from the last time it was tested), and a pass adds the step's bound on the block's
//! motion ([`Step::motion`]) and skips the block unread while the sum stays within the slack.
//! A failing vertex's last position (for the swept test) is the one the step gives back
//! ([`Step::before`]), so such passes copy no last positions; the solve reports its final ones
//! when it ends ([`Projection::settled`](crate::solver::Projection::settled)). Same answers
//! and counters as whole passes; over the bench's clip ~77 % (10k-vertex tube) and ~94 %
//! (100k) of the vertices a pass would test are skipped this way (session 25).
//!
//! The test is conservative (it implies [`Reach::skips`]), so a pass resolves a superset of the
//! vertices the caller-order pass resolves, and resolving a vertex the reserve would have
//! skipped finds exactly nothing to do: the positions and contacts are the same either way.
//! The one exception is a vertex held on a face ([`Reach::hold`]): touching, the caller-order
//! pass resolves it, but the test here may skip it, and the pass then reports it as touching
//! with the contact it had, which is what resolving it would find (see `hold_of`).

use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use glam::Vec3;
use rayon::prelude::*;

use super::{CHUNK, ChunkPass, Counters, Ctx, NONE, Reach, SkinCollision, VertexState};
use crate::solver::Step;
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
    /// Whether passes after a solver's step ([`Step`]) moved the positions on since `prev`
    /// was written: then neither `prev` nor [`SkinCollision::last`] holds the last positions
    /// until the solve reports them ([`SkinCollision::settle_view`]).
    prev_stale: bool,
    /// Per block of [`BLOCK`] vertices: how far each of its vertices may move from where the
    /// block was last tested and still pass its test (`-∞`: test it every pass)...
    slack: Vec<f32>,
    /// ... how far its vertices moved since, by the solver's steps' bounds...
    moved_since: Vec<f64>,
    /// ... and a bound on its coordinates' magnitudes then, plus its largest limit (the
    /// rounding of the steps, [`Step::motion`]).
    magnitude: Vec<f32>,
    /// The vertices held on a face ([`Reach::hold`]), by increasing internal index: their
    /// skip test is [`Holder::keeps`] instead (their `limit2` fails every pass), and they are
    /// reported as touching when it passes.
    holders: Vec<Holder>,
    /// The vertices (internal indices) the last pass moved...
    pub(super) moved: Vec<u32>,
    /// ... and where to, in the same order (a pass leaves its positions as they were; the
    /// caller applies these).
    pub(super) moves: Vec<Vec3>,
    /// Buffers kept from pass to pass, so that a pass does not grow its lists from empty
    /// (reallocations were ~5 % of a 10k tube's passes' instructions, session 28): each
    /// group's results...
    outs: Vec<GroupPass>,
    /// ... the holds of the pass before the last (the next pass's list)...
    spare_holders: Vec<Holder>,
    /// ... and the touching vertices' list, handed back by [`SkinCollision::project_after`].
    pub(super) touching: Vec<(u32, u32)>,
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
        self.prev_stale = false;
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

/// What one group of a pass did (see `pass_on`).
#[derive(Debug, Clone, Default)]
struct GroupPass {
    counters: Counters,
    /// Vertices whose skip test passed.
    skipped: u64,
    /// Of those, the ones in blocks skipped whole after a step.
    in_blocks: u64,
    /// Held vertices their hold kept.
    kept: u64,
    /// The vertices resolved to a new position (internal indices, increasing)...
    moved: Vec<u32>,
    /// ... and their new positions.
    moves: Vec<Vec3>,
    /// The vertices still too close after their resolution (caller's indices).
    unresolved: Vec<u32>,
    /// `(internal, caller's)` index of every vertex touching a collider, by internal index.
    touching: Vec<(u32, u32)>,
    /// The holds after the pass, by internal index.
    holders: Vec<Holder>,
}

impl GroupPass {
    /// Empty again, its lists' capacity kept.
    fn clear(&mut self) {
        self.counters = Counters::default();
        (self.skipped, self.in_blocks, self.kept) = (0, 0, 0);
        self.moved.clear();
        self.moves.clear();
        self.unresolved.clear();
        self.touching.clear();
        self.holders.clear();
    }
}

impl SkinCollision {
    /// Hands the last positions held in the solver's order back to the caller's order and
    /// marks the view stale: every caller-order use of `reach` or `last` starts with this.
    pub(super) fn leave_view(&mut self) {
        if self.view.holds_last && self.view.prev_stale {
            // A solve that stepped without reporting where it ended: no last positions, so
            // the next pass sweeps nothing (as after `clear_frame_state`).
            self.last.fill(Vec3::NAN);
        } else if self.view.holds_last {
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
    pub(super) fn project_pass(
        &mut self,
        x: &[Vec3],
        step: Option<&Step<'_>>,
        alongside: bool,
    ) -> Option<(ChunkPass, Vec<(u32, u32)>)> {
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
        // A step names the positions of the last pass; without one, `prev` must hold them.
        let step = step.filter(|s| s.blocks() == n.div_ceil(BLOCK));
        if step.is_none() && self.view.prev_stale {
            self.view.prev.fill(Vec3::NAN);
            self.view.prev_stale = false;
        }
        Par::current(|par| Some(self.pass_on(par, x, (step, alongside), &travel, travel_sum)))
    }

    /// A solve that called [`project_pass`](Self::project_pass) with its steps ended with the
    /// positions `x` (solver's order) of its last pass: the last positions again.
    pub(super) fn settle_view(&mut self, x: &[Vec3]) {
        if self.view.prev_stale && self.view.prev.len() == x.len() {
            self.view.prev.copy_from_slice(x);
            self.view.prev_stale = false;
        }
    }

    /// [`project_pass`](Self::project_pass) once the view is up to date, its loop on `par`.
    ///
    /// One parallel loop over groups of vertices in the solver's order: each group tests its
    /// vertices' skips and resolves the ones that fail right there. A vertex's state is kept in
    /// the caller's order, at its rank (`rank_of`, a permutation): each one is resolved by the
    /// one group that holds its internal index, so the groups touch disjoint state, and a
    /// resolution reads and writes only its own vertex's (the counters are sums). The groups'
    /// results are joined in group order, which is the solver's order.
    ///
    /// After a solver's step (`step`), a block of vertices whose bounded motion since its last
    /// test stays within its slack is skipped whole (its vertices would all pass their tests),
    /// each failing vertex's last position is the one the step gives back, and the last
    /// positions are not copied (the solve reports them at its end).
    #[expect(unsafe_code, reason = "disjoint chunks written by one parallel loop")]
    fn pass_on(
        &mut self,
        par: Par<'_>,
        x: &[Vec3],
        (step, alongside): (Option<&Step<'_>>, bool),
        travel: &[f64],
        travel_sum: f64,
    ) -> (ChunkPass, Vec<(u32, u32)>) {
        let nc = self.colliders.len();
        let n = x.len();
        let ctx = Ctx {
            colliders: &self.colliders,
            travel,
            travel_sum,
            config: &self.config,
            swept: true,
            face_holds: self.face_holds,
        };
        let groups = n.div_ceil(GROUP);
        let view = &mut self.view;
        let mut outs = std::mem::take(&mut view.outs);
        outs.resize_with(groups, GroupPass::default);
        outs.iter_mut().for_each(GroupPass::clear);
        {
            let prevs = Chunked::new(&mut view.prev, GROUP);
            let (ats, limits) = (
                Chunked::new(&mut view.at, GROUP),
                Chunked::new(&mut view.limit2, GROUP),
            );
            let out = Chunked::new(&mut outs, 1);
            let per_group = GROUP / BLOCK;
            let (slacks, moveds, magnitudes) = (
                Chunked::new(&mut view.slack, per_group),
                Chunked::new(&mut view.moved_since, per_group),
                Chunked::new(&mut view.magnitude, per_group),
            );
            // The caller-order state, one vertex at a time.
            let (reach, states) = (
                Chunked::new(&mut self.reach, 1),
                Chunked::new(&mut self.states, 1),
            );
            let (slots, patches) = (
                Chunked::new(&mut self.slots, nc),
                Chunked::new(&mut self.patches, nc),
            );
            let (rank_of, thickness, holders) = (&self.rank_of, &self.thickness, &view.holders);
            // The groups' CPU time, ns, when the pass runs alongside a gather.
            let nanos = AtomicU64::new(0);
            par.for_each_min(groups, SKIP_TASK_GROUPS, |g| {
                let started = alongside.then(Instant::now);
                // SAFETY: each group index once per loop.
                let xs = &x[g * GROUP..((g + 1) * GROUP).min(n)];
                let (prevs, ats, limits, out) = unsafe {
                    (
                        prevs.chunk(g),
                        ats.chunk(g),
                        limits.chunk(g),
                        &mut out.chunk(g)[0],
                    )
                };
                // SAFETY: as above.
                let (slack, moved_since, magnitude) =
                    unsafe { (slacks.chunk(g), moveds.chunk(g), magnitudes.chunk(g)) };
                let first = g * GROUP;
                // This group's holders, by increasing internal index.
                let mut held = holders[holders.partition_point(|h| (h.i as usize) < first)..]
                    .iter()
                    .peekable();
                for (b, ((xs, prevs), (at, limit2))) in xs
                    .chunks(BLOCK)
                    .zip(prevs.chunks_mut(BLOCK))
                    .zip(ats.chunks_mut(BLOCK).zip(limits.chunks_mut(BLOCK)))
                    .enumerate()
                {
                    if let Some(step) = step {
                        let moved = moved_since[b] + step.motion(g * per_group + b, magnitude[b]);
                        if moved <= f64::from(slack[b]) {
                            // Every vertex of the block still passes its test.
                            moved_since[b] = moved;
                            out.skipped += xs.len() as u64;
                            out.in_blocks += xs.len() as u64;
                            continue;
                        }
                    }
                    let (mut bits, clear) = failures(xs, at, limit2, step.is_some());
                    let block_moves = out.moves.len();
                    (slack[b], magnitude[b], moved_since[b]) = match clear {
                        Some(c) if bits == 0 => (c.slack, c.magnitude, 0.0),
                        _ => (f32::NEG_INFINITY, 0.0, 0.0),
                    };
                    out.skipped += u64::from(xs.len() as u32 - bits.count_ones());
                    while bits != 0 {
                        let k = bits.trailing_zeros() as usize;
                        bits &= bits - 1;
                        let i = (first + b * BLOCK + k) as u32;
                        let o = rank_of[i as usize];
                        // A vertex held on a face that its hold keeps: touching, as the last
                        // pass left it (its skip test always fails).
                        while held.next_if(|h| h.i < i).is_some() {}
                        if let Some(h) = held.next_if(|h| h.i == i && h.keeps(xs[k])) {
                            out.kept += 1;
                            out.touching.push((i, o));
                            out.holders.push(*h);
                            continue;
                        }
                        let o_ = o as usize;
                        // SAFETY: `o` is the rank of `i`, resolved by this group only.
                        let (reach, state, slots, patches) = unsafe {
                            (
                                &mut reach.chunk(o_)[0],
                                &mut states.chunk(o_)[0],
                                slots.chunk(o_),
                                patches.chunk(o_),
                            )
                        };
                        let mut p = xs[k];
                        let mut last = match step {
                            Some(step) => step.before(i as usize, p),
                            None => prevs[k],
                        };
                        let (moved, unresolved) = ctx.resolve(
                            &mut p,
                            thickness[o_],
                            (reach, &mut last),
                            state,
                            (slots, patches),
                            &mut out.counters,
                        );
                        if moved {
                            out.moved.push(i);
                            out.moves.push(p);
                        }
                        if unresolved {
                            out.unresolved.push(o);
                        }
                        if state.touches[0].collider != NONE {
                            out.touching.push((i, o));
                        }
                        out.holders.extend(Holder::of(i, reach, state, travel_sum));
                        (at[k], limit2[k]) = test_of(reach, travel_sum);
                    }
                    // Block by block, while in cache (and below the size from which `memcpy`
                    // switches to `rep movsb`, which callgrind counts byte by byte). After a
                    // step the step gives them back instead.
                    if step.is_none() {
                        prevs.copy_from_slice(xs);
                        let block = first + b * BLOCK;
                        for (&i, &p) in out.moved[block_moves..]
                            .iter()
                            .zip(&out.moves[block_moves..])
                        {
                            prevs[i as usize - block] = p;
                        }
                    }
                }
                if let Some(t) = started {
                    let ns = u64::try_from(t.elapsed().as_nanos()).unwrap_or(u64::MAX);
                    nanos.fetch_add(ns, Ordering::Relaxed);
                }
            });
            self.alongside += Duration::from_nanos(nanos.into_inner());
        }
        // The groups' results in group order: the solver's order.
        let mut pass = ChunkPass::default();
        let mut touching = std::mem::take(&mut view.touching);
        touching.clear();
        let mut holders = std::mem::take(&mut view.spare_holders);
        holders.clear();
        for out in &outs {
            let c = &mut pass.counters;
            c.add(&out.counters);
            c.skipped_vertices += out.skipped + out.kept;
            c.skipped_in_blocks += out.in_blocks;
            c.skipped_bound += out.skipped * nc as u64;
            c.contacts += out.kept;
            c.moved += out.moved.len() as u64;
            view.moved.extend_from_slice(&out.moved);
            view.moves.extend_from_slice(&out.moves);
            pass.unresolved.extend_from_slice(&out.unresolved);
            touching.extend_from_slice(&out.touching);
            holders.extend_from_slice(&out.holders);
        }
        view.outs = outs;
        // Rare: a sort only when some vertex stayed unresolved.
        pass.unresolved.sort_unstable();
        view.prev_stale |= step.is_some();
        view.spare_holders = std::mem::replace(&mut view.holders, holders);
        (pass, touching)
    }

    /// Rebuilds the skip tests in the solver's order for the colliders' summed travel
    /// `travel_sum`, and takes the last positions over from the caller's order.
    fn rebuild_view(&mut self, travel_sum: f64) {
        let n = self.rank_of.len();
        let view = &mut self.view;
        view.at.resize(n, Vec3::ZERO);
        view.limit2.resize(n, 0.0);
        // Every block is tested again (its tests changed).
        let blocks = n.div_ceil(BLOCK);
        view.slack.clear();
        view.slack.resize(blocks, f32::NEG_INFINITY);
        view.moved_since.clear();
        view.moved_since.resize(blocks, 0.0);
        view.magnitude.clear();
        view.magnitude.resize(blocks, 0.0);
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

/// Vertices per work item of the skip test (a whole number of blocks).
pub(super) const GROUP: usize = 1024;
const _: () = assert!(GROUP.is_multiple_of(BLOCK));

/// Groups per task of a pass on rayon's pool (a projection called outside a solve): ~8k
/// vertices (the skip test costs ~1 ns per vertex, less than waking another thread for a
/// smaller task; session 7 measured a tube-10k frame's projections ~15 % faster with the skip
/// test on one thread). A solve's team ignores it: its helpers are awake.
const SKIP_TASK_GROUPS: usize = 8;

/// Vertices per block of the skip test (one bit each in a `u64`); a whole number of blocks
/// makes a chunk.
const BLOCK: usize = 64;
const _: () = assert!(CHUNK.is_multiple_of(BLOCK));
// A pass's blocks are the solver's step blocks.
const _: () = assert!(BLOCK == crate::solver::STEP_BLOCK);

/// How far a block whose every vertex passed its test may move and still pass (see
/// [`failures`]).
#[derive(Debug, Clone, Copy, PartialEq)]
struct Clear {
    /// Any vertex of the block may move this far from where it was tested, m, and its test
    /// `|x − at|² ≤ limit²` (in f32) still passes.
    slack: f32,
    /// A bound on the block's coordinates (absolute values) while it moves within `slack`,
    /// m: for the rounding of the steps ([`Step::motion`]).
    magnitude: f32,
}

impl Clear {
    /// From the smallest `√limit² − √|x − at|²` of a block, its largest `√limit²` and its
    /// largest coordinate (absolute value), each computed in f32: the slack less 1e-5 of the
    /// largest limit, which covers the rounding of those roots and of the f32 test (a few
    /// ulps of the limit).
    fn new(smallest: f32, limit: f32, coordinate: f32) -> Self {
        Self {
            slack: smallest - 1e-5 * limit,
            magnitude: coordinate + limit,
        }
    }
}

/// Bit `k` set for each vertex `k` of a block (at most [`BLOCK`]) at `xs` that fails its skip
/// test `|x − at|² ≤ limit²` (NaN fails); when none fails and `slack` asks for it, how far
/// the block may move and still pass (a pass outside a solve's steps has no use for it).
#[cfg_attr(
    target_arch = "x86_64",
    expect(unsafe_code, reason = "the AVX2 path, behind its run-time CPU check")
)]
fn failures(xs: &[Vec3], at: &[Vec3], limit2: &[f32], slack: bool) -> (u64, Option<Clear>) {
    #[cfg(target_arch = "x86_64")]
    if xs.len() == BLOCK && at.len() == BLOCK && limit2.len() == BLOCK && avx2::available() {
        if !slack {
            // SAFETY: AVX2 is available and the three slices hold a whole block.
            return (unsafe { avx2::failures::<false>(xs, at, limit2) }.0, None);
        }
        // SAFETY: as above.
        let (fail, [smallest, limit, coordinate]) =
            unsafe { avx2::failures::<true>(xs, at, limit2) };
        return (
            fail,
            (fail == 0).then(|| Clear::new(smallest, limit, coordinate)),
        );
    }
    let (fail, clear) = failures_portable(xs, at, limit2);
    (fail, clear.filter(|_| slack))
}

/// [`failures`] one vertex at a time.
fn failures_portable(xs: &[Vec3], at: &[Vec3], limit2: &[f32]) -> (u64, Option<Clear>) {
    let mut fail = 0u64;
    let (mut smallest, mut limit, mut coordinate) = (f32::INFINITY, 0.0f32, 0.0f32);
    for (k, ((p, a), l)) in xs.iter().zip(at).zip(limit2).enumerate() {
        let (dx, dy, dz) = (p.x - a.x, p.y - a.y, p.z - a.z);
        let d2 = dx * dx + dy * dy + dz * dz;
        let near = d2 <= *l;
        fail |= u64::from(!near) << k;
        smallest = smallest.min(l.sqrt() - d2.sqrt());
        limit = limit.max(l.sqrt());
        coordinate = coordinate.max(p.abs().max_element());
    }
    (
        fail,
        (fail == 0).then(|| Clear::new(smallest, limit, coordinate)),
    )
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
    /// operations in the same order (so the same bits): the failures, and the smallest
    /// `√limit² − √|x − at|²`, the largest `√limit²` and the largest coordinate (absolute
    /// value; meaningful when nothing failed).
    ///
    /// # Safety
    /// AVX2 must be available and the slices must hold [`BLOCK`] entries.
    #[target_feature(enable = "avx2")]
    pub unsafe fn failures<const SLACK: bool>(
        xs: &[Vec3],
        at: &[Vec3],
        limit2: &[f32],
    ) -> (u64, [f32; 3]) {
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
        let (mut smallest, mut limit, mut coordinate) = (
            _mm256_set1_ps(f32::INFINITY),
            _mm256_setzero_ps(),
            _mm256_setzero_ps(),
        );
        let magnitude = _mm256_castsi256_ps(_mm256_set1_epi32(i32::MAX));
        for step in 0..BLOCK / 8 {
            // SAFETY: 24 floats of `xs` and `at` and 8 of `limit2` from vertex 8 step on are in
            // the block.
            unsafe {
                let o = 24 * step;
                let mut sq = |i: usize| {
                    let p = _mm256_loadu_ps(x.add(o + i));
                    if SLACK {
                        coordinate = _mm256_max_ps(coordinate, _mm256_and_ps(p, magnitude));
                    }
                    let d = _mm256_sub_ps(p, _mm256_loadu_ps(a.add(o + i)));
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
                let lim = _mm256_loadu_ps(l.add(8 * step));
                let near = _mm256_cmp_ps::<_CMP_LE_OQ>(sum, lim);
                let bits = !_mm256_movemask_ps(near) as u64 & 0xff;
                fail |= bits << (8 * step);
                if SLACK {
                    let root = _mm256_sqrt_ps(lim);
                    smallest = _mm256_min_ps(smallest, _mm256_sub_ps(root, _mm256_sqrt_ps(sum)));
                    limit = _mm256_max_ps(limit, root);
                }
            }
        }
        if !SLACK {
            return (fail, [0.0; 3]);
        }
        let lanes = |v: __m256| {
            let mut out = [0.0f32; 8];
            // SAFETY: eight writable floats.
            unsafe { _mm256_storeu_ps(out.as_mut_ptr(), v) };
            out
        };
        (
            fail,
            [
                lanes(smallest).into_iter().fold(f32::INFINITY, f32::min),
                lanes(limit).into_iter().fold(0.0, f32::max),
                lanes(coordinate).into_iter().fold(0.0, f32::max),
            ],
        )
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
            let (bits, clear) = failures(&xs, &at, &limit2, true);
            assert_eq!(failures(&xs, &at, &limit2, false), (bits, None));
            assert_eq!(
                (bits, clear),
                failures_portable(&xs, &at, &limit2),
                "round {round}"
            );
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
        assert_eq!(
            failures(&xs, &at, &[2.0, 0.5, 1.0, -1.0, 1.5], true).0,
            0b01010
        );
    }

    /// The slack is sound: after every vertex of a block that passed moves by at most the
    /// slack (measured exactly, in f64), in any direction, every vertex still passes its f32
    /// test. The hardest moves are tried too: straight away from `at`, by the whole slack (the
    /// vertex with the least clearance then ends within the slack's rounding margin of its
    /// limit), far from the origin (coordinates up to 8 m against limits down to 0.1 mm).
    #[test]
    fn a_block_moved_within_its_slack_still_passes() {
        let mut rng = Lcg(11);
        let (mut tight, mut full) = (0, 0u32);
        for round in 0..400 {
            let centre = rng.point(if round % 2 == 0 { 8.0 } else { 0.5 });
            let at: Vec<Vec3> = (0..BLOCK).map(|_| centre + rng.point(0.05)).collect();
            // Limits over three decades in half the rounds, all alike in the others.
            let one = 10f32.powf(-4.0 + 3.0 * rng.next());
            let limit2: Vec<f32> = (0..BLOCK)
                .map(|_| match round % 2 {
                    0 => 10f32.powf(-4.0 + 3.0 * rng.next()).powi(2),
                    _ => one * one,
                })
                .collect();
            let xs: Vec<Vec3> = (0..BLOCK)
                .map(|v| {
                    let dir = (rng.point(1.0) + Vec3::splat(1e-3)).normalize();
                    // Some clearances within 0.1 % of the limit, the rest anywhere inside.
                    let reach = if v % 16 == round % 16 {
                        0.999
                    } else {
                        0.999 * rng.next()
                    };
                    at[v] + dir * (limit2[v].sqrt() * reach)
                })
                .collect();
            let (bits, clear) = failures(&xs, &at, &limit2, true);
            assert_eq!((bits, clear), failures_portable(&xs, &at, &limit2));
            let Some(clear) = clear else {
                // A clearance rounded past its limit: this block would not be skipped.
                assert_ne!(bits, 0);
                continue;
            };
            assert!(clear.slack < limit2.iter().fold(f32::INFINITY, |a, l| a.min(l.sqrt())));
            if clear.slack <= 0.0 {
                continue;
            }
            tight += 1;
            for trial in 0..8 {
                let moved: Vec<Vec3> = xs
                    .iter()
                    .zip(&at)
                    .map(|(x, a)| {
                        let dir = if trial < 2 {
                            // Straight away from `at`: the move that spends the most slack.
                            (*x - *a).normalize_or(Vec3::X)
                        } else {
                            rng.point(1.0).normalize_or(Vec3::X)
                        };
                        let far = if trial % 2 == 0 { 1.0 } else { rng.next() };
                        let mut scale = f64::from(clear.slack) * f64::from(far);
                        // The moved position is an f32: shrink the move until its exact
                        // length is within the slack.
                        let ulp = f64::from(x.abs().max_element() * f32::EPSILON);
                        loop {
                            let p = (x.as_dvec3() + dir.as_dvec3() * scale).as_vec3();
                            let over = p.as_dvec3().distance(x.as_dvec3()) - f64::from(clear.slack);
                            if over <= 0.0 {
                                full += u32::from(over > -0.01 * f64::from(clear.slack));
                                break p;
                            }
                            scale -= over + ulp;
                            // A slack under the coordinates' ulp: no move fits.
                            if scale <= 0.0 {
                                break *x;
                            }
                        }
                    })
                    .collect();
                assert_eq!(
                    failures(&moved, &at, &limit2, false).0,
                    0,
                    "round {round} trial {trial}: a vertex moved within the slack fails"
                );
                assert_eq!(failures_portable(&moved, &at, &limit2).0, 0);
            }
        }
        // Most rounds were blocks that pass and have room to move, and many vertices moved by
        // the whole slack (to 1 %).
        assert!(
            tight > 200 && full > 20_000,
            "{tight} blocks, {full} whole moves"
        );
    }
}
