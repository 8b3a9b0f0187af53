//! Spring forces and energy, and the quasi-static relaxation that settles the skin.
#![doc = include_str!("README.md")]

mod contact;
mod kernels;
mod reorder;
mod sell;
mod simd;
pub(crate) mod team;

pub use reorder::{bandwidth_order, morton_order};

/// The SIMD path the relaxation kernels take in this process: on x86-64 (detected at run
/// time) `"avx512"` on an AMD CPU with AVX-512F/VL (Zen 4 on, where it is the fastest),
/// `"avx2"` on any other CPU with AVX2 and FMA, else `"scalar"` (portable code). The
/// environment variable `DERMIS_SIMD=scalar|avx2|avx512` picks another path, never one the CPU
/// lacks (it falls back to the best below it). Every path gives the same bits (the portable
/// code takes the kernels' fused multiply-adds from `mul_add`, which is slow on a CPU without
/// FMA); this is for reports (`dermis bench` prints it) and for comparing paths.
///
/// ```
/// assert!(["scalar", "avx2", "avx512"].contains(&dermis::solver::kernel_path()));
/// ```
pub fn kernel_path() -> &'static str {
    match simd::Isa::detect(0) {
        simd::Isa::Scalar => "scalar",
        simd::Isa::Avx2 => "avx2",
        simd::Isa::Avx512 => "avx512",
    }
}

use std::time::Instant;

use glam::Vec3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::mesh::TriMesh;
use contact::ContactSet;
use kernels::{Frame, Spills, Sums, advance, dot, retreat, update_direction};
use sell::Sell;
use simd::SlicedAnchors;
use team::{Par, Team};

/// Iterations at the start of a projected solve in which a newly held contact restarts the
/// conjugate directions. A solve after a collider moved (a substep) holds whole rings of
/// vertices in its first iterations; later holds come one by one at the rim of a contact patch,
/// and restarting on each of those had a contact frame run as steepest descent (tube-10k, 60
/// frames of `examples/tube_profile`: 10,077 iterations with restarts on every hold, 8,079 with
/// early ones only; with 2 instead of 3, the swinging-bone test lets a ring escape).
const EARLY_HOLD_RESTARTS: u32 = 3;

/// One spring as seen from one of its ends (the system stores each twice, once per end).
#[derive(Debug, Clone, Copy, PartialEq)]
#[repr(C)]
pub struct Spring {
    /// The vertex at the other end (internal index).
    pub other: u32,
    /// Stiffness, N/m.
    pub k: f32,
    /// Rest length, m.
    pub rest: f32,
}

/// The kernels' fused dot products on single vectors: the operations of their eight lanes
/// ([`simd`]), rounded where theirs are, so per-vertex code (a partial slice, the tests' plain
/// loops) gives their bits. (Fused `a s + c` per component is glam's `mul_add`.)
pub(crate) mod fused {
    use glam::{DVec3, Vec3};

    /// `a·b` as `fma(a_z, b_z, fma(a_y, b_y, a_x b_x))`.
    #[inline]
    pub(crate) fn dot(a: Vec3, b: Vec3) -> f32 {
        a.z.mul_add(b.z, a.y.mul_add(b.y, a.x * b.x))
    }

    /// [`dot`] in f64.
    #[inline]
    pub(crate) fn dot64(a: DVec3, b: DVec3) -> f64 {
        a.z.mul_add(b.z, a.y.mul_add(b.y, a.x * b.x))
    }
}

/// A per-vertex anchor spring towards a target, stiffer along the body normal than across it:
/// skin slides along the body more easily than it leaves it.
///
/// Energy: `½ k_n ((x−t)·n)² + ½ k_t |(x−t) − ((x−t)·n) n|²`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct VertexAnchor {
    /// Where the vertex wants to be.
    pub target: Vec3,
    /// Unit body normal at the target (any unit vector when `k_normal == k_tangent`).
    pub normal: Vec3,
    /// Stiffness along the normal, N/m.
    pub k_normal: f32,
    /// Stiffness in the tangent plane, N/m.
    pub k_tangent: f32,
}

impl VertexAnchor {
    /// Whether every float of the anchor is finite (a solve refuses one that is not).
    pub fn is_finite(&self) -> bool {
        self.target.is_finite()
            && self.normal.is_finite()
            && self.k_normal.is_finite()
            && self.k_tangent.is_finite()
    }

    #[cfg_attr(
        not(test),
        expect(
            dead_code,
            reason = "the kernels evaluate this in eight lanes; the reference their tests match"
        )
    )]
    #[inline]
    fn force_energy(&self, x: Vec3) -> (Vec3, f64) {
        let d = x - self.target;
        let n = self.normal;
        let dn = fused::dot(d, n);
        let dt = n.mul_add(Vec3::splat(-dn), d);
        let kdn = self.k_normal * dn;
        let force = -n.mul_add(Vec3::splat(kdn), dt * self.k_tangent);
        // Energy in f64 from the exact difference, for the line search's sake.
        let d64 = x.as_dvec3() - self.target.as_dvec3();
        let n64 = n.as_dvec3();
        let dn64 = fused::dot64(d64, n64);
        let p = n64.mul_add(glam::DVec3::splat(-dn64), d64);
        let tangent = 0.5 * self.k_tangent as f64 * fused::dot64(p, p);
        let energy = (0.5 * self.k_normal as f64 * dn64).mul_add(dn64, tangent);
        (force, energy)
    }

    #[inline]
    fn curvature(&self, u: Vec3) -> f32 {
        let un = fused::dot(u, self.normal);
        let across = (-un).mul_add(un, fused::dot(u, u)).max(0.0);
        (self.k_normal * un).mul_add(un, self.k_tangent * across)
    }
}

/// What acts on the mesh besides its springs, in the caller's vertex order. All optional.
#[derive(Debug, Clone, Copy, Default)]
pub struct Loads<'a> {
    /// External force per vertex, N.
    pub forces: Option<&'a [Vec3]>,
    /// `true` for vertices held where they are.
    pub pinned: Option<&'a [bool]>,
    /// Anchor spring per vertex.
    pub anchors: Option<&'a [VertexAnchor]>,
}

/// A contact plane a [`Projection`] holds a vertex against (see
/// [`Projection::active_contacts`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ActiveContact {
    /// The vertex (internal index).
    pub vertex: u32,
    /// Outward unit normal of the contact plane: the direction the contact can push.
    pub normal: Vec3,
    /// `true` when friction sticks the vertex where it is on the surface: a held contact then
    /// takes the tangential force too.
    pub stick: bool,
}

