//! Friction across frames in a scene: the anchors are part of the checkpoint.

use super::{arm, bits, run, thick_contact, world_with};
use dermis::ecs::{capture_state, restore_state, scene_diagnostics, scene_skin_positions};

/// With full friction the skin's contacts carry their anchors from frame to frame; a checkpoint
/// taken mid-run holds them, so the restored run continues bit for bit, and the same restore
/// with the anchors dropped does not (the check has teeth).
#[test]
fn friction_anchors_make_checkpoints_exact() {
    let scene = arm();
    let mut options = thick_contact();
    options.contact.as_mut().unwrap().friction = 1.0;
    let (n, m) = (27, 3);
    let (mut direct, mut schedule, spawned) = world_with(&scene, &options);
    run(&mut direct, &mut schedule, n);
    let state = capture_state(&mut direct).unwrap();
    assert!(
        state.skins[0].friction_anchors.iter().any(Option::is_some),
        "no vertex touching at the checkpoint"
    );
    run(&mut direct, &mut schedule, m);
    let a = scene_skin_positions(&direct, spawned.skins[0].entity).unwrap();

    let (mut restored, mut schedule2, spawned2) = world_with(&scene, &options);
    let json = serde_json::to_string(&state).unwrap();
    restore_state(&mut restored, &serde_json::from_str(&json).unwrap()).unwrap();
    run(&mut restored, &mut schedule2, m);
    let b = scene_skin_positions(&restored, spawned2.skins[0].entity).unwrap();
    assert_eq!(bits(&a), bits(&b));
    let d = scene_diagnostics(&restored).unwrap();
    assert!(d.skins[0].contact.as_ref().unwrap().contacts > 0);

    let mut forgetful = state.clone();
    forgetful.skins[0].friction_anchors.clear();
    let (mut lost, mut schedule3, spawned3) = world_with(&scene, &options);
    restore_state(&mut lost, &forgetful).unwrap();
    run(&mut lost, &mut schedule3, m);
    let c = scene_skin_positions(&lost, spawned3.skins[0].entity).unwrap();
    assert_ne!(bits(&a), bits(&c));
}
