//! The joint estimator: every pose of the hand-held projector (and the focal scale, when
//! asked) from all crossings at once, the hand's motion as a soft term, each kind of
//! residual weighed by its own measured spread, and the uncertainty of every plane from
//! the estimator's own information.
//!
//! Owns the minimisation and the covariance; the residual formulas are in
//! [`super::terms`], the scatter rule's information in [`super::scatter`], the
//! parametrisation in [`super::pose`], the start in [`super::init`].
//!
//! # Cost
//! ```text
//!   Σ_crossings ρ_C(e_k / σ_class)  +  Σ_triples ρ_H(|D_C| / σ_C)  +  ρ_H(D_aim / σ_aim) + ρ_H(D_roll / σ_roll)
//! ```
//! over the poses `(R_f, C_f)`: the crossings' image distances from the line where their
//! planes meet (pixels; Cauchy's loss, so that wrong crossings fade out), and the second
//! differences of the hand's centre and rotation (Huber's loss). Orthogonality needs no
//! term: it is in the parametrisation. The one freedom no crossing fixes, the global
//! scale, is held by a gauge row: the mean log inverse depth at the crossings stays where
//! it started (the centres are rescaled to it after every step). Relative depth errors
//! then come out as after the best global scale, and nothing a crossing leaves free is
//! pinned by the gauge.
//!
//! # Minimisation
//! Levenberg–Marquardt on the dense normal equations (six unknowns a pose, one more for
//! the focal scale), the robust weights recomputed at every linearisation. A step must
//! keep the ray of every crossing: below some focal scale the lens model folds back over
//! a crossing's pixel (no ray), the crossing drops out of the cost, and the cost would
//! fall by losing data rather than by fitting it. Dense,
//! because a sweep's crossing graph is: each frame's stripe crosses the other laser's
//! stripes of most frames, so a sparse factor would fill in.
//!
//! # Spreads and uncertainty
//! The spreads are measured, not set: after the minimisation, each kind of residual's
//! spread is the robust spread of its residuals standardised by their own redundancy
//! (`|e| / √(1 − w h)`, `h` the leverage from the covariance; see [`super::spreads`]),
//! and the minimisation is repeated until they settle.
//! The covariance of the poses is the inverse of the crossings' information at the
//! estimate, the motion terms left out ([`evidence_covariance`] says why); each pose
//! keeps its marginal block (with the focal scale), from which the relative depth
//! uncertainty of any point on its planes follows ([`Estimate::depth_sigma`]).

use faer::Mat;
use nalgebra::{SMatrix, SVector};

use super::dense::{Cholesky, DenseThreads};
use super::evidence::{CrossingClass, Evidence, PlaneSlot, Ray};
use super::pose::{CrossPose, POSE_DOF};
pub(super) use super::spreads::MIN_REDUNDANCY;
use super::spreads::{measured_spreads, relative_change};
use super::terms::{self, Loss, MotionTerm};
use super::SolveError;

/// The marginal covariance of one pose's six local parameters and the focal scale.
pub type PoseMarginal = SMatrix<f64, 7, 7>;

/// Settings of the estimator.
#[derive(Clone, Debug, PartialEq)]
pub struct EstimateParams {
    pub estimate_focal: bool,
    /// Include the hand's motion terms.
    pub motion: bool,
    /// Largest number of Levenberg–Marquardt steps per round.
    pub max_iterations: usize,
    /// Largest number of rounds of measuring the spreads and minimising again.
    pub variance_rounds: usize,
    /// Cauchy scale of the crossings, in their spread.
    pub crossing_loss: f64,
    /// Huber threshold of the motion terms, in their spread.
    pub motion_loss: f64,
    /// Stops the estimate between steps ([`SolveError::Cancelled`]).
    pub cancel: super::Cancel,
    /// Threads of the dense factorisations ([`super::dense`]).
    pub threads: DenseThreads,
}

impl Default for EstimateParams {
    fn default() -> Self {
        Self {
            estimate_focal: false,
            motion: true,
            max_iterations: 30,
            variance_rounds: 4,
            // 95 % efficiency on Gaussian noise for Cauchy's loss (2.385) and Huber's (1.345)
            // would call good crossings wrong at the tails; a wider window keeps them.
            crossing_loss: 3.0,
            motion_loss: 2.0,
            cancel: super::Cancel::default(),
            threads: DenseThreads::default(),
        }
    }
}

/// The spread of each kind of residual: crossings (pixels) by class, the centre's
/// second difference (length per frame², in the solution's scale) and the rotation's
/// (radians per frame²) about the laser normals (aim) and the axis (roll).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Spreads {
    pub crossing_px: [f64; 2],
    pub centre: f64,
    pub aim_rad: f64,
    pub roll_rad: f64,
}

