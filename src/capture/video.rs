//! Recorded video files (MP4, MOV, MKV, AVI: a GoPro's dive) as a frame source,
//! decoded by FFmpeg in a child process.
//!
//! Owns the two FFmpeg tools and nothing of the pipeline: [`VideoFile::probe`] asks
//! `ffprobe` for the first video stream's size, codec and the container timestamp of
//! every frame that decodes (ffprobe decodes the file to count them, so a cut-off file
//! is measured by what can be read, not by what its index promises); a [`VideoReader`]
//! runs `ffmpeg … -f rawvideo -pix_fmt rgb24 -` and reads exactly `width·height·3`
//! bytes a frame from its standard output. No library is linked: FFmpeg only has to be
//! on `PATH` at run time.
//!
//! - Frames are as coded (`-noautorotate`), one per decoded frame (`-fps_mode
//!   passthrough`: nothing duplicated or dropped to a constant rate), so frame `k` of
//!   the pipe is frame `k` of the probe. This needs FFmpeg 5.1 or later.
//! - Timestamps are the container's (`best_effort_timestamp` in the stream's time
//!   base), in nanoseconds as dump records carry them.
//! - A [`Window`] (`--start`, `--duration`, seconds after the first frame) selects part
//!   of the file; the frames before it are decoded and skipped, which keeps the frame
//!   to timestamp pairing exact.
//! - A file cut off by a power loss is read up to its last whole frame, with a
//!   warning naming how many frames were read. (An MP4 whose index, the `moov` atom,
//!   was to be written at the end cannot be read at all; the error says so.)
//! - The child is killed and waited for on every path, and the last lines of its
//!   standard error go into the errors.

use std::collections::VecDeque;
use std::io::{BufRead, BufReader, Read};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdout, Command, Stdio};
use std::sync::{Arc, Mutex};

use super::dump::{DumpHeader, Record, MAX_PIXELS, MAX_SIDE};

/// File extensions read as video (compared without case).
pub const VIDEO_EXTENSIONS: [&str; 4] = ["mp4", "mov", "mkv", "avi"];

/// Lines of FFmpeg's standard error kept for error messages.
const STDERR_LINES: usize = 8;

/// True when `path` is named like a video file.
pub fn is_video(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| VIDEO_EXTENSIONS.contains(&e.to_ascii_lowercase().as_str()))
}

#[derive(Debug, thiserror::Error)]
pub enum VideoError {
    #[error("{program} is not installed (or not on PATH): crossline decodes video files with FFmpeg; install it, e.g. `apt-get install ffmpeg` (Debian, Ubuntu), `dnf install ffmpeg` (Fedora, with RPM Fusion) or `brew install ffmpeg` (macOS)")]
    NotInstalled { program: String },
    #[error("cannot run {program}: {source}")]
    Spawn {
        program: String,
        #[source]
        source: std::io::Error,
    },
    #[error("{program} cannot read {path}: {stderr}")]
    Tool {
        program: String,
        path: PathBuf,
        stderr: String,
    },
    #[error("{path}: the MP4 index (moov atom) is missing: the recording was cut off before the camera finished the file; a repair tool such as untrunc can rebuild it from a good file of the same camera")]
    NoIndex { path: PathBuf },
    #[error("{path}: no video stream")]
    NoVideo { path: PathBuf },
    #[error("{path}: unexpected ffprobe output: {message}")]
    Probe { path: PathBuf, message: String },
    #[error("{path}: {message}")]
    Window { path: PathBuf, message: String },
    #[error("reading decoded frames of {path} from ffmpeg: {source}")]
    Pipe {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("ffmpeg decoded no frame of {path}: {stderr}")]
    NoFrames { path: PathBuf, stderr: String },
}

/// Part of a file: from `start_s` seconds after its first frame, for `duration_s`
/// seconds (to the end when `None`).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Window {
    pub start_s: f64,
    pub duration_s: Option<f64>,
}

