//! Sliced ELLPACK storage of the half-springs: eight vertices per slice, one slot per spring.
//!
//! Each slice of [`LANES`] consecutive (internal) vertices is padded to the largest degree among
//! them and stored slot-major: entry `slot * LANES + lane` of the slice is the `slot`-th spring
//! of vertex `8 * slice + lane`. One SIMD load then reads one spring of eight vertices, so the
//! kernels never shuffle lanes. Each vertex's springs are right-aligned in its lane (padding
//! first), so the springs to higher-numbered vertices, which carry the energy and the
//! curvature, sit in the last slots of every slice: the kernels visit only those slots for them.
//! Padding entries point at the vertex itself with zero stiffness and rest length (a real spring
//! never joins a vertex to itself), and contribute nothing.
//!
//! The other end of a spring is stored as a 16-bit offset from the slice's first vertex
//! (vertices are in Morton order, so almost every neighbour is near), times three when all of
//! the slice's offsets allow it ("tripled": the float offset of the neighbour's position, which
//! the kernels use as an address without a multiplication); a slice with a neighbour
//! farther than that ("wide", flagged in [`Sell::upper`]) keeps full 32-bit indices in
//! [`Sell::far`] instead. So does every slice that names the last vertex (the last slice and
//! its neighbours): the kernels read a vertex as 16 bytes, one float past its own, which they
//! may do without a check in the near slices only.

use super::Spring;

/// Vertices per slice (the SIMD width of the kernels).
pub(crate) const LANES: usize = 8;

/// Flag bit of [`Sell::upper`]: the slice's other ends are in [`Sell::far`].
const WIDE: u32 = 1 << 31;

/// Flag bit of [`Sell::upper`]: the slice's offsets in [`Sell::near`] are stored times three
/// (the float offset of the other end's row, which the kernels use as an address directly).
const TRIPLE: u32 = 1 << 30;

/// The half-springs of every vertex, in slices of [`LANES`] vertices.
#[derive(Debug, Clone, Default)]
pub(crate) struct Sell {
    /// Number of vertices.
    pub n: usize,
    /// Start of each slice's entries (`slices + 1` values, multiples of [`LANES`]).
    pub start: Vec<u32>,
    /// Per slice, the first entry from which some lane has a spring to a higher vertex, with
    /// the top bit set for a wide slice and the next one for a tripled slice.
    pub upper: Vec<u32>,
    /// The vertex at the other end (the vertex itself for padding), minus the slice's first
    /// vertex (0 in wide slices; times three in tripled slices).
    pub near: Vec<i16>,
    /// Stiffness, N/m (0 for padding).
    pub k: Vec<f32>,
    /// Rest length, m (0 for padding).
    pub rest: Vec<f32>,
    /// `(slice, offset)` of each wide slice, by slice: its entries' other ends are
    /// `far[offset..offset + entries]`.
    pub wide: Vec<(u32, u32)>,
    /// The other ends of the wide slices' entries.
    pub far: Vec<u32>,
}

