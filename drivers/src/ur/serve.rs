//! The child side: the process that owns every `ur_rtde` Python object and makes every SDK
//! call, one request at a time, for one `UrArm`.
//!
//! ur_rtde 1.6.5 can crash its process (SIGSEGV in the control interface's own background
//! reconnection threads after a link loss); here that kills only this process, and the driver
//! reports it and starts a fresh one. ur_rtde prints to stdout itself, so the protocol gets a
//! private copy of stdout and fd 1 is pointed at stderr before any Python runs.

use std::io::{BufRead, Write};
use std::os::fd::FromRawFd;
use std::process::ExitCode;

use pyo3::exceptions::PyImportError;
use pyo3::prelude::*;

use super::proto::{Reply, Request, State, WireError, PROTOCOL};
use super::UrError;
use crate::{DriverError, Result};

/// The Python objects of one controller.
#[derive(Default)]
struct Session {
    /// `rtde_receive.RTDEReceiveInterface`.
    receive: Option<Py<PyAny>>,
    /// `rtde_control.RTDEControlInterface`.
    control: Option<Py<PyAny>>,
    /// `dashboard_client.DashboardClient`.
    dashboard: Option<Py<PyAny>>,
}

impl Session {
    /// Disconnects the interfaces whose link is up (errors ignored: this is cleanup). A
    /// broken interface is left alone: its background threads may still be running, and
    /// the process exits right after without destroying anything.
    fn close(&mut self, py: Python<'_>) {
        for obj in [
            self.control.take(),
            self.receive.take(),
            self.dashboard.take(),
        ]
        .into_iter()
        .flatten()
        {
            if call::<bool, _>(py, &obj, "isConnected", ()).unwrap_or(false) {
                let _ = obj.call_method0(py, "disconnect");
            }
            std::mem::forget(obj);
        }
    }
}

/// A Python exception as a driver error, with what to do about the common ones.
fn py_error(py: Python<'_>, what: &str, e: PyErr) -> DriverError {
    if e.is_instance_of::<PyImportError>(py) {
        return DriverError::Backend(Box::new(UrError::Sdk(format!(
            "python3 cannot import ur_rtde ({}): python3 -m pip install ur-rtde==1.6.5",
            e.value(py)
        ))));
    }
    let msg = e.value(py).to_string().replace('\n', " ");
    if msg.contains("remote control") {
        DriverError::Refused(format!(
            "{what}: the controller is not in remote control: switch the pendant to Remote Control"
        ))
    } else {
        DriverError::Connection(format!("{what}: {msg}"))
    }
}

fn import<'py>(py: Python<'py>, module: &str) -> Result<Bound<'py, PyModule>> {
    py.import(module).map_err(|e| py_error(py, "import", e))
}

/// Calls `name` on `obj` with `args` and extracts the result.
fn call<'py, T, A>(py: Python<'py>, obj: &Py<PyAny>, name: &str, args: A) -> Result<T>
where
    T: for<'a> FromPyObject<'a, 'py>,
    A: pyo3::call::PyCallArgs<'py>,
{
    obj.bind(py)
        .call_method1(name, args)
        .and_then(|v| v.extract::<T>().map_err(Into::into))
        .map_err(|e| py_error(py, name, e))
}

fn control(s: &Session) -> Result<&Py<PyAny>> {
    s.control
        .as_ref()
        .ok_or_else(|| DriverError::Connection("no control interface".into()))
}

fn read_state(py: Python<'_>, s: &Session) -> Result<State> {
    let r = s
        .receive
        .as_ref()
        .ok_or_else(|| DriverError::Connection("not connected".into()))?;
    let rx_connected: bool = call(py, r, "isConnected", ())?;
    let (ctl_connected, async_running) = match &s.control {
        Some(c) => {
            let connected: bool = call(py, c, "isConnected", ())?;
            let running = if connected {
                let status = c
                    .bind(py)
                    .call_method0("getAsyncOperationProgressEx")
                    .map_err(|e| py_error(py, "getAsyncOperationProgressEx", e))?;
                status
                    .call_method0("isAsyncOperationRunning")
                    .and_then(|v| v.extract::<bool>())
                    .map_err(|e| py_error(py, "isAsyncOperationRunning", e))?
            } else {
                false
            };
            (connected, running)
        }
        None => (true, false),
    };
    Ok(State {
        q: call(py, r, "getActualQ", ())?,
        qd: call(py, r, "getActualQd", ())?,
        robot_mode: call(py, r, "getRobotMode", ())?,
        safety_mode: call(py, r, "getSafetyMode", ())?,
        runtime_state: call(py, r, "getRuntimeState", ())?,
        connected: rx_connected && ctl_connected,
        async_running,
    })
}

/// A connected dashboard client (reconnected if its link dropped).
fn dashboard(py: Python<'_>, s: &mut Session, host: &str) -> Result<Py<PyAny>> {
    if let Some(d) = &s.dashboard {
        if call::<bool, _>(py, d, "isConnected", ()).unwrap_or(false) {
            return Ok(d.clone_ref(py));
        }
    }
    let module = import(py, "dashboard_client")?;
    let d = module
        .getattr("DashboardClient")
        .and_then(|c| c.call1((host,)))
        .map_err(|e| py_error(py, "DashboardClient", e))?
        .unbind();
    call::<Py<PyAny>, _>(py, &d, "connect", (2000,))?;
    if let Some(old) = s.dashboard.replace(d.clone_ref(py)) {
        std::mem::forget(old);
    }
    Ok(d)
}

fn json<T: serde::Serialize>(v: T) -> Result<serde_json::Value> {
    serde_json::to_value(v).map_err(|e| DriverError::Backend(Box::new(e)))
}

