//! The thread that owns every `ur_rtde` Python object and makes every SDK call, one at a time.
//!
//! ur_rtde's calls hold the GIL and some block for seconds (constructors wait for the first
//! data package, a script upload waits for the program to start) or forever (a peer that
//! accepts and never answers). Running them on one dedicated thread keeps the async runtime
//! free, and the caller's side enforces a time limit per call: a call that does not answer in
//! time is a [`DriverError::Timeout`], and while the thread is stuck in it every later call
//! fails at once instead of queueing behind it.

use std::sync::mpsc::{sync_channel, SyncSender, TrySendError};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use pyo3::prelude::*;
use tokio::sync::oneshot;

use crate::{DriverError, Result};

/// The Python objects of one controller, touched only on the worker thread.
#[derive(Default)]
pub(super) struct Session {
    /// `rtde_receive.RTDEReceiveInterface`.
    pub receive: Option<Py<PyAny>>,
    /// `rtde_control.RTDEControlInterface` (created before the first move: it uploads and
    /// starts ur_rtde's control script on the controller).
    pub control: Option<Py<PyAny>>,
    /// `dashboard_client.DashboardClient`.
    pub dashboard: Option<Py<PyAny>>,
    /// Control interfaces whose link broke. Kept alive, never disconnected: ur_rtde's
    /// background thread of a broken interface can still be running, and disconnecting or
    /// destroying the object under it crashes the process (seen with 1.6.5).
    pub retired: Vec<Py<PyAny>>,
}

impl Session {
    /// Disconnects and forgets every interface (errors ignored: this is cleanup). After a lost
    /// link nothing is touched and the objects are leaked: a broken interface's destructor can
    /// block for seconds holding the GIL, or race its own reconnection threads.
    pub fn close(&mut self, py: Python<'_>) {
        let objects = [
            self.control.take(),
            self.receive.take(),
            self.dashboard.take(),
        ];
        if !self.retired.is_empty() {
            std::mem::forget(std::mem::take(&mut self.retired));
            std::mem::forget(objects);
            return;
        }
        for obj in objects.into_iter().flatten() {
            let _ = obj.call_method0(py, "disconnect");
        }
    }
}

type Job = Box<dyn FnOnce(Python<'_>, &mut Session) + Send>;

/// Handle to the worker thread; the thread ends (closing the interfaces) when the last
/// handle is dropped.
pub(super) struct Worker {
    tx: SyncSender<Job>,
    /// When the call now running started.
    busy_since: Arc<Mutex<Option<(Instant, &'static str)>>>,
}

impl Worker {
    /// Starts the thread.
    pub fn spawn(name: String) -> Result<Worker> {
        let (tx, rx) = sync_channel::<Job>(8);
        let busy_since: Arc<Mutex<Option<(Instant, &'static str)>>> = Arc::default();
        std::thread::Builder::new()
            .name(name)
            .spawn(move || {
                let mut session = Session::default();
                while let Ok(job) = rx.recv() {
                    Python::attach(|py| job(py, &mut session));
                }
                Python::attach(|py| session.close(py));
            })
            .map_err(|e| DriverError::Backend(Box::new(e)))?;
        Ok(Worker { tx, busy_since })
    }

    /// Runs `f` on the worker thread and waits at most `limit` for its answer.
    pub async fn call<R, F>(&self, what: &'static str, limit: Duration, f: F) -> Result<R>
    where
        R: Send + 'static,
        F: FnOnce(Python<'_>, &mut Session) -> Result<R> + Send + 'static,
    {
        if let Some((since, stuck)) = *self.busy_since.lock().unwrap_or_else(|e| e.into_inner()) {
            if since.elapsed() > limit {
                return Err(DriverError::Connection(format!(
                    "ur_rtde has been stuck in {stuck} for {:.1} s (the controller stopped answering); restart the daemon once it is reachable",
                    since.elapsed().as_secs_f64()
                )));
            }
        }
        let (done_tx, done_rx) = oneshot::channel();
        let busy = self.busy_since.clone();
        let job: Job = Box::new(move |py, session| {
            *busy.lock().unwrap_or_else(|e| e.into_inner()) = Some((Instant::now(), what));
            let out = f(py, session);
            *busy.lock().unwrap_or_else(|e| e.into_inner()) = None;
            let _ = done_tx.send(out);
        });
        match self.tx.try_send(job) {
            Ok(()) => {}
            Err(TrySendError::Full(_)) => return Err(DriverError::Timeout(limit)),
            Err(TrySendError::Disconnected(_)) => {
                return Err(DriverError::Connection(
                    "the ur_rtde worker thread is gone".into(),
                ))
            }
        }
        match tokio::time::timeout(limit, done_rx).await {
            Ok(Ok(out)) => out,
            Ok(Err(_)) => Err(DriverError::Connection(
                "the ur_rtde worker thread ended during a call".into(),
            )),
            Err(_) => Err(DriverError::Timeout(limit)),
        }
    }
}
