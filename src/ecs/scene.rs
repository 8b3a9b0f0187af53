//! glTF scenes in the ECS: skins and colliders spawned from a [`Scene`], its clip played on a fixed clock.

use std::collections::BTreeMap;
use std::sync::Arc;

use bevy_ecs::prelude::*;
use glam::{Mat3, Mat4, Vec3};
use parry3d::math::Pose;
use serde::{Deserialize, Serialize};
use thiserror::Error;

use super::components::*;
use super::spawn::{SkinBuilder, vertex_normals};
use super::{DermisSystems, SkinError};
use crate::animation::{apply_morph_targets, skin_normals, skin_positions};
use crate::collision::{
    ColliderMesh, CollisionError, ContactConfig, ContactDiagnostics, FrictionAnchor, SkinCollision,
};
use crate::gltf::{Capsule, GltfError, Primitive, Role, Scene};
use crate::mesh::TriMesh;
use crate::solver::{StopReason, VertexAnchor};

/// Why a scene could not be spawned, checkpointed or read back.
#[derive(Debug, Error)]
pub enum SceneError {
    /// The requested clip does not exist ([`GltfError::ClipNotFound`] lists the clips).
    #[error(transparent)]
    Gltf(#[from] GltfError),
    /// The timestep must be finite and positive, seconds (e.g. `1.0 / 30.0`).
    #[error("timestep {dt_s} s is not finite and positive")]
    BadTimestep {
        /// The value given.
        dt_s: f64,
    },
    /// No mesh has the role skin: give one the role through glTF extras
    /// (`{"dermis": {"role": "skin"}}`), its name, or [`LoadOptions::role_overrides`](crate::gltf::LoadOptions::role_overrides).
    #[error("the scene has no mesh with the role skin")]
    NoSkin,
    /// A skin primitive could not become a spring mesh (degenerate or non-manifold triangles,
    /// bad material). Repair the mesh named here.
    #[error("skin {node}.{primitive}: {source}")]
    Skin {
        /// Node name.
        node: String,
        /// Primitive index.
        primitive: u32,
        /// The reason.
        source: SkinError,
    },
    /// A muscle or bone primitive is not a closed, consistently wound mesh (or a fitted capsule
    /// is degenerate). Close or re-orient the mesh named here, or give it another role.
    #[error("collider {node}.{primitive}: {source}")]
    Collider {
        /// Node name (or joint node name for a capsule).
        node: String,
        /// Primitive index (capsule index for capsules).
        primitive: u32,
        /// The reason.
        source: CollisionError,
    },
    /// [`SceneOptions::contact`] is out of range; the message names the field.
    #[error("contact config: {0}")]
    Contact(CollisionError),
    /// The world already holds a scene; spawn each scene in its own `World`.
    #[error("the world already holds a scene (one SceneAnimation per World)")]
    AlreadySpawned,
    /// The world holds no scene: call [`spawn_scene`] first.
    #[error("the world holds no scene (call spawn_scene first)")]
    NotSpawned,
    /// The entity is not a skin or collider spawned by [`spawn_scene`].
    #[error("entity {0} is not a {1} spawned from a scene")]
    NotSceneEntity(Entity, &'static str),
    /// A [`SceneState`] was captured from a different scene or with other options; restore it
    /// into a world spawned from the same file with the same [`SceneOptions`].
    #[error("state does not match this scene: {0}")]
    StateMismatch(String),
}

/// How [`spawn_scene`] builds and plays a scene.
#[derive(Debug, Clone, PartialEq)]
pub struct SceneOptions {
    /// Clip name or index (as in `dermis pose --clip`); `None`: the first clip, if any.
    pub clip: Option<String>,
    /// Fixed timestep, s: every frame advances the clock by exactly this much.
    pub dt_s: f64,
    /// Wrap the time around the clip's duration instead of holding the last pose.
    pub looping: bool,
    /// Material of every skin.
    pub material: SkinMaterial,
    /// Anchor stiffness along the skinned normal, N/m per vertex.
    pub anchor_k_normal_n_per_m: f32,
    /// Anchor stiffness across the skinned normal, N/m per vertex (low: the skin slides).
    pub anchor_k_tangent_n_per_m: f32,
    /// Collision of the skins with the muscles and bones (thickness, friction, substeps);
    /// `None`: no collision.
    pub contact: Option<ContactConfig>,
    /// Relaxation budget of every scene skin (a [`RelaxSettings`] component on it).
    pub relax: RelaxSettings,
}

impl SceneOptions {
    /// 30 frames per second, first clip, held at its end; human skin anchored at 500 N/m along
    /// the normal and 50 N/m across; 2 mm frictionless contact with at most 16 substeps; 60
    /// solver iterations per frame shared by the substeps.
    ///
    /// The iteration budget is modest on purpose: a contact projection that moves vertices
    /// restarts the solver's conjugate directions and contact forces count in its residual, so
    /// a constrained solve tends to run to its budget rather than converge.
    pub const DEFAULT: Self = Self {
        clip: None,
        dt_s: 1.0 / 30.0,
        looping: false,
        material: SkinMaterial::HUMAN_SKIN,
        anchor_k_normal_n_per_m: 500.0,
        anchor_k_tangent_n_per_m: 50.0,
        contact: Some(ContactConfig {
            max_substeps: 16,
            ..ContactConfig::DEFAULT
        }),
        relax: RelaxSettings {
            max_iterations: 60,
            ..RelaxSettings::DEFAULT
        },
    };
}

impl Default for SceneOptions {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// The fixed-step clock of a scene: frame `n` shows the clip at `n × dt_s` (never wall-clock
/// time, so runs are reproducible).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SceneClock {
    /// Timestep, s.
    pub dt_s: f64,
    /// Frames advanced since spawn (0 at spawn).
    pub frame: u64,
    /// Wrap around the clip's duration.
    pub looping: bool,
    /// Duration of the clip, s (0 without a clip).
    pub duration_s: f32,
}

impl SceneClock {
    /// Time since spawn, s.
    pub fn time_s(&self) -> f64 {
        self.frame as f64 * self.dt_s
    }

    /// The clip time sampled this frame, s: the time since spawn, held at the clip's end or
    /// wrapped around it when looping.
    pub fn sample_time_s(&self) -> f32 {
        let t = self.time_s();
        let d = f64::from(self.duration_s);
        let t = if d <= 0.0 {
            t
        } else if self.looping {
            t.rem_euclid(d)
        } else {
            t.min(d)
        };
        t as f32
    }
}

/// The skeleton's state at the current frame: what [`sample_scene`] computes.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ScenePose {
    /// World transform of every node.
    pub globals: Vec<Mat4>,
    /// Joint matrices (`global(joint) × inverse_bind`) of every skin.
    pub joint_matrices: Vec<Vec<Mat4>>,
    /// Morph weights in effect for every node (animated, else the node's, else its mesh's).
    pub morph_weights: Vec<Vec<f32>>,
}

impl ScenePose {
    /// Evaluates `scene` at `time_s` of `clip` (`None`: the rest pose), as
    /// [`Scene::pose`] does.
    pub fn evaluate(scene: &Scene, clip: Option<usize>, time_s: f32) -> Self {
        let pose = scene.sample(clip, time_s);
        let globals = scene.hierarchy.global_transforms(&pose.locals);
        let joint_matrices = scene
            .skins
            .iter()
            .map(|s| s.joint_matrices(&globals))
            .collect();
        let morph_weights = scene
            .nodes
            .iter()
            .enumerate()
            .map(|(n, node)| {
                pose.morph_weights
                    .get(n)
                    .and_then(Option::as_deref)
                    .or(node.weights.as_deref())
                    .or(node
                        .mesh
                        .and_then(|m| scene.meshes.get(m as usize))
                        .map(|m| m.weights.as_slice()))
                    .unwrap_or(&[])
                    .to_vec()
            })
            .collect();
        Self {
            globals,
            joint_matrices,
            morph_weights,
        }
    }

