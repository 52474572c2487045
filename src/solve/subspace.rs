//! The smallest eigenpairs of a symmetric positive definite matrix, by subspace
//! iteration on its inverse through one Cholesky factorisation.
//!
//! Owns the iteration and its two stopping rules. Its callers want different things:
//!
//! - the global solve ([`super::nullspace`]) wants the smallest vector, its solution,
//!   and only a rough second value, which tests whether the system has a second
//!   solution ([`Wanted::Smallest`]);
//! - the fixed-centre start ([`super::centre`]) wants the two smallest vectors, for on a
//!   table top the second spans the family of tables that fit the lines
//!   ([`Wanted::SmallestTwo`]).
//!
//! Each step solves `M X = X_old` (one factorisation, reused), orthonormalises `X` and
//! rotates it to the Ritz vectors of `Xᵀ M X`. Vector `j` closes in on its eigenvector
//! at the ratio `λ_j / λ_{k+1}` per step, with `k` vectors. `M` is factored as
//! `M + 10⁻¹² m̄ I` (`m̄` its mean diagonal), so that an exactly singular system still
//! factors; a uniform shift leaves the eigenvectors as they are.

use super::dense::{Cholesky, DenseThreads};

/// Iterations at most; `None` beyond (the caller falls back on a dense eigensolver or
/// gives the direction up).
const MAX_ITERATIONS: usize = 100;

/// What the caller needs of the iteration, which sets its size and its stop.
#[derive(Clone, Copy, Debug)]
pub enum Wanted<'a> {
    /// The smallest vector to an angle of [`VECTOR_TOLERANCE`], and the second value to
    /// [`VALUE_TOLERANCE`], with eight vectors: the second eigenvalue of a coplanarity
    /// system sits in a cluster (on the 600-frame room its next six lie within 1.7× of
    /// it), so with four vectors its value took 17–48 steps to settle, with eight about
    /// four. `start`, the solution of a system close to this one (the previous robust
    /// round's), replaces the first vector's pseudo-random start.
    Smallest { start: Option<&'a [f64]> },
    /// The two smallest vectors, with four vectors, until the second Ritz value has
    /// settled to 1e-9 of itself over one step: the rule the fixed-centre start has
    /// always been judged with. [`Self::Smallest`] would bound the second vector's angle
    /// only by `0.1 λ₂/λ₃`, which is no bound where `λ₂` and `λ₃` are close.
    SmallestTwo,
}

impl Wanted<'_> {
    fn vectors(&self) -> usize {
        match self {
            Self::Smallest { .. } => 8,
            Self::SmallestTwo => 4,
        }
    }
}

/// The smallest vector is taken when its residual bounds its angle to the true one by
/// this (radians; Davis–Kahan: the residual over the gap to the second value).
const VECTOR_TOLERANCE: f64 = 1e-9;
/// The second value is taken when its residual bounds its relative error by this (an
/// eigenvalue lies within a Ritz value's residual of it). The global solve only tests
/// it against `1e-10 ρ`, a threshold orders of magnitude from where it lies.
const VALUE_TOLERANCE: f64 = 0.1;

/// The two smallest eigenvectors of a symmetric positive definite matrix and its
/// smallest eigenvalues (as many as the iteration's vectors), ascending.
pub struct SmallestPairs {
    pub vectors: [Vec<f64>; 2],
    pub values: Vec<f64>,
}

/// The smallest eigenpairs of the symmetric positive definite `mat` (both triangles
/// read), to what `wanted` needs; the factorisation on `threads`. `None` when `mat`
/// does not factor or the iteration does not settle.
pub fn smallest_pairs(
    mat: &faer::Mat<f64>,
    wanted: Wanted<'_>,
    threads: DenseThreads,
) -> Option<SmallestPairs> {
    let (dim, k) = (mat.nrows(), wanted.vectors());
    if dim < 2 * k {
        return None;
    }
    let mean_diagonal = (0..dim).map(|i| mat[(i, i)]).sum::<f64>() / dim as f64;
    let llt = Cholesky::of_lower_shifted(mat, 1e-12 * mean_diagonal, threads)?;
    let mut x = pseudo_random(dim, k);
    if let Wanted::Smallest { start: Some(v) } = wanted {
        if v.len() == dim {
            for (i, &e) in v.iter().enumerate() {
                x[(i, 0)] = e;
            }
        }
    }
    let mut last_l1 = f64::NAN;
    let mut last_r0 = f64::INFINITY;
    for _ in 0..MAX_ITERATIONS {
        llt.solve_columns(x.as_mut());
        orthonormalise(&mut x)?;
        // Rayleigh–Ritz: the eigenpairs of Xᵀ M X, the vectors rotated to them.
        let mx = mat * &x;
        let h = x.transpose() * &mx;
        let h = nalgebra::DMatrix::<f64>::from_fn(k, k, |i, j| 0.5 * (h[(i, j)] + h[(j, i)]));
        let eig = nalgebra::SymmetricEigen::new(h);
        let mut order: Vec<usize> = (0..k).collect();
        order.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
        let rotation = faer::Mat::<f64>::from_fn(k, k, |i, j| eig.eigenvectors[(i, order[j])]);
        x = &x * &rotation;
        let values: Vec<f64> = order.iter().map(|&o| eig.eigenvalues[o]).collect();
        let (l0, l1) = (values[0], values[1]);
        if !(l0.is_finite() && l1.is_finite()) {
            return None;
        }
        let done = match wanted {
            Wanted::SmallestTwo => (l1 - last_l1).abs() <= 1e-9 * l1.abs(),
            Wanted::Smallest { .. } => {
                let mx = &mx * &rotation;
                let residual = |j: usize| {
                    (0..dim)
                        .map(|i| (mx[(i, j)] - values[j] * x[(i, j)]).powi(2))
                        .sum::<f64>()
                        .sqrt()
                };
                // The first vector is done at the tolerance, or, within a thousand
                // times it, once its residual stops halving: it is then at the level
                // of the rounding in `M x`.
                let (r0, gap) = (residual(0), l1 - l0);
                let first = r0 <= VECTOR_TOLERANCE * gap
                    || (r0 <= 1e3 * VECTOR_TOLERANCE * gap && r0 > 0.5 * last_r0);
                last_r0 = r0;
                first && residual(1) <= VALUE_TOLERANCE * l1
            }
        };
        last_l1 = l1;
        if done {
            let column = |j: usize| (0..dim).map(|i| x[(i, j)]).collect::<Vec<f64>>();
            return Some(SmallestPairs {
                vectors: [column(0), column(1)],
                values: values.iter().map(|v| v.max(0.0)).collect(),
            });
        }
    }
    None
}

