//! The scatter rule's information: the part of the estimate's information that the
//! crossings' scatter along their own lines would give ([`scatter_information`]), which
//! [`super::estimate::depth_sigma_of`] does not count as evidence, and its bound: that
//! part can be at most the information itself ([`with_bounded_scatter`]).
//!
//! The scatter part is an expectation, `C = Σ_k w_k b_k b_kᵀ`, with the crossings'
//! scatter along their lines taken equal to their measured scatter across them. Where
//! that assumption fails, `C` reads as more information than the estimate has: on a
//! flat table, each pose is nearly free to turn about its stripes' traces, the
//! covariance `Σ` there is huge, and `[Σ C Σ]` squares it. Held-out table 110 showed
//! shares of 200 to 10⁷ where a share is at most one, and three quarters of its points
//! were left out for it, although their variance alone was 0.009 %.
//!
//! The bound clips `C` to the information `H = L Lᵀ` direction by direction: with
//! `L⁻¹ C L⁻ᵀ = W Λ Wᵀ`, `C' = L W min(Λ, 1) Wᵀ Lᵀ`, so that
//! `Σ C' Σ = L⁻ᵀ W min(Λ, 1) Wᵀ L⁻¹`. A direction clipped to one is all scatter and a
//! depth along it stays undetermined; every other keeps its evidence. A bound on each
//! pose's 7×7 block alone does not do: the excess lives in directions shared between
//! poses, and per pose it kept 38.9 % of table 110's coverage against 38.5 % unbounded.
//!
//! It costs three triangular solves and one symmetric eigendecomposition of the joint
//! system (0.46 s at 1,350 unknowns, 1.3 s at 1,800), so it runs once, on the final
//! estimate. The log says how long it took and how many directions it clipped.

use faer::{Mat, Side};

use super::dense::Cholesky;
use super::estimate::{
    accumulate, information_factor, Estimate, EstimateParams, Layout, PoseMarginal, Spreads, State,
};
use super::evidence::Evidence;
use super::pose::POSE_DOF;

/// The information that the crossings' scatter along their own lines alone would give.
///
/// A crossing's residual is its distance from the line `l` where its two planes meet.
/// Its derivatives depend on where along `l` the crossing lies, and a noisy crossing lies
/// off its true place along `l` by noise: the derivatives carry a term `(t̂ · δ) t̂·∂n̂/∂p`
/// (`δ` the crossing's error, `t̂` the line's direction, `n̂` its normal). Its square
/// enters Gauss–Newton's information as if it were evidence, about one radian⁻² of the
/// line's turn per crossing, in every direction where the crossings themselves say
/// nothing: a plane whose crossings all lie on one line of a wall would read as known to
/// about `1/√n` radians of turn. Its expectation, with the crossings' scatter along `l`
/// taken equal to their measured scatter across it, is `C = Σ_k w_k b_k b_kᵀ`, `b_k` the
/// line's turn rate. Mapped as the marginals are, `[Σ C Σ]_ff` per pose. Also returns
/// each pose's number of crossings (of weight at least one half).
pub(super) fn scatter_information(
    layout: &Layout,
    state: &State,
    spreads: &Spreads,
    cov: &Mat<f64>,
) -> (Vec<PoseMarginal>, Vec<usize>) {
    let (c, counts) = scatter_matrix(layout, state, spreads);
    let t = &c * cov;
    let blocks = pose_unknowns(layout)
        .iter()
        .map(|idx| {
            PoseMarginal::from_fn(|a, b| match (idx[a], idx[b]) {
                // [Σ C Σ]_{ia ib} = Σ_r Σ_{r ia} (C Σ)_{r ib}.
                (Some(ia), Some(ib)) => {
                    let (col_s, col_t) = (cov.col_as_slice(ia), t.col_as_slice(ib));
                    col_s.iter().zip(col_t).map(|(x, y)| x * y).sum()
                }
                _ => 0.0,
            })
        })
        .collect();
    (blocks, counts)
}

/// Per pose, its unknowns in the order of its marginal: six of its own, then the focal
/// scale's when it is estimated.
fn pose_unknowns(layout: &Layout) -> Vec<[Option<usize>; 7]> {
    let focal = layout.focal_index();
    (0..layout.evidence.num_poses())
        .map(|p| std::array::from_fn(|i| if i < 6 { Some(p * POSE_DOF + i) } else { focal }))
        .collect()
}