/// A constraint applied after each accepted step (the collision issue's sliding contact).
///
/// `x` is in the system's internal order; `order[i]` is the caller's index of internal vertex
/// `i`. [`project`](Self::project) returns `true` if any vertex moved (the solver then
/// recomputes the forces: everywhere, or only where they read a vertex that
/// [`moved_vertices`](Self::moved_vertices) names).
///
/// A projection that reports its [`active_contacts`](Self::active_contacts) makes the solve
/// converge on the contact set: for a contact whose net force pushes into the collider, the
/// solver drops that normal component from the residual and the search direction (the contact
/// takes it), so the conjugate gradients work in the tangent space of the contacts; held
/// contacts whose net force pulls them away are released together once that pull outweighs the
/// rest of the residual (MPRGP's proportioning; see the module documentation). The default
/// methods report no contacts: the
/// projection then only moves vertices, and a solve against it can stop only on its budget or
/// a stall.
///
/// The solve runs on the rayon pool's worker threads (see
/// [`SpringSystem::relax_projected`]), so a projection is `Send`.
pub trait Projection: Send {
    /// Projects `x` onto the admissible set.
    fn project(&mut self, x: &mut [Vec3], order: &[u32]) -> bool;

    /// The contacts the last [`project`](Self::project) left active (vertices on or just above
    /// the constraint surface), sorted by vertex; a vertex may have one entry per contact plane.
    fn active_contacts(&self) -> &[ActiveContact] {
        &[]
    }

    /// The vertices (indices into the `x` of the last [`project`](Self::project), the
    /// solver's order) that it moved, when the projection knows them: the solver then
    /// recomputes the forces only where they read a moved vertex. `None` (the default): any
    /// vertex may have moved.
    fn moved_vertices(&self) -> Option<&[u32]> {
        None
    }

    /// Which of the last [`active_contacts`](Self::active_contacts) the solver holds (one flag
    /// per entry; empty: none): the next [`project`](Self::project) should keep those vertices
    /// on the constraint surface, correcting a drift away from it as well as into it (a step
    /// in the tangent plane of a curved surface leaves it).
    fn hold(&mut self, held: &[bool]) {
        let _ = held;
    }

    /// [`project`](Self::project) right after the solver's step `step` (the only motion of
    /// `x` since the last projection): `step` tells where each vertex was at that projection
    /// ([`Step::before`]) and bounds how far each block of [`STEP_BLOCK`] vertices moved
    /// ([`Step::motion`]), so that a projection can skip whole blocks that provably stayed
    /// clear, and need not keep its own copy of the last positions. The default projects
    /// as [`project`](Self::project). A solve that calls this ends with
    /// [`settled`](Self::settled).
    fn project_step(&mut self, x: &mut [Vec3], order: &[u32], step: &Step<'_>) -> bool {
        let _ = step;
        self.project(x, order)
    }

    /// [`project_step`](Self::project_step) without writing `x`, for a solver that runs it
    /// alongside its force gather at the same point: `moves` (cleared first) receives each
    /// vertex it moves (internal index) with its new position, in the order of
    /// [`moved_vertices`](Self::moved_vertices), and the solver applies them. Its parallel
    /// loops find the solve's team through the usual route and share their first loop with
    /// the gather. `None` (the default): the projection does not project this way, and the
    /// solver calls [`project_step`](Self::project_step) after the gather instead.
    ///
    /// When the solver rejects the step (the energy rose there), it goes back to the point
    /// before it, reports that point with [`settled`](Self::settled), and projects the next
    /// step it accepts with [`project`](Self::project): the moves are dropped. After two such
    /// rejections in a solve it calls [`project_step`](Self::project_step) for the rest of it.
    fn project_step_deferred(
        &mut self,
        x: &[Vec3],
        order: &[u32],
        step: &Step<'_>,
        moves: &mut Vec<(u32, Vec3)>,
    ) -> Option<bool> {
        let _ = (x, order, step, moves);
        None
    }

    /// The solve that called [`project_step`](Self::project_step) ended; `x` (internal
    /// order) holds the positions of its last projection. The default does nothing.
    fn settled(&mut self, x: &[Vec3]) {
        let _ = x;
    }
}

/// Vertices per block of a [`Step`]'s motion bounds (internal order: block `b` is the
/// vertices `STEP_BLOCK b..STEP_BLOCK (b + 1)`).
pub const STEP_BLOCK: usize = 64;

/// The solver's last step `x += a d` (internal order), as a [`Projection`] sees it: exactly
/// where each vertex was before it, and a bound on how far each block of [`STEP_BLOCK`]
/// vertices moved.
///
/// ```
/// use dermis::prelude::*;
/// use dermis::solver::{Loads, Projection, STEP_BLOCK, Step};
/// use glam::Vec3;
/// /// Keeps the vertices above the plane `z = 0`; checks what the steps tell.
/// struct Floor {
///     steps: usize,
/// }
/// impl Projection for Floor {
///     fn project(&mut self, x: &mut [Vec3], _order: &[u32]) -> bool {
///         let low: Vec<&mut Vec3> = x.iter_mut().filter(|p| p.z < 0.0).collect();
///         let moved = !low.is_empty();
///         low.into_iter().for_each(|p| p.z = 0.0);
///         moved
///     }
///     fn project_step(&mut self, x: &mut [Vec3], order: &[u32], step: &Step<'_>) -> bool {
///         for (i, &p) in x.iter().enumerate() {
///             // Where the vertex was at the last projection, bit for bit ...
///             let was = step.before(i, p);
///             // ... and how far its block may have moved since (coordinates below 10 m).
///             assert!(f64::from(p.distance(was)) <= step.motion(i / STEP_BLOCK, 10.0));
///         }
///         self.steps += 1;
///         self.project(x, order)
///     }
/// }
/// // A chain of 100 springs hanging from its first vertex, pulled down through the floor.
/// let rest: Vec<Vec3> = (0..101).map(|i| Vec3::new(0.01 * i as f32, 0.0, 0.1)).collect();
/// let edges: Vec<[u32; 2]> = (0..100).map(|i| [i, i + 1]).collect();
/// let system = SpringSystem::new(&rest, &edges, &[50.0; 100], &[0.01; 100]).unwrap();
/// let forces = vec![Vec3::new(0.0, 0.0, -0.5); 101];
/// let mut pinned = vec![false; 101];
/// pinned[0] = true;
/// let loads = Loads { forces: Some(&forces), pinned: Some(&pinned), ..Default::default() };
/// let mut floor = Floor { steps: 0 };
/// let mut x = rest.clone();
/// system
///     .relax_projected(&mut x, &loads, &RelaxConfig::default(), Some(&mut floor))
///     .unwrap();
/// assert!(floor.steps > 0 && x.iter().all(|p| p.z >= 0.0));
/// ```
pub struct Step<'a> {
    d: &'a [Vec3],
    a: f32,
    spills: &'a Spills,
    /// The largest `|d|` component of each block.
    reach: &'a [f32],
}

