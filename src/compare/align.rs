//! Aligning a cloud to a reference cloud before measuring distances: a global scale
//! about the camera centre, or a similarity (rotation, translation, scale) by trimmed
//! ICP with Umeyama's closed form.
//!
//! Both clouds live in the camera frame of the same fixed camera, so the self-calibrated
//! reconstruction differs from the truth mainly by the one global scale the method
//! cannot observe; `scale` removes exactly that. `similarity` is for references in
//! another frame (a LiDAR scan registered by hand, for example).

use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;
use serde::Serialize;

use super::kdtree::KdTree;
use super::stats::median_mut;

/// `point ↦ scale · rotation · point + translation`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Similarity {
    pub scale: f64,
    pub rotation: Matrix3<f64>,
    pub translation: Vector3<f64>,
}

impl Default for Similarity {
    fn default() -> Self {
        Self {
            scale: 1.0,
            rotation: Matrix3::identity(),
            translation: Vector3::zeros(),
        }
    }
}

impl Similarity {
    #[inline]
    pub fn apply(&self, p: &[f32; 3]) -> Vector3<f64> {
        let v = Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64);
        self.rotation * v * self.scale + self.translation
    }

    /// Rotation angle in radians.
    pub fn angle(&self) -> f64 {
        ((self.rotation.trace() - 1.0) * 0.5)
            .clamp(-1.0, 1.0)
            .acos()
    }

    /// Umeyama (1991): the least-squares similarity taking `from[i]` to `to[i]`. `None`
    /// for fewer than 3 pairs or degenerate (collinear) `from`.
    pub fn umeyama(from: &[Vector3<f64>], to: &[Vector3<f64>]) -> Option<Self> {
        let n = from.len();
        if n < 3 || to.len() != n {
            return None;
        }
        let inv = 1.0 / n as f64;
        let mean_from = from.iter().sum::<Vector3<f64>>() * inv;
        let mean_to = to.iter().sum::<Vector3<f64>>() * inv;
        let mut cov = Matrix3::zeros();
        let mut var_from = 0.0;
        for (a, b) in from.iter().zip(to) {
            let da = a - mean_from;
            cov += (b - mean_to) * da.transpose();
            var_from += da.norm_squared();
        }
        cov *= inv;
        var_from *= inv;
        if var_from <= 0.0 {
            return None;
        }
        let svd = cov.svd(true, true);
        let (u, v_t) = (svd.u?, svd.v_t?);
        let mut s = Matrix3::identity();
        if u.determinant() * v_t.determinant() < 0.0 {
            s[(2, 2)] = -1.0;
        }
        let d = svd.singular_values;
        // A rank below 2 leaves the rotation undetermined.
        if d[1] <= d[0] * 1e-12 {
            return None;
        }
        let rotation = u * s * v_t;
        let scale = (d[0] * s[(0, 0)] + d[1] * s[(1, 1)] + d[2] * s[(2, 2)]) / var_from;
        let translation = mean_to - rotation * mean_from * scale;
        Some(Self {
            scale,
            rotation,
            translation,
        })
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum AlignMode {
    /// Distances as given.
    None,
    /// One global scale about the camera centre.
    Scale,
    /// Rotation, translation and scale (trimmed ICP).
    Similarity,
}

#[derive(Clone, Debug)]
pub struct AlignParams {
    /// At most this many evenly spread cloud points drive the estimate.
    pub max_samples: usize,
    /// Per stage (median and least squares for the scale; ICP for the similarity):
    /// point-to-point ICP converges slowly along the scene's weak directions.
    pub max_iterations: usize,
    /// Pairs kept per iteration: those closer than three times this quantile of the
    /// pair distances. Set it below the share of the cloud that overlaps the reference.
    pub keep_fraction: f64,
    /// Stop when the relative parameter change of an iteration falls below this.
    pub tolerance: f64,
}

impl Default for AlignParams {
    fn default() -> Self {
        Self {
            max_samples: 200_000,
            max_iterations: 300,
            keep_fraction: 0.5,
            tolerance: 1e-8,
        }
    }
}

/// The alignment found and how well its kept pairs fit.
#[derive(Clone, Debug, PartialEq)]
pub struct Alignment {
    pub mode: AlignMode,
    /// Maps cloud points onto the reference.
    pub transform: Similarity,
    pub iterations: usize,
    /// Pairs kept in the last iteration.
    pub pairs: usize,
    /// RMS distance of the kept pairs in the last iteration.
    pub rms: f64,
}

#[derive(Debug, thiserror::Error)]
pub enum AlignError {
    #[error("no finite points to align")]
    NoPoints,
    #[error("alignment is degenerate (the overlapping points are collinear or too few)")]
    Degenerate,
}

/// At most `max` finite points, spread over the whole cloud by the golden-ratio
/// sequence `frac(i·φ)` rather than a fixed stride, which would alias with any periodic
/// order of the points (alternating lasers, interleaved surfaces).
fn samples(points: &[[f32; 3]], max: usize) -> Vec<[f32; 3]> {
    let finite = |p: &&[f32; 3]| p.iter().all(|c| c.is_finite());
    let n = points.len();
    if n <= max {
        return points.iter().filter(finite).copied().collect();
    }
    const PHI_FRAC: f64 = 0.618_033_988_749_894_8;
    (0..max)
        .map(|i| {
            let f = (i as f64 * PHI_FRAC).fract();
            &points[((f * n as f64) as usize).min(n - 1)]
        })
        .filter(finite)
        .copied()
        .collect()
}

fn median_range(points: &[[f32; 3]]) -> f64 {
    let mut r: Vec<f64> = points
        .iter()
        .map(|p| Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64).norm())
        .collect();
    median_mut(&mut r)
}

