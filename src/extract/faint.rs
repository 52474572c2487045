//! Activation of tiles by stripes too faint for any single pixel to show them.
//!
//! Under water a stripe fades with distance to a peak of a few times the sensor noise.
//! No pixel of it reaches `min_value`, and a per-pixel test low enough to see it fires
//! on noise all over the frame (at 3σ, a few pixels in every tile) and on the other
//! sheet's glow, which lights whole regions by 5–20 grey levels.
//!
//! A stripe differs from both by being a *ridge* that *continues*. So the
//! difference to the background is summed over 4×4 blocks (a quarter of the noise; a
//! thin stripe across a block keeps about two thirds of its peak), and per
//! channel a block is a ridge across x when it stands above both blocks two to its left
//! and right (8 px away, beyond a faint stripe's width) by `RIDGE_SIGMAS` times the
//! noise of a block sum, and a ridge across y likewise. A ridge counts where the block
//! rows above and below it (for a ridge across x), or the columns left and right of it
//! (across y), hold a ridge of the same kind and channel within one block sideways: a
//! stripe at any angle is a ridge across x or across y, and continues for 12 px. A glow
//! plateau or its edge is no ridge (one side is as bright), and noise rarely makes
//! three ridges in a row.
//!
//! The noise is measured on the frame itself: the robust spread (median absolute value)
//! of differences between horizontally neighbouring block sums over every fourth block
//! row, so a smooth glow does not inflate it and the threshold follows the camera.
//! Each region of 64 × 64 px needs more where its own spread is larger: the other
//! sheet's glow on a textured surface is a field of ridges.
//!
//! Only the channel in which the block's ridge is highest counts, and it activates the
//! lasers whose light is in that channel ([`super::LaserColour::channels`]): a bright
//! green stripe leaks a few per cent into red, far below its ridge in green.

/// A block is a ridge when it rises above both sides by this many times the noise of
/// a block sum.
pub const RIDGE_SIGMAS: f32 = 3.0;

/// Pixels per side of a block.
pub(super) const BLOCK: usize = 4;

/// Blocks per side of a cell whose darkening is measured ([`FaintRidges::darkening`]).
pub(super) const DARK_CELL: usize = 8;

/// A darkened cell is lifted only when the robust spread of its 4×4-block means about
/// their median is at most this (grey levels): lifted, the spread is what is left.
const LIFT_MAX_SPREAD: f32 = 3.0;

/// Cells whose mean lies less than this far below the background (grey levels) are
/// not lifted: noise alone puts half of them below it.
const LIFT_MIN: f32 = 2.0;

/// Blocks per side of a region whose own noise (or texture) is measured: 64 px.
const REGION: usize = 16;

/// A region's spread is measured on every this many block rows.
const REGION_ROW_STEP: usize = 4;

/// Differences of neighbouring block sums are clipped at this many times the frame's
/// noise before a region's mean is taken, so that a bright stripe through the region
/// raises its threshold only a little.
const REGION_CLIP_SIGMAS: f32 = 16.0;

/// Blocks sideways at which a ridge's sides are read (8 px).
const SIDE_BLOCKS: usize = 2;

/// Smallest ridge height (sum of a block's grey levels) whatever the noise measured:
/// a clean synthetic frame has none, and quantisation alone leaves ±0.5 per pixel.
const MIN_RIDGE_SUM: i32 = 4;

/// Scratch of the faint-stripe activation, reused across frames.
#[derive(Default)]
pub(super) struct FaintRidges {
    bw: usize,
    bh: usize,
    /// Per channel, per block: the sum of the difference over its `BLOCK²` pixels.
    sums: [Vec<i16>; 3],
    /// Per block: the background's sum over it, per channel (the surface's colour
    /// against a local background).
    surface: Vec<[u16; 3]>,
    /// The [`super::Background::id`] whose sums `surface` holds; `None` for a
    /// background made for its frame, summed again each time.
    surface_of: Option<u64>,
    /// Per block: the frame's sum over it, per channel.
    frame_sums: Vec<[u16; 3]>,
    /// Per block: bit `c` = ridge across x in channel `c`, bit `3 + c` = across y.
    flags: Vec<u8>,
    /// The four-row sums of one block row.
    row: Vec<u16>,
    hist: Vec<u32>,
    /// Per region of `REGION` × `REGION` blocks, per channel: the ridge height a block
    /// there must reach.
    region_threshold: Vec<[i16; 3]>,
    /// The last frame's noise of a block sum (grey levels), measured by `threshold`.
    pub noise: f32,
}

