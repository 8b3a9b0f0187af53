//! `dermis export` end to end on the bundled arm: files read back match the in-memory
//! simulation, output is byte-identical across runs and thread counts, an interrupted export
//! resumes to the same bytes, and bad input fails cleanly.

use crate::common::dermis;
use std::path::{Path, PathBuf};

use bevy_ecs::prelude::*;
use dermis::ecs::{DermisPlugin, SceneOptions, scene_skin_positions, spawn_scene};
use dermis::export::{ExportConfig, ExportJob, Format, FrameRange, checkpoint_path, run_export};
use glam::Vec3;

fn arm_path() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/arm.glb")
}

fn job(out: &Path, format: Format, frames: u32) -> ExportJob {
    let mut config = ExportConfig::default();
    config.output.checkpoint_every = 2;
    ExportJob {
        model: arm_path(),
        clip: None,
        frames: FrameRange::Count(frames),
        out: out.to_path_buf(),
        format,
        config,
        resume: false,
    }
}

/// The skin's positions of the first `frames` frames, simulated directly through the ECS with
/// the settings the export job derives from the default config.
fn simulate(frames: usize) -> Vec<Vec<Vec3>> {
    let scene = dermis::gltf::load(&arm_path(), &Default::default()).unwrap();
    let mut world = World::new();
    let mut schedule = DermisPlugin.build_schedule(&mut world);
    let spawned = spawn_scene(&mut world, &scene, &export_like_options()).unwrap();
    let skin = spawned.skins[0].entity;
    let mut out = vec![scene_skin_positions(&world, skin).unwrap()];
    for _ in 1..frames {
        schedule.run(&mut world);
        out.push(scene_skin_positions(&world, skin).unwrap());
    }
    out
}

/// The scene options `run_export` builds from `ExportConfig::default()`, written out
/// independently of the job's own mapping.
fn export_like_options() -> SceneOptions {
    use dermis::collision::ContactConfig;
    use dermis::ecs::{RelaxSettings, SkinMaterial};
    use dermis::stiffness::{Modulus, StiffnessRule};
    SceneOptions {
        clip: None,
        dt_s: 1.0 / 30.0,
        looping: false,
        material: SkinMaterial {
            youngs_2d_n_per_m: Modulus::Uniform(1000.0),
            stiffness_rule: StiffnessRule::AreaOverLengthSquared,
            poisson_ratio: 0.3,
            thickness_m: 0.002,
            ..SkinMaterial::HUMAN_SKIN
        },
        anchor_k_normal_n_per_m: 200.0,
        anchor_k_tangent_n_per_m: 20.0,
        contact: Some(ContactConfig {
            thickness_m: 0.002,
            friction: 0.0,
            ..SceneOptions::DEFAULT.contact.unwrap()
        }),
        relax: RelaxSettings {
            max_iterations: 60,
            tolerance: 1e-3,
            ..RelaxSettings::DEFAULT
        },
    }
}

#[test]
fn glb_reads_back_as_the_simulated_frames() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("arm.glb");
    let summary = run_export(&job(&out, Format::Glb, 5), |_, _| {}).unwrap();
    assert_eq!(summary.frames, 5);
    assert_eq!(summary.files, vec![out.clone()]);
    assert!(
        !checkpoint_path(&out).exists(),
        "the checkpoint is removed after success"
    );
    let expected = simulate(5);
    let (doc, buffers, _) = gltf::import(&out).unwrap();
    let mesh = doc.meshes().next().unwrap();
    let prim = mesh.primitives().next().unwrap();
    let reader = prim.reader(|b| Some(&buffers[b.index()]));
    let base: Vec<Vec3> = reader
        .read_positions()
        .unwrap()
        .map(Vec3::from_array)
        .collect();
    assert_eq!(base.len(), expected[0].len());
    assert_eq!(summary.vertices, base.len());
    let targets: Vec<Vec<Vec3>> = reader
        .read_morph_targets()
        .map(|(p, _, _)| p.unwrap().map(Vec3::from_array).collect())
        .collect();
    assert_eq!(targets.len(), 5, "one morph target per frame");
    for (k, frame) in expected.iter().enumerate() {
        for (v, want) in frame.iter().enumerate() {
            let got = base[v] + targets[k][v];
            assert!(
                (got - *want).length() <= 1e-6 * (1.0 + want.length()),
                "frame {k} vertex {v}: {got} vs {want}"
            );
        }
    }
}

