//! `dermis inspect`: meshes with roles and quality, skins, clips of a glTF model.

use std::error::Error;
use std::fmt::Write as _;
use std::path::PathBuf;

use clap::Args;
use dermis::gltf::{LoadOptions, Role, load};
use dermis::mesh::TriMesh;

use crate::pose::parse_role;

/// Arguments of `dermis inspect`.
#[derive(Args)]
pub struct InspectArgs {
    /// The .gltf or .glb model.
    model: PathBuf,
    /// Print JSON instead of text.
    #[arg(long)]
    json: bool,
    /// Role for a mesh or node name the file says nothing about: NAME=skin|muscle|bone.
    #[arg(long = "role", value_parser = parse_role)]
    roles: Vec<(String, Role)>,
}

/// Runs `dermis inspect`.
pub fn run(args: InspectArgs) -> Result<(), Box<dyn Error>> {
    let scene = load(
        &args.model,
        &LoadOptions {
            role_overrides: args.roles,
        },
    )?;
    let mut meshes = Vec::new();
    for (m, mesh) in scene.meshes.iter().enumerate() {
        let mut prims = Vec::new();
        for (p, prim) in mesh.primitives.iter().enumerate() {
            let quality = match TriMesh::new(prim.positions.clone(), prim.triangles.clone()) {
                Ok(tm) => serde_json::to_value(tm.quality())?,
                Err(e) => serde_json::json!({ "error": e.to_string() }),
            };
            prims.push(serde_json::json!({
                "primitive": p,
                "vertices": prim.positions.len(),
                "triangles": prim.triangles.len(),
                "influences_per_vertex": prim.influences.as_ref().map(|i| i.per_vertex()),
                "morph_targets": prim.targets.len(),
                "quality": quality,
            }));
        }
        meshes.push(serde_json::json!({
            "mesh": m,
            "name": mesh.name,
            "role": mesh.role,
            "role_source": mesh.role_source,
            "primitives": prims,
        }));
    }
    let skins: Vec<_> = scene
        .skins
        .iter()
        .enumerate()
        .map(|(s, skin)| serde_json::json!({ "skin": s, "joints": skin.joints.len(), "skeleton": skin.skeleton }))
        .collect();
    let clips: Vec<_> = scene
        .clips
        .iter()
        .enumerate()
        .map(|(c, clip)| {
            serde_json::json!({
                "clip": c,
                "name": clip.name,
                "duration_s": clip.duration(),
                "channels": clip.channels.len(),
            })
        })
        .collect();
    let mut out = String::new();
    if args.json {
        let report = serde_json::json!({
            "model": args.model,
            "nodes": scene.nodes.len(),
            "meshes": meshes,
            "skins": skins,
            "clips": clips,
            "capsules": scene.capsules,
            "warnings": scene.warnings,
        });
        writeln!(out, "{}", serde_json::to_string_pretty(&report)?)?;
        return crate::pose::emit(&out);
    }
    writeln!(out, "{}: {} nodes", args.model.display(), scene.nodes.len())?;
    writeln!(out, "meshes:")?;
    for (mesh, j) in scene.meshes.iter().zip(&meshes) {
        let role = mesh.role.map_or("-", |r| r.as_str());
        writeln!(out, "  {:?} role {role}", mesh.name)?;
        for p in j["primitives"].as_array().into_iter().flatten() {
            let q = &p["quality"];
            let quality = if let Some(e) = q.get("error") {
                format!("not a valid simulation mesh: {}", e.as_str().unwrap_or(""))
            } else {
                format!(
                    "edges {} boundary {} obtuse {} near-degenerate {} angles min {:.1} median {:.1} max {:.1} deg, area ratio {:.3e}",
                    q["edges"],
                    q["boundary_edges"],
                    q["obtuse_triangles"],
                    q["near_degenerate_triangles"],
                    q["min_angle_deg"].as_f64().unwrap_or(f64::NAN),
                    q["median_angle_deg"].as_f64().unwrap_or(f64::NAN),
                    q["max_angle_deg"].as_f64().unwrap_or(f64::NAN),
                    q["area_ratio"].as_f64().unwrap_or(f64::NAN),
                )
            };
            writeln!(
                out,
                "    primitive {}: {} vertices, {} triangles; {quality}",
                p["primitive"], p["vertices"], p["triangles"]
            )?;
        }
    }
    writeln!(out, "skins:")?;
    for (s, skin) in scene.skins.iter().enumerate() {
        writeln!(out, "  {s}: {} joints", skin.joints.len())?;
    }
    writeln!(out, "clips:")?;
    for (c, clip) in scene.clips.iter().enumerate() {
        writeln!(
            out,
            "  {c}: {:?} {:.3} s, {} channels",
            clip.name,
            clip.duration(),
            clip.channels.len()
        )?;
    }
    if !scene.capsules.is_empty() {
        writeln!(out, "capsules fitted along bones: {}", scene.capsules.len())?;
    }
    for w in &scene.warnings {
        writeln!(out, "warning: {w}")?;
    }
    crate::pose::emit(&out)
}
