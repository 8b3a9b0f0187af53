//! glTF scenes in the ECS: spawn, playback against `Scene::pose`, collision, checkpoints.

use std::path::Path;

use bevy_ecs::prelude::*;
use dermis::ecs::{
    DermisPlugin, SceneAnimation, SceneError, SceneOptions, SceneSkin, SceneState, SkinAnchors,
    Tissue, capture_state, collider_geometry, restore_state, scene_diagnostics,
    scene_skin_positions, spawn_scene,
};
use dermis::gltf::{GltfError, LoadOptions, Role, Scene, load};
use glam::Vec3;
use parry3d::math::Pose;
use parry3d::query::PointQuery;
use parry3d::shape::{TriMesh as ParryMesh, TriMeshFlags};

mod friction;
mod warm_start;

fn arm() -> Scene {
    load(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/arm.glb"),
        &LoadOptions::default(),
    )
    .unwrap()
}

fn no_contact() -> SceneOptions {
    SceneOptions {
        contact: None,
        ..SceneOptions::default()
    }
}

/// A world with the scene spawned and its schedule.
fn world_with(
    scene: &Scene,
    options: &SceneOptions,
) -> (World, Schedule, dermis::ecs::SpawnedScene) {
    let mut world = World::new();
    let schedule = DermisPlugin.build_schedule(&mut world);
    let spawned = spawn_scene(&mut world, scene, options).unwrap();
    (world, schedule, spawned)
}

fn run(world: &mut World, schedule: &mut Schedule, frames: usize) {
    for _ in 0..frames {
        schedule.run(world);
    }
}

fn bits(x: &[Vec3]) -> Vec<[u32; 3]> {
    x.iter().map(|p| p.to_array().map(f32::to_bits)).collect()
}

/// A run of `scene` checkpointed after `before` frames and continued for `after` more: the
/// checkpoint, the world, and the bits of its skin's positions at the end.
fn checkpointed(
    scene: &Scene,
    options: &SceneOptions,
    before: usize,
    after: usize,
) -> (SceneState, World, Vec<[u32; 3]>) {
    let (mut world, mut schedule, spawned) = world_with(scene, options);
    run(&mut world, &mut schedule, before);
    let state = capture_state(&mut world).unwrap();
    run(&mut world, &mut schedule, after);
    let x = scene_skin_positions(&world, spawned.skins[0].entity).unwrap();
    (state, world, bits(&x))
}

/// `frames` frames run in a fresh world of `scene` restored from `state` (through its JSON
/// form, as a checkpoint file holds it): the world, and the bits of its skin's positions.
fn resumed(
    scene: &Scene,
    options: &SceneOptions,
    state: &SceneState,
    frames: usize,
) -> (World, Vec<[u32; 3]>) {
    let (mut world, mut schedule, spawned) = world_with(scene, options);
    let json = serde_json::to_string(state).unwrap();
    restore_state(&mut world, &serde_json::from_str(&json).unwrap()).unwrap();
    run(&mut world, &mut schedule, frames);
    let x = scene_skin_positions(&world, spawned.skins[0].entity).unwrap();
    (world, bits(&x))
}

#[test]
fn the_arm_spawns_one_skin_two_muscles_and_two_bones() {
    let scene = arm();
    let (_, _, spawned) = world_with(&scene, &SceneOptions::default());
    assert_eq!(spawned.skins.len(), 1);
    assert_eq!(spawned.skins[0].name, "arm_skin.0");
    let mut colliders: Vec<(&str, Tissue)> = spawned
        .colliders
        .iter()
        .map(|c| (c.name.as_str(), c.tissue))
        .collect();
    colliders.sort();
    let mut expected: Vec<(String, Tissue)> = scene
        .nodes
        .iter()
        .filter_map(|n| {
            let role = scene.meshes[n.mesh? as usize].role?;
            let tissue = match role {
                Role::Muscle => Tissue::Muscle,
                Role::Bone => Tissue::Bone,
                Role::Skin => return None,
            };
            Some((format!("{}.0", n.name), tissue))
        })
        .collect();
    expected.sort();
    assert_eq!(expected.len(), 4);
    let expected: Vec<(&str, Tissue)> = expected.iter().map(|(n, t)| (n.as_str(), *t)).collect();
    assert_eq!(colliders, expected);
    assert!(spawned.colliders.iter().all(|c| !c.capsule));
    assert_eq!(spawned.clip, Some(0));
    assert_eq!(spawned.clip_duration_s, scene.clips[0].duration());
}

