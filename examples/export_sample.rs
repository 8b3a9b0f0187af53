//! Writes a small synthetic clip in every export format, for checking the writers with
//! external validators (`.ci/validate-gltf.mjs`, `.ci/validate-usd.py`) and viewers.
//!
//! The skin is a closed tube (an "arm") around a bone; over the clip a bulge travels along the
//! skin (a muscle contracting) and the bone sways. Run:
//!
//! ```sh
//! cargo run --example export_sample -- OUT_DIR [FRAMES]
//! ```
//!
//! It writes `OUT_DIR/arm.glb`, `OUT_DIR/arm.usda`, `OUT_DIR/obj/arm_NNNNNN.obj` and
//! `OUT_DIR/ply/arm_NNNNNN.ply`, all with the bone as a collider and strain colours, and
//! `OUT_DIR/arm_plain.glb` and `OUT_DIR/arm_plain.usda` with the skin only and no colours.

use std::path::PathBuf;

use dermis::export::{ExportMeta, ExportOptions, Format, FrameSequence, MeshMeta, MeshRole};
use glam::Vec3;

/// A closed tube along +Y: `rings × segments` vertices plus two cap centres.
fn tube(radius: f32, length: f32, rings: u32, segments: u32) -> (Vec<Vec3>, Vec<[u32; 3]>) {
    let mut p = Vec::new();
    for r in 0..rings {
        let y = length * r as f32 / (rings - 1) as f32;
        for s in 0..segments {
            let a = std::f32::consts::TAU * s as f32 / segments as f32;
            p.push(Vec3::new(radius * a.cos(), y, -radius * a.sin()));
        }
    }
    let bottom = p.len() as u32;
    p.push(Vec3::ZERO);
    let top = p.len() as u32;
    p.push(Vec3::new(0.0, length, 0.0));
    let mut t = Vec::new();
    let at = |r: u32, s: u32| r * segments + s % segments;
    for r in 0..rings - 1 {
        for s in 0..segments {
            t.push([at(r, s), at(r, s + 1), at(r + 1, s + 1)]);
            t.push([at(r, s), at(r + 1, s + 1), at(r + 1, s)]);
        }
    }
    for s in 0..segments {
        t.push([bottom, at(0, s + 1), at(0, s)]);
        t.push([top, at(rings - 1, s), at(rings - 1, s + 1)]);
    }
    (p, t)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let out = PathBuf::from(args.next().ok_or("usage: export_sample OUT_DIR [FRAMES]")?);
    let frames: u32 = args.next().map_or(Ok(24), |s| s.parse())?;

    let (skin_rest, skin_tris) = tube(0.04, 0.3, 24, 32);
    let (bone_rest, bone_tris) = tube(0.01, 0.3, 6, 8);
    let meta = ExportMeta::new(
        vec![
            MeshMeta::new("forearm", MeshRole::Skin, skin_tris, skin_rest.clone()),
            MeshMeta::new("radius", MeshRole::Bone, bone_tris, bone_rest.clone()),
        ],
        24.0,
    );
    let mut seq = FrameSequence::new(meta);
    for f in 0..frames {
        let phase = f as f32 / frames.max(1) as f32;
        let centre = 0.3 * phase;
        let skin = skin_rest
            .iter()
            .map(|p| {
                let bulge = 1.0 + 0.3 * (-((p.y - centre) / 0.05).powi(2)).exp();
                Vec3::new(p.x * bulge, p.y, p.z * bulge)
            })
            .collect();
        let sway = 0.01 * (std::f32::consts::TAU * phase).sin();
        let bone = bone_rest
            .iter()
            .map(|p| *p + Vec3::new(sway, 0.0, 0.0))
            .collect();
        seq.push(f, vec![skin, bone]);
    }
    let options = ExportOptions {
        with_colliders: true,
        ..ExportOptions::default()
    };
    std::fs::create_dir_all(out.join("obj"))?;
    std::fs::create_dir_all(out.join("ply"))?;
    for (format, path) in [
        (Format::Glb, out.join("arm.glb")),
        (Format::Usda, out.join("arm.usda")),
        (Format::Obj, out.join("obj/arm.obj")),
        (Format::Ply, out.join("ply/arm.ply")),
    ] {
        let written = seq.write_to(format.sink(&path, &options).as_mut())?;
        println!(
            "{format}: {} file(s), first {}",
            written.len(),
            written[0].display()
        );
    }
    // The other option set: skin only, no strain colours.
    let plain = ExportOptions {
        strain_colors: None,
        ..ExportOptions::default()
    };
    for format in [Format::Glb, Format::Usda] {
        let path = out.join(format!("arm_plain.{format}"));
        seq.write_to(format.sink(&path, &plain).as_mut())?;
        println!("{format}: {}", path.display());
    }
    Ok(())
}