impl FaintRidges {
    /// Marks in `active[k]` the tiles (of `tile` px, `tiles_x` per row) holding a
    /// continued ridge in one of laser `k`'s `channels`. `frame` and `background` are
    /// packed RGB of `width × height`; `local`: the background is the frame's own
    /// local background, which leaves the surfaces' texture in the excess, so each
    /// ridge's part in the surface's colour is taken out first
    /// ([`Self::take_out_surface`]).
    #[allow(clippy::too_many_arguments)]
    pub fn activate(
        &mut self,
        frame: &[u8],
        (background, background_id): (&[u8], Option<u64>),
        (width, height): (usize, usize),
        (tile, tiles_x): (usize, usize),
        channels: &[[bool; 3]],
        active: &mut [Vec<bool>],
        local: bool,
    ) {
        let (bw, bh) = (width / BLOCK, height / BLOCK);
        if bw < 2 * SIDE_BLOCKS + 1 || bh < 2 * SIDE_BLOCKS + 1 {
            return;
        }
        self.sum_blocks(frame, (background, background_id), width, bw, bh);
        let threshold = self.threshold();
        self.region_thresholds(threshold);
        self.mark_ridges(local);
        // A ridge that continues into the block rows above and below (across x) or the
        // block columns left and right (across y), within one block sideways.
        let (flags, bw) = (&self.flags, self.bw);
        let has = |bx: usize, by: usize, bit: u8| flags[by * bw + bx] & bit != 0;
        for by in 1..bh - 1 {
            for bx in 1..bw - 1 {
                let f = flags[by * bw + bx];
                if f == 0 {
                    continue;
                }
                for c in 0..3 {
                    let (x_bit, y_bit) = (1u8 << c, 8u8 << c);
                    let sideways = |b: usize| b - 1..=b + 1;
                    let across_x = f & x_bit != 0
                        && sideways(bx).any(|x| has(x, by - 1, x_bit))
                        && sideways(bx).any(|x| has(x, by + 1, x_bit));
                    let across_y = f & y_bit != 0
                        && sideways(by).any(|y| has(bx - 1, y, y_bit))
                        && sideways(by).any(|y| has(bx + 1, y, y_bit));
                    if across_x || across_y {
                        let t = (BLOCK * by / tile) * tiles_x + BLOCK * bx / tile;
                        for (k, ch) in channels.iter().enumerate() {
                            if ch[c] {
                                active[k][t] = true;
                            }
                        }
                    }
                }
            }
        }
    }

    /// Per cell of `DARK_CELL` × `DARK_CELL` blocks (32 px), per channel: how far the
    /// frame lies evenly below its background there, into `out` (cells in rows of
    /// `(bw + DARK_CELL − 1) / DARK_CELL`, returned). That is the median of the cell's
    /// block means when the cell's mean is at least `LIFT_MIN` below and the blocks'
    /// robust spread about the median is at most `LIFT_MAX_SPREAD`; 0 otherwise. Empty
    /// before the first [`Self::activate`].
    pub fn darkening(&self, out: &mut Vec<[u8; 3]>) -> usize {
        let (bw, bh) = (self.bw, self.bh);
        let (cx, cy) = (bw.div_ceil(DARK_CELL), bh.div_ceil(DARK_CELL));
        out.clear();
        out.resize(cx * cy, [0; 3]);
        let mut vals: Vec<i16> = Vec::with_capacity(DARK_CELL * DARK_CELL);
        for cyi in 0..cy {
            for cxi in 0..cx {
                for (c, sums) in self.sums.iter().enumerate() {
                    vals.clear();
                    for by in DARK_CELL * cyi..(DARK_CELL * (cyi + 1)).min(bh) {
                        let row = &sums[by * bw..(by + 1) * bw];
                        vals.extend_from_slice(
                            &row[DARK_CELL * cxi..(DARK_CELL * (cxi + 1)).min(bw)],
                        );
                    }
                    // Most cells are not darkened: their mean tells at once.
                    let sum: i32 = vals.iter().map(|&v| i32::from(v)).sum();
                    let px = (BLOCK * BLOCK) as f32;
                    if vals.is_empty() || (sum as f32) > -LIFT_MIN * px * vals.len() as f32 {
                        continue;
                    }
                    let mid = vals.len() / 2;
                    let m = *vals.select_nth_unstable(mid).1;
                    if m >= 0 {
                        continue;
                    }
                    // Only an even darkening: a textured surface darkened would, lifted,
                    // be a field of ridges as high as its spread.
                    for v in vals.iter_mut() {
                        *v = (*v - m).abs();
                    }
                    let mad = *vals.select_nth_unstable(mid).1;
                    if 1.4826 * f32::from(mad) / px > LIFT_MAX_SPREAD {
                        continue;
                    }
                    out[cyi * cx + cxi][c] = (-f32::from(m) / px).round().clamp(0.0, 255.0) as u8;
                }
            }
        }
        cx
    }

