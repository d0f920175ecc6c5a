//! `easyhec publish` against an independent ROS 2 implementation: Eclipse Cyclone DDS's Python
//! binding (tests/ros2/tf_peer.py) plays the other nodes. Every run happens in a private
//! network namespace (`unshare --net`, multicast on loopback), so no DDS traffic leaves the
//! machine and parallel tests cannot hear each other.

#![cfg(feature = "ros2")]

#[path = "ros2/peers.rs"]
mod peers;

use std::path::Path;

use peers::{can_run_peers, in_private_network, max_difference, received_edge, received_edges};

use easyhec::geometry::{exp_se3, Twist};
use easyhec::run::ResultFile;
use nalgebra::{Isometry3, Translation3, UnitQuaternion};

fn write_result(dir: &Path) -> Isometry3<f64> {
    let camera_from_base = exp_se3(&Twist::new(0.31, -0.27, 1.13, 0.52, -1.21, 2.03));
    easyhec::io::write_json_atomic(
        &dir.join("result.json"),
        &ResultFile::new(&camera_from_base, "link_base"),
    )
    .unwrap();
    camera_from_base.inverse()
}

/// A late joiner (started after the edge was sent) gets it, with the right frames and the
/// result's numbers to 1e-9; the publisher stops cleanly on SIGTERM.
#[test]
fn a_late_joiner_receives_the_calibration_on_tf_static() {
    if !can_run_peers() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let base_from_optical = write_result(dir.path());
    let (ok, log) = in_private_network(
        dir.path(),
        r#"
"$EASYHEC" publish result.json --child-frame-id cam_optical --domain-id 17 --listen-s 1 2> publish.log &
pid=$!
wait_for publish.log "on /tf_static" || { cat publish.log; exit 3; }
sleep 2
timeout 60 python3 "$PEER" listen 17 30 > got.json
status=$?
kill -TERM $pid
wait $pid
echo "publish exited $?"
cat publish.log
exit $status
"#,
    );
    assert!(ok, "{log}");
    assert!(log.contains("publish exited 0"), "{log}");
    let (parent, got) = received_edge(dir.path(), "cam_optical");
    assert_eq!(parent, "link_base");
    let diff = max_difference(&got, &base_from_optical);
    assert!(diff < 1e-9, "{diff}");
}

/// Edges a RealSense-like driver latches: camera_link → camera_color_frame →
/// camera_color_optical_frame, as `PARENT CHILD x y z qx qy qz qw` words.
fn driver_edges() -> (Vec<String>, Isometry3<f64>) {
    let link_from_color = Isometry3::from_parts(
        Translation3::new(-0.000_21, 0.014_87, 0.000_33),
        UnitQuaternion::from_euler_angles(0.0012, -0.0031, 0.0047),
    );
    let color_from_optical = Isometry3::from_parts(
        Translation3::identity(),
        UnitQuaternion::from_euler_angles(
            -std::f64::consts::FRAC_PI_2,
            0.0,
            -std::f64::consts::FRAC_PI_2,
        ),
    );
    let mut words = Vec::new();
    for (parent, child, pose) in [
        ("camera_link", "camera_color_frame", &link_from_color),
        (
            "camera_color_frame",
            "camera_color_optical_frame",
            &color_from_optical,
        ),
    ] {
        let t = pose.translation.vector;
        let q = pose.rotation;
        words.extend([parent.to_string(), child.to_string()]);
        words.extend([t.x, t.y, t.z, q.i, q.j, q.k, q.w].map(|v| format!("{v:?}")));
    }
    (words, link_from_color * color_from_optical)
}

