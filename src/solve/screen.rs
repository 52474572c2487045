//! Whether a later start of the self-calibration is worth refining on all the anchors.
//!
//! Owns [`on_half`], [`OnHalf::best_score`] and [`OnHalf::loses_to_score`]. The joint
//! estimate's cost per step grows as the cube of the anchors' unknowns (1,800 at 300
//! anchors: 42 ms a factorisation on two cores), and the fixed-centre start
//! ([`super::centre`]) begins far from any minimum where the hand walks: on the
//! 600-frame room its four rounds and two further shifts took about 150
//! of the solve's 279 factorisations, 10 of its 22 s, to lose by 3·10⁵ in score. Such a
//! start is refined first on every other anchor, an eighth of the work a step; only a
//! start that competes there is refined on all of them, exactly as before.
//!
//! # The comparison
//! Both solutions are estimated and scored ([`super::choose::score`]) on the same
//! evidence, the crossings and motion terms of every other anchor: the start refined
//! there as on all of them, and the best estimate so far restricted to those anchors
//! and refined there from it. (Restricted alone, it was fitted to other evidence than
//! it is judged on, and on tuning seed 1 the centre start beat it on the half by 326
//! while losing on all the anchors.) A start that scores worse by [`AMBIGUOUS_CHI2`]
//! (the evidence of the half tells the two apart) is left out; a start that cannot be
//! refined on the half, or with no estimate to compare with, is not screened.

use nalgebra::Vector3;

use super::calibrate::{median_inverse_depth, normalise_scale, refine_starts};
use super::choose::{least_cost, score, AMBIGUOUS_CHI2};
use super::conditional::AnchorSplit;
use super::estimate::{estimate, Estimate, EstimateParams, Start};
use super::evidence::Evidence;
use super::pose::CrossPose;

type V3 = Vector3<f64>;

/// Fewest poses for the screen: below it the joint estimate of all of them is cheap
/// (600 unknowns factor in 6 ms) and a half would hold too few crossings to judge by.
const MIN_POSES: usize = 100;

/// Whether the start `planes` (per plane of `sub`, refined at focal scale 1 from the
/// spread `sigma_px`) scores worse than the best of `estimates` by [`AMBIGUOUS_CHI2`]
/// on every other anchor of `sub` (see the module docs): [`on_half`], then
/// [`OnHalf::best_score`] and [`OnHalf::loses_to_score`].
#[cfg(test)]
pub(super) fn loses_on_half(
    sub: &Evidence,
    planes: &[Option<V3>],
    sigma_px: f64,
    eparams: &EstimateParams,
    estimates: &[Estimate],
) -> bool {
    on_half(sub, planes, sigma_px, eparams).is_some_and(|h| {
        h.best_score(sub, estimates, eparams)
            .is_some_and(|best| h.loses_to_score(best))
    })
}

/// A start refined on every other anchor, and its score there.
pub(super) struct OnHalf {
    half: AnchorSplit,
    start_score: f64,
}

/// The start `planes` refined and scored on every other anchor of `sub`; `None` when
/// `sub` has too few poses to screen ([`MIN_POSES`]) or the start does not refine
/// there (then it is not screened). Needs nothing of the other starts, so the caller
/// may run it beside them.
pub(super) fn on_half(
    sub: &Evidence,
    planes: &[Option<V3>],
    sigma_px: f64,
    eparams: &EstimateParams,
) -> Option<OnHalf> {
    let n = sub.num_poses();
    if n < MIN_POSES {
        return None;
    }
    let mut marked = sub.clone();
    marked.anchors = (0..n).map(|p| p % 2 == 0).collect();
    let half = AnchorSplit::of(&marked);
    let coarse = &half.evidence;
    let found = match refine_starts(coarse, &half.planes_of(planes), 1.0, sigma_px, eparams) {
        Ok(found) => found,
        Err(e) => {
            tracing::debug!("the start did not refine on every other anchor: {e}");
            return None;
        }
    };
    let start_score = found
        .iter()
        .map(|e| score(coarse, e, eparams))
        .min_by(f64::total_cmp)?;
    Some(OnHalf { half, start_score })
}

