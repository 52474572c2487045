//! Planes the crossings leave free to turn, fixed by the smooth motion of the hand.
//!
//! A curve whose crossings with solved curves all lie on one image line (a cross
//! falling on a single flat wall, with its partner unsolved too) pins its plane only
//! up to a turn about the 3D line through those crossings. The paper's pipeline leaves
//! such planes out; on scenes of large flat surfaces that is most of the unsolved area.
//!
//! The projector is hand-held and the video runs at tens of frames per second, so the
//! same laser's planes in the neighbouring frames are close to this one. The prior is
//! interpolated from the nearest solved planes of the same laser (at most `max_gap`
//! frames away) as homogeneous planes, which move smoothly even where the sheet
//! sweeps through the camera centre. The crossings decide the two directions they
//! determine, and the turn about the third is the one that brings the plane closest
//! to the prior. For a straight curve on a flat surface the turn does not change its
//! points at all; where the curve leaves the surface, the prior keeps it close.
//!
//! A sheet passing within centimetres of the camera centre is the exception: its
//! crossings lie within a pixel of one line, too close for the ordinary fit, yet its
//! depths follow those sub-pixel offsets more closely than any prior. Where the prior
//! disagrees with the crossings, their own least-squares plane is taken, if no single
//! crossing sets its turn and all agree with it within the cloud's crossing check.

use std::collections::{BTreeMap, HashMap};

use nalgebra::{Matrix3, SymmetricEigen, Vector3, Vector4};

use super::{Problem, Solution};

/// What [`fill_free_turns`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct MotionFill {
    /// Planes fixed by the motion prior, or by their own crossings where those
    /// disagree with the prior but fix the turn themselves.
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

/// One crossing with a solved curve: its ray `u` and `b = u·v` of that curve's plane,
/// which this plane must meet (`u·v = b`).
type Row = (Vector3<f64>, f64);

/// Largest relative disagreement at a crossing for a plane that its crossings fix
/// alone but barely ([`own_turn`]): the crossing check of the cloud's, so that the
/// plane is kept only where the check would keep its points.
const MAX_RELATIVE_DEPTH_OWN_TURN: f64 = 0.02;

/// Smallest eigenvalue of the unit crossing rows' `AᵀA`, as a fraction of the
/// largest, for the crossings to fix the turn themselves: their rays' mean square
/// distance from their best plane through the camera centre, about 0.05 px RMS off
/// one image line at a focal length of 1450 px, the noise of a crossing's position.
/// Below it their offsets are noise; above it, the agreement checks judge the fit.
const MIN_TURN_SPREAD: f64 = 1e-9;

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
            let rows: Vec<Row> = adj[c]
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
        &solution.not_rejected(problem.crossings.len()),
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
    let (given, rc, rv) = extend_around_solved(
        problem,
        &solution.not_rejected(problem.crossings.len()),
        solution,
        &ctx,
    );
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
        &solution.not_rejected(problem.crossings.len()),
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

/// The prior plane of `frame` as a unit homogeneous plane `(v, −1)/|(v, −1)|`, up to
/// sign: linear interpolation between the nearest solved planes of this laser before
/// and after (each at most `max_gap` frames away), or the one of them that exists.
///
/// Interpolated in homogeneous form, not as `v`: a hand-held sheet can sweep through
/// the camera centre, where `v = n/d` grows without bound and changes sign while the
/// homogeneous plane moves smoothly. Each is signed to agree with the other first.
fn interpolate(
    frames: &BTreeMap<u32, usize>,
    frame: u32,
    max_gap: u32,
    planes: &[Option<Vector3<f64>>],
) -> Option<Vector4<f64>> {
    let homogeneous = |v: Vector3<f64>| Vector4::new(v.x, v.y, v.z, -1.0).normalize();
    let before = frames
        .range(frame.saturating_sub(max_gap)..frame)
        .rev()
        .find_map(|(&f, &c)| planes[c].map(|v| (f, homogeneous(v))));
    let after = frames
        .range(frame + 1..=frame.saturating_add(max_gap))
        .find_map(|(&f, &c)| planes[c].map(|v| (f, homogeneous(v))));
    match (before, after) {
        (Some((f0, p0)), Some((f1, p1))) => {
            let p1 = if p0.xyz().dot(&p1.xyz()) < 0.0 {
                -p1
            } else {
                p1
            };
            let t = f64::from(frame - f0) / f64::from(f1 - f0);
            Some(p0 * (1.0 - t) + p1 * t)
        }
        (Some((_, p)), None) | (None, Some((_, p))) => Some(p),
        (None, None) => None,
    }
}

