//! Effects of real camera frames that the clean renderer leaves out, as options of a
//! run ([`Realism`], in [`super::SimParams`]): a lit room's white and grey structures
//! (a checkerboard target, thin bright rims, specular spots), a surface of a laser's
//! own colour, an overexposed stripe whose colour leaks into the other channels with a
//! wide halo (clipped by the sensor), wide beams, 4:2:0 chroma subsampling as MJPEG
//! has it, one laser of the two switched off, and an object that is in the sweep's
//! frames but not in the laser-off frame.
//!
//! Owns only the image-space decorations and their post-processing; the stripe model
//! is [`super::render`]'s. The default is no effect at all, so every existing scene
//! renders bit for bit as before.

use super::motion::SplitMix64;
use super::scene::mix64;

/// The realistic effects of one run; [`Realism::default`] has none.
#[derive(Clone, Debug, PartialEq)]
pub struct Realism {
    /// A checkerboard target painted over part of the view (ambient grey levels).
    pub checker: Option<Checker>,
    /// Small white specular spots: count, and the largest Gaussian std, px.
    pub specular_spots: usize,
    /// Thin bright grey-white lines (rims, board edges, lamp tubes).
    pub bright_lines: usize,
    /// A rectangle of the view whose ambient has this colour (a surface of a laser's
    /// own colour), as `[x0, y0, x1, y1]` shares of the image and RGB grey levels.
    pub coloured_patch: Option<([f64; 4], [f64; 3])>,
    /// Laser light scaled by this factor (1: none); above ~1.5 the own channel clips.
    pub laser_gain: f64,
    /// Share of the laser's own-channel light that reaches the other two channels
    /// (sensor crosstalk of an overexposed stripe): the core they still show.
    pub crosstalk: f64,
    /// Blooming halo: its share of the stripe's peak and its Gaussian std, px.
    pub bloom: Option<(f64, f64)>,
    /// Average chroma over 2×2 blocks (YCbCr 4:2:0, as MJPEG cameras send).
    pub chroma_420: bool,
    /// How the 4:2:0 chroma is rebuilt to full size: interpolated between the blocks'
    /// centres as JPEG decoders do (libjpeg's and zune-jpeg's "fancy upsampling"; with
    /// a JPEG quality, the frame is one real 4:2:0 JPEG round trip), or, when false,
    /// each block's chroma repeated over its four pixels (FFmpeg's unscaled conversion
    /// to RGB, a YUYV pair's shared chroma).
    pub chroma_interpolated: bool,
    /// Which of the two lasers are on.
    pub lasers_on: [bool; 2],
    /// A thin dark object (a hair, a cable) that moves: in the laser-off frame at one
    /// place, in each laser frame at another.
    pub moving_object: bool,
}

impl Default for Realism {
    fn default() -> Self {
        Self::none()
    }
}

impl Realism {
    /// No effect: the clean renderer.
    pub fn none() -> Self {
        Self {
            checker: None,
            specular_spots: 0,
            bright_lines: 0,
            coloured_patch: None,
            laser_gain: 1.0,
            crosstalk: 0.0,
            bloom: None,
            chroma_420: false,
            chroma_interpolated: false,
            lasers_on: [true, true],
            moving_object: false,
        }
    }

    /// Whether any effect is on.
    pub fn is_none(&self) -> bool {
        *self == Self::none()
    }

    /// Laser gain, with the unset default read as 1.
    pub(crate) fn gain(&self) -> f64 {
        if self.laser_gain > 0.0 {
            self.laser_gain
        } else {
            1.0
        }
    }

    /// Whether laser `k` is on.
    pub(crate) fn laser_on(&self, k: usize) -> bool {
        self.lasers_on[k]
    }
}

/// A checkerboard over a rectangle of the view.
#[derive(Clone, Debug, PartialEq)]
pub struct Checker {
    /// `[x0, y0, x1, y1]` as shares of the image.
    pub rect: [f64; 4],
    pub square_px: f64,
    /// Ambient grey levels of the dark and the light squares (white may reach 255).
    pub dark: f64,
    pub light: f64,
    /// Tint of the light (warm lamps): per-channel factors.
    pub tint: [f64; 3],
}