    /// Row `y` of a packed image of `stride` bytes per row.
    fn row_of(img: &[u8], stride: usize, y: usize) -> &[u8] {
        &img[y * stride..(y + 1) * stride]
    }

    /// Per block and channel, the sums of the frame less those of the background
    /// (into `sums`), and the background's own (into `surface`). The difference is
    /// signed, so that the noise is the same where the frame is at its background and
    /// where a glow lifts it. A background's sums are kept while its id does: a
    /// laser-off frame or a median serves many frames.
    fn sum_blocks(
        &mut self,
        frame: &[u8],
        (background, background_id): (&[u8], Option<u64>),
        width: usize,
        bw: usize,
        bh: usize,
    ) {
        if (self.bw, self.bh) != (bw, bh) {
            self.bw = bw;
            self.bh = bh;
            for s in &mut self.sums {
                *s = vec![0; bw * bh];
            }
            self.flags = vec![0; bw * bh];
            self.surface_of = None;
        }
        if background_id.is_none() || background_id != self.surface_of {
            Self::block_sums(
                background,
                width,
                (bw, bh),
                &mut self.row,
                &mut self.surface,
            );
            self.surface_of = background_id;
        }
        Self::block_sums(frame, width, (bw, bh), &mut self.row, &mut self.frame_sums);
        let [r, g, b] = &mut self.sums;
        for ((((r, g), b), f), s) in r
            .iter_mut()
            .zip(g.iter_mut())
            .zip(b.iter_mut())
            .zip(&self.frame_sums)
            .zip(&self.surface)
        {
            // At most 16 · 255 each: the difference fits an i16.
            *r = f[0] as i16 - s[0] as i16;
            *g = f[1] as i16 - s[1] as i16;
            *b = f[2] as i16 - s[2] as i16;
        }
    }

    /// Per block (`bw × bh` of them), per channel: the sum of packed RGB `image`
    /// (`width` px wide) over the block's `BLOCK²` pixels, into `out`; `row` is
    /// scratch.
    fn block_sums(
        image: &[u8],
        width: usize,
        (bw, bh): (usize, usize),
        row: &mut Vec<u16>,
        out: &mut Vec<[u16; 3]>,
    ) {
        let stride = 3 * width;
        row.resize(stride, 0);
        out.resize(bw * bh, [0; 3]);
        for by in 0..bh {
            let y = BLOCK * by;
            let (p0, p1, p2, p3) = (
                Self::row_of(image, stride, y),
                Self::row_of(image, stride, y + 1),
                Self::row_of(image, stride, y + 2),
                Self::row_of(image, stride, y + 3),
            );
            // One pass over the block's four rows, all slices of one length: the
            // compiler vectorises it.
            let row = &mut row[..stride];
            for i in 0..stride {
                row[i] = u16::from(p0[i]) + u16::from(p1[i]) + u16::from(p2[i]) + u16::from(p3[i]);
            }
            for (o, px) in out[by * bw..(by + 1) * bw]
                .iter_mut()
                .zip(row.chunks_exact(3 * BLOCK))
            {
                let mut sum = [0u16; 3];
                for p in px.chunks_exact(3) {
                    sum[0] += p[0];
                    sum[1] += p[1];
                    sum[2] += p[2];
                }
                *o = sum;
            }
        }
    }

