//! The second-order warm start in a scene: its deviation history is part of the checkpoint.

use super::{arm, bits, run, thick_contact, world_with};
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
    let a = scene_skin_positions(&direct, spawned.skins[0].entity).unwrap();

    let (mut restored, mut schedule2, spawned2) = world_with(&scene, &options);
    let json = serde_json::to_string(&state).unwrap();
    restore_state(&mut restored, &serde_json::from_str(&json).unwrap()).unwrap();
    run(&mut restored, &mut schedule2, m);
    let b = scene_skin_positions(&restored, spawned2.skins[0].entity).unwrap();
    assert_eq!(bits(&a), bits(&b));

    let mut forgetful = state.clone();
    forgetful.skins[0].motion_targets.clear();
    forgetful.skins[0].motion_deviations.clear();
    let (mut lost, mut schedule3, spawned3) = world_with(&scene, &options);
    restore_state(&mut lost, &forgetful).unwrap();
    run(&mut lost, &mut schedule3, m);
    let c = scene_skin_positions(&lost, spawned3.skins[0].entity).unwrap();
    assert_ne!(bits(&a), bits(&c));

    // A history of another length is a typed error, not a panic.
    let mut short = state.clone();
    short.skins[0].motion_deviations.pop();
    let (mut bad, _, _) = world_with(&scene, &options);
    assert!(restore_state(&mut bad, &short).is_err());
}
