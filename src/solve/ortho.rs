//! Orthogonality of the crosses: the gauge shift `w` and the focal scale `λ`.
//!
//! With the scale fixed to `s = 1`, the planes in the given normalised coordinates are
//! `v'_i = v0_i + w`. If the true focal length is `λ` times the one used, the planes in
//! true coordinates are `n_i = D v'_i`, `D = diag(λ, λ, 1)`. Cross `c = (i, j)` is
//! orthogonal when `n_i · n_j = 0`; the residual is the scale-free cosine
//! `r_c = n_i · n_j / (|n_i| |n_j|)`.
//!
//! Linear start (`λ = 1`): `f_c(w) = p_c + q_c · w + w · w = 0` with `p_c = v0_i · v0_j`,
//! `q_c = v0_i + v0_j` (a sphere through which `−w` sees `v0_i` and `v0_j` at a right
//! angle). Subtracting the mean equation removes `w · w`:
//! `(q_c − q̄) · w = −(p_c − p̄)`, least squares over all crosses. When the centres of the
//! spheres are nearly coplanar the weakest direction `e` of that system is fixed
//! instead by the mean quadratic equation along `w_0 + t e` (two roots): all candidates
//! are refined and the one of least cost wins.
//!
//! With `λ` unknown, `f_c = μ (p^{ab}_c + w_x q^a_c + w_y q^b_c) + p^c_c + w_z q^c_c +
//! [μ (w_x² + w_y²) + w_z²]`, `μ = λ²`, is linear in
//! `ξ = (μ, μ w_x, μ w_y, w_z, μ(w_x² + w_y²) + w_z²)`: a second linear start.
//!
//! Refinement: Levenberg–Marquardt on `r_c` over `(w, [λ])` with the analytic Jacobian
//! `∂r/∂n_i = n_j / (|n_i||n_j|) − r n_i / |n_i|²`, `∂n_i/∂w = D`,
//! `∂n_i/∂λ = (a'_i, b'_i, 0)`. The standard deviation of `λ` comes from the
//! Gauss–Newton covariance `σ² (JᵀJ)⁻¹`, `σ² = Σ r² / (m − p)`.

use super::SolveError;
use nalgebra::{DMatrix, DVector, Matrix3, SymmetricEigen, Vector3};

/// Result of the orthogonality stage.
#[derive(Clone, Debug)]
pub struct Orthogonality {
    /// The shift: planes in the given coordinates are `v0_i + w`.
    pub w: Vector3<f64>,
    /// `λ` (1 unless estimated).
    pub focal_scale: f64,
    pub focal_scale_std: Option<f64>,
    /// RMS of the angle between each cross's planes and 90°, in radians.
    pub rms_rad: f64,
}

fn residuals_and_jacobian(
    v0: &[Vector3<f64>],
    crosses: &[(usize, usize)],
    theta: &[f64],
    jac: Option<&mut DMatrix<f64>>,
) -> DVector<f64> {
    let w = Vector3::new(theta[0], theta[1], theta[2]);
    let lambda = theta.get(3).copied().unwrap_or(1.0);
    let d = Vector3::new(lambda, lambda, 1.0);
    let mut r = DVector::zeros(crosses.len());
    let mut jac = jac;
    for (k, &(i, j)) in crosses.iter().enumerate() {
        let (pi, pj) = (v0[i] + w, v0[j] + w);
        let (ni, nj) = (pi.component_mul(&d), pj.component_mul(&d));
        let (li, lj) = (ni.norm(), nj.norm());
        if li == 0.0 || lj == 0.0 {
            r[k] = 1.0;
            continue;
        }
        let cos = ni.dot(&nj) / (li * lj);
        r[k] = cos;
        if let Some(jm) = jac.as_deref_mut() {
            let gi = nj / (li * lj) - ni * (cos / (li * li));
            let gj = ni / (li * lj) - nj * (cos / (lj * lj));
            let dw = (gi + gj).component_mul(&d);
            for a in 0..3 {
                jm[(k, a)] = dw[a];
            }
            if jm.ncols() > 3 {
                jm[(k, 3)] = gi.x * pi.x + gi.y * pi.y + gj.x * pj.x + gj.y * pj.y;
            }
        }
    }
    r
}

