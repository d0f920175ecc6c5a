//! Where diagnostics go: one `tracing` subscriber for the whole process, set up from the
//! global `--verbose`/`--quiet`/`--log-format` flags and `RUST_LOG`.
//!
//! The text form prints an `info` record as its bare message, so a default run reads exactly
//! as a plain program's output would; other levels carry a `warning:`/`error:`/`debug:`
//! prefix. The daemon adds `--log-format json` (one object per line, for log shippers) and
//! `journald` (structured fields straight to systemd's journal).

use std::fmt;

use clap::{Args, ValueEnum};
use tracing::{Event, Level, Subscriber};
use tracing_subscriber::filter::EnvFilter;
use tracing_subscriber::fmt::format::Writer;
use tracing_subscriber::fmt::{FmtContext, FormatEvent, FormatFields, FormattedFields};
use tracing_subscriber::layer::SubscriberExt;
use tracing_subscriber::registry::LookupSpan;
use tracing_subscriber::util::SubscriberInitExt;

/// Our own crates: `--verbose` and `--quiet` move these; everything else stays at `warn`.
const OUR_CRATES: [&str; 3] = ["easyhec", "easyhec_drivers", "easyhec_mocks"];

/// The logging flags every subcommand takes.
#[derive(Args, Debug, Default)]
pub struct LogArgs {
    /// More diagnostics: -v debug, -vv trace (overrides RUST_LOG).
    #[arg(short, long, global = true, action = clap::ArgAction::Count, conflicts_with = "quiet")]
    pub verbose: u8,
    /// Warnings and errors only (overrides RUST_LOG).
    #[arg(short, long, global = true)]
    pub quiet: bool,
    /// How records are written to stderr: text, json (one object per line) or journald.
    #[arg(
        long,
        global = true,
        value_enum,
        env = "EASYHEC_LOG_FORMAT",
        default_value_t = LogFormat::Text
    )]
    pub log_format: LogFormat,
}

/// Where and how records are written.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, ValueEnum)]
pub enum LogFormat {
    /// Plain lines on stderr; `info` records are the bare message.
    #[default]
    Text,
    /// One JSON object per line on stderr, with timestamp, level, target and fields.
    Json,
    /// Records sent to systemd's journal with their fields (falls back to text with a warning
    /// when there is no journal socket).
    Journald,
}

impl LogArgs {
    /// The filter: `--quiet`/`--verbose` when given, else `RUST_LOG` when set, else `info`
    /// for our crates and `warn` for the rest. A `RUST_LOG` that does not parse is reported
    /// once and the default used.
    fn filter(&self) -> (EnvFilter, Option<String>) {
        let ours = |level: &str| {
            let mut spec = String::from("warn");
            for c in OUR_CRATES {
                spec.push_str(&format!(",{c}={level}"));
            }
            EnvFilter::new(spec)
        };
        match (self.quiet, self.verbose) {
            (true, _) => return (ours("warn"), None),
            (false, 1) => return (ours("debug"), None),
            (false, 2..) => return (ours("trace"), None),
            _ => {}
        }
        match std::env::var("RUST_LOG") {
            Ok(spec) if !spec.trim().is_empty() => match EnvFilter::try_new(&spec) {
                Ok(f) => (f, None),
                Err(e) => (
                    ours("info"),
                    Some(format!(
                        "RUST_LOG={spec:?} does not parse ({e}); using the default (info)"
                    )),
                ),
            },
            _ => (ours("info"), None),
        }
    }

    /// Installs the process's subscriber. Called once, before the subcommand runs.
    pub fn init(&self) {
        let (filter, filter_problem) = self.filter();
        let registry = tracing_subscriber::registry().with(filter);
        let mut fallback = None;
        match self.log_format {
            LogFormat::Text => text_layer(registry).init(),
            LogFormat::Json => registry
                .with(
                    tracing_subscriber::fmt::layer()
                        .json()
                        .with_ansi(false)
                        .with_current_span(true)
                        .with_span_list(false)
                        .with_writer(std::io::stderr),
                )
                .init(),
            LogFormat::Journald => match journald() {
                Ok(layer) => registry.with(layer).init(),
                Err(e) => {
                    text_layer(registry).init();
                    fallback = Some(e);
                }
            },
        }
        if let Some(e) = fallback {
            tracing::warn!("--log-format journald: {e}; writing text to stderr instead");
        }
        if let Some(m) = filter_problem {
            tracing::warn!("{m}");
        }
    }
}

/// The text layer on top of `registry`.
fn text_layer<S>(registry: S) -> impl SubscriberInitExt
where
    S: Subscriber + for<'a> LookupSpan<'a> + Send + Sync + 'static,
{
    registry.with(
        tracing_subscriber::fmt::layer()
            .event_format(PlainText)
            .with_ansi(colour())
            .with_writer(std::io::stderr),
    )
}

/// Colours only on a terminal, and never under `NO_COLOR`.
fn colour() -> bool {
    use std::io::IsTerminal;
    std::io::stderr().is_terminal() && std::env::var_os("NO_COLOR").is_none_or(|v| v.is_empty())
}

/// The journald layer, or why there is none.
#[cfg(unix)]
fn journald() -> Result<tracing_journald::Layer, String> {
    tracing_journald::layer()
        .map(|l| l.with_syslog_identifier("easyhec".into()))
        .map_err(|e| format!("no journal socket ({e})"))
}

/// There is no journal off unix.
#[cfg(not(unix))]
fn journald() -> Result<tracing_subscriber::layer::Identity, String> {
    Err("journald exists only on Linux".into())
}

/// The text form: `[span fields: ]message`, with a level prefix on anything but `info`.
struct PlainText;

impl<S, N> FormatEvent<S, N> for PlainText
where
    S: Subscriber + for<'a> LookupSpan<'a>,
    N: for<'a> FormatFields<'a> + 'static,
{
    fn format_event(
        &self,
        ctx: &FmtContext<'_, S, N>,
        mut writer: Writer<'_>,
        event: &Event<'_>,
    ) -> fmt::Result {
        let prefix = match *event.metadata().level() {
            Level::INFO => "",
            Level::WARN => "warning: ",
            Level::ERROR => "error: ",
            Level::DEBUG => "debug: ",
            Level::TRACE => "trace: ",
        };
        writer.write_str(prefix)?;
        if let Some(scope) = ctx.event_scope() {
            for span in scope.from_root() {
                let ext = span.extensions();
                if let Some(fields) = ext.get::<FormattedFields<N>>() {
                    if !fields.is_empty() {
                        write!(writer, "{fields}: ")?;
                    }
                }
            }
        }
        ctx.field_format().format_fields(writer.by_ref(), event)?;
        writeln!(writer)
    }
}
