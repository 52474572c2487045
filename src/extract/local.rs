//! The local background: what a frame would show without its stripes, estimated from
//! the frame alone, for when no laser-off frame exists (one photo, the first frames of
//! a live scan, a scene that changed during the sweep).
//!
//! Per channel, a morphological opening (a minimum, then a maximum, over a square
//! window `2r + 1` px wide, each separable: down the columns by van Herk / Gil–Werman
//! in three comparisons per pixel whatever `r`, along the rows by doubling in
//! `log₂(2r + 1) + 1`, both over whole rows, which vectorise; the columns block by
//! block and the rows one at a time, so that the scratch stays in the cache): anything
//! bright and narrower than the window (a stripe) is taken out, while surfaces, their
//! shading and the steps between them (a checkerboard's squares, a lit wall's edge)
//! are kept as they are. The opening of a noisy surface lies below its mean by the
//! noise's extreme over the window, which differs from surface to surface (shot noise
//! grows with brightness; texture differs); that bias is measured on the frame (per
//! channel, the median of the frame over the opening in each 64 px tile, interpolated
//! between tile centres) and added back, so the excess of a bare surface is centred on
//! zero, as it is over a laser-off frame.
//!
//! Owns its scratch buffers; knows nothing of colours or lasers.

use image::RgbImage;

/// Half width (px) of the opening's window by default: a window of 17 px takes out
/// stripes up to ~8 px wide (FWHM) entirely and leaves of a wider one the cap above
/// its value 8 px off centre, still centred on it, while keeping surfaces, squares and
/// objects larger than the window as they are (a wider window takes a 50 px square of
/// a checkerboard for a stripe).
pub const DEFAULT_RADIUS_PX: usize = 8;

/// The scratch of [`LocalBackground::estimate_into`].
#[derive(Clone, Debug, Default)]
pub struct LocalBackground {
    radius: usize,
    a: Vec<u8>,
    /// Prefix and suffix extremes of the van Herk passes; padded rows of the row passes.
    g: Vec<u8>,
    h: Vec<u8>,
    bias: BiasScratch,
}

impl LocalBackground {
    /// An estimator with an opening of half width `radius_px` (at least 1).
    pub fn new(radius_px: usize) -> Self {
        Self {
            radius: radius_px.max(1),
            ..Self::default()
        }
    }

    pub fn radius_px(&self) -> usize {
        self.radius
    }

    /// Writes the local background of `frame` into `out` (resized if needed).
    pub fn estimate_into(&mut self, frame: &RgbImage, out: &mut RgbImage) {
        let (w, h) = (frame.width() as usize, frame.height() as usize);
        if out.dimensions() != frame.dimensions() {
            *out = RgbImage::new(frame.width(), frame.height());
        }
        let r = self.radius;
        let stride = 3 * w;
        self.a.resize(stride * h, 0);
        // The two blocks of extremes of the column passes, and the padded rows of the
        // row passes.
        for v in [&mut self.g, &mut self.h] {
            v.resize((2 * (2 * r + 1) * stride).max(3 * (w + 2 * r)), 0);
        }
        let src: &[u8] = frame.as_raw();
        // A square window is a row window after a column window, for the minimum and
        // the maximum alike; the row minimum and maximum run on one row at a time,
        // while it is in the cache.
        let (a, g, hs) = (&mut self.a, &mut self.g, &mut self.h);
        cols_pass(src, a, (w, h), r, (g, hs), u8::min);
        for row in a.chunks_exact_mut(stride) {
            row_extreme(row, r, (g, hs), u8::min, u8::MAX);
            row_extreme(row, r, (g, hs), u8::max, 0);
        }
        let dst: &mut [u8] = out;
        cols_pass(a, dst, (w, h), r, (g, hs), u8::max);
        add_local_bias(src, dst, (w, h), BIAS_TILE_PX, &mut self.bias);
    }
}

/// Side (px) of the tiles over which the opening's bias is measured: wide enough that
/// a stripe (at most a window, 17 px, across) and a crossing leave most of a tile's
/// pixels bare surface, and narrow enough to follow the surfaces of a scene.
const BIAS_TILE_PX: usize = 64;

/// Rows that share one interpolated bias line: the bias moves by a sixteenth of a
/// tile's difference over them.
const BIAS_ROWS: usize = 4;

/// A tile's bias is measured on every this many rows.
const BIAS_SAMPLE_ROWS: usize = 4;

/// Scratch of [`add_local_bias`].
#[derive(Clone, Debug, Default)]
struct BiasScratch {
    /// Per tile, per channel: the opening's bias (grey levels × 256).
    tiles: Vec<[i32; 3]>,
    /// Per tile column: the bias interpolated to the current rows (× 256).
    column: Vec<[i32; 3]>,
    /// Per pixel column: the two tile columns it lies between and its weight on the
    /// second (of 256).
    xs: Vec<(u32, u32, i32)>,
    /// The bias of the current rows, per byte.
    line: Vec<u8>,
}