    /// Morphed then skinned (or node-transformed) positions of primitive `prim` drawn by node
    /// `node`, world space, in the primitive's order: the same arithmetic as [`Scene::pose`].
    pub fn deform_positions(&self, scene: &Scene, node: usize, prim: &Primitive) -> Vec<Vec3> {
        let weights = self.morph_weights.get(node).map_or(&[][..], Vec::as_slice);
        let targets: Vec<&[Vec3]> = prim
            .targets
            .iter()
            .map(|t| t.positions.as_slice())
            .collect();
        let mut positions = apply_morph_targets(&prim.positions, &targets, weights);
        match (self.skin_of(scene, node), &prim.influences) {
            (Some(joints), Some(inf)) => skin_positions(&positions, inf, joints),
            _ => {
                let g = self.global(node);
                for v in &mut positions {
                    *v = g.transform_point3(*v);
                }
                positions
            }
        }
    }

    /// Unit normals to go with [`deform_positions`](Self::deform_positions), from `rest` (the
    /// primitive's normals, morphed, when it has them, else `rest` as given).
    fn deform_normals(
        &self,
        scene: &Scene,
        node: usize,
        prim: &Primitive,
        rest: &[Vec3],
    ) -> Vec<Vec3> {
        let weights = self.morph_weights.get(node).map_or(&[][..], Vec::as_slice);
        let base = match &prim.normals {
            Some(n) if n.len() == rest.len() => {
                let nt: Vec<&[Vec3]> = prim
                    .targets
                    .iter()
                    .map(|t| t.normals.as_deref().unwrap_or(&[]))
                    .collect();
                apply_morph_targets(n, &nt, weights)
            }
            _ => rest.to_vec(),
        };
        match (self.skin_of(scene, node), &prim.influences) {
            (Some(joints), Some(inf)) => skin_normals(&base, inf, joints),
            _ => {
                let nm = Mat3::from_mat4(self.global(node)).inverse().transpose();
                base.iter()
                    .map(|n| (nm * *n).normalize_or(Vec3::Z))
                    .collect()
            }
        }
    }

    fn skin_of(&self, scene: &Scene, node: usize) -> Option<&[Mat4]> {
        scene.nodes[node]
            .skin
            .and_then(|s| self.joint_matrices.get(s as usize))
            .map(Vec::as_slice)
    }

    fn global(&self, node: usize) -> Mat4 {
        self.globals.get(node).copied().unwrap_or(Mat4::IDENTITY)
    }
}

/// The scene being played: the loaded [`Scene`], the clip, the clock and the current pose.
/// One per `World` (inserted by [`spawn_scene`]).
#[derive(Resource, Debug, Clone)]
pub struct SceneAnimation {
    scene: Arc<Scene>,
    clip: Option<usize>,
    /// The fixed-step clock.
    pub clock: SceneClock,
    pose: ScenePose,
}

impl SceneAnimation {
    /// The scene.
    pub fn scene(&self) -> &Scene {
        &self.scene
    }
    /// The clip played.
    pub fn clip(&self) -> Option<usize> {
        self.clip
    }
    /// The pose of the current frame.
    pub fn pose(&self) -> &ScenePose {
        &self.pose
    }
}

/// Which glTF primitive an entity was made from.
#[derive(Component, Debug, Clone, PartialEq, Eq)]
pub struct SceneMesh {
    /// Node index.
    pub node: u32,
    /// Mesh index.
    pub mesh: u32,
    /// Primitive index within the mesh.
    pub primitive: u32,
    /// `<node name>.<primitive index>`, as `dermis pose` names it.
    pub name: String,
}

/// Vertex welding of a primitive.
///
/// glTF primitives often repeat a vertex along UV or normal seams. The spring mesh of a skin
/// (and the triangle mesh of a collider) welds vertices whose positions are bit-for-bit equal,
/// keeping the first occurrence; [`SceneSkin`] keeps the map both ways, so
/// [`scene_skin_positions`] and [`collider_geometry`] answer in the primitive's own vertex
/// order (what `dermis pose` writes). Triangles that collapse under the weld are dropped.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct VertexWeld {
    /// Welded vertex of every primitive vertex.
    pub primitive_to_welded: Vec<u32>,
    /// The primitive vertex each welded vertex was taken from (its first occurrence).
    pub welded_to_primitive: Vec<u32>,
}

