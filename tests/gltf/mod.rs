//! glTF loading and skeletal playback against closed-form answers, malformed input, the arm asset.

mod arm;
mod builder;
mod malformed;
mod playback;

use builder::TestGltf;
use dermis::gltf::{LoadOptions, Scene};
use glam::Vec3;
use serde_json::{Value, json};

/// Two joints on the x axis (joint 1 at x = 1, child of joint 0) and a skinned triangle:
/// v0 = (2, 0, 0) on joint 1, v1 = (0.5, 0, 0) on joint 0, v2 = (1, 1, 0) half on each. The
/// skinned mesh's node is translated by (5, 5, 5), which glTF says to ignore.
/// `animate` adds accessors and returns the `animations` array.
pub fn two_joint(animate: impl FnOnce(&mut TestGltf) -> Value) -> TestGltf {
    let mut g = TestGltf::new();
    let pos = g.floats(&[2.0, 0.0, 0.0, 0.5, 0.0, 0.0, 1.0, 1.0, 0.0], "VEC3");
    let joints = g.joints(&[[1, 0, 0, 0], [0, 0, 0, 0], [0, 1, 0, 0]]);
    let weights = g.floats(
        &[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.5, 0.5, 0.0, 0.0],
        "VEC4",
    );
    let idx = g.indices(&[0, 1, 2]);
    let mut ibm = glam::Mat4::IDENTITY.to_cols_array().to_vec();
    ibm.extend(glam::Mat4::from_translation(-Vec3::X).to_cols_array());
    let ibm = g.floats(&ibm, "MAT4");
    g.node(json!({ "name": "joint0", "children": [1] }));
    g.node(json!({ "name": "joint1", "translation": [1.0, 0.0, 0.0] }));
    g.node(json!({ "name": "tri", "mesh": 0, "skin": 0, "translation": [5.0, 5.0, 5.0] }));
    g.mesh(json!({ "name": "tri", "primitives": [{
        "attributes": { "POSITION": pos, "JOINTS_0": joints, "WEIGHTS_0": weights },
        "indices": idx,
    }]}));
    g.json["skins"] = json!([{ "joints": [0, 1], "inverseBindMatrices": ibm }]);
    g.json["scenes"] = json!([{ "nodes": [0, 2] }]);
    let animations = animate(&mut g);
    g.json["animations"] = animations;
    g
}

/// Loads `bytes` (no base directory) and poses the first clip at `t`; positions of the first
/// primitive.
pub fn posed(bytes: &[u8], t: f32) -> Vec<Vec3> {
    let scene = Scene::from_slice(bytes, None, &LoadOptions::default()).unwrap();
    let clip = (!scene.clips.is_empty()).then_some(0);
    scene.pose(clip, t).primitives[0].positions.clone()
}

/// Asserts two points agree to `1e-5`.
pub fn assert_near(a: Vec3, b: Vec3, what: &str) {
    assert!((a - b).length() < 1e-5, "{what}: got {a}, expected {b}");
}
