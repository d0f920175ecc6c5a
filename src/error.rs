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
    /// A computation could not produce a trustworthy answer.
    #[error("{0}")]
    Solve(String),
    /// An arm or camera failed or refused.
    #[error("{0}")]
    Hardware(String),
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
            field: field.into(),
            message: message.into(),
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
