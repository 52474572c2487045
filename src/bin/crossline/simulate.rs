//! `crossline simulate` (placeholder, filled by its owner).

use std::process::ExitCode;

/// (placeholder)
#[derive(clap::Args)]
pub struct Args {}

pub fn run(_args: Args) -> anyhow::Result<ExitCode> {
    anyhow::bail!("`crossline simulate` is not implemented yet")
}
