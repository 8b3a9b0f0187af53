//! Simulation checkpoints for resuming an export: named `f32` arrays, bit-exact, written atomically.

use std::io::Write as _;
use std::path::Path;

use glam::Vec3;

use super::ExportError;
use super::atomic::write_atomic_with;

/// Format version written in every checkpoint; [`Checkpoint::read`] rejects any other.
pub const CHECKPOINT_VERSION: u32 = 1;

const MAGIC: &[u8; 8] = b"DERMISCK";

/// One named array of a [`Checkpoint`].
#[derive(Debug, Clone, PartialEq)]
pub struct CheckpointArray {
    /// What the array holds, e.g. `"skin/positions"`.
    pub name: String,
    /// The values; their bits are preserved exactly (NaN payloads and `-0.0` included).
    pub values: Vec<f32>,
}

/// The state a simulation needs to continue after frame [`frame`](Self::frame), as named
/// `f32` arrays (positions, velocities, contact state, ...).
///
/// The file layout (all integers little-endian) is the 8-byte magic `DERMISCK`, `u32` version
/// ([`CHECKPOINT_VERSION`]), `u32` frame, `u32` array count, then per array a `u32` name length,
/// the UTF-8 name, a `u64` value count and the values as `f32` bits. Nothing may follow.
///
/// ```
/// use dermis::export::Checkpoint;
/// use glam::Vec3;
/// let mut c = Checkpoint::new(12);
/// c.push_vec3("skin/positions", &[Vec3::new(0.1, -0.0, 3.0)]);
/// let dir = tempfile::tempdir()?;
/// let path = dir.path().join("arm.ckpt");
/// c.write(&path)?;
/// assert_eq!(Checkpoint::read(&path)?, c);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Checkpoint {
    /// The last frame completed when the checkpoint was taken.
    pub frame: u32,
    /// The state, in the order it was pushed.
    pub arrays: Vec<CheckpointArray>,
}

impl Checkpoint {
    /// An empty checkpoint after `frame`.
    pub fn new(frame: u32) -> Self {
        Self {
            frame,
            arrays: Vec::new(),
        }
    }

    /// Appends an array.
    pub fn push(&mut self, name: impl Into<String>, values: Vec<f32>) {
        self.arrays.push(CheckpointArray {
            name: name.into(),
            values,
        });
    }

    /// Appends positions or velocities as `x y z` triples.
    pub fn push_vec3(&mut self, name: impl Into<String>, values: &[Vec3]) {
        self.push(name, values.iter().flat_map(|v| v.to_array()).collect());
    }

    /// The first array named `name`.
    pub fn get(&self, name: &str) -> Option<&[f32]> {
        self.arrays
            .iter()
            .find(|a| a.name == name)
            .map(|a| a.values.as_slice())
    }

    /// The first array named `name` as `Vec3`s (`None` if absent or not a multiple of 3 long).
    pub fn get_vec3(&self, name: &str) -> Option<Vec<Vec3>> {
        let v = self.get(name)?;
        (v.len() % 3 == 0).then(|| v.chunks_exact(3).map(Vec3::from_slice).collect())
    }

    /// The file contents.
    pub fn to_bytes(&self) -> Vec<u8> {
        let size: usize = self
            .arrays
            .iter()
            .map(|a| 12 + a.name.len() + 4 * a.values.len())
            .sum();
        let mut b = Vec::with_capacity(20 + size);
        b.extend_from_slice(MAGIC);
        b.extend_from_slice(&CHECKPOINT_VERSION.to_le_bytes());
        b.extend_from_slice(&self.frame.to_le_bytes());
        b.extend_from_slice(&(self.arrays.len() as u32).to_le_bytes());
        for a in &self.arrays {
            b.extend_from_slice(&(a.name.len() as u32).to_le_bytes());
            b.extend_from_slice(a.name.as_bytes());
            b.extend_from_slice(&(a.values.len() as u64).to_le_bytes());
            for v in &a.values {
                b.extend_from_slice(&v.to_bits().to_le_bytes());
            }
        }
        b
    }

    /// Parses file contents; `path` only names the file in errors.
    pub fn from_bytes(bytes: &[u8], path: &Path) -> Result<Self, ExportError> {
        let bad = |reason: String| ExportError::BadCheckpoint {
            path: path.to_owned(),
            reason,
        };
        let mut r = Reader { bytes, at: 0 };
        if r.take(8) != Some(MAGIC.as_slice()) {
            return Err(bad("not a dermis checkpoint (wrong magic)".into()));
        }
        let truncated = || bad("truncated".into());
        let version = r.u32().ok_or_else(truncated)?;
        if version != CHECKPOINT_VERSION {
            return Err(bad(format!(
                "version {version}, this dermis reads version {CHECKPOINT_VERSION}"
            )));
        }
        let frame = r.u32().ok_or_else(truncated)?;
        let count = r.u32().ok_or_else(truncated)?;
        let mut arrays = Vec::new();
        for i in 0..count {
            let len = r.u32().ok_or_else(truncated)? as usize;
            let name = r.take(len).ok_or_else(truncated)?;
            let name = std::str::from_utf8(name)
                .map_err(|_| bad(format!("array {i}: name is not UTF-8")))?
                .to_owned();
            let n = r.u64().ok_or_else(truncated)?;
            let n = usize::try_from(n)
                .ok()
                .filter(|n| n.checked_mul(4).is_some_and(|b| b <= r.remaining()))
                .ok_or_else(|| {
                    bad(format!(
                        "array {name:?} claims {n} values, more than the file holds"
                    ))
                })?;
            let raw = r.take(4 * n).ok_or_else(truncated)?;
            let values = raw
                .chunks_exact(4)
                .map(|c| f32::from_bits(u32::from_le_bytes([c[0], c[1], c[2], c[3]])))
                .collect();
            arrays.push(CheckpointArray { name, values });
        }
        if r.remaining() != 0 {
            return Err(bad(format!("{} trailing bytes", r.remaining())));
        }
        Ok(Self { frame, arrays })
    }

    /// Writes the checkpoint atomically and durably (synced to disk before the rename), so a
    /// crash leaves either the previous checkpoint or this one.
    pub fn write(&self, path: &Path) -> Result<(), ExportError> {
        let bytes = self.to_bytes();
        write_atomic_with(path, true, |w| w.write_all(&bytes))
    }

    /// Reads a checkpoint written by [`write`](Self::write).
    pub fn read(path: &Path) -> Result<Self, ExportError> {
        let bytes = std::fs::read(path).map_err(|source| ExportError::Io {
            path: path.to_owned(),
            source,
        })?;
        Self::from_bytes(&bytes, path)
    }
}

struct Reader<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize) -> Option<&'a [u8]> {
        let end = self.at.checked_add(n)?;
        let s = self.bytes.get(self.at..end)?;
        self.at = end;
        Some(s)
    }
    fn u32(&mut self) -> Option<u32> {
        self.take(4)
            .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }
    fn u64(&mut self) -> Option<u64> {
        let b = self.take(8)?;
        let mut a = [0; 8];
        a.copy_from_slice(b);
        Some(u64::from_le_bytes(a))
    }
    fn remaining(&self) -> usize {
        self.bytes.len() - self.at
    }
}