/// The estimator's answer.
#[derive(Clone, Debug)]
pub struct Estimate {
    pub poses: Vec<CrossPose>,
    pub focal_scale: f64,
    pub spreads: Spreads,
    /// Per crossing, its robust weight at the end (1: a full inlier, near 0: ignored),
    /// 0 where the crossing could not be evaluated.
    pub crossing_weights: Vec<f32>,
    /// Per crossing, its residual in units of its spread (NaN where not evaluated).
    pub crossing_residuals: Vec<f32>,
    /// Per pose, the marginal covariance of `(δθ, δC, λ)`.
    pub marginals: Vec<PoseMarginal>,
    /// Per pose, the part of the information that the crossings' scatter along their own
    /// lines would give on its own, mapped to the pose's parameters as its marginal is
    /// (`[Σ C Σ]_ff`, see [`Estimate::depth_sigma`]), and the number of crossings of the
    /// pose, which says how far that part may fluctuate.
    pub scatter: Vec<PoseMarginal>,
    pub scatter_crossings: Vec<usize>,
    /// Final robust cost, in units of the spreads.
    pub cost: f64,
    pub iterations: usize,
    /// Per kind of residual (crossings strong, faint; centre; aim; roll): its share of the
    /// redundancy, `Σ (w − h)`.
    pub redundancy: [f64; 5],
    /// The covariance of every unknown estimated jointly (six a pose, then the focal
    /// scale when estimated), from the crossings alone ([`evidence_covariance`]),
    /// which the poses fitted against these need
    /// ([`super::conditional`]): the anchors' where the other poses were fitted.
    pub covariance: Mat<f64>,
    /// Per pose, its place among the jointly estimated poses (its unknowns are six from
    /// six times it in [`Self::covariance`]); `None` for a fitted pose.
    pub joint_of_pose: Vec<Option<u32>>,
}

impl Estimate {
    /// One standard deviation of the relative depth `δZ / Z` of a point seen along `ray`
    /// on laser `laser` of pose `pose`, from the pose's marginal covariance (the focal
    /// scale's included). Infinite where the plane gives no depth there.
    pub fn depth_sigma(&self, pose: usize, laser: usize, ray: &Ray) -> f64 {
        depth_sigma_of(
            &self.poses[pose],
            &self.marginals[pose],
            &self.scatter[pose],
            self.scatter_crossings[pose],
            laser,
            ray,
        )
    }
}

/// [`Estimate::depth_sigma`] of one pose, from its marginal covariance, its scatter
/// information and its number of crossings.
pub fn depth_sigma_of(
    p: &CrossPose,
    marginal: &PoseMarginal,
    scatter: &PoseMarginal,
    crossings: usize,
    laser: usize,
    ray: &Ray,
) -> f64 {
    let lin = p.linearise(laser);
    let rho = lin.n.dot(&ray.r) / lin.d;
    if !(rho.is_finite() && rho > 0.0) {
        return f64::INFINITY;
    }
    // ρ = n·r / d: ∂ρ/∂θ = (n × r)/d − (ρ/d)(n × C), ∂ρ/∂C = −(ρ/d) n,
    // ∂ρ/∂λ = n·∂r/∂λ / d.
    let dt = lin.n.cross(&ray.r) / lin.d - lin.dd_dtheta * (rho / lin.d);
    let dc = -lin.n * (rho / lin.d);
    let dl = lin.n.dot(&ray.dr_dscale) / lin.d;
    let j = SVector::<f64, 7>::from_column_slice(&[dt.x, dt.y, dt.z, dc.x, dc.y, dc.z, dl]);
    let var = (j.transpose() * marginal * j)[(0, 0)];
    if var.is_nan() || var < 0.0 {
        return f64::INFINITY;
    }
    if var == 0.0 {
        return 0.0;
    }
    // Of the information the estimate has about this depth (1/var, along the direction
    // z = Σq/var that estimates it), the crossings' scatter along their lines accounts
    // for zᵀCz = qᵀ[ΣCΣ]q / var², a share `scatter` of it, give or take its own
    // fluctuation over n crossings (three deviations of √(2/n) each): only the rest
    // is evidence.
    let share = (j.transpose() * scatter * j)[(0, 0)] / var;
    let n = crossings.max(1) as f64;
    let margin = 1.0 + SCATTER_DEVIATIONS * (2.0 / n).sqrt();
    let left = 1.0 - margin * share;
    if left.is_nan() || left <= 0.0 {
        return f64::INFINITY;
    }
    (var / left).sqrt() / rho
}

/// Where the minimisation starts.
#[derive(Clone, Debug)]
pub struct Start {
    pub poses: Vec<CrossPose>,
    pub focal_scale: f64,
    pub spreads: Spreads,
}

/// Three consecutive poses and their frame steps.
#[derive(Clone, Copy, Debug)]
pub(super) struct Triple {
    poses: [u32; 3],
    h: [f64; 2],
}

/// The fixed structure of a problem: which terms exist and where their unknowns are.
pub(super) struct Layout<'a> {
    pub(super) evidence: &'a Evidence,
    params: &'a EstimateParams,
    pub(super) triples: Vec<Triple>,
    /// Number of unknowns: six per pose, one more with the focal scale.
    pub(super) n: usize,
    /// The crossings' rays at the focal scale last asked for ([`Self::rays`]).
    rays_at: RaysAt,
}

/// The rays of a layout's crossings at one focal scale (its bits), kept: a
/// Levenberg–Marquardt step asked for them four times and more (normal equations,
/// gauge, and each trial's renormalisation and cost), each time undistorting every
/// crossing, while the focal scale moves only when it is estimated.
type RaysAt = std::sync::Mutex<Option<(u64, std::sync::Arc<Vec<Option<Ray>>>)>>;

