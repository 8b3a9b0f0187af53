//! The bundled arm model (`assets/arm.glb`), generated deterministically by [`build_arm_glb`].
//!
//! The arm lies along +x with y up: shoulder joint at the origin, elbow at
//! [`ELBOW_X_M`], wrist at [`WRIST_X_M`]. Elbow flexion rotates the forearm about +z towards
//! +y, the side the biceps lies on. Meshes (all closed, all bound to one three-joint skin,
//! roles in `extras.dermis.role`):
//!
//! | node | role | content |
//! |---|---|---|
//! | `humerus` | bone | upper-arm bone, bound to the shoulder |
//! | `forearm_bones` | bone | radius and ulna as one rod, bound to the elbow |
//! | `biceps` | muscle | over the humerus (+y), inserting past the elbow; morph target `flex` bulges it |
//! | `triceps` | muscle | under the humerus (-y); morph target `stretch` thins it |
//! | `arm_skin` | skin | tube around everything, blended across the elbow |
//!
//! The clip `elbow_flexion` (2 s, LINEAR) bends the elbow 0 -> 120 -> 0 degrees with keys
//! every 0.5 s and drives both morph weights with the bend. Only IEEE-exact arithmetic is used
//! (sines from a Taylor series, no platform `libm`), so the bytes are the same everywhere.

use serde_json::{Value, json};

/// Elbow joint position on the x axis, metres.
pub const ELBOW_X_M: f32 = 0.30;
/// Wrist joint position on the x axis, metres.
pub const WRIST_X_M: f32 = 0.55;
/// Duration of the flexion clip, seconds.
pub const FLEXION_DURATION_S: f32 = 2.0;
/// Largest elbow flexion in the clip, degrees (reached at 1 s).
pub const MAX_FLEXION_DEG: f64 = 120.0;

/// Sine and cosine by Taylor series (|x| <= 2 pi): only IEEE-exact operations, so results do
/// not depend on the platform's math library.
fn sin_cos(x: f64) -> (f64, f64) {
    let pi = std::f64::consts::PI;
    let x = if x > pi { x - 2.0 * pi } else { x };
    let (mut s, mut c) = (0.0f64, 0.0f64);
    let mut term = 1.0f64; // x^k / k!
    for k in 0..40 {
        match k % 4 {
            0 => c += term,
            1 => s += term,
            2 => c -= term,
            _ => s -= term,
        }
        term *= x / f64::from(k + 1);
    }
    (s, c)
}

