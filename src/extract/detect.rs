//! Steger's ridge detector restricted to tiles that can hold a stripe.
//!
//! The caller marks *active* tiles (tiles holding at least one laser-coloured pixel) and
//! fills the response image around them; the detector then runs the separable
//! Gaussian-derivative filters and the Hessian only there:
//! - the response is needed on the active tiles and the kernel radius around them,
//! - the row pass (smooth, first and second derivative along x) on the active tiles
//!   and the kernel radius above and below them,
//! - the column pass, the Hessian and the sub-pixel test on the active tiles.
//!
//! A tile is at least as large as the kernel radius, so one tile of margin holds every
//! kernel's support. All buffers are full-frame and reused; nothing is allocated per
//! frame once the point list has grown to its working size.

mod profile;
mod sample;
mod width;
use sample::bilinear;
use width::{NO_LINE, WIDTH_MARGIN};

/// Where in a pixel's [`Detector::masked`] byte its chromatic share
/// ([`super::colour::ColourLut::response_local`], in
/// [`super::colour::SHARE_FULL`]ths) is.
pub(crate) const SHARE_SHIFT: u32 = 2;

/// Offsets `-r..=r` of the sampled Gaussian and its first two derivatives, normalised so
/// that they are exact on constants, ramps and parabolas.
///
/// `k0` and `k2` are exactly symmetric and `k1` exactly antisymmetric (zero at the
/// centre), bit for bit: each tap is computed from `i²` or `i` times a function of `i²`,
/// and negating is exact. The passes rely on it to fold the taps `±i` together.
#[derive(Clone, Debug)]
pub(crate) struct Kernels {
    pub radius: usize,
    pub k0: Vec<f32>,
    pub k1: Vec<f32>,
    pub k2: Vec<f32>,
}

impl Kernels {
    pub fn new(sigma: f64) -> Self {
        let radius = (3.5 * sigma).ceil().max(1.0) as usize;
        let offsets: Vec<f64> = (0..=2 * radius).map(|j| j as f64 - radius as f64).collect();
        let g: Vec<f64> = offsets
            .iter()
            .map(|&i| (-0.5 * i * i / (sigma * sigma)).exp())
            .collect();
        let sum_g: f64 = g.iter().sum();
        let k0: Vec<f64> = g.iter().map(|v| v / sum_g).collect();
        // Correlation convention: out(x) = Σ_i f(x + i) k(i).
        let k1: Vec<f64> = offsets.iter().zip(&k0).map(|(i, g)| i * g).collect();
        let s1: f64 = offsets.iter().zip(&k1).map(|(i, k)| i * k).sum();
        let k1: Vec<f64> = k1.iter().map(|k| k / s1).collect();
        let m: f64 = offsets.iter().zip(&k0).map(|(i, g)| i * i * g).sum();
        let k2: Vec<f64> = offsets
            .iter()
            .zip(&k0)
            .map(|(i, g)| (i * i - m) * g)
            .collect();
        let s2: f64 = offsets.iter().zip(&k2).map(|(i, k)| 0.5 * i * i * k).sum();
        let k2: Vec<f64> = k2.iter().map(|k| k / s2).collect();
        let f = |v: Vec<f64>| v.into_iter().map(|x| x as f32).collect();
        Self {
            radius,
            k0: f(k0),
            k1: f(k1),
            k2: f(k2),
        }
    }
}

/// One ridge point: sub-pixel position (pixel centres at integers), unit normal across
/// the line, and strength `-λ` (the magnitude of the negative Hessian eigenvalue) in
/// grey levels of stripe contrast (divided by its scale's eigenvalue per grey level).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct LinePoint {
    pub x: f32,
    pub y: f32,
    pub nx: f32,
    pub ny: f32,
    pub strength: f32,
    pub pixel: u32,
    /// What [`step_shift`] needs to move the point off a glow step under it: the
    /// offset found without one, the smoothed response and its first two derivatives
    /// across, the flank distance from which the step is measured
    /// ([`Detector::step_across`]) and the scale. The linker measures the steps of
    /// linked points only (`super::glow::glow_moves`).
    pub ridge: [f32; 4],
    pub flank_px: f32,
    pub sigma: f32,
}

impl LinePoint {
    /// The move along the normal (px) that takes this point off a glow step of
    /// `step` grey levels ([`step_shift`]).
    pub fn step_move(&self, step: f32) -> f32 {
        let [t, g, d1, d2] = self.ridge;
        let flanks = [self.flank_px, self.flank_px + (STEP_DISTANCES - 1) as f32];
        step_shift(t, [g, d1, d2], step, flanks, self.sigma) - t
    }
}

pub(crate) const NO_POINT: u32 = u32::MAX;