/// Relative change of the spreads below which the rounds stop.
const SPREAD_SETTLED: f64 = 0.05;
/// The minimisation ends when what is left to gain is under this, in units of the
/// spreads squared: the parameters are then within a fraction of a standard deviation
/// of the minimum. What is left is judged from the last decrease and how fast the
/// decreases shrink (a geometric tail, as iteratively reweighted steps give).
const COST_SETTLED: f64 = 1.0;
/// Least sine of the angle between a crossing's ray and its plane for the crossing to
/// count in the gauge.
const GAUGE_MIN_RAY_PLANE_SIN: f64 = 0.1;
/// How many of its own deviations the information that the crossings' scatter along
/// their lines gives is allowed to fluctuate by before the rest counts as evidence.
const SCATTER_DEVIATIONS: f64 = 3.0;
/// Ridge on the diagonal, relative to its mean: directions no term sees (the turn of a
/// laser never observed) get a finite, huge variance instead of a singular matrix.
pub(super) const RIDGE: f64 = 1e-10;

impl<'a> Layout<'a> {
    pub(super) fn new(evidence: &'a Evidence, params: &'a EstimateParams) -> Self {
        let f = &evidence.pose_frames;
        let triples = if params.motion {
            (2..f.len())
                .map(|i| Triple {
                    poses: [i as u32 - 2, i as u32 - 1, i as u32],
                    h: [(f[i - 1] - f[i - 2]) as f64, (f[i] - f[i - 1]) as f64],
                })
                .collect()
        } else {
            Vec::new()
        };
        let n = POSE_DOF * f.len() + usize::from(params.estimate_focal);
        Self {
            evidence,
            params,
            triples,
            n,
            rays_at: RaysAt::default(),
        }
    }

