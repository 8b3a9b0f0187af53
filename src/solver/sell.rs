//! Sliced ELLPACK storage of the springs: eight vertices per slice, `(k, rest)` once per spring.
//!
//! Each slice of [`LANES`] consecutive (internal) vertices is padded to the largest degree among
//! them and stored slot-major: entry `slot * LANES + lane` of the slice is the `slot`-th spring
//! of vertex `8 * slice + lane`. One SIMD load then reads one spring of eight vertices, so the
//! kernels never shuffle lanes. Each vertex's springs are right-aligned in its lane (padding
//! first), so the springs to higher-numbered vertices, which carry the energy and the
//! curvature, sit in the last slots of every slice: the kernels visit only those slots for them.
//! Padding entries point at the vertex itself (a real spring never joins a vertex to itself),
//! and contribute nothing.
//!
//! The other end of a spring is stored as a 16-bit offset from the slice's first vertex
//! (vertices are in bandwidth order, so almost every neighbour is near), times three when all of
//! the slice's offsets allow it ("tripled": the float offset of the neighbour's position, which
//! the kernels use as an address without a multiplication); a slice with a neighbour
//! farther than that ("wide", flagged in [`Sell::upper`]) keeps full 32-bit indices in
//! [`Sell::far`] instead. So does every slice that names the last vertex (the last slice and
//! its neighbours): the kernels read a vertex as 16 bytes, one float past its own, which they
//! may do without a check in the near slices only.
//!
//! Stiffness and rest length are stored once per spring, not once per half-spring. A slice's
//! entries split in two: the *upper* slots, from the first slot in which some lane has a spring
//! to a higher vertex, and the *lower* slots before them, which hold only springs to lower
//! vertices (and padding). The upper slots keep a `(k, rest)` pair per entry in
//! [`Sell::kr`] (a lane's spring to a lower vertex there keeps a copy of its pair with the
//! stiffness negated, so that the kernels tell the springs whose energy and curvature they
//! take by its sign; padding zeros); the lower slots keep none: each of their entries names
//! the pair of the same spring at its other end, a lower vertex whose upper slots hold it (an
//! earlier slice, or this one), as a 16-bit distance back from the end of this slice's pairs,
//! or as a full 32-bit pair index in the few slices with a partner farther back
//! ([`Sell::far_refs`]). An upper entry takes 2 + 8 bytes, a lower one 2 + 2 (instead of
//! 2 + 8 + 8 for every half-spring before): on the bench's skin tubes (degree 6; per vertex
//! about 3.7 upper and 2.3 lower slots) 47-50 bytes of springs per vertex with the per-slice
//! offsets, instead of 61-63.
//!
//! The pairs of one upper slot (eight lanes, 64 bytes) are stored in the lane order
//! [`PAIR_LANES`], so that two 32-byte loads and two in-lane shuffles give the stiffness and the
//! rest length of the eight lanes in lane order.

use rayon::prelude::*;

use super::Spring;

/// Vertices per slice (the SIMD width of the kernels).
pub(crate) const LANES: usize = 8;

/// The lane whose `(k, rest)` pair sits at position `m` of an upper slot's eight pairs (and, as
/// the permutation is its own inverse, the position of lane `m`'s pair): lanes 0, 1, 4, 5 in
/// the first 32 bytes and 2, 3, 6, 7 in the next.
pub(crate) const PAIR_LANES: [usize; LANES] = [0, 1, 4, 5, 2, 3, 6, 7];

/// Flag bit of [`Sell::upper`]: the slice's other ends are in [`Sell::far`].
const WIDE: u32 = 1 << 31;

/// Flag bit of [`Sell::upper`]: the slice's offsets in [`Sell::near`] are stored times three
/// (the float offset of the other end's row, which the kernels use as an address directly).
const TRIPLE: u32 = 1 << 30;

/// Flag bit of [`Sell::upper`]: the slice's lower entries name their pairs in
/// [`Sell::far_refs`].
const FAR_REFS: u32 = 1 << 29;

