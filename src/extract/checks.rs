//! Checks on a frame's curves once they are linked: the share of points measured where
//! the laser's own channel is clipped (and the advice when it is large), a curve of one
//! laser that only repeats another laser's (one overexposed laser seen as two), a curve
//! that runs along an edge of the scene (a chroma fringe, without a laser-off frame),
//! and whether both lasers of a two-laser setting are in the frames at all.
//!
//! Owns the counters across frames and the one-time warnings; changes no point.

use std::sync::{Arc, Mutex};

use image::RgbImage;

use super::{ColourLut, Curve, LaserColour};

/// A share of clipped points above this is worth telling the user.
pub const CLIPPED_WARN_SHARE: f64 = 0.2;
/// Points of a curve within this distance (px) of another laser's curve repeat it.
const REPEAT_PX: f32 = 2.0;
/// A curve whose points repeat another laser's curve for at least this share is the
/// other laser seen a second time.
const REPEAT_SHARE: f64 = 0.8;
/// Frames after which a laser never seen, while the other was in most, is absent.
const PRESENCE_FRAMES: usize = 10;

/// Points on clipped own channels, of all points of `curves` (lasers as in `lut`).
pub(crate) fn clipped_points(lut: &ColourLut, frame: &RgbImage, curves: &[Curve]) -> usize {
    let (w, h) = (frame.width() as usize, frame.height() as usize);
    let raw = frame.as_raw();
    curves
        .iter()
        .map(|c| {
            c.points_px
                .iter()
                .filter(|p| {
                    let (x, y) = (p[0].round() as usize, p[1].round() as usize);
                    x < w && y < h && lut.own_clipped(c.laser, &raw[3 * (y * w + x)..])
                })
                .count()
        })
        .sum()
}

/// Drops the curves of one laser that lie along another laser's curves (an
/// overexposed stripe's core is bright in every channel, and a two-laser setting
/// would read it once per laser); returns how many points were dropped. At the cross
/// centre the two stripes meet over a few pixels only, well under [`REPEAT_SHARE`].
pub(crate) fn drop_repeats(
    curves: &mut Vec<Curve>,
    (w, h): (usize, usize),
    scratch: &mut Vec<u8>,
) -> usize {
    scratch.clear();
    scratch.resize(w * h, 0);
    let r = REPEAT_PX.ceil() as isize;
    for c in curves.iter() {
        let bit = 1u8 << c.laser.min(7);
        for p in &c.points_px {
            let (x, y) = (p[0].round() as isize, p[1].round() as isize);
            for yy in (y - r).max(0)..(y + r + 1).min(h as isize) {
                for xx in (x - r).max(0)..(x + r + 1).min(w as isize) {
                    scratch[yy as usize * w + xx as usize] |= bit;
                }
            }
        }
    }
    // The weaker of two repeating curves goes: strength summed over its points.
    let total = |c: &Curve| c.strength.iter().map(|&s| s as f64).sum::<f64>();
    let mut dropped = 0;
    let mut keep = vec![true; curves.len()];
    for (i, c) in curves.iter().enumerate() {
        let others = !(1u8 << c.laser.min(7));
        let near = c
            .points_px
            .iter()
            .filter(|p| {
                let (x, y) = (p[0].round() as usize, p[1].round() as usize);
                x < w && y < h && scratch[y * w + x] & others != 0
            })
            .count();
        if (near as f64) < REPEAT_SHARE * c.points_px.len() as f64 {
            continue;
        }
        // Stronger than everything of the other lasers it lies along: keep it.
        let rival = curves
            .iter()
            .filter(|o| o.laser != c.laser)
            .map(total)
            .fold(0.0, f64::max);
        if total(c) < rival {
            keep[i] = false;
            dropped += c.points_px.len();
        }
    }
    let mut k = keep.iter();
    curves.retain(|_| *k.next().unwrap_or(&true));
    dropped
}

/// Half the distances (px) across a curve at which [`drop_edge_fringes`] compares the
/// light, the larger step counting: one and two 4:2:0 chroma blocks. A chroma fringe
/// lies within one block of its edge; the band that a patch too small for the local
/// background's window leaks along its edge lies beside the edge's blur, a block or two
/// further in, where one block out the step caught about half of the edge's contrast,
/// less than the band's strength. Two blocks alone miss a fringe beside a narrow
/// feature, whose far side is the same surface again. Measured on the realistic bench
/// without a background (12 scans, 36 frames), stray points / recall: 2 px 7.03 % /
/// 91.8 %, 4 px 4.81 % / 91.8 %, 2 and 4 px 4.69 % / 91.8 %, 2, 4 and 6 px 3.59 % /
/// 91.0 %: past two blocks the step takes in the texture beside real stripes.
const FRINGE_HALF_SPANS_PX: [f32; 2] = [2.0, 4.0];