impl Step<'_> {
    /// The position of internal vertex `i` before the step, bit for bit, given its position
    /// `x` after it: `x − a d` (one rounding per component), with the few floats that does
    /// not give back (noted by the step) put back.
    ///
    /// # Panics
    /// If `i` is not a vertex of the solve.
    pub fn before(&self, i: usize, x: Vec3) -> Vec3 {
        let d = self.d[i];
        let mut p = Vec3::new(
            d.x.mul_add(-self.a, x.x),
            d.y.mul_add(-self.a, x.y),
            d.z.mul_add(-self.a, x.z),
        );
        let (chunk, first) = (i / kernels::CHUNK, 3 * (i % kernels::CHUNK));
        for &simd::Spilled { at, old } in self.spills.get(chunk).map_or(&[][..], Vec::as_slice) {
            let f = at as usize;
            if (first..first + 3).contains(&f) {
                p[f - first] = old;
            }
        }
        p
    }

    /// A bound, m, on how far any vertex of block `b` moved in the step, for vertices whose
    /// coordinates were at most `magnitude` (absolute value) before it: `|a| √3 max |d|`
    /// plus the rounding of `x + a d` (half an ulp of the result per component).
    ///
    /// # Panics
    /// If `b` is not below [`blocks`](Self::blocks).
    pub fn motion(&self, b: usize, magnitude: f32) -> f64 {
        let along = f64::from(self.a.abs()) * f64::from(self.reach[b]);
        let rounding = (f64::from(magnitude) + along) * f64::from(f32::EPSILON);
        (along * (1.0 + 1e-6) + rounding) * 3f64.sqrt() * (1.0 + 1e-9)
    }

    /// The number of blocks (the vertex count over [`STEP_BLOCK`], rounded up).
    pub fn blocks(&self) -> usize {
        self.reach.len()
    }
}
/// Iteration budget and tolerance of a relaxation.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct RelaxConfig {
    /// Stop after this many iterations even if not converged.
    pub max_iterations: u32,
    /// Converged when `|net force| <= tolerance * force_scale` (Euclidean norms over the free
    /// vertices).
    pub tolerance: f32,
    /// The force the residual is measured against, N. `None`: the norm of the external forces,
    /// or, when there are none, the norm of the net force at the start of the solve.
    pub force_scale: Option<f32>,
    /// Record the energy after every iteration in [`RelaxReport::energy_history`].
    pub record_energy: bool,
    /// Stop as [`StopReason::Stalled`] when the residual has not fallen below 90 % of its best
    /// value for this many iterations (0: never). With f32 positions the residual reaches a
    /// floor and then only creeps while the energy changes in its last digits; this stops
    /// there instead of spending the whole budget. Under a projection the residual is the
    /// projected one (contact forces held by active contacts left out), so the stop works there
    /// too.
    pub stagnation_window: u32,
}

impl RelaxConfig {
    /// 500 iterations, relative residual 1e-4, stop after 50 iterations without progress.
    pub const DEFAULT: Self = Self {
        max_iterations: 500,
        tolerance: 1e-4,
        force_scale: None,
        record_energy: false,
        stagnation_window: 50,
    };
}

impl Default for RelaxConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// Why a relaxation stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum StopReason {
    /// The residual fell under the tolerance.
    Converged,
    /// The iteration budget was spent.
    Budget,
    /// No step along the search direction lowers the energy any more: the answer is as exact
    /// as f32 positions allow.
    Stalled,
}

/// What a relaxation did.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RelaxReport {
    /// Iterations taken (accepted steps).
    pub iterations: u32,
    /// Final relative residual `|net force| / force_scale`.
    pub residual: f32,
    /// Final total energy (springs + anchors − work of external forces), J.
    pub energy: f64,
    /// Why it stopped.
    pub stop: StopReason,
    /// The force scale the residual was measured against, N.
    pub force_scale: f32,
    /// Energy after each iteration (first entry: before the first), if asked for.
    #[serde(skip_serializing_if = "Vec::is_empty", default)]
    pub energy_history: Vec<f64>,
}

impl RelaxReport {
    /// `true` when the tolerance was met.
    pub fn converged(&self) -> bool {
        self.stop == StopReason::Converged
    }
}

/// Wall time of a solve's parallel loops, s, summed over its iterations (see
/// [`SpringSystem::relax_timed`]). What the five loops leave of `total` is the solve's set-up,
/// its copy back and the serial work between the loops.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub(crate) struct LoopTimes {
    /// The whole solve, from its call to its return.
    pub total: f64,
    /// The curvature gathers (`dᵀ H d` along each direction).
    pub curvature: f64,
    /// The force gathers: at each trial point, at the start, and again after a rejected trial
    /// or a projection that moved vertices.
    pub force: f64,
    /// The steps to the trial points, and their undoing after a rejection.
    pub step: f64,
    /// The direction updates (with the held contacts' projection).
    pub direction: f64,
    /// The projections after accepted steps (without the first one, before the solve's first
    /// force gather).
    pub projection: f64,
}

/// Adds a solve's loop times to a [`LoopTimes`], or does nothing.
struct Clock<'a>(Option<&'a mut LoopTimes>);

impl Clock<'_> {
    /// Runs `f`, adding its wall time to the loop `field` when timing.
    #[inline]
    fn time<R>(&mut self, field: fn(&mut LoopTimes) -> &mut f64, f: impl FnOnce() -> R) -> R {
        match self.0.as_deref_mut() {
            Some(times) => {
                let start = Instant::now();
                let out = f();
                *field(times) += start.elapsed().as_secs_f64();
                out
            }
            None => f(),
        }
    }
}

/// Why a spring system could not be built or relaxed.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum SolverError {
    /// An input array does not have one entry per vertex (or edge).
    #[error("{what} has {given} entries, expected {expected}")]
    Length {
        /// Which input.
        what: &'static str,
        /// Entries given.
        given: usize,
        /// Entries expected.
        expected: usize,
    },
    /// An edge names a vertex that does not exist or joins a vertex to itself.
    #[error("edge {edge} ({a}, {b}) is invalid for {vertex_count} vertices")]
    BadEdge {
        /// Edge index.
        edge: usize,
        /// First vertex.
        a: u32,
        /// Second vertex.
        b: u32,
        /// Vertex count.
        vertex_count: usize,
    },
    /// A stiffness or rest length is negative or not finite.
    #[error("edge {edge} has stiffness {k} and rest length {rest}; both must be finite and >= 0")]
    BadSpring {
        /// Edge index.
        edge: usize,
        /// Its stiffness.
        k: f32,
        /// Its rest length.
        rest: f32,
    },
    /// A position, force or anchor is NaN or infinite.
    #[error("{what} of vertex {vertex} is not finite")]
    NonFinite {
        /// Which input.
        what: &'static str,
        /// The caller's vertex index.
        vertex: usize,
    },
    /// The mesh has more half-springs (with the padding of their slices of eight vertices)
    /// than the solver's 29-bit entry indices address: split the skin into several systems.
    #[error("{entries} spring entries exceed the solver's limit of {limit}")]
    TooManySprings {
        /// Entries the mesh needs.
        entries: usize,
        /// The most a system can hold.
        limit: usize,
    },
}

