//! The self-calibrating plane solver: laser planes from the crossings of their curves.
//!
//! Owns everything between the crossings of [`crate::intersect`] and one plane per
//! curve; knows nothing of pixels, images or point clouds. A laser plane is
//! `v · X = 1` in camera coordinates, `v ∈ R³`; a crossing of curves `i, j` at the
//! image point `u = (x, y, 1)` lies on both planes, so `(v_i − v_j) · u = 0`.
//!
//! # Stages
//! Each stage is a function of its own so the live daemon can rerun them one by one
//! (add crossings, extend new curves from solved ones, re-solve the global set).
//! 1. [`subset::select_global`]: a connected subset of at most `max_global_planes`
//!    curves, each with at least `min_global_crossings` crossings inside it,
//!    grown greedily cross by cross (a curve and its partner together).
//! 2. [`nullspace::normal_matrix`] and [`nullspace::null_space`]: the stacked
//!    system `A V = 0` through its normal matrix `AᵀA`, gauge shifted out; its null
//!    vector `V0` gives all planes as `V = s V0 + (w, …, w)`, a 4-DOF family.
//! 3. Robust rounds ([`robust_global`]): each crossing's Sampson residual (the image
//!    distance, in normalised units, from the line where its two planes meet);
//!    starting weights from [`seed::consensus_weights`] (small seeds grown curve by
//!    curve by consensus), then Cauchy reweighting with scale `2.385 σ`,
//!    `σ = 1.4826 · median |e|`; crossings beyond `outlier_mad_k · σ` are outliers,
//!    curves with most of their crossings out are rejected, and the subset is pruned
//!    and re-solved.
//! 4. [`ortho::solve_orthogonality`]: the orthogonality of each cross's two planes
//!    fixes `w` (and the focal scale `λ` if asked), leaving the one global scale.
//! 5. [`extend::fit_plane`]: every other curve from its crossings with solved curves
//!    (and its partner's orthogonality), in passes until no more can be solved.
//! 6. Refinement: Gauss–Seidel rounds re-fitting each extended curve from all its
//!    solved neighbours. The global subset stays fixed, which keeps the gauge and scale.
//! 7. `refit_shift`: `w` (and `λ`) once more from the orthogonality of every cross
//!    with both planes solved, the extended ones included, applied to all planes.
//!
//! # Conventions of the result
//! Planes are returned in the *corrected* normalised coordinates `(x/λ, y/λ, 1)` of a
//! camera whose focal length is `λ` ([`Solution::focal_scale`]) times the one used to
//! normalise the crossings (`λ = 1` unless estimated): with `u = (x, y, 1)` as given,
//! the inverse depth of a point on plane `v` is `v · (x/λ, y/λ, 1)`. The global scale
//! is fixed so that the median inverse depth of the global crossings is 1 (median depth
//! about 1) and depths are positive; the caller rescales to metric units.

pub mod calibrate;
pub mod centre;
pub mod choose;
pub mod conditional;
mod consensus;
pub mod dense;
pub mod estimate;
pub mod evidence;
pub mod extend;
mod folds;
mod global;
pub mod init;
pub mod nullspace;
pub mod ortho;
pub mod outside;
mod pieces;
pub mod pose;
mod scatter;
mod screen;
pub mod seed;
mod spreads;
pub mod subset;
pub mod subspace;
pub mod synthetic;
pub mod terms;

pub use calibrate::{calibrate, calibrate_from, calibrate_until, Calibration, PlaneVerdict};
pub use global::{robust_global, GlobalCoplanarity};

use crate::intersect::Crossing;
use crate::rng::mix64;
use extend::{fit_plane, FitContext};
use nalgebra::Vector3;
use serde::Deserialize;
use subset::adjacency;

/// Smallest noise level assumed for any residual: rounding, not measurement.
const NOISE_FLOOR: f64 = 1e-9;
/// Least bend ([`subset::bend`]) of an extended curve's crossings without a solved
/// partner, in units of the measured Sampson noise `σ_img` (when below
/// [`SolveParams::min_curve_bend`]): the plane's turn about its 3D line is then known to
/// about `σ_img / bend` radians over the spread of its crossings.
const EXTEND_BEND_SIGMA: f64 = 20.0;
/// Least spread of a minimal sample in the extension's consensus start, in units of
/// `σ_img` (see [`extend::FitContext::min_sample_spread`]).
const MIN_SAMPLE_SPREAD_SIGMA: f64 = 4.0;
/// Extended planes whose relative depth is known to better than this are kept however
/// their peers fare (see [`SolveParams::uncertain_plane_ratio`]): on exact or nearly
/// exact crossings, dropping the least determined would only lose planes.
const KEEP_DEPTH_SIGMA: f64 = 5e-4;
/// Sampson residual scale from the median absolute residual of a Gaussian.
const MAD_TO_SIGMA: f64 = 1.4826;
/// Cauchy weight scale in robust standard deviations (95 % efficiency on Gaussian noise).
const CAUCHY_SCALE: f64 = 2.385;

