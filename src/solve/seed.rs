//! Robust start of the global solve: small seeds grown by consensus.
//!
//! A least-squares solve of the whole subset lets wrong crossings pull the planes
//! along the weak directions of the system (each plane turning about its 3D line,
//! held only by the crossings off that line), and reweighting from there may never
//! recover. Instead: several seeds (a few well-connected curves around different
//! starting curves) are solved on their own (least squares, then Cauchy reweighting
//! of the Sampson residuals), and each seed is grown over the subset one curve at a
//! time, every new plane fitted by consensus from its crossings with the planes
//! solved so far ([`super::extend::fit_plane`], which works for any member of the
//! 4-DOF family since `v · u = v_j · u` is preserved by `v ↦ s v + w`). The seed whose
//! grown planes agree with the most crossings within `k σ` (`σ` the smallest seed
//! noise) wins; its residuals give the starting weights of the global reweighting.

use super::extend::{fit_plane, FitContext};
use super::nullspace::{normal_matrix, null_space, sampson};
use super::subset::{adjacency, prune, Subset};
use super::{median, Problem, SolveParams, MAD_TO_SIGMA, NOISE_FLOOR};
use nalgebra::Vector3;

/// Curves per seed before pruning.
const SEED_SIZE: usize = 16;
/// Seeds tried.
const SEEDS: usize = 8;

/// Starting Cauchy weights for every crossing (1 where the winning seed says nothing)
/// and the noise estimate, or `None` when no seed could be solved.
pub fn consensus_weights(
    problem: &Problem,
    active: &[bool],
    subset: &Subset,
    params: &SolveParams,
) -> Option<(Vec<f64>, f64)> {
    let n_curves = problem.num_curves;
    let cr = problem.crossings;
    let adj = adjacency(n_curves, cr, active);
    let inside = |c: u32| subset.local[c as usize].is_some();
    let degree = |c: u32| adj[c as usize].iter().filter(|(o, _)| inside(*o)).count();
    let mut by_degree = subset.curves.clone();
    by_degree.sort_by_key(|&c| std::cmp::Reverse(degree(c)));
    let step = (by_degree.len() / SEEDS).max(1);
    let mut grown: Vec<(Vec<Option<Vector3<f64>>>, f64)> = Vec::new();
    for &start in by_degree.iter().step_by(step).take(SEEDS) {
        // Greedy: the curve with the most crossings into the seed joins next.
        let mut chosen = vec![false; n_curves];
        let mut score = vec![0usize; n_curves];
        chosen[start as usize] = true;
        for &(o, _) in &adj[start as usize] {
            score[o as usize] += 1;
        }
        for _ in 1..SEED_SIZE {
            let next = subset
                .curves
                .iter()
                .copied()
                .filter(|&c| !chosen[c as usize] && score[c as usize] > 0)
                .max_by_key(|&c| (score[c as usize], c));
            let Some(c) = next else { break };
            chosen[c as usize] = true;
            for &(o, _) in &adj[c as usize] {
                score[o as usize] += 1;
            }
        }
        let seed = prune(
            n_curves,
            &adj,
            chosen,
            params.min_global_crossings,
            params.min_curve_bend,
            cr,
            active,
        );
        if seed.curves.len() < 6 {
            continue;
        }
        if let Some(g) = solve_and_grow(problem, &adj, subset, &seed, params) {
            grown.push(g);
        }
    }
    let sigma_ref = grown.iter().map(|g| g.1).fold(f64::INFINITY, f64::min);
    let thr = params.outlier_mad_k * sigma_ref;
    let (planes, _) = grown.into_iter().max_by_key(|(planes, _)| {
        subset
            .crossings
            .iter()
            .filter(|&&k| {
                let c = &cr[k];
                match (planes[c.a as usize], planes[c.b as usize]) {
                    (Some(vi), Some(vj)) => {
                        sampson(&vi, &vj, c.u).is_some_and(|(e, _)| e.abs() <= thr)
                    }
                    _ => false,
                }
            })
            .count()
    })?;
    let weights = cr
        .iter()
        .map(|c| match (planes[c.a as usize], planes[c.b as usize]) {
            (Some(vi), Some(vj)) => sampson(&vi, &vj, c.u).map_or(1.0, |(e, _)| {
                let r = e / thr;
                1.0 / (1.0 + r * r)
            }),
            _ => 1.0,
        })
        .collect();
    Some((weights, sigma_ref))
}

