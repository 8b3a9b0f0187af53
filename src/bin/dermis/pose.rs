//! `dermis pose`: write every mesh primitive of a glTF model posed at a time, in world space.

use std::error::Error;
use std::io::Write;
use std::path::{Path, PathBuf};

use clap::Args;
use dermis::gltf::{LoadOptions, Role, Scene, load};

/// Arguments of `dermis pose`.
#[derive(Args)]
pub struct PoseArgs {
    /// The .gltf or .glb model.
    model: PathBuf,
    /// Animation to sample, by name or index (default: the first, if any).
    #[arg(long)]
    clip: Option<String>,
    /// Time to sample, seconds.
    #[arg(long, default_value_t = 0.0)]
    time: f32,
    /// Output file, .obj (one object per primitive) or .ply.
    #[arg(long)]
    out: PathBuf,
    /// Print a JSON summary on stdout.
    #[arg(long)]
    json: bool,
    /// Role for a mesh or node name the file says nothing about: NAME=skin|muscle|bone.
    #[arg(long = "role", value_parser = parse_role)]
    roles: Vec<(String, Role)>,
}

/// Parses `NAME=ROLE`.
pub fn parse_role(s: &str) -> Result<(String, Role), String> {
    let (name, role) = s
        .rsplit_once('=')
        .ok_or_else(|| format!("expected NAME=ROLE, got {s:?}"))?;
    let role =
        Role::parse(role).ok_or_else(|| format!("unknown role {role:?} (skin, muscle, bone)"))?;
    Ok((name.to_string(), role))
}

/// Writes `bytes` to `path` through a temporary file in the same directory and a rename.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let tmp = dir.join(format!(".{name}.tmp-{}", std::process::id()));
    let result = std::fs::File::create(&tmp).and_then(|mut f| {
        f.write_all(bytes)?;
        f.sync_all()
    });
    match result.and_then(|()| std::fs::rename(&tmp, path)) {
        Ok(()) => Ok(()),
        Err(e) => {
            let _ = std::fs::remove_file(&tmp);
            Err(e)
        }
    }
}

/// Prints `text` on stdout; a closed pipe (`dermis ... | head`) is not an error.
pub fn emit(text: &str) -> Result<(), Box<dyn Error>> {
    match std::io::stdout().lock().write_all(text.as_bytes()) {
        Err(e) if e.kind() != std::io::ErrorKind::BrokenPipe => Err(e.into()),
        _ => Ok(()),
    }
}

/// Runs `dermis pose`.
pub fn run(args: PoseArgs) -> Result<(), Box<dyn Error>> {
    let options = LoadOptions {
        role_overrides: args.roles.clone(),
    };
    let ext = args
        .out
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    if ext != "obj" && ext != "ply" {
        return Err(format!(
            "--out {}: extension must be .obj or .ply",
            args.out.display()
        )
        .into());
    }
    let scene: Scene = load(&args.model, &options)?;
    let clip = match &args.clip {
        Some(c) => Some(scene.find_clip(c)?),
        None => (!scene.clips.is_empty()).then_some(0),
    };
    if !args.time.is_finite() {
        return Err(format!("--time must be finite, got {}", args.time).into());
    }
    let posed = scene.pose(clip, args.time);
    let mut bytes = Vec::new();
    match ext.as_str() {
        "obj" => posed.write_obj(&mut bytes)?,
        "ply" => posed.write_ply(&mut bytes)?,
        _ => {
            return Err(format!(
                "--out {}: extension must be .obj or .ply",
                args.out.display()
            )
            .into());
        }
    }
    write_atomic(&args.out, &bytes)
        .map_err(|e| format!("cannot write {}: {e}", args.out.display()))?;
    let objects: Vec<_> = posed
        .primitives
        .iter()
        .map(|p| {
            serde_json::json!({
                "name": p.name,
                "node": p.node,
                "mesh": p.mesh,
                "primitive": p.primitive,
                "vertices": p.positions.len(),
                "triangles": p.triangles.len(),
            })
        })
        .collect();
    if args.json {
        let report = serde_json::json!({
            "model": args.model,
            "clip": clip.map(|c| scene.clips[c].name.clone()),
            "clip_index": clip,
            "time_s": args.time,
            "out": args.out,
            "objects": objects,
            "warnings": scene.warnings,
        });
        emit(&format!("{}\n", serde_json::to_string_pretty(&report)?))?;
    } else {
        for w in &scene.warnings {
            eprintln!("warning: {w}");
        }
        emit(&format!(
            "wrote {} objects ({} vertices) to {}\n",
            posed.primitives.len(),
            posed
                .primitives
                .iter()
                .map(|p| p.positions.len())
                .sum::<usize>(),
            args.out.display()
        ))?;
    }
    Ok(())
}
