//! Each format read back and compared with the input frames.

use std::path::Path;

use dermis::export::{ExportOptions, Format, StrainColorMap};
use glam::Vec3;

use super::*;

fn colliders() -> ExportOptions {
    ExportOptions {
        with_colliders: true,
        ..ExportOptions::default()
    }
}

#[test]
fn glb_morph_targets_reproduce_every_frame() {
    let seq = clip();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("clip.glb");
    let written = seq
        .write_to(Format::Glb.sink(&path, &colliders()).as_mut())
        .unwrap();
    assert_eq!(written, vec![path.clone()]);

    let (doc, buffers, _) = gltf::import(&path).unwrap();
    let names: Vec<_> = doc.nodes().map(|n| n.name().unwrap().to_owned()).collect();
    assert_eq!(names, ["skin:sheet", "bone:ulna"]);
    for (m, node) in doc.nodes().enumerate() {
        let meta = &seq.meta.meshes[m];
        let prim = node.mesh().unwrap().primitives().next().unwrap();
        let reader = prim.reader(|b| Some(&buffers[b.index()]));
        let base: Vec<Vec3> = reader.read_positions().unwrap().map(Vec3::from).collect();
        assert_eq!(base, meta.rest_positions, "base is the rest pose");
        let indices: Vec<u32> = reader.read_indices().unwrap().into_u32().collect();
        let expected: Vec<u32> = meta.triangles.iter().flatten().copied().collect();
        assert_eq!(indices, expected);
        let targets: Vec<_> = reader.read_morph_targets().collect();
        assert_eq!(targets.len(), FRAMES as usize, "one morph target per frame");
        for (k, (dp, dn, _)) in targets.into_iter().enumerate() {
            let want = &seq.frames[k].positions[m];
            let got: Vec<Vec3> = dp
                .unwrap()
                .zip(&base)
                .map(|(d, b)| *b + Vec3::from(d))
                .collect();
            assert_eq!(got.len(), want.len());
            for (v, (g, w)) in got.iter().zip(want).enumerate() {
                assert_reconstructed(*g, *w, base[v], &format!("mesh {m} frame {k} vertex {v}"));
            }
            if m == 0 && (k as u32) < FLAT {
                let base_n: Vec<Vec3> = reader.read_normals().unwrap().map(Vec3::from).collect();
                for (n, b) in dn.unwrap().zip(base_n) {
                    assert!((b + Vec3::from(n) - Vec3::Z).length() < 1e-6);
                }
            }
        }
    }

    // One STEP channel per node, keyed at frame / fps, one-hot on that frame's target.
    let anim = doc.animations().next().unwrap();
    let channels: Vec<_> = anim.channels().collect();
    assert_eq!(channels.len(), 2);
    for ch in channels {
        assert_eq!(
            ch.target().property(),
            gltf::animation::Property::MorphTargetWeights
        );
        assert_eq!(
            ch.sampler().interpolation(),
            gltf::animation::Interpolation::Step
        );
        let r = ch.reader(|b| Some(&buffers[b.index()]));
        let times: Vec<f32> = r.read_inputs().unwrap().collect();
        let want: Vec<f32> = (0..FRAMES).map(|k| (FIRST + k) as f32 / FPS).collect();
        for (t, w) in times.iter().zip(&want) {
            assert!((t - w).abs() <= f32::EPSILON * w, "{t} vs {w}");
        }
        assert_eq!(times.len(), want.len());
        let Some(gltf::animation::util::ReadOutputs::MorphTargetWeights(w)) = r.read_outputs()
        else {
            panic!("weights expected");
        };
        let w: Vec<f32> = w.into_f32().collect();
        let n = FRAMES as usize;
        assert_eq!(w.len(), n * n);
        for k in 0..n {
            for j in 0..n {
                assert_eq!(w[k * n + j], if j == k { 1.0 } else { 0.0 });
            }
        }
    }
}

