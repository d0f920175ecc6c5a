//! The daemon with `[ros2]`: the active calibration reaches an independent ROS 2 peer (Cyclone
//! DDS, tests/ros2/tf_peer.py) on `/tf_static` when a calibration is activated, and again from
//! a restarted daemon, each time to a listener that joined after the edge was sent. In a cell
//! of several cameras every camera's edge is in that one message, also after one camera alone
//! was recalibrated.

#![cfg(feature = "ros2")]

#[path = "ros2/peers.rs"]
mod peers;

mod common;

use std::path::Path;

use easyhec::config::ros2::Ros2Settings;
use easyhec::geometry::from_rows;
use nalgebra::Isometry3;
use peers::{can_run_peers, in_private_network, max_difference, received_edge, received_edges};

/// Starts a calibration over HTTP, waits for it to end, and prints the active calibration.
const CALIBRATE: &str = r#"
import json, sys, time, urllib.request
base, token = "http://127.0.0.1:8787", sys.argv[1]
def call(method, path):
    req = urllib.request.Request(base + path, method=method, headers={"Authorization": "Bearer " + token})
    with urllib.request.urlopen(req, timeout=30) as r:
        return json.load(r)
job = call("POST", "/api/v1/calibrations")
for _ in range(1800):
    state = call("GET", "/api/v1/calibrations/" + job["id"])["state"]
    if state not in ("queued", "running"):
        break
    time.sleep(0.1)
print(json.dumps(call("GET", "/api/v1/calibration")))
"#;

/// The active calibration's base frame and `base_from_camera`, as the API returned them.
fn active_edge(active: &Path) -> (String, Isometry3<f64>) {
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(active).unwrap()).unwrap();
    let rows: [[f64; 4]; 4] =
        serde_json::from_value(v["result"]["camera_from_base"].clone()).unwrap();
    let base = v["result"]["base_link"].as_str().unwrap().to_string();
    (base, from_rows(&rows).unwrap().inverse())
}

#[test]
fn the_active_calibration_is_published_on_activation_and_after_a_restart() {
    if !can_run_peers() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    common::daemon::write_config(dir.path(), |c| {
        c.ros2 = Some(Ros2Settings {
            domain_id: Some(19),
            namespace: "/".into(),
            publish_tf: true,
            frame_id: None,
            child_frame_id: "cam_optical".into(),
            optical_from_child: None,
            listen_s: 1.0,
        })
    });
    std::fs::write(dir.path().join("calibrate.py"), CALIBRATE).unwrap();
    let token = common::daemon::TOKEN;
    let body = format!(
        r#"
start() {{ "$EASYHEC" daemon --config cell.toml --data data --listen 127.0.0.1:8787 2> "$1" & }}
start daemon1.log
d=$!
wait_for daemon1.log "listening on" || {{ cat daemon1.log; exit 3; }}
python3 calibrate.py {token} > active.json || exit 4
wait_for daemon1.log "on /tf_static" || {{ cat daemon1.log; exit 5; }}
timeout 60 python3 "$PEER" listen 19 30 cam_optical > got.json || exit 6
kill -TERM $d; wait $d
start daemon2.log
d=$!
wait_for daemon2.log "on /tf_static" || {{ cat daemon2.log; exit 7; }}
sleep 1
mv got.json got1.json
timeout 60 python3 "$PEER" listen 19 30 cam_optical > got.json || exit 8
kill -TERM $d; wait $d
echo "daemon exited $?"
cat daemon1.log daemon2.log
"#
    );
    let (ok, log) = in_private_network(dir.path(), &body);
    assert!(ok, "{log}");
    assert!(log.contains("daemon exited 0"), "{log}");
    let (base, want) = active_edge(&dir.path().join("active.json"));
    let (parent, after_restart) = received_edge(dir.path(), "cam_optical");
    std::fs::rename(dir.path().join("got1.json"), dir.path().join("got.json")).unwrap();
    let (parent1, on_activation) = received_edge(dir.path(), "cam_optical");
    assert_eq!((&parent, &parent1), (&base, &base));
    for (what, got) in [
        ("on activation", on_activation),
        ("after a restart", after_restart),
    ] {
        let diff = max_difference(&got, &want);
        assert!(diff < 1e-9, "{what}: {diff}");
    }
}

/// Calibrates every camera, then `front` alone, writing `GET /api/v1/cameras` after each to
/// cameras1.json and cameras2.json; waits for the daemon's /tf_static line between the two.
const CALIBRATE_LIST: &str = r#"
import json, subprocess, sys, time, urllib.request
base, token = "http://127.0.0.1:8787", sys.argv[1]
def call(method, path, body=None):
    data = None if body is None else json.dumps(body).encode()
    req = urllib.request.Request(base + path, data=data, method=method,
        headers={"Authorization": "Bearer " + token, "Content-Type": "application/json"})
    with urllib.request.urlopen(req, timeout=30) as r:
        return json.load(r)
