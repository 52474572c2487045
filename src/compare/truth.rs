//! Evaluation against the simulator's ground truth: for every reconstructed point, the
//! true depth on the same camera ray, the global scale the self-calibration cannot
//! observe, relative depth errors, the planes whose points are wrong together
//! ([`super::planes`]), and the coverage of the lit image area.
//!
//! The truth is reached through the small [`GroundTruth`] trait so that this module does
//! not depend on the simulator's types; the simulator's output folder implements it.

use nalgebra::Vector3;
use rayon::prelude::*;
use serde::Serialize;

use super::planes::{plane_errors, PlaneIds};
use super::stats::{median_mut, ErrorStats};
use crate::camera::Camera;

/// What the evaluation needs to know about the simulated scene.
pub trait GroundTruth: Sync {
    /// The camera that saw the scene (with its distortion).
    fn camera(&self) -> &Camera;
    /// Depth (camera `Z`) of the first surface on the ray from the camera centre along
    /// `ray_in_camera` (any positive multiple of the direction, e.g. `(x, y, 1)`);
    /// `None` when the ray meets no surface.
    fn true_depth(&self, ray_in_camera: &Vector3<f64>) -> Option<f64>;
    /// Pixels lit by a laser in any frame, row-major, `width × height`.
    fn lit_mask(&self) -> &[bool];
    /// The lit pixels where the stripe stood clear of the sensor noise in some frame,
    /// when the truth knows (same layout as [`Self::lit_mask`]). A stripe attenuated
    /// to nothing (red light after metres of water) is lit, but no camera sees it.
    fn visible_mask(&self) -> Option<&[bool]> {
        None
    }
}

#[derive(Clone, Debug)]
pub struct TruthParams {
    /// A point is an outlier when `|s·Z − Z_true| / Z_true` exceeds this (0.02 = 2 %).
    pub outlier_relative: f64,
    /// A lit pixel counts as covered when a point projects within this radius.
    pub coverage_radius_px: f64,
    /// A plane (one frame's one laser) is wrong when the median relative error of its
    /// points exceeds this (0.02 = 2 %).
    pub wrong_plane_relative: f64,
}

impl Default for TruthParams {
    fn default() -> Self {
        Self {
            outlier_relative: 0.02,
            coverage_radius_px: 2.0,
            wrong_plane_relative: 0.02,
        }
    }
}

#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Coverage {
    pub lit_pixels: u64,
    pub covered_lit_pixels: u64,
    /// `covered_lit_pixels / lit_pixels` (0 when nothing is lit).
    pub fraction: f64,
    pub radius_px: f64,
}

#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TruthReport {
    pub points: usize,
    /// Points with a surface on their ray, over which errors are measured.
    pub evaluated: usize,
    /// Points whose ray meets no surface of the scene.
    pub no_surface: usize,
    /// Points behind the camera or not finite.
    pub invalid: usize,
    /// Median of `Z_true / Z`: the robust start.
    pub scale_median: f64,
    /// Least squares of the relative errors over the inliers: the scale reported.
    pub scale: f64,
    pub outlier_relative: f64,
    /// Share of evaluated points whose relative error exceeds `outlier_relative`.
    pub outlier_fraction: f64,
    /// Statistics of `|s·Z − Z_true| / Z_true` (dimensionless).
    pub relative_error: ErrorStats,
    pub wrong_plane_relative: f64,
    /// Planes (frame, laser) with an evaluated point; `None` (JSON `null`), as are the
    /// three below, when the cloud does not say which plane each point lies on.
    pub planes_evaluated: Option<usize>,
    /// Planes whose median relative error exceeds `wrong_plane_relative`.
    pub wrong_planes: Option<usize>,
    /// Evaluated points on wrong planes.
    pub points_on_wrong_planes: Option<usize>,
    /// `points_on_wrong_planes / evaluated`.
    pub points_on_wrong_planes_fraction: Option<f64>,
    /// How well the cloud's `depth_sigma` predicts its errors, where it has them; set by
    /// the caller ([`super::planes::uncertainty_check`]).
    pub uncertainty: Option<super::planes::UncertaintyCheck>,
    pub coverage: Coverage,
    /// Coverage of the visible part of the lit area ([`GroundTruth::visible_mask`]).
    pub coverage_visible: Option<Coverage>,
    /// Relative error of every input point, `NaN` where there is none (no surface,
    /// invalid); for plots and coloured clouds, not serialised.
    #[serde(skip)]
    pub per_point: Vec<f32>,
    /// The same errors with their sign, `(s·Z − Z_true) / Z_true`; not serialised.
    #[serde(skip)]
    pub per_point_signed: Vec<f32>,
}

