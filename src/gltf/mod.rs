//! glTF 2.0 (`.gltf` and `.glb`) to a plain scene description: hierarchy, meshes, roles, skins, clips.
//!
//! [`load`] reads a file with the `gltf` crate, checks every accessor it uses against
//! its buffer, and returns a [`Scene`]; [`Scene::pose`] evaluates it at a time the way a
//! conforming glTF viewer does (morph targets, then skinning; a skinned mesh ignores its own
//! node's transform).
//!
//! ```
//! use dermis::gltf::{Role, Scene, LoadOptions};
//!
//! let bytes = dermis::gltf::arm::build_arm_glb();
//! let scene = Scene::from_slice(&bytes, None, &LoadOptions::default()).unwrap();
//! assert_eq!(scene.clips.len(), 1);
//! let skin = scene.meshes.iter().find(|m| m.role == Some(Role::Skin)).unwrap();
//! assert!(skin.primitives[0].influences.is_some());
//! let posed = scene.pose(Some(0), 1.0);
//! assert_eq!(posed.primitives.len(), scene.mesh_instance_count());
//! ```

pub mod arm;
mod capsule;
mod load;
mod posed;
mod read;

use std::path::{Path, PathBuf};

use glam::Vec3;
use serde::Serialize;
use thiserror::Error;

use crate::animation::{AnimationError, Clip, Hierarchy, Influences, Skin};

pub use capsule::{Capsule, fit_capsules};
pub use posed::{PosedPrimitive, PosedScene};

/// What a mesh is in the anatomy.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Role {
    /// The simulated skin surface.
    Skin,
    /// A deforming collider (muscle).
    Muscle,
    /// A rigid collider (bone).
    Bone,
}

impl Role {
    /// Parses `skin`, `muscle` or `bone` (case-insensitive).
    pub fn parse(s: &str) -> Option<Self> {
        match s.to_ascii_lowercase().as_str() {
            "skin" => Some(Self::Skin),
            "muscle" => Some(Self::Muscle),
            "bone" => Some(Self::Bone),
            _ => None,
        }
    }

    /// Lower-case name.
    pub fn as_str(&self) -> &'static str {
        match self {
            Self::Skin => "skin",
            Self::Muscle => "muscle",
            Self::Bone => "bone",
        }
    }
}

/// Where a mesh's [`Role`] came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum RoleSource {
    /// `extras: {"dermis": {"role": ...}}` on the mesh or on a node using it.
    Extras,
    /// A keyword (`skin`, `muscle`, `bone`) in the mesh or node name.
    Name,
    /// [`LoadOptions::role_overrides`].
    Override,
    /// The model's only skinned mesh, made the skin by default.
    SingleSkinnedMesh,
}

/// Options for [`load`].
#[derive(Debug, Clone, Default)]
pub struct LoadOptions {
    /// Roles for meshes whose extras and name say nothing: (mesh or node name, role).
    pub role_overrides: Vec<(String, Role)>,
}

/// A node of the glTF hierarchy.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Node {
    /// Name (`node<i>` when the file has none).
    pub name: String,
    /// Parent node.
    pub parent: Option<u32>,
    /// Mesh drawn at this node.
    pub mesh: Option<u32>,
    /// Skin binding the mesh.
    pub skin: Option<u32>,
    /// Default morph weights of this node (override the mesh's).
    pub weights: Option<Vec<f32>>,
}

/// One morph target of a primitive: displacements added with the target's weight.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MorphTarget {
    /// Position displacements, metres (zeros when the target has none).
    pub positions: Vec<Vec3>,
    /// Normal displacements, if given.
    pub normals: Option<Vec<Vec3>>,
}

/// A drawable part of a mesh, in the file's own vertex order.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Primitive {
    /// Bind-pose (or local) positions, metres.
    pub positions: Vec<Vec3>,
    /// Normals, if given.
    pub normals: Option<Vec<Vec3>>,
    /// Triangles (strips and fans converted; empty for points and lines).
    pub triangles: Vec<[u32; 3]>,
    /// Joint influences from every `JOINTS_n`/`WEIGHTS_n` set, weights renormalised.
    pub influences: Option<Influences>,
    /// Morph targets.
    pub targets: Vec<MorphTarget>,
}

