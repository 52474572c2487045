//! `crossline record`: every buffer a V4L2 camera delivers, as it came, into a dump
//! (format in `crossline::capture::dump`), with the driver's sequence numbers and
//! timestamps, until a frame count, a duration or Ctrl-C.

use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use crossline::capture::dump::DumpWriter;
use crossline::capture::v4l2::{fourcc_name, Device, FormatRequest, FrameSize, V4l2Error};

/// Record raw frames from a V4L2 camera into a dump file.
///
/// Asks the camera for the pixel formats in the order given, the size and the frame
/// rate; the driver may grant something else, and what it granted is printed (and
/// stored in the dump's header). Each buffer is written as the driver delivered it and
/// flushed at once, so a crash or pulled cable leaves a readable dump. Frames the driver
/// dropped (jumps in its sequence numbers) are counted and reported at the end.
#[derive(clap::Args)]
#[command(after_help = "\
Examples:
  crossline record --device /dev/video0 --out dive.dump --seconds 60
  crossline record --device /dev/v4l/by-id/usb-Camera-video-index0 \\
      --out test.dump --format yuyv --size 640x480 --fps 15 --frames 100
  crossline record --device /dev/video0 --list-formats   # what the camera offers

Stops at --frames, at --seconds, or on Ctrl-C / SIGTERM (the dump is complete
either way). Exits non-zero if the device is missing, not a camera, lost while
recording, or silent for --timeout seconds; the frames recorded until then stay
in the dump.")]
pub struct Args {
    /// The camera: /dev/videoN or a stable /dev/v4l/by-id/... link.
    #[arg(long)]
    device: PathBuf,
    /// Where to write the dump.
    #[arg(long, required_unless_present = "list_formats")]
    out: Option<PathBuf>,
    /// List the pixel formats, frame sizes and frame rates the camera offers, and exit.
    #[arg(long)]
    list_formats: bool,
    /// Pixel formats in order of preference (repeat or separate with commas). If the
    /// camera offers none of them, any of mjpg, yuyv, rgb3 it offers is used instead.
    #[arg(long = "format", value_enum, value_delimiter = ',', ignore_case = true,
          default_values_t = [PixelFormat::Mjpg, PixelFormat::Yuyv])]
    formats: Vec<PixelFormat>,
    /// Frame size WIDTHxHEIGHT; the driver picks the nearest it supports.
    #[arg(long, default_value = "1920x1080", value_parser = parse_size)]
    size: (u32, u32),
    /// Frames per second to ask for (0 keeps the camera's current rate).
    #[arg(long, default_value_t = 30)]
    fps: u32,
    /// Stop after this many frames.
    #[arg(long)]
    frames: Option<u64>,
    /// Stop after this many seconds.
    #[arg(long)]
    seconds: Option<f64>,
    /// Give up (exit 1) when no frame arrives for this many seconds; by default wait
    /// for as long as it takes, warning every 5 s.
    #[arg(long)]
    timeout: Option<f64>,
    /// Driver buffers to queue; more buffers ride out longer stalls of the disk.
    #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u32).range(2..=32))]
    buffers: u32,
}

#[derive(Clone, Copy, Debug, clap::ValueEnum)]
pub enum PixelFormat {
    /// Motion JPEG: small, what USB cameras deliver at full size.
    Mjpg,
    /// YUV 4:2:2, uncompressed.
    Yuyv,
    /// Packed 8-bit RGB, uncompressed.
    Rgb3,
}

impl PixelFormat {
    pub fn fourcc(self) -> [u8; 4] {
        match self {
            PixelFormat::Mjpg => *b"MJPG",
            PixelFormat::Yuyv => *b"YUYV",
            PixelFormat::Rgb3 => *b"RGB3",
        }
    }
}

pub fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let bad = || format!("{s:?}: expected WIDTHxHEIGHT, e.g. 1920x1080");
    let (w, h) = s.split_once(['x', 'X']).ok_or_else(bad)?;
    let (w, h) = (
        w.trim().parse::<u32>().map_err(|_| bad())?,
        h.trim().parse::<u32>().map_err(|_| bad())?,
    );
    if w == 0 || h == 0 {
        return Err(bad());
    }
    Ok((w, h))
}

