//! When self-calibrated planes must not give a cloud: the two checks that judge the
//! estimate from outside it, the crossing check's count and the planes' fit against the
//! extraction's own precision. Used by [`super::reconstruct_scan`] and the daemon's
//! epochs alike. Between what right planes show and the crossing check's limit, its
//! count makes a doubt ([`doubts`]): the cloud is written, and the user is told.

use crate::cloud;

/// How well self-calibrated planes fit the strong crossings, against how well the
/// extraction says they can be fitted.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Fit {
    /// The estimate's spread of the strong crossings' residuals, pixels.
    pub fitted_px: f64,
    /// The extraction's predicted precision of the same crossings, pixels (the median
    /// of their refinements' deviations, [`crate::intersect::RefinedCrossing::sigma`]).
    pub predicted_px: f64,
}

impl Fit {
    /// The fit of `calibration`'s planes to the strong crossings against `predicted_px`;
    /// `None` without either.
    pub fn of(calibration: &crate::solve::Calibration, predicted_px: Option<f64>) -> Option<Self> {
        calibration
            .summary
            .spreads
            .zip(predicted_px)
            .map(|(s, predicted_px)| Self {
                fitted_px: s.crossing_px[0],
                predicted_px,
            })
    }
}

/// How many times the extraction's predicted crossing precision the planes' fit may be.
/// The prediction comes from each crossing's two local fits ([`crate::intersect::
/// refine_crossing`]) and reads low, since neighbouring ridge points share noise and the
/// planes' model has its own errors (refraction, distortion). Measured with the right
/// planes on the 48 configurations of both generality draws (rooms, tables, clutter,
/// water at turbidity up to 1.2): 1.4 to 5.0 times it, median 2.4. A wrong basin whose
/// planes the crossing check cannot catch, since the crossings agree with them, fit
/// held-out seed 122 at 28-35 times it. Twice the largest seen in right solutions: a fit
/// past it is not extraction noise (docs/method.md).
pub(crate) const FIT_LIMIT: f64 = 10.0;

/// The least crossing precision [`refusal`] credits the extraction with, pixels: curves
/// drawn without noise (tests) are placed to rounding, which no fit matches; real ones
/// are predicted at 0.003-0.044 px (the same 48 configurations).
const PRECISION_FLOOR_PX: f64 = 1e-3;

/// Why self-calibrated planes must not give a cloud, in words; `None` when they may.
///
/// 1. More points left out for disagreeing at crossings than kept. The estimator does
///    not make this test of itself: the crossing check ([`crate::cloud::check_crossings`])
///    compares the depths the planes give at every crossing of the cloud's curves, so
///    when it leaves out more points than it keeps, the planes are not the ones the
///    curves describe (a wrong basin), however well the estimate fits its own weights;
///    what it keeps then lies on wrong planes too (generality seed 122: 12,782 points
///    kept, every one on a plane over 2 % off). Right solutions on the generality bench
///    lose at most 15 % of their points to it (turbid water); the wrong basins seen,
///    80-95 %.
/// 2. The planes fit the strong crossings more than [`FIT_LIMIT`] times worse than the
///    extraction places them (`fit`): a wrong basin the crossings agree with, which the
///    first test cannot see (seed 122 under another start: 97.5 % of 274,151 points on
///    wrong planes, fitted at 0.30 px where the curves give 0.011 px).
///
/// Used by the daemon's epochs as well.
pub(crate) fn refusal(stats: &cloud::TriangulateStats, fit: Option<Fit>) -> Option<String> {
    const ADVICE: &str = "The report has the estimate. Give the focal length if it is \
        known (without --estimate-focal), sweep the cross over more relief, or lower the \
        laser power if the stripes saturate. A rolling-shutter camera (most webcams and \
        action cameras) sees a fast-moving cross on planes that turn while the rows are \
        read out, which no single plane per frame fits: sweep more slowly, or use a \
        global-shutter camera";
    if stats.inconsistent_points > stats.kept {
        return Some(format!(
            "the self-calibration failed its check, so no cloud is written: the planes' \
             depths disagree at the crossings of most curves ({} points left out for it, \
             {} agreeing), so the planes are not the ones the curves describe. {ADVICE}",
            stats.inconsistent_points, stats.kept
        ));
    }
    let fit = fit.filter(|f| f.predicted_px > 0.0)?;
    let ratio = fit.fitted_px / fit.predicted_px.max(PRECISION_FLOOR_PX);
    (ratio > FIT_LIMIT).then(|| {
        format!(
            "the self-calibration failed its check, so no cloud is written: the planes fit \
             the crossings to {:.3} px where the curves place them to {:.4} px, {:.0} \
             times worse (right planes fit within 5 times, and {FIT_LIMIT:.0} is the \
             limit), so the planes are not the ones the curves describe. {ADVICE}",
            fit.fitted_px, fit.predicted_px, ratio
        )
    })
}

/// The largest share of the triangulated points that right planes lose to the crossing
/// check: at most 15 % on both generality draws (turbid water), 0.2-2.4 % on the others.
/// Past it, the check's premise (a wrong curve is one among right ones, which disagree
/// only with it) no longer holds of the cloud.
const DOUBT_INCONSISTENT_SHARE: f64 = 0.15;

/// Why planes that pass [`refusal`] are still in doubt, in words: more of the points
/// left out for disagreeing at crossings than right planes lose. A wrong basin between
/// that and the refusal: generality seed 104 at 100 frames, before a crossing behind
/// the camera counted against a solution (docs/method.md), 43 % of the points
/// disagreeing and every kept point on a plane over 2 % off, where the same frames
/// started from the true planes lose 0.2 % (at 300 frames, 0.7 %). Its fit did not
/// tell: 5.8 times the extraction's precision, and 5.5 from the true planes.
pub(crate) fn doubts(stats: &cloud::TriangulateStats) -> Option<String> {
    let judged = stats.kept + stats.inconsistent_points;
    let share = stats.inconsistent_points as f64 / judged.max(1) as f64;
    (share > DOUBT_INCONSISTENT_SHARE).then(|| {
        format!(
            "{:.0} % of the curve points are left out because their planes' depths disagree \
             at the crossings (right planes lose at most {:.0} %): the planes may not be \
             the ones the curves describe. Record longer or sweep the cross over more \
             relief, and check the cloud against a known distance",
            100.0 * share,
            100.0 * DOUBT_INCONSISTENT_SHARE
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn stats(kept: usize, inconsistent_points: usize) -> cloud::TriangulateStats {
        cloud::TriangulateStats {
            kept,
            inconsistent_points,
            ..Default::default()
        }
    }

    /// Generality seed 104 at 100 frames: the wrong basin passes the refusal (fewer
    /// points disagree than are kept) and is told as a doubt; the same frames from the
    /// true planes, and the scan at 300 frames, are not.
    #[test]
    fn a_cloud_between_right_planes_and_the_refusal_is_in_doubt() {
        let wrong = stats(75_490, 58_129);
        assert!(refusal(&wrong, None).is_none());
        let doubt = doubts(&wrong).expect("a doubt");
        assert!(doubt.starts_with("44 % of the curve points"), "{doubt}");
        assert!(doubts(&stats(152_088, 299)).is_none());
        assert!(doubts(&stats(457_389, 3_200)).is_none());
        // Turbid water, right planes: the most the draws lost.
        assert!(doubts(&stats(85_000, 15_000)).is_none());
        assert!(doubts(&stats(0, 0)).is_none());
    }
}
