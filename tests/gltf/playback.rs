//! Skinned positions at several times against closed forms, per interpolation mode.

use std::f32::consts::PI;

use dermis::gltf::{LoadOptions, Role, RoleSource, Scene};
use glam::{Quat, Vec3};
use serde_json::{Value, json};

use super::builder::TestGltf;
use super::{assert_near, posed, two_joint};

/// Joint 1 rotated by `theta` about z at (1, 0, 0): the three vertices in closed form.
fn expected(theta: f32) -> [Vec3; 3] {
    let (s, c) = theta.sin_cos();
    [
        Vec3::new(1.0 + c, s, 0.0),
        Vec3::new(0.5, 0.0, 0.0),
        Vec3::new(1.0 - 0.5 * s, 0.5 + 0.5 * c, 0.0),
    ]
}

fn rotation_clip(g: &mut TestGltf, interp: &str, times: &[f32], quats: &[Quat]) -> Value {
    let input = g.floats(times, "SCALAR");
    let q: Vec<f32> = quats.iter().flat_map(|q| q.to_array()).collect();
    let output = g.floats(&q, "VEC4");
    json!([{ "name": "bend", "samplers": [{ "input": input, "output": output, "interpolation": interp }],
             "channels": [{ "sampler": 0, "target": { "node": 1, "path": "rotation" } }] }])
}

#[test]
fn linear_rotation_matches_closed_form_and_ignores_the_skinned_node_transform() {
    let g = two_joint(|g| {
        rotation_clip(
            g,
            "LINEAR",
            &[0.0, 1.0, 2.0],
            &[
                Quat::IDENTITY,
                Quat::from_rotation_z(PI / 2.0),
                Quat::from_rotation_z(PI),
            ],
        )
    });
    for bytes in [g.to_glb(), g.to_embedded_gltf()] {
        for (t, theta) in [
            (0.0, 0.0),
            (0.25, PI / 8.0),
            (0.5, PI / 4.0),
            (1.5, 0.75 * PI),
            (2.0, PI),
            (9.0, PI),
        ] {
            let p = posed(&bytes, t);
            for (v, e) in p.iter().zip(expected(theta)) {
                assert_near(*v, e, &format!("t = {t}"));
            }
        }
    }
}

#[test]
fn linear_rotation_takes_the_short_path_when_keys_have_opposite_signs() {
    // The second key is -q(90 deg): the same rotation, but a naive lerp/slerp would swing
    // through the long way. Halfway must be 45 degrees.
    let g = two_joint(|g| {
        rotation_clip(
            g,
            "LINEAR",
            &[0.0, 1.0],
            &[Quat::IDENTITY, -Quat::from_rotation_z(PI / 2.0)],
        )
    });
    let p = posed(&g.to_glb(), 0.5);
    assert_near(p[0], expected(PI / 4.0)[0], "short path");
}

#[test]
fn step_translation_holds_each_key_until_the_next() {
    let g = two_joint(|g| {
        let input = g.floats(&[0.0, 1.0, 2.0], "SCALAR");
        let output = g.floats(&[1.0, 0.0, 0.0, 1.0, 2.0, 0.0, 1.0, 4.0, 0.0], "VEC3");
        json!([{ "samplers": [{ "input": input, "output": output, "interpolation": "STEP" }],
                 "channels": [{ "sampler": 0, "target": { "node": 1, "path": "translation" } }] }])
    });
    let bytes = g.to_glb();
    for (t, y) in [(0.0, 0.0), (0.99, 0.0), (1.0, 2.0), (1.5, 2.0), (2.5, 4.0)] {
        // Joint 1 moved to (1, y, 0): vertex 0 follows rigidly, vertex 2 half-way.
        let p = posed(&bytes, t);
        assert_near(p[0], Vec3::new(2.0, y, 0.0), &format!("v0 t = {t}"));
        assert_near(
            p[2],
            Vec3::new(1.0, 1.0 + 0.5 * y, 0.0),
            &format!("v2 t = {t}"),
        );
    }
}

