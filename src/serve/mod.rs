//! The live daemon (`crossline serve`): camera or replay in, growing cloud out.
//!
//! ```text
//!  capture ──ring (preallocated slots)──▶ extract-0..N ──bounded──▶ solver ──▶ hub ──▶ net, web (tokio)
//!     │  (drops + counts when full)          (decode, background,     (reorder,          stream clients
//!     └─▶ recording (dump)                    Steger, colour, link)    incremental,      status socket
//!                                                                      checkpoint)
//!                                                                                        live view pages
//! ```
//!
//! - `capture` never waits on the workers (except in a lossless replay, which has no
//!   camera to keep up with): a frame that finds no free ring slot is dropped and
//!   counted. It records every buffer before anything else looks at it.
//! - `extract-i` decode and extract, each frame against the rolling temporal median
//!   `reconstruct` uses too ([`crate::extract::rolling`], kept by [`background`]): a
//!   frame whose background needs a sample still in another worker's hands is parked,
//!   and the worker goes on. Frames are numbered by the capture thread, so the results
//!   are the same for any number of workers.
//! - `solver` puts results back in frame order, checkpoints them, and feeds the
//!   [`incremental`] solver, whose output goes to the [`net::Hub`].
//! - `web` serves the live view in the browser ([`web`]): each page is one more
//!   subscriber of the hub, under the same bounds as the stream clients.
//! - `status` publishes a status line every interval and on events, and talks to
//!   systemd (`READY`, `STATUS`, `WATCHDOG` from pipeline progress).
//!
//! Shutdown (SIGTERM/SIGINT, end of a replay): capture stops, the ring drains, the
//! final solve runs over every curve, the cloud (PLY) and report (JSON) are written,
//! stream clients get the final epoch and `END`, and `run` returns.

mod background;
pub mod checkpoint;
pub mod incremental;
pub mod net;
pub mod notify;
pub mod status;
pub mod stream;
mod threads;
pub mod web;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicU8, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use crossbeam_channel::{bounded, Receiver, RecvTimeoutError};
use serde::{Deserialize, Serialize};

use crate::camera::Camera;
use crate::capture::dump::{DumpHeader, DumpWriter};
use crate::capture::FrameSource;
use crate::cloud::ScaleMode;
use crate::config::Config;
use crate::extract::rolling::Policy;
use crate::extract::{Curve, Extractor};
use crate::ring::{self, FrameMeta};

use background::LiveBackground;
use checkpoint::{Checkpoint, CheckpointWriter, FrameCurves};
use incremental::{Incremental, IncrementalParams, SolverCounts};
use status::{DeviceState, Status};
use stream::EpochReason;

/// The `[serve]` section of `crossline.toml`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ServeConfig {
    pub camera: String,
    pub device: String,
    pub formats: Vec<String>,
    pub width: u32,
    pub height: u32,
    pub fps: u32,
    pub buffers: u32,
    pub ring_slots: usize,
    pub workers: usize,
    pub out_dir: String,
    pub record: bool,
    pub record_rotate_mib: u64,
    pub checkpoint_interval_s: f64,
    pub min_planes_first_solve: usize,
    pub solve_growth: f64,
    pub status_socket: String,
    pub status_interval_ms: u64,
    pub stream_tcp: String,
    pub stream_unix: String,
    pub client_queue_mib: usize,
    pub stream_clients_max: usize,
    pub drain_timeout_s: f64,
    pub reconnect_max_backoff_s: f64,
    pub http_listen: String,
    pub http_clients_max: usize,
}

