//! The shape of a ridge point's profile across its line, the test by which, against a
//! local background, a point on a patch of surface is told from a point on a beam.
//!
//! A laser stripe's profile is bell-shaped: the beam's Gaussian, blurred by the optics,
//! of which the local background (an opening) leaves the cap ([`FlatTop`]). A surface
//! in the laser's own hue narrower than the opening's window (the face of a box seen at
//! an angle, a checker square, a painted band) stays in the response as a flat top whose
//! sides are as steep as the optics allow. Its centre is a ridge at the scale of its
//! width, with dark flanks, so neither the Hessian nor the flank test tells it from a
//! wide stripe, and the tiles' own flatness rule (`width.rs`) misses it where the
//! tile's brightest part is elsewhere (a face shaded along its length). Its shape does:
//! the profile's width at 20 % of its centre over its width at 80 % is 2.685 for every
//! Gaussian, whatever its amplitude and width, 2 for the flattest cap, and close to 1
//! for a flat top.

/// Width of a Gaussian's profile at 20 % of its peak over its width at 80 %:
/// `√(ln 5 / ln 1.25)`.
#[cfg(test)]
const GAUSSIAN_RATIO: f32 = 2.685;

/// Profiles narrower than this at half their centre (px) are not judged: the tiles'
/// own flatness limit. A flat top this narrow is blurred by the optics towards a bell,
/// and a beam's 80 % width (under 2.6 px) is too few pixels to measure (judged from
/// 4 px, the realistic bench lost 3 % of its recall).
const MIN_JUDGED_WIDTH_PX: f32 = super::width::FLAT_MIN_WIDTH as f32;

/// The optics' blur (σ, px) assumed for the sides of a flat top: a focused camera's.
/// More blur makes a flat top rounder, and the test more lenient.
const OPTICS_BLUR_PX: f64 = 1.0;

/// How much wider (px) than the widest cap a beam's profile may measure at half its
/// centre, for the noise of that measure: beyond, every profile is flat.
const WIDEST_CAP_MARGIN_PX: f64 = 1.0;

/// Bins (px) of the half-maximum width over which the thresholds are tabulated.
const BIN_PX: f32 = 0.25;

/// The ratio of widths (20 % over 80 %) below which a profile of a given half-maximum
/// width is a flat top, against a local background of a given window.
///
/// That background (a morphological opening `2r + 1` px wide) leaves of a beam of std
/// `s` its cap above its value `r` px off centre: `g(d) − g(r)`. The cap's ratio falls
/// from a Gaussian's (2.685, `s ≪ r`) to a parabola's (`√(0.8 / 0.2)` = 2, `s ≫ r`), and
/// its half-maximum width is at most `√2 r`. A flat top `W` px wide whose sides are
/// blurred by [`OPTICS_BLUR_PX`] has `(W + 1.68 b) / (W − 1.68 b)`: 1.78 at 6 px, 1.25
/// at 15. At each width the line is the geometric mean of the two ratios, as far (in
/// ratio) from either shape.
#[derive(Clone, Debug)]
pub(super) struct FlatTop {
    thresholds: Vec<f32>,
}

impl FlatTop {
    /// The thresholds for an opening of half width `radius_px`, from
    /// [`MIN_JUDGED_WIDTH_PX`] to the window's full width (wider flat tops are the
    /// background's own).
    pub(super) fn new(radius_px: usize) -> Self {
        let r = radius_px.max(1) as f64;
        let bins =
            ((2.0 * r + 1.0 - MIN_JUDGED_WIDTH_PX as f64) / BIN_PX as f64).ceil() as usize + 1;
        let thresholds = (0..bins)
            .map(|i| {
                let w50 = MIN_JUDGED_WIDTH_PX as f64 + i as f64 * BIN_PX as f64;
                if w50 > std::f64::consts::SQRT_2 * r + WIDEST_CAP_MARGIN_PX {
                    return f32::INFINITY;
                }
                let b = 1.68 * OPTICS_BLUR_PX;
                let flat = (w50 + b) / (w50 - b);
                (flat * cap_ratio(w50, r)).sqrt() as f32
            })
            .collect();
        Self { thresholds }
    }

    /// The threshold for a profile `w50` px wide at half its centre.
    fn threshold(&self, w50: f32) -> f32 {
        let i = ((w50 - MIN_JUDGED_WIDTH_PX) / BIN_PX).round().max(0.0) as usize;
        self.thresholds[i.min(self.thresholds.len() - 1)]
    }
}

