//! `easyhec publish`: a result on ROS 2's `/tf_static` until stopped, as tf2_ros's static
//! transform publisher would send it, after checking that the edge keeps the tf tree a tree.

use std::path::PathBuf;

use clap::Args;

use super::frames::FrameArgs;

#[derive(Args)]
pub struct PublishArgs {
    /// easyhec-result/1 file, or an easyhec-result/2 file: every camera is published, each
    /// to its own child frame (--child-frame-id with {name}, else `<name>_` in front).
    pub result: PathBuf,
    #[command(flatten)]
    pub frames: FrameArgs,
    /// The camera driver's optical frame: read optical_from_child from the driver's fixed
    /// edges on /tf_static (from --child-frame-id down to this frame) instead of
    /// --optical-from-child.
    #[arg(long, conflicts_with = "optical_from_child")]
    pub optical_frame_id: Option<String>,
    /// DDS domain (default: ROS_DOMAIN_ID, else 0).
    #[arg(long)]
    pub domain_id: Option<u16>,
    /// Node namespace; tf topics resolve inside it (`/` gives /tf_static).
    #[arg(long, default_value = "/")]
    pub namespace: String,
    /// Seconds to listen to /tf and /tf_static before publishing: the other nodes' edges must
    /// be seen to refuse a child frame that already has a parent.
    #[arg(long, default_value_t = 3.0)]
    pub listen_s: f64,
}

/// Publishes until SIGINT or SIGTERM.
#[cfg(feature = "ros2")]
pub fn run(a: PublishArgs) -> anyhow::Result<()> {
    use anyhow::Context as _;
    use easyhec::config::ros2::MAX_LISTEN_S;
    use easyhec::error::Error;
    use easyhec::interop::export::check_frame_name;
    use easyhec::ros2::tf::{StaticTfPublisher, TfListener};
    use easyhec::ros2::{domain_id_from_env, join, GraphPlace};

    use super::frames::FLAGS;

    if !(0.0..=MAX_LISTEN_S).contains(&a.listen_s) {
        return Err(Error::Usage(format!(
            "--listen-s is {}; allowed: 0 to {MAX_LISTEN_S}",
            a.listen_s
        ))
        .into());
    }
    let results = easyhec::run::rig::ResultCameras::read(&a.result)?;
    let rig = results.layout == easyhec::run::rig::RunLayout::NamedCameras;
    if rig && a.optical_frame_id.is_some() {
        return Err(Error::Usage(
            "--optical-frame-id: the result holds several cameras, and a driver's frames belong to one; allowed: only for a result of one camera".into(),
        )
        .into());
    }
    let rig_edges = if rig {
        Some(a.frames.rig_edges(&results)?)
    } else {
        None
    };
    let result = results.cameras[0].result.clone();
    check_frame_name(&result.base_link)
        .map_err(|m| Error::input(&a.result, "base_link", format!("is {m}")))?;
    if let Some(optical) = &a.optical_frame_id {
        check_frame_name(optical)
            .map_err(|m| Error::Usage(format!("--optical-frame-id is {m}")))?;
    }
    // The flags alone must describe a valid edge before anything joins the graph (a rig's
    // edges were built, and so checked, above; its `{name}` pattern is no frame by itself).
    if rig_edges.is_none() {
        a.frames.edge(&result)?;
    }
    let place = GraphPlace {
        domain_id: match a.domain_id {
            Some(d) => d,
            None => domain_id_from_env()?,
        },
        namespace: a.namespace.clone(),
        node_name: "easyhec_publish".into(),
    };
    easyhec::config::ros2::check_namespace(&place.namespace)
        .map_err(|m| Error::Usage(format!("--namespace is {m}")))?;
    if place.domain_id > easyhec::config::ros2::MAX_DOMAIN_ID {
        return Err(Error::Usage(format!(
            "--domain-id is {}; allowed: 0 to {}",
            place.domain_id,
            easyhec::config::ros2::MAX_DOMAIN_ID
        ))
        .into());
    }
    let (_context, mut node) = join(&place)?;
    let mut listener = TfListener::new(&mut node, &place.namespace)?;
    let tree = listener.gather(std::time::Duration::from_secs_f64(a.listen_s), None)?;
    let edges = match (rig_edges, &a.optical_frame_id) {
        (Some(edges), _) => edges,
        (None, None) => vec![a.frames.edge(&result)?],
        (None, Some(optical)) => {
            let child = &a.frames.child_frame_id;
            let child_from_optical = tree.static_chain(child, optical).ok_or_else(|| {
                Error::Usage(format!(
                    "--optical-frame-id: no chain of /tf_static edges from {child:?} down to {optical:?} was seen in {} s; \
                     allowed: the driver's optical frame below --child-frame-id, or --optical-from-child",
                    a.listen_s
                ))
            })?;
            vec![easyhec::interop::TfEdge::from_result(
                &result,
                a.frames.frame_id.as_deref(),
                child,
                Some(&child_from_optical.inverse()),
                FLAGS,
            )?]
        }
    };
    for edge in &edges {
        tree.check_can_add(edge)?;
    }
    let publisher = StaticTfPublisher::new(&mut node, &place.namespace)?;
    publisher.send(&edges)?;
    let names: Vec<String> = edges
        .iter()
        .map(|e| format!("{} -> {}", e.parent, e.child))
        .collect();
    tracing::info!(
        "easyhec publish: {} on /tf_static (domain {}, {} other frames seen); stop with Ctrl-C",
        names.join(", "),
        place.domain_id,
        tree.len()
    );
    tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .context("starting the signal runtime")?
        .block_on(wait_for_stop())
}

#[cfg(feature = "ros2")]
async fn wait_for_stop() -> anyhow::Result<()> {
    use tokio::signal::unix::{signal, SignalKind};
    let mut term = signal(SignalKind::terminate())?;
    tokio::select! {
        r = tokio::signal::ctrl_c() => r?,
        _ = term.recv() => {}
    }
    Ok(())
}

/// Without ROS 2 support, says how to get it.
#[cfg(not(feature = "ros2"))]
pub fn run(_a: PublishArgs) -> anyhow::Result<()> {
    Err(easyhec::error::Error::Usage(
        "publish needs ROS 2 support, which this build leaves out: rebuild with --features ros2"
            .into(),
    )
    .into())
}