impl Default for ServeConfig {
    fn default() -> Self {
        Self {
            camera: String::new(),
            device: "/dev/video0".into(),
            formats: vec!["MJPG".into(), "YUYV".into()],
            width: 1920,
            height: 1080,
            fps: 30,
            buffers: 4,
            ring_slots: 16,
            workers: 0,
            out_dir: "/var/lib/crossline".into(),
            record: true,
            record_rotate_mib: 2048,
            checkpoint_interval_s: 2.0,
            min_planes_first_solve: 40,
            solve_growth: 1.5,
            status_socket: "/run/crossline/status.sock".into(),
            status_interval_ms: 1000,
            stream_tcp: "127.0.0.1:7878".into(),
            stream_unix: String::new(),
            client_queue_mib: 64,
            stream_clients_max: 64,
            drain_timeout_s: 5.0,
            reconnect_max_backoff_s: 5.0,
            http_listen: "127.0.0.1:8080".into(),
            http_clients_max: 8,
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum ServeError {
    #[error("the stream is {got_w}x{got_h} but the camera file is for {want_w}x{want_h}: calibrate at the capture size or change [serve] width/height")]
    Size {
        got_w: u32,
        got_h: u32,
        want_w: u32,
        want_h: u32,
    },
    #[error(transparent)]
    Net(#[from] net::NetError),
    #[error(transparent)]
    Web(#[from] web::WebError),
    #[error(transparent)]
    Checkpoint(#[from] checkpoint::CheckpointError),
    #[error(transparent)]
    Dump(#[from] crate::capture::dump::DumpError),
    #[error(transparent)]
    Extract(#[from] crate::extract::ExtractError),
    #[error("{what} {path}: {source}")]
    Io {
        what: &'static str,
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("writing the cloud: {0}")]
    Ply(#[from] crate::ply::PlyError),
    #[error("writing the cloud: {0}")]
    E57(#[from] crate::e57::E57Error),
    #[error("{path} is in use by another crossline serve (pid {pid}): one daemon per out_dir; stop it or give this one another [serve] out_dir")]
    Busy { path: PathBuf, pid: String },
    #[error("the stream's frames ({header}) are larger than crossline buffers: {message}")]
    FrameSize { header: String, message: String },
    #[error("cannot start thread {name}: {source}")]
    Thread {
        name: String,
        #[source]
        source: std::io::Error,
    },
}

/// Everything `run` needs besides the source.
pub struct ServeOptions {
    pub camera: Camera,
    pub config: Config,
    pub scale: ScaleMode,
    /// Where the scan's state, cloud and report go.
    pub out_dir: PathBuf,
    /// Output paths (default: `out_dir/<scan>.ply` and `.json`).
    pub cloud_path: Option<PathBuf>,
    pub report_path: Option<PathBuf>,
    /// Identity of the input, to recognise the scan a checkpoint belongs to.
    pub input_id: String,
    /// Record raw buffers (a live camera; replays are not recorded again).
    pub record: bool,
    /// The live view's port, bound by the caller (the demo, to print its address);
    /// `None`: bind `[serve] http_listen`.
    pub http_listener: Option<std::net::TcpListener>,
}

/// Counters shared by the threads; read by the status publisher.
#[derive(Default)]
pub struct Shared {
    pub frames_in: AtomicU64,
    pub frames_dropped_ring: AtomicU64,
    pub frames_dropped_driver: AtomicU64,
    pub frames_decoded: AtomicU64,
    pub decode_errors: AtomicU64,
    pub frames_processed: AtomicU64,
    pub frames_with_laser: AtomicU64,
    pub ring_depth: AtomicU64,
    pub device_state: AtomicU8,
    /// Times the device was lost: a loss shorter than the status interval still gets
    /// its status line.
    pub device_losses: AtomicU64,
    pub recording_bytes: AtomicU64,
    pub recording_file: Mutex<String>,
    pub solver: Mutex<SolverCounts>,
    pub capture_beats: AtomicU64,
    pub solver_beats: AtomicU64,
    pub last_error: Mutex<Option<String>>,
    pub solver_frame_micros: Mutex<Vec<u64>>,
    pub live_solver: Mutex<SolverCounts>,
}

/// The status lines to publish for `current`: when the device was lost since the last
/// line (`lost_since`) but is not lost now, a line saying it was lost comes first, so
/// that a loss shorter than the status interval is still seen by every reader.
fn status_lines(current: &Status, lost_since: bool) -> Vec<Status> {
    let mut lines = Vec::with_capacity(2);
    if lost_since && current.device != DeviceState::Lost {
        let mut was = current.clone();
        was.device = DeviceState::Lost;
        lines.push(was);
    }
    lines.push(current.clone());
    lines
}

/// How a serve run ended.
#[derive(Debug, Serialize)]
pub struct ServeReport {
    pub version: u32,
    pub scan: String,
    pub input: String,
    pub resumed_frames: u64,
    pub frames_in: u64,
    pub frames_dropped_ring: u64,
    pub frames_dropped_driver: u64,
    pub decode_errors: u64,
    pub frames_processed: u64,
    pub epochs: u32,
    pub cloud: PathBuf,
    pub points: usize,
    /// From a frame's capture to its points written to a stream client's socket.
    pub latency: net::Latency,
    /// Time the solver thread spent per frame (crossings, placing planes,
    /// triangulating, adopting a new epoch).
    pub solver_frame: net::Latency,
    /// The live solver's last counts (before the final solve) and time per phase.
    pub live_solver: SolverCounts,
    pub stream_clients_total: u64,
    pub stream_resyncs: u64,
    pub stream_dropped_clients: u64,
    pub cpu_seconds: f64,
    pub wall_seconds: f64,
    /// Why capture stopped early (a damaged recording, a failed device), if it did.
    pub capture_error: Option<String>,
    /// Why the checkpoint stopped during the scan (the scan went on), if it did.
    pub checkpoint_error: Option<String>,
    pub reconstruction: Option<crate::reconstruct::ReconstructReport>,
    pub solve_error: Option<String>,
}

impl ServeReport {
    /// The counters of a run, everything else empty.
    fn counted(scan: &str, input: &str, shared: &Shared, hub: &net::Hub, started: Instant) -> Self {
        let n = |c: &AtomicU64| c.load(Ordering::Relaxed);
        Self {
            version: REPORT_VERSION,
            scan: scan.to_string(),
            input: input.to_string(),
            resumed_frames: 0,
            frames_in: n(&shared.frames_in),
            frames_dropped_ring: n(&shared.frames_dropped_ring),
            frames_dropped_driver: n(&shared.frames_dropped_driver),
            decode_errors: n(&shared.decode_errors),
            frames_processed: n(&shared.frames_processed),
            epochs: 0,
            cloud: PathBuf::new(),
            points: 0,
            latency: hub.stats.latency(),
            solver_frame: net::Latency::of_micros(lock(&shared.solver_frame_micros).clone()),
            live_solver: *lock(&shared.live_solver),
            stream_clients_total: hub.stats.clients_total.load(Ordering::Relaxed),
            stream_resyncs: hub.stats.resyncs.load(Ordering::Relaxed),
            stream_dropped_clients: hub.stats.dropped_clients.load(Ordering::Relaxed),
            cpu_seconds: 0.0,
            wall_seconds: started.elapsed().as_secs_f64(),
            capture_error: None,
            checkpoint_error: None,
            reconstruction: None,
            solve_error: None,
        }
    }
}

pub const REPORT_VERSION: u32 = 1;

/// Stack of the extraction and solver threads: the detector's and the median's
/// per-pixel work arrays live on the stack, more than the 2 MiB default.
pub const WORKER_STACK_BYTES: usize = 16 << 20;

/// Locks a mutex of the daemon's shared state. A panic while holding one is a bug
/// elsewhere; the data (counters, queues of immutable messages) stays consistent, so
/// carry on with it rather than take the daemon down.
fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// What a worker sends the solver.
struct Extracted {
    meta: FrameMeta,
    curves: Vec<Curve>,
}

/// A scan's identity and where its files go.
struct ScanFiles {
    id: String,
    state: PathBuf,
    cloud: PathBuf,
    report: PathBuf,
    recordings: PathBuf,
}

#[derive(Serialize, Deserialize)]
struct Session {
    version: u32,
    scan: String,
    input: String,
    width: u32,
    height: u32,
}

/// UTC time as `YYYYMMDDTHHMMSSZ` (civil-from-days, no time zone database needed).
fn utc_stamp() -> String {
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs()) as i64;
    let (days, rem) = (secs.div_euclid(86_400), secs.rem_euclid(86_400));
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!(
        "{y:04}{m:02}{d:02}T{:02}{:02}{:02}Z",
        rem / 3600,
        (rem / 60) % 60,
        rem % 60
    )
}

/// Finds the unfinished scan in `out_dir/state` (same input) or starts a new one.
fn open_scan(
    opts: &ServeOptions,
    width: u32,
    height: u32,
) -> Result<(ScanFiles, bool), ServeError> {
    let io = |what, path: &Path| {
        let path = path.to_path_buf();
        move |source| ServeError::Io { what, path, source }
    };
    let state = opts.out_dir.join("state");
    std::fs::create_dir_all(&opts.out_dir).map_err(io("cannot create", &opts.out_dir))?;
    let session_path = state.join("session.json");
    let mut resumed = false;
    let mut id = None;
    if let Ok(text) = std::fs::read_to_string(&session_path) {
        match serde_json::from_str::<Session>(&text) {
            Ok(s) if s.input == opts.input_id && (s.width, s.height) == (width, height) => {
                id = Some(s.scan);
                resumed = true;
            }
            Ok(s) => {
                let aside = opts.out_dir.join(format!("{}.state", s.scan));
                tracing::warn!(
                    "{} holds an unfinished scan of another input ({}); keeping it in {}",
                    state.display(),
                    s.input,
                    aside.display()
                );
                std::fs::rename(&state, &aside).map_err(io("cannot move", &state))?;
            }
            Err(e) => {
                let aside = opts
                    .out_dir
                    .join(format!("unreadable-{}.state", utc_stamp()));
                tracing::warn!(
                    "{}: {e}; keeping that state in {}",
                    session_path.display(),
                    aside.display()
                );
                std::fs::rename(&state, &aside).map_err(io("cannot move", &state))?;
            }
        }
    }
    let id = id.unwrap_or_else(utc_stamp);
    std::fs::create_dir_all(&state).map_err(io("cannot create", &state))?;
    if !resumed {
        let s = Session {
            version: 1,
            scan: id.clone(),
            input: opts.input_id.clone(),
            width,
            height,
        };
        let text = serde_json::to_string_pretty(&s).unwrap_or_default();
        std::fs::write(&session_path, text).map_err(io("cannot write", &session_path))?;
    }
    Ok((
        ScanFiles {
            cloud: opts
                .cloud_path
                .clone()
                .unwrap_or_else(|| opts.out_dir.join(format!("{id}.ply"))),
            report: opts
                .report_path
                .clone()
                .unwrap_or_else(|| opts.out_dir.join(format!("{id}.json"))),
            recordings: opts.out_dir.join("recordings"),
            state,
            id,
        },
        resumed,
    ))
}

/// Rotating recording of raw buffers.
struct Recorder {
    dir: PathBuf,
    scan: String,
    header: DumpHeader,
    rotate_bytes: u64,
    part: u32,
    writer: Option<DumpWriter>,
}

impl Recorder {
    fn write(&mut self, shared: &Shared, sequence: u32, ts: u64, flags: u32, payload: &[u8]) {
        if self
            .writer
            .as_ref()
            .is_some_and(|w| w.bytes() >= self.rotate_bytes)
        {
            if let Some(w) = self.writer.take() {
                let _ = w.finish();
            }
        }
        if self.writer.is_none() {
            self.part += 1;
            let path = self
                .dir
                .join(format!("{}-{:03}.dump", self.scan, self.part));
            match std::fs::create_dir_all(&self.dir)
                .map_err(|source| crate::capture::dump::DumpError::Io {
                    path: self.dir.clone(),
                    source,
                })
                .and_then(|_| DumpWriter::create(&path, &self.header))
            {
                Ok(w) => {
                    tracing::info!("recording to {}", path.display());
                    *lock(&shared.recording_file) = path.display().to_string();
                    self.writer = Some(w);
                }
                Err(e) => {
                    tracing::error!("cannot record: {e}");
                    *lock(&shared.last_error) = Some(format!("recording: {e}"));
                    return;
                }
            }
        }
        if let Some(w) = self.writer.as_mut() {
            let before = w.bytes();
            if let Err(e) = w.write_frame(sequence, ts, flags, payload) {
                tracing::error!("recording: {e}");
                *lock(&shared.last_error) = Some(format!("recording: {e}"));
                self.writer = None;
                return;
            }
            shared
                .recording_bytes
                .fetch_add(w.bytes() - before, Ordering::Relaxed);
        }
    }
}

/// A resumed scan's checkpoint (nothing for a new scan), its state said in the log.
fn resume_scan(
    scan: &ScanFiles,
    resumed: bool,
    width: u32,
    height: u32,
) -> Result<checkpoint::Resumed, ServeError> {
    if !resumed {
        return Ok(checkpoint::Resumed {
            background: None,
            frames: Vec::new(),
            stopped: None,
        });
    }
    let r = checkpoint::resume(&scan.state, width, height)?;
    if let Some(why) = &r.stopped {
        tracing::warn!("checkpoint ended early ({why}); those frames are processed again");
    }
    tracing::info!(
        scan = %scan.id,
        frames = r.frames.len(),
        "resuming the unfinished scan from its checkpoint"
    );
    Ok(r)
}

/// The bytes of one ring slot for frames of `header`, refused when a frame has no
/// bounded size or the ring would need more than [`MAX_RING_BYTES`].
fn ring_slot_bytes(header: &DumpHeader, ring_slots: usize) -> Result<usize, ServeError> {
    crate::capture::dump::frame_capacity(header)
        .filter(|b| b.saturating_mul(ring_slots.max(2)) <= MAX_RING_BYTES)
        .ok_or_else(|| ServeError::FrameSize {
            header: format!(
                "{} {}x{}, {} bytes per line",
                String::from_utf8_lossy(&header.fourcc),
                header.width,
                header.height,
                header.bytes_per_line
            ),
            message: crate::capture::dump::check_frame_size(header)
                .err()
                .unwrap_or_else(|| {
                    format!(
                        "[serve] ring_slots = {ring_slots} of them need more than {MAX_RING_BYTES} bytes"
                    )
                }),
        })
}

/// Runs the daemon on `source` until it ends or `stop` is set.
pub fn run(
    mut source: Box<dyn FrameSource>,
    mut opts: ServeOptions,
    stop: Arc<AtomicBool>,
) -> Result<ServeReport, ServeError> {
    let started = Instant::now();
    let cpu_start = cpu_seconds();
    let cfg = opts.config.serve.clone();
    let header = source.header().clone();
    if (header.width, header.height) != (opts.camera.width, opts.camera.height) {
        return Err(ServeError::Size {
            got_w: header.width,
            got_h: header.height,
            want_w: opts.camera.width,
            want_h: opts.camera.height,
        });
    }
    Extractor::new(&opts.config.extract, &opts.camera)?;
    // Sizes first: nothing is allocated or touched for a stream we cannot buffer.
    let slot_bytes = ring_slot_bytes(&header, cfg.ring_slots)?;
    // Then the lock, before reading or moving anything in out_dir: a second daemon on
    // the same directory would append to the same log and replace the sockets.
    let _lock = lock_out_dir(&opts.out_dir)?;
    // Descriptors held back for the final cloud and report, released just before
    // they are written, so that clients exhausting the limit cannot lose the scan.
    let mut reserve = FdReserve::new(RESERVED_FDS);
    let (scan, resumed_scan) = open_scan(&opts, header.width, header.height)?;
    let resumed = resume_scan(&scan, resumed_scan, header.width, header.height)?;
    let resumed_frames = resumed.frames.len() as u64;
    // Sockets first, so a bad address fails before any work.
    let none_if_empty = |s: &str| (!s.is_empty()).then(|| s.to_string());
    let endpoints = net::Endpoints {
        stream_tcp: none_if_empty(&cfg.stream_tcp),
        stream_unix: none_if_empty(&cfg.stream_unix).map(PathBuf::from),
        status_unix: none_if_empty(&cfg.status_socket).map(PathBuf::from),
        max_clients: cfg.stream_clients_max,
    };
    let listeners = net::bind(&endpoints)?;
    if let Some(addr) = listeners.tcp_addr {
        tracing::info!(%addr, "cloud stream listening");
    }
    let web_listener = match opts.http_listener.take() {
        Some(l) => Some(web::from_std(l)?),
        None => none_if_empty(&cfg.http_listen)
            .map(|a| web::bind(&a))
            .transpose()?,
    };
    if let Some(l) = &web_listener {
        tracing::info!("live view at http://{}/", l.addr);
    }
    let hello = serde_json::json!({
        "width": header.width,
        "height": header.height,
        "scan": scan.id,
        "daemon": concat!("crossline ", env!("CARGO_PKG_VERSION")),
    })
    .to_string();
    let hub = Arc::new(net::Hub::new(
        &hello,
        cfg.client_queue_mib.saturating_mul(1 << 20),
        started,
    ));
    let feed = Arc::new(net::StatusFeed::new());
    let net_stop = Arc::new(tokio::sync::Notify::new());
    let shared = Arc::new(Shared::default());
    let notifier = notify::Notifier::from_env();

    let workers = if cfg.workers == 0 {
        std::thread::available_parallelism().map_or(1, |n| n.get())
    } else {
        cfg.workers
    }
    .min(MAX_WORKERS);
    let (producer, consumer) = ring::ring(cfg.ring_slots.max(2), slot_bytes);
    let (result_tx, result_rx) = bounded::<Extracted>(2 * workers + 2);
    let live_background = Arc::new(LiveBackground::for_scan(
        Policy::new(&opts.config.background)?,
        &header,
        &scan.state.join("samples"),
        resumed.background.clone(),
        resumed_frames,
    ));
    let mut solver = Incremental::new(
        opts.camera.clone(),
        opts.config.clone(),
        IncrementalParams {
            min_planes_first_solve: cfg.min_planes_first_solve,
            solve_growth: cfg.solve_growth,
        },
        opts.scale.clone(),
    );
    if let Some(bg) = &resumed.background {
        solver.set_colour_source(Arc::new(bg.clone()));
    }
    let mut checkpoint = Checkpoint::new(CheckpointWriter::open(
        &scan.state,
        header.width,
        header.height,
        seconds(cfg.checkpoint_interval_s, 0.05, 86_400.0),
    )?);
    // Replay the checkpointed frames into the solver (no sending: nobody listens yet).
    let mut start_position = 0;
    for f in resumed.frames {
        start_position = f.source_position + 1;
        let _ = solver.add_frame(f.curves, 0);
    }
    shared
        .frames_processed
        .store(resumed_frames, Ordering::Relaxed);
    if start_position > 0 {
        source.seek(start_position).map_err(|e| ServeError::Io {
            what: "cannot resume in",
            path: PathBuf::from(&opts.input_id),
            source: std::io::Error::other(e.to_string()),
        })?;
    }
    let workers_stop = Arc::new(AtomicBool::new(false));
    let capture_error: Arc<Mutex<Option<String>>> = Arc::new(Mutex::new(None));

    let mut report = None;
    let capture_done = Arc::new(AtomicBool::new(false));
    let scope_result: Result<(), ServeError> = std::thread::scope(|s| {
        // Sockets.
        let net_handle = {
            let (hub, feed, net_stop) = (hub.clone(), feed.clone(), net_stop.clone());
            let drain = seconds(cfg.drain_timeout_s, 0.0, 3600.0);
            std::thread::Builder::new()
                .name("net".into())
                .spawn_scoped(s, move || listeners.serve(hub, feed, net_stop, drain))
                .map_err(|source| ServeError::Thread {
                    name: "net".into(),
                    source,
                })?
        };
        // The live view.
        let web_stop = Arc::new(tokio::sync::Notify::new());
        let web_handle = match web_listener {
            Some(l) => {
                let ctx = web::WebContext {
                    hub: hub.clone(),
                    status: feed.clone(),
                    camera: opts.camera.clone(),
                    max_clients: cfg.http_clients_max,
                };
                let (web_stop, drain) =
                    (web_stop.clone(), seconds(cfg.drain_timeout_s, 0.0, 3600.0));
                let h = std::thread::Builder::new()
                    .name("web".into())
                    .spawn_scoped(s, move || l.serve(ctx, web_stop, drain))
                    .map_err(|source| ServeError::Thread {
                        name: "web".into(),
                        source,
                    })?;
                Some(h)
            }
            None => None,
        };

        // Capture.
        let recorder = opts.record.then(|| Recorder {
            dir: scan.recordings.clone(),
            scan: scan.id.clone(),
            header: header.clone(),
            rotate_bytes: cfg.record_rotate_mib.max(1) << 20,
            part: 0,
            writer: None,
        });
        let capture = threads::Capture {
            shared: &shared,
            stop: &stop,
            first_index: resumed_frames,
            started,
            error: &capture_error,
            background: &live_background,
            done: &capture_done,
        };
        capture.spawn(s, source.as_mut(), producer, recorder)?;

        // Workers.
        let ctx = threads::WorkerContext {
            header: &header,
            camera: &opts.camera,
            params: &opts.config.extract,
            shared: &shared,
            background: &live_background,
            stop: &workers_stop,
        };
        threads::spawn_workers(s, workers, &consumer, &result_tx, ctx)?;
        drop(consumer);
        drop(result_tx);

        // Status.
        let status_stop = Arc::new(AtomicBool::new(false));
        {
            let (shared, feed, hub, status_stop) = (
                shared.clone(),
                feed.clone(),
                hub.clone(),
                status_stop.clone(),
            );
            let interval = Duration::from_millis(cfg.status_interval_ms.clamp(50, 3_600_000));
            let scan_id = scan.id.clone();
            let notifier = &notifier;
            let capture_done = capture_done.clone();
            std::thread::Builder::new()
                .name("status".into())
                .spawn_scoped(s, move || {
                    let st = threads::StatusThread {
                        shared: &shared,
                        hub: &hub,
                        feed: &feed,
                        notifier,
                        scan_id: &scan_id,
                        started,
                        interval,
                    };
                    st.run(&status_stop, &capture_done)
                })
                .map_err(|source| ServeError::Thread {
                    name: "status".into(),
                    source,
                })?;
        }

        // Solver, on this thread. It owns the results' receiver: should it end early,
        // the workers' sends fail and they end too, instead of waiting for ever.
        let results = result_rx;
        solver_loop(
            &mut solver,
            &results,
            &mut checkpoint,
            &scan,
            &live_background,
            &hub,
            &feed,
            &shared,
            resumed_frames,
        );
        drop(results);
        workers_stop.store(true, Ordering::Relaxed);
        let outcome = finish(
            &mut solver,
            &mut checkpoint,
            &mut reserve,
            &scan,
            &hub,
            &feed,
            &shared,
            &opts,
        );
        notifier.notify("STOPPING=1");
        net_stop.notify_one();
        web_stop.notify_one();
        status_stop.store(true, Ordering::Relaxed);
        let _ = net_handle.join();
        if let Some(h) = web_handle {
            let _ = h.join();
        }
        report = Some(outcome);
        Ok(())
    });
    scope_result?;
    let (points, rec, solve_error) = match report {
        Some(r) => r?,
        None => (0, None, None),
    };
    // The scan is finished: its state moves beside its cloud.
    let done_state = opts.out_dir.join(format!("{}.state", scan.id));
    let _ = std::fs::remove_dir_all(&done_state);
    if let Err(e) = std::fs::rename(&scan.state, &done_state) {
        tracing::warn!("cannot move {} aside: {e}", scan.state.display());
    }
    let report = ServeReport {
        resumed_frames,
        epochs: solver.epoch(),
        cloud: scan.cloud.clone(),
        points,
        cpu_seconds: cpu_seconds() - cpu_start,
        capture_error: lock(&capture_error).clone(),
        checkpoint_error: checkpoint.error().map(str::to_string),
        reconstruction: rec,
        solve_error,
        ..ServeReport::counted(&scan.id, &opts.input_id, &shared, &hub, started)
    };
    if report.decode_errors > 0 {
        tracing::warn!(
            "{} of {} frames could not be decoded and were skipped",
            report.decode_errors,
            report.frames_in
        );
    }
    let text = serde_json::to_string_pretty(&report).unwrap_or_default();
    write_atomic(&scan.report, text.as_bytes())?;
    Ok(report)
}

/// Extraction threads at most, whatever `[serve] workers` or `--workers` say.
pub const MAX_WORKERS: usize = 256;
/// Largest ring (slots × slot size) the daemon allocates.
pub const MAX_RING_BYTES: usize = 4 << 30;
/// File descriptors held back for writing the final cloud and report.
pub const RESERVED_FDS: usize = 16;

/// `secs` clamped to `lo..=hi` (NaN to `lo`) as a duration: the config's bounds are
/// checked when a file is parsed, but a `ServeConfig` may be built in code.
fn seconds(secs: f64, lo: f64, hi: f64) -> Duration {
    let s = if secs.is_nan() {
        lo
    } else {
        secs.clamp(lo, hi)
    };
    Duration::try_from_secs_f64(s).unwrap_or(Duration::from_secs_f64(lo))
}

/// Open files kept only to be closed when they are needed (see [`RESERVED_FDS`]).
struct FdReserve(Vec<std::fs::File>);

impl FdReserve {
    fn new(n: usize) -> Self {
        Self(
            (0..n)
                .filter_map(|_| std::fs::File::open("/dev/null").ok())
                .collect(),
        )
    }

    fn release(&mut self) {
        self.0.clear();
    }
}

/// Takes the exclusive lock of `out_dir` (`out_dir/lock`, holding the owner's pid),
/// for as long as the returned file lives.
fn lock_out_dir(out_dir: &Path) -> Result<std::fs::File, ServeError> {
    use std::io::{Read, Seek, Write};
    let path = out_dir.join("lock");
    let io = |what| {
        let path = path.clone();
        move |source| ServeError::Io { what, path, source }
    };
    std::fs::create_dir_all(out_dir).map_err(io("cannot create the directory of"))?;
    let mut file = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .create(true)
        .truncate(false)
        .open(&path)
        .map_err(io("cannot open"))?;
    match file.try_lock() {
        Ok(()) => {}
        Err(std::fs::TryLockError::WouldBlock) => {
            let mut pid = String::new();
            let _ = file.read_to_string(&mut pid);
            let pid = crate::truncate_echo(pid.trim());
            return Err(ServeError::Busy {
                path: out_dir.to_path_buf(),
                pid: if pid.is_empty() {
                    "unknown".into()
                } else {
                    pid
                },
            });
        }
        Err(std::fs::TryLockError::Error(e)) => return Err(io("cannot lock")(e)),
    }
    file.set_len(0).map_err(io("cannot write"))?;
    file.rewind().map_err(io("cannot write"))?;
    writeln!(file, "{}", std::process::id()).map_err(io("cannot write"))?;
    Ok(file)
}

fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), ServeError> {
    let tmp = path.with_extension("tmp");
    let io = |what| {
        move |source| ServeError::Io {
            what,
            path: path.to_path_buf(),
            source,
        }
    };
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(io("cannot create the folder of"))?;
    }
    std::fs::write(&tmp, bytes).map_err(io("cannot write"))?;
    std::fs::rename(&tmp, path).map_err(io("cannot write"))
}

/// Process CPU time (user + system), seconds.
pub fn cpu_seconds() -> f64 {
    // /proc/self/stat fields 14 and 15: utime and stime in clock ticks (100 Hz on
    // every Linux configuration that matters here).
    std::fs::read_to_string("/proc/self/stat")
        .ok()
        .and_then(|s| {
            let rest = &s[s.rfind(')')? + 2..];
            let f: Vec<&str> = rest.split(' ').collect();
            let ut: f64 = f.get(11)?.parse().ok()?;
            let st: f64 = f.get(12)?.parse().ok()?;
            Some((ut + st) / 100.0)
        })
        .unwrap_or(0.0)
}

#[allow(clippy::too_many_arguments)]
fn solver_loop(
    solver: &mut Incremental,
    results: &Receiver<Extracted>,
    checkpoint: &mut Checkpoint,
    scan: &ScanFiles,
    background: &LiveBackground,
    hub: &net::Hub,
    feed: &net::StatusFeed,
    shared: &Shared,
    first_index: u64,
) {
    let mut pending: BTreeMap<u64, Extracted> = BTreeMap::new();
    let mut next = first_index;
    let mut background_saved = false;
    let mut epoch_seen = solver.epoch();
    if epoch_seen > 0 {
        // A resumed scan with a solution already: the stream starts from it.
        hub.begin_epoch(epoch_seen, EpochReason::First);
    }
    loop {
        shared.solver_beats.fetch_add(1, Ordering::Relaxed);
        match results.recv_timeout(Duration::from_millis(100)) {
            Ok(e) => {
                pending.insert(e.meta.index, e);
            }
            Err(RecvTimeoutError::Timeout) => continue,
            Err(RecvTimeoutError::Disconnected) => {
                if !pending.is_empty() {
                    tracing::warn!(
                        "{} frames after a gap at frame {next} were not processed",
                        pending.len()
                    );
                }
                break;
            }
        }
        while let Some(e) = pending.remove(&next) {
            if !background_saved {
                if let Some(bg) = background.first() {
                    if !scan.state.join("background.png").exists() {
                        checkpoint.save_background(&scan.state, bg.image());
                    }
                    solver.set_colour_source(Arc::new(bg.image().clone()));
                    background_saved = true;
                }
            }
            if !e.curves.is_empty() {
                shared.frames_with_laser.fetch_add(1, Ordering::Relaxed);
            }
            checkpoint.append(&FrameCurves {
                index: e.meta.index,
                source_position: e.meta.source_position,
                sequence: e.meta.sequence,
                timestamp_nanos: e.meta.timestamp_nanos,
                curves: e.curves.clone(),
            });
            let t = Instant::now();
            let out = solver.add_frame(e.curves, e.meta.received_nanos);
            if let Some((epoch, reason)) = out.epoch {
                hub.begin_epoch(epoch, reason);
                tracing::info!(
                    epoch,
                    planes = solver.counts.planes,
                    "new epoch of the cloud"
                );
                feed.publish(status::event_line("epoch", &format!("epoch {epoch}")));
                epoch_seen = epoch;
            }
            if !out.points.is_empty() {
                hub.push_points(stream::points(epoch_seen, out.captured_nanos, &out.points));
            }
            shared.frames_processed.fetch_add(1, Ordering::Relaxed);
            *lock(&shared.solver) = solver.counts;
            let mut times = lock(&shared.solver_frame_micros);
            if times.len() < 1 << 20 {
                times.push(t.elapsed().as_micros() as u64);
            }
            drop(times);
            tracing::trace!(frame = e.meta.index, "frame processed");
            next += 1;
        }
    }
    checkpoint.sync();
}

type Finished = (
    usize,
    Option<crate::reconstruct::ReconstructReport>,
    Option<String>,
);

#[allow(clippy::too_many_arguments)]
fn finish(
    solver: &mut Incremental,
    checkpoint: &mut Checkpoint,
    reserve: &mut FdReserve,
    scan: &ScanFiles,
    hub: &net::Hub,
    feed: &net::StatusFeed,
    shared: &Shared,
    opts: &ServeOptions,
) -> Result<Finished, ServeError> {
    checkpoint.sync();
    *lock(&shared.live_solver) = solver.counts;
    feed.publish(status::event_line(
        "final_solve",
        "capture stopped; final solve",
    ));
    let (cloud, rec, err) = match solver.finish() {
        Ok(rec) => (rec.cloud, Some(rec.report), None),
        Err(e) => {
            let msg = anyhow_like(&e);
            tracing::warn!("final solve: {msg}; writing an empty cloud");
            // A refused cloud still has the report of what the solve found.
            let report = match e {
                crate::reconstruct::ReconstructError::Pipeline(
                    crate::pipeline::PipelineError::Refused { report, .. },
                ) => Some(*report),
                _ => None,
            };
            (
                crate::ply::Cloud {
                    colors: Some(Vec::new()),
                    frames: Some(Vec::new()),
                    lasers: Some(Vec::new()),
                    ..Default::default()
                },
                report,
                Some(msg),
            )
        }
    };
    // The descriptors held back are released only now, for the cloud and the report:
    // released before the final solve, clients waiting to be accepted took them.
    reserve.release();
    if let Some(dir) = scan.cloud.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|source| ServeError::Io {
            what: "cannot create",
            path: dir.to_path_buf(),
            source,
        })?;
    }
    let comments = vec![
        format!("crossline serve scan {}", scan.id),
        format!("input {}", opts.input_id),
        "camera frame, OpenCV axes; one global scale (see the report's scale_mode)".to_string(),
    ];
    if crate::e57::is_e57(&scan.cloud) {
        let meta = crate::e57::ScanMeta {
            name: scan.id.clone(),
            description: format!("crossline serve; {}; scale {:?}", opts.input_id, opts.scale),
            sensor_model: Some(format!(
                "{} at {}x{}",
                opts.input_id, opts.camera.width, opts.camera.height
            )),
            // The capture has just stopped.
            acquisition_end: Some(std::time::SystemTime::now()),
            coordinate_metadata: Some(comments[2].clone()),
            ..Default::default()
        };
        crate::e57::write_e57_atomic(&scan.cloud, &cloud, &meta)?;
    } else {
        crate::ply::write_ply_atomic(&scan.cloud, &cloud, &comments)?;
    }
    tracing::info!(
        points = cloud.len(),
        "cloud written to {}",
        scan.cloud.display()
    );
    hub.begin_epoch(solver.epoch(), EpochReason::Final);
    hub.push_points(stream::points(
        solver.epoch(),
        0,
        &stream::points_of(&cloud, 0..cloud.len()),
    ));
    hub.end(cloud.len() as u64);
    *lock(&shared.solver) = solver.counts;
    Ok((cloud.len(), rec, err))
}

/// An error with its chain of causes, one line.
fn anyhow_like(e: &dyn std::error::Error) -> String {
    let mut s = e.to_string();
    let mut src = e.source();
    while let Some(c) = src {
        s.push_str(": ");
        s.push_str(&c.to_string());
        src = c.source();
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::capture::dump::DumpReader;

    #[test]
    fn a_loss_shorter_than_the_status_interval_still_gets_its_line() {
        let shared = Shared::default();
        let hub = net::Hub::new("{}", 1 << 20, Instant::now());
        shared
            .device_state
            .store(DeviceState::Streaming as u8, Ordering::Relaxed);
        let st = Status::gather(&shared, &hub, "scan", Instant::now());
        let devices = |lines: Vec<Status>| lines.iter().map(|l| l.device).collect::<Vec<_>>();
        assert_eq!(devices(status_lines(&st, false)), [DeviceState::Streaming]);
        // Lost and back between two lines: both are told, in order.
        assert_eq!(
            devices(status_lines(&st, true)),
            [DeviceState::Lost, DeviceState::Streaming]
        );
        // Still lost: one line says so.
        shared
            .device_state
            .store(DeviceState::Lost as u8, Ordering::Relaxed);
        let st = Status::gather(&shared, &hub, "scan", Instant::now());
        assert_eq!(devices(status_lines(&st, true)), [DeviceState::Lost]);
    }

    #[test]
    fn recordings_rotate_by_size_and_keep_every_frame() {
        let dir = tempfile::tempdir().expect("tempdir");
        let shared = Shared::default();
        let header = DumpHeader {
            fourcc: *b"MJPG",
            width: 64,
            height: 48,
            bytes_per_line: 0,
            interval_num: 1,
            interval_den: 30,
            device: "/dev/video0".into(),
            card: "test".into(),
        };
        let mut rec = Recorder {
            dir: dir.path().join("recordings"),
            scan: "scan".into(),
            header: header.clone(),
            rotate_bytes: 250_000,
            part: 0,
            writer: None,
        };
        let payload = |i: u32| vec![(i % 251) as u8; 100_000];
        for i in 0..10u32 {
            rec.write(&shared, 100 + i, u64::from(i) * 33_000_000, 0, &payload(i));
        }
        if let Some(w) = rec.writer.take() {
            w.finish().expect("finish");
        }
        let mut files: Vec<PathBuf> = std::fs::read_dir(dir.path().join("recordings"))
            .expect("recordings")
            .map(|e| e.expect("entry").path())
            .collect();
        files.sort();
        assert_eq!(files.len(), 4, "3 frames per 250 kB file: {files:?}");
        let mut seq = Vec::new();
        for f in &files {
            let mut r = DumpReader::open(f).expect("a whole dump");
            assert_eq!(r.header(), &header);
            while let Some(record) = r.next_record().expect("record") {
                assert_eq!(record.payload, payload(record.sequence - 100));
                seq.push(record.sequence);
            }
        }
        assert_eq!(
            seq,
            (100..110).collect::<Vec<_>>(),
            "every frame once, in order"
        );
        let total: u64 = files
            .iter()
            .map(|f| std::fs::metadata(f).expect("meta").len())
            .sum();
        assert_eq!(
            shared.recording_bytes.load(Ordering::Relaxed) + 4 * header_len(&header),
            total
        );
    }

    fn header_len(h: &DumpHeader) -> u64 {
        (42 + 2 + h.device.len() + h.card.len() + 4) as u64
    }

    #[test]
    fn a_second_daemon_on_the_same_out_dir_is_refused_naming_the_first() {
        let dir = tempfile::tempdir().expect("tempdir");
        let held = lock_out_dir(dir.path()).expect("first");
        let err = lock_out_dir(dir.path()).expect_err("second");
        let msg = err.to_string();
        assert!(
            msg.contains(&format!("pid {}", std::process::id())),
            "{msg}"
        );
        drop(held);
        lock_out_dir(dir.path()).expect("free again once the first is gone");
    }

    #[test]
    fn durations_from_the_config_never_panic() {
        for s in [f64::INFINITY, 1e300, -1.0, f64::NAN, f64::NEG_INFINITY] {
            let d = seconds(s, 0.05, 86_400.0);
            assert!(d >= Duration::from_millis(50) && d <= Duration::from_secs(86_400));
        }
    }
}
