//! The joint estimator's dense Cholesky factorisation, solve and inverse, on as many
//! threads as the caller can spare.
//!
//! Owns only the linear algebra. The binary runs faer's kernels on one thread
//! (`faer::set_global_parallelism(Seq)`): on the small systems of the starts (100-500
//! unknowns) waking threads costs more than it saves. The anchors' joint system has up
//! to 1,800 unknowns, and once the extraction is done (`reconstruct`, the daemon's final
//! solve) the other cores are idle; there the factorisation and the inverse take
//! [`DenseThreads`] threads. faer splits the work into tiles, each summed in the same
//! order whatever the thread count, so the answer does not depend on it (the test below
//! holds that bit for bit).

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::llt;
use faer::{Mat, Par};

/// Threads for the dense factorisations: 1 where other work needs the cores (the
/// daemon's epochs, beside the extraction workers).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DenseThreads(pub usize);

impl Default for DenseThreads {
    fn default() -> Self {
        Self(1)
    }
}

/// Systems smaller than this are factored on one thread whatever [`DenseThreads`] says:
/// below it, faer's parallel kernels were slower than its sequential ones (measured on
/// the 2-core machine: 600 unknowns 5.6 ms on one thread, 13 ms on two).
const PARALLEL_MIN_DIM: usize = 1000;

impl DenseThreads {
    fn par(self, n: usize) -> Par {
        if self.0 > 1 && n >= PARALLEL_MIN_DIM {
            Par::rayon(self.0)
        } else {
            Par::Seq
        }
    }
}

/// The Cholesky factor `L` of a symmetric positive definite matrix.
pub(super) struct Cholesky {
    l: Mat<f64>,
    par: Par,
}

impl Cholesky {
    /// Factors `a + damping · diag(a)`, reading only `a`'s lower triangle; `None` where it
    /// is not positive definite.
    pub(super) fn of_lower(a: &Mat<f64>, damping: f64, threads: DenseThreads) -> Option<Self> {
        Self::of_lower_with(a, |d| d + damping * d, threads)
    }

    /// Factors `a + shift · I`, reading only `a`'s lower triangle.
    pub(super) fn of_lower_shifted(
        a: &Mat<f64>,
        shift: f64,
        threads: DenseThreads,
    ) -> Option<Self> {
        Self::of_lower_with(a, |d| d + shift, threads)
    }

    /// [`Self::of_lower`] in `storage`'s matrix where it has `a`'s size, which it takes
    /// (a factor's [`Self::into_storage`] gives it back). The joint estimate factors a
    /// system of up to ~1,800 unknowns (26 MB) at every damped step; a new matrix of
    /// that size is fresh pages from the kernel, each faulted in and zeroed (9 % of the
    /// 1,800-frame dive's solve samples, with the normal equations' own).
    pub(super) fn of_lower_in(
        a: &Mat<f64>,
        damping: f64,
        threads: DenseThreads,
        storage: &mut Option<Mat<f64>>,
    ) -> Option<Self> {
        let l = storage
            .take()
            .filter(|l| l.nrows() == a.nrows() && l.ncols() == a.ncols());
        Self::of_lower_with_storage(a, |d| d + damping * d, threads, l)
    }

    /// The factor's matrix, for [`Self::of_lower_in`] to reuse.
    pub(super) fn into_storage(self) -> Mat<f64> {
        self.l
    }

    /// Factors `a` with each diagonal entry `d` replaced by `diagonal(d)`.
    fn of_lower_with(
        a: &Mat<f64>,
        diagonal: impl Fn(f64) -> f64,
        threads: DenseThreads,
    ) -> Option<Self> {
        Self::of_lower_with_storage(a, diagonal, threads, None)
    }

    /// [`Self::of_lower_with`] in `l` (`a`'s size) if given, else in a new matrix. Its
    /// strictly upper triangle is zeroed, whatever it held: the factor is `L` alone.
    fn of_lower_with_storage(
        a: &Mat<f64>,
        diagonal: impl Fn(f64) -> f64,
        threads: DenseThreads,
        l: Option<Mat<f64>>,
    ) -> Option<Self> {
        let n = a.nrows();
        let par = threads.par(n);
        let mut l = l.unwrap_or_else(|| Mat::<f64>::zeros(n, n));
        for j in 0..n {
            let (col, from) = (l.col_as_slice_mut(j), a.col_as_slice(j));
            col[..j].fill(0.0);
            col[j..].copy_from_slice(&from[j..]);
            col[j] = diagonal(from[j]);
        }
        let mut mem = MemBuffer::new(llt::factor::cholesky_in_place_scratch::<f64>(
            n,
            par,
            Default::default(),
        ));
        llt::factor::cholesky_in_place(
            l.as_mut(),
            Default::default(),
            par,
            MemStack::new(&mut mem),
            Default::default(),
        )
        .ok()?;
        Some(Self { l, par })
    }