#[test]
fn obj_frames_hold_the_simulated_positions_bit_for_bit() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("arm.obj");
    let summary = run_export(&job(&out, Format::Obj, 3), |_, _| {}).unwrap();
    assert_eq!(summary.files.len(), 3);
    let expected = simulate(3);
    for (k, file) in summary.files.iter().enumerate() {
        let text = std::fs::read_to_string(file).unwrap();
        let v: Vec<Vec3> = text
            .lines()
            .filter(|l| l.starts_with("v "))
            .map(|l| {
                let f: Vec<f32> = l
                    .split_whitespace()
                    .skip(1)
                    .take(3)
                    .map(|x| x.parse().unwrap())
                    .collect();
                Vec3::new(f[0], f[1], f[2])
            })
            .collect();
        assert_eq!(v, expected[k], "frame {k}");
        assert!(text.contains("o skin:"), "objects are named <role>:<name>");
    }
}

/// Same input, same bytes: two CLI runs, with 1 and 2 threads.
#[test]
fn exports_are_byte_identical_across_runs_and_thread_counts() {
    let dir = tempfile::tempdir().unwrap();
    let mut bytes = Vec::new();
    for threads in ["1", "2"] {
        let out = dir.path().join(format!("arm{threads}.usda"));
        let status = dermis()
            .env("RAYON_NUM_THREADS", threads)
            .arg("export")
            .arg(arm_path())
            .args(["--frames", "4", "--out"])
            .arg(&out)
            .status()
            .unwrap();
        assert!(status.success());
        bytes.push(std::fs::read(&out).unwrap());
    }
    assert!(bytes[0] == bytes[1], "1 and 2 threads gave different files");
}

/// An export interrupted after a checkpoint (here: the progress callback panics, as a kill
/// would stop it) resumes to exactly the bytes of an uninterrupted run.
#[test]
fn resume_after_interruption_gives_identical_bytes() {
    let dir = tempfile::tempdir().unwrap();
    let full = dir.path().join("full.glb");
    run_export(&job(&full, Format::Glb, 7), |_, _| {}).unwrap();

    let cut = dir.path().join("cut.glb");
    let interrupted = std::panic::catch_unwind(|| {
        run_export(&job(&cut, Format::Glb, 7), |done, _| {
            if done == 5 {
                panic!("killed");
            }
        })
    });
    assert!(interrupted.is_err());
    assert!(
        !cut.exists(),
        "a single-file format writes nothing until the end"
    );
    assert!(
        checkpoint_path(&cut).exists(),
        "a checkpoint was left at frame 4"
    );
    let mut again = job(&cut, Format::Glb, 7);
    again.resume = true;
    let summary = run_export(&again, |_, _| {}).unwrap();
    assert_eq!(summary.resumed_from_frame, 4);
    assert_eq!(std::fs::read(&cut).unwrap(), std::fs::read(&full).unwrap());
    assert!(!checkpoint_path(&cut).exists());
}

