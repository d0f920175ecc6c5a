//! The HTTP/1 server under the router: an accept loop with a connection limit and two
//! timeouts, so that clients which connect and then say nothing (or stop half-way) cannot
//! use up the daemon's connections or file descriptors while a cell controller is polling
//! `/healthz`.
//!
//! - **Connection limit** (`[daemon] max_connections`): each connection holds a permit of a
//!   semaphore; one more is answered `503` with a JSON error and closed at once, instead of
//!   waiting unseen in the kernel's backlog. The limit is lowered to what the process's
//!   open-file limit allows ([`open_file_limit`] first raises the soft limit to the hard one).
//! - **Header-read timeout** (`header_read_timeout_s`): a connection must send a complete
//!   request head within this time of opening or of its previous response (hyper's timer).
//! - **Idle timeout** (`idle_timeout_s`): a connection that moves no byte either way for this
//!   long (a stalled upload, a client that stops reading) is closed. A handler at work (a bump
//!   check can take seconds) does not count as idle once it has the whole request body, and
//!   event streams send keep-alive comments well within the timeout
//!   ([`keep_alive_interval`]).
//!
//! Shutdown stops accepting, asks every connection to finish its current response and close,
//! and waits for them (at most [`DRAIN`]).

use std::io;
use std::pin::Pin;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::Arc;
use std::task::{Context, Poll};
use std::time::{Duration, Instant};

use axum::Router;
use hyper::body::Body as _;
use hyper::server::conn::http1;
use hyper_util::rt::{TokioIo, TokioTimer};
use hyper_util::service::TowerToHyperService;
use tokio::io::{AsyncRead, AsyncWrite, AsyncWriteExt, ReadBuf};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{watch, OwnedSemaphorePermit, Semaphore};

use crate::config::DaemonSettings;

/// Longest wait at shutdown for open connections to finish.
pub const DRAIN: Duration = Duration::from_secs(30);
/// File descriptors kept for everything but connections (run files, images, the camera, the
/// listener, the runtime).
pub const RESERVED_FILES: usize = 256;
/// Over-limit connections answered with a 503 at the same time; beyond that they are closed
/// without an answer, so a flood cannot grow the refusals instead.
const REFUSING_AT_ONCE: usize = 64;

/// Connection counters for `/metrics`.
#[derive(Default)]
pub struct HttpStats {
    /// Connections open now.
    pub open: AtomicU64,
    /// Connections refused with a 503 (or closed) at the limit.
    pub refused: AtomicU64,
    /// Connections closed by the header-read timeout.
    pub header_timeouts: AtomicU64,
    /// Connections closed by the idle timeout.
    pub idle_timeouts: AtomicU64,
}

/// The server's limits, resolved from `[daemon]` and the open-file limit.
#[derive(Clone, Copy, Debug)]
pub struct Limits {
    /// `header_read_timeout_s`.
    pub header_read: Duration,
    /// `idle_timeout_s`.
    pub idle: Duration,
    /// Connections at once.
    pub max_connections: usize,
}

impl Limits {
    /// The configured limits, with `max_connections` lowered (and logged) to what
    /// `open_files` file descriptors allow.
    pub fn resolve(settings: &DaemonSettings, open_files: Option<usize>) -> Limits {
        let wanted = settings.max_connections();
        let allowed = open_files.map_or(wanted, |n| n.saturating_sub(RESERVED_FILES).max(1));
        if allowed < wanted {
            tracing::warn!(
                "easyhec daemon: daemon.max_connections: {wanted} lowered to {allowed}: the open-file limit is {} (raise it with `ulimit -n`)",
                open_files.unwrap_or(0)
            );
        }
        Limits {
            header_read: settings.header_read_timeout(),
            idle: settings.idle_timeout(),
            max_connections: wanted.min(allowed),
        }
    }
}