/// Executes one request.
fn handle(py: Python<'_>, s: &mut Session, req: Request) -> Result<serde_json::Value> {
    match req {
        Request::Hello => json(PROTOCOL),
        Request::ReceiveConnected => json(match &s.receive {
            Some(r) => call::<bool, _>(py, r, "isConnected", ())?,
            None => false,
        }),
        Request::ConnectReceive {
            host,
            frequency_hz,
            variables,
        } => {
            if let Some(r) = s.receive.take() {
                let _ = r.call_method0(py, "disconnect");
            }
            let module = import(py, "rtde_receive")?;
            let r = module
                .getattr("RTDEReceiveInterface")
                .and_then(|c| c.call1((host.as_str(), frequency_hz, variables)))
                .map_err(|e| py_error(py, "RTDEReceiveInterface", e))?;
            s.receive = Some(r.unbind());
            json(())
        }
        Request::ControlConnected => json(match &s.control {
            Some(c) => Some(call::<bool, _>(py, c, "isConnected", ())?),
            None => None,
        }),
        Request::ReadState => json(read_state(py, s)?),
        Request::ConnectControl { host, frequency_hz } => {
            // A previous interface is never reconnected or destroyed here (its background
            // threads may still run): the driver replaces the whole process instead.
            if let Some(old) = s.control.take() {
                std::mem::forget(old);
            }
            let module = import(py, "rtde_control")?;
            let c = module
                .getattr("RTDEControlInterface")
                .and_then(|c| c.call1((host.as_str(), frequency_hz)))
                .map_err(|e| py_error(py, "RTDEControlInterface", e))?;
            s.control = Some(c.unbind());
            json(())
        }
        Request::IsProgramRunning => {
            json(call::<bool, _>(py, control(s)?, "isProgramRunning", ())?)
        }
        Request::ReuploadScript => {
            call::<bool, _>(py, control(s)?, "reuploadScript", ())?;
            json(())
        }
        Request::MoveJ {
            q,
            speed,
            accel,
            asynchronous,
        } => json(call::<bool, _>(
            py,
            control(s)?,
            "moveJ",
            (q, speed, accel, asynchronous),
        )?),
        Request::StopJ { decel } => json(match &s.control {
            Some(c) if call::<bool, _>(py, c, "isConnected", ())? => {
                call::<Py<PyAny>, _>(py, c, "stopJ", (decel,))?;
                true
            }
            _ => false,
        }),
        Request::IsInRemoteControl { host } => {
            let d = dashboard(py, s, &host)?;
            json(call::<bool, _>(py, &d, "isInRemoteControl", ())?)
        }
        Request::DashboardStop { host } => {
            let d = dashboard(py, s, &host)?;
            let reply: String = call(py, &d, "send", ("stop\n",))
                .and_then(|_: Py<PyAny>| call(py, &d, "receive", ()))?;
            if reply.contains("Stopped") {
                json(())
            } else {
                Err(DriverError::Refused(format!(
                    "dashboard stop answered {reply:?}"
                )))
            }
        }
        Request::ClearFault { host } => {
            let d = dashboard(py, s, &host)?;
            call::<Py<PyAny>, _>(py, &d, "closeSafetyPopup", ())?;
            call::<Py<PyAny>, _>(py, &d, "unlockProtectiveStop", ())?;
            json(())
        }
    }
}

/// Takes a private copy of stdout for the protocol and points fd 1 at stderr, so that what
/// ur_rtde prints cannot corrupt the replies.
fn protocol_stdout() -> std::io::Result<std::fs::File> {
    // SAFETY: plain fd syscalls on the process's own standard descriptors; the duplicate is
    // owned by the returned File alone.
    unsafe {
        let fd = libc::dup(libc::STDOUT_FILENO);
        if fd < 0 {
            return Err(std::io::Error::last_os_error());
        }
        let out = std::fs::File::from_raw_fd(fd);
        if libc::dup2(libc::STDERR_FILENO, libc::STDOUT_FILENO) < 0 {
            return Err(std::io::Error::last_os_error());
        }
        Ok(out)
    }
}

/// Serves requests from stdin until it closes; the process's exit code.
pub(super) fn serve() -> u8 {
    // Dies with the driver's thread that started it, even if that cannot say goodbye.
    #[cfg(target_os = "linux")]
    // SAFETY: prctl with integer arguments only.
    unsafe {
        libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGKILL);
    }
    let mut out = match protocol_stdout() {
        Ok(out) => std::io::BufWriter::new(out),
        Err(e) => {
            // The child process has no subscriber: its stderr is what the parent forwards.
            eprintln!("easyhec ur_rtde worker: cannot set up stdout: {e}");
            return 2;
        }
    };
    let mut session = Session::default();
    let stdin = std::io::stdin();
    let mut line = String::new();
    loop {
        line.clear();
        match stdin.lock().read_line(&mut line) {
            Ok(0) | Err(_) => break,
            Ok(_) => {}
        }
        let reply = match serde_json::from_str::<Request>(line.trim_end()) {
            Ok(req) => match Python::attach(|py| handle(py, &mut session, req)) {
                Ok(v) => Reply::Ok(v),
                Err(e) => Reply::Err(WireError::from_driver(e)),
            },
            Err(e) => Reply::Err(WireError::Other(format!("bad request: {e}"))),
        };
        let written = serde_json::to_writer(&mut out, &reply)
            .map_err(std::io::Error::from)
            .and_then(|()| out.write_all(b"\n"))
            .and_then(|()| out.flush());
        if written.is_err() {
            break;
        }
    }
    Python::attach(|py| session.close(py));
    0
}

/// Runs the worker loop of the `easyhec-ur-worker` binary.
pub(super) fn serve_exit_code() -> ExitCode {
    ExitCode::from(serve())
}
