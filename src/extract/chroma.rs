//! Where a frame's colour was sampled coarser than its luma, and what that does to a
//! ridge point's centre.
//!
//! MJPEG cameras send 4:2:0 or 4:2:2 (chroma per 2×2 or 2×1 pixels), a YUYV camera
//! 4:2:2, and most video files 4:2:0. A decoder rebuilds the chroma at every pixel:
//! JPEG decoders (zune-jpeg, libjpeg) interpolate between the blocks' centres, FFmpeg's
//! unscaled conversion and a YUYV pair repeat it. A laser's own channel is largely
//! chroma (red is 70 % chroma and 30 % luma, green 41 %, blue 89 %), so a stripe
//! narrower than about three pixels reaches the detector as the sum of a sharp luma
//! profile and a chroma profile sampled every two pixels. Steger's centre is a
//! Gaussian-weighted centre of mass, and on that sum it is pulled towards the chroma
//! blocks' centres: a 2 px sawtooth of the stripe's position, up to ±0.1 px with
//! interpolation and ±0.2 px with repetition for a stripe 2.4 px wide (FWHM).
//!
//! Both are measured, not assumed:
//! - [`Sampling::read`] reads the rebuild off the frames themselves. Each rebuild leaves an
//!   exact linear relation between neighbouring pixels' chroma at one of the two
//!   phases of the 2 px grid (a repeated pair is equal; an interpolated run satisfies
//!   `c[2i+2] − c[2i−1] = 3 (c[2i+1] − c[2i])`), which no full-resolution chroma
//!   does.
//! - [`Sampling::normal_shift`] gives a ridge point's shift along its normal from the
//!   model of that rebuild: a Gaussian stripe of the point's own width (from its
//!   smoothed response and curvature), of which the point's own share of chroma (from
//!   its excess) goes through box averaging over the block and the rebuild, located as
//!   the detector does at its scale. Per axis, the shift is tabulated once
//!   ([`ShiftTable`]) as a sine series of the phase; along the line, the detector's
//!   window averages it over the phases the line passes through.
//!
//! Assumed: the encoder averages each block (libjpeg does) and sites its chroma at the
//! block's centre (JFIF). A camera that sites it on the first pixel (MPEG-2 4:2:2)
//! would need its own table; none is claimed here. Where the frames' bytes are ours to
//! decode (MJPEG, YUYV, a JPEG file), the decoder's knowledge is given to the extractor
//! ([`crate::capture::chroma`]) and nothing is read. Otherwise the extractor keeps what
//! a frame told it ([`Reader`]), so with several workers on a subsampled recording of
//! that kind the frames before a worker's first telling one get no move
//! (docs/extraction.md).

use image::RgbImage;

use super::colour::CLIP_LEVEL;
use super::detect::LinePoint;

mod model;
use model::{Series, ShiftTable};

pub use crate::capture::chroma::Rebuild;

/// A frame's chroma sampling, per axis (x, then y): how it was rebuilt, the first
/// pixel (0 or 1) of the first whole block, and whether a frame has told (an axis not
/// yet told is taken as full).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Sampling {
    pub rebuild: [Rebuild; 2],
    pub offset: [u8; 2],
    pub told: [bool; 2],
}

impl Sampling {
    /// Nothing told yet: no shift anywhere.
    pub const UNKNOWN: Self = Self {
        rebuild: [Rebuild::Full, Rebuild::Full],
        offset: [0, 0],
        told: [false, false],
    };

    /// As the decoder says the frame was rebuilt (`crate::capture::chroma`): told
    /// along both axes, the first block at pixel 0.
    pub fn known(rebuild: [Rebuild; 2]) -> Self {
        Self {
            rebuild,
            offset: [0, 0],
            told: [true, true],
        }
    }

    /// Whether any axis was subsampled.
    pub fn is_subsampled(&self) -> bool {
        self.rebuild != [Rebuild::Full; 2]
    }

    /// Whether both axes have been told.
    pub fn is_told(&self) -> bool {
        self.told == [true; 2]
    }

    /// The axes not yet told taken as full.
    pub fn settle(&mut self) {
        self.told = [true; 2];
    }
}

/// Frames read for their chroma sampling before an axis they did not tell is taken as
/// full ([`Reader::sampling`]).
const SAMPLING_TRIES: u32 = 30;