/// Adds to `opening`, per channel, how far it lies below the bare surface around each
/// pixel: the median of `frame − opening` per tile of `tile` px, interpolated
/// bilinearly between tile centres. The opening of a noisy or textured surface lies
/// below its mean by the extreme of its noise over the window, which varies across a
/// scene (shot noise grows with brightness, texture differs from surface to surface);
/// one bias for the whole frame left smooth surfaces' excess below zero (a stripe's
/// shoulders lost) and textured ones' above (texture taken for stripes).
fn add_local_bias(
    frame: &[u8],
    opening: &mut [u8],
    (w, h): (usize, usize),
    tile: usize,
    s: &mut BiasScratch,
) {
    let (tx, ty) = (w.div_ceil(tile), h.div_ceil(tile));
    let stride = 3 * w;
    s.tiles.clear();
    for j in 0..ty {
        for i in 0..tx {
            let mut hist = [[0u32; 256]; 3];
            let mut count = 0u32;
            let (x0, x1) = (i * tile, ((i + 1) * tile).min(w));
            // Every other pixel of every few rows, staggered: 512 samples of a whole
            // tile, whose median is within 0.06 σ of the tile's.
            for y in (j * tile..((j + 1) * tile).min(h)).step_by(BIAS_SAMPLE_ROWS) {
                let row = &frame[y * stride..(y + 1) * stride];
                let orow = &opening[y * stride..(y + 1) * stride];
                for x in (x0 + (y / BIAS_SAMPLE_ROWS) % 2..x1).step_by(2) {
                    for (c, hc) in hist.iter_mut().enumerate() {
                        let k = 3 * x + c;
                        hc[row[k].saturating_sub(orow[k]) as usize] += 1;
                    }
                    count += 1;
                }
            }
            s.tiles
                .push(hist.map(|hc| 256 * median_of_histogram(&hc, count) as i32));
        }
    }
    // Tile centres lie at `(i + ½) tile`; outside the outer centres the bias is held.
    let place = |p: usize, n: usize| -> (usize, usize, i32) {
        let f = ((p as f32 + 0.5) / tile as f32 - 0.5).clamp(0.0, (n - 1) as f32);
        let i0 = f as usize;
        (i0, (i0 + 1).min(n - 1), ((f - i0 as f32) * 256.0) as i32)
    };
    s.xs.clear();
    s.xs.extend((0..w).map(|x| {
        let (i0, i1, f) = place(x, tx);
        (i0 as u32, i1 as u32, f)
    }));
    s.column.resize(tx, [0; 3]);
    s.line.resize(stride, 0);
    for y0 in (0..h).step_by(BIAS_ROWS) {
        let y1 = (y0 + BIAS_ROWS).min(h);
        let (j0, j1, fy) = place((y0 + y1) / 2, ty);
        for (i, col) in s.column.iter_mut().enumerate() {
            let (a, b) = (s.tiles[j0 * tx + i], s.tiles[j1 * tx + i]);
            *col = std::array::from_fn(|c| a[c] + (((b[c] - a[c]) * fy) >> 8));
        }
        for (px, &(i0, i1, fx)) in s.line.chunks_exact_mut(3).zip(&s.xs) {
            let (a, b) = (s.column[i0 as usize], s.column[i1 as usize]);
            for c in 0..3 {
                px[c] = ((a[c] + (((b[c] - a[c]) * fx) >> 8) + 128) >> 8).clamp(0, 255) as u8;
            }
        }
        for row in opening[y0 * stride..y1 * stride].chunks_exact_mut(stride) {
            for (v, b) in row.iter_mut().zip(&s.line) {
                *v = v.saturating_add(*b);
            }
        }
    }
}

/// The median of the `count` values counted in `hist` (0 for none).
fn median_of_histogram(hist: &[u32; 256], count: u32) -> u8 {
    let mut acc = 0;
    hist.iter()
        .position(|&k| {
            acc += k;
            2 * acc > count
        })
        .unwrap_or(0) as u8
}

