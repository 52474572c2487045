//! The capture thread, the extraction workers and the status thread of [`super::run`]:
//! frames from the source into the ring (never waiting on the workers, except in a
//! lossless replay), and from the ring through decoding, the background policy
//! ([`super::background`]) and extraction to the solver; [`Pipeline::start`] starts
//! them together.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Mutex;
use std::time::{Duration, Instant};

use crossbeam_channel::Sender;
use image::RgbImage;

use super::background::{self, LiveBackground};
use super::listeners::{spawn_named, spawn_sized};
use super::scan::ScanFiles;
use super::status::{DeviceState, Status};
use super::{
    lock, net, notify, status_lines, Extracted, Recorder, ServeError, ServeOptions, Shared,
    WORKER_STACK_BYTES,
};
use crate::camera::Camera;
use crate::capture::chroma;
use crate::capture::dump::{decode_rgb, DumpHeader};
use crate::capture::{CaptureError, FrameSource, Next};
use crate::extract::{Background, Curve, ExtractParams, Extractor, Presence};
use crate::ring::{self, FrameMeta, Recv, Slot};

/// The flags the threads of one run are stopped and watched by.
#[derive(Default)]
pub(super) struct Flags {
    /// Set when the solver has ended: the workers give up parked frames.
    pub workers_stop: AtomicBool,
    pub status_stop: AtomicBool,
    /// Set when capture has ended.
    pub capture_done: AtomicBool,
    /// Why capture stopped, if a source failed.
    pub capture_error: Mutex<Option<String>>,
    /// The one-time warnings of extraction, which every worker counts into.
    pub warnings: Presence,
}

/// What the capture, worker and status threads of one run read, all owned by
/// [`super::run`] for the threads' scope.
pub(super) struct Pipeline<'a> {
    pub opts: &'a ServeOptions,
    pub header: &'a DumpHeader,
    pub scan: &'a ScanFiles,
    pub shared: &'a Shared,
    pub background: &'a LiveBackground,
    pub hub: &'a net::Hub,
    pub feed: &'a net::StatusFeed,
    pub notifier: &'a notify::Notifier,
    /// Set by the caller (a signal) or the end of a replay: capture stops.
    pub stop: &'a AtomicBool,
    pub flags: &'a Flags,
    pub started: Instant,
    /// The number the first frame gets (a resumed scan goes on counting).
    pub first_index: u64,
}

impl<'env> Pipeline<'env> {
    /// Starts `capture` (reading `source` into `producer`), `workers` extraction
    /// threads (from `consumer` to `results`) and `status`, in `s`. Should one fail to
    /// start, those already running are told to stop, so that the scope can end.
    pub(super) fn start<'scope>(
        &self,
        s: &'scope std::thread::Scope<'scope, 'env>,
        source: &'env mut dyn FrameSource,
        (producer, consumer): (ring::Producer, ring::Consumer),
        results: Sender<Extracted>,
        workers: usize,
    ) -> Result<(), ServeError> {
        let started = self.spawn_all(s, source, producer, consumer, results, workers);
        if started.is_err() {
            for flag in [self.stop, &self.flags.workers_stop, &self.flags.status_stop] {
                flag.store(true, Ordering::Relaxed);
            }
        }
        started
    }

    fn spawn_all<'scope>(
        &self,
        s: &'scope std::thread::Scope<'scope, 'env>,
        source: &'env mut dyn FrameSource,
        producer: ring::Producer,
        consumer: ring::Consumer,
        results: Sender<Extracted>,
        workers: usize,
    ) -> Result<(), ServeError> {
        let cfg = &self.opts.config.serve;
        let recorder = self
            .opts
            .record
            .then(|| Recorder::new(self.scan, self.header, cfg));
        let capture = Capture {
            shared: self.shared,
            stop: self.stop,
            first_index: self.first_index,
            started: self.started,
            error: &self.flags.capture_error,
            background: self.background,
            done: &self.flags.capture_done,
        };
        capture.spawn(s, source, producer, recorder)?;
        let ctx = WorkerContext {
            header: self.header,
            camera: &self.opts.camera,
            params: &self.opts.config.extract,
            shared: self.shared,
            background: self.background,
            stop: &self.flags.workers_stop,
            warnings: &self.flags.warnings,
        };
        spawn_workers(s, workers, &consumer, &results, ctx)?;
        let status = StatusThread {
            shared: self.shared,
            hub: self.hub,
            feed: self.feed,
            notifier: self.notifier,
            scan_id: &self.scan.id,
            started: self.started,
            interval: Duration::from_millis(cfg.status_interval_ms.clamp(50, 3_600_000)),
        };
        status.spawn(s, &self.flags.status_stop, &self.flags.capture_done)
    }
}

