//! A V4L2 camera as a [`FrameSource`]: opened and negotiated once, then, whenever the
//! device disappears (a cable, a housing connector, a feeder that stopped), reopened
//! with exponential back-off, so the scan resumes where it was.
//!
//! The format negotiated at the start is the scan's: a device that comes back with
//! another size or pixel format is refused (reported, and retried), since the camera
//! model and every recorded frame depend on it.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use super::dump::DumpHeader;
use super::v4l2::{Device, FormatRequest, Negotiated, Stream, V4l2Error};
use super::{CaptureError, Frame, FrameSource, Next};

/// What to ask the camera for.
#[derive(Clone, Debug)]
pub struct LiveParams {
    pub request: FormatRequest,
    pub buffers: u32,
    /// Longest wait between reopen attempts.
    pub max_backoff: Duration,
}

/// How the device is doing.
enum State {
    Streaming(Box<Stream>),
    /// Lost; the next attempt is due at `retry_at`.
    Lost {
        retry_at: Instant,
        backoff: Duration,
    },
}

pub struct LiveSource {
    path: PathBuf,
    params: LiveParams,
    negotiated: Negotiated,
    header: DumpHeader,
    state: State,
    /// Frames delivered so far (the source position of the next one).
    count: u64,
    /// The last frame, copied out of the driver's buffer.
    buf: Vec<u8>,
}

fn open(path: &Path, params: &LiveParams) -> Result<Stream, V4l2Error> {
    let mut dev = Device::open(path)?;
    dev.negotiate(&params.request)?;
    dev.start(params.buffers)
}

fn same_format(a: &Negotiated, b: &Negotiated) -> bool {
    (a.fourcc, a.width, a.height, a.bytes_per_line)
        == (b.fourcc, b.width, b.height, b.bytes_per_line)
}

fn describe(n: &Negotiated) -> String {
    format!(
        "{} {}x{}",
        String::from_utf8_lossy(&n.fourcc),
        n.width,
        n.height
    )
}

impl LiveSource {
    /// Opens and negotiates; fails if the camera is not there at the start (a daemon
    /// started without its camera should say so, not wait silently).
    pub fn open(path: &Path, params: LiveParams) -> Result<Self, V4l2Error> {
        let stream = open(path, &params)?;
        let negotiated = stream.negotiated().clone();
        for note in &negotiated.fallbacks {
            tracing::warn!("{}: {note}", path.display());
        }
        tracing::info!(
            "{}: {} ({}), {} buffers",
            path.display(),
            describe(&negotiated),
            negotiated.card,
            stream.buffer_count()
        );
        Ok(Self {
            path: path.to_path_buf(),
            header: negotiated.dump_header(),
            negotiated,
            params,
            state: State::Streaming(Box::new(stream)),
            count: 0,
            buf: Vec::new(),
        })
    }

    pub fn negotiated(&self) -> &Negotiated {
        &self.negotiated
    }

    fn lose(&mut self, why: String) -> Next<'static> {
        let backoff = Duration::from_millis(100);
        self.state = State::Lost {
            retry_at: Instant::now() + backoff,
            backoff,
        };
        Next::Lost(why)
    }
}

impl FrameSource for LiveSource {
    fn header(&self) -> &DumpHeader {
        &self.header
    }

    fn lossless(&self) -> bool {
        false
    }

    fn next(&mut self, timeout: Duration) -> Result<Next<'_>, CaptureError> {
        if let State::Lost { retry_at, backoff } = self.state {
            let now = Instant::now();
            if now < retry_at {
                std::thread::sleep((retry_at - now).min(timeout));
                return Ok(Next::Idle);
            }
            match open(&self.path, &self.params) {
                Ok(stream) if same_format(stream.negotiated(), &self.negotiated) => {
                    tracing::info!("{}: streaming again", self.path.display());
                    self.state = State::Streaming(Box::new(stream));
                    return Ok(Next::Resumed);
                }
                Ok(stream) => {
                    let now_fmt = describe(stream.negotiated());
                    drop(stream);
                    tracing::warn!(
                        "{}: came back as {now_fmt}, the scan is {}; waiting for the scan's format",
                        self.path.display(),
                        describe(&self.negotiated)
                    );
                }
                Err(e) if e.is_retryable() => {
                    tracing::debug!("{}: still away: {e}", self.path.display());
                }
                Err(e) => {
                    tracing::warn!("{}: reopening failed: {e}", self.path.display());
                }
            }
            let backoff =
                (backoff * 2).min(self.params.max_backoff.max(Duration::from_millis(100)));
            self.state = State::Lost {
                retry_at: Instant::now() + backoff,
                backoff,
            };
            return Ok(Next::Idle);
        }
        let State::Streaming(stream) = &mut self.state else {
            return Ok(Next::Idle);
        };
        // The frame is copied out so that the device's buffer goes back to the driver
        // at once (and so that the error path may replace the stream).
        let got = match stream.next_frame(timeout) {
            Ok(Some(f)) => {
                self.buf.clear();
                self.buf.extend_from_slice(f.bytes);
                Ok(Some((f.sequence, f.timestamp_nanos, f.flags)))
            }
            Ok(None) => Ok(None),
            Err(e) => Err(e),
        };
        match got {
            Ok(None) => Ok(Next::Idle),
            Ok(Some((sequence, timestamp_nanos, flags))) => {
                let position = self.count;
                self.count += 1;
                Ok(Next::Frame(Frame {
                    sequence,
                    timestamp_nanos,
                    flags,
                    position,
                    bytes: &self.buf,
                }))
            }
            Err(e) => {
                let why = e.to_string();
                tracing::warn!("{why}");
                Ok(self.lose(why))
            }
        }
    }

    fn seek(&mut self, position: u64) -> Result<(), CaptureError> {
        // A camera cannot go back; a resumed scan's new frames simply follow.
        self.count = self.count.max(position);
        Ok(())
    }
}