/// Solves a seed by reweighted least squares and grows it over `subset` (`adj`: the
/// adjacency of the active crossings, [`adjacency`]).
fn solve_and_grow(
    problem: &Problem,
    adj: &[Vec<(u32, usize)>],
    subset: &Subset,
    seed: &Subset,
    params: &SolveParams,
) -> Option<(Vec<Option<Vector3<f64>>>, f64)> {
    let cr = problem.crossings;
    let n = seed.curves.len();
    let mut weights: Vec<f64> = seed
        .crossings
        .iter()
        .map(|&k| 1.0 / (1.0 + cr[k].u[0].powi(2) + cr[k].u[1].powi(2)))
        .collect();
    let mut v0 = Vec::new();
    let mut sigma = f64::INFINITY;
    for _ in 0..10 {
        let ns = null_space(normal_matrix(n, &seed.local, cr, &seed.crossings, &weights)).ok()?;
        let resid: Vec<f64> =
            seed.crossings
                .iter()
                .map(|&k| {
                    let c = &cr[k];
                    match (seed.local[c.a as usize], seed.local[c.b as usize]) {
                        (Some(i), Some(j)) => sampson(&ns.v0[i], &ns.v0[j], c.u)
                            .map_or(f64::INFINITY, |(e, _)| e.abs()),
                        _ => f64::INFINITY,
                    }
                })
                .collect();
        let s = (MAD_TO_SIGMA * median(resid.clone()).unwrap_or(0.0)).max(NOISE_FLOOR);
        for ((w, &k), e) in weights.iter_mut().zip(&seed.crossings).zip(&resid) {
            let u = cr[k].u;
            let r = e / (params.outlier_mad_k * s);
            *w = 1.0 / ((1.0 + u[0] * u[0] + u[1] * u[1]) * (1.0 + r * r));
        }
        v0 = ns.v0;
        let settled = (s - sigma).abs() <= 0.05 * sigma;
        sigma = s;
        if settled {
            break;
        }
    }
    let mut planes: Vec<Option<Vector3<f64>>> = vec![None; problem.num_curves];
    for (i, &c) in seed.curves.iter().enumerate() {
        planes[c as usize] = Some(v0[i]);
    }
    let ctx = FitContext {
        focal_scale: 1.0,
        sigma_img: sigma,
        sigma_ortho: 1.0,
        outlier_k: params.outlier_mad_k,
        min_crossings: 4,
        min_bend: params.min_curve_bend,
        // The seed's noise is a rough one: every sample may vote.
        min_sample_spread: 0.0,
        // Only the global solve's own extension judges uncertainty.
        max_depth_sigma: f64::INFINITY,
        min_sin_angle: params.min_sin_angle,
        parallel: params.dense_threads.0 > 1,
    };
    let mut failed = vec![false; problem.num_curves];
    // Crossings of each curve with the planes solved so far, kept as planes are added
    // (each crossing is listed under both of its curves).
    let mut known_count = vec![0usize; problem.num_curves];
    for &c in &seed.curves {
        for &(o, _) in &adj[c as usize] {
            known_count[o as usize] += 1;
        }
    }
    loop {
        let next = subset
            .curves
            .iter()
            .copied()
            .filter(|&c| planes[c as usize].is_none() && !failed[c as usize])
            .map(|c| (known_count[c as usize], c))
            .filter(|&(m, _)| m >= 4)
            .max();
        let Some((_, c)) = next else { break };
        let known: Vec<(usize, Vector3<f64>)> = adj[c as usize]
            .iter()
            .filter_map(|&(o, k)| planes[o as usize].map(|v| (k, v)))
            .collect();
        // The partner is not used: orthogonality holds only once the gauge is fixed.
        match fit_plane(cr, &known, None, &ctx, None) {
            Some(fit) => {
                planes[c as usize] = Some(fit.plane);
                for &(o, _) in &adj[c as usize] {
                    known_count[o as usize] += 1;
                }
            }
            None => failed[c as usize] = true,
        }
    }
    Some((planes, sigma))
}