/// A spring mesh ready to relax: springs in slices of eight vertices (for the SIMD kernels), in a
/// locality-friendly internal vertex order.
///
/// Vertices are renumbered when the system is built so that every spring's two ends are close
/// in memory ([`bandwidth_order`]: a shuffled input runs as fast as a well-ordered one, and gives
/// the same answers); every public method takes and returns data in the caller's order.
///
/// ```
/// use dermis::prelude::*;
/// use dermis::solver::Loads;
/// use glam::Vec3;
/// // One spring of rest length 1 and stiffness 100 N/m, pinned at vertex 0, pulled by 2 N.
/// let rest = vec![Vec3::ZERO, Vec3::X];
/// let system = SpringSystem::new(&rest, &[[0, 1]], &[100.0], &[1.0]).unwrap();
/// let mut x = rest.clone();
/// let forces = [Vec3::ZERO, Vec3::new(2.0, 0.0, 0.0)];
/// let pinned = [true, false];
/// let loads = Loads { forces: Some(&forces), pinned: Some(&pinned), ..Default::default() };
/// let report = system.relax(&mut x, &loads, &RelaxConfig::default()).unwrap();
/// assert!(report.converged());
/// assert!((x[1].x - 1.02).abs() < 1e-5); // stretch = f / k
/// ```
#[derive(Debug, Clone)]
pub struct SpringSystem {
    order: Vec<u32>,
    rank: Vec<u32>,
    sell: Sell,
    /// Each vertex's stiffness summed over its springs (internal order): the spring part of
    /// the Jacobi preconditioner, the same for every solve (only the anchors are added per
    /// solve).
    spring_diagonal: Vec<f32>,
    /// Per chunk of [`kernels::CHUNK`] vertices (internal order), the chunks whose forces read
    /// one of its vertices (its own included), sorted.
    chunk_readers: Vec<Vec<u32>>,
    edge_count: usize,
}

impl SpringSystem {
    /// Builds the system for `edges` with per-edge `stiffness` and `rest_lengths`.
    /// `positions` (one per vertex) only decide the internal vertex order.
    pub fn new(
        positions: &[Vec3],
        edges: &[[u32; 2]],
        stiffness: &[f32],
        rest_lengths: &[f32],
    ) -> Result<Self, SolverError> {
        check_finite("position", positions)?;
        check_springs(positions.len(), edges, stiffness, rest_lengths)?;
        Self::in_order(
            bandwidth_order(positions, edges),
            edges,
            stiffness,
            rest_lengths,
        )
    }

    /// The system [`new`](Self::new) builds from the same positions and `edges` as this one
    /// with other `stiffness` and `rest_lengths`, without computing the vertex order again
    /// (the order depends only on the positions and edges): for a skin whose stiffness
    /// changes while its rest mesh does not. The result is the same as `new`'s, bit for bit.
    ///
    /// Other edges on the same vertices are accepted too; they keep this system's order, which
    /// then may keep their ends less close in memory than `new` would.
    ///
    /// ```
    /// use dermis::prelude::*;
    /// use dermis::solver::Loads;
    /// use glam::Vec3;
    /// // A chain of two springs pinned at one end and pulled at the other.
    /// let rest = [Vec3::ZERO, Vec3::X, Vec3::new(2.0, 0.0, 0.0)];
    /// let edges = [[0, 1], [1, 2]];
    /// let soft = SpringSystem::new(&rest, &edges, &[10.0, 10.0], &[1.0, 1.0]).unwrap();
    /// let stiff = soft.with_stiffness(&edges, &[50.0, 80.0], &[1.0, 1.0]).unwrap();
    /// let forces = [Vec3::ZERO, Vec3::ZERO, Vec3::new(4.0, 0.0, 0.0)];
    /// let pinned = [true, false, false];
    /// let loads = Loads { forces: Some(&forces), pinned: Some(&pinned), ..Default::default() };
    /// let mut x = rest.to_vec();
    /// stiff.relax(&mut x, &loads, &RelaxConfig::default()).unwrap();
    /// assert!((x[2].x - (2.0 + 4.0 / 50.0 + 4.0 / 80.0)).abs() < 1e-4);
    /// // The same bits as a system built afresh.
    /// let fresh = SpringSystem::new(&rest, &edges, &[50.0, 80.0], &[1.0, 1.0]).unwrap();
    /// let mut y = rest.to_vec();
    /// fresh.relax(&mut y, &loads, &RelaxConfig::default()).unwrap();
    /// assert_eq!(x, y);
    /// ```
    pub fn with_stiffness(
        &self,
        edges: &[[u32; 2]],
        stiffness: &[f32],
        rest_lengths: &[f32],
    ) -> Result<Self, SolverError> {
        check_springs(self.vertex_count(), edges, stiffness, rest_lengths)?;
        Self::in_order(self.order.clone(), edges, stiffness, rest_lengths)
    }

    /// [`new`](Self::new) after its checks, with the internal order given (`order[i]`: the
    /// caller's index of internal vertex `i`, a permutation).
    fn in_order(
        order: Vec<u32>,
        edges: &[[u32; 2]],
        stiffness: &[f32],
        rest_lengths: &[f32],
    ) -> Result<Self, SolverError> {
        let n = order.len();
        let mut rank = vec![0u32; n];
        for (i, &o) in order.iter().enumerate() {
            rank[o as usize] = i as u32;
        }
        let pairs = edges
            .iter()
            .map(|&[a, b]| (rank[a as usize], rank[b as usize]));
        let blank = Spring {
            other: 0,
            k: 0.0,
            rest: 0.0,
        };
        let (offsets, mut springs) = reorder::symmetric_rows(n, pairs, blank, |other, e| Spring {
            other,
            k: stiffness[e],
            rest: rest_lengths[e],
        });
        for i in 0..n {
            springs[offsets[i]..offsets[i + 1]].sort_by_key(|s| s.other);
        }
        let too_many = |entries| SolverError::TooManySprings {
            entries,
            limit: sell::MAX_ENTRIES,
        };
        let offsets = offsets
            .iter()
            .map(|&o| u32::try_from(o).map_err(|_| too_many(springs.len())))
            .collect::<Result<Vec<u32>, _>>()?;
        let sell = Sell::from_csr(&offsets, &springs).map_err(too_many)?;
        let mut chunk_readers: Vec<Vec<u32>> =
            (0..kernels::chunks(n) as u32).map(|c| vec![c]).collect();
        for &[a, b] in edges {
            let (ca, cb) = (
                rank[a as usize] as usize / kernels::CHUNK,
                rank[b as usize] as usize / kernels::CHUNK,
            );
            if ca != cb {
                chunk_readers[ca].push(cb as u32);
                chunk_readers[cb].push(ca as u32);
            }
        }
        for readers in &mut chunk_readers {
            readers.sort_unstable();
            readers.dedup();
        }
        Ok(Self {
            order,
            rank,
            chunk_readers,
            spring_diagonal: sell.stiffness_diagonal(),
            sell,
            edge_count: edges.len(),
        })
    }

