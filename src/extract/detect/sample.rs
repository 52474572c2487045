//! What a ridge point's tests read of the response and the flags around it, beyond
//! its Hessian: the holes within its window, its flanks, its chromatic share and the
//! step across it, read for [`Detector::column_pass_and_hessian`]. Samplers only; the
//! decisions are the detector's.

use super::{Detector, Rect, SHARE_SHIFT, STEP_DISTANCES};
use crate::extract::colour::SHARE_FULL;

/// The response at `(x, y)`, bilinear between pixel centres, the border repeated.
#[inline]
pub(super) fn bilinear(response: &[f32], (w, h): (usize, usize), x: f32, y: f32) -> f32 {
    let (xf, yf) = (x.floor(), y.floor());
    let (fx, fy) = (x - xf, y - yf);
    let (x0, y0) = (xf as isize, yf as isize);
    let px = |xx: isize, yy: isize| {
        let xx = xx.clamp(0, w as isize - 1) as usize;
        let yy = yy.clamp(0, h as isize - 1) as usize;
        response[yy * w + xx]
    };
    (px(x0, y0) * (1.0 - fx) + px(x0 + 1, y0) * fx) * (1.0 - fy)
        + (px(x0, y0 + 1) * (1.0 - fx) + px(x0 + 1, y0 + 1) * fx) * fy
}

impl Detector {
    /// Whether a pixel zeroed for another colour lies within `r` of the pixels
    /// `[x0, x1) × [y0, y1)`: the smoothed response there is distorted by the hole (e.g.
    /// at the cross centre).
    pub(super) fn near_mask(
        masked: &[u8],
        (w, h): (usize, usize),
        r: usize,
        [x0, x1, y0, y1]: Rect,
    ) -> bool {
        let (xa, xb) = (x0.saturating_sub(r), (x1 + r).min(w));
        let (ya, yb) = (y0.saturating_sub(r), (y1 + r).min(h));
        // OR-ing whole rows, rather than stopping at the first hit, vectorises.
        (ya..yb).any(|yy| {
            masked[yy * w + xa..yy * w + xb]
                .iter()
                .fold(0, |a, &m| a | m)
                & 1
                != 0
        })
    }

    /// The response at `p` and at its two flanks, `flank_px` back and forth along the
    /// normal `n`: `[centre, behind, ahead]`, each the mean of three samples along
    /// the line.
    pub(super) fn flanks(
        response: &[f32],
        (w, h): (usize, usize),
        p: [f32; 2],
        n: [f32; 2],
        flank_px: f32,
    ) -> [f32; 3] {
        let at = |x: f32, y: f32| bilinear(response, (w, h), x, y);
        // Mean of three samples along the line (the tangent is (−ny, nx)).
        let mean = |d: f32| -> f32 {
            let (cx, cy) = (p[0] + d * n[0], p[1] + d * n[1]);
            (at(cx - n[1], cy + n[0]) + at(cx, cy) + at(cx + n[1], cy - n[0])) / 3.0
        };
        [mean(0.0), mean(-flank_px), mean(flank_px)]
    }

    /// The chromatic share of the ridge point at `p` (normal `n`): over the three
    /// pixels nearest to it along the line, the mean of their shares weighted by
    /// their response, 0 to 1. On a stripe it is the laser's own saturation (0.6–1,
    /// less where 4:2:0 chroma spreads the colour over the pixel beside it); on a
    /// grey or white texture near 0; on a pale tint in between.
    pub(super) fn chromatic_share(
        response: &[f32],
        masked: &[u8],
        (w, h): (usize, usize),
        p: [f32; 2],
        n: [f32; 2],
    ) -> f32 {
        let (mut sum, mut weighted) = (0.0f32, 0.0f32);
        for d in [-1.0f32, 0.0, 1.0] {
            let (x, y) = ((p[0] - d * n[1]).round(), (p[1] + d * n[0]).round());
            if x < 0.0 || y < 0.0 || x >= w as f32 || y >= h as f32 {
                continue;
            }
            let i = y as usize * w + x as usize;
            let r = response[i];
            sum += r;
            weighted += r * f32::from(masked[i] >> SHARE_SHIFT);
        }
        if sum > 0.0 {
            weighted / (sum * f32::from(SHARE_FULL))
        } else {
            0.0
        }
    }

    /// The step of the response across a line at `p` (normal `n`) at
    /// [`STEP_DISTANCES`] distances, `flank_px` out and one px apart: at each, the
    /// mean of three samples along the line ahead minus the same behind.
    pub(crate) fn step_across(
        &self,
        p: [f32; 2],
        n: [f32; 2],
        flank_px: f32,
    ) -> [f32; STEP_DISTANCES] {
        let at = |x: f32, y: f32| bilinear(&self.response, (self.width, self.height), x, y);
        let side = |d: f32| -> f32 {
            let (cx, cy) = (p[0] + d * n[0], p[1] + d * n[1]);
            at(cx - n[1], cy + n[0]) + at(cx, cy) + at(cx + n[1], cy - n[0])
        };
        std::array::from_fn(|k| {
            let d = flank_px + k as f32;
            (side(d) - side(-d)) / 3.0
        })
    }
}
