//! `crossline status`: tail the daemon's status socket.

use std::io::{BufRead, BufReader, Write};
use std::os::unix::net::UnixStream;
use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use crossline::serve::status::Status;

/// Show what a running `crossline serve` is doing: device state, frames in, dropped and
/// processed, planes solved, the cloud's epoch and size, stream clients, recording.
///
/// The socket streams one JSON object per line (type "status" once a second, type
/// "event" on events); --json prints them as they come, for scripts. Without
/// --json, a one-line summary per status. `socat - UNIX-CONNECT:PATH` shows the raw
/// lines too.
///
/// Examples:
///
///   crossline status
///   crossline status --once --json | jq .points
#[derive(clap::Args)]
#[command(verbatim_doc_comment)]
pub struct Args {
    /// The daemon's status socket ([serve] status_socket).
    #[arg(
        long,
        value_name = "PATH",
        default_value = "/run/crossline/status.sock"
    )]
    socket: PathBuf,
    /// Print the first status line and exit.
    #[arg(long)]
    once: bool,
    /// Print the raw JSON lines.
    #[arg(long)]
    json: bool,
}

pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    let sock = UnixStream::connect(&args.socket).with_context(|| {
        format!(
            "connecting to {} (is `crossline serve` running, and may this user open its socket?)",
            args.socket.display()
        )
    })?;
    let mut out = std::io::stdout().lock();
    for line in BufReader::new(sock).lines() {
        let line = line.context("reading the status socket")?;
        let value: serde_json::Value = serde_json::from_str(&line)
            .with_context(|| format!("status line is not JSON: {line}"))?;
        let is_status = value.get("type").and_then(|t| t.as_str()) == Some("status");
        if args.json {
            writeln!(out, "{line}")?;
        } else if is_status {
            let st: Status = serde_json::from_value(value)
                .with_context(|| format!("unexpected status line: {line}"))?;
            writeln!(out, "{}", st.summary())?;
        } else {
            let event = value.get("event").and_then(|e| e.as_str()).unwrap_or("?");
            let detail = value.get("detail").and_then(|e| e.as_str()).unwrap_or("");
            writeln!(out, "event {event}: {detail}")?;
        }
        out.flush()?;
        if args.once && is_status {
            break;
        }
    }
    Ok(ExitCode::SUCCESS)
}
