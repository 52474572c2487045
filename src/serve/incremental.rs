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
//!   or at 1.5 while no epoch has been adopted.
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
//!   same scan ([`crate::pipeline::reconstruct_scan`]), so the final cloud is exactly
//!   what `crossline reconstruct` makes of the same curves, whatever the order and
//!   timing of the live epochs were.

use std::sync::Arc;

use crossbeam_channel::{Receiver, TryRecvError};
use image::RgbImage;

use crate::camera::Camera;
use crate::cloud::{self, ScaleMode};
use crate::config::Config;
use crate::extract::Curve;
use crate::pipeline::{self, PlaneSource, Reconstruction, Scan};
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

/// An epoch being made. Dropped (adopted, or superseded by the final solve), it stops
/// the epoch if still running: on a small machine the final solve must not share the CPU
/// with an epoch nobody will read.
struct Pending {
    answer: Receiver<Result<Answer, NotAdopted>>,
    /// Planes in the snapshot it is made of.
    planes: usize,
    /// Capture time of the snapshot's newest frame: its points are no newer.
    captured_nanos: u64,
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
        let (planes, captured) = self
            .pending
            .take()
            .map_or((0, 0), |p| (p.planes, p.captured_nanos));
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

    /// The final solve over every curve, exactly as `crossline reconstruct` does it on
    /// the same scan. Afterwards no more frames can be added.
    pub fn finish(&mut self) -> Result<Reconstruction, ReconstructError> {
        // A background solve still running is superseded.
        self.pending = None;
        self.current = None;
        self.backlog = 0..0;
        let scan = std::mem::replace(&mut self.scan, Scan::new(&self.camera, &self.config));
        let rec = pipeline::reconstruct_scan(
            scan,
            self.counts.crossings_s,
            &self.camera,
            &self.config,
            PlaneSource::SelfCalibrated,
            &self.scale,
            self.colour.as_deref(),
        )?;
        self.epoch += 1;
        self.counts.epoch = self.epoch;
        self.counts.points = rec.cloud.len() as u64;
        self.counts.planes_solved = rec.report.planes_solved as u64;
        self.counts.planes_in_global_solve = rec.report.planes_in_global_solve as u64;
        Ok(rec)
    }

    pub fn epoch(&self) -> u32 {
        self.epoch
    }