impl VertexWeld {
    /// Welds vertices with bit-identical positions, in order of first occurrence.
    pub fn new(positions: &[Vec3]) -> Self {
        let mut seen: BTreeMap<[u32; 3], u32> = BTreeMap::new();
        let mut primitive_to_welded = Vec::with_capacity(positions.len());
        let mut welded_to_primitive = Vec::new();
        for (i, p) in positions.iter().enumerate() {
            let key = p.to_array().map(f32::to_bits);
            let w = *seen.entry(key).or_insert_with(|| {
                welded_to_primitive.push(i as u32);
                welded_to_primitive.len() as u32 - 1
            });
            primitive_to_welded.push(w);
        }
        Self {
            primitive_to_welded,
            welded_to_primitive,
        }
    }

    /// Welded values (the first occurrence of each vertex).
    pub fn gather<T: Copy>(&self, primitive_values: &[T]) -> Vec<T> {
        self.welded_to_primitive
            .iter()
            .map(|&v| primitive_values[v as usize])
            .collect()
    }

    /// Values in the primitive's order from welded ones.
    pub fn scatter<T: Copy>(&self, welded_values: &[T]) -> Vec<T> {
        self.primitive_to_welded
            .iter()
            .map(|&w| welded_values[w as usize])
            .collect()
    }

    /// Triangles re-indexed to welded vertices; those that collapse are dropped.
    pub fn triangles(&self, triangles: &[[u32; 3]]) -> Vec<[u32; 3]> {
        triangles
            .iter()
            .map(|t| t.map(|v| self.primitive_to_welded[v as usize]))
            .filter(|[a, b, c]| a != b && b != c && a != c)
            .collect()
    }
}

/// What a skin entity spawned from a scene needs to follow the skeleton.
#[derive(Component, Debug, Clone)]
pub struct SceneSkin {
    /// The weld of the primitive.
    pub weld: VertexWeld,
    /// Rest normals in the primitive's order (its own, else the welded bind mesh's).
    rest_normals: Vec<Vec3>,
}

/// What a collider entity is in the anatomy.
#[derive(
    Component, Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize,
)]
#[serde(rename_all = "lowercase")]
pub enum Tissue {
    /// A deforming muscle.
    Muscle,
    /// A rigid bone.
    Bone,
}

/// How a collider follows the skeleton.
#[derive(Debug, Clone, PartialEq)]
pub enum ColliderDrive {
    /// Re-skinned every frame: [`ColliderState::local_vertices`] are world positions and the
    /// collider is refitted ([`ColliderMesh::set_vertices`]).
    Deforming {
        /// The weld of the primitive.
        weld: VertexWeld,
    },
    /// Rigidly bound to one joint (or an unskinned node): vertices stay in the bind frame and
    /// the collider moves with [`ColliderMesh::set_pose`], no refit.
    Rigid {
        /// The weld of the primitive (`None` for a capsule).
        weld: Option<VertexWeld>,
        /// `(skin, joint)` driving it; `None`: the node's world transform.
        joint: Option<(u32, u32)>,
    },
}

/// The current shape of a collider entity: rest-frame vertices and a pose (world vertex =
/// `pose × local`).
#[derive(Component, Debug, Clone)]
pub struct ColliderState {
    /// Vertices in the collider's rest frame, m (welded; for a capsule, a tessellation).
    pub local_vertices: Vec<Vec3>,
    /// Triangles over `local_vertices`.
    pub triangles: Arc<Vec<[u32; 3]>>,
    /// Rest frame → world.
    pub pose: Pose,
    /// How it follows the skeleton.
    pub drive: ColliderDrive,
    /// The collider as built at spawn (cloned into every skin's [`SkinContact`]).
    pub(crate) template: ColliderMesh,
}

/// A skin entity made by [`spawn_scene`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SpawnedSkin {
    /// The entity.
    pub entity: Entity,
    /// `<node name>.<primitive index>`.
    pub name: String,
    /// Node index.
    pub node: u32,
    /// Primitive index.
    pub primitive: u32,
}

/// A collider entity made by [`spawn_scene`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SpawnedCollider {
    /// The entity.
    pub entity: Entity,
    /// Muscle or bone.
    pub tissue: Tissue,
    /// `<node name>.<primitive index>`, or `capsule.<joint node name>` for fitted capsules.
    pub name: String,
    /// Whether it is one of the scene's fitted capsules.
    pub capsule: bool,
}

/// What [`spawn_scene`] made.
#[derive(Debug, Clone, PartialEq)]
pub struct SpawnedScene {
    /// Skin entities in node order, then primitive order.
    pub skins: Vec<SpawnedSkin>,
    /// Collider entities in node order, then primitive order (capsules in the scene's order).
    pub colliders: Vec<SpawnedCollider>,
    /// The clip played.
    pub clip: Option<usize>,
    /// Its duration, s (0 without a clip).
    pub clip_duration_s: f32,
}

fn is_rigid(scene: &Scene, node: usize, prim: &Primitive) -> Option<Option<(u32, u32)>> {
    if !prim.targets.is_empty() {
        return None;
    }
    let Some(skin) = scene.nodes[node].skin else {
        return Some(None);
    };
    let inf = prim.influences.as_ref()?;
    let mut joint = None;
    for v in 0..inf.vertex_count() {
        for (&j, &w) in inf.joints_of(v).iter().zip(inf.weights_of(v)) {
            if w == 0.0 {
                continue;
            }
            if w != 1.0 || joint.is_some_and(|k| k != j) {
                return None;
            }
            joint = Some(j);
        }
    }
    joint.map(|j| Some((skin, j)))
}

