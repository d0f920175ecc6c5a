//! `easyhec sim-camera`: a simulated cell's camera as a ROS 2 camera driver. It renders the
//! robot at the joints its config's `joints_from` reads (a ROS 2 arm's `/joint_states`, a
//! controller's report port) and publishes `sensor_msgs/Image` (rgb8, stamped when the joints
//! were read) and `sensor_msgs/CameraInfo`, so a ROS 2 pipeline, or easyhec's own
//! `[camera] kind = "ros2"`, can be tried without a camera.

use std::path::PathBuf;

use clap::Args;

#[derive(Args)]
pub struct SimCameraArgs {
    /// Cell config with `[camera] kind = "sim"` (and `[ros2]` for the domain).
    #[arg(long)]
    pub config: PathBuf,
    /// Image topic.
    #[arg(long, default_value = "/camera/color/image_raw")]
    pub image_topic: String,
    /// CameraInfo topic.
    #[arg(long, default_value = "/camera/color/camera_info")]
    pub camera_info_topic: String,
    /// The images' frame_id (the optical frame).
    #[arg(long, default_value = "easyhec_camera_optical_frame")]
    pub frame_id: String,
    /// Frames per second, 0.1 to 60.
    #[arg(long, default_value_t = 10.0)]
    pub rate_hz: f64,
}

/// Publishes until SIGINT or SIGTERM.
#[cfg(feature = "ros2")]
pub fn run(a: SimCameraArgs) -> anyhow::Result<()> {
    use easyhec::error::Error;
    /// Fastest frame rate accepted, Hz.
    const MAX_RATE_HZ: f64 = 60.0;
    if !(a.rate_hz.is_finite() && (0.1..=MAX_RATE_HZ).contains(&a.rate_hz)) {
        return Err(Error::Usage(format!(
            "--rate-hz is {}; allowed: 0.1 to {MAX_RATE_HZ}",
            a.rate_hz
        ))
        .into());
    }
    for (flag, topic) in [
        ("--image-topic", &a.image_topic),
        ("--camera-info-topic", &a.camera_info_topic),
    ] {
        easyhec::config::ros2::check_topic(topic)
            .map_err(|m| Error::Usage(format!("{flag} is {m}")))?;
    }
    easyhec::config::ros2::check_frame_name(&a.frame_id)
        .map_err(|m| Error::Usage(format!("--frame-id is {m}")))?;
    let config = easyhec::config::read_config(&a.config)?;
    config.camera.require_one(&a.config, "easyhec sim-camera")?;
    let cell = easyhec::cell::Cell::build(config, &a.config)?;
    if cell.units[0].sim.camera.is_none() {
        return Err(Error::input(
            &a.config,
            "camera.kind",
            "sim-camera publishes a simulated camera; allowed: [camera] kind = \"sim\"",
        )
        .into());
    }
    let ros2 = cell.config.ros2.as_ref();
    let place = easyhec::ros2::GraphPlace {
        domain_id: easyhec::config::ros2::Ros2Settings::domain(ros2)?,
        namespace: easyhec::config::ros2::Ros2Settings::namespace_of(ros2),
        node_name: "easyhec_sim_camera".into(),
    };
    let publisher = easyhec::ros2::camera_out::CameraPublisher::new(
        &place,
        &a.image_topic,
        &a.camera_info_topic,
        &a.frame_id,
    )?;
    tracing::info!(
        "easyhec sim-camera: publishing {} and {} at {} Hz (domain {}); stop with Ctrl-C",
        a.image_topic,
        a.camera_info_topic,
        a.rate_hz,
        place.domain_id
    );
    let camera = &cell.units[0].device;
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    runtime.block_on(async {
        let mut tick = tokio::time::interval(std::time::Duration::from_secs_f64(1.0 / a.rate_hz));
        let mut term = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())?;
        loop {
            tokio::select! {
                _ = tokio::signal::ctrl_c() => return Ok(()),
                _ = term.recv() => return Ok(()),
                _ = tick.tick() => {
                    // Stamped before the joints are read: the exposure happened no earlier.
                    let exposed = std::time::SystemTime::now();
                    let frame = camera.grab().await?;
                    publisher.send(&frame, camera.intrinsics(), exposed)?;
                }
            }
        }
    })
}

/// Without ROS 2 support, says how to get it.
#[cfg(not(feature = "ros2"))]
pub fn run(_a: SimCameraArgs) -> anyhow::Result<()> {
    Err(easyhec::error::Error::Usage(
        "sim-camera needs ROS 2 support, which this build leaves out: rebuild with --features ros2"
            .into(),
    )
    .into())
}
