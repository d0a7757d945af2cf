//! The library's one error type. Every variant that concerns a file names it.

use std::path::PathBuf;

/// Result alias used throughout the library.
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// Everything that can go wrong in btfquilt.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// An operating-system I/O error on a named file.
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// The file does not start with a btfquilt container header.
    #[error("{}: not a btfquilt container ({reason})", path.display())]
    NotContainer { path: PathBuf, reason: String },
    /// The file was written by a newer btfquilt.
    #[error("{}: container format version {found} is newer than this build supports (version {supported}); upgrade btfquilt", path.display())]
    UnsupportedVersion {
        path: PathBuf,
        found: u32,
        supported: u32,
    },
    /// The file is shorter than its header says: an interrupted copy or write.
    #[error("{}: truncated: the header promises {expected} bytes but the file has {actual}", path.display())]
    Truncated {
        path: PathBuf,
        expected: u64,
        actual: u64,
    },
    /// A chunk (or the metadata/index block) failed to decode or its checksum does not match.
    #[error("{}: array '{array}', chunk {chunk}: {reason}", path.display())]
    Corrupt {
        path: PathBuf,
        array: String,
        chunk: String,
        reason: String,
    },
    /// An input file (image, mesh, manifest, container of the wrong kind, ...) is unusable.
    #[error("{}: {reason}", path.display())]
    Input { path: PathBuf, reason: String },
    /// A parameter or option is out of range.
    #[error("{0}")]
    Config(String),
}

impl Error {
    /// Shorthand for [`Error::Io`].
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Error::Io {
            path: path.into(),
            source,
        }
    }

    /// Shorthand for [`Error::Input`].
    pub fn input(path: impl Into<PathBuf>, reason: impl Into<String>) -> Self {
        Error::Input {
            path: path.into(),
            reason: reason.into(),
        }
    }
}
