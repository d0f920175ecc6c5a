//! What a long command shows while it works: an indicatif spinner on stderr with the current
//! step and the elapsed time. Only on a terminal and only at the default log level or above
//! (`--quiet` hides it); piped or redirected output gets the plain log lines alone, so logs
//! and CI output stay free of control characters.

use std::io::IsTerminal;
use std::time::Duration;

use indicatif::{ProgressBar, ProgressStyle};

/// A spinner for one command, cleared when dropped.
pub struct Activity {
    pb: ProgressBar,
}

impl Activity {
    /// Starts the spinner labelled `what` (hidden off a terminal or under `--quiet`).
    pub fn start(what: &str) -> Self {
        // Hidden at debug level too: the solver's records would be written over it.
        let shown = std::io::stderr().is_terminal()
            && tracing::enabled!(tracing::Level::INFO)
            && !tracing::enabled!(tracing::Level::DEBUG);
        if !shown {
            return Activity {
                pb: ProgressBar::hidden(),
            };
        }
        let pb = ProgressBar::new_spinner();
        pb.set_style(
            ProgressStyle::with_template("{spinner} {prefix} [{elapsed}] {wide_msg}")
                .unwrap_or_else(|_| ProgressStyle::default_spinner()),
        );
        pb.set_prefix(what.to_string());
        pb.enable_steady_tick(Duration::from_millis(120));
        Activity { pb }
    }

    /// Logs `line` (info) above the spinner and shows it as the current step.
    pub fn note(&self, line: &str) {
        self.pb.suspend(|| tracing::info!("{line}"));
        self.pb.set_message(line.to_string());
    }
}

impl Drop for Activity {
    fn drop(&mut self) {
        self.pb.finish_and_clear();
    }
}
