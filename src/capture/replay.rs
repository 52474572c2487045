//! A recording played back as a camera: a dump, or a video file decoded by FFmpeg
//! ([`super::video`]), at the recorded frame rate (the driver's or the container's
//! timestamps set the pace) or as fast as the pipeline takes it, losslessly.

use std::path::Path;
use std::time::{Duration, Instant};

use super::dump::{DumpError, DumpHeader, DumpReader, Record};
use super::video::{VideoError, VideoFile, VideoReader, Window};
use super::{CaptureError, Frame, FrameSource, Next};

/// How fast a replay runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Rate {
    /// Frames are released at their recorded times, as a camera would deliver them;
    /// like a camera, frames the workers cannot take are dropped.
    Realtime,
    /// As fast as the pipeline takes them, dropping nothing.
    Max,
}

/// Where a replay's records come from.
enum Recording {
    Dump(DumpReader),
    Video {
        header: DumpHeader,
        reader: VideoReader,
    },
}

impl Recording {
    fn header(&self) -> &DumpHeader {
        match self {
            Self::Dump(r) => r.header(),
            Self::Video { header, .. } => header,
        }
    }

    fn next_record(&mut self) -> Result<Option<Record>, CaptureError> {
        match self {
            Self::Dump(r) => Ok(r.next_record()?),
            Self::Video { reader, .. } => Ok(reader.next_record()?),
        }
    }
}

pub struct ReplaySource {
    reader: Recording,
    rate: Rate,
    /// Read ahead, not yet released (waiting for its time).
    record: Option<Record>,
    /// Released: the frame last returned borrows it.
    current: Option<Record>,
    position: u64,
    /// When the last frame was due and its timestamp, for real-time pacing.
    clock: Option<(Instant, u64)>,
    /// Gaps between recorded timestamps longer than [`MAX_REPLAY_GAP`] (or going
    /// backwards), replayed as that long; not yet reported.
    gaps_clamped: u64,
    ended: bool,
}

/// Longest pause a real-time replay makes between two frames. A recording's gap is a
/// lost device or a damaged timestamp (`u64::MAX`, a jump of days); waiting it out
/// would stall the replay for ever while its status says "streaming".
pub const MAX_REPLAY_GAP: Duration = Duration::from_secs(1);

impl ReplaySource {
    pub fn open(path: &Path, rate: Rate) -> Result<Self, DumpError> {
        Ok(Self::new(Recording::Dump(DumpReader::open(path)?), rate))
    }

    /// The frames of a video file in `window`, decoded by FFmpeg, with the
    /// container's timestamps.
    pub fn open_video(path: &Path, window: Window, rate: Rate) -> Result<Self, VideoError> {
        let file = VideoFile::probe(path, window)?;
        let recording = Recording::Video {
            header: file.header(),
            reader: file.reader()?,
        };
        Ok(Self::new(recording, rate))
    }

    fn new(reader: Recording, rate: Rate) -> Self {
        Self {
            reader,
            rate,
            record: None,
            current: None,
            position: 0,
            clock: None,
            gaps_clamped: 0,
            ended: false,
        }
    }

    /// Reads the next record into `self.record` (unless one is waiting).
    fn fill(&mut self) -> Result<bool, CaptureError> {
        if self.record.is_some() {
            return Ok(true);
        }
        if self.ended {
            return Ok(false);
        }
        match self.reader.next_record() {
            Ok(Some(r)) => {
                self.record = Some(r);
                Ok(true)
            }
            Ok(None) => {
                self.ended = true;
                Ok(false)
            }
            Err(e) => {
                self.ended = true;
                Err(e)
            }
        }
    }
}

/// The pause between frames recorded at `last_ts` and `ts`, and whether it had to be
/// clamped: a backward step is no pause, a jump is [`MAX_REPLAY_GAP`].
fn replay_gap(last_ts: u64, ts: u64) -> (Duration, bool) {
    match ts.checked_sub(last_ts).map(Duration::from_nanos) {
        Some(g) if g <= MAX_REPLAY_GAP => (g, false),
        Some(_) => (MAX_REPLAY_GAP, true),
        None => (Duration::ZERO, true),
    }
}

