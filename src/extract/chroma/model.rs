//! The model of a chroma rebuild's pull on a ridge centre ([`super::Sampling::normal_shift`]):
//! a 1D Gaussian stripe whose chroma share goes through the block average and the
//! rebuild, located as the detector locates it, tabulated once per process as a sine
//! series of the phase.

use std::sync::OnceLock;

use super::Rebuild;
use crate::extract::detect::Kernels;

/// One grid axis of [`ShiftTable`]: first value, step, count.
#[derive(Clone, Copy)]
struct Grid(f32, f32, usize);

impl Grid {
    fn value(&self, i: usize) -> f32 {
        self.0 + self.1 * i as f32
    }

    /// The cell below `v` and the weight of the one above; `None` outside.
    fn locate(&self, v: f32) -> Option<(usize, f32)> {
        let f = (v - self.0) / self.1;
        if !(f >= 0.0 && f <= (self.2 - 1) as f32) {
            return None;
        }
        let i = (f as usize).min(self.2 - 2);
        Some((i, f - i as f32))
    }
}

/// The detector's scale along the axis (px): past the widest, the shift is below a
/// thousandth of a pixel.
const SIGMA_S: Grid = Grid(0.5, 0.25, 19);
/// The stripe's Gaussian std along the axis (px); below the first it is clamped, past
/// the last the shift is negligible.
const SIGMA_W: Grid = Grid(0.25, 0.125, 23);
/// The chroma share of the response (negative where the excess's luma exceeds its own
/// channel, e.g. a green stripe on the red one).
const SHARE: Grid = Grid(-0.5, 0.25, 7);
/// Phases sampled over the 2 px period, and sine harmonics kept.
const PHASES: usize = 32;
const HARMONICS: usize = 12;

/// Per rebuild, the 1D shift of a ridge centre as a sine series of its phase
/// `φ ∈ [0, 2)` (from the block's first pixel):
/// `Σ_k a_k sin(πk(φ − ½))` — odd about the block's centre and about its edge, where
/// the rebuild is symmetric about the stripe.
pub(super) struct ShiftTable {
    coefficients: Vec<[f32; HARMONICS]>,
    /// Per cell, the stripe's std as the detector then measures it (its smoothed
    /// response over its curvature, less its scale), averaged over the phases: the
    /// rebuild blurs the chroma, so a point's measured width is wider than its stripe.
    apparent: Vec<f32>,
}

