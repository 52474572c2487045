//! The solver thread of [`super::run`]: puts the workers' results back in frame
//! order, checkpoints them, feeds the [`Incremental`] solver and sends its epochs to the
//! hub; at the end, the final solve over every curve and the cloud written.

use std::collections::BTreeMap;
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::{Duration, Instant};

use crossbeam_channel::{Receiver, RecvTimeoutError};

use super::background::LiveBackground;
use super::checkpoint::{Checkpoint, FrameCurves};
use super::incremental::{BatchKind, Incremental};
use super::scan::{FdReserve, ScanFiles};
use super::stream::{self, EpochReason};
use super::{lock, net, status, Extracted, ServeError, ServeOptions, Shared};

/// How the final solve ended.
pub(super) struct Finished {
    /// Points in the final cloud.
    pub points: usize,
    pub reconstruction: Option<crate::reconstruct::ReconstructReport>,
    /// Why the final solve failed, if it did.
    pub solve_error: Option<String>,
    /// From the last frame's capture to the final cloud written, seconds.
    pub after_last_frame_s: Option<f64>,
}

/// What the solver thread tells and where it writes.
#[derive(Clone, Copy)]
pub(super) struct Live<'a> {
    pub hub: &'a net::Hub,
    pub feed: &'a net::StatusFeed,
    pub shared: &'a Shared,
    pub scan: &'a ScanFiles,
}

impl Live<'_> {
    /// Feeds `solver` the frames of `results` in frame order from `first_index` until
    /// the workers are gone, checkpointing each and streaming each epoch.
    pub(super) fn run(
        self,
        solver: &mut Incremental,
        results: Receiver<Extracted>,
        checkpoint: &mut Checkpoint,
        background: &LiveBackground,
        first_index: u64,
    ) {
        let (hub, feed, shared, scan) = (self.hub, self.feed, self.shared, self.scan);
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
                Err(RecvTimeoutError::Timeout) => {
                    checkpoint.sync_if_due();
                    continue;
                }
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
                for b in out.batches.iter().filter(|b| !b.points.is_empty()) {
                    let timed = match b.kind {
                        BatchKind::Arrival => net::Timed::Frame,
                        BatchKind::Epoch | BatchKind::Backlog => net::Timed::Epoch,
                    };
                    hub.push_points(
                        stream::points(epoch_seen, b.captured_nanos, &b.points),
                        timed,
                    );
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

    /// The final solve over every curve: the cloud written (empty, with the reason in
    /// the report, when the solve fails), then sent as the final epoch and `END`.
    pub(super) fn finish(
        self,
        solver: &mut Incremental,
        checkpoint: &mut Checkpoint,
        reserve: &mut FdReserve,
        opts: &ServeOptions,
    ) -> Result<Finished, ServeError> {
        let (hub, feed, shared, scan) = (self.hub, self.feed, self.shared, self.scan);
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
                // A refused or unsolved cloud still has the report of what was found.
                let report = match e {
                    crate::reconstruct::ReconstructError::Pipeline(p) => p.into_report(),
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
        let after_last_frame_s = solver
            .last_captured_nanos()
            .map(|t| hub.now_nanos().saturating_sub(t) as f64 / 1e9);
        tracing::info!(
            points = cloud.len(),
            after_last_frame_s,
            "cloud written to {}",
            scan.cloud.display()
        );
        hub.begin_epoch(solver.epoch(), EpochReason::Final);
        hub.push_points(
            stream::points(
                solver.epoch(),
                0,
                &stream::points_of(&cloud, 0..cloud.len()),
            ),
            net::Timed::No,
        );
        hub.end(cloud.len() as u64);
        *lock(&shared.solver) = solver.counts;
        Ok(Finished {
            points: cloud.len(),
            reconstruction: rec,
            solve_error: err,
            after_last_frame_s,
        })
    }
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