impl Window {
    fn check(&self, path: &Path) -> Result<(), VideoError> {
        let ok = self.start_s.is_finite()
            && self.start_s >= 0.0
            && self.duration_s.is_none_or(|d| d.is_finite() && d > 0.0);
        if ok {
            return Ok(());
        }
        Err(VideoError::Window {
            path: path.to_path_buf(),
            message: format!(
                "--start {} and --duration {:?} must be seconds, start ≥ 0 and duration > 0",
                self.start_s, self.duration_s
            ),
        })
    }

    fn contains(&self, seconds_in: f64) -> bool {
        // Half a microsecond of slack: timestamps printed in decimal round.
        let t = seconds_in + 5e-7;
        t >= self.start_s && self.duration_s.is_none_or(|d| t < self.start_s + d)
    }
}

/// One frame of the window: its index among the file's decoded frames and its time.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FrameTime {
    pub index: u64,
    pub timestamp_nanos: u64,
}

/// What `ffprobe` says about a file's first video stream, restricted to a window.
#[derive(Clone, Debug)]
pub struct VideoFile {
    pub path: PathBuf,
    pub width: u32,
    pub height: u32,
    pub codec: String,
    /// Frames per second as a fraction, when the container says.
    pub frame_rate: Option<(u32, u32)>,
    /// The container's `creation_time` tag, when present (ISO 8601).
    pub creation_time: Option<String>,
    /// The frames in the window, in order.
    pub frames: Vec<FrameTime>,
    /// Frames that decode in the whole file.
    pub decodable: u64,
    /// Frames the container's index lists (`nb_frames`), when it says.
    pub listed: Option<u64>,
    ffmpeg: String,
}

/// The FFmpeg programs, by name on `PATH` (tests swap them for missing ones).
#[derive(Clone, Debug)]
pub struct Tools {
    pub ffmpeg: String,
    pub ffprobe: String,
}

impl Default for Tools {
    fn default() -> Self {
        Self {
            ffmpeg: "ffmpeg".into(),
            ffprobe: "ffprobe".into(),
        }
    }
}

fn spawn_error(program: &str, source: std::io::Error) -> VideoError {
    if source.kind() == std::io::ErrorKind::NotFound {
        VideoError::NotInstalled {
            program: program.into(),
        }
    } else {
        VideoError::Spawn {
            program: program.into(),
            source,
        }
    }
}

/// The last [`STDERR_LINES`] non-empty lines of `text`, joined by " | ".
fn tail(text: &str) -> String {
    let lines: Vec<&str> = text.lines().filter(|l| !l.trim().is_empty()).collect();
    lines[lines.len().saturating_sub(STDERR_LINES)..].join(" | ")
}

impl VideoFile {
    /// Probes `path` with the default tools; see [`VideoFile::probe_with`].
    pub fn probe(path: &Path, window: Window) -> Result<Self, VideoError> {
        Self::probe_with(path, window, &Tools::default())
    }

    /// Asks `ffprobe` for the first video stream and the timestamp of every frame that
    /// decodes, and keeps the frames in `window`. Warns when fewer frames decode than
    /// the container lists (a cut-off file).
    pub fn probe_with(path: &Path, window: Window, tools: &Tools) -> Result<Self, VideoError> {
        window.check(path)?;
        let out = Command::new(&tools.ffprobe)
            .args(["-v", "error", "-select_streams", "v:0", "-show_entries"])
            .arg(
                "stream=width,height,codec_name,avg_frame_rate,time_base,nb_frames\
                 :stream_tags=creation_time:format_tags=creation_time\
                 :frame=best_effort_timestamp",
            )
            .args(["-of", "json", "--"])
            .arg(path)
            .stdin(Stdio::null())
            .output()
            .map_err(|e| spawn_error(&tools.ffprobe, e))?;
        let stderr = String::from_utf8_lossy(&out.stderr);
        if stderr.contains("moov atom not found") {
            return Err(VideoError::NoIndex {
                path: path.to_path_buf(),
            });
        }
        if !out.status.success() {
            return Err(VideoError::Tool {
                program: tools.ffprobe.clone(),
                path: path.to_path_buf(),
                stderr: tail(&stderr),
            });
        }
        let mut file = parse_probe(&out.stdout, path, window)?;
        file.ffmpeg = tools.ffmpeg.clone();
        if file.listed.is_some_and(|n| file.decodable < n) {
            tracing::warn!(
                "{}: cut off? read {} whole frames of the {} its index lists; using those ({})",
                path.display(),
                file.decodable,
                file.listed.unwrap_or_default(),
                tail(&stderr)
            );
        }
        Ok(file)
    }