#[test]
fn anchors_at_mid_clip_are_the_posed_skin_of_dermis_pose() {
    let scene = arm();
    let (mut world, mut schedule, spawned) = world_with(&scene, &no_contact());
    let frames = (0.5 * f64::from(spawned.clip_duration_s) * 30.0).round() as usize;
    run(&mut world, &mut schedule, frames);
    let t = world.resource::<SceneAnimation>().clock.sample_time_s();
    assert!((t - 0.5 * spawned.clip_duration_s).abs() < 1e-6, "t = {t}");
    let posed = scene.pose(Some(0), t);
    let skin = &spawned.skins[0];
    let reference = posed
        .primitives
        .iter()
        .find(|p| p.node == skin.node && p.primitive == skin.primitive)
        .unwrap();
    let anchors = world.get::<SkinAnchors>(skin.entity).unwrap();
    let weld = &world.get::<SceneSkin>(skin.entity).unwrap().weld;
    assert_eq!(weld.primitive_to_welded.len(), reference.positions.len());
    let mut moved = 0.0f32;
    let bind = &scene.meshes[4].primitives[0].positions;
    for (v, p) in reference.positions.iter().enumerate() {
        let a = anchors[weld.primitive_to_welded[v] as usize].target;
        assert!(
            (a - *p).length() < 1e-6,
            "vertex {v}: anchor {a}, posed {p}"
        );
        moved = moved.max(p.distance(bind[v]));
    }
    assert!(moved > 0.05, "the elbow bent: largest motion {moved} m");
    // Colliders too: deforming muscles and rigidly posed bones, in the primitive's order.
    for c in &spawned.colliders {
        let (v, t) = collider_geometry(&world, c.entity).unwrap();
        let reference = posed.primitives.iter().find(|p| p.name == c.name).unwrap();
        assert_eq!(t, reference.triangles, "{}", c.name);
        assert_eq!(v.len(), reference.positions.len(), "{}", c.name);
        for (i, (a, b)) in v.iter().zip(&reference.positions).enumerate() {
            assert!(
                (*a - *b).length() < 1e-5,
                "{} vertex {i}: {a} vs {b}",
                c.name
            );
        }
    }
}

/// Depth of `p` inside a closed mesh (0 outside), by parry's own solid query.
fn depth_inside(mesh: &ParryMesh, p: Vec3) -> f32 {
    let proj = mesh.project_point(&Pose::IDENTITY, p, false);
    if proj.is_inside {
        proj.point.distance(p)
    } else {
        0.0
    }
}

/// Thick enough (12 mm: skin and subcutaneous fat) that the skinned skin of the arm comes
/// closer than that to its biceps and triceps, so the contact has work to do.
fn thick_contact() -> SceneOptions {
    let mut options = SceneOptions::default();
    options.contact.as_mut().unwrap().thickness_m = 0.012;
    options
}

/// Smallest signed distance from `points` to a closed mesh (negative inside), by parry.
fn clearance(mesh: &ParryMesh, points: &[Vec3]) -> f32 {
    points
        .iter()
        .map(|p| {
            let proj = mesh.project_point(&Pose::IDENTITY, *p, false);
            let d = proj.point.distance(*p);
            if proj.is_inside { -d } else { d }
        })
        .fold(f32::INFINITY, f32::min)
}

#[test]
fn with_collision_no_skin_vertex_ends_inside_a_muscle_or_bone() {
    let scene = arm();
    let options = thick_contact();
    let h = options.contact.unwrap().thickness_m;
    let (mut world, mut schedule, spawned) = world_with(&scene, &options);
    let skin = spawned.skins[0].entity;
    let mut touched = false;
    for frame in 1..=6 {
        run(&mut world, &mut schedule, 1);
        let x = scene_skin_positions(&world, skin).unwrap();
        let anchors: Vec<Vec3> = world
            .get::<SkinAnchors>(skin)
            .unwrap()
            .iter()
            .map(|a| a.target)
            .collect();
        let (mut skin_min, mut anchor_min) = (f32::INFINITY, f32::INFINITY);
        for c in &spawned.colliders {
            let (v, t) = collider_geometry(&world, c.entity).unwrap();
            let mesh = ParryMesh::with_flags(v, t, TriMeshFlags::ORIENTED).unwrap();
            skin_min = skin_min.min(clearance(&mesh, &x));
            anchor_min = anchor_min.min(clearance(&mesh, &anchors));
        }
        let d = scene_diagnostics(&world).unwrap();
        let contact = d.skins[0].contact.clone().unwrap();
        println!(
            "frame {frame}: skin clearance {skin_min} m, skinned anchors {anchor_min} m, \
             {} contacts, {} substeps",
            contact.contacts, contact.substeps
        );
        // The skinned skin alone would be closer than the thickness: collision matters.
        assert!(
            anchor_min < h - 1e-4,
            "frame {frame}: anchors {anchor_min} m away"
        );
        // No vertex inside anything, and every vertex at the thickness (to 1 %).
        assert!(
            skin_min > 0.99 * h,
            "frame {frame}: a skin vertex is {skin_min} m from a collider"
        );
        assert!(contact.unresolved.is_empty(), "{:?}", contact.unresolved);
        touched |= contact.contacts > 0;
    }
    assert!(touched);
}

