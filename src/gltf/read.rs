//! Bounds-checked accessor reading (dense and sparse, any component type, normalised ints).

use ::gltf::Accessor;
use ::gltf::accessor::{DataType, Dimensions};

use super::GltfError;

/// Value of one component at `bytes[0..]`, normalised to [-1, 1] / [0, 1] when `normalized`.
fn component(bytes: &[u8], ty: DataType, normalized: bool) -> f64 {
    let b = |n: usize| bytes.get(n).copied().unwrap_or(0);
    let raw: f64 = match ty {
        DataType::I8 => f64::from(b(0) as i8),
        DataType::U8 => f64::from(b(0)),
        DataType::I16 => f64::from(i16::from_le_bytes([b(0), b(1)])),
        DataType::U16 => f64::from(u16::from_le_bytes([b(0), b(1)])),
        DataType::U32 => f64::from(u32::from_le_bytes([b(0), b(1), b(2), b(3)])),
        DataType::F32 => f64::from(f32::from_le_bytes([b(0), b(1), b(2), b(3)])),
    };
    if !normalized {
        return raw;
    }
    match ty {
        DataType::I8 => (raw / 127.0).max(-1.0),
        DataType::U8 => raw / 255.0,
        DataType::I16 => (raw / 32767.0).max(-1.0),
        DataType::U16 => raw / 65535.0,
        _ => raw,
    }
}

fn dims_name(d: Dimensions) -> &'static str {
    match d {
        Dimensions::Scalar => "SCALAR",
        Dimensions::Vec2 => "VEC2",
        Dimensions::Vec3 => "VEC3",
        Dimensions::Vec4 => "VEC4",
        Dimensions::Mat2 => "MAT2",
        Dimensions::Mat3 => "MAT3",
        Dimensions::Mat4 => "MAT4",
    }
}

/// The bytes of buffer view `view` within `buffers`, checked.
fn view_bytes<'b>(
    view: &::gltf::buffer::View,
    buffers: &'b [Vec<u8>],
    accessor: usize,
    usage: &str,
) -> Result<&'b [u8], GltfError> {
    let data = buffers
        .get(view.buffer().index())
        .map_or(&[][..], Vec::as_slice);
    let start = view.offset();
    let end = start.saturating_add(view.length());
    data.get(start..end)
        .ok_or_else(|| GltfError::AccessorOutOfRange {
            accessor,
            usage: format!("{usage}, buffer view {}", view.index()),
            start,
            end,
            available: data.len(),
        })
}

/// Reads `count * n` values starting at byte `offset` of `bytes` with the given stride.
#[expect(
    clippy::too_many_arguments,
    reason = "one call site per dense/sparse part"
)]
fn read_elements(
    bytes: &[u8],
    offset: usize,
    count: usize,
    stride: Option<usize>,
    n: usize,
    ty: DataType,
    normalized: bool,
    accessor: usize,
    usage: &str,
) -> Result<Vec<f64>, GltfError> {
    let size = ty.size();
    let elem = size * n;
    let stride = stride.unwrap_or(elem).max(elem);
    let end = if count == 0 {
        offset
    } else {
        (count - 1)
            .checked_mul(stride)
            .and_then(|x| x.checked_add(offset))
            .and_then(|x| x.checked_add(elem))
            .unwrap_or(usize::MAX)
    };
    if end > bytes.len() || offset > bytes.len() {
        return Err(GltfError::AccessorOutOfRange {
            accessor,
            usage: usage.to_string(),
            start: offset,
            end,
            available: bytes.len(),
        });
    }
    let mut out = Vec::with_capacity(count * n);
    for i in 0..count {
        let base = offset + i * stride;
        for c in 0..n {
            let at = base + c * size;
            out.push(component(&bytes[at..at + size], ty, normalized));
        }
    }
    Ok(out)
}

