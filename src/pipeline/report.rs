//! What a reconstruction found, as the `--report` JSON and the daemon's final report.
//!
//! # Report JSON, version 2
//! Version 2 replaced the counts of version 1's repair passes (motion fill, rescue,
//! re-solve, faint extension, joint refinement) by the estimator's own account of every
//! plane (`calibration`) and of the points it left out (`points_undetermined`). Within a
//! version keys are only ever added; readers should ignore keys they do not know.
//!
//! | key | meaning |
//! |---|---|
//! | `version` | 2 |
//! | `frames`, `frames_with_laser`, `curves`, `planes`, `crossings` | input counts (a plane is one laser of one frame) |
//! | `crossings_strong`, `crossings_faint` | crossings the estimator weighs, by class (a faint curve or ridge: its own spread) |
//! | `calibration` | [`crate::solve::calibrate::CalibrationSummary`]; `null` with known planes |
//! | `planes_in_global_solve` | planes of the linear start's global subset |
//! | `planes_solved` | planes with at least one point in the cloud |
//! | `max_depth_sigma`, `points_undetermined` | the triangulation's rule and the points it left out for it |
//! | `focal_scale`, `focal_scale_std`, `focal_px` | the (estimated) focal scale and the focal length it gives |
//! | `scale_mode`, `scale_factor` | how the global scale was fixed, and the factor applied |
//! | `points`, `triangulation` | the cloud, and what the other checks left out |
//! | `seconds` | wall seconds per stage, in sequence; `reconstruct` runs the crossing search beside the extraction, so its `intersect_s` is only what the search adds after the last frame |
//! | `warnings` | why the result is doubtful, as logged (empty when nothing is) |
//! | `crossing_precision_px` | the extraction's predicted precision of the strong crossings (pixels; median of each refined crossing's deviation from its two local fits), or `null` |
//! | `refused` | why no cloud was written although the planes were solved (the crossing check failed; `points` is then 0), or `null` |
//! | `unsolved` | why no plane was solved (the self-calibration failed: `points` is 0, and the counts above are what the extraction and the crossings found), or `null`; added 2026-12-07 |

use nalgebra::Vector3;
use serde::Serialize;

use super::triangulate::CloudOut;
use super::Record;
use crate::camera::Camera;
use crate::cloud::{ScaleMode, TriangulateStats};
use crate::ply::Cloud;
use crate::solve::calibrate::CalibrationSummary;
use crate::solve::evidence::{CrossingClass, Evidence};
use crate::solve::Calibration;

/// Version of the report JSON.
pub const REPORT_VERSION: u32 = 2;

/// Seconds spent in each stage.
#[derive(Clone, Debug, Default, Serialize)]
pub struct StageTimes {
    pub background_s: f64,
    pub extract_s: f64,
    pub intersect_s: f64,
    pub solve_s: f64,
    pub triangulate_s: f64,
}

/// See the module docs.
#[derive(Clone, Debug, Serialize)]
pub struct ReconstructReport {
    pub version: u32,
    pub frames: usize,
    /// Frames that could not be decoded and were skipped (counted as frames).
    pub frames_skipped: usize,
    pub frames_with_laser: usize,
    pub curves: usize,
    pub planes: usize,
    pub crossings: usize,
    pub crossings_strong: usize,
    pub crossings_faint: usize,
    pub calibration: Option<CalibrationSummary>,
    pub planes_in_global_solve: usize,
    pub planes_solved: usize,
    pub max_depth_sigma: f64,
    pub points_undetermined: usize,
    pub focal_scale: f64,
    pub focal_scale_std: Option<f64>,
    pub focal_px: [f64; 2],
    pub scale_mode: ScaleMode,
    pub scale_factor: f64,
    pub points: usize,
    pub triangulation: TriangulateStats,
    pub seconds: StageTimes,
    pub warnings: Vec<String>,
    pub refused: Option<String>,
    pub unsolved: Option<String>,
    /// The precision the extraction predicts for the strong crossings (pixels, median):
    /// what the planes' fit (`calibration.spreads.crossing_px[0]`) is judged against.
    pub crossing_precision_px: Option<f64>,
}

/// A finished reconstruction.
pub struct Reconstruction {
    pub cloud: Cloud,
    /// Distorted pixel of every cloud point.
    pub pixels: Vec<[f32; 2]>,
    pub report: ReconstructReport,
    /// Per plane (one laser of one frame, in frame order): the plane `v · X = 1` in the
    /// output's (scaled) camera frame, where it was solved.
    pub planes: Vec<Option<Vector3<f64>>>,
}

/// The report and the reconstruction from the stages' outputs.
#[allow(clippy::too_many_arguments)]
pub(crate) fn assemble(
    scan: &Record,
    evidence: &Evidence,
    calibration: Option<&Calibration>,
    out: CloudOut,
    frames_with_laser: usize,
    scale: &ScaleMode,
    factor: f64,
    camera: &Camera,
    seconds: StageTimes,
) -> Reconstruction {
    let class_count = |k: CrossingClass| evidence.crossings.iter().filter(|c| c.class == k).count();
    let (focal_scale, focal_scale_std) = calibration.map_or((1.0, None), |c| {
        (c.summary.focal_scale, c.summary.focal_scale_std)
    });
    let report = ReconstructReport {
        version: REPORT_VERSION,
        frames: scan.frames(),
        frames_skipped: 0,
        frames_with_laser,
        curves: scan.num_curves(),
        planes: scan.planes().len(),
        crossings: scan.num_crossings(),
        crossings_strong: class_count(CrossingClass::Strong),
        crossings_faint: class_count(CrossingClass::Faint),
        calibration: calibration.map(|c| c.summary.clone()),
        planes_in_global_solve: calibration.map_or(0, |c| c.summary.planes_in_global_start),
        planes_solved: out.planes_with_points,
        max_depth_sigma: out.max_depth_sigma,
        points_undetermined: out.undetermined_points,
        focal_scale,
        focal_scale_std,
        focal_px: [camera.fx * focal_scale, camera.fy * focal_scale],
        scale_mode: scale.clone(),
        scale_factor: factor,
        points: out.cloud.len(),
        triangulation: out.stats,
        seconds,
        warnings: Vec::new(),
        refused: None,
        unsolved: None,
        crossing_precision_px: None,
    };
    Reconstruction {
        planes: out.planes.iter().map(|p| p.map(|v| v / factor)).collect(),
        cloud: out.cloud,
        pixels: out.pixels,
        report,
    }
}
