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

/// The output policy of every command, for a file it writes (`--out`): why `out` may not
/// be written, if it may not. An existing `out` must be a regular file (writing through a
/// temporary file and a rename would replace a device node, a FIFO or a symbolic link), and
/// it must not be one of `reads`, the files the command reads: a result written over its own
/// input would leave a run that no longer solves.
pub fn output_file_problem(out: &Path, reads: &[std::path::PathBuf]) -> Option<String> {
    if let Some(problem) = existing_output_problem(out, false) {
        return Some(problem);
    }
    let target = resolved(out);
    reads.iter().find(|r| resolved(r) == target).map(|r| {
        format!(
            "is {}, which this command reads; allowed: a path that is none of its inputs",
            r.display()
        )
    })
}

/// The output policy for a folder a command writes into or replaces: an existing `dir` must
/// be a folder (not a link to one), it must not hold any of `reads` (a file it would write
/// could be one of them, and a replaced folder would delete them), and it must not lie
/// inside a folder among `reads` (the command would write into its own source).
pub fn output_dir_problem(dir: &Path, reads: &[std::path::PathBuf]) -> Option<String> {
    if let Some(problem) = existing_output_problem(dir, true) {
        return Some(problem);
    }
    let target = resolved(dir);
    for r in reads {
        let read = resolved(r);
        if read.starts_with(&target) {
            return Some(format!(
                "holds {}, which this command reads; allowed: a folder that holds none of its inputs",
                r.display()
            ));
        }
        if target.starts_with(&read) && r.is_dir() {
            return Some(format!(
                "lies inside {}, a folder this command reads; allowed: a folder outside its inputs",
                r.display()
            ));
        }
    }
    None
}

/// An existing output that is a link, or not the kind of entry the command writes.
fn existing_output_problem(out: &Path, folder: bool) -> Option<String> {
    let meta = std::fs::symlink_metadata(out).ok()?;
    if meta.file_type().is_symlink() {
        return Some("is a symbolic link, which writing would replace; allowed: a new path, or the file or folder itself".into());
    }
    match (folder, meta.is_dir(), meta.is_file()) {
        (true, false, _) => Some("exists and is not a folder; allowed: a new path or a folder".into()),
        (false, _, false) => Some("exists and is not a regular file (a device, FIFO or folder); allowed: a new path or a regular file".into()),
        _ => None,
    }
}

/// `p` with links and `..` resolved as far as it exists: a path that does not exist yet
/// is its resolved parent joined with its name.
fn resolved(p: &Path) -> std::path::PathBuf {
    if let Ok(real) = std::fs::canonicalize(p) {
        return real;
    }
    let absolute = std::path::absolute(p).unwrap_or_else(|_| p.to_path_buf());
    match (absolute.parent(), absolute.file_name()) {
        (Some(parent), Some(name)) => resolved(parent).join(name),
        _ => absolute,
    }
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