    /// This layout without the motion terms: the crossings' information alone.
    pub(super) fn crossings_only(&self) -> Layout<'a> {
        Layout {
            evidence: self.evidence,
            params: self.params,
            triples: Vec::new(),
            n: self.n,
            rays_at: RaysAt::default(),
        }
    }

    pub(super) fn focal_index(&self) -> Option<usize> {
        self.params
            .estimate_focal
            .then_some(POSE_DOF * self.evidence.num_poses())
    }

    /// The crossing term of observation `k`, or `None` where it cannot be evaluated.
    pub(super) fn crossing(
        &self,
        state: &State,
        k: usize,
        rays: &[Option<Ray>],
    ) -> Option<terms::CrossingTerm> {
        let ev = self.evidence;
        let c = &ev.crossings[k];
        let (a, b) = (ev.planes[c.a as usize], ev.planes[c.b as usize]);
        let ray = rays[k].as_ref()?;
        terms::crossing(
            &state.poses[a.pose as usize],
            usize::from(a.laser),
            &state.poses[b.pose as usize],
            usize::from(b.laser),
            ray,
            ev.focal_px,
            state.focal_scale,
        )
    }

    /// Whether crossing `k`'s point lies in front of the camera on both of its planes
    /// (`v · r > 0`): the camera saw it, so any right planes put it there.
    fn in_front(&self, state: &State, k: usize, rays: &[Option<Ray>]) -> bool {
        let ev = self.evidence;
        let c = &ev.crossings[k];
        let Some(ray) = rays[k].as_ref() else {
            return false;
        };
        [c.a, c.b].into_iter().all(|p| {
            ev.planes[p as usize]
                .plane_in(&state.poses)
                .is_some_and(|v| v.dot(&ray.r) > 0.0)
        })
    }

    /// The residual of [`Self::crossing`] alone (the same bits): what a cost needs.
    fn crossing_error(&self, state: &State, k: usize, rays: &[Option<Ray>]) -> Option<f64> {
        let ev = self.evidence;
        let c = &ev.crossings[k];
        let (a, b) = (ev.planes[c.a as usize], ev.planes[c.b as usize]);
        let ray = rays[k].as_ref()?;
        terms::crossing_error(
            &state.poses[a.pose as usize].linearise(usize::from(a.laser)),
            &state.poses[b.pose as usize].linearise(usize::from(b.laser)),
            ray,
            ev.focal_px,
            state.focal_scale,
        )
    }

    /// The crossings' rays at focal scale `lambda` (the same bits as made afresh).
    pub(super) fn rays(&self, lambda: f64) -> std::sync::Arc<Vec<Option<Ray>>> {
        let mut kept = self.rays_at.lock().unwrap_or_else(|e| e.into_inner());
        match &*kept {
            Some((bits, rays)) if *bits == lambda.to_bits() => rays.clone(),
            _ => {
                let rays: std::sync::Arc<Vec<Option<Ray>>> = std::sync::Arc::new(
                    self.evidence
                        .crossings
                        .iter()
                        .map(|c| self.evidence.rays.ray(c.u, lambda))
                        .collect(),
                );
                *kept = Some((lambda.to_bits(), rays.clone()));
                rays
            }
        }
    }

    pub(super) fn motion_terms(&self, state: &State, t: &Triple) -> (MotionTerm, MotionTerm) {
        let p = t.poses.map(|i| &state.poses[i as usize]);
        (
            terms::centre_motion(p, t.h[0], t.h[1]),
            terms::rotation_motion(p, t.h[0], t.h[1]),
        )
    }

    pub(super) fn crossing_loss(&self) -> Loss {
        Loss::Cauchy(self.params.crossing_loss)
    }

    pub(super) fn motion_loss(&self) -> Loss {
        Loss::Huber(self.params.motion_loss)
    }

    /// The robust cost at `state`.
    fn cost(&self, state: &State, spreads: &Spreads) -> f64 {
        self.cost_and_rays(state, spreads).0
    }

    /// The robust cost at `state`, and how many crossings have a ray at its focal scale:
    /// the others lie where the distortion, applied at the corrected radius, folds back
    /// and has no inverse, and are not in the cost.
    fn cost_and_rays(&self, state: &State, spreads: &Spreads) -> (f64, usize) {
        let rays = self.rays(state.focal_scale);
        let formed = rays.iter().filter(|r| r.is_some()).count();
        // The residuals alone, and their losses summed by products (`terms::CostSum`).
        let mut crossings = terms::CostSum::new(self.crossing_loss());
        for (k, c) in self.evidence.crossings.iter().enumerate() {
            if let Some(e) = self.crossing_error(state, k, &rays) {
                crossings.add(e / spreads.crossing_px[c.class as usize]);
            }
        }
        let mut cost = crossings.total();
        for t in &self.triples {
            let (c, r) = self.motion_terms(state, t);
            cost += self.motion_cost(&c, &r, spreads);
        }
        (cost, formed)
    }

    fn motion_cost(&self, c: &MotionTerm, r: &MotionTerm, s: &Spreads) -> f64 {
        let loss = self.motion_loss();
        loss.cost(c.r.norm() / s.centre)
            + loss.cost(r.r.xy().norm() / s.aim_rad)
            + loss.cost(r.r.z / s.roll_rad)
    }

    /// The normal equations `H δ = −g` at `state` (robust weights from its residuals) and
    /// the robust cost there.
    pub(super) fn normal_equations(
        &self,
        state: &State,
        spreads: &Spreads,
    ) -> (Mat<f64>, Vec<f64>, f64) {
        let mut h = Mat::<f64>::zeros(self.n, self.n);
        let mut g = vec![0.0; self.n];
        let cost = self.normal_equations_into(state, spreads, &mut h, &mut g);
        (h, g, cost)
    }

    /// [`Self::normal_equations`] into `h` (its lower triangle) and `g`, resized to the
    /// unknowns and zeroed first, so that the minimisation's steps reuse one matrix; the
    /// cost.
    pub(super) fn normal_equations_into(
        &self,
        state: &State,
        spreads: &Spreads,
        h: &mut Mat<f64>,
        g: &mut Vec<f64>,
    ) -> f64 {
        let n = self.n;
        if (h.nrows(), h.ncols()) == (n, n) {
            // Only the lower triangle is ever written or read (the terms, the gauge and
            // the ridge add to it; the factorisations and the predicted decrease read
            // it), so the upper one stays the zeros it was made with: half the memory
            // to clear at every step (26 MB at 1,800 unknowns).
            for j in 0..n {
                h.col_as_slice_mut(j)[j..].fill(0.0);
            }
        } else {
            *h = Mat::<f64>::zeros(n, n);
        }
        g.clear();
        g.resize(n, 0.0);
        let (h, g) = (&mut *h, g.as_mut_slice());
        let mut crossing_cost = terms::CostSum::new(self.crossing_loss());
        let rays = self.rays(state.focal_scale);
        let fi = self.focal_index();
        let ev = self.evidence;
        for k in 0..ev.crossings.len() {
            let Some(t) = self.crossing(state, k, &rays) else {
                continue;
            };
            let c = &ev.crossings[k];
            let sigma = spreads.crossing_px[c.class as usize];
            let x = t.e / sigma;
            crossing_cost.add(x);
            let w = self.crossing_loss().weight(x) / (sigma * sigma);
            let (pa, pb) = (
                ev.planes[c.a as usize].pose as usize * POSE_DOF,
                ev.planes[c.b as usize].pose as usize * POSE_DOF,
            );
            let mut idx = [0usize; 13];
            let mut jac = [0.0; 13];
            for i in 0..6 {
                idx[i] = pa + i;
                jac[i] = t.ja[i];
                idx[6 + i] = pb + i;
                jac[6 + i] = t.jb[i];
            }
            let len = match fi {
                Some(f) => {
                    idx[12] = f;
                    jac[12] = t.j_scale;
                    13
                }
                None => 12,
            };
            accumulate(h, g, &idx[..len], &jac[..len], w, t.e);
        }
        let mut cost = crossing_cost.total();
        for t in &self.triples {
            let (cm, rm) = self.motion_terms(state, t);
            cost += self.motion_cost(&cm, &rm, spreads);
            let loss = self.motion_loss();
            // Centre: one weight for the vector (isotropic), from its length.
            let wc = loss.weight(cm.r.norm() / spreads.centre) / spreads.centre.powi(2);
            let wa = loss.weight(rm.r.xy().norm() / spreads.aim_rad) / spreads.aim_rad.powi(2);
            let wr = loss.weight(rm.r.z / spreads.roll_rad) / spreads.roll_rad.powi(2);
            for row in 0..3 {
                let (idx, jr, jc) = motion_row(t, &cm, &rm, row);
                let w_rot = if row == 2 { wr } else { wa };
                accumulate(h, g, &idx, &jr, w_rot, rm.r[row]);
                let cidx = idx.map(|i| i + 3);
                accumulate(h, g, &cidx, &jc, wc, cm.r[row]);
            }
        }
        cost
    }
}