/// The isometry of `m` if it has no scale or shear (within 1e-4), else `None`.
fn rigid_pose(m: Mat4) -> Option<Pose> {
    let (scale, rotation, translation) = m.to_scale_rotation_translation();
    let rebuilt = Mat4::from_rotation_translation(rotation, translation);
    let ok = (scale - Vec3::ONE).abs().max_element() < 1e-4
        && rebuilt.abs_diff_eq(m, 1e-4 * (1.0 + translation.length()));
    ok.then(|| Pose::from_parts(translation, rotation))
}

fn rigid_matrix(pose: &ScenePose, node: usize, joint: Option<(u32, u32)>) -> Mat4 {
    match joint {
        Some((s, j)) => pose
            .joint_matrices
            .get(s as usize)
            .and_then(|m| m.get(j as usize))
            .copied()
            .unwrap_or(Mat4::IDENTITY),
        None => pose.global(node),
    }
}

/// Spawns the skins and colliders of `scene` into `world` and inserts its [`SceneAnimation`]
/// at frame 0. Run [`DermisPlugin`](super::DermisPlugin)'s schedule once per frame afterwards.
///
/// Skins get their bind-pose primitive (welded) as rest geometry, the skinned positions at
/// time 0 as warm start, and anchors towards the skinned positions. Muscles and bones become
/// collider entities: bones rigidly bound to one joint (or unskinned) are moved by pose,
/// everything else is re-skinned and refitted every frame. A scene without muscles and bones
/// uses its fitted capsules as bones. With [`SceneOptions::contact`], every skin gets a
/// [`SkinContact`] holding all colliders.
///
/// One skin entity per primitive of a mesh with [`Role::Skin`] and one collider entity per
/// muscle or bone primitive (or fitted [`Capsule`]). The [`SceneAnimation`] resource holds the
/// scene and its [`SceneClock`]; the systems added by [`DermisPlugin`](super::DermisPlugin)
/// advance it by a fixed timestep ([`advance_scene_clock`], [`sample_scene`] in
/// [`DermisSystems::Animate`](super::DermisSystems::Animate)), skin the anchors and the colliders
/// ([`deform_scene`] in [`DermisSystems::Deform`](super::DermisSystems::Deform)) and copy the
/// colliders into every skin's [`SkinContact`] ([`refresh_colliders`] in
/// [`DermisSystems::Colliders`](super::DermisSystems::Colliders)).
///
/// ```
/// use bevy_ecs::prelude::*;
/// use dermis::ecs::{DermisPlugin, SceneOptions, spawn_scene, scene_skin_positions};
/// use dermis::gltf::{LoadOptions, Scene};
///
/// let bytes = dermis::gltf::arm::build_arm_glb();
/// let scene = Scene::from_slice(&bytes, None, &LoadOptions::default()).unwrap();
/// let mut world = World::new();
/// let mut schedule = DermisPlugin.build_schedule(&mut world);
/// let spawned = spawn_scene(&mut world, &scene, &SceneOptions::default()).unwrap();
/// assert_eq!(spawned.skins.len(), 1);
/// schedule.run(&mut world); // one frame of 1/30 s
/// let skin = scene_skin_positions(&world, spawned.skins[0].entity).unwrap();
/// assert_eq!(skin.len(), scene.meshes[4].primitives[0].positions.len());
/// ```
pub fn spawn_scene(
    world: &mut World,
    scene: &Scene,
    options: &SceneOptions,
) -> Result<SpawnedScene, SceneError> {
    if !(options.dt_s.is_finite() && options.dt_s > 0.0) {
        return Err(SceneError::BadTimestep { dt_s: options.dt_s });
    }
    if world.contains_resource::<SceneAnimation>() {
        return Err(SceneError::AlreadySpawned);
    }
    let clip = match &options.clip {
        Some(c) => Some(scene.find_clip(c)?),
        None => (!scene.clips.is_empty()).then_some(0),
    };
    let contact_template = options
        .contact
        .map(|c| SkinCollision::new(0, c))
        .transpose()
        .map_err(SceneError::Contact)?;
    let duration_s = clip.map_or(0.0, |c| scene.clips[c].duration());
    let clock = SceneClock {
        dt_s: options.dt_s,
        frame: 0,
        looping: options.looping,
        duration_s,
    };
    let pose = ScenePose::evaluate(scene, clip, clock.sample_time_s());

    let mut skins = Vec::new();
    let mut colliders = Vec::new();
    let mut skin_bundles = Vec::new();
    let mut collider_bundles = Vec::new();
    for (n, node) in scene.nodes.iter().enumerate() {
        let Some(mesh_index) = node.mesh else {
            continue;
        };
        let Some(mesh) = scene.meshes.get(mesh_index as usize) else {
            continue;
        };
        let Some(role) = mesh.role else {
            continue;
        };
        for (p, prim) in mesh.primitives.iter().enumerate() {
            if prim.triangles.is_empty() {
                continue;
            }
            let name = format!("{}.{p}", node.name);
            let tag = SceneMesh {
                node: n as u32,
                mesh: mesh_index,
                primitive: p as u32,
                name: name.clone(),
            };
            let weld = VertexWeld::new(&prim.positions);
            let triangles = weld.triangles(&prim.triangles);
            match role {
                Role::Skin => {
                    let err = |source| SceneError::Skin {
                        node: node.name.clone(),
                        primitive: p as u32,
                        source,
                    };
                    // Bind pose: mesh space for a skinned mesh, else the node's rest transform.
                    let mut bind = weld.gather(&prim.positions);
                    if node.skin.is_none() || prim.influences.is_none() {
                        let rest = ScenePose::evaluate(scene, None, 0.0);
                        let g = rest.global(n);
                        for v in &mut bind {
                            *v = g.transform_point3(*v);
                        }
                    }
                    let rest_mesh =
                        TriMesh::new(bind, triangles).map_err(|e| err(SkinError::Topology(e)))?;
                    let rest_normals = weld.scatter(&vertex_normals(&rest_mesh));
                    let skin = SceneSkin { weld, rest_normals };
                    let (targets, normals) = skin_targets(&pose, scene, &tag, &skin);
                    let anchors = targets
                        .iter()
                        .zip(&normals)
                        .map(|(&target, &normal)| VertexAnchor {
                            target,
                            normal,
                            k_normal: options.anchor_k_normal_n_per_m,
                            k_tangent: options.anchor_k_tangent_n_per_m,
                        })
                        .collect();
                    let bundle = SkinBuilder::new(rest_mesh, options.material.clone())
                        .with_positions(targets)
                        .with_anchors(anchors)
                        .with_relax_settings(options.relax)
                        .build()
                        .map_err(err)?;
                    skin_bundles.push((bundle, tag, skin));
                }
                Role::Muscle | Role::Bone => {
                    let err = |source| SceneError::Collider {
                        node: node.name.clone(),
                        primitive: p as u32,
                        source,
                    };
                    let tissue = if role == Role::Bone {
                        Tissue::Bone
                    } else {
                        Tissue::Muscle
                    };
                    let rigid = (role == Role::Bone)
                        .then(|| is_rigid(scene, n, prim))
                        .flatten()
                        .and_then(|joint| {
                            rigid_pose(rigid_matrix(&pose, n, joint)).map(|pose| (joint, pose))
                        });
                    let (local, drive, pose_now) = match rigid {
                        Some((joint, pose_now)) => (
                            weld.gather(&prim.positions),
                            ColliderDrive::Rigid {
                                weld: Some(weld),
                                joint,
                            },
                            pose_now,
                        ),
                        None => (
                            weld.gather(&pose.deform_positions(scene, n, prim)),
                            ColliderDrive::Deforming { weld },
                            Pose::IDENTITY,
                        ),
                    };
                    let template = ColliderMesh::from_mesh(local.clone(), triangles.clone())
                        .map_err(err)?
                        .with_pose(pose_now);
                    colliders.push((tissue, name, false));
                    collider_bundles.push((
                        tissue,
                        tag,
                        ColliderState {
                            local_vertices: local,
                            triangles: Arc::new(triangles),
                            pose: pose_now,
                            drive,
                            template,
                        },
                    ));
                }
            }
        }
    }
    if skin_bundles.is_empty() {
        return Err(SceneError::NoSkin);
    }
    if collider_bundles.is_empty() {
        // A model whose only skinned mesh is the skin: the fitted capsules are its bones.
        let skin_index = skin_bundles
            .iter()
            .find_map(|(_, tag, _)| scene.nodes[tag.node as usize].skin);
        // Capsules of zero radius (a bone whose vertices lie on its axis) are skipped.
        for (i, capsule) in scene.capsules.iter().enumerate() {
            let Some(s) = skin_index else { break };
            if capsule.radius_m.is_nan() || capsule.radius_m <= 0.0 {
                continue;
            }
            let node_name = scene
                .nodes
                .get(capsule.node as usize)
                .map_or_else(|| format!("node{}", capsule.node), |n| n.name.clone());
            let err = |source| SceneError::Collider {
                node: node_name.clone(),
                primitive: i as u32,
                source,
            };
            let (state, tag) = capsule_collider(&pose, s, capsule, i, &node_name).map_err(err)?;
            colliders.push((Tissue::Bone, tag.name.clone(), true));
            collider_bundles.push((Tissue::Bone, tag, state));
        }
    }

    let mut spawned_colliders = Vec::new();
    let mut contact_colliders = Vec::new();
    for ((tissue, tag, state), (_, name, capsule)) in collider_bundles.into_iter().zip(colliders) {
        let template = state.template.clone();
        let entity = world.spawn((tissue, tag, state)).id();
        contact_colliders.push((entity, template));
        spawned_colliders.push(SpawnedCollider {
            entity,
            tissue,
            name,
            capsule,
        });
    }
    for ((bundle, relax), tag, skin) in skin_bundles {
        let vertex_count = skin.weld.welded_to_primitive.len();
        let spawned = SpawnedSkin {
            entity: Entity::PLACEHOLDER,
            name: tag.name.clone(),
            node: tag.node,
            primitive: tag.primitive,
        };
        let mut e = world.spawn((bundle, tag, skin));
        if let Some(relax) = relax {
            e.insert(relax);
        }
        if let Some(template) = &contact_template {
            let mut collision = SkinCollision::new(vertex_count, *template.config())
                .map_err(SceneError::Contact)?;
            let ids = contact_colliders
                .iter()
                .map(|(entity, mesh)| (*entity, collision.add_collider(mesh.clone())))
                .collect();
            e.insert(SkinContact {
                collision,
                colliders: ids,
            });
        }
        skins.push(SpawnedSkin {
            entity: e.id(),
            ..spawned
        });
    }
    world.insert_resource(SceneAnimation {
        scene: Arc::new(scene.clone()),
        clip,
        clock,
        pose,
    });
    Ok(SpawnedScene {
        skins,
        colliders: spawned_colliders,
        clip,
        clip_duration_s: duration_s,
    })
}

