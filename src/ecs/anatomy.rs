//! Muscles and bones as entities: an [`AnatomyRig`] stepped in [`DermisSystems::Muscles`], its muscles and bones serving as skin colliders.

use std::sync::Arc;

use bevy_ecs::prelude::*;
use glam::{Quat, Vec3};
use parry3d::math::Pose;
use thiserror::Error;

use super::components::{RelaxSettings, SkinAnchors, SkinContact, SkinMaterial};
use super::scene::{ColliderDrive, ColliderState, Tissue, VertexWeld};
use super::spawn::{SkinBuilder, vertex_normals};
use super::{DermisSystems, SkinError, refresh_colliders};
use crate::anatomy::AnatomyError;
use crate::anatomy::dynamics::AnatomySystem;
use crate::anatomy::rigid::BoneKind;
use crate::anatomy::scenes::{JawConfig, JawScene, jaw, sleeve_mesh};
use crate::collision::{ColliderMesh, CollisionError, ContactConfig, SkinCollision};

/// Why an anatomy rig could not be spawned or wired to a skin.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum RigError {
    /// The anatomy model rejected a call (the inner error names the muscle, bone or particle).
    #[error(transparent)]
    Anatomy(#[from] AnatomyError),
    /// A muscle surface or bone mesh cannot be a skin collider (open or inside-out mesh). Fix
    /// the mesh the bone was built from; muscle surfaces are closed by construction.
    #[error("{tissue:?} {index} cannot be a collider: {source}")]
    Collider {
        /// Muscle or bone.
        tissue: Tissue,
        /// Its index in the [`AnatomySystem`].
        index: usize,
        /// The reason.
        source: CollisionError,
    },
    /// The contact configuration of a skin is out of range; the message names the field.
    #[error("contact config: {0}")]
    Contact(CollisionError),
    /// `steps_per_frame` must be at least 1.
    #[error("steps_per_frame must be at least 1")]
    NoSteps,
    /// The entity is not a rig (or one of its muscles or bones) spawned by [`spawn_anatomy`].
    #[error("entity {0} is not part of an anatomy rig")]
    NotARig(Entity),
    /// A skin binding has the wrong length or names a bone the rig does not have.
    #[error("skin binding: {0}")]
    Binding(String),
    /// The skin could not be built (see the inner error).
    #[error(transparent)]
    Skin(#[from] SkinError),
}

/// The muscles-and-bones simulation of one body, owned by the rig entity.
///
/// The muscles and bones of one body are a single coupled particle system: insertion springs
/// join bone particles to muscle particles, contact pushes muscle particles out of bones and
/// the bones feel the reaction. Splitting that state over entities would make every step
/// gather and scatter it, so one **rig entity** owns the whole
/// [`AnatomySystem`] (this component), and each
/// muscle and bone is a **child entity** ([`ChildOf`] the rig) that exposes what a user
/// drives or reads:
///
/// | entity | inputs (you write) | outputs (the systems write) |
/// |---|---|---|
/// | rig | [`AnatomyRig::steps_per_frame`] | [`AnatomyDiagnostics`] |
/// | muscle | [`MuscleActivation`] | [`MuscleState`], [`ColliderState`] (surface vertices) |
/// | bone | [`BoneTarget`] (kinematic bones) | [`BonePose`], [`ColliderState`] (rigid pose) |
///
/// Muscle and bone entities carry [`Tissue`] and [`ColliderState`] exactly like the colliders
/// [`spawn_scene`](super::spawn_scene) makes, so the existing [`refresh_colliders`] system
/// refits a skin's muscle colliders ([`ColliderMesh::set_vertices`]) and moves its bone
/// colliders ([`ColliderMesh::set_pose`], no refit) in [`DermisSystems::Colliders`], and
/// [`relax_skins`](super::relax_skins) keeps the skin outside them. Wire a skin to them with
/// [`SpawnedAnatomy::skin_contact`].
///
/// Each frame, in [`DermisSystems::Muscles`] (chained): [`apply_anatomy_inputs`] copies
/// activations and kinematic targets into the rig, [`step_anatomy`] runs
/// [`AnatomyRig::steps_per_frame`] fixed steps (each of the system's fixed substeps), and
/// [`write_anatomy_outputs`] publishes poses, muscle surfaces and volumes, then
/// [`follow_bones`] moves the anchors of skins bound to the bones ([`BoneSkinning`]).
///
/// ```
/// use bevy_ecs::prelude::*;
/// use dermis::anatomy::scenes::{JawConfig, jaw};
/// use dermis::ecs::*;
///
/// let scene = jaw(&JawConfig::default()).unwrap();
/// let mut world = World::new();
/// let mut schedule = DermisPlugin.build_schedule(&mut world);
/// let rig = spawn_anatomy(&mut world, scene.system, 5).unwrap();
/// let muscle = rig.muscles[scene.muscle];
/// world.get_mut::<MuscleActivation>(muscle).unwrap().0 = 1.0;
/// for _ in 0..20 {
///     schedule.run(&mut world);
/// }
/// let jaw_pose = world.get::<BonePose>(rig.bones[scene.jaw]).unwrap();
/// assert!(jaw_pose.angle_about(glam::Vec3::X) > 0.0, "the jaw opens");
/// ```
#[derive(Component, Debug, Clone)]
pub struct AnatomyRig {
    system: AnatomySystem,
    /// Fixed steps of [`DynamicsConfig::dt_s`](crate::anatomy::dynamics::DynamicsConfig::dt_s)
    /// (each of the config's substeps) run every frame: one frame lasts
    /// `steps_per_frame × dt_s`.
    pub steps_per_frame: u32,
    /// Kinematic bones to drive this frame: (body, pose at the frame's start, target).
    pending: Vec<(usize, BonePose, BonePose)>,
}

impl AnatomyRig {
    /// The simulation (read-only).
    pub fn system(&self) -> &AnatomySystem {
        &self.system
    }
    /// The simulation, mutable: for edits the components do not cover (new springs, body
    /// motion). Changing its muscles or bones after spawn is not reflected in the children.
    pub fn system_mut(&mut self) -> &mut AnatomySystem {
        &mut self.system
    }
    /// Simulated time per frame, s.
    pub fn frame_dt_s(&self) -> f64 {
        f64::from(self.system.config().dt_s) * f64::from(self.steps_per_frame)
    }
}

/// What the rig's systems did last frame.
#[derive(Component, Debug, Clone, Default, PartialEq)]
pub struct AnatomyDiagnostics {
    /// Frames stepped since spawn.
    pub frames: u64,
    /// Dynamics steps completed since spawn.
    pub steps: u64,
    /// The last frame's error: a rejected input (activation out of range, bad kinematic pose;
    /// the input is ignored) or a diverged step (rolled back, the frame's remaining steps
    /// skipped). `None` when the last frame went through.
    pub error: Option<AnatomyError>,
}

/// A muscle of the parent rig ([`ChildOf`] the rig entity).
#[derive(Component, Debug, Clone, Copy, PartialEq, Eq)]
#[require(MuscleActivation, MuscleState)]
pub struct AnatomyMuscle {
    /// Index of the muscle in the rig's [`AnatomySystem`].
    pub index: usize,
}

/// A muscle's activation in `[0, 1]`: write it to contract the muscle (its longitudinal rest
/// lengths shorten by `activation × max_contraction`). Applied at the next frame.
#[derive(Component, Debug, Clone, Copy, Default, PartialEq)]
pub struct MuscleActivation(pub f32);

/// A muscle's measured state after the last frame.
#[derive(Component, Debug, Clone, Copy, Default, PartialEq)]
pub struct MuscleState {
    /// Volume enclosed by the lattice, m³.
    pub volume_m3: f32,
    /// Volume at spawn, m³.
    pub rest_volume_m3: f32,
    /// Distance between the centroids of the first and last cross-sections, m.
    pub length_m: f32,
    /// That length at spawn, m.
    pub rest_length_m: f32,
}

impl MuscleState {
    /// `volume / rest volume` (1 when incompressible).
    pub fn volume_ratio(&self) -> f32 {
        self.volume_m3 / self.rest_volume_m3
    }
}

/// A bone of the parent rig ([`ChildOf`] the rig entity).
#[derive(Component, Debug, Clone, Copy, PartialEq, Eq)]
#[require(BonePose)]
pub struct AnatomyBone {
    /// Index of the body in the rig's [`AnatomySystem`].
    pub index: usize,
    /// Dynamic (moved by forces) or kinematic (follows its [`BoneTarget`]).
    pub kind: BoneKind,
}

/// A bone's pose relative to rest after the last frame: a rest point `p` is now at
/// `rotation * p + translation`.
#[derive(Component, Debug, Clone, Copy, PartialEq)]
pub struct BonePose {
    /// Rotation from rest.
    pub rotation: Quat,
    /// Translation, m.
    pub translation: Vec3,
}

impl Default for BonePose {
    fn default() -> Self {
        Self {
            rotation: Quat::IDENTITY,
            translation: Vec3::ZERO,
        }
    }
}

impl BonePose {
    /// Where rest point `p` is now.
    pub fn transform_point(&self, p: Vec3) -> Vec3 {
        self.rotation * p + self.translation
    }
    /// Signed rotation angle about the unit `axis`, radians, in `(-π, π]` (twist part of the
    /// swing-twist decomposition).
    pub fn angle_about(&self, axis: Vec3) -> f32 {
        let q = self.rotation;
        let q = if q.w < 0.0 { -q } else { q };
        2.0 * Vec3::new(q.x, q.y, q.z).dot(axis).atan2(q.w)
    }
}

/// Where a kinematic bone must be at the end of every frame (rest-relative, as [`BonePose`]):
/// each step of the frame moves it a fraction of the way there (slerp and lerp from its pose at
/// the frame's start), so it arrives with the frame's last step. A target on a dynamic bone is
/// rejected ([`AnatomyError::NotKinematic`] in [`AnatomyDiagnostics::error`]).
#[derive(Component, Debug, Clone, Copy, PartialEq)]
pub struct BoneTarget(pub BonePose);

/// A skin whose anchors follow the bones of a rig by linear blend skinning: every anchor target
/// is `Σ w_b (R_b p + t_b)` over its influences, from its rest target `p`.
#[derive(Component, Debug, Clone, PartialEq)]
pub struct BoneSkinning {
    /// The rig entity.
    pub rig: Entity,
    /// Per skin vertex: up to two (bone index, weight) pairs, weights summing to 1.
    pub influences: Vec<[(u32, f32); 2]>,
    /// Anchor targets at rest.
    pub rest_targets: Vec<Vec3>,
    /// Anchor normals at rest.
    pub rest_normals: Vec<Vec3>,
}

impl BoneSkinning {
    /// Binds a skin to `rig`'s bones: per vertex, its rest anchor target and normal and up to
    /// two (bone index, weight) influences. Errors on unequal lengths, a bone index the rig
    /// does not have, or weights that are negative, non-finite or do not sum to 1 (within 1e-4).
    pub fn new(
        world: &World,
        rig: Entity,
        influences: Vec<[(u32, f32); 2]>,
        rest_targets: Vec<Vec3>,
        rest_normals: Vec<Vec3>,
    ) -> Result<Self, RigError> {
        let system = world
            .get::<AnatomyRig>(rig)
            .ok_or(RigError::NotARig(rig))?
            .system();
        let n = influences.len();
        if rest_targets.len() != n || rest_normals.len() != n {
            return Err(RigError::Binding(format!(
                "{n} influences, {} targets, {} normals: give one of each per skin vertex",
                rest_targets.len(),
                rest_normals.len()
            )));
        }
        for (v, inf) in influences.iter().enumerate() {
            let sum: f32 = inf.iter().map(|i| i.1).sum();
            if inf.iter().any(|&(b, w)| {
                !(w.is_finite() && w >= 0.0) || (w > 0.0 && system.body(b as usize).is_none())
            }) || (sum - 1.0).abs() > 1e-4
            {
                return Err(RigError::Binding(format!(
                    "vertex {v}: influences {inf:?} need existing bones and weights >= 0 summing to 1"
                )));
            }
        }
        Ok(Self {
            rig,
            influences,
            rest_targets,
            rest_normals,
        })
    }
}

/// The entities [`spawn_anatomy`] made.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SpawnedAnatomy {
    /// The rig.
    pub rig: Entity,
    /// One entity per muscle, in the system's muscle order.
    pub muscles: Vec<Entity>,
    /// One entity per bone, in the system's body order.
    pub bones: Vec<Entity>,
}

