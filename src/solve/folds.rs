//! Runs of frames the joint estimate folded, started again from their neighbours.
//!
//! Owns the detection of such runs (kinks in the hand's path) and their restarts; the
//! minimisation is [`super::estimate`]'s, the judge [`super::choose::score`].

use nalgebra::Vector3;

use super::calibrate::normalise_scale;
use super::choose::score;
use super::estimate::{self, Estimate, EstimateParams, Start};
use super::evidence::Evidence;
use super::init;

type V3 = Vector3<f64>;

/// Runs of frames the estimate folded: the joint estimate stops in local minima where a
/// run of consecutive poses turns together, up to tens of degrees, held there by the
/// motion terms at the run's two ends (generality seed 9: frames 181-184 75° off, their
/// neighbours right). Such a run shows as kinks in the hand's path: second differences
/// of the centre, aim or roll beyond [`FOLD_SPREADS`] of their measured spreads, at both
/// of its ends ([`MIN_FOLD_SPAN`]). Each run (kinks closer than [`FOLD_GAP_FRAMES`]
/// joined, the largest first, at most [`MAX_FOLDS`]) is started again from the poses its
/// two neighbours give (interpolated between them) and the whole scan minimised again;
/// the estimate that explains the evidence better ([`score`]) stays. A run the hand
/// really made leaves the estimate as it was, at the cost of one minimisation.
pub(super) fn reseed_folds(
    evidence: &Evidence,
    mut est: Estimate,
    params: &EstimateParams,
) -> Estimate {
    let mut best = score(evidence, &est, params);
    for (first, last) in folds(evidence, &est, params) {
        // The poses between `first` and `last` (inclusive), from their neighbours.
        let (Some(before), true) = (first.checked_sub(1), last + 1 < est.poses.len()) else {
            continue;
        };
        let frame = |p: usize| f64::from(evidence.pose_frames[p]);
        let (lo, hi) = (
            &est.poses[before],
            est.poses[last + 1].aligned_to(&est.poses[before]),
        );
        let mut poses = est.poses.clone();
        for (p, pose) in poses.iter_mut().enumerate().take(last + 1).skip(first) {
            let t = (frame(p) - frame(before)) / (frame(last + 1) - frame(before));
            *pose = init::interpolate(lo, &hi, t).aligned_to(lo);
        }
        let start = Start {
            poses,
            focal_scale: est.focal_scale,
            spreads: est.spreads,
        };
        let Ok(mut again) = estimate::estimate(evidence, &start, params) else {
            continue;
        };
        normalise_scale(evidence, &mut again);
        let s = score(evidence, &again, params);
        tracing::debug!(
            first = evidence.pose_frames[first],
            last = evidence.pose_frames[last],
            before = best,
            after = s,
            "a folded run started again"
        );
        if s < best {
            best = s;
            est = again;
        }
    }
    est
}

/// Second differences of the hand's path beyond this many of their spreads are kinks
/// (the motion terms' Huber threshold is 2: a kink is far into their linear part; under
/// Gaussian noise one in 10⁸ would be).
const FOLD_SPREADS: f64 = 6.0;
/// Kinks fewer frames apart than this belong to one folded run.
const FOLD_GAP_FRAMES: u32 = 12;
/// Folded runs started again at most.
const MAX_FOLDS: usize = 4;
/// Least span (poses) of a run's kinks for it to be a fold: poses `a..=b` turned
/// together bend the path at both ends, the triples `a−2, a−1` and `b−1, b`, which span
/// `b − a + 5` poses, six or more for a run of two; one pose out of line (the hand's own
/// jerk, a roll jitter) bends three triples, five poses, and is left alone (seen on room
/// seed 121: four such runs started again, none kept, 10 s spent).
const MIN_FOLD_SPAN: usize = 6;

/// The folded runs of `est` (see [`reseed_folds`]), as first and last pose, the run with
/// the largest kink first.
fn folds(evidence: &Evidence, est: &Estimate, params: &EstimateParams) -> Vec<(usize, usize)> {
    let [_, _, centre, aim, roll] = estimate::residuals_by_kind(evidence, est, params);
    let sp = est.spreads;
    // Per triple (its middle pose is t + 1): the largest kink, in spreads.
    let kinks: Vec<f64> = (0..roll.len())
        .map(|t| {
            let c = V3::new(centre[3 * t], centre[3 * t + 1], centre[3 * t + 2]).norm();
            let a = aim[2 * t].hypot(aim[2 * t + 1]);
            (c / sp.centre)
                .max(a / sp.aim_rad)
                .max(roll[t].abs() / sp.roll_rad)
        })
        .collect();
    let mut runs: Vec<(usize, usize, f64)> = Vec::new();
    for (t, &k) in kinks.iter().enumerate() {
        if k.is_nan() || k <= FOLD_SPREADS {
            continue;
        }
        // The triple's three poses.
        let (first, last) = (t, t + 2);
        match runs.last_mut() {
            Some(run)
                if evidence.pose_frames[first] <= evidence.pose_frames[run.1] + FOLD_GAP_FRAMES =>
            {
                run.1 = last;
                run.2 = run.2.max(k);
            }
            _ => runs.push((first, last, k)),
        }
    }
    if tracing::enabled!(tracing::Level::DEBUG) {
        let mut top: Vec<(f64, u32)> = kinks
            .iter()
            .enumerate()
            .filter(|(_, k)| k.is_finite())
            .map(|(t, &k)| (k, evidence.pose_frames[t + 1]))
            .collect();
        top.sort_by(|a, b| b.0.total_cmp(&a.0));
        top.truncate(6);
        tracing::debug!(?top, spreads = ?sp, "the path's largest kinks (in spreads, at frame)");
    }
    runs.retain(|&(first, last, _)| last + 1 - first >= MIN_FOLD_SPAN);
    runs.sort_by(|a, b| b.2.total_cmp(&a.2));
    runs.into_iter()
        .take(MAX_FOLDS)
        .map(|(first, last, _)| (first, last))
        .collect()
}