#[test]
fn cubic_spline_translation_reproduces_a_cubic_with_matching_tangents() {
    // y(t) = t^3 - t: keys at 0, 1, 2 with in/out tangents y'(t) = 3 t^2 - 1. Hermite
    // interpolation of a cubic with exact tangents is exact.
    let y = |t: f32| t * t * t - t;
    let dy = |t: f32| 3.0 * t * t - 1.0;
    let g = two_joint(|g| {
        let times = [0.0f32, 1.0, 2.0];
        let input = g.floats(&times, "SCALAR");
        let out: Vec<f32> = times
            .iter()
            .flat_map(|&t| [0.0, dy(t), 0.0, 1.0, y(t), 0.0, 0.0, dy(t), 0.0])
            .collect();
        let output = g.floats(&out, "VEC3");
        json!([{ "samplers": [{ "input": input, "output": output, "interpolation": "CUBICSPLINE" }],
                 "channels": [{ "sampler": 0, "target": { "node": 1, "path": "translation" } }] }])
    });
    let bytes = g.to_glb();
    for t in [0.0f32, 0.3, 0.5, 1.0, 1.25, 1.8, 2.0] {
        let p = posed(&bytes, t);
        assert_near(p[0], Vec3::new(2.0, y(t), 0.0), &format!("t = {t}"));
    }
}

#[test]
fn cubic_spline_rotation_with_zero_tangents_is_smoothstep_between_keys() {
    // Zero tangents: q(s) = normalize(q0 (1 - h) + q1 h) with h = 3 s^2 - 2 s^3, which for two
    // rotations about z is the rotation by 2 atan2(h sin(a/2), (1 - h) + h cos(a/2)).
    let a = PI / 2.0;
    let g = two_joint(|g| {
        let input = g.floats(&[0.0, 1.0], "SCALAR");
        let q1 = Quat::from_rotation_z(a).to_array();
        let mut out = vec![0.0; 4];
        out.extend([0.0, 0.0, 0.0, 1.0]);
        out.extend([0.0; 8]);
        out.extend(q1);
        out.extend([0.0; 4]);
        let output = g.floats(&out, "VEC4");
        json!([{ "samplers": [{ "input": input, "output": output, "interpolation": "CUBICSPLINE" }],
                 "channels": [{ "sampler": 0, "target": { "node": 1, "path": "rotation" } }] }])
    });
    let bytes = g.to_glb();
    for s in [0.2f32, 0.5, 0.7] {
        let h = 3.0 * s * s - 2.0 * s * s * s;
        let theta = 2.0 * (h * (a / 2.0).sin()).atan2((1.0 - h) + h * (a / 2.0).cos());
        let p = posed(&bytes, s);
        assert_near(p[0], expected(theta)[0], &format!("s = {s}"));
    }
}

#[test]
fn morph_targets_are_applied_before_skinning() {
    // Target 0 moves v0 by (1, 0, 0) in bind space; with weight w and joint 1 at theta = 90
    // degrees the displaced vertex (offset 1 + w from the joint) swings to (1, 1 + w, 0).
    let mut g = two_joint(|g| {
        let input = g.floats(&[0.0, 1.0], "SCALAR");
        let q: Vec<f32> = [Quat::from_rotation_z(PI / 2.0); 2]
            .iter()
            .flat_map(|q| q.to_array())
            .collect();
        let rot = g.floats(&q, "VEC4");
        let w = g.floats(&[0.0, 1.0], "SCALAR");
        json!([{ "samplers": [
                    { "input": input, "output": rot },
                    { "input": input, "output": w }],
                 "channels": [
                    { "sampler": 0, "target": { "node": 1, "path": "rotation" } },
                    { "sampler": 1, "target": { "node": 2, "path": "weights" } }] }])
    });
    let dense = g.floats(&[1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0], "VEC3");
    // The same displacement as a sparse accessor without a buffer view.
    let sparse = g.sparse_vec3(3, &[0], &[1.0, 0.0, 0.0]);
    g.json["meshes"][0]["weights"] = json!([0.0]);
    for target in [dense, sparse] {
        g.json["meshes"][0]["primitives"][0]["targets"] = json!([{ "POSITION": target }]);
        let bytes = g.to_glb();
        for w in [0.0f32, 0.25, 1.0] {
            let p = posed(&bytes, w);
            assert_near(p[0], Vec3::new(1.0, 1.0 + w, 0.0), &format!("w = {w}"));
            assert_near(p[1], Vec3::new(0.5, 0.0, 0.0), "v1 has no displacement");
        }
    }
}

