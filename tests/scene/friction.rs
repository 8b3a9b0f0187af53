//! Friction across frames in a scene: the anchors are part of the checkpoint.

use super::{arm, checkpointed, resumed, thick_contact};
use dermis::ecs::scene_diagnostics;

/// With full friction the skin's contacts carry their anchors from frame to frame; a checkpoint
/// taken mid-run holds them, so the restored run continues bit for bit, and the same restore
/// with the anchors dropped does not (the check has teeth).
#[test]
fn friction_anchors_make_checkpoints_exact() {
    let scene = arm();
    let mut options = thick_contact();
    options.contact.as_mut().unwrap().friction = 1.0;
    let (state, _, a) = checkpointed(&scene, &options, 27, 3);
    assert!(
        state.skins[0].friction_anchors.iter().any(Option::is_some),
        "no vertex touching at the checkpoint"
    );
    let (restored, b) = resumed(&scene, &options, &state, 3);
    assert_eq!(a, b);
    let d = scene_diagnostics(&restored).unwrap();
    assert!(d.skins[0].contact.as_ref().unwrap().contacts > 0);

    let mut forgetful = state.clone();
    forgetful.skins[0].friction_anchors.clear();
    assert_ne!(a, resumed(&scene, &options, &forgetful, 3).1);
}
