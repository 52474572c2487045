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

use super::nullspace::{sampson, sampson_squared};
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
    let mut plane = initial.or_else(|| consensus_start(crossings, known, partner, ctx));
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

/// Most trials of the consensus start per curve (each of triples and, with a solved
/// partner, of pairs).
const CONSENSUS_TRIALS: usize = 64;

/// Crossings a consensus candidate meets between looks at whether it can still win
/// ([`Consensus::vote`]): long enough for the loop to run without a branch, short next
/// to a curve's hundreds of crossings.
const CONSENSUS_CHUNK: usize = 32;

/// Draws times crossings below which a consensus runs on one thread even where the
/// cores are spared ([`FitContext::parallel`]): about 10 µs of work, where a join
/// costs a few µs.
const PARALLEL_CONSENSUS_WORK: usize = 4096;

/// The plane of a minimal sample, rows `r · v = d` (unit `r` up to scale), if its
/// smallest singular value over unit rows is at least `min_sv`.
fn sample_plane(rows: [(Vector3<f64>, f64); 3], min_sv: f64) -> Option<Vector3<f64>> {
    let unit = rows.map(|(r, d)| {
        let n = r.norm();
        (r / n, d / n)
    });
    let a = Matrix3::from_rows(&[
        unit[0].0.transpose(),
        unit[1].0.transpose(),
        unit[2].0.transpose(),
    ]);
    // Without a spread to demand, a singular sample fails in the solve below.
    if min_sv > 0.0 && !smallest_singular_value_at_least(&a, min_sv) {
        return None;
    }
    let v = a
        .lu()
        .solve(&Vector3::new(unit[0].1, unit[1].1, unit[2].1))?;
    v.iter().all(|x| x.is_finite()).then_some(v)
}

/// Whether the smallest singular value `σ₃` of `a` is at least `s`, as the singular
/// values say, mostly without computing them: `σ₃ = |det a| / (σ₁σ₂)`, and `σ₁σ₂`, the
/// largest singular value of the cofactor matrix, lies between its Frobenius norm
/// `‖C‖` over √3 and `‖C‖`. So `|det a| ≥ s ‖C‖` keeps the sample and `√3 |det a| <
/// s ‖C‖` drops it, in a few dozen flops; only between the two are the singular values
/// computed (an iterative decomposition: 6 % of the solve's time at 5,400 frames, when
/// every sample took it). False with a NaN.
fn smallest_singular_value_at_least(a: &Matrix3<f64>, s: f64) -> bool {
    let (r0, r1, r2) = (a.row(0), a.row(1), a.row(2));
    let cofactors = [r1.cross(&r2), r2.cross(&r0), r0.cross(&r1)];
    let det = r0.dot(&cofactors[0]).abs();
    let c = cofactors
        .iter()
        .map(|c| c.norm_squared())
        .sum::<f64>()
        .sqrt();
    if det >= s * c {
        true
    } else if 3f64.sqrt() * det < s * c {
        false
    } else {
        a.singular_values().min() >= s
    }
}

/// A fixed sequence of `count` distinct index tuples below `m`: all of them when there
/// are at most `CONSENSUS_TRIALS`, else drawn (the same problem always gives the same
/// planes).
pub(crate) fn samples<const K: usize>(m: usize) -> Vec<[usize; K]> {
    let mut out = Vec::new();
    if m < K {
        return out;
    }
    let total: usize = (0..K).map(|i| m - i).product::<usize>() / (1..=K).product::<usize>();
    if total <= CONSENSUS_TRIALS {
        let mut t = [0usize; K];
        fn rec<const K: usize>(
            d: usize,
            from: usize,
            m: usize,
            t: &mut [usize; K],
            out: &mut Vec<[usize; K]>,
        ) {
            if d == K {
                out.push(*t);
                return;
            }
            for i in from..m {
                t[d] = i;
                rec(d + 1, i + 1, m, t, out);
            }
        }
        rec(0, 0, m, &mut t, &mut out);
        return out;
    }
    let mut state = 0x2545_F491_4F6C_DD1Du64 ^ (m as u64) ^ (((K as u64) ^ 3) << 32);
    let mut next = |n: usize| {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state % n as u64) as usize
    };
    let mut tries = 0;
    while out.len() < CONSENSUS_TRIALS && tries < 16 * CONSENSUS_TRIALS {
        tries += 1;
        let mut t = [0usize; K];
        for x in t.iter_mut() {
            *x = next(m);
        }
        if (0..K).all(|i| (i + 1..K).all(|j| t[i] != t[j])) {
            out.push(t);
        }
    }
    out
}

