//! The second-order warm start in a scene: its deviation history is part of the checkpoint.

use super::{arm, checkpointed, resumed, thick_contact, world_with};
use dermis::ecs::restore_state;

/// The warm start extrapolates the skin's deviation from its anchors over the last two solves;
/// a checkpoint taken mid-clip holds that history (one target and one deviation per vertex),
/// so the restored run continues bit for bit, and the same restore with the history dropped
/// (the first-order start for a frame) does not (the check has teeth).
#[test]
fn the_motion_history_makes_checkpoints_exact() {
    let scene = arm();
    let options = thick_contact();
    let (state, _, a) = checkpointed(&scene, &options, 27, 3);
    let skin = &state.skins[0];
    assert_eq!(skin.motion_targets.len(), skin.positions.len());
    assert_eq!(skin.motion_deviations.len(), skin.positions.len());
    assert!(skin.motion_deviations.iter().any(|u| u.length() > 0.0));
    assert_eq!(a, resumed(&scene, &options, &state, 3).1);

    let mut forgetful = state.clone();
    forgetful.skins[0].motion_targets.clear();
    forgetful.skins[0].motion_deviations.clear();
    assert_ne!(a, resumed(&scene, &options, &forgetful, 3).1);

    // A history of another length is a typed error, not a panic.
    let mut short = state.clone();
    short.skins[0].motion_deviations.pop();
    let (mut bad, _, _) = world_with(&scene, &options);
    assert!(restore_state(&mut bad, &short).is_err());
}
