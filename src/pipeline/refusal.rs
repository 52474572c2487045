//! When self-calibrated planes must not give a cloud: the two checks that judge the
//! estimate from outside it, the crossing check's count and the planes' fit against the
//! extraction's own precision. Used by [`super::reconstruct_scan`] and the daemon's
//! epochs alike.

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
