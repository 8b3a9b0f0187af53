//! Linear blend skinning and morph targets on the CPU, parallel over fixed-size vertex chunks.

use glam::{Mat4, Vec3};
use rayon::prelude::*;
use serde::Serialize;

use super::AnimationError;

/// Vertices per rayon task in [`skin_positions`] and [`skin_normals`]. Each vertex is computed
/// independently, so results are bit-identical for any thread count.
pub const SKIN_CHUNK: usize = 2048;

/// Per-vertex joint influences: `per_vertex` (joint, weight) pairs for every vertex, stored
/// vertex-major (glTF `JOINTS_n`/`WEIGHTS_n` sets concatenated, 4 per set).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Influences {
    per_vertex: usize,
    joints: Vec<u32>,
    weights: Vec<f32>,
}

impl Influences {
    /// Wraps joint and weight arrays of `vertices * per_vertex` entries each.
    pub fn new(
        per_vertex: usize,
        joints: Vec<u32>,
        weights: Vec<f32>,
    ) -> Result<Self, AnimationError> {
        let ok = per_vertex > 0
            && joints.len() == weights.len()
            && joints.len().is_multiple_of(per_vertex);
        if !ok {
            return Err(AnimationError::InfluenceLength {
                expected: joints
                    .len()
                    .max(weights.len())
                    .next_multiple_of(per_vertex.max(1)),
                joints: joints.len(),
                weights: weights.len(),
            });
        }
        Ok(Self {
            per_vertex,
            joints,
            weights,
        })
    }

    /// Number of vertices.
    pub fn vertex_count(&self) -> usize {
        self.joints.len() / self.per_vertex
    }

    /// Influences per vertex.
    pub fn per_vertex(&self) -> usize {
        self.per_vertex
    }

    /// Joint indices (into the skin's joint list) of vertex `v`.
    pub fn joints_of(&self, v: usize) -> &[u32] {
        &self.joints[v * self.per_vertex..(v + 1) * self.per_vertex]
    }

    /// Weights of vertex `v`, in the order of [`Self::joints_of`].
    pub fn weights_of(&self, v: usize) -> &[f32] {
        &self.weights[v * self.per_vertex..(v + 1) * self.per_vertex]
    }

    /// Scales every vertex's weights to sum to one. Negative or non-finite weights count as
    /// zero. Fails on the first vertex with no positive weight.
    pub fn normalize(&mut self) -> Result<(), AnimationError> {
        for (vertex, w) in self.weights.chunks_mut(self.per_vertex).enumerate() {
            for x in w.iter_mut() {
                if !x.is_finite() || *x < 0.0 {
                    *x = 0.0;
                }
            }
            let sum: f32 = w.iter().sum();
            if !(sum > 0.0 && sum.is_finite()) {
                return Err(AnimationError::ZeroWeights { vertex });
            }
            for x in w.iter_mut() {
                *x /= sum;
            }
        }
        Ok(())
    }

    /// Checks that every joint index with a non-zero weight is below `joint_count`.
    pub fn check_joints(&self, joint_count: usize) -> Result<(), AnimationError> {
        for (i, (&joint, &w)) in self.joints.iter().zip(&self.weights).enumerate() {
            if w != 0.0 && joint as usize >= joint_count {
                return Err(AnimationError::JointOutOfRange {
                    vertex: i / self.per_vertex,
                    joint,
                    joint_count,
                });
            }
        }
        Ok(())
    }

    /// The joint with the largest weight for each vertex (ties: the first listed).
    pub fn dominant_joints(&self) -> Vec<u32> {
        (0..self.vertex_count())
            .map(|v| {
                let (j, w) = (self.joints_of(v), self.weights_of(v));
                let mut best = 0;
                for k in 1..w.len() {
                    if w[k] > w[best] {
                        best = k;
                    }
                }
                j[best]
            })
            .collect()
    }
}

fn blend(v: usize, influences: &Influences, joints: &[Mat4], f: impl Fn(&Mat4) -> Vec3) -> Vec3 {
    let mut acc = Vec3::ZERO;
    for (&j, &w) in influences.joints_of(v).iter().zip(influences.weights_of(v)) {
        if w != 0.0
            && let Some(m) = joints.get(j as usize)
        {
            acc += w * f(m);
        }
    }
    acc
}

