//! A pose fitted after the estimate: a frame that arrives once an estimate is made
//! (the live daemon's next frames after an epoch) is fitted against that estimate's
//! joint poses exactly as [`super::conditional::complete`] fits every pose outside the
//! anchors: the same robust cost at the estimate's spreads, the same starts, and the
//! same covariance, the joint poses' own uncertainty propagated into it. Its planes get
//! the verdict [`super::calibrate`] gives every plane, from the same counts.
//!
//! What it cannot see is what the estimate did not have: crossings with frames after
//! it, and the spreads the later frames would show. A later estimate supersedes it.

use nalgebra::Vector3;

use super::conditional::{fit_ties, term, Tie};
use super::estimate::{depth_sigma_of, Estimate, EstimateParams, PoseMarginal};
use super::evidence::{CrossingClass, Evidence, Ray};
use super::pose::CrossPose;
use super::terms::Loss;
use super::PlaneVerdict;

/// A crossing of the pose to fit: its own laser, the other plane (`None`: the pose's own
/// other laser, at the cross's centre; otherwise the joint pose, as its index in the
/// estimate's covariance ([`Estimate::joint_of_pose`]), and its laser), the undistorted
/// normalised image point, and its class.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Link {
    pub laser: u8,
    pub other: Option<(u32, u8)>,
    pub u: [f64; 2],
    pub class: CrossingClass,
}

/// A pose fitted against a finished estimate (see the module docs).
#[derive(Clone, Debug)]
pub struct OutsideFit {
    pub pose: CrossPose,
    pub marginal: PoseMarginal,
    pub scatter: PoseMarginal,
    pub scatter_crossings: usize,
    /// Per laser, what its own crossings say of the fit.
    pub verdicts: [PlaneVerdict; 2],
}

impl OutsideFit {
    /// Laser `laser`'s plane (`v · r = 1/Z` on the rays at the estimate's focal scale),
    /// `None` unless determined.
    pub fn plane(&self, laser: usize) -> Option<Vector3<f64>> {
        (self.verdicts[laser] == PlaneVerdict::Determined)
            .then(|| self.pose.plane(laser))
            .flatten()
    }

    /// One standard deviation of the relative depth of a point along `ray` on laser
    /// `laser`, as [`Estimate::depth_sigma`] gives it for a pose of the estimate.
    pub fn depth_sigma(&self, laser: usize, ray: &Ray) -> f64 {
        depth_sigma_of(
            &self.pose,
            &self.marginal,
            &self.scatter,
            self.scatter_crossings,
            laser,
            ray,
        )
    }
}

/// The poses of `est` estimated jointly, as their indices among its poses, in the order
/// of its covariance.
pub fn joint_order(est: &Estimate) -> Vec<usize> {
    let mut out: Vec<(u32, usize)> = est
        .joint_of_pose
        .iter()
        .enumerate()
        .filter_map(|(p, j)| Some(((*j)?, p)))
        .collect();
    out.sort_unstable();
    out.into_iter().map(|(_, p)| p).collect()
}

