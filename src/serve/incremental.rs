//! The live solver: curves arrive frame by frame, crossings accumulate, and the cloud
//! grows in *epochs*. It runs the offline pipeline's own stages, on a
//! [`crate::pipeline::Scan`] built frame by frame exactly as `reconstruct` builds it:
//!
//! - Each new frame's curves go into the scan at once: their crossings with the anchors'
//!   curves (and an anchor's with every curve) are found and refined.
//! - An epoch is the estimator's answer on the evidence so far:
//!   [`crate::solve::calibrate_until`] on the scan's evidence: the offline estimator's
//!   two cold starts and, as a third, the last epoch's planes (the frames since placed
//!   by their crossings with those), the best explanation of the evidence winning; and
//!   the offline triangulation of every plane it determines (the same uncertainty rule,
//!   and the same crossing check: an epoch whose planes most curves contradict is not
//!   adopted). All of it runs on a thread of its own ([`super::epoch`]), on a snapshot
//!   of the scan taken when it starts. The first
//!   is tried once `min_planes_first_solve` planes have arrived, the next whenever the
//!   planes have grown by `solve_growth`; a failed one is retried at the same growth,
//!   or at 1.5 while no epoch has been adopted. Once one has been, the thread rests
//!   after each attempt, so that epochs are in the making at most `epoch_duty` of the
//!   time ([`rest_after`]): late in a long scan one takes a minute or more of a core.
//!   Before the first is adopted the user sees nothing, and the tries go on unrested.
//! - Between epochs, each new frame is placed against the current epoch as it arrives:
//!   its pose fitted from its crossings with the epoch's joint poses exactly as the
//!   offline estimate fits every frame outside its anchors, with the joint poses'
//!   uncertainty propagated into it ([`crate::solve::outside`]), and its points
//!   triangulated with the same depth rule and crossing check. A frame its crossings do
//!   not fix gives no points until an epoch holds it. The frames that arrived while an
//!   epoch was made are placed against it after it is adopted, a few per frame.
//!   (An earlier attempt fitted each plane on its own against the anchors' planes, with
//!   no uncertainty of theirs, and placed a few frames of a synthetic sweep 7-9 % off.)
//! - At the end, [`Incremental::finish`] runs the offline pipeline's final stages on the
//!   same scan ([`crate::pipeline::reconstruct_scan`]), its two cold starts and the last
//!   epoch's planes as a third. Where the third leads to the solution the cold starts
//!   find, the cold one is kept, so the final cloud is exactly what `crossline
//!   reconstruct` makes of the same curves, whatever the order and timing of the live
//!   epochs were. Where the cold starts settle in a worse solution (clutter seed 14 as
//!   an MJPEG dump: refused offline) and the epochs' leads to a better one, the daemon
//!   gives the better cloud, which then depends on its epochs.

use std::sync::Arc;
use std::time::{Duration, Instant};

use crossbeam_channel::{Receiver, TryRecvError};
use image::RgbImage;

use crate::camera::Camera;
use crate::cloud::{self, ScaleMode};
use crate::config::Config;
use crate::extract::Curve;
use crate::pipeline::{self, PipelineError, PlaneSource, Reconstruction, Scan};
use crate::reconstruct::ReconstructError;
use crate::solve::{self, SolveError};

use super::epoch::{self, Answer, Estimate, NotAdopted};
use super::stream::{self, EpochReason, Point};

/// How often the live solver re-solves globally.
#[derive(Clone, Debug)]
pub struct IncrementalParams {
    /// Planes needed before the first global solve is tried.
    pub min_planes_first_solve: usize,
    /// A new global solve starts when the planes have grown by this factor since the
    /// last one (and a failed first solve is retried at the same growth).
    pub solve_growth: f64,
    /// The largest share of the time an epoch may be in the making: once one has been
    /// adopted, after an attempt that took `t` the next starts no sooner than
    /// `t (1 / epoch_duty − 1)` after it ([`rest_after`]).
    pub epoch_duty: f64,
}

