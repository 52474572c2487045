//! Planes of curves outside the global subset, from their crossings with solved curves.
//!
//! A crossing of the unknown curve with a solved curve `j` at `u` gives
//! `v · u = v_j · u = 1 / Z_j`, one linear equation in `v`. Rows are weighted first by
//! `1 / (v_j · u)²` (relative depth), then by `1 / |(v − v_j)_{xy}|²` from the previous
//! fit, so the residual is the Sampson image distance as in the global solve, divided by
//! its noise `σ_img`. A solved partner `p` adds the soft orthogonality row
//! `v · D² v_p / (|D v_p|²) = 0` (`D = diag(λ, λ, 1)`, the planes being nearly of equal
//! norm), divided by the orthogonality noise `σ_ortho` (radians). At least three
//! equations are needed and the 3×3 normal matrix must be well conditioned (crossings
//! all on one image line leave the plane free to turn about the 3D line through them).
//! Crossings whose Sampson residual exceeds `k σ_img` are dropped and the plane refit.

use super::nullspace::sampson;
use crate::intersect::Crossing;
use nalgebra::{Matrix3, Vector3};

/// What a plane fit needs to know besides the crossings.
#[derive(Clone, Copy, Debug)]
pub struct FitContext {
    pub focal_scale: f64,
    /// Noise of the Sampson residual (normalised image units).
    pub sigma_img: f64,
    /// Noise of the orthogonality of a cross (radians).
    pub sigma_ortho: f64,
    /// Outlier threshold in units of `sigma_img`.
    pub outlier_k: f64,
    pub min_crossings: usize,
    /// Without a solved partner, the inlier crossings must be off one image line by
    /// this much ([`super::subset::bend`]).
    pub min_bend: f64,
    /// Least spread of a minimal sample of the consensus start: the smallest singular
    /// value of its unit rows (about the smallest height of the triangle of the rays,
    /// normalised units). Crossings nearly on one image line give a plane turned at
    /// random about their 3D line, which agrees with every crossing on that line and
    /// would win the vote with a wild norm. Zero takes every sample.
    pub min_sample_spread: f64,
    /// A refined plane whose fit leaves the relative depth at one of its crossings
    /// more uncertain than this many times the median of the refined planes (one
    /// standard deviation, from the fit's covariance) is dropped
    /// ([`super::SolveParams::uncertain_plane_ratio`]); infinity keeps all.
    pub max_depth_sigma: f64,
    /// Crossings of two curves at an angle whose sine is below this are left out
    /// ([`super::SolveParams::min_sin_angle`]): their position along the curves is
    /// poorly fixed.
    pub min_sin_angle: f64,
    /// Whether a consensus start may weigh its draws on two threads (where the caller
    /// spares the cores: [`super::SolveParams::dense_threads`] above one). The answer
    /// does not depend on it.
    pub parallel: bool,
}

#[cfg(test)]
impl FitContext {
    /// A context for tests: focal scale 1, the given noises, and otherwise what the
    /// solve uses (4σ outliers, three crossings, a bend of 1e-3, no sample spread or
    /// depth limit, crossings down to a sine of 0.1).
    pub(crate) fn for_tests(sigma_img: f64, sigma_ortho: f64) -> Self {
        Self {
            focal_scale: 1.0,
            sigma_img,
            sigma_ortho,
            outlier_k: 4.0,
            min_crossings: 3,
            min_bend: 1e-3,
            min_sample_spread: 0.0,
            max_depth_sigma: f64::INFINITY,
            min_sin_angle: 0.1,
            parallel: false,
        }
    }
}

impl PlaneFit {
    /// One standard deviation of the relative depth `δZ / Z` on the plane at the image
    /// point `u` (normalised), from [`Self::covariance`]: `√(uᵀ Σ u) / |v · u|`.
    pub fn depth_sigma(&self, u: [f64; 2]) -> f64 {
        let u = Vector3::new(u[0], u[1], 1.0);
        match self.covariance {
            Some(cov) => u.dot(&(cov * u)).max(0.0).sqrt() / self.plane.dot(&u).abs(),
            None => f64::INFINITY,
        }
    }
}

/// A fitted plane and the crossings judged outliers.
#[derive(Clone, Debug)]
pub struct PlaneFit {
    pub plane: Vector3<f64>,
    /// Covariance of `plane` from the last fit's normal matrix (rows in units of
    /// their noise), as if the other curves' planes were exact.
    pub covariance: Option<Matrix3<f64>>,
    pub inliers: usize,
    pub outliers: Vec<usize>,
}

