//! The poses outside the anchors: each fitted on its own from its crossings with the
//! anchors' planes, held at the joint estimate, and its uncertainty with the anchors'
//! own propagated into it.
//!
//! Owns the split of the evidence into its anchors ([`AnchorSplit`]) and the fits of
//! the other poses ([`complete`]); the joint estimate of the anchors is
//! [`super::estimate`]'s, the residual formulas [`super::terms`]'.
//!
//! # The fit
//! A pose `f` that is not an anchor meets the anchors' planes at its crossings (and its
//! own other plane, at the cross's centre). With the anchors at their estimate `θ_A`,
//! its pose is the minimum of the same robust cost as the joint estimator's, over its
//! six parameters alone: its crossings' image distances (pixels) from the lines where
//! their planes meet, under Cauchy's loss at the spreads the joint estimate measured.
//! Levenberg–Marquardt starts from the planes its crossings give linearly (each
//! crossing fixes the inverse depth `v · r = ρ_anchor(r)`) and from the anchor nearest
//! in time, and keeps the better. Where the fitted frames' crossings show wider spreads
//! than the anchors measured, every fit is repeated at those, from its own end.
//!
//! # Its uncertainty
//! The fit's own information `H_ff` (its crossings' Gauss–Newton information) gives the
//! noise part; the anchors' errors move it by `δp_f = −H_ff⁻¹ H_fA δθ_A`, so its
//! covariance is `H_ff⁻¹ + H_ff⁻¹ H_fA Σ_AA H_Af H_ff⁻¹`, `Σ_AA` the joint estimate's
//! covariance (focal scale included). That is the linearised law of the two-stage
//! estimate, not an approximation of it: what it leaves out is only what the fitted
//! poses would have told the anchors (they do not feed back), which makes it no
//! smaller than the joint one.

use faer::Mat;

use nalgebra::{SMatrix, SVector, Vector3};
use rayon::prelude::*;

use super::estimate::{Estimate, EstimateParams, PoseMarginal, Spreads, MIN_REDUNDANCY, RIDGE};
use super::evidence::{Evidence, Observation, Ray};
use super::pose::{CrossPose, PlaneLinearisation, POSE_DOF};
use super::terms::{self, Loss};

type V3 = Vector3<f64>;
type M6 = SMatrix<f64, 6, 6>;
type V6 = SVector<f64, 6>;

/// Rounds of reweighting of the linear start's plane fits.
const LINEAR_ROUNDS: usize = 5;
/// Least ratio of the smallest to the largest eigenvalue of a linear plane fit's normal
/// matrix: below it the rays span too little (nearly one image line) to fix the plane.
const MIN_CONDITION: f64 = 1e-12;
/// The fits are repeated at the spreads their own residuals show when those exceed the
/// anchors' by more than this share.
const SPREAD_SETTLED: f64 = 0.05;

/// The anchors of an evidence as an evidence of their own.
#[derive(Clone, Debug)]
pub struct AnchorSplit {
    /// The anchors' poses, planes and the crossings among them.
    pub evidence: Evidence,
    /// Per pose of the whole evidence, its index among the anchors.
    pub anchor_of_pose: Vec<Option<u32>>,
    /// Per plane of the whole evidence, its index in [`Self::evidence`].
    pub anchor_of_plane: Vec<Option<u32>>,
}

impl AnchorSplit {
    /// The anchors of `evidence` (every pose when none is marked).
    pub fn of(evidence: &Evidence) -> Self {
        let mut anchor_of_pose = vec![None; evidence.num_poses()];
        let mut pose_frames = Vec::new();
        for (p, slot) in anchor_of_pose.iter_mut().enumerate() {
            if evidence.is_anchor(p) {
                *slot = Some(pose_frames.len() as u32);
                pose_frames.push(evidence.pose_frames[p]);
            }
        }
        let mut anchor_of_plane = vec![None; evidence.planes.len()];
        let mut planes = Vec::new();
        for (i, slot) in evidence.planes.iter().enumerate() {
            if let Some(pose) = anchor_of_pose[slot.pose as usize] {
                anchor_of_plane[i] = Some(planes.len() as u32);
                planes.push(super::evidence::PlaneSlot { pose, ..*slot });
            }
        }
        let crossings = evidence
            .crossings
            .iter()
            .filter_map(|c| {
                Some(Observation {
                    a: anchor_of_plane[c.a as usize]?,
                    b: anchor_of_plane[c.b as usize]?,
                    ..*c
                })
            })
            .collect();
        Self {
            evidence: Evidence {
                pose_frames,
                anchors: Vec::new(),
                planes,
                crossings,
                focal_px: evidence.focal_px,
                rays: evidence.rays.clone(),
            },
            anchor_of_pose,
            anchor_of_plane,
        }
    }