/// What the recording saw, for the closing report.
#[derive(Default)]
struct Tally {
    frames: u64,
    bytes: u64,
    /// Frames missing from the driver's sequence numbers.
    dropped: u64,
    /// Places where the sequence jumped.
    gaps: u64,
    /// Frames the driver flagged as damaged, or delivered empty.
    damaged: u64,
    first_sequence: Option<u32>,
    last_sequence: Option<u32>,
}

impl Tally {
    fn add(&mut self, sequence: u32, bytes: usize, damaged: bool) {
        if let Some(last) = self.last_sequence {
            let step = sequence.wrapping_sub(last);
            if step > 1 && step < u32::MAX / 2 {
                self.dropped += u64::from(step - 1);
                self.gaps += 1;
                tracing::debug!("sequence jumped from {last} to {sequence}");
            }
        }
        self.first_sequence.get_or_insert(sequence);
        self.last_sequence = Some(sequence);
        self.frames += 1;
        self.bytes += bytes as u64;
        self.damaged += u64::from(damaged);
    }

    fn report(&self) -> String {
        let mut s = format!("{} frames, {} MB", self.frames, self.bytes / 1_000_000);
        if let (Some(a), Some(b)) = (self.first_sequence, self.last_sequence) {
            s.push_str(&format!(", sequence {a}..={b}"));
        }
        s.push_str(&format!("; {} frames dropped by the driver", self.dropped));
        if self.gaps > 0 {
            let plural = if self.gaps == 1 { "" } else { "s" };
            s.push_str(&format!(" (in {} gap{plural})", self.gaps));
        }
        if self.damaged > 0 {
            s.push_str(&format!(
                "; {} frames flagged as damaged or empty",
                self.damaged
            ));
        }
        s
    }
}

/// One line per format and frame size, with the frame rates of discrete sizes.
fn print_formats(device: &Device) -> anyhow::Result<()> {
    for format in device.formats()? {
        println!(
            "{} ({}{})",
            fourcc_name(format.fourcc),
            format.description,
            if format.compressed {
                ", compressed"
            } else {
                ""
            }
        );
        for size in &format.sizes {
            match size {
                FrameSize::Discrete {
                    width,
                    height,
                    intervals,
                } => {
                    let rates: Vec<String> = intervals
                        .iter()
                        .filter(|(num, _)| *num > 0)
                        .map(|(num, den)| format!("{:.4}", *den as f64 / *num as f64))
                        .map(|r| r.trim_end_matches('0').trim_end_matches('.').to_string())
                        .collect();
                    if rates.is_empty() {
                        println!("  {width}x{height}");
                    } else {
                        println!("  {width}x{height} at {} fps", rates.join(", "));
                    }
                }
                FrameSize::Stepwise {
                    min_width,
                    max_width,
                    step_width,
                    min_height,
                    max_height,
                    step_height,
                } => println!(
                    "  {min_width}..={max_width} (step {step_width}) x {min_height}..={max_height} (step {step_height})"
                ),
            }
        }
    }
    Ok(())
}

pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    if args.frames == Some(0) {
        bail!("--frames 0 would record nothing");
    }
    let duration = match args.seconds {
        Some(s) if !(s.is_finite() && s > 0.0) => {
            bail!("--seconds {s}: expected a positive number")
        }
        Some(s) => Some(Duration::from_secs_f64(s)),
        None => None,
    };
    let timeout = match args.timeout {
        Some(s) if !(s.is_finite() && s > 0.0) => {
            bail!("--timeout {s}: expected a positive number of seconds")
        }
        Some(s) => Some(Duration::from_secs_f64(s)),
        None => None,
    };
    let stop = crate::stop_on_signals()?;

    let mut device = Device::open(&args.device)?;
    let Some(out) = args.out.clone() else {
        print_formats(&device)?;
        return Ok(ExitCode::SUCCESS);
    };
    let request = FormatRequest {
        fourccs: args.formats.iter().map(|f| f.fourcc()).collect(),
        width: args.size.0,
        height: args.size.1,
        fps: args.fps,
    };
    let negotiated = device.negotiate(&request)?;
    eprintln!("crossline record: negotiated {negotiated}");
    for note in &negotiated.fallbacks {
        eprintln!("crossline record: note: {note}");
    }
    let mut stream = device.start(args.buffers)?;
    let mut writer = DumpWriter::create(&out, &negotiated.dump_header())?;
    eprintln!(
        "crossline record: recording to {} with {} buffers; Ctrl-C stops",
        out.display(),
        stream.buffer_count()
    );

    let started = Instant::now();
    let deadline = duration.map(|d| started + d);
    let mut tally = Tally::default();
    let mut last_frame_at = Instant::now();
    let mut warned_silence = Duration::ZERO;
    let end = loop {
        if stop.load(Ordering::Relaxed) {
            break "stopped by signal";
        }
        if args.frames.is_some_and(|n| tally.frames >= n) {
            break "frame count reached";
        }
        let now = Instant::now();
        if deadline.is_some_and(|d| now >= d) {
            break "duration reached";
        }
        // Short waits keep Ctrl-C and the deadline prompt.
        let wait = deadline.map_or(Duration::from_millis(250), |d| {
            (d - now).min(Duration::from_millis(250))
        });
        match stream.next_frame(wait) {
            Ok(Some(frame)) => {
                let damaged = frame.is_error() || frame.bytes.is_empty();
                tally.add(frame.sequence, frame.bytes.len(), damaged);
                writer
                    .write_frame(
                        frame.sequence,
                        frame.timestamp_nanos,
                        frame.flags,
                        frame.bytes,
                    )
                    .with_context(|| format!("after {}", tally.report()))?;
                last_frame_at = Instant::now();
                warned_silence = Duration::ZERO;
            }
            Ok(None) => {
                let silent = last_frame_at.elapsed();
                if timeout.is_some_and(|t| silent >= t) {
                    writer.finish()?;
                    bail!(
                        "no frame from {} for {:.1} s (--timeout) after {}; {} holds the frames recorded until then",
                        args.device.display(),
                        silent.as_secs_f64(),
                        tally.report(),
                        out.display()
                    );
                }
                if silent >= warned_silence + Duration::from_secs(5) {
                    warned_silence = silent;
                    tracing::warn!(
                        "{}: no frame for {:.0} s",
                        args.device.display(),
                        silent.as_secs_f64()
                    );
                }
            }
            Err(e) => {
                let lost = matches!(e, V4l2Error::DeviceLost { .. });
                let what = if lost {
                    "camera lost"
                } else {
                    "capture failed"
                };
                // The dump was flushed after every frame: it holds everything so far.
                let _ = writer.finish();
                return Err(anyhow::Error::new(e).context(format!(
                    "{what} after {}; {} holds the frames recorded until then",
                    tally.report(),
                    out.display()
                )));
            }
        }
    };
    drop(stream);
    let bytes = writer.bytes();
    writer.finish()?;
    eprintln!(
        "crossline record: {end} after {:.1} s: {} to {} ({} bytes)",
        started.elapsed().as_secs_f64(),
        tally.report(),
        out.display(),
        bytes
    );
    Ok(ExitCode::SUCCESS)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_parse() {
        assert_eq!(parse_size("1920x1080"), Ok((1920, 1080)));
        assert_eq!(parse_size("640X480"), Ok((640, 480)));
        assert!(parse_size("640").is_err());
        assert!(parse_size("0x480").is_err());
    }

    #[test]
    fn sequence_jumps_count_dropped_frames() {
        let mut t = Tally::default();
        for s in [10, 11, 14, 15, 15, 20] {
            t.add(s, 100, false);
        }
        assert_eq!((t.frames, t.dropped, t.gaps), (6, 6, 2));
        // Wrap-around of the 32-bit counter is not a gap.
        let mut t = Tally::default();
        t.add(u32::MAX, 1, false);
        t.add(0, 1, true);
        assert_eq!((t.dropped, t.damaged), (0, 1));
    }
}