/// Errors of the plane solver.
#[derive(Debug, thiserror::Error)]
pub enum SolveError {
    #[error("invalid problem: {0}")]
    InvalidProblem(String),
    #[error(
        "too few planes in the global subset: {found}, need at least {needed} (the curves of \
         that many frames must cross each other's, each in several places; were the lasers \
         seen, and did the projector move?)"
    )]
    TooFewPlanes { found: usize, needed: usize },
    #[error(
        "too few crosses with both planes in the global subset: {found}, need at least \
         {needed} (the orthogonality of a cross's two planes fixes the solution, so both \
         lines of a cross must be seen crossing other frames' curves: a laser too faint, \
         such as red far under water, or lost in its sheet's glow, leaves too few)"
    )]
    TooFewCrosses { found: usize, needed: usize },
    #[error(
        "no start for the self-calibration of {planes} planes with {crossings} crossings \
         ({strong} strong enough for the linear start): the linear start: {linear}; the \
         fixed-centre start: no centre of the hand gives planes whose crosses come out \
         orthogonal. The planes may be fixed by the crossings, but nothing here finds \
         them: a longer sweep with more crossings between frames, or brighter stripes, \
         gives the starts more to stand on"
    )]
    NoStart {
        planes: usize,
        crossings: usize,
        strong: usize,
        linear: Box<SolveError>,
    },
    #[error("degenerate system: {0}")]
    Degenerate(&'static str),
    /// The caller asked the solve to stop ([`Cancel`]): a live epoch superseded by the
    /// final solve.
    #[error("cancelled")]
    Cancelled,
}

/// A request to stop a solve early, shared between the solve and its caller. The solve
/// looks at it between estimator steps, between starts, and in the linear start
/// between robust rounds and plane fits ([`SolveParams::cancel`]), and then returns
/// [`SolveError::Cancelled`]: the daemon's final solve must not share the CPU with an
/// epoch it supersedes.
#[derive(Clone, Debug, Default)]
pub struct Cancel(std::sync::Arc<std::sync::atomic::AtomicBool>);

impl Cancel {
    pub fn cancel(&self) {
        self.0.store(true, std::sync::atomic::Ordering::Relaxed);
    }

    pub fn is_cancelled(&self) -> bool {
        self.0.load(std::sync::atomic::Ordering::Relaxed)
    }

    /// `Err(Cancelled)` once cancelled.
    pub fn check(&self) -> Result<(), SolveError> {
        if self.is_cancelled() {
            Err(SolveError::Cancelled)
        } else {
            Ok(())
        }
    }
}

/// Not a setting: two parameter sets differ in what they compute, never in who may stop
/// them.
impl PartialEq for Cancel {
    fn eq(&self, _: &Self) -> bool {
        true
    }
}

