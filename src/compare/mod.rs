//! Accuracy evaluation of a reconstructed cloud: against a reference cloud (nearest
//! neighbour distances after an optional alignment, as the paper checks its chapel scan
//! against a Riegl LiDAR cloud) or against the simulator's ground truth (relative depth
//! errors along the camera rays, and coverage of the lit image area).
//!
//! Owns the k-d tree ([`kdtree`]), alignment ([`align`]), statistics ([`stats`]), the
//! histogram plot and distance colour map ([`plot`]), the truth evaluation
//! ([`truth`]) and its count of wrong laser planes ([`planes`]). It reads and writes nothing itself: files are the CLI's business.
//!
//! # Report (JSON, version 1)
//! `crossline compare --json` prints one object; `mode` says which half is present.
//! Within a version keys are only added, never renamed or removed.
//!
//! | key | meaning |
//! |---|---|
//! | version | 1 |
//! | mode | `"reference"` or `"truth"` |
//! | cloud, reference / truth_dir | input paths |
//! | points, reference_points | point counts (reference mode) |
//! | alignment | `{mode, scale, rotation (3×3 rows), translation, rotation_deg, iterations, pairs, rms}` |
//! | thresholds | distances (scene units) for `distances.over` |
//! | distances | `{count, mean, median, rms, p95, p99, max, over: [{threshold, fraction}]}` in scene units |
//! | truth | the [`truth::TruthReport`] (truth mode): `points, evaluated, no_surface, invalid, scale_median, scale, outlier_relative, outlier_fraction, relative_error {count, mean, median, rms, p95, p99, max, over}, wrong_plane_relative, planes_evaluated, wrong_planes, points_on_wrong_planes, points_on_wrong_planes_fraction, coverage {lit_pixels, covered_lit_pixels, fraction, radius_px}, coverage_visible` (the same, or `null`) |
//!
//! The plane keys of `truth`: a *plane* is one laser of one frame (the PLY's `frame` and
//! `laser` properties); it is *wrong* when the median relative depth error of its
//! evaluated points, after the global scale, exceeds `wrong_plane_relative` (default
//! 0.02). `planes_evaluated` counts planes with an evaluated point, `wrong_planes` the
//! wrong ones, `points_on_wrong_planes` the evaluated points on them, and
//! `points_on_wrong_planes_fraction` that count over `evaluated`. All four are `null`
//! when the cloud has no per-point `frame` and `laser`.

pub mod align;
pub mod kdtree;
pub mod planes;
pub mod plot;
pub mod stats;
pub mod truth;

use rayon::prelude::*;
use serde::Serialize;

pub use align::{AlignError, AlignMode, AlignParams, Alignment, Similarity};
pub use kdtree::KdTree;
pub use planes::{PlaneErrors, PlaneIds};
pub use stats::ErrorStats;
pub use truth::{
    evaluate_against_truth, evaluate_cloud_against_truth, GroundTruth, TruthError, TruthParams,
    TruthReport,
};

/// Version of the JSON report.
pub const REPORT_VERSION: u32 = 1;

/// Fewest points with finite coordinates a cloud or reference must have: statistics
/// of fewer (or of none, if all are NaN or inf) would be zeros that look like a
/// perfect match.
pub const MIN_FINITE_POINTS: usize = 3;

/// Refuses a point set with fewer than [`MIN_FINITE_POINTS`] finite points.
pub fn check_finite(which: &'static str, points: &[[f32; 3]]) -> Result<(), CompareError> {
    let finite = points
        .iter()
        .filter(|p| p.iter().all(|c| c.is_finite()))
        .take(MIN_FINITE_POINTS)
        .count();
    if finite < MIN_FINITE_POINTS {
        let finite = points
            .iter()
            .filter(|p| p.iter().all(|c| c.is_finite()))
            .count();
        return Err(CompareError::TooFewFinite {
            which,
            finite,
            total: points.len(),
        });
    }
    Ok(())
}

/// Points per parallel work item (and per progress update) in distance queries.
const CHUNK: usize = 1 << 14;

