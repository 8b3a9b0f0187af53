//! A deforming mesh's BVH cut into subtrees, searched as one tree, each subtree refitted only
//! when a search first enters it after the mesh moved.

use glam::Vec3;
use parry3d::bounding_volume::{Aabb, BoundingVolume};
use parry3d::partitioning::{Bvh, BvhNode, BvhNodeIndex, TraversalAction};
use parry3d::shape::TriMesh as ParryMesh;
use rayon::prelude::*;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Mutex, OnceLock, PoisonError};
use std::time::Instant;

/// Largest part: a subtree with more triangles is split (where both of its children have more
/// than one triangle). A mesh up to this size is one part, refitted whole when it moves; the
/// parts of a larger one are refitted only when a search enters them, so the smaller the parts
/// the less of a mesh far from the skin is refitted, and the more top levels a search visits.
/// The bench's 50k-triangle muscle is in 80 parts (the choice measured in `benches/README.md`,
/// session 11: 512 / 1024 / 2048 / 4096).
pub(crate) const PART_TRIANGLES: usize = 1024;

/// Triangles of one subtree, as a parry mesh over their own vertices.
///
/// A part of a split mesh holds its mesh in one of two states: fitted to the mesh's live
/// vertices (`fitted`), or awaiting its refit (`stale`) since the vertices last moved. A move
/// refits at once the parts a search entered since the move before (`used`); the others wait,
/// and the first search to enter one refits it (parry's refit: the BVH depends only on the
/// vertices it is fitted to, so a part refitted late, by any thread, is the part refitted at
/// once). Its box is kept current at every move: the top levels prune with it.
#[derive(Debug)]
pub(super) struct Part {
    /// The part's triangles over part-local vertices, without `ORIENTED`, fitted to the live
    /// vertices (unset while the refit waits).
    fitted: OnceLock<ParryMesh>,
    /// The same mesh while its refit waits (`None` while `fitted` is set).
    stale: Mutex<Option<ParryMesh>>,
    /// The box of the part's vertices at the live vertices: parry's root box of the refitted
    /// BVH, bit for bit (min and max are exact).
    aabb: Aabb,
    /// A search entered the part since it last moved: the next move refits it at once.
    used: AtomicBool,
    /// Part-local vertex → mesh vertex (empty: the identity, a part holding the whole mesh).
    vertices: Vec<u32>,
    /// Part-local triangle → mesh triangle (empty: the identity).
    triangles: Vec<u32>,
}

impl Clone for Part {
    fn clone(&self) -> Self {
        let stale = self
            .stale
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .clone();
        // Neither state: a search on another thread is refitting the part (it took the stale
        // mesh); the clone waits for that refit.
        let fitted = match (&stale, self.fitted.get()) {
            (_, Some(mesh)) => OnceLock::from(mesh.clone()),
            (Some(_), None) => OnceLock::new(),
            (None, None) => OnceLock::from(self.fitted.wait().clone()),
        };
        Self {
            fitted,
            stale: Mutex::new(stale),
            aabb: self.aabb,
            used: AtomicBool::new(self.used.load(Ordering::Relaxed)),
            vertices: self.vertices.clone(),
            triangles: self.triangles.clone(),
        }
    }
}

impl Part {
    fn new(mesh: ParryMesh, vertices: Vec<u32>, triangles: Vec<u32>) -> Self {
        Self {
            aabb: mesh.local_aabb(),
            fitted: OnceLock::from(mesh),
            stale: Mutex::new(None),
            used: AtomicBool::new(false),
            vertices,
            triangles,
        }
    }

    /// The mesh triangle of part-local triangle `t`.
    #[inline]
    pub(super) fn global(&self, t: u32) -> u32 {
        if self.triangles.is_empty() {
            t
        } else {
            self.triangles[t as usize]
        }
    }