/// Parameters of the plane solver.
#[derive(Clone, Debug, PartialEq, serde::Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SolveParams {
    /// Largest number of planes in the global coplanarity solve (the paper used 400).
    pub max_global_planes: usize,
    /// Largest number of anchor crosses: those estimated jointly, and crossed with every
    /// curve; every other frame's pose is fitted on its own against them
    /// ([`crate::pipeline::anchors`]). Bounds the work per frame.
    pub max_anchor_poses: usize,
    /// Least number of crossings a curve needs with other solved curves to be extended
    /// (three determine a plane).
    pub min_crossings_per_plane: usize,
    /// Least number of crossings a curve needs with other curves of the global subset:
    /// more than three, so that a wrong one shows in the residuals.
    pub min_global_crossings: usize,
    /// Crossings at angles whose sine is below this are ignored.
    pub min_sin_angle: f64,
    /// A curve enters the global solve only if its crossings are off one image line by
    /// at least this RMS distance, in pixels of the ideal camera ([`subset::bend`]
    /// × focal length): crossings on one line (a curve on a flat wall) leave its plane
    /// free to turn about its 3D line. Must be well above the crossing noise. In
    /// pixels so that one setting serves every resolution and field of view.
    pub min_curve_bend_px: f64,
    /// `min_curve_bend_px` in normalised units, set by [`solve`] from the problem's
    /// focal length.
    #[serde(skip)]
    pub(crate) min_curve_bend: f64,
    /// Outlier threshold in robust standard deviations (`1.4826 × MAD`) of the
    /// crossings' Sampson residuals.
    pub outlier_mad_k: f64,
    /// Estimate the focal scale `λ` (true focal length over the one used) together
    /// with the gauge; a flat port under water gives about 1.33.
    pub estimate_focal: bool,
    /// Largest number of reweighted solves of the global system per subset.
    pub robust_rounds: usize,
    /// Gauss–Seidel rounds re-fitting the extended planes from all their neighbours.
    pub refine_rounds: usize,
    /// A curve with more than this fraction of its crossings rejected is rejected.
    pub max_outlier_fraction: f64,
    /// Only curves whose strongest point reaches this ridge strength (the stripe's
    /// contrast, grey levels) shape the planes; fainter ones are triangulated on the
    /// planes the strong ones give, if a crossing confirms them. Extraction goes lower
    /// to cover dim surfaces, where faint false ridges (the sheet's glow under water)
    /// would otherwise pull the planes.
    pub min_curve_strength: f32,
    /// And a crossing of two strong curves shapes the planes only where both are at
    /// least this strong (grey levels): not on a faint stretch that hangs on a strong
    /// curve (into its sheet's glow, say).
    pub min_crossing_strength: f32,
    /// An extended plane whose fit leaves the relative depth at one of its crossings
    /// more uncertain than this many times the median of the extended planes (one
    /// standard deviation of `δZ / Z` from the fit's covariance, the other curves'
    /// planes taken as exact) is dropped after the refinement; the motion prior may
    /// then give it the turn of its neighbours. Such planes (few crossings, close
    /// together) were the worst of the water scenes, 1.3-3 % off. Relative, so that
    /// noisier crossings everywhere drop nothing more. 0 keeps all.
    pub uncertain_plane_ratio: f64,
    /// Threads of the joint estimator's dense factorisations: set by the caller, not the
    /// configuration (`reconstruct` and the daemon's final solve run after the
    /// extraction and have the cores; the daemon's epochs share them with its
    /// extraction workers and keep one). The answer does not depend on it.
    #[serde(skip)]
    pub dense_threads: dense::DenseThreads,
    /// Stops the linear start ([`solve`]) between its robust rounds and its plane fits:
    /// set by the caller (a live epoch's, which the final solve supersedes), never by the
    /// configuration.
    #[serde(skip)]
    pub cancel: Cancel,
}

impl Default for SolveParams {
    fn default() -> Self {
        Self {
            max_global_planes: 400,
            max_anchor_poses: 300,
            min_crossings_per_plane: 3,
            min_global_crossings: 6,
            min_sin_angle: 0.1,
            min_curve_bend_px: 1.0,
            min_curve_bend: 1.0 / 1000.0,
            outlier_mad_k: 4.0,
            estimate_focal: false,
            robust_rounds: 12,
            refine_rounds: 2,
            max_outlier_fraction: 0.5,
            min_curve_strength: 40.0,
            min_crossing_strength: 15.0,
            uncertain_plane_ratio: 4.0,
            dense_threads: dense::DenseThreads::default(),
            cancel: Cancel::default(),
        }
    }
}

impl SolveParams {
    /// The joint estimator's settings these make (never cancelled): one place, so that
    /// a pose fitted after the estimate ([`outside`]) is fitted as the estimate's own.
    pub fn estimate_params(&self) -> estimate::EstimateParams {
        estimate::EstimateParams {
            estimate_focal: self.estimate_focal,
            threads: self.dense_threads,
            ..estimate::EstimateParams::default()
        }
    }
}

/// The crossings of a scan and which curves form a cross.
#[derive(Clone, Copy, Debug)]
pub struct Problem<'a> {
    pub num_curves: usize,
    pub crossings: &'a [Crossing],
    /// Per curve: the other curve of its cross, if seen.
    pub partner: &'a [Option<u32>],
    /// Focal length (pixels) of the normalisation, to turn pixel settings into
    /// normalised units.
    pub focal_px: f64,
}

