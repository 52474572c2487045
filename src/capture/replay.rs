//! A recorded dump played back as a camera: at the recorded frame rate (the driver's
//! timestamps set the pace) or as fast as the pipeline takes it, losslessly.

use std::path::Path;
use std::time::{Duration, Instant};

use super::dump::{DumpError, DumpHeader, DumpReader, Record};
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

pub struct ReplaySource {
    reader: DumpReader,
    rate: Rate,
    /// Read ahead, not yet released (waiting for its time).
    record: Option<Record>,
    /// Released: the frame last returned borrows it.
    current: Option<Record>,
    position: u64,
    /// Wall-clock start and the first timestamp, for real-time pacing.
    clock: Option<(Instant, u64)>,
    ended: bool,
}

impl ReplaySource {
    pub fn open(path: &Path, rate: Rate) -> Result<Self, DumpError> {
        Ok(Self {
            reader: DumpReader::open(path)?,
            rate,
            record: None,
            current: None,
            position: 0,
            clock: None,
            ended: false,
        })
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
                Err(e.into())
            }
        }
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
            let (start, first) = *self.clock.get_or_insert((Instant::now(), ts));
            let due = start + Duration::from_nanos(ts.saturating_sub(first));
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
