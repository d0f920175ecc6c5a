//! One error type for the library: every variant names the file and the field at fault and,
//! where there is one, the fix — so a user sees a single actionable line.

use std::path::{Path, PathBuf};

/// Library error. Binaries print it as one line and exit non-zero.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// Bad or missing content in an input file.
    #[error("{}: {field}: {message}", file.display())]
    Input {
        /// The file at fault.
        file: PathBuf,
        /// The field (JSON path, URDF element, pixel row …) at fault.
        field: String,
        /// What is wrong and how to fix it.
        message: String,
    },
    /// The operating system refused a read or write.
    #[error("{}: {message}", file.display())]
    Io {
        /// The file at fault.
        file: PathBuf,
        /// What failed.
        message: String,
    },
    /// A command-line flag or argument is out of range or malformed.
    #[error("{0}")]
    Usage(String),
    /// A computation could not produce a trustworthy answer.
    #[error("{0}")]
    Solve(String),
    /// The library found an arm or camera in a state it cannot work with (a frame of the
    /// wrong size, an arm that moved since its path was checked, a segmenter's device error).
    #[error("{0}")]
    Hardware(String),
    /// The ROS 2 side failed: a DDS participant, topic or writer could not be made, or a
    /// publication was refused.
    #[error("ROS 2: {0}")]
    Ros2(String),
    /// A driver call failed. The driver's error is kept whole, so a caller can tell a refused
    /// target from a fault, a stall, a timeout or a lost link (`DriverError::kind`, or match
    /// the variant) instead of reading a string.
    #[error("{}{driver}", if context.is_empty() { String::new() } else { format!("{context}: ") })]
    Driver {
        /// What the library was doing ("reading joints before a move"); may be empty.
        context: String,
        /// The driver's error. Not a `source` in the error chain: its text is already in this
        /// error's message, and the command line prints the chain.
        driver: easyhec_drivers::DriverError,
    },
}

/// Longest text an error line echoes from its input before [`cut`] shortens it.
pub const ECHO_BYTES: usize = 600;

/// `text` as an error line may echo it: whole when short, else its first and last 240 bytes
/// around a note of how much was cut, so a 60 MB value in a file becomes one readable line
/// that still ends with what is allowed.
pub fn cut(text: &str) -> std::borrow::Cow<'_, str> {
    if text.len() <= ECHO_BYTES {
        return std::borrow::Cow::Borrowed(text);
    }
    let head = floor_boundary(text, 240);
    let tail = ceil_boundary(text, text.len() - 240);
    std::borrow::Cow::Owned(format!(
        "{} … ({} bytes cut) … {}",
        &text[..head],
        tail - head,
        &text[tail..]
    ))
}

fn floor_boundary(s: &str, mut i: usize) -> usize {
    while !s.is_char_boundary(i) {
        i -= 1;
    }
    i
}

fn ceil_boundary(s: &str, mut i: usize) -> usize {
    while !s.is_char_boundary(i) {
        i += 1;
    }
    i
}

impl From<easyhec_drivers::DriverError> for Error {
    fn from(driver: easyhec_drivers::DriverError) -> Self {
        Error::Driver {
            context: String::new(),
            driver,
        }
    }
}

impl Error {
    /// Bad content in `file` at `field`.
    pub fn input(
        file: impl AsRef<Path>,
        field: impl Into<String>,
        message: impl Into<String>,
    ) -> Self {
        Error::Input {
            file: file.as_ref().to_path_buf(),
            field: cut(&field.into()).into_owned(),
            message: cut(&message.into()).into_owned(),
        }
    }

    /// A driver error with what the library was doing when it happened.
    pub fn driver(context: impl Into<String>, driver: easyhec_drivers::DriverError) -> Self {
        Error::Driver {
            context: context.into(),
            driver,
        }
    }

    /// The driver error behind this error, when a driver call failed.
    pub fn driver_error(&self) -> Option<&easyhec_drivers::DriverError> {
        match self {
            Error::Driver { driver, .. } => Some(driver),
            _ => None,
        }
    }

    /// An I/O failure on `file`.
    pub fn io(file: impl AsRef<Path>, err: impl std::fmt::Display) -> Self {
        Error::Io {
            file: file.as_ref().to_path_buf(),
            message: err.to_string(),
        }
    }
}

/// Library result.
pub type Result<T, E = Error> = std::result::Result<T, E>;