/// What the live solver wants sent.
#[derive(Debug, Default)]
pub struct Output {
    /// A new epoch begins (its points follow in `batches`).
    pub epoch: Option<(u32, EpochReason)>,
    /// Points to send, in order: an adopted epoch's cloud, then frames placed against
    /// the current epoch.
    pub batches: Vec<Batch>,
}

/// Points for the stream.
#[derive(Debug)]
pub struct Batch {
    pub points: Vec<Point>,
    /// Capture time of the newest frame these points come from.
    pub captured_nanos: u64,
    pub kind: BatchKind,
}

/// Where a batch's points come from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BatchKind {
    /// An epoch's cloud: every frame up to the snapshot it was made on.
    Epoch,
    /// The frame just added, placed against the current epoch on arrival.
    Arrival,
    /// A frame that arrived while the current epoch was made, placed against it when
    /// it was adopted.
    Backlog,
}

/// Growth of the planes at which a first epoch is tried again while none has been
/// adopted (at most `solve_growth`): until then the user sees no point, and the tries
/// are cheap, being small.
const FIRST_EPOCH_GROWTH: f64 = 1.5;

/// Frames of an adopted epoch's backlog placed per frame added: at 30 frames a second,
/// a backlog of 10 s is placed in about 3 s, and no frame waits long for it.
const BACKLOG_PER_FRAME: usize = 3;

/// The rest after an epoch that took `took`, so that epochs are in the making at most
/// `duty` of the time: `took (1 / duty − 1)`, none at a duty of 1 or more.
pub(super) fn rest_after(took: Duration, duty: f64) -> Duration {
    if duty.is_nan() || duty <= 0.0 || duty >= 1.0 {
        return Duration::ZERO;
    }
    took.mul_f64(1.0 / duty - 1.0)
}

/// An epoch being made. Dropped (adopted, or superseded by the final solve), it stops
/// the epoch if still running: on a small machine the final solve must not share the CPU
/// with an epoch nobody will read.
struct Pending {
    answer: Receiver<Result<Answer, NotAdopted>>,
    /// Planes in the snapshot it is made of.
    planes: usize,
    /// Capture time of the snapshot's newest frame: its points are no newer.
    captured_nanos: u64,
    /// When it was started.
    started: Instant,
    cancel: solve::Cancel,
}

impl Drop for Pending {
    fn drop(&mut self) {
        self.cancel.cancel();
    }
}

/// Live counters for status.
#[derive(Clone, Copy, Debug, Default, serde::Serialize)]
pub struct SolverCounts {
    pub frames: u64,
    pub curves: u64,
    pub planes: u64,
    pub crossings: u64,
    pub planes_solved: u64,
    pub global_solves: u64,
    pub failed_global_solves: u64,
    pub planes_in_global_solve: u64,
    pub residual_rms_px: f64,
    pub orthogonality_rms_deg: f64,
    pub epoch: u32,
    pub points: u64,
    /// Seconds spent so far: finding and refining crossings, placing new planes,
    /// triangulating growth, adopting epochs.
    pub crossings_s: f64,
    /// Of `crossings_s`, refining crossings on the dense points.
    pub refine_s: f64,
    /// Placing frames against the current epoch, and adopting epochs.
    pub place_s: f64,
    pub adopt_s: f64,
    /// Frames placed against the current epoch on arrival that gave points.
    pub frames_placed_on_arrival: u64,
    /// Frames placed from an adopted epoch's backlog that gave points (a frame may be
    /// placed against several epochs).
    pub frames_placed_late: u64,
}

pub struct Incremental {
    camera: Camera,
    config: Config,
    params: IncrementalParams,
    scale: ScaleMode,
    colour: Option<Arc<RgbImage>>,
    scan: Scan,
    epoch: u32,
    current: Option<Arc<Estimate>>,
    /// Frames that arrived while the current epoch was made, still to place against it.
    backlog: std::ops::Range<usize>,
    /// Per frame, its capture time.
    captured: Vec<u64>,
    pending: Option<Pending>,
    next_solve_at: usize,
    /// No epoch starts before this (the duty rule, [`rest_after`]).
    rest_until: Option<Instant>,
    /// The last epoch's focal estimate was too uncertain (warned once when it turns so).
    focal_uncertain: bool,
    pub counts: SolverCounts,
}