/// Row `row` of triple `t`'s motion terms over the unknowns: the indices of its three
/// poses' rotation unknowns, the rotation term's derivatives there, and the centre
/// term's derivatives (whose unknowns are each index plus 3).
pub(super) fn motion_row(
    t: &Triple,
    cm: &MotionTerm,
    rm: &MotionTerm,
    row: usize,
) -> ([usize; 9], [f64; 9], [f64; 9]) {
    let mut idx = [0usize; 9];
    let mut jr = [0.0; 9];
    let mut jc = [0.0; 9];
    for (s, &p) in t.poses.iter().enumerate() {
        for col in 0..3 {
            idx[3 * s + col] = p as usize * POSE_DOF + col;
            jr[3 * s + col] = rm.j[s][(row, col)];
            jc[3 * s + col] = cm.j[s][(row, col)];
        }
    }
    (idx, jr, jc)
}

/// `H += w j jᵀ` (its lower triangle, row ≥ column) and `g += w j e` over the unknowns
/// `idx` (one term's row; an unknown may appear twice, as when both planes of a crossing
/// are one pose's).
pub(super) fn accumulate(
    h: &mut Mat<f64>,
    g: &mut [f64],
    idx: &[usize],
    jac: &[f64],
    w: f64,
    e: f64,
) {
    for (&jb, &ib) in jac.iter().zip(idx) {
        if jb == 0.0 {
            continue;
        }
        g[ib] += w * jb * e;
        let wj = w * jb;
        let col = h.col_as_slice_mut(ib);
        for (&ja, &ia) in jac.iter().zip(idx) {
            if ia >= ib {
                col[ia] += wj * ja;
            }
        }
    }
}

/// The poses and focal scale being estimated.
#[derive(Clone, Debug)]
pub(super) struct State {
    pub(super) poses: Vec<CrossPose>,
    pub(super) focal_scale: f64,
}

impl State {
    /// The state moved by `step` (local parameters).
    fn moved(&self, step: &[f64], focal: Option<usize>) -> State {
        let mut next = self.clone();
        for (i, p) in next.poses.iter_mut().enumerate() {
            p.retract(&step[POSE_DOF * i..POSE_DOF * (i + 1)]);
        }
        if let Some(f) = focal {
            next.focal_scale += step[f];
        }
        next
    }
}

/// `∂ log ρ` of the inverse depth `ρ = n·r / d` of laser `laser` of `pose` along `ray`,
/// with respect to the pose's `(δθ, δC)` and the focal scale; `None` where `ρ` is 0.
fn log_depth_gradient(pose: &CrossPose, laser: usize, ray: &Ray) -> Option<([f64; 6], f64)> {
    let lin = pose.linearise(laser);
    let nr = lin.n.dot(&ray.r);
    if nr == 0.0 || lin.d == 0.0 {
        return None;
    }
    let t = lin.n.cross(&ray.r) / nr - lin.dd_dtheta / lin.d;
    let c = -lin.n / lin.d;
    Some((
        [t.x, t.y, t.z, c.x, c.y, c.z],
        lin.n.dot(&ray.dr_dscale) / nr,
    ))
}

impl Layout<'_> {
    /// The gauge: the mean log inverse depth over the crossings' planes, and its
    /// gradient. Holding it fixes the global scale without touching anything a crossing
    /// determines or leaves free: the turn of a plane about the line of its crossings
    /// moves no depth at them, so it stays free, where holding the centres' scale would
    /// pin it. Rays within [`GAUGE_MIN_RAY_PLANE_SIN`] of their plane are left out: there
    /// the log depth turns with the plane without bound, and a few such crossings would
    /// make the gauge hold their depths instead of the scale.
    pub(super) fn gauge(&self, state: &State, rays: &[Option<Ray>]) -> (f64, Vec<f64>) {
        let mut grad = vec![0.0; self.n];
        let fi = self.focal_index();
        let (sum, count) = self.gauge_terms(state, rays, |pose, slot, ray| {
            let Some((g, gl)) = log_depth_gradient(pose, usize::from(slot.laser), ray) else {
                return false;
            };
            let base = slot.pose as usize * POSE_DOF;
            for (i, gi) in g.iter().enumerate() {
                grad[base + i] += gi;
            }
            if let Some(f) = fi {
                grad[f] += gl;
            }
            true
        });
        let k = count.max(1) as f64;
        for x in &mut grad {
            *x /= k;
        }
        (sum / k, grad)
    }

    /// The gauge's value alone, as [`Self::gauge`] gives it, for [`Self::renormalise`]
    /// after every trial step, which threw the gradient away (the gauge was 11 % of the
    /// minimisation's own thread's samples in the dive's fold restarts). The same terms
    /// in the same order: a term whose gradient does not exist (`n·r = 0`) has `|ρ|`
    /// within rounding of 0, which the ray-plane angle test leaves out first.
    fn gauge_value(&self, state: &State, rays: &[Option<Ray>]) -> f64 {
        let (sum, count) = self.gauge_terms(state, rays, |_, _, _| true);
        sum / count.max(1) as f64
    }

    /// The sum of the log inverse depths the gauge holds, and their count: `keep` is
    /// asked of each term ([`Self::gauge`]) and says whether it counts.
    fn gauge_terms(
        &self,
        state: &State,
        rays: &[Option<Ray>],
        mut keep: impl FnMut(&CrossPose, PlaneSlot, &Ray) -> bool,
    ) -> (f64, usize) {
        let ev = self.evidence;
        let (mut sum, mut count) = (0.0, 0usize);
        for (c, ray) in ev.crossings.iter().zip(rays) {
            let Some(ray) = ray else { continue };
            for p in [c.a, c.b] {
                let slot = ev.planes[p as usize];
                let pose = &state.poses[slot.pose as usize];
                let Some(v) = pose.plane(usize::from(slot.laser)) else {
                    continue;
                };
                let rho = v.dot(&ray.r);
                if rho.abs() < GAUGE_MIN_RAY_PLANE_SIN * v.norm() * ray.r.norm() {
                    continue;
                }
                if !keep(pose, slot, ray) {
                    continue;
                }
                sum += rho.abs().ln();
                count += 1;
            }
        }
        (sum, count)
    }

    /// Rescales the centres so that the gauge is `target` again (the crossings' costs do
    /// not change; the motion terms' do).
    fn renormalise(&self, state: &mut State, target: f64) {
        let rays = self.rays(state.focal_scale);
        let now = self.gauge_value(state, &rays);
        let s = (now - target).exp();
        if s.is_finite() && s > 0.0 {
            for p in &mut state.poses {
                p.centre *= s;
            }
        }
    }
}