/// A mesh with its role.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Mesh {
    /// Name (`mesh<i>` when the file has none).
    pub name: String,
    /// Role, if any rule gave one.
    pub role: Option<Role>,
    /// Which rule gave the role.
    pub role_source: Option<RoleSource>,
    /// Primitives in file order.
    pub primitives: Vec<Primitive>,
    /// Default morph weights.
    pub weights: Vec<f32>,
}

/// Everything dermis needs from a glTF file, as plain data.
#[derive(Debug, Clone, PartialEq)]
pub struct Scene {
    /// All nodes, in file order.
    pub nodes: Vec<Node>,
    /// Parent links and rest transforms of `nodes`.
    pub hierarchy: Hierarchy,
    /// All meshes, in file order.
    pub meshes: Vec<Mesh>,
    /// All skins, in file order.
    pub skins: Vec<Skin>,
    /// All animations, in file order.
    pub clips: Vec<Clip>,
    /// Colliders fitted along the bones when the model's only skinned mesh is the skin and
    /// no mesh is a muscle or bone.
    pub capsules: Vec<Capsule>,
    /// Things skipped while loading (e.g. animation channels with no target node).
    pub warnings: Vec<String>,
}

/// Why a glTF file could not be loaded or played. Messages name the offending item.
#[derive(Debug, Error)]
pub enum GltfError {
    /// The model file could not be read. Check the path.
    #[error("cannot read {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// The `.glb` container is truncated or corrupt (header, chunk lengths). Re-export it.
    #[error("invalid .glb container: {reason}")]
    Glb {
        /// What is wrong.
        reason: String,
    },
    /// The JSON is not valid glTF 2.0 (syntax, missing fields, dangling indices).
    /// Run the Khronos glTF validator on the file.
    #[error("invalid glTF JSON: {reason}")]
    Json {
        /// The parser's or validator's message.
        reason: String,
    },
    /// An external buffer file (or data URI) could not be read. Put the `.bin` next to the
    /// `.gltf` under the name its `uri` gives.
    #[error("buffer {buffer} ({uri}) cannot be loaded: {reason}")]
    MissingBuffer {
        /// Buffer index.
        buffer: usize,
        /// Its URI (data URIs abbreviated).
        uri: String,
        /// Why.
        reason: String,
    },
    /// A buffer holds fewer bytes than its `byteLength` declares.
    #[error("buffer {buffer} declares {expected} bytes but holds {actual}")]
    BufferTooShort {
        /// Buffer index.
        buffer: usize,
        /// Declared length, bytes.
        expected: usize,
        /// Available bytes.
        actual: usize,
    },
    /// An accessor reads past the end of its buffer view or buffer (or a view past its
    /// buffer). Fix `byteOffset`, `count` or `byteStride` in the exporter.
    #[error("accessor {accessor} ({usage}) reads bytes {start}..{end}, but only {available} exist")]
    AccessorOutOfRange {
        /// Accessor index.
        accessor: usize,
        /// What it was read for, e.g. `mesh 0 primitive 1 POSITION`.
        usage: String,
        /// First byte read.
        start: usize,
        /// One past the last byte read.
        end: usize,
        /// Bytes available.
        available: usize,
    },
    /// An accessor has the wrong type for its use (e.g. a SCALAR `POSITION`).
    #[error("accessor {accessor} ({usage}) should be {expected}, found {found}")]
    AccessorType {
        /// Accessor index.
        accessor: usize,
        /// What it was read for.
        usage: String,
        /// Accepted types.
        expected: &'static str,
        /// The accessor's type.
        found: String,
    },
    /// Two per-vertex attributes of a primitive have different lengths, or an index points
    /// past the vertices.
    #[error("mesh {mesh} primitive {primitive}: {reason}")]
    Primitive {
        /// Mesh index.
        mesh: usize,
        /// Primitive index.
        primitive: usize,
        /// What is inconsistent.
        reason: String,
    },
    /// A vertex uses a joint index the skin does not have. Re-bind the mesh to its skin.
    #[error(
        "mesh {mesh} primitive {primitive} vertex {vertex} uses joint {joint}, but skin {skin} has only {joint_count} joints"
    )]
    JointOutOfRange {
        /// Mesh index.
        mesh: usize,
        /// Primitive index.
        primitive: usize,
        /// Vertex index.
        vertex: usize,
        /// Joint index as stored.
        joint: u32,
        /// Skin index.
        skin: usize,
        /// Joints in that skin.
        joint_count: usize,
    },
    /// A skinned vertex's weights are all zero. Paint weights onto it.
    #[error("mesh {mesh} primitive {primitive} vertex {vertex} has all skin weights zero")]
    ZeroWeights {
        /// Mesh index.
        mesh: usize,
        /// Primitive index.
        primitive: usize,
        /// Vertex index.
        vertex: usize,
    },
    /// A skin's inverse bind matrices do not match its joints.
    #[error("skin {skin} has {joints} joints but {matrices} inverse bind matrices")]
    InverseBindCount {
        /// Skin index.
        skin: usize,
        /// Joint count.
        joints: usize,
        /// Matrix count.
        matrices: usize,
    },
    /// An animation sampler is inconsistent (input/output count mismatch, unsorted times).
    #[error("animation {animation} channel {channel}: {source}")]
    Sampler {
        /// Animation index.
        animation: usize,
        /// Channel index.
        channel: usize,
        /// The check that failed.
        source: AnimationError,
    },
    /// The node hierarchy is not a forest.
    #[error("node hierarchy: {0}")]
    Hierarchy(AnimationError),
    /// No animation has the requested name or index. `dermis inspect` lists the clips.
    #[error("no animation {requested:?}: the file has {available} ({names})")]
    ClipNotFound {
        /// The name or index asked for.
        requested: String,
        /// How many animations exist.
        available: usize,
        /// Their names.
        names: String,
    },
}