    /// Capture time of the last frame added.
    pub fn last_captured_nanos(&self) -> Option<u64> {
        self.captured.last().copied()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::solve::synthetic::{curve_polyline, random_scan, worst_off_surface, ScanSpec};

    /// With the focal length estimated (the in-air calibration under water: every
    /// normalised point 1.33 times too far out), the streamed cloud lies on the
    /// surface. It once came out many times off: the epoch's planes were turned back
    /// into the focal-corrected coordinates and met the uncorrected points.
    #[test]
    fn an_epoch_with_an_estimated_focal_length_lies_on_the_surface() {
        let camera = Camera::with_fov(1200, 900, 2.0 * 0.6f64.atan());
        let scan = random_scan(&ScanSpec::default());
        let lambda = 1.33;
        let mut config = Config::default();
        config.solve.estimate_focal = true;
        let strength = 2.0 * config.solve.min_curve_strength;
        let mut solver = Incremental::new(
            camera.clone(),
            config,
            IncrementalParams {
                min_planes_first_solve: scan.planes.len(),
                solve_growth: 10.0,
            },
            ScaleMode::Factor { factor: 1.0 },
        );
        let mut points = Vec::new();
        let mut epochs = 0;
        let mut take = |out: Output| {
            epochs += usize::from(out.epoch.is_some());
            points.extend(out.batches.into_iter().flat_map(|b| b.points));
            epochs
        };
        for k in 0..scan.planes.len() / 2 {
            let curves: Vec<Curve> = (0..2)
                .filter_map(|l| {
                    let v = scan.planes[2 * k + l];
                    let pts: Vec<[f64; 2]> = curve_polyline(&scan.scene, &v, 1.0 / camera.fx)?
                        .into_iter()
                        .map(|p| [p[0] * lambda, p[1] * lambda])
                        .collect();
                    Some(Curve {
                        laser: l as u8,
                        points_px: pts
                            .iter()
                            .map(|p| {
                                let [u, v] = camera.pixel_from_normalized(p[0], p[1]);
                                [u as f32, v as f32]
                            })
                            .collect(),
                        strength: vec![strength; pts.len()],
                        polyline: pts.clone(),
                        points: pts,
                    })
                })
                .collect();
            take(solver.add_frame(curves, 0));
        }
        // The solve runs in the background; empty frames poll it (for as long as a loaded
        // machine needs: this is no speed test).
        let deadline = std::time::Instant::now() + std::time::Duration::from_secs(300);
        while std::time::Instant::now() < deadline {
            if take(solver.add_frame(Vec::new(), 0)) > 0 {
                break;
            }
            std::thread::sleep(std::time::Duration::from_millis(10));
        }
        assert!(points.len() > 1000, "{} points", points.len());
        let xyz: Vec<[f32; 3]> = points.iter().map(|p| p.xyz).collect();
        let worst = worst_off_surface(&scan.scene, &xyz);
        assert!(
            worst < 1e-3,
            "a point {:.3} % off the surface",
            100.0 * worst
        );
    }

    /// What one epoch sent: its cloud, and the frames placed against it.
    #[derive(Default)]
    struct Sent {
        cloud: Vec<Point>,
        placed: Vec<Point>,
    }

    /// Feeds `frames` to `solver` at about 30 fps and returns what each epoch sent.
    fn live_epochs(solver: &mut Incremental, frames: Vec<Vec<Curve>>) -> Vec<Sent> {
        let mut epochs: Vec<Sent> = Vec::new();
        for curves in frames {
            let out = solver.add_frame(curves, 0);
            if out.epoch.is_some() {
                epochs.push(Sent::default());
            }
            for b in out.batches {
                let e = epochs.last_mut().expect("no points before the first epoch");
                match b.kind {
                    BatchKind::Epoch => e.cloud.extend(b.points),
                    BatchKind::Arrival | BatchKind::Backlog => e.placed.extend(b.points),
                }
            }
            // Give the background solve time, as frames at 30 fps would.
            std::thread::sleep(std::time::Duration::from_millis(20));
        }
        epochs
    }

    /// Of one epoch's points (one global scale, fitted as the median), how many lie more
    /// than `tolerance` (relative depth) off the surface.
    fn points_off(
        scene: &crate::solve::synthetic::Scene,
        points: &[Point],
        tolerance: f64,
    ) -> usize {
        let ratios: Vec<f64> = points
            .iter()
            .map(|p| {
                let [x, y, z] = p.xyz.map(f64::from);
                scene.inverse_depth(x / z, y / z) * z
            })
            .collect();
        relative_to_median(&ratios)
            .iter()
            .filter(|e| e.abs() > tolerance)
            .count()
    }

    /// Each of `ratios` over their median, less one: the relative errors after one global
    /// scale. Empty for no ratios.
    fn relative_to_median(ratios: &[f64]) -> Vec<f64> {
        let mut sorted = ratios.to_vec();
        sorted.sort_by(f64::total_cmp);
        let Some(&s0) = sorted.get(sorted.len() / 2) else {
            return Vec::new();
        };
        ratios.iter().map(|r| r / s0 - 1.0).collect()
    }

    /// Of one epoch's points, how many lie on planes (one laser of one frame) whose depth
    /// is off by more than `tolerance` (relative, after one global scale fitted as the
    /// median). A plane's error is measured on the plane itself, not at its noisy
    /// points: each point is on its estimated plane, so `Z (v_true · r)` along the point's
    /// own ray `r` is the ratio of the true plane's inverse depth to the estimated one's.
    /// (The scene's depth at the point would add the point's own noise, which is
    /// several per cent where a plane meets the surface at a grazing angle, and is no
    /// part of the plane's uncertainty.)
    fn points_on_wrong_planes(
        scan: &crate::solve::synthetic::PathScan,
        points: &[Point],
        tolerance: f64,
    ) -> usize {
        points_on_wrong_planes_of(scan, points, tolerance, points.len())
    }

    /// [`points_on_wrong_planes`] of `points`, counting only those before `upto` (the
    /// global scale still fitted on all of them).
    fn points_on_wrong_planes_of(
        scan: &crate::solve::synthetic::PathScan,
        points: &[Point],
        tolerance: f64,
        upto: usize,
    ) -> usize {
        let ratios: Vec<f64> = points
            .iter()
            .map(|p| {
                let [x, y, z] = p.xyz.map(f64::from);
                let truth = scan.planes[p.frame as usize][usize::from(p.laser)];
                z * truth.dot(&nalgebra::Vector3::new(x / z, y / z, 1.0))
            })
            .collect();
        let mut planes: std::collections::HashMap<(u32, u8), Vec<f64>> = Default::default();
        for (p, e) in points.iter().zip(relative_to_median(&ratios)).take(upto) {
            planes.entry((p.frame, p.laser)).or_default().push(e);
        }
        planes
            .values_mut()
            .filter_map(|e| {
                e.sort_by(f64::total_cmp);
                (e[e.len() / 2].abs() > tolerance).then_some(e.len())
            })
            .sum()
    }

    /// More evidence never makes an epoch worse: at 0.05 px of noise on every curve
    /// point (several times what extraction measures on rendered frames), no epoch has
    /// more points on planes that are off by more than three of the depth rule's
    /// deviations (the rule keeps a point only where its plane fixes its depth to
    /// `max_depth_sigma`) than the epoch before it, and the final cloud has none.
    ///
    /// This test once reported 89 such points in the final cloud: it took a plane's error
    /// as the median of its points' error *sizes*, which is the points' own noise on a
    /// plane that meets the surface at a grazing angle (1.7 % on one 89-point curve
    /// whose plane was right). It now measures the planes themselves.
    #[test]
    fn epochs_are_monotone_in_evidence() {
        assert_epochs_monotone(0.05);
    }

    /// The same at 0.3 px of curve noise, where the first epochs see each plane crossed
    /// only a few times and the polylines are jagged. Fails (issue 17): the first epoch
    /// keeps 1,997 points on planes over 1 % off. The mechanism: jagged polylines cross
    /// several times where their curves cross once, and each copy counts as an
    /// observation (704 crossings for 351 pairs of planes on 16 frames); the planes'
    /// errors are then 1.2-3.2 of their deviations (0.67 if honest), against 0.3-0.7
    /// with analytic crossings at the same noise. Keeping one crossing per run of a pair
    /// within the refinement radius made this test pass (at 0.5 px too) and the
    /// generality bench's seed 9 (0.102 % → 0.025 %), but it removed 284 of 34,511
    /// crossings of table-top seed 15, which then settled in a wrong solution (99 % of
    /// its points on wrong planes, unwarned); it was withdrawn until the estimator
    /// detects that second solution.
    #[test]
    #[ignore = "fails: repeated crossings of jagged polylines make the deviations 2-3x optimistic (issue 17)"]
    fn epochs_are_monotone_in_evidence_at_high_noise() {
        assert_epochs_monotone(0.3);
    }

    /// The epochs' and final cloud's points on wrong planes (see
    /// [`epochs_are_monotone_in_evidence`]) with `noise_px` of Gaussian noise on every
    /// curve point.
    fn assert_epochs_monotone(noise_px: f64) {
        let camera = Camera::with_fov(1200, 900, 2.0 * 0.6f64.atan());
        let mut config = Config::default();
        config.solve.max_anchor_poses = 40;
        let (scan, frames) = path_frames(&camera, &config);
        let mut rng = crate::solve::synthetic::Rng::new(5);
        let sigma = noise_px / camera.fx;
        let frames: Vec<Vec<Curve>> = frames
            .into_iter()
            .map(|curves| {
                curves
                    .into_iter()
                    .map(|mut c| {
                        for p in &mut c.points {
                            p[0] += sigma * rng.normal();
                            p[1] += sigma * rng.normal();
                        }
                        c.polyline = c.points.clone();
                        c
                    })
                    .collect()
            })
            .collect();
        let mut solver = Incremental::new(
            camera,
            config.clone(),
            IncrementalParams {
                min_planes_first_solve: 30,
                solve_growth: 1.25,
            },
            ScaleMode::Factor { factor: 1.0 },
        );
        let bound = 3.0 * config.triangulate.max_depth_sigma;
        let epochs = live_epochs(&mut solver, frames);
        let failing: Vec<usize> = epochs
            .iter()
            .map(|e| points_on_wrong_planes(&scan, &e.cloud, bound))
            .collect();
        // The frames placed against each epoch, on its scale.
        let placed_wrong: Vec<(usize, usize)> = epochs
            .iter()
            .map(|e| {
                let both: Vec<Point> = e.cloud.iter().chain(&e.placed).copied().collect();
                let wrong = points_on_wrong_planes(&scan, &both, bound)
                    - points_on_wrong_planes_of(&scan, &both, bound, e.cloud.len());
                (wrong, e.placed.len())
            })
            .collect();
        eprintln!(
            "epochs' points on wrong planes {failing:?}; placed (wrong, all) {placed_wrong:?}"
        );
        assert!(epochs.len() >= 3, "{} epochs", epochs.len());
        // Frames placed against an epoch are no worse than it: none on a wrong plane
        // where the epoch has none.
        assert!(
            placed_wrong.iter().any(|&(_, all)| all > 0),
            "no frame placed"
        );
        for (e, (&(wrong, all), &own)) in placed_wrong.iter().zip(&failing).enumerate() {
            assert!(
                own > 0 || wrong == 0,
                "epoch {e}: {wrong} of {all} points placed against it on wrong planes, none of its own"
            );
        }
        for (e, pair) in failing.windows(2).enumerate() {
            assert!(
                pair[1] <= pair[0],
                "epoch {} has {} points on planes over {bound}, the one before {} (all: {failing:?})",
                e + 1,
                pair[1],
                pair[0]
            );
        }
        let last = solver.finish().expect("final solve");
        let cloud = &last.cloud;
        let (frames_of, lasers_of) = (cloud.frames.as_ref(), cloud.lasers.as_ref());
        let final_points: Vec<Point> = (0..cloud.len())
            .map(|i| Point {
                xyz: cloud.points[i],
                rgb: [0; 3],
                laser: lasers_of.expect("lasers")[i],
                frame: frames_of.expect("frames")[i],
            })
            .collect();
        assert_eq!(points_on_wrong_planes(&scan, &final_points, bound), 0);
    }

    /// Curves of the synthetic path scan, frame by frame, as extracted.
    fn path_frames(
        camera: &Camera,
        config: &Config,
    ) -> (crate::solve::synthetic::PathScan, Vec<Vec<Curve>>) {
        let scan = crate::solve::synthetic::path_scan(&crate::solve::synthetic::PathSpec {
            frames: 80,
            ..Default::default()
        });
        let strength = 2.0 * config.solve.min_curve_strength;
        let frames = scan
            .planes
            .iter()
            .map(|p| {
                (0..2)
                    .filter_map(|l| {
                        let pts = curve_polyline(&scan.scene, &p[l], 1.0 / camera.fx)?;
                        Some(Curve {
                            laser: l as u8,
                            points_px: pts
                                .iter()
                                .map(|q| camera.pixel_from_normalized(q[0], q[1]).map(|c| c as f32))
                                .collect(),
                            strength: vec![strength; pts.len()],
                            polyline: pts.clone(),
                            points: pts,
                        })
                    })
                    .collect()
            })
            .collect();
        (scan, frames)
    }

    /// The live solver runs the offline estimator: with anchors thinned as the scan grows,
    /// its epochs lie on the surface (but for the few points of the known limit), and its final
    /// cloud is `reconstruct`'s of the same curves, point for point.
    #[test]
    fn live_epochs_lie_on_the_surface_and_the_final_cloud_is_reconstructs() {
        let camera = Camera::with_fov(1200, 900, 2.0 * 0.6f64.atan());
        let mut config = Config::default();
        config.solve.max_anchor_poses = 40;
        let (scan, frames) = path_frames(&camera, &config);
        let mut solver = Incremental::new(
            camera.clone(),
            config.clone(),
            IncrementalParams {
                min_planes_first_solve: 40,
                solve_growth: 1.5,
            },
            ScaleMode::Factor { factor: 1.0 },
        );
        let epochs = live_epochs(&mut solver, frames.clone());
        assert!(epochs.len() >= 2, "{} epochs", epochs.len());
        // Nearly every live point on the surface. Not every one: an epoch made on the
        // evidence of a partial sweep (when it is made depends on the machine's load)
        // can place a few of the newest frames a few per cent off (the known limit).
        let (off, all) = epochs.iter().fold((0, 0), |(off, all), e| {
            (
                off + points_off(&scan.scene, &e.cloud, 1e-3),
                all + e.cloud.len(),
            )
        });
        assert!(off * 50 < all, "{off} of {all} live points off the surface");
        let (off, all) = epochs.iter().fold((0, 0), |(off, all), e| {
            let both: Vec<Point> = e.cloud.iter().chain(&e.placed).copied().collect();
            (
                off + points_off(&scan.scene, &both, 1e-3)
                    - points_off(&scan.scene, &e.cloud, 1e-3),
                all + e.placed.len(),
            )
        });
        assert!(all > 0, "no frame placed against an epoch");
        assert!(
            off * 50 < all,
            "{off} of {all} placed points off the surface"
        );
        let live = solver.finish().expect("final solve");
        let offline = crate::pipeline::reconstruct_curves(
            frames,
            &camera,
            &config,
            PlaneSource::SelfCalibrated,
            &ScaleMode::Factor { factor: 1.0 },
            None,
        )
        .expect("offline");
        assert!(live.cloud.len() > 10_000);
        assert_eq!(live.cloud.points, offline.cloud.points);
        assert_eq!(live.planes, offline.planes);
    }

    /// The final solve supersedes a running epoch's: that one is told to stop, so that
    /// the two do not share the CPU (on a one-CPU machine the final cloud came minutes
    /// late), and the final cloud is still made.
    #[test]
    fn the_final_solve_stops_an_epoch_still_running() {
        let camera = Camera::with_fov(1200, 900, 2.0 * 0.6f64.atan());
        let config = Config::default();
        let (_, frames) = path_frames(&camera, &config);
        let planes: usize = frames.iter().map(Vec::len).sum();
        let mut solver = Incremental::new(
            camera,
            config,
            IncrementalParams {
                min_planes_first_solve: planes,
                solve_growth: 10.0,
            },
            ScaleMode::Factor { factor: 1.0 },
        );
        for curves in frames {
            solver.add_frame(curves, 0);
        }
        let running = solver
            .pending
            .as_ref()
            .expect("a solve started")
            .cancel
            .clone();
        assert!(!running.is_cancelled());
        let rec = solver.finish().expect("final solve");
        assert!(
            running.is_cancelled(),
            "the epoch's solve was not told to stop"
        );
        assert!(rec.cloud.len() > 10_000, "{} points", rec.cloud.len());
    }
}