/// Raises the soft open-file limit to the hard one (capped at what the largest connection
/// limit needs) and returns the soft limit in force; `None` where it cannot be read. Each
/// connection is a file descriptor, and the usual soft limit of 1024 is below the default
/// connection limit.
#[cfg(unix)]
pub fn open_file_limit() -> Option<usize> {
    let mut r = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: getrlimit only writes the struct it is given, which lives on this stack.
    if unsafe { libc::getrlimit(libc::RLIMIT_NOFILE, &mut r) } != 0 {
        return None;
    }
    let cap = (crate::config::daemon::MAX_CONNECTIONS_MAX + RESERVED_FILES) as libc::rlim_t;
    let target = r.rlim_max.min(cap);
    if r.rlim_cur < target {
        let raised = libc::rlimit {
            rlim_cur: target,
            rlim_max: r.rlim_max,
        };
        // SAFETY: setrlimit only reads the struct it is given.
        if unsafe { libc::setrlimit(libc::RLIMIT_NOFILE, &raised) } == 0 {
            r.rlim_cur = target;
        }
    }
    Some(usize::try_from(r.rlim_cur).unwrap_or(usize::MAX))
}

/// Elsewhere there is no soft limit to raise.
#[cfg(not(unix))]
pub fn open_file_limit() -> Option<usize> {
    None
}

/// Serves `router` on `listener` until `shutdown` resolves, then drains the connections.
pub async fn run(
    listener: TcpListener,
    router: Router,
    limits: Limits,
    stats: Arc<HttpStats>,
    shutdown: impl std::future::Future<Output = ()>,
) {
    let permits = Arc::new(Semaphore::new(limits.max_connections));
    let refusing = Arc::new(Semaphore::new(REFUSING_AT_ONCE));
    let (stop_tx, stop_rx) = watch::channel(false);
    let conn = Arc::new(Conn {
        router,
        builder: builder(limits.header_read),
        idle: limits.idle,
        stats,
        max_connections: limits.max_connections,
    });
    let mut errors = AcceptErrors::default();
    tokio::pin!(shutdown);
    loop {
        let stream = tokio::select! {
            () = &mut shutdown => break,
            r = listener.accept() => match r {
                Ok((s, _)) => s,
                Err(e) => {
                    errors.wait(e).await;
                    continue;
                }
            },
        };
        match permits.clone().try_acquire_owned() {
            Ok(permit) => {
                tokio::spawn(conn.clone().serve(stream, permit, stop_rx.clone()));
            }
            Err(_) => conn.refuse(stream, &refusing),
        }
    }
    drop(listener);
    let _ = stop_tx.send(true);
    let all = u32::try_from(limits.max_connections).unwrap_or(u32::MAX);
    if tokio::time::timeout(DRAIN, permits.acquire_many(all))
        .await
        .is_err()
    {
        tracing::warn!(
            "easyhec daemon: connections still open {} s after shutdown began: closing them",
            DRAIN.as_secs()
        );
    }
}

/// hyper's HTTP/1 connection settings: keep-alive, the header-read timeout on tokio's timer.
fn builder(header_read: Duration) -> http1::Builder {
    let mut b = http1::Builder::new();
    b.timer(TokioTimer::new())
        .header_read_timeout(header_read)
        .keep_alive(true);
    b
}

/// Accept errors: a full file table (`EMFILE`) would otherwise spin the loop; wait a little
/// and log one line per second at most.
#[derive(Default)]
struct AcceptErrors {
    last_log: Option<Instant>,
}