    /// The system of a mesh's edges at their rest lengths, with the given per-edge stiffness
    /// (from [`StiffnessRule::edge_stiffness`](crate::stiffness::StiffnessRule::edge_stiffness)).
    pub fn from_mesh(mesh: &TriMesh, stiffness: &[f32]) -> Result<Self, SolverError> {
        Self::new(
            mesh.positions(),
            mesh.topology().edges(),
            stiffness,
            &mesh.edge_lengths(),
        )
    }

    /// Number of vertices.
    pub fn vertex_count(&self) -> usize {
        self.order.len()
    }
    /// Number of springs (edges).
    pub fn edge_count(&self) -> usize {
        self.edge_count
    }
    /// The springs in internal order as CSR `(offsets, springs)`: the half-springs of internal
    /// vertex `i` are `springs[offsets[i]..offsets[i + 1]]`, sorted by their other end. Built on
    /// demand (the solver stores them in slices of eight vertices); for benchmarks and
    /// diagnostics.
    pub fn csr(&self) -> (Vec<u32>, Vec<Spring>) {
        self.sell.to_csr()
    }
    /// Internal order: `order()[i]` is the caller's index of internal vertex `i`.
    pub fn order(&self) -> &[u32] {
        &self.order
    }
    /// Bytes of spring data per vertex: a 16-bit other end per half-spring, padded to the
    /// largest degree in each slice of eight vertices; stiffness and rest length (8 bytes) once
    /// per spring, at its lower end (and for the padding and springs to lower vertices that
    /// share a slot with such springs), with a 16-bit reference to them from the other end;
    /// three offsets per slice; 32-bit indices for the few slices with a neighbour beyond a
    /// 16-bit offset or a reference beyond 16 bits; and each vertex's summed stiffness (4 bytes,
    /// the preconditioner's spring part). About 48 bytes on a triangle mesh (the bench tubes:
    /// 47.5-48.0).
    pub fn bytes_per_vertex(&self) -> f64 {
        (self.sell.bytes() + self.spring_diagonal.len() * size_of::<f32>()) as f64
            / self.vertex_count().max(1) as f64
    }

    /// Bytes per vertex of the vectors a relaxation iterates on besides the springs: positions,
    /// direction and force (12 B each) and the inverse diagonal with the pin flag (4 B), 40 B;
    /// with the springs ([`bytes_per_vertex`](Self::bytes_per_vertex)), about 88 B of solver
    /// state per vertex on a triangle mesh.
    pub const VECTOR_BYTES_PER_VERTEX: usize = 3 * 12 + 4;

    /// The chunks whose forces read one of the `moved` vertices (internal indices), into
    /// `chunks` (sorted, no repeats).
    fn readers_of(&self, moved: &[u32], chunks: &mut Vec<u32>) {
        chunks.clear();
        let mut last = usize::MAX;
        for &v in moved {
            let c = v as usize / kernels::CHUNK;
            if c != last {
                chunks.extend(self.chunk_readers.get(c).into_iter().flatten());
                last = c;
            }
        }
        chunks.sort_unstable();
        chunks.dedup();
    }

    fn to_internal<T: Copy + Send + Sync>(&self, data: &[T]) -> Vec<T> {
        self.order.par_iter().map(|&o| data[o as usize]).collect()
    }

    fn to_caller<T: Copy + Send + Sync>(&self, internal: &[T], out: &mut [T]) {
        out.par_iter_mut()
            .zip(self.rank.par_iter())
            .for_each(|(o, &r)| *o = internal[r as usize]);
    }

