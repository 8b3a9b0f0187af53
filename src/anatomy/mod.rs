//! Muscles and bones as physics (Dima, Dima & Cristea 2009): particles, springs, pressure cells, rigid bones, muscle lattices.
//!
//! The engine is a mass-spring particle system integrated by velocity Verlet with drag
//! ([`dynamics::AnatomySystem`]). On top of plain springs it supports:
//!
//! - **pressure cells** ([`pressure::PressureCell`]): closed triangulated surfaces filled with an
//!   isothermal ideal gas, `P = P0 V0 / V`, pushing on each face with `P * area` along its
//!   outward normal (minus the pressure outside the cell);
//! - **rigid bodies** ([`rigid::BoneDesc`]): bones built from a triangle mesh whose particles keep
//!   their distances; spring forces on them give a net force and a torque that changes the angular
//!   momentum `L = I w`; a bone may instead be kinematic (driven by a pose every step);
//! - **muscle lattices** ([`lattice::MuscleLattice`]): built from a closed muscle surface and a
//!   contraction poly-line as the paper describes, contracted by an activation in `[0, 1]`;
//! - **insertions**: springs from bone particles to a muscle's end sections;
//! - **muscle-bone contact**: muscle particles are projected out of bones.
//!
//! [`scenes::jaw`] builds the paper's Fig. 1 scene (a platysma-like muscle opening a hinged jaw).
//!
//! ```
//! use dermis::anatomy::dynamics::{AnatomySystem, DynamicsConfig};
//! use glam::Vec3;
//! // Two 1 kg particles on a 100 N/m spring, stretched by 1 cm, no drag.
//! let mut sys = AnatomySystem::new(DynamicsConfig { dt_s: 1e-3, substeps: 1, drag: 0.0, ..Default::default() }).unwrap();
//! let a = sys.add_particle(Vec3::ZERO, 1.0).unwrap();
//! let b = sys.add_particle(Vec3::new(1.01, 0.0, 0.0), 1.0).unwrap();
//! sys.add_spring(a, b, 100.0, 1.0).unwrap();
//! let e0 = sys.total_energy();
//! for _ in 0..1000 {
//!     sys.step().unwrap();
//! }
//! assert!((sys.total_energy() - e0).abs() < 1e-3 * e0);
//! ```

pub mod dynamics;
pub mod export;
pub mod lattice;
pub mod pressure;
pub mod rigid;
pub mod scenes;

use thiserror::Error;

use crate::mesh::TopologyError;