/// The running extreme (`op`, the window clipped at the borders) over `2r + 1` pixels
/// along `row` (packed RGB), per channel, in place, by doubling: the extreme over `2s`
/// pixels is that of two windows of `s`, so `log₂(2r + 1)` passes give a window of
/// `s ≤ 2r + 1`, and two such windows overlapping cover `2r + 1` exactly. Each pass is
/// one shifted comparison of the whole row, which vectorises; the row is padded with
/// `identity` (what `op` ignores) for the border, in `p` and `q`.
fn row_extreme<F: Fn(u8, u8) -> u8 + Copy>(
    row: &mut [u8],
    r: usize,
    (p, q): (&mut [u8], &mut [u8]),
    op: F,
    identity: u8,
) {
    let len = 2 * r + 1;
    let stride = row.len();
    let padded = stride + 6 * r;
    let (mut p, mut q) = (&mut p[..padded], &mut q[..padded]);
    p[..3 * r].fill(identity);
    p[3 * r..3 * r + stride].copy_from_slice(row);
    p[3 * r + stride..].fill(identity);
    // `p[3x + c]` holds the extreme over pixels `x .. x + s` of the padded row.
    let mut s = 1;
    while 2 * s <= len {
        let shift = 3 * s;
        for ((o, a), b) in q[..padded - shift]
            .iter_mut()
            .zip(&p[..padded - shift])
            .zip(&p[shift..])
        {
            *o = op(*a, *b);
        }
        q[padded - shift..].copy_from_slice(&p[padded - shift..]);
        std::mem::swap(&mut p, &mut q);
        s *= 2;
    }
    // Original pixel x's window is padded pixels x .. x + 2r: the windows of `s`
    // starting at x and at x + len − s.
    let shift = 3 * (len - s);
    for ((o, a), b) in row
        .iter_mut()
        .zip(&p[..stride])
        .zip(&p[shift..shift + stride])
    {
        *o = op(*a, *b);
    }
}

