//! Skin as ECS: components, the frame's system sets, the stiffness and relaxation systems, and
//! [`DermisPlugin`].
//!
//! The [crate-level guide](crate) walks through a standalone `World`, the frame pipeline, the
//! feature flags and an FAQ. [`spawn_scene`] turns a glTF [`Scene`](crate::gltf::Scene) into
//! skins and colliders played on a fixed clock; [`capture_state`] and [`restore_state`]
//! checkpoint it.

mod anatomy;
mod components;
mod scene;
mod spawn;
mod systems;

pub use anatomy::*;
pub use components::*;
pub use scene::*;
pub use spawn::*;
pub use systems::*;

use bevy_ecs::prelude::*;
use bevy_ecs::schedule::{LogLevel, ScheduleBuildSettings, ScheduleLabel};
use thiserror::Error;

use crate::collision::CollisionError;
use crate::mesh::TopologyError;
use crate::solver::SolverError;
use crate::stiffness::StiffnessError;

/// Why a skin could not be built, or why a system skipped it (see [`RelaxDiagnostics`]).
#[derive(Debug, Clone, PartialEq, Error)]
pub enum SkinError {
    /// The mesh is invalid; fix it in the modelling tool (the message names the element).
    #[error(transparent)]
    Topology(#[from] TopologyError),
    /// The material cannot give a stiffness (bad modulus, Poisson ratio, per-triangle count);
    /// fix the [`SkinMaterial`].
    #[error(transparent)]
    Stiffness(#[from] StiffnessError),
    /// The spring system rejected its input (for instance an [`EdgeStiffness`] or
    /// [`ExternalLoads`] array of the wrong length written by another system).
    #[error(transparent)]
    Solver(#[from] SolverError),
    /// An array does not have one entry per vertex; pass one per mesh vertex.
    #[error("{what} has {given} entries, expected one per vertex ({expected})")]
    Length {
        /// Which array.
        what: &'static str,
        /// Entries given.
        given: usize,
        /// Vertices in the mesh.
        expected: usize,
    },
    /// A position, anchor or force given to the builder is NaN or infinite; fix the data.
    #[error("{what} of vertex {vertex} is not finite")]
    NonFinite {
        /// Which input.
        what: &'static str,
        /// The vertex.
        vertex: usize,
    },
    /// A pinned vertex index is not a vertex of the mesh.
    #[error("pinned vertex {vertex} is out of range: the mesh has {vertex_count} vertices")]
    PinOutOfRange {
        /// The index given.
        vertex: u32,
        /// Vertices in the mesh.
        vertex_count: usize,
    },
    /// The entity has no skin components (it was not spawned by [`SkinBuilder`], or was
    /// despawned).
    #[error("entity {0} is not a skin")]
    NotASkin(Entity),
    /// The contact set-up rejected the frame (wrong vertex count, non-finite positions).
    #[error(transparent)]
    Collision(#[from] CollisionError),
}

/// The phases of one dermis frame, in order. [`DermisPlugin`] chains them; put your own systems
/// in the phase they belong to (`my_system.in_set(DermisSystems::Animate)`).
#[derive(SystemSet, Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum DermisSystems {
    /// Empty hook before everything else.
    First,
    /// Advance animation players, sample clips, compute joint matrices.
    Animate,
    /// Skin bone and muscle meshes and the skin anchors.
    Deform,
    /// Step muscle and bone physics.
    Muscles,
    /// Refresh collider shapes from the deformed vertices.
    Colliders,
    /// [`compute_edge_stiffness`] then [`rebuild_springs`], only for skins that changed.
    Stiffness,
    /// [`relax_skins`]: settle every skin, warm-started from the last frame.
    Relax,
    /// Hand the frame to a sink.
    Export,
    /// Empty hook after everything else.
    Last,
}

impl DermisSystems {
    /// Every phase, in frame order.
    pub const ORDER: [Self; 9] = [
        Self::First,
        Self::Animate,
        Self::Deform,
        Self::Muscles,
        Self::Colliders,
        Self::Stiffness,
        Self::Relax,
        Self::Export,
        Self::Last,
    ];
}

/// The label of the schedule made by [`DermisPlugin::build_schedule`].
#[derive(ScheduleLabel, Debug, Clone, PartialEq, Eq, Hash)]
pub struct DermisSchedule;

/// Adds the dermis resources, system sets and systems to a schedule: on a standalone `World`
/// with [`build_schedule`](Self::build_schedule) or [`add_to`](Self::add_to); with the `bevy_app`
/// feature, also a Bevy `Plugin` running in `Update`.
#[derive(Debug, Clone, Copy, Default)]
pub struct DermisPlugin;

impl DermisPlugin {
    /// Configures the chained [`DermisSystems`] and adds the dermis systems to `schedule`.
    /// Resources are not touched (see [`init_world`](Self::init_world)).
    pub fn configure(&self, schedule: &mut Schedule) {
        schedule.configure_sets(
            (
                DermisSystems::First,
                DermisSystems::Animate,
                DermisSystems::Deform,
                DermisSystems::Muscles,
                DermisSystems::Colliders,
                DermisSystems::Stiffness,
                DermisSystems::Relax,
                DermisSystems::Export,
                DermisSystems::Last,
            )
                .chain(),
        );
        schedule.add_systems((
            (compute_edge_stiffness, rebuild_springs)
                .chain()
                .in_set(DermisSystems::Stiffness),
            relax_skins.in_set(DermisSystems::Relax),
        ));
        scene::configure(schedule);
        anatomy::configure(schedule);
    }

    /// Inserts the resources the systems read, keeping any already present:
    /// [`DermisConfig`] and [`Messages<SkinQuarantined>`].
    pub fn init_world(&self, world: &mut World) {
        world.init_resource::<DermisConfig>();
        world.init_resource::<Messages<SkinQuarantined>>();
    }

    /// Everything a standalone `World` needs: the resources, the sets and systems, and
    /// [`update_skin_messages`] before [`DermisSystems::First`] (a Bevy `App` swaps message
    /// buffers itself).
    pub fn add_to(&self, world: &mut World, schedule: &mut Schedule) {
        self.init_world(world);
        self.configure(schedule);
        schedule.add_systems(update_skin_messages.before(DermisSystems::First));
    }

    /// A new [`DermisSchedule`] with everything added and ambiguous system order reported as an
    /// error: run it once per frame.
    pub fn build_schedule(&self, world: &mut World) -> Schedule {
        let mut schedule = Schedule::new(DermisSchedule);
        schedule.set_build_settings(ScheduleBuildSettings {
            ambiguity_detection: LogLevel::Error,
            ..Default::default()
        });
        self.add_to(world, &mut schedule);
        schedule
    }
}

#[cfg(feature = "bevy_app")]
impl bevy_app::Plugin for DermisPlugin {
    fn build(&self, app: &mut bevy_app::App) {
        app.init_resource::<DermisConfig>()
            .add_message::<SkinQuarantined>()
            .edit_schedule(bevy_app::Update, |schedule| self.configure(schedule));
    }
}

#[cfg(test)]
mod tests;