/// The decorations of the view, drawn into the ambient image once per scene.
pub(crate) fn decorate_ambient(
    realism: &Realism,
    seed: u64,
    (w, h): (usize, usize),
    ambient: &mut [[f32; 3]],
) {
    let mut rng = SplitMix64::new(mix64(seed ^ 0x7265_616c_6973_6d31));
    let (wf, hf) = (w as f64, h as f64);
    if let Some((r, rgb)) = &realism.coloured_patch {
        fill_rect(ambient, w, *r, (wf, hf), |_, _| *rgb);
    }
    if let Some(c) = &realism.checker {
        let (x0, y0) = (c.rect[0] * wf, c.rect[1] * hf);
        fill_rect(ambient, w, c.rect, (wf, hf), |x, y| {
            let (i, j) = (
                ((x - x0) / c.square_px) as i64,
                ((y - y0) / c.square_px) as i64,
            );
            if (i + j) % 2 == 0 {
                c.tint.map(|t| t * c.light)
            } else {
                [c.dark; 3]
            }
        });
    }
    for _ in 0..realism.bright_lines {
        let line = Line::random(&mut rng, (wf, hf), 0.8, 1.8);
        let level = 150.0 + 100.0 * rng.next_f64();
        let tint = [
            1.0,
            0.97 + 0.03 * rng.next_f64(),
            0.92 + 0.08 * rng.next_f64(),
        ];
        line.draw(ambient, (w, h), |v, a| {
            for c in 0..3 {
                v[c] = v[c].max((a * level * tint[c]) as f32);
            }
        });
    }
    for _ in 0..realism.specular_spots {
        let (cx, cy) = (rng.next_f64() * wf, rng.next_f64() * hf);
        let s = 1.0 + 3.0 * rng.next_f64();
        let r = (4.0 * s).ceil() as i64;
        for y in (cy as i64 - r).max(0)..(cy as i64 + r).min(h as i64) {
            for x in (cx as i64 - r).max(0)..(cx as i64 + r).min(w as i64) {
                let d2 = (x as f64 - cx).powi(2) + (y as f64 - cy).powi(2);
                let a = (300.0 * (-0.5 * d2 / (s * s)).exp()) as f32;
                let v = &mut ambient[y as usize * w + x as usize];
                for c in v.iter_mut() {
                    *c = (*c + a).min(300.0);
                }
            }
        }
    }
}

fn fill_rect(
    ambient: &mut [[f32; 3]],
    w: usize,
    r: [f64; 4],
    (wf, hf): (f64, f64),
    f: impl Fn(f64, f64) -> [f64; 3],
) {
    let (x0, x1) = ((r[0] * wf) as usize, ((r[2] * wf) as usize).min(w));
    let h = ambient.len() / w;
    let (y0, y1) = ((r[1] * hf) as usize, ((r[3] * hf) as usize).min(h));
    for y in y0..y1 {
        for x in x0..x1 {
            ambient[y * w + x] = f(x as f64, y as f64).map(|v| v as f32);
        }
    }
}

/// A straight segment with a Gaussian profile across.
struct Line {
    a: [f64; 2],
    b: [f64; 2],
    s: f64,
}

impl Line {
    fn random(rng: &mut SplitMix64, (wf, hf): (f64, f64), s_lo: f64, s_hi: f64) -> Line {
        let a = [rng.next_f64() * wf, rng.next_f64() * hf];
        let len = 100.0 + 300.0 * rng.next_f64();
        let t = std::f64::consts::TAU * rng.next_f64();
        Line {
            a,
            b: [a[0] + len * t.cos(), a[1] + len * t.sin()],
            s: s_lo + (s_hi - s_lo) * rng.next_f64(),
        }
    }

    /// Calls `f(pixel, weight)` on the pixels within 4σ of the segment.
    fn draw(
        &self,
        img: &mut [[f32; 3]],
        (w, h): (usize, usize),
        mut f: impl FnMut(&mut [f32; 3], f64),
    ) {
        let r = 4.0 * self.s;
        let (xa, xb) = (self.a[0].min(self.b[0]) - r, self.a[0].max(self.b[0]) + r);
        let (ya, yb) = (self.a[1].min(self.b[1]) - r, self.a[1].max(self.b[1]) + r);
        let (dx, dy) = (self.b[0] - self.a[0], self.b[1] - self.a[1]);
        let l2 = dx * dx + dy * dy;
        for y in (ya.max(0.0) as usize)..(yb.min(h as f64 - 1.0).max(0.0) as usize) {
            for x in (xa.max(0.0) as usize)..(xb.min(w as f64 - 1.0).max(0.0) as usize) {
                let (px, py) = (x as f64 - self.a[0], y as f64 - self.a[1]);
                let t = ((px * dx + py * dy) / l2).clamp(0.0, 1.0);
                let d2 = (px - t * dx).powi(2) + (py - t * dy).powi(2);
                if d2 < r * r {
                    f(&mut img[y * w + x], (-0.5 * d2 / (self.s * self.s)).exp());
                }
            }
        }
    }
}

/// Draws the moving object of frame `key` (a thin dark strand, a hair or a cable,
/// whose place depends on the frame) into `img`: where it lay in the laser-off frame,
/// the sweep's frames show the lit surface, brighter than their background.
pub(crate) fn draw_moving_object(seed: u64, key: u64, img: &mut [u8], (w, h): (usize, usize)) {
    let mut rng = SplitMix64::new(mix64(seed ^ 0x6d6f_7665_7231 ^ mix64(key)));
    // Near the middle, where the sweep passes most.
    let (wf, hf) = (w as f64, h as f64);
    let mut line = Line::random(&mut rng, (0.5 * wf, 0.5 * hf), 1.0, 1.6);
    for p in [&mut line.a, &mut line.b] {
        p[0] += 0.25 * wf;
        p[1] += 0.25 * hf;
    }
    let mut shade = vec![[0f32; 3]; w * h];
    line.draw(&mut shade, (w, h), |v, a| *v = [a as f32; 3]);
    for (px, a) in img.chunks_exact_mut(3).zip(&shade) {
        if a[0] > 0.0 {
            for c in px.iter_mut() {
                *c = (*c as f32 * (1.0 - 0.8 * a[0])).round() as u8;
            }
        }
    }
}