#[test]
fn glb_color_is_the_peak_strain_colour() {
    // Only the flat frames: the peak principal stretch is the largest scale, everywhere.
    let mut seq = clip();
    seq.frames.truncate(FLAT as usize);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("flat.glb");
    seq.write_to(Format::Glb.sink(&path, &ExportOptions::default()).as_mut())
        .unwrap();
    let (doc, buffers, _) = gltf::import(&path).unwrap();
    assert_eq!(doc.nodes().count(), 1, "colliders are off by default");
    let prim = doc.meshes().next().unwrap().primitives().next().unwrap();
    let colors: Vec<[f32; 3]> = prim
        .reader(|b| Some(&buffers[b.index()]))
        .read_colors(0)
        .unwrap()
        .into_rgb_f32()
        .collect();
    // Stretch 1.3 with the default range 0.25 saturates to red.
    assert_eq!(flat_scale(FLAT - 1), 1.3);
    assert_eq!(colors.len(), 30);
    for c in colors {
        assert!(
            (c[0] - 1.0).abs() < 1e-6 && c[1].abs() < 1e-5 && c[2].abs() < 1e-5,
            "{c:?}"
        );
    }
}

/// `(r, g, b)` the map gives flat frame `k`, from the closed form of the colour map.
fn flat_color(k: u32) -> [f32; 3] {
    let t = ((flat_scale(k) - 1.0) / StrainColorMap::default().range).min(1.0);
    [1.0, 1.0 - t, 1.0 - t]
}

#[test]
fn obj_frames_read_back_with_tobj() {
    let seq = clip();
    let dir = tempfile::tempdir().unwrap();
    let written = seq
        .write_to(
            Format::Obj
                .sink(&dir.path().join("clip.obj"), &colliders())
                .as_mut(),
        )
        .unwrap();
    let names: Vec<String> = written
        .iter()
        .map(|p| p.file_name().unwrap().to_string_lossy().into_owned())
        .collect();
    let want: Vec<String> = (0..FRAMES)
        .map(|k| format!("clip_{:06}.obj", FIRST + k))
        .collect();
    assert_eq!(names, want);
    assert_eq!(
        listing(dir.path()),
        written,
        "nothing else in the directory"
    );

    let options = tobj::LoadOptions {
        single_index: true,
        ..Default::default()
    };
    for (k, (path, frame)) in written.iter().zip(&seq.frames).enumerate() {
        let (models, _) = tobj::load_obj(path, &options).unwrap();
        let names: Vec<_> = models.iter().map(|m| m.name.as_str()).collect();
        assert_eq!(names, ["skin:sheet", "bone:ulna"]);
        for (m, model) in models.iter().enumerate() {
            let meta = &seq.meta.meshes[m];
            let mesh = &model.mesh;
            assert_eq!(mesh.indices.len(), 3 * meta.triangles.len());
            let at = |a: &[f32], i: u32| Vec3::from_slice(&a[3 * i as usize..3 * i as usize + 3]);
            for (t, tri) in meta.triangles.iter().enumerate() {
                for (c, &v) in tri.iter().enumerate() {
                    let i = mesh.indices[3 * t + c];
                    let want = frame.positions[m][v as usize];
                    // Shortest round-trip text: bit-exact.
                    assert_eq!(at(&mesh.positions, i), want, "frame {k} mesh {m}");
                    if m == 0 && (k as u32) < FLAT {
                        assert!((at(&mesh.normals, i) - Vec3::Z).length() < 1e-6);
                        let col = at(&mesh.vertex_color, i).to_array();
                        let exp = flat_color(k as u32);
                        for ch in 0..3 {
                            assert!((col[ch] - exp[ch]).abs() < 1e-5, "{col:?} vs {exp:?}");
                        }
                    }
                }
            }
        }
    }
}

/// A parsed binary PLY: header lines, vertex rows (x y z nx ny nz [r g b]), faces.
struct Ply {
    header: Vec<String>,
    vertices: Vec<([f32; 6], Option<[u8; 3]>)>,
    faces: Vec<[u32; 3]>,
}