#[test]
fn capture_restore_continues_bit_for_bit() {
    let scene = arm();
    let options = thick_contact();
    let (state, direct, a) = checkpointed(&scene, &options, 27, 3);
    let (restored, b) = resumed(&scene, &options, &state, 3);
    assert_eq!(a, b);
    let contact = scene_diagnostics(&restored).unwrap().skins[0]
        .contact
        .clone()
        .unwrap();
    assert!(contact.contacts > 0, "the contact took part");
    assert_eq!(
        direct.resource::<SceneAnimation>().clock,
        restored.resource::<SceneAnimation>().clock
    );
    // A restored world that is not advanced differs: the check above has teeth.
    let (fresh, _, spawned3) = world_with(&scene, &options);
    let c = scene_skin_positions(&fresh, spawned3.skins[0].entity).unwrap();
    assert_ne!(a, bits(&c));
}

/// The contact query cache carries over from frame to frame, and a capture clears it in the
/// running world: the captured run's next frame then does exactly the work of the restored
/// run's, query for query.
#[test]
fn the_query_cache_carries_over_frames_and_a_capture_clears_it() {
    let scene = arm();
    let options = thick_contact();
    let n = 27;
    let contact = |world: &World| {
        scene_diagnostics(world).unwrap().skins[0]
            .contact
            .clone()
            .unwrap()
    };
    let (mut direct, mut schedule, _) = world_with(&scene, &options);
    run(&mut direct, &mut schedule, n);
    let (mut uncaptured, mut schedule0, _) = world_with(&scene, &options);
    run(&mut uncaptured, &mut schedule0, n + 1);
    let state = capture_state(&mut direct).unwrap();
    run(&mut direct, &mut schedule, 1);
    let (mut restored, mut schedule2, _) = world_with(&scene, &options);
    restore_state(&mut restored, &state).unwrap();
    run(&mut restored, &mut schedule2, 1);
    let (warm, captured, fresh) = (contact(&uncaptured), contact(&direct), contact(&restored));
    assert_eq!(captured, fresh);
    assert!(fresh.passes > 0 && fresh.exact_queries > 0);
    // The uncaptured run's cache carried over: its queries went otherwise (which is what makes
    // the equality above mean something).
    assert_ne!(warm, fresh);
}

#[test]
fn restore_rejects_a_state_of_another_timestep() {
    let scene = arm();
    let (mut direct, _, _) = world_with(&scene, &no_contact());
    let state = capture_state(&mut direct).unwrap();
    let other = SceneOptions {
        dt_s: 1.0 / 60.0,
        ..no_contact()
    };
    let (mut world, _, _) = world_with(&scene, &other);
    let err = restore_state(&mut world, &state).unwrap_err();
    assert!(matches!(err, SceneError::StateMismatch(_)), "{err}");
}

fn hash_after(threads: usize, frames: usize) -> Vec<[u32; 3]> {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    pool.install(|| {
        let scene = arm();
        let (mut world, mut schedule, spawned) = world_with(&scene, &thick_contact());
        run(&mut world, &mut schedule, frames);
        bits(&scene_skin_positions(&world, spawned.skins[0].entity).unwrap())
    })
}

#[test]
fn one_and_two_threads_give_identical_skins() {
    assert_eq!(hash_after(1, 3), hash_after(2, 3));
}