impl OnHalf {
    /// The best of `estimates` (of all the anchors of `sub`, the evidence [`on_half`] was
    /// given) refitted on the half and scored there; `None` without an estimate, or when
    /// it does not refine there. Every start screened on the same `sub` has the same half
    /// (every other anchor), so one refit serves them all.
    pub(super) fn best_score(
        &self,
        sub: &Evidence,
        estimates: &[Estimate],
        eparams: &EstimateParams,
    ) -> Option<f64> {
        let coarse = &self.half.evidence;
        let k = least_cost(sub, estimates, eparams)?;
        let best = &estimates[k];
        let refit = Start {
            poses: restricted(best, coarse, &self.half),
            focal_scale: best.focal_scale,
            spreads: best.spreads,
        };
        match estimate(coarse, &refit, eparams) {
            Ok(mut est) => {
                normalise_scale(coarse, &mut est);
                Some(score(coarse, &est, eparams))
            }
            Err(e) => {
                tracing::debug!("the best estimate did not refine on every other anchor: {e}");
                None
            }
        }
    }

    /// Whether the start scores worse on the half than `best` ([`Self::best_score`]) by
    /// [`AMBIGUOUS_CHI2`].
    pub(super) fn loses_to_score(&self, best: f64) -> bool {
        let delta = self.start_score - best;
        tracing::debug!(
            delta,
            "the start against the best estimate on every other anchor"
        );
        delta >= AMBIGUOUS_CHI2
    }
}

/// The poses of `est` (of all the anchors) on the anchors of `half` alone, their scale
/// normalised on `coarse`'s crossings as the start's estimates are (the start of its
/// refit there; every crossing counts, as `est`'s weights are of other crossings).
fn restricted(est: &Estimate, coarse: &Evidence, half: &AnchorSplit) -> Vec<CrossPose> {
    let mut poses: Vec<CrossPose> = (0..est.poses.len())
        .filter(|p| half.anchor_of_pose[*p].is_some())
        .map(|p| est.poses[p])
        .collect();
    if let Some(m) = median_inverse_depth(coarse, &poses, est.focal_scale, |_| true) {
        for p in &mut poses {
            p.centre *= m;
        }
    }
    poses
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::solve::estimate::{estimate, Spreads, Start};
    use crate::solve::init;
    use crate::solve::synthetic::{path_evidence, path_scan, PathSpec};

    /// A walking hand over 120 frames: the true planes' estimate is the best so far; a
    /// start at the truth competes with it on every other anchor (it is the same
    /// solution), and the fixed-centre start, every plane through one centre of a hand
    /// that walks 0.3 units, loses there by far.
    #[test]
    fn a_start_is_screened_out_only_when_it_loses_on_half_the_anchors() {
        let scan = path_scan(&PathSpec {
            frames: 120,
            drift: 0.3,
            ..PathSpec::default()
        });
        let ev = path_evidence(&scan, 1000.0, 0.05, 3, |_, _| true);
        let truth: Vec<Option<V3>> = scan.flat_planes().into_iter().map(Some).collect();
        let (poses, _) = init::poses_from_planes(&ev, &truth).expect("poses");
        let params = EstimateParams::default();
        let spreads = Spreads {
            crossing_px: [0.05, 0.1],
            centre: 0.01,
            aim_rad: 0.02,
            roll_rad: 0.02,
        };
        let start = Start {
            poses,
            focal_scale: 1.0,
            spreads,
        };
        let mut best = estimate(&ev, &start, &params).expect("the truth's estimate");
        normalise_scale(&ev, &mut best);
        let best = [best];
        assert!(!loses_on_half(&ev, &truth, 0.05, &params, &best));
        let centre =
            super::super::centre::fixed_centre_start(&ev, &Default::default()).expect("start");
        for twin in &centre.twins {
            assert!(loses_on_half(&ev, twin, 0.05, &params, &best));
        }
    }
}