struct LmResult {
    theta: Vec<f64>,
    cost: f64,
    jtj: DMatrix<f64>,
}

fn levenberg_marquardt(v0: &[Vector3<f64>], crosses: &[(usize, usize)], start: &[f64]) -> LmResult {
    let p = start.len();
    let m = crosses.len();
    let mut theta = start.to_vec();
    let mut jac = DMatrix::zeros(m, p);
    let mut r = residuals_and_jacobian(v0, crosses, &theta, Some(&mut jac));
    let mut cost = r.norm_squared();
    let mut mu = 1e-3;
    for _ in 0..200 {
        let jtj = jac.transpose() * &jac;
        let g = jac.transpose() * &r;
        let mut improved = false;
        while mu < 1e12 {
            let mut a = jtj.clone();
            for d in 0..p {
                a[(d, d)] += mu * jtj[(d, d)].max(1e-300);
            }
            let Some(step) = a.cholesky().map(|c| c.solve(&(-&g))) else {
                mu *= 10.0;
                continue;
            };
            let cand: Vec<f64> = theta.iter().zip(step.iter()).map(|(t, s)| t + s).collect();
            let rc = residuals_and_jacobian(v0, crosses, &cand, None);
            let cc = rc.norm_squared();
            if cc.is_finite() && cc < cost {
                let rel = (cost - cc) / cost.max(1e-300);
                let step_small =
                    step.norm() <= 1e-14 * (1.0 + theta.iter().map(|t| t * t).sum::<f64>().sqrt());
                theta = cand;
                r = residuals_and_jacobian(v0, crosses, &theta, Some(&mut jac));
                cost = cc;
                mu = (mu * 0.3).max(1e-12);
                improved = !(rel < 1e-15 || step_small);
                break;
            }
            mu *= 10.0;
        }
        if !improved || cost < 1e-30 {
            break;
        }
    }
    let jtj = jac.transpose() * &jac;
    LmResult { theta, cost, jtj }
}

/// A local minimum of the orthogonality cost over the shift `w` (focal scale 1).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ShiftMinimum {
    pub w: Vector3<f64>,
    /// Sum of the squared cosines of the crosses there.
    pub cost: f64,
}

/// Every distinct local minimum of the orthogonality cost of `crosses` over a common
/// shift `w` of the planes `v0`, best first: Levenberg–Marquardt from the linear starts,
/// from no shift, and from a shell of starts along the linear system's axes at three
/// scales of the planes' typical norm. Two minima are one when they lie within
/// `1e-4` of that norm. The orthogonality cost is a quartic in `w`: a scan whose crosses
/// all look alike has more than one minimum, and picking one without saying so settles
/// the whole cloud in a projective warp of the truth.
pub fn shift_minima(v0: &[Vector3<f64>], crosses: &[(usize, usize)]) -> Vec<ShiftMinimum> {
    if crosses.len() < 3 {
        return Vec::new();
    }
    let norms: Vec<f64> = v0
        .iter()
        .map(|v| v.norm())
        .filter(|n| n.is_finite())
        .collect();
    let typical = super::median(norms).unwrap_or(1.0).max(f64::MIN_POSITIVE);
    let mut starts = linear_starts(v0, crosses);
    starts.push(Vector3::zeros());
    for scale in [0.1, 0.5, 2.0] {
        for axis in 0..3 {
            for sign in [-1.0, 1.0] {
                let mut w = Vector3::zeros();
                w[axis] = sign * scale * typical;
                starts.push(w);
            }
        }
    }
    let mut minima: Vec<ShiftMinimum> = Vec::new();
    for w in starts {
        let r = levenberg_marquardt(v0, crosses, &[w.x, w.y, w.z]);
        let w = Vector3::new(r.theta[0], r.theta[1], r.theta[2]);
        if !(r.cost.is_finite() && w.iter().all(|x| x.is_finite())) {
            continue;
        }
        match minima
            .iter_mut()
            .find(|m| (m.w - w).norm() <= 1e-4 * typical)
        {
            Some(m) if r.cost < m.cost => *m = ShiftMinimum { w, cost: r.cost },
            Some(_) => {}
            None => minima.push(ShiftMinimum { w, cost: r.cost }),
        }
    }
    minima.sort_by(|a, b| a.cost.total_cmp(&b.cost));
    minima
}