    /// The stream as a dump header: packed RGB, one line of `3·width` bytes.
    pub fn header(&self) -> DumpHeader {
        let (fps_num, fps_den) = self.frame_rate.unwrap_or((0, 1));
        DumpHeader {
            fourcc: *b"RGB3",
            width: self.width,
            height: self.height,
            bytes_per_line: 3 * self.width,
            // A frame interval is the inverse of the rate.
            interval_num: fps_den,
            interval_den: fps_num,
            device: self.path.display().to_string(),
            card: format!("video file ({})", self.codec),
        }
    }

    /// Bytes of one decoded frame.
    pub fn frame_bytes(&self) -> usize {
        3 * self.width as usize * self.height as usize
    }

    /// Starts decoding the window's frames, in order.
    pub fn reader(&self) -> Result<VideoReader, VideoError> {
        VideoReader::spawn(self)
    }
}

#[derive(serde::Deserialize)]
struct ProbeJson {
    #[serde(default)]
    streams: Vec<ProbeStream>,
    #[serde(default)]
    frames: Vec<ProbeFrame>,
    #[serde(default)]
    format: Option<ProbeTagged>,
}

#[derive(serde::Deserialize)]
struct ProbeStream {
    width: Option<u32>,
    height: Option<u32>,
    codec_name: Option<String>,
    avg_frame_rate: Option<String>,
    time_base: Option<String>,
    nb_frames: Option<String>,
    tags: Option<Tags>,
}

#[derive(serde::Deserialize)]
struct ProbeFrame {
    best_effort_timestamp: Option<i64>,
}

#[derive(serde::Deserialize)]
struct ProbeTagged {
    tags: Option<Tags>,
}

#[derive(serde::Deserialize)]
struct Tags {
    creation_time: Option<String>,
}

fn fraction(text: &str) -> Option<(u32, u32)> {
    let (n, d) = text.split_once('/')?;
    let (n, d) = (n.trim().parse().ok()?, d.trim().parse().ok()?);
    (n > 0 && d > 0).then_some((n, d))
}

