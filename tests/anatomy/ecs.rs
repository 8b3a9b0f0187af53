//! Muscles and bones in a `World` + `Schedule`: the jaw opens, the muscle surface is the skin's
//! collider, the skin stays outside it, the volume holds, contact pushes bones back, and the
//! `dermis anatomy jaw` export is deterministic and reads back.

use crate::common::dermis;

use bevy_ecs::prelude::*;
use dermis::anatomy::dynamics::{AnatomySystem, DynamicsConfig};
use dermis::anatomy::export::{JawExportJob, run_jaw_export};
use dermis::anatomy::rigid::BoneDesc;
use dermis::anatomy::scenes::{JawConfig, JawScene, box_mesh};
use dermis::ecs::*;
use dermis::export::Format;
use glam::{Vec2, Vec3};

use parry3d::query::PointQuery;

/// Closed-form signed volume of a closed triangle mesh (divergence theorem).
fn enclosed_volume(x: &[Vec3], triangles: &[[u32; 3]]) -> f64 {
    triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| x[i as usize].as_dvec3());
            a.dot(b.cross(c)) / 6.0
        })
        .sum()
}

/// The jaw's opening angle measured from where its pose puts two rest points: the hinge and a
/// point on the chin, in the hinge's (y, z) plane.
fn chin_angle_deg(pose: &BonePose) -> f32 {
    let (hinge, chin) = (Vec3::ZERO, Vec3::new(0.0, -0.012, 0.09));
    let rest = chin - hinge;
    let now = pose.transform_point(chin) - pose.transform_point(hinge);
    let (r, n) = (Vec2::new(rest.z, rest.y), Vec2::new(now.z, now.y));
    // Opening turns the chin down: clockwise in (z, y).
    -(r.perp_dot(n)).atan2(r.dot(n)).to_degrees()
}

fn world() -> (World, Schedule) {
    let mut world = World::new();
    let schedule = DermisPlugin.build_schedule(&mut world);
    (world, schedule)
}

#[test]
fn raising_a_muscle_entity_activation_opens_the_jaw_monotonically() {
    let (mut world, mut schedule) = world();
    let jaw = spawn_jaw(&mut world, &JawConfig::default(), 40, None).unwrap();
    let mut angles = Vec::new();
    for step in 0..=10 {
        world.get_mut::<MuscleActivation>(jaw.muscle).unwrap().0 = step as f32 / 10.0;
        for _ in 0..8 {
            schedule.run(&mut world);
        }
        let d = world.get::<AnatomyDiagnostics>(jaw.anatomy.rig).unwrap();
        assert_eq!(d.error, None);
        angles.push(chin_angle_deg(world.get::<BonePose>(jaw.jaw).unwrap()));
    }
    assert!(angles[0].abs() < 0.05, "closed at rest: {angles:?}");
    for w in angles.windows(2) {
        assert!(w[1] > w[0], "opens monotonically: {angles:?}");
    }
    assert!(angles[10] > 10.0, "opens visibly: {angles:?}");
    // The skull and spine are kinematic and undriven: they do not move.
    for bone in [jaw.skull, jaw.spine] {
        let p = world.get::<BonePose>(bone).unwrap();
        assert_eq!(p.translation, Vec3::ZERO);
    }
    // The steps ran: 88 frames of 40 steps each.
    let d = world.get::<AnatomyDiagnostics>(jaw.anatomy.rig).unwrap();
    assert_eq!((d.frames, d.steps), (88, 88 * 40));
}