/// Linear starts for `w` with `λ = 1` (see the module docs).
fn linear_starts(v0: &[Vector3<f64>], crosses: &[(usize, usize)]) -> Vec<Vector3<f64>> {
    let m = crosses.len() as f64;
    let pq: Vec<(f64, Vector3<f64>)> = crosses
        .iter()
        .map(|&(i, j)| (v0[i].dot(&v0[j]), v0[i] + v0[j]))
        .collect();
    let pbar = pq.iter().map(|x| x.0).sum::<f64>() / m;
    let qbar = pq.iter().map(|x| x.1).sum::<Vector3<f64>>() / m;
    let mut a = Matrix3::zeros();
    let mut b = Vector3::zeros();
    for (p, q) in &pq {
        let dq = q - qbar;
        a += dq * dq.transpose();
        b -= dq * (p - pbar);
    }
    let eig = SymmetricEigen::new(a);
    let (mut kmin, mut kmax) = (0, 0);
    for k in 1..3 {
        if eig.eigenvalues[k] < eig.eigenvalues[kmin] {
            kmin = k;
        }
        if eig.eigenvalues[k] > eig.eigenvalues[kmax] {
            kmax = k;
        }
    }
    let top = eig.eigenvalues[kmax];
    if top <= 0.0 {
        return Vec::new();
    }
    let mut starts = Vec::new();
    // Full solution and the one restricted to the well-determined directions.
    let mut w_full = Vector3::zeros();
    let mut w_restricted = Vector3::zeros();
    for k in 0..3 {
        let e = eig.eigenvectors.column(k).into_owned();
        let l = eig.eigenvalues[k];
        if l > 1e-14 * top {
            w_full += e * (e.dot(&b) / l);
            if k != kmin {
                w_restricted += e * (e.dot(&b) / l);
            }
        }
    }
    starts.push(w_full);
    // Along the weakest direction, the mean quadratic equation gives two candidates.
    let e = eig.eigenvectors.column(kmin).into_owned();
    let qa = m;
    let qb: f64 = pq.iter().map(|(_, q)| q.dot(&e)).sum::<f64>() + 2.0 * m * w_restricted.dot(&e);
    let qc: f64 = pq
        .iter()
        .map(|(p, q)| p + q.dot(&w_restricted))
        .sum::<f64>()
        + m * w_restricted.norm_squared();
    let disc = qb * qb - 4.0 * qa * qc;
    if disc >= 0.0 {
        for sgn in [-1.0, 1.0] {
            starts.push(w_restricted + e * ((-qb + sgn * disc.sqrt()) / (2.0 * qa)));
        }
    } else {
        starts.push(w_restricted + e * (-qb / (2.0 * qa)));
    }
    starts
}