/// One smoothing scale of the detector.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Scale {
    pub sigma_px: f64,
    /// Hessian eigenvalue of a stripe of one grey level of peak that this scale is for;
    /// strengths are divided by it, so thresholds and strengths are in grey levels at
    /// every scale.
    pub eigenvalue_per_grey_level: f64,
    /// The widest stripe (FWHM, px) this scale is chosen for; the last scale takes the
    /// rest.
    pub max_width_px: f64,
}

/// One scale's kernels and constants.
struct Level {
    kernels: Kernels,
    /// Points whose window of this radius holds a masked pixel are dropped.
    mask_radius: usize,
    /// Distance (px) across the line at which a ridge point's flanks are sampled.
    flank_px: f32,
    per_grey: f32,
    max_width_px: f64,
    sigma_px: f32,
}

/// A ridge point's flanks are sampled this many smoothing scales `σ` (at least 2 px)
/// away across the line: a Gaussian stripe as wide as its scale is made for
/// (`2√3 σ`) has fallen to a quarter there, a narrower one further.
const FLANK_SIGMAS: f64 = 2.5;
/// Neither flank of a ridge point may exceed this share of its centre
/// ([`Detector::flanks`]).
const FLANK_RATIO: f32 = 0.5;

/// The centre of a stripe that lies on a step of the response, as offset along the
/// normal from the pixel where the smoothed response `g` and its first and second
/// derivatives across, `d1` and `d2`, were measured; `t` is the offset found without
/// the step, `flank_step` the response ahead of the stripe minus behind it, as the
/// mean at the distances `flanks` either side, `sigma` the smoothing scale.
///
/// Under water the sheet lights the water in front of the surface: its glow fills the
/// image on one side of the stripe and ends at the stripe's centre, where the sheet
/// meets the surface. A step under a Gaussian ridge tilts it, and the detector's
/// centre moves towards the bright side by `step / peak · S² / (s √2π)` (`s` the
/// stripe's own width, `S² = s² + σ²`, the step blurred as the stripe): 0.1–0.3 px on
/// the simulated pipes, every one towards the camera. The step's own share of `g`,
/// `d1` and `d2` is taken out, with its edge at the centre being solved for and
/// blurred as the stripe is (the glow crosses the same sheet thickness, through the
/// same lens: `S = √(g / −d2)` of the ridge), and the offset solved again. A response
/// with no step gives `t` back.
pub(crate) fn step_shift(
    t: f32,
    [g, d1, d2]: [f32; 3],
    flank_step: f32,
    flanks: [f32; 2],
    sigma: f32,
) -> f32 {
    if flank_step == 0.0 || d2 >= 0.0 {
        return t;
    }
    const INV_SQRT_2PI: f32 = 0.398_942_3;
    let (mut c, mut gr, mut d2r) = (t, g, d2);
    for _ in 0..STEP_ITERATIONS {
        // The ridge's width from its value and curvature `c` off its centre: a Gaussian
        // of std `S` there has `−d2 / g = 1/S² − c²/S⁴`. The edge is blurred as the
        // ridge is, and never less than by the smoothing.
        let q = (-d2r / gr.max(f32::MIN_POSITIVE)).max(0.0);
        let c2 = c * c;
        let disc = 1.0 - 4.0 * c2 * q;
        let inv_s2 = if c2 > 1e-6 && disc > 0.0 {
            (1.0 - disc.sqrt()) / (2.0 * c2)
        } else {
            q
        };
        let blur = if inv_s2 > 0.0 {
            (1.0 / inv_s2).max(sigma * sigma).sqrt()
        } else {
            sigma
        };
        // The flanks, `flank` px either side, miss the blurred step's own tails.
        let seen = normal_cdf(flanks[0] / blur) + normal_cdf(flanks[1] / blur) - 1.0;
        let step = flank_step / seen;
        let u = -c / blur;
        let phi = INV_SQRT_2PI * (-0.5 * u * u).exp();
        // The step rises by `step` along the normal from nothing on its dark side.
        gr = g - step * normal_cdf(u) - (-step).max(0.0);
        let d1r = d1 - step * phi / blur;
        d2r = d2 + step * u * phi / (blur * blur);
        if d2r >= 0.0 {
            return t;
        }
        c = if gr > 0.0 {
            d1r * gr / (d1r * d1r - gr * d2r)
        } else {
            -d1r / d2r
        };
    }
    c
}

/// Distances, one px apart from a point's flank distance out, at which the step
/// under it is measured ([`Detector::step_across`]).
pub(crate) const STEP_DISTANCES: usize = 4;

/// A step counts only where it is this steady over [`STEP_DISTANCES`] (largest over
/// smallest, one sign): glow is a plateau, a neighbouring stripe is not.
const PLATEAU_RATIO: f32 = 2.0;

