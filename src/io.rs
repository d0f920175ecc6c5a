//! File I/O with guarantees. Writes are crash-safe: temp file in the same folder, fsync,
//! rename, fsync the folder, so a reader sees the old file or the new one, never half of one.
//! Whole-file reads of user inputs check first that the path is a bounded regular file.

use std::io::Write;
use std::path::Path;

use crate::error::{Error, Result};

/// Atomically replaces `path` with `bytes`.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    std::fs::create_dir_all(dir)
        .map_err(|e| Error::io(dir, format!("cannot create folder: {e}")))?;
    let mut tmp = tempfile::NamedTempFile::new_in(dir)
        .map_err(|e| Error::io(dir, format!("cannot create temp file: {e}")))?;
    tmp.write_all(bytes)
        .map_err(|e| Error::io(path, format!("write failed: {e}")))?;
    // Temp files are created 0600; results and recordings are meant to be shared.
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        tmp.as_file()
            .set_permissions(std::fs::Permissions::from_mode(0o644))
            .map_err(|e| Error::io(path, format!("cannot set permissions: {e}")))?;
    }
    tmp.as_file()
        .sync_all()
        .map_err(|e| Error::io(path, format!("fsync failed: {e}")))?;
    tmp.persist(path)
        .map_err(|e| Error::io(path, format!("rename failed: {}", e.error)))?;
    if let Ok(d) = std::fs::File::open(dir) {
        let _ = d.sync_all();
    }
    Ok(())
}

/// Serialises `value` as pretty JSON and writes it atomically.
pub fn write_json_atomic<T: serde::Serialize>(path: &Path, value: &T) -> Result<()> {
    let mut bytes = serde_json::to_vec_pretty(value)
        .map_err(|e| Error::io(path, format!("cannot serialise: {e}")))?;
    bytes.push(b'\n');
    write_atomic(path, &bytes)
}

/// Largest text input read whole (a run.json, a cell config, a result, a URDF): far above any
/// real one, low enough that a wrong path never fills memory.
pub const MAX_TEXT_INPUT_BYTES: u64 = 64 * 1024 * 1024;

/// Why a file with metadata `meta` cannot be read as an input of at most `max_bytes`, if it
/// cannot: a FIFO or a device would block or never end, and a huge file would fill memory.
pub fn input_file_problem(meta: &std::fs::Metadata, max_bytes: u64) -> Option<String> {
    if !meta.is_file() {
        return Some("is not a regular file".into());
    }
    (meta.len() > max_bytes)
        .then(|| format!("is {} bytes; allowed: at most {max_bytes}", meta.len()))
}

/// Reads a whole text input after checking that it is a regular file of at most
/// [`MAX_TEXT_INPUT_BYTES`].
pub fn read_text_input(path: &Path) -> Result<String> {
    let meta = std::fs::metadata(path).map_err(|e| Error::io(path, format!("cannot read: {e}")))?;
    if let Some(problem) = input_file_problem(&meta, MAX_TEXT_INPUT_BYTES) {
        return Err(Error::input(path, "(file)", problem));
    }
    std::fs::read_to_string(path).map_err(|e| Error::io(path, format!("cannot read: {e}")))
}