/// Linear start for `(w, λ)` from the 5-unknown system of the module docs.
fn linear_start_focal(v0: &[Vector3<f64>], crosses: &[(usize, usize)]) -> Option<[f64; 4]> {
    let m = crosses.len();
    if m < 5 {
        return None;
    }
    let mut a = DMatrix::zeros(m, 5);
    let mut b = DVector::zeros(m);
    for (k, &(i, j)) in crosses.iter().enumerate() {
        let (x, y) = (v0[i], v0[j]);
        let row = [x.x * y.x + x.y * y.y, x.x + y.x, x.y + y.y, x.z + y.z, 1.0];
        let scale = (row.iter().map(|r| r * r).sum::<f64>() + (x.z * y.z).powi(2)).sqrt();
        for c in 0..5 {
            a[(k, c)] = row[c] / scale;
        }
        b[k] = -x.z * y.z / scale;
    }
    let xi = a.svd(true, true).solve(&b, 1e-12).ok()?;
    let mu = xi[0];
    if mu.is_nan() || mu <= 0.0 {
        return None;
    }
    Some([xi[1] / mu, xi[2] / mu, xi[3], mu.sqrt()])
}

/// Fits `w` (and `λ` when `estimate_focal`) to the orthogonality of `crosses` (pairs of
/// local indices into `v0`). A cross whose cosine residual exceeds `outlier_k` robust
/// standard deviations (`1.4826 · median |r|`, at least `noise_floor`) is dropped and
/// the fit repeated, so one wrong plane cannot bend the gauge; the dropped crosses are
/// returned as indices into `crosses`.
pub fn solve_orthogonality(
    v0: &[Vector3<f64>],
    crosses: &[(usize, usize)],
    estimate_focal: bool,
    outlier_k: f64,
    noise_floor: f64,
) -> Result<(Orthogonality, Vec<usize>), SolveError> {
    let mut kept: Vec<usize> = (0..crosses.len()).collect();
    for _ in 0..4 {
        let sub: Vec<(usize, usize)> = kept.iter().map(|&c| crosses[c]).collect();
        let fit = fit_orthogonality(v0, &sub, estimate_focal)?;
        let mut theta = vec![fit.w.x, fit.w.y, fit.w.z];
        if estimate_focal {
            theta.push(fit.focal_scale);
        }
        let r = residuals_and_jacobian(v0, &sub, &theta, None);
        let mut abs: Vec<f64> = r.iter().map(|x| x.abs()).collect();
        let mid = abs.len() / 2;
        let med = *abs.select_nth_unstable_by(mid, f64::total_cmp).1;
        let thr = outlier_k * (1.4826 * med).max(noise_floor);
        let next: Vec<usize> = kept
            .iter()
            .zip(r.iter())
            .filter(|(_, x)| x.abs() <= thr)
            .map(|(c, _)| *c)
            .collect();
        let p = if estimate_focal { 4 } else { 3 };
        if next.len() == kept.len() || next.len() < p + 1 {
            let dropped = (0..crosses.len()).filter(|c| !kept.contains(c)).collect();
            return Ok((fit, dropped));
        }
        kept = next;
    }
    let sub: Vec<(usize, usize)> = kept.iter().map(|&c| crosses[c]).collect();
    let fit = fit_orthogonality(v0, &sub, estimate_focal)?;
    let dropped = (0..crosses.len()).filter(|c| !kept.contains(c)).collect();
    Ok((fit, dropped))
}

