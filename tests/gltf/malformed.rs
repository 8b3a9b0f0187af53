//! Malformed input gives a typed error naming the offending item, never a panic.

use dermis::animation::AnimationError;
use dermis::gltf::{GltfError, LoadOptions, Scene, load};
use glam::Quat;
use serde_json::json;

use super::builder::TestGltf;
use super::two_joint;

fn rotation_clip(g: &mut TestGltf) -> serde_json::Value {
    let input = g.floats(&[0.0, 1.0], "SCALAR");
    let q: Vec<f32> = [Quat::IDENTITY; 2]
        .iter()
        .flat_map(|q| q.to_array())
        .collect();
    let output = g.floats(&q, "VEC4");
    json!([{ "name": "bend", "samplers": [{ "input": input, "output": output }],
             "channels": [{ "sampler": 0, "target": { "node": 1, "path": "rotation" } }] }])
}

fn load_err(bytes: &[u8]) -> GltfError {
    match Scene::from_slice(bytes, None, &LoadOptions::default()) {
        Ok(_) => panic!("malformed input was accepted"),
        Err(e) => e,
    }
}

#[test]
fn truncated_glb_is_a_container_error() {
    let glb = two_joint(rotation_clip).to_glb();
    for cut in [0usize, 5, 11, 12, 19, 40, glb.len() / 2, glb.len() - 1] {
        let e = Scene::from_slice(&glb[..cut], None, &LoadOptions::default());
        match e {
            Err(GltfError::Glb { reason }) => assert!(!reason.is_empty()),
            // Under 4 bytes there is no magic: it is read as (invalid) JSON.
            Err(GltfError::Json { .. }) if cut < 4 => {}
            other => panic!("cut at {cut}: {other:?}"),
        }
    }
}

#[test]
fn accessor_past_its_buffer_names_the_accessor() {
    let mut g = two_joint(rotation_clip);
    g.json["accessors"][0]["count"] = json!(1000); // POSITION
    match load_err(&g.to_glb()) {
        GltfError::AccessorOutOfRange {
            accessor, usage, ..
        } => {
            assert_eq!(accessor, 0);
            assert!(usage.contains("POSITION"), "{usage}");
        }
        other => panic!("{other:?}"),
    }
    let mut g = two_joint(rotation_clip);
    g.json["accessors"][0]["byteOffset"] = json!(4); // reads 4 bytes past its 36-byte view
    assert!(matches!(
        load_err(&g.to_glb()),
        GltfError::AccessorOutOfRange { accessor: 0, .. }
    ));
}

#[test]
fn joint_index_beyond_the_skin_names_vertex_and_joint() {
    let mut g = two_joint(rotation_clip);
    let joints = g.joints(&[[1, 0, 0, 0], [5, 0, 0, 0], [0, 1, 0, 0]]);
    g.json["meshes"][0]["primitives"][0]["attributes"]["JOINTS_0"] = json!(joints);
    let e = load_err(&g.to_glb());
    assert!(
        matches!(
            e,
            GltfError::JointOutOfRange {
                mesh: 0,
                primitive: 0,
                vertex: 1,
                joint: 5,
                skin: 0,
                joint_count: 2
            }
        ),
        "{e:?}"
    );
    assert!(e.to_string().contains("vertex 1"));
}