/// YCbCr 4:2:0: the chroma of each 2×2 block averaged (BT.601 full range), luma kept;
/// the blocks' chroma rebuilt at every pixel by repeating it, or, `interpolated`, as
/// JPEG decoders do: per axis, 3/4 of the pixel's own block and 1/4 of the next block
/// on its side (the blocks' centres lie between their two pixels), the image's edge
/// repeating its last block.
pub(crate) fn subsample_chroma(img: &mut [u8], (w, h): (usize, usize), interpolated: bool) {
    let ycc = |p: &[u8]| {
        let (r, g, b) = (p[0] as f32, p[1] as f32, p[2] as f32);
        let y = 0.299 * r + 0.587 * g + 0.114 * b;
        (
            y,
            -0.168_736 * r - 0.331_264 * g + 0.5 * b,
            0.5 * r - 0.418_688 * g - 0.081_312 * b,
        )
    };
    let (bw, bh) = (w.div_ceil(2), h.div_ceil(2));
    let mut blocks = vec![[0f32; 2]; bw * bh];
    for by in 0..bh {
        for bx in 0..bw {
            let (mut cb, mut cr, mut n) = (0.0, 0.0, 0.0);
            for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                let (x, y) = (2 * bx + dx, 2 * by + dy);
                if x < w && y < h {
                    let i = 3 * (y * w + x);
                    let (_, u, v) = ycc(&img[i..i + 3]);
                    cb += u;
                    cr += v;
                    n += 1.0;
                }
            }
            blocks[by * bw + bx] = [cb / n, cr / n];
        }
    }
    // Per pixel coordinate: its block and the neighbouring block on its side, with
    // their weights.
    let taps = |p: usize, blocks: usize| -> [(usize, f32); 2] {
        let b = p / 2;
        if !interpolated {
            return [(b, 1.0), (b, 0.0)];
        }
        let next = if p.is_multiple_of(2) {
            b.saturating_sub(1)
        } else {
            (b + 1).min(blocks - 1)
        };
        [(b, 0.75), (next, 0.25)]
    };
    for y in 0..h {
        for x in 0..w {
            let (mut cb, mut cr) = (0.0, 0.0);
            for (by, wy) in taps(y, bh) {
                for (bx, wx) in taps(x, bw) {
                    let [u, v] = blocks[by * bw + bx];
                    cb += wx * wy * u;
                    cr += wx * wy * v;
                }
            }
            let i = 3 * (y * w + x);
            let (l, _, _) = ycc(&img[i..i + 3]);
            let rgb = [
                l + 1.402 * cr,
                l - 0.344_136 * cb - 0.714_136 * cr,
                l + 1.772 * cb,
            ];
            for c in 0..3 {
                img[i + c] = rgb[c].round().clamp(0.0, 255.0) as u8;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::subsample_chroma;

    /// A frame whose red rises along x by `step` grey levels a pixel (a chroma ramp).
    fn ramp(w: usize, h: usize, step: f32) -> Vec<u8> {
        (0..w * h)
            .flat_map(|i| [(40.0 + step * (i % w) as f32).round() as u8, 90, 60])
            .collect()
    }

    #[test]
    fn the_interpolated_rebuild_keeps_a_chroma_ramp_and_the_repeated_one_steps_it() {
        let (w, h) = (32, 4);
        let truth = ramp(w, h, 4.0);
        let red = |img: &[u8]| -> Vec<i32> { (0..w).map(|x| img[3 * (w + x)] as i32).collect() };
        let mut interpolated = truth.clone();
        subsample_chroma(&mut interpolated, (w, h), true);
        let mut repeated = truth.clone();
        subsample_chroma(&mut repeated, (w, h), false);
        let (t, i, r) = (red(&truth), red(&interpolated), red(&repeated));
        // Away from the edges (which repeat the last block), interpolation between the
        // blocks' centres gives a linear ramp back, within rounding.
        for x in 2..w - 2 {
            assert!((i[x] - t[x]).abs() <= 1, "x {x}: {} against {}", i[x], t[x]);
        }
        // Repeating a block's chroma over its pixels makes pairs equal in chroma, so
        // red steps by pairs: half a step low on one pixel, half high on the other.
        let off: i32 = (2..w - 2).map(|x| (r[x] - t[x]).abs()).sum();
        assert!(
            off >= (w as i32 - 4) / 2,
            "repeated rebuild off by {off} in all"
        );
    }
}
