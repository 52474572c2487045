//! The robust global coplanarity stage (stages 1–3 of [`super::solve`]): the subset of
//! well-conditioned curves, the null space of its coplanarity system, and the
//! reweighting rounds that fade out wrong crossings and reject curves that most of
//! their crossings contradict.
//!
//! Owns [`robust_global`] and its outcome; the null space itself is
//! [`super::nullspace`]'s, the subset [`super::subset`]'s.

use nalgebra::Vector3;

use super::subset::{self, adjacency, select_global, Subset};
use super::{
    crossing_weight, median, nullspace, seed, Problem, SolveError, SolveParams, CAUCHY_SCALE,
    MAD_TO_SIGMA, NOISE_FLOOR,
};

/// Outcome of the robust global coplanarity stage.
#[derive(Clone, Debug)]
pub struct GlobalCoplanarity {
    /// The final subset; its `crossings` are the inliers among its curves.
    pub subset: Subset,
    pub null_space: nullspace::NullSpace,
    /// Active crossings among the subset's curves judged outliers.
    pub rejected_crossings: Vec<usize>,
    pub sigma_img: f64,
    pub residual_rms: f64,
    pub rejected_curves: Vec<u32>,
}

/// Stages 1–3: subset, coplanarity null space, robust rounds.
///
/// Inner loop (iteratively reweighted least squares): solve the subset over every
/// active crossing among its curves with weight `ω_k = 1 / (|u|² (1 + (e_k / c σ)²))`,
/// `c = 2.385` and `e_k` the Sampson residual of the previous round (a Cauchy weight:
/// wrong crossings fade out without ever removing a row, so the system keeps its
/// rank), `σ = 1.4826 · median |e|`; until the set with `|e| ≤ k σ`
/// and `σ` settle. Outer loop: crossings beyond `k σ` are outliers; curves with most of
/// their crossings out are rejected; the subset is pruned again over the inliers (a
/// curve whose remaining crossings lie on one line must leave) and re-solved if it
/// changed.
pub fn robust_global(
    problem: &Problem,
    active: &[bool],
    params: &SolveParams,
) -> Result<GlobalCoplanarity, SolveError> {
    let n_curves = problem.num_curves;
    let cr = problem.crossings;
    let mut excluded = vec![false; n_curves];
    let mut rejected_curves = Vec::new();
    let mut inlier = active.to_vec();
    let mut subset = select_global(
        n_curves,
        cr,
        &inlier,
        problem.partner,
        &excluded,
        &subset::SubsetLimits {
            max_planes: params.max_global_planes,
            min_crossings: params.min_global_crossings,
            min_bend: params.min_curve_bend,
        },
    );
    let mut prev: Vec<Option<Vector3<f64>>> = vec![None; n_curves];
    let mut robust_weight = match seed::consensus_weights(problem, active, &subset, params) {
        Some((w, _)) => w,
        None => vec![1.0; cr.len()],
    };
    let k_out = params.outlier_mad_k;
    for _outer in 0..30 {
        params.cancel.check()?;
        let n = subset.curves.len();
        if n < 4 {
            return Err(SolveError::TooFewPlanes {
                found: n,
                needed: 4,
            });
        }
        // Every active crossing among the subset's curves, so a crossing judged wrong
        // early can come back.
        let candidates = Subset::from_curves(n_curves, subset.curves.clone(), cr, active).crossings;
        let mut last: Option<(nullspace::NullSpace, Vec<f64>, f64)> = None;
        let mut last_hard: Option<Vec<bool>> = None;
        let mut was_settled = false;
        for _round in 0..params.robust_rounds.max(1) {
            let weights: Vec<f64> = candidates
                .iter()
                .map(|&k| crossing_weight(&cr[k]) * robust_weight[k])
                .collect();
            // Bound the weights: two nearly equal planes would dominate.
            let cap = median(weights.iter().copied().filter(|w| *w > 0.0).collect()).unwrap_or(1.0)
                * 100.0;
            let weights: Vec<f64> = weights.iter().map(|w| w.min(cap)).collect();
            let nm = nullspace::normal_matrix(n, &subset.local, cr, &candidates, &weights);
            // The last round's planes start this one (they differ by a reweighting).
            let start: Option<Vec<Vector3<f64>>> =
                subset.curves.iter().map(|&c| prev[c as usize]).collect();
            let ns = match nullspace::null_space_from(nm, start.as_deref(), params.dense_threads) {
                Ok(ns) => ns,
                // Down-weighting took the last off-line crossings of some curve: prune.
                Err(_) if last.is_some() => break,
                Err(e) => return Err(e),
            };
            let resid: Vec<f64> = candidates
                .iter()
                .map(|&k| {
                    let c = &cr[k];
                    match (subset.local[c.a as usize], subset.local[c.b as usize]) {
                        (Some(i), Some(j)) => nullspace::sampson(&ns.v0[i], &ns.v0[j], c.u)
                            .map_or(f64::INFINITY, |(e, _)| e.abs()),
                        _ => f64::INFINITY,
                    }
                })
                .collect();
            let sigma = (MAD_TO_SIGMA * median(resid.clone()).unwrap_or(0.0)).max(NOISE_FLOOR);
            for (&k, e) in candidates.iter().zip(&resid) {
                let r = e / (CAUCHY_SCALE * sigma);
                robust_weight[k] = 1.0 / (1.0 + r * r);
            }
            for (c, v) in prev.iter_mut().enumerate() {
                *v = subset.local[c].map(|i| ns.v0[i]);
            }
            let hard: Vec<bool> = resid.iter().map(|e| *e <= k_out * sigma).collect();
            let settled = match (&last, &last_hard) {
                (Some((_, _, s_old)), Some(h)) => {
                    *h == hard && (sigma - s_old).abs() <= 0.05 * s_old
                }
                _ => false,
            };
            // A curve left without enough well-spread inliers must leave before the
            // next solve, or its plane would be free.
            let mut inlier_points: Vec<Vec<[f64; 2]>> = vec![Vec::new(); n];
            for (&k, &ok) in candidates.iter().zip(&hard) {
                if ok {
                    for c in [cr[k].a, cr[k].b] {
                        if let Some(i) = subset.local[c as usize] {
                            inlier_points[i].push(cr[k].u);
                        }
                    }
                }
            }
            let needs_pruning = inlier_points.iter().any(|p| {
                p.len() < params.min_global_crossings
                    || subset::bend(p.iter().copied()) < params.min_curve_bend
            });
            last = Some((ns, resid, sigma));
            last_hard = Some(hard);
            was_settled = settled;
            if settled || needs_pruning {
                break;
            }
        }
        let Some((ns, resid, sigma)) = last else {
            return Err(SolveError::Degenerate("no robust round ran"));
        };
        let threshold = k_out * sigma;
        let mut changed = false;
        for (&k, e) in candidates.iter().zip(&resid) {
            let ok = *e <= threshold;
            changed |= ok != inlier[k];
            inlier[k] = ok;
        }
        let mut count = vec![(0usize, 0usize); n];
        for (&k, e) in candidates.iter().zip(&resid) {
            for c in [cr[k].a, cr[k].b] {
                if let Some(i) = subset.local[c as usize] {
                    count[i].0 += 1;
                    count[i].1 += usize::from(*e > threshold);
                }
            }
        }
        // Judged only on a settled solution: a half-way one misfits good curves too.
        for (i, &(tot, bad)) in count.iter().enumerate() {
            if was_settled && tot > 0 && bad as f64 > params.max_outlier_fraction * tot as f64 {
                let c = subset.curves[i];
                excluded[c as usize] = true;
                rejected_curves.push(c);
                changed = true;
            }
        }
        let mut chosen = vec![false; n_curves];
        for &c in &subset.curves {
            chosen[c as usize] = !excluded[c as usize];
        }
        let adj = adjacency(n_curves, cr, &inlier);
        let pruned = subset::prune(
            n_curves,
            &adj,
            chosen,
            params.min_global_crossings,
            params.min_curve_bend,
            cr,
            &inlier,
        );
        if pruned.curves == subset.curves {
            let sq: Vec<f64> = resid
                .iter()
                .filter(|e| **e <= threshold)
                .map(|e| e * e)
                .collect();
            let residual_rms = (sq.iter().sum::<f64>() / sq.len().max(1) as f64).sqrt();
            let rejected_crossings = candidates
                .iter()
                .zip(&resid)
                .filter(|(_, e)| **e > threshold)
                .map(|(k, _)| *k)
                .collect();
            return Ok(GlobalCoplanarity {
                subset: pruned,
                null_space: ns,
                rejected_crossings,
                sigma_img: sigma,
                residual_rms,
                rejected_curves,
            });
        }
        let _ = changed;
        subset = pruned;
    }
    Err(SolveError::Degenerate("the global subset did not settle"))
}
