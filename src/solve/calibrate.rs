//! The self-calibration of a whole scan: a linear start, then the joint estimator, then
//! what each plane's own evidence says about it.
//!
//! Owns the order of the solver's stages and the small API the pipeline calls
//! ([`calibrate`] → [`Calibration`]); the stages are [`super::solve`] (the linear start:
//! coplanarity null space, the shift `w` from the orthogonality of the crosses,
//! extension), [`super::init`] (poses from planes) and [`super::estimate`] (the joint
//! robust estimate and its covariance).
//!
//! # What a plane is told
//! Every plane of the evidence gets a verdict ([`PlaneVerdict`]):
//! - `Determined`: its pose was estimated; the uncertainty of each point on it follows
//!   from the estimate ([`Calibration::depth_sigma`]), and triangulation keeps the points
//!   that are determined well enough;
//! - `Disputed`: most of its own crossings reject the estimate (their robust weight under
//!   one half): the plane contradicts its evidence and is not used;
//! - `NoEvidence`: no crossing of it could be evaluated, or the start could not place
//!   its pose.

use nalgebra::Vector3;
use rayon::prelude::*;
use serde::Serialize;

use super::choose::{best_of_preferring, least_cost, score};
pub use super::choose::{Alternative, AMBIGUOUS_CHI2};
use super::conditional::{self, AnchorSplit};
use super::estimate::{self, Estimate, EstimateParams, Spreads, Start};
use super::evidence::{CrossingClass, Evidence, Observation, Ray};
use super::{init, Problem, SolveError, SolveParams};
use crate::intersect::Crossing;

type V3 = Vector3<f64>;

/// What the estimate says of one plane.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum PlaneVerdict {
    Determined,
    Disputed,
    NoEvidence,
}

impl PlaneVerdict {
    /// The verdict on a plane with `total` crossings evaluated, of which the estimate
    /// weighs `bad` under one half.
    pub fn of_counts(total: usize, bad: usize) -> Self {
        if total == 0 {
            Self::NoEvidence
        } else if 2 * bad > total {
            Self::Disputed
        } else {
            Self::Determined
        }
    }
}

/// Counts for the report.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct CalibrationSummary {
    pub planes: usize,
    pub planes_determined: usize,
    pub planes_disputed: usize,
    pub planes_without_evidence: usize,
    /// Planes the linear start solved (and of those, in its global subset).
    pub planes_in_start: usize,
    pub planes_in_global_start: usize,
    pub crossings: usize,
    /// Crossings the estimate weighs at under one half (beyond its Cauchy scale).
    pub crossings_outlying: usize,
    pub iterations: usize,
    pub spreads: Option<Spreads>,
    pub focal_scale: f64,
    pub focal_scale_std: Option<f64>,
    /// RMS departure from 90° of the crosses (0 by construction in the estimate; kept for
    /// the report's continuity).
    pub orthogonality_rms_deg: f64,
    /// Other solutions the search over the shift `w` found and refined, best first: a
    /// scan whose crosses fix `w` poorly has more than one.
    pub alternatives: Vec<Alternative>,
}

/// Largest number of minima of the orthogonality cost refined jointly.
const MAX_CANDIDATES: usize = 3;

/// A minimum of the orthogonality cost is refined jointly when its cost is at most this
/// many times the best one's: the start's planes are noisy, and the joint estimate,
/// not the start, judges.
const CANDIDATE_COST_RATIO: f64 = 4.0;

/// Linear starts made at most, each in the rays of the focal scale the one before found
/// (see [`linear_start_at`]).
const FOCAL_START_ROUNDS: usize = 6;

/// Times the linear start is made again at the joint estimate's focal scale at most
/// (see [`restart_at_found_focal`]).
const FOCAL_RESTARTS: usize = 2;

/// The linear starts stop when one finds the focal scale it was made at to this
/// relative change.
const FOCAL_START_TOLERANCE: f64 = 2e-3;

/// The scan's planes and how well each is known.
#[derive(Clone, Debug)]
pub struct Calibration {
    /// The estimate (see [`calibrate`]).
    pub estimate: Estimate,
    /// The evidence the estimate was made on (the caller's).
    pub evidence: Evidence,
    /// Per plane of the evidence.
    pub verdicts: Vec<PlaneVerdict>,
    pub summary: CalibrationSummary,
}