/// What the capture thread reads and tells.
pub(super) struct Capture<'a> {
    pub shared: &'a Shared,
    pub stop: &'a AtomicBool,
    /// The number the first frame gets (a resumed scan goes on counting).
    pub first_index: u64,
    pub started: Instant,
    /// Why capture stopped, if a source failed.
    pub error: &'a Mutex<Option<String>>,
    pub background: &'a LiveBackground,
    /// Set when capture has ended.
    pub done: &'a AtomicBool,
}

impl<'env> Capture<'env> {
    /// Spawns the `capture` thread in `s`: [`capture_loop`], then the frame count to the
    /// background policy.
    pub(super) fn spawn<'scope>(
        self,
        s: &'scope std::thread::Scope<'scope, 'env>,
        source: &'env mut dyn FrameSource,
        producer: ring::Producer,
        recorder: Option<Recorder>,
    ) -> Result<(), ServeError> {
        spawn_named(s, "capture", move || {
            let frames = capture_loop(source, producer, recorder, &self);
            self.background.end_at(frames);
            self.done.store(true, Ordering::Relaxed);
        })
        .map(drop)
    }
}

/// Frames from `source` into the ring until it ends or `stop`; returns how many were
/// numbered (published).
fn capture_loop(
    source: &mut dyn FrameSource,
    producer: ring::Producer,
    mut recorder: Option<Recorder>,
    ctx: &Capture<'_>,
) -> u64 {
    let Capture {
        shared,
        stop,
        first_index,
        started,
        error: capture_error,
        ..
    } = *ctx;
    let lossless = source.lossless();
    let mut index = first_index;
    let mut last_sequence: Option<u32> = None;
    shared
        .device_state
        .store(DeviceState::Streaming as u8, Ordering::Relaxed);
    while !stop.load(Ordering::Relaxed) {
        shared.capture_beats.fetch_add(1, Ordering::Relaxed);
        shared
            .ring_depth
            .store(producer.depth() as u64, Ordering::Relaxed);
        if let Some(warning) = source.take_warning() {
            *lock(&shared.last_error) = Some(warning);
        }
        let frame = match source.next(Duration::from_millis(100)) {
            Ok(Next::Frame(f)) => f,
            Ok(Next::Idle) => continue,
            Ok(Next::Lost(why)) => {
                tracing::warn!("camera lost: {why}; retrying");
                *lock(&shared.last_error) = Some(format!("device lost: {why}"));
                shared
                    .device_state
                    .store(DeviceState::Lost as u8, Ordering::Relaxed);
                shared.device_losses.fetch_add(1, Ordering::Relaxed);
                last_sequence = None;
                continue;
            }
            Ok(Next::Resumed) => {
                tracing::info!("camera back; the scan continues");
                shared
                    .device_state
                    .store(DeviceState::Streaming as u8, Ordering::Relaxed);
                continue;
            }
            Ok(Next::End) => break,
            Err(e) => {
                let msg = match &e {
                    CaptureError::Dump(d) => d.to_string(),
                    other => other.to_string(),
                };
                tracing::error!("capture stopped: {msg}");
                *lock(capture_error) = Some(msg.clone());
                *lock(&shared.last_error) = Some(msg);
                break;
            }
        };
        let received_nanos = started.elapsed().as_nanos() as u64;
        shared.frames_in.fetch_add(1, Ordering::Relaxed);
        if let Some(last) = last_sequence {
            let gap = frame.sequence.wrapping_sub(last).wrapping_sub(1);
            if gap > 0 && gap < 1 << 30 {
                shared
                    .frames_dropped_driver
                    .fetch_add(u64::from(gap), Ordering::Relaxed);
            }
        }
        last_sequence = Some(frame.sequence);
        if let Some(r) = recorder.as_mut() {
            r.write(
                shared,
                frame.sequence,
                frame.timestamp_nanos,
                frame.flags,
                frame.bytes,
            );
        }
        let slot = if lossless {
            let mut slot = None;
            while slot.is_none() && !stop.load(Ordering::Relaxed) {
                shared.capture_beats.fetch_add(1, Ordering::Relaxed);
                slot = producer.claim_timeout(Duration::from_millis(100));
            }
            slot
        } else {
            producer.try_claim()
        };
        let Some(mut slot): Option<Slot> = slot else {
            shared.frames_dropped_ring.fetch_add(1, Ordering::Relaxed);
            tracing::trace!(sequence = frame.sequence, "ring full: frame dropped");
            continue;
        };
        slot.fill(
            FrameMeta {
                index,
                sequence: frame.sequence,
                timestamp_nanos: frame.timestamp_nanos,
                flags: frame.flags,
                source_position: frame.position,
                received_nanos,
            },
            frame.bytes,
        );
        index += 1;
        if producer.publish(slot).is_err() {
            break;
        }
    }
    if let Some(w) = recorder.and_then(|r| r.writer) {
        let _ = w.finish();
    }
    shared
        .device_state
        .store(DeviceState::Stopped as u8, Ordering::Relaxed);
    index
}