/// The glow step of a run of a curve from the medians of its points' steps at each
/// distance ([`Detector::step_across`]): their mean if they hold steady, else none.
pub(crate) fn plateau_step(profile: &[f32; STEP_DISTANCES]) -> f32 {
    let lo = profile.iter().copied().fold(f32::MAX, f32::min);
    let hi = profile.iter().copied().fold(f32::MIN, f32::max);
    let steady = (lo > 0.0 && hi <= PLATEAU_RATIO * lo) || (hi < 0.0 && lo >= PLATEAU_RATIO * hi);
    if steady {
        profile.iter().sum::<f32>() / STEP_DISTANCES as f32
    } else {
        0.0
    }
}

/// Rounds of [`step_shift`]: each moves the step's edge to the last centre found.
const STEP_ITERATIONS: usize = 6;

/// `Φ(u)`, the standard normal distribution function (Abramowitz & Stegun 7.1.26,
/// error under 1e-7).
fn normal_cdf(u: f32) -> f32 {
    let x = u.abs() * std::f32::consts::FRAC_1_SQRT_2;
    let k = 1.0 / (1.0 + 0.327_591_1 * x);
    let poly = k
        * (0.254_829_6
            + k * (-0.284_496_74 + k * (1.421_413_7 + k * (-1.453_152_1 + k * 1.061_405_4))));
    let erf = 1.0 - poly * (-x * x).exp();
    if u >= 0.0 {
        0.5 + 0.5 * erf
    } else {
        0.5 - 0.5 * erf
    }
}

/// A pixel rectangle `[x0, x1, y0, y1)`; empty when `x0 >= x1`.
type Rect = [usize; 4];
const EMPTY: Rect = [usize::MAX, 0, usize::MAX, 0];

fn merge(a: &mut Rect, b: Rect) {
    a[0] = a[0].min(b[0]);
    a[1] = a[1].max(b[1]);
    a[2] = a[2].min(b[2]);
    a[3] = a[3].max(b[3]);
}

pub(crate) struct Detector {
    pub width: usize,
    pub height: usize,
    pub tile: usize,
    pub tiles_x: usize,
    pub tiles_y: usize,
    levels: Vec<Level>,
    /// Per tile: index into `levels` (meaningful on active tiles only), or [`NO_LINE`].
    tile_level: Vec<u8>,
    /// The response still holds the surfaces' texture (a local background): tiles whose
    /// band is round ([`width::MAX_BAND_ROUNDNESS`]) or flat-topped ([`width::FLAT_RATIO`]) are not
    /// searched, and a ridge point's strength is scaled by its chromatic share
    /// ([`Self::chromatic_share`]). Set per frame.
    pub texture_kept: bool,
    /// Active tiles not searched for that since the last [`Self::prepare`].
    pub round_tiles: usize,
    /// The test by which, where the response holds texture, a ridge point on a patch of
    /// surface is told from one on a beam, for the local background's window.
    flat_top: profile::FlatTop,
    pub response: Vec<f32>,
    /// Per pixel: bit 0 where the response was zeroed for another laser's colour and
    /// lost light by it (a hole), bit 1 where the laser's own channel is clipped, bits
    /// 2–7 ([`SHARE_SHIFT`]) the chromatic share in [`super::colour::SHARE_FULL`]ths (bits 1–7
    /// against a local background only).
    pub masked: Vec<u8>,
    row_s: Vec<f32>,
    row_d1: Vec<f32>,
    row_d2: Vec<f32>,
    /// Per tile: the part whose response must be computed (kernel margins of the
    /// active tiles around it), and the part that needs the row pass.
    response_box: Vec<Rect>,
    filled_box: Vec<Rect>,
    rows_box: Vec<Rect>,
    acc: Vec<f32>,

    pub points: Vec<LinePoint>,
    /// Per pixel: index into `points`, or `NO_POINT`.
    pub index: Vec<u32>,
}

impl Detector {
    /// A detector over `scales` (at least one; sorted by `max_width_px`).
    pub fn new(width: usize, height: usize, scales: &[Scale]) -> Self {
        let levels: Vec<Level> = scales
            .iter()
            .map(|s| Level {
                kernels: Kernels::new(s.sigma_px),
                mask_radius: (2.5 * s.sigma_px).ceil() as usize,
                flank_px: (FLANK_SIGMAS * s.sigma_px).max(2.0) as f32,
                per_grey: s.eigenvalue_per_grey_level as f32,
                max_width_px: s.max_width_px,
                sigma_px: s.sigma_px as f32,
            })
            .collect();
        let max_radius = levels.iter().map(|l| l.kernels.radius).max().unwrap_or(1);
        let tile = max_radius.max(16);
        let tiles_x = width.div_ceil(tile);
        let tiles_y = height.div_ceil(tile);
        let n = width * height;
        Self {
            width,
            height,
            tile,
            tiles_x,
            tiles_y,
            tile_level: vec![0; tiles_x * tiles_y],
            texture_kept: false,
            round_tiles: 0,
            flat_top: profile::FlatTop::new(super::local::DEFAULT_RADIUS_PX),
            response: vec![0.0; n],
            masked: vec![0; n],
            row_s: vec![0.0; n],
            row_d1: vec![0.0; n],
            row_d2: vec![0.0; n],
            response_box: vec![EMPTY; tiles_x * tiles_y],
            filled_box: vec![EMPTY; tiles_x * tiles_y],
            rows_box: vec![EMPTY; tiles_x * tiles_y],
            acc: vec![0.0; 8 * tile],
            points: Vec::new(),
            index: vec![NO_POINT; n],
            levels,
        }
    }

