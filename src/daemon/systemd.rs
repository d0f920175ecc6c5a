//! The systemd service protocol (`sd_notify`), for `contrib/easyhec.service`: readiness once
//! the daemon listens, watchdog pings while its runtime runs, and a stopping notice. Outside
//! systemd (`NOTIFY_SOCKET` unset) every call does nothing.

use std::ffi::OsStr;
use std::os::unix::net::UnixDatagram;
use std::time::Duration;

/// Sends `state` (newline-separated `KEY=VALUE` lines) to the service manager when it asked
/// for notifications; errors are ignored, since a lost notice must not stop the daemon.
pub fn notify(state: &str) {
    if let Some(socket) = std::env::var_os("NOTIFY_SOCKET") {
        let _ = notify_to(&socket, state);
    }
}

/// Sends `state` to the datagram socket `socket`: a path, or `@name` for Linux's abstract
/// namespace.
pub fn notify_to(socket: &OsStr, state: &str) -> std::io::Result<()> {
    let sender = UnixDatagram::unbound()?;
    let bytes = socket.as_encoded_bytes();
    if let Some(name) = bytes.strip_prefix(b"@") {
        #[cfg(target_os = "linux")]
        {
            use std::os::linux::net::SocketAddrExt;
            let addr = std::os::unix::net::SocketAddr::from_abstract_name(name)?;
            sender.send_to_addr(state.as_bytes(), &addr)?;
            return Ok(());
        }
        #[cfg(not(target_os = "linux"))]
        return Err(std::io::Error::other(format!(
            "abstract socket {} needs Linux",
            String::from_utf8_lossy(name)
        )));
    }
    sender.send_to(state.as_bytes(), socket)?;
    Ok(())
}

/// How often to ping the watchdog: half the interval systemd set (`WATCHDOG_USEC`) when it is
/// meant for this process (`WATCHDOG_PID` unset or ours); `None` without a watchdog.
pub fn watchdog_period() -> Option<Duration> {
    let usec = std::env::var("WATCHDOG_USEC").ok()?;
    let pid = std::env::var("WATCHDOG_PID").ok();
    period_from(&usec, pid.as_deref(), std::process::id())
}

fn period_from(usec: &str, pid: Option<&str>, own_pid: u32) -> Option<Duration> {
    if pid.is_some_and(|p| p.trim().parse::<u32>().ok() != Some(own_pid)) {
        return None;
    }
    let usec: u64 = usec.trim().parse().ok().filter(|&u| u > 0)?;
    Some(Duration::from_micros(usec / 2))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn notices_reach_a_path_socket() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("notify");
        let manager = UnixDatagram::bind(&path).unwrap();
        notify_to(path.as_os_str(), "READY=1\nSTATUS=listening").unwrap();
        let mut buf = [0u8; 64];
        let n = manager.recv(&mut buf).unwrap();
        assert_eq!(&buf[..n], b"READY=1\nSTATUS=listening");
        assert!(notify_to(dir.path().join("absent").as_os_str(), "READY=1").is_err());
    }

    #[cfg(target_os = "linux")]
    #[test]
    fn notices_reach_an_abstract_socket() {
        use std::os::linux::net::SocketAddrExt;
        let name = format!("easyhec-test-{}", std::process::id());
        let addr = std::os::unix::net::SocketAddr::from_abstract_name(name.as_bytes()).unwrap();
        let manager = UnixDatagram::bind_addr(&addr).unwrap();
        notify_to(OsStr::new(&format!("@{name}")), "WATCHDOG=1").unwrap();
        let mut buf = [0u8; 16];
        let n = manager.recv(&mut buf).unwrap();
        assert_eq!(&buf[..n], b"WATCHDOG=1");
    }

    #[test]
    fn watchdog_period_is_half_the_interval_and_only_for_this_process() {
        assert_eq!(
            period_from("30000000", None, 7),
            Some(Duration::from_secs(15))
        );
        assert_eq!(
            period_from("30000000", Some("7"), 7),
            Some(Duration::from_secs(15))
        );
        assert_eq!(period_from("30000000", Some("8"), 7), None);
        assert_eq!(period_from("0", None, 7), None);
        assert_eq!(period_from("soon", None, 7), None);
    }
}
