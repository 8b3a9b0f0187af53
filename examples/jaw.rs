//! Opens a hinged jaw by contracting a platysma-like muscle, as in Fig. 1 of Dima, Dima & Cristea
//! (2009), through the ECS: a plain `World` and the dermis `Schedule`.
//!
//! [`spawn_jaw`] spawns the scene as entities: a rig entity owning the coupled muscle-and-bone
//! simulation, a child entity per muscle and bone, and a skin sleeve over the muscle. A kinematic
//! skull holds the jaw on a two-spring hinge; the muscle lattice (pressure cells plus
//! longitudinal and in-section springs) runs from under the chin to a fixed spine anchor. Each
//! frame the example raises the muscle's [`MuscleActivation`] and runs the schedule once: the
//! rig steps its dynamics (`DermisSystems::Muscles`), the muscle surface and bone poses refresh
//! the skin's colliders (`DermisSystems::Colliders`), and the skin relaxes over the bulging
//! muscle (`DermisSystems::Relax`). The muscle shortens, its insertion springs pull the chin
//! down and back, and the jaw rotates open. The example prints the jaw angle (from the jaw's
//! [`BonePose`]), the muscle's length and volume ([`MuscleState`]) and the skin's contact count.
//!
//! Run with `cargo run --release --example jaw`.

use std::error::Error;

use bevy_ecs::prelude::*;
use dermis::anatomy::scenes::{JawConfig, JawScene};
use dermis::ecs::*;

fn main() -> Result<(), Box<dyn Error>> {
    let mut world = World::new();
    let mut schedule = DermisPlugin.build_schedule(&mut world);
    let frames = 60;
    let jaw = spawn_jaw(
        &mut world,
        &JawConfig::default(),
        40,
        Some(&JawSkinConfig::default()),
    )?;
    println!("frame  activation  jaw angle (deg)  muscle length  muscle volume  skin contacts");
    for frame in 0..frames {
        let activation = frame as f32 / (frames - 1) as f32;
        world
            .get_mut::<MuscleActivation>(jaw.muscle)
            .ok_or("no muscle")?
            .0 = activation;
        schedule.run(&mut world);
        if let Some(e) = &world
            .get::<AnatomyDiagnostics>(jaw.anatomy.rig)
            .ok_or("no rig")?
            .error
        {
            return Err(e.clone().into());
        }
        let angle = world
            .get::<BonePose>(jaw.jaw)
            .ok_or("no jaw")?
            .angle_about(JawScene::HINGE_AXIS);
        let muscle = *world.get::<MuscleState>(jaw.muscle).ok_or("no muscle")?;
        let contacts = jaw
            .skin
            .and_then(|s| world.get::<RelaxDiagnostics>(s))
            .and_then(|d| d.contact.as_ref())
            .map_or(0, |c| c.contacts);
        if frame % 6 == 0 || frame + 1 == frames {
            println!(
                "{frame:>5}  {activation:>10.2}  {:>15.2}  {:>13.3}  {:>13.4}  {contacts:>13}",
                angle.to_degrees(),
                muscle.length_m / muscle.rest_length_m,
                muscle.volume_ratio(),
            );
        }
    }
    Ok(())
}
