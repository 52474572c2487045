//! `crossline inspect`: what a dump holds and whether it is whole, as JSON lines, for
//! people checking a recording and for scripts (the VM tests compare recordings by the
//! per-frame CRCs printed here).

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{bail, Context};
use crossline::capture::dump::{decode_rgb, DumpError, DumpReader, Record, VERSION};

/// Check a recording (dump): its header, its frames, where and why reading stopped.
///
/// Prints JSON lines on standard output, one object per line, each with a "type":
///
///   header  the negotiated stream: fourcc, width, height, bytes_per_line, the frame
///           interval (interval_num/interval_den seconds, and fps), device, card
///   frame   with --frames, one per record: index, offset (byte in the file),
///           sequence and timestamp_nanos (the driver's), flags (V4L2 buffer flags),
///           bytes (payload length), crc32 (of the payload, 8 hex digits)
///   decode  with --decode N: frame N decoded to RGB, its width and height, and the
///           PNG written with --png
///   end     status "clean" (the file ends after a whole record), "truncated" (cut off
///           inside a record: a crash or a full disk) or "corrupt" (a record fails its
///           checks), with a message saying where; frames (whole records read),
///           first_sequence, last_sequence, dropped (frames missing between
///           consecutive sequence numbers), sequence_not_increasing and
///           timestamp_decreasing (counts of records breaking the order), duration_nanos
///           (last minus first timestamp) and fps (measured from the timestamps)
///
/// The exit status is 0 for a clean dump and 1 for a truncated or corrupt one, or one
/// that cannot be read at all (not a dump, wrong version, bad header: the error is on
/// standard error). The frames before the damage are still listed and decodable, which
/// is what `crossline reconstruct` uses of such a dump.
///
/// Examples:
///
///   crossline inspect rec.dump
///   crossline inspect rec.dump --frames | head
///   crossline inspect rec.dump --decode 0 --png first.png
#[derive(clap::Args)]
#[command(verbatim_doc_comment)]
pub struct Args {
    /// The dump (from `crossline record` or `crossline simulate --format dump`).
    dump: PathBuf,
    /// Print one line per frame record.
    #[arg(long)]
    frames: bool,
    /// Decode frame N (counted from 0) to RGB, as `reconstruct` would.
    #[arg(long, value_name = "N")]
    decode: Option<usize>,
    /// Write the frame decoded with --decode to this PNG.
    #[arg(long, value_name = "OUT", requires = "decode")]
    png: Option<PathBuf>,
}

/// Order statistics over the records read so far.
#[derive(Default)]
struct Summary {
    frames: usize,
    first_sequence: Option<u32>,
    last_sequence: Option<u32>,
    first_timestamp_nanos: Option<u64>,
    last_timestamp_nanos: Option<u64>,
    dropped: u64,
    sequence_not_increasing: usize,
    timestamp_decreasing: usize,
}

impl Summary {
    fn add(&mut self, record: &Record) {
        if let Some(last) = self.last_sequence {
            if record.sequence > last {
                self.dropped += u64::from(record.sequence - last - 1);
            } else {
                self.sequence_not_increasing += 1;
            }
        }
        if let Some(last) = self.last_timestamp_nanos {
            if record.timestamp_nanos < last {
                self.timestamp_decreasing += 1;
            }
        }
        self.first_sequence.get_or_insert(record.sequence);
        self.first_timestamp_nanos
            .get_or_insert(record.timestamp_nanos);
        self.last_sequence = Some(record.sequence);
        self.last_timestamp_nanos = Some(record.timestamp_nanos);
        self.frames += 1;
    }

    fn duration_nanos(&self) -> Option<u64> {
        Some(
            self.last_timestamp_nanos?
                .saturating_sub(self.first_timestamp_nanos?),
        )
    }

    fn fps(&self) -> Option<f64> {
        let d = self.duration_nanos()?;
        (self.frames > 1 && d > 0).then(|| (self.frames - 1) as f64 * 1e9 / d as f64)
    }
}