    /// Whether every pose is an anchor.
    pub fn is_everything(&self) -> bool {
        self.anchor_of_pose.iter().all(Option::is_some)
    }

    /// Per anchor plane, the given planes of the whole evidence.
    pub fn planes_of<T: Copy>(&self, all: &[T]) -> Vec<T> {
        self.anchor_of_plane
            .iter()
            .zip(all)
            .filter_map(|(a, v)| a.map(|_| *v))
            .collect()
    }
}

/// One crossing of a fitted pose: its own laser, the other plane's pose (`None`: its own
/// other laser) and laser, and where it is.
#[derive(Clone, Copy)]
pub(super) struct Tie {
    pub laser: usize,
    pub other: Option<(usize, usize)>,
    pub ray: Ray,
    pub sigma: f64,
    pub class: usize,
}

/// A tie's term with the fitted pose first.
pub(super) fn term(
    pose: &CrossPose,
    tie: &Tie,
    anchors: &[CrossPose],
    focal_px: f64,
    lambda: f64,
) -> Option<terms::CrossingTerm> {
    match tie.other {
        Some((a, la)) => {
            terms::crossing(pose, tie.laser, &anchors[a], la, &tie.ray, focal_px, lambda)
        }
        None => terms::crossing(pose, 0, pose, 1, &tie.ray, focal_px, lambda).map(|mut t| {
            for i in 0..6 {
                t.ja[i] += t.jb[i];
                t.ta[i] += t.tb[i];
                t.jb[i] = 0.0;
                t.tb[i] = 0.0;
            }
            t
        }),
    }
}

struct Fit {
    pose: CrossPose,
    cost: f64,
}

/// The planes each tie's own plane meets, linearised once for a whole fit (the anchors
/// are held): `None` for a tie at the pose's own cross centre.
fn held_planes(ties: &[Tie], anchors: &[CrossPose]) -> Vec<Option<PlaneLinearisation>> {
    ties.iter()
        .map(|t| t.other.map(|(a, la)| anchors[a].linearise(la)))
        .collect()
}

/// A tie's residual and its derivatives with respect to the fitted pose, from the pose's
/// two planes linearised (`own`) and the held plane it meets (`held`, from
/// [`held_planes`]): [`term`]'s `e` and `ja`, to the same bits.
fn residual(
    own: &[PlaneLinearisation; 2],
    tie: &Tie,
    held: Option<&PlaneLinearisation>,
    focal_px: f64,
    lambda: f64,
) -> Option<(f64, [f64; 6])> {
    match held {
        Some(b) => terms::crossing_residual(&own[tie.laser], b, &tie.ray, focal_px, lambda),
        None => terms::crossing_of(&own[0], &own[1], &tie.ray, focal_px, lambda)
            .map(|t| (t.e, std::array::from_fn(|i| t.ja[i] + t.jb[i]))),
    }
}

/// The robust cost of `pose` over `ties` (whose held planes are `held`), and its
/// normal equations.
fn normal_equations(
    pose: &CrossPose,
    (ties, held): (&[Tie], &[Option<PlaneLinearisation>]),
    focal_px: f64,
    lambda: f64,
    loss: Loss,
    inflate: f64,
) -> (f64, M6, V6) {
    let (mut cost, mut h, mut g) = (terms::CostSum::new(loss), M6::zeros(), V6::zeros());
    let own = [pose.linearise(0), pose.linearise(1)];
    for (tie, held) in ties.iter().zip(held) {
        let Some((e, ja)) = residual(&own, tie, held.as_ref(), focal_px, lambda) else {
            continue;
        };
        let sigma = tie.sigma * inflate;
        let x = e / sigma;
        cost.add(x);
        let w = loss.weight(x) / (sigma * sigma);
        // The lower triangle of `j jᵀ w` (each entry `(j_r j_c) w`, as the whole
        // product rounds it), mirrored below.
        for c in 0..6 {
            for r in c..6 {
                h[(r, c)] += ja[r] * ja[c] * w;
            }
        }
        g += V6::from_column_slice(&ja) * (w * e);
    }
    for c in 0..6 {
        for r in c + 1..6 {
            h[(c, r)] = h[(r, c)];
        }
    }
    (cost.total(), h, g)
}