#[test]
fn muscle_collider_tracks_the_lattice_and_the_skin_stays_outside() {
    let (mut world, mut schedule) = world();
    let skin_config = JawSkinConfig::default();
    let thickness = skin_config.contact.thickness_m;
    let jaw = spawn_jaw(&mut world, &JawConfig::default(), 40, Some(&skin_config)).unwrap();
    let skin = jaw.skin.unwrap();
    let muscle_index = world.get::<AnatomyMuscle>(jaw.muscle).unwrap().index;
    let frames = 24;
    let mut touching_at_end = 0;
    for frame in 0..frames {
        world.get_mut::<MuscleActivation>(jaw.muscle).unwrap().0 =
            frame as f32 / (frames - 1) as f32;
        schedule.run(&mut world);
        let rig = world.get::<AnatomyRig>(jaw.anatomy.rig).unwrap();
        let surface = rig.system().muscle(muscle_index).unwrap().surface().clone();
        let lattice: Vec<Vec3> = surface
            .particles
            .iter()
            .map(|&p| rig.system().positions()[p as usize])
            .collect();
        // The collider the skin touches holds exactly the lattice's surface positions.
        let contact = world.get::<SkinContact>(skin).unwrap();
        let (_, id) = contact
            .colliders
            .iter()
            .find(|(e, _)| *e == jaw.muscle)
            .copied()
            .unwrap();
        let collider = contact.collision.collider(id).unwrap();
        assert_eq!(collider.parry_mesh().unwrap().vertices(), &lattice[..]);
        // The jaw's collider is moved rigidly to the jaw's pose.
        let (_, jaw_id) = contact
            .colliders
            .iter()
            .find(|(e, _)| *e == jaw.jaw)
            .copied()
            .unwrap();
        let pose = world.get::<BonePose>(jaw.jaw).unwrap();
        let jaw_collider = contact.collision.collider(jaw_id).unwrap();
        assert_eq!(jaw_collider.pose().rotation, pose.rotation);
        assert_eq!(jaw_collider.pose().translation, pose.translation);
        // parry's own inside test on a mesh built from the lattice surface.
        let shape = parry3d::shape::TriMesh::with_flags(
            lattice.clone(),
            surface.triangles.clone(),
            parry3d::shape::TriMeshFlags::ORIENTED,
        )
        .unwrap();
        let x = world.get::<SkinPositions>(skin).unwrap();
        touching_at_end = 0;
        for (v, &p) in x.iter().enumerate() {
            let proj = shape.project_local_point(p, false);
            assert!(
                !proj.is_inside,
                "frame {frame}: skin vertex {v} inside the muscle"
            );
            let d = (proj.point - p).length();
            assert!(
                d > 0.5 * thickness,
                "frame {frame}: skin vertex {v} only {d} m from the muscle"
            );
            if d < 1.1 * thickness {
                touching_at_end += 1;
            }
        }
    }
    // Not vacuous: the bulging muscle carries the skin.
    assert!(
        touching_at_end > 20,
        "{touching_at_end} skin vertices touch"
    );
}

#[test]
fn muscle_volume_holds_within_5_percent_through_the_ecs() {
    let (mut world, mut schedule) = world();
    let jaw = spawn_jaw(&mut world, &JawConfig::default(), 40, None).unwrap();
    let rest = {
        let c = world.get::<ColliderState>(jaw.muscle).unwrap();
        enclosed_volume(&c.local_vertices, &c.triangles)
    };
    let mut shortest = 1.0f32;
    for frame in 0..30 {
        world.get_mut::<MuscleActivation>(jaw.muscle).unwrap().0 = (frame as f32 / 20.0).min(1.0);
        schedule.run(&mut world);
        let c = world.get::<ColliderState>(jaw.muscle).unwrap();
        let v = enclosed_volume(&c.local_vertices, &c.triangles);
        assert!(
            (v / rest - 1.0).abs() < 0.05,
            "frame {frame}: volume x{}",
            v / rest
        );
        let state = world.get::<MuscleState>(jaw.muscle).unwrap();
        assert!(
            // Cells and surface split the non-planar side quads differently.
            (f64::from(state.volume_m3) / v - 1.0).abs() < 1e-2,
            "frame {frame}: cells {} m3, surface {v} m3",
            state.volume_m3
        );
        shortest = shortest.min(state.length_m / state.rest_length_m);
    }
    assert!(shortest < 0.85, "the muscle contracted: length x{shortest}");
}