/// The solved planes and what the solver judged on the way.
#[derive(Clone, Debug)]
pub struct Solution {
    /// Per curve, its plane `v · X = 1` (see the module docs for coordinates and
    /// scale); `None` when it could not be solved or was rejected.
    pub planes: Vec<Option<Vector3<f64>>>,
    /// Curves of the global coplanarity solve.
    pub global: Vec<u32>,
    /// True focal length over the one used to normalise (1 unless estimated).
    pub focal_scale: f64,
    pub focal_scale_std: Option<f64>,
    /// Indices into the problem's crossings judged wrong (not those below the angle
    /// threshold).
    pub rejected_crossings: Vec<usize>,
    /// Curves judged wrong (most of their crossings rejected).
    pub rejected_curves: Vec<u32>,
    /// Number of crossings ignored for their shallow angle.
    pub shallow_crossings: usize,
    /// RMS Sampson residual of the global inlier crossings, normalised image units.
    pub residual_rms: f64,
    /// Robust noise estimate of the Sampson residual, normalised image units.
    pub sigma_img: f64,
    /// RMS deviation from 90° of the crosses with both planes solved, degrees.
    pub orthogonality_rms_deg: f64,
    /// Smallest and second smallest eigenvalue of the gauge-fixed normal matrix,
    /// relative to its mean eigenvalue: a clear gap means a well-determined subset.
    pub null_space_eigenvalues: [f64; 2],
    /// What fitting one more plane against these needs (noise levels, thresholds), in
    /// the given coordinates: planes there are `(v.x/λ, v.y/λ, v.z)` of [`Self::planes`].
    /// `None` for a solution not made by [`solve`].
    pub fit_context: Option<FitContext>,
    /// Extended planes dropped because their crossings fixed them too loosely
    /// ([`SolveParams::uncertain_plane_ratio`]).
    pub uncertain_planes: usize,
}

impl Solution {
    /// The planes in the coordinates of the crossings (and curve points) they were
    /// solved from, the file's normalised ones: [`Self::planes`] are in the
    /// focal-corrected ones, `v · (x/λ, y/λ, 1)` being the inverse depth, which is
    /// `(v.x/λ, v.y/λ, v.z) · (x, y, 1)`.
    pub fn given_planes(&self) -> Vec<Option<Vector3<f64>>> {
        let lambda = self.focal_scale;
        self.planes
            .iter()
            .map(|p| p.map(|v| Vector3::new(v.x / lambda, v.y / lambda, v.z)))
            .collect()
    }

    /// Which of the `count` crossings it was solved from it did not reject.
    pub fn not_rejected(&self, count: usize) -> Vec<bool> {
        let mut usable = vec![true; count];
        for &k in &self.rejected_crossings {
            if let Some(u) = usable.get_mut(k) {
                *u = false;
            }
        }
        usable
    }

    /// A solution with no plane solved (focal scale 1, zero residuals).
    pub fn empty() -> Self {
        Self {
            planes: Vec::new(),
            global: Vec::new(),
            focal_scale: 1.0,
            focal_scale_std: None,
            rejected_crossings: Vec::new(),
            rejected_curves: Vec::new(),
            shallow_crossings: 0,
            residual_rms: 0.0,
            sigma_img: 0.0,
            orthogonality_rms_deg: 0.0,
            null_space_eigenvalues: [0.0; 2],
            fit_context: None,
            uncertain_planes: 0,
        }
    }
}

/// Above this RMS (degrees) the crosses of a self-calibration are too far from
/// orthogonal to trust: a good solve of a real cross laser leaves a few hundredths to
/// a few tenths of a degree (the projector's own tolerance, the crossings' noise).
pub const SUSPECT_ORTHOGONALITY_DEG: f64 = 1.0;

/// What to tell the user when the solved crosses are far from orthogonal: the cloud
/// is then likely warped, from a wrong solution or an input the method does not fit.
pub fn orthogonality_warning(rms_deg: f64) -> Option<String> {
    (rms_deg > SUSPECT_ORTHOGONALITY_DEG).then(|| {
        format!(
            "the solved crosses are {rms_deg:.2}° from orthogonal (RMS; a good solve \
             leaves well under {SUSPECT_ORTHOGONALITY_DEG}°), so the cloud is probably \
             warped: check that the two lasers are told apart (the overlay of \
             `crossline extract`), that the camera file belongs to this camera and \
             resolution, and that the projector's two lines are orthogonal"
        )
    })
}

/// Above this standard deviation of an estimated focal scale the cloud cannot be
/// trusted to 2 %: twice the deviation is then over 1 % of the focal length, which
/// alone moves points at the image's edge by several pixels and tilts the planes.
pub const SUSPECT_FOCAL_SCALE_STD: f64 = 0.005;

/// What to tell the user when the focal scale was estimated (`std` is its standard
/// deviation) and is too uncertain for a cloud good to 2 %.
pub fn focal_warning(scale: f64, std: Option<f64>) -> Option<String> {
    let std = std.filter(|s| *s > SUSPECT_FOCAL_SCALE_STD)?;
    Some(format!(
        "the focal length estimated from the crosses is uncertain: scale {scale:.4} ±          {std:.4} (±{:.1} %), so the cloud may be off by a few per cent; calibrate the          camera in the water, or scan with more crosses at different angles",
        100.0 * std
    ))
}

