//! Skeletal animation: node hierarchies, clips and their sampling, linear blend skinning.
//!
//! Everything here is plain data and pure functions, independent of the glTF loader and of any
//! ECS. A frame is evaluated as
//!
//! 1. [`Pose::rest`] copies the rest local transforms of every node,
//! 2. [`Clip::apply`] overwrites the animated translation, rotation, scale and morph weights at
//!    time `t` (STEP, LINEAR with shortest-path slerp, CUBICSPLINE with in/out tangents),
//! 3. [`Hierarchy::global_transforms`] composes local transforms parents first,
//! 4. [`Skin::joint_matrices`] gives `global(joint) * inverse_bind` per joint,
//! 5. [`apply_morph_targets`] then [`skin_positions`] deform each mesh on the CPU.
//!
//! ```
//! use dermis::animation::{Hierarchy, LocalTransform, Pose, Skin, Influences, skin_positions};
//! use glam::{Mat4, Quat, Vec3};
//!
//! // Two joints on the x axis; the second one rotated 90 degrees about z.
//! let rest = vec![
//!     LocalTransform::IDENTITY,
//!     LocalTransform::from_trs(Vec3::X, Quat::from_rotation_z(std::f32::consts::FRAC_PI_2), Vec3::ONE),
//! ];
//! let hierarchy = Hierarchy::new(vec![None, Some(0)], rest).unwrap();
//! let pose = Pose::rest(&hierarchy);
//! let globals = hierarchy.global_transforms(&pose.locals);
//! let skin = Skin {
//!     joints: vec![0, 1],
//!     inverse_bind: vec![Mat4::IDENTITY, Mat4::from_translation(-Vec3::X)],
//!     skeleton: None,
//! };
//! let joints = skin.joint_matrices(&globals);
//! // A vertex at x = 2, fully bound to the second joint, swings up to (1, 1, 0).
//! let influences = Influences::new(2, vec![1, 0], vec![1.0, 0.0]).unwrap();
//! let posed = skin_positions(&[Vec3::new(2.0, 0.0, 0.0)], &influences, &joints);
//! assert!((posed[0] - Vec3::new(1.0, 1.0, 0.0)).length() < 1e-6);
//! ```

mod clip;
mod hierarchy;
mod skinning;

pub use clip::{Channel, Clip, Interpolation, Keyframes, Sampler, Trs, slerp_short};
pub use hierarchy::{Hierarchy, LocalTransform, Pose, Skin};
pub use skinning::{Influences, SKIN_CHUNK, apply_morph_targets, skin_normals, skin_positions};

use thiserror::Error;

/// Why skeleton, clip or skinning data was rejected.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum AnimationError {
    /// A node's parent index does not exist. Fix the hierarchy so every parent is a node.
    #[error("node {node} has parent {parent}, but there are only {node_count} nodes")]
    ParentOutOfRange {
        /// The node.
        node: usize,
        /// Its parent index as given.
        parent: usize,
        /// Number of nodes.
        node_count: usize,
    },
    /// Following parents from a node comes back to it. Break the cycle in the modelling tool.
    #[error("node {node} is its own ancestor (the hierarchy has a cycle)")]
    Cycle {
        /// A node on the cycle.
        node: usize,
    },
    /// Parent and rest-transform lists differ in length.
    #[error("{parents} parents but {transforms} rest transforms")]
    LengthMismatch {
        /// Number of parent entries.
        parents: usize,
        /// Number of rest transforms.
        transforms: usize,
    },
    /// A sampler has a different number of output values than its keyframe times require
    /// (one per key, three per key for CUBICSPLINE, times the morph-target count for weights).
    #[error(
        "sampler has {inputs} keyframe times, so {expected} output values are required, found {outputs}"
    )]
    SamplerCountMismatch {
        /// Number of keyframe times.
        inputs: usize,
        /// Number of output values required.
        expected: usize,
        /// Number of output values found.
        outputs: usize,
    },
    /// Keyframe times must be finite and strictly increasing. Re-export the clip.
    #[error("keyframe {key} time {time} is not finite or not after the previous key")]
    UnsortedKeyframes {
        /// Index of the offending keyframe.
        key: usize,
        /// Its time, seconds.
        time: f32,
    },
    /// A sampler has no keyframes at all.
    #[error("sampler has no keyframes")]
    NoKeyframes,
    /// Influence arrays do not hold `vertices * per_vertex` entries.
    #[error(
        "influences need {expected} joint and weight entries, found {joints} joints and {weights} weights"
    )]
    InfluenceLength {
        /// Entries required.
        expected: usize,
        /// Joint entries given.
        joints: usize,
        /// Weight entries given.
        weights: usize,
    },
    /// A vertex's weights sum to zero (or are negative / non-finite), so it follows no joint.
    /// Paint weights onto the vertex in the modelling tool.
    #[error("vertex {vertex} has no positive finite skin weight")]
    ZeroWeights {
        /// The vertex.
        vertex: usize,
    },
    /// A vertex is bound to a joint index the skin does not have.
    #[error("vertex {vertex} uses joint {joint}, but the skin has only {joint_count} joints")]
    JointOutOfRange {
        /// The vertex.
        vertex: usize,
        /// The joint index as stored.
        joint: u32,
        /// Number of joints in the skin.
        joint_count: usize,
    },
}