impl AcceptErrors {
    async fn wait(&mut self, e: io::Error) {
        if self
            .last_log
            .is_none_or(|t| t.elapsed() >= Duration::from_secs(1))
        {
            tracing::warn!("easyhec daemon: accepting a connection failed: {e}");
            self.last_log = Some(Instant::now());
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

/// What every connection shares.
struct Conn {
    router: Router,
    builder: http1::Builder,
    idle: Duration,
    stats: Arc<HttpStats>,
    max_connections: usize,
}

impl Conn {
    /// Serves one connection until it closes, times out or shutdown asks it to finish.
    async fn serve(
        self: Arc<Self>,
        stream: TcpStream,
        _permit: OwnedSemaphorePermit,
        mut stop: watch::Receiver<bool>,
    ) {
        let _open = OpenGuard::new(&self.stats.open);
        let _ = stream.set_nodelay(true);
        let activity = Arc::new(Activity::new());
        let io = TokioIo::new(Tracked {
            inner: stream,
            activity: activity.clone(),
        });
        let service = Counted {
            inner: TowerToHyperService::new(self.router.clone()),
            activity: activity.clone(),
        };
        let conn = self.builder.serve_connection(io, service);
        tokio::pin!(conn);
        let idle = idle_expired(&activity, self.idle);
        tokio::pin!(idle);
        let mut stopping = false;
        loop {
            tokio::select! {
                r = conn.as_mut() => {
                    if r.is_err_and(|e| e.is_timeout()) {
                        self.stats.header_timeouts.fetch_add(1, Ordering::Relaxed);
                    }
                    return;
                }
                _ = stop.changed(), if !stopping => {
                    stopping = true;
                    conn.as_mut().graceful_shutdown();
                }
                () = &mut idle => {
                    self.stats.idle_timeouts.fetch_add(1, Ordering::Relaxed);
                    return;
                }
            }
        }
    }

    /// Answers a connection over the limit with a 503 and closes it (or just closes it when
    /// [`REFUSING_AT_ONCE`] are being answered already).
    fn refuse(&self, mut stream: TcpStream, refusing: &Arc<Semaphore>) {
        self.stats.refused.fetch_add(1, Ordering::Relaxed);
        let Ok(permit) = refusing.clone().try_acquire_owned() else {
            return;
        };
        let body = format!(
            "{{\"error\": \"too many connections: the daemon serves {} at once ([daemon] max_connections); retry later\"}}",
            self.max_connections
        );
        let response = format!(
            "HTTP/1.1 503 Service Unavailable\r\ncontent-type: application/json\r\ncontent-length: {}\r\nconnection: close\r\nretry-after: 1\r\n\r\n{body}",
            body.len()
        );
        tokio::spawn(async move {
            let _permit = permit;
            let answer = async {
                stream.write_all(response.as_bytes()).await?;
                stream.shutdown().await?;
                // Read what the client sent, so closing does not reset the connection before
                // it has read the answer.
                let mut sink = [0u8; 4096];
                while tokio::io::AsyncReadExt::read(&mut stream, &mut sink).await? > 0 {}
                io::Result::Ok(())
            };
            let _ = tokio::time::timeout(Duration::from_secs(2), answer).await;
        });
    }
}

/// Counts a connection as open while it lives.
struct OpenGuard<'a>(&'a AtomicU64);

impl<'a> OpenGuard<'a> {
    fn new(open: &'a AtomicU64) -> Self {
        open.fetch_add(1, Ordering::Relaxed);
        OpenGuard(open)
    }
}

impl Drop for OpenGuard<'_> {
    fn drop(&mut self) {
        self.0.fetch_sub(1, Ordering::Relaxed);
    }
}

/// The interval of an event stream's keep-alive comments: often enough that an idle stream
/// is never taken for an idle connection, at most every 15 s.
pub fn keep_alive_interval(idle: Duration) -> Duration {
    (idle / 3).min(Duration::from_secs(15))
}

/// When a connection last moved a byte, how many of its requests are being handled, and how
/// many of those still wait for the rest of their body.
struct Activity {
    epoch: Instant,
    last_ms: AtomicU64,
    handling: AtomicUsize,
    uploading: AtomicUsize,
}

impl Activity {
    fn new() -> Activity {
        Activity {
            epoch: Instant::now(),
            last_ms: AtomicU64::new(0),
            handling: AtomicUsize::new(0),
            uploading: AtomicUsize::new(0),
        }
    }

    fn now_ms(&self) -> u64 {
        u64::try_from(self.epoch.elapsed().as_millis()).unwrap_or(u64::MAX)
    }

    fn touch(&self) {
        self.last_ms.store(self.now_ms(), Ordering::Relaxed);
    }

    fn idle_for(&self) -> Duration {
        let last = self.last_ms.load(Ordering::Relaxed);
        Duration::from_millis(self.now_ms().saturating_sub(last))
    }

