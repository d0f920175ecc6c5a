//! How a command ends, beyond success and the one-line error (exit 1): the codes a script
//! can tell apart (docs/cli.md lists them), and standard output that never panics.
//!
//! | code | meaning |
//! |---|---|
//! | 0 | done |
//! | 1 | bad input or an error, one `error:` line |
//! | 3 | `calibrate`: the loop stopped on an arm fault (the run folder keeps what it recorded) |
//! | 129, 130, 143 | `calibrate`: stopped by SIGHUP, SIGINT or SIGTERM (the arm was stopped) |
//! | 141 | standard output was closed by its reader (`… \| head`): ended quietly |

use std::fmt;
use std::io::Write;
use std::sync::atomic::{AtomicBool, Ordering};

/// Exit code: the loop stopped on an arm fault.
pub const FAULT: u8 = 3;
/// Exit code: the reader closed standard output (128 + SIGPIPE, as a shell reports a tool
/// that SIGPIPE ended).
pub const CLOSED_PIPE: u8 = 141;

/// A command's end with its own exit code and, unless quiet, one `error:` line.
#[derive(Debug)]
pub struct Exit {
    /// The process's exit code.
    pub code: u8,
    /// The line printed after `error: ` (none: end quietly).
    pub message: Option<String>,
}

impl fmt::Display for Exit {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.message.as_deref().unwrap_or("(quiet exit)"))
    }
}

impl std::error::Error for Exit {}

/// Writes a command's output to standard output. A reader that closed the pipe ends the
/// command quietly ([`CLOSED_PIPE`]); any other failure, a closed standard output included
/// (which the standard library would otherwise ignore), is one error line: a script must
/// never take a result it did not get for success.
pub fn stdout(args: fmt::Arguments<'_>) -> anyhow::Result<()> {
    if !stdout_is_open() {
        anyhow::bail!("standard output is closed: nowhere to write the result (drop `>&-`, or redirect it to a file)");
    }
    let mut out = std::io::stdout().lock();
    let written = out.write_fmt(args).and_then(|()| out.flush());
    match written {
        Ok(()) => Ok(()),
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => Err(Exit {
            code: CLOSED_PIPE,
            message: None,
        }
        .into()),
        Err(e) => anyhow::bail!("standard output: {e}"),
    }
}

/// Whether file descriptor 1 was open when the process started. The standard library
/// reopens a closed standard output on /dev/null before `main` runs, so by then `>&-` looks
/// like `> /dev/null`; this is recorded first, by a constructor the loader runs.
static STDOUT_OPEN_AT_START: AtomicBool = AtomicBool::new(true);

#[cfg(target_os = "linux")]
#[used]
#[link_section = ".init_array"]
static RECORD_STDOUT_AT_START: extern "C" fn() = {
    extern "C" fn record() {
        // SAFETY: F_GETFD only reads the descriptor's flags.
        let open = unsafe { libc::fcntl(1, libc::F_GETFD) } != -1;
        STDOUT_OPEN_AT_START.store(open, Ordering::Relaxed);
    }
    record
};

/// Whether standard output leads anywhere: it was open at start.
fn stdout_is_open() -> bool {
    STDOUT_OPEN_AT_START.load(Ordering::Relaxed)
}

/// `println!` for a command's output, through [`stdout`]; returns from the function on error.
macro_rules! outln {
    ($($arg:tt)*) => {
        $crate::cli::exit::stdout(format_args!("{}\n", format_args!($($arg)*)))?
    };
}

/// `print!` for a command's output, through [`stdout`].
macro_rules! out {
    ($($arg:tt)*) => {
        $crate::cli::exit::stdout(format_args!($($arg)*))?
    };
}

pub(crate) use {out, outln};