/// Adds the gauge row `gauge` (weight: the mean diagonal) and the ridge to `h`'s lower
/// triangle, the only one the factorisations read (`Side::Lower`): the upper triangle
/// stays as it was, so `h` is not symmetric afterwards.
fn regularise(h: &mut Mat<f64>, gauge: &[f64]) {
    let n = h.nrows();
    let mean_diag = (0..n).map(|i| h[(i, i)]).sum::<f64>() / n.max(1) as f64;
    let norm = gauge.iter().map(|x| x * x).sum::<f64>().sqrt();
    if norm > 0.0 {
        let scale = mean_diag / (norm * norm);
        for (j, &gj) in gauge.iter().enumerate() {
            if gj == 0.0 {
                continue;
            }
            let col = &mut h.col_as_slice_mut(j)[j..];
            for (c, &gi) in col.iter_mut().zip(&gauge[j..]) {
                *c += scale * gi * gj;
            }
        }
    }
    let ridge = RIDGE * mean_diag.max(f64::MIN_POSITIVE);
    for i in 0..n {
        h[(i, i)] += ridge;
    }
}

/// Solves `(H + μ diag H) δ = −g`; `None` if it does not factor.
fn damped_step(
    h: &Mat<f64>,
    g: &[f64],
    mu: f64,
    threads: DenseThreads,
    storage: &mut Option<Mat<f64>>,
) -> Option<Vec<f64>> {
    let llt = Cholesky::of_lower_in(h, mu, threads, storage)?;
    let minus_g: Vec<f64> = g.iter().map(|x| -x).collect();
    let out = llt.solve(&minus_g);
    *storage = Some(llt.into_storage());
    out.iter().all(|x| x.is_finite()).then_some(out)
}

/// The decrease of the cost that the Gauss–Newton model predicts for `step`:
/// `−(2 g·δ + δᵀ H δ)`, the cost being a sum of squares with `g = Jᵀ W e`; `h` is read
/// from its lower triangle.
pub(super) fn predicted_decrease(h: &Mat<f64>, g: &[f64], step: &[f64]) -> f64 {
    let mut quad = 0.0;
    for (j, &sj) in step.iter().enumerate() {
        let col = &h.col_as_slice(j)[j..];
        quad += col[0] * sj * sj;
        quad += 2.0
            * sj
            * col[1..]
                .iter()
                .zip(&step[j + 1..])
                .map(|(c, s)| c * s)
                .sum::<f64>();
    }
    let linear: f64 = g.iter().zip(step).map(|(a, b)| a * b).sum();
    -(2.0 * linear + quad)
}