impl SpawnedAnatomy {
    /// A [`SkinContact`] for a skin of `vertex_count` vertices touching every muscle and bone
    /// of the rig at their current shapes; insert it on the skin entity.
    pub fn skin_contact(
        &self,
        world: &World,
        vertex_count: usize,
        config: ContactConfig,
    ) -> Result<SkinContact, RigError> {
        let mut collision = SkinCollision::new(vertex_count, config).map_err(RigError::Contact)?;
        let mut colliders = Vec::new();
        let tagged = (self.muscles.iter().map(|e| (Tissue::Muscle, e)).enumerate())
            .chain(self.bones.iter().map(|e| (Tissue::Bone, e)).enumerate());
        for (index, (tissue, &entity)) in tagged {
            let state = world
                .get::<ColliderState>(entity)
                .ok_or(RigError::NotARig(entity))?;
            let mesh = current_collider(state, tissue, index)?;
            colliders.push((entity, collision.add_collider(mesh)));
        }
        Ok(SkinContact {
            collision,
            colliders,
        })
    }
}

/// The collider of `state` as it is now (rebuilt, so no stale motion is counted).
fn current_collider(
    state: &ColliderState,
    tissue: Tissue,
    index: usize,
) -> Result<ColliderMesh, RigError> {
    match state.drive {
        ColliderDrive::Deforming { .. } => ColliderMesh::from_mesh(
            state.local_vertices.clone(),
            state.triangles.as_ref().clone(),
        )
        .map_err(|source| RigError::Collider {
            tissue,
            index,
            source,
        }),
        ColliderDrive::Rigid { .. } => Ok(state.template.clone().with_pose(state.pose)),
    }
}

