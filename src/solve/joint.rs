//! Stage 9: every solved plane refined together.
//!
//! The global solve fixes the planes of its subset from the algebraic null vector of
//! the coplanarity system, and the orthogonality of their crosses fixes the shift `w`
//! of that family (and the focal scale, when it is estimated); every other plane is
//! then fitted with those held fixed. Each step is sound, but none weighs all the
//! evidence at once: the shift is set by the crosses alone with the planes held as
//! they are, so the planes' own noise goes into it whole, and a shift off by 1 % of
//! the inverse depth makes the depth error grow with depth.
//!
//! Here all solved planes move together, minimising
//!
//! ```text
//!   Σ_crossings ρ(e_k / σ_img)  +  Σ_crosses ρ(cos θ_ab / σ_ortho)  +  Σ_planes |v_i − v_i⁰|²_Q_i
//! ```
//!
//! with `e_k` the Sampson residual of crossing `k` (image units), `ρ` Huber's loss,
//! `cos θ_ab` the cosine between the two planes of a cross, and `Q_i` a weak prior
//! that holds only the directions a plane's own crossings leave unfixed (a plane
//! whose crossings lie on one image line keeps the turn the motion prior gave it).
//! Each kind of residual is weighed by its robust spread, measured at the start and
//! again after a first pass. With the focal scale estimated it is one more unknown,
//! through the rays of the crossings; its deviation is a jackknife of the refinement
//! and no smaller than the refinement's move. Gauss–Newton with Levenberg–Marquardt
//! damping on a dense system of three unknowns a plane; the global scale, which no
//! term fixes, is restored afterwards to the median inverse depth at the crossings.

use faer::Mat;
use nalgebra::{Matrix3, SymmetricEigen, Vector3};

use super::nullspace::sampson;
use super::{Problem, Solution};

/// What [`refine_jointly`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct JointFit {
    /// Planes refined together.
    pub planes: usize,
    /// Crossings and crosses used.
    pub crossings: usize,
    pub crosses: usize,
    /// Accepted Gauss–Newton steps.
    pub steps: usize,
    /// Cost (in units of the noise, squared) before and after.
    pub cost_before: f64,
    pub cost_after: f64,
}

/// Fewest crosses for the refinement: their spread weighs them, and the orthogonality
/// fit before has already set four unknowns (the shift and the focal scale) from them,
/// so that a handful fit exactly and would say nothing of their noise.
const MIN_CROSSES: usize = 8;

/// Huber's threshold, in units of the noise.
const HUBER_K: f64 = 2.0;

/// A plane's direction whose information from its own crossings is below this fraction
/// of its best-fixed direction's is held by the prior.
const WEAK_FRACTION: f64 = 1e-4;

/// Robust spread (1.4826 × the median absolute value, [`super::MAD_TO_SIGMA`]) of
/// residuals.
fn spread(values: impl Iterator<Item = f64>) -> Option<f64> {
    super::median(values.map(f64::abs).collect())
        .map(|m| super::MAD_TO_SIGMA * m)
        .filter(|s| s.is_finite() && *s > 0.0)
}

/// The evidence: crossings `(a, b, u)` between solved planes `a` and `b` at the ray
/// `u` (focal-corrected), crosses `(a, b)`, and the noise of each.
struct Evidence {
    rows: Vec<(usize, usize, Vector3<f64>)>,
    crosses: Vec<(usize, usize)>,
    sigma: f64,
    sigma_ortho: f64,
}

impl Evidence {
    /// Ray of crossing row `u` (focal-corrected at the start) at the focal ratio `r`
    /// to the start's.
    fn ray(u: &Vector3<f64>, r: f64) -> Vector3<f64> {
        Vector3::new(u.x / r, u.y / r, 1.0)
    }

    /// The robust spreads of the crossings' Sampson residuals and of the crosses'
    /// cosines at `planes` and focal ratio `r`.
    fn spreads(&self, planes: &[Vector3<f64>], r: f64) -> Option<(f64, f64)> {
        let sigma = spread(self.rows.iter().filter_map(|&(a, b, u)| {
            let u = Self::ray(&u, r);
            sampson(&planes[a], &planes[b], [u.x, u.y]).map(|(e, _)| e)
        }))?;
        let sigma_ortho = spread(
            self.crosses
                .iter()
                .map(|&(a, b)| cosine(&planes[a], &planes[b])),
        )?;
        Some((sigma, sigma_ortho))
    }

