//! One error type for the core: every variant names the file or the quantity at fault, so that a user
//! reading the message knows what to fix. Nothing in the core panics on bad input.

use std::path::PathBuf;

/// Errors from reading, validating and fitting diffusion data.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// Opening, reading, writing or creating a file (or directory) failed in the operating system.
    #[error("{path}: {source}")]
    Io {
        /// The file or directory the operation was on.
        path: PathBuf,
        /// The operating system's error (missing file, permission denied, ...).
        source: std::io::Error,
    },
    /// A file exists and was read, but its content is not what its format requires.
    #[error("{path}: {reason}")]
    Format {
        /// The file whose content is at fault.
        path: PathBuf,
        /// What is wrong with it, naming the field or value at fault.
        reason: String,
    },
    /// Arrays or files that must agree in size do not.
    #[error("shape mismatch: {0}")]
    Shape(String),
    /// A parameter outside its valid range.
    #[error("invalid parameter: {0}")]
    Param(String),
}

/// The core's result type: [`Error`] unless another error type is named.
pub type Result<T, E = Error> = std::result::Result<T, E>;

impl Error {
    pub(crate) fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Error::Io { path: path.into(), source }
    }
    pub(crate) fn format(path: impl Into<PathBuf>, reason: impl Into<String>) -> Self {
        Error::Format { path: path.into(), reason: reason.into() }
    }
}