/// `est` with its scatter parts bounded by the crossings' information in the whole
/// space ([`super::scatter`]): for the final estimate, where the bound's cost (one
/// eigendecomposition of the joint system) is paid once.
pub fn with_bounded_scatter(
    evidence: &Evidence,
    mut est: Estimate,
    params: &EstimateParams,
) -> Estimate {
    let layout = Layout::new(evidence, params).crossings_only();
    let state = State {
        poses: est.poses.clone(),
        focal_scale: est.focal_scale,
    };
    let Some(chol) = information_factor(&layout, &state, &est.spreads) else {
        return est;
    };
    let (c, _) = scatter_matrix(&layout, &state, &est.spreads);
    let started = std::time::Instant::now();
    let bounded = bounded_blocks(&chol, &c, &pose_unknowns(&layout));
    tracing::debug!(
        unknowns = layout.n,
        clipped = bounded.as_ref().map_or(0, |b| b.1),
        ms = started.elapsed().as_secs_f64() * 1e3,
        "the scatter part bounded by the information"
    );
    if let Some((blocks, _)) = bounded {
        est.scatter = blocks;
    }
    est
}

/// The scatter matrix `C` of [`scatter_information`] (both triangles), and each pose's
/// number of crossings of weight at least one half.
fn scatter_matrix(layout: &Layout, state: &State, spreads: &Spreads) -> (Mat<f64>, Vec<usize>) {
    let ev = layout.evidence;
    let n = layout.n;
    let rays = layout.rays(state.focal_scale);
    let loss = layout.crossing_loss();
    let mut c = Mat::<f64>::zeros(n, n);
    let mut g = vec![0.0; n];
    let mut counts = vec![0usize; ev.num_poses()];
    for k in 0..ev.crossings.len() {
        let Some(t) = layout.crossing(state, k, &rays) else {
            continue;
        };
        let o = &ev.crossings[k];
        let sigma = spreads.crossing_px[o.class as usize];
        let w = loss.weight(t.e / sigma);
        let (qa, qb) = (
            ev.planes[o.a as usize].pose as usize,
            ev.planes[o.b as usize].pose as usize,
        );
        if w >= 0.5 {
            counts[qa] += 1;
            if qb != qa {
                counts[qb] += 1;
            }
        }
        let mut idx = [0usize; 12];
        let mut jac = [0.0; 12];
        for i in 0..6 {
            idx[i] = qa * POSE_DOF + i;
            jac[i] = t.ta[i];
            idx[6 + i] = qb * POSE_DOF + i;
            jac[6 + i] = t.tb[i];
        }
        // In units of the residual's noise: b's scatter term is (t̂·δ) b with t̂·δ of
        // the same spread σ as the residual, so its information is w b bᵀ.
        accumulate(&mut c, &mut g, &idx, &jac, w, 0.0);
    }
    for j in 0..n {
        for i in 0..j {
            let v = c[(j, i)];
            c[(i, j)] = v;
        }
    }
    (c, counts)
}

/// Per pose, `[Σ C' Σ]` over its unknowns `blocks[p]` (`None`: an unknown not estimated,
/// the focal scale's when it is fixed), `C'` the scatter matrix `c` bounded by the
/// information `chol` factors (module docs), and how many directions were clipped.
/// `None` where no direction exceeds the bound (the unbounded blocks are then already
/// right) or the decomposition fails.
pub(super) fn bounded_blocks(
    chol: &Cholesky,
    c: &Mat<f64>,
    blocks: &[[Option<usize>; 7]],
) -> Option<(Vec<PoseMarginal>, usize)> {
    let n = c.nrows();
    // A = L⁻¹ C L⁻ᵀ: X = L⁻¹ C, then L⁻¹ Xᵀ (C is symmetric, so Xᵀ = C L⁻ᵀ).
    let mut x = c.clone();
    chol.solve_lower_columns(x.as_mut());
    let mut a = x.transpose().to_owned();
    chol.solve_lower_columns(a.as_mut());
    for j in 0..n {
        for i in 0..j {
            let m = 0.5 * (a[(i, j)] + a[(j, i)]);
            a[(i, j)] = m;
            a[(j, i)] = m;
        }
    }
    let eig = a.self_adjoint_eigen(Side::Lower).ok()?;
    let lambda = eig.S().column_vector();
    let top = (0..n).map(|i| lambda[i]).fold(f64::NEG_INFINITY, f64::max);
    if top.is_nan() || top <= 1.0 {
        return None;
    }
    // G = L⁻ᵀ W min(Λ, 1)^{1/2}; then [Σ C' Σ] = G Gᵀ.
    let u = eig.U();
    let root: Vec<f64> = (0..n).map(|j| lambda[j].clamp(0.0, 1.0).sqrt()).collect();
    let mut g = Mat::<f64>::from_fn(n, n, |i, j| u[(i, j)] * root[j]);
    chol.solve_upper_columns(g.as_mut());
    let out = blocks
        .iter()
        .map(|idx| {
            PoseMarginal::from_fn(|r, s| match (idx[r], idx[s]) {
                (Some(ir), Some(is)) => (0..n).map(|j| g[(ir, j)] * g[(is, j)]).sum(),
                _ => 0.0,
            })
        })
        .collect();
    Some((out, (0..n).filter(|&i| lambda[i] > 1.0).count()))
}