pub(crate) fn median(mut x: Vec<f64>) -> Option<f64> {
    if x.is_empty() {
        return None;
    }
    let mid = x.len() / 2;
    let (_, m, _) = x.select_nth_unstable_by(mid, f64::total_cmp);
    Some(*m)
}

/// Stage 5 and 6: planes (in the given coordinates) for every curve not yet solved,
/// from crossings with solved curves, then `refine_rounds` Gauss–Seidel rounds over
/// the curves not in `fixed`; then the refined planes that their crossings fix too
/// loosely (`ctx.max_depth_sigma` times the median) are dropped again. Returns the crossings and curves
/// rejected on the way, and the number of planes dropped as too uncertain; once
/// `cancel` is set it fits no more planes, and its answer is none.
pub fn extend_and_refine(
    problem: &Problem,
    active: &[bool],
    planes: &mut [Option<Vector3<f64>>],
    fixed: &[bool],
    (ctx, cancel): (&FitContext, &Cancel),
    refine_rounds: usize,
) -> (Vec<usize>, Vec<u32>, usize) {
    let cr = problem.crossings;
    let adj = adjacency(problem.num_curves, cr, active);
    let mut rejected_crossings = Vec::new();
    let mut rejected_curves = Vec::new();
    let mut gave_up = vec![false; problem.num_curves];
    let gather = |c: usize, planes: &[Option<Vector3<f64>>]| -> Vec<(usize, Vector3<f64>)> {
        adj[c]
            .iter()
            .filter_map(|&(o, k)| planes[o as usize].map(|v| (k, v)))
            .collect()
    };
    let partner_plane = |c: usize, planes: &[Option<Vector3<f64>>]| {
        problem
            .partner
            .get(c)
            .copied()
            .flatten()
            .and_then(|p| planes.get(p as usize).copied().flatten())
    };
    // Extension passes: most-connected curves first, solved planes used at once.
    loop {
        let mut order: Vec<(usize, usize)> = (0..problem.num_curves)
            .filter(|&c| planes[c].is_none() && !gave_up[c])
            .map(|c| (gather(c, planes).len(), c))
            .filter(|&(m, _)| m >= 2)
            .collect();
        order.sort_unstable_by(|a, b| b.cmp(a));
        let mut progress = false;
        for (_, c) in order {
            if cancel.is_cancelled() {
                break;
            }
            let known = gather(c, planes);
            let partner = partner_plane(c, planes);
            if known.len() < ctx.min_crossings && partner.is_none() {
                continue;
            }
            match fit_plane(cr, &known, partner, ctx, None) {
                Some(fit) if (fit.outliers.len() as f64) <= 0.5 * known.len() as f64 => {
                    planes[c] = Some(fit.plane);
                    progress = true;
                }
                Some(fit) => {
                    gave_up[c] = true;
                    rejected_curves.push(c as u32);
                    rejected_crossings.extend(known.iter().map(|(k, _)| *k));
                    let _ = fit;
                }
                None => {}
            }
        }
        if !progress {
            break;
        }
    }
    let mut uncertain = vec![f64::NAN; problem.num_curves];
    let mut dropped_uncertain = 0;
    for round in 0..refine_rounds {
        for c in 0..problem.num_curves {
            if fixed[c] || planes[c].is_none() || cancel.is_cancelled() {
                continue;
            }
            let known = gather(c, planes);
            let partner = partner_plane(c, planes);
            let warm = fit_plane(cr, &known, partner, ctx, planes[c]);
            // A plane first fitted from a few of its crossings (its other curves' partners
            // not yet solved) may hold on to that turn and call the rest outliers: where a
            // fit leaves outliers, a fresh consensus start over all crossings is tried too
            // and kept when it agrees with more of them.
            let fit = match warm {
                Some(w) if !w.outliers.is_empty() => {
                    match fit_plane(cr, &known, partner, ctx, None) {
                        Some(fresh) if fresh.inliers > w.inliers => Some(fresh),
                        _ => Some(w),
                    }
                }
                other => other,
            };
            if let Some(fit) = fit {
                planes[c] = Some(fit.plane);
                if round + 1 == refine_rounds {
                    rejected_crossings.extend(fit.outliers.iter().copied());
                    // Judged at the crossings it has, its partner's included.
                    let sigma = known
                        .iter()
                        .map(|(k, _)| fit.depth_sigma(cr[*k].u))
                        .fold(0.0f64, f64::max);
                    uncertain[c] = sigma;
                }
            }
        }
    }
    // Planes fixed too loosely by their crossings are dropped after the refinement
    // (not during it, so that the order of the curves does not matter); the motion
    // prior may give them a plane from the neighbouring frames.
    let typical = median(
        uncertain
            .iter()
            .copied()
            .filter(|s| s.is_finite())
            .collect(),
    );
    if let Some(typical) = typical {
        let limit = (ctx.max_depth_sigma * typical).max(KEEP_DEPTH_SIGMA);
        for c in 0..problem.num_curves {
            if uncertain[c] > limit && planes[c].is_some() {
                planes[c] = None;
                dropped_uncertain += 1;
            }
        }
    }
    if refine_rounds == 0 {
        // Without refinement, report the outliers of the extension fits.
        for c in 0..problem.num_curves {
            if fixed[c] || planes[c].is_none() {
                continue;
            }
            if let Some(fit) = fit_plane(
                cr,
                &gather(c, planes),
                partner_plane(c, planes),
                ctx,
                planes[c],
            ) {
                rejected_crossings.extend(fit.outliers);
            }
        }
    }
    (rejected_crossings, rejected_curves, dropped_uncertain)
}

