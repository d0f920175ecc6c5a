//! The dashboard server (29999) and the script port (30003) of the mock controller.
//!
//! The dashboard answers one line per command with the reply strings clients match on
//! (docs/protocols.md §2.6). State-changing commands are refused while the controller is not in
//! remote control; the refusal text is this mock's choice (no document pins it down).

use std::sync::Arc;

use easyhec_drivers::ur::model::{
    self, RUNTIME_PLAYING, SAFETY_MODE_NORMAL, SAFETY_MODE_PROTECTIVE_STOP,
};
use tokio::io::{AsyncBufReadExt, AsyncReadExt, AsyncWriteExt, BufReader};
use tokio::net::TcpStream;

use super::controller::{Controller, RUNTIME_PAUSED};
use super::{closed, ScriptUpload, Shared};

/// The greeting a dashboard client reads first.
pub const GREETING: &str = "Connected: Universal Robots Dashboard Server";

/// Commands that change the controller's state and need remote control.
const NEEDS_REMOTE: [&str; 10] = [
    "power on",
    "power off",
    "brake release",
    "play",
    "stop",
    "pause",
    "load",
    "unlock protective stop",
    "restart safety",
    "shutdown",
];

/// The reply to one dashboard command line.
pub(super) fn reply(c: &mut Controller, line: &str) -> String {
    let cmd = line.trim();
    c.dashboard.push(cmd.to_string());
    let lower = cmd.to_ascii_lowercase();
    let gated = NEEDS_REMOTE
        .iter()
        .any(|g| lower == *g || (lower.starts_with(g) && lower[g.len()..].starts_with(' ')));
    if gated && !c.remote_control {
        return "Command is not allowed due to robot being in local control mode: switch the pendant to remote control".into();
    }
    let v = &c.cfg.version;
    match lower.as_str() {
        "robotmode" => format!("Robotmode: {}", model::robot_mode_name(c.robot_mode)),
        "safetymode" => format!("Safetymode: {}", model::safety_mode_name(c.safety_mode)),
        "safetystatus" => format!("Safetystatus: {}", model::safety_mode_name(c.safety_mode)),
        "is in remote control" => c.remote_control.to_string(),
        "polyscopeversion" => format!(
            "URSoftware {}.{}.{}.{} (Mar 24 2022)",
            v[0], v[1], v[2], v[3]
        ),
        "get serial number" => c.cfg.serial_number.clone(),
        "get robot model" => "UR5".into(),
        "running" => format!("Program running: {}", c.runtime == RUNTIME_PLAYING),
        "programstate" => {
            let state = match c.runtime {
                RUNTIME_PLAYING => "PLAYING",
                RUNTIME_PAUSED => "PAUSED",
                _ => "STOPPED",
            };
            format!("{state} rtde_control")
        }
        "get loaded program" => "Loaded program: <unnamed>".into(),
        "isprogramsaved" => "true <unnamed>".into(),
        "power on" => {
            if c.robot_mode < 5 {
                c.robot_mode = 5;
            }
            "Powering on".into()
        }
        "brake release" => {
            if c.robot_mode >= 4 {
                c.robot_mode = model::ROBOT_MODE_RUNNING;
            }
            "Brake releasing".into()
        }
        "power off" => {
            c.stop_program("powered off");
            c.robot_mode = 3;
            "Powering off".into()
        }
        "stop" => {
            c.stop_program("stopped (dashboard)");
            "Stopped".into()
        }
        "pause" => {
            c.halt("paused (dashboard)");
            if c.runtime == RUNTIME_PLAYING {
                c.runtime = RUNTIME_PAUSED;
            }
            "Pausing program".into()
        }
        "play" => {
            if c.runtime == RUNTIME_PAUSED && c.safety_mode == SAFETY_MODE_NORMAL {
                c.runtime = RUNTIME_PLAYING;
                "Starting program".into()
            } else {
                "Failed to execute: play".into()
            }
        }
        "unlock protective stop" => {
            if c.safety_mode == SAFETY_MODE_PROTECTIVE_STOP {
                c.safety_mode = SAFETY_MODE_NORMAL;
            }
            "Protective stop releasing".into()
        }
        "close safety popup" => "closing safety popup".into(),
        "close popup" => "closing popup".into(),
        "restart safety" => {
            c.stop_program("safety restarted");
            c.safety_mode = SAFETY_MODE_NORMAL;
            c.robot_mode = 3;
            "Restarting safety".into()
        }
        "shutdown" => "Shutting down".into(),
        "quit" => "Disconnected".into(),
        _ if lower.starts_with("load ") => format!("Loading program: {}", &cmd[5..]),
        _ if lower.starts_with("popup ") => "showing popup".into(),
        _ if lower.starts_with("addtolog ") => "Added log message".into(),
        _ if lower.starts_with("setuserrole ") => "Setting user role".into(),
        _ => format!("could not understand: '{cmd}'"),
    }
}

