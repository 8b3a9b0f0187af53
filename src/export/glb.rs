//! Animated binary glTF: rest mesh plus one morph target per frame, driven by a STEP animation.

use std::borrow::Cow;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use glam::Vec3;
use gltf::json;
use json::validation::{Checked::Valid, USize64};

use super::atomic::write_atomic;
use super::geometry::vertex_normals;
use super::{ExportError, ExportMeta, ExportOptions, FrameSink, Lifecycle, Staged};

/// Writes one binary glTF 2.0 file. Layout, per exported mesh (one node and one mesh each,
/// node named `<role>:<name>`):
///
/// - the base primitive holds the **rest** positions, their angle-weighted normals, `u32`
///   triangle indices and, with strain colours, `COLOR_0`;
/// - morph target `k` holds frame `k`'s positions and normals as deltas from the base;
/// - one animation (`"dermis"`) drives every node's morph weights with STEP interpolation:
///   at time `frame / fps` the weights are one-hot on that frame's target, so a viewer shows
///   each simulated frame exactly as exported (`base + delta`, equal to the input up to one
///   `f32` rounding). The node's default weights select the first frame.
///
/// glTF vertex colours cannot be animated (morph targets carry only positions, normals and
/// tangents in `gltf-json`), so `COLOR_0` is static: the colour of each vertex's **peak**
/// strain over the clip, showing where the skin stretched most.
///
/// All frames are kept in memory until [`FrameSink::finish`], which writes the file
/// atomically. The file size grows as `frames × vertices × 24` bytes plus `frames²× 4` for
/// the weights, and a glb is limited to 4 GiB.
#[derive(Debug)]
pub struct GlbSink {
    out: PathBuf,
    options: ExportOptions,
    life: Lifecycle,
    /// Frame indices written.
    frames: Vec<u32>,
    /// Positions per frame per exported mesh.
    positions: Vec<Vec<Vec<Vec3>>>,
    /// Peak strain per exported mesh per vertex.
    peak_strain: Vec<Vec<f32>>,
}

impl GlbSink {
    /// A sink writing the file `out`.
    pub fn new(out: &Path, options: ExportOptions) -> Self {
        Self {
            out: out.to_owned(),
            options,
            life: Lifecycle::default(),
            frames: Vec::new(),
            positions: Vec::new(),
            peak_strain: Vec::new(),
        }
    }
}

impl FrameSink for GlbSink {
    fn begin(&mut self, meta: &ExportMeta) -> Result<(), ExportError> {
        let staged = self.life.begin(meta, &self.options, &self.out)?;
        self.peak_strain = staged
            .meshes
            .iter()
            .map(|m| vec![1.0; m.rest_positions.len()])
            .collect();
        Ok(())
    }

    fn write_frame(&mut self, frame: u32, positions: &[&[Vec3]]) -> Result<(), ExportError> {
        let (staged, meshes) = self.life.frame(frame, positions)?;
        if let Some(map) = self.options.strain_colors {
            for ((rest, peak), p) in staged.rest.iter().zip(&mut self.peak_strain).zip(&meshes) {
                for (peak, s) in peak.iter_mut().zip(rest.vertex_strain(p, map.measure)) {
                    // Peak by distance from rest, so strong compression shows too.
                    if (s - 1.0).abs() > (*peak - 1.0).abs() {
                        *peak = s;
                    }
                }
            }
        }
        self.frames.push(frame);
        self.positions
            .push(meshes.iter().map(|p| p.to_vec()).collect());
        Ok(())
    }

    fn finish(&mut self) -> Result<Vec<PathBuf>, ExportError> {
        let staged = self.life.finish()?;
        if self.frames.is_empty() {
            return Err(ExportError::NoFrames {
                path: self.out.clone(),
            });
        }
        let (root, bin) = build(
            staged,
            &self.options,
            &self.frames,
            &self.positions,
            &self.peak_strain,
        );
        let json_text = json::serialize::to_vec(&root).map_err(|source| ExportError::Json {
            path: self.out.clone(),
            source,
        })?;
        let total = 12 + 8 + json_text.len().next_multiple_of(4) + 8 + bin.len();
        let length = u32::try_from(total).map_err(|_| ExportError::TooLarge {
            path: self.out.clone(),
            bytes: total as u64,
        })?;
        let glb = gltf::binary::Glb {
            header: gltf::binary::Header {
                magic: *b"glTF",
                version: 2,
                length,
            },
            json: Cow::Owned(json_text),
            bin: Some(Cow::Owned(bin)),
        };
        write_atomic(&self.out, |w| {
            glb.to_writer(w).map_err(std::io::Error::other)
        })?;
        // Free the frames: the sink is done.
        self.positions = Vec::new();
        Ok(vec![self.out.clone()])
    }
}