impl Incremental {
    pub fn new(
        camera: Camera,
        config: Config,
        params: IncrementalParams,
        scale: ScaleMode,
    ) -> Self {
        Self {
            next_solve_at: params.min_planes_first_solve.max(2),
            scan: Scan::new(&camera, &config),
            camera,
            config,
            params,
            scale,
            colour: None,
            epoch: 0,
            current: None,
            backlog: 0..0,
            captured: Vec::new(),
            pending: None,
            rest_until: None,
            focal_uncertain: false,
            counts: SolverCounts::default(),
        }
    }

    /// The image points are coloured from (the background).
    pub fn set_colour_source(&mut self, image: Arc<RgbImage>) {
        self.colour = Some(image);
    }

    pub fn frames(&self) -> usize {
        self.scan.frames()
    }

    /// Adds the curves of the next frame (frames must come in index order).
    pub fn add_frame(&mut self, curves: Vec<Curve>, captured_nanos: u64) -> Output {
        self.counts.frames += 1;
        self.counts.curves += curves.len() as u64;
        let t = std::time::Instant::now();
        self.scan.add_frame(curves);
        let t_refine = std::time::Instant::now();
        self.scan.refine_crossings(&self.camera, &self.config);
        self.counts.refine_s += t_refine.elapsed().as_secs_f64();
        self.counts.planes = self.scan.planes().len() as u64;
        self.counts.crossings = self.scan.num_crossings() as u64;
        self.counts.crossings_s += t.elapsed().as_secs_f64();

        self.captured.push(captured_nanos);
        let mut out = Output::default();
        let t = std::time::Instant::now();
        if let Some((epoch, reason, batch)) = self.poll_solve() {
            out.epoch = Some((epoch, reason));
            out.batches.push(batch);
            self.counts.adopt_s += t.elapsed().as_secs_f64();
        }
        let t = std::time::Instant::now();
        let frame = self.scan.frames() - 1;
        out.batches.extend(self.place(frame, BatchKind::Arrival));
        for _ in 0..BACKLOG_PER_FRAME {
            let Some(f) = self.backlog.next() else { break };
            out.batches.extend(self.place(f, BatchKind::Backlog));
        }
        self.counts.place_s += t.elapsed().as_secs_f64();
        self.counts.points += out
            .batches
            .iter()
            .map(|b| b.points.len() as u64)
            .sum::<u64>();
        self.maybe_start_solve(captured_nanos);
        out
    }

    /// Frame `frame`'s points placed against the current epoch (see
    /// [`crate::pipeline::Record::frame_cloud`]), if it came after the epoch and gave any.
    fn place(&mut self, frame: usize, kind: BatchKind) -> Option<Batch> {
        let est = self.current.as_ref().filter(|e| frame >= e.frames)?;
        let out = self.scan.record().frame_cloud(
            frame,
            &est.calibration,
            &est.plane_index,
            &est.placing,
            &self.config,
            self.colour.as_deref(),
        )?;
        let mut cloud = out.cloud;
        if cloud.points.is_empty() {
            return None;
        }
        cloud::apply_scale(&mut cloud, est.factor);
        match kind {
            BatchKind::Arrival => self.counts.frames_placed_on_arrival += 1,
            _ => self.counts.frames_placed_late += 1,
        }
        Some(Batch {
            points: stream::points_of(&cloud, 0..cloud.points.len()),
            captured_nanos: self.captured.get(frame).copied().unwrap_or(0),
            kind,
        })
    }