/// The crosses among `curves` (pairs of partners both in it), as local indices
/// `(i, j)`, `i < j`, with `local[c]` the index of curve `c` in `curves`.
fn crosses_among(
    curves: &[u32],
    local: &[Option<usize>],
    partner: &[Option<u32>],
) -> Vec<(usize, usize)> {
    curves
        .iter()
        .enumerate()
        .filter_map(|(i, &c)| {
            let p = partner.get(c as usize).copied().flatten()?;
            let j = local.get(p as usize).copied().flatten()?;
            (i < j).then_some((i, j))
        })
        .collect()
}

/// Median over the crossings `ids` of the mean inverse depth `½ (v_a + v_b) · u` that
/// the planes `plane(curve)` give them, where both are known.
fn median_inverse_depth(
    crossings: &[Crossing],
    ids: &[usize],
    plane: impl Fn(u32) -> Option<Vector3<f64>>,
) -> Option<f64> {
    median(
        ids.iter()
            .filter_map(|&k| {
                let c = crossings.get(k)?;
                let (a, b) = (plane(c.a)?, plane(c.b)?);
                Some(0.5 * (a + b).dot(&Vector3::new(c.u[0], c.u[1], 1.0)))
            })
            .collect(),
    )
}

/// Stage 7: the shift `w` (and `λ`) again, from the crosses of every solved plane.
/// Extended planes follow the global ones through their crossings, so all solved
/// planes are still one family `v + w`; their crosses add orthogonality constraints
/// that the global subset alone lacks (under water, where fewer curves qualify for it,
/// about as many again). `planes` (given coordinates) are shifted and rescaled to a
/// median inverse depth of 1 over `scale_crossings`; returns the fit, or `None`
/// (planes untouched) when it fails or would use no more than `global_crosses`.
fn refit_shift(
    problem: &Problem,
    planes: &mut [Option<Vector3<f64>>],
    scale_crossings: &[usize],
    global_crosses: usize,
    params: &SolveParams,
) -> Option<ortho::Orthogonality> {
    let solved: Vec<u32> = (0..planes.len() as u32)
        .filter(|&c| planes[c as usize].is_some())
        .collect();
    let mut local = vec![None; planes.len()];
    for (i, &c) in solved.iter().enumerate() {
        local[c as usize] = Some(i);
    }
    let crosses = crosses_among(&solved, &local, problem.partner);
    if crosses.len() <= global_crosses {
        return None;
    }
    let v: Vec<Vector3<f64>> = solved.iter().filter_map(|&c| planes[c as usize]).collect();
    let (orth, _) = ortho::solve_orthogonality(
        &v,
        &crosses,
        params.estimate_focal,
        params.outlier_mad_k,
        NOISE_FLOOR,
    )
    .ok()?;
    let m = median_inverse_depth(problem.crossings, scale_crossings, |c| {
        planes
            .get(c as usize)
            .copied()
            .flatten()
            .map(|p| p + orth.w)
    })
    .filter(|m| m.is_finite() && *m > 0.0)?;
    for p in planes.iter_mut().flatten() {
        *p = (*p + orth.w) / m;
    }
    tracing::debug!(w = ?orth.w, rms_rad = orth.rms_rad, crosses = crosses.len(), "shift refitted on all crosses");
    Some(orth)
}

/// Groups of the delete-a-group jackknife of the focal scale ([`focal_jackknife_std`]).
const JACKKNIFE_GROUPS: usize = 10;

