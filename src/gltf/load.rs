//! Container parsing, buffer loading and conversion of a glTF document into a [`Scene`].

use std::borrow::Cow;
use std::path::Path;

use ::gltf::accessor::Dimensions;
use ::gltf::animation::{Interpolation as GInterp, Property};
use ::gltf::mesh::{Mode, Semantic};
use ::gltf::scene::Transform;
use ::gltf::{Document, json};
use glam::{Mat4, Quat, Vec3};

use super::read::{read, read_indices, read_scalar, read_vec3};
use super::{
    GltfError, LoadOptions, Mesh, MorphTarget, Node, Primitive, Role, RoleSource, Scene,
    fit_capsules,
};
use crate::animation::{
    Channel, Clip, Hierarchy, Influences, Interpolation, Keyframes, LocalTransform, Sampler, Skin,
};

/// JSON text and the optional BIN chunk of a container.
type Split<'a> = (Cow<'a, [u8]>, Option<Vec<u8>>);

/// Splits a `.glb` into JSON and BIN chunks, or passes `.gltf` JSON through.
fn split_container(bytes: &[u8]) -> Result<Split<'_>, GltfError> {
    if !bytes.starts_with(b"glTF") {
        return Ok((Cow::Borrowed(bytes), None));
    }
    let glb = |reason: String| GltfError::Glb { reason };
    let Some(header) = bytes.get(8..12) else {
        return Err(glb(format!(
            "file is {} bytes, shorter than the 12-byte header",
            bytes.len()
        )));
    };
    let length = u32::from_le_bytes([header[0], header[1], header[2], header[3]]) as usize;
    if length < 20 || length > bytes.len() {
        return Err(glb(format!(
            "header declares {length} bytes, file has {} (truncated?)",
            bytes.len()
        )));
    }
    let parsed =
        ::gltf::binary::Glb::from_slice(&bytes[..length]).map_err(|e| glb(e.to_string()))?;
    Ok((
        Cow::Owned(parsed.json.into_owned()),
        parsed.bin.map(Cow::into_owned),
    ))
}

/// Drops animation channels without a target node (allowed by glTF 2.0, meant for
/// extensions, but rejected by the `gltf` crate's schema). Returns the JSON and warnings.
fn without_untargeted_channels(json_bytes: &[u8]) -> Option<(Vec<u8>, Vec<String>)> {
    let mut value: serde_json::Value = serde_json::from_slice(json_bytes).ok()?;
    let mut warnings = Vec::new();
    let animations = value.get_mut("animations")?.as_array_mut()?;
    for (a, anim) in animations.iter_mut().enumerate() {
        let Some(channels) = anim.get_mut("channels").and_then(|c| c.as_array_mut()) else {
            continue;
        };
        let mut c = 0;
        channels.retain(|ch| {
            let keep = ch.get("target").and_then(|t| t.get("node")).is_some();
            if !keep {
                warnings.push(format!(
                    "animation {a} channel {c} has no target node and was ignored"
                ));
            }
            c += 1;
            keep
        });
    }
    if warnings.is_empty() {
        return None;
    }
    Some((serde_json::to_vec(&value).ok()?, warnings))
}

/// Checks what the `gltf` crate's validation skips (or indexes before checking): primitive
/// POSITION accessor indices, animation channel target nodes and paths.
fn check_channels(root: &json::Root) -> Result<(), GltfError> {
    for (m, mesh) in root.meshes.iter().enumerate() {
        for (p, prim) in mesh.primitives.iter().enumerate() {
            let position = prim.attributes.get(&json::validation::Checked::Valid(
                json::mesh::Semantic::Positions,
            ));
            if let Some(i) = position
                && i.value() >= root.accessors.len()
            {
                return Err(GltfError::Json {
                    reason: format!(
                        "meshes[{m}].primitives[{p}].attributes.POSITION: accessor {} does not exist ({} accessors)",
                        i.value(),
                        root.accessors.len()
                    ),
                });
            }
        }
    }
    for (a, anim) in root.animations.iter().enumerate() {
        for (c, ch) in anim.channels.iter().enumerate() {
            let at = format!("animations[{a}].channels[{c}].target");
            if ch.target.node.value() >= root.nodes.len() {
                return Err(GltfError::Json {
                    reason: format!(
                        "{at}.node: node {} does not exist ({} nodes)",
                        ch.target.node.value(),
                        root.nodes.len()
                    ),
                });
            }
            if !matches!(ch.target.path, json::validation::Checked::Valid(_)) {
                return Err(GltfError::Json {
                    reason: format!("{at}.path: not translation, rotation, scale or weights"),
                });
            }
        }
    }
    Ok(())
}

