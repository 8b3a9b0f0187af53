//! Node hierarchy, per-frame pose and skins (joint lists with inverse bind matrices).

use glam::{Mat4, Quat, Vec3};
use serde::Serialize;

use super::{AnimationError, Trs};

/// A node's transform relative to its parent: TRS (animatable) or a full matrix.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub enum LocalTransform {
    /// Translation, rotation, scale, composed as `T * R * S`.
    Trs(Trs),
    /// A column-major matrix (glTF `matrix`); may hold shear.
    Matrix(Mat4),
}

impl LocalTransform {
    /// The identity transform.
    pub const IDENTITY: Self = Self::Trs(Trs::IDENTITY);

    /// A TRS transform.
    pub fn from_trs(translation: Vec3, rotation: Quat, scale: Vec3) -> Self {
        Self::Trs(Trs {
            translation,
            rotation,
            scale,
        })
    }

    /// The transform as a matrix.
    pub fn to_mat4(&self) -> Mat4 {
        match self {
            Self::Trs(trs) => trs.to_mat4(),
            Self::Matrix(m) => *m,
        }
    }

    /// The transform as TRS (a matrix is decomposed, dropping any shear), for animation to
    /// overwrite one of its parts.
    pub fn to_trs(&self) -> Trs {
        match self {
            Self::Trs(trs) => *trs,
            Self::Matrix(m) => {
                let (scale, rotation, translation) = m.to_scale_rotation_translation();
                Trs {
                    translation,
                    rotation,
                    scale,
                }
            }
        }
    }
}

/// Parent links and rest transforms of every node, with a parents-first evaluation order.
#[derive(Debug, Clone, PartialEq)]
pub struct Hierarchy {
    parents: Vec<Option<u32>>,
    rest: Vec<LocalTransform>,
    order: Vec<u32>,
}

impl Hierarchy {
    /// Builds the hierarchy, checking parent indices and rejecting cycles.
    pub fn new(
        parents: Vec<Option<u32>>,
        rest: Vec<LocalTransform>,
    ) -> Result<Self, AnimationError> {
        let n = parents.len();
        if rest.len() != n {
            return Err(AnimationError::LengthMismatch {
                parents: n,
                transforms: rest.len(),
            });
        }
        for (node, p) in parents.iter().enumerate() {
            if let Some(p) = *p
                && p as usize >= n
            {
                return Err(AnimationError::ParentOutOfRange {
                    node,
                    parent: p as usize,
                    node_count: n,
                });
            }
        }
        // Depth of each node, by walking up with a step bound that detects cycles.
        let mut depth = vec![u32::MAX; n];
        for start in 0..n {
            let mut chain = Vec::new();
            let mut node = Some(start);
            let mut base = 0;
            while let Some(v) = node {
                if depth[v] != u32::MAX {
                    base = depth[v] + 1;
                    break;
                }
                if chain.len() >= n {
                    return Err(AnimationError::Cycle { node: start });
                }
                chain.push(v);
                node = parents[v].map(|p| p as usize);
            }
            for (k, &c) in chain.iter().rev().enumerate() {
                depth[c] = base + k as u32;
            }
        }
        let mut order: Vec<u32> = (0..n as u32).collect();
        order.sort_by_key(|&i| (depth[i as usize], i));
        Ok(Self {
            parents,
            rest,
            order,
        })
    }

    /// Number of nodes.
    pub fn len(&self) -> usize {
        self.parents.len()
    }

    /// True when there are no nodes.
    pub fn is_empty(&self) -> bool {
        self.parents.is_empty()
    }

    /// Parent of each node.
    pub fn parents(&self) -> &[Option<u32>] {
        &self.parents
    }

    /// Rest (unanimated) local transform of each node.
    pub fn rest(&self) -> &[LocalTransform] {
        &self.rest
    }

    /// Node indices with every parent before its children.
    pub fn order(&self) -> &[u32] {
        &self.order
    }

    /// World transforms from local ones (`locals[i]` for node `i`), parents first.
    /// `locals` must have one entry per node; missing entries count as identity.
    pub fn global_transforms(&self, locals: &[LocalTransform]) -> Vec<Mat4> {
        let mut globals = vec![Mat4::IDENTITY; self.len()];
        for &i in &self.order {
            let i = i as usize;
            let local = locals
                .get(i)
                .map_or(Mat4::IDENTITY, LocalTransform::to_mat4);
            globals[i] = match self.parents[i] {
                Some(p) => globals[p as usize] * local,
                None => local,
            };
        }
        globals
    }
}

/// The animatable state of every node at one instant.
#[derive(Debug, Clone, PartialEq)]
pub struct Pose {
    /// Local transform of each node.
    pub locals: Vec<LocalTransform>,
    /// Morph-target weights set by animation, per node (`None`: use the node's or mesh's
    /// default weights).
    pub morph_weights: Vec<Option<Vec<f32>>>,
}

impl Pose {
    /// The rest pose: every node at its rest transform, no animated weights.
    pub fn rest(hierarchy: &Hierarchy) -> Self {
        Self {
            locals: hierarchy.rest.clone(),
            morph_weights: vec![None; hierarchy.len()],
        }
    }
}

/// A skin: the joint nodes a mesh is bound to and their inverse bind matrices.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Skin {
    /// Node index of each joint.
    pub joints: Vec<u32>,
    /// Inverse bind matrix of each joint (same length as `joints`), mapping mesh (bind) space
    /// to the joint's space.
    pub inverse_bind: Vec<Mat4>,
    /// Common root of the joints, if the file names one.
    pub skeleton: Option<u32>,
}

impl Skin {
    /// Joint matrices `global(joint) * inverse_bind(joint)`, mapping bind-space vertices to
    /// world space. Joints whose node index is outside `globals` use the identity.
    pub fn joint_matrices(&self, globals: &[Mat4]) -> Vec<Mat4> {
        self.joints
            .iter()
            .zip(&self.inverse_bind)
            .map(|(&j, ib)| globals.get(j as usize).copied().unwrap_or(Mat4::IDENTITY) * *ib)
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    #[test]
    fn children_listed_before_parents_still_evaluate_parents_first() {
        // Node 0 is the child of node 2, which is the child of node 1.
        let t =
            |x: f32| LocalTransform::from_trs(Vec3::new(x, 0.0, 0.0), Quat::IDENTITY, Vec3::ONE);
        let h = Hierarchy::new(
            vec![Some(2), None, Some(1)],
            vec![t(1.0), t(10.0), t(100.0)],
        )
        .unwrap();
        assert_eq!(h.order(), &[1, 2, 0]);
        let g = h.global_transforms(h.rest());
        assert_relative_eq!(g[0].w_axis.x, 111.0);
        assert_relative_eq!(g[2].w_axis.x, 110.0);
    }

    #[test]
    fn cycles_and_bad_parents_are_rejected() {
        let r = vec![LocalTransform::IDENTITY; 3];
        assert_eq!(
            Hierarchy::new(vec![Some(1), Some(2), Some(0)], r.clone()),
            Err(AnimationError::Cycle { node: 0 })
        );
        assert!(matches!(
            Hierarchy::new(vec![None, Some(7), None], r),
            Err(AnimationError::ParentOutOfRange {
                node: 1,
                parent: 7,
                ..
            })
        ));
    }
}
