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
mod epoch;
pub mod incremental;
mod listeners;
pub mod net;
pub mod notify;
mod scan;
mod solver;
pub mod status;
pub mod stream;
mod threads;
pub mod web;

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicU8, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use crossbeam_channel::bounded;
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
use checkpoint::{Checkpoint, CheckpointWriter};
use incremental::{Incremental, IncrementalParams, SolverCounts};
use listeners::Listeners;
use scan::{FdReserve, ScanFiles};
use status::{DeviceState, Status};

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
    pub epoch_duty: f64,
    pub status_socket: String,
    pub status_interval_ms: u64,
    pub stream_tcp: String,
    pub stream_unix: String,
    pub client_queue_mib: usize,
    pub stream_send_buffer_kib: usize,
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
            solve_growth: 3.0,
            epoch_duty: 0.3,
            status_socket: "/run/crossline/status.sock".into(),
            status_interval_ms: 1000,
            stream_tcp: "127.0.0.1:7878".into(),
            stream_unix: String::new(),
            client_queue_mib: 64,
            stream_send_buffer_kib: 256,
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
    /// How decoding the stream's buffers rebuilds their chroma, from the first whose
    /// bytes say ([`crate::capture::chroma`]); set before that frame is extracted, so
    /// every frame is extracted knowing it, whichever worker decoded it.
    pub chroma: std::sync::OnceLock<[crate::capture::chroma::Rebuild; 2]>,
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
    /// From the last frame's capture to the final cloud written, seconds.
    pub final_cloud_after_last_frame_s: Option<f64>,
    /// From a frame's capture to its points written to a stream client's socket, for
    /// the frames placed on arrival against the current epoch
    /// (`live_solver.frames_placed_on_arrival` counts them).
    pub latency: net::Latency,
    /// From the capture of the newest frame an epoch's cloud holds (or a frame placed
    /// late against it, from its backlog) to those points written to the socket.
    pub epoch_latency: net::Latency,
    /// Time the solver thread spent per frame (crossings, placing planes,
    /// triangulating, adopting a new epoch).
    pub solver_frame: net::Latency,
    /// The live solver's last counts (before the final solve) and time per phase.
    pub live_solver: SolverCounts,
    pub stream_clients_total: u64,
    pub stream_resyncs: u64,
    /// Stream clients and live-view pages dropped: fallen behind twice, or still
    /// holding unsent stream when the drain (`[serve] drain_timeout_s`) ended.
    pub stream_dropped_clients: u64,
    pub cpu_seconds: f64,
    pub wall_seconds: f64,
    /// The process's CPU time and the wall time from the start until the last frame was
    /// processed, before the final solve: the load of live capture itself.
    pub live_cpu_seconds: f64,
    pub live_wall_seconds: f64,
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
            final_cloud_after_last_frame_s: None,
            latency: hub.stats.latency(),
            epoch_latency: hub.stats.epoch_latency(),
            solver_frame: net::Latency::of_micros(lock(&shared.solver_frame_micros).clone()),
            live_solver: *lock(&shared.live_solver),
            stream_clients_total: hub.stats.clients_total.load(Ordering::Relaxed),
            stream_resyncs: hub.stats.resyncs.load(Ordering::Relaxed),
            stream_dropped_clients: hub.stats.dropped_clients.load(Ordering::Relaxed),
            cpu_seconds: 0.0,
            wall_seconds: started.elapsed().as_secs_f64(),
            live_cpu_seconds: 0.0,
            live_wall_seconds: 0.0,
            capture_error: None,
            checkpoint_error: None,
            reconstruction: None,
            solve_error: None,
        }
    }
}