    /// `A⁻¹ b`.
    pub(super) fn solve(&self, b: &[f64]) -> Vec<f64> {
        let n = self.l.nrows();
        let mut x = Mat::<f64>::from_fn(n, 1, |i, _| b[i]);
        // On one thread: the two triangular solves are O(n²), and faer's parallel ones
        // sum in another order (the answer would depend on the thread count).
        let mut mem = MemBuffer::new(llt::solve::solve_in_place_scratch::<f64>(n, 1, Par::Seq));
        llt::solve::solve_in_place(
            self.l.as_ref(),
            x.as_mut(),
            Par::Seq,
            MemStack::new(&mut mem),
        );
        (0..n).map(|i| x[(i, 0)]).collect()
    }

    /// `A⁻¹ X` in place, for every column of `x` (on one thread, as [`Self::solve`]).
    pub(super) fn solve_columns(&self, x: faer::MatMut<'_, f64>) {
        let (n, k) = (self.l.nrows(), x.ncols());
        let mut mem = MemBuffer::new(llt::solve::solve_in_place_scratch::<f64>(n, k, Par::Seq));
        llt::solve::solve_in_place(self.l.as_ref(), x, Par::Seq, MemStack::new(&mut mem));
    }

    /// `L⁻¹ X` in place, `A = L Lᵀ` (on one thread, as [`Self::solve`]).
    pub(super) fn solve_lower_columns(&self, x: faer::MatMut<'_, f64>) {
        faer::linalg::triangular_solve::solve_lower_triangular_in_place(
            self.l.as_ref(),
            x,
            Par::Seq,
        );
    }

    /// `L⁻ᵀ X` in place (on one thread, as [`Self::solve`]).
    pub(super) fn solve_upper_columns(&self, x: faer::MatMut<'_, f64>) {
        faer::linalg::triangular_solve::solve_upper_triangular_in_place(
            self.l.transpose(),
            x,
            Par::Seq,
        );
    }