/// The plane of a minimal sample that agrees with the most crossings within `k σ_img`
/// (ties: the smaller truncated squared error). Samples are triples of crossings
/// (`v · u_m = v_j · u_m`) and, with a solved partner, pairs of crossings with the
/// partner's orthogonality `v · D² v_p = 0`, which holds the plane even when all its
/// crossings lie on one image line (a curve on one flat surface). Samples nearly on one
/// image line are skipped ([`FitContext::min_sample_spread`]). A least-squares start would let
/// a wrong crossing turn the plane about its 3D line, which crossings nearly on one
/// image line barely resist. `None` with fewer than four crossings or when no sample
/// is well conditioned.
fn consensus_start(
    crossings: &[Crossing],
    known: &[(usize, Vector3<f64>)],
    partner: Option<Vector3<f64>>,
    ctx: &FitContext,
) -> Option<Vector3<f64>> {
    let m = known.len();
    if m < 4 {
        return None;
    }
    // The rows gathered once, side by side: every candidate meets every one.
    let rows: Vec<([f64; 2], Vector3<f64>)> =
        known.iter().map(|(k, vj)| (crossings[*k].u, *vj)).collect();
    let mut draws: Vec<Draw> = samples::<3>(m).into_iter().map(Draw::Triple).collect();
    if partner.is_some() {
        draws.extend(samples::<2>(m).into_iter().map(Draw::Pair));
    }
    let consensus = Consensus {
        rows: &rows,
        partner,
        ctx,
        d: Vector3::new(ctx.focal_scale, ctx.focal_scale, 1.0),
        thr2: (ctx.outlier_k * ctx.sigma_img).powi(2),
    };
    // The two halves of the draws side by side where the caller spares the cores; the
    // winner is the one the draws give in sequence ([`Vote::beats`]).
    let best = if ctx.parallel && draws.len() * m >= PARALLEL_CONSENSUS_WORK {
        let (a, b) = draws.split_at(draws.len() / 2);
        let (a, b) = rayon::join(|| consensus.best_of(a), || consensus.best_of(b));
        match (a, b) {
            (Some(a), Some(b)) if b.beats(&a) => Some(b),
            (a, b) => a.or(b),
        }
    } else {
        consensus.best_of(&draws)
    };
    best.filter(|b| b.count >= 3).map(|b| b.plane)
}

/// A minimal sample of [`consensus_start`]: three crossings, or two and the partner's
/// orthogonality.
#[derive(Clone, Copy)]
enum Draw {
    Triple([usize; 3]),
    Pair([usize; 2]),
}

/// What [`consensus_start`] weighs its candidates against.
struct Consensus<'a> {
    rows: &'a [([f64; 2], Vector3<f64>)],
    partner: Option<Vector3<f64>>,
    ctx: &'a FitContext,
    /// `diag(λ, λ, 1)` as a vector.
    d: Vector3<f64>,
    /// The squared inlier threshold, `(k σ_img)²`.
    thr2: f64,
}

/// A candidate's votes: crossings (and the partner) within the threshold, and the
/// truncated squared error that breaks ties.
#[derive(Clone, Copy)]
struct Vote {
    count: usize,
    cost: f64,
    plane: Vector3<f64>,
}

impl Vote {
    /// Whether this vote, drawn later, wins over `earlier`: more votes, or as many at a
    /// smaller cost (the first of equals stays).
    fn beats(&self, earlier: &Vote) -> bool {
        self.count > earlier.count || (self.count == earlier.count && self.cost < earlier.cost)
    }
}

