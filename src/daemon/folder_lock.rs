//! One daemon per data folder: an exclusive `flock` on `DATA/daemon.lock`, taken before the
//! daemon binds its port or repairs anything, and held for the life of the process. A second
//! daemon on the same folder fails at once, naming the holder's pid, and writes nothing. The
//! kernel drops the lock when the holder exits, however it exits, so a crash leaves no stale
//! lock behind (the pid in the file is then only a hint).

use std::fs::{File, OpenOptions};
use std::io::{Read, Seek, Write};
use std::path::Path;

use crate::error::{Error, Result};

/// The lock file's name inside the data folder.
pub const LOCK_FILE: &str = "daemon.lock";

/// The held lock; released when dropped (or when the process ends).
pub struct FolderLock {
    file: File,
}

impl FolderLock {
    /// Takes the lock on `dir`, creating the folder and the lock file when absent. Writes
    /// nothing else: the pid is recorded by [`FolderLock::record_pid`] once the daemon has
    /// bound its port.
    pub fn take(dir: &Path) -> Result<FolderLock> {
        std::fs::create_dir_all(dir)
            .map_err(|e| Error::io(dir, format!("cannot create the data folder: {e}")))?;
        let path = dir.join(LOCK_FILE);
        let mut file = OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(&path)
            .map_err(|e| Error::io(&path, format!("cannot open the data folder's lock: {e}")))?;
        if !try_lock(&file).map_err(|e| Error::io(&path, format!("cannot lock: {e}")))? {
            let mut text = String::new();
            let _ = Read::by_ref(&mut file).take(64).read_to_string(&mut text);
            let holder = match text.trim().parse::<u32>() {
                Ok(pid) => format!("pid {pid}"),
                Err(_) => "a process that has not yet recorded its pid".to_string(),
            };
            return Err(Error::io(
                dir,
                format!("another easyhec daemon ({holder}) is using this data folder; stop it first, or give this one another --data"),
            ));
        }
        Ok(FolderLock { file })
    }

    /// Writes this process's pid into the lock file, for a second daemon's message.
    pub fn record_pid(&mut self) {
        let pid = std::process::id();
        let _ = self.file.set_len(0);
        let _ = self.file.rewind();
        let _ = writeln!(self.file, "{pid}");
    }
}

/// Tries an exclusive, non-blocking lock: `Ok(false)` when another open file holds it.
#[cfg(unix)]
fn try_lock(file: &File) -> std::io::Result<bool> {
    use std::os::fd::AsRawFd;
    // SAFETY: flock on a file descriptor this File owns for the duration of the call.
    let r = unsafe { libc::flock(file.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) };
    if r == 0 {
        return Ok(true);
    }
    let e = std::io::Error::last_os_error();
    if e.raw_os_error() == Some(libc::EWOULDBLOCK) {
        return Ok(false);
    }
    Err(e)
}

/// Elsewhere the folder is not locked (the daemon targets Linux).
#[cfg(not(unix))]
fn try_lock(_file: &File) -> std::io::Result<bool> {
    Ok(true)
}