/// The plane for `rows` (`u·v = b`, one per crossing with a solved curve): the
/// prior's turn where the crossings agree with it ([`constrained`], every crossing
/// within [`MAX_RELATIVE_DEPTH`]), else the crossings' own plane where they fix the
/// turn themselves, if barely ([`own_turn`], [`turn_is_shared`]). `None` if neither
/// agrees.
fn trimmed(prior: Vector4<f64>, rows: Vec<Row>) -> Option<Vector3<f64>> {
    if let Some((v, _)) = trimmed_by(rows.clone(), MAX_RELATIVE_DEPTH, |r| constrained(prior, r)) {
        return Some(v);
    }
    let (v, kept) = trimmed_by(rows, MAX_RELATIVE_DEPTH_OWN_TURN, own_turn)?;
    turn_is_shared(&kept).then_some(v)
}

/// `fit`, leaving out the worst-agreeing row while any disagrees by more than `limit`
/// (up to a quarter of them, keeping one more than the directions the fit fixes):
/// the plane and the rows it kept. `None` if they cannot be made to agree.
fn trimmed_by(
    mut rows: Vec<Row>,
    limit: f64,
    fit: impl Fn(&[Row]) -> Option<(Vector3<f64>, usize)>,
) -> Option<(Vector3<f64>, Vec<Row>)> {
    let max_drop = rows.len() / 4;
    for _ in 0..=max_drop {
        let (v, rank) = fit(&rows)?;
        if rows.len() <= rank {
            return None;
        }
        let (worst, e) = rows
            .iter()
            .enumerate()
            .map(|(i, r)| (i, relative_error(&v, r)))
            .max_by(|a, b| a.1.total_cmp(&b.1))?;
        if e <= limit {
            return Some((v, rows));
        }
        rows.swap_remove(worst);
    }
    None
}

fn relative_error(v: &Vector3<f64>, (u, b): &Row) -> f64 {
    ((v.dot(u) - b) / b).abs()
}

/// The eigen-decomposition of the unit rows' `AᵀA`, `Aᵀb`, and the eigenvalues'
/// order from the largest.
type NormalEquations = (SymmetricEigen<f64, nalgebra::U3>, Vector3<f64>, [usize; 3]);

/// The eigen-decomposition of the unit rows' `AᵀA` (every crossing weighs the same
/// whatever its ray's length), with `Aᵀb`, and its directions from the best
/// determined to the least; `None` if the rows are empty.
fn normal_equations(rows: &[Row]) -> Option<NormalEquations> {
    let mut ata = Matrix3::zeros();
    let mut atb = Vector3::zeros();
    for (u, b) in rows {
        let s = 1.0 / u.norm();
        let (u, b) = (u * s, b * s);
        ata += u * u.transpose();
        atb += u * b;
    }
    let eig = SymmetricEigen::new(ata);
    let top = eig.eigenvalues.max();
    if top.is_nan() || top <= 0.0 {
        return None;
    }
    let mut order = [0usize, 1, 2];
    order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
    Some((eig, atb, order))
}

/// The plane that meets every row `u·v = b` in the two directions the rows determine
/// best (the eigenvectors of `AᵀA` with the largest eigenvalues), turned about the
/// third to lie closest to the homogeneous `prior` (largest |cos| of the angle
/// between them as 4-vectors).
fn constrained(prior: Vector4<f64>, rows: &[Row]) -> Option<(Vector3<f64>, usize)> {
    let (eig, atb, order) = normal_equations(rows)?;
    let top = eig.eigenvalues[order[0]];
    // The two directions the crossings fix best (their 3D line); the turn about it
    // is the prior's. Crossings that fix the turn too would have given the plane
    // through the ordinary fit, so here one stray crossing off the line must not set
    // it.
    let mut fixed = Vector3::zeros();
    for &i in &order[..2] {
        let l = eig.eigenvalues[i];
        if l <= RANK_THRESHOLD * top {
            return None;
        }
        let e = eig.eigenvectors.column(i);
        fixed += e * (e.dot(&atb) / l);
    }
    // v = fixed + t·e, with `fixed` ⟂ e: the homogeneous plane w(t) = (v, −1) is
    // closest to the prior where (p·w)² / |w|² = (a + t·b)² / (c + t²) peaks, at
    // t = b·c / a. A prior through the camera centre (a = 0) fixes no finite turn.
    let e: Vector3<f64> = eig.eigenvectors.column(order[2]).into();
    let a = prior.xyz().dot(&fixed) - prior.w;
    let b = prior.xyz().dot(&e);
    let c = fixed.norm_squared() + 1.0;
    if a.abs() < 1e-12 * c.sqrt() {
        return None;
    }
    Some((fixed + e * (b * c / a), 2))
}

