//! Typed errors shared across module boundaries. Modules with their own failure modes
//! define their own `thiserror` enum beside their code; this file holds the ones that
//! several modules return.

use std::path::PathBuf;

/// A file of ours or a user's could not be read or parsed.
#[derive(Debug, thiserror::Error)]
pub enum FileError {
    #[error("cannot read {path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}:{line}: {message}")]
    Parse {
        path: PathBuf,
        line: usize,
        message: String,
    },
}