/// The real thing: kill the process once a checkpoint exists, then `--resume`.
#[test]
fn resume_after_kill_gives_identical_bytes() {
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("dermis.toml");
    std::fs::write(
        &config,
        "[output]\nformat = \"ply\"\ncheckpoint_every = 1\n",
    )
    .unwrap();
    let run = |out: &Path, resume: bool| {
        let mut c = dermis();
        c.arg("export")
            .arg(arm_path())
            .args(["--frames", "12", "--config"])
            .arg(&config)
            .arg("--out")
            .arg(out);
        if resume {
            c.arg("--resume");
        }
        c
    };
    let full = dir.path().join("full/arm.ply");
    assert!(run(&full, false).status().unwrap().success());

    let cut = dir.path().join("cut/arm.ply");
    let mut child = run(&cut, false).spawn().unwrap();
    let ck = checkpoint_path(&cut);
    let start = std::time::Instant::now();
    while !ck.exists() && start.elapsed().as_secs() < 60 {
        if child.try_wait().unwrap().is_some() {
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(2));
    }
    let _ = child.kill();
    let _ = child.wait();
    assert!(run(&cut, true).status().unwrap().success());
    let list = |d: &Path| {
        let mut v: Vec<String> = std::fs::read_dir(d)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    };
    let names = list(full.parent().unwrap());
    assert_eq!(names.len(), 12);
    assert_eq!(
        names,
        list(cut.parent().unwrap()),
        "no temporary or extra files"
    );
    for name in names {
        let a = std::fs::read(full.parent().unwrap().join(&name)).unwrap();
        let b = std::fs::read(cut.parent().unwrap().join(&name)).unwrap();
        assert!(a == b, "{name} differs after resume");
    }
}

#[test]
fn bad_input_fails_with_a_clear_error_and_no_files() {
    let dir = tempfile::tempdir().unwrap();
    // Unknown clip.
    let out = dir.path().join("a/arm.glb");
    let o = dermis()
        .arg("export")
        .arg(arm_path())
        .args(["--clip", "wave", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(1));
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("wave"),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(!out.exists());
    // Output directory that cannot exist (a file is in the way).
    let blocker = dir.path().join("file");
    std::fs::write(&blocker, b"x").unwrap();
    let o = dermis()
        .arg("export")
        .arg(arm_path())
        .arg("--out")
        .arg(blocker.join("arm.glb"))
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("cannot write into directory"));
    // A model with no skin: the arm without its skin role and with its skin renamed.
    let scene_dir = dir.path().join("noskin");
    std::fs::create_dir_all(&scene_dir).unwrap();
    let model = scene_dir.join("bones.glb");
    std::fs::write(&model, strip_skin(&dermis::gltf::arm::build_arm_glb())).unwrap();
    let out = scene_dir.join("out.glb");
    let o = dermis()
        .arg("export")
        .arg(&model)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert_eq!(
        o.status.code(),
        Some(1),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("skin"),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(!out.exists());
    assert_eq!(
        std::fs::read_dir(&scene_dir).unwrap().count(),
        1,
        "only the model is left"
    );
    // Missing model file.
    let o = dermis()
        .arg("export")
        .arg(dir.path().join("nope.glb"))
        .arg("--out")
        .arg(dir.path().join("x.glb"))
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(1));
}

/// The arm's GLB with every skin role removed: the skin mesh becomes a bone.
fn strip_skin(glb: &[u8]) -> Vec<u8> {
    let json_len = u32::from_le_bytes(glb[12..16].try_into().unwrap()) as usize;
    let json = std::str::from_utf8(&glb[20..20 + json_len]).unwrap();
    let mut patched = json.replace("\"skin\"}", "\"bone\"}");
    assert_ne!(patched, json, "the arm marks its skin in extras");
    while !patched.len().is_multiple_of(4) {
        patched.push(' ');
    }
    let rest = &glb[20 + json_len..];
    let mut out = Vec::new();
    out.extend_from_slice(&glb[0..8]);
    out.extend_from_slice(&((12 + 8 + patched.len() + rest.len()) as u32).to_le_bytes());
    out.extend_from_slice(&(patched.len() as u32).to_le_bytes());
    out.extend_from_slice(&glb[16..20]);
    out.extend_from_slice(patched.as_bytes());
    out.extend_from_slice(rest);
    out
}