fn identity_weld(n: usize) -> VertexWeld {
    let ids: Vec<u32> = (0..n as u32).collect();
    VertexWeld {
        primitive_to_welded: ids.clone(),
        welded_to_primitive: ids,
    }
}

fn to_pose((rotation, translation): (Quat, Vec3)) -> Pose {
    Pose::from_parts(translation, rotation)
}

fn muscle_length(system: &AnatomySystem, muscle: usize) -> Result<f32, AnatomyError> {
    let sections = system.muscle(muscle).map_or(1, |m| m.sections());
    Ok((system.muscle_section_centroid(muscle, sections - 1)?
        - system.muscle_section_centroid(muscle, 0)?)
    .length())
}

/// Spawns `system` as a rig entity with a child entity per muscle and per bone (see the
/// [`AnatomyRig`] docs); `steps_per_frame` fixed steps run every frame.
///
/// Muscle-bone contacts, insertions and kinematic bones are whatever `system` was built with.
pub fn spawn_anatomy(
    world: &mut World,
    system: AnatomySystem,
    steps_per_frame: u32,
) -> Result<SpawnedAnatomy, RigError> {
    if steps_per_frame == 0 {
        return Err(RigError::NoSteps);
    }
    let mut muscle_bundles = Vec::new();
    for index in 0.. {
        let Some(m) = system.muscle(index) else { break };
        let surface = m.surface();
        let vertices = system.muscle_surface_positions(index)?;
        let template = ColliderMesh::from_mesh(vertices.clone(), surface.triangles.clone())
            .map_err(|source| RigError::Collider {
                tissue: Tissue::Muscle,
                index,
                source,
            })?;
        let (volume_m3, length_m) = (
            system.muscle_volume_m3(index)?,
            muscle_length(&system, index)?,
        );
        muscle_bundles.push((
            AnatomyMuscle { index },
            MuscleActivation(m.activation()),
            MuscleState {
                volume_m3,
                rest_volume_m3: volume_m3,
                length_m,
                rest_length_m: length_m,
            },
            Tissue::Muscle,
            ColliderState {
                drive: ColliderDrive::Deforming {
                    weld: identity_weld(vertices.len()),
                },
                local_vertices: vertices,
                triangles: Arc::new(surface.triangles.clone()),
                pose: Pose::IDENTITY,
                template,
            },
        ));
    }
    let mut bone_bundles = Vec::new();
    for index in 0.. {
        let Some(b) = system.body(index) else { break };
        let rest = b.rest_mesh_vertices();
        let triangles = b.triangles().to_vec();
        let pose = to_pose(b.pose());
        let template = ColliderMesh::from_mesh(rest.clone(), triangles.clone())
            .map_err(|source| RigError::Collider {
                tissue: Tissue::Bone,
                index,
                source,
            })?
            .with_pose(pose);
        let (rotation, translation) = b.pose();
        bone_bundles.push((
            AnatomyBone {
                index,
                kind: b.kind(),
            },
            BonePose {
                rotation,
                translation,
            },
            Tissue::Bone,
            ColliderState {
                local_vertices: rest,
                triangles: Arc::new(triangles),
                pose,
                drive: ColliderDrive::Rigid {
                    weld: None,
                    joint: None,
                },
                template,
            },
        ));
    }
    let rig = world
        .spawn((
            AnatomyRig {
                system,
                steps_per_frame,
                pending: Vec::new(),
            },
            AnatomyDiagnostics::default(),
        ))
        .id();
    let muscles = muscle_bundles
        .into_iter()
        .map(|b| world.spawn((b, ChildOf(rig))).id())
        .collect();
    let bones = bone_bundles
        .into_iter()
        .map(|b| world.spawn((b, ChildOf(rig))).id())
        .collect();
    Ok(SpawnedAnatomy {
        rig,
        muscles,
        bones,
    })
}