#[derive(Debug, thiserror::Error)]
pub enum CompareError {
    #[error("the cloud has no points")]
    EmptyCloud,
    #[error("the reference has no points")]
    EmptyReference,
    #[error("the {which} has {finite} points with finite coordinates (of {total}); at least {MIN_FINITE_POINTS} are needed for a comparison")]
    TooFewFinite {
        which: &'static str,
        finite: usize,
        total: usize,
    },
    #[error("the reference has more than 4294967295 points")]
    TooManyPoints,
    #[error("alignment failed")]
    Align(#[from] AlignError),
}

#[derive(Clone, Debug)]
pub struct CompareParams {
    pub align: AlignMode,
    pub align_params: AlignParams,
    /// Distances (scene units) whose exceedance is reported; `None` for
    /// [`default_thresholds`] of the reference.
    pub thresholds: Option<Vec<f64>>,
}

impl Default for CompareParams {
    fn default() -> Self {
        Self {
            align: AlignMode::None,
            align_params: AlignParams::default(),
            thresholds: None,
        }
    }
}

/// Progress callback: `(stage, done, total)`; called from worker threads.
pub type Progress<'a> = &'a (dyn Fn(&str, u64, u64) + Sync);

/// A progress callback that ignores everything.
pub fn no_progress(_: &str, _: u64, _: u64) {}

#[derive(Clone, Debug)]
pub struct ReferenceComparison {
    pub alignment: Alignment,
    /// Distance of every cloud point (after alignment) to its nearest reference point;
    /// `NaN` for non-finite points.
    pub distances: Vec<f32>,
    pub stats: ErrorStats,
    pub thresholds: Vec<f64>,
    /// Diagonal of the reference's bounding box.
    pub reference_diagonal: f64,
}

/// Diagonal of the bounding box of the finite points (0 when there are none).
pub fn bbox_diagonal(points: &[[f32; 3]]) -> f64 {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in points.iter().filter(|p| p.iter().all(|c| c.is_finite())) {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k] as f64);
            hi[k] = hi[k].max(p[k] as f64);
        }
    }
    if lo[0] > hi[0] {
        return 0.0;
    }
    (0..3).map(|k| (hi[k] - lo[k]).powi(2)).sum::<f64>().sqrt()
}

/// 0.1 %, 0.5 % and 1 % of the reference's bounding-box diagonal.
pub fn default_thresholds(reference: &[[f32; 3]]) -> Vec<f64> {
    let d = bbox_diagonal(reference);
    [0.001, 0.005, 0.01].iter().map(|f| f * d).collect()
}

/// Distance from `t(points[i])` to its nearest neighbour in `tree`, into `out[i]`
/// (`NaN` for non-finite points), in parallel.
pub fn nearest_distances(
    tree: &KdTree,
    points: &[[f32; 3]],
    t: &Similarity,
    out: &mut [f32],
    progress: Progress,
) {
    let total = points.len() as u64;
    let done = std::sync::atomic::AtomicU64::new(0);
    let identity = *t == Similarity::default();
    out.par_chunks_mut(CHUNK)
        .zip(points.par_chunks(CHUNK))
        .for_each(|(out, points)| {
            for (d, p) in out.iter_mut().zip(points) {
                let q = if identity {
                    *p
                } else {
                    let m = t.apply(p);
                    [m.x as f32, m.y as f32, m.z as f32]
                };
                *d = match tree.nearest(q) {
                    Some(nn) if nn.distance_sq.is_finite() => {
                        // Recompute in f64: f32 squares lose digits on small distances.
                        let e = (0..3).map(|k| (q[k] as f64 - nn.point[k] as f64).powi(2));
                        e.sum::<f64>().sqrt() as f32
                    }
                    _ => f32::NAN,
                };
            }
            let n = done.fetch_add(points.len() as u64, std::sync::atomic::Ordering::Relaxed);
            progress("distances", n + points.len() as u64, total);
        });
}

/// Aligns `cloud` to `reference` as asked, then measures every point's distance.
pub fn compare_to_reference(
    cloud: &[[f32; 3]],
    reference: &[[f32; 3]],
    params: &CompareParams,
    progress: Progress,
) -> Result<ReferenceComparison, CompareError> {
    if cloud.is_empty() {
        return Err(CompareError::EmptyCloud);
    }
    if reference.is_empty() {
        return Err(CompareError::EmptyReference);
    }
    check_finite("cloud", cloud)?;
    check_finite("reference", reference)?;
    progress("building k-d tree", 0, 1);
    let tree = KdTree::new(reference).ok_or(CompareError::TooManyPoints)?;
    progress("aligning", 0, 1);
    let alignment = match params.align {
        AlignMode::None => Alignment {
            mode: AlignMode::None,
            transform: Similarity::default(),
            iterations: 0,
            pairs: 0,
            rms: f64::NAN,
        },
        AlignMode::Scale => align::align_scale(cloud, reference, &tree, &params.align_params)?,
        AlignMode::Similarity => {
            align::align_similarity(cloud, reference, &tree, &params.align_params)?
        }
    };
    let mut distances = vec![0f32; cloud.len()];
    nearest_distances(&tree, cloud, &alignment.transform, &mut distances, progress);
    let thresholds = params
        .thresholds
        .clone()
        .unwrap_or_else(|| default_thresholds(reference));
    let mut finite: Vec<f64> = distances
        .iter()
        .filter(|d| d.is_finite())
        .map(|&d| d as f64)
        .collect();
    let stats = ErrorStats::from_values(&mut finite, &thresholds);
    Ok(ReferenceComparison {
        alignment,
        distances,
        stats,
        thresholds,
        reference_diagonal: bbox_diagonal(reference),
    })
}