    /// The ridge height a block must reach: `RIDGE_SIGMAS` times the noise of a block
    /// sum, from the median absolute difference of horizontal neighbours.
    fn threshold(&mut self) -> i32 {
        self.hist.clear();
        self.hist.resize(1024, 0);
        let mut n = 0u64;
        for s in &self.sums {
            for row in s.chunks_exact(self.bw).step_by(4) {
                for pair in row.windows(2) {
                    let d = (i32::from(pair[0]) - i32::from(pair[1])).unsigned_abs() as usize;
                    self.hist[d.min(1023)] += 1;
                    n += 1;
                }
            }
        }
        // Median with linear interpolation inside its bin: the differences are whole
        // grey levels, and at low noise the median is a bin or two.
        let half = n as f64 / 2.0;
        let mut below = 0u64;
        let mut median = 0.0;
        for (d, &count) in self.hist.iter().enumerate() {
            let next = below + u64::from(count);
            if next as f64 >= half {
                let frac = if count > 0 {
                    (half - below as f64) / count as f64
                } else {
                    0.0
                };
                // Bin d holds |difference| = d; it spans d − 0.5 .. d + 0.5 (0 .. 0.5).
                median = if d == 0 {
                    0.5 * frac
                } else {
                    d as f64 - 0.5 + frac
                };
                break;
            }
            below = next;
        }
        // MAD of a difference of two sums → σ of one sum.
        let sigma = 1.4826 * median / std::f64::consts::SQRT_2;
        self.noise = sigma as f32;
        ((RIDGE_SIGMAS as f64 * sigma).ceil() as i32).max(MIN_RIDGE_SUM)
    }

    /// Per region and channel, the larger of the frame's `threshold` and
    /// `RIDGE_SIGMAS` times the region's own spread of neighbouring block sums (their
    /// mean absolute difference, clipped): where the other sheet's glow lights a
    /// textured surface, the texture is a field of ridges, and only a stripe that
    /// stands out of it counts.
    fn region_thresholds(&mut self, threshold: i32) {
        let (bw, bh) = (self.bw, self.bh);
        let (rx, ry) = (bw.div_ceil(REGION), bh.div_ceil(REGION));
        let clip = (REGION_CLIP_SIGMAS * self.noise * std::f32::consts::SQRT_2).max(1.0) as u16;
        // Every `REGION_ROW_STEP`-th block row: 4 rows and 60 differences per channel
        // and region.
        let mut sum = vec![[0u32; 3]; rx * ry];
        for by in (0..bh).step_by(REGION_ROW_STEP) {
            let region_row = (by / REGION) * rx;
            for (c, s) in self.sums.iter().enumerate() {
                let row = &s[by * bw..(by + 1) * bw];
                for (r, chunk) in row.chunks(REGION).enumerate() {
                    let total: u32 = chunk
                        .windows(2)
                        .map(|p| u32::from(p[0].abs_diff(p[1]).min(clip)))
                        .sum();
                    sum[region_row + r][c] += total;
                }
            }
        }
        self.region_threshold.clear();
        for (r, sums) in sum.iter().enumerate() {
            let (x, y) = (r % rx, r / rx);
            let cols = REGION.min(bw - x * REGION);
            let rows = (y * REGION..((y + 1) * REGION).min(bh))
                .filter(|r| r % REGION_ROW_STEP == 0)
                .count();
            let n = ((cols - 1) * rows).max(1);
            self.region_threshold.push(sums.map(|total| {
                // Mean absolute difference of two sums of σ: 2σ/√π.
                let sigma = total as f32 / n as f32 * std::f32::consts::PI.sqrt() / 2.0;
                let local = (RIDGE_SIGMAS * sigma).ceil() as i32;
                local.max(threshold).min(i32::from(i16::MAX)) as i16
            }));
        }
    }