#[test]
fn normalised_integer_weights_and_rotation_keys_are_decoded() {
    // WEIGHTS_0 as normalised u8 (v2: 128/255 each, renormalised to 1/2) and rotation keys as
    // normalised i16 (0, 0, 23170, 23170) / 32767: 90 degrees about z after normalisation.
    let mut g = two_joint(|g| {
        let input = g.floats(&[0.0, 1.0], "SCALAR");
        let keys: [i16; 8] = [0, 0, 0, 32767, 0, 0, 23170, 23170];
        let bytes: Vec<u8> = keys.iter().flat_map(|x| x.to_le_bytes()).collect();
        let output = g.raw(&bytes, 5122, 2, "VEC4", true);
        json!([{ "samplers": [{ "input": input, "output": output }],
                 "channels": [{ "sampler": 0, "target": { "node": 1, "path": "rotation" } }] }])
    });
    let w = g.raw(
        &[255, 0, 0, 0, 255, 0, 0, 0, 128, 128, 0, 0],
        5121,
        3,
        "VEC4",
        true,
    );
    g.json["meshes"][0]["primitives"][0]["attributes"]["WEIGHTS_0"] = json!(w);
    let bytes = g.to_glb();
    for (t, theta) in [(0.5, PI / 4.0), (1.0, PI / 2.0)] {
        let p = posed(&bytes, t);
        for (v, e) in p.iter().zip(expected(theta)) {
            assert_near(*v, e, &format!("t = {t}"));
        }
    }
}

#[test]
fn non_joint_parents_and_non_uniform_scale_compose_parents_first() {
    // A (not a joint): translation (0, 0, 1), scale (2, 1, 1). J0 child of A: 90 deg about z.
    // J1 child of J0: translation (1, 0, 0). Identity inverse binds. B child of A: translation
    // (0, 1, 0), an unskinned mesh. Nodes are listed children first to test the ordering.
    let mut g = TestGltf::new();
    let pos = g.floats(&[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0], "VEC3");
    let joints = g.joints(&[[1, 0, 0, 0], [1, 0, 0, 0], [0, 0, 0, 0]]);
    let weights = g.floats(
        &[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0],
        "VEC4",
    );
    g.mesh(json!({ "name": "skinned", "primitives": [{ "attributes": { "POSITION": pos, "JOINTS_0": joints, "WEIGHTS_0": weights } }] }));
    g.mesh(json!({ "name": "rigid", "primitives": [{ "attributes": { "POSITION": pos } }] }));
    g.node(json!({ "name": "J1", "translation": [1.0, 0.0, 0.0] })); // 0
    g.node(json!({ "name": "J0", "rotation": Quat::from_rotation_z(PI / 2.0).to_array(), "children": [0] })); // 1
    g.node(json!({ "name": "B", "translation": [0.0, 1.0, 0.0], "mesh": 1 })); // 2
    g.node(json!({ "name": "A", "translation": [0.0, 0.0, 1.0], "scale": [2.0, 1.0, 1.0], "children": [1, 2] })); // 3
    g.node(json!({ "name": "S", "mesh": 0, "skin": 0 })); // 4
    g.json["skins"] = json!([{ "joints": [1, 0] }]);
    g.json["scenes"] = json!([{ "nodes": [3, 4] }]);
    let scene = Scene::from_slice(&g.to_glb(), None, &LoadOptions::default()).unwrap();
    let posed = scene.pose(None, 0.0);
    // Output order is node-index order: B (node 2) first, then S (node 4).
    assert_eq!(posed.primitives[0].name, "B.0");
    assert_eq!(posed.primitives[1].name, "S.0");
    let rigid = &posed.primitives[0].positions;
    assert_near(rigid[0], Vec3::new(2.0, 1.0, 1.0), "B (1,0,0)");
    assert_near(rigid[1], Vec3::new(0.0, 2.0, 1.0), "B (0,1,0)");
    let skinned = &posed.primitives[1].positions;
    // J1 p = p + x; Rz90 (x, y) = (-y, x); scale x by 2; lift z by 1.
    assert_near(skinned[0], Vec3::new(0.0, 2.0, 1.0), "S v0");
    assert_near(skinned[1], Vec3::new(-2.0, 1.0, 1.0), "S v1");
    assert_near(skinned[2], Vec3::new(0.0, 0.0, 1.0), "S v2 on J0");
}

