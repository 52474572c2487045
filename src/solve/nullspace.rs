//! The coplanarity system of the global subset and its null space.
//!
//! A crossing `k` of curves `i, j` at `u = (x, y, 1)` gives the row
//! `√ω_k (v_i − v_j) · u = 0`. The normal matrix `N = Σ_k ω_k a_k a_kᵀ` (`3n × 3n`) is
//! built directly from its `3 × 3` blocks: `N_ii += ω uuᵀ`, `N_jj += ω uuᵀ`,
//! `N_ij = N_ji −= ω uuᵀ`. `N` annihilates the three gauge directions
//! `G = [I; I; …; I] / √n` exactly (every row's blocks sum to zero), so
//! `N' = N + ρ G Gᵀ`, with `ρ = trace(N) / 3n` the mean eigenvalue, moves them away
//! from zero. The eigenvector of the smallest eigenvalue of `N'` is then the solution
//! `V0` with `Σ v0_i = 0` and `|V0| = 1`; the true planes are `s V0 + (w, …, w)`. The
//! second smallest eigenvalue measures how well the subset is determined: near zero
//! (relative to `ρ`) the system has a second solution and is rejected.
//!
//! Weights: rows are first normalised by `|u|`; later rounds use
//! `ω_k = 1 / |(v_i − v_j)_{xy}|²` from the previous solution, so that the residual is
//! the Sampson (first-order geometric) distance of the crossing from the image line
//! where the two planes meet, `e_k = (v_i − v_j) · u / |(v_i − v_j)_{xy}|`, in
//! normalised image units. It is invariant to the gauge and to the scale, so it is
//! available before orthogonality fixes them.

use super::dense::DenseThreads;
use super::subspace::{smallest_pairs, Wanted};
use super::SolveError;
use crate::intersect::Crossing;
use nalgebra::{DMatrix, Vector3};

/// Solution of the coplanarity system over a subset.
#[derive(Clone, Debug)]
pub struct NullSpace {
    /// Per local curve, `v0_i`; `Σ v0_i = 0`, `Σ |v0_i|² = 1`.
    pub v0: Vec<Vector3<f64>>,
    /// Smallest eigenvalue of `N'` over `ρ` (zero for exact data).
    pub lambda_min: f64,
    /// Second smallest eigenvalue of `N'` over `ρ`.
    pub lambda_second: f64,
}

fn homog(u: [f64; 2]) -> Vector3<f64> {
    Vector3::new(u[0], u[1], 1.0)
}

/// The normal matrix `N` of the rows of `crossing_ids` with weights `weights` (one per
/// entry of `crossing_ids`), curves mapped to local indices by `local`.
pub fn normal_matrix(
    n: usize,
    local: &[Option<usize>],
    crossings: &[Crossing],
    crossing_ids: &[usize],
    weights: &[f64],
) -> DMatrix<f64> {
    let mut nm = DMatrix::zeros(3 * n, 3 * n);
    for (&k, &w) in crossing_ids.iter().zip(weights) {
        let c = &crossings[k];
        let (Some(i), Some(j)) = (local[c.a as usize], local[c.b as usize]) else {
            continue;
        };
        let u = homog(c.u);
        let m = u * u.transpose() * w;
        for (r, s, sign) in [(i, i, 1.0), (j, j, 1.0), (i, j, -1.0), (j, i, -1.0)] {
            let mut block = nm.fixed_view_mut::<3, 3>(3 * r, 3 * s);
            block += m * sign;
        }
    }
    nm
}

/// Smallest eigenpairs of the gauge-shifted normal matrix `N'`, from a pseudo-random
/// start on one thread ([`null_space_from`]).
pub fn null_space(nm: DMatrix<f64>) -> Result<NullSpace, SolveError> {
    null_space_from(nm, None, DenseThreads::default())
}

/// Smallest eigenpairs of the gauge-shifted normal matrix `N'`.
///
/// Only the smallest vector and the second value are needed, and `N'` is symmetric
/// positive definite, so they come from subspace iteration on `N'⁻¹` through one
/// Cholesky factorisation on `threads` ([`Wanted::Smallest`]): far less than faer's
/// dense self-adjoint eigensolver at 1200 unknowns (0.3 s there, called once per robust
/// round). `start`, the solution of a system close to this one (the previous robust
/// round's), saves the steps its smallest vector would need. Should the factorisation
/// fail or the iteration not settle, the dense eigensolver answers.
pub fn null_space_from(
    mut nm: DMatrix<f64>,
    start: Option<&[Vector3<f64>]>,
    threads: DenseThreads,
) -> Result<NullSpace, SolveError> {
    let dim = nm.nrows();
    let n = dim / 3;
    if n < 2 {
        return Err(SolveError::TooFewPlanes {
            found: n,
            needed: 2,
        });
    }
    let rho = gauge_shift(&mut nm).ok_or(SolveError::Degenerate(
        "empty or non-finite coplanarity system",
    ))?;
    let mat = faer::Mat::<f64>::from_fn(dim, dim, |i, j| nm[(i, j)]);
    let start: Option<Vec<f64>> = start.map(|v| v.iter().flat_map(|p| p.iter().copied()).collect());
    let wanted = Wanted::Smallest {
        start: start.as_deref(),
    };
    let (v0, l0, l1) = match smallest_pairs(&mat, wanted, threads) {
        Some(pairs) => {
            let [v0, _] = pairs.vectors;
            (v0, pairs.values[0], pairs.values[1])
        }
        None => smallest_dense(&mat)?,
    };
    let (l0, l1) = (l0 / rho, l1 / rho);
    if l1 < 1e-10 {
        return Err(SolveError::Degenerate(
            "coplanarity system has more than one solution (collinear crossings or a planar scene)",
        ));
    }
    let v0 = (0..n)
        .map(|i| Vector3::new(v0[3 * i], v0[3 * i + 1], v0[3 * i + 2]))
        .collect();
    Ok(NullSpace {
        v0,
        lambda_min: l0,
        lambda_second: l1,
    })
}