    /// `A⁻¹`, both triangles.
    pub(super) fn inverse(&self) -> Mat<f64> {
        let n = self.l.nrows();
        let mut out = Mat::<f64>::zeros(n, n);
        let mut mem = MemBuffer::new(llt::inverse::inverse_scratch::<f64>(n, self.par));
        llt::inverse::inverse(
            out.as_mut(),
            self.l.as_ref(),
            self.par,
            MemStack::new(&mut mem),
        );
        for j in 0..n {
            for i in 0..j {
                out[(i, j)] = out[(j, i)];
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A well-conditioned random symmetric positive definite matrix of size `n`, with
    /// garbage in its upper triangle (which must not be read).
    fn spd(n: usize) -> Mat<f64> {
        let a = Mat::<f64>::from_fn(n, n, |i, j| {
            ((i * 7919 + j * 104_729) % 1009) as f64 / 1009.0 - 0.5
        });
        let mut h = &a * a.transpose();
        for i in 0..n {
            h[(i, i)] += n as f64 * 0.1;
            for j in i + 1..n {
                h[(i, j)] = f64::NAN;
            }
        }
        h
    }

    #[test]
    fn solve_and_inverse_agree_with_the_matrix() {
        let n = 40;
        let h = spd(n);
        let full = Mat::<f64>::from_fn(n, n, |i, j| h[(i.max(j), i.min(j))]);
        let c = Cholesky::of_lower(&h, 0.0, DenseThreads(1)).expect("factors");
        let b: Vec<f64> = (0..n).map(|i| (i as f64).sin()).collect();
        let x = c.solve(&b);
        for i in 0..n {
            let row: f64 = (0..n).map(|j| full[(i, j)] * x[j]).sum();
            assert!((row - b[i]).abs() < 1e-10, "row {i}: {row} vs {}", b[i]);
        }
        let inv = c.inverse();
        let eye = &full * &inv;
        for i in 0..n {
            for j in 0..n {
                let want = if i == j { 1.0 } else { 0.0 };
                assert!(
                    (eye[(i, j)] - want).abs() < 1e-10,
                    "({i}, {j}): {}",
                    eye[(i, j)]
                );
            }
        }
    }

    #[test]
    fn the_two_triangular_solves_compose_to_the_inverse() {
        let n = 30;
        let h = spd(n);
        let c = Cholesky::of_lower(&h, 0.0, DenseThreads(1)).expect("factors");
        // L⁻ᵀ L⁻¹ = A⁻¹.
        let mut x = Mat::<f64>::identity(n, n);
        c.solve_lower_columns(x.as_mut());
        c.solve_upper_columns(x.as_mut());
        let inv = c.inverse();
        for i in 0..n {
            for j in 0..n {
                assert!((x[(i, j)] - inv[(i, j)]).abs() < 1e-9 * (1.0 + inv[(i, j)].abs()));
            }
        }
    }

    #[test]
    fn damping_scales_the_diagonal() {
        let n = 10;
        let h = spd(n);
        let damped = Cholesky::of_lower(&h, 0.5, DenseThreads(1)).expect("factors");
        let mut h2 = h.clone();
        for i in 0..n {
            h2[(i, i)] *= 1.5;
        }
        let plain = Cholesky::of_lower(&h2, 0.0, DenseThreads(1)).expect("factors");
        let b = vec![1.0; n];
        assert_eq!(damped.solve(&b), plain.solve(&b));
    }

    /// A factor made in a reused matrix (here another system's factor, its upper
    /// triangle filled with garbage) is the fresh one to the bit, and a matrix of the
    /// wrong size is not taken.
    #[test]
    fn a_reused_matrix_gives_the_fresh_factor() {
        let n = 60;
        let h = spd(n);
        let fresh = Cholesky::of_lower(&h, 0.25, DenseThreads(1)).expect("factors");
        let mut other = spd(n);
        for i in 0..n {
            other[(i, i)] *= 3.0;
        }
        let mut old = Cholesky::of_lower(&other, 0.0, DenseThreads(1))
            .expect("factors")
            .into_storage();
        for j in 0..n {
            for i in 0..j {
                old[(i, j)] = 1e6 + (i * j) as f64;
            }
        }
        let mut storage = Some(old);
        let reused =
            Cholesky::of_lower_in(&h, 0.25, DenseThreads(1), &mut storage).expect("factors");
        assert!(storage.is_none(), "the storage is taken");
        let same = |a: &Mat<f64>, b: &Mat<f64>| {
            (0..n).all(|j| (0..n).all(|i| a[(i, j)].to_bits() == b[(i, j)].to_bits()))
        };
        assert!(same(&fresh.inverse(), &reused.inverse()));
        let b: Vec<f64> = (0..n).map(|i| (i as f64).cos()).collect();
        assert_eq!(fresh.solve(&b), reused.solve(&b));
        assert!(same(&fresh.into_storage(), &reused.into_storage()));
        let mut small = Some(Mat::<f64>::zeros(n - 1, n - 1));
        let c = Cholesky::of_lower_in(&h, 0.25, DenseThreads(1), &mut small).expect("factors");
        assert_eq!(c.into_storage().nrows(), n);
    }

    /// The answer does not depend on the number of threads, to the bit, at a size that
    /// runs in parallel.
    #[test]
    fn two_threads_give_the_same_bits_as_one() {
        let n = PARALLEL_MIN_DIM + 37;
        let h = spd(n);
        let b: Vec<f64> = (0..n).map(|i| (i as f64 * 0.1).cos()).collect();
        let one = Cholesky::of_lower(&h, 1e-3, DenseThreads(1)).expect("factors");
        let two = Cholesky::of_lower(&h, 1e-3, DenseThreads(2)).expect("factors");
        assert_eq!(two.par, Par::rayon(2));
        assert_eq!(one.solve(&b), two.solve(&b));
        let (a, b) = (one.inverse(), two.inverse());
        assert!((0..n).all(|j| (0..n).all(|i| a[(i, j)].to_bits() == b[(i, j)].to_bits())));
    }
}
