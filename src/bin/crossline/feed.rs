//! `crossline feed`: plays a dump into a v4l2loopback device, so that anything that
//! reads cameras (the daemon, `record`, a viewer) can be tested without one.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use crossline::capture::dump::{DumpError, DumpHeader, DumpReader};
use crossline::capture::v4l2::{fourcc_name, OutputDevice, OutputFormat};

/// Play a dump into a v4l2loopback device, as if it were a camera.
///
/// Sets the device's output format to the dump's pixel format and size, then writes
/// each recorded buffer unchanged, paced by the clock at --fps (by default the rate
/// recorded in the dump). Readers of the device see a camera delivering those frames.
#[derive(clap::Args)]
#[command(after_help = "\
Examples:
  sudo modprobe v4l2loopback video_nr=10 exclusive_caps=1 card_label=crossline-feed
  crossline feed --device /dev/video10 --input dive.dump --loop
  crossline record --device /dev/video10 --out copy.dump --frames 50

  # Simulate a camera that stalls for 3 s after 100 frames, then comes back:
  crossline feed --device /dev/video10 --input dive.dump --pause-after 100 --pause-seconds 3
  # ... or that vanishes (the writer closes the device during the pause):
  crossline feed --device /dev/video10 --input dive.dump --pause-after 100 \\
      --pause-seconds 3 --close-during-pause

The device keeps its format only while feed holds it open; with exclusive_caps=1
it shows up as a capture device only then. Stops at the end of the dump (unless
--loop), at --stop-after, or on Ctrl-C / SIGTERM.")]
pub struct Args {
    /// The v4l2loopback node to write to.
    #[arg(long)]
    device: PathBuf,
    /// The dump to play (from `crossline record`).
    #[arg(long)]
    input: PathBuf,
    /// Frames per second; by default the dump's recorded rate, or 30 if it has none.
    #[arg(long)]
    fps: Option<f64>,
    /// Start again from the first frame at the end of the dump.
    #[arg(long = "loop")]
    repeat: bool,
    /// Stop after writing this many frames.
    #[arg(long)]
    stop_after: Option<u64>,
    /// Pause once after writing this many frames...
    #[arg(long, requires = "pause_seconds")]
    pause_after: Option<u64>,
    /// ...for this many seconds, then go on.
    #[arg(long, requires = "pause_after")]
    pause_seconds: Option<f64>,
    /// Close the device during the pause and reopen it after, as an unplugged camera.
    #[arg(long, requires = "pause_after")]
    close_during_pause: bool,
}

fn output_format(header: &DumpHeader, fps: f64) -> OutputFormat {
    OutputFormat {
        fourcc: header.fourcc,
        width: header.width,
        height: header.height,
        bytes_per_line: header.bytes_per_line,
        fps,
    }
}

fn open(path: &Path, format: &OutputFormat) -> anyhow::Result<OutputDevice> {
    OutputDevice::open(path, format)
        .context("is the v4l2loopback module loaded? (modprobe v4l2loopback)")
}

/// Sleeps until `until`, in short steps so a signal stops it promptly. False if
/// stopped.
fn sleep_until(until: Instant, stop: &AtomicBool) -> bool {
    loop {
        if stop.load(Ordering::Relaxed) {
            return false;
        }
        let now = Instant::now();
        if now >= until {
            return true;
        }
        std::thread::sleep((until - now).min(Duration::from_millis(100)));
    }
}

/// Frame `k` is due at `start + k·period`: the schedule comes from the clock, so
/// sleeping late once does not slow every later frame.
struct Pacer {
    start: Instant,
    period: Duration,
    next: u64,
}

impl Pacer {
    fn new(period: Duration) -> Pacer {
        Pacer {
            start: Instant::now(),
            period,
            next: 0,
        }
    }

    /// When the next frame is due. More than a period behind (a pause, a slow disk),
    /// the schedule restarts now instead of bursting to catch up.
    fn due(&mut self) -> Instant {
        let due = self.start + self.period.mul_f64(self.next as f64);
        let now = Instant::now();
        if now > due + self.period {
            self.start = now;
            self.next = 0;
            return now;
        }
        due
    }

    fn sent(&mut self) {
        self.next += 1;
    }