/// The alignment as the JSON report writes it.
#[derive(Clone, Debug, Serialize)]
pub struct AlignmentReport {
    pub mode: AlignMode,
    pub scale: f64,
    /// Row-major.
    pub rotation: [[f64; 3]; 3],
    pub translation: [f64; 3],
    pub rotation_deg: f64,
    pub iterations: usize,
    pub pairs: usize,
    /// RMS distance of the kept pairs; `null` without alignment.
    pub rms: Option<f64>,
}

impl From<&Alignment> for AlignmentReport {
    fn from(a: &Alignment) -> Self {
        let r = &a.transform.rotation;
        let t = &a.transform.translation;
        Self {
            mode: a.mode,
            scale: a.transform.scale,
            rotation: [0, 1, 2].map(|i| [r[(i, 0)], r[(i, 1)], r[(i, 2)]]),
            translation: [t.x, t.y, t.z],
            rotation_deg: a.transform.angle().to_degrees(),
            iterations: a.iterations,
            pairs: a.pairs,
            rms: a.rms.is_finite().then_some(a.rms),
        }
    }
}

/// The reference-mode JSON report (see the module doc).
#[derive(Clone, Debug, Serialize)]
pub struct ReferenceReport {
    pub version: u32,
    pub mode: &'static str,
    pub cloud: String,
    pub reference: String,
    pub points: usize,
    pub reference_points: usize,
    pub alignment: AlignmentReport,
    pub thresholds: Vec<f64>,
    pub distances: ErrorStats,
}

impl ReferenceComparison {
    pub fn report(&self, cloud: &str, reference: &str, reference_points: usize) -> ReferenceReport {
        ReferenceReport {
            version: REPORT_VERSION,
            mode: "reference",
            cloud: cloud.to_string(),
            reference: reference.to_string(),
            points: self.distances.len(),
            reference_points,
            alignment: (&self.alignment).into(),
            thresholds: self.thresholds.clone(),
            distances: self.stats.clone(),
        }
    }
}

/// The truth-mode JSON report (see the module doc).
#[derive(Clone, Debug, Serialize)]
pub struct TruthModeReport {
    pub version: u32,
    pub mode: &'static str,
    pub cloud: String,
    pub truth_dir: String,
    pub truth: TruthReport,
}