/// Loads a `.gltf` (external or embedded buffers) or `.glb` file.
pub fn load(path: &Path, options: &LoadOptions) -> Result<Scene, GltfError> {
    let bytes = std::fs::read(path).map_err(|source| GltfError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let base = path.parent().map(|p| {
        if p.as_os_str().is_empty() {
            Path::new(".")
        } else {
            p
        }
    });
    Scene::from_slice(&bytes, base, options)
}

impl Scene {
    /// Loads from the bytes of a `.gltf` or `.glb`; relative buffer URIs resolve against
    /// `base_dir` (none: only embedded buffers are allowed).
    pub fn from_slice(
        bytes: &[u8],
        base_dir: Option<&Path>,
        options: &LoadOptions,
    ) -> Result<Self, GltfError> {
        load::load_slice(bytes, base_dir, options)
    }

    /// Finds a clip by exact name, else by index.
    pub fn find_clip(&self, name_or_index: &str) -> Result<usize, GltfError> {
        if let Some(i) = self.clips.iter().position(|c| c.name == name_or_index) {
            return Ok(i);
        }
        if let Ok(i) = name_or_index.parse::<usize>()
            && i < self.clips.len()
        {
            return Ok(i);
        }
        Err(GltfError::ClipNotFound {
            requested: name_or_index.to_string(),
            available: self.clips.len(),
            names: self
                .clips
                .iter()
                .enumerate()
                .map(|(i, c)| format!("{i}: {:?}", c.name))
                .collect::<Vec<_>>()
                .join(", "),
        })
    }

    /// Number of (node, primitive) pairs drawn, i.e. of [`PosedScene::primitives`].
    pub fn mesh_instance_count(&self) -> usize {
        self.nodes
            .iter()
            .filter_map(|n| n.mesh)
            .filter_map(|m| self.meshes.get(m as usize))
            .map(|m| m.primitives.len())
            .sum()
    }
}
