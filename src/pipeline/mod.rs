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
//!    curves' dense points, each with the precision its two local fits predict; each is
//!    then made once as the crossing check takes it (each curve's point nearest it).
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
mod record;
mod refusal;
pub mod report;
pub mod triangulate;

use std::sync::Arc;
use std::time::Instant;

use image::RgbImage;
use nalgebra::Vector3;
use rayon::prelude::*;

use crate::camera::Camera;
use crate::cloud::{self, ScaleMode};
use crate::config::Config;
use crate::extract::Curve;
use crate::intersect::{Crossing, SegmentIndex};

use crate::solve::{self, Calibration};

pub(crate) use refusal::{refusal, Fit};

pub(crate) use live::Placing;
pub(crate) use planes::PlaneCurves;
pub use record::Record;
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
    /// Self-calibration with these planes per frame and laser (an earlier estimate's: the
    /// daemon's last epoch) as one more start beside its own two
    /// ([`crate::solve::calibrate_until`]); where they lead to the solution the cold
    /// starts find, the answer is the cold one, as with [`Self::SelfCalibrated`]. The
    /// daemon's final solve, where the cold starts alone gave no cloud.
    AlsoFrom(&'a [[Option<Vector3<f64>>; 2]]),
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
    /// The self-calibration found no planes: no cloud. The report says what the
    /// extraction and the crossings found, and why (`unsolved`).
    #[error("solving the planes")]
    Unsolved {
        #[source]
        error: solve::SolveError,
        report: Box<ReconstructReport>,
    },
}

impl PipelineError {
    /// The report of what was found, where the error carries one (no cloud: the planes
    /// refused, or none solved).
    pub fn report_mut(&mut self) -> Option<&mut ReconstructReport> {
        match self {
            Self::Refused { report, .. } | Self::Unsolved { report, .. } => Some(report),
            Self::Solve(_) | Self::Scale(_) => None,
        }
    }

    /// [`Self::report_mut`], taken.
    pub fn into_report(self) -> Option<ReconstructReport> {
        match self {
            Self::Refused { report, .. } | Self::Unsolved { report, .. } => Some(*report),
            Self::Solve(_) | Self::Scale(_) => None,
        }
    }
}

/// Whether no point of `curve` reaches `min_strength` (curves read without strengths
/// count as strong).
pub(crate) fn is_faint(curve: &Curve, min_strength: f32) -> bool {
    !curve.strength.is_empty() && !curve.strength.iter().any(|&s| s >= min_strength)
}