/// Why an anatomy model or a simulation call was rejected. Every variant names the offending
/// element; its docs say how to fix the input.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum AnatomyError {
    /// A mesh given to the anatomy builders is not a valid triangle mesh. Fix the mesh as the
    /// inner error says.
    #[error("invalid mesh: {0}")]
    Topology(#[from] TopologyError),
    /// A surface that must enclose a volume (pressure cell, muscle surface) has a boundary edge,
    /// an edge used by more than two faces, or inconsistently oriented faces. Close the surface
    /// and orient all its faces the same way.
    #[error(
        "surface is not closed and consistently oriented: directed edge ({a}, {b}) has no single opposite"
    )]
    OpenSurface {
        /// First vertex of the offending edge.
        a: u32,
        /// Second vertex of the offending edge.
        b: u32,
    },
    /// A closed surface encloses a non-positive volume: its faces point inwards (or it is flat).
    /// Reverse the winding of every face.
    #[error("cell {cell} encloses a non-positive volume {volume_m3} m³ (faces point inwards?)")]
    InvertedCell {
        /// Index of the cell (in the order given to the builder or system).
        cell: usize,
        /// The signed volume found.
        volume_m3: f32,
    },
    /// A contraction poly-line needs at least two points.
    #[error("the contraction poly-line has {points} point(s); it needs at least 2")]
    PolylineTooShort {
        /// Number of points given.
        points: usize,
    },
    /// Two consecutive poly-line points coincide. Remove the duplicate point.
    #[error("poly-line segment {segment} has zero length")]
    DegenerateSegment {
        /// Index of the segment (between points `segment` and `segment + 1`).
        segment: usize,
    },
    /// The plane of a cross-section does not cut the muscle surface around its poly-line point.
    /// Keep the poly-line inside the muscle, with its ends just inside the muscle's ends.
    #[error("cross-section {section} does not cut the muscle surface around the poly-line")]
    NoCrossSection {
        /// Index of the cross-section, from the poly-line's start.
        section: usize,
    },
    /// A ray from a cross-section's centroid does not reach its outline, so radial similarity
    /// cannot map the lattice into it. Cross-sections must be star-shaped about their centroids.
    #[error("cross-section {section} is not star-shaped about its centroid")]
    NotStarShaped {
        /// Index of the cross-section.
        section: usize,
    },
    /// The lattice cell area is too large to put a single triangle in the main cross-section.
    /// Use a smaller cell area.
    #[error(
        "a cell area of {cell_area_m2} m² leaves the main cross-section (area {section_area_m2} m²) without a triangle"
    )]
    EmptyLattice {
        /// Requested area of one lattice triangle.
        cell_area_m2: f32,
        /// Area of the largest cross-section.
        section_area_m2: f32,
    },
    /// An activation outside `[0, 1]` (or NaN) was requested.
    #[error("activation {activation} of muscle {muscle} is outside [0, 1]")]
    ActivationOutOfRange {
        /// Index of the muscle.
        muscle: usize,
        /// The activation given.
        activation: f32,
    },
    /// A parameter is NaN, infinite, or outside its allowed range (masses, stiffnesses, pressures
    /// and time steps must be positive or at least non-negative as documented).
    #[error("parameter `{name}` has invalid value {value}")]
    InvalidParameter {
        /// Name of the parameter.
        name: &'static str,
        /// The value given.
        value: f32,
    },
    /// A position or vector input is NaN or infinite.
    #[error("{what} {index} is not finite")]
    NonFinite {
        /// What kind of input (for example `"particle position"`).
        what: &'static str,
        /// Its index.
        index: usize,
    },
    /// An index refers to a particle, body, muscle or cell that does not exist.
    #[error("{what} index {index} is out of range (there are {count})")]
    IndexOutOfRange {
        /// What kind of object.
        what: &'static str,
        /// The bad index.
        index: usize,
        /// How many exist.
        count: usize,
    },
    /// A particle already belongs to a rigid body. Give each bone its own particles.
    #[error("particle {particle} already belongs to rigid body {body}")]
    ParticleOwned {
        /// The particle.
        particle: usize,
        /// The body that owns it.
        body: usize,
    },
    /// The particles of a rigid body are collinear (or a single point), so its inertia tensor
    /// cannot be inverted. Give the bone a mesh with some extent in every direction.
    #[error("rigid body {body} has a singular inertia tensor (collinear particles)")]
    DegenerateBody {
        /// Index of the body.
        body: usize,
    },
    /// Only kinematic bodies can be driven by a pose.
    #[error("rigid body {body} is dynamic, not kinematic; it cannot be driven by a pose")]
    NotKinematic {
        /// Index of the body.
        body: usize,
    },
    /// parry3d rejected the bone mesh as a collider. Fix the bone mesh (closed, oriented).
    #[error("rigid body {body} cannot be a collider: {message}")]
    Collider {
        /// Index of the body.
        body: usize,
        /// parry3d's reason.
        message: String,
    },
    /// The simulation produced a NaN or infinite position; the step was rolled back. Lower the
    /// time step, raise the substeps or the drag, or soften the stiffest spring.
    #[error("particle {particle} became non-finite; the step was rolled back")]
    Diverged {
        /// The first particle found non-finite.
        particle: usize,
    },
}

/// Returns `Err(InvalidParameter)` unless `value` is finite and `value > 0`.
pub(crate) fn positive(name: &'static str, value: f32) -> Result<f32, AnatomyError> {
    if value.is_finite() && value > 0.0 {
        Ok(value)
    } else {
        Err(AnatomyError::InvalidParameter { name, value })
    }
}

/// Returns `Err(InvalidParameter)` unless `value` is finite and `value >= 0`.
pub(crate) fn non_negative(name: &'static str, value: f32) -> Result<f32, AnatomyError> {
    if value.is_finite() && value >= 0.0 {
        Ok(value)
    } else {
        Err(AnatomyError::InvalidParameter { name, value })
    }
}