/// One matched pair: the transformed cloud point's nearest reference point.
struct Pair {
    from: Vector3<f64>,
    to: Vector3<f64>,
    distance: f64,
}

fn pairs(sample: &[[f32; 3]], tree: &KdTree, t: &Similarity) -> Vec<Pair> {
    sample
        .par_iter()
        .filter_map(|p| {
            let moved = t.apply(p);
            let q = [moved.x as f32, moved.y as f32, moved.z as f32];
            let nn = tree.nearest(q)?;
            let to = Vector3::new(nn.point[0] as f64, nn.point[1] as f64, nn.point[2] as f64);
            let distance = (to - moved).norm();
            distance.is_finite().then(|| Pair {
                from: Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64),
                to,
                distance,
            })
        })
        .collect()
}

/// Keeps the pairs closer than three times the `fraction`-quantile of the distances (at
/// least the quantile's own pairs stay, and all within `at_least`), returning the RMS distance of the kept ones.
///
/// A threshold rather than a fixed share: keeping exactly the closest share prefers one
/// side of a two-sided error distribution whenever the estimate is slightly off, which
/// feeds back into the estimate and biases it.
fn trim(pairs: &mut Vec<Pair>, fraction: f64, at_least: f64) -> f64 {
    if pairs.len() > 3 {
        let k = ((pairs.len() - 1) as f64 * fraction.clamp(0.0, 1.0)).round() as usize;
        let (_, q, _) = pairs.select_nth_unstable_by(k, |a, b| a.distance.total_cmp(&b.distance));
        let threshold = (3.0 * q.distance).max(at_least);
        pairs.retain(|p| p.distance <= threshold);
    }
    let sum: f64 = pairs.iter().map(|p| p.distance * p.distance).sum();
    (sum / pairs.len().max(1) as f64).sqrt()
}