/// Standard deviation of the focal scale from the noise of the crossings: the global
/// subset's null vector and the orthogonality fit solved again [`JACKKNIFE_GROUPS`]
/// times, each time without one group of its inlier crossings (every tenth, by a
/// hash of its index), and the jackknife's `√(K − 1)` times the replicates' spread.
/// Systematic errors (a bias of the stripe centres) are not in it. `None` when a
/// re-solve fails.
fn focal_jackknife_std(
    problem: &Problem,
    global: &GlobalCoplanarity,
    crosses: &[(usize, usize)],
    params: &SolveParams,
) -> Option<f64> {
    let subset = &global.subset;
    let cr = problem.crossings;
    let n = subset.curves.len();
    let group = |k: usize| (mix64(k as u64) % JACKKNIFE_GROUPS as u64) as usize;
    let mut lambdas = Vec::with_capacity(JACKKNIFE_GROUPS);
    for g in 0..JACKKNIFE_GROUPS {
        let ids: Vec<usize> = subset
            .crossings
            .iter()
            .copied()
            .filter(|&k| group(k) != g)
            .collect();
        // The weights of the robust rounds' inliers, without their Cauchy factor.
        let weights: Vec<f64> = ids.iter().map(|&k| crossing_weight(&cr[k])).collect();
        let nm = nullspace::normal_matrix(n, &subset.local, cr, &ids, &weights);
        let start = Some(global.null_space.v0.as_slice());
        let ns = nullspace::null_space_from(nm, start, params.dense_threads).ok()?;
        let (orth, _) =
            ortho::solve_orthogonality(&ns.v0, crosses, true, params.outlier_mad_k, NOISE_FLOOR)
                .ok()?;
        lambdas.push(orth.focal_scale);
    }
    // The spread of the replicates, robustly (one replicate may find the fit's other
    // minimum): each moved by about a K-th of the data, so the whole by √(K − 1) times.
    let mid = median(lambdas.clone())?;
    let mad = median(lambdas.iter().map(|l| (l - mid).abs()).collect())?;
    Some(MAD_TO_SIGMA * mad * ((lambdas.len() - 1) as f64).sqrt())
}

/// Weight of a crossing's row in the normal matrix, before any robust factor:
/// `1 / |u|²` with `u = (x, y, 1)`.
fn crossing_weight(c: &Crossing) -> f64 {
    1.0 / (1.0 + c.u[0] * c.u[0] + c.u[1] * c.u[1])
}