    /// The part's parry mesh fitted to `live` (the mesh's live vertices, which the part was
    /// last moved to), for a search entering it: refitted here, once, if it waits for its
    /// refit (concurrent callers wait for the one refitting it), and marked for a refit at
    /// the next move.
    #[inline]
    pub(super) fn mesh(&self, live: &[Vec3], refits: &Refits) -> &ParryMesh {
        if !self.used.load(Ordering::Relaxed) {
            self.used.store(true, Ordering::Relaxed);
        }
        self.fit(live, refits)
    }

    /// The part's parry mesh fitted to `live`, refitted here if it waits (not marked).
    #[inline]
    fn fit(&self, live: &[Vec3], refits: &Refits) -> &ParryMesh {
        self.fitted.get_or_init(|| {
            let start = Instant::now();
            let mut mesh = self
                .stale
                .lock()
                .unwrap_or_else(PoisonError::into_inner)
                .take()
                .expect("a part's mesh is either fitted or waiting for its refit");
            self.refit(&mut mesh, live);
            refits.add(start);
            mesh
        })
    }

    /// Moves `mesh`'s vertices to `live` and refits its BVH (parry's refit).
    fn refit(&self, mesh: &mut ParryMesh, live: &[Vec3]) {
        let map = &self.vertices;
        mesh.update_vertices(|v| {
            if map.is_empty() {
                v.copy_from_slice(live);
            } else {
                for (d, &g) in v.iter_mut().zip(map) {
                    *d = live[g as usize];
                }
            }
        });
    }

    /// The part moved to `live`: its refit waits for the next search that enters it; its box
    /// is recomputed now.
    fn defer(&mut self, live: &[Vec3]) {
        if let Some(mesh) = self.fitted.take() {
            *self.stale.get_mut().unwrap_or_else(PoisonError::into_inner) = Some(mesh);
        }
        let mut lo = Vec3::INFINITY;
        let mut hi = Vec3::NEG_INFINITY;
        for &g in &self.vertices {
            let v = live[g as usize];
            lo = lo.min(v);
            hi = hi.max(v);
        }
        self.aabb = Aabb::new(lo, hi);
    }

    /// The part moved to `live`, refitted now.
    fn refit_now(&mut self, live: &[Vec3], refits: &Refits) {
        let start = Instant::now();
        let mut mesh = self
            .fitted
            .take()
            .or_else(|| {
                self.stale
                    .get_mut()
                    .unwrap_or_else(PoisonError::into_inner)
                    .take()
            })
            .expect("a part's mesh is either fitted or waiting for its refit");
        self.refit(&mut mesh, live);
        self.aabb = mesh.local_aabb();
        self.fitted = OnceLock::from(mesh);
        refits.add(start);
    }

    /// Whether the part is fitted to the live vertices.
    #[cfg(test)]
    fn is_fitted(&self) -> bool {
        self.fitted.get().is_some()
    }
}

/// Parts refitted and the time their refits took, since the mesh was built (summed over
/// threads).
#[derive(Debug, Default)]
pub(super) struct Refits {
    count: AtomicU64,
    nanos: AtomicU64,
}

impl Clone for Refits {
    fn clone(&self) -> Self {
        let (count, nanos) = self.get();
        Self {
            count: AtomicU64::new(count),
            nanos: AtomicU64::new(nanos),
        }
    }
}

impl Refits {
    fn add(&self, start: Instant) {
        let nanos = start.elapsed().as_nanos().min(u128::from(u64::MAX)) as u64;
        self.count.fetch_add(1, Ordering::Relaxed);
        self.nanos.fetch_add(nanos, Ordering::Relaxed);
    }

    /// `(parts refitted, nanoseconds)`.
    pub(super) fn get(&self) -> (u64, u64) {
        (
            self.count.load(Ordering::Relaxed),
            self.nanos.load(Ordering::Relaxed),
        )
    }
}

/// A child of a top node: another top node or a part.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Child {
    Node(u32),
    Part(u32),
}

/// One wide node of the whole BVH above the parts: its two children and their boxes.
#[derive(Debug, Clone)]
struct TopNode {
    children: [Child; 2],
    aabbs: [Aabb; 2],
}