pub(super) async fn serve_dashboard(shared: Arc<Shared>, stream: TcpStream, generation: u64) {
    let mut rx = shared.links.subscribe();
    let (read, mut write) = stream.into_split();
    if write
        .write_all(format!("{GREETING}\n").as_bytes())
        .await
        .is_err()
    {
        return;
    }
    let mut lines = BufReader::new(read).lines();
    loop {
        let line = tokio::select! {
            l = lines.next_line() => match l {
                Ok(Some(l)) => l,
                _ => return,
            },
            _ = closed(&mut rx, generation) => return,
        };
        let answer = shared.with(|c| reply(c, &line));
        if write
            .write_all(format!("{answer}\n").as_bytes())
            .await
            .is_err()
        {
            return;
        }
        if answer == "Disconnected" {
            return;
        }
    }
}

/// Moves complete top-level items out of `buf` into `out`: programs (`def name():` … `end`
/// at column 0) and single top-level statements (`stopj(2)`). An unfinished program stays.
fn take_programs(buf: &mut String, out: &mut Vec<String>) {
    'scan: loop {
        let mut pos = 0;
        let mut def_start: Option<usize> = None;
        for line in buf.split_inclusive('\n') {
            if !line.ends_with('\n') {
                break;
            }
            let start = pos;
            pos += line.len();
            let text = line.trim_end();
            let item = match def_start {
                None if text.starts_with("def ") || text.starts_with("sec ") => {
                    def_start = Some(start);
                    None
                }
                None if text.trim().is_empty() => None,
                None => Some(start..pos),
                Some(s) if text == "end" => Some(s..pos),
                Some(_) => None,
            };
            if let Some(range) = item {
                out.push(buf[range.clone()].to_string());
                buf.replace_range(..range.end, "");
                continue 'scan;
            }
        }
        if def_start.is_none() {
            // Only blank lines (and maybe a partial line) remain.
            buf.replace_range(..pos, "");
        }
        return;
    }
}

pub(super) async fn serve_script(shared: Arc<Shared>, mut stream: TcpStream, generation: u64) {
    let mut rx = shared.links.subscribe();
    let mut buf = String::new();
    let mut chunk = vec![0u8; 16384];
    loop {
        let n = tokio::select! {
            r = stream.read(&mut chunk) => match r {
                Ok(0) | Err(_) => return,
                Ok(n) => n,
            },
            _ = closed(&mut rx, generation) => return,
        };
        buf.push_str(&String::from_utf8_lossy(&chunk[..n]));
        let mut programs = Vec::new();
        take_programs(&mut buf, &mut programs);
        for text in programs {
            let first = text.lines().next().unwrap_or("").trim().to_string();
            shared.with(|c| {
                if first.starts_with("def ") || first.starts_with("sec ") {
                    c.start_script(ScriptUpload {
                        first_line: first.clone(),
                        bytes: text.len(),
                    });
                } else if first.starts_with("stopj")
                    || first.starts_with("stopl")
                    || first.starts_with("halt")
                {
                    c.stop_program("stopped (script)");
                } else {
                    c.uploads.push(ScriptUpload {
                        first_line: first.clone(),
                        bytes: text.len(),
                    });
                }
            });
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn programs_are_cut_at_top_level_end() {
        let mut buf =
            String::from("def a():\n  if x:\n    y()\n  end\nend\nstopj(2)\ndef b():\n  z()\n");
        let mut out = Vec::new();
        take_programs(&mut buf, &mut out);
        assert_eq!(out.len(), 2, "{out:?}");
        assert!(out[0].starts_with("def a():") && out[0].ends_with("end\n"));
        assert_eq!(out[1], "stopj(2)\n");
        assert_eq!(buf, "def b():\n  z()\n");
        buf.push_str("end\n");
        take_programs(&mut buf, &mut out);
        assert_eq!(out.len(), 3);
        assert!(buf.is_empty());
    }
}