    fn frame<'a>(
        &'a self,
        external: Option<&'a [Vec3]>,
        anchors: Option<&'a SlicedAnchors>,
        par: Par<'a>,
    ) -> Frame<'a> {
        Frame {
            sell: &self.sell,
            spring_diagonal: &self.spring_diagonal,
            isa: simd::Isa::detect(self.vertex_count()),
            external,
            anchors,
            par,
        }
    }

    /// Spring forces on every vertex at positions `x` (caller's order), with no loads.
    pub fn spring_forces(&self, x: &[Vec3]) -> Result<Vec<Vec3>, SolverError> {
        check_len("positions", x.len(), self.vertex_count())?;
        let xi = self.to_internal(x);
        let mut f = vec![Vec3::ZERO; xi.len()];
        let mut partial = vec![Sums::default(); kernels::chunks(xi.len())];
        self.frame(None, None, Par::Pool)
            .gather(&xi, None, &mut f, &mut partial);
        let mut out = vec![Vec3::ZERO; xi.len()];
        self.to_caller(&f, &mut out);
        Ok(out)
    }

    /// Elastic energy of the springs at positions `x` (caller's order), J.
    pub fn spring_energy(&self, x: &[Vec3]) -> Result<f64, SolverError> {
        check_len("positions", x.len(), self.vertex_count())?;
        let xi = self.to_internal(x);
        let mut f = vec![Vec3::ZERO; xi.len()];
        let mut partial = vec![Sums::default(); kernels::chunks(xi.len())];
        Ok(self
            .frame(None, None, Par::Pool)
            .gather(&xi, None, &mut f, &mut partial)
            .energy)
    }

    /// Moves `x` (caller's order; the warm start) to the equilibrium of the springs under
    /// `loads`, by Jacobi-preconditioned nonlinear conjugate gradients on the total energy.
    ///
    /// Every accepted step strictly lowers the energy (a backtracking line search rejects any
    /// that does not), so the energy never rises from one iteration to the next; when no step
    /// can lower it any more the solve stops as [`StopReason::Stalled`].
    pub fn relax(
        &self,
        x: &mut [Vec3],
        loads: &Loads<'_>,
        config: &RelaxConfig,
    ) -> Result<RelaxReport, SolverError> {
        self.relax_projected(x, loads, config, None)
    }

    /// [`relax`](Self::relax) with a constraint projection before the first step and after
    /// every accepted one. A projection may raise the energy: the monotone-energy guarantee holds
    /// between projections. The contacts the projection reports
    /// ([`Projection::active_contacts`]) and whose net force pushes into the constraint are held:
    /// their normal force leaves the residual and the search direction, so the solve converges
    /// on the contact set (see the module documentation).
    pub fn relax_projected(
        &self,
        x: &mut [Vec3],
        loads: &Loads<'_>,
        config: &RelaxConfig,
        projection: Option<&mut dyn Projection>,
    ) -> Result<RelaxReport, SolverError> {
        self.lead(x, loads, config, projection, Clock(None))
    }

    /// [`relax`](Self::relax), with the wall time of its loops added to `times` (the bench's
    /// breakdown of an iteration). The same answers: the timers only read the clock.
    pub(crate) fn relax_timed(
        &self,
        x: &mut [Vec3],
        loads: &Loads<'_>,
        config: &RelaxConfig,
        times: &mut LoopTimes,
    ) -> Result<RelaxReport, SolverError> {
        let start = Instant::now();
        let report = self.lead(x, loads, config, None, Clock(Some(&mut *times)));
        times.total += start.elapsed().as_secs_f64();
        report
    }

    /// Runs the solve as the leader of a team of the pool's threads (see `team`).
    fn lead(
        &self,
        x: &mut [Vec3],
        loads: &Loads<'_>,
        config: &RelaxConfig,
        projection: Option<&mut dyn Projection>,
        clock: Clock<'_>,
    ) -> Result<RelaxReport, SolverError> {
        // The whole solve runs on the rayon pool as the leader of a team (see `team`): each
        // iteration has several short parallel loops, and handed to rayon one by one every
        // loop would wait for a sleeping worker to wake up (futex round trips that cost more
        // than a 10k-vertex loop). The team's helpers stay awake for the whole solve.
        let helpers = team_size(self.vertex_count()) - 1;
        Team::lead(helpers, |team| {
            self.relax_on_pool(x, loads, config, projection, team, clock)
        })
    }

    /// [`relax_projected`](Self::relax_projected), on a worker of the rayon pool.
    fn relax_on_pool(
        &self,
        x: &mut [Vec3],
        loads: &Loads<'_>,
        config: &RelaxConfig,
        mut projection: Option<&mut dyn Projection>,
        team: &Team,
        mut clock: Clock<'_>,
    ) -> Result<RelaxReport, SolverError> {
        let par = Par::Team(team);
        let n = self.vertex_count();
        check_len("positions", x.len(), n)?;
        check_finite("position", x)?;
        if let Some(f) = loads.forces {
            check_len("forces", f.len(), n)?;
            check_finite("force", f)?;
        }
        if let Some(p) = loads.pinned {
            check_len("pinned", p.len(), n)?;
        }
        // The anchors laid out for the kernels, checked finite as they are.
        let anchors = match loads.anchors {
            Some(a) => {
                check_len("anchors", a.len(), n)?;
                let sliced = SlicedAnchors::finite(a, &self.order, par);
                let Some(sliced) = sliced else {
                    return Err(SolverError::NonFinite {
                        what: "anchor",
                        vertex: a.iter().position(|a| !a.is_finite()).unwrap_or(0),
                    });
                };
                Some(sliced)
            }
            None => None,
        };
        let external = loads.forces.map(|f| self.to_internal(f));
        let pinned = match loads.pinned {
            Some(p) => self.to_internal(p),
            None => vec![false; n],
        };
        let frame = self.frame(external.as_deref(), anchors.as_ref(), par);
        let mut xi = self.to_internal(x);

        // The inverse diagonal carries the pin flags (as its sign).
        let inv_diag = frame.inverse_diagonal(&pinned);
        let chunks = kernels::chunks(n);
        let mut sums_scratch = vec![Sums::default(); chunks];
        let mut scalar_scratch = vec![0.0f64; chunks];
        // Each block's largest direction component, for the projection's motion bounds.
        let mut reach = vec![0.0f32; n.div_ceil(STEP_BLOCK)];
        let mut r = vec![Vec3::ZERO; n];
        let mut spills = Spills::new();
        let mut stale = Vec::new();
        // The projection's active contacts and the ones held (their normal force is taken by
        // the contact, so it leaves the residual and the directions).
        let mut contacts = ContactSet::default();
        if let Some(p) = projection.as_deref_mut() {
            p.hold(&[]);
            p.project(&mut xi, &self.order);
        }
        let mut sums = clock.time(
            |l| &mut l.force,
            || frame.gather(&xi, Some(&inv_diag), &mut r, &mut sums_scratch),
        );
        // `Σ β²` of the held contacts that pull away (see `ContactSet::constrain`): part of the
        // residual the convergence test sees, though not of the directions.
        let mut chopped_rr = 0.0;
        if let Some(p) = projection.as_deref_mut() {
            contacts.refresh(p.active_contacts());
            chopped_rr = contacts.constrain(&mut r, &inv_diag, &mut sums).chopped_rr;
            p.hold(&contacts.held_flags);
        }
        let mut energy = sums.energy;
        let external_norm = external.as_deref().map_or(0.0, |f| {
            let free: Vec<Vec3> = f
                .iter()
                .zip(&pinned)
                .map(|(f, p)| if *p { Vec3::ZERO } else { *f })
                .collect();
            dot(par, &free, &free, &mut scalar_scratch).sqrt()
        });
        let mut r_norm = (sums.rr + chopped_rr).sqrt();
        let scale = config
            .force_scale
            .map(f64::from)
            .unwrap_or(if external_norm > 0.0 {
                external_norm
            } else {
                r_norm
            });
        let mut history = Vec::new();
        if config.record_energy {
            history.push(energy);
        }
        let report = |iterations, r_norm: f64, energy, stop, history| RelaxReport {
            iterations,
            residual: if scale > 0.0 {
                (r_norm / scale) as f32
            } else {
                0.0
            },
            energy,
            stop,
            force_scale: scale as f32,
            energy_history: history,
        };
        let converged = |r_norm: f64| r_norm <= config.tolerance as f64 * scale;

        // d = z = w r (preconditioned steepest descent), slope = r·d.
        let mut d = vec![Vec3::ZERO; n];
        let mut rz = sums.rzr;
        let mut slope = clock.time(
            |l| &mut l.direction,
            || {
                steepest(
                    par,
                    (&mut d, &r, &inv_diag),
                    &contacts,
                    (&mut scalar_scratch, &mut reach),
                )
            },
        );
        let mut iterations = 0;
        let mut stop = StopReason::Budget;
        let (mut best, mut best_at) = (r_norm, 0u32);
        // The last step was a proportioning step: the next direction starts afresh.
        let mut after_proportioning = false;
        // Whether the projection saw a step (it then expects `settled` at the end).
        let mut stepped = false;
        // The moves of a projection run alongside the force gather (`project_step_deferred`).
        // A trial step the solve rejects after such a pass costs a whole pass after it: after
        // `ALONGSIDE_MISSES` of them the solve's passes follow the gather instead (a solve from
        // rest often rejects its first trial; one that rejects many trials rejects more).
        let mut moves: Vec<(u32, Vec3)> = Vec::new();
        let mut misses = 0;
        while iterations < config.max_iterations {
            if converged(r_norm) {
                stop = StopReason::Converged;
                break;
            }
            if r_norm < 0.9 * best {
                (best, best_at) = (r_norm, iterations);
            } else if config.stagnation_window > 0
                && iterations - best_at >= config.stagnation_window
            {
                stop = StopReason::Stalled;
                break;
            }
            if slope <= 0.0 {
                // Not a descent direction: restart with steepest (preconditioned) descent.
                slope = clock.time(
                    |l| &mut l.direction,
                    || {
                        steepest(
                            par,
                            (&mut d, &r, &inv_diag),
                            &contacts,
                            (&mut scalar_scratch, &mut reach),
                        )
                    },
                );
                if rz <= 0.0 || slope <= 0.0 {
                    stop = StopReason::Stalled;
                    break;
                }
            }
            let curvature = clock.time(
                |l| &mut l.curvature,
                || frame.curvature(&xi, &d, &mut scalar_scratch),
            );
            let mut alpha = if curvature > 0.0 {
                slope / curvature
            } else {
                1.0
            };
            // `x` moves to the trial point `x + a d` in place, so that the force gather there
            // reads one row per neighbour (not `x` and `d` to form the point); the solver keeps
            // no copy of the last point: the step notes the few floats `x + a d − a d` would
            // not give back, and a rejected trial is undone bit for bit. The gather overwrites
            // `r`, reading the old force for `Σ w r·r_old` first; a rejected trial restores it.
            let mut accepted = None;
            let mut at = 0.0f32;
            // The projection's pass at the trial point when it ran alongside the gather (what
            // it returned: whether it moved a vertex; see `Projection::project_step_deferred`).
            let mut alongside = None;
            // A rejected trial after such a pass: the accepted one is projected whole.
            let mut whole = false;
            for attempt in 0..30 {
                if attempt > 0 {
                    clock.time(|l| &mut l.step, || retreat(par, &mut xi, &d, at, &spills));
                    if let (Some(_), Some(p)) = (alongside.take(), projection.as_deref_mut()) {
                        // The pass saw a point the solver left: it hears where it is instead.
                        p.settled(&xi);
                        whole = true;
                        misses += 1;
                    }
                    clock.time(
                        |l| &mut l.force,
                        || frame.gather(&xi, Some(&inv_diag), &mut r, &mut sums_scratch),
                    );
                    contacts.reapply(&mut r);
                }
                let a = alpha as f32;
                clock.time(
                    |l| &mut l.step,
                    || advance(par, &mut xi, &d, a, &mut spills),
                );
                at = a;
                let alongside_now = attempt == 0 && misses < ALONGSIDE_MISSES;
                let sums = match projection.as_deref_mut().filter(|_| alongside_now) {
                    // The projection's pass reads the trial point as the gather does, so it runs
                    // in the gather's loop (one member resolving the few vertices near a
                    // collider while the other gathers); its moves wait for the verdict.
                    Some(p) => {
                        let step = Step {
                            d: &d,
                            a,
                            spills: &spills,
                            reach: &reach,
                        };
                        let (sums, pass) = clock.time(
                            |l| &mut l.force,
                            || {
                                frame.gather_along_with(
                                    (&xi, &d, Some(&inv_diag)),
                                    &mut r,
                                    &mut sums_scratch,
                                    || p.project_step_deferred(&xi, &self.order, &step, &mut moves),
                                )
                            },
                        );
                        if pass.is_some() {
                            stepped = true;
                        }
                        alongside = pass;
                        sums
                    }
                    None => clock.time(
                        |l| &mut l.force,
                        || frame.gather_along(&xi, &d, Some(&inv_diag), &mut r, &mut sums_scratch),
                    ),
                };
                if sums.energy < energy {
                    accepted = Some(sums);
                    break;
                }
                alpha *= 0.5;
            }
            let Some(mut sums) = accepted else {
                // Back to the last point and its force.
                retreat(par, &mut xi, &d, at, &spills);
                let mut sums = frame.gather(&xi, Some(&inv_diag), &mut r, &mut sums_scratch);
                let c = contacts.constrain(&mut r, &inv_diag, &mut sums);
                r_norm = (sums.rr + c.chopped_rr).sqrt();
                stop = StopReason::Stalled;
                break;
            };
            energy = sums.energy;
            iterations += 1;
            // `Σ w r·r_old` against the previous (projected) residual, taken at the trial point:
            // a projection that keeps the held set only corrects a drift, and the held
            // vertices' residuals are tangent to their contacts before and after.
            let rz_old = sums.rz_old;
            // `Σ r·d` at the trial point, from the same gather, corrected below where the
            // held contacts change `r`.
            let mut rd = sums.rd;
            let mut proportioning = false;
            let mut hold_restart = false;
            if let Some(p) = projection.as_deref_mut() {
                let step = Step {
                    d: &d,
                    a: at,
                    spills: &spills,
                    reach: &reach,
                };
                let moved = match alongside {
                    Some(moved) => {
                        for &(i, to) in &moves {
                            xi[i as usize] = to;
                        }
                        moved
                    }
                    None if whole => {
                        clock.time(|l| &mut l.projection, || p.project(&mut xi, &self.order))
                    }
                    None => clock.time(
                        |l| &mut l.projection,
                        || p.project_step(&mut xi, &self.order, &step),
                    ),
                };
                stepped = true;
                if moved {
                    // The forces again where they read a moved vertex (every chunk when the
                    // projection does not say which moved): the same sums as a whole gather.
                    sums = match p.moved_vertices() {
                        Some(moved) => {
                            self.readers_of(moved, &mut stale);
                            frame.regather(&xi, Some(&inv_diag), &mut r, &mut sums_scratch, &stale)
                        }
                        None => frame.gather(&xi, Some(&inv_diag), &mut r, &mut sums_scratch),
                    };
                    energy = sums.energy;
                    rd = dot(par, &r, &d, &mut scalar_scratch);
                }
                contacts.refresh(p.active_contacts());
                rd -= contacts.dot_at_contacts(&r, &d);
                let c = contacts.constrain(&mut r, &inv_diag, &mut sums);
                rd += contacts.dot_at_contacts(&r, &d);
                chopped_rr = c.chopped_rr;
                // A release restarts the directions with a proportioning step: only the
                // released vertices move, along their own forces (see
                // `ContactSet::proportioning_direction`), and the conjugate gradients start
                // afresh after it. A new hold only projects the old direction onto the new
                // contact's tangent plane and keeps the conjugacy of the rest of the mesh:
                // restarting on every new hold (as on a release) had a contact frame run as
                // steepest descent while the contacts at a patch's rim landed one by one,
                // each release followed by a few re-holds.
                proportioning = c.released;
                // Except in a solve's first iterations, where a collider that moved since the
                // last solve (a substep) pushes whole rings of vertices onto it: those holds
                // restart the directions, whose conjugacy they break for most of the mesh.
                hold_restart = c.new_hold && iterations <= EARLY_HOLD_RESTARTS;
                p.hold(&contacts.held_flags);
            }
            if proportioning || hold_restart {
                // A release is progress the residual does not show (it may jump up as the
                // released contacts' pulls rejoin the free residual): the stagnation window
                // starts again; so does an early new hold. Later new holds restart neither it
                // nor the directions.
                best_at = iterations;
                best = (sums.rr + chopped_rr).sqrt();
            }
            if config.record_energy {
                history.push(energy);
            }
            r_norm = (sums.rr + chopped_rr).sqrt();
            // Hestenes-Stiefel, preconditioned and capped by Fletcher-Reeves:
            // `β = max(0, min(Σ w r·(r − r_old) / d·(r_old − r), Σ w r·r / Σ w r_old·r_old))`,
            // restarted after a proportioning step. Its denominator, the change of the slope
            // along `d` over the step, keeps the new direction conjugate to the old one over
            // that step whatever the step length; Polak-Ribiere's (`Σ w r_old·r_old`) equals it
            // only after an exact line search, which the Gauss-Newton step is not where
            // compressed springs buckle (see the module documentation).
            let beta = if after_proportioning || hold_restart || rz <= 0.0 {
                0.0
            } else {
                let slope_change = slope - rd;
                if slope_change > 0.0 {
                    ((sums.rzr - rz_old) / slope_change)
                        .min(sums.rzr / rz)
                        .max(0.0)
                } else {
                    0.0
                }
            };
            rz = sums.rzr;
            after_proportioning = proportioning;
            slope = clock.time(
                |l| &mut l.direction,
                || {
                    let slope = if proportioning {
                        // A proportioning step: only the released vertices move (see
                        // `ContactSet::proportioning_direction`); the next iteration restarts.
                        let slope = contacts.proportioning_direction(&mut d, &r, &inv_diag);
                        block_reach(&d, &mut reach);
                        slope
                    } else {
                        update_direction(
                            par,
                            &mut d,
                            &r,
                            &inv_diag,
                            beta as f32,
                            (&mut scalar_scratch, &mut reach),
                        )
                    };
                    slope + contacts.constrain_direction(&mut d, &r)
                },
            );
        }
        if stop == StopReason::Budget && converged(r_norm) {
            stop = StopReason::Converged;
        }
        if let Some(p) = projection.filter(|_| stepped) {
            p.settled(&xi);
        }
        self.to_caller(&xi, x);
        Ok(report(iterations, r_norm, energy, stop, history))
    }
}