/// `N' = N + ρ G Gᵀ` in place (see the module docs); returns `ρ`, or `None` when `N`
/// is empty or not finite.
fn gauge_shift(nm: &mut DMatrix<f64>) -> Option<f64> {
    let n = nm.nrows() / 3;
    let rho = nm.trace() / nm.nrows() as f64;
    if !(rho > 0.0 && rho.is_finite()) {
        return None;
    }
    let g = rho / n as f64;
    for i in 0..n {
        for j in 0..n {
            for a in 0..3 {
                nm[(3 * i + a, 3 * j + a)] += g;
            }
        }
    }
    Some(rho)
}

/// The same from faer's dense self-adjoint eigensolver.
fn smallest_dense(mat: &faer::Mat<f64>) -> Result<(Vec<f64>, f64, f64), SolveError> {
    let evd = mat
        .self_adjoint_eigen(faer::Side::Lower)
        .map_err(|_| SolveError::Degenerate("eigensolver did not converge"))?;
    let s = evd.S().column_vector();
    let u = evd.U();
    let v0 = (0..mat.nrows()).map(|i| *u.get(i, 0)).collect();
    Ok((v0, *s.get(0), *s.get(1)))
}

/// The square of [`sampson`]'s residual, without its square root (infinite where the
/// planes agree): for loops that only compare residuals with a bound.
pub fn sampson_squared(vi: &Vector3<f64>, vj: &Vector3<f64>, u: [f64; 2]) -> f64 {
    let d = vi - vj;
    let g2 = d.x * d.x + d.y * d.y;
    let r = d.x * u[0] + d.y * u[1] + d.z;
    if g2 > 0.0 && g2.is_finite() {
        r * r / g2
    } else {
        f64::INFINITY
    }
}