impl FrameSource for ReplaySource {
    fn header(&self) -> &DumpHeader {
        self.reader.header()
    }

    fn lossless(&self) -> bool {
        self.rate == Rate::Max
    }

    fn next(&mut self, timeout: Duration) -> Result<Next<'_>, CaptureError> {
        if !self.fill()? {
            return Ok(Next::End);
        }
        let Some(ts) = self.record.as_ref().map(|r| r.timestamp_nanos) else {
            return Ok(Next::End);
        };
        if self.rate == Rate::Realtime {
            // Each frame is due its recorded gap after the one before, the gap clamped.
            let (last_due, last_ts) = *self.clock.get_or_insert((Instant::now(), ts));
            let due = last_due + replay_gap(last_ts, ts).0;
            let now = Instant::now();
            if due > now {
                let wait = due - now;
                if wait > timeout {
                    std::thread::sleep(timeout);
                    return Ok(Next::Idle);
                }
                std::thread::sleep(wait);
            }
        }
        if let Some((last_due, last_ts)) = self.clock.as_mut() {
            let (gap, clamped) = replay_gap(*last_ts, ts);
            if clamped {
                self.gaps_clamped += 1;
                tracing::warn!(
                    position = self.position,
                    "recorded timestamp jumps from {last_ts} ns to {ts} ns; replayed as a {} s pause",
                    gap.as_secs_f64()
                );
            }
            *last_due += gap;
            *last_ts = ts;
        }
        let position = self.position;
        self.position += 1;
        self.current = self.record.take();
        let Some(r) = self.current.as_ref() else {
            return Ok(Next::End);
        };
        Ok(Next::Frame(Frame {
            sequence: r.sequence,
            timestamp_nanos: r.timestamp_nanos,
            flags: r.flags,
            position,
            bytes: &r.payload,
        }))
    }

    fn take_warning(&mut self) -> Option<String> {
        (self.gaps_clamped > 0).then(|| {
            let n = std::mem::take(&mut self.gaps_clamped);
            format!(
                "replay: {n} recorded timestamp gap(s) over {} s or backwards, replayed shortened",
                MAX_REPLAY_GAP.as_secs_f64()
            )
        })
    }

    fn seek(&mut self, position: u64) -> Result<(), CaptureError> {
        while self.position < position {
            if !self.fill()? {
                break;
            }
            self.record = None;
            self.position += 1;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::capture::dump::{DumpHeader, DumpWriter};

    #[test]
    fn a_realtime_replay_does_not_wait_out_absurd_timestamp_jumps() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("jumps.dump");
        let header = DumpHeader {
            fourcc: *b"RGB3",
            width: 2,
            height: 1,
            bytes_per_line: 6,
            interval_num: 1,
            interval_den: 30,
            device: "test".into(),
            card: "test".into(),
        };
        let mut w = DumpWriter::create(&path, &header).expect("create");
        let stamps = [0, 1_000_000_000_000_000, u64::MAX, 5, 6];
        for (i, ts) in stamps.iter().enumerate() {
            w.write_frame(i as u32, *ts, 0, &[0; 6]).expect("write");
        }
        w.finish().expect("finish");
        let mut source = ReplaySource::open(&path, Rate::Realtime).expect("open");
        // Two jumps forward are clamped to a second each, one backward step to none:
        // with 50 ms polls the five frames come within a bounded number of polls
        // (about 40), where the recorded gaps would need 10^15 ns of them.
        let (mut frames, mut polls) = (Vec::new(), 0);
        while polls < 200 {
            polls += 1;
            match source.next(Duration::from_millis(50)).expect("next") {
                Next::Frame(f) => frames.push(f.timestamp_nanos),
                Next::End => break,
                _ => {}
            }
        }
        assert_eq!(frames, stamps, "after {polls} polls");
        let warning = source.take_warning().expect("the clamping is reported");
        assert!(warning.contains("3 recorded timestamp gap"), "{warning}");
        assert!(source.take_warning().is_none(), "reported once");
    }
}