/// Accumulates the binary chunk and the JSON objects that describe it.
struct Builder {
    root: json::Root,
    bin: Vec<u8>,
    buffer: json::Index<json::Buffer>,
}

impl Builder {
    /// A buffer view over `data` (4-byte aligned) and an accessor of `count` elements on it.
    fn accessor_f32(
        &mut self,
        data: &[f32],
        type_: json::accessor::Type,
        target: Option<json::buffer::Target>,
        with_bounds: bool,
    ) -> json::Index<json::Accessor> {
        let components = match type_ {
            json::accessor::Type::Scalar => 1,
            json::accessor::Type::Vec3 => 3,
            _ => unreachable!("only SCALAR and VEC3 float accessors are written"),
        };
        let (min, max) = if with_bounds {
            let mut min = vec![f32::INFINITY; components];
            let mut max = vec![f32::NEG_INFINITY; components];
            for chunk in data.chunks_exact(components) {
                for c in 0..components {
                    min[c] = min[c].min(chunk[c]);
                    max[c] = max[c].max(chunk[c]);
                }
            }
            (Some(json::Value::from(min)), Some(json::Value::from(max)))
        } else {
            (None, None)
        };
        let bytes: Vec<u8> = data.iter().flat_map(|x| x.to_le_bytes()).collect();
        let view = self.view(&bytes, target);
        self.root.push(json::Accessor {
            buffer_view: Some(view),
            byte_offset: None,
            count: USize64::from(data.len() / components),
            component_type: Valid(json::accessor::GenericComponentType(
                json::accessor::ComponentType::F32,
            )),
            extensions: None,
            extras: Default::default(),
            type_: Valid(type_),
            min,
            max,
            name: None,
            normalized: false,
            sparse: None,
        })
    }

    fn accessor_indices(&mut self, triangles: &[[u32; 3]]) -> json::Index<json::Accessor> {
        let bytes: Vec<u8> = triangles
            .iter()
            .flatten()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        let view = self.view(&bytes, Some(json::buffer::Target::ElementArrayBuffer));
        self.root.push(json::Accessor {
            buffer_view: Some(view),
            byte_offset: None,
            count: USize64::from(triangles.len() * 3),
            component_type: Valid(json::accessor::GenericComponentType(
                json::accessor::ComponentType::U32,
            )),
            extensions: None,
            extras: Default::default(),
            type_: Valid(json::accessor::Type::Scalar),
            min: None,
            max: None,
            name: None,
            normalized: false,
            sparse: None,
        })
    }

    fn view(
        &mut self,
        bytes: &[u8],
        target: Option<json::buffer::Target>,
    ) -> json::Index<json::buffer::View> {
        let offset = self.bin.len();
        self.bin.extend_from_slice(bytes);
        self.bin.resize(self.bin.len().next_multiple_of(4), 0);
        self.root.push(json::buffer::View {
            buffer: self.buffer,
            byte_length: USize64::from(bytes.len()),
            byte_offset: Some(USize64::from(offset)),
            byte_stride: None,
            name: None,
            target: target.map(Valid),
            extensions: None,
            extras: Default::default(),
        })
    }
}

fn flat(v: &[Vec3]) -> Vec<f32> {
    v.iter().flat_map(|p| p.to_array()).collect()
}