/// What every extraction worker reads.
#[derive(Clone, Copy)]
pub(super) struct WorkerContext<'a> {
    pub header: &'a DumpHeader,
    pub camera: &'a Camera,
    pub params: &'a ExtractParams,
    pub shared: &'a Shared,
    pub background: &'a LiveBackground,
    /// Set when the solver has ended: parked frames are given up.
    pub stop: &'a AtomicBool,
    /// The one-time warnings every worker counts into.
    pub warnings: &'a Presence,
}

/// Spawns the extraction workers `extract-0..n` in `s`, each with its own end of the
/// ring and of the results' channel.
pub(super) fn spawn_workers<'scope, 'env>(
    s: &'scope std::thread::Scope<'scope, 'env>,
    n: usize,
    consumer: &ring::Consumer,
    results: &Sender<Extracted>,
    ctx: WorkerContext<'env>,
) -> Result<(), ServeError> {
    for w in 0..n {
        let (consumer, results) = (consumer.clone(), results.clone());
        let name = format!("extract-{w}");
        spawn_sized(s, &name, Some(WORKER_STACK_BYTES), move || {
            worker_loop(consumer, results, ctx)
        })?;
    }
    Ok(())
}

fn worker_loop(consumer: ring::Consumer, results: Sender<Extracted>, ctx: WorkerContext<'_>) {
    let WorkerContext {
        header,
        camera,
        params,
        shared,
        background,
        stop,
        warnings,
    } = ctx;
    let Ok(extractor) = Extractor::new(params, camera) else {
        return;
    };
    let mut extractor = extractor.sharing_warnings(warnings.clone());
    let send =
        |meta: FrameMeta, curves: Vec<Curve>| results.send(Extracted { meta, curves }).is_ok();
    let extract = |extractor: &mut Extractor, (meta, image, bg): background::Ready| {
        if let Some(&rebuild) = shared.chroma.get() {
            extractor.know_chroma(rebuild);
        }
        let curves = image.map_or_else(Vec::new, |i| extractor.extract(&i, &bg));
        send(meta, curves)
    };
    loop {
        while let Some(ready) = background.take_ready() {
            if !extract(&mut extractor, ready) {
                return;
            }
        }
        let slot = match consumer.recv_timeout(Duration::from_millis(100)) {
            Recv::Frame(s) => s,
            Recv::Idle => continue,
            Recv::Closed => break,
        };
        let meta = slot.meta;
        background.begin(meta.index);
        // YUYV, where no sample is wanted of it: straight from the buffer, RGB only where
        // a stripe can be.
        if &header.fourcc == b"YUYV" {
            if let Some(bg) = background.ready_without_decoding(meta.index) {
                let curves = yuyv_curves(&mut extractor, &slot.bytes, header, &bg, shared, meta);
                drop(slot);
                if !send(meta, curves) {
                    return;
                }
                continue;
            }
        }
        background.keep_sample(meta.index, &slot.bytes);
        let image = decode_checked(header, &slot.bytes, camera, shared, meta);
        if image.is_some() && shared.chroma.get().is_none() {
            if let Some(rebuild) = chroma::of_buffer(header, &slot.bytes) {
                if shared.chroma.set(rebuild).is_ok() {
                    chroma::tell_user(rebuild);
                }
            }
        }
        drop(slot);
        if let Some(ready) = background.arrive(meta, image) {
            if !extract(&mut extractor, ready) {
                return;
            }
        }
    }
    // The stream ended: the frames still parked wait only for other workers' samples
    // (or for the capture thread to say how many frames there were).
    while background.pending() && !stop.load(Ordering::Relaxed) {
        match background.take_ready() {
            Some(ready) => {
                if !extract(&mut extractor, ready) {
                    return;
                }
            }
            None => std::thread::sleep(Duration::from_millis(5)),
        }
    }
}

