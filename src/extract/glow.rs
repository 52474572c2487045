//! The glow step under a curve's points: under water a laser sheet's glow fills one
//! side of its stripe and tilts the ridge towards it; each linked chain's points are
//! moved off the step measured across the line ([`glow_moves`]).
//!
//! Owns the measurement along a chain (runs of points, their medians, the plateau
//! rule); the step across one point is [`super::detect`]'s.

use super::detect::{self, Detector};

/// The move along the normal (px) of each point of `chain` off the glow step under
/// it. Each point's step is measured across the line ([`Detector::step_across`]); the
/// chain is cut into runs of [`STEP_RUN`] points, whose step is the median at each
/// distance, and each point takes the step of the runs about it, linearly between
/// their middles. The steps are measured again about the centres they give (the
/// flanks of an off-centre point see the stripe's own tails unevenly), and kept only
/// where a run's is a plateau ([`detect::plateau_step`]), before the points are moved.
/// A chain with no glow (in air, nearly all) costs one measurement of every other
/// point (every `σ`-th on wide stripes).
pub(super) fn glow_moves(det: &Detector, chain: &[u32]) -> Vec<f32> {
    let points: Vec<&detect::LinePoint> = chain.iter().map(|&i| &det.points[i as usize]).collect();
    let n = points.len();
    let runs = (n / STEP_RUN).max(1);
    let run_of = |r: usize| r * n / runs..(r + 1) * n / runs;
    // Every other point, or one per smoothing scale on wide stripes: neighbours'
    // flank samples overlap, and the response is smooth over `σ`.
    let stride = (points[0].sigma.round() as usize).max(2);
    let measure = |moves: &[f32], plateau: bool| -> Vec<f32> {
        let profiles: Vec<[f32; detect::STEP_DISTANCES]> = points
            .iter()
            .zip(moves)
            .step_by(stride)
            .map(|(p, m)| {
                let centre = [p.x + m * p.nx, p.y + m * p.ny];
                det.step_across(centre, [p.nx, p.ny], p.flank_px)
            })
            .collect();
        let mut column = Vec::with_capacity(n / runs + 1);
        let steps: Vec<f32> = (0..runs)
            .map(|r| {
                let span = run_of(r);
                let measured = &profiles[span.start.div_ceil(stride)
                    ..span
                        .end
                        .div_ceil(stride)
                        .max(span.start.div_ceil(stride) + 1)
                        .min(profiles.len())];
                let medians: [f32; detect::STEP_DISTANCES] = std::array::from_fn(|k| {
                    column.clear();
                    column.extend(measured.iter().map(|p| p[k]));
                    let mid = column.len() / 2;
                    *column.select_nth_unstable_by(mid, f32::total_cmp).1
                });
                if plateau {
                    detect::plateau_step(&medians)
                } else {
                    medians.iter().sum::<f32>() / detect::STEP_DISTANCES as f32
                }
            })
            .collect();
        if steps.iter().all(|&s| s == 0.0) {
            return vec![0.0; n];
        }
        // Linearly between the middles of the runs, flat beyond the outer ones.
        let middle = |r: usize| {
            let span = run_of(r);
            0.5 * (span.start + span.end - 1) as f32
        };
        (0..n)
            .map(|j| {
                let x = j as f32;
                let r = (0..runs).rposition(|r| middle(r) <= x).unwrap_or(0);
                if r + 1 >= runs || x <= middle(r) {
                    return steps[r];
                }
                let f = (x - middle(r)) / (middle(r + 1) - middle(r));
                steps[r] + f * (steps[r + 1] - steps[r])
            })
            .collect()
    };
    // Solved at every `stride`-th point and the last, linearly between.
    let to_moves = |steps: &[f32]| -> Vec<f32> {
        let at = |j: usize| {
            let s = steps[j];
            if s == 0.0 {
                0.0
            } else {
                points[j].step_move(s)
            }
        };
        let mut moves = vec![0.0; n];
        let mut j0 = 0;
        let mut m0 = at(0);
        moves[0] = m0;
        while j0 + 1 < n {
            let j1 = (j0 + stride).min(n - 1);
            let m1 = at(j1);
            for (k, m) in moves[j0 + 1..=j1].iter_mut().enumerate() {
                let f = (k + 1) as f32 / (j1 - j0) as f32;
                *m = m0 + f * (m1 - m0);
            }
            (j0, m0) = (j1, m1);
        }
        moves
    };
    // First about the centres as found, every run's mean step whether a plateau or
    // not (about an off-centre point the stripe's own tails can hide one); a chain
    // whose steps are all under a twentieth of its response has no glow worth a move.
    let first = measure(&vec![0.0; n], false);
    let mut strength: Vec<f32> = points.iter().map(|p| p.ridge[1]).collect();
    let mid = strength.len() / 2;
    let typical = *strength.select_nth_unstable_by(mid, f32::total_cmp).1;
    if first.iter().all(|s| s.abs() < NEGLIGIBLE_STEP * typical) {
        return vec![0.0; n];
    }
    let moves: Vec<f32> = to_moves(&first)
        .iter()
        .map(|m| m.clamp(-1.0, 1.0))
        .collect();
    to_moves(&measure(&moves, true))
}

/// A chain's glow steps under this share of its typical smoothed response move its
/// points by a few hundredths of a pixel at most, and are not measured again
/// ([`glow_moves`]).
const NEGLIGIBLE_STEP: f32 = 0.02;

/// Points in a run of a curve whose glow steps ([`detect::step_shift`]) are taken
/// together: one point's step is as noisy as a few pixels, while the glow beside a
/// stripe changes over tens of pixels.
const STEP_RUN: usize = 21;