/// Entries (half-springs with their slices' padding) a layout can index: entry indices carry
/// flags in their top three bits.
pub(crate) const MAX_ENTRIES: usize = FAR_REFS as usize;

/// The flag bits of [`Sell::upper`].
const FLAGS: u32 = WIDE | TRIPLE | FAR_REFS;

/// Largest distance back (in pairs) a 16-bit reference spans.
const NEAR_REF: usize = u16::MAX as usize;

/// Where the lower entries of one slice find their `(k, rest)` pairs.
#[derive(Debug, Clone, Copy)]
pub(crate) enum Refs<'a> {
    /// Entry `e` names pair `base + refs[r]` (a sign-extended 16-bit value) for
    /// `r = e - first` with its lane permuted by [`PAIR_LANES`] (the references of one slot
    /// are stored in the order of its pairs).
    Near {
        /// The slice's references, from its first entry.
        refs: &'a [i16],
        /// Added to each reference.
        base: isize,
    },
    /// Entry `e` names pair `refs[r]`, `r` as for `Near`.
    Far {
        /// The slice's pair indices, from its first entry.
        refs: &'a [u32],
    },
}

/// The springs of one slice, as the kernels walk them.
#[derive(Debug, Clone)]
pub(crate) struct Parts<'a> {
    /// The lower entries (springs to lower vertices and padding), which name their pairs by
    /// `refs`.
    pub lower: std::ops::Range<usize>,
    /// The upper entries, each holding its pair.
    pub upper: std::ops::Range<usize>,
    /// The index in [`Sell::kr`] of the upper entries' first pair (the pairs of entry
    /// `upper.start + 8 m` start at `pairs + 8 m`).
    pub pairs: usize,
    /// The lower entries' references.
    pub refs: Refs<'a>,
}

/// The half-springs of every vertex, in slices of [`LANES`] vertices.
#[derive(Debug, Clone, Default)]
pub(crate) struct Sell {
    /// Number of vertices.
    pub n: usize,
    /// Start of each slice's entries (`slices + 1` values, multiples of [`LANES`]).
    pub start: Vec<u32>,
    /// Per slice, the first entry from which some lane has a spring to a higher vertex (its
    /// upper entries; the entries before hold no pairs), with the flag bits `WIDE`, `TRIPLE`
    /// and `FAR_REFS`.
    pub upper: Vec<u32>,
    /// Per slice, the number of lower entries in the slices up to and including it: the upper
    /// entry `e` of slice `s` has its pair at `e - low[s]` (before [`PAIR_LANES`]), and its
    /// lower entry `e` its reference at `e - upper + low[s]`.
    pub low: Vec<u32>,
    /// The vertex at the other end (the vertex itself for padding), minus the slice's first
    /// vertex (0 in wide slices; times three in tripled slices).
    pub near: Vec<i16>,
    /// Stiffness (N/m) and rest length (m) of the upper entries, eight pairs per slot in the
    /// lane order [`PAIR_LANES`] (zeros for padding). The stiffness is negated (`-0.0` for
    /// zero) in the entries of springs to lower vertices, which only these copies hold: every
    /// pair a lower entry names is that of a spring to a higher vertex, so positive.
    pub kr: Vec<[f32; 2]>,
    /// Per lower entry (the eight of a slot in the lane order [`PAIR_LANES`]): the pair of its
    /// spring, as `32 768 - (end - pair)` for `end` the end of the slice's pairs (unused in the
    /// slices of [`far_refs`](Self::far_refs); padding names any pair, here the slice's last).
    pub refs: Vec<i16>,
    /// `(slice, offset)` of each slice whose lower entries' pairs are in `far_refs`: its lower
    /// entries name pairs `far_refs[offset..offset + lower entries]`.
    pub wide_refs: Vec<(u32, u32)>,
    /// Pair indices of the lower entries of the slices in `wide_refs`.
    pub far_refs: Vec<u32>,
    /// `(slice, offset)` of each wide slice, by slice: its entries' other ends are
    /// `far[offset..offset + entries]`.
    pub wide: Vec<(u32, u32)>,
    /// The other ends of the wide slices' entries.
    pub far: Vec<u32>,
}