/// Scale about the camera centre: starts from the ratio of median ranges, then iterates
/// nearest neighbours and the median, over the closest pairs, of the per-pair scale
/// `(q · p) / (p · p)` that brings `p` onto the projection of its match `q` on `p`'s ray;
/// then refines by least squares over the closest pairs.
pub fn align_scale(
    cloud: &[[f32; 3]],
    reference: &[[f32; 3]],
    tree: &KdTree,
    params: &AlignParams,
) -> Result<Alignment, AlignError> {
    let sample = samples(cloud, params.max_samples);
    let ref_sample = samples(reference, params.max_samples);
    if sample.is_empty() || ref_sample.is_empty() {
        return Err(AlignError::NoPoints);
    }
    let (rc, rr) = (median_range(&sample), median_range(&ref_sample));
    let mut t = Similarity {
        scale: if rc > 0.0 && rr > 0.0 { rr / rc } else { 1.0 },
        ..Similarity::default()
    };
    let mut ratios = Vec::with_capacity(sample.len());
    let (mut iterations, mut kept, mut rms) = (0, 0, f64::NAN);
    // Median of ratios first (robust from a far start), then least squares on the kept
    // pairs, `s = Σ q·p / Σ p·p`, whose noise averages out where a median of a
    // two-sided error distribution would sit anywhere in its gap.
    for least_squares in [false, true] {
        for _ in 0..params.max_iterations {
            iterations += 1;
            let mut p = pairs(&sample, tree, &t);
            rms = trim(&mut p, params.keep_fraction, 0.0);
            kept = p.len();
            let s = if least_squares {
                let num: f64 = p.iter().map(|p| p.to.dot(&p.from)).sum();
                let den: f64 = p.iter().map(|p| p.from.norm_squared()).sum();
                num / den
            } else {
                ratios.clear();
                ratios.extend(
                    p.iter()
                        .filter(|p| p.from.norm_squared() > 0.0)
                        .map(|p| p.to.dot(&p.from) / p.from.norm_squared()),
                );
                median_mut(&mut ratios)
            };
            if !(s.is_finite() && s > 0.0) {
                return Err(AlignError::Degenerate);
            }
            let change = (s - t.scale).abs() / t.scale;
            t.scale = s;
            if change < params.tolerance {
                break;
            }
        }
    }
    Ok(Alignment {
        mode: AlignMode::Scale,
        transform: t,
        iterations,
        pairs: kept,
        rms,
    })
}

/// Trimmed ICP with scale, started from [`align_scale`] (both clouds share the camera
/// frame in the common case); each iteration solves Umeyama's closed form on the
/// closest `keep_fraction` of the pairs.
pub fn align_similarity(
    cloud: &[[f32; 3]],
    reference: &[[f32; 3]],
    tree: &KdTree,
    params: &AlignParams,
) -> Result<Alignment, AlignError> {
    let start = align_scale(cloud, reference, tree, params)?;
    let sample = samples(cloud, params.max_samples);
    let mut t = start.transform;
    let (mut iterations, mut kept, mut rms) = (start.iterations, start.pairs, start.rms);
    let mut from = Vec::new();
    let mut to = Vec::new();
    // A far start can leave a whole part of the scene beyond the trimming threshold, and
    // ICP then slides into a fit of the rest (a wall and a sphere fit under any rotation
    // about the sphere's centre along the wall's normal). So the threshold starts at a
    // tenth of the cloud's size and shrinks geometrically towards the adaptive one.
    let size = super::bbox_diagonal(&sample) * t.scale;
    let mut last_rms = f64::INFINITY;
    for it in 1..=params.max_iterations {
        iterations = start.iterations + it;
        let mut p = pairs(&sample, tree, &t);
        let anneal = 0.1 * size * 0.8f64.powi(it as i32 - 1);
        rms = trim(&mut p, params.keep_fraction, anneal);
        kept = p.len();
        from.clear();
        to.clear();
        from.extend(p.iter().map(|p| p.from));
        to.extend(p.iter().map(|p| p.to));
        let next = Similarity::umeyama(&from, &to).ok_or(AlignError::Degenerate)?;
        let extent = from.iter().map(|v| v.norm()).fold(0.0, f64::max).max(1e-12);
        let change = (next.rotation - t.rotation).norm()
            + (next.scale - t.scale).abs() / t.scale
            + (next.translation - t.translation).norm() / (extent * t.scale);
        t = next;
        if anneal < rms && (change < params.tolerance || (rms >= last_rms && change < 1e-6)) {
            break;
        }
        last_rms = rms;
    }
    Ok(Alignment {
        mode: AlignMode::Similarity,
        transform: t,
        iterations,
        pairs: kept,
        rms,
    })
}