    /// The cost of `planes` at focal ratio `r` (each plane's prior `q` about `start`).
    fn cost(
        &self,
        planes: &[Vector3<f64>],
        r: f64,
        start: &[Vector3<f64>],
        q: &[Matrix3<f64>],
    ) -> f64 {
        let mut total = 0.0;
        for &(a, b, u) in &self.rows {
            let u = Self::ray(&u, r);
            if let Some((e, _)) = sampson(&planes[a], &planes[b], [u.x, u.y]) {
                total += huber(e / self.sigma);
            }
        }
        for &(a, b) in &self.crosses {
            total += huber(cosine(&planes[a], &planes[b]) / self.sigma_ortho);
        }
        for ((v, v0), q) in planes.iter().zip(start).zip(q) {
            let d = v - v0;
            total += d.dot(&(q * d));
        }
        total
    }

    /// Gauss–Newton normal equations at `planes` and focal ratio `r`: `H` (dense, 3
    /// unknowns per plane, then the ratio when `focal`) and the gradient `g`, Huber's
    /// weights applied.
    fn normal_equations(
        &self,
        planes: &[Vector3<f64>],
        r: f64,
        focal: bool,
        start: &[Vector3<f64>],
        q: &[Matrix3<f64>],
    ) -> (Mat<f64>, Vec<f64>) {
        let dim = 3 * planes.len() + usize::from(focal);
        let mut h = Mat::<f64>::zeros(dim, dim);
        let mut g = vec![0.0; dim];
        // One residual `res` of noise `sigma` with its non-zero derivatives.
        let mut term = |entries: &[(usize, f64)], res: f64, sigma: f64| {
            let z = res / sigma;
            let w = if z.abs() <= HUBER_K {
                1.0
            } else {
                HUBER_K / z.abs()
            } / (sigma * sigma);
            for &(i, ji) in entries {
                g[i] += w * ji * res;
                for &(j, jj) in entries {
                    h[(i, j)] += w * ji * jj;
                }
            }
        };
        let lam = 3 * planes.len();
        let mut entries: Vec<(usize, f64)> = Vec::with_capacity(7);
        for &(a, b, u0) in &self.rows {
            let u = Self::ray(&u0, r);
            let d = planes[a] - planes[b];
            let (Some(j), Some((e, inv_g))) = (
                sampson_jacobian(&d, &u),
                sampson(&planes[a], &planes[b], [u.x, u.y]),
            ) else {
                continue;
            };
            entries.clear();
            for x in 0..3 {
                entries.push((3 * a + x, j[x]));
                entries.push((3 * b + x, -j[x]));
            }
            if focal {
                // ∂u/∂r = −(u.x, u.y, 0)/r.
                entries.push((lam, -(d.x * u.x + d.y * u.y) / r * inv_g));
            }
            term(&entries, e, self.sigma);
        }
        for &(a, b) in &self.crosses {
            let (va, vb) = (planes[a], planes[b]);
            let (na, nb) = (va.norm(), vb.norm());
            let c = cosine(&va, &vb);
            let ja = vb / (na * nb) - va * (c / (na * na));
            let jb = va / (na * nb) - vb * (c / (nb * nb));
            entries.clear();
            for x in 0..3 {
                entries.push((3 * a + x, ja[x]));
                entries.push((3 * b + x, jb[x]));
            }
            term(&entries, c, self.sigma_ortho);
        }
        for (i, ((v, v0), q)) in planes.iter().zip(start).zip(q).enumerate() {
            let pg = q * (v - v0);
            for x in 0..3 {
                g[3 * i + x] += pg[x];
                for y in 0..3 {
                    h[(3 * i + x, 3 * i + y)] += q[(x, y)];
                }
            }
        }
        (h, g)
    }
}

