//! `crossline status`: tail the daemon's status socket.

use std::io::{BufReader, Write};
use std::os::unix::net::UnixStream;
use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use crossline::serve::status as wire;

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
    let mut reader = BufReader::new(sock);
    let mut text = String::new();
    while let Some(line) = wire::read_line(&mut reader, &mut text)? {
        let is_status = matches!(line, wire::Line::Status(_));
        if args.json {
            writeln!(out, "{text}")?;
        } else {
            match line {
                wire::Line::Status(st) => writeln!(out, "{}", st.summary())?,
                wire::Line::Event { event, detail } => writeln!(out, "event {event}: {detail}")?,
            }
        }
        out.flush()?;
        if args.once && is_status {
            break;
        }
    }
    Ok(ExitCode::SUCCESS)
}