    /// Starts an epoch on its own thread when the planes have grown enough;
    /// `captured_nanos` is the capture time of the newest frame in the scan.
    fn maybe_start_solve(&mut self, captured_nanos: u64) {
        let n = self.scan.planes().len();
        if self.pending.is_some() || n < self.next_solve_at {
            return;
        }
        if self.rest_until.is_some_and(|t| Instant::now() < t) {
            return;
        }
        let job = epoch::Job {
            record: self.scan.snapshot(),
            camera: self.camera.clone(),
            config: self.config.clone(),
            scale: self.scale.clone(),
            colour: self.colour.clone(),
            warm: self.current.clone(),
        };
        let cancel = solve::Cancel::default();
        match epoch::start(job, cancel.clone()) {
            Ok(answer) => {
                self.pending = Some(Pending {
                    answer,
                    planes: n,
                    captured_nanos,
                    started: Instant::now(),
                    cancel,
                })
            }
            Err(e) => tracing::warn!("cannot start a background solve: {e}"),
        }
        // Until an epoch is adopted nothing is shown, so the first is tried again sooner.
        let growth = match self.current {
            Some(_) => self.params.solve_growth,
            None => self.params.solve_growth.min(FIRST_EPOCH_GROWTH),
        };
        self.next_solve_at = ((n as f64) * growth.max(1.05)).ceil() as usize;
    }

    /// Adopts a finished epoch; returns its number and cloud. The frames since its
    /// snapshot become the backlog to place against it.
    fn poll_solve(&mut self) -> Option<(u32, EpochReason, Batch)> {
        let pending = self.pending.as_ref()?;
        let result = match pending.answer.try_recv() {
            Ok(r) => r,
            Err(TryRecvError::Empty) => return None,
            Err(TryRecvError::Disconnected) => Err(NotAdopted::Solve(SolveError::Degenerate(
                "solver thread died",
            ))),
        };
        let (planes, captured, started) = self.pending.take().map_or((0, 0, None), |p| {
            (p.planes, p.captured_nanos, Some(p.started))
        });
        // The duty bounds what refreshing an estimate costs. Until one is adopted the
        // user sees nothing, and the tries are small: they go on without a rest.
        if let Some(started) = started.filter(|_| result.is_ok() || self.current.is_some()) {
            let now = Instant::now();
            self.rest_until = Some(now + rest_after(now - started, self.params.epoch_duty));
        }
        self.counts.global_solves += 1;
        let answer = match result {
            Ok(a) => a,
            Err(e) => {
                self.counts.failed_global_solves += 1;
                tracing::info!(planes, "{e}");
                return None;
            }
        };
        let summary = &answer.estimate.calibration.summary;
        self.counts.planes_in_global_solve = summary.planes_in_global_start as u64;
        self.counts.residual_rms_px = summary.spreads.map_or(0.0, |s| s.crossing_px[0]);
        let focal_warning = solve::focal_warning(summary.focal_scale, summary.focal_scale_std);
        if let (Some(warning), false) = (&focal_warning, self.focal_uncertain) {
            tracing::warn!(epoch = self.epoch + 1, "{warning}");
        }
        self.focal_uncertain = focal_warning.is_some();
        self.counts.planes_solved = answer.planes_with_points as u64;
        // The newest frame is placed by the caller.
        self.backlog = answer.estimate.frames..self.scan.frames().saturating_sub(1);
        self.current = Some(answer.estimate);
        let reason = if self.epoch == 0 {
            EpochReason::First
        } else {
            EpochReason::Reestimate
        };
        self.epoch += 1;
        self.counts.epoch = self.epoch;
        self.counts.points = 0;
        Some((
            self.epoch,
            reason,
            Batch {
                points: answer.points,
                captured_nanos: captured,
                kind: BatchKind::Epoch,
            },
        ))
    }