/// A skin sleeve around the jaw scene's muscle: an open cylinder on the muscle's axis, its
/// anchors skinned to the jaw (chin end) and the spine (neck end), touching every muscle and
/// bone of the rig.
#[derive(Debug, Clone, PartialEq)]
pub struct JawSkinConfig {
    /// Radius of the sleeve, m (the muscle's is [`JawScene::MUSCLE_RADIUS_M`]).
    pub radius_m: f32,
    /// Fraction of the muscle's length left bare at each end.
    pub margin: f32,
    /// Vertices around the sleeve.
    pub segments: u32,
    /// Rings of vertices along the sleeve, minus one.
    pub rings: u32,
    /// Material of the skin.
    pub material: SkinMaterial,
    /// Anchor stiffness along the skinned normal, N/m per vertex.
    pub anchor_k_normal_n_per_m: f32,
    /// Anchor stiffness across the skinned normal, N/m per vertex.
    pub anchor_k_tangent_n_per_m: f32,
    /// Contact with the muscle and bones.
    pub contact: ContactConfig,
    /// Relaxation budget per frame.
    pub relax: RelaxSettings,
}

impl Default for JawSkinConfig {
    /// A 12 mm sleeve (2 mm over the 10 mm muscle), 24 × 16 quads, human skin anchored at
    /// 500 / 50 N/m, 2 mm frictionless contact, 60 iterations per frame.
    fn default() -> Self {
        Self {
            radius_m: 0.012,
            margin: 0.1,
            segments: 24,
            rings: 16,
            material: SkinMaterial::HUMAN_SKIN,
            anchor_k_normal_n_per_m: 500.0,
            anchor_k_tangent_n_per_m: 50.0,
            contact: ContactConfig {
                max_substeps: 16,
                ..ContactConfig::DEFAULT
            },
            relax: RelaxSettings {
                max_iterations: 60,
                ..RelaxSettings::DEFAULT
            },
        }
    }
}