/// A scan between extraction and the cloud: what it has seen ([`Record`]) and the
/// indices that find each new curve's crossings.
pub struct Scan {
    record: Record,
    /// Every curve so far, and the anchors' curves only.
    index: SegmentIndex,
    anchor_index: SegmentIndex,
    /// The index cell (normalised units) and least crossing sine, to rebuild the anchors'.
    index_cell: f64,
    min_sin_angle: f64,
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
            record: Record {
                frames: 0,
                frames_with_curves: 0,
                planes: Vec::new(),
                curve_plane: Vec::new(),
                curve_local: Vec::new(),
                anchors: anchors::Anchors::new(config.solve.max_anchor_poses),
                plane_first_curve: Vec::new(),
                frame_first_plane: Vec::new(),
                frame_first_crossing: Vec::new(),
                crossings: Vec::new(),
                curve_ids: Vec::new(),
                crossing_sigma: Vec::new(),
                curve_crossings: Vec::new(),
            },
            anchor_index: index.clone(),
            index,
            index_cell,
            min_sin_angle: config.solve.min_sin_angle,
            refined: 0,
            fresh: Vec::new(),
        }
    }

    pub fn frames(&self) -> usize {
        self.record.frames()
    }

    pub(crate) fn planes(&self) -> &[Arc<PlaneCurves>] {
        self.record.planes()
    }

    pub fn num_curves(&self) -> usize {
        self.record.num_curves()
    }

    pub fn num_crossings(&self) -> usize {
        self.record.num_crossings()
    }

    /// What the scan has seen so far.
    pub fn record(&self) -> &Record {
        &self.record
    }

    /// What the scan has seen so far, for a live epoch's own thread: its planes are
    /// shared, the rest (crossings, per curve ids) copied.
    pub fn snapshot(&self) -> Record {
        debug_assert_eq!(
            self.refined,
            self.record.crossings.len(),
            "unrefined crossings"
        );
        self.record.clone()
    }

    /// Adds the next frame's curves: its planes, and their crossings (see the module
    /// docs; not yet refined).
    pub fn add_frame(&mut self, curves: Vec<Curve>) {
        let record = &mut self.record;
        let frame = record.frames as u32;
        record.frames += 1;
        record.frame_first_plane.push(record.planes.len() as u32);
        record
            .frame_first_crossing
            .push(record.crossings.len() as u32);
        record.frames_with_curves += usize::from(!curves.is_empty());
        let admission = record.anchors.next_frame(!curves.is_empty());
        if admission.thinned {
            self.rebuild_anchor_index();
        }
        // A frame's own two lasers cross each other, at the cross's centre.
        let mut own = SegmentIndex::with_cell_size(self.index_cell, self.min_sin_angle);
        for plane in PlaneCurves::of_frame(frame, curves) {
            let id = self.record.planes.len() as u32;
            self.record
                .plane_first_curve
                .push(self.record.curve_plane.len() as u32);
            for (local, curve) in plane.curves.iter().enumerate() {
                let cid = self.record.curve_plane.len() as u32;
                self.record.curve_plane.push(id);
                self.record.curve_local.push(local as u32);
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
                        self.record.curve_plane[c.a as usize],
                        self.record.curve_plane[c.b as usize],
                    );
                    if pa != pb {
                        self.record.crossings.push(Crossing { a: pa, b: pb, ..*c });
                        self.record.curve_ids.push([c.a, c.b]);
                    }
                }
            }
            self.record.planes.push(Arc::new(plane));
        }
    }

    /// The anchors' index anew, after the schedule thinned them.
    fn rebuild_anchor_index(&mut self) {
        let mut index = SegmentIndex::with_cell_size(self.index_cell, self.min_sin_angle);
        for (p, plane) in self.record.planes.iter().enumerate() {
            if self.record.anchors.is_anchor(plane.frame) {
                for (local, curve) in plane.curves.iter().enumerate() {
                    index.add(
                        self.record.plane_first_curve[p] + local as u32,
                        &curve.polyline,
                    );
                }
            }
        }
        self.anchor_index = index;
    }

    /// Refines the crossings found since the last call on the curves' dense points
    /// (`[intersect] refine_radius_px`), in parallel, and makes them as the crossing
    /// check takes them ([`Record::curve_crossings`]).
    pub fn refine_crossings(&mut self, camera: &Camera, config: &Config) {
        let radius = config.intersect.refine_radius_px / camera.fx.max(camera.fy);
        let planes = &self.record.planes;
        self.record
            .crossing_sigma
            .resize(self.record.crossings.len(), 0.0);
        if radius > 0.0 {
            self.record.crossings[self.refined..]
                .par_iter_mut()
                .zip(self.record.crossing_sigma[self.refined..].par_iter_mut())
                .for_each(|(c, sigma)| {
                    let a = planes[c.a as usize].dense_near(c.u, radius);
                    let b = planes[c.b as usize].dense_near(c.u, radius);
                    if let Some(r) = crate::intersect::refine_crossing(a, b, c.u, radius) {
                        c.u = r.u;
                        *sigma = r.sigma;
                    }
                });
        }
        self.refined = self.record.crossings.len();
        self.record.extend_curve_crossings();
    }
}

/// The planes of a scan as triangulation takes them.
pub(crate) enum Planes<'a> {
    /// Self-calibrated: `plane_index[i]` is plane `i`'s index in the evidence; the
    /// planes of a frame placed against the calibration after it, if any, from `placed`.
    Calibrated {
        calibration: &'a Calibration,
        plane_index: &'a [Option<u32>],
        placed: Option<live::Placed<'a>>,
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
    reconstruct_scan(&scan, build_s, camera, config, source, scale, colour_source)
}