/// An extractor's reading of its frames' chroma sampling: kept once told (a camera
/// does not change it), read off each frame until then.
#[derive(Clone, Debug)]
pub(super) struct Reader {
    pub(super) sampling: Sampling,
    tries: u32,
}

impl Default for Reader {
    fn default() -> Self {
        Self {
            sampling: Sampling::UNKNOWN,
            tries: 0,
        }
    }
}

impl Reader {
    /// Takes the frames to come as rebuilt `rebuild` (known from their bytes), from now
    /// on without reading them.
    pub(super) fn know(&mut self, rebuild: [Rebuild; 2]) {
        self.sampling = Sampling::known(rebuild);
    }

    /// The sampling to take `frame` as having ([`Sampling::read`]): each axis read off
    /// the frames until one tells; after [`SAMPLING_TRIES`] frames, an axis not told is
    /// taken as full.
    pub(super) fn sampling(&mut self, frame: &RgbImage) -> Sampling {
        if !self.sampling.is_told() {
            self.sampling.read(frame);
            self.tries += 1;
            if self.tries >= SAMPLING_TRIES {
                self.sampling.settle();
            }
            if self.sampling.is_told() {
                tracing::debug!("chroma sampling: {:?}", self.sampling);
            }
        }
        self.sampling
    }
}

/// Every this many rows (columns) is read to tell the rebuild along x (y).
const SAMPLE_EVERY: usize = 4;

/// A window of six neighbouring chroma values counts when they span at least this
/// many grey levels: twenty times the std of chroma's rounding from 8-bit RGB (0.19),
/// so that rounding moves a relation's residual, as a share of the span, by 5 % at
/// most. Flat chroma says nothing about how it was sampled.
const MIN_SPAN: f32 = 4.0;

/// Counted windows needed at each phase before the frame is read.
const MIN_WINDOWS: f64 = 64.0;

/// A relation holds at a phase when its mean squared residual there (as a share of
/// the windows' spans²) is within rounding, under this, and under [`PHASE_RATIO`] of
/// the other phase's. Measured on rendered frames: 0.001-0.002 for repeated pairs and
/// 0.013-0.024 for the interpolated relation where they hold; 0.10-0.12 and 0.40-0.58
/// in a 4:4:4 JPEG whose pixel-aligned checker edges favour one phase; 0.34 and 3.3
/// in full-resolution frames.
const HOLDS: [f64; 2] = [0.01, 0.1];

/// See [`HOLDS`]. The interpolated relation annihilates quadratics, so smooth chroma
/// satisfies it at both phases, and at the wrong one only a block's edge leaves a
/// third difference of the blocks: measured 0.05-0.25 of the other phase where the
/// rebuild interpolated, 0.97-1.03 in full-resolution frames.
const PHASE_RATIO: f64 = 0.4;

/// Above this ratio for both relations, the chroma is full.
const FULL_RATIO: f64 = 0.7;

/// Residual sums of one axis: per relation (repeated, interpolated) and phase, the sum
/// of squared residuals as shares of their window's span, and the windows counted.
#[derive(Default)]
struct Residuals {
    sum: [[f64; 2]; 2],
    n: [f64; 2],
}

impl Residuals {
    /// Adds one line of chroma values `c` (`clipped` where a channel was at 0 or 255,
    /// which breaks the relations). Both phases are read at each even pixel `x` and
    /// the next, against the span of the six values both relations there touch: a
    /// window chosen by either phase's own values alone would favour the phase whose
    /// windows straddle more blocks.
    fn add_line(&mut self, c: &[f32], clipped: &[bool]) {
        for x in (2..c.len().saturating_sub(4)).step_by(2) {
            let w = &c[x - 2..x + 4];
            let span = w.iter().fold(f32::MIN, |a, &b| a.max(b))
                - w.iter().fold(f32::MAX, |a, &b| a.min(b));
            if span < MIN_SPAN || clipped[x - 2..x + 4].iter().any(|&k| k) {
                continue;
            }
            for (phase, x) in [(0, x), (1, x + 1)] {
                let repeated = f64::from((c[x + 1] - c[x]) / span);
                let interpolated =
                    f64::from((c[x + 2] - c[x - 1] - 3.0 * (c[x + 1] - c[x])) / span);
                self.sum[0][phase] += repeated * repeated;
                self.sum[1][phase] += interpolated * interpolated;
                self.n[phase] += 1.0;
            }
        }
    }

