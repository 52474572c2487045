//! Which of a scan's estimates to output, and what the others are to it.
//!
//! Owns the comparison of solutions ([`score`], the robust likelihood), the choice
//! ([`best_of`]) and the report of the others ([`Alternative`]); the estimates themselves
//! are [`super::estimate`]'s, the starts [`super::calibrate`]'s.

use serde::Serialize;

use super::estimate::{self, Estimate, EstimateParams};
use super::evidence::Evidence;
use super::init;

/// A second solution of the self-calibration and how it compares with the one output
/// (one whose depths lie within three of the output's own median deviations of the
/// output's, or with no ridge of the cost between the two, is the same solution, found
/// twice, and not reported).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Alternative {
    /// How much worse it explains the evidence: twice the difference of the two robust
    /// log-likelihoods, each solution at the spreads its own residuals show
    /// ([`score`]; χ² units).
    pub delta_chi2: f64,
    /// Median relative difference of its depths from the output's at the crossings.
    pub median_depth_difference: f64,
    /// Whether it fits about as well: `delta_chi2` under the 99 % point of χ² with three
    /// degrees of freedom (those of the shift).
    pub ambiguous: bool,
}

/// The 99 % point of χ² with three degrees of freedom: two solutions whose costs differ
/// by less are not told apart by the evidence.
pub const AMBIGUOUS_CHI2: f64 = 11.34;

/// The estimate among `estimates` that explains the evidence best ([`score`]), and how
/// each other one compares with it.
#[cfg(test)]
pub(crate) fn best_of(
    evidence: &Evidence,
    estimates: Vec<Estimate>,
    params: &EstimateParams,
) -> Option<(Estimate, Vec<Alternative>)> {
    best_of_preferring(evidence, estimates, params, 0..0)
}

/// [`best_of`], where the estimates in `second` (those from an earlier estimate's
/// planes) give way to any other that is the same solution: found by the cold starts
/// alone, the answer is the one `reconstruct` gives, to the last bit.
pub(crate) fn best_of_preferring(
    evidence: &Evidence,
    mut estimates: Vec<Estimate>,
    params: &EstimateParams,
    second: std::ops::Range<usize>,
) -> Option<(Estimate, Vec<Alternative>)> {
    let mut k = least_cost(evidence, &estimates, params)?;
    // The same solution, found twice: its depths within the estimate's own deviation, or
    // in the same basin of the cost (two starts rarely stop at one point).
    let same_as = |a: &Estimate, b: &Estimate| {
        depth_difference(evidence, a, b) <= 3.0 * median_crossing_sigma(evidence, a)
            || same_basin(evidence, a, b, params)
    };
    if second.contains(&k) {
        if let Some(j) = (0..estimates.len())
            .filter(|j| !second.contains(j))
            .find(|&j| same_as(&estimates[k], &estimates[j]))
        {
            k = j;
        }
    }
    let best = estimates.swap_remove(k);
    let base = score(evidence, &best, params);
    let mut alternatives: Vec<Alternative> = estimates
        .iter()
        .filter(|e| !same_as(&best, e))
        .map(|e| {
            let delta_chi2 = score(evidence, e, params) - base;
            Alternative {
                delta_chi2,
                median_depth_difference: depth_difference(evidence, &best, e),
                ambiguous: delta_chi2 < AMBIGUOUS_CHI2,
            }
        })
        .collect();
    alternatives.sort_by(|a, b| a.delta_chi2.total_cmp(&b.delta_chi2));
    Some((best, alternatives))
}

/// The index of the estimate that explains the evidence best ([`score`]).
pub(super) fn least_cost(
    evidence: &Evidence,
    estimates: &[Estimate],
    params: &EstimateParams,
) -> Option<usize> {
    let scores: Vec<f64> = estimates
        .iter()
        .map(|e| score(evidence, e, params))
        .collect();
    tracing::debug!(?scores, "the starts' scores");
    (0..estimates.len()).min_by(|&a, &b| scores[a].total_cmp(&scores[b]))
}