fn with_ridge(h: &M6) -> M6 {
    let mean = h.trace() / 6.0;
    h + M6::identity() * (RIDGE * mean.max(f64::MIN_POSITIVE))
}

/// The robust size of the residuals at `pose` relative to their spreads: the median of
/// `|e| / σ`, times 1.4826.
fn residual_scale(
    pose: &CrossPose,
    (ties, held): (&[Tie], &[Option<PlaneLinearisation>]),
    focal_px: f64,
    lambda: f64,
) -> f64 {
    let own = [pose.linearise(0), pose.linearise(1)];
    let x: Vec<f64> = ties
        .iter()
        .zip(held)
        .filter_map(|(tie, held)| {
            let (e, _) = residual(&own, tie, held.as_ref(), focal_px, lambda)?;
            Some(e.abs() / tie.sigma)
        })
        .collect();
    super::median(x).map_or(1.0, |m| super::MAD_TO_SIGMA * m)
}

/// Levenberg–Marquardt over one pose from `start`, with the spreads first widened to
/// what the start's residuals show and narrowed fourfold a stage down to the measured
/// ones: Cauchy's loss at the final spreads, far from the minimum, would call every
/// crossing an outlier (on exact data, at a spread of rounding, every one is).
fn minimise(
    start: CrossPose,
    ties: (&[Tie], &[Option<PlaneLinearisation>]),
    focal_px: f64,
    lambda: f64,
    params: &EstimateParams,
) -> Fit {
    let mut fit = Fit {
        pose: start,
        cost: f64::INFINITY,
    };
    let mut inflate = residual_scale(&start, ties, focal_px, lambda).max(1.0);
    loop {
        fit = minimise_at(fit.pose, ties, (focal_px, lambda), params, inflate);
        if inflate <= 1.0 {
            return fit;
        }
        inflate = (inflate / 4.0).max(1.0);
    }
}

/// Levenberg–Marquardt over one pose from `start` at spreads `inflate` times the ties'.
fn minimise_at(
    start: CrossPose,
    ties: (&[Tie], &[Option<PlaneLinearisation>]),
    (focal_px, lambda): (f64, f64),
    params: &EstimateParams,
    inflate: f64,
) -> Fit {
    let loss = Loss::Cauchy(params.crossing_loss);
    let mut pose = start;
    let (mut cost, mut h, mut g) = normal_equations(&pose, ties, focal_px, lambda, loss, inflate);
    let mut mu = 1e-4;
    for _ in 0..params.max_iterations {
        let ridged = with_ridge(&h);
        let mut accepted = None;
        for _ in 0..10 {
            let mut a = ridged;
            for i in 0..6 {
                a[(i, i)] += mu * ridged[(i, i)];
            }
            if let Some(step) = a.cholesky().map(|c| c.solve(&(-g))) {
                let mut trial = pose;
                trial.retract(step.as_slice());
                let next = normal_equations(&trial, ties, focal_px, lambda, loss, inflate);
                if next.0.is_finite() && next.0 < cost {
                    accepted = Some((trial, next));
                    mu = (mu / 3.0).max(1e-12);
                    break;
                }
            }
            mu *= 10.0;
        }
        let Some((trial, next)) = accepted else { break };
        let decrease = cost - next.0;
        pose = trial;
        (cost, h, g) = next;
        if decrease < 0.1 {
            break;
        }
    }
    Fit { pose, cost }
}