/// Fits the plane of one curve from `(crossing index, solved plane of the other curve)`
/// and the solved partner plane, if any. `None` when under-determined.
pub fn fit_plane(
    crossings: &[Crossing],
    known: &[(usize, Vector3<f64>)],
    partner: Option<Vector3<f64>>,
    ctx: &FitContext,
    initial: Option<Vector3<f64>>,
) -> Option<PlaneFit> {
    let mut plane =
        initial.or_else(|| super::consensus::consensus_start(crossings, known, partner, ctx));
    let mut information = Matrix3::zeros();
    let mut inlier: Vec<bool> = match plane {
        Some(v) => known
            .iter()
            .map(|(k, vj)| {
                sampson(&v, vj, crossings[*k].u)
                    .is_some_and(|(e, _)| e.abs() <= ctx.outlier_k * ctx.sigma_img)
            })
            .collect(),
        None => vec![true; known.len()],
    };
    if inlier.iter().filter(|&&x| x).count() < 3 {
        inlier.fill(true);
    }
    let d2 = {
        let l2 = ctx.focal_scale * ctx.focal_scale;
        Vector3::new(l2, l2, 1.0)
    };
    for round in 0..4 {
        let mut a = Matrix3::zeros();
        let mut b = Vector3::zeros();
        let mut rows = 0usize;
        for ((k, vj), &ok) in known.iter().zip(&inlier) {
            if !ok {
                continue;
            }
            let c = &crossings[*k];
            let u = Vector3::new(c.u[0], c.u[1], 1.0);
            let depth_inv = vj.dot(&u);
            let w = match plane.and_then(|v| sampson(&v, vj, c.u)) {
                Some((_, inv_g)) => inv_g * inv_g,
                None if depth_inv.abs() > 0.0 => 1.0 / (depth_inv * depth_inv),
                None => continue,
            } / (ctx.sigma_img * ctx.sigma_img);
            a += u * u.transpose() * w;
            b += u * (depth_inv * w);
            rows += 1;
        }
        if let Some(vp) = partner {
            let n = vp.component_mul(&d2);
            let scale = vp
                .component_mul(&Vector3::new(ctx.focal_scale, ctx.focal_scale, 1.0))
                .norm_squared();
            if scale > 0.0 {
                let row = n / scale;
                a += row * row.transpose() / (ctx.sigma_ortho * ctx.sigma_ortho);
                rows += 1;
            }
        }
        if rows < 3 || rows.saturating_sub(usize::from(partner.is_some())) < 2 {
            return None;
        }
        let (lo, hi) = a
            .symmetric_eigenvalues()
            .iter()
            .fold((f64::INFINITY, 0.0f64), |(lo, hi), &l| {
                (lo.min(l), hi.max(l))
            });
        if lo.is_nan() || lo <= 1e-10 * hi {
            return None;
        }
        let v = a.cholesky()?.solve(&b);
        plane = Some(v);
        information = a;
        // Outliers judged with the current plane; stop when the set is stable.
        let mut changed = false;
        for ((k, vj), ok) in known.iter().zip(inlier.iter_mut()) {
            let e = sampson(&v, vj, crossings[*k].u).map_or(f64::INFINITY, |(e, _)| e.abs());
            let now = e <= ctx.outlier_k * ctx.sigma_img;
            changed |= now != *ok;
            *ok = now;
        }
        if !changed && round > 0 {
            break;
        }
    }
    let plane = plane?;
    let inliers = inlier.iter().filter(|&&x| x).count();
    if inliers < ctx.min_crossings.clamp(2, 3) {
        return None;
    }
    if partner.is_none() {
        let points = known
            .iter()
            .zip(&inlier)
            .filter(|(_, &ok)| ok)
            .map(|((k, _), _)| crossings[*k].u);
        if super::subset::bend(points) < ctx.min_bend {
            return None;
        }
    }
    Some(PlaneFit {
        plane,
        covariance: information.try_inverse(),
        inliers,
        outliers: known
            .iter()
            .zip(&inlier)
            .filter(|(_, &ok)| !ok)
            .map(|((k, _), _)| *k)
            .collect(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::solve::synthetic::{analytic_crossings, random_scan, ScanSpec};

    #[test]
    fn a_plane_is_recovered_from_crossings_with_known_planes() {
        let scan = random_scan(&ScanSpec {
            num_crosses: 12,
            seed: 21,
            ..ScanSpec::default()
        });
        let cr = analytic_crossings(&scan.scene, &scan.planes, 0.05);
        let target = 0u32;
        let known: Vec<(usize, Vector3<f64>)> = cr
            .iter()
            .enumerate()
            .filter(|(_, c)| c.a == target && c.b != 1)
            .map(|(k, c)| (k, scan.planes[c.b as usize]))
            .collect();
        assert!(known.len() >= 3);
        let ctx = FitContext {
            min_sample_spread: 4e-9,
            ..FitContext::for_tests(1e-9, 1e-9)
        };
        let fit = fit_plane(&cr, &known, Some(scan.planes[1]), &ctx, None).expect("fit");
        let truth = scan.planes[0];
        assert!(
            (fit.plane - truth).norm() < 1e-9 * truth.norm(),
            "{} vs {}",
            fit.plane,
            truth
        );
        assert!(fit.outliers.is_empty());
        // Two crossings on one facet leave the plane free without its partner.
        assert!(fit_plane(&cr, &known[..2], None, &ctx, None).is_none());
    }

    #[test]
    fn crossings_on_one_image_line_and_a_solved_partner_fix_the_plane() {
        // The curve lies on one flat wall: its crossings are on one image line, so only
        // the partner's orthogonality holds the plane's turn about its 3D line.
        let v = Vector3::new(0.3, -0.2, 0.5);
        let wall = Vector3::new(0.05, 0.1, 0.25);
        let line_dir = v.cross(&wall);
        let a_point = {
            // A point on both planes: least-norm solution of [v; wall] X = [1; 1].
            let m = nalgebra::Matrix2x3::from_rows(&[v.transpose(), wall.transpose()]);
            m.transpose()
                * (m * m.transpose()).try_inverse().expect("planes cross")
                * nalgebra::Vector2::new(1.0, 1.0)
        };
        let partner = {
            let p: Vector3<f64> = v.cross(&Vector3::new(1.0, 0.4, -0.3));
            p / p.dot(&(a_point + 4.0 * line_dir))
        };
        assert!(v.dot(&partner).abs() < 1e-12);
        let mut crossings = Vec::new();
        let mut known = Vec::new();
        for k in 0..12 {
            let x = a_point + line_dir * (k as f64 * 0.7 - 3.0);
            assert!(x.z > 0.0);
            let u = x / x.z;
            let uu = Vector3::new(u.x, u.y, 1.0);
            // Some other plane through the same point.
            let tilt = Vector3::new(0.2 * k as f64, 1.0, -0.3).cross(&uu);
            crossings.push(Crossing {
                a: 0,
                b: k + 2,
                // Noise of 1e-5 across the line: collinear triples then give planes
                // turned at random about it.
                u: [u.x, u.y + 1e-5 * ((k * 7 % 5) as f64 - 2.0)],
                sin_angle: 1.0,
            });
            known.push((k as usize, v + tilt));
        }
        assert!(crate::solve::subset::bend(crossings.iter().map(|c| c.u)) < 1e-4);
        let ctx = FitContext {
            min_sample_spread: 4e-5,
            ..FitContext::for_tests(1e-5, 1e-5)
        };
        let fit = fit_plane(&crossings, &known, Some(partner), &ctx, None).expect("fit");
        assert!(
            (fit.plane - v).norm() < 1e-3 * v.norm(),
            "{} vs {v}",
            fit.plane
        );
        // Without the partner the plane is free: no fit.
        assert!(fit_plane(&crossings, &known, None, &ctx, None).is_none());
    }

    /// The fit's depth uncertainty scales with the crossings' noise, and grows from the
    /// middle of the crossings outwards.
    #[test]
    fn depth_uncertainty_follows_the_noise_and_the_spread_of_the_crossings() {
        let scan = random_scan(&ScanSpec {
            num_crosses: 12,
            seed: 21,
            ..ScanSpec::default()
        });
        let cr = analytic_crossings(&scan.scene, &scan.planes, 0.05);
        let known: Vec<(usize, Vector3<f64>)> = cr
            .iter()
            .enumerate()
            .filter(|(_, c)| c.a == 0 && c.b != 1)
            .map(|(k, c)| (k, scan.planes[c.b as usize]))
            .collect();
        assert!(known.len() >= 6, "{} crossings", known.len());
        let ctx = |sigma: f64| FitContext {
            outlier_k: 1e9,
            min_bend: 0.0,
            ..FitContext::for_tests(sigma, 1.0)
        };
        let worst = |fit: &PlaneFit| {
            known
                .iter()
                .map(|(k, _)| fit.depth_sigma(cr[*k].u))
                .fold(0.0f64, f64::max)
        };
        let all = fit_plane(&cr, &known, None, &ctx(1e-4), None).expect("fit");
        let all_noisier = fit_plane(&cr, &known, None, &ctx(2e-4), None).expect("fit");
        assert!(
            (worst(&all_noisier) / worst(&all) - 2.0).abs() < 1e-6,
            "{} vs {}",
            worst(&all_noisier),
            worst(&all)
        );
        // Least at the middle of the crossings, growing beyond them.
        let n = known.len() as f64;
        let mid = known.iter().fold([0.0, 0.0], |m, (k, _)| {
            [m[0] + cr[*k].u[0] / n, m[1] + cr[*k].u[1] / n]
        });
        let far = known
            .iter()
            .map(|(k, _)| cr[*k].u)
            .max_by(|a, b| {
                let d = |u: [f64; 2]| (u[0] - mid[0]).hypot(u[1] - mid[1]);
                d(*a).total_cmp(&d(*b))
            })
            .expect("crossings");
        let beyond = [
            mid[0] + 3.0 * (far[0] - mid[0]),
            mid[1] + 3.0 * (far[1] - mid[1]),
        ];
        assert!(all.depth_sigma(mid) < worst(&all));
        assert!(
            all.depth_sigma(beyond) > 2.0 * worst(&all),
            "{} vs {}",
            all.depth_sigma(beyond),
            worst(&all)
        );
    }
}