/// A pose fitted from `links` against the joint poses `joint` (in [`joint_order`]) of the
/// finished estimate `est` of `ev`; `nearest`, the joint pose nearest in time, is one
/// start. `None` when nothing fixes it.
pub fn fit_outside(
    ev: &Evidence,
    est: &Estimate,
    joint: &[CrossPose],
    params: &EstimateParams,
    links: &[Link],
    nearest: Option<CrossPose>,
) -> Option<OutsideFit> {
    let lambda = est.focal_scale;
    let ties: Vec<Tie> = links
        .iter()
        .filter(|l| l.other.is_none_or(|(j, _)| (j as usize) < joint.len()))
        .filter_map(|l| {
            Some(Tie {
                laser: usize::from(l.laser),
                other: l.other.map(|(j, la)| (j as usize, usize::from(la))),
                ray: ev.rays.ray(l.u, lambda)?,
                sigma: est.spreads.crossing_px[l.class as usize],
                class: l.class as usize,
            })
        })
        .collect();
    let fit = fit_ties(ev, joint, &est.covariance, lambda, params, &ties, nearest)?;
    // The verdicts' counts: per plane, its crossings evaluated, and those the robust
    // cost weighs under one half (a crossing at the cross's centre counts for both).
    let loss = Loss::Cauchy(params.crossing_loss);
    let mut counts = [(0usize, 0usize); 2];
    for tie in &ties {
        let Some(t) = term(&fit.pose, tie, joint, ev.focal_px, lambda) else {
            continue;
        };
        let w = loss.weight(t.e / tie.sigma);
        let lasers = if tie.other.is_some() {
            &[tie.laser][..]
        } else {
            &[0, 1][..]
        };
        for &l in lasers {
            counts[l].0 += 1;
            counts[l].1 += usize::from(w < 0.5);
        }
    }
    let verdicts = counts.map(|(total, bad)| PlaneVerdict::of_counts(total, bad));
    Some(OutsideFit {
        pose: fit.pose,
        marginal: fit.marginal,
        scatter: fit.scatter,
        scatter_crossings: fit.scatter_crossings,
        verdicts,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::solve::calibrate::calibrate;
    use crate::solve::estimate_tests::{anchored_every, evidence_of};
    use crate::solve::synthetic::{path_scan, PathSpec};
    use crate::solve::SolveParams;

    /// A frame fitted after the estimate is fitted as the estimate fitted it: every
    /// pose outside the anchors of a noisy synthetic sweep (every third frame an
    /// anchor), fitted again from its crossings with the anchors alone, comes out at
    /// the pose, covariance and verdicts the estimate gave it.
    #[test]
    fn a_frame_fitted_after_the_estimate_is_fitted_as_the_estimate_fits_it() {
        let scan = path_scan(&PathSpec {
            frames: 60,
            ..PathSpec::default()
        });
        let ev = anchored_every(evidence_of(&scan, 0.1, 7, |_, _| true), 3);
        let params = SolveParams::default();
        let cal = calibrate(&ev, &params).expect("calibration");
        let est = &cal.estimate;
        let joint: Vec<CrossPose> = joint_order(est).iter().map(|&p| est.poses[p]).collect();
        let eparams = params.estimate_params();
        let mut compared = 0;
        for f in (0..ev.num_poses()).filter(|&f| !ev.is_anchor(f)) {
            let links: Vec<Link> = ev
                .crossings
                .iter()
                .filter_map(|c| {
                    let (a, b) = (ev.planes[c.a as usize], ev.planes[c.b as usize]);
                    let (own, other) = match (a.pose as usize == f, b.pose as usize == f) {
                        (true, true) => (a, None),
                        (true, false) => (a, Some(b)),
                        (false, true) => (b, Some(a)),
                        (false, false) => return None,
                    };
                    let other = match other {
                        None => None,
                        Some(o) => Some((est.joint_of_pose[o.pose as usize]?, o.laser)),
                    };
                    Some(Link {
                        laser: own.laser,
                        other,
                        u: c.u,
                        class: c.class,
                    })
                })
                .collect();
            let frame = ev.pose_frames[f];
            let nearest = ev
                .pose_frames
                .iter()
                .enumerate()
                .filter_map(|(p, &pf)| Some((pf.abs_diff(frame), est.joint_of_pose[p]?)))
                .min()
                .map(|(_, j)| joint[j as usize]);
            let fit = fit_outside(&ev, est, &joint, &eparams, &links, nearest).expect("a fit");
            for laser in 0..2 {
                let slot = ev
                    .planes
                    .iter()
                    .position(|s| s.pose as usize == f && usize::from(s.laser) == laser)
                    .expect("plane");
                assert_eq!(
                    fit.verdicts[laser], cal.verdicts[slot],
                    "pose {f} laser {laser}"
                );
                let (Some(v), Some(w)) = (fit.pose.plane(laser), est.poses[f].plane(laser)) else {
                    panic!("pose {f} has no plane {laser}");
                };
                assert!(
                    (v - w).norm() <= 1e-9 * w.norm(),
                    "pose {f}: {v} against {w}"
                );
            }
            let (m, n) = (fit.marginal, est.marginals[f]);
            assert!((m - n).norm() <= 1e-6 * n.norm(), "pose {f}'s covariance");
            compared += 1;
        }
        assert!(compared >= 30, "{compared} poses compared");
    }
}