fn parse_document(json_bytes: &[u8]) -> Result<(Document, Vec<String>), GltfError> {
    let root = match serde_json::from_slice::<json::Root>(json_bytes) {
        Ok(root) => (root, Vec::new()),
        Err(first) => {
            let fixed = without_untargeted_channels(json_bytes).and_then(|(bytes, warnings)| {
                serde_json::from_slice::<json::Root>(&bytes)
                    .ok()
                    .map(|r| (r, warnings))
            });
            fixed.ok_or_else(|| GltfError::Json {
                reason: first.to_string(),
            })?
        }
    };
    check_channels(&root.0)?;
    let doc = Document::from_json(root.0).map_err(|e| GltfError::Json {
        reason: match e {
            ::gltf::Error::Validation(list) => list
                .iter()
                .take(5)
                .map(|(path, err)| format!("{path}: {err}"))
                .collect::<Vec<_>>()
                .join("; "),
            other => other.to_string(),
        },
    })?;
    Ok((doc, root.1))
}

fn load_buffers(
    doc: &Document,
    base: Option<&Path>,
    mut blob: Option<Vec<u8>>,
) -> Result<Vec<Vec<u8>>, GltfError> {
    let mut out = Vec::new();
    for buffer in doc.buffers() {
        let uri = match buffer.source() {
            ::gltf::buffer::Source::Bin => "GLB BIN chunk".to_string(),
            ::gltf::buffer::Source::Uri(u) if u.starts_with("data:") => {
                format!("{}...", u.chars().take(40).collect::<String>())
            }
            ::gltf::buffer::Source::Uri(u) => u.to_string(),
        };
        let data = ::gltf::buffer::Data::from_source_and_blob(buffer.source(), base, &mut blob)
            .map_err(|e| GltfError::MissingBuffer {
                buffer: buffer.index(),
                uri,
                reason: match (&e, base) {
                    (::gltf::Error::ExternalReferenceInSliceImport, None) => {
                        "external file referenced but no base directory given".to_string()
                    }
                    _ => e.to_string(),
                },
            })?;
        if data.0.len() < buffer.length() {
            return Err(GltfError::BufferTooShort {
                buffer: buffer.index(),
                expected: buffer.length(),
                actual: data.0.len(),
            });
        }
        out.push(data.0);
    }
    Ok(out)
}

fn role_from_extras(extras: &json::Extras) -> Option<Role> {
    let raw = extras.as_ref()?;
    let v: serde_json::Value = serde_json::from_str(raw.get()).ok()?;
    Role::parse(v.get("dermis")?.get("role")?.as_str()?)
}

fn role_from_name(name: &str) -> Option<Role> {
    let n = name.to_ascii_lowercase();
    [
        ("skin", Role::Skin),
        ("muscle", Role::Muscle),
        ("bone", Role::Bone),
    ]
    .into_iter()
    .find(|(k, _)| n.contains(k))
    .map(|(_, r)| r)
}

fn triangles_of(mode: Mode, idx: &[u32]) -> Vec<[u32; 3]> {
    match mode {
        Mode::Triangles => idx.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
        Mode::TriangleStrip => (2..idx.len())
            .map(|i| {
                if i % 2 == 0 {
                    [idx[i - 2], idx[i - 1], idx[i]]
                } else {
                    [idx[i - 1], idx[i - 2], idx[i]]
                }
            })
            .collect(),
        Mode::TriangleFan => (2..idx.len())
            .map(|i| [idx[i - 1], idx[i], idx[0]])
            .collect(),
        _ => Vec::new(),
    }
}

