//! The detector's choice of scale, tile by tile: the width of the stripe in a tile,
//! measured on the response from the second moments of its half-maximum band, and the
//! two rules by which a tile's band is no stripe at all (round, or flat-topped where the
//! laser's own channel is not clipped). `detect.rs` runs the filters at that scale.

use super::Detector;

/// Margin around an active tile over which its stripe width is measured.
pub(super) const WIDTH_MARGIN: usize = 8;

/// Level (share of the window's maximum) of the top band of [`Detector::stripe_width`].
const TOP_LEVEL: f32 = 0.8;
/// Width of a Gaussian's band above [`TOP_LEVEL`] of its peak over its FWHM:
/// `√(ln(1 / 0.8) / ln 2)`.
const TOP_TO_HALF_WIDTH: f64 = 0.567;
/// A top band narrower than this share of the half-maximum band (after the Gaussian's
/// own ratio) means a stripe on a pedestal.
const PEDESTAL_RATIO: f64 = 0.6;

/// Integer moments of a band of pixels about the window's corner: exact, and at most
/// 48² pixels.
#[derive(Default)]
struct BandMoments {
    n: i64,
    sx: i64,
    sy: i64,
    sxx: i64,
    sxy: i64,
    syy: i64,
}

impl BandMoments {
    fn add(&mut self, i: i64, j: i64) {
        self.n += 1;
        self.sx += i;
        self.sy += j;
        self.sxx += i * i;
        self.sxy += i * j;
        self.syy += j * j;
    }

    /// The smaller and the larger eigenvalue of the covariance of the band's positions
    /// (at least 3 of them).
    fn spreads(&self) -> Option<(f64, f64)> {
        if self.n < 3 {
            return None;
        }
        let nf = self.n as f64;
        let (mx, my) = (self.sx as f64 / nf, self.sy as f64 / nf);
        let cxx = self.sxx as f64 / nf - mx * mx;
        let cxy = self.sxy as f64 / nf - mx * my;
        let cyy = self.syy as f64 / nf - my * my;
        let half_trace = 0.5 * (cxx + cyy);
        let disc = (0.25 * (cxx - cyy) * (cxx - cyy) + cxy * cxy).sqrt();
        Some(((half_trace - disc).max(0.0), half_trace + disc))
    }

    /// Width across of the band: `√12` times the square root of the smaller eigenvalue
    /// of the covariance of its positions (a band `w` wide has `w² / 12`).
    fn width(&self) -> f64 {
        self.spreads()
            .map_or(self.n as f64, |(across, _)| (12.0 * across).sqrt())
    }

    /// The smaller over the larger of those eigenvalues: `(w / L)²` for a band `w` wide
    /// and `L` long, 1/4 for two equal arms at a right angle, about 1 for a patch or a
    /// pattern spread over the window.
    fn roundness(&self) -> f64 {
        self.spreads().map_or(
            0.0,
            |(across, along)| {
                if along > 0.0 {
                    across / along
                } else {
                    0.0
                }
            },
        )
    }
}

/// Above this [`BandMoments::roundness`], a tile's half-maximum band is no stripe, and
/// where the response still holds the surfaces' texture (against a local background)
/// the tile is not searched ([`Detector::texture_kept`]). The squares of a checkerboard
/// in a laser's own hue narrower than the local background's window stay in the
/// response, and its widest scale blurs them into ridges along their diagonals; their
/// band fills the window about evenly (near 1). A stripe crossing the window is a
/// band `(w / L)²`, 0.03 for 8 px across 48; bent at a right angle 0.25; ending in the
/// window after `1.4 w`, 0.5. So a stripe is kept up to its last `1.4 w`, and
/// one fainter than twice a laser-hued texture under it, whose band the texture
/// fills, is lost: not told apart from the texture there.
const MAX_BAND_ROUNDNESS: f64 = 0.5;

/// [`Detector`]'s level of a tile not searched ([`MAX_BAND_ROUNDNESS`], [`FLAT_RATIO`]).
pub(super) const NO_LINE: u8 = u8::MAX;