fn capsule_collider(
    pose: &ScenePose,
    skin: u32,
    capsule: &Capsule,
    index: usize,
    node_name: &str,
) -> Result<(ColliderState, SceneMesh), CollisionError> {
    let joint = Some((skin, capsule.joint));
    let m = rigid_matrix(pose, capsule.node as usize, joint);
    let pose_now = rigid_pose(m).unwrap_or(Pose::IDENTITY);
    let template =
        ColliderMesh::capsule(capsule.a, capsule.b, capsule.radius_m)?.with_pose(pose_now);
    let (local, triangles) =
        parry3d::shape::Capsule::new(capsule.a, capsule.b, capsule.radius_m).to_trimesh(16, 8);
    let tag = SceneMesh {
        node: capsule.node,
        mesh: u32::MAX,
        primitive: index as u32,
        name: format!("capsule.{node_name}"),
    };
    Ok((
        ColliderState {
            local_vertices: local,
            triangles: Arc::new(triangles),
            pose: pose_now,
            drive: ColliderDrive::Rigid { weld: None, joint },
            template,
        },
        tag,
    ))
}

/// Skinned anchor targets and normals of a scene skin (welded order).
fn skin_targets(
    pose: &ScenePose,
    scene: &Scene,
    tag: &SceneMesh,
    skin: &SceneSkin,
) -> (Vec<Vec3>, Vec<Vec3>) {
    let node = tag.node as usize;
    let prim = &scene.meshes[tag.mesh as usize].primitives[tag.primitive as usize];
    let positions = pose.deform_positions(scene, node, prim);
    let normals = pose.deform_normals(scene, node, prim, &skin.rest_normals);
    (skin.weld.gather(&positions), skin.weld.gather(&normals))
}