impl Calibration {
    /// Plane `i` (of the caller's evidence) as `v` with `v · r = 1/Z` on the rays at the
    /// estimated focal scale; `None` unless determined.
    pub fn plane(&self, i: usize) -> Option<V3> {
        if self.verdicts.get(i) != Some(&PlaneVerdict::Determined) {
            return None;
        }
        self.evidence.planes.get(i)?.plane_in(&self.estimate.poses)
    }

    /// The ray of the undistorted normalised point `u` (camera file coordinates) at the
    /// estimated focal scale.
    pub fn ray(&self, u: [f64; 2]) -> Option<Ray> {
        self.evidence.rays.ray(u, self.estimate.focal_scale)
    }

    /// One standard deviation of the relative depth of a point along `ray` on plane `i`
    /// (of the caller's evidence); infinite for a plane not estimated.
    pub fn depth_sigma(&self, i: usize, ray: &Ray) -> f64 {
        let Some(slot) = self.evidence.planes.get(i) else {
            return f64::INFINITY;
        };
        self.estimate
            .depth_sigma(slot.pose as usize, usize::from(slot.laser), ray)
    }
}

/// A crossing of the evidence as the linear start takes it.
fn as_crossing(c: &Observation) -> Crossing {
    Crossing {
        a: c.a.min(c.b),
        b: c.a.max(c.b),
        u: c.u,
        sin_angle: c.sin_angle,
    }
}

/// The linear start: the strong crossings solved by [`super::solve`], then every plane
/// it left unsolved fitted from all its crossings, faint ones too, with the solved
/// planes (the far end of a sweep under water has only faint curves). Planes on the
/// rays at the start's focal scale (`v · (x/λ, y/λ, 1)`, the rays without distortion).
/// With the focal scale estimated, the start is made again in the rays of the scale it
/// found ([`linear_start_at`]) until that scale stops moving.
pub(super) fn linear_start(
    evidence: &Evidence,
    params: &SolveParams,
) -> Result<(super::Solution, Vec<Option<V3>>), SolveError> {
    if !params.estimate_focal {
        return linear_start_at(evidence, params, 1.0);
    }
    let mut at = 1.0;
    let mut best: Option<(super::Solution, Vec<Option<V3>>)> = None;
    for round in 0..FOCAL_START_ROUNDS {
        let (start, planes) = match linear_start_at(evidence, params, at) {
            Ok(found) => found,
            // The last start made stands: in other rays other crossings can fall short.
            Err(e) if best.is_some() => {
                tracing::debug!(
                    round,
                    at,
                    "no linear start in the rays of a focal scale: {e}"
                );
                break;
            }
            Err(e) => return Err(e),
        };
        let relative = start.focal_scale / at;
        tracing::debug!(
            round,
            at,
            found = start.focal_scale,
            "linear start in the rays of a focal scale"
        );
        // A scale that is no number ends the rounds; the last start made stands.
        if !(relative.is_finite() && relative > 0.0) && best.is_some() {
            break;
        }
        best = Some((start, planes));
        if (relative - 1.0).abs() < FOCAL_START_TOLERANCE || !relative.is_finite() {
            break;
        }
        at *= relative;
    }
    best.ok_or(SolveError::Degenerate("no linear start"))
}