/// Refines every solved plane of `solution` together over the `usable` crossings of
/// `problem` (those among solved planes that the current planes keep as inliers) and
/// the crosses of solved partners that are not outliers; at most `max_steps` accepted
/// steps a pass, the focal scale too when `focal` (with a new deviation). `None`
/// (planes as they were) when the solution has no fit context or too little to refine.
pub fn refine_jointly(
    problem: &Problem,
    usable: &[bool],
    solution: &mut Solution,
    max_steps: usize,
    focal: bool,
) -> Option<JointFit> {
    let ctx = solution.fit_context?;
    if max_steps == 0 {
        return None;
    }
    let lambda = solution.focal_scale;
    let n = problem.num_curves.min(solution.planes.len());
    let mut index = vec![usize::MAX; n];
    let mut start: Vec<Vector3<f64>> = Vec::new();
    let mut curve_of = Vec::new();
    for (c, p) in solution.planes.iter().enumerate().take(n) {
        if let Some(p) = p {
            index[c] = start.len();
            start.push(*p);
            curve_of.push(c);
        }
    }
    let m = start.len();
    let solved = |c: usize| index.get(c).copied().filter(|&i| i != usize::MAX);
    // Inliers by the solve's own noise; the spread below is then measured on them.
    let gate = ctx.outlier_k * ctx.sigma_img / lambda;
    let rows: Vec<(usize, usize, Vector3<f64>)> = problem
        .crossings
        .iter()
        .enumerate()
        .filter(|&(k, c)| usable.get(k).copied().unwrap_or(false) && c.a != c.b)
        .filter(|(_, c)| c.sin_angle >= ctx.min_sin_angle)
        .filter_map(|(_, c)| {
            let (a, b) = (solved(c.a as usize)?, solved(c.b as usize)?);
            let u = Vector3::new(c.u[0] / lambda, c.u[1] / lambda, 1.0);
            let (e, _) = sampson(&start[a], &start[b], [u.x, u.y])?;
            (e.abs() <= gate).then_some((a, b, u))
        })
        .collect();
    let crosses: Vec<(usize, usize)> = problem
        .partner
        .iter()
        .enumerate()
        .take(n)
        .filter_map(|(c, p)| {
            let p = (*p)? as usize;
            (p > c).then_some((solved(c)?, solved(p)?))
        })
        .collect();
    if m < 4 || rows.len() < 3 * m || crosses.len() < MIN_CROSSES {
        return None;
    }
    // The noise of each kind from the current residuals, so that the two kinds of
    // evidence weigh as their scatter says; crosses beyond the outlier bound stay out.
    let mut evidence = Evidence {
        rows,
        crosses,
        sigma: 1.0,
        sigma_ortho: 1.0,
    };
    (evidence.sigma, evidence.sigma_ortho) = evidence.spreads(&start, 1.0)?;
    let bound = ctx.outlier_k * evidence.sigma_ortho;
    evidence
        .crosses
        .retain(|&(a, b)| cosine(&start[a], &start[b]).abs() <= bound);
    let q = weak_prior(&evidence, &start);

    let cost_before = evidence.cost(&start, 1.0, &start, &q);
    let state = (start.clone(), 1.0, cost_before, 0);
    let (mut planes, mut ratio, mut current, mut steps) =
        minimise(&evidence, state, focal, &start, &q, max_steps);
    // The spreads again at the result, and a second pass with them: the first ones
    // hold whatever the refinement then took away (with the focal scale free, a
    // shared tilt of every cross).
    if let Some(spreads) = evidence.spreads(&planes, ratio) {
        (evidence.sigma, evidence.sigma_ortho) = spreads;
        let cost = evidence.cost(&planes, ratio, &start, &q);
        (planes, ratio, current, steps) = minimise(
            &evidence,
            (planes, ratio, cost, steps),
            focal,
            &start,
            &q,
            max_steps,
        );
    }
    // Both costs in the units of the last spreads.
    let cost_before = evidence.cost(&start, 1.0, &start, &q);
    // The scale no term fixes: the median inverse depth at the crossings as before.
    let inverse_depth = |v: &[Vector3<f64>], r: f64| {
        super::median(
            evidence
                .rows
                .iter()
                .map(|&(a, b, u)| 0.5 * (v[a] + v[b]).dot(&Evidence::ray(&u, r)))
                .collect(),
        )
        .filter(|m| m.is_finite() && *m > 0.0)
    };
    let rescale = inverse_depth(&start, 1.0)? / inverse_depth(&planes, ratio)?;
    for (v, &c) in planes.iter().zip(&curve_of) {
        solution.planes[c] = Some(v * rescale);
    }
    if focal {
        // The replicates' spread, and no less than the refinement's own move: the two
        // estimates see the same data, so their difference is a part of the error that
        // neither jackknife sees (the weighting, the model), and it is not claimed away.
        if let Some(std) = focal_jackknife(&evidence, &planes, ratio, &start, &q) {
            solution.focal_scale_std = Some(solution.focal_scale * std.hypot(ratio - 1.0));
        }
    }
    solution.focal_scale *= ratio;
    Some(JointFit {
        planes: m,
        crossings: evidence.rows.len(),
        crosses: evidence.crosses.len(),
        steps,
        cost_before,
        cost_after: current,
    })
}