/// Levenberg–Marquardt from `state` at fixed spreads; returns the state, its cost and
/// the steps taken.
fn minimise(layout: &Layout, mut state: State, spreads: &Spreads) -> (State, f64, usize) {
    let focal = layout.focal_index();
    let target = layout.gauge_value(&state, &layout.rays(state.focal_scale));
    let mut mu = 1e-4;
    let mut steps = 0;
    let (mut current, rays_now) = layout.cost_and_rays(&state, spreads);
    let mut last_decrease = f64::INFINITY;
    // One matrix each for the normal equations and their factor, reused by every step.
    let (mut h, mut g, mut factor) = (Mat::<f64>::zeros(0, 0), Vec::new(), None);
    for _ in 0..layout.params.max_iterations {
        if layout.params.cancel.is_cancelled() {
            break;
        }
        layout.normal_equations_into(&state, spreads, &mut h, &mut g);
        let (_, gauge) = layout.gauge(&state, &layout.rays(state.focal_scale));
        regularise(&mut h, &gauge);
        let mut accepted = None;
        let mut raise = 2.0;
        for _ in 0..10 {
            if let Some(step) = damped_step(&h, &g, mu, layout.params.threads, &mut factor) {
                let mut trial = state.moved(&step, focal);
                layout.renormalise(&mut trial, target);
                // A focal scale at which some crossing's ray cannot be formed drops that
                // crossing from the cost: the cost falls by losing data, not by fitting
                // it. Such a step is no step.
                let (c, rays) = layout.cost_and_rays(&trial, spreads);
                if c.is_finite() && c < current && trial.focal_scale > 0.0 && rays >= rays_now {
                    accepted = Some((trial, c));
                    // Nielsen's rule: the damping follows how well the quadratic model
                    // predicted the decrease (gain ratio ρ), not a fixed factor.
                    let predicted = predicted_decrease(&h, &g, &step);
                    let shrink = if predicted > 0.0 {
                        let rho = (current - c) / predicted;
                        (1.0 - (2.0 * rho - 1.0).powi(3)).max(1.0 / 3.0)
                    } else {
                        1.0 / 3.0
                    };
                    mu = (mu * shrink).max(1e-12);
                    break;
                }
            }
            mu *= raise;
            raise *= 2.0;
        }
        let Some((trial, c)) = accepted else { break };
        let decrease = current - c;
        tracing::trace!(steps, cost = c, decrease, mu, "step");
        let ratio = decrease / last_decrease;
        let left = if last_decrease.is_finite() && ratio < 1.0 {
            decrease * ratio / (1.0 - ratio)
        } else {
            f64::INFINITY
        };
        let settled = decrease < 0.1 * COST_SETTLED || left < COST_SETTLED;
        last_decrease = decrease;
        state = trial;
        current = c;
        steps += 1;
        if settled {
            break;
        }
    }
    (state, current, steps)
}

/// The full covariance at `state`: the inverse of the information matrix with the gauge
/// and ridge. `None` if it does not factor.
fn covariance(layout: &Layout, state: &State, spreads: &Spreads) -> Option<Mat<f64>> {
    Some(information_factor(layout, state, spreads)?.inverse())
}

/// The Cholesky factor of the information matrix at `state`, with the gauge and ridge;
/// `None` if it does not factor.
pub(super) fn information_factor(
    layout: &Layout,
    state: &State,
    spreads: &Spreads,
) -> Option<Cholesky> {
    let (mut h, _, _) = layout.normal_equations(state, spreads);
    let (_, gauge) = layout.gauge(state, &layout.rays(state.focal_scale));
    regularise(&mut h, &gauge);
    Cholesky::of_lower(&h, 0.0, layout.params.threads)
}

/// The covariance the crossings alone give at `state`: [`covariance`] without the
/// motion terms. The estimate keeps the motion terms (they steer the minimisation, and
/// tell a walking hand's solution from its twin), but the uncertainty it reports is
/// this one. The motion terms model the hand, with spreads measured from the estimate
/// itself. Where the crossings leave a pose free, the estimate has only that model for
/// it, and no check can catch the model being wrong. A short sweep over a table top is
/// the case: its crossings lie almost in one plane, the common shift of all planes
/// that the crosses' orthogonality fixes is then weakly held, and 60 frames of tuning
/// table 5 came out 4.4 of their own deviations off with the motion terms' information
/// counted, 1.3 without (the planes it then leaves out are the ones the crossings do
/// not fix). On a sweep whose crossings fix every pose the two agree.
fn evidence_covariance(layout: &Layout, state: &State, spreads: &Spreads) -> Option<Mat<f64>> {
    covariance(&layout.crossings_only(), state, spreads)
}

