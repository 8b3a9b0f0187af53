//! The second-order warm start in a scene: its deviation history is part of the checkpoint.

use super::{arm, bits, resumed, run, thick_contact, world_with};
use dermis::ecs::{capture_state, restore_state, scene_skin_positions};

/// The warm start extrapolates the skin's deviation from its anchors over the last two solves;
/// a checkpoint taken mid-clip holds that history (one target and one deviation per vertex),
/// so the restored run continues bit for bit, and the same restore with the history dropped
/// (the first-order start for a frame) does not (the check has teeth).
#[test]
fn the_motion_history_makes_checkpoints_exact() {
    let scene = arm();
    let options = thick_contact();
    let (n, m) = (27, 3);
    let (mut direct, mut schedule, spawned) = world_with(&scene, &options);
    run(&mut direct, &mut schedule, n);
    let state = capture_state(&mut direct).unwrap();
    let skin = &state.skins[0];
    assert_eq!(skin.motion_targets.len(), skin.positions.len());
    assert_eq!(skin.motion_deviations.len(), skin.positions.len());
    assert!(skin.motion_deviations.iter().any(|u| u.length() > 0.0));
    run(&mut direct, &mut schedule, m);
    let a = bits(&scene_skin_positions(&direct, spawned.skins[0].entity).unwrap());
    assert_eq!(a, resumed(&scene, &options, &state, m).1);

    let mut forgetful = state.clone();
    forgetful.skins[0].motion_targets.clear();
    forgetful.skins[0].motion_deviations.clear();
    assert_ne!(a, resumed(&scene, &options, &forgetful, m).1);

    // A history of another length is a typed error, not a panic.
    let mut short = state.clone();
    short.skins[0].motion_deviations.pop();
    let (mut bad, _, _) = world_with(&scene, &options);
    assert!(restore_state(&mut bad, &short).is_err());
}