/// The preconditioned steepest-descent direction `d = w r` without the held contacts'
/// normal components (with each block's largest component in `reach`); returns the slope
/// `Σ r·d`.
fn steepest(
    par: Par<'_>,
    (d, r, w): (&mut [Vec3], &[Vec3], &[f32]),
    contacts: &ContactSet,
    scratch: (&mut [f64], &mut [f32]),
) -> f64 {
    update_direction(par, d, r, w, 0.0, scratch) + contacts.constrain_direction(d, r)
}

/// Each block's largest `|d|` component into `reach` (one entry per [`STEP_BLOCK`] vertices).
fn block_reach(d: &[Vec3], reach: &mut [f32]) {
    for (r, block) in reach.iter_mut().zip(d.chunks(STEP_BLOCK)) {
        *r = block
            .iter()
            .fold(0.0f32, |m, v| m.max(v.abs().max_element()));
    }
}

/// Trial steps rejected after a projection pass run alongside the force gather
/// ([`Projection::project_step_deferred`]) after which a solve projects after the gather.
const ALONGSIDE_MISSES: u32 = 2;

/// Members of the team a solve of `n` vertices runs on: one per thread of the current rayon
/// pool, at most one per chunk of its loops (a helper with no chunk would only spin).
pub(crate) fn team_size(n: usize) -> usize {
    kernels::chunks(n).min(rayon::current_num_threads()).max(1)
}

