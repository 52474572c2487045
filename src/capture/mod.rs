//! Frames from cameras and recordings.
//!
//! - [`chroma`]: how decoding a buffer rebuilds its chroma, read off its bytes.
//! - [`dump`]: the recording format of raw camera buffers (versioned, documented there).
//! - [`replay`]: a recorded dump or video file played back as if it were a camera.
//! - [`video`]: video files (MP4, MOV, MKV, AVI) decoded by an FFmpeg child process.
//! - [`v4l2`] (Linux): capture from V4L2 cameras through our own ioctl layer, and
//!   writing frames into a v4l2loopback device.
//! - [`live`] (Linux): a V4L2 camera as a [`FrameSource`], reopened with back-off when
//!   it disappears.
//!
//! Every source implements [`FrameSource`], so the daemon runs the identical pipeline
//! on a live camera and on a replay.

pub mod chroma;
pub mod dump;
#[cfg(target_os = "linux")]
pub mod live;
pub mod replay;
#[cfg(target_os = "linux")]
pub mod v4l2;
pub mod video;

use std::time::Duration;

use dump::{DumpError, DumpHeader};
use video::VideoError;

/// One buffer from a source, borrowed until the next call.
#[derive(Clone, Copy, Debug)]
pub struct Frame<'a> {
    /// The driver's sequence number.
    pub sequence: u32,
    /// The driver's timestamp, nanoseconds.
    pub timestamp_nanos: u64,
    /// V4L2 buffer flags.
    pub flags: u32,
    /// Position in the source (record index of a dump; the running count of a camera).
    pub position: u64,
    pub bytes: &'a [u8],
}

/// What a source had to say.
#[derive(Debug)]
pub enum Next<'a> {
    Frame(Frame<'a>),
    /// Nothing within the timeout (or still waiting for the device to come back).
    Idle,
    /// The device went away; the source keeps trying to reopen it.
    Lost(String),
    /// The device is streaming again after a loss; the format is unchanged.
    Resumed,
    /// No more frames will come (end of a replay).
    End,
}

#[derive(Debug, thiserror::Error)]
pub enum CaptureError {
    #[error(transparent)]
    Dump(#[from] DumpError),
    #[error(transparent)]
    Video(#[from] VideoError),
    #[error("{0}")]
    Device(String),
    #[error("the device came back with another format ({now}) than the scan's ({was})")]
    FormatChanged { was: String, now: String },
}

/// A camera or a recording.
pub trait FrameSource: Send {
    /// The negotiated stream, as it goes into a dump header.
    fn header(&self) -> &DumpHeader;
    /// True when frames must never be dropped (replay as fast as possible): the
    /// capture thread then waits for a free ring slot instead of dropping.
    fn lossless(&self) -> bool;
    /// The next frame, waiting at most `timeout`.
    fn next(&mut self, timeout: Duration) -> Result<Next<'_>, CaptureError>;
    /// Skips to the first frame at `position` or after it (resuming a scan).
    fn seek(&mut self, position: u64) -> Result<(), CaptureError>;
    /// Something about the input the status should say (once), such as a replay's
    /// timestamps that had to be clamped.
    fn take_warning(&mut self) -> Option<String> {
        None
    }
}