/// Where the cost is and how it got there: planes, focal ratio, cost, steps.
type State = (Vec<Vector3<f64>>, f64, f64, usize);

/// Levenberg–Marquardt from `state` (its steps counted on) for at most `max_steps`
/// more accepted steps, or until the cost settles; the ratio moves only if `focal`.
fn minimise(
    evidence: &Evidence,
    state: State,
    focal: bool,
    start: &[Vector3<f64>],
    q: &[Matrix3<f64>],
    max_steps: usize,
) -> State {
    let (mut planes, mut ratio, mut current, mut steps) = state;
    let limit = steps + max_steps;
    let mut mu = 1e-4;
    while steps < limit {
        let (mut h, g) = evidence.normal_equations(&planes, ratio, focal, start, q);
        let diagonal: Vec<f64> = (0..h.nrows()).map(|i| h[(i, i)]).collect();
        let mut next = None;
        // Levenberg–Marquardt: more damping until a step lowers the cost. The damping
        // goes on the diagonal in place (the matrix is the largest allocation here).
        for _ in 0..6 {
            for (i, d) in diagonal.iter().enumerate() {
                h[(i, i)] = d + mu * d.max(f64::MIN_POSITIVE);
            }
            let Some(step) = newton_step(&h, &g) else {
                mu *= 10.0;
                continue;
            };
            let trial: Vec<Vector3<f64>> = planes
                .iter()
                .enumerate()
                .map(|(i, v)| {
                    v + Vector3::new(step[(3 * i, 0)], step[(3 * i + 1, 0)], step[(3 * i + 2, 0)])
                })
                .collect();
            let trial_ratio = if focal {
                ratio + step[(g.len() - 1, 0)]
            } else {
                ratio
            };
            let c = evidence.cost(&trial, trial_ratio, start, q);
            if c.is_finite() && c < current && trial_ratio > 0.0 {
                next = Some((trial, trial_ratio, c));
                mu = (mu / 3.0).max(1e-12);
                break;
            }
            mu *= 10.0;
        }
        let Some((trial, trial_ratio, c)) = next else {
            break;
        };
        let settled = current - c < 1e-7 * current;
        planes = trial;
        ratio = trial_ratio;
        current = c;
        steps += 1;
        if settled {
            break;
        }
    }
    (planes, ratio, current, steps)
}

/// The step `−H⁻¹ g` through the Cholesky factor of `h`; `None` if `h` does not
/// factor.
fn newton_step(h: &Mat<f64>, g: &[f64]) -> Option<Mat<f64>> {
    let llt = h.llt(faer::Side::Lower).ok()?;
    let mut step = Mat::<f64>::from_fn(g.len(), 1, |i, _| -g[i]);
    faer::linalg::solvers::Solve::solve_in_place(&llt, step.as_mut());
    Some(step)
}

/// Standard deviation of the refined focal ratio by the delete-a-group jackknife, as
/// the solve's own (`focal_jackknife_std`): [`super::JACKKNIFE_GROUPS`] replicates,
/// each without one group of the crossings and crosses (every tenth, by a hash of its
/// index), each one Gauss–Newton step from the refined planes (the cost is nearly
/// quadratic there), and the replicates' robust spread times `√(K − 1)`. It carries
/// the planes' noise; systematic errors (a bias of the stripe centres) are not in it.
fn focal_jackknife(
    evidence: &Evidence,
    planes: &[Vector3<f64>],
    ratio: f64,
    start: &[Vector3<f64>],
    q: &[Matrix3<f64>],
) -> Option<f64> {
    let k = super::JACKKNIFE_GROUPS;
    let group = |i: usize| (super::mix64(i as u64) % k as u64) as usize;
    let offset = evidence.rows.len();
    let mut ratios = Vec::with_capacity(k);
    for g in 0..k {
        let part = Evidence {
            rows: (0..evidence.rows.len())
                .filter(|&i| group(i) != g)
                .map(|i| evidence.rows[i])
                .collect(),
            crosses: (0..evidence.crosses.len())
                .filter(|&i| group(offset + i) != g)
                .map(|i| evidence.crosses[i])
                .collect(),
            ..*evidence
        };
        let (mut h, grad) = part.normal_equations(planes, ratio, true, start, q);
        let dim = h.nrows();
        for i in 0..dim {
            h[(i, i)] *= 1.0 + 1e-9;
        }
        let step = newton_step(&h, &grad)?;
        ratios.push(ratio + step[(dim - 1, 0)]);
    }
    let mid = super::median(ratios.clone())?;
    let mad = super::median(ratios.iter().map(|r| (r - mid).abs()).collect())?;
    Some(super::MAD_TO_SIGMA * mad * ((k - 1) as f64).sqrt()).filter(|s| s.is_finite())
}