/// A mesh's triangles in parts, searched as one BVH and refitted part by part as searches
/// need them.
///
/// parry refits a [`TriMesh`](ParryMesh)'s BVH whole and gives no mutable access to it, so
/// a mesh collider holds its triangles in parts: each part is a parry mesh over the triangles
/// of one subtree of the BVH parry builds over the whole mesh, below its top levels. parry's
/// binned build splits a set of leaves the same way wherever that set sits in a tree, so each
/// part's own BVH is that subtree, node for node (checked when the parts are made; a mesh whose
/// parts would differ keeps one part). A search visits the top levels as parry's best-first
/// traversal of the whole tree would, in the same order with the same pruning, and each part's
/// subtree with parry's own search bounded by the best cost so far: it finds the triangle the
/// search over the whole mesh finds, ties included.
///
/// When the mesh moves, the top levels' boxes are recomputed at once from the parts' vertices,
/// the parts searched since the last move are refitted at once (in parallel), and each other
/// part when a search first enters it (a skin touches a deforming muscle over a small part of
/// its surface: the rest of it is not refitted at all). A mesh in one part is refitted at once.
#[derive(Debug, Clone)]
pub(super) struct Parts {
    parts: Vec<Part>,
    /// The whole BVH's wide nodes above the parts, parents before children (empty: one part).
    top: Vec<TopNode>,
    refits: Refits,
}

impl Parts {
    /// Cuts `whole` (a parry mesh over every triangle, as built) into parts of at most
    /// `max_part` triangles where its BVH allows; one part when a part's BVH would not be the
    /// whole BVH's subtree.
    pub(super) fn new(whole: ParryMesh, max_part: usize) -> Self {
        let bvh = whole.bvh();
        let mut plan = Plan {
            bvh,
            max_part: max_part.max(2),
            parts: Vec::new(),
            top: Vec::new(),
            subtrees: Vec::new(),
        };
        let n = bvh.leaf_count() as usize;
        let root = root_children(bvh);
        match root {
            Some([l, r]) if n > plan.max_part => {
                plan.top.push(TopNode {
                    children: [Child::Part(0); 2],
                    aabbs: [Aabb::new_invalid(); 2],
                });
                let left = plan.split(l);
                let right = plan.split(r);
                plan.top[0].children = [left, right];
            }
            _ => {}
        }
        if plan.parts.len() < 2 {
            return Self::single(whole);
        }
        let (parts, top, subtrees) = (plan.parts, plan.top, plan.subtrees);
        let built: Option<Vec<Part>> = parts
            .into_iter()
            .zip(&subtrees)
            .map(|(tris, &subtree)| make_part(&whole, tris, subtree))
            .collect();
        let Some(parts) = built else {
            return Self::single(whole);
        };
        let mut out = Self {
            parts,
            top,
            refits: Refits::default(),
        };
        out.update_top();
        out
    }

    fn single(whole: ParryMesh) -> Self {
        Self {
            parts: vec![Part::new(whole, Vec::new(), Vec::new())],
            top: Vec::new(),
            refits: Refits::default(),
        }
    }

    /// The bounding box of the whole mesh, as parry's root box of the whole BVH.
    pub(super) fn local_aabb(&self) -> Aabb {
        match self.top.first() {
            Some(root) => root.aabbs[0].merged(&root.aabbs[1]),
            None => self.parts[0].aabb,
        }
    }

    /// Moves every part to `live` (the mesh's vertices): a mesh in one part is refitted now;
    /// of a split mesh, the parts a search entered since the last move are refitted now, in
    /// parallel (the skin most likely reaches them again), and the others wait for the first
    /// search that enters them ([`Part::mesh`]); the top levels' boxes are recomputed now.
    pub(super) fn move_to(&mut self, live: &[Vec3]) {
        if let [part] = &mut self.parts[..] {
            part.refit_now(live, &self.refits);
            return;
        }
        let refits = &self.refits;
        self.parts.par_iter_mut().for_each(|part| {
            if std::mem::take(part.used.get_mut()) {
                part.refit_now(live, refits);
            } else {
                part.defer(live);
            }
        });
        self.update_top();
    }

