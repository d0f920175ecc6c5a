//! Whether `python3` can import a vendor SDK, shared by the SDK conformance tests.

use std::process::{Command, Stdio};

/// Runs `python3 -c IMPORTS`; on failure, `missing` and Python's last error line. Tried
/// twice: on a fresh machine the first imports run right after pip installed the package,
/// and one of two tests importing it at once has been seen to fail there.
pub fn sdk_importable(imports: &str, missing: &str) -> Result<(), String> {
    let mut last = String::new();
    for attempt in 0..2 {
        if attempt > 0 {
            std::thread::sleep(std::time::Duration::from_secs(2));
        }
        let out = Command::new("python3")
            .args(["-c", imports])
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .output()
            .map_err(|e| format!("python3 cannot run ({e})"))?;
        if out.status.success() {
            return Ok(());
        }
        last = String::from_utf8_lossy(&out.stderr)
            .lines()
            .last()
            .unwrap_or_default()
            .to_string();
    }
    Err(format!("{missing}: {last}"))
}