    /// The rebuild these residuals show, and its offset; `None` without enough
    /// evidence either way.
    fn decide(&self) -> Option<(Rebuild, u8)> {
        if self.n[0] < MIN_WINDOWS || self.n[1] < MIN_WINDOWS {
            return None;
        }
        let mean = |r: usize, p: usize| self.sum[r][p] / self.n[p];
        // The smaller of the two phases' ratios, and the phase it is at.
        let ratio = |r: usize| {
            let (a, b) = (mean(r, 0) / mean(r, 1), mean(r, 1) / mean(r, 0));
            if a <= b {
                (a, 0)
            } else {
                (b, 1)
            }
        };
        let (repeated, interpolated) = (ratio(0), ratio(1));
        let holds = |r: usize, (ratio, phase): (f64, usize)| {
            ratio < PHASE_RATIO && mean(r, phase) < HOLDS[r]
        };
        if holds(0, repeated) {
            Some((Rebuild::Repeated, repeated.1 as u8))
        } else if holds(1, interpolated) {
            Some((Rebuild::Interpolated, interpolated.1 as u8))
        } else if repeated.0 > FULL_RATIO && interpolated.0 > FULL_RATIO {
            Some((Rebuild::Full, 0))
        } else {
            None
        }
    }
}

impl Sampling {
    /// Reads the axes not yet told off `frame`'s chroma; an axis along which the
    /// frame gives too little evidence (flat chroma, no edge across it) stays untold.
    pub fn read(&mut self, frame: &RgbImage) {
        let (w, h) = (frame.width() as usize, frame.height() as usize);
        let px = frame.as_raw();
        let chroma = |i: usize| -> (f32, f32, bool) {
            let (r, g, b) = (px[i] as f32, px[i + 1] as f32, px[i + 2] as f32);
            let clipped = px[i..i + 3].iter().any(|&v| v == 0 || v == 255);
            (
                0.5 * r - 0.418_688 * g - 0.081_312 * b,
                -0.168_736 * r - 0.331_264 * g + 0.5 * b,
                clipped,
            )
        };
        for axis in 0..2 {
            if self.told[axis] {
                continue;
            }
            // The lines read (rows along x, columns along y), gathered row by row into
            // one buffer per quantity: walked down one at a time, the columns would
            // touch every cache line of the frame once each.
            let (lines, len): (Vec<usize>, usize) = if axis == 0 {
                ((SAMPLE_EVERY / 2..h).step_by(SAMPLE_EVERY).collect(), w)
            } else {
                ((SAMPLE_EVERY / 2..w).step_by(SAMPLE_EVERY).collect(), h)
            };
            let n = lines.len() * len;
            let (mut cr, mut cb, mut clipped) = (vec![0f32; n], vec![0f32; n], vec![false; n]);
            let mut put = |at: usize, i: usize| {
                (cr[at], cb[at], clipped[at]) = chroma(i);
            };
            if axis == 0 {
                for (k, &y) in lines.iter().enumerate() {
                    for x in 0..w {
                        put(k * len + x, 3 * (y * w + x));
                    }
                }
            } else {
                for y in 0..h {
                    for (k, &x) in lines.iter().enumerate() {
                        put(k * len + y, 3 * (y * w + x));
                    }
                }
            }
            let mut sums = Residuals::default();
            for k in 0..lines.len() {
                let span = k * len..(k + 1) * len;
                sums.add_line(&cr[span.clone()], &clipped[span.clone()]);
                sums.add_line(&cb[span.clone()], &clipped[span]);
            }
            if let Some((rebuild, offset)) = sums.decide() {
                self.rebuild[axis] = rebuild;
                self.offset[axis] = offset;
                self.told[axis] = true;
            }
        }
    }

