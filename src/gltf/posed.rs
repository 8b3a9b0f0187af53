//! Evaluating a [`Scene`] at a time into world-space primitives; OBJ and PLY output.

use std::io::{self, Write};

use glam::{Mat4, Vec3};
use serde::Serialize;

use super::Scene;
use crate::animation::{Pose, apply_morph_targets, skin_normals, skin_positions};

/// One (node, primitive) pair posed in world space.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PosedPrimitive {
    /// Node drawing the mesh.
    pub node: u32,
    /// Mesh index.
    pub mesh: u32,
    /// Primitive index within the mesh.
    pub primitive: u32,
    /// `<node name>.<primitive index>`.
    pub name: String,
    /// World-space positions, metres, in the primitive's accessor order.
    pub positions: Vec<Vec3>,
    /// World-space unit normals, if the primitive has normals.
    pub normals: Option<Vec<Vec3>>,
    /// Triangles (indices into `positions`).
    pub triangles: Vec<[u32; 3]>,
}

/// Every mesh primitive at one instant: node-index order, then primitive order.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PosedScene {
    /// Clip index sampled, if any.
    pub clip: Option<usize>,
    /// Time sampled, seconds.
    pub time_s: f32,
    /// The posed primitives.
    pub primitives: Vec<PosedPrimitive>,
}

impl Scene {
    /// The pose at `time_s` seconds of clip `clip` (`None`: the rest pose).
    pub fn sample(&self, clip: Option<usize>, time_s: f32) -> Pose {
        let mut pose = Pose::rest(&self.hierarchy);
        if let Some(c) = clip.and_then(|c| self.clips.get(c)) {
            c.apply(time_s, &mut pose);
        }
        pose
    }

    /// Poses every mesh primitive at `time_s` of `clip` in world space: morph targets first,
    /// then linear blend skinning for skinned nodes (whose own transform is ignored), else the
    /// node's world transform.
    pub fn pose(&self, clip: Option<usize>, time_s: f32) -> PosedScene {
        let pose = self.sample(clip, time_s);
        let globals = self.hierarchy.global_transforms(&pose.locals);
        let joint_mats: Vec<Vec<Mat4>> = self
            .skins
            .iter()
            .map(|s| s.joint_matrices(&globals))
            .collect();
        let mut primitives = Vec::new();
        for (n, node) in self.nodes.iter().enumerate() {
            let Some(mesh) = node.mesh.and_then(|m| self.meshes.get(m as usize)) else {
                continue;
            };
            let weights: &[f32] = pose
                .morph_weights
                .get(n)
                .and_then(Option::as_deref)
                .or(node.weights.as_deref())
                .unwrap_or(&mesh.weights);
            let skin = node.skin.and_then(|s| joint_mats.get(s as usize));
            for (p, prim) in mesh.primitives.iter().enumerate() {
                let targets: Vec<&[Vec3]> = prim
                    .targets
                    .iter()
                    .map(|t| t.positions.as_slice())
                    .collect();
                let mut positions = apply_morph_targets(&prim.positions, &targets, weights);
                let mut normals = prim.normals.as_ref().map(|base| {
                    let nt: Vec<&[Vec3]> = prim
                        .targets
                        .iter()
                        .map(|t| t.normals.as_deref().unwrap_or(&[]))
                        .collect();
                    apply_morph_targets(base, &nt, weights)
                });
                match (skin, &prim.influences) {
                    (Some(joints), Some(inf)) => {
                        positions = skin_positions(&positions, inf, joints);
                        normals = normals.map(|nr| skin_normals(&nr, inf, joints));
                    }
                    _ => {
                        let g = globals[n];
                        let nm = Mat4::from_mat3(glam::Mat3::from_mat4(g).inverse().transpose());
                        for v in &mut positions {
                            *v = g.transform_point3(*v);
                        }
                        if let Some(nr) = normals.as_mut() {
                            for v in nr.iter_mut() {
                                *v = nm.transform_vector3(*v).normalize_or_zero();
                            }
                        }
                    }
                }
                primitives.push(PosedPrimitive {
                    node: n as u32,
                    mesh: node.mesh.unwrap_or(0),
                    primitive: p as u32,
                    name: format!("{}.{p}", node.name),
                    positions,
                    normals,
                    triangles: prim.triangles.clone(),
                });
            }
        }
        PosedScene {
            clip,
            time_s,
            primitives,
        }
    }
}

