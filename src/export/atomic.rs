//! Atomic file writes: a temporary file in the target directory, renamed into place when complete.

use std::io::{self, BufWriter, Write};
use std::path::Path;

use tempfile::NamedTempFile;

use super::{ExportError, parent_dir};

/// Writes `path` atomically: `fill` writes into a temporary file in the same directory, which is
/// renamed to `path` only if `fill` and the flush succeed. On any error the temporary file is
/// removed and `path` is untouched (a previous version stays as it was).
///
/// ```
/// let dir = tempfile::tempdir()?;
/// let path = dir.path().join("hello.txt");
/// dermis::export::write_atomic(&path, |w| w.write_all(b"hello"))?;
/// assert_eq!(std::fs::read(&path)?, b"hello");
/// # use std::io::Write;
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub fn write_atomic(
    path: &Path,
    fill: impl FnOnce(&mut BufWriter<&mut NamedTempFile>) -> io::Result<()>,
) -> Result<(), ExportError> {
    write_atomic_with(path, false, fill)
}

/// [`write_atomic`], with `sync_all` before the rename (the file survives a power cut).
pub fn write_atomic_durable(
    path: &Path,
    fill: impl FnOnce(&mut BufWriter<&mut NamedTempFile>) -> io::Result<()>,
) -> Result<(), ExportError> {
    write_atomic_with(path, true, fill)
}

/// [`write_atomic`], with `sync_all` before the rename when `durable` (survives a power cut).
pub(super) fn write_atomic_with(
    path: &Path,
    durable: bool,
    fill: impl FnOnce(&mut BufWriter<&mut NamedTempFile>) -> io::Result<()>,
) -> Result<(), ExportError> {
    let mut tmp = temp_in(parent_dir(path))?;
    let io_err = |source| ExportError::Io {
        path: path.to_owned(),
        source,
    };
    {
        let mut w = BufWriter::with_capacity(1 << 16, &mut tmp);
        fill(&mut w).map_err(io_err)?;
        w.flush().map_err(io_err)?;
    }
    if durable {
        tmp.as_file().sync_all().map_err(io_err)?;
    }
    // On failure the returned `PersistError` owns the temporary file and deletes it on drop.
    tmp.persist(path).map_err(|e| io_err(e.error))?;
    Ok(())
}

/// A temporary file in `dir`, or [`ExportError::UnwritableDirectory`]. It gets the permissions
/// of any new file (`0o666` less the umask), not the owner-only default of temporary files,
/// since it becomes the output.
fn temp_in(dir: &Path) -> Result<NamedTempFile, ExportError> {
    let mut builder = tempfile::Builder::new();
    builder.prefix(".dermis-").suffix(".tmp");
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        builder.permissions(std::fs::Permissions::from_mode(0o666));
    }
    builder
        .tempfile_in(dir)
        .map_err(|source| ExportError::UnwritableDirectory {
            path: dir.to_owned(),
            source,
        })
}

/// Checks that files can be created in the directory of `out` (creates and removes a
/// temporary file), so a bad `--out` fails before any simulation work.
pub(super) fn check_writable(out: &Path) -> Result<(), ExportError> {
    let dir = parent_dir(out);
    let tmp = temp_in(dir)?;
    tmp.close()
        .map_err(|source| ExportError::UnwritableDirectory {
            path: dir.to_owned(),
            source,
        })
}
