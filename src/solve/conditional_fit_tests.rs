//! Unit tests of the single-pose fits of [`super`]: their normal equations against the
//! whole crossing terms, and the repeat from a fit's own end against a cold one.

use super::super::terms::tests::pose;
use super::*;

/// A pose fitted again at wider spreads from its own end (the repeat in
/// [`complete`]) lands where the fit from its cold starts does, to a hundredth of
/// its own deviation, and both lie within a few deviations of the truth.
#[test]
fn a_fit_repeated_from_its_own_end_lands_where_a_cold_one_does() {
    let (anchors, truth, ties) = ties_around_anchors();
    let focal_px = 1000.0;
    let params = EstimateParams::default();
    let fit =
        |ties: &[Tie], start| fit_pose(focal_px, &anchors, 1.0, &params, ties, start).expect("fit");
    let first = fit(&ties, Start::Cold(Some(anchors[2])));
    let wider: Vec<Tie> = ties.iter().map(|t| Tie { sigma: 0.08, ..*t }).collect();
    let cold = fit(&wider, Start::Cold(Some(anchors[2])));
    let warm = fit(&wider, Start::Warm(first.pose));
    // The difference in the pose's local parameters, against its deviations.
    let apart = |p: &CrossPose, q: &CrossPose| -> V6 {
        let turn = nalgebra::Rotation3::from_matrix_unchecked(p.rotation * q.rotation.transpose());
        let t = turn.scaled_axis();
        let c = p.centre - q.centre;
        V6::new(t.x, t.y, t.z, c.x, c.y, c.z)
    };
    let sd = V6::from_fn(|i, _| cold.h_inv[(i, i)].sqrt());
    let worst = |d: V6| d.component_div(&sd).amax();
    assert!(
        worst(apart(&warm.pose, &cold.pose)) < 0.01,
        "{}",
        worst(apart(&warm.pose, &cold.pose))
    );
    assert!(
        worst(apart(&cold.pose, &truth)) < 5.0,
        "{}",
        worst(apart(&cold.pose, &truth))
    );
}

/// A superseded epoch's fits stop before the anchors' uncertainty is carried into
/// them: once cancelled, no fit is propagated.
#[test]
fn a_cancelled_propagation_gives_no_pose() {
    let (anchors, _, ties) = ties_around_anchors();
    let params = EstimateParams::default();
    let fit = || {
        fit_pose(
            1000.0,
            &anchors,
            1.0,
            &params,
            &ties,
            Start::Cold(Some(anchors[2])),
        )
    };
    let cov = Mat::<f64>::identity(POSE_DOF * anchors.len(), POSE_DOF * anchors.len()) * 1e-8;
    let fits = || vec![fit(), None, fit()];
    let count = |out: Vec<Option<Fitted>>| out.iter().filter(|f| f.is_some()).count();
    assert_eq!(count(propagated_all(fits(), &cov, &params)), 2);
    params.cancel.cancel();
    assert_eq!(count(propagated_all(fits(), &cov, &params)), 0);
}

/// Six anchor poses, the pose between them they are fitted against (the truth), and
/// its ties with them: its crossings with each anchor's planes, 0.05 px of noise across.
fn ties_around_anchors() -> (Vec<CrossPose>, CrossPose, Vec<Tie>) {
    let anchors: Vec<CrossPose> = (0..6).map(|k| pose(0.37 * f64::from(k) - 0.9)).collect();
    let truth = pose(0.25);
    let focal_px = 1000.0;
    let mut rng = crate::rng::SplitMix64::new(3);
    let mut ties = Vec::new();
    for (a, anchor) in anchors.iter().enumerate() {
        for (la, l) in [(0, 0), (0, 1), (1, 0), (1, 1)] {
            let (Some(vf), Some(va)) = (truth.plane(l), anchor.plane(la)) else {
                continue;
            };
            // On both planes: (v_f − v_a) · r = 0, with 0.05 px of noise across.
            let d = vf - va;
            for x in [-0.3, -0.15, 0.0, 0.15, 0.3] {
                let y = -(d.x * x + d.z) / d.y;
                if y.is_nan() || y.abs() >= 0.4 {
                    continue;
                }
                let y = y + 0.05 / focal_px * (2.0 * rng.next_f64() - 1.0) * 3f64.sqrt();
                ties.push(Tie {
                    laser: l,
                    other: Some((a, la)),
                    ray: Ray {
                        r: V3::new(x, y, 1.0),
                        dr_dscale: V3::zeros(),
                    },
                    sigma: 0.05,
                    class: 0,
                });
            }
        }
    }
    assert!(ties.len() >= 40, "{} ties", ties.len());
    (anchors, truth, ties)
}

/// The fit's normal equations, from each tie's residual alone and the pose's planes
/// linearised once, are those of the whole terms ([`term`]) to the bit: every entry
/// of `H` (its upper triangle mirrored) and the gradient; the cost to rounding.
#[test]
fn the_normal_equations_are_the_whole_terms_to_the_bit() {
    let anchors: Vec<CrossPose> = (0..5).map(|k| pose(0.31 * f64::from(k) - 0.5)).collect();
    let ties: Vec<Tie> = (0..40)
        .map(|k| Tie {
            laser: k % 2,
            other: (k % 7 != 0).then_some((k % 5, (k / 2) % 2)),
            ray: Ray {
                r: V3::new(0.02 * (k as f64) - 0.4, 0.3 - 0.015 * (k as f64), 1.0),
                dr_dscale: V3::new(-0.1, 0.07, 0.0),
            },
            sigma: 0.05 + 0.01 * (k % 3) as f64,
            class: k % 2,
        })
        .collect();
    let fitted = pose(0.2);
    let (focal_px, lambda, loss, inflate) = (1100.0, 1.03, Loss::Cauchy(2.0), 1.7);
    let held = held_planes(&ties, &anchors);
    let (cost, h, g) = normal_equations(&fitted, (&ties, &held), focal_px, lambda, loss, inflate);
    let (mut cost0, mut h0, mut g0) = (0.0, M6::zeros(), V6::zeros());
    for tie in &ties {
        let Some(t) = term(&fitted, tie, &anchors, focal_px, lambda) else {
            continue;
        };
        let sigma = tie.sigma * inflate;
        let x = t.e / sigma;
        cost0 += loss.cost(x);
        let w = loss.weight(x) / (sigma * sigma);
        let j = V6::from_column_slice(&t.ja);
        h0 += j * j.transpose() * w;
        g0 += j * (w * t.e);
    }
    assert!(cost0 > 0.0 && h0.trace() > 0.0);
    // The cost is summed by products of its logarithms' arguments: to rounding.
    assert!(
        (cost - cost0).abs() <= 1e-13 * cost0,
        "{cost} against {cost0}"
    );
    assert_eq!(h.map(f64::to_bits), h0.map(f64::to_bits));
    assert_eq!(g.map(f64::to_bits), g0.map(f64::to_bits));
}