impl PosedScene {
    /// Writes Wavefront OBJ: one `o <node name>.<primitive>` object per primitive, its
    /// vertices (and normals) in accessor order, 1-based faces.
    pub fn write_obj(&self, w: &mut impl Write) -> io::Result<()> {
        writeln!(
            w,
            "# dermis pose: clip {:?}, t = {} s",
            self.clip, self.time_s
        )?;
        let (mut v0, mut n0) = (1usize, 1usize);
        for p in &self.primitives {
            writeln!(w, "o {}", p.name.replace(['\n', '\r'], " "))?;
            for v in &p.positions {
                writeln!(w, "v {} {} {}", v.x, v.y, v.z)?;
            }
            if let Some(normals) = &p.normals {
                for n in normals {
                    writeln!(w, "vn {} {} {}", n.x, n.y, n.z)?;
                }
            }
            for t in &p.triangles {
                let [a, b, c] = t.map(|i| i as usize);
                if p.normals.is_some() {
                    writeln!(
                        w,
                        "f {}//{} {}//{} {}//{}",
                        a + v0,
                        a + n0,
                        b + v0,
                        b + n0,
                        c + v0,
                        c + n0
                    )?;
                } else {
                    writeln!(w, "f {} {} {}", a + v0, b + v0, c + v0)?;
                }
            }
            v0 += p.positions.len();
            if let Some(normals) = &p.normals {
                n0 += normals.len();
            }
        }
        Ok(())
    }

    /// Writes ASCII PLY with all primitives concatenated in order (vertex indices offset).
    pub fn write_ply(&self, w: &mut impl Write) -> io::Result<()> {
        let nv: usize = self.primitives.iter().map(|p| p.positions.len()).sum();
        let nf: usize = self.primitives.iter().map(|p| p.triangles.len()).sum();
        writeln!(w, "ply\nformat ascii 1.0")?;
        writeln!(
            w,
            "comment dermis pose: clip {:?}, t = {} s",
            self.clip, self.time_s
        )?;
        for p in &self.primitives {
            writeln!(
                w,
                "comment object {} vertices {}",
                p.name,
                p.positions.len()
            )?;
        }
        writeln!(
            w,
            "element vertex {nv}\nproperty float x\nproperty float y\nproperty float z"
        )?;
        writeln!(
            w,
            "element face {nf}\nproperty list uchar uint vertex_indices\nend_header"
        )?;
        for p in &self.primitives {
            for v in &p.positions {
                writeln!(w, "{} {} {}", v.x, v.y, v.z)?;
            }
        }
        let mut v0 = 0usize;
        for p in &self.primitives {
            for t in &p.triangles {
                let [a, b, c] = t.map(|i| i as usize + v0);
                writeln!(w, "3 {a} {b} {c}")?;
            }
            v0 += p.positions.len();
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn two_triangles() -> PosedScene {
        let prim = |node: u32, name: &str| PosedPrimitive {
            node,
            mesh: 0,
            primitive: 0,
            name: name.into(),
            positions: vec![Vec3::ZERO, Vec3::X, Vec3::Y],
            normals: None,
            triangles: vec![[0, 1, 2]],
        };
        PosedScene {
            clip: None,
            time_s: 0.0,
            primitives: vec![prim(0, "a.0"), prim(1, "b.0")],
        }
    }

    #[test]
    fn obj_and_ply_offset_the_second_primitive_indices() {
        let scene = two_triangles();
        let mut obj = Vec::new();
        scene.write_obj(&mut obj).unwrap();
        let obj = String::from_utf8(obj).unwrap();
        let faces: Vec<&str> = obj.lines().filter(|l| l.starts_with("f ")).collect();
        assert_eq!(faces, ["f 1 2 3", "f 4 5 6"]);
        assert_eq!(obj.lines().filter(|l| l.starts_with("o ")).count(), 2);
        let mut ply = Vec::new();
        scene.write_ply(&mut ply).unwrap();
        let ply = String::from_utf8(ply).unwrap();
        assert!(ply.contains("element vertex 6\n") && ply.contains("element face 2\n"));
        assert!(ply.trim_end().ends_with("3 3 4 5"));
    }
}