def calibrate(body, out):
    job = call("POST", "/api/v1/calibrations", body)
    for _ in range(3000):
        if call("GET", "/api/v1/calibrations/" + job["id"])["state"] not in ("queued", "running"):
            break
        time.sleep(0.1)
    json.dump(call("GET", "/api/v1/cameras"), open(out, "w"))
    return job["id"]
calibrate(None, "cameras1.json")
"#;

/// Each camera's (id, base frame, base_from_camera) in a `GET /api/v1/cameras` answer.
fn active_edges(cameras: &Path) -> Vec<(String, String, String, Isometry3<f64>)> {
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(cameras).unwrap()).unwrap();
    v["cameras"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| {
            let a = &c["active"];
            let rows: [[f64; 4]; 4] =
                serde_json::from_value(a["result"]["camera_from_base"].clone()).unwrap();
            (
                c["camera"].as_str().unwrap().to_string(),
                a["id"].as_str().unwrap().to_string(),
                a["result"]["base_link"].as_str().unwrap().to_string(),
                from_rows(&rows).unwrap().inverse(),
            )
        })
        .collect()
}

/// What the peer received matches each camera's active entry: parent, `NAME_optical`, pose.
fn assert_every_camera_received(dir: &Path, cameras: &str) {
    let mut got = received_edges(dir);
    got.sort_by(|a, b| a.1.cmp(&b.1));
    let want = active_edges(&dir.join(cameras));
    assert_eq!(got.len(), want.len(), "{got:?}");
    for ((parent, child, pose), (name, id, base, base_from_camera)) in got.iter().zip(&want) {
        assert_eq!(child, &format!("{name}_optical"), "{cameras}");
        assert_eq!(parent, base, "{name} of {id}");
        let diff = max_difference(pose, base_from_camera);
        assert!(diff < 1e-9, "{name} of {id}: {diff}");
    }
}

#[test]
fn every_camera_of_a_list_is_published_and_a_lone_recalibration_keeps_the_others() {
    if !can_run_peers() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let config = common::daemon::write_shipped_config(dir.path(), "sim-xarm6-fixed-and-wrist.toml");
    let text = std::fs::read_to_string(&config).unwrap();
    std::fs::write(
        &config,
        format!("{text}\n[ros2]\ndomain_id = 21\nchild_frame_id = \"optical\"\nlisten_s = 1.0\n"),
    )
    .unwrap();
    let again = CALIBRATE_LIST.replace(
        "calibrate(None, \"cameras1.json\")",
        "calibrate({\"cameras\": [\"front\"]}, \"cameras2.json\")",
    );
    std::fs::write(dir.path().join("calibrate1.py"), CALIBRATE_LIST).unwrap();
    std::fs::write(dir.path().join("calibrate2.py"), again).unwrap();
    let token = common::daemon::TOKEN;
    let body = format!(
        r#"
"$EASYHEC" daemon --config cell.toml --data data --listen 127.0.0.1:8787 2> daemon.log &
d=$!
wait_for daemon.log "listening on" || {{ cat daemon.log; exit 3; }}
python3 calibrate1.py {token} || exit 4
wait_for daemon.log "wrist_optical on /tf_static" || {{ cat daemon.log; exit 5; }}
timeout 60 python3 "$PEER" listen 21 30 wrist_optical > got1.json || exit 6
python3 calibrate2.py {token} || exit 7
wait_for daemon.log "cal-0002: world -> front_optical on /tf_static" || {{ cat daemon.log; exit 8; }}
sleep 1
timeout 60 python3 "$PEER" listen 21 30 wrist_optical > got.json || exit 9
kill -TERM $d; wait $d
echo "daemon exited $?"
cat daemon.log
"#
    );
    let (ok, log) = in_private_network(dir.path(), &body);
    assert!(ok, "{log}");
    assert!(log.contains("daemon exited 0"), "{log}");
    let after = active_edges(&dir.path().join("cameras2.json"));
    let ids: Vec<(&str, &str)> = after
        .iter()
        .map(|(n, id, _, _)| (n.as_str(), id.as_str()))
        .collect();
    assert_eq!(ids, [("front", "cal-0002"), ("wrist", "cal-0001")], "{log}");
    assert_eq!(after[1].2, "link6");
    assert_every_camera_received(dir.path(), "cameras2.json");
    std::fs::rename(dir.path().join("got1.json"), dir.path().join("got.json")).unwrap();
    assert_every_camera_received(dir.path(), "cameras1.json");
}