/// Version of [`ServeReport`]'s JSON. 2: `latency` counts only frames placed on
/// arrival, `epoch_latency` and `final_cloud_after_last_frame_s` are new, and `live_solver` has `place_s`,
/// `frames_placed_on_arrival` and `frames_placed_late` instead of `extend_s` and
/// `triangulate_s`. 3: `live_cpu_seconds` and `live_wall_seconds` are new.
pub const REPORT_VERSION: u32 = 3;

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
    /// A recording of the scan's raw buffers into `out_dir/recordings/<scan>-NNN.dump`,
    /// a new part every `[serve] record_rotate_mib`.
    fn new(scan: &ScanFiles, header: &DumpHeader, cfg: &ServeConfig) -> Self {
        Self {
            dir: scan.recordings.clone(),
            scan: scan.id.clone(),
            header: header.clone(),
            rotate_bytes: cfg.record_rotate_mib.max(1) << 20,
            part: 0,
            writer: None,
        }
    }

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
    let (started, cpu_start) = (Instant::now(), cpu_seconds());
    let cfg = opts.config.serve.clone();
    let header = source.header().clone();
    // Sizes first: nothing is allocated or touched for a stream we cannot buffer.
    let slot_bytes = check_stream(&header, &opts)?;
    // Then the lock, before reading or moving anything in out_dir: a second daemon on
    // the same directory would append to the same log and replace the sockets.
    let _lock = scan::lock_out_dir(&opts.out_dir)?;
    // Descriptors held back for the final cloud and report, released just before
    // they are written, so that clients exhausting the limit cannot lose the scan.
    let mut reserve = FdReserve::new(RESERVED_FDS);
    let (scan, resuming) = scan::open_scan(&opts, header.width, header.height)?;
    let resumed = scan::resume_scan(&scan, resuming, header.width, header.height)?;
    let resumed_frames = resumed.frames.len() as u64;
    // Sockets before any work, so that a bad address fails first.
    let http = opts.http_listener.take();
    let listeners = Listeners::bind(&cfg, http, &header, &scan.id, started)?;
    let (hub, feed) = (listeners.hub.clone(), listeners.feed.clone());
    let shared = Shared::default();
    let (background, mut solver, mut checkpoint) =
        restore(&opts, &header, &scan, resumed, source.as_mut(), &shared)?;
    let workers = worker_count(cfg.workers);
    let (producer, consumer) = ring::ring(cfg.ring_slots.max(2), slot_bytes);
    let (result_tx, result_rx) = bounded::<Extracted>(2 * workers + 2);
    let notifier = notify::Notifier::from_env();
    let flags = threads::Flags::default();
    let pipeline = threads::Pipeline {
        opts: &opts,
        header: &header,
        scan: &scan,
        shared: &shared,
        background: &background,
        hub: &hub,
        feed: &feed,
        notifier: &notifier,
        stop: &stop,
        flags: &flags,
        started,
        first_index: resumed_frames,
    };
    let mut live_load = (0.0, 0.0);
    let outcome = std::thread::scope(|s| {
        // Should a thread fail to start, `serving` is dropped and stops the listeners.
        let serving = listeners.spawn(s, &opts.camera, &cfg)?;
        let ring = (producer, consumer);
        pipeline.start(s, source.as_mut(), ring, result_tx, workers)?;
        // The solver runs on this thread. It owns the results' receiver: should it end
        // early, the workers' sends fail and they end too, instead of waiting for ever.
        let live = solver::Live {
            hub: &hub,
            feed: &feed,
            shared: &shared,
            scan: &scan,
        };
        live.run(
            &mut solver,
            result_rx,
            &mut checkpoint,
            &background,
            resumed_frames,
        );
        live_load = (cpu_seconds() - cpu_start, started.elapsed().as_secs_f64());
        flags.workers_stop.store(true, Ordering::Relaxed);
        let outcome = live.finish(&mut solver, &mut checkpoint, &mut reserve, &opts);
        notifier.notify("STOPPING=1");
        serving.stop();
        flags.status_stop.store(true, Ordering::Relaxed);
        outcome
    });
    let finished = outcome?;
    let report = ServeReport {
        resumed_frames,
        epochs: solver.epoch(),
        cloud: scan.cloud.clone(),
        points: finished.points,
        final_cloud_after_last_frame_s: finished.after_last_frame_s,
        cpu_seconds: cpu_seconds() - cpu_start,
        live_cpu_seconds: live_load.0,
        live_wall_seconds: live_load.1,
        capture_error: lock(&flags.capture_error).clone(),
        checkpoint_error: checkpoint.error().map(str::to_string),
        reconstruction: finished.reconstruction,
        solve_error: finished.solve_error,
        ..ServeReport::counted(&scan.id, &opts.input_id, &shared, &hub, started)
    };
    scan::close(&scan, &opts.out_dir, &report)?;
    Ok(report)
}