/// The plane `v` (`v · r = 1/Z`) that the inverse depths `rho` at `rays` give by
/// reweighted least squares; `None` when they do not fix it.
pub(super) fn linear_plane(rows: &[(V3, f64)]) -> Option<V3> {
    if rows.len() < 3 {
        return None;
    }
    let mut weights = vec![1.0; rows.len()];
    let mut v = None;
    for _ in 0..LINEAR_ROUNDS {
        let (mut a, mut b) = (nalgebra::Matrix3::<f64>::zeros(), V3::zeros());
        for ((r, rho), w) in rows.iter().zip(&weights) {
            a += r * r.transpose() * *w;
            b += r * (*rho * *w);
        }
        let eig = a.symmetric_eigen().eigenvalues;
        let (lo, hi) = (eig.min(), eig.max());
        if lo.is_nan() || lo <= MIN_CONDITION * hi {
            return None;
        }
        let sol = a.cholesky()?.solve(&b);
        let res: Vec<f64> = rows
            .iter()
            .map(|(r, rho)| (sol.dot(r) - rho).abs())
            .collect();
        let scale = super::median(res.clone()).unwrap_or(0.0) * super::MAD_TO_SIGMA * 3.0;
        v = Some(sol);
        if scale <= 0.0 {
            break;
        }
        for (w, e) in weights.iter_mut().zip(&res) {
            *w = 1.0 / (1.0 + (e / scale).powi(2));
        }
    }
    v.filter(|v| v.iter().all(|x| x.is_finite()))
}

/// The fitted pose `f`'s ties (see [`Tie`]).
fn ties_of(
    ev: &Evidence,
    split: &AnchorSplit,
    anchor_est: &Estimate,
    spreads: &Spreads,
    crossings: &[u32],
    f: usize,
) -> Vec<Tie> {
    let lambda = anchor_est.focal_scale;
    crossings
        .iter()
        .filter_map(|&k| {
            let c = &ev.crossings[k as usize];
            let (pa, pb) = (ev.planes[c.a as usize], ev.planes[c.b as usize]);
            let (own, other) = if pa.pose as usize == f {
                (pa, pb)
            } else {
                (pb, pa)
            };
            let other = if other.pose as usize == f {
                None
            } else {
                let a = split.anchor_of_pose[other.pose as usize]?;
                Some((a as usize, usize::from(other.laser)))
            };
            Some(Tie {
                laser: usize::from(own.laser),
                other,
                ray: ev.rays.ray(c.u, lambda)?,
                sigma: spreads.crossing_px[c.class as usize],
                class: c.class as usize,
            })
        })
        .collect()
}

/// Starts for a pose: the planes its ties give linearly, and the anchor nearest in time.
fn starts(anchors: &[CrossPose], nearest: Option<CrossPose>, ties: &[Tie]) -> Vec<CrossPose> {
    let mut out = Vec::new();
    let mut planes = [None, None];
    for (laser, plane) in planes.iter_mut().enumerate() {
        let rows: Vec<(V3, f64)> = ties
            .iter()
            .filter(|t| t.laser == laser)
            .filter_map(|t| {
                let (a, la) = t.other?;
                let v = anchors[a].plane(la)?;
                Some((t.ray.r, v.dot(&t.ray.r)))
            })
            .collect();
        *plane = linear_plane(&rows);
    }
    if let Some(near) = nearest {
        let other = |k: usize| Some(near.normal(k));
        let hint_normal = if planes[0].is_none() {
            other(0)
        } else {
            other(1)
        };
        if let Some(p) = CrossPose::from_planes(planes, near.centre, hint_normal) {
            out.push(p.aligned_to(&near));
        }
        out.push(near);
    } else if let Some(p) = CrossPose::from_planes(planes, V3::zeros(), None) {
        out.push(p);
    }
    out
}

/// What one fitted pose contributes to the whole estimate.
pub(super) struct Fitted {
    pub pose: CrossPose,
    cost: f64,
    pub marginal: PoseMarginal,
    pub scatter: PoseMarginal,
    pub scatter_crossings: usize,
}