#[cfg(test)]
mod tests {
    use super::super::dense::DenseThreads;
    use super::*;

    /// An information matrix of two "poses" of three unknowns each that share one
    /// weakly held direction (their difference in unknown 0), and a scatter matrix that
    /// reads far more than that along it.
    fn problem() -> (Mat<f64>, Mat<f64>) {
        let n = 6;
        let mut h = Mat::<f64>::zeros(n, n);
        for i in 0..n {
            h[(i, i)] = 100.0 + i as f64;
        }
        // A strong tie of unknowns 0 and 3: their sum is held, their difference barely.
        let strong = 1e6;
        h[(0, 0)] += strong;
        h[(3, 3)] += strong;
        h[(3, 0)] += strong;
        h[(0, 3)] += strong;
        h[(0, 0)] -= 99.99;
        h[(3, 3)] -= 99.99;
        // The scatter: a share of the information everywhere, and 1e4 along the
        // difference, which the information holds at about 1.5.
        let mut c = Mat::<f64>::zeros(n, n);
        for i in 0..n {
            for j in 0..n {
                c[(i, j)] = 0.3 * h[(i, j)];
            }
        }
        let d = [1.0, 0.0, 0.0, -1.0, 0.0, 0.0];
        for i in 0..n {
            for j in 0..n {
                c[(i, j)] += 1e4 * d[i] * d[j];
            }
        }
        (h, c)
    }

    /// Pose `p`'s three unknowns; the rest of the seven not estimated.
    fn idx(p: usize) -> [Option<usize>; 7] {
        let mut out = [None; 7];
        for (i, slot) in out.iter_mut().take(3).enumerate() {
            *slot = Some(3 * p + i);
        }
        out
    }

    fn sigma_c_sigma(h: &Mat<f64>, c: &Mat<f64>) -> Mat<f64> {
        let chol = Cholesky::of_lower(h, 0.0, DenseThreads(1)).expect("factors");
        let s = chol.inverse();
        &s * c * &s
    }

    #[test]
    fn the_bound_keeps_every_share_at_most_one_and_spares_the_rest() {
        let (h, c) = problem();
        let chol = Cholesky::of_lower(&h, 0.0, DenseThreads(1)).expect("factors");
        let sigma = chol.inverse();
        let (blocks, clipped) =
            bounded_blocks(&chol, &c, &[idx(0), idx(1)]).expect("over the bound");
        assert_eq!(clipped, 1, "one direction is over the bound");
        let unbounded = sigma_c_sigma(&h, &c);
        // Unbounded, the weak difference reads as hundreds of times its information.
        let dir = |p: usize, j: [f64; 3]| {
            let marginal = |r: usize, s: usize| sigma[(3 * p + r, 3 * p + s)];
            let var: f64 = (0..3)
                .flat_map(|r| (0..3).map(move |s| (r, s)))
                .map(|(r, s)| j[r] * marginal(r, s) * j[s])
                .sum();
            let raw: f64 = (0..3)
                .flat_map(|r| (0..3).map(move |s| (r, s)))
                .map(|(r, s)| j[r] * unbounded[(3 * p + r, 3 * p + s)] * j[s])
                .sum();
            let bounded: f64 = (0..3)
                .flat_map(|r| (0..3).map(move |s| (r, s)))
                .map(|(r, s)| j[r] * blocks[p][(r, s)] * j[s])
                .sum();
            (raw / var, bounded / var)
        };
        let (raw, bounded) = dir(0, [1.0, 0.0, 0.0]);
        assert!(raw > 10.0, "the test's excess is missing: {raw}");
        assert!(bounded <= 1.0 + 1e-9 && bounded > 0.9, "{bounded}");
        // An unknown the difference does not touch keeps its share of 0.3.
        let (raw, bounded) = dir(1, [0.0, 1.0, 0.0]);
        assert!(
            (raw - 0.3).abs() < 1e-6 && (bounded - 0.3).abs() < 1e-6,
            "{raw} {bounded}"
        );
        // The unestimated seventh unknown stays out.
        assert!(blocks[0].row(6).iter().all(|x| *x == 0.0));
    }

    #[test]
    fn within_the_bound_nothing_is_recomputed() {
        let (h, _) = problem();
        let chol = Cholesky::of_lower(&h, 0.0, DenseThreads(1)).expect("factors");
        let half = Mat::<f64>::from_fn(6, 6, |i, j| 0.5 * h[(i, j)]);
        assert!(bounded_blocks(&chol, &half, &[idx(0)]).is_none());
    }
}