/// Per plane, a prior on the directions its own crossings fix least (below
/// [`WEAK_FRACTION`] of the best), as strong as that fraction: a plane whose
/// crossings lie on one image line keeps its turn.
fn weak_prior(evidence: &Evidence, start: &[Vector3<f64>]) -> Vec<Matrix3<f64>> {
    let mut info = vec![Matrix3::zeros(); start.len()];
    for &(a, b, u) in &evidence.rows {
        if let Some(j) = sampson_jacobian(&(start[a] - start[b]), &u) {
            let jj = j * j.transpose() / (evidence.sigma * evidence.sigma);
            info[a] += jj;
            info[b] += jj;
        }
    }
    info.iter()
        .map(|h| {
            let eig = SymmetricEigen::new(*h);
            let floor = WEAK_FRACTION * eig.eigenvalues.max().max(0.0);
            let mut q = Matrix3::zeros();
            for i in 0..3 {
                if eig.eigenvalues[i] < floor {
                    let e = eig.eigenvectors.column(i);
                    q += e * e.transpose() * floor;
                }
            }
            q
        })
        .collect()
}

/// Cosine of the angle between two planes' normals.
fn cosine(a: &Vector3<f64>, b: &Vector3<f64>) -> f64 {
    a.dot(b) / (a.norm() * b.norm())
}

/// Huber's loss of a residual in units of the noise (`r²` within [`HUBER_K`]).
fn huber(r: f64) -> f64 {
    if r.abs() <= HUBER_K {
        r * r
    } else {
        2.0 * HUBER_K * r.abs() - HUBER_K * HUBER_K
    }
}