    fn restart(&mut self) {
        self.start = Instant::now();
        self.next = 0;
    }
}

pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    let mut reader = DumpReader::open(&args.input)?;
    let header = reader.header().clone();
    let fps = match args.fps {
        Some(f) if !(f.is_finite() && f > 0.0) => bail!("--fps {f}: expected a positive number"),
        Some(f) => f,
        None if header.interval_num > 0 && header.interval_den > 0 => {
            header.interval_den as f64 / header.interval_num as f64
        }
        None => 30.0,
    };
    let pause = match args.pause_seconds {
        Some(s) if !(s.is_finite() && s >= 0.0) => {
            bail!("--pause-seconds {s}: expected a number of seconds")
        }
        Some(s) => Some(Duration::from_secs_f64(s)),
        None => None,
    };
    let stop = crate::stop_on_signals()?;
    let format = output_format(&header, fps);
    let mut device = Some(open(&args.device, &format)?);
    eprintln!(
        "crossline feed: {} {}x{} from {} (recorded from {}, {}) into {} at {fps:.3} fps",
        fourcc_name(header.fourcc),
        header.width,
        header.height,
        args.input.display(),
        header.device,
        header.card,
        args.device.display()
    );

    let mut pacer = Pacer::new(Duration::from_secs_f64(1.0 / fps));
    let mut written: u64 = 0;
    let mut in_pass: u64 = 0;
    let mut paused = false;
    let end = 'feed: loop {
        if args.stop_after.is_some_and(|n| written >= n) {
            break "--stop-after reached";
        }
        if let (Some(after), Some(pause), false) = (args.pause_after, pause, paused) {
            if written >= after {
                paused = true;
                if args.close_during_pause {
                    device = None;
                }
                eprintln!(
                    "crossline feed: pausing {:.1} s after {written} frames{}",
                    pause.as_secs_f64(),
                    if args.close_during_pause {
                        " with the device closed"
                    } else {
                        ""
                    }
                );
                if !sleep_until(Instant::now() + pause, &stop) {
                    break "stopped by signal";
                }
                if device.is_none() {
                    device = Some(open(&args.device, &format)?);
                }
                eprintln!("crossline feed: resuming");
                pacer.restart();
            }
        }
        let record = match reader.next_record() {
            Ok(Some(r)) => r,
            Ok(None) => {
                if !args.repeat {
                    break "end of dump";
                }
                if in_pass == 0 {
                    bail!("{}: no frames to loop over", args.input.display());
                }
                reader = DumpReader::open(&args.input)?;
                in_pass = 0;
                continue;
            }
            Err(e @ (DumpError::Truncated { .. } | DumpError::Corrupt { .. })) => {
                // The whole frames before it are good; a recording cut off by a crash
                // is the usual case.
                tracing::warn!("{e}; treating it as the end of the dump");
                if !args.repeat || in_pass == 0 {
                    break 'feed "end of the readable dump";
                }
                reader = DumpReader::open(&args.input)?;
                in_pass = 0;
                continue;
            }
            Err(e) => return Err(e.into()),
        };
        if !sleep_until(pacer.due(), &stop) {
            break "stopped by signal";
        }
        let Some(out) = device.as_mut() else {
            bail!("internal: device closed outside a pause");
        };
        out.write_frame(&record.payload).with_context(|| {
            format!(
                "writing frame {} (sequence {}) of {}",
                in_pass,
                record.sequence,
                args.input.display()
            )
        })?;
        tracing::trace!(
            sequence = record.sequence,
            bytes = record.payload.len(),
            "fed"
        );
        pacer.sent();
        written += 1;
        in_pass += 1;
    };
    eprintln!("crossline feed: {end}: wrote {written} frames");
    Ok(ExitCode::SUCCESS)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_pacer_follows_the_clock_and_does_not_burst_after_a_stall() {
        let period = Duration::from_millis(10);
        let mut p = Pacer::new(period);
        let t0 = p.start;
        assert_eq!(p.due(), t0);
        p.sent();
        p.sent();
        assert_eq!(p.due(), t0 + 2 * period);
        std::thread::sleep(Duration::from_millis(50));
        let late = p.due();
        assert!(late > t0 + 40 * Duration::from_millis(1), "restarted now");
        assert_eq!(p.next, 0);
    }
}
