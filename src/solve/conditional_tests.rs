//! The poses fitted against the anchors ([`super::conditional`]) against the joint
//! estimate of every pose, on noisy analytic crossings of the synthetic room.

use super::calibrate::{calibrate, Calibration, PlaneVerdict};
use super::estimate_tests::{anchored_every, evidence_of};
use super::evidence::Evidence;
use super::synthetic::{path_scan, PathSpec};
use super::SolveParams;

/// Per crossing of a plane that is no anchor in `anchored`: the depth error (after the
/// one global scale) and the deviation both calibrations give it, the joint one's too.
fn depth_errors(
    ev: &Evidence,
    truth: &[nalgebra::Vector3<f64>],
    anchored: &Calibration,
    joint: &Calibration,
) -> Vec<(f64, f64, f64)> {
    let scale = |cal: &Calibration| {
        let ratios: Vec<f64> = ev
            .crossings
            .iter()
            .filter_map(|c| {
                let ray = cal.ray(c.u)?;
                Some(truth[c.a as usize].dot(&ray.r) / cal.plane(c.a as usize)?.dot(&ray.r))
            })
            .collect();
        super::median(ratios).expect("crossings")
    };
    let sa = scale(anchored);
    ev.crossings
        .iter()
        .filter(|c| !ev.is_anchor(ev.planes[c.a as usize].pose as usize))
        .filter_map(|c| {
            let ray = anchored.ray(c.u)?;
            let i = c.a as usize;
            let rho = anchored.plane(i)?.dot(&ray.r) * sa;
            let err = (truth[i].dot(&ray.r) / rho - 1.0).abs();
            Some((
                err,
                anchored.depth_sigma(i, &ray),
                joint.depth_sigma(i, &ray),
            ))
        })
        .collect()
}

/// Every third frame an anchor: the others, fitted against them, come out as the joint
/// estimate's, their deviations no smaller than the joint ones (the anchors' errors are
/// in them) and honest (the errors are about their size).
#[test]
fn poses_fitted_against_anchors_know_how_well_they_are_known() {
    let scan = path_scan(&PathSpec {
        frames: 90,
        ..PathSpec::default()
    });
    let truth = scan.flat_planes();
    let all = evidence_of(&scan, 0.1, 3, |_, _| true);
    let ev = anchored_every(all.clone(), 3);
    let params = SolveParams::default();
    let joint = calibrate(&all, &params).expect("joint");
    let anchored = calibrate(&ev, &params).expect("anchored");
    let determined = anchored
        .verdicts
        .iter()
        .filter(|v| **v == PlaneVerdict::Determined)
        .count();
    assert!(
        determined as f64 > 0.95 * ev.planes.len() as f64,
        "{determined} of {}",
        ev.planes.len()
    );
    let rows = depth_errors(&ev, &truth, &anchored, &joint);
    assert!(rows.len() > 500, "{}", rows.len());
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let finite: Vec<&(f64, f64, f64)> = rows
        .iter()
        .filter(|r| r.1.is_finite() && r.2.is_finite())
        .collect();
    let ratio = median(finite.iter().map(|r| r.1 / r.2).collect());
    assert!(
        (1.0..3.0).contains(&ratio),
        "fitted over joint deviation: {ratio}"
    );
    let z = median(finite.iter().map(|r| r.0 / r.1).collect());
    // |N(0,1)| has median 0.67. Without the anchors' errors in the deviations it is
    // 0.96 here: too small deviations.
    assert!(z > 0.45 && z < 0.9, "median error in deviations: {z}");
    let err = median(finite.iter().map(|r| r.0).collect());
    assert!(err < 1e-3, "median depth error {err}");
}

/// A cancelled solve (a live epoch the final solve supersedes) fits no pose outside the
/// anchors: each fit looks at the request first, and the fits are seconds of a core.
#[test]
fn a_cancelled_completion_fits_no_pose() {
    let scan = path_scan(&PathSpec {
        frames: 45,
        ..PathSpec::default()
    });
    let ev = anchored_every(evidence_of(&scan, 0.1, 3, |_, _| true), 3);
    let params = SolveParams::default();
    let split = super::conditional::AnchorSplit::of(&ev);
    let anchors = calibrate(&split.evidence, &params).expect("anchors");
    let outside = (0..ev.num_poses()).filter(|&p| !ev.is_anchor(p)).count();
    let fitted = |cancelled: bool| {
        let eparams = params.estimate_params();
        if cancelled {
            eparams.cancel.cancel();
        }
        let est = super::conditional::complete(&ev, &split, anchors.estimate.clone(), &eparams);
        (0..ev.num_poses())
            .filter(|&p| !ev.is_anchor(p) && est.marginals[p][(0, 0)].is_finite())
            .count()
    };
    assert!(outside > 20, "{outside} poses outside the anchors");
    assert_eq!(fitted(false), outside);
    assert_eq!(fitted(true), 0);
    // The fits themselves stop, not only the propagation after them.
    let fits = |cancelled: bool| {
        let eparams = params.estimate_params();
        if cancelled {
            eparams.cancel.cancel();
        }
        let est = &anchors.estimate;
        super::conditional::Outside::new(&ev, &split, est, &eparams)
            .fit_all(&est.spreads, None)
            .iter()
            .filter(|f| f.is_some())
            .count()
    };
    assert_eq!(fits(false), outside);
    assert_eq!(fits(true), 0);
}

/// Where the caller spares the cores, the solve runs its pieces, a consensus start's
/// draws and a start's further shifts side by side; the answer is the one of one
/// thread, to the bit.
#[test]
fn two_threads_give_the_answer_of_one() {
    let scan = path_scan(&PathSpec {
        frames: 90,
        ..PathSpec::default()
    });
    let ev = evidence_of(&scan, 0.1, 3, |_, _| true);
    let one = calibrate(&ev, &SolveParams::default()).expect("one thread");
    let two = calibrate(
        &ev,
        &SolveParams {
            dense_threads: super::dense::DenseThreads(2),
            ..SolveParams::default()
        },
    )
    .expect("two threads");
    let planes =
        |cal: &Calibration| -> Vec<_> { (0..ev.planes.len()).map(|i| cal.plane(i)).collect() };
    assert_eq!(planes(&one), planes(&two));
    assert!(planes(&one).iter().flatten().count() > ev.planes.len() / 2);
    assert_eq!(one.verdicts, two.verdicts);
    assert_eq!(one.estimate.poses, two.estimate.poses);
}

/// Where neither start finds anything (three frames: too few planes for the global
/// subset, and no centre whose crosses come out orthogonal), the error says so of both,
/// with the counts of planes and crossings there were, not only the linear start's
/// question whether the lasers were seen.
#[test]
fn without_any_start_the_error_names_both_and_what_there_was() {
    let scan = path_scan(&PathSpec {
        frames: 3,
        ..PathSpec::default()
    });
    let ev = evidence_of(&scan, 0.1, 3, |_, _| true);
    let err = calibrate(&ev, &SolveParams::default()).expect_err("no start");
    let super::SolveError::NoStart {
        planes,
        crossings,
        linear,
        ..
    } = &err
    else {
        panic!("another error: {err}");
    };
    assert_eq!((*planes, *crossings), (ev.planes.len(), ev.crossings.len()));
    assert!(
        matches!(**linear, super::SolveError::TooFewPlanes { .. }),
        "{linear}"
    );
    let message = err.to_string();
    assert!(
        message.contains(&format!("{} planes", ev.planes.len())),
        "{message}"
    );
    assert!(message.contains("fixed-centre start"), "{message}");
}