/// The arm with only its skin left, unnamed and without extras: a rigged character as any tool
/// exports it. The glTF JSON chunk of the `.glb` is rewritten; the binary chunk is kept.
fn skin_only_arm() -> Scene {
    let glb = dermis::gltf::arm::build_arm_glb();
    let u32_at = |i: usize| u32::from_le_bytes(glb[i..i + 4].try_into().unwrap()) as usize;
    let json_len = u32_at(12);
    let mut json: serde_json::Value = serde_json::from_slice(&glb[20..20 + json_len]).unwrap();
    let skin_mesh = json["meshes"]
        .as_array()
        .unwrap()
        .iter()
        .position(|m| m["name"] == "arm_skin")
        .unwrap();
    let mut mesh = json["meshes"][skin_mesh].clone();
    mesh.as_object_mut().unwrap().remove("extras");
    mesh["name"] = "arm".into();
    json["meshes"] = serde_json::json!([mesh]);
    for node in json["nodes"].as_array_mut().unwrap() {
        let node = node.as_object_mut().unwrap();
        node.remove("extras");
        match node.get("mesh").and_then(serde_json::Value::as_u64) {
            Some(m) if m as usize == skin_mesh => {
                node.insert("mesh".into(), 0.into());
                node.insert("name".into(), "arm".into());
            }
            Some(_) => {
                node.remove("mesh");
                node.remove("skin");
            }
            None => {}
        }
    }
    let mut text = serde_json::to_vec(&json).unwrap();
    while !text.len().is_multiple_of(4) {
        text.push(b' ');
    }
    let bin = &glb[20 + json_len..];
    let mut out = Vec::new();
    out.extend_from_slice(&glb[..8]);
    out.extend_from_slice(&((12 + 8 + text.len() + bin.len()) as u32).to_le_bytes());
    out.extend_from_slice(&(text.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&text);
    out.extend_from_slice(bin);
    Scene::from_slice(&out, None, &LoadOptions::default()).unwrap()
}

#[test]
fn a_model_with_only_a_skinned_mesh_gets_capsule_bones() {
    let scene = skin_only_arm();
    assert_eq!(scene.meshes.len(), 1);
    assert_eq!(scene.meshes[0].role, Some(Role::Skin));
    assert!(!scene.capsules.is_empty());
    let (mut world, mut schedule, spawned) = world_with(&scene, &SceneOptions::default());
    assert_eq!(spawned.skins.len(), 1);
    assert_eq!(spawned.colliders.len(), scene.capsules.len());
    assert!(
        spawned
            .colliders
            .iter()
            .all(|c| c.capsule && c.tissue == Tissue::Bone)
    );
    run(&mut world, &mut schedule, 20);
    let d = scene_diagnostics(&world).unwrap();
    assert!(d.skins[0].error.is_none(), "{:?}", d.skins[0].error);
    // The capsules follow their joints: a capsule tessellation, posed from its joint, holds the
    // posed joint position of the bone's start (an independent answer from the scene's pose).
    let pose = scene.pose(Some(0), d.time_s);
    assert!(!pose.primitives.is_empty());
    let skin = scene_skin_positions(&world, spawned.skins[0].entity).unwrap();
    let globals = scene
        .hierarchy
        .global_transforms(&scene.sample(Some(0), d.time_s).locals);
    for (c, capsule) in spawned.colliders.iter().zip(&scene.capsules) {
        let (v, t) = collider_geometry(&world, c.entity).unwrap();
        let mesh = ParryMesh::with_flags(v, t, TriMeshFlags::ORIENTED).unwrap();
        let joint = globals[capsule.node as usize].w_axis.truncate();
        assert!(
            mesh.contains_point(&Pose::IDENTITY, joint),
            "{} does not hold its joint at {joint}",
            c.name
        );
        // No skin vertex inside (the tessellation lies within the exact capsule).
        let worst = skin
            .iter()
            .map(|p| depth_inside(&mesh, *p))
            .fold(0.0f32, f32::max);
        assert!(
            worst < 1e-4,
            "{}: a skin vertex is {worst} m inside",
            c.name
        );
    }
}

#[test]
fn a_missing_clip_and_a_bad_timestep_are_typed_errors() {
    let scene = arm();
    let mut world = World::new();
    let err = spawn_scene(
        &mut world,
        &scene,
        &SceneOptions {
            clip: Some("wave".into()),
            ..SceneOptions::default()
        },
    )
    .unwrap_err();
    match &err {
        SceneError::Gltf(GltfError::ClipNotFound { requested, .. }) => {
            assert_eq!(requested, "wave");
        }
        other => panic!("wrong error {other}"),
    }
    assert!(err.to_string().contains("elbow_flexion"), "{err}");
    let err = spawn_scene(
        &mut world,
        &scene,
        &SceneOptions {
            dt_s: 0.0,
            ..SceneOptions::default()
        },
    )
    .unwrap_err();
    assert!(matches!(err, SceneError::BadTimestep { .. }), "{err}");
    assert!(!world.contains_resource::<SceneAnimation>());
}
