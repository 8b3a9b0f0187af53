//! Friction across frames in a scene: the anchors are part of the checkpoint.

use super::{arm, bits, resumed, run, thick_contact, world_with};
use dermis::ecs::{capture_state, scene_diagnostics, scene_skin_positions};

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
    let a = bits(&scene_skin_positions(&direct, spawned.skins[0].entity).unwrap());

    let (restored, b) = resumed(&scene, &options, &state, m);
    assert_eq!(a, b);
    let d = scene_diagnostics(&restored).unwrap();
    assert!(d.skins[0].contact.as_ref().unwrap().contacts > 0);

    let mut forgetful = state.clone();
    forgetful.skins[0].friction_anchors.clear();
    assert_ne!(a, resumed(&scene, &options, &forgetful, m).1);
}