#[test]
fn a_bad_activation_is_reported_not_applied() {
    let (mut world, mut schedule) = world();
    let jaw = spawn_jaw(&mut world, &JawConfig::default(), 2, None).unwrap();
    world.get_mut::<MuscleActivation>(jaw.muscle).unwrap().0 = 1.5;
    schedule.run(&mut world);
    let d = world.get::<AnatomyDiagnostics>(jaw.anatomy.rig).unwrap();
    assert!(matches!(
        d.error,
        Some(dermis::anatomy::AnatomyError::ActivationOutOfRange { .. })
    ));
    let rig = world.get::<AnatomyRig>(jaw.anatomy.rig).unwrap();
    assert_eq!(rig.system().muscle(0).unwrap().activation(), 0.0);
}

/// A muscle thrown at a free box: contact stops the muscle and the box takes its momentum, so
/// the total momentum of muscle and bone is conserved (no drag, no gravity).
#[test]
fn bones_feel_the_reaction_of_muscle_contact() {
    let surface =
        dermis::anatomy::scenes::tube_mesh(Vec3::ZERO, Vec3::new(0.0, 0.0, 0.1), 0.01, 16, 6)
            .unwrap();
    let line = [Vec3::new(0.0, 0.0, 0.001), Vec3::new(0.0, 0.0, 0.099)];
    let lattice = dermis::anatomy::lattice::MuscleLattice::build(
        &surface,
        &line,
        dermis::anatomy::lattice::MuscleConfig {
            sections: 6,
            cell_area_m2: 2e-5,
            ..Default::default()
        },
    )
    .unwrap();
    let mut sys = AnatomySystem::new(DynamicsConfig {
        dt_s: 1e-3,
        substeps: 10,
        drag: 0.0,
        gravity: Vec3::ZERO,
    })
    .unwrap();
    let m = sys.add_muscle(&lattice).unwrap();
    let slab = sys
        .add_bone(&BoneDesc::new(
            box_mesh(
                Vec3::new(0.015, -0.03, 0.02),
                Vec3::new(0.03, 0.03, 0.08),
                2,
            )
            .unwrap(),
            0.002,
        ))
        .unwrap();
    sys.add_bone_contact(m, slab).unwrap();
    let particles = sys.muscle(m).unwrap().particles();
    for p in particles.clone() {
        sys.set_velocity(p, Vec3::new(1.0, 0.0, 0.0)).unwrap();
    }
    let momentum = |s: &AnatomySystem| -> Vec3 {
        let muscle: Vec3 = particles
            .clone()
            .map(|p| s.masses()[p] * s.velocities()[p])
            .sum();
        let b = s.body(slab).unwrap();
        muscle + b.mass_kg() * b.velocity()
    };
    let p0 = momentum(&sys);
    for _ in 0..30 {
        sys.step().unwrap();
    }
    let p1 = momentum(&sys);
    let bone_v = sys.body(slab).unwrap().velocity();
    assert!(bone_v.x > 0.05, "the bone was pushed: {bone_v}");
    assert!(
        (p1 - p0).length() < 1e-3 * p0.length(),
        "momentum {p0} -> {p1}"
    );
}

/// Same input, same bytes: three CLI runs, with 1, 2 and 2 threads.
#[test]
fn export_bytes_are_identical_across_runs_and_thread_counts() {
    let dir = tempfile::tempdir().unwrap();
    let mut bytes = Vec::new();
    for (k, threads) in ["1", "2", "2"].into_iter().enumerate() {
        let out = dir.path().join(format!("jaw{k}.usda"));
        crate::common::run_ok(
            dermis()
                .env("RAYON_NUM_THREADS", threads)
                .args(["anatomy", "jaw", "--frames", "4", "--steps-per-frame", "10"])
                .arg("--out")
                .arg(&out),
        );
        bytes.push(std::fs::read(&out).unwrap());
    }
    assert!(bytes[0] == bytes[1], "1 and 2 threads gave different files");
    assert!(bytes[1] == bytes[2], "two runs gave different files");
}