/// How badly an estimate explains the evidence: −2 log of its robust likelihood, every
/// kind of residual (crossings strong and faint, the centre's, aim's and roll's second
/// differences) under Cauchy's density at the scale that fits that kind best
/// ([`cauchy_profile`]). Two solutions of one scan are compared by it, not by their
/// costs under one set of spreads: under the spreads of a wrong solution, which read
/// the evidence as noisier, the wrong one fits about as well as the right one (seen on a
/// turbid scan: 0.39 px against 0.05 px, and the right one lost); each solution's own
/// spreads enter through the `N ln s` of the density's normalisation, so a solution
/// cannot win by calling the data noisy.
pub fn score(evidence: &Evidence, est: &Estimate, params: &EstimateParams) -> f64 {
    estimate::residuals_by_kind(evidence, est, params)
        .iter()
        .zip(SCORE_FLOORS)
        .map(|(r, floor)| 2.0 * cauchy_profile(r, floor))
        .sum()
}

/// The least scale [`score`] fits to each kind of residual (crossings strong and faint,
/// pixels; the centre's second differences, in the estimate's scale, where the median
/// inverse depth is 1; aim and roll, radians per frame²): far below anything measured,
/// so that two solutions that both fit exactly (to rounding) score alike rather than by
/// the size of their rounding errors.
const SCORE_FLOORS: [f64; 5] = [1e-4, 1e-4, 1e-7, 1e-7, 1e-7];

/// `min_{s ≥ floor} Σ [ln s + ln(1 + r²/s²)]`: the negative log-likelihood (less its
/// constant) of `r` under a Cauchy density of the scale that fits them best
/// ([`cauchy_scale`]). 0 for no residuals.
fn cauchy_profile(r: &[f64], floor: f64) -> f64 {
    if r.is_empty() {
        return 0.0;
    }
    let s2 = cauchy_scale(r, floor).powi(2);
    r.iter().map(|x| (x * x / s2).ln_1p()).sum::<f64>() + 0.5 * r.len() as f64 * s2.ln()
}