    /// Refits every part that waits for its refit, in parallel.
    pub(super) fn refit_all(&self, live: &[Vec3]) {
        self.parts.par_iter().for_each(|p| {
            p.fit(live, &self.refits);
        });
    }

    /// The parts' refits so far: `(parts refitted, nanoseconds)`, summed over threads.
    pub(super) fn refits(&self) -> (u64, u64) {
        self.refits.get()
    }

    /// The number of parts.
    pub(super) fn count(&self) -> usize {
        self.parts.len()
    }

    /// The refit counter [`Part::mesh`] adds to.
    #[inline]
    pub(super) fn refit_counter(&self) -> &Refits {
        &self.refits
    }

    /// Recomputes the top nodes' boxes from the parts' (children before parents).
    fn update_top(&mut self) {
        for i in (0..self.top.len()).rev() {
            for k in 0..2 {
                self.top[i].aabbs[k] = match self.top[i].children[k] {
                    Child::Part(p) => self.parts[p as usize].aabb,
                    Child::Node(j) => {
                        let a = &self.top[j as usize].aabbs;
                        a[0].merged(&a[1])
                    }
                };
            }
        }
    }

    /// parry's [`Bvh::find_best`] over the whole mesh: `node_cost` is the cost of a box given
    /// the best cost so far, as parry's search takes it; `part_best` searches one part's BVH
    /// bounded by a cost and returns its best cost and answer (parry returns only answers
    /// cheaper than the bound). The top nodes are visited in the order and with the pruning of
    /// parry's traversal, so the answer is the one parry's search over the whole BVH gives.
    pub(super) fn find_best<T>(
        &self,
        max_cost: f32,
        node_cost: impl Fn(&Aabb, f32) -> f32,
        mut part_best: impl FnMut(&Part, f32) -> Option<(f32, T)>,
    ) -> Option<(f32, T)> {
        let mut best = (max_cost, None);
        if self.top.is_empty() {
            self.visit_part(0, &mut best, &mut part_best);
        } else {
            self.visit(0, &mut best, &node_cost, &mut part_best);
        }
        let (cost, value) = best;
        value.map(|v| (cost, v))
    }

    fn visit_part<T>(
        &self,
        part: u32,
        best: &mut (f32, Option<T>),
        part_best: &mut impl FnMut(&Part, f32) -> Option<(f32, T)>,
    ) {
        if let Some((cost, value)) = part_best(&self.parts[part as usize], best.0)
            && cost < best.0
        {
            *best = (cost, Some(value));
        }
    }

    /// One wide node as parry's `find_best` loop handles it: both children scored with the
    /// best cost at this point, the cheaper first (the left one on a tie), each kept if its
    /// score is below that best cost; the farther child waits until the nearer one's subtree
    /// is done (parry's stack), without being scored again.
    fn visit<T>(
        &self,
        node: u32,
        best: &mut (f32, Option<T>),
        node_cost: &impl Fn(&Aabb, f32) -> f32,
        part_best: &mut impl FnMut(&Part, f32) -> Option<(f32, T)>,
    ) {
        let n = &self.top[node as usize];
        let mut near = (node_cost(&n.aabbs[0], best.0), n.children[0]);
        let mut far = (node_cost(&n.aabbs[1], best.0), n.children[1]);
        if near.0 > far.0 {
            std::mem::swap(&mut near, &mut far);
        }
        let keep = |score: f32| score < best.0 && score != f32::MAX;
        let (go_near, go_far) = (keep(near.0), keep(far.0));
        for (go, child) in [(go_near, near.1), (go_far, far.1)] {
            if go {
                match child {
                    Child::Node(j) => self.visit(j, best, node_cost, part_best),
                    Child::Part(p) => self.visit_part(p, best, part_best),
                }
            }
        }
    }
}

#[cfg(test)]
impl Parts {
    /// Number of parts.
    pub(super) fn len(&self) -> usize {
        self.parts.len()
    }