/// A start with a component along every eigenvector: fixed pseudo-random entries (the
/// same for every call, so the answer does not depend on what ran before).
fn pseudo_random(dim: usize, k: usize) -> faer::Mat<f64> {
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    faer::Mat::<f64>::from_fn(dim, k, |_, _| {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
    })
}

/// Modified Gram–Schmidt on the columns of `x`; `None` if they are dependent.
fn orthonormalise(x: &mut faer::Mat<f64>) -> Option<()> {
    let (dim, k) = (x.nrows(), x.ncols());
    for j in 0..k {
        for p in 0..j {
            let dot: f64 = (0..dim).map(|i| x[(i, j)] * x[(i, p)]).sum();
            for i in 0..dim {
                let v = x[(i, p)];
                x[(i, j)] -= dot * v;
            }
        }
        let norm = (0..dim).map(|i| x[(i, j)] * x[(i, j)]).sum::<f64>().sqrt();
        if !(norm > 0.0 && norm.is_finite()) {
            return None;
        }
        for i in 0..dim {
            x[(i, j)] /= norm;
        }
    }
    Some(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A symmetric positive definite matrix with the given spectrum, in a pseudo-random
    /// orthonormal basis, and that basis.
    fn with_spectrum(values: &[f64]) -> (faer::Mat<f64>, faer::Mat<f64>) {
        let n = values.len();
        let mut q = pseudo_random(n, n);
        for i in 0..n {
            q[(i, i)] += 1.0;
        }
        orthonormalise(&mut q).expect("independent");
        let d = faer::Mat::<f64>::from_fn(n, n, |i, j| if i == j { values[i] } else { 0.0 });
        (&q * &d * q.transpose(), q)
    }

    /// The sine of the angle between the unit `a` and column `j` of `q`, from the part
    /// of `a` off it (`acos` of the dot product loses half the digits near 0).
    fn angle(a: &[f64], q: &faer::Mat<f64>, j: usize) -> f64 {
        let dot: f64 = a.iter().enumerate().map(|(i, v)| v * q[(i, j)]).sum();
        a.iter()
            .enumerate()
            .map(|(i, v)| (v - dot * q[(i, j)]).powi(2))
            .sum::<f64>()
            .sqrt()
    }

    /// A clustered spectrum, as a coplanarity system's: both rules find the smallest
    /// vector; the two-vector rule also finds the second, and the one-vector rule's
    /// second value is within its tolerance.
    #[test]
    fn both_rules_find_the_smallest_vectors_of_a_clustered_spectrum() {
        let n = 60;
        let values: Vec<f64> = (0..n)
            .map(|i| match i {
                0 => 1e-9,
                1..=8 => 1e-3 * (1.0 + 0.1 * i as f64),
                _ => 1.0 + i as f64,
            })
            .collect();
        let (m, q) = with_spectrum(&values);
        let one =
            smallest_pairs(&m, Wanted::Smallest { start: None }, DenseThreads(1)).expect("settles");
        assert!(angle(&one.vectors[0], &q, 0) < 1e-7);
        assert!((one.values[1] / values[1] - 1.0).abs() <= VALUE_TOLERANCE);
        let two = smallest_pairs(&m, Wanted::SmallestTwo, DenseThreads(1)).expect("settles");
        assert!(angle(&two.vectors[0], &q, 0) < 1e-7);
        assert!(angle(&two.vectors[1], &q, 1) < 1e-4);
        assert!((two.values[1] / values[1] - 1.0).abs() < 1e-6);
    }

    /// A start on the answer is kept, and the iteration stops at once.
    #[test]
    fn a_start_on_the_solution_is_kept() {
        let values: Vec<f64> = (0..30).map(|i| 1e-6 + i as f64).collect();
        let (m, q) = with_spectrum(&values);
        let start: Vec<f64> = (0..30).map(|i| q[(i, 0)]).collect();
        let pairs = smallest_pairs(
            &m,
            Wanted::Smallest {
                start: Some(&start),
            },
            DenseThreads(1),
        )
        .expect("settles");
        assert!(angle(&pairs.vectors[0], &q, 0) < 1e-9);
    }

    #[test]
    fn too_small_or_indefinite_matrices_give_nothing() {
        let (m, _) = with_spectrum(&[1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0]);
        assert!(smallest_pairs(&m, Wanted::SmallestTwo, DenseThreads(1)).is_none());
        let (m, _) = with_spectrum(&[-1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 10.0]);
        assert!(smallest_pairs(&m, Wanted::SmallestTwo, DenseThreads(1)).is_none());
    }
}
