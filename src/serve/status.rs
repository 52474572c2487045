//! Status lines, version 1: what `crossline status` shows and what the status socket
//! streams, one JSON object per line (newline-delimited JSON), once per interval and
//! on events. Every line has `"type"` (`"status"` or `"event"`) and `"version"`.
//!
//! A `status` line:
//! ```json
//! {"type":"status","version":1,"scan":"20261122T101500Z","uptime_s":12.0,
//!  "device":"streaming","frames_in":360,"frames_decoded":358,"frames_dropped":2,
//!  "frames_dropped_driver":0,"decode_errors":0,"frames_processed":350,
//!  "frames_with_laser":349,"ring_depth":1,"curves":700,"planes":698,
//!  "crossings":41000,"planes_solved":650,"planes_in_global_solve":120,
//!  "residual_rms_px":0.05,"orthogonality_rms_deg":0.1,"epoch":2,"points":900000,
//!  "stream_clients":1,"recording":"/var/lib/crossline/recordings/...dump",
//!  "recording_bytes":123456789,"latency_p50_ms":40.0,"latency_p95_ms":80.0,
//!  "last_error":null}
//! ```
//! `device` is one of `starting`, `streaming`, `lost` (the daemon keeps retrying) and
//! `stopped`. An `event` line: `{"type":"event","version":1,"event":"epoch","detail":"..."}`.

use std::sync::atomic::Ordering;
use std::time::Instant;

use serde::{Deserialize, Serialize};

use super::{lock, net::Hub, Shared};

pub const VERSION: u32 = 1;

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
#[repr(u8)]
pub enum DeviceState {
    Starting = 0,
    Streaming = 1,
    Lost = 2,
    Stopped = 3,
}

impl DeviceState {
    fn from_u8(v: u8) -> Self {
        match v {
            1 => Self::Streaming,
            2 => Self::Lost,
            3 => Self::Stopped,
            _ => Self::Starting,
        }
    }
}

/// One status line.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Status {
    #[serde(rename = "type")]
    pub kind: String,
    pub version: u32,
    pub scan: String,
    pub uptime_s: f64,
    pub device: DeviceState,
    pub frames_in: u64,
    pub frames_decoded: u64,
    pub frames_dropped: u64,
    pub frames_dropped_driver: u64,
    pub decode_errors: u64,
    pub frames_processed: u64,
    pub frames_with_laser: u64,
    pub ring_depth: u64,
    pub curves: u64,
    pub planes: u64,
    pub crossings: u64,
    pub planes_solved: u64,
    pub planes_in_global_solve: u64,
    pub residual_rms_px: f64,
    pub orthogonality_rms_deg: f64,
    pub epoch: u32,
    pub points: u64,
    pub stream_clients: u64,
    pub recording: String,
    pub recording_bytes: u64,
    pub latency_p50_ms: f64,
    pub latency_p95_ms: f64,
    pub last_error: Option<String>,
}

impl Status {
    pub fn gather(shared: &Shared, hub: &Hub, scan: &str, started: Instant) -> Self {
        let solver = *lock(&shared.solver);
        let latency = hub.stats.latency();
        let r = |a: &std::sync::atomic::AtomicU64| a.load(Ordering::Relaxed);
        Self {
            kind: "status".into(),
            version: VERSION,
            scan: scan.to_string(),
            uptime_s: started.elapsed().as_secs_f64(),
            device: DeviceState::from_u8(shared.device_state.load(Ordering::Relaxed)),
            frames_in: r(&shared.frames_in),
            frames_decoded: r(&shared.frames_decoded),
            frames_dropped: r(&shared.frames_dropped_ring),
            frames_dropped_driver: r(&shared.frames_dropped_driver),
            decode_errors: r(&shared.decode_errors),
            frames_processed: r(&shared.frames_processed),
            frames_with_laser: r(&shared.frames_with_laser),
            ring_depth: r(&shared.ring_depth),
            curves: solver.curves,
            planes: solver.planes,
            crossings: solver.crossings,
            planes_solved: solver.planes_solved,
            planes_in_global_solve: solver.planes_in_global_solve,
            residual_rms_px: solver.residual_rms_px,
            orthogonality_rms_deg: solver.orthogonality_rms_deg,
            epoch: solver.epoch,
            points: solver.points,
            stream_clients: r(&hub.stats.clients),
            recording: lock(&shared.recording_file).clone(),
            recording_bytes: r(&shared.recording_bytes),
            latency_p50_ms: latency.p50_ms,
            latency_p95_ms: latency.p95_ms,
            last_error: lock(&shared.last_error).clone(),
        }
    }

