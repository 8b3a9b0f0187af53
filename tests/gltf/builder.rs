//! A minimal glTF writer for hand-built test models (JSON + one binary buffer).

use serde_json::{Value, json};

/// A glTF document under construction with its binary buffer.
pub struct TestGltf {
    /// The JSON document (without `buffers`, added on output).
    pub json: Value,
    /// The binary buffer.
    pub bin: Vec<u8>,
}

impl TestGltf {
    pub fn new() -> Self {
        Self {
            json: json!({
                "asset": { "version": "2.0" },
                "accessors": [], "bufferViews": [], "nodes": [], "meshes": [],
            }),
            bin: Vec::new(),
        }
    }

    fn push_view(&mut self, bytes: &[u8]) -> usize {
        while !self.bin.len().is_multiple_of(4) {
            self.bin.push(0);
        }
        let views = self.json["bufferViews"].as_array_mut().unwrap();
        views.push(json!({ "buffer": 0, "byteOffset": self.bin.len(), "byteLength": bytes.len() }));
        self.bin.extend_from_slice(bytes);
        views.len() - 1
    }

    fn push_accessor(&mut self, view: usize, component: u32, count: usize, ty: &str) -> usize {
        let accessors = self.json["accessors"].as_array_mut().unwrap();
        accessors.push(
            json!({ "bufferView": view, "componentType": component, "count": count, "type": ty }),
        );
        accessors.len() - 1
    }

    /// f32 accessor of `ty` (`SCALAR`, `VEC3`, `VEC4`, `MAT4`).
    pub fn floats(&mut self, data: &[f32], ty: &str) -> usize {
        let width = match ty {
            "SCALAR" => 1,
            "VEC3" => 3,
            "VEC4" => 4,
            "MAT4" => 16,
            _ => panic!("type {ty}"),
        };
        let bytes: Vec<u8> = data.iter().flat_map(|x| x.to_le_bytes()).collect();
        let view = self.push_view(&bytes);
        let a = self.push_accessor(view, 5126, data.len() / width, ty);
        if ty == "VEC3" {
            // glTF requires bounds on POSITION accessors; harmless elsewhere.
            let bound = |f: fn(f32, f32) -> f32, init: f32| -> Vec<f32> {
                (0..3)
                    .map(|k| data.iter().skip(k).step_by(3).copied().fold(init, f))
                    .collect()
            };
            self.json["accessors"][a]["min"] = json!(bound(f32::min, f32::INFINITY));
            self.json["accessors"][a]["max"] = json!(bound(f32::max, f32::NEG_INFINITY));
        }
        a
    }

    /// Accessor over raw little-endian `bytes` of `component` type (glTF code), optionally
    /// normalised.
    pub fn raw(
        &mut self,
        bytes: &[u8],
        component: u32,
        count: usize,
        ty: &str,
        normalized: bool,
    ) -> usize {
        let view = self.push_view(bytes);
        let a = self.push_accessor(view, component, count, ty);
        if normalized {
            self.json["accessors"][a]["normalized"] = json!(true);
        }
        a
    }

    /// Sparse VEC3 f32 accessor of `count` zeros (no buffer view) with `values` at `indices`.
    pub fn sparse_vec3(&mut self, count: usize, indices: &[u16], values: &[f32]) -> usize {
        let ib: Vec<u8> = indices.iter().flat_map(|x| x.to_le_bytes()).collect();
        let iv = self.push_view(&ib);
        let vb: Vec<u8> = values.iter().flat_map(|x| x.to_le_bytes()).collect();
        let vv = self.push_view(&vb);
        let accessors = self.json["accessors"].as_array_mut().unwrap();
        accessors.push(json!({
            "componentType": 5126, "count": count, "type": "VEC3",
            "min": [-10.0, -10.0, -10.0], "max": [10.0, 10.0, 10.0],
            "sparse": {
                "count": indices.len(),
                "indices": { "bufferView": iv, "componentType": 5123 },
                "values": { "bufferView": vv },
            },
        }));
        accessors.len() - 1
    }

    /// u8 VEC4 accessor (joints).
    pub fn joints(&mut self, data: &[[u8; 4]]) -> usize {
        let bytes: Vec<u8> = data.iter().flatten().copied().collect();
        let view = self.push_view(&bytes);
        self.push_accessor(view, 5121, data.len(), "VEC4")
    }

    /// u16 SCALAR accessor (indices).
    pub fn indices(&mut self, data: &[u16]) -> usize {
        let bytes: Vec<u8> = data.iter().flat_map(|x| x.to_le_bytes()).collect();
        let view = self.push_view(&bytes);
        self.push_accessor(view, 5123, data.len(), "SCALAR")
    }

    /// Appends a node, returning its index.
    pub fn node(&mut self, node: Value) -> usize {
        let nodes = self.json["nodes"].as_array_mut().unwrap();
        nodes.push(node);
        nodes.len() - 1
    }

    /// Appends a mesh, returning its index.
    pub fn mesh(&mut self, mesh: Value) -> usize {
        let meshes = self.json["meshes"].as_array_mut().unwrap();
        meshes.push(mesh);
        meshes.len() - 1
    }

    fn with_buffer(&self, uri: Option<String>) -> Vec<u8> {
        let mut doc = self.json.clone();
        let mut buffer = json!({ "byteLength": self.bin.len() });
        if let Some(uri) = uri {
            buffer["uri"] = json!(uri);
        }
        doc["buffers"] = json!([buffer]);
        serde_json::to_vec(&doc).unwrap()
    }

    /// `.gltf` text with the buffer embedded as a base64 data URI.
    pub fn to_embedded_gltf(&self) -> Vec<u8> {
        let uri = format!(
            "data:application/octet-stream;base64,{}",
            base64::encode(&self.bin)
        );
        self.with_buffer(Some(uri))
    }

    /// `.gltf` text referring to an external buffer file `uri` (not written).
    pub fn to_external_gltf(&self, uri: &str) -> Vec<u8> {
        self.with_buffer(Some(uri.to_string()))
    }

    /// Binary `.glb`.
    pub fn to_glb(&self) -> Vec<u8> {
        let mut json = self.with_buffer(None);
        while !json.len().is_multiple_of(4) {
            json.push(b' ');
        }
        let mut bin = self.bin.clone();
        while !bin.len().is_multiple_of(4) {
            bin.push(0);
        }
        let total = 12 + 8 + json.len() + 8 + bin.len();
        let mut out = Vec::new();
        out.extend_from_slice(b"glTF");
        out.extend_from_slice(&2u32.to_le_bytes());
        out.extend_from_slice(&(total as u32).to_le_bytes());
        out.extend_from_slice(&(json.len() as u32).to_le_bytes());
        out.extend_from_slice(b"JSON");
        out.extend_from_slice(&json);
        out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
        out.extend_from_slice(b"BIN\0");
        out.extend_from_slice(&bin);
        out
    }
}