    /// Against a local background: takes out of each block's ridge heights (across x
    /// in `hx`, across y in `hy`, per channel) their part along the colour of the
    /// surface under the block (`surface`, the background's block sums). A surface's
    /// texture is its reflectance varying, so its ridges in the excess have the
    /// surface's own colour, in every channel in proportion; a laser adds light of its
    /// own hue, whatever the surface. What is left is the ridge that the surface's
    /// colour does not explain: about nothing for texture, most of a stripe of another
    /// hue (a faint blue stripe on a dark red box keeps nearly all of its height). A stripe
    /// in the surface's own hue is left out: the frame alone does not tell it from the
    /// texture.
    fn take_out_surface(hx: &mut [Vec<i16>; 3], hy: &mut [Vec<i16>; 3], surface: &[[u16; 3]]) {
        for h in [hx, hy] {
            let [r, g, b] = h;
            for (((r, g), b), s) in r
                .iter_mut()
                .zip(g.iter_mut())
                .zip(b.iter_mut())
                .zip(surface)
            {
                let v = [f32::from(*r), f32::from(*g), f32::from(*b)];
                let s = s.map(f32::from);
                let ss = s[0] * s[0] + s[1] * s[1] + s[2] * s[2];
                // Only a ridge *along* the surface's colour is texture: a dip in it
                // leaves the ridge as it is.
                let along = if ss > 0.0 {
                    ((v[0] * s[0] + v[1] * s[1] + v[2] * s[2]) / ss).max(0.0)
                } else {
                    0.0
                };
                *r = (v[0] - along * s[0]) as i16;
                *g = (v[1] - along * s[1]) as i16;
                *b = (v[2] - along * s[2]) as i16;
            }
        }
    }

    /// Sets each block's ridge flags: across x and across y, in the channel where its
    /// ridge is highest. Blocks within `SIDE_BLOCKS` of the border have no two sides
    /// and are no ridges.
    fn mark_ridges(&mut self, local: bool) {
        let (bw, bh) = (self.bw, self.bh);
        let k = SIDE_BLOCKS;
        let regions_x = bw.div_ceil(REGION);
        self.flags.fill(0);
        // Per channel, the ridge heights of one block row and the thresholds of its
        // columns (interior columns only): slices of one length, and the rule below
        // without branches, so that the compiler vectorises both loops (this was a
        // third of the faint activation's time, which reads every pixel of a frame).
        let inner = bw - 2 * k;
        let mut hx = [vec![0i16; inner], vec![0i16; inner], vec![0i16; inner]];
        let mut hy = [vec![0i16; inner], vec![0i16; inner], vec![0i16; inner]];
        let mut th = [vec![0i16; inner], vec![0i16; inner], vec![0i16; inner]];
        let mut region_row = usize::MAX;
        for by in k..bh - k {
            if by / REGION != region_row {
                region_row = by / REGION;
                let thresholds = &self.region_threshold[region_row * regions_x..];
                for (c, th) in th.iter_mut().enumerate() {
                    for (j, t) in th.iter_mut().enumerate() {
                        *t = thresholds[(j + k) / REGION][c];
                    }
                }
            }
            for c in 0..3 {
                let s = &self.sums[c];
                let row = &s[by * bw..(by + 1) * bw];
                let (left, mid, right) = (&row[..inner], &row[k..k + inner], &row[2 * k..]);
                let up = &s[(by - k) * bw + k..][..inner];
                let down = &s[(by + k) * bw + k..][..inner];
                for (j, (x, y)) in hx[c].iter_mut().zip(hy[c].iter_mut()).enumerate() {
                    let v = mid[j];
                    *x = v.saturating_sub(left[j].max(right[j]));
                    *y = v.saturating_sub(up[j].max(down[j]));
                }
            }
            if local {
                Self::take_out_surface(&mut hx, &mut hy, &self.surface[by * bw + k..][..inner]);
            }
            let flags = &mut self.flags[by * bw + k..][..inner];
            let ([x0, x1, x2], [y0, y1, y2], [t0, t1, t2]) = (&hx, &hy, &th);
            for (j, f) in flags.iter_mut().enumerate() {
                let h = [x0[j].max(y0[j]), x1[j].max(y1[j]), x2[j].max(y2[j])];
                // The channel where the ridge is highest (the first of equals).
                let c0 = h[0] >= h[1] && h[0] >= h[2];
                let c1 = !c0 && h[1] >= h[2];
                let c2 = !c0 && !c1;
                *f = u8::from(c0 & (x0[j] >= t0[j]))
                    | u8::from(c1 & (x1[j] >= t1[j])) << 1
                    | u8::from(c2 & (x2[j] >= t2[j])) << 2
                    | u8::from(c0 & (y0[j] >= t0[j])) << 3
                    | u8::from(c1 & (y1[j] >= t1[j])) << 4
                    | u8::from(c2 & (y2[j] >= t2[j])) << 5;
            }
        }
    }
}

#[cfg(test)]
#[path = "faint_tests.rs"]
mod tests;