/// One least-squares fit of the orthogonality (see [`solve_orthogonality`]).
pub fn fit_orthogonality(
    v0: &[Vector3<f64>],
    crosses: &[(usize, usize)],
    estimate_focal: bool,
) -> Result<Orthogonality, SolveError> {
    let p = if estimate_focal { 4 } else { 3 };
    if crosses.len() < p + 1 {
        return Err(SolveError::TooFewCrosses {
            found: crosses.len(),
            needed: p + 1,
        });
    }
    let mut best: Option<LmResult> = None;
    let mut consider = |res: LmResult| {
        if res.cost.is_finite() && best.as_ref().is_none_or(|b| res.cost < b.cost) {
            best = Some(res);
        }
    };
    for w in linear_starts(v0, crosses) {
        let r3 = levenberg_marquardt(v0, crosses, &[w.x, w.y, w.z]);
        if estimate_focal {
            let t = &r3.theta;
            consider(levenberg_marquardt(v0, crosses, &[t[0], t[1], t[2], 1.0]));
        } else {
            consider(r3);
        }
    }
    if estimate_focal {
        if let Some(s) = linear_start_focal(v0, crosses) {
            consider(levenberg_marquardt(v0, crosses, &s));
        }
    }
    let best = best.ok_or(SolveError::Degenerate("no start for the orthogonality fit"))?;
    let m = crosses.len();
    let sigma2 = best.cost / (m - p) as f64;
    let (focal_scale, focal_scale_std) = if estimate_focal {
        let std = best
            .jtj
            .clone()
            .try_inverse()
            .map(|inv| (sigma2 * inv[(3, 3)]).max(0.0).sqrt());
        (best.theta[3].abs(), std)
    } else {
        (1.0, None)
    };
    let rms_rad = (best.cost / m as f64).sqrt().min(1.0).asin();
    Ok(Orthogonality {
        w: Vector3::new(best.theta[0], best.theta[1], best.theta[2]),
        focal_scale,
        focal_scale_std,
        rms_rad,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::solve::synthetic::{random_scan, ScanSpec};

    fn centred_truth(planes: &[Vector3<f64>], scale: f64) -> (Vec<Vector3<f64>>, Vector3<f64>) {
        let mean = planes.iter().sum::<Vector3<f64>>() / planes.len() as f64;
        (
            planes.iter().map(|p| (p - mean) * scale).collect(),
            mean * scale,
        )
    }

    #[test]
    fn orthogonality_recovers_the_shift_exactly() {
        let scan = random_scan(&ScanSpec {
            num_crosses: 20,
            seed: 11,
            ..ScanSpec::default()
        });
        for scale in [0.37, -2.5] {
            let (v0, w_true) = centred_truth(&scan.planes, scale);
            let crosses: Vec<(usize, usize)> = (0..20).map(|k| (2 * k, 2 * k + 1)).collect();
            let (o, _) = solve_orthogonality(&v0, &crosses, false, 4.0, 1e-9).expect("solvable");
            assert!(
                (o.w - w_true).norm() < 1e-9 * w_true.norm(),
                "{} vs {}",
                o.w,
                w_true
            );
            assert!(o.rms_rad < 1e-9);
        }
    }

    #[test]
    fn focal_scale_is_recovered_with_its_uncertainty() {
        let scan = random_scan(&ScanSpec {
            num_crosses: 20,
            seed: 12,
            ..ScanSpec::default()
        });
        let lambda = 1.33;
        // Planes in the coordinates of a focal length 1/λ times the true one.
        let given: Vec<Vector3<f64>> = scan
            .planes
            .iter()
            .map(|v| Vector3::new(v.x / lambda, v.y / lambda, v.z))
            .collect();
        let (v0, w_true) = centred_truth(&given, 0.8);
        let crosses: Vec<(usize, usize)> = (0..20).map(|k| (2 * k, 2 * k + 1)).collect();
        let (o, _) = solve_orthogonality(&v0, &crosses, true, 4.0, 1e-9).expect("solvable");
        assert!(
            (o.focal_scale - lambda).abs() < 1e-8,
            "λ = {}",
            o.focal_scale
        );
        assert!((o.w - w_true).norm() < 1e-8 * w_true.norm());
        assert!(o.focal_scale_std.is_some_and(|s| s < 1e-6));
        // Without estimating it, the crosses are visibly not orthogonal.
        let o1 = fit_orthogonality(&v0, &crosses, false).expect("solvable");
        assert!(o1.rms_rad > 1e-3);
    }

    #[test]
    fn too_few_crosses_is_an_error() {
        let v0 = vec![Vector3::x(), Vector3::y(), Vector3::z(), -Vector3::x()];
        assert!(matches!(
            solve_orthogonality(&v0, &[(0, 1), (2, 3)], false, 4.0, 1e-9),
            Err(SolveError::TooFewCrosses { .. })
        ));
    }
}