impl Sell {
    /// The layout of CSR half-springs (`springs[offsets[i]..offsets[i + 1]]` for vertex `i`,
    /// sorted by their other end), keeping each vertex's springs in their CSR order. Every
    /// spring is listed at both of its ends with the same stiffness and rest length, as
    /// [`SpringSystem::new`](super::SpringSystem::new) lists them.
    ///
    /// `Err(entries)` for [`MAX_ENTRIES`] or more entries (about 80 million vertices).
    ///
    /// # Panics
    /// If a spring to a lower vertex has no twin at that vertex.
    pub fn from_csr(offsets: &[u32], springs: &[Spring]) -> Result<Self, usize> {
        let n = offsets.len().saturating_sub(1);
        let slices = n.div_ceil(LANES);
        let mut start = Vec::with_capacity(slices + 1);
        start.push(0u32);
        for s in 0..slices {
            let width = (s * LANES..((s + 1) * LANES).min(n))
                .map(|i| offsets[i + 1] - offsets[i])
                .max()
                .unwrap_or(0);
            start.push(start[s] + width * LANES as u32);
        }
        let total = start[slices] as usize;
        if total >= MAX_ENTRIES {
            return Err(total);
        }
        let mut near = vec![0i16; total];
        // The CSR spring of each entry (`u32::MAX` for padding).
        let mut spring = vec![u32::MAX; total];
        let mut upper = Vec::with_capacity(slices);
        let (mut wide, mut far) = (Vec::new(), Vec::new());
        let mut other = Vec::new();
        for s in 0..slices {
            let (begin, end) = (start[s] as usize, start[s + 1] as usize);
            let width = (end - begin) / LANES;
            let mut first_upper = width;
            other.clear();
            other.resize(end - begin, 0u32);
            for lane in 0..LANES {
                let i = (s * LANES + lane).min(n - 1);
                let range = offsets[i] as usize..offsets[i + 1] as usize;
                let range = if s * LANES + lane < n { range } else { 0..0 };
                let own = &springs[range.clone()];
                let pad = width - own.len();
                // CSR springs are sorted by their other end: the upper ones are a suffix.
                let lower = own.partition_point(|sp| (sp.other as usize) < i);
                if lower < own.len() {
                    first_upper = first_upper.min(pad + lower);
                }
                for (slot, e) in (begin + lane..end).step_by(LANES).enumerate() {
                    match slot.checked_sub(pad) {
                        Some(o) => {
                            other[e - begin] = own[o].other;
                            spring[e] = (range.start + o) as u32;
                        }
                        None => other[e - begin] = i as u32,
                    }
                }
            }
            let base = (s * LANES) as i64;
            let offset = |o: &u32| {
                i16::try_from(*o as i64 - base)
                    .ok()
                    .filter(|_| *o as usize + 1 < n)
            };
            let mut flag = 0;
            if other.iter().all(|o| offset(o).is_some()) {
                // Times three when every offset allows it.
                let triple = other
                    .iter()
                    .all(|o| offset(o).and_then(|o| o.checked_mul(3)).is_some());
                let scale = if triple { 3 } else { 1 };
                for (slot, o) in near[begin..end].iter_mut().zip(&other) {
                    *slot = offset(o).unwrap_or_default() * scale;
                }
                if triple {
                    flag = TRIPLE;
                }
            } else {
                flag = WIDE;
                wide.push((s as u32, far.len() as u32));
                far.extend_from_slice(&other);
            }
            upper.push((begin + first_upper * LANES) as u32 | flag);
        }
        let mut low = Vec::with_capacity(slices);
        let mut lower_entries = 0u32;
        for s in 0..slices {
            lower_entries += (upper[s] & !FLAGS) - start[s];
            low.push(lower_entries);
        }
        let mut sell = Self {
            n,
            start,
            upper,
            low,
            near,
            kr: vec![[0.0; 2]; total - lower_entries as usize],
            refs: vec![0; lower_entries as usize],
            wide_refs: Vec::new(),
            far_refs: Vec::new(),
            wide,
            far,
        };
        // The upper entries' own pairs, the stiffness negated for a spring to a lower vertex
        // (its energy and curvature belong to the other end).
        for s in 0..slices {
            for e in sell.upper_entries(s) {
                if let Some(sp) = springs.get(spring[e] as usize) {
                    let p = sell.own_pair(s, e);
                    let lower = (sp.other as usize) < s * LANES + e % LANES;
                    sell.kr[p] = [if lower { -sp.k } else { sp.k }, sp.rest];
                }
            }
        }
        // The lower entries name the pair of their spring's twin, an upper entry of the
        // lower vertex.
        let entry_of = |j: usize, m: usize| {
            let s = j / LANES;
            let width = (sell.start[s + 1] - sell.start[s]) as usize / LANES;
            let pad = width - (offsets[j + 1] - offsets[j]) as usize;
            (s, sell.start[s] as usize + (pad + m) * LANES + j % LANES)
        };
        let mut pairs = Vec::new();
        for s in 0..slices {
            // The references of one slot follow its pairs' lane order: reference `r` is
            // that of entry `r - r % LANES + PAIR_LANES[r % LANES]` (relative to the first).
            let lower = sell.start[s] as usize..(sell.upper[s] & !FLAGS) as usize;
            let end = sell.start[s + 1] as usize - sell.low[s] as usize;
            pairs.clear();
            for r in 0..lower.len() {
                let e = lower.start + r - r % LANES + PAIR_LANES[r % LANES];
                let Some(sp) = springs.get(spring[e] as usize) else {
                    // Padding: any pair will do (its force is masked out); the slice's last.
                    pairs.push(end - 1);
                    continue;
                };
                let i = (s * LANES + e % LANES) as u32;
                let j = sp.other as usize;
                let theirs = offsets[j] as usize..offsets[j + 1] as usize;
                let m = springs[theirs]
                    .iter()
                    .position(|t| {
                        t.other == i
                            && t.k.to_bits() == sp.k.to_bits()
                            && t.rest.to_bits() == sp.rest.to_bits()
                    })
                    .expect("every spring is listed at both ends");
                let (sj, twin) = entry_of(j, m);
                debug_assert!(sell.upper_entries(sj).contains(&twin));
                pairs.push(sell.own_pair(sj, twin));
            }
            let first = sell.low[s] as usize - lower.len();
            if pairs.iter().all(|&p| end - p <= NEAR_REF) {
                let refs = &mut sell.refs[first..first + lower.len()];
                for (r, &p) in refs.iter_mut().zip(&pairs) {
                    *r = (32_768 - (end - p) as i32) as i16;
                }
            } else {
                sell.upper[s] |= FAR_REFS;
                sell.wide_refs.push((s as u32, sell.far_refs.len() as u32));
                sell.far_refs.extend(pairs.iter().map(|&p| p as u32));
            }
        }
        Ok(sell)
    }

