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

use glam::Vec3;
use rayon::prelude::*;

use super::{CHUNK, Counters, Ctx, NONE, Reach, SkinCollision};

/// The skip tests and last positions in the solver's order (see the module docs).
#[derive(Debug, Clone, Default)]
pub(super) struct View {
    /// Whether `test` is up to date with the caller-order [`Reach`]es for the colliders'
    /// identities and travels in `key`.
    valid: bool,
    key: Vec<(u64, f64)>,
    /// Per internal vertex: where it was resolved last (x, y, z) and how far, squared, it may
    /// move from there before a pass must resolve it (negative: every pass resolves it).
    test: Vec<[f32; 4]>,
    /// Each vertex's position after the last pass, in the solver's order, while `holds_last`.
    prev: Vec<Vec3>,
    /// Whether `prev` holds the last positions (then [`SkinCollision::last`] is stale).
    holds_last: bool,
}

impl View {
    /// Forgets the view, the last positions included (the caller's state was reset).
    pub(super) fn discard(&mut self) {
        self.valid = false;
        self.holds_last = false;
    }
}

/// The skip test of a vertex whose reach is `r`, the colliders' summed travel `travel`:
/// `[at, limit²]` such that `|p − at|² ≤ limit²` in f32 implies `r.skips(p, travel)`.
fn test_of(r: &Reach, travel: f64) -> [f32; 4] {
    let limit = r.reserve as f64 / (1.0 + 1e-5) - (travel - r.travel_at);
    // The relative margin (4e-6) covers the f32 rounding of the squared distance, of its
    // square root in `skips` and of `limit²` itself (a few 1e-7 together).
    let limit2 = if limit > 0.0 && r.at.is_finite() {
        (limit * (1.0 - 4e-6)).powi(2) as f32
    } else {
        -1.0
    };
    [r.at.x, r.at.y, r.at.z, limit2]
}

/// What a projection pass did.
pub(super) struct ProjectPass {
    pub counters: Counters,
    /// Vertices still too close after the last round (caller's indices, increasing).
    pub unresolved: Vec<u32>,
    /// `(internal, caller's)` index of every vertex touching a collider after the pass.
    pub touching: Vec<(u32, u32)>,
}