/// Solves the plane of every curve it can (see the module docs for the stages).
pub fn solve(problem: &Problem, params: &SolveParams) -> Result<Solution, SolveError> {
    if !(problem.focal_px.is_finite() && problem.focal_px > 0.0) {
        return Err(SolveError::InvalidProblem(format!(
            "focal length {} px is not positive",
            problem.focal_px
        )));
    }
    let params = &SolveParams {
        min_curve_bend: params.min_curve_bend_px / problem.focal_px,
        ..params.clone()
    };
    let n_curves = problem.num_curves;
    let cr = problem.crossings;
    if problem.partner.len() != n_curves {
        return Err(SolveError::InvalidProblem(format!(
            "partner has {} entries for {} curves",
            problem.partner.len(),
            n_curves
        )));
    }
    if let Some(c) = cr
        .iter()
        .find(|c| c.a as usize >= n_curves || c.b as usize >= n_curves)
    {
        return Err(SolveError::InvalidProblem(format!(
            "crossing of curves {} and {} beyond {} curves",
            c.a, c.b, n_curves
        )));
    }
    let active: Vec<bool> = cr
        .iter()
        .map(|c| {
            c.a != c.b && c.u.iter().all(|x| x.is_finite()) && c.sin_angle >= params.min_sin_angle
        })
        .collect();
    let shallow_crossings = active.iter().filter(|&&a| !a).count();

    params.cancel.check()?;
    let started = std::time::Instant::now();
    let global = robust_global(problem, &active, params)?;
    let subset = &global.subset;
    tracing::debug!(
        planes = subset.curves.len(),
        inlier_crossings = subset.crossings.len(),
        ms = started.elapsed().as_secs_f64() * 1e3,
        "global coplanarity solved"
    );
    let crosses = crosses_among(&subset.curves, &subset.local, problem.partner);
    let (orth, _bad_crosses) = ortho::solve_orthogonality(
        &global.null_space.v0,
        &crosses,
        params.estimate_focal,
        params.outlier_mad_k,
        NOISE_FLOOR,
    )?;

    // Planes in the given coordinates; sign and scale from the global inlier crossings.
    let mut given: Vec<Vector3<f64>> = global.null_space.v0.iter().map(|v| v + orth.w).collect();
    let m = median_inverse_depth(cr, &subset.crossings, |c| {
        subset
            .local
            .get(c as usize)
            .copied()
            .flatten()
            .map(|i| given[i])
    })
    .unwrap_or(0.0);
    if !(m.abs() > 0.0 && m.is_finite()) {
        return Err(SolveError::Degenerate("planes through the camera centre"));
    }
    for v in &mut given {
        *v /= m;
    }
    let mut planes: Vec<Option<Vector3<f64>>> = vec![None; n_curves];
    let mut fixed = vec![false; n_curves];
    for (i, &c) in subset.curves.iter().enumerate() {
        planes[c as usize] = Some(given[i]);
        fixed[c as usize] = true;
    }
    let mut rejected_crossings = global.rejected_crossings.clone();
    let mut rejected_curves = global.rejected_curves.clone();
    let mut ext_active = active.clone();
    for &k in &rejected_crossings {
        ext_active[k] = false;
    }
    for &c in &rejected_curves {
        for (k, x) in cr.iter().enumerate() {
            if x.a == c || x.b == c {
                ext_active[k] = false;
            }
        }
    }
    let ctx = FitContext {
        focal_scale: orth.focal_scale,
        sigma_img: global.sigma_img,
        sigma_ortho: orth.rms_rad.max(NOISE_FLOOR),
        outlier_k: params.outlier_mad_k,
        min_crossings: params.min_crossings_per_plane,
        min_bend: params
            .min_curve_bend
            .min(EXTEND_BEND_SIGMA * global.sigma_img),
        min_sample_spread: MIN_SAMPLE_SPREAD_SIGMA * global.sigma_img,
        max_depth_sigma: if params.uncertain_plane_ratio > 0.0 {
            params.uncertain_plane_ratio
        } else {
            f64::INFINITY
        },
        min_sin_angle: params.min_sin_angle,
        parallel: params.dense_threads.0 > 1,
    };
    params.cancel.check()?;
    let (rc, rv, uncertain_planes) = extend_and_refine(
        problem,
        &ext_active,
        &mut planes,
        &fixed,
        (&ctx, &params.cancel),
        params.refine_rounds,
    );
    // Cut short when cancelled: what it gave is no answer.
    params.cancel.check()?;
    rejected_crossings.extend(rc);
    rejected_crossings.sort_unstable();
    rejected_crossings.dedup();
    rejected_curves.extend(rv);
    rejected_curves.sort_unstable();
    rejected_curves.dedup();

    let orth = refit_shift(
        problem,
        &mut planes,
        &subset.crossings,
        crosses.len(),
        params,
    )
    .unwrap_or(orth);
    // To the corrected coordinates (x/λ, y/λ, 1).
    let lambda = orth.focal_scale;
    for v in planes.iter_mut().flatten() {
        v.x *= lambda;
        v.y *= lambda;
    }
    let mut sum = 0.0;
    let mut count = 0usize;
    for (c, p) in problem.partner.iter().enumerate() {
        if let (Some(p), Some(vi)) = (p, planes[c]) {
            if (*p as usize) > c {
                if let Some(Some(vj)) = planes.get(*p as usize) {
                    let cos = vi.dot(vj) / (vi.norm() * vj.norm());
                    sum += cos.clamp(-1.0, 1.0).asin().powi(2);
                    count += 1;
                }
            }
        }
    }
    // The fit's own deviation sees only the crosses' scatter about the planes it was
    // given; the planes' own noise, through the null vector, dominates.
    let focal_scale_std = match (orth.focal_scale_std, params.estimate_focal) {
        (Some(fit), true) => {
            let planes_std = focal_jackknife_std(problem, &global, &crosses, params);
            Some(fit.hypot(planes_std.unwrap_or(0.0)))
        }
        (fit, _) => fit,
    };
    Ok(Solution {
        planes,
        global: subset.curves.clone(),
        focal_scale: lambda,
        focal_scale_std,
        rejected_crossings,
        rejected_curves,
        shallow_crossings,
        residual_rms: global.residual_rms,
        sigma_img: global.sigma_img,
        orthogonality_rms_deg: (sum / count.max(1) as f64).sqrt().to_degrees(),
        null_space_eigenvalues: [
            global.null_space.lambda_min,
            global.null_space.lambda_second,
        ],
        fit_context: Some(ctx),
        uncertain_planes,
    })
}

#[cfg(test)]
mod conditional_tests;
#[cfg(test)]
mod estimate_tests;
#[cfg(test)]
mod tests;