fn load_primitive(
    prim: &::gltf::Primitive,
    m: usize,
    buffers: &[Vec<u8>],
) -> Result<Primitive, GltfError> {
    let p = prim.index();
    let usage = |what: &str| format!("mesh {m} primitive {p} {what}");
    let perr = |reason: String| GltfError::Primitive {
        mesh: m,
        primitive: p,
        reason,
    };
    let Some(pos_acc) = prim.get(&Semantic::Positions) else {
        return Err(perr("has no POSITION attribute".into()));
    };
    let positions = read_vec3(&pos_acc, buffers, &usage("POSITION"))?;
    let n = positions.len();
    let normals = match prim.get(&Semantic::Normals) {
        Some(a) => {
            let v = read_vec3(&a, buffers, &usage("NORMAL"))?;
            if v.len() != n {
                return Err(perr(format!("{} normals for {n} positions", v.len())));
            }
            Some(v)
        }
        None => None,
    };
    let indices = match prim.indices() {
        Some(a) => read_indices(&a, buffers, &usage("indices"))?,
        None => (0..n as u32).collect(),
    };
    if let Some((i, &bad)) = indices.iter().enumerate().find(|(_, x)| **x as usize >= n) {
        return Err(perr(format!(
            "index {i} is {bad} but there are {n} vertices"
        )));
    }
    let triangles = triangles_of(prim.mode(), &indices);

    let mut joints = Vec::new();
    let mut weights = Vec::new();
    let mut sets = 0;
    while let (Some(ja), Some(wa)) = (
        prim.get(&Semantic::Joints(sets)),
        prim.get(&Semantic::Weights(sets)),
    ) {
        let (_, j) = read(
            &ja,
            buffers,
            &[Dimensions::Vec4],
            &usage(&format!("JOINTS_{sets}")),
        )?;
        let (_, w) = read(
            &wa,
            buffers,
            &[Dimensions::Vec4],
            &usage(&format!("WEIGHTS_{sets}")),
        )?;
        if j.len() != 4 * n || w.len() != 4 * n {
            return Err(perr(format!(
                "JOINTS_{sets}/WEIGHTS_{sets} have {}/{} entries for {n} vertices",
                j.len() / 4,
                w.len() / 4
            )));
        }
        joints.push(j);
        weights.push(w);
        sets += 1;
    }
    let influences = if sets == 0 {
        None
    } else {
        let k = 4 * sets as usize;
        let mut jv = Vec::with_capacity(n * k);
        let mut wv = Vec::with_capacity(n * k);
        for v in 0..n {
            for s in 0..sets as usize {
                jv.extend(joints[s][4 * v..4 * v + 4].iter().map(|&x| x as u32));
                wv.extend(weights[s][4 * v..4 * v + 4].iter().map(|&x| x as f32));
            }
        }
        Some(Influences::new(k, jv, wv).map_err(|e| perr(e.to_string()))?)
    };

    let mut targets = Vec::new();
    for (t, target) in prim.morph_targets().enumerate() {
        let positions = match target.positions() {
            Some(a) => read_vec3(&a, buffers, &usage(&format!("target {t} POSITION")))?,
            None => vec![Vec3::ZERO; n],
        };
        let normals = match target.normals() {
            Some(a) => Some(read_vec3(
                &a,
                buffers,
                &usage(&format!("target {t} NORMAL")),
            )?),
            None => None,
        };
        if positions.len() != n || normals.as_ref().is_some_and(|v| v.len() != n) {
            return Err(perr(format!("morph target {t} does not have {n} entries")));
        }
        targets.push(MorphTarget { positions, normals });
    }
    Ok(Primitive {
        positions,
        normals,
        triangles,
        influences,
        targets,
    })
}

fn local_of(node: &::gltf::Node) -> LocalTransform {
    match node.transform() {
        Transform::Matrix { matrix } => LocalTransform::Matrix(Mat4::from_cols_array_2d(&matrix)),
        Transform::Decomposed {
            translation,
            rotation,
            scale,
        } => LocalTransform::from_trs(
            Vec3::from(translation),
            Quat::from_array(rotation),
            Vec3::from(scale),
        ),
    }
}