/// [`DermisSystems::Animate`]: advances the scene clock by one fixed timestep.
pub fn advance_scene_clock(animation: Option<ResMut<SceneAnimation>>) {
    if let Some(mut a) = animation {
        a.clock.frame += 1;
    }
}

/// [`DermisSystems::Animate`]: samples the clip at the clock's time into the [`ScenePose`]
/// (node transforms, joint matrices, morph weights).
pub fn sample_scene(animation: Option<ResMut<SceneAnimation>>) {
    if let Some(mut a) = animation {
        let t = a.clock.sample_time_s();
        a.pose = ScenePose::evaluate(&a.scene, a.clip, t);
    }
}

/// [`DermisSystems::Deform`]: morph targets then linear blend skinning for the skin anchors
/// (targets and normals) and the colliders (vertices of deforming ones, poses of rigid ones).
pub fn deform_scene(
    animation: Option<Res<SceneAnimation>>,
    mut skins: Query<(&SceneMesh, &SceneSkin, &mut SkinAnchors)>,
    mut colliders: Query<(&SceneMesh, &mut ColliderState)>,
) {
    let Some(animation) = animation else { return };
    let scene = &*animation.scene;
    let pose = &animation.pose;
    for (tag, skin, mut anchors) in &mut skins {
        let (targets, normals) = skin_targets(pose, scene, tag, skin);
        for ((a, t), n) in anchors.0.iter_mut().zip(targets).zip(normals) {
            a.target = t;
            a.normal = n;
        }
    }
    for (tag, mut state) in &mut colliders {
        let node = tag.node as usize;
        let state = &mut *state;
        match &state.drive {
            ColliderDrive::Deforming { weld } => {
                let prim = &scene.meshes[tag.mesh as usize].primitives[tag.primitive as usize];
                state.local_vertices = weld.gather(&pose.deform_positions(scene, node, prim));
            }
            ColliderDrive::Rigid { joint, .. } => {
                let m = rigid_matrix(pose, node, *joint);
                // A joint that picked up scale keeps its last rigid pose (bones are rigid).
                if let Some(p) = rigid_pose(m) {
                    state.pose = p;
                }
            }
        }
    }
}

/// [`DermisSystems::Colliders`]: copies every collider entity's [`ColliderState`] into the
/// skins' [`SkinContact`]s (a BVH refit for deforming meshes, a pose for rigid ones).
pub fn refresh_colliders(
    mut skins: Query<(&mut SkinContact, &mut RelaxDiagnostics)>,
    colliders: Query<&ColliderState>,
) {
    for (mut contact, mut diagnostics) in &mut skins {
        let contact = &mut *contact;
        for &(entity, id) in &contact.colliders {
            let Ok(state) = colliders.get(entity) else {
                continue;
            };
            let Ok(collider) = contact.collision.collider_mut(id) else {
                continue;
            };
            let result = match state.drive {
                ColliderDrive::Deforming { .. } => collider.set_vertices(&state.local_vertices),
                ColliderDrive::Rigid { .. } => collider.set_pose(state.pose),
            };
            if let Err(e) = result {
                diagnostics.solve_error = Some(SkinError::Collision(e));
            }
        }
    }
}

/// Adds the scene systems to their [`DermisSystems`] phases (called by
/// [`DermisPlugin::configure`](super::DermisPlugin::configure)). They do nothing without a
/// [`SceneAnimation`].
pub(crate) fn configure(schedule: &mut Schedule) {
    schedule.add_systems((
        (advance_scene_clock, sample_scene)
            .chain()
            .in_set(DermisSystems::Animate),
        deform_scene.in_set(DermisSystems::Deform),
        refresh_colliders.in_set(DermisSystems::Colliders),
    ));
}

/// Everything later frames of a scene depend on, at a frame boundary: serialise it to
/// checkpoint a run (see [`capture_state`], [`restore_state`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SceneState {
    /// The clock (frame counter, timestep, looping, clip duration).
    pub clock: SceneClock,
    /// The clip played.
    pub clip: Option<usize>,
    /// Every scene skin, in node then primitive order.
    pub skins: Vec<SkinState>,
}

/// One skin of a [`SceneState`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SkinState {
    /// `<node name>.<primitive index>`.
    pub name: String,
    /// Node index.
    pub node: u32,
    /// Primitive index.
    pub primitive: u32,
    /// Current (relaxed) positions, welded order, m.
    pub positions: Vec<Vec3>,
    /// Last positions that passed the non-finite guard, welded order, m.
    pub last_valid: Vec<Vec3>,
    /// Each vertex's last contact, where friction anchors it in the next frame (welded order;
    /// empty without collision). Absent from older checkpoints: no anchors then.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub friction_anchors: Vec<Option<FrictionAnchor>>,
    /// The anchor targets of the solve before the captured frame's, welded order, m: half of
    /// the warm start's deviation history ([`MotionHistory`](crate::collision::MotionHistory);
    /// empty: none). Absent from older checkpoints: no history then.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub motion_targets: Vec<Vec3>,
    /// The skin's deviation from those targets at that solve, welded order, m.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub motion_deviations: Vec<Vec3>,
}