/// Gradient of the Sampson residual `e = d·u / |d_xy|` with respect to `d = v_a − v_b`.
fn sampson_jacobian(d: &Vector3<f64>, u: &Vector3<f64>) -> Option<Vector3<f64>> {
    let g = d.x.hypot(d.y);
    if g == 0.0 || !g.is_finite() {
        return None;
    }
    let e = d.dot(u);
    Some(u / g - Vector3::new(d.x, d.y, 0.0) * (e / (g * g * g)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::solve::synthetic::{analytic_crossings, random_scan, Rng, ScanSpec};
    use crate::solve::FitContext;

    /// Largest relative depth error at the crossings of `planes` against `truth`,
    /// after the best global scale (the median ratio).
    fn worst_depth_error(
        planes: &[Option<Vector3<f64>>],
        truth: &[Vector3<f64>],
        crossings: &[crate::intersect::Crossing],
    ) -> f64 {
        let ratios: Vec<(f64, f64)> = crossings
            .iter()
            .flat_map(|c| [c.a, c.b])
            .zip(crossings.iter().flat_map(|c| [c.u, c.u]))
            .filter_map(|(i, u)| {
                let u = Vector3::new(u[0], u[1], 1.0);
                let v = planes[i as usize]?;
                Some((truth[i as usize].dot(&u), v.dot(&u)))
            })
            .collect();
        let k =
            super::super::median(ratios.iter().map(|(t, v)| v / t).collect()).expect("crossings");
        ratios
            .iter()
            .map(|(t, v)| (t * k / v - 1.0).abs())
            .fold(0.0, f64::max)
    }

    /// Planes off the truth by a common shift `w` (1 % of the inverse depth, the error
    /// that grows with depth) and by noise of their own: the crossings cannot see the
    /// shift, the crosses' orthogonality can, and only once each plane may move too.
    #[test]
    fn a_common_shift_and_plane_noise_are_refined_away() {
        let scan = random_scan(&ScanSpec {
            num_crosses: 30,
            seed: 5,
            ..ScanSpec::default()
        });
        let crossings = analytic_crossings(&scan.scene, &scan.planes, 0.1);
        let median_inverse_depth =
            super::super::median(scan.planes.iter().map(|v| v.norm()).collect()).expect("planes");
        let w = Vector3::new(0.6, -0.3, 0.74).normalize() * (0.01 * median_inverse_depth);
        let mut rng = Rng::new(11);
        let mut sol = Solution::empty();
        sol.planes = scan
            .planes
            .iter()
            .map(|v| {
                let noise = Vector3::new(rng.normal(), rng.normal(), rng.normal());
                Some(v + w + noise * (2e-3 * v.norm()))
            })
            .collect();
        sol.fit_context = Some(FitContext::for_tests(1.0, 1e-2));
        let problem = Problem {
            num_curves: scan.planes.len(),
            crossings: &crossings,
            partner: &scan.partner,
            focal_px: 1000.0,
        };
        let before = worst_depth_error(&sol.planes, &scan.planes, &crossings);
        let fit = refine_jointly(&problem, &vec![true; crossings.len()], &mut sol, 20, false)
            .expect("refined");
        let after = worst_depth_error(&sol.planes, &scan.planes, &crossings);
        assert!(before > 0.005, "the start is off: {before}");
        // What remains is the planes' noise in the directions their own crossings
        // barely fix, which the weak prior holds.
        assert!(
            after < before / 50.0 && after < 1e-3,
            "{before} -> {after} ({fit:?})"
        );
        assert_eq!(fit.crosses, 30);
        assert!(fit.cost_after < fit.cost_before);

        // Nothing to refine without a fit context, or with no step allowed.
        let mut bare = Solution::empty();
        bare.planes = sol.planes.clone();
        assert!(
            refine_jointly(&problem, &vec![true; crossings.len()], &mut bare, 20, false).is_none()
        );
        assert!(
            refine_jointly(&problem, &vec![true; crossings.len()], &mut sol, 0, false).is_none()
        );
        // Nor from so few crosses that the orthogonality fit before fitted them exactly.
        let few: Vec<Option<u32>> = scan
            .partner
            .iter()
            .enumerate()
            .map(|(c, p)| p.filter(|_| c < 2 * (MIN_CROSSES - 1)))
            .collect();
        let sparse = Problem {
            partner: &few,
            ..problem
        };
        assert!(
            refine_jointly(&sparse, &vec![true; crossings.len()], &mut sol, 20, false).is_none()
        );
    }

    /// A focal scale 0.5 % off (the given planes right, as the crossings fix them): the
    /// crosses' orthogonality pulls the scale back, with a deviation that covers the
    /// move, and only when the scale is free.
    #[test]
    fn a_focal_scale_off_by_half_a_percent_is_refined() {
        let scan = random_scan(&ScanSpec {
            num_crosses: 30,
            seed: 7,
            ..ScanSpec::default()
        });
        // Crossings with noise (0.1 px at a focal length of 1000 px): the noise sets
        // the weights, and exact ones would weigh without bound.
        let mut rng = Rng::new(3);
        let mut crossings = analytic_crossings(&scan.scene, &scan.planes, 0.1);
        for c in &mut crossings {
            c.u[0] += 1e-4 * rng.normal();
            c.u[1] += 1e-4 * rng.normal();
        }
        let lambda = 1.005;
        let mut sol = Solution::empty();
        // Planes in the coordinates corrected by the wrong scale: the given ones are
        // the true ones (the true scale is 1).
        sol.planes = scan
            .planes
            .iter()
            .map(|g| Some(Vector3::new(g.x * lambda, g.y * lambda, g.z)))
            .collect();
        sol.focal_scale = lambda;
        sol.fit_context = Some(FitContext {
            focal_scale: lambda,
            ..FitContext::for_tests(1.0, 1e-2)
        });
        let problem = Problem {
            num_curves: scan.planes.len(),
            crossings: &crossings,
            partner: &scan.partner,
            focal_px: 1000.0,
        };
        let all = vec![true; crossings.len()];
        let mut fixed = sol.clone();
        refine_jointly(&problem, &all, &mut fixed, 20, false).expect("refined");
        assert_eq!(fixed.focal_scale, lambda, "the scale moves only when asked");
        refine_jointly(&problem, &all, &mut sol, 20, true).expect("refined");
        assert!((sol.focal_scale - 1.0).abs() < 1e-3, "{}", sol.focal_scale);
        let std = sol.focal_scale_std.expect("a deviation");
        assert!((0.004..0.01).contains(&std), "{std}");
    }
}
