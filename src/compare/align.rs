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
    pub max_iterations: usize,
    /// Pairs kept per iteration: the closest this fraction. Set it below the share of
    /// the cloud that overlaps the reference.
    pub keep_fraction: f64,
    /// Stop when the relative parameter change of an iteration falls below this.
    pub tolerance: f64,
}

impl Default for AlignParams {
    fn default() -> Self {
        Self {
            max_samples: 200_000,
            max_iterations: 100,
            keep_fraction: 0.5,
            tolerance: 1e-9,
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

/// Every `k`-th finite point so that at most `max` remain.
fn samples(points: &[[f32; 3]], max: usize) -> Vec<[f32; 3]> {
    let step = points.len().div_ceil(max.max(1)).max(1);
    points
        .iter()
        .step_by(step)
        .filter(|p| p.iter().all(|c| c.is_finite()))
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

/// Keeps the closest `fraction` of `pairs` (at least 3 when there are), returning the
/// RMS distance of the kept ones.
fn trim(pairs: &mut Vec<Pair>, fraction: f64) -> f64 {
    let keep = ((pairs.len() as f64 * fraction.clamp(0.0, 1.0)).ceil() as usize)
        .max(3)
        .min(pairs.len());
    if keep < pairs.len() {
        pairs.select_nth_unstable_by(keep, |a, b| a.distance.total_cmp(&b.distance));
        pairs.truncate(keep);
    }
    let sum: f64 = pairs.iter().map(|p| p.distance * p.distance).sum();
    (sum / pairs.len().max(1) as f64).sqrt()
}

/// Scale about the camera centre: starts from the ratio of median ranges, then iterates
/// nearest neighbours and the median, over the closest pairs, of the per-pair scale
/// `(q · p) / (p · p)` that brings `p` onto the projection of its match `q` on `p`'s ray.
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
    for it in 1..=params.max_iterations {
        iterations = it;
        let mut p = pairs(&sample, tree, &t);
        rms = trim(&mut p, params.keep_fraction);
        kept = p.len();
        ratios.clear();
        ratios.extend(
            p.iter()
                .filter(|p| p.from.norm_squared() > 0.0)
                .map(|p| p.to.dot(&p.from) / p.from.norm_squared()),
        );
        let s = median_mut(&mut ratios);
        if !(s.is_finite() && s > 0.0) {
            return Err(AlignError::Degenerate);
        }
        let change = (s - t.scale).abs() / t.scale;
        t.scale = s;
        if change < params.tolerance {
            break;
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
    let mut last_rms = f64::INFINITY;
    for it in 1..=params.max_iterations {
        iterations = start.iterations + it;
        let mut p = pairs(&sample, tree, &t);
        rms = trim(&mut p, params.keep_fraction);
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
        // Trimmed ICP with a fixed fraction decreases the trimmed error monotonically;
        // stop on a vanishing step or once it stops improving.
        if change < params.tolerance || (rms >= last_rms && change < 1e-6) {
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
