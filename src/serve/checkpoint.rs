//! Checkpoints of a live scan, so a crash or `kill -9` loses at most the last few
//! seconds of processing.
//!
//! The expensive, irreplaceable part of the state is what extraction found in every
//! frame; crossings, planes and the cloud follow from it in about a second by
//! re-solving. A scan's state directory holds:
//!
//! - `background.png`: the first background the curves were measured against
//!   (lossless), which the points take their colour from;
//! - `samples/`: the rolling background's recent samples, so frames processed after a
//!   resume are measured identically (written by `super::background`, documented
//!   there);
//! - `curves.log`: every frame's curves, appended in frame order and flushed to disk
//!   every `checkpoint_interval_s` (and at shutdown).
//!
//! # `curves.log`, version 1 (little-endian)
//! Header: magic `CRSLCURV` (8), version u32 (= 1), width u32, height u32.
//! Then one record per frame:
//!
//! | size | field |
//! |---|---|
//! | 4 | magic `FRCV` |
//! | 8 | frame index (consecutive from 0) |
//! | 8 | source position (dump record index, or camera frame count) |
//! | 4 | driver sequence |
//! | 8 | driver timestamp, ns |
//! | 4 | number of curves `n` |
//! | … | `n` curves: laser u8, point count `m` u32, `m` × (x_px f32, y_px f32, x f64, y f64, strength f32), polyline count `p` u32, `p` × (x f64, y f64) |
//! | 4 | CRC-32 of the record from its magic on |
//!
//! A record cut off by a crash, or failing its CRC, ends the log: everything before
//! it is used, the rest is cut away on resume, and its frames are processed again.

use std::fs::{File, OpenOptions};
use std::io::{BufWriter, Read, Write};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use image::RgbImage;

use crate::extract::Curve;

pub const MAGIC: &[u8; 8] = b"CRSLCURV";
pub const RECORD_MAGIC: &[u8; 4] = b"FRCV";
pub const VERSION: u32 = 1;
const HEADER_BYTES: u64 = 20;

#[derive(Debug, thiserror::Error)]
pub enum CheckpointError {
    #[error("checkpoint {path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("checkpoint {path}: {message}")]
    Format { path: PathBuf, message: String },
    #[error("checkpoint {path} is for {got_w}x{got_h} frames, this scan's are {want_w}x{want_h}")]
    Size {
        path: PathBuf,
        got_w: u32,
        got_h: u32,
        want_w: u32,
        want_h: u32,
    },
}

/// One frame as checkpointed.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameCurves {
    pub index: u64,
    pub source_position: u64,
    pub sequence: u32,
    pub timestamp_nanos: u64,
    pub curves: Vec<Curve>,
}

/// What a state directory held.
pub struct Resumed {
    pub background: Option<RgbImage>,
    pub frames: Vec<FrameCurves>,
    /// Why the log stopped early, if it did (a cut-off last record after a crash).
    pub stopped: Option<String>,
}

fn encode(f: &FrameCurves, out: &mut Vec<u8>) {
    out.clear();
    out.extend_from_slice(RECORD_MAGIC);
    out.extend_from_slice(&f.index.to_le_bytes());
    out.extend_from_slice(&f.source_position.to_le_bytes());
    out.extend_from_slice(&f.sequence.to_le_bytes());
    out.extend_from_slice(&f.timestamp_nanos.to_le_bytes());
    out.extend_from_slice(&(f.curves.len() as u32).to_le_bytes());
    for c in &f.curves {
        out.push(c.laser);
        out.extend_from_slice(&(c.points.len() as u32).to_le_bytes());
        for i in 0..c.points.len() {
            let px = c.points_px.get(i).copied().unwrap_or([f32::NAN; 2]);
            out.extend_from_slice(&px[0].to_le_bytes());
            out.extend_from_slice(&px[1].to_le_bytes());
            out.extend_from_slice(&c.points[i][0].to_le_bytes());
            out.extend_from_slice(&c.points[i][1].to_le_bytes());
            out.extend_from_slice(&c.strength.get(i).copied().unwrap_or(0.0).to_le_bytes());
        }
        out.extend_from_slice(&(c.polyline.len() as u32).to_le_bytes());
        for p in &c.polyline {
            out.extend_from_slice(&p[0].to_le_bytes());
            out.extend_from_slice(&p[1].to_le_bytes());
        }
    }
    let crc = crc32fast::hash(out);
    out.extend_from_slice(&crc.to_le_bytes());
}