impl Sell {
    /// The layout of CSR half-springs (`springs[offsets[i]..offsets[i + 1]]` for vertex `i`),
    /// keeping each vertex's springs in their CSR order.
    pub fn from_csr(offsets: &[u32], springs: &[Spring]) -> Self {
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
        let mut near = vec![0i16; total];
        let mut k = vec![0.0f32; total];
        let mut rest = vec![0.0f32; total];
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
                let own = &springs[offsets[i] as usize..offsets[i + 1] as usize];
                let own = if s * LANES + lane < n { own } else { &[] };
                let pad = width - own.len();
                // CSR springs are sorted by their other end: the upper ones are a suffix.
                let lower = own.partition_point(|sp| (sp.other as usize) < i);
                if lower < own.len() {
                    first_upper = first_upper.min(pad + lower);
                }
                for (slot, e) in (begin + lane..end).step_by(LANES).enumerate() {
                    match slot.checked_sub(pad).map(|o| own[o]) {
                        Some(sp) => (other[e - begin], k[e], rest[e]) = (sp.other, sp.k, sp.rest),
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
                // Times three when every offset allows it (and the flag bit is free).
                let triple = end < TRIPLE as usize
                    && other
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
        Self {
            n,
            start,
            upper,
            near,
            k,
            rest,
            wide,
            far,
        }
    }

    /// The entries of slice `s`: `start..end`, in steps of [`LANES`].
    #[inline(always)]
    pub fn entries(&self, s: usize) -> std::ops::Range<usize> {
        self.start[s] as usize..self.start[s + 1] as usize
    }

    /// The entries of slice `s` from which some lane has a spring to a higher vertex.
    #[inline(always)]
    pub fn upper_entries(&self, s: usize) -> std::ops::Range<usize> {
        (self.upper[s] & !(WIDE | TRIPLE)) as usize..self.start[s + 1] as usize
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

    /// The half-springs of vertex `i` in order (padding skipped).
    pub fn springs_of(&self, i: usize) -> impl Iterator<Item = Spring> + '_ {
        let (s, lane) = (i / LANES, i % LANES);
        self.entries(s)
            .skip(lane)
            .step_by(LANES)
            .map(move |e| Spring {
                other: self.other(s, e),
                k: self.k[e],
                rest: self.rest[e],
            })
            .filter(move |sp| sp.other as usize != i)
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
        (self.start.len() + self.upper.len() + self.k.len() + self.rest.len() + self.far.len()) * 4
            + self.near.len() * 2
            + self.wide.len() * 8
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trips_csr_with_uneven_degrees() {
        // 11 vertices (a partial last slice), degrees 0..=4.
        let mut offsets = vec![0u32];
        let mut springs = Vec::new();
        for i in 0..11u32 {
            let first = springs.len();
            for d in 0..i % 5 {
                springs.push(Spring {
                    other: (i + d + 1) % 11,
                    k: i as f32 + 0.5,
                    rest: d as f32,
                });
            }
            // As in the solver: each vertex's springs sorted by their other end.
            springs[first..].sort_by_key(|s| s.other);
            offsets.push(springs.len() as u32);
        }
        let sell = Sell::from_csr(&offsets, &springs);
        assert_eq!(sell.slices(), 2);
        // Slice 0 holds degrees 0,1,2,3,4,0,1,2: width 4.
        assert_eq!(sell.entries(0), 0..32);
        let (o2, s2) = sell.to_csr();
        assert_eq!(o2, offsets);
        assert_eq!(s2, springs);
        // Padding is inert: zero stiffness (these sums are exact: halves of small integers).
        let total: f32 = springs.iter().map(|s| s.k).sum();
        assert_eq!(sell.k.iter().sum::<f32>(), total);
        assert_eq!(sell.near.len(), 32 + 32);
        // Only the last slice names the last vertex (10 is a neighbour of 9 alone): it keeps
        // full indices, from the start of `far`.
        assert_eq!(sell.wide, vec![(1, 0)]);
        // Every spring to a higher vertex lies in its slice's upper entries.
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
    fn far_neighbours_keep_full_indices() {
        // 40 000 vertices in a chain, plus springs from the first slice to the far end: the
        // first and last slices are wide, the others near.
        let n = 40_000u32;
        let mut edges: Vec<[u32; 2]> = (0..n - 1).map(|i| [i, i + 1]).collect();
        edges.extend([[0, n - 1], [3, n - 20], [7, 32_000]]);
        let mut lists = vec![Vec::new(); n as usize];
        for (e, &[a, b]) in edges.iter().enumerate() {
            for (from, to) in [(a, b), (b, a)] {
                lists[from as usize].push(Spring {
                    other: to,
                    k: e as f32,
                    rest: 1.0,
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
        let sell = Sell::from_csr(&offsets, &springs);
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
        let (o2, s2) = sell.to_csr();
        assert_eq!(o2, offsets);
        assert_eq!(s2, springs);
    }
}
