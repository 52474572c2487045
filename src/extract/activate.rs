//! Which tiles the detector searches, per laser: those holding a pixel of the laser's
//! colour in the frame's excess over its background (and white pixels next to them),
//! those on a stripe too faint for any pixel to show it ([`super::faint`]), and, while
//! curves grow, the tiles ahead of their ends. Split from `mod.rs`, which runs the
//! extraction.

use image::RgbImage;

use super::{colour, tiles_near, Curve, Extractor};

/// Points back from a curve's end over which its direction there is taken.
const FOLLOW_DIRECTION_POINTS: usize = 8;

/// Whether the excess `d` over a local background is more saturated than the surface
/// under it (`surface`, the local background's pixel), halfway from the surface's
/// saturation to a pure hue. A laser's light is nearly monochrome, so what it adds is
/// far purer than any lit surface; a surface's own texture, which a local background
/// (unlike a laser-off frame) leaves in the excess, has the surface's colour.
#[inline]
fn purer_than_surface(d: [u8; 3], surface: &[u8]) -> bool {
    // HSV saturation is (max − min) / max (0 for black); in integers, exactly:
    // (d_max − d_min) / d_max ≥ (1 + s_num / s_den) / 2.
    let spread = |p: [u8; 3]| {
        let (max, min) = (p[0].max(p[1]).max(p[2]), p[0].min(p[1]).min(p[2]));
        (u32::from(max), u32::from(max - min))
    };
    let (d_max, d_chroma) = spread(d);
    let (s_max, s_chroma) = spread([surface[0], surface[1], surface[2]]);
    let (s_num, s_den) = if s_max == 0 {
        (0, 1)
    } else {
        (s_chroma, s_max)
    };
    d_max > 0 && 2 * d_chroma * s_den >= d_max * (s_den + s_num)
}

impl Extractor {
    /// Marks in `self.grown` the inactive tiles of laser `laser` that lie ahead of an
    /// end of one of `curves` (half a tile and one tile beyond it, along the curve's
    /// direction over its last few points); whether there is any.
    pub(super) fn tiles_ahead(&mut self, laser: usize, curves: &[Curve]) -> bool {
        self.grown.fill(false);
        let det = &self.detector;
        let (tile, tiles_x) = (det.tile as f32, det.tiles_x);
        let (w, h) = (det.width as f32, det.height as f32);
        let mut any = false;
        for c in curves {
            let n = c.points_px.len();
            if n < 2 {
                continue;
            }
            let back = FOLLOW_DIRECTION_POINTS.min(n - 1);
            for (end, from) in [
                (c.points_px[n - 1], c.points_px[n - 1 - back]),
                (c.points_px[0], c.points_px[back]),
            ] {
                let (dx, dy) = (end[0] - from[0], end[1] - from[1]);
                let len = (dx * dx + dy * dy).sqrt();
                if len <= 0.0 {
                    continue;
                }
                for step in [0.5, 1.0] {
                    let (x, y) = (
                        end[0] + dx / len * step * tile,
                        end[1] + dy / len * step * tile,
                    );
                    if !(x >= 0.0 && y >= 0.0 && x < w && y < h) {
                        continue;
                    }
                    let t = (y / tile) as usize * tiles_x + (x / tile) as usize;
                    if !self.active[laser][t] && !self.grown[t] {
                        self.grown[t] = true;
                        any = true;
                    }
                }
            }
        }
        any
    }

    /// Marks, per laser, the tiles holding a pixel of that laser's colour, and the
    /// tiles holding a white pixel next to those (a saturated stripe core is white, and
    /// a wide one fills a tile with no coloured fringe in it). A cheap byte-wise test
    /// (any channel of the difference reaching `min_value`) runs over every tile-wide
    /// chunk of every row; the look-up table only on chunks that pass.
    /// `background_id`: the background's [`super::Background::id`], `None` for one
    /// made for this frame.
    pub(super) fn activate_rgb(
        &mut self,
        frame: &RgbImage,
        (background, background_id): (&RgbImage, Option<u64>),
        local: bool,
    ) {
        for a in &mut self.active {
            a.fill(false);
        }
        self.white.fill(false);
        let (w, tile, tiles_x) = (
            self.detector.width,
            self.detector.tile,
            self.detector.tiles_x,
        );
        let n_lasers = self.active.len() as u8;
        let min_value = self.params.min_value;
        let (fr, bg) = (frame.as_raw(), background.as_raw());
        for (y, (frow, brow)) in fr.chunks(3 * w).zip(bg.chunks(3 * w)).enumerate() {
            let trow = (y / tile) * tiles_x;
            for (tx, (fc, bc)) in frow.chunks(3 * tile).zip(brow.chunks(3 * tile)).enumerate() {
                let t = trow + tx;
                if self.active.iter().all(|a| a[t]) {
                    continue;
                }
                let strong = fc
                    .iter()
                    .zip(bc)
                    .fold(0u8, |m, (f, b)| m.max(f.saturating_sub(*b)));
                if strong < min_value {
                    continue;
                }
                for (f, b) in fc.chunks_exact(3).zip(bc.chunks_exact(3)) {
                    let (dr, dg, db) = (
                        f[0].saturating_sub(b[0]),
                        f[1].saturating_sub(b[1]),
                        f[2].saturating_sub(b[2]),
                    );
                    if let Some(c) = self.lut.classify(dr, dg, db) {
                        if c < n_lasers {
                            let a = &mut self.active[c as usize][t];
                            if !*a && (!local || purer_than_surface([dr, dg, db], b)) {
                                *a = true;
                            }
                        } else if c == colour::Class::White as u8 {
                            self.white[t] = true;
                        } else {
                            // A hue of no laser: a laser's stripe under a dim veil
                            // of another colour ([`ColourLut::response`]). Over a
                            // local background the veil is in the background, and
                            // what is left must be purer than the surface, as above:
                            // a surface's own texture in a hue between the lasers'
                            // (a purple checker under a blue laser) activated most
                            // of a frame's tiles, for no point.
                            for k in 0..n_lasers {
                                let a = &mut self.active[k as usize][t];
                                if !*a
                                    && self.lut.response(k, dr, dg, db).0 >= min_value
                                    && (!local || purer_than_surface([dr, dg, db], b))
                                {
                                    *a = true;
                                }
                            }
                        }
                    }
                }
            }
        }
        // Stripes too faint for any pixel to reach `min_value`.
        self.dark.lift.clear();
        if self.params.faint_activation && !self.yuyv_frame {
            self.faint.activate(
                fr,
                (bg, background_id),
                (w, self.detector.height),
                (tile, tiles_x),
                self.lut.channels(),
                &mut self.active,
                local,
            );
            // A local background is the frame's own: nothing lies evenly below it.
            if self.params.lift_darkened && !local {
                self.dark.cells_x = self.faint.darkening(&mut self.dark.lift);
            }
        }
        let (tx_n, ty_n) = (tiles_x, self.detector.tiles_y);
        for active in &mut self.active {
            self.grown.copy_from_slice(active);
            for (t, _) in self.white.iter().enumerate().filter(|(_, w)| **w) {
                self.grown[t] |= tiles_near(t, 1, tx_n, ty_n).any(|u| active[u]);
            }
            std::mem::swap(active, &mut self.grown);
        }
    }
}