struct Cursor<'a> {
    b: &'a [u8],
    at: usize,
}

impl Cursor<'_> {
    fn take(&mut self, n: usize) -> Option<&[u8]> {
        let s = self.b.get(self.at..self.at + n)?;
        self.at += n;
        Some(s)
    }
    fn u8(&mut self) -> Option<u8> {
        self.take(1).map(|s| s[0])
    }
    fn u32(&mut self) -> Option<u32> {
        self.take(4)
            .and_then(|s| s.try_into().ok())
            .map(u32::from_le_bytes)
    }
    fn u64(&mut self) -> Option<u64> {
        self.take(8)
            .and_then(|s| s.try_into().ok())
            .map(u64::from_le_bytes)
    }
    fn f32(&mut self) -> Option<f32> {
        self.take(4)
            .and_then(|s| s.try_into().ok())
            .map(f32::from_le_bytes)
    }
    fn f64(&mut self) -> Option<f64> {
        self.take(8)
            .and_then(|s| s.try_into().ok())
            .map(f64::from_le_bytes)
    }
}

/// Decodes the record at the start of `b`: the frame and the record's length.
fn decode(b: &[u8]) -> Result<(FrameCurves, usize), String> {
    let mut c = Cursor { b, at: 0 };
    let short = || "cut off".to_string();
    if c.take(4).ok_or_else(short)? != RECORD_MAGIC {
        return Err("bad record magic".into());
    }
    let index = c.u64().ok_or_else(short)?;
    let source_position = c.u64().ok_or_else(short)?;
    let sequence = c.u32().ok_or_else(short)?;
    let timestamp_nanos = c.u64().ok_or_else(short)?;
    let n = c.u32().ok_or_else(short)? as usize;
    let mut curves = Vec::with_capacity(n.min(64));
    for _ in 0..n {
        let laser = c.u8().ok_or_else(short)?;
        let m = c.u32().ok_or_else(short)? as usize;
        // A point is 28 bytes: a count the rest of the record cannot hold is damage,
        // and must not size an allocation.
        if m > (b.len() - c.at) / 28 {
            return Err("cut off or damaged: point count beyond the record".into());
        }
        let mut curve = Curve {
            laser,
            points_px: Vec::with_capacity(m),
            points: Vec::with_capacity(m),
            strength: Vec::with_capacity(m),
            polyline: Vec::new(),
        };
        for _ in 0..m {
            let px = [c.f32().ok_or_else(short)?, c.f32().ok_or_else(short)?];
            let p = [c.f64().ok_or_else(short)?, c.f64().ok_or_else(short)?];
            curve.points_px.push(px);
            curve.points.push(p);
            curve.strength.push(c.f32().ok_or_else(short)?);
        }
        let p = c.u32().ok_or_else(short)? as usize;
        if p > (b.len() - c.at) / 16 {
            return Err("cut off or damaged: polyline length beyond the record".into());
        }
        for _ in 0..p {
            curve
                .polyline
                .push([c.f64().ok_or_else(short)?, c.f64().ok_or_else(short)?]);
        }
        curves.push(curve);
    }
    let body_end = c.at;
    let crc = c.u32().ok_or_else(short)?;
    if crc32fast::hash(&b[..body_end]) != crc {
        return Err("CRC mismatch".into());
    }
    Ok((
        FrameCurves {
            index,
            source_position,
            sequence,
            timestamp_nanos,
            curves,
        },
        c.at,
    ))
}