/// Captures the state of the scene in `world` at a frame boundary (after a schedule run).
///
/// The contact query cache is not part of it: capturing clears it in `world` (see
/// [`SkinContact`]), as a world restored from the state starts without one, so both continue
/// bit for bit. The friction anchors are part of it, and the colliders' previous-frame state
/// is recomputed from the clock.
pub fn capture_state(world: &mut World) -> Result<SceneState, SceneError> {
    let state = capture(world)?;
    for mut contact in world.query::<&mut SkinContact>().iter_mut(world) {
        contact.collision.clear_query_cache();
    }
    Ok(state)
}

fn capture(world: &World) -> Result<SceneState, SceneError> {
    let animation = world
        .get_resource::<SceneAnimation>()
        .ok_or(SceneError::NotSpawned)?;
    let (clock, clip) = (animation.clock, animation.clip);
    let mut query = world
        .try_query::<(Entity, &SceneMesh, &SkinPositions, &LastValidPositions)>()
        .ok_or(SceneError::NotSpawned)?;
    let mut skins: Vec<SkinState> = query
        .iter(world)
        .map(|(entity, tag, x, last)| SkinState {
            name: tag.name.clone(),
            node: tag.node,
            primitive: tag.primitive,
            positions: x.0.clone(),
            last_valid: last.0.clone(),
            friction_anchors: world
                .get::<SkinContact>(entity)
                .map_or_else(Vec::new, |c| c.collision.friction_anchors()),
            motion_targets: world
                .get::<SolvedAnchors>(entity)
                .map_or_else(Vec::new, |s| s.1.targets().to_vec()),
            motion_deviations: world
                .get::<SolvedAnchors>(entity)
                .map_or_else(Vec::new, |s| s.1.deviations().to_vec()),
        })
        .collect();
    skins.sort_by_key(|s| (s.node, s.primitive));
    Ok(SceneState { clock, clip, skins })
}

/// Restores a [`SceneState`] into a world spawned from the same scene with the same options:
/// the clock, every skin's positions, and the pose, anchors and colliders of that frame (the
/// colliders' previous-frame state, which the next frame's substeps start from). Running the
/// schedule afterwards continues the captured run bit for bit (tested over contact-heavy
/// frames). One caveat: each collider's running sum of surface travel, which the contact
/// cache's distance bounds are measured against, restarts at the restore; only the last
/// rounding bits of those bounds differ, so a pair of results could only differ if a bound
/// fell within about 1e-16 of its threshold.
pub fn restore_state(world: &mut World, state: &SceneState) -> Result<(), SceneError> {
    let mismatch = |m: String| Err(SceneError::StateMismatch(m));
    {
        let animation = world
            .get_resource::<SceneAnimation>()
            .ok_or(SceneError::NotSpawned)?;
        let c = animation.clock;
        if c.dt_s.to_bits() != state.clock.dt_s.to_bits()
            || c.looping != state.clock.looping
            || animation.clip != state.clip
        {
            return mismatch(format!(
                "captured with clip {:?}, dt {} s, looping {}; this world plays clip {:?}, dt {} s, looping {}",
                state.clip,
                state.clock.dt_s,
                state.clock.looping,
                animation.clip,
                c.dt_s,
                c.looping
            ));
        }
    }
    let mut query = world.query::<(
        &SceneMesh,
        &mut SkinPositions,
        &mut LastValidPositions,
        Option<&mut SkinContact>,
        Option<&mut SolvedAnchors>,
    )>();
    let count = query.iter(world).count();
    if count != state.skins.len() {
        return mismatch(format!(
            "{} skins captured, {count} in this world",
            state.skins.len()
        ));
    }
    for (tag, mut x, mut last, contact, solved) in query.iter_mut(world) {
        let Some(s) = state
            .skins
            .iter()
            .find(|s| s.node == tag.node && s.primitive == tag.primitive)
        else {
            return mismatch(format!("skin {} was not captured", tag.name));
        };
        if s.positions.len() != x.len() || s.last_valid.len() != last.len() {
            return mismatch(format!(
                "skin {} has {} vertices, {} captured",
                tag.name,
                x.len(),
                s.positions.len()
            ));
        }
        x.0.copy_from_slice(&s.positions);
        last.0.copy_from_slice(&s.last_valid);
        if let Some(mut solved) = solved {
            let history = if s.motion_targets.is_empty() && s.motion_deviations.is_empty() {
                Some(crate::collision::MotionHistory::default())
            } else if s.motion_targets.len() == x.len() {
                crate::collision::MotionHistory::from_parts(
                    s.motion_targets.clone(),
                    s.motion_deviations.clone(),
                )
            } else {
                None
            };
            let Some(history) = history else {
                return mismatch(format!(
                    "skin {}: {} motion targets and {} deviations captured for {} vertices",
                    tag.name,
                    s.motion_targets.len(),
                    s.motion_deviations.len(),
                    x.len()
                ));
            };
            solved.1 = history;
        }
        if let Some(mut contact) = contact {
            let collision = &mut contact.collision;
            collision.clear_cache();
            if !s.friction_anchors.is_empty() {
                collision
                    .set_friction_anchors(&s.friction_anchors)
                    .or_else(|e| mismatch(format!("skin {}: {e}", tag.name)))?;
            }
        }
    }
    world.resource_mut::<SceneAnimation>().clock.frame = state.clock.frame;
    let mut schedule = Schedule::default();
    schedule.add_systems((sample_scene, deform_scene, refresh_colliders).chain());
    schedule.run(world);
    for mut contact in world.query::<&mut SkinContact>().iter_mut(world) {
        // As the captured run cleared its cache at the capture.
        contact.collision.clear_query_cache();
        for c in 0..contact.colliders.len() {
            let id = contact.colliders[c].1;
            if let Ok(collider) = contact.collision.collider_mut(id) {
                collider.commit_frame();
            }
        }
    }
    // The captured frame's anchors are what its relaxation solved for: the next frame's warm
    // start moves the skin by the anchors' motion from there, as the uninterrupted run does.
    for (anchors, mut solved) in world
        .query::<(&SkinAnchors, &mut SolvedAnchors)>()
        .iter_mut(world)
    {
        solved.0.clear();
        solved.0.extend_from_slice(anchors);
    }
    Ok(())
}