/// [`reconstruct_curves`] of a scan built already (the live daemon builds its own frame
/// by frame, with the same [`Scan::add_frame`]); `build_s` is the time that took.
pub fn reconstruct_scan(
    scan: &Scan,
    build_s: f64,
    camera: &Camera,
    config: &Config,
    source: PlaneSource<'_>,
    scale: &ScaleMode,
    colour_source: Option<&RgbImage>,
) -> Result<Reconstruction, PipelineError> {
    let record = &scan.record;
    let mut times = StageTimes::default();
    let frames_with_laser = record.frames_with_curves;
    let t = Instant::now();
    let curve_crossings = record.curve_crossings();
    let faint = record.faint_curves(config);
    let (evidence, plane_index) = record.evidence(camera, config, curve_crossings, &faint);
    let predicted_px =
        record.predicted_crossing_px(curve_crossings, &faint, config, evidence.focal_px);
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
    // Per plane of the evidence, the given planes of its frame and laser.
    let start_of = |given: &[[Option<Vector3<f64>>; 2]]| -> Vec<Option<Vector3<f64>>> {
        evidence
            .planes
            .iter()
            .map(|slot| {
                let frame = evidence.pose_frames[slot.pose as usize] as usize;
                given
                    .get(frame)
                    .and_then(|f| f[usize::from(slot.laser & 1)])
            })
            .collect()
    };
    let calibrated = match source {
        PlaneSource::SelfCalibrated => solve::calibrate(&evidence, &solve_params).map(Some),
        PlaneSource::StartedFrom(known) => {
            solve::calibrate_from(&evidence, &solve_params, Some(&start_of(known))).map(Some)
        }
        PlaneSource::AlsoFrom(earlier) => solve::calibrate_until(
            &evidence,
            &solve_params,
            Some(&start_of(earlier)),
            &solve::Cancel::default(),
        )
        .map(Some),
        PlaneSource::Known(_) => Ok(None),
    };
    // A failed self-calibration still reports what the extraction and the crossings
    // found: the cloud is empty, and the report says why.
    let (calibration, unsolved) = match calibrated {
        Ok(calibration) => (calibration, None),
        Err(e) => (None, Some(e)),
    };
    let planes = match (&calibration, source) {
        (_, PlaneSource::Known(known)) => Planes::Known(
            record
                .planes()
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
                placed: None,
            },
            None => Planes::Known(Vec::new()),
        },
    };
    times.solve_s = t.elapsed().as_secs_f64();

    let t = Instant::now();
    let mut out = triangulate::cloud(
        record,
        &planes,
        0..record.planes.len(),
        curve_crossings,
        &faint,
        colour_source,
        config,
    );
    let factor = match unsolved {
        Some(_) => 1.0,
        None => cloud::scale_for(scale, &out.cloud, &out.pixels)?,
    };
    cloud::apply_scale(&mut out.cloud, factor);
    times.triangulate_s = t.elapsed().as_secs_f64();
    let calibration = calibration.as_ref();
    let fit = calibration.and_then(|c| Fit::of(c, predicted_px));
    let refused = calibration.and_then(|_| refusal(&out.stats, fit));
    let mut warnings = doubts(calibration, &out, config.triangulate.max_depth_sigma);
    if refused.is_none() && calibration.is_some() {
        warnings.extend(refusal::doubts(&out.stats));
    }
    for w in &warnings {
        tracing::warn!("{w}");
    }
    let mut rec = report::assemble(
        record,
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
    if let Some(error) = unsolved {
        rec.report.points = 0;
        rec.report.unsolved = Some(error.to_string());
        return Err(PipelineError::Unsolved {
            error,
            report: Box::new(rec.report),
        });
    }
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
/// focal scale too uncertain, a second solution that fits alike, and most of the
/// points left out by the depth rule (`max_sigma`) for `cloud`'s planes.
fn doubts(
    calibration: Option<&solve::Calibration>,
    cloud: &triangulate::CloudOut,
    max_sigma: f64,
) -> Vec<String> {
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
    out.extend(mostly_undetermined(
        cloud.undetermined_points,
        cloud.cloud.len(),
        max_sigma,
    ));
    out
}

/// The doubt when most curve points are left out because their planes do not fix
/// their depth (`undetermined` of them, against `kept` in the cloud): the cloud is then
/// the part of the scene that the crossings fix, and the user should know that the
/// rest was not lost to noise but to geometry.
fn mostly_undetermined(undetermined: usize, kept: usize, max_sigma: f64) -> Option<String> {
    (undetermined > kept).then(|| {
        format!(
            "{:.0} % of the curve points are left out because the crossings do not fix \
             their depth to {:.2} % (one deviation): where the stripes crossed, the scene \
             is nearly flat or the projector barely moved. The cloud is the part the \
             crossings fix; sweep the cross over more relief, or move it more",
            100.0 * undetermined as f64 / (undetermined + kept) as f64,
            100.0 * max_sigma
        )
    })
}

#[cfg(test)]
mod tests;