    /// Every part's vertices, and its BVH's nodes in traversal order (boxes as bits, leaves as
    /// mesh triangle ids), each part fitted to `live` first: equal fingerprints, equal parts.
    pub(super) fn fingerprint(&self, live: &[Vec3]) -> Vec<(Vec<[u32; 3]>, Vec<Visited>)> {
        self.parts
            .iter()
            .map(|p| {
                let mesh = p.fit(live, &self.refits);
                assert_eq!(
                    visited_box(&p.aabb),
                    visited_box(&mesh.local_aabb()),
                    "a part's box is its refitted BVH's"
                );
                let v = mesh
                    .vertices()
                    .iter()
                    .map(|v| v.to_array().map(f32::to_bits));
                let mut nodes = Vec::new();
                mesh.bvh().traverse(|node| {
                    nodes.push(visited(node, |t| p.global(t)));
                    TraversalAction::Continue
                });
                (v.collect(), nodes)
            })
            .collect()
    }

    /// The number of triangles in each part.
    pub(super) fn sizes(&self) -> Vec<usize> {
        self.parts
            .iter()
            .map(|p| match p.fitted.get() {
                Some(m) => m.indices().len(),
                None => p
                    .stale
                    .lock()
                    .unwrap_or_else(PoisonError::into_inner)
                    .as_ref()
                    .map_or(0, |m| m.indices().len()),
            })
            .collect()
    }

    /// The number of parts fitted to the live vertices.
    pub(super) fn fitted(&self) -> usize {
        self.parts.iter().filter(|p| p.is_fitted()).count()
    }

    /// Depth of the top levels above the parts (0: one part).
    pub(super) fn top_depth(&self) -> usize {
        fn depth(top: &[TopNode], c: Child) -> usize {
            match c {
                Child::Part(_) => 0,
                Child::Node(i) => {
                    1 + top[i as usize]
                        .children
                        .iter()
                        .map(|&c| depth(top, c))
                        .max()
                        .unwrap_or(0)
                }
            }
        }
        if self.top.is_empty() {
            0
        } else {
            depth(&self.top, Child::Node(0))
        }
    }
}

/// Splitting state while the parts are planned.
struct Plan<'a> {
    bvh: &'a Bvh,
    max_part: usize,
    /// Each part's triangles (mesh ids).
    parts: Vec<Vec<u32>>,
    top: Vec<TopNode>,
    /// Each part's subtree root in the whole BVH.
    subtrees: Vec<BvhNodeIndex>,
}

impl Plan<'_> {
    /// A part for the subtree at `index` if it is small enough (or cannot be split into two
    /// subtrees of at least two triangles), else a top node over its two children.
    fn split(&mut self, index: BvhNodeIndex) -> Child {
        let leaves = subtree_leaves(self.bvh, index);
        if leaves.len() > self.max_part
            && let Some([l, r]) = children(self.bvh, index)
        {
            let id = self.top.len() as u32;
            self.top.push(TopNode {
                children: [Child::Part(0); 2],
                aabbs: [Aabb::new_invalid(); 2],
            });
            let left = self.split(l);
            let right = self.split(r);
            self.top[id as usize].children = [left, right];
            return Child::Node(id);
        }
        self.parts.push(leaves);
        self.subtrees.push(index);
        Child::Part(self.parts.len() as u32 - 1)
    }
}

/// The root's two children, when the root has two internal ones (more than one leaf each).
fn root_children(bvh: &Bvh) -> Option<[BvhNodeIndex; 2]> {
    let mut found = Vec::with_capacity(2);
    bvh.traverse_indexed(None, |node, index| {
        found.push((index, node.is_leaf()));
        TraversalAction::Prune
    });
    internal_pair(&found)
}

/// The two children of the internal node at `index`, when both are internal.
fn children(bvh: &Bvh, index: BvhNodeIndex) -> Option<[BvhNodeIndex; 2]> {
    let mut found = Vec::with_capacity(3);
    bvh.traverse_indexed(Some(index), |node, i| {
        found.push((i, node.is_leaf()));
        if found.len() == 1 {
            TraversalAction::Continue
        } else {
            TraversalAction::Prune
        }
    });
    internal_pair(found.get(1..).unwrap_or(&[]))
}

