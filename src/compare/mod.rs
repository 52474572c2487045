//! Accuracy evaluation of a reconstructed cloud: against a reference cloud (nearest
//! neighbour distances after an optional alignment, as the paper checks its chapel scan
//! against a Riegl LiDAR cloud) or against the simulator's ground truth (relative depth
//! errors along the camera rays, and coverage of the lit image area).
//!
//! Owns the k-d tree ([`kdtree`]), alignment ([`align`]), statistics ([`stats`]), the
//! histogram plot and distance colour map ([`plot`]) and the truth evaluation
//! ([`truth`]). It reads and writes nothing itself: files are the CLI's business.
//!
//! # Report (JSON, version 1)
//! `crossline compare --json` prints one object; `mode` says which half is present.
//!
//! | key | meaning |
//! |---|---|
//! | version | 1 |
//! | mode | `"reference"` or `"truth"` |
//! | cloud, reference / truth | input paths |
//! | points, reference_points | point counts (reference mode) |
//! | alignment | `{mode, scale, rotation (3×3 rows), translation, rotation_deg, iterations, pairs, rms}` |
//! | thresholds | distances (scene units) for `distances.over` |
//! | distances | `{count, mean, median, rms, p95, p99, max, over: [{threshold, fraction}]}` in scene units |
//! | truth | the [`truth::TruthReport`] (truth mode) |

pub mod align;
pub mod kdtree;
pub mod plot;
pub mod stats;
pub mod truth;

use rayon::prelude::*;
use serde::Serialize;

pub use align::{AlignError, AlignMode, AlignParams, Alignment, Similarity};
pub use kdtree::KdTree;
pub use stats::ErrorStats;

/// Version of the JSON report.
pub const REPORT_VERSION: u32 = 1;

/// Points per parallel work item (and per progress update) in distance queries.
const CHUNK: usize = 1 << 14;

#[derive(Debug, thiserror::Error)]
pub enum CompareError {
    #[error("the cloud has no points")]
    EmptyCloud,
    #[error("the reference has no points")]
    EmptyReference,
    #[error("the reference has more than 4294967295 points")]
    TooManyPoints,
    #[error("alignment failed: {0}")]
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