/// A pose fitted on its ties, before the anchors' uncertainty is propagated into it
/// ([`PoseFit::propagated`]): the pose's own information and its blocks with the anchors.
pub(super) struct PoseFit {
    pose: CrossPose,
    cost: f64,
    /// `H_ff⁻¹`, the noise part of the pose's covariance.
    h_inv: M6,
    /// The scatter's `C_ff`: the ties' residual directions, robustly weighted.
    c: M6,
    /// `H_fA` by anchor pose.
    blocks: Vec<(usize, M6)>,
    /// `H_fλ`, the focal scale's column.
    b_focal: V6,
    scatter_crossings: usize,
    /// Per tie: its class and its size standardised by its own
    /// redundancy, `|e| / √(1 − w h)` (pixels).
    standardised: Vec<(usize, f64)>,
}

/// A pose fitted on `ties` against the jointly estimated poses `anchors` (in the order
/// of their covariance `cov`), see the module docs; `None` without a tie or a start.
pub(super) fn fit_ties(
    ev: &Evidence,
    anchors: &[CrossPose],
    cov: &Mat<f64>,
    lambda: f64,
    params: &EstimateParams,
    ties: &[Tie],
    nearest: Option<CrossPose>,
) -> Option<Fitted> {
    let fit = fit_pose(
        ev.focal_px,
        anchors,
        lambda,
        params,
        ties,
        Start::Cold(nearest),
    )?;
    Some(fit.propagated(cov, params.estimate_focal))
}

/// Where a pose's fit starts.
#[derive(Clone, Copy)]
enum Start {
    /// Cold: the planes its ties give linearly, and the anchor nearest in time if any
    /// ([`starts`]); the better end is kept.
    Cold(Option<CrossPose>),
    /// The same pose's fit at other spreads: from its end alone (see [`complete`]).
    Warm(CrossPose),
}

/// The pose of [`fit_ties`] and its information, without the anchors' uncertainty.
fn fit_pose(
    focal_px: f64,
    anchors: &[CrossPose],
    lambda: f64,
    params: &EstimateParams,
    ties: &[Tie],
    start: Start,
) -> Option<PoseFit> {
    if ties.is_empty() {
        return None;
    }
    let held = held_planes(ties, anchors);
    let from = match start {
        Start::Cold(nearest) => starts(anchors, nearest, ties),
        Start::Warm(pose) => vec![pose],
    };
    let best = from
        .into_iter()
        .map(|s| minimise(s, (ties, &held), focal_px, lambda, params))
        .min_by(|a, b| a.cost.total_cmp(&b.cost))?;
    let loss = Loss::Cauchy(params.crossing_loss);
    // H_ff, H_fA (by anchor pose; the focal scale's column apart), the scatter's C_ff.
    let (mut h, mut c) = (M6::zeros(), M6::zeros());
    let mut blocks: Vec<(usize, M6)> = Vec::new();
    let mut b_focal = V6::zeros();
    let mut counted = 0;
    // Each tie's term at the fit, once for both passes below.
    let at_fit: Vec<(&Tie, terms::CrossingTerm)> = ties
        .iter()
        .filter_map(|tie| Some((tie, term(&best.pose, tie, anchors, focal_px, lambda)?)))
        .collect();
    for (tie, t) in &at_fit {
        let x = t.e / tie.sigma;
        let rw = loss.weight(x);
        counted += usize::from(rw >= 0.5);
        let w = rw / (tie.sigma * tie.sigma);
        let j = V6::from_column_slice(&t.ja);
        h += j * j.transpose() * w;
        let tf = V6::from_column_slice(&t.ta);
        c += tf * tf.transpose() * rw;
        if let Some((a, _)) = tie.other {
            let jb = V6::from_column_slice(&t.jb);
            let block = j * jb.transpose() * w;
            match blocks.iter_mut().find(|(p, _)| *p == a) {
                Some((_, b)) => *b += block,
                None => blocks.push((a, block)),
            }
        }
        b_focal += j * (w * t.j_scale);
    }
    let h_inv = with_ridge(&h).try_inverse()?;
    let mut standardised = Vec::new();
    for (tie, t) in &at_fit {
        let j = V6::from_column_slice(&t.ja);
        let rw = loss.weight(t.e / tie.sigma);
        let r = 1.0 - rw * (j.transpose() * h_inv * j)[(0, 0)] / (tie.sigma * tie.sigma);
        if r > MIN_REDUNDANCY {
            standardised.push((tie.class, t.e.abs() / r.sqrt()));
        }
    }
    Some(PoseFit {
        pose: best.pose,
        cost: best.cost,
        h_inv,
        c,
        blocks,
        b_focal,
        scatter_crossings: counted,
        standardised,
    })
}