/// A YUYV frame's curves, extracted from the camera's buffer; an unreadable frame has
/// none and is counted.
fn yuyv_curves(
    extractor: &mut Extractor,
    bytes: &[u8],
    header: &DumpHeader,
    bg: &Background,
    shared: &Shared,
    meta: FrameMeta,
) -> Vec<Curve> {
    let stride = if header.bytes_per_line > 0 {
        header.bytes_per_line as usize
    } else {
        2 * header.width as usize
    };
    match extractor.extract_yuyv(bytes, stride, bg) {
        Ok(c) => {
            shared.frames_decoded.fetch_add(1, Ordering::Relaxed);
            c
        }
        Err(e) => {
            if shared.decode_errors.fetch_add(1, Ordering::Relaxed) == 0 {
                tracing::warn!(frame = meta.index, "skipping a YUYV frame: {e}");
            } else {
                tracing::debug!(frame = meta.index, "skipping a YUYV frame: {e}");
            }
            Vec::new()
        }
    }
}

/// A frame decoded to RGB and of the camera's size, or `None` (warned about and
/// counted).
fn decode_checked(
    header: &DumpHeader,
    bytes: &[u8],
    camera: &Camera,
    shared: &Shared,
    meta: FrameMeta,
) -> Option<RgbImage> {
    let image = match decode_rgb(header, bytes) {
        Ok(img) if img.dimensions() == (camera.width, camera.height) => Some(img),
        Ok(img) => {
            tracing::warn!(
                frame = meta.index,
                "frame is {:?}, expected {}x{}",
                img.dimensions(),
                camera.width,
                camera.height
            );
            None
        }
        Err(e) => {
            if shared.decode_errors.load(Ordering::Relaxed) == 0 {
                tracing::warn!(frame = meta.index, "skipping a frame: {e}");
            } else {
                tracing::debug!(frame = meta.index, "skipping a frame: {e}");
            }
            None
        }
    };
    if image.is_some() {
        shared.frames_decoded.fetch_add(1, Ordering::Relaxed);
    } else {
        shared.decode_errors.fetch_add(1, Ordering::Relaxed);
    }
    image
}

/// What the `status` thread reads and where it tells it.
pub(super) struct StatusThread<'a> {
    pub shared: &'a Shared,
    pub hub: &'a net::Hub,
    pub feed: &'a net::StatusFeed,
    pub notifier: &'a notify::Notifier,
    pub scan_id: &'a str,
    pub started: Instant,
    pub interval: Duration,
}

impl<'env> StatusThread<'env> {
    /// Spawns the `status` thread in `s`: [`Self::run`].
    pub(super) fn spawn<'scope>(
        self,
        s: &'scope std::thread::Scope<'scope, 'env>,
        stop: &'env AtomicBool,
        capture_done: &'env AtomicBool,
    ) -> Result<(), ServeError> {
        spawn_named(s, "status", move || self.run(stop, capture_done)).map(drop)
    }

    /// Publishes a status line every interval and on events, and talks to systemd
    /// (`READY`, `STATUS`, `WATCHDOG` from pipeline progress), until `stop`.
    pub(super) fn run(&self, stop: &AtomicBool, capture_done: &AtomicBool) {
        let shared = self.shared;
        let mut last_beats = (u64::MAX, u64::MAX);
        let mut ready = false;
        let mut last_ping = Instant::now();
        let mut seen_losses = 0;
        while !stop.load(Ordering::Relaxed) {
            let losses = shared.device_losses.load(Ordering::Relaxed);
            let st = Status::gather(shared, self.hub, self.scan_id, self.started);
            if !ready && st.device == DeviceState::Streaming {
                self.notifier.notify("READY=1");
                ready = true;
            }
            for line in status_lines(&st, losses != seen_losses) {
                self.notifier.notify(&format!("STATUS={}", line.summary()));
                self.feed.publish(line.to_line());
            }
            seen_losses = losses;
            // The watchdog hears from the pipeline's progress: both the capture loop
            // and the solver loop must have turned since the last ping (they turn at
            // least every 100 ms while alive).
            let beats = (
                shared.capture_beats.load(Ordering::Relaxed),
                shared.solver_beats.load(Ordering::Relaxed),
            );
            let capture_alive = beats.0 != last_beats.0 || capture_done.load(Ordering::Relaxed);
            if let Some(every) = self.notifier.watchdog_every {
                if capture_alive && beats.1 != last_beats.1 && last_ping.elapsed() >= every / 2 {
                    self.notifier.notify("WATCHDOG=1");
                    last_ping = Instant::now();
                }
            }
            last_beats = beats;
            // A change of the device's state is published at once.
            let t = Instant::now();
            while t.elapsed() < self.interval
                && !stop.load(Ordering::Relaxed)
                && shared.device_losses.load(Ordering::Relaxed) == seen_losses
                && shared.device_state.load(Ordering::Relaxed) == st.device as u8
            {
                std::thread::sleep(Duration::from_millis(20));
            }
        }
    }
}