    pub fn to_line(&self) -> String {
        serde_json::to_string(self).unwrap_or_default()
    }

    /// A short human summary (systemd's STATUS=, `crossline status`).
    pub fn summary(&self) -> String {
        format!(
            "{:?} | frames {} in, {} dropped, {} processed | planes {}/{} solved | epoch {} | {} points | {} clients",
            self.device,
            self.frames_in,
            self.frames_dropped + self.frames_dropped_driver,
            self.frames_processed,
            self.planes_solved,
            self.planes,
            self.epoch,
            self.points,
            self.stream_clients
        )
    }
}

/// An event line.
pub fn event_line(event: &str, detail: &str) -> String {
    serde_json::json!({"type": "event", "version": VERSION, "event": event, "detail": detail})
        .to_string()
}

/// Longest status line a client reads (they are a few hundred bytes).
pub const MAX_LINE_BYTES: usize = 64 << 10;

/// One line of the status socket as a client understands it.
#[derive(Debug)]
pub enum Line {
    Status(Box<Status>),
    Event { event: String, detail: String },
}

/// Why a status line could not be used; the line is echoed shortened.
#[derive(Debug, thiserror::Error)]
pub enum LineError {
    #[error("reading the status socket: {0}")]
    Io(#[from] std::io::Error),
    #[error("status line longer than {MAX_LINE_BYTES} bytes")]
    TooLong,
    #[error("status line is not JSON ({why}): {line}")]
    NotJson { why: String, line: String },
    #[error("unexpected status line ({why}): {line}")]
    Unexpected { why: String, line: String },
}

/// Reads the next line into `buf` (without its newline) and parses it; `Ok(None)` at
/// the end of the stream. A line is read at most [`MAX_LINE_BYTES`] long.
pub fn read_line(
    r: &mut impl std::io::BufRead,
    buf: &mut String,
) -> Result<Option<Line>, LineError> {
    use std::io::{BufRead, Read};
    buf.clear();
    let mut bytes = Vec::new();
    let n = r
        .by_ref()
        .take(MAX_LINE_BYTES as u64 + 1)
        .read_until(b'\n', &mut bytes)?;
    if n == 0 {
        return Ok(None);
    }
    if !bytes.ends_with(b"\n") && n > MAX_LINE_BYTES {
        return Err(LineError::TooLong);
    }
    buf.push_str(String::from_utf8_lossy(&bytes).trim_end_matches(['\n', '\r']));
    parse_line(buf).map(Some)
}

/// Parses one status line.
pub fn parse_line(line: &str) -> Result<Line, LineError> {
    let value: serde_json::Value = serde_json::from_str(line).map_err(|e| LineError::NotJson {
        why: e.to_string(),
        line: crate::truncate_echo(line),
    })?;
    if value.get("type").and_then(|t| t.as_str()) == Some("status") {
        let st: Status = serde_json::from_value(value).map_err(|e| LineError::Unexpected {
            why: e.to_string(),
            line: crate::truncate_echo(line),
        })?;
        return Ok(Line::Status(Box::new(st)));
    }
    let text = |k: &str| {
        value
            .get(k)
            .and_then(|e| e.as_str())
            .unwrap_or(if k == "event" { "?" } else { "" })
            .to_string()
    };
    Ok(Line::Event {
        event: text("event"),
        detail: text("detail"),
    })
}
