//! The stages after extraction, shared by `reconstruct` and `serve`: curves are grouped
//! into planes, their crossings found and refined, the planes self-calibrated (or given),
//! and every curve point triangulated where its plane determines it.
//!
//! Owns [`Scan`], the state of a scan between extraction and the cloud, and
//! [`reconstruct_curves`], the one driver both callers use. Knows nothing of where frames
//! come from (files, dumps, cameras); the background policy and extraction live in
//! [`crate::extract`], the estimator in [`crate::solve`], triangulation in
//! [`crate::cloud`].
//!
//! # Stages
//! 1. [`Scan::add_frame`]: a frame's curves become one plane per laser
//!    ([`planes::PlaneCurves`]); their crossings are found in the segment indices (curves
//!    of one plane do not constrain it): an anchor's ([`anchors`]) with every earlier
//!    curve, any other frame's with the anchors' curves and its own.
//! 2. [`Scan::refine_crossings`]: crossings found on the simplified polylines move to the
//!    curves' dense points, each with the precision its two local fits predict.
//! 3. [`Scan::evidence`]: the crossings as the estimator sees them: crossings of two
//!    strong ridges and those of a faint one, each kind weighed by its own measured spread.
//! 4. [`crate::solve::calibrate`]: every pose of the projector and how well it is known.
//! 5. [`triangulate::cloud`]: every point whose depth its plane determines to
//!    `[triangulate] max_depth_sigma`, and that its crossings do not dispute.
//! 6. [`refusal`]: no cloud from planes most curves contradict, or that fit the crossings
//!    far worse than the extraction places them.

pub mod anchors;
mod live;
pub mod planes;
mod refusal;
pub mod report;
pub mod triangulate;

use std::time::Instant;

use image::RgbImage;
use nalgebra::Vector3;
use rayon::prelude::*;

use crate::camera::Camera;
use crate::cloud::{self, ScaleMode};
use crate::config::Config;
use crate::extract::Curve;
use crate::intersect::{Crossing, SegmentIndex};
use crate::solve::evidence::{CrossingClass, Evidence, Observation, PlaneSlot, RayModel};
use crate::solve::{self, Calibration};

pub(crate) use refusal::{refusal, Fit};

pub(crate) use planes::PlaneCurves;
pub use report::{ReconstructReport, Reconstruction, StageTimes, REPORT_VERSION};

