//! The driver's side of the `ur_rtde` child process: spawns it, sends one request at a time
//! over its stdin and reads the answer from its stdout, on one dedicated thread.
//!
//! ur_rtde's calls block for seconds (constructors wait for the first data package, a script
//! upload waits for the program to start) or forever (a peer that accepts and never answers),
//! and after a lost link its background threads can crash their process. So every call has a
//! time limit enforced here: a call that does not answer in time is a
//! [`DriverError::Timeout`] and the stuck child is killed; a child that dies (a crash, a kill)
//! is a [`DriverError::Connection`] naming the signal; either way the next call starts a fresh
//! child, with no interfaces (the driver reconnects them).
//!
//! Which executable: `EASYHEC_UR_WORKER` if set; else the current executable if its `main`
//! called `serve_worker_if_asked` (the `easyhec` and `easyhec-mock` binaries do); else the
//! first of `easyhec-ur-worker`, `easyhec`, `easyhec-mock` next to the current executable or in
//! its parent directory (test binaries live in `target/<profile>/deps`) that passes the
//! protocol handshake. Each is run with the argument `--easyhec-ur-worker`.

use std::collections::VecDeque;
use std::io::{BufRead, BufReader, Write};
use std::path::PathBuf;
use std::process::{Child, ChildStdin, ChildStdout, Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{sync_channel, Receiver, SyncSender, TrySendError};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use serde::de::DeserializeOwned;
use tokio::sync::oneshot;

use super::proto::{Reply, Request, PROTOCOL, WORKER_ARG};
use super::UrError;
use crate::{DriverError, Result};

/// Set by `serve_worker_if_asked`: the current executable can serve as the worker.
pub(super) static HOST_EXE: AtomicBool = AtomicBool::new(false);

/// The executable that last passed the handshake.
static RESOLVED: Mutex<Option<PathBuf>> = Mutex::new(None);

/// Lines of the child's stderr kept for error messages.
const STDERR_LINES: usize = 20;

type Reply1 = oneshot::Sender<Result<serde_json::Value>>;

enum Job {
    /// Send the request line; answer the reply.
    Call {
        what: &'static str,
        line: String,
        done: Reply1,
    },
    /// Kill the child (if any); the next call starts a fresh one.
    Restart { done: Reply1 },
}

/// One running child: its pipes (the [`Child`] itself is shared, so a caller whose call
/// timed out can kill it while this thread is blocked reading).
struct Proc {
    stdin: ChildStdin,
    stdout: BufReader<ChildStdout>,
    stderr: Arc<Mutex<VecDeque<String>>>,
}

/// Handle to the thread that talks to the child; dropping it closes the child's stdin (the
/// child disconnects and exits) and kills the child if it has not exited 3 s later.
pub(super) struct Worker {
    tx: SyncSender<Job>,
    child: Arc<Mutex<Option<Child>>>,
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

fn signal_name(sig: i32) -> String {
    match sig {
        libc::SIGSEGV => "SIGSEGV".into(),
        libc::SIGABRT => "SIGABRT".into(),
        libc::SIGBUS => "SIGBUS".into(),
        libc::SIGKILL => "SIGKILL".into(),
        libc::SIGTERM => "SIGTERM".into(),
        libc::SIGILL => "SIGILL".into(),
        libc::SIGFPE => "SIGFPE".into(),
        other => format!("signal {other}"),
    }
}

/// Candidate executables, in order (see the module documentation).
fn candidates() -> Vec<PathBuf> {
    if let Some(p) = std::env::var_os("EASYHEC_UR_WORKER") {
        return vec![PathBuf::from(p)];
    }
    let mut out = Vec::new();
    if let Some(p) = lock(&RESOLVED).clone() {
        out.push(p);
    }
    let exe = std::env::current_exe().ok();
    if HOST_EXE.load(Ordering::Relaxed) {
        out.extend(exe.clone());
    }
    if let Some(dir) = exe.as_deref().and_then(|e| e.parent()) {
        for d in [Some(dir), dir.parent()].into_iter().flatten() {
            for name in ["easyhec-ur-worker", "easyhec", "easyhec-mock"] {
                let p = d.join(format!("{name}{}", std::env::consts::EXE_SUFFIX));
                if p.is_file() && !out.contains(&p) {
                    out.push(p);
                }
            }
        }
    }
    out
}

/// Starts `path` as the worker and checks the handshake; the child is left in `slot`.
fn start(path: &PathBuf, slot: &Mutex<Option<Child>>) -> std::result::Result<Proc, String> {
    let mut child = Command::new(path)
        .arg(WORKER_ARG)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .map_err(|e| format!("{}: {e}", path.display()))?;
    let (Some(stdin), Some(stdout), Some(stderr)) =
        (child.stdin.take(), child.stdout.take(), child.stderr.take())
    else {
        let _ = child.kill();
        let _ = child.wait();
        return Err(format!("{}: no pipes", path.display()));
    };
    let tail: Arc<Mutex<VecDeque<String>>> = Arc::default();
    let forward = Arc::new(AtomicBool::new(false));
    {
        let tail = tail.clone();
        let forward = forward.clone();
        let _ = std::thread::Builder::new()
            .name("ur_rtde stderr".into())
            .spawn(move || {
                for line in BufReader::new(stderr).lines() {
                    let Ok(line) = line else { break };
                    if forward.load(Ordering::Relaxed) {
                        tracing::warn!("ur_rtde: {line}");
                    }
                    let mut t = lock(&tail);
                    if t.len() == STDERR_LINES {
                        t.pop_front();
                    }
                    t.push_back(line);
                }
            });
    }
    *lock(slot) = Some(child);
    let mut proc = Proc {
        stdin,
        stdout: BufReader::new(stdout),
        stderr: tail,
    };
    match exchange(&mut proc, &request_line(&Request::Hello)) {
        Ok(Reply::Ok(v)) if v == serde_json::json!(PROTOCOL) => {
            forward.store(true, Ordering::Relaxed);
            Ok(proc)
        }
        other => {
            if let Some(mut c) = lock(slot).take() {
                let _ = c.kill();
                let _ = c.wait();
            }
            let detail = match other {
                Ok(r) => format!("answered {r:?}"),
                Err(_) => match lock(&proc.stderr).back() {
                    Some(l) => format!("no handshake ({l})"),
                    None => "no handshake".into(),
                },
            };
            Err(format!("{}: {detail}", path.display()))
        }
    }
}

fn request_line(req: &Request) -> String {
    // Requests hold only strings and numbers: serialising cannot fail.
    serde_json::to_string(req).unwrap_or_default()
}

/// Writes one line and reads one reply line; `Err` when the pipe broke (the child is gone).
fn exchange(proc: &mut Proc, line: &str) -> std::result::Result<Reply, ()> {
    proc.stdin
        .write_all(line.as_bytes())
        .and_then(|()| proc.stdin.write_all(b"\n"))
        .and_then(|()| proc.stdin.flush())
        .map_err(|_| ())?;
    let mut answer = String::new();
    match proc.stdout.read_line(&mut answer) {
        Ok(n) if n > 0 => {}
        _ => return Err(()),
    }
    serde_json::from_str(answer.trim_end()).or(Err(()))
}

/// Why the child ended, after its pipe broke during `what`.
fn ended(proc: &Proc, slot: &Mutex<Option<Child>>, what: &str) -> DriverError {
    let status = lock(slot).take().map(|mut c| {
        // The pipe is closed, so the child is exiting; a live one is killed.
        let deadline = Instant::now() + Duration::from_secs(1);
        loop {
            match c.try_wait() {
                Ok(Some(s)) => break Some(s),
                Ok(None) if Instant::now() < deadline => {
                    std::thread::sleep(Duration::from_millis(5))
                }
                _ => {
                    let _ = c.kill();
                    break c.wait().ok();
                }
            }
        }
    });
    // Give the stderr thread a moment to collect the last words.
    std::thread::sleep(Duration::from_millis(20));
    let last = lock(&proc.stderr).back().cloned();
    let how = match status.flatten() {
        Some(s) => {
            use std::os::unix::process::ExitStatusExt;
            match s.signal() {
                Some(sig) => format!("crashed ({})", signal_name(sig)),
                None => format!("exited ({s})"),
            }
        }
        None => "ended".into(),
    };
    let mut msg = format!("ur_rtde worker {how} during {what}; the next call starts a fresh one");
    if let Some(l) = last {
        msg.push_str(&format!(" (its last words: {l})"));
    }
    DriverError::Connection(msg)
}

fn kill(slot: &Mutex<Option<Child>>) {
    if let Some(c) = lock(slot).as_mut() {
        let _ = c.kill();
    }
}

fn spawn_proc(slot: &Mutex<Option<Child>>) -> Result<Proc> {
    let mut tried = Vec::new();
    for path in candidates() {
        match start(&path, slot) {
            Ok(p) => {
                *lock(&RESOLVED) = Some(path);
                return Ok(p);
            }
            Err(e) => tried.push(e),
        }
    }
    Err(DriverError::Backend(Box::new(UrError::Sdk(format!(
        "no ur_rtde worker executable answered (tried: {}): build easyhec-ur-worker (cargo build --release -p easyhec-drivers --features ur) and put it next to this program, or set EASYHEC_UR_WORKER to its path",
        if tried.is_empty() { "none found".into() } else { tried.join("; ") }
    )))))
}

fn run(rx: Receiver<Job>, slot: Arc<Mutex<Option<Child>>>) {
    let mut proc: Option<Proc> = None;
    while let Ok(job) = rx.recv() {
        match job {
            Job::Restart { done } => {
                kill(&slot);
                if let Some(mut c) = lock(&slot).take() {
                    let _ = c.wait();
                }
                proc = None;
                let _ = done.send(Ok(serde_json::Value::Null));
            }
            Job::Call { what, line, done } => {
                if done.is_closed() {
                    // The caller gave up (timed out) before the call started.
                    continue;
                }
                if proc.is_none() {
                    match spawn_proc(&slot) {
                        Ok(p) => proc = Some(p),
                        Err(e) => {
                            let _ = done.send(Err(e));
                            continue;
                        }
                    }
                }
                let Some(p) = proc.as_mut() else { continue };
                let out = match exchange(p, &line) {
                    Ok(Reply::Ok(v)) => Ok(v),
                    Ok(Reply::Err(e)) => Err(e.into_driver()),
                    Err(()) => {
                        let e = ended(p, &slot, what);
                        proc = None;
                        Err(e)
                    }
                };
                let _ = done.send(out);
            }
        }
    }
    // Every handle is gone: close stdin so the child disconnects and exits, then reap it.
    drop(proc);
    let deadline = Instant::now() + Duration::from_secs(3);
    if let Some(mut c) = lock(&slot).take() {
        loop {
            match c.try_wait() {
                Ok(None) if Instant::now() < deadline => {
                    std::thread::sleep(Duration::from_millis(10))
                }
                Ok(Some(_)) => break,
                _ => {
                    let _ = c.kill();
                    let _ = c.wait();
                    break;
                }
            }
        }
    }
}

impl Worker {
    /// Starts the thread (the child starts on the first call).
    pub fn spawn(name: String) -> Result<Worker> {
        let (tx, rx) = sync_channel::<Job>(8);
        let child: Arc<Mutex<Option<Child>>> = Arc::default();
        let slot = child.clone();
        std::thread::Builder::new()
            .name(name)
            .spawn(move || run(rx, slot))
            .map_err(|e| DriverError::Backend(Box::new(e)))?;
        Ok(Worker { tx, child })
    }

    /// Sends `req` to the child and waits at most `limit` (starting the child included) for
    /// its answer; a child that misses the limit is killed.
    pub async fn call<R: DeserializeOwned>(
        &self,
        what: &'static str,
        limit: Duration,
        req: Request,
    ) -> Result<R> {
        let (done, done_rx) = oneshot::channel();
        let job = Job::Call {
            what,
            line: request_line(&req),
            done,
        };
        let v = self.submit(job, done_rx, limit).await?;
        serde_json::from_value(v).map_err(|e| {
            DriverError::Connection(format!("ur_rtde worker: unexpected answer to {what}: {e}"))
        })
    }

    /// Kills the child (with whatever ur_rtde interfaces it holds); the next call starts a
    /// fresh one.
    pub async fn restart(&self, limit: Duration) -> Result<()> {
        kill(&self.child);
        let (done, done_rx) = oneshot::channel();
        self.submit(Job::Restart { done }, done_rx, limit)
            .await
            .map(|_| ())
    }

    async fn submit(
        &self,
        job: Job,
        done_rx: oneshot::Receiver<Result<serde_json::Value>>,
        limit: Duration,
    ) -> Result<serde_json::Value> {
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
            Err(_) => {
                // Stuck in ur_rtde: the only way out is a fresh process.
                kill(&self.child);
                Err(DriverError::Timeout(limit))
            }
        }
    }
}