#[derive(Debug, thiserror::Error)]
pub enum TruthError {
    #[error("lit mask has {found} entries, expected width × height = {expected}")]
    MaskSize { expected: usize, found: usize },
    #[error("{points} points but {frames} frame and {lasers} laser labels")]
    PlaneIdsLength {
        points: usize,
        frames: usize,
        lasers: usize,
    },
}

/// Evaluates `points` (camera frame, reconstruction scale) against `truth`, without
/// the per-plane counts.
pub fn evaluate_against_truth(
    points: &[[f32; 3]],
    truth: &dyn GroundTruth,
    params: &TruthParams,
) -> Result<TruthReport, TruthError> {
    evaluate_cloud_against_truth(points, None, truth, params)
}

/// Evaluates `points` (camera frame, reconstruction scale) against `truth`; with
/// `planes` (which plane triangulated each point), also counts the wrong planes.
pub fn evaluate_cloud_against_truth(
    points: &[[f32; 3]],
    planes: Option<PlaneIds>,
    truth: &dyn GroundTruth,
    params: &TruthParams,
) -> Result<TruthReport, TruthError> {
    if let Some(ids) = planes {
        if ids.frames.len() != points.len() || ids.lasers.len() != points.len() {
            return Err(TruthError::PlaneIdsLength {
                points: points.len(),
                frames: ids.frames.len(),
                lasers: ids.lasers.len(),
            });
        }
    }
    let camera = truth.camera();
    let (w, h) = (camera.width as usize, camera.height as usize);
    let lit = truth.lit_mask();
    let visible = truth.visible_mask();
    for mask in std::iter::once(lit).chain(visible) {
        if mask.len() != w * h {
            return Err(TruthError::MaskSize {
                expected: w * h,
                found: mask.len(),
            });
        }
    }
    // (estimated depth, true depth); NaN true depth = no surface, NaN estimate = invalid.
    let depths: Vec<(f64, f64)> = points
        .par_iter()
        .map(|p| {
            let v = Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64);
            if !(v.iter().all(|c| c.is_finite()) && v.z > 0.0) {
                return (f64::NAN, f64::NAN);
            }
            let ray = v / v.z;
            match truth.true_depth(&ray) {
                Some(z) if z.is_finite() && z > 0.0 => (v.z, z),
                _ => (v.z, f64::NAN),
            }
        })
        .collect();
    let invalid = depths.iter().filter(|d| d.0.is_nan()).count();
    let no_surface = depths
        .iter()
        .filter(|d| !d.0.is_nan() && d.1.is_nan())
        .count();
    let valid = || depths.iter().filter(|d| !d.0.is_nan() && !d.1.is_nan());

    let mut ratios: Vec<f64> = valid().map(|&(z, zt)| zt / z).collect();
    let scale_median = median_mut(&mut ratios);
    drop(ratios);
    // Refine: minimise Σ ((s·Z − Z_t)/Z_t)² over the inliers, i.e. with r = Z/Z_t,
    // s = Σ r / Σ r²; the inlier set follows the scale.
    let mut scale = scale_median;
    if scale.is_finite() {
        for _ in 0..20 {
            let (mut sum, mut sum_sq) = (0.0, 0.0);
            for &(z, zt) in valid() {
                let r = z / zt;
                if (scale * r - 1.0).abs() <= params.outlier_relative {
                    sum += r;
                    sum_sq += r * r;
                }
            }
            if sum_sq <= 0.0 {
                break;
            }
            let next = sum / sum_sq;
            let change = (next - scale).abs() / scale;
            scale = next;
            if change < 1e-12 {
                break;
            }
        }
    }
    let mut errors: Vec<f64> = valid()
        .map(|&(z, zt)| (scale * z - zt).abs() / zt)
        .collect();
    let relative_error = ErrorStats::from_values(&mut errors, &[params.outlier_relative]);
    drop(errors);
    let per_point_signed: Vec<f32> = depths
        .iter()
        .map(|&(z, zt)| ((scale * z - zt) / zt) as f32)
        .collect();
    let per_point: Vec<f32> = per_point_signed.iter().map(|e| e.abs()).collect();
    let by_plane =
        planes.and_then(|ids| plane_errors(&per_point, ids, params.wrong_plane_relative));
    let outlier_fraction = relative_error.over.first().map_or(0.0, |e| e.fraction);
    Ok(TruthReport {
        points: points.len(),
        evaluated: relative_error.count,
        no_surface,
        invalid,
        scale_median,
        scale,
        outlier_relative: params.outlier_relative,
        outlier_fraction,
        relative_error,
        wrong_plane_relative: params.wrong_plane_relative,
        planes_evaluated: by_plane.as_ref().map(|p| p.planes_evaluated),
        wrong_planes: by_plane.as_ref().map(|p| p.wrong_planes),
        points_on_wrong_planes: by_plane.as_ref().map(|p| p.points_on_wrong_planes),
        points_on_wrong_planes_fraction: by_plane
            .as_ref()
            .map(|p| p.points_on_wrong_planes_fraction),
        uncertainty: None,
        coverage: coverage(points, camera, lit, params.coverage_radius_px),
        coverage_visible: visible.map(|v| coverage(points, camera, v, params.coverage_radius_px)),
        per_point,
        per_point_signed,
    })
}