/// The jaw scene's entities (see [`spawn_jaw`]).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SpawnedJaw {
    /// The rig and all its muscles and bones.
    pub anatomy: SpawnedAnatomy,
    /// The platysma-like muscle.
    pub muscle: Entity,
    /// The skull (kinematic).
    pub skull: Entity,
    /// The jaw (dynamic, hinged to the skull).
    pub jaw: Entity,
    /// The spine (kinematic).
    pub spine: Entity,
    /// The skin sleeve, when asked for.
    pub skin: Option<Entity>,
}

/// Spawns the paper's Fig. 1 jaw scene ([`jaw`]) as a rig, optionally with a skin sleeve over
/// its muscle. Raise the muscle's [`MuscleActivation`] to open the jaw; read the angle with
/// [`BonePose::angle_about`]`(`[`JawScene::HINGE_AXIS`]`)` on the jaw entity.
pub fn spawn_jaw(
    world: &mut World,
    scene: &JawConfig,
    steps_per_frame: u32,
    skin: Option<&JawSkinConfig>,
) -> Result<SpawnedJaw, RigError> {
    let s = jaw(scene)?;
    let (m, sk, j, sp) = (s.muscle, s.skull, s.jaw, s.spine);
    let anatomy = spawn_anatomy(world, s.system, steps_per_frame)?;
    let skin = match skin {
        Some(config) => Some(spawn_jaw_skin(world, &anatomy, j, sp, config)?),
        None => None,
    };
    Ok(SpawnedJaw {
        muscle: anatomy.muscles[m],
        skull: anatomy.bones[sk],
        jaw: anatomy.bones[j],
        spine: anatomy.bones[sp],
        skin,
        anatomy,
    })
}

