//! Vertex renumbering for memory locality.

use glam::Vec3;
use sprs::CsMatViewI;
use sprs::linalg::ordering::{cuthill_mckee_custom, order::Reversed, start::Strategy};

/// A permutation of the vertices that keeps the two ends of every spring close in memory:
/// `order[i]` is the original index of the `i`-th vertex in the new order. This is the order
/// [`SpringSystem`](super::SpringSystem) relaxes in.
///
/// It is the reverse Cuthill-McKee order of the spring graph ([`sprs`]'s, from a
/// pseudo-peripheral vertex of each connected part, each vertex's new neighbours by increasing
/// degree; the time is linear in the springs, whatever the number of parts): the vertices
/// in breadth-first levels, so a spring joins two vertices of the same or adjacent levels: at
/// most two levels' width apart, about `√n` positions on a roughly square surface of `n`
/// vertices, a ring and a half on a skin tube. That keeps the neighbours a pass over the
/// vertices reads within a window that fits the core's cache, where a
/// [Morton curve](morton_order) of the positions leaves some springs spanning a sixth of the
/// mesh (the relaxation 1.15-1.31x as fast at 100k vertices, 1.35-1.62x at 1M; session 21).
///
/// The graph is labelled along the Morton curve first, and the algorithm breaks its ties (the
/// starting vertex of each connected part, neighbours of equal degree) by that label: the result
/// depends on the positions and springs, not on how the input numbered its vertices, and is
/// deterministic. Edges with an end out of range or both ends equal are ignored, as are repeats.
///
/// ```
/// use dermis::solver::bandwidth_order;
/// use glam::Vec3;
/// // A chain 0 - 2 - 1 - 3 listed out of order: the order walks the chain.
/// let p = [Vec3::ZERO, Vec3::new(2.0, 0.0, 0.0), Vec3::X, Vec3::new(3.0, 0.0, 0.0)];
/// let order = bandwidth_order(&p, &[[0, 2], [2, 1], [1, 3]]);
/// assert!(order == [3, 1, 2, 0] || order == [0, 2, 1, 3]);
/// ```
pub fn bandwidth_order(positions: &[Vec3], edges: &[[u32; 2]]) -> Vec<u32> {
    let n = positions.len();
    by_graph(positions, edges, |graph| {
        cuthill_mckee_custom(graph, Peripheral::new(n), Reversed::new())
            .perm
            .vec()
    })
}

/// The rows of the symmetric graph of `pairs` (both ends below `n`) in compressed form: the
/// `k`-th pair `(a, b)` puts `entry(b, k)` in row `a` and `entry(a, k)` in row `b`, each row
/// in the pairs' order. Returns the `n + 1` row offsets and the entries (`blank` only holds
/// their places while they are filled).
pub(super) fn symmetric_rows<E: Copy>(
    n: usize,
    pairs: impl Iterator<Item = (u32, u32)> + Clone,
    blank: E,
    mut entry: impl FnMut(u32, usize) -> E,
) -> (Vec<usize>, Vec<E>) {
    let mut offsets = vec![0usize; n + 1];
    for (a, b) in pairs.clone() {
        offsets[a as usize + 1] += 1;
        offsets[b as usize + 1] += 1;
    }
    for i in 0..n {
        offsets[i + 1] += offsets[i];
    }
    let mut fill = offsets[..n].to_vec();
    let mut entries = vec![blank; offsets[n]];
    for (k, (a, b)) in pairs.enumerate() {
        for (from, to) in [(a, b), (b, a)] {
            let slot = &mut fill[from as usize];
            entries[*slot] = entry(to, k);
            *slot += 1;
        }
    }
    (offsets, entries)
}