impl ShiftTable {
    /// The table of `rebuild`, built once per process (some 10 ms); `None` for
    /// [`Rebuild::Full`].
    pub(super) fn of(rebuild: Rebuild) -> Option<&'static Self> {
        static REPEATED: OnceLock<ShiftTable> = OnceLock::new();
        static INTERPOLATED: OnceLock<ShiftTable> = OnceLock::new();
        match rebuild {
            Rebuild::Full => None,
            Rebuild::Repeated => Some(REPEATED.get_or_init(|| Self::build(rebuild))),
            Rebuild::Interpolated => Some(INTERPOLATED.get_or_init(|| Self::build(rebuild))),
        }
    }

    fn index(is: usize, iw: usize, ih: usize) -> usize {
        (is * SIGMA_W.2 + iw) * SHARE.2 + ih
    }

    fn build(rebuild: Rebuild) -> Self {
        let cells = SIGMA_S.2 * SIGMA_W.2 * SHARE.2;
        let mut coefficients = vec![[0f32; HARMONICS]; cells];
        let mut apparent = vec![0f32; cells];
        // The profiles depend on the width and phase only, and the detector's sums are
        // linear in the profile: per scale, each profile is summed once and the sums
        // mixed per share (`model_1d` does the same one cell at a time).
        let profiles: Vec<Vec<Profiles>> = (0..SIGMA_W.2)
            .map(|iw| {
                (0..PHASES)
                    .map(|m| {
                        let phase = 2.0 * m as f64 / PHASES as f64;
                        Profiles::new(rebuild, f64::from(SIGMA_W.value(iw)), phase)
                    })
                    .collect()
            })
            .collect();
        let mut phases = [(0f64, 0f64); PHASES];
        for is in 0..SIGMA_S.2 {
            let sigma_s = f64::from(SIGMA_S.value(is));
            let kernels = Kernels::new(sigma_s);
            for (iw, of_width) in profiles.iter().enumerate() {
                let sums: Vec<[Sums; 2]> = of_width.iter().map(|p| p.sums(&kernels)).collect();
                for ih in 0..SHARE.2 {
                    let share = f64::from(SHARE.value(ih));
                    for ((out, p), s) in phases.iter_mut().zip(of_width).zip(&sums) {
                        *out = p.shift(s, share);
                    }
                    let cell = Self::index(is, iw, ih);
                    let var = phases.iter().map(|p| p.1).sum::<f64>() / PHASES as f64;
                    apparent[cell] = (var - sigma_s * sigma_s).max(0.0).sqrt() as f32;
                    for (k, a) in coefficients[cell].iter_mut().enumerate() {
                        let k = (k + 1) as f64;
                        let s: f64 = phases
                            .iter()
                            .enumerate()
                            .map(|(m, p)| {
                                let phase = 2.0 * m as f64 / PHASES as f64;
                                p.0 * (std::f64::consts::PI * k * (phase - 0.5)).sin()
                            })
                            .sum();
                        *a = (s * 2.0 / PHASES as f64) as f32;
                    }
                }
            }
        }
        Self {
            coefficients,
            apparent,
        }
    }

    /// The stripe's std along the axis whose rebuilt profile the detector measures as
    /// `measured` (px), at scale `sigma_s` and chroma share `share`: the inverse of
    /// [`Self::apparent`] by interpolation along the width axis; `measured` itself
    /// outside the table's range.
    pub(super) fn true_width(&self, sigma_s: f32, share: f32, measured: f32) -> f32 {
        let (Some((is, fs)), Some((ih, fh))) = (
            SIGMA_S.locate(sigma_s),
            SHARE.locate(share.clamp(SHARE.0, SHARE.value(SHARE.2 - 1))),
        ) else {
            return measured;
        };
        let at = |iw: usize| -> f32 {
            let mut v = 0.0;
            for (ds, ws) in [(0, 1.0 - fs), (1, fs)] {
                for (dh, wh) in [(0, 1.0 - fh), (1, fh)] {
                    v += ws * wh * self.apparent[Self::index(is + ds, iw, ih + dh)];
                }
            }
            v
        };
        let mut below = (SIGMA_W.value(0), at(0));
        if measured <= below.1 {
            return below.0;
        }
        for iw in 1..SIGMA_W.2 {
            let here = (SIGMA_W.value(iw), at(iw));
            if measured <= here.1 && here.1 > below.1 {
                let f = (measured - below.1) / (here.1 - below.1);
                return below.0 + f * (here.0 - below.0);
            }
            below = here;
        }
        measured
    }

    /// The shift (px, along the axis) at `phase`, interpolated in the table, with the
    /// harmonics averaged over a Gaussian spread of phases of std `spread` px.
    #[cfg(test)]
    pub(super) fn bias(
        &self,
        phase: f32,
        sigma_s: f32,
        sigma_w: f32,
        share: f32,
        spread: f32,
    ) -> f32 {
        self.series(sigma_s, sigma_w, share, spread)
            .map_or(0.0, |s| s.at(phase))
    }

    /// The sine series of the shift for a point's scale, width and chroma share, its
    /// harmonics interpolated in the table and averaged over a Gaussian spread of
    /// phases of std `spread` px; `None` (no shift) outside the table. A point's
    /// series is the same at every phase, so it is made once and read per phase
    /// ([`Series::at`]).
    pub(super) fn series(
        &self,
        sigma_s: f32,
        sigma_w: f32,
        share: f32,
        spread: f32,
    ) -> Option<Series> {
        let (Some((is, fs)), Some((ih, fh))) = (
            SIGMA_S.locate(sigma_s),
            SHARE.locate(share.clamp(SHARE.0, SHARE.value(SHARE.2 - 1))),
        ) else {
            return None;
        };
        let (iw, fw) = SIGMA_W.locate(sigma_w.max(SIGMA_W.0))?;
        let mut a = [0f32; HARMONICS];
        for (ds, ws) in [(0, 1.0 - fs), (1, fs)] {
            for (dw, ww) in [(0, 1.0 - fw), (1, fw)] {
                for (dh, wh) in [(0, 1.0 - fh), (1, fh)] {
                    let c = &self.coefficients[Self::index(is + ds, iw + dw, ih + dh)];
                    for (a, c) in a.iter_mut().zip(c) {
                        *a += ws * ww * wh * c;
                    }
                }
            }
        }
        // The damping `exp(−½ (πk spread)²) = q^(k²)`, by steps of `q^(2k−1)`.
        let q = (-0.5 * (std::f32::consts::PI * spread).powi(2)).exp();
        let (mut damp, mut step) = (q, q * q * q);
        for a in &mut a {
            *a *= damp;
            damp *= step;
            step *= q * q;
        }
        Some(Series(a))
    }
}