    /// How far (px, along `(nx, ny)`) the rebuild moved the centre of a ridge point at
    /// `(x, y)` with unit normal `(nx, ny)`, found at scale `sigma_s` on a stripe of
    /// Gaussian std `sigma_w`, of whose response the share `share` is chroma. The
    /// point's centre without the rebuild is `(x, y) − shift · (nx, ny)`.
    pub fn normal_shift(
        &self,
        [x, y]: [f32; 2],
        [nx, ny]: [f32; 2],
        sigma_s: f32,
        sigma_w: f32,
        share: f32,
    ) -> f32 {
        if !self.is_subsampled() {
            return 0.0;
        }
        let n = [nx, ny];
        // Per axis, the point's series: its scale, width and share do not move with
        // the phase, only the phase with the shift.
        let series: [Option<Series>; 2] = std::array::from_fn(|axis| {
            let table = ShiftTable::of(self.rebuild[axis])?;
            let along = n[axis].abs();
            if along < 0.05 {
                return None;
            }
            // Along the line the detector's window (std `sigma_s`) passes phases of
            // this axis at the rate of the normal's other component.
            let spread = sigma_s * n[1 - axis].abs();
            let (scale, width) = (sigma_s / along, sigma_w / along);
            let width = table.true_width(scale, share, width);
            table.series(scale, width, share, spread)
        });
        let mut shift = 0.0;
        // The phase depends on the centre without the shift: two rounds of fixed point.
        for _ in 0..2 {
            let mut next = 0.0;
            for (axis, series) in series.iter().enumerate() {
                let Some(series) = series else {
                    continue;
                };
                let centre = [x, y][axis] - shift * n[axis];
                let phase = (centre - f32::from(self.offset[axis])).rem_euclid(2.0);
                next += n[axis] * series.at(phase);
            }
            shift = next;
        }
        shift
    }
}

/// Pixels each side of a ridge point over which its chroma share is summed: two
/// blocks, which the rebuild's spread does not leave.
const SHARE_REACH: usize = 2;

/// Per ridge point of `points` (laser channels `own`), the move along its normal that
/// takes it back off the chroma rebuild's pull ([`Sampling::normal_shift`]), into `out`
/// (empty where the frame's chroma is full). The point's chroma share is read off the
/// excess over `background` around it: its own channel less the excess's luma, over
/// its own channel; its stripe's width off its smoothed response and curvature. A
/// point whose own channel is clipped is left alone: it was located through the other
/// channels.
pub(super) fn point_moves(
    sampling: &Sampling,
    points: &[LinePoint],
    (frame, background): (&RgbImage, &RgbImage),
    own: [bool; 3],
    out: &mut Vec<f32>,
) {
    out.clear();
    if !sampling.is_subsampled() {
        return;
    }
    let (w, h) = (frame.width() as usize, frame.height() as usize);
    let (f, b) = (frame.as_raw(), background.as_raw());
    out.extend(points.iter().map(|p| {
        let (x, y) = (
            (p.x.round().max(0.0) as usize).min(w - 1),
            (p.y.round().max(0.0) as usize).min(h - 1),
        );
        let i = 3 * (y * w + x);
        let raw = &f[i..i + 3];
        if (0..3).any(|c| own[c] && raw[c] >= CLIP_LEVEL) {
            return 0.0;
        }
        // The rebuild spreads the chroma but keeps its sum, so the share is read off
        // the sums over the pixels around the point, not off its own pixel.
        let (mut luma, mut own_excess) = (0.0, 0.0);
        for v in y.saturating_sub(SHARE_REACH)..(y + SHARE_REACH + 1).min(h) {
            for u in x.saturating_sub(SHARE_REACH)..(x + SHARE_REACH + 1).min(w) {
                let j = 3 * (v * w + u);
                let d: [f32; 3] =
                    std::array::from_fn(|c| f32::from(f[j + c]) - f32::from(b[j + c]));
                luma += 0.299 * d[0] + 0.587 * d[1] + 0.114 * d[2];
                own_excess += (0..3)
                    .filter(|&c| own[c])
                    .map(|c| d[c])
                    .fold(f32::MIN, f32::max);
            }
        }
        let [t, g, _, lambda] = p.ridge;
        if own_excess < 1.0 || lambda >= 0.0 {
            return 0.0;
        }
        let share = 1.0 - luma / own_excess;
        let sigma_w = (-g / lambda - t * t - p.sigma * p.sigma).max(0.0).sqrt();
        -sampling.normal_shift([p.x, p.y], [p.nx, p.ny], p.sigma, sigma_w, share)
    }));
}