/// The library entry point agrees with the file: the last frame's jaw angle is the summary's.
#[test]
fn the_export_summary_reports_every_frame() {
    let dir = tempfile::tempdir().unwrap();
    let job = JawExportJob {
        frames: 3,
        steps_per_frame: 5,
        skin: None,
        ..JawExportJob::new(dir.path().join("jaw.ply"), Format::Ply)
    };
    let summary = run_jaw_export(&job).unwrap();
    assert_eq!(summary.files.len(), 3, "one ply per frame");
    assert_eq!(summary.jaw_angle_deg.len(), 3);
    assert_eq!(summary.skin_vertices, 0);
    assert_eq!(summary.activation, [0.0, 0.5, 1.0]);
    let zero_frames = JawExportJob {
        frames: 0,
        ..job.clone()
    };
    assert!(matches!(
        run_jaw_export(&zero_frames),
        Err(dermis::anatomy::export::JawExportError::InvalidJob { name: "frames", .. })
    ));
}

#[test]
fn the_cli_writes_glb_and_obj_that_read_back() {
    let dir = tempfile::tempdir().unwrap();
    let glb = dir.path().join("jaw.glb");
    let out = crate::common::run_ok(
        dermis()
            .args(["anatomy", "jaw", "--frames", "3", "--steps-per-frame", "5"])
            .arg("--out")
            .arg(&glb)
            .arg("--json"),
    );
    let summary: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(summary["frames"], 3);
    assert_eq!(summary["jaw_angle_deg"].as_array().unwrap().len(), 3);
    assert_eq!(summary["activation"][2], 1.0);

    let (doc, buffers, _) = gltf::import(&glb).unwrap();
    let names: Vec<_> = doc.nodes().map(|n| n.name().unwrap().to_owned()).collect();
    assert_eq!(
        names,
        [
            "skin:sleeve",
            "muscle:platysma",
            "bone:skull",
            "bone:jaw",
            "bone:spine"
        ]
    );
    let skin = JawSkinConfig::default();
    // A box of s × s squares per face: the (s + 1)³ grid points minus the (s - 1)³ inside.
    let box_vertices = |s: u32| (s + 1).pow(3) - (s - 1).pow(3);
    let want_vertices = [
        ((skin.rings + 1) * skin.segments) as usize,
        summary["muscle_vertices"].as_u64().unwrap() as usize,
        box_vertices(2) as usize,
        box_vertices(4) as usize,
        box_vertices(2) as usize,
    ];
    for (node, want) in doc.nodes().zip(want_vertices) {
        let prim = node.mesh().unwrap().primitives().next().unwrap();
        let reader = prim.reader(|b| Some(&buffers[b.index()]));
        assert_eq!(reader.read_positions().unwrap().count(), want);
        assert_eq!(
            reader.read_morph_targets().count(),
            3,
            "one target per frame"
        );
    }

    let obj = dir.path().join("seq").join("jaw.obj");
    crate::common::run_ok(
        dermis()
            .args(["anatomy", "jaw", "--frames", "2", "--steps-per-frame", "5"])
            .arg("--out")
            .arg(&obj),
    );
    let mut files: Vec<_> = std::fs::read_dir(dir.path().join("seq"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    files.sort();
    assert_eq!(files.len(), 2, "{files:?}");
    let (models, _) = tobj::load_obj(&files[1], &tobj::LoadOptions::default()).unwrap();
    assert_eq!(models.len(), 5);
    assert_eq!(
        models[0].mesh.positions.len() / 3,
        want_vertices[0],
        "skin sleeve"
    );
}

#[test]
fn bad_cli_arguments_exit_1_and_write_nothing() {
    let dir = tempfile::tempdir().unwrap();
    for (args, out) in [
        (vec!["--frames", "0"], "a/jaw.usda"),
        (vec!["--format", "fbx"], "b/jaw.usda"),
        (vec!["--fps=-3"], "c/jaw.glb"),
        (vec!["--steps-per-frame", "0"], "d/jaw.ply"),
        (vec!["--frames", "many"], "e/jaw.usda"),
    ] {
        let path = dir.path().join(out);
        let status = dermis()
            .args(["anatomy", "jaw"])
            .args(&args)
            .arg("--out")
            .arg(&path)
            .output()
            .unwrap();
        // Values clap cannot parse are usage errors (clap's exit code 2); values it parses
        // but the job rejects exit 1.
        let want = if args.get(1) == Some(&"many") { 2 } else { 1 };
        assert_eq!(status.status.code(), Some(want), "{args:?}");
        assert!(!path.exists(), "{args:?} left {}", path.display());
        assert!(
            !path.parent().unwrap().exists(),
            "{args:?} created the directory"
        );
    }
}

/// Used by the opening test: the jaw scene's own angle agrees with the chin measurement.
#[test]
fn bone_pose_angle_matches_the_chin_measurement() {
    let (mut world, mut schedule) = world();
    let jaw = spawn_jaw(&mut world, &JawConfig::default(), 40, None).unwrap();
    world.get_mut::<MuscleActivation>(jaw.muscle).unwrap().0 = 1.0;
    for _ in 0..20 {
        schedule.run(&mut world);
    }
    let pose = world.get::<BonePose>(jaw.jaw).unwrap();
    let a = pose.angle_about(JawScene::HINGE_AXIS).to_degrees();
    assert!(a > 1.0);
    assert!(
        (a - chin_angle_deg(pose)).abs() < 0.5,
        "{a} vs {}",
        chin_angle_deg(pose)
    );
}

/// A kinematic bone driven by a `BoneTarget` arrives at the target with the frame's last step,
/// whatever the steps per frame; a target on a dynamic bone is an error.
#[test]
fn a_kinematic_bone_target_is_reached_at_the_end_of_the_frame() {
    let target = BonePose {
        rotation: glam::Quat::from_rotation_y(0.1),
        translation: Vec3::new(0.0, -0.004, 0.002),
    };
    let spine_after = |steps: u32, frames: usize| {
        let (mut world, mut schedule) = world();
        let jaw = spawn_jaw(&mut world, &JawConfig::default(), steps, None).unwrap();
        world.entity_mut(jaw.spine).insert(BoneTarget(target));
        for _ in 0..frames {
            schedule.run(&mut world);
        }
        assert_eq!(
            world
                .get::<AnatomyDiagnostics>(jaw.anatomy.rig)
                .unwrap()
                .error,
            None
        );
        *world.get::<BonePose>(jaw.spine).unwrap()
    };
    let end = spine_after(6, 1);
    assert!((end.translation - target.translation).length() < 1e-6);
    assert!(end.rotation.angle_between(target.rotation) < 1e-4);
    // Twice the steps per frame, two frames: same arrival, and it stays there.
    let end2 = spine_after(12, 2);
    assert!((end2.translation - target.translation).length() < 1e-6);
    // A target on the dynamic jaw is rejected, not applied.
    let (mut world, mut schedule) = world();
    let jaw = spawn_jaw(&mut world, &JawConfig::default(), 2, None).unwrap();
    world.entity_mut(jaw.jaw).insert(BoneTarget(target));
    schedule.run(&mut world);
    assert!(matches!(
        world
            .get::<AnatomyDiagnostics>(jaw.anatomy.rig)
            .unwrap()
            .error,
        Some(dermis::anatomy::AnatomyError::NotKinematic { .. })
    ));
}