/// [`linear_start`] on the rays of the focal scale `at` (`δ⁻¹(δ(u)/at)`, the distortion
/// applied at the radius that focal length gives): the coplanarity of crossings is
/// blind to the focal length only without distortion, so a start made in the camera
/// file's rays when the focal length is far off sees bent crossings. The solution's
/// focal scale is made absolute (`at` times the one found in those rays).
fn linear_start_at(
    evidence: &Evidence,
    params: &SolveParams,
    at: f64,
) -> Result<(super::Solution, Vec<Option<V3>>), SolveError> {
    let as_crossing = |c: &Observation| {
        let mut x = as_crossing(c);
        if at != 1.0 {
            if let Some(ray) = evidence.rays.ray(c.u, at) {
                x.u = [ray.r.x, ray.r.y];
            }
        }
        x
    };
    let strong: Vec<Crossing> = evidence
        .crossings
        .iter()
        .filter(|c| c.class == CrossingClass::Strong)
        .map(as_crossing)
        .collect();
    let by_pose = evidence.planes_of_poses();
    let partner: Vec<Option<u32>> = evidence
        .planes
        .iter()
        .map(|p| by_pose[p.pose as usize][usize::from(p.laser == 0)])
        .collect();
    let problem = Problem {
        num_curves: evidence.planes.len(),
        crossings: &strong,
        partner: &partner,
        focal_px: evidence.focal_px,
    };
    let start = super::solve(&problem, params)?;
    let mut given = start.given_planes();
    if let Some(ctx) = start.fit_context {
        let all: Vec<Crossing> = evidence.crossings.iter().map(&as_crossing).collect();
        let active: Vec<bool> = all
            .iter()
            .map(|c| c.sin_angle >= ctx.min_sin_angle)
            .collect();
        let fixed: Vec<bool> = given.iter().map(Option::is_some).collect();
        super::extend_and_refine(
            &Problem {
                crossings: &all,
                ..problem
            },
            &active,
            &mut given,
            &fixed,
            (&ctx, &params.cancel),
            0,
        );
        params.cancel.check()?;
    }
    let lambda = start.focal_scale;
    let planes = given
        .iter()
        .map(|p| p.map(|v| V3::new(v.x * lambda, v.y * lambda, v.z)))
        .collect();
    let start = super::Solution {
        focal_scale: at * lambda,
        ..start
    };
    Ok((start, planes))
}

/// Self-calibrates the scan of `evidence` (see the module docs).
pub fn calibrate(evidence: &Evidence, params: &SolveParams) -> Result<Calibration, SolveError> {
    calibrate_from(evidence, params, None)
}

/// [`calibrate`], started from the given planes (per plane of `evidence`, `v · r = 1/Z`)
/// instead of the linear start when `given` is set. For evaluation: started from a
/// simulation's true planes, it tells whether the crossings hold the true solution, and
/// determine it, whatever a start finds.
pub fn calibrate_from(
    evidence: &Evidence,
    params: &SolveParams,
    given: Option<&[Option<V3>]>,
) -> Result<Calibration, SolveError> {
    let from = match given {
        Some(planes) => StartFrom::Only(planes),
        None => StartFrom::Starts,
    };
    calibrate_with(evidence, params, from, &super::Cancel::default())
}

/// [`calibrate`], with the planes of an earlier estimate (`warm`, per plane of
/// `evidence`) as one more start beside the two cold ones, and stopped with
/// [`SolveError::Cancelled`] once `cancel` is set: the daemon's epochs, superseded by its
/// final solve. The warm start is a candidate, not the answer: the estimate that
/// explains the evidence best wins, as offline. (Started from the last epoch alone, an
/// epoch that had settled in a wrong solution passed it on to every later one: on a
/// table top every live cloud after the first lay on wrong planes while the final one,
/// made cold, was right.)
pub fn calibrate_until(
    evidence: &Evidence,
    params: &SolveParams,
    warm: Option<&[Option<V3>]>,
    cancel: &super::Cancel,
) -> Result<Calibration, SolveError> {
    let from = match warm {
        Some(planes) => StartFrom::AlsoFrom(planes),
        None => StartFrom::Starts,
    };
    calibrate_with(evidence, params, from, cancel)
}