/// Reads an accessor whose type is one of `dims`, as `count * components` f64 values.
/// Returns the component count per element too.
pub(crate) fn read(
    acc: &Accessor,
    buffers: &[Vec<u8>],
    dims: &[Dimensions],
    usage: &str,
) -> Result<(usize, Vec<f64>), GltfError> {
    let index = acc.index();
    let d = acc.dimensions();
    if !dims.contains(&d) {
        return Err(GltfError::AccessorType {
            accessor: index,
            usage: usage.to_string(),
            expected: match dims {
                [Dimensions::Scalar] => "SCALAR",
                [Dimensions::Vec3] => "VEC3",
                [Dimensions::Vec4] => "VEC4",
                [Dimensions::Mat4] => "MAT4",
                _ => "SCALAR, VEC3 or VEC4",
            },
            found: dims_name(d).to_string(),
        });
    }
    let n = d.multiplicity();
    let ty = acc.data_type();
    let count = acc.count();
    let mut values = match acc.view() {
        Some(view) => {
            let bytes = view_bytes(&view, buffers, index, usage)?;
            read_elements(
                bytes,
                acc.offset(),
                count,
                view.stride(),
                n,
                ty,
                acc.normalized(),
                index,
                usage,
            )?
        }
        None => {
            // Without a view the base values are zeros; bound the allocation by the buffers.
            let total: usize = buffers.iter().map(Vec::len).sum();
            if count > total.saturating_add(1 << 20) {
                return Err(GltfError::AccessorOutOfRange {
                    accessor: index,
                    usage: format!("{usage} (no buffer view)"),
                    start: 0,
                    end: count.saturating_mul(n * ty.size()),
                    available: 0,
                });
            }
            vec![0.0; count * n]
        }
    };
    if let Some(sparse) = acc.sparse() {
        let k = sparse.count();
        let iv = sparse.indices();
        let ibytes = view_bytes(&iv.view(), buffers, index, usage)?;
        let ity = match iv.index_type() {
            ::gltf::accessor::sparse::IndexType::U8 => DataType::U8,
            ::gltf::accessor::sparse::IndexType::U16 => DataType::U16,
            ::gltf::accessor::sparse::IndexType::U32 => DataType::U32,
        };
        let sparse_usage = format!("{usage}, sparse indices");
        let idx = read_elements(
            ibytes,
            iv.offset(),
            k,
            None,
            1,
            ity,
            false,
            index,
            &sparse_usage,
        )?;
        let vv = sparse.values();
        let vbytes = view_bytes(&vv.view(), buffers, index, usage)?;
        let sparse_usage = format!("{usage}, sparse values");
        let vals = read_elements(
            vbytes,
            vv.offset(),
            k,
            None,
            n,
            ty,
            acc.normalized(),
            index,
            &sparse_usage,
        )?;
        for (j, &i) in idx.iter().enumerate() {
            let i = i as usize;
            if i >= count {
                return Err(GltfError::AccessorOutOfRange {
                    accessor: index,
                    usage: format!("{usage}, sparse index {j} = {i} >= count {count}"),
                    start: i,
                    end: i + 1,
                    available: count,
                });
            }
            values[i * n..(i + 1) * n].copy_from_slice(&vals[j * n..(j + 1) * n]);
        }
    }
    Ok((n, values))
}

/// Reads a VEC3 accessor as `[f32; 3]` triples.
pub(crate) fn read_vec3(
    acc: &Accessor,
    buffers: &[Vec<u8>],
    usage: &str,
) -> Result<Vec<glam::Vec3>, GltfError> {
    let (_, v) = read(acc, buffers, &[Dimensions::Vec3], usage)?;
    Ok(v.chunks_exact(3)
        .map(|c| glam::Vec3::new(c[0] as f32, c[1] as f32, c[2] as f32))
        .collect())
}

/// Reads a SCALAR accessor as f32.
pub(crate) fn read_scalar(
    acc: &Accessor,
    buffers: &[Vec<u8>],
    usage: &str,
) -> Result<Vec<f32>, GltfError> {
    let (_, v) = read(acc, buffers, &[Dimensions::Scalar], usage)?;
    Ok(v.into_iter().map(|x| x as f32).collect())
}

/// Reads an integer SCALAR accessor (indices) as u32.
pub(crate) fn read_indices(
    acc: &Accessor,
    buffers: &[Vec<u8>],
    usage: &str,
) -> Result<Vec<u32>, GltfError> {
    if acc.data_type() == DataType::F32 || acc.normalized() {
        return Err(GltfError::AccessorType {
            accessor: acc.index(),
            usage: usage.to_string(),
            expected: "unnormalised unsigned integer SCALAR",
            found: format!("{:?}", acc.data_type()),
        });
    }
    let (_, v) = read(acc, buffers, &[Dimensions::Scalar], usage)?;
    Ok(v.into_iter().map(|x| x as u32).collect())
}