impl Consensus<'_> {
    /// The plane of a draw, if it is well conditioned.
    fn plane(&self, draw: Draw) -> Option<Vector3<f64>> {
        let row = |i: usize| {
            let (u, vj) = &self.rows[i];
            let u = Vector3::new(u[0], u[1], 1.0);
            (u, vj.dot(&u))
        };
        let min_sv = self.ctx.min_sample_spread;
        match draw {
            Draw::Triple(t) => sample_plane([row(t[0]), row(t[1]), row(t[2])], min_sv),
            Draw::Pair(t) => {
                let vp = self.partner?;
                let ortho = (vp.component_mul(&self.d).component_mul(&self.d), 0.0);
                sample_plane([row(t[0]), row(t[1]), ortho], min_sv)
            }
        }
    }

    /// The winning vote of `draws` in order, as if each met every crossing.
    fn best_of(&self, draws: &[Draw]) -> Option<Vote> {
        let mut best: Option<Vote> = None;
        for &draw in draws {
            let Some(plane) = self.plane(draw) else {
                continue;
            };
            if let Some(vote) = self.vote(plane, best.as_ref().map_or(0, |b| b.count)) {
                if best.as_ref().is_none_or(|b| vote.beats(b)) {
                    best = Some(vote);
                }
            }
        }
        best
    }

    /// The votes for `plane`, or `None` once it cannot reach `to_beat` votes even if
    /// every one left agreed (then it cannot win, and most of a long curve's samples
    /// stop after a few chunks).
    fn vote(&self, plane: Vector3<f64>, to_beat: usize) -> Option<Vote> {
        let (mut count, mut cost) = (0usize, 0.0);
        let mut left = self.rows.len() + usize::from(self.partner.is_some());
        for chunk in self.rows.chunks(CONSENSUS_CHUNK) {
            // The squared residual spares a square root per pair.
            for (u, vj) in chunk {
                let e2 = sampson_squared(&plane, vj, *u);
                count += usize::from(e2 <= self.thr2);
                cost += e2.min(self.thr2);
            }
            left -= chunk.len();
            if count + left < to_beat {
                return None;
            }
        }
        // The partner's orthogonality votes too: crossings all but one on a line fit
        // a wrong plane through that one as well as the right one.
        if let Some(vp) = self.partner {
            let (n, np) = (plane.component_mul(&self.d), vp.component_mul(&self.d));
            let cos = n.dot(&np) / (n.norm() * np.norm());
            if cos.abs() <= self.ctx.outlier_k * self.ctx.sigma_ortho {
                count += 1;
            }
        }
        Some(Vote { count, cost, plane })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The bounds' test says what the singular values say, on random and nearly
    /// singular matrices, either side of the threshold and inside the bounds' band.
    #[test]
    fn smallest_singular_value_test_is_the_decompositions() {
        let mut rng = crate::rng::SplitMix64::new(11);
        let mut checked = [0usize; 2];
        for case in 0..4000 {
            let mut a = Matrix3::from_fn(|_, _| rng.next_f64() - 0.5);
            if case % 2 == 0 {
                // The third row nearly in the plane of the first two.
                let mix = a.row(0) * (rng.next_f64() - 0.5) + a.row(1) * (rng.next_f64() - 0.5);
                let eps = 10f64.powf(-1.0 - 6.0 * rng.next_f64());
                a.set_row(2, &(mix + a.row(2) * eps));
            }
            let smallest = a.singular_values().min();
            let s = smallest * (0.3 + 2.0 * rng.next_f64());
            let kept = smallest_singular_value_at_least(&a, s);
            assert_eq!(
                kept,
                smallest >= s,
                "case {case}: {smallest:e} against {s:e}"
            );
            checked[usize::from(kept)] += 1;
        }
        assert!(checked.iter().all(|&c| c > 1000), "{checked:?}");
        let nan = Matrix3::from_element(f64::NAN);
        assert!(!smallest_singular_value_at_least(&nan, 1e-9));
    }
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

    /// The pruned consensus, on one thread and on two, chooses the plane that meeting
    /// every crossing with every draw in order chooses, on a curve with a fifth of its
    /// crossings wrong.
    #[test]
    fn the_consensus_chooses_as_if_every_draw_met_every_crossing() {
        let mut rng = crate::rng::SplitMix64::new(5);
        let truth = Vector3::new(0.3, -0.2, 1.1);
        let partner = Vector3::new(0.9, 0.4, 0.1);
        let sigma = 1e-3;
        let (mut crossings, mut known) = (Vec::new(), Vec::new());
        for k in 0..200 {
            let d = Vector3::new(
                rng.next_f64() - 0.5,
                0.5 + rng.next_f64(),
                rng.next_f64() - 0.5,
            );
            let x = rng.next_f64() - 0.5;
            let wrong = if k % 5 == 0 { 50.0 * sigma } else { 0.0 };
            let y = -(d.x * x + d.z) / d.y + sigma * (rng.next_f64() - 0.5) + wrong;
            crossings.push(Crossing {
                a: 0,
                b: k + 1,
                u: [x, y],
                sin_angle: 1.0,
            });
            known.push((k as usize, truth - d));
        }
        let ctx = FitContext::for_tests(sigma, 1e-3);
        let rows: Vec<([f64; 2], Vector3<f64>)> =
            known.iter().map(|(k, vj)| (crossings[*k].u, *vj)).collect();
        let consensus = Consensus {
            rows: &rows,
            partner: Some(partner),
            ctx: &ctx,
            d: Vector3::new(1.0, 1.0, 1.0),
            thr2: (ctx.outlier_k * sigma).powi(2),
        };
        let draws = samples::<3>(rows.len())
            .into_iter()
            .map(Draw::Triple)
            .chain(samples::<2>(rows.len()).into_iter().map(Draw::Pair));
        let mut reference: Option<Vote> = None;
        for draw in draws {
            let Some(vote) = consensus.plane(draw).and_then(|v| consensus.vote(v, 0)) else {
                continue;
            };
            if reference.as_ref().is_none_or(|b| vote.beats(b)) {
                reference = Some(vote);
            }
        }
        let reference = reference.expect("a vote").plane;
        assert!(
            (reference - truth).norm() < 0.05 * truth.norm(),
            "{reference}"
        );
        for parallel in [false, true] {
            let ctx = FitContext { parallel, ..ctx };
            let found = consensus_start(&crossings, &known, Some(partner), &ctx);
            assert_eq!(found, Some(reference), "parallel {parallel}");
        }
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