/// Where the planes come from.
#[derive(Clone, Copy, Debug)]
pub enum PlaneSource<'a> {
    /// Self-calibration from the crossings (the product).
    SelfCalibrated,
    /// Known planes per frame and laser (e.g. a simulation's truth): the same pipeline
    /// with a perfectly calibrated projector, the yardstick of the self-calibration.
    Known(&'a [[Option<Vector3<f64>>; 2]]),
    /// Self-calibration started from these planes per frame and laser instead of its
    /// linear start (evaluation: from a simulation's truth it shows what the crossings
    /// determine when the start is perfect).
    StartedFrom(&'a [[Option<Vector3<f64>>; 2]]),
}

#[derive(Debug, thiserror::Error)]
pub enum PipelineError {
    #[error("solving the planes")]
    Solve(#[from] solve::SolveError),
    #[error("fixing the scale")]
    Scale(#[from] cloud::ScaleError),
    /// The self-calibrated planes failed the crossing check (see [`refusal`]): no cloud.
    /// The report says what was found.
    #[error("{reason}")]
    Refused {
        reason: String,
        report: Box<ReconstructReport>,
    },
}

/// Whether no point of `curve` reaches `min_strength` (curves read without strengths
/// count as strong).
pub(crate) fn is_faint(curve: &Curve, min_strength: f32) -> bool {
    !curve.strength.is_empty() && !curve.strength.iter().any(|&s| s >= min_strength)
}

/// A scan between extraction and the cloud.
pub struct Scan {
    frames: usize,
    frames_with_curves: usize,
    planes: Vec<PlaneCurves>,
    /// Per curve (global id, in plane order): its plane and its index in that plane.
    curve_plane: Vec<u32>,
    curve_local: Vec<u32>,
    /// Every curve so far, and the anchors' curves only.
    index: SegmentIndex,
    anchor_index: SegmentIndex,
    anchors: anchors::Anchors,
    /// The index cell (normalised units) and least crossing sine, to rebuild the anchors'.
    index_cell: f64,
    min_sin_angle: f64,
    /// Per plane, the global id of its first curve.
    plane_first_curve: Vec<u32>,
    /// Crossings of planes (`a`, `b` are plane ids) and the curves they are of.
    crossings: Vec<Crossing>,
    curve_ids: Vec<[u32; 2]>,
    /// Per crossing, the predicted deviation of its position (normalised units) from
    /// its refinement ([`crate::intersect::RefinedCrossing::sigma`]; 0: not refined).
    crossing_sigma: Vec<f64>,
    /// Crossings before this one are refined on the dense points.
    refined: usize,
    fresh: Vec<Crossing>,
}

impl Scan {
    pub fn new(camera: &Camera, config: &Config) -> Self {
        let index = SegmentIndex::for_image(
            camera.width,
            camera.height,
            camera.fx.max(camera.fy),
            config.solve.min_sin_angle,
        );
        let index_cell = f64::from(camera.width.max(camera.height))
            / crate::intersect::IMAGE_CELLS
            / camera.fx.max(camera.fy);
        Self {
            frames: 0,
            frames_with_curves: 0,
            planes: Vec::new(),
            curve_plane: Vec::new(),
            curve_local: Vec::new(),
            anchor_index: index.clone(),
            index,
            anchors: anchors::Anchors::new(config.solve.max_anchor_poses),
            index_cell,
            min_sin_angle: config.solve.min_sin_angle,
            plane_first_curve: Vec::new(),
            crossings: Vec::new(),
            curve_ids: Vec::new(),
            crossing_sigma: Vec::new(),
            refined: 0,
            fresh: Vec::new(),
        }
    }

    pub fn frames(&self) -> usize {
        self.frames
    }

    pub(crate) fn planes(&self) -> &[PlaneCurves] {
        &self.planes
    }

    pub fn num_curves(&self) -> usize {
        self.curve_plane.len()
    }

    pub fn num_crossings(&self) -> usize {
        self.crossings.len()
    }

    /// Adds the next frame's curves: its planes, and their crossings (see the module
    /// docs; not yet refined).
    pub fn add_frame(&mut self, curves: Vec<Curve>) {
        let frame = self.frames as u32;
        self.frames += 1;
        self.frames_with_curves += usize::from(!curves.is_empty());
        let admission = self.anchors.next_frame(!curves.is_empty());
        if admission.thinned {
            self.rebuild_anchor_index();
        }
        // A frame's own two lasers cross each other, at the cross's centre.
        let mut own = SegmentIndex::with_cell_size(self.index_cell, self.min_sin_angle);
        for plane in PlaneCurves::of_frame(frame, curves) {
            let id = self.planes.len() as u32;
            self.plane_first_curve.push(self.curve_plane.len() as u32);
            for (local, curve) in plane.curves.iter().enumerate() {
                let cid = self.curve_plane.len() as u32;
                self.curve_plane.push(id);
                self.curve_local.push(local as u32);
                self.fresh.clear();
                if admission.anchor {
                    self.index
                        .insert_into(cid, &curve.polyline, &mut self.fresh);
                    self.anchor_index.add(cid, &curve.polyline);
                } else {
                    self.anchor_index
                        .query_into(cid, &curve.polyline, &mut self.fresh);
                    own.insert_into(cid, &curve.polyline, &mut self.fresh);
                    self.index.add(cid, &curve.polyline);
                }
                for c in &self.fresh {
                    let (pa, pb) = (
                        self.curve_plane[c.a as usize],
                        self.curve_plane[c.b as usize],
                    );
                    if pa != pb {
                        self.crossings.push(Crossing { a: pa, b: pb, ..*c });
                        self.curve_ids.push([c.a, c.b]);
                    }
                }
            }
            self.planes.push(plane);
        }
    }

    /// The anchors' index anew, after the schedule thinned them.
    fn rebuild_anchor_index(&mut self) {
        let mut index = SegmentIndex::with_cell_size(self.index_cell, self.min_sin_angle);
        for (p, plane) in self.planes.iter().enumerate() {
            if self.anchors.is_anchor(plane.frame) {
                for (local, curve) in plane.curves.iter().enumerate() {
                    index.add(self.plane_first_curve[p] + local as u32, &curve.polyline);
                }
            }
        }
        self.anchor_index = index;
    }

    /// Refines the crossings found since the last call on the curves' dense points
    /// (`[intersect] refine_radius_px`), in parallel.
    pub fn refine_crossings(&mut self, camera: &Camera, config: &Config) {
        let radius = config.intersect.refine_radius_px / camera.fx.max(camera.fy);
        let planes = &self.planes;
        self.crossing_sigma.resize(self.crossings.len(), 0.0);
        if radius > 0.0 {
            self.crossings[self.refined..]
                .par_iter_mut()
                .zip(self.crossing_sigma[self.refined..].par_iter_mut())
                .for_each(|(c, sigma)| {
                    let a = planes[c.a as usize].dense_near(c.u, radius);
                    let b = planes[c.b as usize].dense_near(c.u, radius);
                    if let Some(r) = crate::intersect::refine_crossing(a, b, c.u, radius) {
                        c.u = r.u;
                        *sigma = r.sigma;
                    }
                });
        }
        self.refined = self.crossings.len();
    }

    fn curve(&self, cid: u32) -> &Curve {
        let (p, local) = (
            self.curve_plane[cid as usize],
            self.curve_local[cid as usize],
        );
        &self.planes[p as usize].curves[local as usize]
    }

    /// The crossings of curves, with each curve's point nearest the crossing and its
    /// ridge strength there, as the triangulation's crossing check needs them.
    fn curve_crossings(&self) -> Vec<cloud::CurveCrossing> {
        (0..self.crossings.len())
            .into_par_iter()
            .map(|k| self.curve_crossing(k))
            .collect()
    }

    /// Crossing `k` as the crossing check takes it.
    fn curve_crossing(&self, k: usize) -> cloud::CurveCrossing {
        let (c, [a, b]) = (&self.crossings[k], self.curve_ids[k]);
        let near = |cid: u32| {
            let (p, local) = (
                self.curve_plane[cid as usize],
                self.curve_local[cid as usize],
            );
            self.planes[p as usize].nearest_point(local as usize, c.u)
        };
        let at = [near(a), near(b)];
        let strength = |cid: u32, i: u32| {
            self.curve(cid)
                .strength
                .get(i as usize)
                .copied()
                .unwrap_or(0.0)
        };
        cloud::CurveCrossing {
            a,
            b,
            u: c.u,
            at,
            strength: [strength(a, at[0]), strength(b, at[1])],
        }
    }

    /// The class of a crossing (see [`Self::evidence`]).
    fn class_of(cc: &cloud::CurveCrossing, faint: [bool; 2], config: &Config) -> CrossingClass {
        let min_local = config.solve.min_crossing_strength;
        let strong =
            !faint[0] && !faint[1] && cc.strength.iter().all(|s| *s >= min_local || *s == 0.0);
        if strong {
            CrossingClass::Strong
        } else {
            CrossingClass::Faint
        }
    }

    /// The precision the extraction predicts for the strong crossings, pixels: the median
    /// over the crossings above `solve.min_sin_angle` of class strong ([`Self::class_of`])
    /// of each refined crossing's predicted deviation
    /// ([`crate::intersect::refine_crossing`]). The estimator's evidence keeps only those
    /// tied to an anchor of them; the prediction takes all, since it is a property of the
    /// curves. `None` without refined strong crossings.
    fn predicted_crossing_px(
        &self,
        curve_crossings: &[cloud::CurveCrossing],
        faint: &[bool],
        config: &Config,
        focal_px: f64,
    ) -> Option<f64> {
        let sigmas: Vec<f64> = self
            .crossings
            .iter()
            .zip(curve_crossings)
            .zip(&self.crossing_sigma)
            .filter(|((c, cc), sigma)| {
                **sigma > 0.0
                    && c.sin_angle >= config.solve.min_sin_angle
                    && Self::class_of(cc, [faint[cc.a as usize], faint[cc.b as usize]], config)
                        == CrossingClass::Strong
            })
            .map(|(_, sigma)| sigma * focal_px)
            .collect();
        crate::solve::median(sigmas)
    }

    /// Per curve, whether it is faint: no point reaches `solve.min_curve_strength`.
    fn faint_curves(&self, config: &Config) -> Vec<bool> {
        self.planes
            .iter()
            .flat_map(|p| &p.curves)
            .map(|c| is_faint(c, config.solve.min_curve_strength))
            .collect()
    }

    /// The estimator's evidence: a pose per frame with a crossing, its planes, and every
    /// crossing at an angle above `solve.min_sin_angle`, of class strong where both
    /// curves are strong (`min_curve_strength`) and both ridges at least
    /// `min_crossing_strength` there, faint otherwise. Also returns, per plane, its index
    /// in the evidence (`None` for planes without a crossing).
    fn evidence(
        &self,
        camera: &Camera,
        config: &Config,
        curve_crossings: &[cloud::CurveCrossing],
        faint: &[bool],
    ) -> (Evidence, Vec<Option<u32>>) {
        let frame_of = |plane: u32| self.planes[plane as usize].frame;
        // A crossing of two frames neither of which is an anchor (any more) ties two
        // poses that are each fitted on their own: it is left to the crossing check.
        let tied = |c: &Crossing| {
            let (fa, fb) = (frame_of(c.a), frame_of(c.b));
            fa == fb || self.anchors.is_anchor(fa) || self.anchors.is_anchor(fb)
        };
        let mut used = vec![false; self.planes.len()];
        for c in &self.crossings {
            if c.sin_angle >= config.solve.min_sin_angle && tied(c) {
                used[c.a as usize] = true;
                used[c.b as usize] = true;
            }
        }
        let mut pose_of_frame: Vec<Option<u32>> = vec![None; self.frames];
        let mut pose_frames = Vec::new();
        let mut slots = Vec::new();
        let mut plane_index = vec![None; self.planes.len()];
        for (i, p) in self.planes.iter().enumerate() {
            if !used[i] {
                continue;
            }
            let pose = *pose_of_frame[p.frame as usize].get_or_insert_with(|| {
                pose_frames.push(p.frame);
                (pose_frames.len() - 1) as u32
            });
            plane_index[i] = Some(slots.len() as u32);
            slots.push(PlaneSlot {
                pose,
                laser: p.laser,
            });
        }
        let crossings = self
            .crossings
            .iter()
            .zip(curve_crossings)
            .filter(|(c, _)| c.sin_angle >= config.solve.min_sin_angle && tied(c))
            .filter_map(|(c, cc)| {
                Some(Observation {
                    a: plane_index[c.a as usize]?,
                    b: plane_index[c.b as usize]?,
                    u: c.u,
                    sin_angle: c.sin_angle,
                    class: Self::class_of(cc, [faint[cc.a as usize], faint[cc.b as usize]], config),
                })
            })
            .collect();
        let anchors = pose_frames
            .iter()
            .map(|&f| self.anchors.is_anchor(f))
            .collect();
        let evidence = Evidence {
            anchors,
            pose_frames,
            planes: slots,
            crossings,
            focal_px: camera.fx.max(camera.fy),
            rays: RayModel::new(camera.distortion),
        };
        (evidence, plane_index)
    }
}

/// The planes of a scan as triangulation takes them.
pub(crate) enum Planes<'a> {
    /// Self-calibrated: `plane_index[i]` is plane `i`'s index in the evidence.
    Calibrated {
        calibration: &'a Calibration,
        plane_index: &'a [Option<u32>],
    },
    /// Given per plane, exactly (on the rays of the camera file).
    Known(Vec<Option<Vector3<f64>>>),
}

/// The stages after extraction: from each frame's curves to the scaled cloud (see the
/// module docs).
pub fn reconstruct_curves(
    per_frame: Vec<Vec<Curve>>,
    camera: &Camera,
    config: &Config,
    source: PlaneSource<'_>,
    scale: &ScaleMode,
    colour_source: Option<&RgbImage>,
) -> Result<Reconstruction, PipelineError> {
    let t = Instant::now();
    let mut scan = Scan::new(camera, config);
    for curves in per_frame {
        scan.add_frame(curves);
    }
    let add_s = t.elapsed().as_secs_f64();
    scan.refine_crossings(camera, config);
    let build_s = t.elapsed().as_secs_f64();
    tracing::debug!(add_s, refine_s = build_s - add_s, "scan built");
    reconstruct_scan(scan, build_s, camera, config, source, scale, colour_source)
}

/// [`reconstruct_curves`] of a scan built already (the live daemon builds its own frame
/// by frame, with the same [`Scan::add_frame`]); `build_s` is the time that took.
pub fn reconstruct_scan(
    scan: Scan,
    build_s: f64,
    camera: &Camera,
    config: &Config,
    source: PlaneSource<'_>,
    scale: &ScaleMode,
    colour_source: Option<&RgbImage>,
) -> Result<Reconstruction, PipelineError> {
    let mut times = StageTimes::default();
    let frames_with_laser = scan.frames_with_curves;
    let t = Instant::now();
    let curve_crossings = scan.curve_crossings();
    let faint = scan.faint_curves(config);
    let (evidence, plane_index) = scan.evidence(camera, config, &curve_crossings, &faint);
    let predicted_px =
        scan.predicted_crossing_px(&curve_crossings, &faint, config, evidence.focal_px);
    times.intersect_s = build_s + t.elapsed().as_secs_f64();
    tracing::debug!(
        s = t.elapsed().as_secs_f64(),
        "crossings checked and evidence made"
    );

    let t = Instant::now();
    // Every frame is extracted by now (offline, and the daemon's final solve): the dense
    // factorisations may take every core. The answer does not depend on it.
    let solve_params = solve::SolveParams {
        dense_threads: solve::dense::DenseThreads(rayon::current_num_threads()),
        ..config.solve.clone()
    };
    let calibration = match source {
        PlaneSource::SelfCalibrated => Some(solve::calibrate(&evidence, &solve_params)?),
        PlaneSource::StartedFrom(known) => {
            let start: Vec<Option<Vector3<f64>>> = evidence
                .planes
                .iter()
                .map(|slot| {
                    let frame = evidence.pose_frames[slot.pose as usize] as usize;
                    known
                        .get(frame)
                        .and_then(|f| f[usize::from(slot.laser & 1)])
                })
                .collect();
            Some(solve::calibrate_from(
                &evidence,
                &solve_params,
                Some(&start),
            )?)
        }
        PlaneSource::Known(_) => None,
    };
    let planes = match (&calibration, source) {
        (_, PlaneSource::Known(known)) => Planes::Known(
            scan.planes()
                .iter()
                .map(|p| {
                    known
                        .get(p.frame as usize)
                        .and_then(|f| f[usize::from(p.laser & 1)])
                })
                .collect(),
        ),
        (calibration, _) => match calibration {
            Some(calibration) => Planes::Calibrated {
                calibration,
                plane_index: &plane_index,
            },
            None => Planes::Known(Vec::new()),
        },
    };
    times.solve_s = t.elapsed().as_secs_f64();

    let t = Instant::now();
    let mut out = triangulate::cloud(
        &scan,
        &planes,
        &curve_crossings,
        &faint,
        colour_source,
        config,
    );
    let factor = cloud::scale_for(scale, &out.cloud, &out.pixels)?;
    cloud::apply_scale(&mut out.cloud, factor);
    times.triangulate_s = t.elapsed().as_secs_f64();
    let calibration = calibration.as_ref();
    let fit = calibration.and_then(|c| Fit::of(c, predicted_px));
    let refused = calibration.and_then(|_| refusal(&out.stats, fit));
    let warnings = doubts(calibration);
    for w in &warnings {
        tracing::warn!("{w}");
    }
    let mut rec = report::assemble(
        &scan,
        &evidence,
        calibration,
        out,
        frames_with_laser,
        scale,
        factor,
        camera,
        times,
    );
    rec.report.warnings = warnings;
    rec.report.crossing_precision_px = predicted_px;
    tracing::info!(
        predicted_px,
        fitted_px = calibration.map(|c| c.summary.spreads.map(|s| s.crossing_px[0])),
        "strong crossings: the extraction's predicted precision and the planes' fit"
    );
    if let Some(reason) = refused {
        rec.report.points = 0;
        rec.report.refused = Some(reason.clone());
        return Err(PipelineError::Refused {
            reason,
            report: Box::new(rec.report),
        });
    }
    Ok(rec)
}

/// Why a self-calibrated result is doubtful, in words for the log and the report: a
/// focal scale too uncertain, and a second solution that fits alike.
fn doubts(calibration: Option<&solve::Calibration>) -> Vec<String> {
    let Some(c) = calibration else {
        return Vec::new();
    };
    let mut out = Vec::new();
    if let Some(w) = solve::focal_warning(c.summary.focal_scale, c.summary.focal_scale_std) {
        out.push(w);
    }
    for alt in c.summary.alternatives.iter().filter(|a| a.ambiguous) {
        out.push(format!(
            "a second solution fits about as well (its cost is {:.1} higher, within \
             chance for the three unknowns of the planes' common shift) and its depths \
             differ from the cloud's by a median {:.2} %: the crosses do not fix the \
             shift; both are in the report. Sweep the cross over more of the scene, \
             roll it more, or check the cloud against a known distance",
            alt.delta_chi2,
            100.0 * alt.median_depth_difference
        ));
    }
    out
}

#[cfg(test)]
mod tests;