/// Appends frames to a state directory's `curves.log`.
pub struct CheckpointWriter {
    path: PathBuf,
    file: BufWriter<File>,
    record: Vec<u8>,
    interval: Duration,
    last_sync: Instant,
    /// Frames appended since the last sync.
    unsynced: u64,
    pub frames: u64,
}

fn io(path: &Path) -> impl Fn(std::io::Error) -> CheckpointError + '_ {
    move |source| CheckpointError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// Reads a state directory (if it holds a scan) and cuts a damaged log tail away.
pub fn resume(dir: &Path, width: u32, height: u32) -> Result<Resumed, CheckpointError> {
    let log = dir.join("curves.log");
    let mut out = Resumed {
        background: None,
        frames: Vec::new(),
        stopped: None,
    };
    let bg = dir.join("background.png");
    if bg.exists() {
        let img = image::open(&bg)
            .map_err(|e| CheckpointError::Format {
                path: bg.clone(),
                message: e.to_string(),
            })?
            .into_rgb8();
        if img.width() != width || img.height() != height {
            return Err(CheckpointError::Size {
                path: bg,
                got_w: img.width(),
                got_h: img.height(),
                want_w: width,
                want_h: height,
            });
        }
        out.background = Some(img);
    }
    if !log.exists() {
        return Ok(out);
    }
    let mut bytes = Vec::new();
    File::open(&log)
        .and_then(|mut f| f.read_to_end(&mut bytes))
        .map_err(io(&log))?;
    let parsed = read_log(&bytes, &log, width, height)?;
    out.frames = parsed.frames;
    out.stopped = parsed.stopped;
    let at = parsed.whole_bytes;
    if at < bytes.len() {
        // Cut the damaged tail so appending continues from the last whole frame.
        OpenOptions::new()
            .write(true)
            .open(&log)
            .and_then(|f| f.set_len(at as u64))
            .map_err(io(&log))?;
    }
    Ok(out)
}

/// The frames of a `curves.log` held in memory.
pub struct Log {
    pub frames: Vec<FrameCurves>,
    /// Why the log stopped before its end, if it did.
    pub stopped: Option<String>,
    /// Bytes of whole header and records (where appending continues); 0 for a log
    /// without a whole header.
    pub whole_bytes: usize,
}

/// Parses the bytes of a `curves.log` (`path` labels errors). A log shorter than its
/// header that is a prefix of a header is an empty log: a crash right after creating
/// it leaves one, and the scan must restart, not fail.
pub fn read_log(
    bytes: &[u8],
    path: &Path,
    width: u32,
    height: u32,
) -> Result<Log, CheckpointError> {
    let mut out = Log {
        frames: Vec::new(),
        stopped: None,
        whole_bytes: 0,
    };
    if bytes.len() < HEADER_BYTES as usize && MAGIC.starts_with(&bytes[..bytes.len().min(8)]) {
        if !bytes.is_empty() {
            out.stopped = Some(format!("the header is cut off after {} bytes", bytes.len()));
        }
        return Ok(out);
    }
    if bytes.len() < HEADER_BYTES as usize || &bytes[..8] != MAGIC {
        return Err(CheckpointError::Format {
            path: path.to_path_buf(),
            message: "not a crossline curves log (expected magic CRSLCURV)".into(),
        });
    }
    let version = u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]);
    if version != VERSION {
        return Err(CheckpointError::Format {
            path: path.to_path_buf(),
            message: format!("version {version}, this crossline reads {VERSION}"),
        });
    }
    let w = u32::from_le_bytes([bytes[12], bytes[13], bytes[14], bytes[15]]);
    let h = u32::from_le_bytes([bytes[16], bytes[17], bytes[18], bytes[19]]);
    if (w, h) != (width, height) {
        return Err(CheckpointError::Size {
            path: path.to_path_buf(),
            got_w: w,
            got_h: h,
            want_w: width,
            want_h: height,
        });
    }
    let mut at = HEADER_BYTES as usize;
    while at < bytes.len() {
        match decode(&bytes[at..]) {
            Ok((f, len)) if f.index == out.frames.len() as u64 => {
                out.frames.push(f);
                at += len;
            }
            Ok((f, _)) => {
                out.stopped = Some(format!(
                    "record at byte {at} is frame {}, expected {}",
                    f.index,
                    out.frames.len()
                ));
                break;
            }
            Err(why) => {
                out.stopped = Some(format!("record at byte {at}: {why}"));
                break;
            }
        }
    }
    out.whole_bytes = at;
    Ok(out)
}