fn check_len(what: &'static str, given: usize, expected: usize) -> Result<(), SolverError> {
    if given == expected {
        Ok(())
    } else {
        Err(SolverError::Length {
            what,
            given,
            expected,
        })
    }
}

/// Every edge joins two different vertices below `n`, and has a finite non-negative stiffness
/// and rest length.
fn check_springs(
    n: usize,
    edges: &[[u32; 2]],
    stiffness: &[f32],
    rest_lengths: &[f32],
) -> Result<(), SolverError> {
    check_len("stiffness", stiffness.len(), edges.len())?;
    check_len("rest lengths", rest_lengths.len(), edges.len())?;
    for (e, &[a, b]) in edges.iter().enumerate() {
        if a as usize >= n || b as usize >= n || a == b {
            return Err(SolverError::BadEdge {
                edge: e,
                a,
                b,
                vertex_count: n,
            });
        }
        let (k, rest) = (stiffness[e], rest_lengths[e]);
        if !(k.is_finite() && k >= 0.0 && rest.is_finite() && rest >= 0.0) {
            return Err(SolverError::BadSpring { edge: e, k, rest });
        }
    }
    Ok(())
}

fn check_finite(what: &'static str, v: &[Vec3]) -> Result<(), SolverError> {
    // Every float read without a branch (the common case: all finite), the first bad one
    // found only when there is one.
    let finite = |p: &Vec3| p.x.is_finite() & p.y.is_finite() & p.z.is_finite();
    if v.iter().fold(true, |ok, p| ok & finite(p)) {
        return Ok(());
    }
    let vertex = v.iter().position(|p| !finite(p)).unwrap_or(0);
    Err(SolverError::NonFinite { what, vertex })
}

#[cfg(test)]
mod tests;