/// The Sampson residual `e = (v_i − v_j) · u / |(v_i − v_j)_{xy}|` of a crossing and
/// the inverse of its gradient norm `1 / |(v_i − v_j)_{xy}|`; `None` if the planes agree.
pub fn sampson(vi: &Vector3<f64>, vj: &Vector3<f64>, u: [f64; 2]) -> Option<(f64, f64)> {
    let d = vi - vj;
    let g = d.x.hypot(d.y);
    if g == 0.0 || !g.is_finite() {
        return None;
    }
    Some((d.dot(&homog(u)) / g, 1.0 / g))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::solve::subset::{select_global, SubsetLimits};
    use crate::solve::synthetic::{analytic_crossings, random_scan, ScanSpec, SyntheticScan};

    /// The curves of `scan` with crossings off one line, in one connected set.
    fn connected_subset(scan: &SyntheticScan, cr: &[Crossing]) -> crate::solve::subset::Subset {
        select_global(
            scan.planes.len(),
            cr,
            &vec![true; cr.len()],
            &scan.partner,
            &vec![false; scan.planes.len()],
            &SubsetLimits {
                max_planes: 1000,
                min_crossings: 3,
                min_bend: 1e-3,
            },
        )
    }

    #[test]
    fn normal_matrix_has_a_four_dimensional_null_space_containing_the_truth() {
        let scan = random_scan(&ScanSpec {
            num_crosses: 15,
            seed: 3,
            ..ScanSpec::default()
        });
        let cr = analytic_crossings(&scan.scene, &scan.planes, 0.05);
        // Curves with crossings off one line, in one connected set.
        let sub = connected_subset(&scan, &cr);
        let n = sub.curves.len();
        assert!(n >= 20, "{n} curves");
        let planes: Vec<Vector3<f64>> = sub
            .curves
            .iter()
            .map(|&c| scan.planes[c as usize])
            .collect();
        let ids = sub.crossings.clone();
        let w: Vec<f64> = ids
            .iter()
            .map(|&k| 1.0 / homog(cr[k].u).norm_squared())
            .collect();
        let nm = normal_matrix(n, &sub.local, &cr, &ids, &w);
        let ev = nm.clone().symmetric_eigen();
        let mut vals: Vec<f64> = ev.eigenvalues.iter().copied().collect();
        vals.sort_by(f64::total_cmp);
        let top = vals[vals.len() - 1];
        assert!(
            vals[3] < 1e-12 * top,
            "4th eigenvalue {} of {}",
            vals[3],
            top
        );
        assert!(
            vals[4] > 1e-6 * top,
            "5th eigenvalue {} of {}",
            vals[4],
            top
        );
        // True V and the gauge directions are annihilated.
        let v =
            nalgebra::DVector::from_iterator(3 * n, planes.iter().flat_map(|p| p.iter().copied()));
        assert!((&nm * &v).norm() < 1e-10 * top * v.norm());
        let g = nalgebra::DVector::from_fn(3 * n, |i, _| if i % 3 == 1 { 1.0 } else { 0.0 });
        assert!((&nm * &g).norm() < 1e-10 * top);

        // The gauge-fixed solution is the truth minus its mean, up to scale.
        let ns = null_space(nm).expect("solvable");
        let mean = planes.iter().sum::<Vector3<f64>>() / n as f64;
        let centred: Vec<Vector3<f64>> = planes.iter().map(|p| p - mean).collect();
        let num: f64 = centred.iter().zip(&ns.v0).map(|(a, b)| a.dot(b)).sum();
        let den: f64 = ns.v0.iter().map(|b| b.norm_squared()).sum();
        let s = num / den;
        let worst = centred
            .iter()
            .zip(&ns.v0)
            .map(|(a, b)| (a - b * s).norm())
            .fold(0.0, f64::max);
        let scale = centred.iter().map(|a| a.norm()).fold(0.0, f64::max);
        assert!(worst < 1e-9 * scale, "worst {worst} of {scale}");
        assert!(ns.lambda_min < 1e-12 && ns.lambda_second > 1e-8);
    }

    #[test]
    fn disconnected_subsets_are_reported_as_degenerate() {
        let scan = random_scan(&ScanSpec {
            num_crosses: 6,
            seed: 4,
            ..ScanSpec::default()
        });
        let cr: Vec<Crossing> = analytic_crossings(&scan.scene, &scan.planes, 0.05)
            .into_iter()
            .filter(|c| (c.a < 6) == (c.b < 6))
            .collect();
        let n = scan.planes.len();
        let local: Vec<Option<usize>> = (0..n).map(Some).collect();
        let ids: Vec<usize> = (0..cr.len()).collect();
        let nm = normal_matrix(n, &local, &cr, &ids, &vec![1.0; cr.len()]);
        assert!(matches!(null_space(nm), Err(SolveError::Degenerate(_))));
    }

    /// The subspace iteration gives the dense eigensolver's smallest pair and second
    /// eigenvalue, on exact crossings (a singular system) and on noisy ones.
    #[test]
    fn inverse_iteration_agrees_with_the_dense_eigensolver() {
        let scan = random_scan(&ScanSpec {
            num_crosses: 40,
            seed: 9,
            ..ScanSpec::default()
        });
        for noise in [0.0, 2e-4] {
            let mut cr = analytic_crossings(&scan.scene, &scan.planes, 0.05);
            let mut state = 12345u64;
            for c in &mut cr {
                for x in &mut c.u {
                    state = state.wrapping_mul(6364136223846793005).wrapping_add(1);
                    *x += noise * ((state >> 11) as f64 / (1u64 << 53) as f64 - 0.5);
                }
            }
            let sub = connected_subset(&scan, &cr);
            let n = sub.curves.len();
            let w = vec![1.0; sub.crossings.len()];
            let mut nm = normal_matrix(n, &sub.local, &cr, &sub.crossings, &w);
            let rho = gauge_shift(&mut nm).expect("a system");
            let mat = faer::Mat::<f64>::from_fn(3 * n, 3 * n, |i, j| nm[(i, j)]);
            let it = smallest_pairs(&mat, Wanted::Smallest { start: None }, DenseThreads(1))
                .expect("iteration settles");
            let (v_it, l0_it, l1_it) = (&it.vectors[0], it.values[0], it.values[1]);
            let (v_d, l0_d, l1_d) = smallest_dense(&mat).expect("dense");
            let dot: f64 = v_it.iter().zip(&v_d).map(|(a, b)| a * b).sum();
            assert!(
                1.0 - dot.abs() < 1e-10,
                "noise {noise}: |cos| {}",
                dot.abs()
            );
            // The second value is only wanted to within its tolerance (10 %).
            assert!(
                (l1_it - l1_d).abs() <= 0.1 * l1_d,
                "noise {noise}: {l1_it} vs {l1_d}"
            );
            assert!(
                (l0_it - l0_d.max(0.0)).abs() <= 1e-10 * rho,
                "noise {noise}: {l0_it} vs {l0_d}"
            );
        }
    }
}