    /// Pixel bounds `(x0, x1, y0, y1)` of tile `t`.
    pub fn tile_bounds(&self, t: usize) -> (usize, usize, usize, usize) {
        let (tx, ty) = (t % self.tiles_x, t / self.tiles_x);
        let x0 = tx * self.tile;
        let y0 = ty * self.tile;
        (
            x0,
            (x0 + self.tile).min(self.width),
            y0,
            (y0 + self.tile).min(self.height),
        )
    }

    /// Fills the response the active tiles need, and chooses each active tile's scale
    /// from the width of its stripe. Calls `fill(y, x0, response, masked)` for image
    /// row spans; the slices cover pixels `x0..x0 + response.len()` of row `y`, and
    /// `masked` must be set nonzero where the response was zeroed for another colour.
    ///
    /// With more than one scale, the response is first filled on the active tiles and
    /// [`WIDTH_MARGIN`] around them, the width measured there ([`Self::stripe_width`]),
    /// and the margins then grown to the chosen kernels' radii.
    pub fn prepare(
        &mut self,
        active: &[bool],
        fill: &mut impl FnMut(usize, usize, &mut [f32], &mut [u8]),
    ) {
        // What the last laser or frame filled goes back to zero, as in a new detector:
        // the flank and step samples reach past the filled margins, and must not read
        // another frame's response there.
        for t in 0..self.filled_box.len() {
            let [x0, x1, y0, y1] = self.filled_box[t];
            for y in y0..y1.min(self.height) {
                let span = y * self.width + x0..y * self.width + x1;
                self.response[span.clone()].fill(0.0);
                self.masked[span].fill(0);
            }
        }
        self.filled_box.fill(EMPTY);
        self.response_box.fill(EMPTY);
        self.round_tiles = 0;
        self.add_tiles(active, fill);
    }

    /// As [`Self::prepare`] for the tiles `more` (none of them active before), keeping
    /// what the earlier tiles filled: [`Self::detect_more`] then finds their points.
    pub fn extend(
        &mut self,
        more: &[bool],
        fill: &mut impl FnMut(usize, usize, &mut [f32], &mut [u8]),
    ) {
        self.add_tiles(more, fill);
    }

    fn add_tiles(
        &mut self,
        tiles: &[bool],
        fill: &mut impl FnMut(usize, usize, &mut [f32], &mut [u8]),
    ) {
        if self.levels.len() > 1 {
            self.mark_boxes(tiles, |_| WIDTH_MARGIN);
            self.fill_boxes(fill);
            for (t, _) in tiles.iter().enumerate().filter(|(_, a)| **a) {
                let (width, no_line) = self.stripe_width(t);
                if no_line {
                    self.tile_level[t] = NO_LINE;
                    self.round_tiles += 1;
                    continue;
                }
                let last = self.levels.len() - 1;
                let level = self
                    .levels
                    .iter()
                    .position(|l| width <= l.max_width_px)
                    .unwrap_or(last);
                self.tile_level[t] = level as u8;
            }
        } else {
            for (t, _) in tiles.iter().enumerate().filter(|(_, a)| **a) {
                self.tile_level[t] = 0;
            }
        }
        self.mark_boxes_by_level(tiles);
        self.fill_boxes(fill);
    }

    /// Adds to the response boxes every tile of `active` and the margin `margin(t)`
    /// around it.
    fn mark_boxes(&mut self, active: &[bool], margin: impl Fn(usize) -> usize) {
        let (tx_n, ty_n) = (self.tiles_x as isize, self.tiles_y as isize);
        for (t, _) in active.iter().enumerate().filter(|(_, a)| **a) {
            let r = margin(t);
            let (tx, ty) = ((t % self.tiles_x) as isize, (t / self.tiles_x) as isize);
            for dy in -1..=1 {
                for dx in -1..=1 {
                    let (x, y) = (tx + dx, ty + dy);
                    if x < 0 || y < 0 || x >= tx_n || y >= ty_n {
                        continue;
                    }
                    let u = (y * tx_n + x) as usize;
                    let (x0, x1, y0, y1) = self.tile_bounds(u);
                    // Only the margin next to the active tile is needed.
                    let (xa, xb) = match dx {
                        -1 => (x1.saturating_sub(r).max(x0), x1),
                        0 => (x0, x1),
                        _ => (x0, (x0 + r).min(x1)),
                    };
                    let (ya, yb) = match dy {
                        -1 => (y1.saturating_sub(r).max(y0), y1),
                        0 => (y0, y1),
                        _ => (y0, (y0 + r).min(y1)),
                    };
                    merge(&mut self.response_box[u], [xa, xb, ya, yb]);
                }
            }
        }
    }