fn build(
    staged: &Staged,
    options: &ExportOptions,
    frames: &[u32],
    positions: &[Vec<Vec<Vec3>>],
    peak_strain: &[Vec<f32>],
) -> (json::Root, Vec<u8>) {
    let mut root = json::Root {
        asset: json::Asset {
            generator: Some(format!("dermis {}", env!("CARGO_PKG_VERSION"))),
            ..Default::default()
        },
        ..Default::default()
    };
    let buffer = root.push(json::Buffer {
        byte_length: USize64(0), // patched below
        extensions: None,
        extras: Default::default(),
        name: None,
        uri: None,
    });
    let mut b = Builder {
        root,
        bin: Vec::new(),
        buffer,
    };
    let n_frames = frames.len();
    let mut initial_weights = vec![0.0f32; n_frames];
    initial_weights[0] = 1.0;
    let mut nodes = Vec::new();
    for (m, (mesh, peak)) in staged.meshes.iter().zip(peak_strain).enumerate() {
        let indices = b.accessor_indices(&mesh.triangles);
        let rest = &mesh.rest_positions;
        let rest_normals = vertex_normals(&mesh.triangles, rest);
        let vertex = Some(json::buffer::Target::ArrayBuffer);
        let mut attributes = BTreeMap::new();
        let pos = b.accessor_f32(&flat(rest), json::accessor::Type::Vec3, vertex, true);
        attributes.insert(Valid(json::mesh::Semantic::Positions), pos);
        let nor = b.accessor_f32(
            &flat(&rest_normals),
            json::accessor::Type::Vec3,
            vertex,
            false,
        );
        attributes.insert(Valid(json::mesh::Semantic::Normals), nor);
        if let Some(map) = options.strain_colors {
            let colors: Vec<f32> = peak.iter().flat_map(|&s| map.color(s)).collect();
            let col = b.accessor_f32(&colors, json::accessor::Type::Vec3, vertex, false);
            attributes.insert(Valid(json::mesh::Semantic::Colors(0)), col);
        }
        let mut targets = Vec::with_capacity(n_frames);
        for frame in positions {
            let p = &frame[m];
            let dp: Vec<f32> = p
                .iter()
                .zip(rest)
                .flat_map(|(p, r)| (*p - *r).to_array())
                .collect();
            let normals = vertex_normals(&mesh.triangles, p);
            let dn: Vec<f32> = normals
                .iter()
                .zip(&rest_normals)
                .flat_map(|(n, r)| (*n - *r).to_array())
                .collect();
            targets.push(json::mesh::MorphTarget {
                positions: Some(b.accessor_f32(&dp, json::accessor::Type::Vec3, vertex, true)),
                normals: Some(b.accessor_f32(&dn, json::accessor::Type::Vec3, vertex, false)),
                tangents: None,
            });
        }
        let gmesh = b.root.push(json::Mesh {
            extensions: None,
            extras: Default::default(),
            name: Some(mesh.qualified_name()),
            primitives: vec![json::mesh::Primitive {
                attributes,
                extensions: None,
                extras: Default::default(),
                indices: Some(indices),
                material: None,
                mode: Valid(json::mesh::Mode::Triangles),
                targets: Some(targets),
            }],
            weights: Some(initial_weights.clone()),
        });
        nodes.push(b.root.push(json::Node {
            mesh: Some(gmesh),
            name: Some(mesh.qualified_name()),
            ..Default::default()
        }));
    }

    // Keyframe times and one-hot weights, shared by every channel.
    let fps = f64::from(staged.fps);
    let times: Vec<f32> = frames
        .iter()
        .map(|&f| (f64::from(f) / fps) as f32)
        .collect();
    let mut weights = vec![0.0f32; n_frames * n_frames];
    for k in 0..n_frames {
        weights[k * n_frames + k] = 1.0;
    }
    let input = b.accessor_f32(&times, json::accessor::Type::Scalar, None, true);
    let output = b.accessor_f32(&weights, json::accessor::Type::Scalar, None, false);
    let mut samplers = Vec::new();
    let mut channels = Vec::new();
    for (i, &node) in nodes.iter().enumerate() {
        samplers.push(json::animation::Sampler {
            extensions: None,
            extras: Default::default(),
            input,
            interpolation: Valid(json::animation::Interpolation::Step),
            output,
        });
        channels.push(json::animation::Channel {
            sampler: json::Index::new(i as u32),
            target: json::animation::Target {
                extensions: None,
                extras: Default::default(),
                node,
                path: Valid(json::animation::Property::MorphTargetWeights),
            },
            extensions: None,
            extras: Default::default(),
        });
    }
    b.root.push(json::Animation {
        extensions: None,
        extras: Default::default(),
        channels,
        name: Some("dermis".to_owned()),
        samplers,
    });
    let scene = b.root.push(json::Scene {
        extensions: None,
        extras: Default::default(),
        name: Some("dermis".to_owned()),
        nodes,
    });
    b.root.scene = Some(scene);
    let Builder { mut root, bin, .. } = b;
    root.buffers[0].byte_length = USize64::from(bin.len());
    (root, bin)
}