/// Each fit with the anchors' covariance `cov` propagated into it
/// ([`PoseFit::propagated`]); none once `params.cancel` is set, checked per pose: on a
/// replay's last epoch (4,000 poses) the propagation ran 1.6 s of a core after the
/// final solve had cancelled it.
fn propagated_all(
    fits: Vec<Option<PoseFit>>,
    cov: &Mat<f64>,
    params: &EstimateParams,
) -> Vec<Option<Fitted>> {
    fits.into_par_iter()
        .map(|fit| {
            let fit = fit.filter(|_| !params.cancel.is_cancelled())?;
            Some(fit.propagated(cov, params.estimate_focal))
        })
        .collect()
}

impl PoseFit {
    /// The fit with the anchors' covariance `cov` propagated into its own:
    /// `H_ff⁻¹ + H_ff⁻¹ (B Σ_AA Bᵀ) H_ff⁻¹`, `B = H_fA` over the anchors it touches (and
    /// the focal scale, the last unknown of `cov`, when it is estimated).
    fn propagated(self, cov: &Mat<f64>, estimate_focal: bool) -> Fitted {
        let h_inv = self.h_inv;
        let focal = estimate_focal.then(|| cov.nrows() - 1);
        let mut idx: Vec<usize> = self
            .blocks
            .iter()
            .flat_map(|(a, _)| (0..POSE_DOF).map(move |i| a * POSE_DOF + i))
            .collect();
        let mut bcols: Vec<V6> = self
            .blocks
            .iter()
            .flat_map(|(_, b)| (0..POSE_DOF).map(move |i| b.column(i).into_owned()))
            .collect();
        if let Some(fi) = focal {
            idx.push(fi);
            bcols.push(self.b_focal);
        }
        // T = B Σ[idx, :] restricted to idx columns, then M = T Bᵀ; and B Σ[idx, λ].
        // Four columns of Σ at a time: each column's sum still runs over `r` in order and
        // the columns join `m` in order, so the numbers are those of one column at a
        // time, but the four sums are independent chains of additions where one column's
        // was a single chain (this product was a third of the pose fits' time on the
        // 5,400-frame dive: a pose meets up to a few hundred anchor unknowns).
        const COLUMNS: usize = 4;
        let mut m = M6::zeros();
        let mut b_sigma_focal = V6::zeros();
        for (g, group) in idx.chunks(COLUMNS).enumerate() {
            // A short last group repeats its last column; the repeats are not used.
            let cols: [&[f64]; COLUMNS] =
                std::array::from_fn(|q| cov.col_as_slice(group[q.min(group.len() - 1)]));
            let mut t = [V6::zeros(); COLUMNS];
            for (b, &ir) in bcols.iter().zip(&idx) {
                for (t, col) in t.iter_mut().zip(&cols) {
                    *t += b * col[ir];
                }
            }
            for (q, (&is, t)) in group.iter().zip(&t).enumerate() {
                let s = g * COLUMNS + q;
                m += t * bcols[s].transpose();
                if let Some(fi) = focal {
                    b_sigma_focal += bcols[s] * cov[(is, fi)];
                }
            }
        }
        let cov_ff = h_inv + h_inv * m * h_inv;
        let mut marginal = PoseMarginal::zeros();
        marginal.fixed_view_mut::<6, 6>(0, 0).copy_from(&cov_ff);
        if let Some(fi) = focal {
            let cross = -(h_inv * b_sigma_focal);
            for i in 0..6 {
                marginal[(i, 6)] = cross[i];
                marginal[(6, i)] = cross[i];
            }
            marginal[(6, 6)] = cov[(fi, fi)];
        }
        let mut c7 = PoseMarginal::zeros();
        c7.fixed_view_mut::<6, 6>(0, 0).copy_from(&self.c);
        Fitted {
            pose: self.pose,
            cost: self.cost,
            marginal,
            scatter: marginal * c7 * marginal,
            scatter_crossings: self.scatter_crossings,
        }
    }
}