/// The scale `s ≥ floor` of the Cauchy density that fits `r` best: it solves
/// `Σ t/(1 + t) = N/2`, `t = r²/s²`, whose left side falls with `s`; found by bisection
/// on `ln s`.
fn cauchy_scale(r: &[f64], floor: f64) -> f64 {
    let n = r.len() as f64;
    let top = r.iter().fold(0.0f64, |m, x| m.max(x.abs()));
    if r.is_empty() || !top.is_finite() {
        return floor;
    }
    let excess = |ln_s: f64| {
        let s2 = (2.0 * ln_s).exp();
        r.iter()
            .map(|x| {
                let t = x * x / s2;
                t / (1.0 + t)
            })
            .sum::<f64>()
            - 0.5 * n
    };
    let (mut lo, mut hi) = (floor.ln(), top.max(floor).ln() + 3.0);
    if excess(lo) <= 0.0 {
        return floor;
    }
    for _ in 0..60 {
        let mid = 0.5 * (lo + hi);
        if excess(mid) > 0.0 {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    (0.5 * (lo + hi)).exp()
}

/// Whether `a` and `b` are one minimum of the cost, reached twice: nothing rises
/// between them. Two minima are distinct when a ridge separates them; two stops of the
/// minimisation in one basin (it ends when under one unit of χ² is left to gain, and each
/// start ends somewhere else) are not, however their depths differ. Judged on the straight
/// path between their poses (rotations along the geodesic), under `a`'s spreads: one
/// basin when no point of it costs more than the worse end by [`BASIN_RIDGE_CHI2`].
fn same_basin(evidence: &Evidence, a: &Estimate, b: &Estimate, params: &EstimateParams) -> bool {
    if a.poses.len() != b.poses.len() {
        return false;
    }
    let cost = |t: f64| {
        let poses: Vec<_> = a
            .poses
            .iter()
            .zip(&b.poses)
            .map(|(pa, pb)| init::interpolate(pa, &pb.aligned_to(pa), t))
            .collect();
        let focal = a.focal_scale + t * (b.focal_scale - a.focal_scale);
        estimate::cost_of(evidence, &poses, focal, &a.spreads, params)
    };
    let ends = cost(0.0).max(cost(1.0));
    [0.25, 0.5, 0.75]
        .iter()
        .all(|&t| cost(t) <= ends + BASIN_RIDGE_CHI2)
}

/// How far the cost may rise between two stops of the minimisation for them to count
/// as one minimum: the stopping rule's own tolerance, one unit of χ².
const BASIN_RIDGE_CHI2: f64 = 1.0;

/// The median relative depth deviation that `est` gives the crossings (each on its first
/// plane).
fn median_crossing_sigma(evidence: &Evidence, est: &Estimate) -> f64 {
    let sigmas: Vec<f64> = evidence
        .crossings
        .iter()
        .step_by(7)
        .filter_map(|c| {
            let slot = evidence.planes[c.a as usize];
            let ray = evidence.rays.ray(c.u, est.focal_scale)?;
            let s = est.depth_sigma(slot.pose as usize, usize::from(slot.laser), &ray);
            s.is_finite().then_some(s)
        })
        .collect();
    super::median(sigmas).unwrap_or(0.0)
}

/// Median relative difference of the depths two estimates give at the crossings (each
/// crossing on its first plane, both at their own scale normalisation).
fn depth_difference(evidence: &Evidence, a: &Estimate, b: &Estimate) -> f64 {
    let diffs: Vec<f64> = evidence
        .crossings
        .iter()
        .filter_map(|c| {
            let slot = evidence.planes[c.a as usize];
            let depth = |e: &Estimate| {
                let v = slot.plane_in(&e.poses)?;
                let ray = evidence.rays.ray(c.u, e.focal_scale)?;
                Some(v.dot(&ray.r))
            };
            let (da, db) = (depth(a)?, depth(b)?);
            Some((da / db - 1.0).abs())
        })
        .collect();
    super::median(diffs).unwrap_or(f64::INFINITY)
}

#[cfg(test)]
mod tests {
    use super::{cauchy_profile, cauchy_scale};
    use crate::solve::synthetic::Rng;

    /// Scaling every residual by `k` moves the fitted scale by `k`, and the score by
    /// exactly `N ln k`: the density's normalisation is what stops a solution from
    /// winning by calling its residuals noise.
    #[test]
    fn the_profile_likelihood_charges_for_a_wider_spread() {
        let mut rng = Rng::new(3);
        let r: Vec<f64> = (0..500).map(|_| 0.05 * rng.normal()).collect();
        let base = cauchy_profile(&r, 1e-6);
        for k in [0.5, 3.0, 7.5] {
            let scaled: Vec<f64> = r.iter().map(|x| k * x).collect();
            let got = cauchy_profile(&scaled, 1e-6) - base;
            let want = r.len() as f64 * f64::ln(k);
            assert!(
                (got - want).abs() < 1e-6 * want.abs().max(1.0),
                "{k}: {got} {want}"
            );
        }
        // Below the floor, residuals score alike whatever their size.
        let tiny: Vec<f64> = r.iter().map(|x| 1e-9 * x).collect();
        let tinier: Vec<f64> = r.iter().map(|x| 1e-12 * x).collect();
        let (a, b) = (cauchy_profile(&tiny, 1e-6), cauchy_profile(&tinier, 1e-6));
        assert!((a - b).abs() < 1e-3, "{a} {b}");
    }

    /// A tenth of the residuals a hundred times wider (wrong crossings) move the fitted
    /// scale by under a quarter, where they make the RMS thirty times larger: a
    /// solution's score is set by what it fits, not by its outliers.
    #[test]
    fn outliers_barely_move_the_fitted_scale() {
        let mut rng = Rng::new(4);
        let clean: Vec<f64> = (0..900).map(|_| rng.normal()).collect();
        let mut dirty = clean.clone();
        dirty.extend((0..100).map(|_| 100.0 * rng.normal()));
        let (c, d) = (cauchy_scale(&clean, 1e-9), cauchy_scale(&dirty, 1e-9));
        assert!(c > 0.3 && c < 1.5, "{c}");
        assert!((d / c - 1.0).abs() < 0.25, "{c} {d}");
        let rms = |r: &[f64]| (r.iter().map(|x| x * x).sum::<f64>() / r.len() as f64).sqrt();
        assert!(rms(&dirty) > 20.0 * rms(&clean));
    }
}
