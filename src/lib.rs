//! # dermis
//!
//! Anatomical skin as a triangulated spring mesh that slides over muscles and bones and settles
//! into elastic equilibrium every animation frame.
//!
//! The crate is a pure core (plain structs and functions, usable without any ECS) under a thin
//! bevy_ecs layer. Units are SI throughout: metres, newtons, seconds; the 2D Young's modulus
//! `E2` is in N/m.
//!
//! | module | what it holds |
//! |---|---|
//! | [`mesh`] | validated triangle and tetrahedral topology, quality report |
//! | [`stiffness`] | per-edge spring stiffness (Van Gelder Eq. 27, 29, 30, baselines) |
//! | [`solver`] | spring forces and energy, quasi-static relaxation |
//! | [`fem`] | constant-strain membrane FEM, the reference the springs are measured against |
//! | [`paper`] | the source paper's experiments, reproducible |

pub mod collision;
pub mod fem;
pub mod io;
pub mod mesh;
pub mod paper;
pub mod solver;
pub mod stiffness;

/// The types most programs need.
pub mod prelude {
    pub use crate::mesh::{TetMesh, TopologyError, TriMesh};
    pub use crate::solver::{RelaxConfig, RelaxReport, SpringSystem};
    pub use crate::stiffness::{Modulus, StiffnessRule};
}
