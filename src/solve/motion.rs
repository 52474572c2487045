//! Planes the crossings leave free to turn, fixed by the smooth motion of the hand.
//!
//! A curve whose crossings with solved curves all lie on one image line (a cross
//! falling on a single flat wall, with its partner unsolved too) pins its plane only
//! up to a turn about the 3D line through those crossings. The paper's pipeline leaves
//! such planes out; on scenes of large flat surfaces that is most of the unsolved area.
//!
//! The projector is hand-held and the video runs at tens of frames per second, so the
//! same laser's planes in the neighbouring frames are close to this one. The plane is
//! taken as the prior interpolated from the nearest solved planes of the same laser
//! (at most `max_gap` frames away), moved the least amount that makes it agree with
//! every crossing: `v = v_prior + A⁺ (b − A v_prior)`, with `A⁺` the pseudo-inverse of
//! the crossing rows truncated to the directions they determine. The crossings then
//! decide everything they can; the prior only the turn. For a straight curve on a flat
//! surface the turn does not change its points at all; where the curve leaves the
//! surface, the prior keeps it close.

use std::collections::{BTreeMap, HashMap};

use nalgebra::{Matrix3, SymmetricEigen, Vector3};

use super::{Problem, Solution};

/// What [`fill_free_turns`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct MotionFill {
    /// Planes fixed by the motion prior.
    pub filled: usize,
    /// Planes that had a prior and enough crossings, but disagreed with them.
    pub refused: usize,
    /// Unsolved planes with fewer than three crossings with solved planes (last pass).
    pub too_few: usize,
    /// Unsolved planes with no solved plane of their laser near enough (last pass).
    pub no_prior: usize,
}

/// Largest relative disagreement between the filled plane and a crossing's depth from
/// the solved curve it crosses.
const MAX_RELATIVE_DEPTH: f64 = 0.005;

/// Eigenvalues of the unit crossing rows' `AᵀA` below this fraction of the largest
/// count as undetermined (coincident crossings fix no line).
const RANK_THRESHOLD: f64 = 1e-4;

/// Which of `problem`'s crossings `solution` did not reject.
fn not_rejected(problem: &Problem, solution: &Solution) -> Vec<bool> {
    let mut usable = vec![true; problem.crossings.len()];
    for &k in &solution.rejected_crossings {
        if let Some(u) = usable.get_mut(k) {
            *u = false;
        }
    }
    usable
}

/// Fills unsolved planes that have at least three `usable` crossings with solved
/// planes (at an angle whose sine is at least the solve's `min_sin_angle`), using
/// `sequence[c] = (frame, laser)` of every curve for the prior. Planes and crossings
/// are in the solution's (focal-corrected) coordinates.
pub fn fill_free_turns(
    problem: &Problem,
    usable: &[bool],
    solution: &mut Solution,
    sequence: &[(u32, u8)],
    max_gap: u32,
) -> MotionFill {
    let mut out = MotionFill::default();
    let n = problem.num_curves;
    if sequence.len() != n || solution.planes.len() != n || usable.len() != problem.crossings.len()
    {
        return out;
    }
    let lambda = solution.focal_scale;
    let min_sin_angle = solution
        .fit_context
        .map_or(super::SolveParams::default().min_sin_angle, |c| {
            c.min_sin_angle
        });
    let mut bad_curve = vec![false; n];
    for &c in &solution.rejected_curves {
        if let Some(b) = bad_curve.get_mut(c as usize) {
            *b = true;
        }
    }
    let mut adj: Vec<Vec<(usize, usize)>> = vec![Vec::new(); n];
    for (k, c) in problem.crossings.iter().enumerate() {
        let (a, b) = (c.a as usize, c.b as usize);
        if !usable[k] || a == b || a >= n || b >= n {
            continue;
        }
        if c.sin_angle < min_sin_angle {
            continue;
        }
        adj[a].push((b, k));
        adj[b].push((a, k));
    }
    let mut by_laser: HashMap<u8, BTreeMap<u32, usize>> = HashMap::new();
    for (c, &(frame, laser)) in sequence.iter().enumerate() {
        by_laser.entry(laser).or_default().insert(frame, c);
    }
    // Passes until nothing changes: a filled plane can be the neighbour of the next.
    for _ in 0..4 {
        let mut filled_now = Vec::new();
        (out.too_few, out.no_prior, out.refused) = (0, 0, 0);
        for c in 0..n {
            if solution.planes[c].is_some() || bad_curve[c] {
                continue;
            }
            let rows: Vec<(Vector3<f64>, f64)> = adj[c]
                .iter()
                .filter_map(|&(o, k)| {
                    let vo = solution.planes[o]?;
                    let u = problem.crossings[k].u;
                    let u = Vector3::new(u[0] / lambda, u[1] / lambda, 1.0);
                    Some((u, vo.dot(&u)))
                })
                .collect();
            // At least one crossing more than the directions it fixes, so that a
            // wrong crossing shows.
            if rows.len() < 3 {
                out.too_few += 1;
                continue;
            }
            let (frame, laser) = sequence[c];
            let Some(prior) = by_laser
                .get(&laser)
                .and_then(|m| interpolate(m, frame, max_gap, &solution.planes))
            else {
                out.no_prior += 1;
                continue;
            };
            match trimmed(prior, rows) {
                Some(v) => filled_now.push((c, v)),
                None => out.refused += 1,
            }
        }
        if filled_now.is_empty() {
            break;
        }
        out.filled += filled_now.len();
        for (c, v) in filled_now {
            solution.planes[c] = Some(v);
        }
    }
    out
}