impl CheckpointWriter {
    /// Opens `dir/curves.log` for appending (creating it with its header).
    pub fn open(
        dir: &Path,
        width: u32,
        height: u32,
        interval: Duration,
    ) -> Result<Self, CheckpointError> {
        std::fs::create_dir_all(dir).map_err(io(dir))?;
        let path = dir.join("curves.log");
        let exists = path.metadata().is_ok_and(|m| m.len() >= HEADER_BYTES);
        let file = OpenOptions::new()
            .create(true)
            .append(true)
            .open(&path)
            .map_err(io(&path))?;
        let mut file = BufWriter::with_capacity(1 << 20, file);
        if !exists {
            file.get_ref().set_len(0).map_err(io(&path))?;
            let mut h = Vec::with_capacity(HEADER_BYTES as usize);
            h.extend_from_slice(MAGIC);
            h.extend_from_slice(&VERSION.to_le_bytes());
            h.extend_from_slice(&width.to_le_bytes());
            h.extend_from_slice(&height.to_le_bytes());
            file.write_all(&h).map_err(io(&path))?;
            // On disk before any frame: a log whose header still sat in the buffer
            // when the process was killed would be empty, and refused on every restart.
            file.flush().map_err(io(&path))?;
            file.get_ref().sync_all().map_err(io(&path))?;
            if let Ok(d) = File::open(dir) {
                let _ = d.sync_all();
            }
        }
        Ok(Self {
            path,
            file,
            record: Vec::new(),
            interval,
            last_sync: Instant::now(),
            unsynced: 0,
            frames: 0,
        })
    }

    /// Saves the background (once per scan).
    pub fn save_background(dir: &Path, image: &RgbImage) -> Result<(), CheckpointError> {
        let path = dir.join("background.png");
        let tmp = dir.join("background.png.tmp");
        image
            .save_with_format(&tmp, image::ImageFormat::Png)
            .map_err(|e| CheckpointError::Format {
                path: tmp.clone(),
                message: e.to_string(),
            })?;
        std::fs::rename(&tmp, &path).map_err(io(&path))
    }

    /// Appends a frame; every `interval` the log is flushed and synced to disk.
    pub fn append(&mut self, frame: &FrameCurves) -> Result<(), CheckpointError> {
        encode(frame, &mut self.record);
        self.file.write_all(&self.record).map_err(io(&self.path))?;
        self.frames += 1;
        self.unsynced += 1;
        self.sync_if_due()
    }

    /// [`Self::sync`] when frames were appended since the last one and `interval` has
    /// passed: called with each frame, and by the solver thread while it waits for
    /// frames, so that frames appended just before a pause (a burst after the warm-up,
    /// a camera that stalls) do not wait in the buffer for the next frame.
    pub fn sync_if_due(&mut self) -> Result<(), CheckpointError> {
        if self.unsynced > 0 && self.last_sync.elapsed() >= self.interval {
            self.sync()?;
        }
        Ok(())
    }

    pub fn sync(&mut self) -> Result<(), CheckpointError> {
        self.file.flush().map_err(io(&self.path))?;
        self.file.get_ref().sync_data().map_err(io(&self.path))?;
        self.last_sync = Instant::now();
        self.unsynced = 0;
        Ok(())
    }
}

/// The checkpoint as a running scan keeps it: a write that fails stops the checkpoint,
/// not the scan. The curves are in memory and the final cloud needs nothing of the
/// checkpoint; only a resume after a crash loses what was not written. A failed write
/// used to end the solver thread while the extraction workers waited for ever to hand
/// it their frames: the daemon hung without a word, ignored SIGTERM and wrote no cloud
/// (a background checkpoint that found no descriptor left, or its directory deleted).
pub struct Checkpoint {
    writer: CheckpointWriter,
    /// The first write that failed; nothing is written after it.
    error: Option<String>,
}