fn read_ply(path: &Path) -> Ply {
    let bytes = std::fs::read(path).unwrap();
    let end = bytes
        .windows(11)
        .position(|w| w == b"end_header\n")
        .unwrap()
        + 11;
    let header: Vec<String> = String::from_utf8(bytes[..end].to_vec())
        .unwrap()
        .lines()
        .map(str::to_owned)
        .collect();
    assert_eq!(header[0], "ply");
    assert_eq!(header[1], "format binary_little_endian 1.0");
    let count = |element: &str| -> usize {
        let line = header
            .iter()
            .find(|l| l.starts_with(&format!("element {element} ")))
            .unwrap();
        line.rsplit(' ').next().unwrap().parse().unwrap()
    };
    let props: Vec<&str> = header
        .iter()
        .filter(|l| l.starts_with("property "))
        .map(String::as_str)
        .collect();
    let colors = props.contains(&"property uchar red");
    let mut body = &bytes[end..];
    let f32_ = |b: &mut &[u8]| {
        let v = f32::from_le_bytes(b[..4].try_into().unwrap());
        *b = &b[4..];
        v
    };
    let mut vertices = Vec::new();
    for _ in 0..count("vertex") {
        let row = [(); 6].map(|_| f32_(&mut body));
        let rgb = colors.then(|| {
            let c = [body[0], body[1], body[2]];
            body = &body[3..];
            c
        });
        vertices.push((row, rgb));
    }
    let mut faces = Vec::new();
    for _ in 0..count("face") {
        assert_eq!(body[0], 3);
        let mut f = [0u32; 3];
        for (c, v) in f.iter_mut().enumerate() {
            *v = u32::from_le_bytes(body[1 + 4 * c..5 + 4 * c].try_into().unwrap());
        }
        body = &body[13..];
        faces.push(f);
    }
    assert!(body.is_empty(), "{} trailing bytes", body.len());
    Ply {
        header,
        vertices,
        faces,
    }
}

#[test]
fn ply_frames_read_back() {
    let seq = clip();
    let dir = tempfile::tempdir().unwrap();
    let written = seq
        .write_to(
            Format::Ply
                .sink(&dir.path().join("clip.ply"), &colliders())
                .as_mut(),
        )
        .unwrap();
    assert_eq!(written.len(), FRAMES as usize);
    assert!(written[2].ends_with(format!("clip_{:06}.ply", FIRST + 2)));
    let skin_n = seq.meta.meshes[0].rest_positions.len();
    for (k, (path, frame)) in written.iter().zip(&seq.frames).enumerate() {
        let ply = read_ply(path);
        assert!(
            ply.header
                .contains(&"comment mesh skin:sheet vertices 0 30 faces 0 40".into())
        );
        assert!(
            ply.header
                .contains(&"comment mesh bone:ulna vertices 30 4 faces 40 4".into())
        );
        let all: Vec<Vec3> = frame.positions.concat();
        assert_eq!(ply.vertices.len(), all.len());
        for (i, ((row, rgb), want)) in ply.vertices.iter().zip(&all).enumerate() {
            assert_eq!(
                Vec3::new(row[0], row[1], row[2]),
                *want,
                "frame {k} vertex {i}"
            );
            if i < skin_n && (k as u32) < FLAT {
                assert!((Vec3::new(row[3], row[4], row[5]) - Vec3::Z).length() < 1e-6);
                let exp = flat_color(k as u32).map(|c| (c * 255.0).round() as u8);
                assert_eq!(rgb.unwrap(), exp);
            }
        }
        let mut want_faces = seq.meta.meshes[0].triangles.clone();
        want_faces.extend(
            seq.meta.meshes[1]
                .triangles
                .iter()
                .map(|t| t.map(|v| v + 30)),
        );
        assert_eq!(ply.faces, want_faces);
    }
}

/// The `name.timeSamples = { ... }` block of the `index`-th mesh as (time code, tuples).
fn usda_samples(text: &str, attribute: &str, index: usize) -> Vec<(u32, Vec<Vec3>)> {
    let open = format!("{attribute}.timeSamples = {{\n");
    let start = text.match_indices(&open).nth(index).unwrap().0 + open.len();
    let block = &text[start..start + text[start..].find("        }\n").unwrap()];
    block
        .lines()
        .map(|line| {
            let (code, rest) = line.trim().split_once(": [").unwrap();
            let body = rest.trim_end_matches("],");
            let tuples = body
                .split("), (")
                .map(|t| {
                    let v: Vec<f32> = t
                        .trim_matches(|c| c == '(' || c == ')')
                        .split(", ")
                        .map(|x| x.parse().unwrap())
                        .collect();
                    Vec3::from_slice(&v)
                })
                .collect();
            (code.parse().unwrap(), tuples)
        })
        .collect()
}