    /// The index in [`kr`](Self::kr) of the pair of upper entry `e` of slice `s`.
    #[inline(always)]
    fn own_pair(&self, s: usize, e: usize) -> usize {
        let q = e - self.low[s] as usize;
        q - q % LANES + PAIR_LANES[q % LANES]
    }

    /// The upper entries of slice `s` and the index in [`kr`](Self::kr) of their first pair
    /// (the eight pairs of entry `upper.start + 8 m` start at `pairs + 8 m`, in the lane order
    /// [`PAIR_LANES`]).
    #[inline(always)]
    pub fn upper_pairs(&self, s: usize) -> (std::ops::Range<usize>, usize) {
        let upper = self.upper_entries(s);
        let pairs = upper.start - self.low[s] as usize;
        (upper, pairs)
    }

    /// The [`Parts`] of slice `s`.
    #[inline(always)]
    pub fn parts(&self, s: usize) -> Parts<'_> {
        let (begin, end) = (self.start[s] as usize, self.start[s + 1] as usize);
        let upper = self.upper[s];
        let first = (upper & !FLAGS) as usize;
        let low = self.low[s] as usize;
        let refs = if upper & FAR_REFS == 0 {
            Refs::Near {
                refs: &self.refs[low - (first - begin)..low],
                base: (end - low) as isize - 32_768,
            }
        } else {
            self.refs_of(s)
        };
        Parts {
            lower: begin..first,
            upper: first..end,
            pairs: first - low,
            refs,
        }
    }

    /// The entries of slice `s`: `start..end`, in steps of [`LANES`].
    #[inline(always)]
    pub fn entries(&self, s: usize) -> std::ops::Range<usize> {
        self.start[s] as usize..self.start[s + 1] as usize
    }

    /// The entries of slice `s` from which some lane has a spring to a higher vertex (each
    /// with its pair in [`kr`](Self::kr)).
    #[inline(always)]
    pub fn upper_entries(&self, s: usize) -> std::ops::Range<usize> {
        (self.upper[s] & !FLAGS) as usize..self.start[s + 1] as usize
    }

    /// The entries of slice `s` before its upper ones: springs to lower vertices and padding,
    /// which name their pairs through [`refs_of`](Self::refs_of).
    #[inline(always)]
    pub fn lower_entries(&self, s: usize) -> std::ops::Range<usize> {
        self.start[s] as usize..(self.upper[s] & !FLAGS) as usize
    }

    /// Where the [lower entries](Self::lower_entries) of slice `s` find their pairs (one
    /// reference per entry, from the slice's first).
    #[inline(always)]
    pub fn refs_of(&self, s: usize) -> Refs<'_> {
        let lower = self.lower_entries(s).len();
        if self.upper[s] & FAR_REFS != 0 {
            let k = self.wide_refs.partition_point(|w| (w.0 as usize) < s);
            let offset = self.wide_refs[k].1 as usize;
            return Refs::Far {
                refs: &self.far_refs[offset..offset + lower],
            };
        }
        let last = self.low[s] as usize;
        let end = self.start[s + 1] as usize - last;
        Refs::Near {
            refs: &self.refs[last - lower..last],
            base: end as isize - 32_768,
        }
    }

    /// The other ends of slice `s`'s entries: `None` when they are in [`near`](Self::near),
    /// else the slice's part of [`far`](Self::far) (one per entry, from the slice's start).
    #[inline(always)]
    pub fn far_of(&self, s: usize) -> Option<&[u32]> {
        if self.upper[s] & WIDE == 0 {
            return None;
        }
        let k = self.wide.partition_point(|w| (w.0 as usize) < s);
        let offset = self.wide[k].1 as usize;
        Some(&self.far[offset..offset + self.entries(s).len()])
    }

    /// Whether slice `s` (a near one) stores its offsets times three.
    #[inline(always)]
    pub fn tripled(&self, s: usize) -> bool {
        self.upper[s] & TRIPLE != 0
    }

    /// Whether slice `s`'s lower entries name their pairs by full index.
    #[cfg(test)]
    pub fn has_far_refs(&self, s: usize) -> bool {
        self.upper[s] & FAR_REFS != 0
    }

    /// Number of slices.
    pub fn slices(&self) -> usize {
        self.start.len() - 1
    }

    /// The other end of entry `e`, in slice `s`.
    pub fn other(&self, s: usize, e: usize) -> u32 {
        match self.far_of(s) {
            Some(far) => far[e - self.start[s] as usize],
            None => {
                let offset = i32::from(self.near[e]) / if self.tripled(s) { 3 } else { 1 };
                ((s * LANES) as u32).wrapping_add_signed(offset)
            }
        }
    }

    /// The index in [`kr`](Self::kr) of the pair of entry `e`, in slice `s`.
    pub fn pair(&self, s: usize, e: usize) -> usize {
        if self.upper_entries(s).contains(&e) {
            return self.own_pair(s, e);
        }
        let r = e - self.start[s] as usize;
        let r = r - r % LANES + PAIR_LANES[r % LANES];
        match self.refs_of(s) {
            Refs::Near { refs, base } => (base + refs[r] as isize) as usize,
            Refs::Far { refs } => refs[r] as usize,
        }
    }

    /// The half-springs of vertex `i` in order (padding skipped).
    pub fn springs_of(&self, i: usize) -> impl Iterator<Item = Spring> + '_ {
        let (s, lane) = (i / LANES, i % LANES);
        self.entries(s)
            .skip(lane)
            .step_by(LANES)
            .filter(move |&e| self.other(s, e) as usize != i)
            .map(move |e| {
                let [k, rest] = self.kr[self.pair(s, e)];
                Spring {
                    other: self.other(s, e),
                    k: k.abs(),
                    rest,
                }
            })
    }

    /// The stiffness summed over each vertex's springs, for the eight vertices of slice `s` (one
    /// per lane; lanes past the last vertex mean nothing): the same f32 sums, in the same order,
    /// as [`springs_of`](Self::springs_of), read slice by slice (see
    /// [`stiffness_diagonal`](Self::stiffness_diagonal)).
    pub fn stiffness_sums(&self, s: usize) -> [f32; LANES] {
        let mut sums = [0.0f32; LANES];
        let (start, base) = (self.start[s] as usize, s * LANES);
        for e in self.entries(s) {
            let lane = (e - start) % LANES;
            if self.other(s, e) as usize != base + lane {
                sums[lane] += self.kr[self.pair(s, e)][0].abs();
            }
        }
        sums
    }

    /// [`stiffness_sums`](Self::stiffness_sums) of every slice, one per vertex (the
    /// preconditioner's spring part, kept with the system: summing it per solve cost ~0.3 ms
    /// of a 10k frame).
    pub fn stiffness_diagonal(&self) -> Vec<f32> {
        // Tasks of 128 slices (1,024 vertices): one per slice would cost more in hand-offs
        // than the sums.
        const SLICES: usize = 128;
        let mut diag = vec![0.0f32; self.n];
        diag.par_chunks_mut(SLICES * LANES)
            .enumerate()
            .for_each(|(c, chunk)| {
                for (j, d) in chunk.chunks_mut(LANES).enumerate() {
                    let sums = self.stiffness_sums(c * SLICES + j);
                    d.copy_from_slice(&sums[..d.len()]);
                }
            });
        diag
    }

    /// Back to CSR: `(offsets, springs)`.
    pub fn to_csr(&self) -> (Vec<u32>, Vec<Spring>) {
        let mut offsets = Vec::with_capacity(self.n + 1);
        let mut springs = Vec::new();
        offsets.push(0);
        for i in 0..self.n {
            springs.extend(self.springs_of(i));
            offsets.push(springs.len() as u32);
        }
        (offsets, springs)
    }

    /// Bytes held.
    pub fn bytes(&self) -> usize {
        (self.start.len() + self.upper.len() + self.low.len() + self.far_refs.len())
            * size_of::<u32>()
            + (self.near.len() + self.refs.len()) * size_of::<i16>()
            + self.kr.len() * size_of::<[f32; 2]>()
            + (self.wide.len() + self.wide_refs.len()) * size_of::<(u32, u32)>()
            + self.far.len() * size_of::<u32>()
    }
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;

    /// CSR half-springs of `edges` (each listed at both ends, sorted by the other end), with
    /// stiffness `k(edge)` and rest length `rest(edge)`.
    pub(in crate::solver) fn csr(
        n: usize,
        edges: &[[u32; 2]],
        k: impl Fn(usize) -> f32,
        rest: impl Fn(usize) -> f32,
    ) -> (Vec<u32>, Vec<Spring>) {
        let mut lists = vec![Vec::new(); n];
        for (e, &[a, b]) in edges.iter().enumerate() {
            for (from, to) in [(a, b), (b, a)] {
                lists[from as usize].push(Spring {
                    other: to,
                    k: k(e),
                    rest: rest(e),
                });
            }
        }
        let mut offsets = vec![0u32];
        let mut springs = Vec::new();
        for mut list in lists {
            list.sort_by_key(|s| s.other);
            springs.extend(list);
            offsets.push(springs.len() as u32);
        }
        (offsets, springs)
    }

    /// Checks what the kernels rely on: every upper entry holds its own spring's pair, every
    /// lower entry names a pair with its spring's values, and the pairs are in bounds.
    fn check_pairs(sell: &Sell, offsets: &[u32], springs: &[Spring]) {
        let (o2, s2) = sell.to_csr();
        assert_eq!(o2, offsets);
        assert_eq!(s2, springs);
        for s in 0..sell.slices() {
            let (lower, upper) = (sell.lower_entries(s), sell.upper_entries(s));
            assert_eq!(lower.end, upper.start);
            for e in sell.entries(s) {
                let lane = (e - sell.start[s] as usize) % LANES;
                let i = (s * LANES + lane).min(sell.n - 1);
                let j = sell.other(s, e) as usize;
                // Lower entries hold springs to lower vertices (or padding) only.
                assert!(upper.contains(&e) || j <= i, "slice {s} entry {e}");
                assert!(sell.pair(s, e) < sell.kr.len(), "slice {s} entry {e}");
                // The stiffness the kernels read is negative exactly for the copies an upper
                // slot holds of springs to lower vertices (all stiffnesses here are positive),
                // and the pairs the lower entries name are positive.
                if j != i {
                    let k = sell.kr[sell.pair(s, e)][0];
                    let copy = upper.contains(&e) && j < i;
                    assert_eq!(k.is_sign_negative(), copy, "slice {s} entry {e}");
                }
            }
            // The slice's stiffness sums are its vertices' springs summed in their CSR order,
            // bit for bit.
            for (lane, sum) in sell.stiffness_sums(s).into_iter().enumerate() {
                let i = s * LANES + lane;
                if i < sell.n {
                    let own = &springs[offsets[i] as usize..offsets[i + 1] as usize];
                    let expected = own.iter().fold(0.0f32, |a, sp| a + sp.k);
                    assert_eq!(sum.to_bits(), expected.to_bits(), "vertex {i}");
                }
            }
        }
        // The diagonal kept with a system: one sum per vertex, the same bits.
        let diagonal = sell.stiffness_diagonal();
        assert_eq!(diagonal.len(), sell.n);
        for (i, d) in diagonal.iter().enumerate() {
            let own = &springs[offsets[i] as usize..offsets[i + 1] as usize];
            let expected = own.iter().fold(0.0f32, |a, sp| a + sp.k);
            assert_eq!(d.to_bits(), expected.to_bits(), "vertex {i}");
        }
    }

    #[test]
    fn round_trips_csr_with_uneven_degrees() {
        // 11 vertices (a partial last slice), uneven degrees, and two parallel springs between
        // vertices 2 and 3 with different stiffness.
        let mut edges = vec![[2, 3]];
        for i in 0..11u32 {
            for d in 0..i % 5 {
                edges.push([i, (i + d + 1) % 11]);
            }
        }
        let n = 11;
        let (offsets, springs) = csr(n, &edges, |e| e as f32 + 0.5, |e| (e % 3) as f32);
        let sell = Sell::from_csr(&offsets, &springs).unwrap();
        assert_eq!(sell.slices(), 2);
        let degree = |i: usize| (offsets[i + 1] - offsets[i]) as usize;
        let width = (0..8).map(degree).max().unwrap();
        assert!(width > (0..8).map(degree).min().unwrap());
        assert_eq!(sell.entries(0), 0..8 * width);
        check_pairs(&sell, &offsets, &springs);
        // One pair per upper entry, none for the lower ones: fewer pairs than entries.
        let upper: usize = (0..2).map(|s| sell.upper_entries(s).len()).sum();
        assert_eq!(sell.kr.len(), upper);
        assert!(sell.kr.len() < sell.near.len());
        assert_eq!(sell.refs.len(), sell.near.len() - sell.kr.len());
        // The last slice names the last vertex: it keeps full indices, from the start of `far`.
        assert_eq!(sell.wide, vec![(1, 0)]);
        // Every spring to a higher vertex lies in its slice's upper entries, and holds its own
        // pair there.
        for s in 0..sell.slices() {
            for e in sell.entries(s) {
                let i = (s * LANES + (e - sell.start[s] as usize) % LANES).min(10);
                if sell.other(s, e) as usize > i {
                    assert!(sell.upper_entries(s).contains(&e), "entry {e}");
                }
            }
        }
    }

    #[test]
    fn upper_pairs_are_in_lane_order_after_the_shuffle() {
        // A chain: every vertex has one spring up, with stiffness its index.
        let n = 64;
        let edges: Vec<[u32; 2]> = (0..n - 1).map(|i| [i, i + 1]).collect();
        let (offsets, springs) = csr(n as usize, &edges, |e| e as f32, |_| 1.0);
        let sell = Sell::from_csr(&offsets, &springs).unwrap();
        check_pairs(&sell, &offsets, &springs);
        for s in 0..sell.slices() - 1 {
            // The upper slot is the last one; lane `l`'s pair at position PAIR_LANES[l].
            let (upper, p) = sell.upper_pairs(s);
            assert_eq!(upper.len(), LANES);
            for (l, position) in PAIR_LANES.iter().enumerate() {
                assert_eq!(sell.kr[p + position][0], (s * LANES + l) as f32);
            }
        }
    }

    #[test]
    fn far_neighbours_keep_full_indices() {
        // 40 000 vertices in a chain, plus springs from the first slice to the far end: the
        // first and last slices are wide, the others near.
        let n = 40_000u32;
        let mut edges: Vec<[u32; 2]> = (0..n - 1).map(|i| [i, i + 1]).collect();
        edges.extend([[0, n - 1], [3, n - 20], [7, 32_000]]);
        let (offsets, springs) = csr(n as usize, &edges, |e| e as f32, |_| 1.0);
        let sell = Sell::from_csr(&offsets, &springs).unwrap();
        let wide: Vec<u32> = sell.wide.iter().map(|w| w.0).collect();
        // Slice 0 reaches n - 1 (wide); the slice of n - 20 and the last slice reach 3 and 0
        // (wide); the slice of 32 000 reaches 7 (offset -31 993, still near). Only the last
        // slice names the last vertex along the chain (it holds it).
        let last = (n as usize).div_ceil(LANES) as u32 - 1;
        assert_eq!(wide, vec![0, (n - 20) / 8, last]);
        assert!(sell.far_of(32_000 / 8).is_none());
        // Its offset (-31 993) is too far to store times three; the chain's slices, whose
        // neighbours are within a few vertices, store theirs tripled.
        assert!(!sell.tripled(32_000 / 8));
        assert!(sell.tripled(10) && sell.tripled(32_000 / 8 + 1));
        let s = 10;
        for e in sell.entries(s) {
            let lane = (e - sell.start[s] as usize) % LANES;
            let i = (s * LANES + lane) as i32;
            let o = sell.other(s, e) as i32;
            assert_eq!(i32::from(sell.near[e]), 3 * (o - s as i32 * LANES as i32));
            assert!((o - i).abs() <= 1, "entry {e}");
        }
        check_pairs(&sell, &offsets, &springs);
    }

    #[test]
    fn far_twins_are_named_by_full_index() {
        // A band of 100 000 vertices (springs to the next three: three pairs per vertex) and
        // springs 30 000 vertices long: a 16-bit offset reaches their other end, but a 16-bit
        // reference back (65 535 pairs, about 22 000 vertices) does not reach their twin's pair.
        let n = 100_000u32;
        let mut edges: Vec<[u32; 2]> = (1..4)
            .flat_map(|d| (0..n - d).map(move |i| [i, i + d]))
            .collect();
        edges.extend((0..20).map(|i| [1000 + i * 101, 31_000 + i * 101]));
        let (offsets, springs) = csr(n as usize, &edges, |e| 1.0 + e as f32, |e| e as f32);
        let sell = Sell::from_csr(&offsets, &springs).unwrap();
        let s = (31_000 + 5 * 101) / LANES;
        assert!(sell.has_far_refs(s) && sell.far_of(s).is_none());
        assert!(!sell.has_far_refs(s - 1) && !sell.has_far_refs(10));
        assert_eq!(sell.wide_refs.len(), 20);
        check_pairs(&sell, &offsets, &springs);
    }
}