/// Where the joint estimate starts.
#[derive(Clone, Copy)]
enum StartFrom<'a> {
    /// The two cold starts (the linear start and the fixed-centre start).
    Starts,
    /// These planes only.
    Only(&'a [Option<V3>]),
    /// The two cold starts and these planes.
    AlsoFrom(&'a [Option<V3>]),
}

fn calibrate_with(
    evidence: &Evidence,
    params: &SolveParams,
    from: StartFrom<'_>,
    cancel: &super::Cancel,
) -> Result<Calibration, SolveError> {
    evidence.validate().map_err(SolveError::InvalidProblem)?;
    if let StartFrom::Only(planes) | StartFrom::AlsoFrom(planes) = from {
        if planes.len() != evidence.planes.len() {
            return Err(SolveError::InvalidProblem(format!(
                "{} start planes for {} planes",
                planes.len(),
                evidence.planes.len()
            )));
        }
    }
    // The linear start looks at the cancellation too: a superseded epoch in its
    // extension (seconds of one core at thousands of planes) held a core the final
    // solve wanted.
    let params = &SolveParams {
        cancel: cancel.clone(),
        ..params.clone()
    };
    // The anchors are estimated jointly (everything below up to `best_of`), the other
    // poses fitted against them after.
    let split = AnchorSplit::of(evidence);
    let sub = &split.evidence;
    let eparams = EstimateParams {
        cancel: cancel.clone(),
        ..params.estimate_params()
    };
    let given = |planes: &[Option<V3>]| -> Result<Starts, SolveError> {
        let planes = split.planes_of(&extended(evidence, planes));
        let estimates = refine_starts(sub, &planes, 1.0, 0.1, &eparams)?;
        Ok((super::Solution::empty(), planes, estimates))
    };
    // The estimates from the warm start, which give way to a cold one of the same solution.
    let mut second = 0..0;
    let (cold, (start, planes, mut estimates)) = match from {
        StartFrom::Starts => (true, two_starts(evidence, &split, params, &eparams)?),
        StartFrom::Only(planes) => (false, given(planes)?),
        StartFrom::AlsoFrom(planes) => {
            // Side by side: neither depends on the other.
            let (warm, cold) = rayon::join(
                || given(planes),
                || two_starts(evidence, &split, params, &eparams),
            );
            match cold {
                Ok((start, planes, mut estimates)) => {
                    if let Ok((_, _, w)) = warm {
                        second = estimates.len()..estimates.len() + w.len();
                        estimates.extend(w);
                    }
                    (true, (start, planes, estimates))
                }
                Err(SolveError::Cancelled) => return Err(SolveError::Cancelled),
                Err(e) => match warm {
                    Ok(w) if !w.2.is_empty() => (false, w),
                    _ => return Err(e),
                },
            }
        }
    };
    let sigma_px = start_spread_px(&start, evidence);
    if params.estimate_focal && cold {
        let made_at = start.focal_scale;
        restart_at_found_focal(
            evidence,
            &split,
            params,
            (made_at, sigma_px),
            &eparams,
            &mut estimates,
        );
    }
    cancel.check()?;
    let (est, alternatives) = best_of_preferring(sub, estimates, &eparams, second)
        .ok_or(SolveError::Degenerate("no start for the joint estimate"))?;
    let est = super::folds::reseed_folds(sub, est, &eparams);
    cancel.check()?;
    let est = super::scatter::with_bounded_scatter(sub, est, &eparams);
    let focal_scale_std = params
        .estimate_focal
        .then(|| est.marginals.first().map(|m| m[(6, 6)].max(0.0).sqrt()))
        .flatten();
    let est = if split.is_everything() {
        est
    } else {
        conditional::complete(evidence, &split, est, &eparams)
    };
    // The fits stop early once cancelled: what they gave is no answer.
    cancel.check()?;
    let verdicts = verdicts(evidence, &est);
    let count = |v: PlaneVerdict| verdicts.iter().filter(|x| **x == v).count();
    let summary = CalibrationSummary {
        planes: evidence.planes.len(),
        planes_determined: count(PlaneVerdict::Determined),
        planes_disputed: count(PlaneVerdict::Disputed),
        planes_without_evidence: count(PlaneVerdict::NoEvidence),
        planes_in_start: planes.iter().filter(|p| p.is_some()).count(),
        planes_in_global_start: start.global.len(),
        crossings: evidence.crossings.len(),
        crossings_outlying: est.crossing_weights.iter().filter(|w| **w < 0.5).count(),
        iterations: est.iterations,
        spreads: Some(est.spreads),
        focal_scale: est.focal_scale,
        focal_scale_std,
        orthogonality_rms_deg: 0.0,
        alternatives,
    };
    Ok(Calibration {
        estimate: est,
        evidence: evidence.clone(),
        verdicts,
        summary,
    })
}

/// `given` with each plane it lacks fitted to its crossings with the planes it has: each
/// such crossing fixes the inverse depth there, `v · r = v_given · r` (robust linear
/// least squares, as a pose fitted against the anchors starts:
/// [`conditional::linear_plane`]), in passes while planes are gained. A warm start (the
/// daemon's last epoch) lacks the frames that came since; their poses would otherwise be
/// carried on from the last two known ones, and 16 frames on, a sweep's aim has turned
/// far enough that the estimate started there ended at 8-125 px (an epoch test, once
/// the first solve took longer than before).
fn extended(evidence: &Evidence, given: &[Option<V3>]) -> Vec<Option<V3>> {
    let mut planes = given.to_vec();
    loop {
        let mut rows: Vec<Vec<(V3, f64)>> = vec![Vec::new(); planes.len()];
        for c in &evidence.crossings {
            let r = V3::new(c.u[0], c.u[1], 1.0);
            for (me, other) in [(c.a, c.b), (c.b, c.a)] {
                if let (None, Some(v)) = (planes[me as usize], planes[other as usize]) {
                    rows[me as usize].push((r, v.dot(&r)));
                }
            }
        }
        let found: Vec<(usize, V3)> = rows
            .iter()
            .enumerate()
            .filter_map(|(i, rows)| Some((i, conditional::linear_plane(rows)?)))
            .collect();
        if found.is_empty() {
            return planes;
        }
        for (i, v) in found {
            planes[i] = Some(v);
        }
    }
}

/// The crossings' spread to start from: the linear start's, or a tenth of a pixel.
fn start_spread_px(start: &super::Solution, evidence: &Evidence) -> f64 {
    if start.sigma_img > 0.0 {
        (start.sigma_img * evidence.focal_px).max(1e-3)
    } else {
        0.1
    }
}

/// The linear start (empty when it failed), its planes, and the estimates of both starts.
type Starts = (super::Solution, Vec<Option<V3>>, Vec<Estimate>);

/// The estimates from both starts of a scan: the linear start (the coplanarity null
/// space; it sees every crossing, those of the other frames with the anchors too, since
/// among the anchors alone a sparse scan's crossings may be too few for its global
/// subset) and the fixed-centre start ([`super::centre`]: every plane through one centre
/// of the hand), each refined at every shift its crosses leave open ([`refine_starts`]).
/// Each start can settle a different part of a scan wrongly: the linear start extends
/// planes from plane to plane, and a run of frames whose crossings barely turn them
/// (stripes on one flat table, the other laser missing) drifts along the chain, which the
/// joint estimate then keeps (a table top: 0.7 % of the points 4-10 % off, the cost 36 %
/// above the truth's); the centre start knows nothing of a hand that walks. The
/// estimator's [`score`] chooses among all. The centre start comes as two twins that its
/// own evidence cannot tell apart (the planes and their reflection through the centre);
/// each is refined on all the anchors unless it loses on every other one
/// ([`super::screen`]) to the linear start's. Also returns the
/// linear start (empty when it failed) and its planes.
fn two_starts(
    evidence: &Evidence,
    split: &AnchorSplit,
    params: &SolveParams,
    eparams: &EstimateParams,
) -> Result<Starts, SolveError> {
    let sub = &split.evidence;
    // The two starts do not depend on each other, nor do the linear start's refinement
    // and the centre start's refinement on every other anchor (its screen): each pair
    // runs side by side (each side is partly serial). Only the screen's verdict waits
    // for the linear start's estimates. The answer is the one made in sequence.
    let (linear, centre) = rayon::join(
        || linear_start(evidence, params),
        || super::centre::fixed_centre_start(sub, &eparams.cancel),
    );
    let (start, planes, linear_error) = match linear {
        Ok((start, planes)) => (start, split.planes_of(&planes), None),
        // Nothing for the null space to stand on (a table top, a standing hand in a
        // plain room): the centre start alone.
        Err(e @ (SolveError::TooFewPlanes { .. } | SolveError::TooFewCrosses { .. })) => {
            // Not a failure of the scan: the centre start is the way on, and when it
            // finds nothing either, `SolveError::NoStart` says both. At INFO, live
            // epochs early in a scan printed the error's advice as if the scan failed.
            tracing::debug!("the linear start found nothing to stand on, the fixed-centre start goes on alone ({e})");
            (
                super::Solution::empty(),
                vec![None; sub.planes.len()],
                Some(e),
            )
        }
        Err(e) => return Err(e),
    };
    let sigma_px = start_spread_px(&start, evidence);
    match &centre {
        Some(c) => tracing::debug!(
            "the centre start: crosses {:.2}° from orthogonal",
            c.orthogonality_rms.asin().to_degrees()
        ),
        None => tracing::debug!("no centre start"),
    }
    // The twins fit the start's own evidence alike; the hand's walk tells them apart.
    // Each is screened against the linear start's estimates only, not against the other
    // twin: a start refined on half the anchors may stop in a poor minimum its
    // refinement on all of them leaves (on tuning 15 the right twin scored worse than
    // the wrong one on the half, then found a shift on all anchors that beat it by
    // 5·10⁴), and which twin comes first is rounding. The linear start's best is
    // refitted on the half once, for both. Each piece begins as soon as what it needs is
    // known ([`super::pieces`]); without the linear start's estimates there is nothing
    // to screen against, and the twins are refined unscreened.
    let pieces = StartPieces {
        sub,
        linear_planes: linear_error
            .is_none()
            .then_some((&planes[..], start.focal_scale)),
        twins: centre.as_ref().map(|c| &c.twins),
        sigma_px,
        eparams,
    };
    let (refined, [first, second]) = super::pieces::run(&pieces);
    let mut estimates = Vec::new();
    let linear_failed = linear_error.is_some();
    let mut failure = linear_error;
    match refined {
        Some(Ok(found)) => estimates.extend(found),
        Some(Err(e)) => failure = Some(e),
        None => {}
    }
    estimates.extend(first);
    estimates.extend(second);
    match (estimates.is_empty(), failure) {
        // Neither start found anything: both say why, with what there was (the linear
        // start's own words alone asked whether the lasers were seen, of a scan with
        // a thousand curves).
        (true, Some(e)) if centre.is_none() && linear_failed => Err(SolveError::NoStart {
            planes: evidence.planes.len(),
            crossings: evidence.crossings.len(),
            strong: evidence
                .crossings
                .iter()
                .filter(|c| c.class == CrossingClass::Strong)
                .count(),
            linear: Box::new(e),
        }),
        (true, Some(e)) => Err(e),
        (true, None) => Err(SolveError::Degenerate("no start for the joint estimate")),
        (false, _) => Ok((start, planes, estimates)),
    }
}

/// The pieces of [`two_starts`]' refinements ([`super::pieces`]).
struct StartPieces<'a> {
    sub: &'a Evidence,
    /// The linear start's planes and focal scale, where it found any.
    linear_planes: Option<(&'a [Option<V3>], f64)>,
    /// The centre start's twins, where it found them.
    twins: Option<&'a [Vec<Option<V3>>; 2]>,
    sigma_px: f64,
    eparams: &'a EstimateParams,
}

impl super::pieces::Pieces for StartPieces<'_> {
    type Estimate = Estimate;
    type Screen = super::screen::OnHalf;

    fn linear(&self) -> Option<Result<Vec<Estimate>, SolveError>> {
        let (planes, lambda) = self.linear_planes?;
        Some(refine_starts(
            self.sub,
            planes,
            lambda,
            self.sigma_px,
            self.eparams,
        ))
    }

    /// Without the linear start's estimates there is nothing to screen against
    /// (`OnHalf::best_score` would give none): the screen is not refined for nothing.
    fn screen(&self, twin: usize) -> Option<Self::Screen> {
        let twins = self.twins.filter(|_| self.linear_planes.is_some())?;
        super::screen::on_half(self.sub, &twins[twin], self.sigma_px, self.eparams)
    }

    fn best_on_half(&self, screen: &Self::Screen, linear: &[Estimate]) -> Option<f64> {
        screen.best_score(self.sub, linear, self.eparams)
    }

    fn loses(&self, screen: &Self::Screen, best: f64) -> bool {
        screen.loses_to_score(best)
    }

    fn refine_twin(&self, twin: usize, loses: bool) -> Vec<Estimate> {
        let Some(twins) = self.twins else {
            return Vec::new();
        };
        if loses {
            tracing::debug!(
                twin,
                "the centre start loses on every other anchor: left out"
            );
            return Vec::new();
        }
        match refine_starts(self.sub, &twins[twin], 1.0, self.sigma_px, self.eparams) {
            Ok(found) => found,
            Err(e) => {
                tracing::debug!(twin, "the centre start did not refine: {e}");
                Vec::new()
            }
        }
    }

    /// Where the caller spares the cores (offline, the daemon's final solve: their dense
    /// factorisations take more than one thread), the pieces run side by side.
    fn side_by_side(&self) -> bool {
        self.eparams.threads.0 > 1
    }
}