    fn mark_boxes_by_level(&mut self, active: &[bool]) {
        let radii: [usize; 8] =
            std::array::from_fn(|i| self.levels.get(i).map_or(0, |l| l.kernels.radius));
        let tile_level = std::mem::take(&mut self.tile_level);
        self.mark_boxes(active, |t| radii[(tile_level[t] as usize).min(7)]);
        self.tile_level = tile_level;
    }

    /// Fills every response box not already filled (a box that grew is filled again
    /// whole: only wide scales grow their margins past [`WIDTH_MARGIN`]).
    fn fill_boxes(&mut self, fill: &mut impl FnMut(usize, usize, &mut [f32], &mut [u8])) {
        for t in 0..self.response_box.len() {
            let mut need = self.response_box[t];
            let done = self.filled_box[t];
            if need[0] >= need[1] {
                continue;
            }
            if done[0] < done[1] {
                if done[0] <= need[0]
                    && done[1] >= need[1]
                    && done[2] <= need[2]
                    && done[3] >= need[3]
                {
                    continue;
                }
                merge(&mut need, done);
            }
            let [x0, x1, y0, y1] = need;
            for y in y0..y1 {
                let span = y * self.width + x0..y * self.width + x1;
                fill(
                    y,
                    x0,
                    &mut self.response[span.clone()],
                    &mut self.masked[span],
                );
            }
            self.filled_box[t] = need;
        }
    }

    /// Finds ridge points of strength (grey levels) at least `min_strength` on the
    /// active tiles (after [`Self::prepare`]), each tile at its scale. Clears the
    /// previous frame's points first.
    pub fn detect(&mut self, active: &[bool], min_strength: f32) {
        for p in &self.points {
            self.index[p.pixel as usize] = NO_POINT;
        }
        self.points.clear();
        self.detect_more(active, min_strength);
    }

    /// Adds the ridge points of the tiles `more` (after [`Self::extend`]) to those found
    /// so far.
    pub fn detect_more(&mut self, active: &[bool], min_strength: f32) {
        // Taken out for the loop, so that the tiles of a scale can be listed while the
        // passes borrow the detector.
        let tile_level = std::mem::take(&mut self.tile_level);
        let tiles_of = |level: usize| {
            active
                .iter()
                .zip(&tile_level)
                .enumerate()
                .filter(move |(_, (a, l))| **a && **l as usize == level)
                .map(|(t, _)| t)
        };
        for level in 0..self.levels.len() {
            if tiles_of(level).next().is_none() {
                continue;
            }
            // Rows needed by this scale's tiles: the tiles and the radius above, below.
            self.rows_box.fill(EMPTY);
            let r = self.levels[level].kernels.radius;
            for t in tiles_of(level) {
                let (tx, ty) = (t % self.tiles_x, t / self.tiles_x);
                for dy in -1isize..=1 {
                    let y = ty as isize + dy;
                    if y < 0 || y >= self.tiles_y as isize {
                        continue;
                    }
                    let u = y as usize * self.tiles_x + tx;
                    let (x0, x1, y0, y1) = self.tile_bounds(u);
                    let (ya, yb) = match dy {
                        -1 => (y1.saturating_sub(r).max(y0), y1),
                        0 => (y0, y1),
                        _ => (y0, (y0 + r).min(y1)),
                    };
                    merge(&mut self.rows_box[u], [x0, x1, ya, yb]);
                }
            }
            for t in 0..self.rows_box.len() {
                if self.rows_box[t][0] < self.rows_box[t][1] {
                    self.row_pass(level, self.rows_box[t]);
                }
            }
            let min_level = min_strength * self.levels[level].per_grey;
            for t in tiles_of(level) {
                self.column_pass_and_hessian(level, t, min_level);
            }
        }
        self.tile_level = tile_level;
    }