/// The order `order_graph` gives the spring graph labelled along the Morton curve (from
/// label `i`: the Morton order's `i`-th vertex), in the input's numbering.
fn by_graph(
    positions: &[Vec3],
    edges: &[[u32; 2]],
    order_graph: impl FnOnce(CsMatViewI<'_, (), u32, usize>) -> Vec<u32>,
) -> Vec<u32> {
    let n = positions.len();
    let morton = morton_order(positions);
    let mut label = vec![0u32; n];
    for (i, &o) in morton.iter().enumerate() {
        label[o as usize] = i as u32;
    }
    // The symmetric adjacency in compressed rows, by Morton label, each row sorted once.
    let valid = edges
        .iter()
        .filter(|&&[a, b]| a != b && (a as usize) < n && (b as usize) < n)
        .map(|&[a, b]| (label[a as usize], label[b as usize]));
    let (mut indptr, mut indices) = symmetric_rows(n, valid, 0u32, |to, _| to);
    // Sort each row and drop repeated edges, compacting in place.
    let mut kept = 0;
    for i in 0..n {
        let (start, end) = (indptr[i], indptr[i + 1]);
        indices[start..end].sort_unstable();
        indptr[i] = kept;
        let mut last = None;
        for k in start..end {
            let v = indices[k];
            if last != Some(v) {
                indices[kept] = v;
                kept += 1;
                last = Some(v);
            }
        }
    }
    indptr[n] = kept;
    indices.truncate(kept);
    let data = vec![(); kept];
    match CsMatViewI::<(), u32, usize>::try_new((n, n), &indptr, &indices, &data) {
        Ok(graph) => order_graph(graph)
            .into_iter()
            .map(|l| morton[l as usize])
            .collect(),
        // Not reached (the rows are sorted and in range); the Morton order is a valid answer.
        Err(_) => morton,
    }
}

/// sprs's pseudo-peripheral starting vertex for each connected part (George and Liu: the
/// lowest-degree vertex of the last level of a breadth-first search, searched again from there
/// while the number of levels grows; the first unvisited vertex by label to begin with), with
/// its buffers kept from one part to the next. sprs's own strategy allocates and scans buffers
/// of all `n` vertices for every part: a mesh of 100,000 separate triangles took 10.6 s.
struct Peripheral {
    /// No vertex below it is left unvisited.
    next: usize,
    /// The number of the search that last reached each vertex.
    reached: Vec<u32>,
    /// The current search's number.
    search: u32,
    /// The current search's vertices, level by level.
    queue: Vec<usize>,
}

impl Peripheral {
    fn new(n: usize) -> Self {
        Self {
            next: 0,
            reached: vec![0; n],
            search: 0,
            queue: Vec::new(),
        }
    }

    /// The breadth-first levels from `root`: the first vertex of least degree in the last
    /// level, and the number of levels.
    fn levels(
        &mut self,
        root: usize,
        degrees: &[usize],
        graph: &CsMatViewI<'_, (), u32, usize>,
    ) -> (usize, usize) {
        if self.search == u32::MAX {
            self.reached.fill(0);
            self.search = 0;
        }
        self.search += 1;
        let search = self.search;
        self.queue.clear();
        self.queue.push(root);
        self.reached[root] = search;
        let (mut start, mut height, mut last) = (0, 0, 0..1);
        while start < self.queue.len() {
            let end = self.queue.len();
            for i in start..end {
                let Some(row) = graph.outer_view(self.queue[i]) else {
                    continue;
                };
                for &w in row.indices() {
                    let w = w as usize;
                    if self.reached[w] != search {
                        self.reached[w] = search;
                        self.queue.push(w);
                    }
                }
            }
            last = start..end;
            start = end;
            height += 1;
        }
        let contender = self.queue[last]
            .iter()
            .copied()
            .min_by_key(|&v| degrees[v])
            .unwrap_or(root);
        (contender, height)
    }
}

impl Strategy<(), u32, usize> for Peripheral {
    fn find_start_vertex(
        &mut self,
        visited: &[bool],
        degrees: &[usize],
        graph: &CsMatViewI<'_, (), u32, usize>,
    ) -> usize {
        // sprs calls this only while some vertex is unvisited, and never unvisits one.
        while visited[self.next] {
            self.next += 1;
        }
        let mut current = self.next;
        if degrees[current] == 0 {
            return current;
        }
        let (mut contender, mut height) = self.levels(current, degrees, graph);
        loop {
            let (next, next_height) = self.levels(contender, degrees, graph);
            if next_height <= height {
                return current;
            }
            (current, contender, height) = (contender, next, next_height);
        }
    }
}

/// A permutation of the vertices along a Morton (Z-order) curve of their positions:
/// `order[i]` is the original index of the `i`-th vertex in the new order.
///
/// Vertices close in space end up close in memory. Ties (and non-finite positions) keep their
/// original relative order, so the result is deterministic. [`bandwidth_order`] starts from it
/// and keeps every spring's ends closer still.
///
/// ```
/// use dermis::solver::morton_order;
/// use glam::Vec3;
/// let p = [Vec3::new(1.0, 1.0, 0.0), Vec3::ZERO, Vec3::new(1.0, 0.0, 0.0)];
/// assert_eq!(morton_order(&p), vec![1, 2, 0]);
/// ```
pub fn morton_order(positions: &[Vec3]) -> Vec<u32> {
    let finite = positions.iter().filter(|p| p.is_finite());
    let (lo, hi) = finite.fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), p| {
        (lo.min(*p), hi.max(*p))
    });
    let extent = (hi - lo).max_element();
    let scale = if extent > 0.0 {
        2_097_151.0 / extent
    } else {
        0.0
    };
    let mut keyed: Vec<(u64, u32)> = positions
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let q = ((*p - lo) * scale).clamp(Vec3::ZERO, Vec3::splat(2_097_151.0));
            let code = if p.is_finite() {
                spread(q.x as u64) | (spread(q.y as u64) << 1) | (spread(q.z as u64) << 2)
            } else {
                u64::MAX
            };
            (code, i as u32)
        })
        .collect();
    keyed.sort_unstable();
    keyed.into_iter().map(|(_, i)| i).collect()
}