/// One resolved vertex.
struct Resolved {
    /// Internal index.
    i: u32,
    /// Caller's index.
    o: u32,
    p: Vec3,
    moved: bool,
    unresolved: bool,
    touching: bool,
    test: [f32; 4],
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
    /// a permutation), with the swept test; `None` when there is nothing to collide with.
    pub(super) fn project_pass(&mut self, x: &mut [Vec3]) -> Option<ProjectPass> {
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

        // The skip test of every vertex, in order; the ones that fail are listed with their
        // last position, and the others' last positions become their positions.
        let view = &mut self.view;
        let per_chunk: Vec<(Vec<(u32, Vec3)>, u64)> = x
            .par_chunks(CHUNK)
            .zip(view.test.par_chunks(CHUNK))
            .zip(view.prev.par_chunks_mut(CHUNK))
            .enumerate()
            .map(|(chunk, ((xs, tests), prevs))| {
                let mut listed = Vec::new();
                for (block, ((xs, tests), prevs)) in xs
                    .chunks(64)
                    .zip(tests.chunks(64))
                    .zip(prevs.chunks_mut(64))
                    .enumerate()
                {
                    // Branch-free over the block; the failures (rare) are visited by their bits.
                    let mut fail = 0u64;
                    let tests = &tests[..xs.len()];
                    for k in 0..xs.len() {
                        let (p, t) = (xs[k], tests[k]);
                        let (dx, dy, dz) = (p.x - t[0], p.y - t[1], p.z - t[2]);
                        // NaN (never resolved) fails.
                        let near = dx * dx + dy * dy + dz * dz <= t[3];
                        fail |= u64::from(!near) << k;
                    }
                    let mut bits = fail;
                    while bits != 0 {
                        let k = bits.trailing_zeros() as usize;
                        bits &= bits - 1;
                        listed.push(((chunk * CHUNK + block * 64 + k) as u32, prevs[k]));
                    }
                    prevs.copy_from_slice(xs);
                }
                let skipped = (xs.len() - listed.len()) as u64;
                (listed, skipped)
            })
            .collect();
        let mut counters = Counters::default();
        let mut listed: Vec<(u32, u32, Vec3)> = Vec::new();
        for (l, skipped) in per_chunk {
            counters.skipped_vertices += skipped;
            counters.skipped_bound += skipped * nc as u64;
            listed.extend(
                l.into_iter()
                    .map(|(i, last)| (self.rank_of[i as usize], i, last)),
            );
        }
        // Resolved in the caller's order, each chunk of state by one task.
        listed.sort_unstable_by_key(|&(o, _, _)| o);
        let bounds: Vec<usize> = (0..=n.div_ceil(CHUNK))
            .map(|c| listed.partition_point(|&(o, _, _)| (o as usize) < c * CHUNK))
            .collect();
        let ctx = Ctx {
            colliders: &self.colliders,
            travel: &travel,
            travel_sum,
            config: &self.config,
            swept: true,
        };
        let xs = &*x;
        let resolved: Vec<(Vec<Resolved>, Counters)> = self
            .reach
            .par_chunks_mut(CHUNK)
            .zip(self.states.par_chunks_mut(CHUNK))
            .zip(self.slots.par_chunks_mut(CHUNK * nc))
            .zip(self.thickness.par_chunks(CHUNK))
            .enumerate()
            .map(|(chunk, (((reach, states), slots), hs))| {
                let mut counters = Counters::default();
                let done = listed[bounds[chunk]..bounds[chunk + 1]]
                    .iter()
                    .map(|&(o, i, last)| {
                        let k = o as usize - chunk * CHUNK;
                        let (mut p, mut last) = (xs[i as usize], last);
                        let (moved, unresolved) = ctx.resolve(
                            &mut p,
                            hs[k],
                            (&mut reach[k], &mut last),
                            &mut states[k],
                            &mut slots[k * nc..(k + 1) * nc],
                            &mut counters,
                        );
                        Resolved {
                            i,
                            o,
                            p,
                            moved,
                            unresolved,
                            touching: states[k].touches[0].collider != NONE,
                            test: test_of(&reach[k], travel_sum),
                        }
                    })
                    .collect();
                (done, counters)
            })
            .collect();

        let mut pass = ProjectPass {
            counters,
            unresolved: Vec::new(),
            touching: Vec::new(),
        };
        let view = &mut self.view;
        for (done, counters) in resolved {
            pass.counters.add(&counters);
            for r in done {
                let i = r.i as usize;
                if r.moved {
                    x[i] = r.p;
                    pass.counters.moved += 1;
                }
                view.prev[i] = r.p;
                view.test[i] = r.test;
                if r.unresolved {
                    pass.unresolved.push(r.o);
                }
                if r.touching {
                    pass.touching.push((r.i, r.o));
                }
            }
        }
        Some(pass)
    }

    /// Rebuilds the skip tests in the solver's order for the colliders' summed travel
    /// `travel_sum`, and takes the last positions over from the caller's order.
    fn rebuild_view(&mut self, travel_sum: f64) {
        let n = self.rank_of.len();
        let view = &mut self.view;
        view.test.resize(n, [0.0; 4]);
        let (order, reach) = (&self.rank_of, &self.reach);
        view.test
            .par_chunks_mut(CHUNK)
            .zip(order.par_chunks(CHUNK))
            .for_each(|(tests, order)| {
                for (t, &o) in tests.iter_mut().zip(order) {
                    *t = test_of(&reach[o as usize], travel_sum);
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
        view.key.clone_from(&self.travel_seen);
        view.valid = true;
    }
}