/// The spreads of the crossings as the fitted frames show them: per class, the larger of
/// `spreads` and 1.4826 times the median standardised residual.
fn shown_spreads(fitted: &[Option<PoseFit>], spreads: &Spreads) -> Spreads {
    let mut out = *spreads;
    for (class, slot) in out.crossing_px.iter_mut().enumerate() {
        let sizes: Vec<f64> = fitted
            .iter()
            .flatten()
            .flat_map(|f| &f.standardised)
            .filter(|(c, _)| *c == class)
            .map(|(_, e)| *e)
            .collect();
        if let Some(m) = super::median(sizes) {
            *slot = slot.max(super::MAD_TO_SIGMA * m);
        }
    }
    out
}

/// The poses outside the anchors and what their fits need: each one's crossings, the
/// anchors' estimate and the settings.
pub(super) struct Outside<'a> {
    ev: &'a Evidence,
    split: &'a AnchorSplit,
    anchor_est: &'a Estimate,
    params: &'a EstimateParams,
    /// Per pose outside the anchors, its crossings.
    by_pose: Vec<Vec<u32>>,
}

impl<'a> Outside<'a> {
    pub(super) fn new(
        ev: &'a Evidence,
        split: &'a AnchorSplit,
        anchor_est: &'a Estimate,
        params: &'a EstimateParams,
    ) -> Self {
        let mut by_pose: Vec<Vec<u32>> = vec![Vec::new(); ev.num_poses()];
        for (k, c) in ev.crossings.iter().enumerate() {
            let (pa, pb) = (ev.planes[c.a as usize].pose, ev.planes[c.b as usize].pose);
            let poses = if pa == pb { &[pa][..] } else { &[pa, pb][..] };
            for &p in poses {
                if split.anchor_of_pose[p as usize].is_none() {
                    by_pose[p as usize].push(k as u32);
                }
            }
        }
        Self {
            ev,
            split,
            anchor_est,
            params,
            by_pose,
        }
    }

    /// The pose of the anchor nearest in frames to pose `f`.
    fn nearest_anchor(&self, f: usize) -> Option<CrossPose> {
        let frame = self.ev.pose_frames[f];
        self.split
            .anchor_of_pose
            .iter()
            .enumerate()
            .filter_map(|(p, a)| a.map(|a| (self.ev.pose_frames[p].abs_diff(frame), a as usize)))
            .min()
            .map(|(_, a)| self.anchor_est.poses[a])
    }

    /// Every pose outside the anchors fitted at `spreads`: cold, or each from its own
    /// fit in `before` where it has one; `None` for the anchors, for a pose that cannot
    /// be fitted, and for every pose not yet begun once `params.cancel` is set.
    pub(super) fn fit_all(
        &self,
        spreads: &Spreads,
        before: Option<&[Option<PoseFit>]>,
    ) -> Vec<Option<PoseFit>> {
        let (ev, split, params) = (self.ev, self.split, self.params);
        (0..ev.num_poses())
            .into_par_iter()
            .map(|f| {
                split.anchor_of_pose[f].is_none().then_some(())?;
                // A superseded live epoch stops here too (the caller then reports the
                // cancellation): on a 7,800-plane epoch these fits were 3.7 s of one
                // core, unchecked, beside the final solve that cancelled it.
                if params.cancel.is_cancelled() {
                    return None;
                }
                let start = match before.and_then(|b| b[f].as_ref()) {
                    Some(fit) => Start::Warm(fit.pose),
                    None => Start::Cold(self.nearest_anchor(f)),
                };
                let ties = ties_of(ev, split, self.anchor_est, spreads, &self.by_pose[f], f);
                let (poses, lambda) = (&self.anchor_est.poses, self.anchor_est.focal_scale);
                fit_pose(ev.focal_px, poses, lambda, params, &ties, start)
            })
            .collect()
    }
}