/// A point's shift as a sine series of the phase, damped ([`ShiftTable::series`]).
pub(super) struct Series([f32; HARMONICS]);

impl Series {
    /// The shift (px, along the axis) at `phase`: `Σ a_k sin(πk(φ − ½))`, the sines by
    /// their recurrence.
    pub(super) fn at(&self, phase: f32) -> f32 {
        let theta = std::f32::consts::PI * (phase - 0.5);
        let (sin1, cos2) = (theta.sin(), 2.0 * theta.cos());
        let (mut s_prev, mut s_k) = (0.0, sin1);
        let mut sum = 0.0;
        for a in self.0 {
            sum += a * s_k;
            (s_prev, s_k) = (s_k, cos2 * s_k - s_prev);
        }
        sum
    }
}

/// Pixels of the 1D model's profile; the stripe sits near its middle.
const MODEL_PX: usize = 64;

/// The detector's sums (smoothed, first and second derivative) at the three pixels
/// nearest a profile's centre.
type Sums = [[f64; 3]; 3];

/// The 1D model's two profiles: a Gaussian stripe of std `sigma_w` (sampled at pixel
/// centres, its width grown by a pixel's box) centred `phase` px after a block's first
/// pixel, and the same through the block average and `rebuild`.
struct Profiles {
    stripe: [f64; MODEL_PX],
    rebuilt: [f64; MODEL_PX],
    centre: f64,
    var: f64,
}

impl Profiles {
    fn new(rebuild: Rebuild, sigma_w: f64, phase: f64) -> Self {
        let centre = (MODEL_PX / 2) as f64 + phase;
        let var = sigma_w * sigma_w + 1.0 / 12.0;
        let stripe: [f64; MODEL_PX] =
            std::array::from_fn(|x| (-0.5 * (x as f64 - centre).powi(2) / var).exp());
        let blocks: [f64; MODEL_PX / 2] =
            std::array::from_fn(|b| 0.5 * (stripe[2 * b] + stripe[2 * b + 1]));
        let last = blocks.len() - 1;
        let rebuilt = std::array::from_fn(|x| {
            let b = x / 2;
            match rebuild {
                Rebuild::Full => stripe[x],
                Rebuild::Repeated => blocks[b],
                Rebuild::Interpolated => {
                    let next = if x.is_multiple_of(2) {
                        b.saturating_sub(1)
                    } else {
                        (b + 1).min(last)
                    };
                    0.75 * blocks[b] + 0.25 * blocks[next]
                }
            }
        });
        Self {
            stripe,
            rebuilt,
            centre,
            var,
        }
    }

    /// The detector's sums over the stripe alone and over the rebuilt one.
    fn sums(&self, kernels: &Kernels) -> [Sums; 2] {
        let around = self.centre.round() as usize;
        [
            sums(&self.stripe, kernels, around),
            sums(&self.rebuilt, kernels, around),
        ]
    }

    /// The detector's centre of the profile of which the share `share` went through
    /// the rebuild, less its centre of the stripe alone, and the width² it measures
    /// there (smoothed response over curvature, less the offset², as [`point_moves`]
    /// reads a ridge point).
    ///
    /// [`point_moves`]: super::point_moves
    fn shift(&self, [stripe, rebuilt]: &[Sums; 2], share: f64) -> (f64, f64) {
        let seen: Sums = std::array::from_fn(|j| {
            std::array::from_fn(|k| (1.0 - share) * stripe[j][k] + share * rebuilt[j][k])
        });
        let around = self.centre.round() as usize;
        match (ridge(&seen, around), ridge(stripe, around)) {
            (Some(a), Some(b)) => (a.0 - b.0, a.1),
            _ => (0.0, self.var),
        }
    }
}