#[test]
fn every_joints_weights_set_is_used_and_weights_are_renormalised() {
    // Two influence sets; v0 has weight 1 on joint 1 in set 1 only, v2 weights 1 + 1 across
    // sets (sum 2, renormalised to 1/2 each).
    let mut g = two_joint(|g| {
        rotation_clip(
            g,
            "LINEAR",
            &[0.0, 1.0],
            &[Quat::from_rotation_z(PI / 2.0); 2],
        )
    });
    let j0 = g.joints(&[[0, 0, 0, 0], [0, 0, 0, 0], [0, 0, 0, 0]]);
    let w0 = g.floats(
        &[0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0],
        "VEC4",
    );
    let j1 = g.joints(&[[1, 0, 0, 0], [0, 0, 0, 0], [1, 0, 0, 0]]);
    let w1 = g.floats(
        &[1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0],
        "VEC4",
    );
    let attrs = &mut g.json["meshes"][0]["primitives"][0]["attributes"];
    attrs["JOINTS_0"] = json!(j0);
    attrs["WEIGHTS_0"] = json!(w0);
    attrs["JOINTS_1"] = json!(j1);
    attrs["WEIGHTS_1"] = json!(w1);
    let p = posed(&g.to_glb(), 0.5);
    let e = expected(PI / 2.0);
    assert_near(p[0], e[0], "v0 from set 1");
    assert_near(p[2], e[2], "v2 renormalised");
}

#[test]
fn roles_come_from_extras_then_names_then_overrides() {
    let mut g = TestGltf::new();
    let pos = g.floats(&[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0], "VEC3");
    let prim = json!([{ "attributes": { "POSITION": pos } }]);
    g.mesh(json!({ "name": "thing_bone", "primitives": prim, "extras": { "dermis": { "role": "muscle" } } }));
    g.mesh(json!({ "name": "left_bone", "primitives": prim }));
    g.mesh(json!({ "name": "cloth", "primitives": prim }));
    g.mesh(json!({ "name": "plain", "primitives": prim }));
    for m in 0..4 {
        g.node(json!({ "mesh": m }));
    }
    let options = LoadOptions {
        role_overrides: vec![
            ("cloth".into(), Role::Skin),
            ("left_bone".into(), Role::Skin),
        ],
    };
    let scene = Scene::from_slice(&g.to_glb(), None, &options).unwrap();
    let roles: Vec<_> = scene
        .meshes
        .iter()
        .map(|m| (m.role, m.role_source))
        .collect();
    assert_eq!(
        roles,
        vec![
            (Some(Role::Muscle), Some(RoleSource::Extras)),
            (Some(Role::Bone), Some(RoleSource::Name)),
            (Some(Role::Skin), Some(RoleSource::Override)),
            (None, None),
        ]
    );
}

#[test]
fn a_single_skinned_mesh_becomes_the_skin_with_capsules_along_its_bone() {
    let g = two_joint(|_| json!([]));
    let scene = Scene::from_slice(&g.to_glb(), None, &LoadOptions::default()).unwrap();
    assert_eq!(scene.meshes[0].role, Some(Role::Skin));
    assert_eq!(
        scene.meshes[0].role_source,
        Some(RoleSource::SingleSkinnedMesh)
    );
    // Joint 0 dominates v1 (0.5, 0, 0) and v2 (1, 1, 0) (tie -> first listed, joint 0):
    // bone from (0,0,0) to (1,0,0); median of distances {0, 1} is the upper one, 1.
    let c = scene.capsules.iter().find(|c| c.joint == 0).unwrap();
    assert_near(c.a, Vec3::ZERO, "capsule a");
    assert_near(c.b, Vec3::X, "capsule b");
    assert!((c.radius_m - 1.0).abs() < 1e-6);
}