/// With the focal scale estimated: while the joint estimate of least cost moves the focal
/// scale away from the one its start was made at (`at.0`), the linear start is made again
/// in the rays of the joint estimate's scale, with that scale held (the joint estimate's
/// is the better determined: the orthogonality of the start's crosses alone can miss it
/// by 10 %), and refined; the cost then chooses among all ([`best_of`]).
fn restart_at_found_focal(
    evidence: &Evidence,
    split: &AnchorSplit,
    params: &SolveParams,
    (mut made_at, sigma_px): (f64, f64),
    eparams: &EstimateParams,
    estimates: &mut Vec<Estimate>,
) {
    let held = SolveParams {
        estimate_focal: false,
        ..params.clone()
    };
    for _ in 0..FOCAL_RESTARTS {
        let Some(k) = least_cost(&split.evidence, estimates, eparams) else {
            return;
        };
        let found = estimates[k].focal_scale;
        if (found / made_at - 1.0).abs() < FOCAL_START_TOLERANCE {
            return;
        }
        tracing::debug!(
            made_at,
            found,
            "the joint estimate moved the focal scale: starting again there"
        );
        let planes = match linear_start_at(evidence, &held, found) {
            Ok((_, planes)) => split.planes_of(&planes),
            Err(e) => {
                tracing::debug!("no linear start at the focal scale found: {e}");
                return;
            }
        };
        made_at = found;
        match refine_starts(&split.evidence, &planes, found, sigma_px, eparams) {
            Ok(more) => estimates.extend(more),
            Err(e) => {
                tracing::debug!("the start at the focal scale found did not refine: {e}");
                return;
            }
        }
    }
}