/// The ratio of widths (20 % over 80 %) of the cap `g(d) − g(r)` of a Gaussian whose cap
/// is `w50` px wide at half its height; a parabola's (2) at and beyond the widest cap,
/// `√2 r`.
fn cap_ratio(w50: f64, r: f64) -> f64 {
    // The distance at which the cap of a Gaussian of std `s` falls to `level` of its
    // height.
    let at = |s: f64, level: f64| {
        let c = (-0.5 * r * r / (s * s)).exp();
        s * (-2.0 * (c + level * (1.0 - c)).ln()).sqrt()
    };
    if w50 >= std::f64::consts::SQRT_2 * r {
        return 2.0;
    }
    // The cap's width grows with `s`, from the Gaussian's own 2.355 s.
    let (mut lo, mut hi) = (0.5 * w50 / 2.3548, 1e3 * r);
    for _ in 0..100 {
        let mid = 0.5 * (lo + hi);
        if 2.0 * at(mid, 0.5) < w50 {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    at(lo, 0.2) / at(lo, 0.8)
}

/// Step (px) of the walk out along the normal.
const STEP_PX: f32 = 1.0;
/// Offsets (px) along the line of the samples averaged at each step.
const ALONG: [f32; 5] = [-2.0, -1.0, 0.0, 1.0, 2.0];

/// The levels, as shares of the centre, at which the profile's widths are read.
const LEVELS: [f32; 3] = [0.8, 0.5, 0.2];

/// One side of the walk out from a ridge point: where it is, the last sample, and the
/// crossings of [`LEVELS`] found so far.
struct Side {
    d: f32,
    prev: f32,
    next: usize,
    crossings: [f32; 3],
}

impl Side {
    fn new(centre: f32) -> Self {
        Self {
            d: 0.0,
            prev: centre,
            next: 0,
            crossings: [0.0; 3],
        }
    }

    /// Walks on until the first `upto` levels are crossed; false past `reach`.
    fn walk(&mut self, mean: impl Fn(f32) -> f32, centre: f32, upto: usize, reach: f32) -> bool {
        while self.next < upto {
            if self.d >= reach {
                return false;
            }
            self.d += STEP_PX;
            let v = mean(self.d);
            while self.next < LEVELS.len() && v < LEVELS[self.next] * centre {
                let level = LEVELS[self.next] * centre;
                // Where the line from the last sample to this one crosses the level.
                let frac = if self.prev > v {
                    ((self.prev - level) / (self.prev - v)).clamp(0.0, 1.0)
                } else {
                    1.0
                };
                self.crossings[self.next] = self.d - STEP_PX * (1.0 - frac);
                self.next += 1;
            }
            self.prev = v;
        }
        true
    }
}

/// Widths (px) of the response's profile across a line at `p` (unit normal `n`) at
/// 80, 50 and 20 % of `centre`, each side's crossing interpolated between the steps of
/// a walk out to `reach` px; each sample is the mean of five along the line. `None`
/// when a side does not fall to 20 % within `reach`, or when the profile is narrower
/// than `min_w50` at half its centre: then the walk stops there, as most beams do.
pub(super) fn level_widths(
    sample: impl Fn(f32, f32) -> f32,
    p: [f32; 2],
    n: [f32; 2],
    centre: f32,
    reach: f32,
    min_w50: f32,
) -> Option<[f32; 3]> {
    let mean = |d: f32| -> f32 {
        let (cx, cy) = (p[0] + d * n[0], p[1] + d * n[1]);
        ALONG
            .iter()
            .map(|&t| sample(cx - t * n[1], cy + t * n[0]))
            .sum::<f32>()
            / ALONG.len() as f32
    };
    let (mut behind, mut ahead) = (Side::new(centre), Side::new(centre));
    let (back, on) = (|d: f32| mean(-d), |d: f32| mean(d));
    if !(behind.walk(back, centre, 2, reach) && ahead.walk(on, centre, 2, reach)) {
        return None;
    }
    if behind.crossings[1] + ahead.crossings[1] < min_w50 {
        return None;
    }
    if !(behind.walk(back, centre, 3, reach) && ahead.walk(on, centre, 3, reach)) {
        return None;
    }
    Some(std::array::from_fn(|k| {
        behind.crossings[k] + ahead.crossings[k]
    }))
}

impl FlatTop {
    /// Whether the profile across a ridge point is flat-topped: wide enough to judge
    /// ([`MIN_JUDGED_WIDTH_PX`]) and with a ratio of widths under the threshold for its
    /// width. A profile that does not fall to 20 % within `reach` is not judged here
    /// (the flank test sees to it).
    pub(super) fn flat_topped(
        &self,
        sample: impl Fn(f32, f32) -> f32,
        p: [f32; 2],
        n: [f32; 2],
        centre: f32,
        reach: f32,
    ) -> bool {
        if centre <= 0.0 {
            return false;
        }
        level_widths(sample, p, n, centre, reach, MIN_JUDGED_WIDTH_PX)
            .is_some_and(|[w80, w50, w20]| w20 < self.threshold(w50) * w80)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A profile `f(d)` across a vertical line at x = 50, the same on every row.
    fn across(f: impl Fn(f32) -> f32) -> impl Fn(f32, f32) -> f32 {
        move |x, _y| f(x - 50.0)
    }

    /// (Whether the test takes a beam for a flat top is judged on what the local
    /// background leaves of it, its cap: below.)
    #[test]
    fn the_ratio_of_a_gaussian_is_its_own_at_any_width() {
        for s in [3.0f32, 4.5, 6.0] {
            let g = across(|d| 40.0 * (-0.5 * d * d / (s * s)).exp());
            let [w80, w50, w20] = level_widths(&g, [50.0, 20.0], [1.0, 0.0], 40.0, 8.0 * s, 0.0)
                .expect("falls to 20 %");
            assert!((w50 / (2.3548 * s) - 1.0).abs() < 0.02, "s {s}: fwhm {w50}");
            assert!(
                (w20 / w80 / GAUSSIAN_RATIO - 1.0).abs() < 0.05,
                "s {s}: {w20} / {w80}"
            );
        }
    }

    #[test]
    fn a_flat_top_with_blurred_sides_is_flat_and_a_narrow_one_is_not_judged() {
        // A band 13 px wide, its sides blurred over about 1 px (a logistic step).
        let band = |width: f32| {
            across(move |d| {
                let side = |e: f32| 1.0 / (1.0 + (-1.7 * e).exp());
                30.0 * side(0.5 * width - d.abs())
            })
        };
        let test = FlatTop::new(8);
        let wide = band(13.0);
        assert!(test.flat_topped(&wide, [50.0, 20.0], [1.0, 0.0], 30.0, 20.0));
        let narrow = band(4.0);
        assert!(!test.flat_topped(&narrow, [50.0, 20.0], [1.0, 0.0], 30.0, 20.0));
    }

    /// What an opening of half width 8 px leaves of beams from 3 to 40 px std (their
    /// caps, up to a parabola) is no flat top; boxes from 7 to 17 px wide, their sides
    /// blurred over 1 px, all are.
    #[test]
    fn caps_of_beams_of_any_width_are_beams_and_boxes_are_flat() {
        let r = 8.0f32;
        let test = FlatTop::new(r as usize);
        let at = [50.0, 20.0];
        for s in [3.0f32, 4.0, 5.5, 8.0, 12.0, 20.0, 40.0] {
            let g = move |d: f32| (-0.5 * d * d / (s * s)).exp();
            let cap = across(move |d| 50.0 * (g(d) - g(r)).max(0.0));
            let centre = 50.0 * (1.0 - g(r));
            assert!(
                !test.flat_topped(&cap, at, [1.0, 0.0], centre, 30.0),
                "s {s}"
            );
        }
        for width in [7.0f32, 9.0, 11.0, 13.0, 15.0, 17.0] {
            let side = |e: f32| 1.0 / (1.0 + (-1.7 * e).exp());
            let band = across(move |d| 30.0 * side(0.5 * width - d.abs()));
            assert!(
                test.flat_topped(&band, at, [1.0, 0.0], 30.0, 30.0),
                "width {width}"
            );
        }
    }

    #[test]
    fn a_profile_that_stays_up_is_not_judged() {
        let ramp = across(|d| 30.0 - 0.5 * d.abs());
        assert_eq!(
            level_widths(&ramp, [50.0, 20.0], [1.0, 0.0], 30.0, 10.0, 0.0),
            None
        );
        assert!(!FlatTop::new(8).flat_topped(&ramp, [50.0, 20.0], [1.0, 0.0], 30.0, 10.0));
    }
}
