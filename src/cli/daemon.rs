//! `easyhec daemon`: serve calibrations of a cell over HTTP until stopped.

use std::path::PathBuf;

use anyhow::Context;
use clap::Args;
use easyhec::daemon::folder_lock::FolderLock;
use easyhec::daemon::{data_dir, resolve_token, serve, Daemon};

#[derive(Args)]
pub struct DaemonArgs {
    /// Cell config (TOML) with an optional [daemon] table.
    #[arg(long)]
    pub config: PathBuf,
    /// HOST:PORT to listen on (default: [daemon] listen, else 127.0.0.1:8787; port 0 picks
    /// a free one).
    #[arg(long)]
    pub listen: Option<String>,
    /// Data folder (default: [daemon] data_dir relative to the config, else the state
    /// folder: $STATE_DIRECTORY, $XDG_STATE_HOME/easyhec or ~/.local/state/easyhec).
    #[arg(long)]
    pub data: Option<PathBuf>,
}

/// Serves the cell until ctrl-c or SIGTERM.
pub fn run(a: DaemonArgs) -> anyhow::Result<()> {
    let config = easyhec::config::read_config(&a.config)?;
    let data = data_dir(&config, &a.config, a.data.as_deref())?;
    // The lock comes first, then the port, and only then the repair of the data folder: a
    // second daemon, or one whose port is taken, leaves the folder as it found it. An
    // existing folder is locked before the cell is built, so a second daemon fails at once;
    // a new one only once the config has passed every check, so a bad config creates nothing.
    let early_lock = if data.is_dir() {
        Some(FolderLock::take(&data)?)
    } else {
        None
    };
    let cell = easyhec::cell::Cell::build(config, &a.config)?;
    let token = resolve_token(&cell)?;
    let mut folder_lock = match early_lock {
        Some(lock) => lock,
        None => FolderLock::take(&data)?,
    };
    let listen = a
        .listen
        .clone()
        .unwrap_or_else(|| cell.config.daemon.listen.clone());
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .thread_name("easyhec-http")
        .enable_all()
        .build()
        .context("starting the async runtime")?;
    runtime.block_on(async move {
        let listener = tokio::net::TcpListener::bind(&listen)
            .await
            .with_context(|| format!("--listen {listen}: cannot listen there (use HOST:PORT)"))?;
        folder_lock.record_pid();
        let daemon = Daemon::open(cell, &data, token)?;
        for id in daemon.recovered() {
            tracing::warn!("easyhec daemon: {id} was running when the daemon stopped: marked interrupted (its views are on disk)");
        }
        let addr = listener.local_addr().context("reading the bound address")?;
        // Output, not a diagnostic: tests and supervisors read this line for the port, so it
        // is written whatever the log level or format.
        eprintln!(
            "easyhec daemon listening on http://{addr} (data {})",
            data.display()
        );
        #[cfg(unix)]
        let _watchdog = service_manager_ready(addr);
        let stop = async {
            stop_signal().await;
            #[cfg(unix)]
            easyhec::daemon::systemd::notify("STOPPING=1");
        };
        serve(daemon, listener, stop).await?;
        tracing::info!("easyhec daemon: stopped");
        anyhow::Ok(())
    })
}

/// Tells a service manager (systemd, `Type=notify`) the daemon is listening, and pings its
/// watchdog from the runtime for as long as the returned task lives.
#[cfg(unix)]
fn service_manager_ready(addr: std::net::SocketAddr) -> Option<tokio::task::JoinHandle<()>> {
    use easyhec::daemon::systemd;
    systemd::notify(&format!("READY=1\nSTATUS=listening on http://{addr}"));
    let period = systemd::watchdog_period()?;
    Some(tokio::spawn(async move {
        let mut tick = tokio::time::interval(period);
        loop {
            tick.tick().await;
            systemd::notify("WATCHDOG=1");
        }
    }))
}

/// Resolves on ctrl-c or SIGTERM.
async fn stop_signal() {
    #[cfg(unix)]
    {
        use tokio::signal::unix::{signal, SignalKind};
        match signal(SignalKind::terminate()) {
            Ok(mut term) => {
                tokio::select! {
                    _ = tokio::signal::ctrl_c() => {}
                    _ = term.recv() => {}
                }
            }
            Err(_) => {
                let _ = tokio::signal::ctrl_c().await;
            }
        }
    }
    #[cfg(not(unix))]
    {
        let _ = tokio::signal::ctrl_c().await;
    }
}