/// The global search over the shift: every minimum of the orthogonality cost of the
/// start's crosses (`planes` at focal scale `lambda`), refined jointly; the start's own
/// first, with the spreads measured, the others under its spreads, and fully only where
/// they compete with it.
pub(super) fn refine_starts(
    sub: &Evidence,
    planes: &[Option<V3>],
    lambda: f64,
    sigma_px: f64,
    eparams: &EstimateParams,
) -> Result<Vec<Estimate>, SolveError> {
    let poses_at = |w: &V3| {
        let shifted: Vec<Option<V3>> = planes.iter().map(|p| p.map(|v| v + w)).collect();
        init::poses_from_planes(sub, &shifted).map(|(poses, _)| poses)
    };
    let shifts = shift_candidates(sub, planes);
    // The first shift that gives poses is refined under spreads of its own, and its
    // failure is the answer's.
    let Some((at, poses)) = shifts
        .iter()
        .enumerate()
        .find_map(|(i, w)| Some((i, poses_at(w)?)))
    else {
        return Ok(Vec::new());
    };
    let start = Start {
        spreads: init::start_spreads(sub, &poses, sigma_px),
        poses,
        focal_scale: lambda,
    };
    let mut first = estimate::estimate(sub, &start, eparams)?;
    normalise_scale(sub, &mut first);
    let base = score(sub, &first, eparams);
    tracing::debug!(
        lambda,
        found = first.focal_scale,
        cost = base,
        "the first start"
    );
    // Every later shift under the first's spreads, each on its own: where the caller
    // spares the cores they run side by side (the twin that the screen keeps refined
    // alone on the dive's final solve, one core idle), in order either way.
    let further = |w: &V3| -> Option<Estimate> {
        let start = Start {
            poses: poses_at(w)?,
            focal_scale: lambda,
            spreads: first.spreads,
        };
        let once = EstimateParams {
            variance_rounds: 1,
            ..eparams.clone()
        };
        let mut est = match estimate::estimate(sub, &start, &once) {
            Ok(est) => est,
            Err(e) => {
                tracing::debug!("an alternative start did not refine: {e}");
                return None;
            }
        };
        normalise_scale(sub, &mut est);
        let delta = score(sub, &est, eparams) - base;
        tracing::debug!(lambda, found = est.focal_scale, delta, "a further start");
        if delta < AMBIGUOUS_CHI2 {
            // It competes: measure its own spreads too.
            let again = Start {
                poses: est.poses.clone(),
                focal_scale: est.focal_scale,
                spreads: est.spreads,
            };
            if let Ok(mut full) = estimate::estimate(sub, &again, eparams) {
                normalise_scale(sub, &mut full);
                est = full;
            }
        }
        Some(est)
    };
    let rest = &shifts[at + 1..];
    let found: Vec<Option<Estimate>> = if eparams.threads.0 > 1 {
        rest.par_iter().map(further).collect()
    } else {
        rest.iter().map(further).collect()
    };
    Ok(std::iter::once(first)
        .chain(found.into_iter().flatten())
        .collect())
}

