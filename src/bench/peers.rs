//! Files for the peer comparisons of `benches/peers/`: the bench's skin tubes and muscle as OBJ.

use std::io::Write;
use std::path::{Path, PathBuf};

use glam::Vec3;
use thiserror::Error;

use super::arm::ArmWorkload;

/// Why the peer files could not be written.
#[derive(Debug, Error)]
pub enum PeerFilesError {
    /// A file or the folder could not be created or written. Check that the folder's parent
    /// exists and is writable, and that the disk is not full.
    #[error("cannot write {path}: {source}")]
    Io {
        /// The file or folder.
        path: PathBuf,
        /// The operating system's error.
        source: std::io::Error,
    },
}

/// Writes `positions` and `triangles` as an OBJ file (1-based indices), through a temporary
/// name renamed into place, so a failed write never leaves a half-written file.
pub fn write_obj(
    path: &Path,
    positions: &[Vec3],
    triangles: &[[u32; 3]],
) -> Result<(), PeerFilesError> {
    let io = |source| PeerFilesError::Io {
        path: path.to_path_buf(),
        source,
    };
    let tmp = path.with_extension("obj.tmp");
    let write = || -> std::io::Result<()> {
        let mut out = std::io::BufWriter::new(std::fs::File::create(&tmp)?);
        for p in positions {
            writeln!(out, "v {} {} {}", p.x, p.y, p.z)?;
        }
        for t in triangles {
            writeln!(out, "f {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1)?;
        }
        out.into_inner().map_err(|e| e.into_error())?.sync_all()
    };
    if let Err(e) = write() {
        let _ = std::fs::remove_file(&tmp);
        return Err(io(e));
    }
    std::fs::rename(&tmp, path).map_err(io)
}

/// Writes, into `dir` (created if needed), one `<name>.obj` per arm workload (the skin tube at
/// rest) and `muscle.obj` (the first workload's muscle at full flexion, the peers' static
/// collider). Returns the files written.
pub fn write_peer_files(dir: &Path, works: &[ArmWorkload]) -> Result<Vec<PathBuf>, PeerFilesError> {
    std::fs::create_dir_all(dir).map_err(|source| PeerFilesError::Io {
        path: dir.to_path_buf(),
        source,
    })?;
    let mut written = Vec::new();
    for work in works {
        let path = dir.join(format!("{}.obj", work.tube.name));
        write_obj(
            &path,
            work.tube.mesh.positions(),
            work.tube.mesh.triangles(),
        )?;
        written.push(path);
    }
    if let Some(work) = works.first() {
        let path = dir.join("muscle.obj");
        write_obj(
            &path,
            &work.muscle_vertices(work.clip_frames / 2),
            work.muscle_triangles(),
        )?;
        written.push(path);
    }
    Ok(written)
}