fn internal_pair(found: &[(BvhNodeIndex, bool)]) -> Option<[BvhNodeIndex; 2]> {
    match found {
        [(l, false), (r, false)] => Some([*l, *r]),
        _ => None,
    }
}

/// The leaves (triangle ids) below the node at `index`, ascending.
fn subtree_leaves(bvh: &Bvh, index: BvhNodeIndex) -> Vec<u32> {
    let mut out = Vec::new();
    bvh.traverse_indexed(Some(index), |node, _| {
        if let Some(t) = node.leaf_data() {
            out.push(t);
        }
        TraversalAction::Continue
    });
    out.sort_unstable();
    out
}

/// One node of a traversal, for comparing two trees: box and leaf id (`None` for an internal
/// node).
pub(super) type Visited = ([u32; 6], Option<u32>);

#[cfg(test)]
fn visited_box(a: &Aabb) -> [u32; 6] {
    let (lo, hi) = (a.mins, a.maxs);
    [lo.x, lo.y, lo.z, hi.x, hi.y, hi.z].map(f32::to_bits)
}

fn visited(node: &BvhNode, leaf: impl Fn(u32) -> u32) -> Visited {
    let (lo, hi) = (node.mins(), node.maxs());
    (
        [lo.x, lo.y, lo.z, hi.x, hi.y, hi.z].map(f32::to_bits),
        node.leaf_data().map(leaf),
    )
}

/// The part over triangles `tris` (ascending mesh ids) of `whole`, if its BVH is the subtree
/// of `whole`'s at `subtree`, node for node (same boxes, same children on the same sides, same
/// triangles).
fn make_part(whole: &ParryMesh, tris: Vec<u32>, subtree: BvhNodeIndex) -> Option<Part> {
    let wv = whole.vertices();
    let wi = whole.indices();
    let mut local = vec![u32::MAX; wv.len()];
    let mut vertices = Vec::new();
    let indices: Vec<[u32; 3]> = tris
        .iter()
        .map(|&t| {
            wi[t as usize].map(|g| {
                if local[g as usize] == u32::MAX {
                    local[g as usize] = vertices.len() as u32;
                    vertices.push(g);
                }
                local[g as usize]
            })
        })
        .collect();
    let positions = vertices.iter().map(|&g| wv[g as usize]).collect();
    let mesh = ParryMesh::new(positions, indices).ok()?;
    // The subtree below `subtree` (its root excluded: the part's root wide node is its
    // children) against the part's whole tree, both in parry's traversal order.
    let mut expected = Vec::new();
    whole.bvh().traverse_indexed(Some(subtree), |node, _| {
        expected.push(visited(node, |t| t));
        TraversalAction::Continue
    });
    let mut got = Vec::with_capacity(expected.len());
    mesh.bvh().traverse(|node| {
        got.push(visited(node, |t| tris[t as usize]));
        TraversalAction::Continue
    });
    (expected.get(1..) == Some(&got[..])).then(|| Part::new(mesh, vertices, tris))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A part cloned while another thread refits it (the stale mesh taken, the fitted one not
    /// yet set) waits for that refit instead of coming out with no mesh.
    #[test]
    fn a_part_cloned_during_its_refit_waits_for_it() {
        let v = vec![Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::Z];
        let t = vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]];
        let mesh = ParryMesh::new(v, t).unwrap();
        let part = Part::new(mesh, vec![0, 1, 2, 3], vec![0, 1, 2, 3]);
        // The state a search leaves while it refits: the stale mesh taken, none fitted.
        let mut refitting = part.clone();
        let mesh = refitting.fitted.take().unwrap();
        let refitting = refitting;
        std::thread::scope(|s| {
            s.spawn(|| {
                std::thread::sleep(std::time::Duration::from_millis(100));
                refitting.fitted.set(mesh).unwrap();
            });
            let clone = refitting.clone();
            assert!(clone.fitted.get().is_some(), "the clone has a mesh");
            assert_eq!(clone.aabb, part.aabb);
        });
    }
}