/// Current positions of a scene skin in its glTF primitive's own vertex order (duplicated seam
/// vertices repeated), m: what an exporter writes for `<node name>.<primitive>`.
pub fn scene_skin_positions(world: &World, skin: Entity) -> Result<Vec<Vec3>, SceneError> {
    let not = || SceneError::NotSceneEntity(skin, "skin");
    let x = world.get::<SkinPositions>(skin).ok_or_else(not)?;
    let s = world.get::<SceneSkin>(skin).ok_or_else(not)?;
    Ok(s.weld.scatter(x))
}

/// World-space vertices and triangles of a collider entity: for a glTF mesh in its primitive's
/// own vertex order with its own triangles, for a fitted capsule a tessellation.
pub fn collider_geometry(
    world: &World,
    collider: Entity,
) -> Result<(Vec<Vec3>, Vec<[u32; 3]>), SceneError> {
    let state = world
        .get::<ColliderState>(collider)
        .ok_or(SceneError::NotSceneEntity(collider, "collider"))?;
    let world_vertices: Vec<Vec3> = state
        .local_vertices
        .iter()
        .map(|v| state.pose.transform_point(*v))
        .collect();
    let weld = match &state.drive {
        ColliderDrive::Deforming { weld } => Some(weld),
        ColliderDrive::Rigid { weld, .. } => weld.as_ref(),
    };
    let animation = world.get_resource::<SceneAnimation>();
    let tag = world.get::<SceneMesh>(collider);
    match (weld, animation, tag) {
        (Some(weld), Some(a), Some(tag)) => {
            let triangles = a.scene.meshes[tag.mesh as usize].primitives[tag.primitive as usize]
                .triangles
                .clone();
            Ok((weld.scatter(&world_vertices), triangles))
        }
        _ => Ok((world_vertices, state.triangles.to_vec())),
    }
}

/// One skin's figures of the last frame.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SkinFrameDiagnostics {
    /// `<node name>.<primitive index>`.
    pub name: String,
    /// Solver iterations, summed over substeps.
    pub iterations: u32,
    /// Final relative residual.
    pub residual: f32,
    /// Why the last solve stopped (`None`: it did not run).
    pub stop: Option<StopReason>,
    /// Contact figures (substeps, unresolved vertices, queries), with collision on.
    pub contact: Option<ContactDiagnostics>,
    /// Non-finite quarantines this frame.
    pub quarantined: usize,
    /// Last solve or collider error, if any.
    pub error: Option<String>,
}

/// The scene's figures of the last frame.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SceneFrameDiagnostics {
    /// Frame number (frames since spawn).
    pub frame: u64,
    /// Clip time sampled, s.
    pub time_s: f32,
    /// Every scene skin, in node then primitive order.
    pub skins: Vec<SkinFrameDiagnostics>,
}

/// Per-frame diagnostics of every scene skin.
pub fn scene_diagnostics(world: &World) -> Result<SceneFrameDiagnostics, SceneError> {
    let clock = world
        .get_resource::<SceneAnimation>()
        .ok_or(SceneError::NotSpawned)?
        .clock;
    let mut query = world
        .try_query::<(&SceneMesh, &RelaxDiagnostics)>()
        .ok_or(SceneError::NotSpawned)?;
    let mut skins: Vec<(u32, u32, SkinFrameDiagnostics)> = query
        .iter(world)
        .map(|(tag, d)| {
            (
                tag.node,
                tag.primitive,
                SkinFrameDiagnostics {
                    name: tag.name.clone(),
                    iterations: d.iterations,
                    residual: d.residual,
                    stop: d.stop,
                    contact: d.contact.clone(),
                    quarantined: d.quarantined.len(),
                    error: d
                        .solve_error
                        .as_ref()
                        .or(d.springs_error.as_ref())
                        .map(ToString::to_string),
                },
            )
        })
        .collect();
    skins.sort_by_key(|s| (s.0, s.1));
    Ok(SceneFrameDiagnostics {
        frame: clock.frame,
        time_s: clock.sample_time_s(),
        skins: skins.into_iter().map(|s| s.2).collect(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn weld_merges_seam_duplicates_and_maps_back() {
        // A quad whose diagonal vertices are duplicated (as at a UV seam).
        let p = vec![
            Vec3::ZERO,
            Vec3::X,
            Vec3::new(1.0, 1.0, 0.0),
            Vec3::ZERO,
            Vec3::new(1.0, 1.0, 0.0),
            Vec3::Y,
        ];
        let weld = VertexWeld::new(&p);
        assert_eq!(weld.primitive_to_welded, vec![0, 1, 2, 0, 2, 3]);
        assert_eq!(weld.welded_to_primitive, vec![0, 1, 2, 5]);
        assert_eq!(weld.scatter(&weld.gather(&p)), p);
        // The second triangle is re-indexed; a triangle collapsing onto a seam is dropped.
        let t = weld.triangles(&[[0, 1, 2], [3, 4, 5], [0, 3, 1]]);
        assert_eq!(t, vec![[0, 1, 2], [0, 2, 3]]);
    }

    #[test]
    fn the_clock_holds_or_wraps_at_the_clip_end() {
        let mut clock = SceneClock {
            dt_s: 0.25,
            frame: 10,
            looping: false,
            duration_s: 2.0,
        };
        assert_eq!(clock.time_s(), 2.5);
        assert_eq!(clock.sample_time_s(), 2.0);
        clock.looping = true;
        assert_eq!(clock.sample_time_s(), 0.5);
    }
}
