//! The live solver: curves arrive frame by frame, crossings accumulate, and the cloud
//! grows in *epochs*.
//!
//! - Each new frame's curves go into the segment index at once; their crossings with
//!   all earlier curves are found and refined (the same stages as
//!   [`crate::reconstruct`]).
//! - The first global solve runs, on a background thread named `solver-epoch`, as soon
//!   as enough planes have arrived; it is retried as evidence grows until it succeeds.
//!   That solution is epoch 1.
//! - From then on every new plane gets its plane at once from its crossings with
//!   solved planes (and its partner's orthogonality), and its points go out as growth
//!   of the current epoch.
//! - When the planes have grown by a factor (`solve_growth`) since the last global
//!   solve, the global solution is re-estimated on the background thread over
//!   everything so far, warm-started from the current epoch (its residuals give the
//!   first robust weights instead of a fresh consensus search, [`solve::solve_warm`]),
//!   while new frames keep being placed with the old one. The new
//!   solution, extended over the planes that arrived meanwhile, is the next epoch: its
//!   whole cloud is sent again.
//! - At the end, [`Incremental::finish`] runs the offline pipeline's final stages over
//!   every curve ([`crate::reconstruct::reconstruct_curves`]), so the final cloud is
//!   exactly what `crossline reconstruct` makes of the same curves, whatever the order
//!   and timing of the live epochs were.

use std::sync::Arc;

use crossbeam_channel::{bounded, Receiver, TryRecvError};
use image::RgbImage;
use nalgebra::Vector3;

use crate::camera::Camera;
use crate::cloud::{self, CurvePoints, ScaleMode};
use crate::config::Config;
use crate::extract::Curve;
use crate::intersect::{Crossing, SegmentIndex};
use crate::pipeline::{self as reconstruct, PlaneCurves, PlaneSource, Reconstruction};
use crate::ply::Cloud;
use crate::reconstruct::ReconstructError;
use crate::solve::extend::{fit_plane, FitContext};
use crate::solve::{self, Problem, Solution, SolveError, WarmStart};

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
    /// A new epoch begins (its points follow in `points`).
    pub epoch: Option<(u32, EpochReason)>,
    pub points: Vec<Point>,
    /// Capture time of the newest frame these points come from.
    pub captured_nanos: u64,
}

/// The solution an epoch is built on, in the solver's given coordinates.
struct EpochSolution {
    planes_given: Vec<Option<Vector3<f64>>>,
    ctx: FitContext,
    lambda: f64,
    factor: f64,
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
    pub extend_s: f64,
    pub triangulate_s: f64,
    pub adopt_s: f64,
}

pub struct Incremental {
    camera: Camera,
    config: Config,
    params: IncrementalParams,
    scale: ScaleMode,
    colour: Option<Arc<RgbImage>>,
    /// Frames added so far (their curves live in `planes`, once).
    frames: usize,
    planes: Vec<PlaneCurves>,
    partner: Vec<Option<u32>>,
    index: SegmentIndex,
    crossings: Vec<Crossing>,
    /// Per plane: (other plane, crossing index).
    adjacency: Vec<Vec<(u32, usize)>>,
    epoch: u32,
    solution: Option<EpochSolution>,
    pending: Option<(Receiver<Result<Solution, SolveError>>, usize)>,
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
        let index = SegmentIndex::for_image(
            camera.width,
            camera.height,
            camera.fx.max(camera.fy),
            config.solve.min_sin_angle,
        );
        Self {
            next_solve_at: params.min_planes_first_solve.max(2),
            camera,
            config,
            params,
            scale,
            colour: None,
            frames: 0,
            planes: Vec::new(),
            partner: Vec::new(),
            index,
            crossings: Vec::new(),
            adjacency: Vec::new(),
            epoch: 0,
            solution: None,
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
        self.frames
    }