pub(crate) fn load_slice(
    bytes: &[u8],
    base: Option<&Path>,
    options: &LoadOptions,
) -> Result<Scene, GltfError> {
    let (json_bytes, blob) = split_container(bytes)?;
    let (doc, mut warnings) = parse_document(&json_bytes)?;
    let buffers = load_buffers(&doc, base, blob)?;

    // Nodes and hierarchy.
    let node_count = doc.nodes().len();
    let mut parents: Vec<Option<u32>> = vec![None; node_count];
    for node in doc.nodes() {
        for child in node.children() {
            let c = child.index();
            if parents[c].is_none() && c != node.index() {
                parents[c] = Some(node.index() as u32);
            } else {
                warnings.push(format!(
                    "node {c} has more than one parent; extra links ignored"
                ));
            }
        }
    }
    let nodes: Vec<Node> = doc
        .nodes()
        .map(|n| Node {
            name: n
                .name()
                .map_or_else(|| format!("node{}", n.index()), str::to_string),
            parent: parents[n.index()],
            mesh: n.mesh().map(|m| m.index() as u32),
            skin: n.skin().map(|s| s.index() as u32),
            weights: n.weights().map(<[f32]>::to_vec),
        })
        .collect();
    let rest: Vec<LocalTransform> = doc.nodes().map(|n| local_of(&n)).collect();
    let hierarchy = Hierarchy::new(parents, rest).map_err(GltfError::Hierarchy)?;

    // Meshes.
    let mut meshes = Vec::new();
    for mesh in doc.meshes() {
        let m = mesh.index();
        let mut primitives = Vec::new();
        for prim in mesh.primitives() {
            primitives.push(load_primitive(&prim, m, &buffers)?);
        }
        let target_count = primitives
            .iter()
            .map(|p| p.targets.len())
            .max()
            .unwrap_or(0);
        let weights = mesh
            .weights()
            .map_or_else(|| vec![0.0; target_count], <[f32]>::to_vec);
        meshes.push(Mesh {
            name: mesh
                .name()
                .map_or_else(|| format!("mesh{m}"), str::to_string),
            role: None,
            role_source: None,
            primitives,
            weights,
        });
    }

    // Skins.
    let mut skins = Vec::new();
    for skin in doc.skins() {
        let s = skin.index();
        let joints: Vec<u32> = skin.joints().map(|j| j.index() as u32).collect();
        let inverse_bind = match skin.inverse_bind_matrices() {
            Some(a) => {
                let (_, v) = read(
                    &a,
                    &buffers,
                    &[Dimensions::Mat4],
                    &format!("skin {s} inverseBindMatrices"),
                )?;
                v.chunks_exact(16)
                    .map(|c| {
                        let f: [f32; 16] = std::array::from_fn(|i| c[i] as f32);
                        Mat4::from_cols_array(&f)
                    })
                    .collect()
            }
            None => vec![Mat4::IDENTITY; joints.len()],
        };
        if inverse_bind.len() != joints.len() {
            return Err(GltfError::InverseBindCount {
                skin: s,
                joints: joints.len(),
                matrices: inverse_bind.len(),
            });
        }
        skins.push(Skin {
            joints,
            inverse_bind,
            skeleton: skin.skeleton().map(|n| n.index() as u32),
        });
    }

    // Skinned instances: weights must be usable and joints inside the skin.
    let mut skinned_mesh = vec![false; meshes.len()];
    for node in &nodes {
        if let (Some(mi), Some(si)) = (node.mesh, node.skin) {
            skinned_mesh[mi as usize] = true;
            let joint_count = skins[si as usize].joints.len();
            for (p, prim) in meshes[mi as usize].primitives.iter().enumerate() {
                if let Some(inf) = &prim.influences {
                    inf.check_joints(joint_count).map_err(|e| match e {
                        crate::animation::AnimationError::JointOutOfRange {
                            vertex, joint, ..
                        } => GltfError::JointOutOfRange {
                            mesh: mi as usize,
                            primitive: p,
                            vertex,
                            joint,
                            skin: si as usize,
                            joint_count,
                        },
                        other => GltfError::Primitive {
                            mesh: mi as usize,
                            primitive: p,
                            reason: other.to_string(),
                        },
                    })?;
                }
            }
        }
    }
    for (m, mesh) in meshes.iter_mut().enumerate() {
        for (p, prim) in mesh.primitives.iter_mut().enumerate() {
            let Some(inf) = prim.influences.as_mut() else {
                continue;
            };
            if let Err(crate::animation::AnimationError::ZeroWeights { vertex }) = inf.normalize() {
                if skinned_mesh[m] {
                    return Err(GltfError::ZeroWeights {
                        mesh: m,
                        primitive: p,
                        vertex,
                    });
                }
                warnings.push(format!(
                    "mesh {m} primitive {p}: vertex {vertex} has zero weights; unused skin data dropped"
                ));
                prim.influences = None;
            }
        }
    }

    // Animations.
    let mut clips = Vec::new();
    for anim in doc.animations() {
        let a = anim.index();
        let mut channels = Vec::new();
        for (c, channel) in anim.channels().enumerate() {
            let node = channel.target().node().index();
            let sampler = channel.sampler();
            let usage = |what: &str| format!("animation {a} channel {c} {what}");
            let times = read_scalar(&sampler.input(), &buffers, &usage("input"))?;
            let out = sampler.output();
            let interpolation = match sampler.interpolation() {
                GInterp::Step => Interpolation::Step,
                GInterp::Linear => Interpolation::Linear,
                GInterp::CubicSpline => Interpolation::CubicSpline,
            };
            let values = match channel.target().property() {
                Property::Translation => {
                    Keyframes::Translation(read_vec3(&out, &buffers, &usage("output"))?)
                }
                Property::Scale => Keyframes::Scale(read_vec3(&out, &buffers, &usage("output"))?),
                Property::Rotation => {
                    let (_, v) = read(&out, &buffers, &[Dimensions::Vec4], &usage("output"))?;
                    Keyframes::Rotation(
                        v.chunks_exact(4)
                            .map(|q| {
                                Quat::from_xyzw(q[0] as f32, q[1] as f32, q[2] as f32, q[3] as f32)
                            })
                            .collect(),
                    )
                }
                Property::MorphTargetWeights => {
                    let values = read_scalar(&out, &buffers, &usage("output"))?;
                    let from_mesh = nodes[node]
                        .mesh
                        .and_then(|m| meshes.get(m as usize))
                        .map(|m| m.weights.len())
                        .filter(|&k| k > 0);
                    let per_key = if interpolation == Interpolation::CubicSpline {
                        3
                    } else {
                        1
                    };
                    let targets =
                        from_mesh.unwrap_or_else(|| values.len() / (times.len() * per_key).max(1));
                    Keyframes::Weights { targets, values }
                }
            };
            let sampler = Sampler::new(interpolation, times, values).map_err(|source| {
                GltfError::Sampler {
                    animation: a,
                    channel: c,
                    source,
                }
            })?;
            channels.push(Channel {
                node: node as u32,
                sampler,
            });
        }
        clips.push(Clip {
            name: anim
                .name()
                .map_or_else(|| format!("animation{a}"), str::to_string),
            channels,
        });
    }

    // Roles: extras, then names, then overrides, then the single-skinned-mesh default.
    for (m, mesh) in meshes.iter_mut().enumerate() {
        let json_mesh = doc.meshes().nth(m);
        let users: Vec<::gltf::Node> = doc
            .nodes()
            .filter(|n| n.mesh().is_some_and(|x| x.index() == m))
            .collect();
        let from_extras = json_mesh
            .as_ref()
            .and_then(|jm| role_from_extras(jm.extras()))
            .or_else(|| users.iter().find_map(|n| role_from_extras(n.extras())));
        let from_name = role_from_name(&mesh.name)
            .or_else(|| users.iter().find_map(|n| n.name().and_then(role_from_name)));
        let from_override = options.role_overrides.iter().find_map(|(name, role)| {
            (name == &mesh.name || users.iter().any(|n| n.name() == Some(name.as_str())))
                .then_some(*role)
        });
        (mesh.role, mesh.role_source) = if let Some(r) = from_extras {
            (Some(r), Some(RoleSource::Extras))
        } else if let Some(r) = from_name {
            (Some(r), Some(RoleSource::Name))
        } else if let Some(r) = from_override {
            (Some(r), Some(RoleSource::Override))
        } else {
            (None, None)
        };
    }
    let has_skin_role = meshes.iter().any(|m| m.role == Some(Role::Skin));
    let skinned: Vec<usize> = (0..meshes.len()).filter(|&m| skinned_mesh[m]).collect();
    if !has_skin_role && skinned.len() == 1 && meshes[skinned[0]].role.is_none() {
        meshes[skinned[0]].role = Some(Role::Skin);
        meshes[skinned[0]].role_source = Some(RoleSource::SingleSkinnedMesh);
    }

    // Capsules along the bones when the skin has nothing else to slide over.
    let has_colliders = meshes
        .iter()
        .any(|m| matches!(m.role, Some(Role::Muscle | Role::Bone)));
    let mut capsules = Vec::new();
    if !has_colliders {
        let skin_instance = nodes.iter().find(|n| {
            n.skin.is_some()
                && n.mesh
                    .is_some_and(|m| meshes[m as usize].role == Some(Role::Skin))
        });
        if let Some(Node {
            mesh: Some(m),
            skin: Some(s),
            ..
        }) = skin_instance
        {
            capsules = fit_capsules(&hierarchy, &skins[*s as usize], &meshes[*m as usize]);
        }
    }

    Ok(Scene {
        nodes,
        hierarchy,
        meshes,
        skins,
        clips,
        capsules,
        warnings,
    })
}