/// [`fill_free_turns`], then the ordinary extension of the planes the filled ones make
/// solvable (a partner, a neighbour), then another fill.
pub fn fill_and_extend(
    problem: &Problem,
    solution: &mut Solution,
    sequence: &[(u32, u8)],
    max_gap: u32,
) -> MotionFill {
    if max_gap == 0 {
        return MotionFill::default();
    }
    let mut total = fill_free_turns(
        problem,
        &not_rejected(problem, solution),
        solution,
        sequence,
        max_gap,
    );
    let Some(ctx) = solution.fit_context else {
        return total;
    };
    if total.filled == 0 {
        return total;
    }
    let (given, rc, rv) =
        extend_around_solved(problem, &not_rejected(problem, solution), solution, &ctx);
    solution.rejected_crossings.extend(rc);
    solution.rejected_crossings.sort_unstable();
    solution.rejected_crossings.dedup();
    solution.rejected_curves.extend(rv);
    solution.rejected_curves.sort_unstable();
    solution.rejected_curves.dedup();
    for (p, g) in solution.planes.iter_mut().zip(given) {
        if p.is_none() {
            *p = g;
        }
    }
    let again = fill_free_turns(
        problem,
        &not_rejected(problem, solution),
        solution,
        sequence,
        max_gap,
    );
    total.filled += again.filled;
    MotionFill {
        filled: total.filled,
        ..again
    }
}

/// Fits the unsolved planes that have enough `usable` crossings with solved planes
/// (see [`super::extend_and_refine`]), the solved ones held fixed, then gives the
/// planes those leave free to turn the hand's motion ([`fill_free_turns`], when
/// `max_gap` > 0); returns how many planes each gave. `problem` may hold more
/// crossings than the one `solution` was solved from (with `usable` saying which
/// count); the solution's rejections are left as they were.
pub fn extend_from(
    problem: &Problem,
    usable: &[bool],
    solution: &mut Solution,
    sequence: &[(u32, u8)],
    max_gap: u32,
) -> (usize, usize) {
    let Some(ctx) = solution.fit_context else {
        return (0, 0);
    };
    // A curve the extension rejects is never given a plane.
    let (given, _, _) = extend_around_solved(problem, usable, solution, &ctx);
    let mut added = 0;
    for (p, g) in solution.planes.iter_mut().zip(given) {
        if p.is_none() && g.is_some() {
            *p = g;
            added += 1;
        }
    }
    let filled = if max_gap > 0 {
        fill_free_turns(problem, usable, solution, sequence, max_gap).filled
    } else {
        0
    };
    (added, filled)
}

