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

use super::Spring;

/// Vertices per slice (the SIMD width of the kernels).
pub(crate) const LANES: usize = 8;

/// The half-springs of every vertex, in slices of [`LANES`] vertices.
#[derive(Debug, Clone, Default)]
pub(crate) struct Sell {
    /// Number of vertices.
    pub n: usize,
    /// Start of each slice's entries (`slices + 1` values, multiples of [`LANES`]).
    pub start: Vec<u32>,
    /// Per slice, the first entry from which some lane has a spring to a higher vertex.
    pub upper: Vec<u32>,
    /// The vertex at the other end (the vertex itself for padding).
    pub other: Vec<u32>,
    /// Stiffness, N/m (0 for padding).
    pub k: Vec<f32>,
    /// Rest length, m (0 for padding).
    pub rest: Vec<f32>,
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
        let mut other = vec![0u32; total];
        let mut k = vec![0.0f32; total];
        let mut rest = vec![0.0f32; total];
        let mut upper = Vec::with_capacity(slices);
        for s in 0..slices {
            let (begin, end) = (start[s] as usize, start[s + 1] as usize);
            let width = (end - begin) / LANES;
            let mut first_upper = width;
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
                        Some(sp) => (other[e], k[e], rest[e]) = (sp.other, sp.k, sp.rest),
                        None => other[e] = i as u32,
                    }
                }
            }
            upper.push((begin + first_upper * LANES) as u32);
        }
        Self {
            n,
            start,
            upper,
            other,
            k,
            rest,
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
        self.upper[s] as usize..self.start[s + 1] as usize
    }

    /// Number of slices.
    pub fn slices(&self) -> usize {
        self.start.len() - 1
    }

    /// The half-springs of vertex `i` in order (padding skipped).
    pub fn springs_of(&self, i: usize) -> impl Iterator<Item = Spring> + '_ {
        let (s, lane) = (i / LANES, i % LANES);
        self.entries(s)
            .skip(lane)
            .step_by(LANES)
            .filter(move |&e| self.other[e] as usize != i)
            .map(|e| Spring {
                other: self.other[e],
                k: self.k[e],
                rest: self.rest[e],
            })
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
        (self.start.len() + self.upper.len()) * 4 + self.other.len() * 12
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
        assert_eq!(sell.other.len(), 32 + 32);
        // Every spring to a higher vertex lies in its slice's upper entries.
        for s in 0..sell.slices() {
            for e in sell.entries(s) {
                let i = (s * LANES + (e - sell.start[s] as usize) % LANES).min(10);
                if sell.other[e] as usize > i {
                    assert!(sell.upper_entries(s).contains(&e), "entry {e}");
                }
            }
        }
    }
}