fn spawn_jaw_skin(
    world: &mut World,
    anatomy: &SpawnedAnatomy,
    jaw_bone: usize,
    spine_bone: usize,
    config: &JawSkinConfig,
) -> Result<Entity, RigError> {
    let [chin, neck] = JawScene::MUSCLE_AXIS;
    let margin = config.margin;
    if !(0.0..0.5).contains(&margin) {
        return Err(AnatomyError::InvalidParameter {
            name: "margin (in [0, 0.5))",
            value: margin,
        }
        .into());
    }
    let (a, b) = (chin.lerp(neck, margin), chin.lerp(neck, 1.0 - margin));
    let mesh = sleeve_mesh(a, b, config.radius_m, config.segments, config.rings)?;
    let normals = vertex_normals(&mesh);
    let axis = neck - chin;
    let influences: Vec<[(u32, f32); 2]> = mesh
        .positions()
        .iter()
        .map(|p| {
            let t = ((*p - chin).dot(axis) / axis.length_squared()).clamp(0.0, 1.0);
            [(jaw_bone as u32, 1.0 - t), (spine_bone as u32, t)]
        })
        .collect();
    let binding = BoneSkinning::new(
        world,
        anatomy.rig,
        influences,
        mesh.positions().to_vec(),
        normals,
    )?;
    let vertex_count = mesh.positions().len();
    let contact = anatomy.skin_contact(world, vertex_count, config.contact)?;
    let entity = SkinBuilder::new(mesh, config.material.clone())
        .with_rest_anchors(
            config.anchor_k_normal_n_per_m,
            config.anchor_k_tangent_n_per_m,
        )
        .with_relax_settings(config.relax)
        .spawn(world)?;
    world.entity_mut(entity).insert((binding, contact));
    Ok(entity)
}

/// Copies every muscle's [`MuscleActivation`] and every kinematic bone's [`BoneTarget`] into
/// its rig. A rejected input is left out and reported in [`AnatomyDiagnostics::error`].
pub fn apply_anatomy_inputs(
    mut rigs: Query<(&mut AnatomyRig, &mut AnatomyDiagnostics)>,
    muscles: Query<(&ChildOf, &AnatomyMuscle, &MuscleActivation)>,
    bones: Query<(&ChildOf, &AnatomyBone, &BoneTarget)>,
) {
    for (_, mut diagnostics) in &mut rigs {
        diagnostics.error = None;
    }
    for (parent, muscle, activation) in &muscles {
        let Ok((mut rig, mut diagnostics)) = rigs.get_mut(parent.parent()) else {
            continue;
        };
        let system = &mut rig.bypass_change_detection().system;
        if system.muscle(muscle.index).map(|m| m.activation()) != Some(activation.0)
            && let Err(e) = system.set_activation(muscle.index, activation.0)
        {
            diagnostics.error = Some(e);
        }
    }
    for (parent, bone, target) in &bones {
        let Ok((mut rig, mut diagnostics)) = rigs.get_mut(parent.parent()) else {
            continue;
        };
        let t = target.0;
        let rig = rig.bypass_change_detection();
        // Validated now (bad pose, dynamic body); the frame's steps interpolate towards it.
        match rig
            .system
            .set_kinematic_pose(bone.index, t.rotation, t.translation)
        {
            Ok(()) => {
                let (rotation, translation) = rig
                    .system
                    .body(bone.index)
                    .map_or((Quat::IDENTITY, Vec3::ZERO), |b| b.pose());
                let start = BonePose {
                    rotation,
                    translation,
                };
                let end = BonePose {
                    rotation: t.rotation.normalize(),
                    translation: t.translation,
                };
                rig.pending.push((bone.index, start, end));
            }
            Err(e) => diagnostics.error = Some(e),
        }
    }
}