/// One output line; the fields are documented on [`Args`].
#[derive(serde::Serialize)]
#[serde(tag = "type", rename_all = "lowercase")]
enum Line<'a> {
    Header {
        version: u32,
        fourcc: String,
        width: u32,
        height: u32,
        bytes_per_line: u32,
        interval_num: u32,
        interval_den: u32,
        fps: Option<f64>,
        device: &'a str,
        card: &'a str,
    },
    Frame {
        index: usize,
        offset: u64,
        sequence: u32,
        timestamp_nanos: u64,
        flags: u32,
        bytes: usize,
        crc32: String,
    },
    Decode {
        index: usize,
        sequence: u32,
        width: u32,
        height: u32,
        png: Option<String>,
    },
    End {
        status: &'static str,
        message: Option<String>,
        frames: usize,
        bytes_read: u64,
        first_sequence: Option<u32>,
        last_sequence: Option<u32>,
        dropped: u64,
        sequence_not_increasing: usize,
        timestamp_decreasing: usize,
        duration_nanos: Option<u64>,
        fps: Option<f64>,
    },
}

impl Line<'_> {
    fn print(&self) -> anyhow::Result<()> {
        let text = serde_json::to_string(self).context("cannot format JSON")?;
        crate::outln!("{text}");
        Ok(())
    }
}

pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    let mut reader = DumpReader::open(&args.dump)?;
    let header = reader.header().clone();
    Line::Header {
        version: VERSION,
        fourcc: String::from_utf8_lossy(&header.fourcc).into_owned(),
        width: header.width,
        height: header.height,
        bytes_per_line: header.bytes_per_line,
        interval_num: header.interval_num,
        interval_den: header.interval_den,
        fps: (header.interval_num > 0)
            .then(|| f64::from(header.interval_den) / f64::from(header.interval_num)),
        device: &header.device,
        card: &header.card,
    }
    .print()?;
    let mut summary = Summary::default();
    let mut wanted: Option<Record> = None;
    let stop = loop {
        let offset = reader.offset();
        match reader.next_record() {
            Ok(Some(record)) => {
                if args.frames {
                    Line::Frame {
                        index: summary.frames,
                        offset,
                        sequence: record.sequence,
                        timestamp_nanos: record.timestamp_nanos,
                        flags: record.flags,
                        bytes: record.payload.len(),
                        crc32: format!("{:08x}", crc32fast::hash(&record.payload)),
                    }
                    .print()?;
                }
                let index = summary.frames;
                summary.add(&record);
                if args.decode == Some(index) {
                    wanted = Some(record);
                }
            }
            Ok(None) => break None,
            Err(e @ (DumpError::Truncated { .. } | DumpError::Corrupt { .. })) => break Some(e),
            Err(e) => return Err(e.into()),
        }
    };

    if let Some(index) = args.decode {
        let Some(record) = wanted else {
            bail!(
                "--decode {index}: {} has {} whole frames (counted from 0)",
                args.dump.display(),
                summary.frames
            );
        };
        let rgb = decode_rgb(&header, &record.payload).map_err(|message| DumpError::Decode {
            path: args.dump.clone(),
            index,
            fourcc: String::from_utf8_lossy(&header.fourcc).into_owned(),
            message,
        })?;
        if let Some(png) = &args.png {
            rgb.save(png)
                .with_context(|| format!("cannot write {}", png.display()))?;
        }
        Line::Decode {
            index,
            sequence: record.sequence,
            width: rgb.width(),
            height: rgb.height(),
            png: args.png.as_ref().map(|p| p.display().to_string()),
        }
        .print()?;
    }

    let (status, message) = match &stop {
        None => ("clean", None),
        Some(e @ DumpError::Truncated { .. }) => ("truncated", Some(e.to_string())),
        Some(e) => ("corrupt", Some(e.to_string())),
    };
    Line::End {
        status,
        message,
        frames: summary.frames,
        bytes_read: reader.offset(),
        first_sequence: summary.first_sequence,
        last_sequence: summary.last_sequence,
        dropped: summary.dropped,
        sequence_not_increasing: summary.sequence_not_increasing,
        timestamp_decreasing: summary.timestamp_decreasing,
        duration_nanos: summary.duration_nanos(),
        fps: summary.fps(),
    }
    .print()?;
    match stop {
        None => Ok(ExitCode::SUCCESS),
        Some(e) => {
            eprintln!("crossline: {e}");
            Ok(ExitCode::FAILURE)
        }
    }
}