/// Spreads the low 21 bits of `v` to every third bit.
fn spread(v: u64) -> u64 {
    let mut x = v & 0x1f_ffff;
    x = (x | (x << 32)) & 0x1f00000000ffff;
    x = (x | (x << 16)) & 0x1f0000ff0000ff;
    x = (x | (x << 8)) & 0x100f00f00f00f00f;
    x = (x | (x << 4)) & 0x10c30c30c30c30c3;
    x = (x | (x << 2)) & 0x1249249249249249;
    x
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn symmetric_rows_list_each_pair_in_both_rows_in_pair_order() {
        // Pairs 0: (2, 0), 1: (0, 1), 2: (2, 0) again, 3: (3, 2); vertex 4 has none. Each
        // entry is (other end, pair).
        let pairs = [(2, 0), (0, 1), (2, 0), (3, 2)];
        let (offsets, entries) = symmetric_rows(5, pairs.iter().copied(), (9, 9), |to, k| (to, k));
        assert_eq!(offsets, [0, 3, 4, 7, 8, 8]);
        let rows: Vec<&[(u32, usize)]> = offsets.windows(2).map(|w| &entries[w[0]..w[1]]).collect();
        assert_eq!(rows[0], [(2, 0), (1, 1), (2, 2)]);
        assert_eq!(rows[1], [(0, 1)]);
        assert_eq!(rows[2], [(0, 0), (0, 2), (3, 3)]);
        assert_eq!(rows[3], [(2, 3)]);
        assert!(rows[4].is_empty());
    }

    #[test]
    fn is_a_permutation_and_groups_neighbours() {
        // A 16x16 grid listed in a scrambled order.
        let mut p = Vec::new();
        for k in 0..256u32 {
            let s = (k * 97) % 256;
            p.push(Vec3::new((s % 16) as f32, (s / 16) as f32, 0.0));
        }
        let order = morton_order(&p);
        let mut seen = order.clone();
        seen.sort_unstable();
        assert_eq!(seen, (0..256).collect::<Vec<_>>());
        // Consecutive vertices in Morton order are close on average (a random order averages ~7).
        let mean: f32 = order
            .windows(2)
            .map(|w| p[w[0] as usize].distance(p[w[1] as usize]))
            .sum::<f32>()
            / 255.0;
        assert!(mean < 2.0, "mean step {mean}");
        assert_eq!(spread(0b111), 0b1001001);
    }

    /// `rank[v]`: the position of vertex `v` in `order`, after checking it is a permutation.
    fn ranks(order: &[u32]) -> Vec<usize> {
        let mut rank = vec![usize::MAX; order.len()];
        for (i, &v) in order.iter().enumerate() {
            assert_eq!(rank[v as usize], usize::MAX, "vertex {v} listed twice");
            rank[v as usize] = i;
        }
        rank
    }

    /// A tube of `around x along` vertices numbered in a scrambled order: its positions and
    /// edges, and `scramble[v]`, the tube's own number of vertex `v`.
    fn scrambled_tube(around: u32, along: u32, key: u64) -> (Vec<Vec3>, Vec<[u32; 2]>, Vec<u32>) {
        let mesh = crate::mesh::shapes::tube(around, along, 0.05, 0.4);
        let n = mesh.positions().len();
        let mut scramble: Vec<u32> = (0..n as u32).collect();
        scramble.sort_by_key(|&v| (u64::from(v) * key) % 1_000_003);
        let mut new_of = vec![0u32; n];
        for (new, &old) in scramble.iter().enumerate() {
            new_of[old as usize] = new as u32;
        }
        let positions = scramble
            .iter()
            .map(|&o| mesh.positions()[o as usize])
            .collect();
        let edges = mesh
            .topology()
            .edges()
            .iter()
            .map(|&[a, b]| [new_of[a as usize], new_of[b as usize]])
            .collect();
        (positions, edges, scramble)
    }

    #[test]
    fn bandwidth_order_keeps_every_spring_within_two_rings_of_a_tube() {
        // Breadth-first levels from one end of a tube are about a ring and a half wide, and a
        // spring joins adjacent levels: no spring spans more than two rings of positions,
        // however the input numbered the vertices. (The Morton curve's farthest spring spans
        // about a sixth of this tube, more than six rings.)
        let (around, along) = (24, 40);
        let (p, edges, _) = scrambled_tube(around, along, 7919);
        let rank = ranks(&bandwidth_order(&p, &edges));
        let span = |rank: &[usize]| {
            edges
                .iter()
                .map(|&[a, b]| rank[a as usize].abs_diff(rank[b as usize]))
                .max()
                .unwrap()
        };
        assert!(span(&rank) <= 2 * around as usize, "span {}", span(&rank));
        assert!(span(&ranks(&morton_order(&p))) > 4 * around as usize);
    }

    #[test]
    fn bandwidth_order_does_not_depend_on_the_input_numbering() {
        let (p1, e1, s1) = scrambled_tube(16, 30, 7919);
        let (p2, e2, s2) = scrambled_tube(16, 30, 104_729);
        let o1: Vec<u32> = bandwidth_order(&p1, &e1)
            .iter()
            .map(|&v| s1[v as usize])
            .collect();
        let o2: Vec<u32> = bandwidth_order(&p2, &e2)
            .iter()
            .map(|&v| s2[v as usize])
            .collect();
        assert_eq!(o1, o2);
    }

    #[test]
    fn bandwidth_order_is_sprs_reverse_cuthill_mckee() {
        // The starting vertices found with buffers kept across parts are those of sprs's own
        // strategy: the same order, on a tube and on many separate parts.
        let (p, edges, _) = scrambled_tube(24, 40, 7919);
        let (q, more) = separate_triangles(300);
        // A 30 x 30 grid with each cell's diagonal one way or the other (degrees 2 to 8),
        // its positions unrelated to its springs.
        let side = 30u32;
        let at = |i: u32, j: u32| i * side + j;
        let mut grid = Vec::new();
        for i in 0..side {
            for j in 0..side {
                if j + 1 < side {
                    grid.push([at(i, j), at(i, j + 1)]);
                }
                if i + 1 < side {
                    grid.push([at(i, j), at(i + 1, j)]);
                    if j + 1 < side {
                        grid.push(if (i * 7 + j * 13) % 5 < 2 {
                            [at(i, j), at(i + 1, j + 1)]
                        } else {
                            [at(i, j + 1), at(i + 1, j)]
                        });
                    }
                }
            }
        }
        // Its first vertex by label is the grid's middle (offset 15) or the middle of a side
        // (offset 450).
        let spread = |offset: u32| -> Vec<Vec3> {
            (0..side * side)
                .map(|v| {
                    let s = (v * 389 + offset) % (side * side);
                    Vec3::new((s % side) as f32, (s / side) as f32, 0.0)
                })
                .collect()
        };
        let (middle, rim) = (spread(15), spread(450));
        for (p, edges) in [(&p, &edges), (&q, &more), (&middle, &grid), (&rim, &grid)] {
            let sprs_order = by_graph(p, edges, |graph| {
                sprs::linalg::reverse_cuthill_mckee(graph).perm.vec()
            });
            assert_eq!(bandwidth_order(p, edges), sprs_order);
        }
    }

    /// `triangles` separate triangles (vertices `t`, `t + triangles`, `t + 2 triangles`) and
    /// two isolated vertices, their positions interleaved.
    fn separate_triangles(triangles: u32) -> (Vec<Vec3>, Vec<[u32; 2]>) {
        let n = 3 * triangles + 2;
        let part = |v: u32| if v < 3 * triangles { v % triangles } else { v };
        let p = (0..n)
            .map(|v| Vec3::new(part(v) as f32, (v / triangles) as f32 * 0.1, 0.0))
            .collect();
        let edges = (0..triangles)
            .flat_map(|t| {
                let [a, b, c] = [t, t + triangles, t + 2 * triangles];
                [[a, b], [b, c], [c, a]]
            })
            .collect();
        (p, edges)
    }

    #[test]
    fn bandwidth_order_lists_each_connected_part_in_one_run() {
        // 40 separate triangles, two isolated vertices, a repeated edge, a loop and an edge out
        // of range (ignored), listed in an interleaved order.
        let triangles = 40u32;
        let n = 3 * triangles + 2;
        let (p, mut edges) = separate_triangles(triangles);
        edges.extend([[0, triangles], [5, 5], [7, n + 3]]);
        assert!(bandwidth_order(&[], &[]).is_empty());
        assert_eq!(bandwidth_order(&[Vec3::ZERO], &[[0, 0]]), [0]);
        let order = bandwidth_order(&p, &edges);
        let rank = ranks(&order);
        assert!(rank.iter().all(|&r| r < n as usize));
        for t in 0..triangles {
            let mut r = [t, t + triangles, t + 2 * triangles].map(|v| rank[v as usize]);
            r.sort_unstable();
            assert_eq!(r[2] - r[0], 2, "triangle {t} split: {r:?}");
        }
    }
}