/// Runs [`AnatomyRig::steps_per_frame`] steps of every rig. A diverged step is rolled back
/// by the system; the frame's remaining steps are skipped and the error reported.
pub fn step_anatomy(mut rigs: Query<(&mut AnatomyRig, &mut AnatomyDiagnostics)>) {
    for (mut rig, mut diagnostics) in &mut rigs {
        let rig = &mut *rig;
        diagnostics.frames += 1;
        let n = rig.steps_per_frame;
        let pending = std::mem::take(&mut rig.pending);
        for k in 0..n {
            let alpha = (k + 1) as f32 / n as f32;
            for (body, start, end) in &pending {
                let (q, t) = (
                    start.rotation.slerp(end.rotation, alpha),
                    start.translation.lerp(end.translation, alpha),
                );
                // Validated when the target was applied.
                let _ = rig.system.set_kinematic_pose(*body, q, t);
            }
            match rig.system.step() {
                Ok(()) => diagnostics.steps += 1,
                Err(e) => {
                    diagnostics.error = Some(e);
                    break;
                }
            }
        }
    }
}

/// Publishes each muscle's surface ([`ColliderState::local_vertices`]) and [`MuscleState`],
/// and each bone's [`BonePose`] and collider pose.
pub fn write_anatomy_outputs(
    rigs: Query<&AnatomyRig>,
    mut muscles: Query<
        (
            &ChildOf,
            &AnatomyMuscle,
            &mut MuscleState,
            &mut ColliderState,
        ),
        Without<AnatomyBone>,
    >,
    mut bones: Query<(&ChildOf, &AnatomyBone, &mut BonePose, &mut ColliderState)>,
) {
    for (parent, muscle, mut state, mut collider) in &mut muscles {
        let Ok(rig) = rigs.get(parent.parent()) else {
            continue;
        };
        let system = &rig.system;
        let Some(m) = system.muscle(muscle.index) else {
            continue;
        };
        let x = system.positions();
        for (v, &p) in collider
            .local_vertices
            .iter_mut()
            .zip(&m.surface().particles)
        {
            *v = x[p as usize];
        }
        if let (Ok(volume_m3), Ok(length_m)) = (
            system.muscle_volume_m3(muscle.index),
            muscle_length(system, muscle.index),
        ) {
            state.volume_m3 = volume_m3;
            state.length_m = length_m;
        }
    }
    for (parent, bone, mut pose, mut collider) in &mut bones {
        let Ok(rig) = rigs.get(parent.parent()) else {
            continue;
        };
        let Some(b) = rig.system.body(bone.index) else {
            continue;
        };
        let (rotation, translation) = b.pose();
        *pose = BonePose {
            rotation,
            translation,
        };
        collider.pose = to_pose((rotation, translation));
    }
}

/// Moves the anchors of every [`BoneSkinning`] skin with its rig's bone poses.
pub fn follow_bones(rigs: Query<&AnatomyRig>, mut skins: Query<(&BoneSkinning, &mut SkinAnchors)>) {
    for (binding, mut anchors) in &mut skins {
        let Ok(rig) = rigs.get(binding.rig) else {
            continue;
        };
        let poses: Vec<(Quat, Vec3)> = (0..)
            .map_while(|b| rig.system.body(b).map(|b| b.pose()))
            .collect();
        for (((a, inf), &p), &n) in anchors
            .iter_mut()
            .zip(&binding.influences)
            .zip(&binding.rest_targets)
            .zip(&binding.rest_normals)
        {
            let (mut target, mut normal) = (Vec3::ZERO, Vec3::ZERO);
            for &(bone, w) in inf {
                if w == 0.0 {
                    continue;
                }
                let (q, t) = poses
                    .get(bone as usize)
                    .copied()
                    .unwrap_or((Quat::IDENTITY, Vec3::ZERO));
                target += w * (q * p + t);
                normal += w * (q * n);
            }
            a.target = target;
            a.normal = normal.normalize_or(n);
        }
    }
}

/// Adds the anatomy systems to [`DermisSystems::Muscles`], chained, before
/// [`refresh_colliders`].
pub(crate) fn configure(schedule: &mut Schedule) {
    schedule.add_systems(
        (
            apply_anatomy_inputs,
            step_anatomy,
            write_anatomy_outputs,
            follow_bones,
        )
            .chain()
            .in_set(DermisSystems::Muscles)
            .before(refresh_colliders),
    );
}