fn smoothstep(a: f32, b: f32, x: f32) -> f32 {
    let t = ((x - a) / (b - a)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// A closed surface of revolution around a line parallel to x.
struct Lathe {
    positions: Vec<[f32; 3]>,
    triangles: Vec<[u16; 3]>,
    /// Axis point (y, z) and normalised length coordinate `s` per vertex.
    axis: [f32; 2],
    s: Vec<f32>,
}

/// `rings` rings of `segments` vertices between poles at `x0` and `x1`; `radius(s)` gives the
/// (y, z) semi-axes at `s` in (0, 1).
fn lathe(
    x0: f32,
    x1: f32,
    axis: [f32; 2],
    rings: usize,
    segments: usize,
    radius: impl Fn(f32) -> (f32, f32),
) -> Lathe {
    let mut positions = vec![[x0, axis[0], axis[1]]];
    let mut s_of = vec![0.0];
    let circle: Vec<(f32, f32)> = (0..segments)
        .map(|j| {
            let (s, c) = sin_cos(2.0 * std::f64::consts::PI * j as f64 / segments as f64);
            (c as f32, s as f32)
        })
        .collect();
    for i in 0..rings {
        let s = (i + 1) as f32 / (rings + 1) as f32;
        let x = x0 + s * (x1 - x0);
        let (ry, rz) = radius(s);
        for &(c, sn) in &circle {
            positions.push([x, axis[0] + ry * c, axis[1] + rz * sn]);
            s_of.push(s);
        }
    }
    positions.push([x1, axis[0], axis[1]]);
    s_of.push(1.0);
    let last = (positions.len() - 1) as u16;
    let v = |i: usize, j: usize| (1 + i * segments + j % segments) as u16;
    let mut triangles = Vec::new();
    for j in 0..segments {
        triangles.push([0, v(0, j + 1), v(0, j)]);
        for i in 0..rings - 1 {
            triangles.push([v(i, j), v(i, j + 1), v(i + 1, j)]);
            triangles.push([v(i, j + 1), v(i + 1, j + 1), v(i + 1, j)]);
        }
        triangles.push([last, v(rings - 1, j), v(rings - 1, j + 1)]);
    }
    Lathe {
        positions,
        triangles,
        axis,
        s: s_of,
    }
}

/// Area-weighted vertex normals.
fn normals(positions: &[[f32; 3]], triangles: &[[u16; 3]]) -> Vec<[f32; 3]> {
    let mut acc = vec![[0.0f32; 3]; positions.len()];
    for t in triangles {
        let [a, b, c] = t.map(|i| positions[i as usize]);
        let u = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
        let w = [c[0] - a[0], c[1] - a[1], c[2] - a[2]];
        let n = [
            u[1] * w[2] - u[2] * w[1],
            u[2] * w[0] - u[0] * w[2],
            u[0] * w[1] - u[1] * w[0],
        ];
        for &i in t {
            for k in 0..3 {
                acc[i as usize][k] += n[k];
            }
        }
    }
    acc.into_iter()
        .map(|n| {
            let l = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
            if l > 0.0 {
                n.map(|x| x / l)
            } else {
                [1.0, 0.0, 0.0]
            }
        })
        .collect()
}

/// Accumulates the binary chunk, buffer views and accessors.
#[derive(Default)]
struct Bin {
    bytes: Vec<u8>,
    views: Vec<Value>,
    accessors: Vec<Value>,
}

impl Bin {
    fn view(&mut self, data: &[u8], target: Option<u32>) -> usize {
        while !self.bytes.len().is_multiple_of(4) {
            self.bytes.push(0);
        }
        let mut v =
            json!({ "buffer": 0, "byteOffset": self.bytes.len(), "byteLength": data.len() });
        if let Some(t) = target {
            v["target"] = json!(t);
        }
        self.bytes.extend_from_slice(data);
        self.views.push(v);
        self.views.len() - 1
    }

    fn floats(
        &mut self,
        data: &[f32],
        ty: &str,
        width: usize,
        target: Option<u32>,
        bounds: bool,
    ) -> usize {
        let bytes: Vec<u8> = data.iter().flat_map(|x| x.to_le_bytes()).collect();
        let view = self.view(&bytes, target);
        let mut a = json!({
            "bufferView": view, "componentType": 5126, "count": data.len() / width, "type": ty,
        });
        if bounds {
            let min: Vec<f32> = (0..width)
                .map(|k| {
                    data.iter()
                        .skip(k)
                        .step_by(width)
                        .copied()
                        .fold(f32::INFINITY, f32::min)
                })
                .collect();
            let max: Vec<f32> = (0..width)
                .map(|k| {
                    data.iter()
                        .skip(k)
                        .step_by(width)
                        .copied()
                        .fold(f32::NEG_INFINITY, f32::max)
                })
                .collect();
            a["min"] = json!(min);
            a["max"] = json!(max);
        }
        self.accessors.push(a);
        self.accessors.len() - 1
    }

    fn u16s(&mut self, data: &[u16], target: u32) -> usize {
        let bytes: Vec<u8> = data.iter().flat_map(|x| x.to_le_bytes()).collect();
        let view = self.view(&bytes, Some(target));
        self.accessors.push(json!({
            "bufferView": view, "componentType": 5123, "count": data.len(), "type": "SCALAR",
        }));
        self.accessors.len() - 1
    }

    fn joints(&mut self, data: &[[u8; 4]]) -> usize {
        let bytes: Vec<u8> = data.iter().flatten().copied().collect();
        let view = self.view(&bytes, Some(34962));
        self.accessors.push(json!({
            "bufferView": view, "componentType": 5121, "count": data.len(), "type": "VEC4",
        }));
        self.accessors.len() - 1
    }
}

/// Rebuilds every JSON object with its keys in sorted order, so the text is the same whether
/// or not `serde_json` keeps insertion order.
fn canonical(v: Value) -> Value {
    match v {
        Value::Object(map) => {
            let mut entries: Vec<(String, Value)> = map.into_iter().collect();
            entries.sort_by(|a, b| a.0.cmp(&b.0));
            Value::Object(
                entries
                    .into_iter()
                    .map(|(k, v)| (k, canonical(v)))
                    .collect(),
            )
        }
        Value::Array(a) => Value::Array(a.into_iter().map(canonical).collect()),
        other => other,
    }
}

/// One mesh of the arm: geometry, per-vertex elbow weight, optional morph target.
struct Part {
    name: &'static str,
    role: &'static str,
    lathe: Lathe,
    elbow_weight: Vec<f32>,
    target: Option<(&'static str, Vec<[f32; 3]>)>,
}

fn parts() -> Vec<Part> {
    let ex = ELBOW_X_M;
    let wx = WRIST_X_M;
    let bulge = |s: f32| {
        let (sn, _) = sin_cos(std::f64::consts::PI * f64::from(s));
        sn as f32
    };
    let blend = |l: &Lathe, a: f32, b: f32| -> Vec<f32> {
        l.positions.iter().map(|p| smoothstep(a, b, p[0])).collect()
    };
    // Radial displacement of each vertex, scaled by `amount * sin(pi s)`.
    let radial = |l: &Lathe, amount: f32| -> Vec<[f32; 3]> {
        l.positions
            .iter()
            .zip(&l.s)
            .map(|(p, &s)| {
                let k = amount * bulge(s);
                [0.0, (p[1] - l.axis[0]) * k, (p[2] - l.axis[1]) * k]
            })
            .collect()
    };

    let humerus = lathe(0.01, ex - 0.012, [0.0, 0.0], 18, 12, |s| {
        let r = 0.011 + 0.006 * (1.0 - bulge(s));
        (r, r)
    });
    let forearm = lathe(ex + 0.012, wx - 0.01, [0.0, 0.0], 16, 12, |s| {
        let r = 0.010 + 0.004 * (1.0 - bulge(s));
        (r, r * 1.4)
    });
    let biceps = lathe(0.05, ex + 0.05, [0.036, 0.0], 24, 16, |s| {
        let k = 0.25 + 0.75 * bulge(s);
        (0.018 * k, 0.024 * k)
    });
    let triceps = lathe(0.02, ex + 0.01, [-0.036, 0.0], 24, 16, |s| {
        let k = 0.25 + 0.75 * bulge(s);
        (0.019 * k, 0.026 * k)
    });
    let skin = lathe(-0.04, wx + 0.04, [0.0, 0.0], 48, 32, |s| {
        let x = -0.04 + s * (wx + 0.08);
        let r = 0.066 - 0.02 * smoothstep(ex - 0.05, wx, x);
        // Round the ends over the first and last few rings.
        let end = (4.0 * bulge(s)).clamp(0.09, 1.0).sqrt();
        (r * end, r * 0.9 * end)
    });
    let humerus_w = vec![0.0; humerus.positions.len()];
    let forearm_w = vec![1.0; forearm.positions.len()];
    let biceps_w = blend(&biceps, ex - 0.03, ex + 0.02);
    let triceps_w = blend(&triceps, ex - 0.03, ex + 0.005);
    let skin_w = blend(&skin, ex - 0.06, ex + 0.06);
    let biceps_t = radial(&biceps, 0.45);
    let triceps_t = radial(&triceps, -0.25);
    vec![
        Part {
            name: "humerus",
            role: "bone",
            lathe: humerus,
            elbow_weight: humerus_w,
            target: None,
        },
        Part {
            name: "forearm_bones",
            role: "bone",
            lathe: forearm,
            elbow_weight: forearm_w,
            target: None,
        },
        Part {
            name: "biceps",
            role: "muscle",
            lathe: biceps,
            elbow_weight: biceps_w,
            target: Some(("flex", biceps_t)),
        },
        Part {
            name: "triceps",
            role: "muscle",
            lathe: triceps,
            elbow_weight: triceps_w,
            target: Some(("stretch", triceps_t)),
        },
        Part {
            name: "arm_skin",
            role: "skin",
            lathe: skin,
            elbow_weight: skin_w,
            target: None,
        },
    ]
}

/// Builds the arm `.glb` (deterministic: the same bytes on every run and platform).
pub fn build_arm_glb() -> Vec<u8> {
    let mut bin = Bin::default();
    let mut meshes = Vec::new();
    let mut nodes = vec![
        json!({ "name": "shoulder", "children": [1] }),
        json!({ "name": "elbow", "translation": [ELBOW_X_M, 0.0, 0.0], "children": [2] }),
        json!({ "name": "wrist", "translation": [WRIST_X_M - ELBOW_X_M, 0.0, 0.0] }),
    ];
    let mut morph_nodes = Vec::new();
    for part in parts() {
        let l = &part.lathe;
        let flat: Vec<f32> = l.positions.iter().flatten().copied().collect();
        let pos = bin.floats(&flat, "VEC3", 3, Some(34962), true);
        let nrm: Vec<f32> = normals(&l.positions, &l.triangles)
            .into_iter()
            .flatten()
            .collect();
        let nrm = bin.floats(&nrm, "VEC3", 3, Some(34962), false);
        let joints = bin.joints(&vec![[0, 1, 0, 0]; l.positions.len()]);
        let w: Vec<f32> = part
            .elbow_weight
            .iter()
            .flat_map(|&w| [1.0 - w, w, 0.0, 0.0])
            .collect();
        let weights = bin.floats(&w, "VEC4", 4, Some(34962), false);
        let idx: Vec<u16> = l.triangles.iter().flatten().copied().collect();
        let indices = bin.u16s(&idx, 34963);
        let mut primitive = json!({
            "attributes": { "POSITION": pos, "NORMAL": nrm, "JOINTS_0": joints, "WEIGHTS_0": weights },
            "indices": indices,
            "mode": 4,
        });
        let mut mesh = json!({
            "name": part.name,
            "primitives": [],
            "extras": { "dermis": { "role": part.role } },
        });
        if let Some((target_name, d)) = &part.target {
            let flat: Vec<f32> = d.iter().flatten().copied().collect();
            let t = bin.floats(&flat, "VEC3", 3, Some(34962), true);
            primitive["targets"] = json!([{ "POSITION": t }]);
            mesh["weights"] = json!([0.0]);
            mesh["extras"]["targetNames"] = json!([target_name]);
            morph_nodes.push(nodes.len());
        }
        mesh["primitives"] = json!([primitive]);
        nodes.push(json!({
            "name": part.name,
            "mesh": meshes.len(),
            "skin": 0,
            "extras": { "dermis": { "role": part.role } },
        }));
        meshes.push(mesh);
    }
    let ibm: Vec<f32> = [0.0, ELBOW_X_M, WRIST_X_M]
        .iter()
        .flat_map(|&x| {
            let mut m = [0.0f32; 16];
            m[0] = 1.0;
            m[5] = 1.0;
            m[10] = 1.0;
            m[15] = 1.0;
            m[12] = -x;
            m
        })
        .collect();
    let ibm = bin.floats(&ibm, "MAT4", 16, None, false);

    // Elbow flexion: keys every 0.5 s, angle 0 -> 60 -> 120 -> 60 -> 0 degrees about +z.
    let times = [0.0f32, 0.5, 1.0, 1.5, 2.0];
    let fraction = [0.0f64, 0.5, 1.0, 0.5, 0.0];
    let rotations: Vec<f32> = fraction
        .iter()
        .flat_map(|&f| {
            let half = (f * MAX_FLEXION_DEG).to_radians() / 2.0;
            let (s, c) = sin_cos(half);
            [0.0, 0.0, s as f32, c as f32]
        })
        .collect();
    let weights: Vec<f32> = fraction.iter().map(|&f| f as f32).collect();
    let input = bin.floats(&times, "SCALAR", 1, None, true);
    let rot = bin.floats(&rotations, "VEC4", 4, None, false);
    let wts = bin.floats(&weights, "SCALAR", 1, None, false);
    let mut samplers = vec![json!({ "input": input, "output": rot, "interpolation": "LINEAR" })];
    let mut channels = vec![json!({ "sampler": 0, "target": { "node": 1, "path": "rotation" } })];
    for &n in &morph_nodes {
        channels
            .push(json!({ "sampler": samplers.len(), "target": { "node": n, "path": "weights" } }));
        samplers.push(json!({ "input": input, "output": wts, "interpolation": "LINEAR" }));
    }
    while !bin.bytes.len().is_multiple_of(4) {
        bin.bytes.push(0);
    }
    let node_count = nodes.len();
    let doc = json!({
        "asset": { "version": "2.0", "generator": "dermis make-arm" },
        "scene": 0,
        "scenes": [{ "name": "arm", "nodes": (0..node_count).filter(|&n| n == 0 || n > 2).collect::<Vec<_>>() }],
        "nodes": nodes,
        "meshes": meshes,
        "skins": [{ "name": "arm", "joints": [0, 1, 2], "skeleton": 0, "inverseBindMatrices": ibm }],
        "animations": [{ "name": "elbow_flexion", "samplers": samplers, "channels": channels }],
        "accessors": bin.accessors,
        "bufferViews": bin.views,
        "buffers": [{ "byteLength": bin.bytes.len() }],
    });
    let mut text = serde_json::to_vec(&canonical(doc)).unwrap_or_default();
    while !text.len().is_multiple_of(4) {
        text.push(b' ');
    }
    let length = 12 + 8 + text.len() + 8 + bin.bytes.len();
    let mut out = Vec::with_capacity(length);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(length as u32).to_le_bytes());
    out.extend_from_slice(&(text.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&text);
    out.extend_from_slice(&(bin.bytes.len() as u32).to_le_bytes());
    out.extend_from_slice(b"BIN\0");
    out.extend_from_slice(&bin.bytes);
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn taylor_sine_matches_std() {
        for k in 0..=64 {
            let x = k as f64 * std::f64::consts::TAU / 64.0;
            let (s, c) = sin_cos(x);
            assert!(
                (s - x.sin()).abs() < 1e-13 && (c - x.cos()).abs() < 1e-13,
                "x = {x}"
            );
        }
    }

    #[test]
    fn every_part_is_a_closed_outward_surface() {
        for part in parts() {
            let pos: Vec<glam::Vec3> = part.lathe.positions.iter().map(|&p| p.into()).collect();
            let tris: Vec<[u32; 3]> = part
                .lathe
                .triangles
                .iter()
                .map(|t| t.map(u32::from))
                .collect();
            let mesh = crate::mesh::TriMesh::new(pos.clone(), tris.clone()).unwrap();
            assert!(mesh.topology().is_closed(), "{} is open", part.name);
            // Divergence theorem: signed volume is positive for outward triangles.
            let vol: f32 = tris
                .iter()
                .map(|t| pos[t[0] as usize].dot(pos[t[1] as usize].cross(pos[t[2] as usize])) / 6.0)
                .sum();
            assert!(vol > 0.0, "{} is inside out", part.name);
        }
    }
}
