//! The consensus start of a plane fit ([`super::extend::fit_plane`]): minimal samples
//! of a curve's crossings with solved curves (triples, and pairs with the partner's
//! orthogonality), each sample's plane voted on by every crossing, the plane with the
//! most votes winning. Owns the draws, the conditioning test of a sample, and the vote,
//! which stops weighing a draw once it cannot win and may weigh the draws' two halves
//! side by side; the winner is always the one the draws give in order.

use super::extend::FitContext;
use super::nullspace::sampson_squared;
use crate::intersect::Crossing;
use nalgebra::{Matrix3, Vector3};

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
fn samples<const K: usize>(m: usize) -> Vec<[usize; K]> {
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
pub(super) fn consensus_start(
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
}