/// Beside a running camera driver: publishing to the driver's optical frame (which has a
/// parent) is refused with one clear line, and publishing to its root link with the chain
/// read from /tf_static gives the edge that makes base → optical what the result holds.
#[test]
fn beside_a_camera_driver_the_edge_goes_to_its_root_link() {
    if !can_run_peers() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let base_from_optical = write_result(dir.path());
    let (words, link_from_optical) = driver_edges();
    let body = format!(
        r#"
python3 "$PEER" latch 18 {words} > driver.log 2>&1 &
driver=$!
wait_for driver.log latched || {{ cat driver.log; exit 3; }}
"$EASYHEC" publish result.json --child-frame-id camera_color_optical_frame --domain-id 18 --listen-s 3 2> refused.log
echo "refused exit $?"
cat refused.log
"$EASYHEC" publish result.json --child-frame-id camera_link --optical-frame-id camera_color_optical_frame --domain-id 18 --listen-s 3 2> publish.log &
pid=$!
wait_for publish.log "on /tf_static" || {{ cat publish.log; exit 4; }}
timeout 60 python3 "$PEER" listen 18 30 camera_link > got.json
status=$?
kill -TERM $pid $driver
wait $pid
echo "publish exited $?"
cat publish.log
exit $status
"#,
        words = words.join(" ")
    );
    let (ok, log) = in_private_network(dir.path(), &body);
    assert!(ok, "{log}");
    assert!(log.contains("refused exit 1"), "{log}");
    assert!(
        log.contains("\"camera_color_optical_frame\" already has the parent \"camera_color_frame\" on /tf_static"),
        "{log}"
    );
    assert!(log.contains("publish exited 0"), "{log}");
    let (parent, base_from_link) = received_edge(dir.path(), "camera_link");
    assert_eq!(parent, "link_base");
    let diff = max_difference(&(base_from_link * link_from_optical), &base_from_optical);
    assert!(diff < 1e-9, "{diff}");
}

/// A frame that moves on `/tf` (an arm's tool, say) already has a parent too: refused, naming
/// `/tf`, and nothing is published.
#[test]
fn a_frame_with_a_parent_on_tf_is_refused() {
    if !can_run_peers() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    write_result(dir.path());
    let (ok, log) = in_private_network(
        dir.path(),
        r#"
python3 "$PEER" broadcast 23 link_base tool0 0.1 0.2 0.3 0.0 0.0 0.0 1.0 > arm.log 2>&1 &
arm=$!
wait_for arm.log broadcasting || { cat arm.log; exit 3; }
"$EASYHEC" publish result.json --child-frame-id tool0 --domain-id 23 --listen-s 2 2> refused.log
echo "refused exit $?"
kill $arm
cat refused.log
"#,
    );
    assert!(ok, "{log}");
    assert!(log.contains("refused exit 1"), "{log}");
    assert!(
        log.contains("\"tool0\" already has the parent \"link_base\" on /tf,"),
        "{log}"
    );
    assert!(!log.contains("on /tf_static (domain"), "{log}");
}

/// A result of several cameras (`easyhec-result/2`) goes out as one message with an edge per
/// camera, each to the camera's own child frame and with its own numbers.
#[test]
fn every_camera_of_a_rig_result_is_published_to_its_own_frame() {
    use easyhec::run::rig::{CameraResult, RigResultFile, RIG_RESULT_FORMAT};
    if !can_run_peers() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let poses = [
        exp_se3(&Twist::new(0.31, -0.27, 1.13, 0.52, -1.21, 2.03)),
        exp_se3(&Twist::new(-0.4, 0.2, 1.4, 1.1, 0.3, -0.7)),
    ];
    let rig = RigResultFile {
        format: RIG_RESULT_FORMAT.into(),
        cameras: ["front", "side"]
            .iter()
            .zip(&poses)
            .map(|(name, p)| CameraResult::of(name, &ResultFile::new(p, "link_base")))
            .collect(),
        stop_reason: String::new(),
        timings_s: Default::default(),
        joint_corrections: None,
    };
    easyhec::io::write_json_atomic(&dir.path().join("result.json"), &rig).unwrap();
    let (ok, log) = in_private_network(
        dir.path(),
        r#"
"$EASYHEC" publish result.json --child-frame-id '{name}_optical' --domain-id 18 --listen-s 1 2> publish.log &
pid=$!
wait_for publish.log "on /tf_static" || { cat publish.log; exit 3; }
sleep 2
timeout 60 python3 "$PEER" listen 18 30 > got.json
status=$?
kill -TERM $pid
wait $pid
cat publish.log
exit $status
"#,
    );
    assert!(ok, "{log}");
    let mut edges = received_edges(dir.path());
    edges.sort_by(|a, b| a.1.cmp(&b.1));
    assert_eq!(edges.len(), 2, "{log}");
    for ((parent, child, got), (name, pose)) in
        edges.iter().zip(["front", "side"].iter().zip(&poses))
    {
        assert_eq!(parent, "link_base");
        assert_eq!(child, &format!("{name}_optical"));
        let diff = max_difference(got, &pose.inverse());
        assert!(diff < 1e-9, "{name}: {diff}");
    }
}