/// A tile's band is flat-topped, a patch of a surface rather than a beam, when its part
/// above [`TOP_LEVEL`] of the peak is at least this share of its half-maximum width
/// (after the grid's own pixel). A Gaussian's share is [`TOP_TO_HALF_WIDTH`] (0.567); a
/// box's is 1, less its blurred sides. Then, against a local background, the tile is
/// not searched, unless the laser's own channel is clipped there (a clipped core is
/// flat too, and is a stripe).
const FLAT_RATIO: f64 = 0.8;
/// Below this half-maximum width (px) a band's flatness is not judged: at 6 px a
/// Gaussian's top band is 3.4 px, and a pixel more of it, by sampling, gives 0.74, still
/// under [`FLAT_RATIO`]; narrower, a pixel is too much of the measure. Each ridge
/// point's own profile test (`profile.rs`) starts at the same width.
pub(super) const FLAT_MIN_WIDTH: f64 = 6.0;

impl Detector {
    /// Full width at half maximum (px) of the stripe in active tile `t`, measured on
    /// the response over the tile and [`WIDTH_MARGIN`] around it: the pixels at or
    /// above half the window's maximum form a band across the stripe; its second
    /// moment across (the smaller eigenvalue of the covariance of their positions) is
    /// `w² / 12` for a band `w` wide, whatever its direction, and the window cutting
    /// the band's length does not change it. A curve or a blob only widens it, which
    /// errs towards a larger scale.
    ///
    /// A stripe on a pedestal (under water, the glow of its own sheet lies along one
    /// side of it) would give the pedestal's width, and a scale that merges the two
    /// into one ridge in the middle of the glow. So the band above [`TOP_LEVEL`] of the
    /// maximum is measured too: on a Gaussian stripe it is [`TOP_TO_HALF_WIDTH`] as
    /// wide as the half-maximum band, on a flat top about as wide; when it is much
    /// narrower than that ([`PEDESTAL_RATIO`]), the stripe is the peak on top and its
    /// width is taken from the top band. Also returns whether, the response holding
    /// texture ([`Self::texture_kept`]), the band is no stripe: round
    /// ([`MAX_BAND_ROUNDNESS`]) or flat-topped where the own channel is not clipped
    /// ([`FLAT_RATIO`]).
    pub(super) fn stripe_width(&self, t: usize) -> (f64, bool) {
        let (x0, x1, y0, y1) = self.tile_bounds(t);
        let m = WIDTH_MARGIN;
        let (xa, xb) = (x0.saturating_sub(m), (x1 + m).min(self.width));
        let (ya, yb) = (y0.saturating_sub(m), (y1 + m).min(self.height));
        let w = self.width;
        let mut peak = 0.0f32;
        for y in ya..yb {
            peak = self.response[y * w + xa..y * w + xb]
                .iter()
                .fold(peak, |p, &v| p.max(v));
        }
        if peak <= 0.0 {
            return (0.0, false);
        }
        let (half, top) = (0.5 * peak, TOP_LEVEL * peak);
        let mut half_band = BandMoments::default();
        let mut top_band = BandMoments::default();
        for (j, y) in (ya..yb).enumerate() {
            for (i, &v) in self.response[y * w + xa..y * w + xb].iter().enumerate() {
                if v >= half {
                    half_band.add(i as i64, j as i64);
                    if v >= top {
                        top_band.add(i as i64, j as i64);
                    }
                }
            }
        }
        let width = half_band.width();
        // The pixel grid widens a sampled band by a pixel's own second moment (1/12).
        let top_raw = (top_band.n >= 3).then(|| (top_band.width().powi(2) + 1.0).sqrt());
        let no_line = self.texture_kept && {
            let flat = top_raw.is_some_and(|t| width >= FLAT_MIN_WIDTH && t / width >= FLAT_RATIO);
            let clipped = || {
                (ya..yb).any(|y| {
                    self.masked[y * w + xa..y * w + xb]
                        .iter()
                        .any(|m| m & 2 != 0)
                })
            };
            half_band.roundness() > MAX_BAND_ROUNDNESS || (flat && !clipped())
        };
        if let Some(top_width) = top_raw.map(|t| t / TOP_TO_HALF_WIDTH) {
            if top_width < PEDESTAL_RATIO * width {
                return (top_width, no_line);
            }
        }
        (width, no_line)
    }
}