    /// The final solve over every curve: `crossline reconstruct`'s on the same scan,
    /// the same estimator from the same cold starts, so the cloud is `reconstruct`'s.
    /// Only where that gives no cloud (the solve fails, or its planes are refused) is
    /// it made again with the last epoch's planes as one more start: where the cold
    /// starts miss the basin and the epochs did not (clutter 14 of the random draw:
    /// refused offline, 511 planes live, none wrong). Until 2026-12-06 that start ran
    /// beside the cold ones every time: on the 1,800- and 5,400-frame replays it never
    /// won, and it cost about 3 s of the two cores after the last frame. Afterwards no
    /// more frames can be added.
    pub fn finish(&mut self) -> Result<Reconstruction, ReconstructError> {
        // A background solve still running is superseded.
        self.pending = None;
        let earlier = self.current.take().map(|e| self.epoch_planes(&e));
        self.backlog = 0..0;
        let solve = |source| {
            pipeline::reconstruct_scan(
                &self.scan,
                self.counts.crossings_s,
                &self.camera,
                &self.config,
                source,
                &self.scale,
                self.colour.as_deref(),
            )
        };
        let result = cold_then_warm(
            || solve(PlaneSource::SelfCalibrated),
            earlier
                .as_deref()
                .map(|planes| move || solve(PlaneSource::AlsoFrom(planes))),
        );
        // The scan is let go whatever the outcome: the caller writes the cloud or the
        // failure's report next, and no frame can follow.
        self.scan = Scan::new(&self.camera, &self.config);
        let rec = result?;
        self.epoch += 1;
        self.counts.epoch = self.epoch;
        self.counts.points = rec.cloud.len() as u64;
        self.counts.planes_solved = rec.report.planes_solved as u64;
        self.counts.planes_in_global_solve = rec.report.planes_in_global_solve as u64;
        Ok(rec)
    }

    /// An epoch's planes per frame and laser of the scan.
    fn epoch_planes(&self, e: &Estimate) -> Vec<[Option<nalgebra::Vector3<f64>>; 2]> {
        let mut out = vec![[None; 2]; self.scan.frames()];
        for (i, plane) in self.scan.planes().iter().enumerate() {
            if let Some(slot) = out.get_mut(plane.frame as usize) {
                slot[usize::from(plane.laser & 1)] = e.scan_plane(i);
            }
        }
        out
    }

    pub fn epoch(&self) -> u32 {
        self.epoch
    }

    /// Capture time of the last frame added.
    pub fn last_captured_nanos(&self) -> Option<u64> {
        self.captured.last().copied()
    }

    /// Whether an epoch is being made and its answer is not in yet.
    #[cfg(test)]
    fn solving(&self) -> bool {
        self.pending.as_ref().is_some_and(|p| p.answer.is_empty())
    }
}

/// The final solve's rule ([`Incremental::finish`]): `cold`'s answer, unless it gives
/// no cloud (its planes refused, or the solve failing) and an epoch can start `warm`;
/// then `warm`'s. Any other error (the scale) is `cold`'s.
fn cold_then_warm<T>(
    cold: impl FnOnce() -> Result<T, PipelineError>,
    warm: Option<impl FnOnce() -> Result<T, PipelineError>>,
) -> Result<T, PipelineError> {
    match (cold(), warm) {
        (
            Err(
                e @ (PipelineError::Refused { .. }
                | PipelineError::Unsolved { .. }
                | PipelineError::Solve(_)),
            ),
            Some(warm),
        ) => {
            tracing::info!(
                "the final solve gave no cloud ({e}); solving again with the last epoch's planes as one more start"
            );
            warm()
        }
        (result, _) => result,
    }
}

#[cfg(test)]
mod rest_tests {
    use super::*;

    #[test]
    fn the_rest_keeps_epochs_to_their_duty() {
        let took = Duration::from_secs(4);
        assert_eq!(rest_after(took, 0.5), took);
        assert_eq!(rest_after(took, 0.25), Duration::from_secs(12));
        assert_eq!(rest_after(took, 1.0), Duration::ZERO);
        assert_eq!(rest_after(took, f64::NAN), Duration::ZERO);
        // At duty d, busy / (busy + rest) = d.
        let d = 0.3;
        let share = took.as_secs_f64() / (took + rest_after(took, d)).as_secs_f64();
        assert!((share - d).abs() < 1e-9, "{share}");
    }
}

#[cfg(test)]
#[path = "incremental_tests.rs"]
mod tests;