/// The running extreme (`op`, the window clipped at the borders) over `2r + 1` samples
/// down each column of each channel: van Herk / Gil–Werman, with blocks of `k = 2r + 1`
/// rows, whole rows at a time, so the extremes vectorise. Block by block: the prefix
/// extremes `g` and suffix extremes `hs` of a block, then every output row whose window
/// ends in it (the rest of the window lies in the block before). So `g` and `hs` hold two
/// blocks each (a ring), small enough to stay in the cache; over whole frames they were
/// two more frames' worth of memory traffic per pass.
fn cols_pass<F: Fn(u8, u8) -> u8 + Copy>(
    src: &[u8],
    dst: &mut [u8],
    (w, h): (usize, usize),
    r: usize,
    (g, hs): (&mut [u8], &mut [u8]),
    op: F,
) {
    let k = 2 * r + 1;
    let stride = 3 * w;
    // Where row `y`'s prefix or suffix extreme lives in its ring.
    let at = |y: usize| ((y / k) % 2 * k + y % k) * stride;
    let src_row = |y: usize| &src[y * stride..(y + 1) * stride];
    let blocks = h.div_ceil(k);
    let mut next = 0;
    for block in 0..blocks {
        let (y0, y1) = (block * k, (block * k + k).min(h));
        g[at(y0)..at(y0) + stride].copy_from_slice(src_row(y0));
        for y in y0 + 1..y1 {
            let (before, cur) = g.split_at_mut(at(y));
            let prev = &before[at(y - 1)..];
            for ((o, p), v) in cur[..stride].iter_mut().zip(prev).zip(src_row(y)) {
                *o = op(*p, *v);
            }
        }
        hs[at(y1 - 1)..at(y1 - 1) + stride].copy_from_slice(src_row(y1 - 1));
        for y in (y0..y1 - 1).rev() {
            let (cur, after) = hs.split_at_mut(at(y + 1));
            let following = &after[..stride];
            for ((o, p), v) in cur[at(y)..].iter_mut().zip(following).zip(src_row(y)) {
                *o = op(*p, *v);
            }
        }
        // The rows whose window ends in this block (at its last row for the last).
        let end = if block + 1 == blocks { h } else { y1 - r };
        let g_row = |y: usize| &g[at(y)..at(y) + stride];
        let h_row = |y: usize| &hs[at(y)..at(y) + stride];
        for y in next..end {
            let out = &mut dst[y * stride..(y + 1) * stride];
            // A window that starts before the top lies in block 0 (y + r < 2r + 1); one
            // that ends past the bottom may lie in the last block alone.
            let (left, right) = if y < r {
                (None, g_row((y + r).min(h - 1)))
            } else if y + r < h {
                (Some(h_row(y - r)), g_row(y + r))
            } else if (y - r) / k == (h - 1) / k {
                (None, h_row(y - r))
            } else {
                (Some(h_row(y - r)), g_row(h - 1))
            };
            match left {
                Some(left) => {
                    for ((o, a), b) in out.iter_mut().zip(left).zip(right) {
                        *o = op(*a, *b);
                    }
                }
                None => out.copy_from_slice(right),
            }
        }
        next = end;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Brute-force opening of one channel for comparison.
    fn opening_reference(img: &RgbImage, r: usize) -> RgbImage {
        let (w, h) = (img.width() as i64, img.height() as i64);
        let ext = |src: &RgbImage, op: fn(u8, u8) -> u8, init: u8| {
            RgbImage::from_fn(w as u32, h as u32, |x, y| {
                let mut v = [init; 3];
                for yy in (y as i64 - r as i64).max(0)..=(y as i64 + r as i64).min(h - 1) {
                    for xx in (x as i64 - r as i64).max(0)..=(x as i64 + r as i64).min(w - 1) {
                        let p = src.get_pixel(xx as u32, yy as u32).0;
                        for c in 0..3 {
                            v[c] = op(v[c], p[c]);
                        }
                    }
                }
                image::Rgb(v)
            })
        };
        ext(&ext(img, u8::min, 255), u8::max, 0)
    }

    /// The local background of `img` at radius `r` is its brute-force opening plus the
    /// bias measured against it.
    fn assert_is_the_opening(img: &RgbImage, r: usize) {
        let mut lb = LocalBackground::new(r);
        let mut out = RgbImage::new(1, 1);
        lb.estimate_into(img, &mut out);
        let mut expected = opening_reference(img, r);
        let (w, h) = img.dimensions();
        let size = (w as usize, h as usize);
        let mut scratch = BiasScratch::default();
        add_local_bias(
            img.as_raw(),
            &mut expected,
            size,
            BIAS_TILE_PX,
            &mut scratch,
        );
        assert_eq!(out.as_raw(), expected.as_raw(), "{w}x{h}, radius {r}");
    }

    /// Heights about the column passes' blocks of `2r + 1` rows (shorter than one
    /// block, one, two and a bit), so that every case of a window's two ends is met.
    #[test]
    fn opening_matches_brute_force_at_every_height() {
        for (w, h) in [
            (23, 1),
            (23, 5),
            (19, 17),
            (30, 34),
            (31, 35),
            (26, 52),
            (9, 60),
        ] {
            let img = RgbImage::from_fn(w, h, |x, y| {
                let v = (x * 37 + y * 101 + (x * y) % 13) % 251;
                image::Rgb([v as u8, (v * 7 % 256) as u8, (255 - v) as u8])
            });
            for r in [1, 3, 8, 16] {
                assert_is_the_opening(&img, r);
            }
        }
    }

    #[test]
    fn opening_matches_brute_force_and_removes_a_stripe() {
        // Noise-free, so the measured bias is zero and the output is the opening.
        let img = RgbImage::from_fn(57, 41, |x, y| {
            let base = if (x / 13 + y / 11) % 2 == 0 { 40 } else { 200 };
            let stripe = if x == 2 * y / 3 + 5 || x == 2 * y / 3 + 6 {
                50
            } else {
                0
            };
            image::Rgb([base + stripe, base, (base / 2) + (x as u8)])
        });
        for r in [1, 2, 3, 4, 8] {
            assert_is_the_opening(&img, r);
        }
    }

    /// A smooth surface beside a noisy one (shot noise on a bright wall, or texture):
    /// the opening lies further below the noisy one's mean, and the bias is measured
    /// per region, so each surface's excess over its local background is centred on
    /// zero. One bias for the frame (a tile as large as the frame) left the smooth
    /// side's median excess at −2, where a faint stripe's shoulders are lost.
    #[test]
    fn each_surface_excess_is_centred_on_zero() {
        let mut rng = crate::rng::SplitMix64::new(7);
        // The sum of four uniforms: near-Gaussian, spread `σ`.
        let mut noise = |sigma: f64| {
            let u: f64 = (0..4).map(|_| rng.next_f64() - 0.5).sum();
            u * sigma * 3f64.sqrt()
        };
        let (w, h) = (384u32, 192u32);
        let img = RgbImage::from_fn(w, h, |x, _| {
            let (mean, sigma) = if x < w / 2 { (60.0, 1.0) } else { (120.0, 6.0) };
            image::Rgb([0; 3].map(|_| (mean + noise(sigma)).round().clamp(0.0, 255.0) as u8))
        });
        let mut lb = LocalBackground::new(DEFAULT_RADIUS_PX);
        let mut out = RgbImage::new(1, 1);
        lb.estimate_into(&img, &mut out);
        // Away from the boundary between the two (a tile and a half).
        for (x0, x1) in [(0, w / 2 - 96), (w / 2 + 96, w)] {
            let mut excess: Vec<i32> = (x0..x1)
                .flat_map(|x| (0..h).map(move |y| (x, y)))
                .map(|(x, y)| {
                    i32::from(img.get_pixel(x, y).0[1]) - i32::from(out.get_pixel(x, y).0[1])
                })
                .collect();
            excess.sort_unstable();
            let median = excess[excess.len() / 2];
            assert!(
                median.abs() <= 1,
                "columns {x0}..{x1}: median excess {median}"
            );
        }
    }
}
