//! How a mock controller's network links end, told to all of them at once.
//!
//! A test drops a controller's connections to see a driver reconnect, refuses reconnects to
//! see it give up, and drops the mock to see every task end. Each listener and each
//! connection watches one shared state for that, so the xArm and UR mocks behave alike where
//! their real controllers do.

use std::time::Duration;

use tokio::net::{TcpListener, TcpStream};
use tokio::sync::watch;

#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) struct LinkState {
    /// Bumped by every drop: a connection accepted under an older one closes.
    drop_generation: u64,
    /// Listeners stop accepting (a controller whose network went away).
    refuse: bool,
    /// The mock was dropped: everything ends.
    shutdown: bool,
}

/// The links of one mock controller.
pub(crate) struct Links(watch::Sender<LinkState>);

impl Links {
    pub(crate) fn new() -> Links {
        Links(watch::Sender::new(LinkState::default()))
    }

    /// Closes every open connection; with `refuse_reconnect` the listeners close too.
    pub(crate) fn drop_all(&self, refuse_reconnect: bool) {
        self.0.send_modify(|s| {
            s.drop_generation += 1;
            s.refuse |= refuse_reconnect;
        });
    }

    /// Ends every listener, connection and background task.
    pub(crate) fn shut_down(&self) {
        self.0.send_modify(|s| s.shutdown = true);
    }

    /// A receiver for [`closed`].
    pub(crate) fn subscribe(&self) -> watch::Receiver<LinkState> {
        self.0.subscribe()
    }

    /// Accepts on `listener` until refused or shut down, handing each stream (no Nagle
    /// delay, as a controller's) to `serve` with the drop generation it was accepted under.
    pub(crate) async fn accept(
        &self,
        listener: TcpListener,
        mut serve: impl FnMut(TcpStream, u64),
    ) {
        let mut rx = self.0.subscribe();
        // A drop that refused, or the shutdown, may have come before this task first ran.
        let at_start = *rx.borrow_and_update();
        if at_start.refuse || at_start.shutdown {
            return;
        }
        loop {
            let stream = tokio::select! {
                r = listener.accept() => match r {
                    Ok((s, _)) => s,
                    Err(_) => continue,
                },
                r = rx.changed() => {
                    let s = *rx.borrow();
                    if r.is_err() || s.refuse || s.shutdown {
                        return;
                    }
                    continue;
                }
            };
            let _ = stream.set_nodelay(true);
            let generation = rx.borrow().drop_generation;
            serve(stream, generation);
        }
    }
}

/// Calls `tick` every `period` until the mock is dropped (ticks missed under load are
/// skipped, not caught up), so a controller's motion and faults run on time even when nobody
/// is asking. `rx` comes from [`Links::subscribe`] before the task is spawned, so a shutdown
/// cannot slip past it.
pub(crate) async fn tick_until_shutdown(
    mut rx: watch::Receiver<LinkState>,
    period: Duration,
    mut tick: impl FnMut(),
) {
    let mut clock = tokio::time::interval(period);
    clock.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    loop {
        tokio::select! {
            _ = clock.tick() => tick(),
            r = rx.changed() => if r.is_err() || rx.borrow().shutdown { return },
        }
    }
}

/// Waits until a connection accepted under `generation` must close (a drop after it was
/// accepted, or shutdown).
pub(crate) async fn closed(rx: &mut watch::Receiver<LinkState>, generation: u64) {
    loop {
        {
            let s = *rx.borrow_and_update();
            if s.shutdown || s.drop_generation != generation {
                return;
            }
        }
        if rx.changed().await.is_err() {
            return;
        }
    }
}