impl Checkpoint {
    pub fn new(writer: CheckpointWriter) -> Self {
        Self {
            writer,
            error: None,
        }
    }

    /// Why the checkpoint stopped, if it did.
    pub fn error(&self) -> Option<&str> {
        self.error.as_deref()
    }

    pub fn append(&mut self, frame: &FrameCurves) {
        if self.error.is_none() {
            let result = self.writer.append(frame);
            self.keep(result);
        }
    }

    pub fn sync(&mut self) {
        if self.error.is_none() {
            let result = self.writer.sync();
            self.keep(result);
        }
    }

    pub fn sync_if_due(&mut self) {
        if self.error.is_none() {
            let result = self.writer.sync_if_due();
            self.keep(result);
        }
    }

    pub fn save_background(&mut self, dir: &Path, image: &RgbImage) {
        if self.error.is_none() {
            self.keep(CheckpointWriter::save_background(dir, image));
        }
    }

    fn keep(&mut self, result: Result<(), CheckpointError>) {
        if let Err(e) = result {
            tracing::error!(
                "{e}: the checkpoint stops here; the scan goes on and its cloud will be \
                 written, but a crash from now on cannot be resumed"
            );
            self.error = Some(e.to_string());
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(i: u64) -> FrameCurves {
        FrameCurves {
            index: i,
            source_position: i + 3,
            sequence: 100 + i as u32,
            timestamp_nanos: 33_000_000 * i,
            curves: vec![Curve {
                laser: (i % 2) as u8,
                points_px: vec![[1.5, 2.25], [3.0, 4.0 + i as f32]],
                points: vec![[0.1, -0.2], [0.3, 0.4 + i as f64 * 1e-9]],
                strength: vec![40.0, 50.5],
                polyline: vec![[0.1, -0.2], [0.3, 0.4]],
            }],
        }
    }

    #[test]
    fn log_round_trips_and_survives_a_cut_tail() {
        let dir = tempfile::tempdir().expect("tempdir");
        let mut w =
            CheckpointWriter::open(dir.path(), 64, 48, Duration::from_secs(3600)).expect("open");
        for i in 0..5 {
            w.append(&frame(i)).expect("append");
        }
        w.sync().expect("sync");
        drop(w);
        let r = resume(dir.path(), 64, 48).expect("resume");
        assert_eq!(r.frames, (0..5).map(frame).collect::<Vec<_>>());
        assert!(r.stopped.is_none());

        // A crash in the middle of the sixth record.
        let log = dir.path().join("curves.log");
        let whole = std::fs::metadata(&log).expect("meta").len();
        let mut rec = Vec::new();
        encode(&frame(5), &mut rec);
        let mut f = OpenOptions::new().append(true).open(&log).expect("open");
        f.write_all(&rec[..rec.len() / 2]).expect("write");
        drop(f);
        let r = resume(dir.path(), 64, 48).expect("resume");
        assert_eq!(r.frames.len(), 5);
        assert!(r.stopped.as_deref().is_some_and(|s| s.contains("cut off")));
        assert_eq!(
            std::fs::metadata(&log).expect("meta").len(),
            whole,
            "tail cut"
        );
        // Appending continues cleanly after the cut.
        let mut w =
            CheckpointWriter::open(dir.path(), 64, 48, Duration::from_secs(3600)).expect("open");
        w.append(&frame(5)).expect("append");
        w.sync().expect("sync");
        let r = resume(dir.path(), 64, 48).expect("resume");
        assert_eq!(r.frames.len(), 6);
        assert!(matches!(
            resume(dir.path(), 640, 480),
            Err(CheckpointError::Size { .. })
        ));
    }

    /// Frames appended within the interval of the last sync reach the file once the
    /// interval has passed and the solver thread asks, with no frame after them.
    #[test]
    fn frames_before_a_pause_are_written_when_the_interval_passes() {
        let dir = tempfile::tempdir().expect("tempdir");
        // Long enough that the appends and first checks surely fall within it.
        let interval = Duration::from_millis(1000);
        let mut w = CheckpointWriter::open(dir.path(), 64, 48, interval).expect("open");
        w.sync().expect("sync");
        for i in 0..4 {
            w.append(&frame(i)).expect("append");
        }
        let on_disk = || {
            let bytes = std::fs::read(dir.path().join("curves.log")).expect("read");
            read_log(&bytes, Path::new("curves.log"), 64, 48)
                .expect("log")
                .frames
                .len()
        };
        assert_eq!(on_disk(), 0, "appended within the interval: still buffered");
        w.sync_if_due().expect("sync");
        assert_eq!(on_disk(), 0, "not due yet");
        std::thread::sleep(interval + Duration::from_millis(100));
        w.sync_if_due().expect("sync");
        assert_eq!(on_disk(), 4);
    }

    #[test]
    fn a_flipped_bit_stops_the_log_there() {
        let dir = tempfile::tempdir().expect("tempdir");
        let mut w =
            CheckpointWriter::open(dir.path(), 8, 8, Duration::from_secs(3600)).expect("open");
        for i in 0..3 {
            w.append(&frame(i)).expect("append");
        }
        w.sync().expect("sync");
        let log = dir.path().join("curves.log");
        let mut bytes = std::fs::read(&log).expect("read");
        let mut rec = Vec::new();
        encode(&frame(0), &mut rec);
        let second = HEADER_BYTES as usize + rec.len() + 60; // inside the points
        bytes[second] ^= 0x10;
        std::fs::write(&log, &bytes).expect("write");
        let r = resume(dir.path(), 8, 8).expect("resume");
        assert_eq!(r.frames.len(), 1);
        assert!(r.stopped.as_deref().is_some_and(|s| s.contains("CRC")));
    }

    #[test]
    fn the_header_is_on_disk_at_creation_and_an_empty_log_resumes_empty() {
        let dir = tempfile::tempdir().expect("tempdir");
        let w =
            CheckpointWriter::open(dir.path(), 64, 48, Duration::from_secs(3600)).expect("open");
        // Read through another handle while the writer is alive (a kill -9 now).
        let log = dir.path().join("curves.log");
        assert_eq!(
            std::fs::read(&log).expect("read").len(),
            HEADER_BYTES as usize
        );
        drop(w);
        // An empty log (or one cut inside its header) is an empty checkpoint.
        for len in [0, 7, 12] {
            let header = std::fs::read(&log).expect("read");
            std::fs::write(&log, &header[..len.min(header.len())]).expect("cut");
            let r = resume(dir.path(), 64, 48).expect("an empty checkpoint");
            assert!(r.frames.is_empty());
            assert_eq!(r.stopped.is_some(), len > 0);
            let mut w = CheckpointWriter::open(dir.path(), 64, 48, Duration::from_secs(3600))
                .expect("reopen");
            w.append(&frame(0)).expect("append");
            w.sync().expect("sync");
            drop(w);
            assert_eq!(
                resume(dir.path(), 64, 48).expect("resume").frames,
                vec![frame(0)]
            );
            std::fs::write(&log, &header).expect("restore");
        }
        // Something else is still refused.
        std::fs::write(&log, b"PK\x03\x04 a zip file, not a log").expect("write");
        assert!(resume(dir.path(), 64, 48).is_err());
    }

    #[test]
    fn a_point_count_larger_than_the_record_is_refused_before_allocating() {
        let mut rec = Vec::new();
        encode(&frame(0), &mut rec);
        // The first curve's point count sits after 4+8+8+4+8+4 bytes and its laser byte.
        rec[37..41].copy_from_slice(&u32::MAX.to_le_bytes());
        let err = decode(&rec).expect_err("refused");
        assert!(err.contains("point count"), "{err}");
    }
}