    /// A handler has its whole request and is at work (not waiting on the client).
    fn working(&self) -> bool {
        self.handling.load(Ordering::Relaxed) > self.uploading.load(Ordering::Relaxed)
    }
}

/// Resolves once the connection has been idle for `limit` with no handler at work.
async fn idle_expired(a: &Activity, limit: Duration) {
    loop {
        let idle = a.idle_for();
        if idle >= limit && !a.working() {
            return;
        }
        tokio::time::sleep(limit.saturating_sub(idle).max(Duration::from_millis(100))).await;
    }
}

/// Marks a request as being handled until it is dropped.
struct Handling(Arc<Activity>);

impl Drop for Handling {
    fn drop(&mut self) {
        self.0.handling.fetch_sub(1, Ordering::Relaxed);
        self.0.touch();
    }
}

/// The router as a hyper service that marks each request as being handled until its
/// response head is ready (the body's bytes then count as activity).
#[derive(Clone)]
struct Counted {
    inner: TowerToHyperService<Router>,
    activity: Arc<Activity>,
}

type Reply = Result<axum::response::Response, std::convert::Infallible>;

impl hyper::service::Service<hyper::Request<hyper::body::Incoming>> for Counted {
    type Response = axum::response::Response;
    type Error = std::convert::Infallible;
    type Future = Pin<Box<dyn std::future::Future<Output = Reply> + Send>>;

    fn call(&self, req: hyper::Request<hyper::body::Incoming>) -> Self::Future {
        self.activity.handling.fetch_add(1, Ordering::Relaxed);
        let guard = Handling(self.activity.clone());
        let activity = self.activity.clone();
        let req = req.map(|b| axum::body::Body::new(Upload::new(b, activity)));
        let fut = self.inner.call(req);
        Box::pin(async move {
            let r = fut.await;
            drop(guard);
            r
        })
    }
}

/// A request body that counts as "uploading" on its connection until it has ended (or the
/// handler drops it), so a stalled upload is idle while a handler at work is not.
struct Upload {
    inner: hyper::body::Incoming,
    activity: Option<Arc<Activity>>,
}

impl Upload {
    fn new(inner: hyper::body::Incoming, activity: Arc<Activity>) -> Upload {
        let activity = (!inner.is_end_stream()).then(|| {
            activity.uploading.fetch_add(1, Ordering::Relaxed);
            activity
        });
        Upload { inner, activity }
    }

    fn ended(&mut self) {
        if let Some(a) = self.activity.take() {
            a.uploading.fetch_sub(1, Ordering::Relaxed);
        }
    }
}

impl Drop for Upload {
    fn drop(&mut self) {
        self.ended();
    }
}

impl hyper::body::Body for Upload {
    type Data = axum::body::Bytes;
    type Error = hyper::Error;

    fn poll_frame(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<hyper::body::Frame<Self::Data>, Self::Error>>> {
        let this = self.get_mut();
        let r = Pin::new(&mut this.inner).poll_frame(cx);
        if matches!(r, Poll::Ready(None | Some(Err(_)))) || this.inner.is_end_stream() {
            this.ended();
        }
        r
    }

    fn is_end_stream(&self) -> bool {
        self.inner.is_end_stream()
    }

    fn size_hint(&self) -> hyper::body::SizeHint {
        self.inner.size_hint()
    }
}

/// A TCP stream that records when it last moved a byte.
struct Tracked {
    inner: TcpStream,
    activity: Arc<Activity>,
}

impl AsyncRead for Tracked {
    fn poll_read(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        let this = self.get_mut();
        let before = buf.filled().len();
        let r = Pin::new(&mut this.inner).poll_read(cx, buf);
        if matches!(r, Poll::Ready(Ok(()))) && buf.filled().len() > before {
            this.activity.touch();
        }
        r
    }
}

impl AsyncWrite for Tracked {
    fn poll_write(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<io::Result<usize>> {
        let this = self.get_mut();
        let r = Pin::new(&mut this.inner).poll_write(cx, buf);
        this.note_written(&r);
        r
    }

    fn poll_write_vectored(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[io::IoSlice<'_>],
    ) -> Poll<io::Result<usize>> {
        let this = self.get_mut();
        let r = Pin::new(&mut this.inner).poll_write_vectored(cx, bufs);
        this.note_written(&r);
        r
    }

    fn is_write_vectored(&self) -> bool {
        self.inner.is_write_vectored()
    }

    fn poll_flush(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.get_mut().inner).poll_flush(cx)
    }

    fn poll_shutdown(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.get_mut().inner).poll_shutdown(cx)
    }
}

impl Tracked {
    fn note_written(&self, r: &Poll<io::Result<usize>>) {
        if matches!(r, Poll::Ready(Ok(n)) if *n > 0) {
            self.activity.touch();
        }
    }
}