/// The [`VideoFile`] that `ffprobe -of json` output describes (a pure function, so
/// tests feed it text).
fn parse_probe(json: &[u8], path: &Path, window: Window) -> Result<VideoFile, VideoError> {
    let bad = |message: String| VideoError::Probe {
        path: path.to_path_buf(),
        message,
    };
    let probe: ProbeJson = serde_json::from_slice(json).map_err(|e| bad(e.to_string()))?;
    let stream = probe.streams.first().ok_or_else(|| VideoError::NoVideo {
        path: path.to_path_buf(),
    })?;
    let (width, height) = match (stream.width, stream.height) {
        (Some(w), Some(h)) if w > 0 && h > 0 => (w, h),
        _ => return Err(bad("the video stream has no image size".into())),
    };
    if width > MAX_SIDE || height > MAX_SIDE || u64::from(width) * u64::from(height) > MAX_PIXELS {
        return Err(bad(format!(
            "image size {width}x{height} is larger than crossline reads"
        )));
    }
    let (tb_num, tb_den) = stream
        .time_base
        .as_deref()
        .and_then(fraction)
        .ok_or_else(|| bad(format!("time base {:?}", stream.time_base)))?;
    let frame_rate = stream.avg_frame_rate.as_deref().and_then(fraction);
    // A frame without a timestamp is one frame interval after the one before.
    let interval_nanos =
        frame_rate.map_or(0, |(n, d)| (1_000_000_000 * i128::from(d)) / i128::from(n));
    let mut nanos: Vec<i128> = Vec::with_capacity(probe.frames.len());
    for f in &probe.frames {
        let t = match f.best_effort_timestamp {
            Some(ts) => i128::from(ts) * i128::from(tb_num) * 1_000_000_000 / i128::from(tb_den),
            None => nanos.last().map_or(0, |t| t + interval_nanos),
        };
        nanos.push(t);
    }
    let first = nanos.first().copied().unwrap_or(0);
    let frames = nanos
        .iter()
        .enumerate()
        .filter(|(_, &t)| window.contains((t - first) as f64 * 1e-9))
        .map(|(i, &t)| FrameTime {
            index: i as u64,
            timestamp_nanos: t.clamp(0, i128::from(u64::MAX)) as u64,
        })
        .collect();
    let creation_time = stream
        .tags
        .as_ref()
        .and_then(|t| t.creation_time.clone())
        .or_else(|| {
            probe
                .format
                .and_then(|f| f.tags)
                .and_then(|t| t.creation_time)
        });
    Ok(VideoFile {
        path: path.to_path_buf(),
        width,
        height,
        codec: stream
            .codec_name
            .clone()
            .unwrap_or_else(|| "unknown".into()),
        frame_rate,
        creation_time,
        frames,
        decodable: nanos.len() as u64,
        listed: stream.nb_frames.as_deref().and_then(|n| n.parse().ok()),
        ffmpeg: Tools::default().ffmpeg,
    })
}

/// One decoded frame of the window.
#[derive(Clone, Debug)]
pub struct VideoFrame {
    /// Position in the window (0 for its first frame).
    pub position: usize,
    pub time: FrameTime,
    /// Packed RGB, `width·height·3` bytes.
    pub rgb: Vec<u8>,
}

/// The window's frames from a running `ffmpeg`, in order. Dropping it kills and
/// reaps the child.
pub struct VideoReader {
    child: Child,
    stdout: ChildStdout,
    stderr: Option<std::thread::JoinHandle<()>>,
    stderr_tail: Arc<Mutex<VecDeque<String>>>,
    path: PathBuf,
    frames: Vec<FrameTime>,
    frame_bytes: usize,
    /// Frames of the file read from the pipe so far.
    decoded: u64,
    /// Window frames returned so far.
    position: usize,
    done: bool,
}

impl VideoReader {
    fn spawn(file: &VideoFile) -> Result<Self, VideoError> {
        let mut child = Command::new(&file.ffmpeg)
            .args([
                "-nostdin",
                "-hide_banner",
                "-loglevel",
                "error",
                "-noautorotate",
            ])
            .arg("-i")
            .arg(&file.path)
            .args(["-map", "0:v:0", "-fps_mode", "passthrough"])
            .args(["-f", "rawvideo", "-pix_fmt", "rgb24", "-"])
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .map_err(|e| spawn_error(&file.ffmpeg, e))?;
        let stderr_tail = Arc::new(Mutex::new(VecDeque::new()));
        let (stdout, stderr) = match (child.stdout.take(), child.stderr.take()) {
            (Some(o), Some(e)) => (o, e),
            _ => {
                let _ = child.kill();
                let _ = child.wait();
                return Err(VideoError::Spawn {
                    program: file.ffmpeg.clone(),
                    source: std::io::Error::other("no pipes to the child"),
                });
            }
        };
        // Drained on a thread of its own, so a chatty ffmpeg never blocks on a full
        // pipe while we wait for frames; the last lines are kept for errors.
        let keep = stderr_tail.clone();
        let drain = std::thread::Builder::new()
            .name("ffmpeg-stderr".into())
            .spawn(move || {
                for line in BufReader::new(stderr).lines() {
                    let Ok(line) = line else { break };
                    let mut q = keep.lock().unwrap_or_else(|e| e.into_inner());
                    if q.len() == STDERR_LINES {
                        q.pop_front();
                    }
                    q.push_back(line);
                }
            });
        let stderr = match drain {
            Ok(h) => Some(h),
            Err(source) => {
                let _ = child.kill();
                let _ = child.wait();
                return Err(VideoError::Spawn {
                    program: "a thread for ffmpeg's stderr".into(),
                    source,
                });
            }
        };
        Ok(Self {
            child,
            stdout,
            stderr,
            stderr_tail,
            path: file.path.clone(),
            frames: file.frames.clone(),
            frame_bytes: file.frame_bytes(),
            decoded: 0,
            position: 0,
            done: false,
        })
    }