/// Share of the lit pixels with a point projecting within `radius_px` of their centre.
pub fn coverage(points: &[[f32; 3]], camera: &Camera, lit: &[bool], radius_px: f64) -> Coverage {
    let (w, h) = (camera.width as i64, camera.height as i64);
    let mut covered = vec![false; lit.len()];
    let r = radius_px.max(0.0);
    let reach = r.ceil() as i64;
    for p in points {
        let v = Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64);
        let Some([u, vv]) = camera.pixel_from_camera(&v) else {
            continue;
        };
        if !(u.is_finite() && vv.is_finite()) {
            continue;
        }
        let (cu, cv) = (u.round() as i64, vv.round() as i64);
        for y in (cv - reach).max(0)..=(cv + reach).min(h - 1) {
            for x in (cu - reach).max(0)..=(cu + reach).min(w - 1) {
                let (dx, dy) = (x as f64 - u, y as f64 - vv);
                if dx * dx + dy * dy <= r * r {
                    covered[(y * w + x) as usize] = true;
                }
            }
        }
    }
    let lit_pixels = lit.iter().filter(|&&l| l).count() as u64;
    let covered_lit_pixels = lit.iter().zip(&covered).filter(|(l, c)| **l && **c).count() as u64;
    Coverage {
        lit_pixels,
        covered_lit_pixels,
        fraction: if lit_pixels == 0 {
            0.0
        } else {
            covered_lit_pixels as f64 / lit_pixels as f64
        },
        radius_px: r,
    }
}

/// A folder written by `crossline simulate` is a ground truth: exact ray casting in its
/// scene, and its lit mask.
impl GroundTruth for crate::simulate::SimDir {
    fn camera(&self) -> &Camera {
        &self.camera
    }

    fn true_depth(&self, ray_in_camera: &Vector3<f64>) -> Option<f64> {
        self.scene.ray_depth(ray_in_camera)
    }

    fn lit_mask(&self) -> &[bool] {
        &self.lit
    }