#[test]
fn all_zero_weights_name_the_vertex() {
    let mut g = two_joint(rotation_clip);
    let w = g.floats(
        &[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        "VEC4",
    );
    g.json["meshes"][0]["primitives"][0]["attributes"]["WEIGHTS_0"] = json!(w);
    let e = load_err(&g.to_glb());
    assert!(
        matches!(
            e,
            GltfError::ZeroWeights {
                mesh: 0,
                primitive: 0,
                vertex: 2
            }
        ),
        "{e:?}"
    );
}

#[test]
fn missing_external_buffer_names_buffer_and_file() {
    let dir = tempfile::tempdir().unwrap();
    let g = two_joint(rotation_clip);
    let path = dir.path().join("model.gltf");
    std::fs::write(&path, g.to_external_gltf("model.bin")).unwrap();
    match load(&path, &LoadOptions::default()) {
        Err(GltfError::MissingBuffer { buffer: 0, uri, .. }) => assert_eq!(uri, "model.bin"),
        other => panic!("{other:?}"),
    }
    // With the file present it loads, and a short file is reported with both lengths.
    std::fs::write(dir.path().join("model.bin"), &g.bin).unwrap();
    load(&path, &LoadOptions::default()).unwrap();
    std::fs::write(dir.path().join("model.bin"), &g.bin[..g.bin.len() - 8]).unwrap();
    assert!(matches!(
        load(&path, &LoadOptions::default()),
        Err(GltfError::BufferTooShort { buffer: 0, .. })
    ));
}

#[test]
fn sampler_with_mismatched_counts_names_animation_and_channel() {
    let g = two_joint(|g| {
        let input = g.floats(&[0.0, 1.0, 2.0], "SCALAR");
        let q: Vec<f32> = [Quat::IDENTITY; 2]
            .iter()
            .flat_map(|q| q.to_array())
            .collect();
        let output = g.floats(&q, "VEC4");
        json!([{ "samplers": [{ "input": input, "output": output }],
                 "channels": [{ "sampler": 0, "target": { "node": 1, "path": "rotation" } }] }])
    });
    let e = load_err(&g.to_glb());
    assert!(
        matches!(
            e,
            GltfError::Sampler {
                animation: 0,
                channel: 0,
                source: AnimationError::SamplerCountMismatch {
                    inputs: 3,
                    expected: 3,
                    outputs: 2
                }
            }
        ),
        "{e:?}"
    );
}

#[test]
fn missing_clip_by_name_or_index_lists_what_exists() {
    let scene = Scene::from_slice(
        &two_joint(rotation_clip).to_glb(),
        None,
        &LoadOptions::default(),
    )
    .unwrap();
    assert_eq!(scene.find_clip("bend").unwrap(), 0);
    assert_eq!(scene.find_clip("0").unwrap(), 0);
    for bad in ["walk", "1"] {
        match scene.find_clip(bad) {
            Err(e @ GltfError::ClipNotFound { .. }) => {
                assert!(e.to_string().contains("bend"), "{e}")
            }
            other => panic!("{other:?}"),
        }
    }
}

#[test]
fn wrong_accessor_type_and_bad_index_are_reported() {
    let mut g = two_joint(rotation_clip);
    g.json["accessors"][0]["type"] = json!("VEC2");
    assert!(matches!(
        load_err(&g.to_glb()),
        GltfError::AccessorType { accessor: 0, .. }
    ));
    let mut g = two_joint(rotation_clip);
    let idx = g.indices(&[0, 1, 7]);
    g.json["meshes"][0]["primitives"][0]["indices"] = json!(idx);
    let e = load_err(&g.to_glb());
    assert!(
        matches!(
            e,
            GltfError::Primitive {
                mesh: 0,
                primitive: 0,
                ..
            }
        ),
        "{e:?}"
    );
    assert!(e.to_string().contains("index 2 is 7"), "{e}");
}

#[test]
fn corrupted_variants_of_the_arm_never_panic() {
    let arm = dermis::gltf::arm::build_arm_glb();
    let json_len = u32::from_le_bytes([arm[12], arm[13], arm[14], arm[15]]) as usize;
    let mut variants: Vec<Vec<u8>> = Vec::new();
    // Truncations, dense in the header and JSON, sparse in the binary chunk.
    let mut cut = 0;
    while cut < arm.len() {
        variants.push(arm[..cut].to_vec());
        cut += if cut < 20 + json_len { 97 } else { 4099 };
    }
    // Byte flips from a fixed linear congruential sequence: single bytes anywhere, digits in
    // the JSON (counts, offsets, indices), and whole header words.
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let mut next = move || {
        state = state
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        (state >> 33) as usize
    };
    // DERMIS_FUZZ_VARIANTS raises the count for a longer local run.
    let n: usize = std::env::var("DERMIS_FUZZ_VARIANTS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(400);
    for k in 0..n {
        let mut v = arm.clone();
        match k % 4 {
            0 => {
                let at = next() % v.len();
                v[at] ^= 1 << (next() % 8);
            }
            1 | 2 => {
                let at = 20 + next() % json_len;
                v[at] = b"0123456789-[]{}\"9e"[next() % 18];
            }
            _ => {
                let at = 4 * (next() % 8);
                v[at..at + 4].copy_from_slice(&(next() as u32).to_le_bytes());
            }
        }
        variants.push(v);
    }
    let mut accepted = 0;
    for v in &variants {
        if let Ok(scene) = Scene::from_slice(v, None, &LoadOptions::default()) {
            accepted += 1;
            let clip = (!scene.clips.is_empty()).then_some(0);
            for t in [0.0, 0.7, 3.0] {
                let _ = scene.pose(clip, t);
            }
        }
    }
    // Some flips hit vertex data and still load: the sweep exercised posing too.
    assert!(accepted > 0 && accepted < variants.len());
}