    /// Adds the curves of the next frame (frames must come in index order).
    pub fn add_frame(&mut self, curves: Vec<Curve>, captured_nanos: u64) -> Output {
        let frame = self.frames as u32;
        self.frames += 1;
        self.counts.frames += 1;
        self.counts.curves += curves.len() as u64;
        let first_new = self.planes.len();
        for plane in PlaneCurves::of_frame(frame, curves) {
            self.planes.push(plane);
            self.partner.push(None);
            self.adjacency.push(Vec::new());
        }
        if self.planes.len() - first_new == 2 {
            self.partner[first_new] = Some(first_new as u32 + 1);
            self.partner[first_new + 1] = Some(first_new as u32);
        }
        let t = std::time::Instant::now();
        // Crossings of the new curves with everything before (and each other).
        let radius = self.config.intersect.refine_radius_px / self.camera.fx.max(self.camera.fy);
        let mut fresh = Vec::new();
        for id in first_new..self.planes.len() {
            // Faint curves do not shape the planes (as in `reconstruct_curves`); their
            // points wait for the final solve, where a crossing must confirm them.
            for curve in &self.planes[id].curves {
                if !reconstruct::is_faint(curve, self.config.solve.min_curve_strength) {
                    self.index
                        .insert_into(id as u32, &curve.polyline, &mut fresh);
                }
            }
        }
        let t_refine = std::time::Instant::now();
        for mut c in fresh {
            if radius > 0.0 {
                let a = self.planes[c.a as usize].dense_near(c.u, radius);
                let b = self.planes[c.b as usize].dense_near(c.u, radius);
                if let Some(u) = crate::intersect::refine_crossing(a, b, c.u, radius) {
                    c.u = u;
                }
            }
            let k = self.crossings.len();
            self.adjacency[c.a as usize].push((c.b, k));
            self.adjacency[c.b as usize].push((c.a, k));
            self.crossings.push(c);
        }
        self.counts.refine_s += t_refine.elapsed().as_secs_f64();
        self.counts.planes = self.planes.len() as u64;
        self.counts.crossings = self.crossings.len() as u64;
        self.counts.crossings_s += t.elapsed().as_secs_f64();

        let mut out = Output {
            captured_nanos,
            ..Default::default()
        };
        let t = std::time::Instant::now();
        if let Some((epoch, reason, points)) = self.poll_solve() {
            out.epoch = Some((epoch, reason));
            out.points = points;
            self.counts.adopt_s += t.elapsed().as_secs_f64();
        } else if self.solution.is_some() {
            self.extend(first_new..self.planes.len());
            let t2 = std::time::Instant::now();
            self.counts.extend_s += (t2 - t).as_secs_f64();
            out.points = self.points_of(first_new..self.planes.len());
            self.counts.triangulate_s += t2.elapsed().as_secs_f64();
        }
        self.counts.points += out.points.len() as u64;
        self.maybe_start_solve();
        out
    }

    /// Starts a background global solve when the planes have grown enough.
    fn maybe_start_solve(&mut self) {
        if self.pending.is_some() || self.planes.len() < self.next_solve_at {
            return;
        }
        let n = self.planes.len();
        let crossings = self.crossings.clone();
        let partner = self.partner.clone();
        let params = self.config.solve.clone();
        let focal_px = self.camera.fx.max(self.camera.fy);
        // Warm start from the current epoch's planes.
        let warm: Option<Vec<Option<Vector3<f64>>>> =
            self.solution.as_ref().map(|s| s.planes_given.clone());
        let (tx, rx) = bounded(1);
        let spawned = std::thread::Builder::new()
            .name("solver-epoch".into())
            .stack_size(super::WORKER_STACK_BYTES)
            .spawn(move || {
                let problem = Problem {
                    num_curves: n,
                    crossings: &crossings,
                    partner: &partner,
                    focal_px,
                };
                let warm = warm.as_deref().map(|planes| WarmStart { planes });
                let _ = tx.send(solve::solve_warm(&problem, &params, warm.as_ref()));
            });
        match spawned {
            Ok(_) => self.pending = Some((rx, n)),
            Err(e) => tracing::warn!("cannot start a background solve: {e}"),
        }
        self.next_solve_at = ((n as f64) * self.params.solve_growth.max(1.05)).ceil() as usize;
    }

    /// Adopts a finished background solve; returns the new epoch and its points.
    fn poll_solve(&mut self) -> Option<(u32, EpochReason, Vec<Point>)> {
        let (rx, n) = self.pending.as_ref()?;
        let n = *n;
        let result = match rx.try_recv() {
            Ok(r) => r,
            Err(TryRecvError::Empty) => return None,
            Err(TryRecvError::Disconnected) => Err(SolveError::Degenerate("solver thread died")),
        };
        self.pending = None;
        self.counts.global_solves += 1;
        let sol = match result {
            Ok(s) if s.fit_context.is_some() => s,
            Ok(_) => return None,
            Err(e) => {
                self.counts.failed_global_solves += 1;
                tracing::info!(planes = n, "global solve not possible yet: {e}");
                return None;
            }
        };
        let lambda = sol.focal_scale;
        let mut planes_given = sol.given_planes();
        planes_given.resize(self.planes.len(), None);
        let ctx = sol.fit_context?;
        self.counts.planes_in_global_solve = sol.global.len() as u64;
        self.counts.residual_rms_px = sol.residual_rms * self.camera.fx.max(self.camera.fy);
        // Said once when the solve turns suspect, not at every epoch.
        if self.counts.orthogonality_rms_deg <= crate::solve::SUSPECT_ORTHOGONALITY_DEG {
            if let Some(warning) = crate::solve::orthogonality_warning(sol.orthogonality_rms_deg) {
                tracing::warn!(epoch = self.epoch + 1, "{warning}");
            }
        }
        self.counts.orthogonality_rms_deg = sol.orthogonality_rms_deg;
        let focal_warning = crate::solve::focal_warning(sol.focal_scale, sol.focal_scale_std);
        if let (Some(warning), false) = (&focal_warning, self.focal_uncertain) {
            tracing::warn!(epoch = self.epoch + 1, "{warning}");
        }
        self.focal_uncertain = focal_warning.is_some();
        self.solution = Some(EpochSolution {
            planes_given,
            ctx,
            lambda,
            factor: 1.0,
        });
        // Planes that arrived while it ran.
        self.extend(n..self.planes.len());
        let reason = if self.epoch == 0 {
            EpochReason::First
        } else {
            EpochReason::Reestimate
        };
        self.epoch += 1;
        self.counts.epoch = self.epoch;
        // The epoch's scale from its whole cloud.
        let (mut cloud, pixels) = self.cloud_of(0..self.planes.len(), 1.0);
        let factor = cloud::scale_for(&self.scale, &cloud, &pixels).unwrap_or(1.0);
        if let Some(s) = self.solution.as_mut() {
            s.factor = factor;
        }
        cloud::apply_scale(&mut cloud, factor);
        self.counts.points = 0;
        Some((
            self.epoch,
            reason,
            stream::points_of(&cloud, 0..cloud.len()),
        ))
    }

