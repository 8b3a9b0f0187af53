//! # dermis
//!
//! Anatomical skin as a triangulated spring mesh that slides over muscles and bones and settles
//! into elastic equilibrium every animation frame.
//!
//! The crate is a pure core (plain structs and functions, usable without any ECS) under a thin
//! `bevy_ecs` layer. Units are SI throughout: metres, newtons, seconds; the 2D Young's modulus
//! `E2` is in N/m.
//!
//! | module | what it holds |
//! |---|---|
//! | [`mesh`] | validated triangle and tetrahedral topology, quality report |
//! | [`stiffness`] | per-edge spring stiffness (Van Gelder Eq. 27, 29, 30, baselines) |
//! | [`collision`] | skin against deforming muscle and bone meshes: sliding contact, thickness, friction |
//! | [`solver`] | spring forces and energy, quasi-static relaxation |
//! | [`fem`] | constant-strain membrane FEM, the reference the springs are measured against |
//! | [`ecs`] | skin components, the frame's system sets and systems, [`ecs::DermisPlugin`] |
//! | [`anatomy`] | muscles and bones: velocity Verlet, pressure cells, rigid bones, lattices |
//! | [`animation`] | skeletons, clips (step/linear/cubic-spline), linear blend skinning |
//! | [`gltf`](mod@gltf) | glTF/GLB loading into a plain scene, roles, posing, the bundled arm |
//! | [`export`] | frame sinks: animated glTF, OBJ/PLY sequences, USD; strain colours |
//! | [`io`] | mesh and load files, atomic writes |
//! | [`paper`] | the source papers' experiments, reproducible |
//! | [`bench`](mod@bench) | the standard performance workloads behind `dermis bench` |
//!
//! # Guide
//!
#![doc = include_str!("guide.md")]

pub mod anatomy;
pub mod animation;
pub mod bench;
pub mod collision;
mod cpu;
pub mod ecs;
pub mod export;
pub mod fem;
pub mod gltf;
pub mod io;
pub mod mesh;
pub mod paper;
pub mod solver;
pub mod stiffness;
pub mod threads;

#[cfg(test)]
mod test_support {
    //! What several modules' unit tests share.

    /// Runs `f` on a fresh rayon pool of `threads` threads (for tests that results do not
    /// depend on the thread count).
    pub(crate) fn in_pool<R: Send>(threads: usize, f: impl FnOnce() -> R + Send) -> R {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("a thread pool")
            .install(f)
    }
}

/// The types most programs need.
pub mod prelude {
    pub use crate::mesh::{TetMesh, TopologyError, TriMesh};
    pub use crate::solver::{RelaxConfig, RelaxReport, SpringSystem};
    pub use crate::stiffness::{Modulus, StiffnessRule};
}