    /// Smooths, and differentiates once and twice, the response rows of `rect` along x.
    ///
    /// The kernels are symmetric (`k0`, `k2`) or antisymmetric (`k1`) about their centre
    /// ([`Kernels::new`]), so each pair of taps `±i` costs one sum and one difference of
    /// the two samples and three multiply-adds, instead of six multiply-adds.
    fn row_pass(&mut self, level: usize, [x0, x1, y0, y1]: Rect) {
        let w = self.width;
        let kernels = &self.levels[level].kernels;
        let r = kernels.radius;
        // Taps at offsets 0..=r; those at −i mirror them.
        let (k0, k1, k2) = (&kernels.k0[r..], &kernels.k1[r..], &kernels.k2[r..]);
        let fast = x0 >= r && x1 + r <= w;
        for y in y0..y1 {
            let row = &self.response[y * w..(y + 1) * w];
            let o0 = &mut self.row_s[y * w + x0..y * w + x1];
            let o1 = &mut self.row_d1[y * w + x0..y * w + x1];
            let o2 = &mut self.row_d2[y * w + x0..y * w + x1];
            if fast {
                // The centre tap (k1 is zero there) and the first pair, written rather
                // than added, so that the outputs need no zeroing.
                let (a, b, c) = (k0[1], k1[1], k2[1]);
                let (c0, c2) = (k0[0], k2[0]);
                let mid = &row[x0..x1];
                let hi = &row[x0 + 1..x1 + 1];
                let lo = &row[x0 - 1..x1 - 1];
                for (((((p0, p1), p2), m), u), v) in o0
                    .iter_mut()
                    .zip(o1.iter_mut())
                    .zip(o2.iter_mut())
                    .zip(mid)
                    .zip(hi)
                    .zip(lo)
                {
                    let (sum, diff) = (u + v, u - v);
                    *p0 = m * c0 + sum * a;
                    *p1 = diff * b;
                    *p2 = m * c2 + sum * c;
                }
                for i in 2..=r {
                    let (a, b, c) = (k0[i], k1[i], k2[i]);
                    let hi = &row[x0 + i..x1 + i];
                    let lo = &row[x0 - i..x1 - i];
                    for ((((p0, p1), p2), u), v) in o0
                        .iter_mut()
                        .zip(o1.iter_mut())
                        .zip(o2.iter_mut())
                        .zip(hi)
                        .zip(lo)
                    {
                        let (sum, diff) = (u + v, u - v);
                        *p0 += sum * a;
                        *p1 += diff * b;
                        *p2 += sum * c;
                    }
                }
            } else {
                // Near the left and right borders, samples past them repeat the edge.
                let at = |x: isize| row[x.clamp(0, w as isize - 1) as usize];
                for (k, x) in (x0..x1).enumerate() {
                    let m = row[x];
                    let (mut s0, mut s1, mut s2) = (m * k0[0], 0.0, m * k2[0]);
                    for i in 1..=r {
                        let (u, v) = (at((x + i) as isize), at(x as isize - i as isize));
                        let (sum, diff) = (u + v, u - v);
                        s0 += sum * k0[i];
                        s1 += diff * k1[i];
                        s2 += sum * k2[i];
                    }
                    o0[k] = s0;
                    o1[k] = s1;
                    o2[k] = s2;
                }
            }
        }
    }