    /// Fits the planes `range` (new since the epoch's solve) from solved neighbours.
    fn extend(&mut self, range: std::ops::Range<usize>) {
        let Some(sol) = self.solution.as_mut() else {
            return;
        };
        sol.planes_given.resize(self.planes.len(), None);
        // The better-connected plane of a cross first, so its partner can use it.
        let mut order: Vec<usize> = range.collect();
        let known_of = |c: usize, planes: &[Option<Vector3<f64>>]| -> Vec<(usize, Vector3<f64>)> {
            self.adjacency[c]
                .iter()
                .filter_map(|&(o, k)| planes[o as usize].map(|v| (k, v)))
                .collect()
        };
        order.sort_by_key(|&c| std::cmp::Reverse(known_of(c, &sol.planes_given).len()));
        for c in order {
            let known = known_of(c, &sol.planes_given);
            let partner = self.partner[c].and_then(|p| sol.planes_given[p as usize]);
            if known.len() < sol.ctx.min_crossings && partner.is_none() {
                continue;
            }
            if let Some(fit) = fit_plane(&self.crossings, &known, partner, &sol.ctx, None) {
                if (fit.outliers.len() as f64) <= 0.5 * known.len() as f64 {
                    sol.planes_given[c] = Some(fit.plane);
                }
            }
        }
        self.counts.planes_solved = sol.planes_given.iter().filter(|p| p.is_some()).count() as u64;
    }

    /// The cloud of planes `range` with the current solution, scaled by `factor`.
    fn cloud_of(&self, range: std::ops::Range<usize>, factor: f64) -> (Cloud, Vec<[f32; 2]>) {
        let mut cloud = Cloud {
            colors: Some(Vec::new()),
            frames: Some(Vec::new()),
            lasers: Some(Vec::new()),
            ..Default::default()
        };
        let mut pixels = Vec::new();
        let Some(sol) = &self.solution else {
            return (cloud, pixels);
        };
        let lambda = sol.lambda;
        for id in range {
            // In the given coordinates, those of the curves' points: the true rays are
            // (x/λ, y/λ, 1), so X and Y are scaled by 1/λ below.
            let Some(v) = sol.planes_given.get(id).copied().flatten() else {
                continue;
            };
            let plane = &self.planes[id];
            for curve in &plane.curves {
                if reconstruct::is_faint(curve, self.config.solve.min_curve_strength) {
                    continue;
                }
                cloud::push_curve(
                    &mut cloud,
                    Some(&mut pixels),
                    &v,
                    CurvePoints {
                        frame: plane.frame,
                        laser: plane.laser,
                        points: &curve.points,
                        points_px: &curve.points_px,
                        depth_sigmas: None,
                    },
                    self.colour.as_deref(),
                    &self.config.triangulate,
                );
            }
        }
        let (sx, sz) = ((factor / lambda) as f32, factor as f32);
        for p in &mut cloud.points {
            p[0] *= sx;
            p[1] *= sx;
            p[2] *= sz;
        }
        (cloud, pixels)
    }

    fn points_of(&self, range: std::ops::Range<usize>) -> Vec<Point> {
        let factor = self.solution.as_ref().map_or(1.0, |s| s.factor);
        let (cloud, _) = self.cloud_of(range, factor);
        stream::points_of(&cloud, 0..cloud.len())
    }

    /// The final solve over every curve, exactly as `crossline reconstruct` does it.
    /// The curves move into it (each is kept once, and this is the end of the scan):
    /// afterwards no more frames can be added.
    pub fn finish(&mut self) -> Result<Reconstruction, ReconstructError> {
        // A background solve still running is superseded.
        self.pending = None;
        // Frame by frame, each laser's curves in their order: the same planes, in the
        // same order, that `reconstruct_curves` makes of the frames' curve lists.
        let mut per_frame: Vec<Vec<Curve>> = vec![Vec::new(); self.frames];
        for p in std::mem::take(&mut self.planes) {
            if let Some(f) = per_frame.get_mut(p.frame as usize) {
                f.extend(p.curves);
            }
        }
        let rec = reconstruct::reconstruct_curves(
            per_frame,
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
            points.extend(out.points);
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
        // The solve runs in the background; empty frames poll it.
        for _ in 0..500 {
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
}