/// The ordinary extension ([`super::extend_and_refine`]) over the `usable` crossings
/// with the solution's planes held fixed: every plane afterwards, in the solution's
/// coordinates, and the crossings and curves the extension rejected.
fn extend_around_solved(
    problem: &Problem,
    usable: &[bool],
    solution: &Solution,
    ctx: &super::FitContext,
) -> (Vec<Option<Vector3<f64>>>, Vec<usize>, Vec<u32>) {
    let lambda = solution.focal_scale;
    let mut given = solution.given_planes();
    let fixed: Vec<bool> = given.iter().map(|p| p.is_some()).collect();
    let active: Vec<bool> = problem
        .crossings
        .iter()
        .zip(usable)
        .map(|(c, &u)| u && c.sin_angle >= ctx.min_sin_angle && c.a != c.b)
        .collect();
    let (rc, rv, _) = super::extend_and_refine(problem, &active, &mut given, &fixed, ctx, 0);
    let planes = given
        .into_iter()
        .map(|g| g.map(|v| Vector3::new(v.x * lambda, v.y * lambda, v.z)))
        .collect();
    (planes, rc, rv)
}

/// The prior plane of `frame`: linear interpolation between the nearest solved planes
/// of this laser before and after (each at most `max_gap` frames away), or the one of
/// them that exists.
fn interpolate(
    frames: &BTreeMap<u32, usize>,
    frame: u32,
    max_gap: u32,
    planes: &[Option<Vector3<f64>>],
) -> Option<Vector3<f64>> {
    let before = frames
        .range(frame.saturating_sub(max_gap)..frame)
        .rev()
        .find_map(|(&f, &c)| planes[c].map(|v| (f, v)));
    let after = frames
        .range(frame + 1..=frame.saturating_add(max_gap))
        .find_map(|(&f, &c)| planes[c].map(|v| (f, v)));
    match (before, after) {
        (Some((f0, v0)), Some((f1, v1))) => {
            let t = f64::from(frame - f0) / f64::from(f1 - f0);
            Some(v0 * (1.0 - t) + v1 * t)
        }
        (Some((_, v)), None) | (None, Some((_, v))) => Some(v),
        (None, None) => None,
    }
}

/// [`constrained`], leaving out the worst-agreeing crossing while any disagrees by
/// more than [`MAX_RELATIVE_DEPTH`] (up to a quarter of them, keeping one more than
/// the directions they fix). `None` if they cannot be made to agree.
fn trimmed(prior: Vector3<f64>, mut rows: Vec<(Vector3<f64>, f64)>) -> Option<Vector3<f64>> {
    let max_drop = rows.len() / 4;
    for _ in 0..=max_drop {
        let (v, rank) = constrained(prior, &rows)?;
        if rows.len() <= rank {
            return None;
        }
        let rel = |(u, b): &(Vector3<f64>, f64)| ((v.dot(u) - b) / b).abs();
        let (worst, e) = rows
            .iter()
            .enumerate()
            .map(|(i, r)| (i, rel(r)))
            .max_by(|a, b| a.1.total_cmp(&b.1))?;
        if e <= MAX_RELATIVE_DEPTH {
            return Some(v);
        }
        rows.swap_remove(worst);
    }
    None
}

