//! `[ros2]` in the daemon: the active calibration on `/tf_static`, published at start and
//! again whenever another calibration becomes active. One thread owns the ROS 2 node, so a
//! slow graph (the listening window before each publication) never holds up the HTTP API;
//! activations queue to it and only the newest is published.
//!
//! In a cell of several cameras every camera's active edge goes out in one message, each to
//! its own child frame: a `/tf_static` writer keeps only its last message for late joiners,
//! so recalibrating one camera must send the others' edges again too. For the same reason a
//! set with one refused edge is not sent at all: a message without that camera would take
//! its earlier edge off `/tf_static`.

use std::sync::mpsc;
use std::time::Duration;

use crate::config::ros2::Ros2Settings;
use crate::error::{Error, Result};
use crate::interop::TfEdge;
use crate::ros2::tf::{StaticTfPublisher, TfListener};
use crate::ros2::{domain_id_from_env, join, GraphPlace};
use crate::run::ResultFile;

/// One camera's active calibration: its id, the camera's name in a list (none for a cell
/// of one camera), and its result.
pub type Announced = (String, Option<String>, ResultFile);

/// The handle the daemon keeps: send it the whole active set after each change.
pub struct TfBroadcast {
    tx: mpsc::Sender<Vec<Announced>>,
    /// Held from reading the active set to queueing it, so two activations that overlap
    /// cannot queue their sets in the opposite order (the older set would be published last).
    queueing: std::sync::Mutex<()>,
    /// Set once a send found the thread gone, so that is logged once.
    lost: std::sync::atomic::AtomicBool,
}

impl TfBroadcast {
    /// Joins the graph on its own thread; fails (before the daemon listens) when the node
    /// cannot be made.
    pub fn start(settings: Ros2Settings) -> Result<Self> {
        let (tx, rx) = mpsc::channel::<Vec<Announced>>();
        let (ready_tx, ready_rx) = mpsc::channel::<Result<()>>();
        std::thread::Builder::new()
            .name("easyhec-ros2".into())
            .spawn(move || serve(settings, rx, ready_tx))
            .map_err(|e| Error::Ros2(format!("starting the ROS 2 thread: {e}")))?;
        ready_rx
            .recv()
            .map_err(|_| Error::Ros2("the ROS 2 thread ended while starting".into()))??;
        Ok(Self {
            tx,
            queueing: Default::default(),
            lost: Default::default(),
        })
    }

    /// Queues the active set `read` returns (every camera's entry) for publication; nothing
    /// while it is empty.
    pub fn announce(&self, read: impl FnOnce() -> Vec<Announced>) {
        let _queueing = self.queueing.lock().unwrap_or_else(|e| e.into_inner());
        let active = read();
        if active.is_empty() {
            return;
        }
        let sent = self.tx.send(active);
        if sent.is_err() && !self.lost.swap(true, std::sync::atomic::Ordering::SeqCst) {
            tracing::warn!("easyhec daemon: ros2: the ROS 2 thread has ended; this and later calibrations are not published");
        }
    }
}

fn serve(
    settings: Ros2Settings,
    rx: mpsc::Receiver<Vec<Announced>>,
    ready: mpsc::Sender<Result<()>>,
) {
    let opened = open(&settings);
    let (_context, _node, mut listener, publisher) = match opened {
        Ok(parts) => {
            let _ = ready.send(Ok(()));
            parts
        }
        Err(e) => {
            let _ = ready.send(Err(e));
            return;
        }
    };
    while let Ok(mut next) = rx.recv() {
        while let Ok(newer) = rx.try_recv() {
            next = newer;
        }
        let ids = next
            .iter()
            .map(|(id, camera, _)| match camera {
                Some(name) => format!("{id} ({name})"),
                None => id.clone(),
            })
            .collect::<Vec<_>>()
            .join(", ");
        match publish(&settings, &mut listener, &publisher, &next) {
            Ok(edges) => edges.iter().zip(&next).for_each(|(edge, (id, _, _))| {
                tracing::info!(
                    "easyhec daemon: ros2: {id}: {} -> {} on /tf_static",
                    edge.parent,
                    edge.child
                )
            }),
            Err(e) => tracing::warn!(
                "easyhec daemon: ros2: {ids} not published (/tf_static keeps what this daemon published before, if anything): {e}"
            ),
        }
    }
}

type Parts = (
    ros2_client::Context,
    ros2_client::Node,
    TfListener,
    StaticTfPublisher,
);

fn open(settings: &Ros2Settings) -> Result<Parts> {
    let place = GraphPlace {
        domain_id: match settings.domain_id {
            Some(d) => d,
            None => domain_id_from_env()?,
        },
        namespace: settings.namespace.clone(),
        node_name: "easyhec_daemon".into(),
    };
    let (context, mut node) = join(&place)?;
    let listener = TfListener::new(&mut node, &place.namespace)?;
    let publisher = StaticTfPublisher::new(&mut node, &place.namespace)?;
    Ok((context, node, listener, publisher))
}

/// The configured edge of every entry of `active`, each checked against what the graph
/// already holds (leaving out the daemon's own earlier edges), then latched in one message.
fn publish(
    settings: &Ros2Settings,
    listener: &mut TfListener,
    publisher: &StaticTfPublisher,
    active: &[Announced],
) -> Result<Vec<TfEdge>> {
    let edges = active
        .iter()
        .map(|(_, camera, result)| {
            super::exports::camera_edge(Some(settings), camera.as_deref(), result)
        })
        .collect::<Result<Vec<_>>>()?;
    let tree = listener.gather(
        Duration::from_secs_f64(settings.listen_s),
        Some(publisher.gid()),
    )?;
    for edge in &edges {
        tree.check_can_add(edge)?;
    }
    publisher.send(&edges)?;
    Ok(edges)
}