/// The ring slot's size for `header`, once the stream is known to fit the camera file
/// and the extraction settings are valid.
fn check_stream(header: &DumpHeader, opts: &ServeOptions) -> Result<usize, ServeError> {
    if (header.width, header.height) != (opts.camera.width, opts.camera.height) {
        return Err(ServeError::Size {
            got_w: header.width,
            got_h: header.height,
            want_w: opts.camera.width,
            want_h: opts.camera.height,
        });
    }
    Extractor::new(&opts.config.extract, &opts.camera)?;
    ring_slot_bytes(header, opts.config.serve.ring_slots)
}

/// `[serve] workers` (0: one per core), at most [`MAX_WORKERS`].
fn worker_count(configured: usize) -> usize {
    let n = if configured == 0 {
        std::thread::available_parallelism().map_or(1, |n| n.get())
    } else {
        configured
    };
    n.min(MAX_WORKERS)
}

/// A scan's state for its threads, from its checkpoint if it is resumed: the rolling
/// background (its kept samples read back), the solver with the checkpointed frames
/// replayed into it (nobody listens yet, so nothing is sent) and `source` moved past
/// them, and the checkpoint that goes on from there.
fn restore(
    opts: &ServeOptions,
    header: &DumpHeader,
    scan: &ScanFiles,
    resumed: checkpoint::Resumed,
    source: &mut dyn FrameSource,
    shared: &Shared,
) -> Result<(LiveBackground, Incremental, Checkpoint), ServeError> {
    let frames = resumed.frames.len() as u64;
    let policy = Policy::new(&opts.config.background)?;
    let samples = scan.state.join("samples");
    let saved = resumed.background.clone();
    let background = LiveBackground::for_scan(policy, header, &samples, saved, frames);
    let params = IncrementalParams {
        min_planes_first_solve: opts.config.serve.min_planes_first_solve,
        solve_growth: opts.config.serve.solve_growth,
        epoch_duty: opts.config.serve.epoch_duty,
    };
    let camera = opts.camera.clone();
    let mut solver = Incremental::new(camera, opts.config.clone(), params, opts.scale.clone());
    if let Some(bg) = resumed.background {
        solver.set_colour_source(Arc::new(bg));
    }
    let mut start_position = 0;
    for f in resumed.frames {
        start_position = f.source_position + 1;
        let _ = solver.add_frame(f.curves, 0);
    }
    shared.frames_processed.store(frames, Ordering::Relaxed);
    if start_position > 0 {
        source.seek(start_position).map_err(|e| ServeError::Io {
            what: "cannot resume in",
            path: PathBuf::from(&opts.input_id),
            source: std::io::Error::other(e.to_string()),
        })?;
    }
    let interval = seconds(opts.config.serve.checkpoint_interval_s, 0.05, 86_400.0);
    let writer = CheckpointWriter::open(&scan.state, header.width, header.height, interval)?;
    Ok((background, solver, Checkpoint::new(writer)))
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
    fn durations_from_the_config_never_panic() {
        for s in [f64::INFINITY, 1e300, -1.0, f64::NAN, f64::NEG_INFINITY] {
            let d = seconds(s, 0.05, 86_400.0);
            assert!(d >= Duration::from_millis(50) && d <= Duration::from_secs(86_400));
        }
    }
}