/// The shifts `w` to refine: every minimum of the orthogonality cost of the crosses whose
/// two planes the start gave, within [`CANDIDATE_COST_RATIO`] of the best, at most
/// [`MAX_CANDIDATES`], the one nearest no shift first (the start's own). Always at least
/// no shift.
fn shift_candidates(evidence: &Evidence, planes: &[Option<V3>]) -> Vec<V3> {
    let mut v0 = Vec::new();
    let mut crosses = Vec::new();
    for slots in evidence.planes_of_poses() {
        if let [Some(a), Some(b)] = slots {
            if let (Some(va), Some(vb)) = (planes[a as usize], planes[b as usize]) {
                crosses.push((v0.len(), v0.len() + 1));
                v0.push(va);
                v0.push(vb);
            }
        }
    }
    let minima = super::ortho::shift_minima(&v0, &crosses);
    let Some(best) = minima.first().map(|m| m.cost) else {
        return vec![V3::zeros()];
    };
    let mut out: Vec<V3> = minima
        .iter()
        .filter(|m| m.cost <= CANDIDATE_COST_RATIO * best.max(f64::MIN_POSITIVE))
        .take(MAX_CANDIDATES)
        .map(|m| m.w)
        .collect();
    out.sort_by(|a, b| a.norm().total_cmp(&b.norm()));
    if out.first().is_none_or(|w| w.norm() > 0.0) {
        // The start's own shift, whatever the search says of it.
        out.insert(0, V3::zeros());
        out.truncate(MAX_CANDIDATES);
    }
    out
}

