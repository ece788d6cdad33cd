//! One error type for the core: every variant names the file or the quantity at fault, so that a user
//! reading the message knows what to fix. Nothing in the core panics on bad input.

use std::path::PathBuf;

/// Errors from reading, validating and fitting diffusion data.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error("{path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    /// A file exists and was read, but its content is not what its format requires.
    #[error("{path}: {reason}")]
    Format { path: PathBuf, reason: String },
    /// Arrays or files that must agree in size do not.
    #[error("shape mismatch: {0}")]
    Shape(String),
    /// A parameter outside its valid range.
    #[error("invalid parameter: {0}")]
    Param(String),
}

pub type Result<T, E = Error> = std::result::Result<T, E>;

impl Error {
    pub(crate) fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Error::Io { path: path.into(), source }
    }
    pub(crate) fn format(path: impl Into<PathBuf>, reason: impl Into<String>) -> Self {
        Error::Format { path: path.into(), reason: reason.into() }
    }
}