/// `prior` moved the least so that `u·v = b` for every row, in the two directions the
/// rows determine best (the eigenvectors of `AᵀA` with the largest eigenvalues).
fn constrained(prior: Vector3<f64>, rows: &[(Vector3<f64>, f64)]) -> Option<(Vector3<f64>, usize)> {
    let mut ata = Matrix3::zeros();
    let mut atr = Vector3::zeros();
    for (u, b) in rows {
        // Unit rows: every crossing weighs the same whatever its ray's length.
        let s = 1.0 / u.norm();
        let (u, r) = (u * s, (b - u.dot(&prior)) * s);
        ata += u * u.transpose();
        atr += u * r;
    }
    let eig = SymmetricEigen::new(ata);
    let top = eig.eigenvalues.max();
    if top.is_nan() || top <= 0.0 {
        return None;
    }
    // The two directions the crossings fix best (their 3D line); the turn about it
    // stays the prior's. Crossings that fix the turn too would have given the plane
    // through the ordinary fit, so here one stray crossing off the line must not set
    // it.
    let mut order = [0usize, 1, 2];
    order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
    let mut delta = Vector3::zeros();
    let mut rank = 0;
    for &i in &order[..2] {
        let l = eig.eigenvalues[i];
        if l > RANK_THRESHOLD * top {
            let e = eig.eigenvectors.column(i);
            delta += e * (e.dot(&atr) / l);
            rank += 1;
        }
    }
    (rank >= 2).then_some((prior + delta, rank))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::intersect::Crossing;

    /// Planes of one laser turning slowly; the middle one's crossings all lie on one
    /// image line, so only the motion prior can fix its turn.
    #[test]
    fn a_collinear_plane_gets_the_turn_of_its_neighbours() {
        let plane = |t: f64| Vector3::new(0.8 + 0.01 * t, 0.05 * t, 0.4);
        // Curves 0, 1, 2: laser 0 in frames 0, 1, 2. Curve 3: a solved crossing curve.
        let other = Vector3::new(-0.3, 0.9, 0.5);
        let truth = plane(1.0);
        // Points on the line where plane(1) meets `other`'s... choose image points
        // along a line and give them depths consistent with the true plane.
        let mut crossings = Vec::new();
        for (i, x) in [-0.2f64, 0.0, 0.15, 0.3].iter().enumerate() {
            // A point u on both planes: solve for y with (truth - other)·(x, y, 1) = 0.
            let d = truth - other;
            let y = -(d.x * x + d.z) / d.y;
            crossings.push(Crossing {
                a: 1,
                b: 3,
                u: [*x, y],
                sin_angle: 0.9,
            });
            let _ = i;
        }
        let problem = Problem {
            num_curves: 4,
            crossings: &crossings,
            partner: &[None, None, None, None],
            focal_px: 1000.0,
        };
        let mut sol = Solution::empty();
        sol.planes = vec![Some(plane(0.0)), None, Some(plane(2.0)), Some(other)];
        let all = vec![true; crossings.len()];
        let fill = fill_free_turns(
            &problem,
            &all,
            &mut sol,
            &[(0, 0), (1, 0), (2, 0), (1, 1)],
            3,
        );
        assert_eq!((fill.filled, fill.refused), (1, 0));
        let v = sol.planes[1].expect("filled");
        assert!((v - truth).norm() < 1e-9, "{v:?} vs {truth:?}");
        // Prior off the truth by a turn about the crossings' line: the crossings keep
        // the line, the result stays on every crossing.
        let mut sol3 = Solution::empty();
        sol3.planes = vec![
            Some(plane(0.0) * 1.01),
            None,
            Some(plane(2.0) * 0.995),
            Some(other),
        ];
        fill_free_turns(
            &problem,
            &all,
            &mut sol3,
            &[(0, 0), (1, 0), (2, 0), (1, 1)],
            3,
        );
        let v = sol3.planes[1].expect("filled");
        for c in &crossings {
            let u = Vector3::new(c.u[0], c.u[1], 1.0);
            assert!(((v - other).dot(&u)).abs() < 1e-12, "off a crossing");
        }

        // The solve's `min_sin_angle` holds here too: crossings at a shallower angle
        // than the configured one fix nothing.
        let mut strict = Solution::empty();
        strict.planes = vec![Some(plane(0.0)), None, Some(plane(2.0)), Some(other)];
        strict.fit_context = Some(super::super::FitContext {
            min_sin_angle: 0.95,
            ..super::super::FitContext::for_tests(1e-4, 1e-3)
        });
        let fill = fill_free_turns(
            &problem,
            &all,
            &mut strict,
            &[(0, 0), (1, 0), (2, 0), (1, 1)],
            3,
        );
        assert_eq!((fill.filled, fill.too_few), (0, 1));
        assert!(strict.planes[1].is_none());

        // Crossings with a second solved curve that disagree with the first ones (two
        // of them, off the line, and not on one plane with it) are refused, not
        // smoothed over.
        let other2 = Vector3::new(0.2, -0.5, 0.6);
        let mut bad = crossings.clone();
        for u in [[0.1, 0.5], [-0.3, 0.6]] {
            bad.push(Crossing {
                a: 1,
                b: 4,
                u,
                sin_angle: 0.9,
            });
        }
        let problem = Problem {
            num_curves: 5,
            crossings: &bad,
            partner: &[None; 5],
            focal_px: 1000.0,
        };
        let mut sol2 = Solution::empty();
        sol2.planes = vec![
            Some(plane(0.0)),
            None,
            Some(plane(2.0)),
            Some(other),
            Some(other2),
        ];
        let fill = fill_free_turns(
            &problem,
            &vec![true; bad.len()],
            &mut sol2,
            &[(0, 0), (1, 0), (2, 0), (1, 1), (5, 1)],
            3,
        );
        assert_eq!(fill.filled, 0);
        assert!(sol2.planes[1].is_none());
    }
}