impl TruthModeReport {
    pub fn new(cloud: &str, truth_dir: &str, truth: TruthReport) -> Self {
        Self {
            version: REPORT_VERSION,
            mode: "truth",
            cloud: cloud.to_string(),
            truth_dir: truth_dir.to_string(),
            truth,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::kdtree::tests::Rng;
    use super::*;
    use nalgebra::{Rotation3, Vector3};

    /// A tilted wall `z = 3 + 0.3 x + 0.2 y` over `|x|, |y| ≤ 0.6` and spheres of radius
    /// 0.3 at `(0.2, 0.1, 2.2)` and 0.15 at `(-0.3, -0.25, 2.5)` (two, so that no rotation
    /// maps the scene onto itself), each sample as (point, unit normal).
    fn wall(x: f64, y: f64) -> (Vector3<f64>, Vector3<f64>) {
        let n = Vector3::new(-0.3, -0.2, 1.0).normalize();
        (Vector3::new(x, y, 3.0 + 0.3 * x + 0.2 * y), n)
    }

    fn ball(dir: Vector3<f64>) -> (Vector3<f64>, Vector3<f64>) {
        let d = dir.normalize();
        (Vector3::new(0.2, 0.1, 2.2) + d * 0.3, d)
    }

    fn small_ball(dir: Vector3<f64>) -> (Vector3<f64>, Vector3<f64>) {
        let d = dir.normalize();
        (Vector3::new(-0.3, -0.25, 2.5) + d * 0.15, d)
    }

    /// Fibonacci lattice direction `i` of `n`.
    fn fibonacci(i: usize, n: usize) -> Vector3<f64> {
        let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
        let r = (1.0 - z * z).sqrt();
        let phi = i as f64 * std::f64::consts::PI * (3.0 - 5f64.sqrt());
        Vector3::new(r * phi.cos(), r * phi.sin(), z)
    }

    fn f32s(v: &Vector3<f64>) -> [f32; 3] {
        [v.x as f32, v.y as f32, v.z as f32]
    }

    /// Regular samples of the three surfaces, spacing about `3 mm · density`.
    fn reference(density: usize) -> Vec<[f32; 3]> {
        let mut out = Vec::new();
        let m = 400 / density;
        for i in 0..m {
            for j in 0..m {
                let (x, y) = (
                    -0.6 + 1.2 * i as f64 / (m - 1) as f64,
                    -0.6 + 1.2 * j as f64 / (m - 1) as f64,
                );
                out.push(f32s(&wall(x, y).0));
            }
        }
        let n = 130_000 / (density * density);
        out.extend((0..n).map(|i| f32s(&ball(fibonacci(i, n)).0)));
        let n = 32_000 / (density * density);
        out.extend((0..n).map(|i| f32s(&small_ball(fibonacci(i, n)).0)));
        out
    }

    /// Random surface samples, each with its normal.
    fn random_surface(rng: &mut Rng, n: usize) -> Vec<(Vector3<f64>, Vector3<f64>)> {
        (0..n)
            .map(|i| {
                let dir = Vector3::new(rng.normal(), rng.normal(), rng.normal());
                match i % 4 {
                    0 | 2 => wall(rng.uniform() * 1.2 - 0.6, rng.uniform() * 1.2 - 0.6),
                    1 => ball(dir),
                    _ => small_ball(dir),
                }
            })
            .collect()
    }

    #[test]
    fn scale_alignment_recovers_scale_and_normal_offset() {
        let reference = reference(1);
        let mut rng = Rng(7);
        let truth_scale = 1.37;
        let offset = 0.01;
        // Offsets of both signs: a one-sided offset on a wall is itself a scale change.
        let cloud: Vec<[f32; 3]> = random_surface(&mut rng, 10_000)
            .iter()
            .enumerate()
            .map(|(i, (p, n))| {
                let sign = if (i / 2) % 2 == 0 { 1.0 } else { -1.0 };
                f32s(&((p + n * (sign * offset)) / truth_scale))
            })
            .collect();
        let params = CompareParams {
            align: AlignMode::Scale,
            thresholds: Some(vec![0.005, 0.02]),
            ..Default::default()
        };
        let c = compare_to_reference(&cloud, &reference, &params, &no_progress).expect("compare");
        let s = c.alignment.transform.scale;
        assert!((s / truth_scale - 1.0).abs() < 1e-3, "scale {s}");
        assert!(
            (c.stats.median - offset).abs() < 4e-4,
            "median {}",
            c.stats.median
        );
        assert_eq!(c.stats.count, cloud.len());
        assert!(c.stats.over[0].fraction > 0.99);
        assert!(c.stats.over[1].fraction < 0.01);
        // Without alignment the cloud is far off.
        let none =
            compare_to_reference(&cloud, &reference, &CompareParams::default(), &no_progress)
                .expect("compare");
        assert!(none.stats.median > 0.1, "{}", none.stats.median);
    }

    #[test]
    fn similarity_icp_recovers_a_known_transform_with_partial_overlap() {
        let reference = reference(1);
        let mut rng = Rng(11);
        let rotation = Rotation3::from_axis_angle(
            &nalgebra::Unit::new_normalize(Vector3::new(0.3, 1.0, -0.2)),
            3f64.to_radians(),
        );
        let truth = Similarity {
            scale: 1.2,
            rotation: *rotation.matrix(),
            translation: Vector3::new(0.05, -0.03, 0.04),
        };
        // 70 % of the cloud on the reference surfaces, 30 % on a floor the reference
        // lacks; the cloud is the reference frame mapped by the inverse of `truth`.
        let mut world: Vec<Vector3<f64>> = random_surface(&mut rng, 14_000)
            .iter()
            .map(|(p, _)| *p)
            .collect();
        world.extend(
            (0..6_000)
                .map(|_| Vector3::new(rng.uniform() * 1.2 - 0.6, 0.9, 2.0 + rng.uniform() * 1.2)),
        );
        let inverse_rotation = truth.rotation.transpose();
        let cloud: Vec<[f32; 3]> = world
            .iter()
            .map(|w| f32s(&(inverse_rotation * (w - truth.translation) / truth.scale)))
            .collect();
        let params = CompareParams {
            align: AlignMode::Similarity,
            align_params: AlignParams {
                max_samples: 3_000,
                ..Default::default()
            },
            ..Default::default()
        };
        let c = compare_to_reference(&cloud, &reference, &params, &no_progress).expect("compare");
        let t = c.alignment.transform;
        assert!(
            (t.scale / truth.scale - 1.0).abs() < 2e-3,
            "scale {}",
            t.scale
        );
        let angle_error = (t.rotation.transpose() * truth.rotation).trace();
        let angle_error = ((angle_error - 1.0) * 0.5)
            .clamp(-1.0, 1.0)
            .acos()
            .to_degrees();
        assert!(angle_error < 0.1, "rotation off by {angle_error}°");
        assert!(
            (t.translation - truth.translation).norm() < 5e-3,
            "{:?}",
            t.translation
        );
        // The overlapping 70 % lie on the reference, the floor does not.
        assert!(c.stats.median < 3e-3, "median {}", c.stats.median);
        assert!(c.distances[14_000..].iter().all(|&d| d > 0.05));
    }

    #[test]
    fn umeyama_is_exact_on_exact_pairs() {
        let mut rng = Rng(3);
        let truth = Similarity {
            scale: 0.7,
            rotation: *Rotation3::from_euler_angles(0.4, -1.1, 2.0).matrix(),
            translation: Vector3::new(1.0, -2.0, 0.5),
        };
        let from: Vec<Vector3<f64>> = (0..50)
            .map(|_| Vector3::new(rng.normal(), rng.normal(), rng.normal()))
            .collect();
        let to: Vec<Vector3<f64>> = from
            .iter()
            .map(|p| truth.rotation * p * truth.scale + truth.translation)
            .collect();
        let t = Similarity::umeyama(&from, &to).expect("solvable");
        assert!((t.scale - truth.scale).abs() < 1e-12);
        assert!((t.rotation - truth.rotation).norm() < 1e-12);
        assert!((t.translation - truth.translation).norm() < 1e-12);
        let line: Vec<Vector3<f64>> = (0..5).map(|i| Vector3::new(i as f64, 0.0, 0.0)).collect();
        assert!(Similarity::umeyama(&line, &line).is_none());
    }

    #[test]
    fn report_carries_version_and_alignment() {
        let reference = vec![[0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [0.0, 1.0, 1.0]];
        let cloud = vec![[0.0, 0.0, 1.5], [1.0, 0.0, 1.5], [0.0, 1.0, 1.5]];
        let c = compare_to_reference(&cloud, &reference, &CompareParams::default(), &no_progress)
            .expect("compare");
        assert!((c.stats.median - 0.5).abs() < 1e-6);
        let json = serde_json::to_value(c.report("a.ply", "b.ply", 3)).expect("json");
        assert_eq!(json["version"], 1);
        assert_eq!(json["alignment"]["mode"], "none");
        assert_eq!(json["alignment"]["scale"], 1.0);
        assert!(json["alignment"]["rms"].is_null());
        assert_eq!(json["distances"]["count"], 3);
        assert!(matches!(
            compare_to_reference(&[], &reference, &CompareParams::default(), &no_progress),
            Err(CompareError::EmptyCloud)
        ));
    }

    #[test]
    fn a_cloud_of_nan_and_inf_is_refused_not_scored_zero() {
        let reference = vec![[0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [0.0, 1.0, 1.0]];
        let cloud = vec![
            [f32::NAN, 0.0, 1.0],
            [f32::INFINITY, 0.0, 1.0],
            [0.0, f32::NEG_INFINITY, 1.0],
            [0.0, 0.0, 1.0],
        ];
        let err = compare_to_reference(&cloud, &reference, &CompareParams::default(), &no_progress)
            .expect_err("one finite point");
        assert!(
            matches!(
                err,
                CompareError::TooFewFinite {
                    which: "cloud",
                    finite: 1,
                    total: 4
                }
            ),
            "{err}"
        );
        let err = compare_to_reference(
            &reference,
            &cloud[..2],
            &CompareParams::default(),
            &no_progress,
        )
        .expect_err("no finite reference point");
        assert!(err.to_string().contains("reference has 0 points"), "{err}");
    }
}