    fn column_pass_and_hessian(&mut self, level: usize, t: usize, min_strength: f32) {
        let (x0, x1, y0, y1) = self.tile_bounds(t);
        let (w, h) = (self.width, self.height);
        let n = x1 - x0;
        let Level {
            kernels,
            mask_radius,
            flank_px,
            per_grey,
            sigma_px,
            ..
        } = &self.levels[level];
        let (mask_radius, flank_px, per_grey, sigma_px) =
            (*mask_radius, *flank_px, *per_grey, *sigma_px);
        let (gx, rest) = self.acc.split_at_mut(self.tile);
        let (gy, rest) = rest.split_at_mut(self.tile);
        let (gxx, rest) = rest.split_at_mut(self.tile);
        let (gxy, rest) = rest.split_at_mut(self.tile);
        let (gyy, rest) = rest.split_at_mut(self.tile);
        let (g, rest) = rest.split_at_mut(self.tile);
        let (smooth, slope) = rest.split_at_mut(self.tile);
        // Taps at offsets 0..=r; those at −i mirror them (see `row_pass`).
        let r = kernels.radius;
        let (k0, k1, k2) = (&kernels.k0[r..], &kernels.k1[r..], &kernels.k2[r..]);
        // Rows past the top and bottom borders repeat the edge row.
        let span = |ys: usize| ys * w + x0..ys * w + x1;
        // Whether the tile is within `mask_radius` of a masked pixel: found out at its
        // first point, and only then are its points tested one by one.
        let mut tile_near_mask = None;
        let (rs, rd1, rd2) = (&self.row_s, &self.row_d1, &self.row_d2);
        for y in y0..y1 {
            // The centre tap (k1 is zero there) and the first pair are written rather
            // than added, so that the sums need no zeroing; each later pair ±i adds the
            // sum and difference of its two rows, weighted once.
            for i in 1..=r {
                let (hi, lo) = (span((y + i).min(h - 1)), span(y.saturating_sub(i)));
                let (a, b, c) = (k0[i], k1[i], k2[i]);
                // Three zipped loops rather than one indexed one: no bounds checks, so
                // they vectorise.
                if i == 1 {
                    let mid = span(y);
                    let (c0, c2) = (k0[0], k2[0]);
                    for (((((a0, a1), a2), m), u), v) in g[..n]
                        .iter_mut()
                        .zip(gy[..n].iter_mut())
                        .zip(gyy[..n].iter_mut())
                        .zip(&rs[mid.clone()])
                        .zip(&rs[hi.clone()])
                        .zip(&rs[lo.clone()])
                    {
                        let (sum, diff) = (u + v, u - v);
                        *a0 = m * c0 + sum * a;
                        *a1 = diff * b;
                        *a2 = m * c2 + sum * c;
                    }
                    for ((((a0, a1), m), u), v) in gx[..n]
                        .iter_mut()
                        .zip(gxy[..n].iter_mut())
                        .zip(&rd1[mid.clone()])
                        .zip(&rd1[hi.clone()])
                        .zip(&rd1[lo.clone()])
                    {
                        *a0 = m * c0 + (u + v) * a;
                        *a1 = (u - v) * b;
                    }
                    for (((a0, m), u), v) in gxx[..n]
                        .iter_mut()
                        .zip(&rd2[mid])
                        .zip(&rd2[hi])
                        .zip(&rd2[lo])
                    {
                        *a0 = m * c0 + (u + v) * a;
                    }
                } else {
                    for ((((a0, a1), a2), u), v) in g[..n]
                        .iter_mut()
                        .zip(gy[..n].iter_mut())
                        .zip(gyy[..n].iter_mut())
                        .zip(&rs[hi.clone()])
                        .zip(&rs[lo.clone()])
                    {
                        let (sum, diff) = (u + v, u - v);
                        *a0 += sum * a;
                        *a1 += diff * b;
                        *a2 += sum * c;
                    }
                    for (((a0, a1), u), v) in gx[..n]
                        .iter_mut()
                        .zip(gxy[..n].iter_mut())
                        .zip(&rd1[hi.clone()])
                        .zip(&rd1[lo.clone()])
                    {
                        *a0 += (u + v) * a;
                        *a1 += (u - v) * b;
                    }
                    for ((a0, u), v) in gxx[..n].iter_mut().zip(&rd2[hi]).zip(&rd2[lo]) {
                        *a0 += (u + v) * a;
                    }
                }
            }
            // The Hessian's eigen-analysis and the sub-pixel offset for the whole row,
            // without branches so that it vectorises (most pixels of a wide stripe pass
            // the strength test and fail the offset test: branching on each test
            // mispredicts, and its square roots and divisions run one at a time). The
            // sums are overwritten in place with (nx, ny, λ, ox, oy, keep), and the
            // smoothed response and its slope across kept for the glow step.
            for (((((((pxx, pxy), pyy), px), py), p), sm), sl) in gxx[..n]
                .iter_mut()
                .zip(gxy[..n].iter_mut())
                .zip(gyy[..n].iter_mut())
                .zip(gx[..n].iter_mut())
                .zip(gy[..n].iter_mut())
                .zip(g[..n].iter_mut())
                .zip(smooth[..n].iter_mut())
                .zip(slope[..n].iter_mut())
            {
                let (a, b, c) = (*pxx, *pxy, *pyy);
                let half = 0.5 * (a + c);
                let disc2 = 0.25 * (a - c) * (a - c) + b * b;
                // −λ = disc − half ≥ min_strength: disc² ≥ need² where need > 0.
                let need = min_strength + half;
                let disc = disc2.sqrt();
                let lambda = half - disc;
                let (ux, uy) = (b, lambda - a);
                let (vx, vy) = (lambda - c, b);
                let (nx, ny) = if ux * ux + uy * uy >= vx * vx + vy * vy {
                    (ux, uy)
                } else {
                    (vx, vy)
                };
                let norm = (nx * nx + ny * ny).sqrt();
                let (nx, ny) = (nx / norm, ny / norm);
                // Offset to the peak along the normal from the second-order Taylor
                // expansion of ln g rather than of g: exact for a Gaussian profile of
                // any width, where Steger's plain step −g'/g'' overshoots by about
                // d³/(s² + σ²) (up to 0.05 px at d = 0.5 px, which also opens gaps
                // where the line crosses between two pixel rows).
                let d1 = nx * *px + ny * *py;
                let gk = *p;
                // t = d1·g / (d1² − g·λ) where g > 0, else −d1 / λ; one division for
                // either.
                let (num, den) = if gk > 0.0 {
                    (d1 * gk, d1 * d1 - gk * lambda)
                } else {
                    (-d1, lambda)
                };
                let tt = num / den;
                let (ox, oy) = (tt * nx, tt * ny);
                // Bright line: the strongest curvature is across it and negative;
                // strong enough; not an isotropic Hessian (a blob, not a line); and
                // the peak inside the pixel.
                let drop = (half > 0.0)
                    | ((need > 0.0) & (disc2 < need * need))
                    | (norm <= f32::EPSILON * disc.max(f32::MIN_POSITIVE))
                    | (ox.abs() > 0.5)
                    | (oy.abs() > 0.5);
                (*pxx, *pxy, *pyy, *px, *py) = (nx, ny, lambda, ox, oy);
                (*sm, *sl) = (gk, d1);
                *p = if drop { 0.0 } else { 1.0 };
            }
            let found = gxx[..n]
                .iter()
                .zip(&gxy[..n])
                .zip(&gyy[..n])
                .zip(&gx[..n])
                .zip(&gy[..n])
                .zip(&g[..n])
                .enumerate()
                .filter(|(_, (_, keep))| **keep != 0.0);
            for (k, (((((&nx, &ny), &lambda), &ox), &oy), _)) in found {
                let (gk, d1) = (smooth[k], slope[k]);
                let x = x0 + k;
                if *tile_near_mask.get_or_insert_with(|| {
                    Self::near_mask(&self.masked, (w, h), mask_radius, [x0, x1, y0, y1])
                }) && Self::near_mask(&self.masked, (w, h), mask_radius, [x, x + 1, y, y + 1])
                {
                    continue;
                }
                let (px, py) = (x as f32 + ox, y as f32 + oy);
                // Against a local background the point is located on the laser's own
                // channel, and its strength is the part of it with the laser's colour.
                let share = if self.texture_kept {
                    Self::chromatic_share(&self.response, &self.masked, (w, h), [px, py], [nx, ny])
                } else {
                    1.0
                };
                if -lambda * share < min_strength {
                    continue;
                }
                let [centre, below, above] =
                    Self::flanks(&self.response, (w, h), [px, py], [nx, ny], flank_px);
                // Stands above both flanks: a stripe (on a dark background or on a
                // pedestal beside it) does; the bright edge of a wide glow band, whose
                // Hessian also reads as a ridge, has the glow on one flank and does not.
                if below > FLANK_RATIO * centre || above > FLANK_RATIO * centre {
                    continue;
                }
                if self.texture_kept
                    && self.masked[y * w + x] & 2 == 0
                    && self.flat_top.flat_topped(
                        |sx, sy| bilinear(&self.response, (w, h), sx, sy),
                        [px, py],
                        [nx, ny],
                        centre,
                        2.0 * flank_px + 2.0,
                    )
                {
                    continue;
                }
                let t = ox * nx + oy * ny;
                let pixel = y * w + x;
                self.index[pixel] = self.points.len() as u32;
                self.points.push(LinePoint {
                    x: px,
                    y: py,
                    nx,
                    ny,
                    strength: -lambda * share / per_grey,
                    pixel: pixel as u32,
                    ridge: [t, gk, d1, lambda],
                    flank_px,
                    sigma: sigma_px,
                });
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The passes fold the taps `±i` together, which is exact only if the kernels are.
    #[test]
    fn kernels_are_exactly_symmetric() {
        for sigma in [1.0, 1.3, 1.7, 2.2, 3.2, 4.5, 7.9] {
            let k = Kernels::new(sigma);
            let r = k.radius;
            assert_eq!(k.k0.len(), 2 * r + 1);
            assert_eq!(k.k1.len(), 2 * r + 1);
            assert_eq!(k.k2.len(), 2 * r + 1);
            assert_eq!(k.k1[r], 0.0, "sigma {sigma}");
            for i in 1..=r {
                assert_eq!(k.k0[r + i], k.k0[r - i], "sigma {sigma}, k0 at ±{i}");
                assert_eq!(k.k1[r + i], -k.k1[r - i], "sigma {sigma}, k1 at ±{i}");
                assert_eq!(k.k2[r + i], k.k2[r - i], "sigma {sigma}, k2 at ±{i}");
            }
        }
    }

    #[test]
    fn kernels_are_exact_on_polynomials() {
        for sigma in [1.0, 1.3, 2.5] {
            let k = Kernels::new(sigma);
            let r = k.radius as i32;
            let apply = |ker: &[f32], f: &dyn Fn(f64) -> f64| -> f64 {
                (-r..=r)
                    .zip(ker)
                    .map(|(i, c)| f(3.0 + i as f64) * *c as f64)
                    .sum()
            };
            assert!((apply(&k.k0, &|_| 1.0) - 1.0).abs() < 1e-5);
            assert!((apply(&k.k1, &|x| 2.0 * x + 1.0) - 2.0).abs() < 1e-5);
            assert!(apply(&k.k1, &|_| 1.0).abs() < 1e-6);
            assert!((apply(&k.k2, &|x| 1.5 * x * x - x + 4.0) - 3.0).abs() < 1e-4);
            assert!(apply(&k.k2, &|_| 1.0).abs() < 1e-5);
        }
    }
}
