//! Plays the bundled arm's elbow flexion with the skin colliding with its muscles and bones,
//! printing per-frame diagnostics.
//!
//! `cargo run --release --example arm [MODEL.glb] [THICKNESS_M]`

use std::path::PathBuf;
use std::time::Instant;

use bevy_ecs::prelude::*;
use dermis::ecs::{
    DermisPlugin, SceneOptions, scene_diagnostics, scene_skin_positions, spawn_scene,
};
use dermis::gltf::{LoadOptions, load};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let path = args.next().map_or_else(
        || PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("assets/arm.glb"),
        PathBuf::from,
    );
    let mut options = SceneOptions::default();
    if let Some(h) = args.next() {
        options.contact.get_or_insert_default().thickness_m = h.parse()?;
    }
    let scene = load(&path, &LoadOptions::default())?;
    let mut world = World::new();
    let mut schedule = DermisPlugin.build_schedule(&mut world);
    let spawned = spawn_scene(&mut world, &scene, &options)?;
    println!(
        "{}: {} skin(s), {} collider(s), clip {:?} of {:.2} s at {:.1} fps",
        path.display(),
        spawned.skins.len(),
        spawned.colliders.len(),
        spawned.clip,
        spawned.clip_duration_s,
        1.0 / options.dt_s
    );
    let frames = (f64::from(spawned.clip_duration_s) / options.dt_s).ceil() as u64 + 1;
    let mut total_ms = 0.0;
    for _ in 0..frames {
        let start = Instant::now();
        schedule.run(&mut world);
        let ms = start.elapsed().as_secs_f64() * 1e3;
        total_ms += ms;
        let d = scene_diagnostics(&world)?;
        for s in &d.skins {
            let (substeps, contacts, unresolved) = s
                .contact
                .as_ref()
                .map_or((0, 0, 0), |c| (c.substeps, c.contacts, c.unresolved.len()));
            println!(
                "frame {:3} t {:.3} s {}: {:3} iterations, residual {:.2e}, {substeps} substeps, \
                 {contacts} contacts, {unresolved} unresolved, {ms:.2} ms{}",
                d.frame,
                d.time_s,
                s.name,
                s.iterations,
                s.residual,
                s.error
                    .as_deref()
                    .map_or(String::new(), |e| format!(", error: {e}")),
            );
        }
    }
    println!(
        "{frames} frames, mean {:.2} ms per frame",
        total_ms / frames as f64
    );
    // FNV-1a over the bits of every skin position: equal for any RAYON_NUM_THREADS.
    let mut hash = 0xcbf2_9ce4_8422_2325u64;
    for skin in &spawned.skins {
        for p in scene_skin_positions(&world, skin.entity)? {
            for b in p.to_array().map(f32::to_bits) {
                hash = (hash ^ u64::from(b)).wrapping_mul(0x100_0000_01b3);
            }
        }
    }
    println!("skin hash {hash:016x}");
    Ok(())
}
