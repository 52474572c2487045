//! Helpers shared by the integration tests.

#![allow(dead_code)]

use std::path::PathBuf;
use std::process::Command;

/// The `crossline` binary Cargo built for these tests.
pub fn crossline() -> Command {
    Command::new(env!("CARGO_BIN_EXE_crossline"))
}

/// The project's `fixtures/` folder.
pub fn fixtures() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("fixtures")
}