/// Drops the curves that run along an edge of the scene rather than across it; returns
/// how many points were dropped.
///
/// Chroma subsampled over 2x2 pixels (MJPEG, JPEG) leaves a one-pixel line of pure
/// colour on the bright side of every edge that cuts a block, as strong as a faint
/// stripe and of any hue; the edge of a patch of the laser's own colour narrower than
/// the local background's opening is a ridge of its hue too. A laser adds light
/// symmetric about its ridge, in every channel, so the two sides of a stripe's centre
/// differ only by the surface under it; beside an edge they differ by its contrast. A
/// point *runs along an edge* when the largest step across it, over the three channels
/// and over [`FRINGE_HALF_SPANS_PX`] to either side along its normal, is larger than
/// its own ridge strength; a curve goes when most of its points do. A stripe crossing an edge
/// meets it at a few points, so it stays.
pub(crate) fn drop_edge_fringes(curves: &mut Vec<Curve>, frame: &RgbImage) -> usize {
    let (w, h) = (frame.width() as f32, frame.height() as f32);
    // The frame's three channels at (x, y), bilinear; none where the four pixels around
    // it are not all in the frame.
    let rgb = |x: f32, y: f32| {
        let inside = x >= 0.0 && y >= 0.0 && x.floor() + 1.0 < w && y.floor() + 1.0 < h;
        inside.then(|| crate::sample::rgb_f32(frame, x, y))
    };
    let along_edge = |c: &Curve| {
        let n = c.points_px.len();
        let mut along = 0;
        for i in 0..n {
            let (a, b) = (
                c.points_px[i.saturating_sub(2)],
                c.points_px[(i + 2).min(n - 1)],
            );
            let (tx, ty) = (b[0] - a[0], b[1] - a[1]);
            let len = tx.hypot(ty);
            if len <= 0.0 {
                continue;
            }
            let p = c.points_px[i];
            // The largest step over R, G and B between the two sides, `span` px out.
            let step_at = |span: f32| {
                let (nx, ny) = (-ty / len * span, tx / len * span);
                let u = rgb(p[0] + nx, p[1] + ny)?;
                let v = rgb(p[0] - nx, p[1] - ny)?;
                Some((0..3).map(|k| (u[k] - v[k]).abs()).fold(0.0, f32::max))
            };
            let step = FRINGE_HALF_SPANS_PX
                .iter()
                .filter_map(|&s| step_at(s))
                .fold(f32::NEG_INFINITY, f32::max);
            if step > c.strength[i] {
                along += 1;
            }
        }
        2 * along > n
    };
    let before: usize = curves.iter().map(|c| c.points_px.len()).sum();
    curves.retain(|c| !along_edge(c));
    before - curves.iter().map(|c| c.points_px.len()).sum::<usize>()
}

/// Counters across frames for the one-time warnings. Clones share them: every
/// extractor of one run (the workers of `reconstruct`, of the daemon) counts into one,
/// so that each warning is given once per run, and a laser missing from all the
/// frames is noticed however the frames are split among the extractors.
#[derive(Clone, Debug, Default)]
pub struct Presence(Arc<Mutex<Counts>>);

#[derive(Debug, Default)]
struct Counts {
    frames: usize,
    frames_with: [usize; 2],
    told_absent: bool,
    told_clipped: bool,
}

impl Presence {
    /// Counts a frame's `curves`; says once when one of two lasers is absent from the
    /// frames while the other is in most of them, and once when a frame's share of
    /// clipped points exceeds [`CLIPPED_WARN_SHARE`].
    pub(crate) fn observe(&self, lasers: &[LaserColour], curves: &[Curve], clipped: usize) {
        // A poisoned lock means another extractor panicked: a bug reported there.
        let Ok(mut counts) = self.0.lock() else {
            return;
        };
        counts.observe(lasers, curves, clipped);
    }

    /// Whether the absence of one laser has been told.
    pub fn absent_told(&self) -> bool {
        self.0.lock().is_ok_and(|c| c.told_absent)
    }
}

impl Counts {
    fn observe(&mut self, lasers: &[LaserColour], curves: &[Curve], clipped: usize) {
        self.frames += 1;
        let points: usize = curves.iter().map(|c| c.points_px.len()).sum();
        for k in 0..lasers.len().min(2) {
            if curves.iter().any(|c| c.laser as usize == k) {
                self.frames_with[k] += 1;
            }
        }
        if !self.told_clipped && points >= 50 && clipped as f64 > CLIPPED_WARN_SHARE * points as f64
        {
            self.told_clipped = true;
            tracing::warn!(
                "stripe saturated over {:.0} % of its length: lower the exposure or the laser power",
                100.0 * clipped as f64 / points as f64
            );
        }
        if lasers.len() == 2 && !self.told_absent && self.frames >= PRESENCE_FRAMES {
            for k in 0..2 {
                if self.frames_with[k] == 0 && 2 * self.frames_with[1 - k] > self.frames {
                    self.told_absent = true;
                    tracing::warn!(
                        "only the {} laser is in the frames ({} of {}), no {} one: is it on? (one laser: set lasers to {:?})",
                        lasers[1 - k].name,
                        self.frames_with[1 - k],
                        self.frames,
                        lasers[k].name,
                        lasers[1 - k].name
                    );
                }
            }
        }
    }
}