    /// Frames in the window (what the probe found).
    pub fn len(&self) -> usize {
        self.frames.len()
    }

    pub fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }

    /// Window frames returned so far.
    pub fn position(&self) -> usize {
        self.position
    }

    /// The next frame of the window, or `None` after its last one (or the last whole
    /// frame ffmpeg could decode, with a warning when that is short of the window).
    pub fn next_frame(&mut self) -> Result<Option<VideoFrame>, VideoError> {
        let Some(&time) = self.frames.get(self.position).filter(|_| !self.done) else {
            self.stop();
            return Ok(None);
        };
        let mut rgb = vec![0u8; self.frame_bytes];
        while self.decoded <= time.index {
            if !self.read_frame(&mut rgb)? {
                return self.ended_early().map(|()| None);
            }
            self.decoded += 1;
        }
        let frame = VideoFrame {
            position: self.position,
            time,
            rgb,
        };
        self.position += 1;
        Ok(Some(frame))
    }

    /// The next frame as a dump record (the sequence number is the frame's index in
    /// the file).
    pub fn next_record(&mut self) -> Result<Option<Record>, VideoError> {
        Ok(self.next_frame()?.map(|f| Record {
            sequence: f.time.index as u32,
            timestamp_nanos: f.time.timestamp_nanos,
            flags: 0,
            payload: f.rgb,
        }))
    }

    /// Fills `buf` with one frame; false at the end of the pipe (a partial frame at
    /// the end is dropped).
    fn read_frame(&mut self, buf: &mut [u8]) -> Result<bool, VideoError> {
        let mut filled = 0;
        while filled < buf.len() {
            match self.stdout.read(&mut buf[filled..]) {
                Ok(0) => return Ok(false),
                Ok(n) => filled += n,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(source) => {
                    self.stop();
                    return Err(VideoError::Pipe {
                        path: self.path.clone(),
                        source,
                    });
                }
            }
        }
        Ok(true)
    }

    /// The pipe ended before the window did: an error with no frame at all, else a
    /// warning saying how many were read.
    fn ended_early(&mut self) -> Result<(), VideoError> {
        self.stop();
        let stderr = self.stderr_text();
        if self.decoded == 0 {
            return Err(VideoError::NoFrames {
                path: self.path.clone(),
                stderr,
            });
        }
        tracing::warn!(
            "{}: ffmpeg stopped after {} whole frames ({} of the window's {}); using those ({stderr})",
            self.path.display(),
            self.decoded,
            self.position,
            self.frames.len()
        );
        Ok(())
    }

    fn stderr_text(&self) -> String {
        let q = self.stderr_tail.lock().unwrap_or_else(|e| e.into_inner());
        let text: Vec<&str> = q.iter().map(String::as_str).collect();
        match text.is_empty() {
            true => "ffmpeg said nothing".into(),
            false => text.join(" | "),
        }
    }

    /// Kills ffmpeg (it may be decoding frames after the window), reaps it and joins
    /// the stderr thread. Idempotent.
    fn stop(&mut self) {
        if self.done {
            return;
        }
        self.done = true;
        let _ = self.child.kill();
        let _ = self.child.wait();
        if let Some(h) = self.stderr.take() {
            let _ = h.join();
        }
    }
}

impl Drop for VideoReader {
    fn drop(&mut self) {
        self.stop();
    }
}

#[cfg(test)]
mod tests;
