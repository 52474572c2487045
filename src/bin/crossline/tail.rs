//! `crossline tail`: a cloud stream client.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::Context;
use crossline::serve::stream::{Event, Follower, StreamError};

/// Follow a running `crossline serve`'s cloud stream and save the cloud.
///
/// The client receives the current cloud, then its growth, then each re-estimated
/// epoch, until the daemon finishes the scan; the saved PLY then equals the daemon's
/// own final cloud. With --save-every the current cloud is also written while the
/// scan grows (atomically: the file is always a whole PLY).
///
/// Examples:
///
///   crossline tail --out live.ply
///   crossline tail --connect 192.168.2.10:7878 --out live.ply --save-every 10
///   crossline tail --unix /run/crossline/cloud.sock --out live.ply
#[derive(clap::Args)]
#[command(verbatim_doc_comment)]
pub struct Args {
    /// The daemon's TCP stream address ([serve] stream_tcp).
    #[arg(long, value_name = "HOST:PORT", default_value = "127.0.0.1:7878")]
    connect: String,
    /// Connect to this Unix socket instead ([serve] stream_unix).
    #[arg(long, value_name = "PATH")]
    unix: Option<PathBuf>,
    /// Where to save the cloud (binary PLY).
    #[arg(long, value_name = "FILE")]
    out: PathBuf,
    /// Also save the growing cloud every this many seconds.
    #[arg(long, value_name = "SECONDS")]
    save_every: Option<f64>,
}

fn save(f: &Follower, out: &std::path::Path) -> anyhow::Result<()> {
    crossline::ply::write_ply_atomic(
        out,
        &f.cloud(),
        &[format!("crossline tail, epoch {}", f.epoch)],
    )
    .with_context(|| format!("saving the cloud to {}", out.display()))
}

pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    let mut reader: Box<dyn std::io::Read> = match &args.unix {
        Some(path) => Box::new(
            std::os::unix::net::UnixStream::connect(path)
                .with_context(|| format!("connecting to {}", path.display()))?,
        ),
        None => Box::new(
            std::net::TcpStream::connect(&args.connect).with_context(|| {
                format!(
                    "connecting to {} (is `crossline serve` running?)",
                    args.connect
                )
            })?,
        ),
    };
    let mut reader = std::io::BufReader::with_capacity(1 << 20, &mut reader);
    let mut f = Follower::default();
    let every = args.save_every.map(Duration::from_secs_f64);
    let mut last_save = Instant::now();
    loop {
        match f.step(&mut reader) {
            Ok(Some(Event::Hello { info })) => tracing::info!("connected: {info}"),
            Ok(Some(Event::Epoch { epoch, reason })) => {
                tracing::info!(epoch, reason, "new epoch");
            }
            Ok(Some(Event::Points { .. })) => {
                if every.is_some_and(|e| last_save.elapsed() >= e) {
                    save(&f, &args.out)?;
                    last_save = Instant::now();
                }
            }
            Ok(Some(Event::End { epoch, total })) => {
                save(&f, &args.out)?;
                eprintln!(
                    "crossline: scan finished (epoch {epoch}): {total} points saved to {}",
                    args.out.display()
                );
                return Ok(ExitCode::SUCCESS);
            }
            Ok(None)
            | Err(StreamError::Io(_))
            | Err(StreamError::Bye(_))
            | Err(StreamError::Malformed { .. })
                if !f.points.is_empty() =>
            {
                save(&f, &args.out)?;
                eprintln!(
                    "crossline: error: the stream ended before the scan finished; saved the {} points of epoch {} to {}",
                    f.points.len(),
                    f.epoch,
                    args.out.display()
                );
                return Ok(ExitCode::FAILURE);
            }
            Ok(None) => anyhow::bail!("the daemon closed the stream before sending any cloud"),
            Err(e) => return Err(e).context("following the cloud stream"),
        }
    }
}
