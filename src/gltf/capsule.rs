//! Capsule colliders fitted along the bones of a skin, for models that have only a skin.

use glam::{Mat4, Vec3};
use serde::Serialize;

use super::Mesh;
use crate::animation::{Hierarchy, Skin};

/// A capsule collider in bind space, attached to one joint of a skin.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Capsule {
    /// Index into the skin's joint list.
    pub joint: u32,
    /// Node index of that joint.
    pub node: u32,
    /// First end point of the axis (bind space, metres).
    pub a: Vec3,
    /// Second end point of the axis (bind space, metres).
    pub b: Vec3,
    /// Radius, metres: the median distance from the axis of the skin vertices this joint
    /// influences most.
    pub radius_m: f32,
}

impl Capsule {
    /// End points moved by the skin's joint matrices (from [`Skin::joint_matrices`]).
    pub fn posed(&self, joint_matrices: &[Mat4]) -> (Vec3, Vec3) {
        let m = joint_matrices
            .get(self.joint as usize)
            .copied()
            .unwrap_or(Mat4::IDENTITY);
        (m.transform_point3(self.a), m.transform_point3(self.b))
    }
}

fn distance_to_segment(p: Vec3, a: Vec3, b: Vec3) -> f32 {
    let ab = b - a;
    let len2 = ab.length_squared();
    let s = if len2 > 0.0 {
        ((p - a).dot(ab) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    p.distance(a + s * ab)
}

/// Fits one capsule per bone (joint to each child joint; a leaf joint extends along its
/// parent bone direction to its farthest vertex) from the skin vertices each joint influences
/// most. Joints that dominate no vertex get no capsule.
pub fn fit_capsules(hierarchy: &Hierarchy, skin: &Skin, mesh: &Mesh) -> Vec<Capsule> {
    let nj = skin.joints.len();
    let pos: Vec<Vec3> = skin
        .inverse_bind
        .iter()
        .map(|ib| ib.inverse().w_axis.truncate())
        .collect();
    // Nearest ancestor that is a joint of this skin.
    let parents = hierarchy.parents();
    let joint_of_node = |node: u32| skin.joints.iter().position(|&j| j == node);
    let parent_joint: Vec<Option<usize>> = skin
        .joints
        .iter()
        .map(|&node| {
            let mut cur = parents.get(node as usize).copied().flatten();
            let mut steps = 0;
            while let Some(p) = cur {
                if let Some(j) = joint_of_node(p) {
                    return Some(j);
                }
                steps += 1;
                if steps > parents.len() {
                    return None;
                }
                cur = parents.get(p as usize).copied().flatten();
            }
            None
        })
        .collect();
    let mut dominated: Vec<Vec<Vec3>> = vec![Vec::new(); nj];
    for prim in &mesh.primitives {
        if let Some(inf) = &prim.influences {
            for (v, j) in inf.dominant_joints().into_iter().enumerate() {
                if let (Some(list), Some(p)) =
                    (dominated.get_mut(j as usize), prim.positions.get(v))
                {
                    list.push(*p);
                }
            }
        }
    }
    let mut capsules = Vec::new();
    for j in 0..nj {
        if dominated[j].is_empty() || !pos[j].is_finite() {
            continue;
        }
        let a = pos[j];
        let children: Vec<usize> = (0..nj).filter(|&k| parent_joint[k] == Some(j)).collect();
        let ends: Vec<Vec3> = if !children.is_empty() {
            children.iter().map(|&k| pos[k]).collect()
        } else if let Some(p) = parent_joint[j] {
            let d = (a - pos[p]).normalize_or_zero();
            let reach = dominated[j]
                .iter()
                .map(|v| (*v - a).dot(d))
                .fold(0.0f32, f32::max);
            vec![a + d * reach]
        } else {
            vec![a]
        };
        let mut per_segment: Vec<Vec<f32>> = vec![Vec::new(); ends.len()];
        for v in &dominated[j] {
            let (best, dist) = ends
                .iter()
                .enumerate()
                .map(|(s, b)| (s, distance_to_segment(*v, a, *b)))
                .fold(
                    (0, f32::INFINITY),
                    |acc, x| if x.1 < acc.1 { x } else { acc },
                );
            per_segment[best].push(dist);
        }
        for (b, mut d) in ends.into_iter().zip(per_segment) {
            if d.is_empty() {
                continue;
            }
            d.sort_by(f32::total_cmp);
            capsules.push(Capsule {
                joint: j as u32,
                node: skin.joints[j],
                a,
                b,
                radius_m: d[d.len() / 2],
            });
        }
    }
    capsules
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::animation::{Influences, LocalTransform};
    use crate::gltf::Primitive;

    #[test]
    fn a_cylinder_around_one_bone_gets_its_radius_and_axis() {
        // Joint 0 at the origin, joint 1 at x = 1; vertices on a radius-0.2 circle ring at
        // x = 0.25, 0.5, 0.75, all bound to joint 0.
        let h = Hierarchy::new(vec![None, Some(0)], vec![LocalTransform::IDENTITY; 2]).unwrap();
        let skin = Skin {
            joints: vec![0, 1],
            inverse_bind: vec![Mat4::IDENTITY, Mat4::from_translation(-Vec3::X)],
            skeleton: None,
        };
        let mut positions = Vec::new();
        for x in [0.25f32, 0.5, 0.75] {
            for k in 0..8 {
                let t = k as f32 * std::f32::consts::TAU / 8.0;
                positions.push(Vec3::new(x, 0.2 * t.cos(), 0.2 * t.sin()));
            }
        }
        let n = positions.len();
        let influences = Influences::new(
            4,
            vec![0; 4 * n],
            (0..n).flat_map(|_| [1.0, 0.0, 0.0, 0.0]).collect(),
        )
        .unwrap();
        let mesh = Mesh {
            name: "skin".into(),
            role: None,
            role_source: None,
            primitives: vec![Primitive {
                positions,
                normals: None,
                triangles: vec![],
                influences: Some(influences),
                targets: vec![],
            }],
            weights: vec![],
        };
        let caps = fit_capsules(&h, &skin, &mesh);
        assert_eq!(caps.len(), 1);
        assert!((caps[0].radius_m - 0.2).abs() < 1e-5);
        assert_eq!(caps[0].a, Vec3::ZERO);
        assert!((caps[0].b - Vec3::X).length() < 1e-6);
    }
}
