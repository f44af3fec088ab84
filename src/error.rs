//! One error type for the whole crate: every message names the file (and line or
//! frame) it is about, so a user can fix their input without reading our code. A path
//! thousands of characters long is shown shortened (`crate::io::short_path`).

use std::path::{Path, PathBuf};

/// Errors raised by sdf-slam. Bad input is always an `Err`, never a panic.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A file could not be opened, read or written.
    #[error("{}: {source}", crate::io::short_path(path))]
    Io {
        /// The file concerned.
        path: PathBuf,
        /// The underlying I/O error.
        #[source]
        source: std::io::Error,
    },
    /// A text file has a malformed line (1-based line number).
    #[error("{}:{line}: {msg}", crate::io::short_path(path))]
    Parse {
        /// The file concerned.
        path: PathBuf,
        /// 1-based line number of the malformed line.
        line: usize,
        /// What is wrong with the line.
        msg: String,
    },
    /// A file is readable but its content is unusable (wrong image format, size...).
    #[error("{}: {msg}", crate::io::short_path(path))]
    Invalid {
        /// The file concerned.
        path: PathBuf,
        /// What is wrong with its content.
        msg: String,
    },
    /// A value could not be written as JSON (its message is serde_json's).
    #[error(transparent)]
    Json(#[from] serde_json::Error),
    /// A value could not be written as TOML (its message is the toml crate's).
    #[error(transparent)]
    TomlWrite(#[from] toml::ser::Error),
    /// An error of a network or a library below, kept whole: its message and its source
    /// chain (see [`Error::wrap`]).
    #[error(transparent)]
    Wrapped(Box<dyn std::error::Error + Send + Sync + 'static>),
    /// Anything else: inconsistent arguments, degenerate data.
    #[error("{0}")]
    Msg(String),
}

/// Crate-wide result.
pub type Result<T, E = Error> = std::result::Result<T, E>;

impl Error {
    /// An [`Error::Io`] about `path`.
    pub fn io(path: impl AsRef<Path>, source: std::io::Error) -> Self {
        Error::Io {
            path: path.as_ref().to_path_buf(),
            source,
        }
    }

    /// An [`Error::Parse`] at 1-based `line` of `path`.
    pub fn parse(path: impl AsRef<Path>, line: usize, msg: impl Into<String>) -> Self {
        Error::Parse {
            path: path.as_ref().to_path_buf(),
            line,
            msg: msg.into(),
        }
    }

    /// An [`Error::Invalid`] about `path`.
    pub fn invalid(path: impl AsRef<Path>, msg: impl Into<String>) -> Self {
        Error::Invalid {
            path: path.as_ref().to_path_buf(),
            msg: msg.into(),
        }
    }

    /// Keeps another error as it is (same message, same source chain).
    pub fn wrap(e: impl std::error::Error + Send + Sync + 'static) -> Self {
        Error::Wrapped(Box::new(e))
    }

    /// An [`Error::Msg`] with the given message.
    pub fn msg(msg: impl Into<String>) -> Self {
        Error::Msg(msg.into())
    }
}

/// The message a panic carried (`panic!` with a string or a format), if any.
pub(crate) fn panic_message(payload: &(dyn std::any::Any + Send)) -> Option<String> {
    payload
        .downcast_ref::<String>()
        .cloned()
        .or_else(|| payload.downcast_ref::<&str>().map(|s| s.to_string()))
}
