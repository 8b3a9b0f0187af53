//! Bad output locations and bad frames: typed errors, no partial files.

use dermis::export::{ExportError, ExportOptions, Format};
use glam::Vec3;

use super::*;

#[test]
fn missing_directory_fails_before_writing_anything() {
    let seq = clip();
    let root = tempfile::tempdir().unwrap();
    let missing = root.path().join("no/such/dir");
    for format in Format::ALL {
        let out = missing.join(format!("clip.{format}"));
        let err = seq
            .write_to(format.sink(&out, &ExportOptions::default()).as_mut())
            .unwrap_err();
        match &err {
            ExportError::UnwritableDirectory { path, .. } => assert_eq!(path, &missing),
            other => panic!("{format}: expected UnwritableDirectory, got {other:?}"),
        }
        assert!(err.to_string().contains("no/such/dir"), "{err}");
    }
    assert!(listing(root.path()).is_empty());
}

#[test]
fn a_file_in_place_of_the_directory_is_unwritable() {
    let seq = clip();
    let root = tempfile::tempdir().unwrap();
    let file = root.path().join("plain");
    std::fs::write(&file, b"x").unwrap();
    let err = seq
        .write_to(
            Format::Glb
                .sink(&file.join("clip.glb"), &ExportOptions::default())
                .as_mut(),
        )
        .unwrap_err();
    assert!(matches!(err, ExportError::UnwritableDirectory { path, .. } if path == file));
    assert_eq!(listing(root.path()), vec![file]);
}

#[test]
fn read_only_directory_is_unwritable() {
    use std::os::unix::fs::PermissionsExt;
    let seq = clip();
    let root = tempfile::tempdir().unwrap();
    let ro = root.path().join("ro");
    std::fs::create_dir(&ro).unwrap();
    std::fs::set_permissions(&ro, std::fs::Permissions::from_mode(0o555)).unwrap();
    if std::fs::write(ro.join("probe"), b"").is_ok() {
        // root ignores directory permissions.
        std::fs::remove_file(ro.join("probe")).unwrap();
        eprintln!("skipped: running as a user that can write into read-only directories (root)");
        return;
    }
    for format in Format::ALL {
        let err = seq
            .write_to(
                format
                    .sink(&ro.join(format!("c.{format}")), &ExportOptions::default())
                    .as_mut(),
            )
            .unwrap_err();
        assert!(
            matches!(err, ExportError::UnwritableDirectory { ref path, .. } if *path == ro),
            "{err:?}"
        );
    }
    assert!(listing(&ro).is_empty());
    std::fs::set_permissions(&ro, std::fs::Permissions::from_mode(0o755)).unwrap();
}

/// The clip with frame `FIRST + 2` broken by a NaN at skin vertex 5.
fn blows_up_at_frame_2() -> FrameSequence {
    let mut seq = clip();
    seq.frames[2].positions[0][5] = Vec3::new(0.0, f32::NAN, 0.0);
    seq
}

#[test]
fn a_sequence_keeps_only_the_complete_frames_before_a_failure() {
    let seq = blows_up_at_frame_2();
    for format in [Format::Obj, Format::Ply] {
        let dir = tempfile::tempdir().unwrap();
        let err = seq
            .write_to(
                format
                    .sink(
                        &dir.path().join(format!("c.{format}")),
                        &ExportOptions::default(),
                    )
                    .as_mut(),
            )
            .unwrap_err();
        match &err {
            ExportError::NonFinite {
                frame,
                mesh,
                vertex,
                ..
            } => {
                assert_eq!(
                    (*frame, mesh.as_str(), *vertex),
                    (Some(FIRST + 2), "sheet", 5)
                );
            }
            other => panic!("expected NonFinite, got {other:?}"),
        }
        let names: Vec<String> = listing(dir.path())
            .iter()
            .map(|p| p.file_name().unwrap().to_string_lossy().into_owned())
            .collect();
        let want: Vec<String> = [FIRST, FIRST + 1]
            .iter()
            .map(|f| format!("c_{f:06}.{format}"))
            .collect();
        assert_eq!(
            names, want,
            "{format}: only the complete frames, no temporary file"
        );
    }
}

#[test]
fn a_single_file_export_that_fails_writes_nothing() {
    let seq = blows_up_at_frame_2();
    for format in [Format::Glb, Format::Usda] {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join(format!("c.{format}"));
        // An older complete export of the same name must survive the failed one untouched.
        std::fs::write(&out, b"previous").unwrap();
        let err = seq
            .write_to(format.sink(&out, &ExportOptions::default()).as_mut())
            .unwrap_err();
        assert!(matches!(err, ExportError::NonFinite { .. }), "{err:?}");
        assert_eq!(listing(dir.path()), vec![out.clone()]);
        assert_eq!(std::fs::read(&out).unwrap(), b"previous");
    }
}

#[test]
fn inconsistent_vertex_counts_name_the_mesh_and_frame() {
    let mut seq = clip();
    seq.frames[1].positions[0].pop();
    let dir = tempfile::tempdir().unwrap();
    let err = seq
        .write_to(
            Format::Usda
                .sink(&dir.path().join("c.usda"), &ExportOptions::default())
                .as_mut(),
        )
        .unwrap_err();
    assert!(matches!(
        &err,
        ExportError::VertexCount { frame, mesh, expected: 30, found: 29 } if *frame == FIRST + 1 && mesh == "sheet"
    ));
    assert!(err.to_string().contains("sheet"));
    assert!(listing(dir.path()).is_empty());
}

#[test]
fn finishing_without_frames_is_an_error_for_single_file_formats() {
    let mut seq = clip();
    seq.frames.clear();
    let dir = tempfile::tempdir().unwrap();
    for format in [Format::Glb, Format::Usda] {
        let out = dir.path().join(format!("c.{format}"));
        let err = seq
            .write_to(format.sink(&out, &ExportOptions::default()).as_mut())
            .unwrap_err();
        assert!(matches!(err, ExportError::NoFrames { path } if path == out));
    }
    assert!(listing(dir.path()).is_empty());
}