/// The least-squares plane of the rows alone, when their rays spread off their best
/// image line by at least [`MIN_TURN_SPREAD`] (with the direction of least spread,
/// the turn).
///
/// This is the sheet that passes within centimetres of the camera centre: all its
/// crossings lie within a pixel of one image line, too close for the ordinary fit's
/// bend, yet with `|v|` large those sub-pixel offsets are what its depths follow,
/// and a prior from the neighbouring frames is rarely that exact.
fn least_squares(rows: &[Row]) -> Option<(Vector3<f64>, Vector3<f64>)> {
    let (eig, atb, order) = normal_equations(rows)?;
    if eig.eigenvalues[order[2]] <= MIN_TURN_SPREAD * eig.eigenvalues[order[0]] {
        return None;
    }
    let v = order
        .iter()
        .map(|&i| {
            let e = eig.eigenvectors.column(i);
            e * (e.dot(&atb) / eig.eigenvalues[i])
        })
        .sum();
    Some((v, eig.eigenvectors.column(order[2]).into_owned()))
}

/// [`least_squares`] as a fit for [`trimmed_by`].
fn own_turn(rows: &[Row]) -> Option<(Vector3<f64>, usize)> {
    least_squares(rows).map(|(v, _)| (v, 3))
}

/// Whether the turn the rows fix is not one crossing's alone: the plane without the
/// row that weighs most on the turn still meets every row within
/// [`MAX_RELATIVE_DEPTH_OWN_TURN`].
fn turn_is_shared(rows: &[Row]) -> bool {
    let Some((_, turn)) = least_squares(rows) else {
        return false;
    };
    let weight = |(u, _): &Row| (turn.dot(u) / u.norm()).abs();
    let Some(heaviest) =
        (0..rows.len()).max_by(|&a, &b| weight(&rows[a]).total_cmp(&weight(&rows[b])))
    else {
        return false;
    };
    let rest: Vec<_> = (0..rows.len())
        .filter(|&i| i != heaviest)
        .map(|i| rows[i])
        .collect();
    least_squares(&rest).is_some_and(|(without, _)| {
        rows.iter()
            .all(|r| relative_error(&without, r) <= MAX_RELATIVE_DEPTH_OWN_TURN)
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::intersect::Crossing;

    /// `v` of the homogeneous plane `a·cos(θ) + b·sin(θ)`, `a` and `b` orthonormal
    /// 4-vectors: planes turning at a steady rate, so that the homogeneous mean of
    /// two is the one halfway.
    fn turning(a: Vector4<f64>, b: Vector4<f64>, theta: f64) -> Vector3<f64> {
        let p = a * theta.cos() + b * theta.sin();
        -p.xyz() / p.w
    }

    fn orthonormal(a: Vector4<f64>, b: Vector4<f64>) -> (Vector4<f64>, Vector4<f64>) {
        let a = a.normalize();
        (a, (b - a * a.dot(&b)).normalize())
    }

    /// Crossings of the plane `truth` with the solved plane `other` at the image
    /// x positions `xs`: on one image line.
    fn crossings_on(truth: Vector3<f64>, other: Vector3<f64>, b: u32, xs: &[f64]) -> Vec<Crossing> {
        let d = truth - other;
        xs.iter()
            .map(|&x| Crossing {
                a: 1,
                b,
                u: [x, -(d.x * x + d.z) / d.y],
                sin_angle: 0.9,
            })
            .collect()
    }

    /// Planes of one laser turning slowly; the middle one's crossings all lie on one
    /// image line, so only the motion prior can fix its turn.
    #[test]
    fn a_collinear_plane_gets_the_turn_of_its_neighbours() {
        let (a, b) = orthonormal(
            Vector4::new(0.8, 0.0, 0.4, -1.0),
            Vector4::new(0.01, 0.05, 0.0, 0.0),
        );
        let plane = |t: f64| turning(a, b, 0.05 * t);
        // Curves 0, 1, 2: laser 0 in frames 0, 1, 2. Curve 3: a solved crossing curve.
        let other = Vector3::new(-0.3, 0.9, 0.5);
        let truth = plane(1.0);
        let crossings = crossings_on(truth, other, 3, &[-0.2, 0.0, 0.15, 0.3]);
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

    /// A sheet sweeping through the camera centre: `v = n/d` of the planes before and
    /// after point opposite ways (their mean in `v` lies beyond the far one), while
    /// the homogeneous planes move smoothly and their mean gives the turn.
    #[test]
    fn a_sheet_sweeping_through_the_camera_centre_gets_a_smooth_turn() {
        let n = Vector3::new(-0.3, 0.94, -0.1).normalize();
        let plane = |d: f64| n / d;
        let (truth, other) = (plane(0.01), Vector3::new(-0.3, 0.9, 0.5));
        let crossings = crossings_on(truth, other, 3, &[-0.2, 0.0, 0.15, 0.3]);
        let problem = Problem {
            num_curves: 4,
            crossings: &crossings,
            partner: &[None; 4],
            focal_px: 1000.0,
        };
        let mut sol = Solution::empty();
        sol.planes = vec![Some(plane(0.03)), None, Some(plane(-0.01)), Some(other)];
        let sequence = [(0, 0), (1, 0), (2, 0), (1, 1)];
        let fill = fill_free_turns(&problem, &[true; 4], &mut sol, &sequence, 3);
        assert_eq!(fill.filled, 1);
        let v = sol.planes[1].expect("filled");
        // Points of the sheet a few degrees off the crossings' line.
        for u in [Vector3::new(0.1, 0.05, 1.0), Vector3::new(-0.2, -0.1, 1.0)] {
            let u = u + n * (-(truth.dot(&u) - 1.0 / 0.8) / truth.dot(&n));
            let rel = (v.dot(&u) / truth.dot(&u) - 1.0).abs();
            assert!(rel < 1e-3, "depth off by {rel} at {u:?}");
        }
    }

    /// A sheet close to the camera centre whose crossings lie within a fraction of a
    /// pixel of one image line: with `|v|` large they still fix its turn, and that
    /// wins over a prior that disagrees with them.
    #[test]
    fn crossings_a_pixel_off_one_line_fix_the_turn_over_a_wrong_prior() {
        let n = Vector3::new(-0.3, 0.94, -0.1).normalize();
        let truth = n / 0.02;
        let other = Vector3::new(-0.3, 0.9, 0.5);
        // Points of the sheet near the line where it meets `other`, each crossed by a
        // solved curve of its own through that point.
        let line = crossings_on(truth, other, 0, &[-0.3, -0.2, -0.1, 0.0, 0.1, 0.2, 0.3]);
        let mut planes = vec![Some(truth * 0.8), None, Some(truth * 0.85)];
        let mut crossings = Vec::new();
        for (k, c) in line.iter().enumerate() {
            // Up to 1.2 px off the line at a focal length of 1450 px.
            let off = [0.6, -1.2, 0.3, 0.9, -0.6, 1.2, -0.3][k] / 1450.0;
            let u = Vector3::new(c.u[0], c.u[1] + off, 1.0);
            let o = other + u * ((truth - other).dot(&u) / u.norm_squared());
            planes.push(Some(o));
            crossings.push(Crossing {
                a: 1,
                b: planes.len() as u32 - 1,
                u: [u.x, u.y],
                sin_angle: 0.9,
            });
        }
        let bends = crate::solve::subset::bend(crossings.iter().map(|c| c.u));
        assert!(bends < 1e-3, "the ordinary fit would take it: bend {bends}");
        let problem = Problem {
            num_curves: planes.len(),
            crossings: &crossings,
            partner: &vec![None; planes.len()],
            focal_px: 1450.0,
        };
        let mut sol = Solution::empty();
        sol.planes = planes;
        let mut sequence = vec![(0, 0), (1, 0), (2, 0)];
        sequence.extend((0..crossings.len() as u32).map(|k| (1 + k, 1)));
        let fill = fill_free_turns(
            &problem,
            &vec![true; crossings.len()],
            &mut sol,
            &sequence,
            3,
        );
        assert_eq!((fill.filled, fill.refused), (1, 0));
        let v = sol.planes[1].expect("filled");
        assert!(
            (v - truth).norm() < 1e-6 * truth.norm(),
            "{v:?} vs {truth:?}"
        );
    }
}