    fn visible_mask(&self) -> Option<&[bool]> {
        Some(&self.visible)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Distortion;

    /// A wall `z = 4 + 0.5 x` that ends above `y = −1` (rays above it see nothing) and a
    /// sphere of radius 0.5 at `(0.3, 0, 2.5)` in front of it, seen by a distorted camera;
    /// the lit area is the band of rows 100..140.
    struct Analytic {
        camera: Camera,
        lit: Vec<bool>,
        /// The left half of the band, when given.
        visible: Option<Vec<bool>>,
    }

    impl Analytic {
        fn new() -> Self {
            let camera = Camera {
                width: 320,
                height: 240,
                fx: 300.0,
                fy: 302.0,
                cx: 161.0,
                cy: 118.5,
                skew: 0.0,
                distortion: Distortion {
                    k1: -0.12,
                    k2: 0.03,
                    p1: 0.001,
                    p2: -0.0005,
                    ..Default::default()
                },
            };
            let lit = (0..240 * 320)
                .map(|i| (100..140).contains(&(i / 320)))
                .collect();
            Self {
                camera,
                lit,
                visible: None,
            }
        }
    }

    impl GroundTruth for Analytic {
        fn camera(&self) -> &Camera {
            &self.camera
        }

        fn true_depth(&self, ray: &Vector3<f64>) -> Option<f64> {
            let centre = Vector3::new(0.3, 0.0, 2.5);
            // |t·ray − c|² = r²
            let a = ray.norm_squared();
            let b = -2.0 * ray.dot(&centre);
            let c = centre.norm_squared() - 0.25;
            let disc = b * b - 4.0 * a * c;
            if disc >= 0.0 {
                let t = (-b - disc.sqrt()) / (2.0 * a);
                if t > 0.0 {
                    return Some(t * ray.z);
                }
            }
            // z − 0.5 x = 4
            let denom = ray.z - 0.5 * ray.x;
            if denom <= 0.0 {
                return None;
            }
            let t = 4.0 / denom;
            (t * ray.y >= -1.0).then_some(t * ray.z)
        }

        fn lit_mask(&self) -> &[bool] {
            &self.lit
        }

        fn visible_mask(&self) -> Option<&[bool]> {
            self.visible.as_deref()
        }
    }

    #[test]
    fn recovers_scale_errors_outliers_and_coverage() {
        let truth = Analytic::new();
        let scale = 1.25;
        let mut points = Vec::new();
        let mut k = 0usize;
        // Points on the left half of the lit band: ±0.5 % depth noise alternating in runs
        // of ten (as many of each sign), every tenth point 20 % too far.
        for v in 100..140 {
            for u in 0..160 {
                let ray = truth
                    .camera
                    .ray_from_pixel(u as f64, v as f64)
                    .expect("ray");
                let z = truth.true_depth(&ray).expect("surface");
                let factor = if k % 10 == 9 {
                    1.2
                } else if (k / 10).is_multiple_of(2) {
                    1.005
                } else {
                    0.995
                };
                k += 1;
                let p = ray * (z * factor / scale);
                points.push([p.x as f32, p.y as f32, p.z as f32]);
            }
        }
        let on_surface = points.len();
        // Rays above the wall's top edge meet nothing; one point behind the camera.
        for i in 0..37 {
            points.push([-0.2 + 0.01 * i as f32, -1.5, 1.0]);
        }
        points.push([0.0, 0.0, -1.0]);
        let r = evaluate_against_truth(&points, &truth, &TruthParams::default()).expect("eval");
        assert_eq!(r.points, on_surface + 38);
        assert_eq!(r.evaluated, on_surface);
        assert_eq!(r.no_surface, 37);
        assert_eq!(r.invalid, 1);
        assert_eq!(r.per_point.len(), r.points);
        assert!(r.per_point[on_surface..].iter().all(|e| e.is_nan()));
        assert!((r.per_point[9] - 0.2).abs() < 2e-3);
        assert!((r.scale / scale - 1.0).abs() < 1e-4, "scale {}", r.scale);
        assert!(
            (r.relative_error.median - 0.005).abs() < 2e-4,
            "{:?}",
            r.relative_error
        );
        assert!(
            (r.outlier_fraction - 0.1).abs() < 1e-3,
            "{}",
            r.outlier_fraction
        );
        assert!((r.relative_error.max - 0.2).abs() < 2e-3);
        // Left half of the band, plus up to two columns reached by the radius.
        assert_eq!(r.coverage.lit_pixels, 40 * 320);
        let f = r.coverage.fraction;
        assert!((0.5..=162.0 / 320.0 + 1e-9).contains(&f), "coverage {f}");
        assert_eq!(r.coverage_visible, None);

        // Where only the left half of the band was visible, all of that is covered.
        let mut truth = truth;
        truth.visible = Some(
            (0..240 * 320)
                .map(|i| truth.lit[i] && i % 320 < 160)
                .collect(),
        );
        let r = evaluate_against_truth(&points, &truth, &TruthParams::default()).expect("eval");
        let v = r.coverage_visible.expect("visible mask given");
        assert_eq!(v.lit_pixels, 40 * 160);
        assert_eq!(v.covered_lit_pixels, 40 * 160);
        assert_eq!(r.coverage.fraction, f);
    }

    #[test]
    fn nothing_covered_and_bad_masks() {
        let mut truth = Analytic::new();
        // A point projecting outside the lit band covers nothing of it.
        let ray = truth.camera.ray_from_pixel(50.0, 20.0).expect("ray");
        let p = [ray.x as f32 * 3.0, ray.y as f32 * 3.0, 3.0];
        let r = evaluate_against_truth(&[p], &truth, &TruthParams::default()).expect("eval");
        assert_eq!(r.coverage.covered_lit_pixels, 0);
        assert_eq!(r.coverage.fraction, 0.0);
        truth.visible = Some(vec![true; 10]);
        assert!(matches!(
            evaluate_against_truth(&[p], &truth, &TruthParams::default()),
            Err(TruthError::MaskSize { .. })
        ));
        truth.visible = None;
        truth.lit.pop();
        assert!(matches!(
            evaluate_against_truth(&[p], &truth, &TruthParams::default()),
            Err(TruthError::MaskSize { .. })
        ));
    }
}