/// The 1D model of one cell and phase ([`Profiles::shift`]).
#[cfg(test)]
fn model_1d(
    rebuild: Rebuild,
    kernels: &Kernels,
    sigma_w: f64,
    share: f64,
    phase: f64,
) -> (f64, f64) {
    let profiles = Profiles::new(rebuild, sigma_w, phase);
    profiles.shift(&profiles.sums(kernels), share)
}

/// The detector's sums of `profile` at the pixels `around − 1 ..= around + 1`.
fn sums(profile: &[f64], kernels: &Kernels, around: usize) -> Sums {
    let r = kernels.radius;
    std::array::from_fn(|d| {
        let j = around + d - 1;
        let (mut g, mut d1, mut d2) = (0.0, 0.0, 0.0);
        for i in 0..=2 * r {
            let v = profile[j + i - r];
            g += v * f64::from(kernels.k0[i]);
            d1 += v * f64::from(kernels.k1[i]);
            d2 += v * f64::from(kernels.k2[i]);
        }
        [g, d1, d2]
    })
}

/// The detector's 1D centre from the sums at `around − 1 ..= around + 1` (at the pixel
/// whose offset `t`, the Taylor step of the log of the smoothed profile `g` as the
/// detector takes it, is at most half a pixel), and the width² it measures there,
/// `−g/d2 − t²`.
fn ridge(sums: &Sums, around: usize) -> Option<(f64, f64)> {
    // (|t|, centre, width²) of the pixel with the smallest offset.
    let mut best: Option<(f64, f64, f64)> = None;
    for (d, &[g, d1, d2]) in sums.iter().enumerate() {
        let j = around + d - 1;
        if d2 >= 0.0 {
            continue;
        }
        // The detector's offset: the Taylor step of ln g where g > 0.
        let t = if g > 0.0 {
            d1 * g / (d1 * d1 - g * d2)
        } else {
            -d1 / d2
        };
        if t.abs() <= 0.5 && best.is_none_or(|(b, _, _)| b > t.abs()) {
            best = Some((t.abs(), j as f64 + t, -g / d2 - t * t));
        }
    }
    best.map(|(_, c, w)| (c, w))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The table's sine series gives its model's shift at every phase of a grid cell
    /// (a stripe 2.4 px wide at the detector's first scale, red's chroma share), and
    /// its width inverts the width the detector measures on average.
    #[test]
    fn the_shift_table_follows_its_model() {
        let (sigma_s, sigma_w, share) = (1.0, 1.0, 0.75);
        let kernels = Kernels::new(sigma_s);
        for rebuild in [Rebuild::Repeated, Rebuild::Interpolated] {
            let table = ShiftTable::of(rebuild).expect("a table");
            let (mut largest, mut mean_width2) = (0f64, 0f64);
            for m in 0..32 {
                let phase = m as f64 / 16.0;
                let (model, width2) = model_1d(rebuild, &kernels, sigma_w, share, phase);
                let series = table.bias(phase as f32, 1.0, 1.0, 0.75, 0.0);
                largest = largest.max(model.abs());
                // At the block's edge (phase 1.5) repetition's shift turns fastest, and
                // the model's own centre there depends on the pixel it is read from:
                // the series, odd about the edge, rounds that off.
                let tolerance = if (phase - 1.5).abs() < 0.1 {
                    0.04
                } else {
                    0.01
                };
                assert!(
                    (f64::from(series) - model).abs() < tolerance,
                    "{rebuild:?} phase {phase}: table {series:.4}, model {model:.4}"
                );
                mean_width2 += width2 / 32.0;
            }
            // The table keeps the width measured over all phases.
            let measured = (mean_width2 - sigma_s * sigma_s).max(0.0).sqrt() as f32;
            let back = table.true_width(1.0, 0.75, measured);
            assert!(
                (back - 1.0).abs() < 0.02,
                "{rebuild:?}: width {back} from {measured}"
            );
            assert!(
                largest > 0.05,
                "{rebuild:?}: the model pulls by {largest:.3} px"
            );
        }
        assert!(ShiftTable::of(Rebuild::Full).is_none());
    }
}