/// Linear blend skinning: `sum_i w_i * joints[j_i] * p` for each bind-space position `p`.
/// `influences` must cover `positions` (extra vertices keep their bind position); joint indices
/// outside `joints` contribute nothing (validate with [`Influences::check_joints`]).
pub fn skin_positions(positions: &[Vec3], influences: &Influences, joints: &[Mat4]) -> Vec<Vec3> {
    let mut out = positions.to_vec();
    let n = influences.vertex_count();
    out.par_chunks_mut(SKIN_CHUNK)
        .enumerate()
        .for_each(|(c, chunk)| {
            for (k, p) in chunk.iter_mut().enumerate() {
                let v = c * SKIN_CHUNK + k;
                if v < n {
                    let q = *p;
                    *p = blend(v, influences, joints, |m| m.transform_point3(q));
                }
            }
        });
    out
}

/// Skins normals with the blended linear part of the joint matrices, then renormalises
/// (exact for rotations and uniform scale).
pub fn skin_normals(normals: &[Vec3], influences: &Influences, joints: &[Mat4]) -> Vec<Vec3> {
    let mut out = normals.to_vec();
    let n = influences.vertex_count();
    out.par_chunks_mut(SKIN_CHUNK)
        .enumerate()
        .for_each(|(c, chunk)| {
            for (k, nrm) in chunk.iter_mut().enumerate() {
                let v = c * SKIN_CHUNK + k;
                if v < n {
                    let q = *nrm;
                    *nrm = blend(v, influences, joints, |m| m.transform_vector3(q))
                        .normalize_or_zero();
                }
            }
        });
    out
}

/// Adds `sum_k weights[k] * targets[k][v]` to every base vertex (glTF morph targets hold
/// displacements). Missing weights count as zero; short targets leave the rest untouched.
pub fn apply_morph_targets<T: AsRef<[Vec3]>>(
    base: &[Vec3],
    targets: &[T],
    weights: &[f32],
) -> Vec<Vec3> {
    let mut out = base.to_vec();
    for (target, &w) in targets.iter().zip(weights) {
        if w != 0.0 {
            for (p, d) in out.iter_mut().zip(target.as_ref()) {
                *p += w * *d;
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Quat;

    #[test]
    fn weights_renormalise_and_zero_weights_are_rejected() {
        let mut i = Influences::new(2, vec![0, 1, 0, 1], vec![1.0, 3.0, 0.0, -1.0]).unwrap();
        assert_eq!(
            i.normalize(),
            Err(AnimationError::ZeroWeights { vertex: 1 })
        );
        let mut i = Influences::new(2, vec![0, 1], vec![1.0, 3.0]).unwrap();
        i.normalize().unwrap();
        assert_eq!(i.weights_of(0), &[0.25, 0.75]);
        assert_eq!(
            i.check_joints(1),
            Err(AnimationError::JointOutOfRange {
                vertex: 0,
                joint: 1,
                joint_count: 1
            })
        );
    }

    #[test]
    fn blend_of_two_translations_is_the_weighted_mean_and_chunking_is_thread_independent() {
        let joints = [
            Mat4::from_translation(Vec3::X),
            Mat4::from_rotation_translation(Quat::from_rotation_z(0.3), Vec3::Y),
        ];
        let n = 3 * SKIN_CHUNK + 17;
        let positions: Vec<Vec3> = (0..n).map(|i| Vec3::splat(i as f32 * 1e-3)).collect();
        let w: Vec<f32> = (0..n).flat_map(|i| [0.25, 0.75 + (i % 3) as f32]).collect();
        let mut inf = Influences::new(2, (0..n).flat_map(|_| [0, 1]).collect(), w).unwrap();
        inf.normalize().unwrap();
        let a = skin_positions(&positions, &inf, &joints);
        let b = crate::test_support::in_pool(1, || skin_positions(&positions, &inf, &joints));
        assert_eq!(a, b);
        let p = positions[5];
        let (w0, w1) = (inf.weights_of(5)[0], inf.weights_of(5)[1]);
        let expect = w0 * (p + Vec3::X) + w1 * (Quat::from_rotation_z(0.3) * p + Vec3::Y);
        assert!((a[5] - expect).length() < 1e-6);
    }
}