#[test]
fn usda_has_one_time_sample_per_frame() {
    let seq = clip();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("clip.usda");
    seq.write_to(Format::Usda.sink(&path, &colliders()).as_mut())
        .unwrap();
    let text = std::fs::read_to_string(&path).unwrap();
    assert!(text.starts_with("#usda 1.0\n"));
    for line in [
        "    timeCodesPerSecond = 30.0\n",
        "    framesPerSecond = 30.0\n",
        &format!("    startTimeCode = {FIRST}\n"),
        &format!("    endTimeCode = {}\n", FIRST + FRAMES - 1),
        "    def Mesh \"skin_sheet\" (\n",
        "    def Mesh \"bone_ulna\" (\n",
    ] {
        assert!(text.contains(line), "missing {line:?}");
    }
    for (m, mesh) in seq.meta.meshes.iter().enumerate() {
        let points = usda_samples(&text, "point3f[] points", m);
        assert_eq!(points.len(), FRAMES as usize);
        for ((code, p), frame) in points.iter().zip(&seq.frames) {
            assert_eq!(*code, frame.index);
            assert_eq!(p, &frame.positions[m], "bit-exact points at {code}");
        }
        let colors = usda_samples(&text, "color3f[] primvars:displayColor", m);
        assert_eq!(colors.len(), FRAMES as usize);
        assert_eq!(
            usda_samples(&text, "normal3f[] normals", m).len(),
            FRAMES as usize
        );
        assert_eq!(
            usda_samples(&text, "float3[] extent", m).len(),
            FRAMES as usize
        );
        if m == 0 {
            for (k, (_, sample)) in colors.iter().take(FLAT as usize).enumerate() {
                let exp = Vec3::from(flat_color(k as u32));
                assert!(sample.iter().all(|c| (*c - exp).length() < 1e-5));
            }
        }
        let counts = format!(
            "int[] faceVertexCounts = [{}]",
            vec!["3"; mesh.triangles.len()].join(", ")
        );
        assert!(text.contains(&counts));
    }
}

#[test]
fn usda_opens_in_pixar_usd_when_available() {
    let probe = std::process::Command::new("python3")
        .args(["-c", "import pxr"])
        .output();
    if !probe.is_ok_and(|o| o.status.success()) {
        eprintln!("skipped: python3 with pxr (pip install usd-core) is not available");
        return;
    }
    let seq = clip();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("clip.usda");
    seq.write_to(Format::Usda.sink(&path, &colliders()).as_mut())
        .unwrap();
    let script = r#"
import sys
from pxr import Usd, UsdGeom
stage = Usd.Stage.Open(sys.argv[1])
mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/dermis/skin_sheet"))
times = mesh.GetPointsAttr().GetTimeSamples()
p = mesh.GetPointsAttr().Get(float(sys.argv[2]))
print(len(times), stage.GetTimeCodesPerSecond(), repr(float(p[7][0])), repr(float(p[7][1])))
"#;
    let probe_frame = FIRST + FLAT - 1;
    let out = std::process::Command::new("python3")
        .args([
            "-c",
            script,
            path.to_str().unwrap(),
            &probe_frame.to_string(),
        ])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8(out.stdout).unwrap();
    let fields: Vec<&str> = text.split_whitespace().collect();
    assert_eq!(fields[0].parse::<u32>().unwrap(), FRAMES);
    assert_eq!(fields[1].parse::<f64>().unwrap(), f64::from(FPS));
    let want = seq.frames[(FLAT - 1) as usize].positions[0][7];
    assert_eq!(fields[2].parse::<f64>().unwrap() as f32, want.x);
    assert_eq!(fields[3].parse::<f64>().unwrap() as f32, want.y);
}

#[cfg(unix)]
#[test]
fn exported_files_get_ordinary_permissions() {
    use std::os::unix::fs::PermissionsExt;
    let dir = tempfile::tempdir().unwrap();
    let reference = dir.path().join("reference");
    std::fs::write(&reference, b"").unwrap();
    let mode = |p: &Path| std::fs::metadata(p).unwrap().permissions().mode() & 0o777;
    for format in Format::ALL {
        let out = dir.path().join(format!("clip.{format}"));
        for file in clip()
            .write_to(format.sink(&out, &colliders()).as_mut())
            .unwrap()
        {
            assert_eq!(
                mode(&file),
                mode(&reference),
                "{} like any new file",
                file.display()
            );
        }
    }
}

#[test]
fn same_input_gives_the_same_bytes() {
    let seq = clip();
    let dirs = [tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap()];
    for format in Format::ALL {
        let files: Vec<Vec<Vec<u8>>> = dirs
            .iter()
            .map(|d| {
                let out = d.path().join(format!("clip.{format}"));
                let written = seq
                    .write_to(format.sink(&out, &colliders()).as_mut())
                    .unwrap();
                written.iter().map(|p| std::fs::read(p).unwrap()).collect()
            })
            .collect();
        assert!(!files[0].is_empty());
        assert!(
            files[0] == files[1],
            "{format} output differs between two runs"
        );
    }
}