/// Rescales the centres (and their covariance, and the centre spread) so that the median
/// inverse depth at the crossings is 1.
pub(super) fn normalise_scale(evidence: &Evidence, est: &mut Estimate) {
    let Some(m) = median_inverse_depth(evidence, &est.poses, est.focal_scale, |k| {
        est.crossing_weights.get(k).is_some_and(|w| *w >= 0.5)
    }) else {
        return;
    };
    for p in &mut est.poses {
        p.centre *= m;
    }
    let t = nalgebra::SVector::<f64, 7>::from_column_slice(&[1.0, 1.0, 1.0, m, m, m, 1.0]);
    let t = nalgebra::SMatrix::<f64, 7, 7>::from_diagonal(&t);
    for cov in &mut est.marginals {
        *cov = t * *cov * t;
    }
    // The centres' rows and columns of the joint covariance likewise.
    let n = est.covariance.nrows();
    let factor = |i: usize| if i < n - n % 6 && i % 6 >= 3 { m } else { 1.0 };
    for j in 0..n {
        for i in 0..n {
            est.covariance[(i, j)] *= factor(i) * factor(j);
        }
    }
    est.spreads.centre *= m.abs();
}

/// The median inverse depth of `poses` (at focal scale `lambda`) at the crossings `k`
/// that `counts(k)` keeps, on the first plane of each; `None` if there is none, or it
/// is not finite or zero. [`normalise_scale`] divides the estimate's scale by it.
pub(super) fn median_inverse_depth(
    evidence: &Evidence,
    poses: &[super::pose::CrossPose],
    lambda: f64,
    counts: impl Fn(usize) -> bool,
) -> Option<f64> {
    let inverse_depths: Vec<f64> = evidence
        .crossings
        .iter()
        .enumerate()
        .filter(|(k, _)| counts(*k))
        .filter_map(|(_, c)| {
            let v = evidence.planes[c.a as usize].plane_in(poses)?;
            let ray = evidence.rays.ray(c.u, lambda)?;
            Some(v.dot(&ray.r))
        })
        .collect();
    super::median(inverse_depths).filter(|m| m.is_finite() && *m != 0.0)
}

/// Per plane, what its own crossings say of the estimate (see the module docs).
fn verdicts(evidence: &Evidence, est: &Estimate) -> Vec<PlaneVerdict> {
    let mut counts = vec![(0usize, 0usize); evidence.planes.len()];
    for (c, &w) in evidence.crossings.iter().zip(&est.crossing_weights) {
        for p in [c.a, c.b] {
            let slot = &mut counts[p as usize];
            if w > 0.0 {
                slot.0 += 1;
                slot.1 += usize::from(w < 0.5);
            }
        }
    }
    counts
        .iter()
        .map(|&(total, bad)| PlaneVerdict::of_counts(total, bad))
        .collect()
}