/// The whole estimate of `ev`: the anchors' joint estimate `anchor_est` (of
/// `split.evidence`), and every other pose fitted against it (see the module docs). A
/// pose that cannot be fitted keeps its nearest anchor's pose with an infinite
/// covariance: nothing it gives is used.
pub fn complete(
    ev: &Evidence,
    split: &AnchorSplit,
    anchor_est: Estimate,
    params: &EstimateParams,
) -> Estimate {
    let started = std::time::Instant::now();
    let outside = Outside::new(ev, split, &anchor_est, params);
    let mut spreads = anchor_est.spreads;
    let mut fits = outside.fit_all(&spreads, None);
    // The anchors measured the spreads on their own crossings; where the other frames'
    // crossings show more (a few anchors absorb part of their own noise), the fits are
    // repeated at what they show, each from its own end: the spreads reweigh the
    // crossings, they do not move a fit to another basin (from cold, the repeat took
    // as long as the first fits: on a 5,400-frame dive the fits took 13.3 s with the
    // cold repeat, 8.6 s with this one). The anchors' uncertainty is propagated into
    // the fits that stay only.
    let shown = shown_spreads(&fits, &spreads);
    if (0..2).any(|c| shown.crossing_px[c] > (1.0 + SPREAD_SETTLED) * spreads.crossing_px[c]) {
        tracing::debug!(?shown, anchors = ?spreads, "the fitted frames' crossings are wider spread than the anchors'");
        spreads = shown;
        fits = outside.fit_all(&spreads, Some(&fits));
    }
    let fitted = propagated_all(fits, &anchor_est.covariance, params);
    tracing::debug!(
        poses = fitted.iter().filter(|f| f.is_some()).count(),
        ms = started.elapsed().as_secs_f64() * 1e3,
        "fitted the poses outside the anchors"
    );
    let unknown = PoseMarginal::from_diagonal_element(f64::INFINITY);
    let mut poses = Vec::with_capacity(ev.num_poses());
    let mut marginals = Vec::with_capacity(ev.num_poses());
    let mut scatter = Vec::with_capacity(ev.num_poses());
    let mut scatter_crossings = Vec::with_capacity(ev.num_poses());
    let mut cost = anchor_est.cost;
    for (f, fit) in fitted.into_iter().enumerate() {
        match (split.anchor_of_pose[f], fit) {
            (Some(a), _) => {
                let a = a as usize;
                poses.push(anchor_est.poses[a]);
                marginals.push(anchor_est.marginals[a]);
                scatter.push(anchor_est.scatter[a]);
                scatter_crossings.push(anchor_est.scatter_crossings[a]);
            }
            (None, Some(fit)) => {
                cost += fit.cost;
                poses.push(fit.pose);
                marginals.push(fit.marginal);
                scatter.push(fit.scatter);
                scatter_crossings.push(fit.scatter_crossings);
            }
            (None, None) => {
                poses.push(outside.nearest_anchor(f).unwrap_or(anchor_est.poses[0]));
                marginals.push(unknown);
                scatter.push(PoseMarginal::zeros());
                scatter_crossings.push(0);
            }
        }
    }
    let lambda = anchor_est.focal_scale;
    let loss = Loss::Cauchy(params.crossing_loss);
    let (weights, residuals): (Vec<f32>, Vec<f32>) = ev
        .crossings
        .par_iter()
        .map(|c| {
            let (a, b) = (ev.planes[c.a as usize], ev.planes[c.b as usize]);
            let e = ev.rays.ray(c.u, lambda).and_then(|ray| {
                let a = poses[a.pose as usize].linearise(usize::from(a.laser));
                let b = poses[b.pose as usize].linearise(usize::from(b.laser));
                terms::crossing_error(&a, &b, &ray, ev.focal_px, lambda)
            });
            let known = marginals[a.pose as usize][(0, 0)].is_finite()
                && marginals[b.pose as usize][(0, 0)].is_finite();
            match e {
                Some(e) if known => {
                    let x = e / spreads.crossing_px[c.class as usize];
                    (loss.weight(x) as f32, x as f32)
                }
                _ => (0.0, f32::NAN),
            }
        })
        .unzip();
    Estimate {
        poses,
        focal_scale: lambda,
        spreads,
        crossing_weights: weights,
        crossing_residuals: residuals,
        marginals,
        scatter,
        scatter_crossings,
        cost,
        iterations: anchor_est.iterations,
        redundancy: anchor_est.redundancy,
        covariance: anchor_est.covariance,
        joint_of_pose: split.anchor_of_pose.clone(),
    }
}

#[cfg(test)]
#[path = "conditional_fit_tests.rs"]
mod tests;
