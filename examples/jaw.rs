//! Opens a hinged jaw by contracting a platysma-like muscle, as in Fig. 1 of Dima, Dima & Cristea
//! (2009). A kinematic skull holds the jaw on a two-spring hinge; a muscle lattice (pressure cells
//! plus longitudinal and in-section springs) runs from under the chin to a fixed spine anchor.
//! Raising the muscle's activation shortens it, and its insertion springs pull the chin down and
//! back: the jaw rotates open. The example prints the jaw angle, the muscle's length and volume
//! for each activation.
//!
//! Run with `cargo run --release --example jaw`.

use dermis::anatomy::AnatomyError;
use dermis::anatomy::scenes::{JawConfig, jaw};

fn main() -> Result<(), AnatomyError> {
    let mut scene = jaw(&JawConfig::default())?;
    let m = scene.muscle;
    let sections = scene.system.muscle(m).map_or(2, |mu| mu.sections());
    let length = |s: &dermis::anatomy::dynamics::AnatomySystem| -> Result<f32, AnatomyError> {
        Ok(
            (s.muscle_section_centroid(m, sections - 1)? - s.muscle_section_centroid(m, 0)?)
                .length(),
        )
    };
    let (l0, v0) = (length(&scene.system)?, scene.system.muscle_volume_m3(m)?);
    println!(
        "{} particles, {} springs, {} pressure cells",
        scene.system.positions().len(),
        scene.system.springs().len(),
        scene.system.cell_count()
    );
    println!("activation  jaw angle (deg)  muscle length  muscle volume");
    for k in 0..=10 {
        let activation = k as f32 / 10.0;
        let angle = scene.settle(activation, 400)?;
        println!(
            "{activation:>10.1}  {:>15.2}  {:>13.3}  {:>13.4}",
            angle.to_degrees(),
            length(&scene.system)? / l0,
            scene.system.muscle_volume_m3(m)? / v0
        );
    }
    Ok(())
}