/// Minimises from `start`, measures the spreads, and repeats until they settle; then the
/// covariance. See the module docs.
pub fn estimate(
    evidence: &Evidence,
    start: &Start,
    params: &EstimateParams,
) -> Result<Estimate, SolveError> {
    evidence.validate().map_err(SolveError::InvalidProblem)?;
    if start.poses.len() != evidence.num_poses() {
        return Err(SolveError::InvalidProblem(format!(
            "{} start poses for {} poses",
            start.poses.len(),
            evidence.num_poses()
        )));
    }
    if evidence.num_poses() == 0 {
        return Err(SolveError::TooFewPlanes {
            found: 0,
            needed: 4,
        });
    }
    let layout = Layout::new(evidence, params);
    let mut state = State {
        poses: start.poses.clone(),
        focal_scale: start.focal_scale,
    };
    let mut spreads = start.spreads;
    let mut iterations = 0;
    let mut cost;
    let mut cov;
    let mut redundancy;
    let mut round = 0;
    loop {
        let (s, c, steps) = minimise(&layout, state, &spreads);
        params.cancel.check()?;
        state = s;
        cost = c;
        iterations += steps;
        cov = covariance(&layout, &state, &spreads).ok_or(SolveError::Degenerate(
            "the information matrix does not factor",
        ))?;
        let (next, r) = measured_spreads(&layout, &state, &spreads, &cov);
        redundancy = r;
        round += 1;
        let change = relative_change(&spreads, &next);
        tracing::debug!(round, cost, steps, ?next, change, "estimator round");
        if round >= params.variance_rounds || change < SPREAD_SETTLED {
            break;
        }
        spreads = next;
    }
    let rays = layout.rays(state.focal_scale);
    let loss = layout.crossing_loss();
    let (mut weights, mut residuals) = (Vec::new(), Vec::new());
    for k in 0..evidence.crossings.len() {
        match layout.crossing(&state, k, &rays) {
            Some(t) => {
                let sigma = spreads.crossing_px[evidence.crossings[k].class as usize];
                weights.push(loss.weight(t.e / sigma) as f32);
                residuals.push((t.e / sigma) as f32);
            }
            None => {
                weights.push(0.0);
                residuals.push(f32::NAN);
            }
        }
    }
    let cov = if layout.triples.is_empty() {
        cov
    } else {
        evidence_covariance(&layout, &state, &spreads).ok_or(SolveError::Degenerate(
            "the crossings' information matrix does not factor",
        ))?
    };
    let (scatter, scatter_crossings) =
        super::scatter::scatter_information(&layout, &state, &spreads, &cov);
    let fi = layout.focal_index();
    let marginals = (0..evidence.num_poses())
        .map(|p| {
            let mut idx = [0usize; 7];
            for (a, slot) in idx.iter_mut().enumerate().take(6) {
                *slot = p * POSE_DOF + a;
            }
            PoseMarginal::from_fn(|i, j| {
                let (ii, jj) = (idx[i], idx[j]);
                match (i == 6, j == 6, fi) {
                    (false, false, _) => cov[(ii, jj)],
                    (true, true, Some(f)) => cov[(f, f)],
                    (true, false, Some(f)) => cov[(f, jj)],
                    (false, true, Some(f)) => cov[(ii, f)],
                    _ => 0.0,
                }
            })
        })
        .collect();
    Ok(Estimate {
        poses: state.poses,
        focal_scale: state.focal_scale,
        spreads,
        crossing_weights: weights,
        crossing_residuals: residuals,
        marginals,
        scatter,
        scatter_crossings,
        cost,
        iterations,
        redundancy,
        covariance: cov,
        joint_of_pose: (0..evidence.num_poses() as u32).map(Some).collect(),
    })
}

/// The residuals of an estimate by kind, in their own units: crossings strong and faint
/// (pixels), the components of the centre's second differences (length per frame², in
/// the estimate's scale), the aim's and the roll's (radians per frame²).
///
/// A crossing that the estimate puts behind the camera on either of its planes is not
/// explained by it, however near its planes' meeting line its pixel lies: its residual
/// is one focal length (the miss of a point at the edge of the view). The residual alone
/// cannot see this: the coplanarity holds for planes through the camera's side too, and
/// an estimate that put half of a table scan's crossings behind the camera, at a scale
/// 800 times smaller where the gauge reads it, fitted the rest about as well as the
/// right planes and won on its centre's second differences, which that scale shrinks
/// (generality seed 104 at 100 frames).
pub fn residuals_by_kind(
    evidence: &Evidence,
    estimate: &Estimate,
    params: &EstimateParams,
) -> [Vec<f64>; 5] {
    let layout = Layout::new(evidence, params);
    let state = State {
        poses: estimate.poses.clone(),
        focal_scale: estimate.focal_scale,
    };
    let rays = layout.rays(state.focal_scale);
    let mut out: [Vec<f64>; 5] = Default::default();
    for k in 0..evidence.crossings.len() {
        if let Some(t) = layout.crossing(&state, k, &rays) {
            let seen = layout.in_front(&state, k, &rays);
            out[evidence.crossings[k].class as usize].push(if seen {
                t.e
            } else {
                evidence.focal_px
            });
        }
    }
    for t in &layout.triples {
        let (c, r) = layout.motion_terms(&state, t);
        out[2].extend(c.r.iter().copied());
        out[3].extend([r.r.x, r.r.y]);
        out[4].push(r.r.z);
    }
    out
}

/// The robust cost of an estimate's poses and focal scale under other `spreads`, so
/// that two estimates of one scan can be compared on one scale.
pub fn cost_at(
    evidence: &Evidence,
    estimate: &Estimate,
    spreads: &Spreads,
    params: &EstimateParams,
) -> f64 {
    cost_of(
        evidence,
        &estimate.poses,
        estimate.focal_scale,
        spreads,
        params,
    )
}

/// The robust cost of `poses` and `focal_scale` under `spreads`.
pub fn cost_of(
    evidence: &Evidence,
    poses: &[CrossPose],
    focal_scale: f64,
    spreads: &Spreads,
    params: &EstimateParams,
) -> f64 {
    let layout = Layout::new(evidence, params);
    let state = State {
        poses: poses.to_vec(),
        focal_scale,
    };
    layout.cost(&state, spreads)
}

/// Whether `class` crossings exist in `evidence` (their spread is measured only then).
pub fn has_class(evidence: &Evidence, class: CrossingClass) -> bool {
    evidence.crossings.iter().any(|c| c.class == class)
}

/// The centre's typical size in the solution (RMS of the centres), for scale-free
/// thresholds on the centre spread.
pub fn centre_scale(poses: &[CrossPose]) -> f64 {
    let s: f64 = poses.iter().map(|p| p.centre.norm_squared()).sum();
    (s / poses.len().max(1) as f64).sqrt()
}
