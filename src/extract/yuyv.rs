//! Extraction straight from YUYV buffers, converting to RGB only where a stripe can
//! be.
//!
//! The colour classes are a look-up on the RGB difference to the background, so the
//! detector needs RGB where a laser may be; elsewhere the conversion is wasted. A cheap
//! test on the YUV difference to the background (kept in YUV once per background)
//! finds the tiles where some RGB channel could rise by about `min_value`; those
//! tiles and a margin of [`MARGIN_TILES`] are converted into a scratch RGB frame whose
//! other tiles hold the background, so the unchanged RGB pipeline sees exactly the
//! frame's pixels wherever it looks and a zero difference elsewhere. Tiles converted
//! for the previous frame are set back to the background first.
//!
//! The faint-stripe activation ([`super::faint`]) needs every pixel, so it is skipped
//! here: from YUYV a stripe that no pixel of raises to about `min_value` is found only
//! where a curve is followed into it. The result equals the RGB extraction of the
//! converted frame with `faint_activation` off, which the tests hold it to.

use image::RgbImage;

use super::{chroma, tiles_near, Background, Curve, ExtractError, Extractor, TileFrame};
use crate::capture::dump::yuyv_row_to_rgb;

/// Tiles around a candidate tile that are converted too: the detector's kernels and
/// the white-tile growth reach one tile beyond an active tile.
pub const MARGIN_TILES: usize = 2;

/// Grey levels the background's round trip RGB → YUV → RGB may be off by.
const ROUND_TRIP_MARGIN: u8 = 4;

/// The background in YUV (BT.601, limited range), per pixel luma and per pixel pair
/// chroma, as a YUYV camera would deliver it.
pub(super) struct BackgroundYuv {
    key: (usize, usize, u64),
    luma: Vec<u8>,
    /// (U, V) per pixel pair.
    chroma: Vec<[u8; 2]>,
    /// The RGB frame handed to the RGB pipeline; background outside converted tiles.
    scratch: RgbImage,
    /// Per tile: converted from the current frame (to be restored next time).
    converted: Vec<bool>,
    candidate: Vec<bool>,
}

/// Identifies a background image's content cheaply: its buffer and a sparse checksum.
fn key_of(img: &RgbImage) -> (usize, usize, u64) {
    let raw = img.as_raw();
    let mut h = 0xcbf2_9ce4_8422_2325u64;
    for b in raw.iter().step_by(997) {
        h = (h ^ u64::from(*b)).wrapping_mul(0x100_0000_01b3);
    }
    (raw.as_ptr() as usize, raw.len(), h)
}

fn to_yuv(p: &[u8]) -> (i32, i32, i32) {
    let (r, g, b) = (i32::from(p[0]), i32::from(p[1]), i32::from(p[2]));
    (
        16 + ((66 * r + 129 * g + 25 * b + 128) >> 8),
        128 + ((-38 * r - 74 * g + 112 * b + 128) >> 8),
        128 + ((112 * r - 94 * g - 18 * b + 128) >> 8),
    )
}

impl BackgroundYuv {
    fn new(bg: &RgbImage, tiles: usize) -> Self {
        let (w, h) = (bg.width() as usize, bg.height() as usize);
        let mut luma = Vec::with_capacity(w * h);
        let mut chroma = Vec::with_capacity(w.div_ceil(2) * h);
        for row in bg.as_raw().chunks_exact(3 * w) {
            for pair in row.chunks(6) {
                let (y0, u0, v0) = to_yuv(&pair[..3]);
                let (y1, u1, v1) = if pair.len() == 6 {
                    to_yuv(&pair[3..])
                } else {
                    (y0, u0, v0)
                };
                luma.push(y0.clamp(0, 255) as u8);
                if pair.len() == 6 {
                    luma.push(y1.clamp(0, 255) as u8);
                }
                chroma.push([
                    ((u0 + u1 + 1) / 2).clamp(0, 255) as u8,
                    ((v0 + v1 + 1) / 2).clamp(0, 255) as u8,
                ]);
            }
        }
        Self {
            key: key_of(bg),
            luma,
            chroma,
            scratch: bg.clone(),
            converted: vec![false; tiles],
            candidate: vec![false; tiles],
        }
    }
}

impl Extractor {
    /// The curves of a YUYV frame (`stride` bytes per row) against `background`, with
    /// RGB made only where a stripe can be (see the module docs). Gives the same curves
    /// as [`Self::extract`] on the frame converted whole.
    pub fn extract_yuyv(
        &mut self,
        yuyv: &[u8],
        stride: usize,
        background: &Background,
    ) -> Result<Vec<Curve>, ExtractError> {
        let (w, h) = (self.camera.width as usize, self.camera.height as usize);
        let bg = background.image();
        if bg.dimensions() != (self.camera.width, self.camera.height) {
            return Err(ExtractError::Size {
                what: "background",
                width: self.camera.width,
                height: self.camera.height,
                got_width: bg.width(),
                got_height: bg.height(),
            });
        }
        if w % 2 != 0 || stride < 2 * w || yuyv.len() < stride * (h - 1) + 2 * w {
            return Err(ExtractError::Size {
                what: "YUYV frame",
                width: self.camera.width,
                height: self.camera.height,
                got_width: (stride / 2) as u32,
                got_height: (yuyv.len() / stride.max(1)) as u32,
            });
        }
        // A YUYV pair's chroma is repeated over its two pixels (`yuyv_row_to_rgb`).
        self.know_chroma([chroma::Rebuild::Repeated, chroma::Rebuild::Full]);
        let (tile, tiles_x, tiles_y) = (
            self.detector.tile,
            self.detector.tiles_x,
            self.detector.tiles_y,
        );
        let stale = self.yuv.as_ref().is_none_or(|y| y.key != key_of(bg));
        if stale {
            self.yuv = Some(BackgroundYuv::new(bg, tiles_x * tiles_y));
        }
        let Some(yuv) = self.yuv.as_mut() else {
            return Ok(Vec::new());
        };
        // 1. Candidate tiles: where some RGB channel of the difference to the
        //    background, from the YUV difference by the conversion's linear map, rises
        //    by min_value less a margin for the background's round trip through YUV.
        //    Clamping to 0..255 only ever lowers the real rise, so this misses nothing.
        let limit = 256
            * i32::from(
                self.params
                    .min_value
                    .saturating_sub(ROUND_TRIP_MARGIN)
                    .max(1),
            );
        yuv.candidate.fill(false);
        for y in 0..h {
            let row = &yuyv[y * stride..y * stride + 2 * w];
            let (bl, bc) = (
                &yuv.luma[y * w..(y + 1) * w],
                &yuv.chroma[y * (w / 2)..(y + 1) * (w / 2)],
            );
            let trow = (y / tile) * tiles_x;
            for (tx, chunk) in row.chunks(2 * tile).enumerate() {
                let t = trow + tx;
                if yuv.candidate[t] {
                    continue;
                }
                let x0 = tx * tile;
                for (k, quad) in chunk.chunks_exact(4).enumerate() {
                    let px = x0 + 2 * k;
                    let [bu, bv] = bc[px / 2];
                    let du = i32::from(quad[1]) - i32::from(bu);
                    let dv = i32::from(quad[3]) - i32::from(bv);
                    let dy = (298 * (i32::from(quad[0]) - i32::from(bl[px])))
                        .max(298 * (i32::from(quad[2]) - i32::from(bl[px + 1])));
                    let rise = (dy + 409 * dv)
                        .max(dy - 100 * du - 208 * dv)
                        .max(dy + 516 * du);
                    if rise >= limit {
                        yuv.candidate[t] = true;
                        break;
                    }
                }
            }
        }
        // 2. Grow by the margin; restore last frame's tiles; convert this frame's.
        let mut want = vec![false; tiles_x * tiles_y];
        for (t, _) in yuv.candidate.iter().enumerate().filter(|(_, c)| **c) {
            for u in tiles_near(t, MARGIN_TILES, tiles_x, tiles_y) {
                want[u] = true;
            }
        }
        // Restores first, then conversions: a tile's even-aligned span may reach one
        // pixel into its neighbour.
        let mut src = YuyvTiles {
            scratch: std::mem::take(&mut yuv.scratch),
            yuyv,
            stride,
            tile,
            converted: std::mem::take(&mut yuv.converted),
        };
        for (t, &wanted) in want.iter().enumerate() {
            if src.converted[t] && !wanted {
                src.restore_tile(t, bg.as_raw());
            }
        }
        for (t, _) in want.iter().enumerate().filter(|(_, w)| **w) {
            src.convert_tile(t);
        }
        // 3. The RGB pipeline on the scratch frame, which converts more tiles if a
        //    curve is followed beyond these. Taken out of the extractor for the call.
        self.yuyv_frame = true;
        let out = self.extract_from(&mut src, bg, None);
        self.yuyv_frame = false;
        if let Some(yuv) = self.yuv.as_mut() {
            yuv.scratch = src.scratch;
            yuv.converted = src.converted;
        }
        out
    }
}

/// The scratch frame of [`Extractor::extract_yuyv`]: the frame's pixels on the
/// converted tiles, the background elsewhere.
struct YuyvTiles<'a> {
    scratch: RgbImage,
    yuyv: &'a [u8],
    stride: usize,
    tile: usize,
    /// Per tile: holds the frame's pixels.
    converted: Vec<bool>,
}

impl YuyvTiles<'_> {
    /// Tile `t`'s rows and its even-aligned column span `[x0, x1)` (YUYV pairs share
    /// their chroma, so the span may reach one pixel into the next tile).
    fn tile_span(&self, t: usize) -> (std::ops::Range<usize>, usize, usize) {
        let (w, h) = (
            self.scratch.width() as usize,
            self.scratch.height() as usize,
        );
        let (tx, ty) = (t % w.div_ceil(self.tile), t / w.div_ceil(self.tile));
        let (x0, x1) = (tx * self.tile, ((tx + 1) * self.tile).min(w));
        let rows = ty * self.tile..((ty + 1) * self.tile).min(h);
        (rows, x0 & !1, (x1 + 1).min(w) & !1)
    }

    /// Writes tile `t` of the scratch frame from the YUYV frame.
    fn convert_tile(&mut self, t: usize) {
        let (rows, x0, x1) = self.tile_span(t);
        let w = self.scratch.width() as usize;
        let scratch: &mut [u8] = &mut self.scratch;
        for y in rows {
            yuyv_row_to_rgb(
                &self.yuyv[y * self.stride + 2 * x0..y * self.stride + 2 * x1],
                &mut scratch[3 * (y * w + x0)..3 * (y * w + x1)],
            );
        }
        self.converted[t] = true;
    }

    /// Writes tile `t` of the scratch frame back from the background.
    fn restore_tile(&mut self, t: usize, background: &[u8]) {
        let (rows, x0, x1) = self.tile_span(t);
        let w = self.scratch.width() as usize;
        let scratch: &mut [u8] = &mut self.scratch;
        for y in rows {
            let span = 3 * (y * w + x0)..3 * (y * w + x1);
            scratch[span.clone()].copy_from_slice(&background[span]);
        }
        self.converted[t] = false;
    }
}

impl TileFrame for YuyvTiles<'_> {
    fn frame(&self) -> &RgbImage {
        &self.scratch
    }

    fn ensure(&mut self, tiles: &[bool], tiles_x: usize, tiles_y: usize) {
        for (t, _) in tiles.iter().enumerate().filter(|(_, m)| **m) {
            for u in tiles_near(t, 1, tiles_x, tiles_y) {
                if !self.converted[u] {
                    self.convert_tile(u);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::capture::dump::{decode_rgb, DumpHeader};
    use crate::extract::ExtractParams;
    use crate::simulate::{builtin_scene, SimParams, Simulator};

    /// YUYV from RGB (BT.601 limited range, chroma of each pair averaged), as a
    /// camera delivers it.
    fn yuyv_of(img: &RgbImage) -> Vec<u8> {
        let mut out = Vec::with_capacity(img.as_raw().len() / 3 * 2);
        for row in img.as_raw().chunks_exact(3 * img.width() as usize) {
            for pair in row.chunks_exact(6) {
                let (y0, u0, v0) = to_yuv(&pair[..3]);
                let (y1, u1, v1) = to_yuv(&pair[3..]);
                let c = |x: i32| x.clamp(0, 255) as u8;
                out.extend_from_slice(&[c(y0), c((u0 + u1 + 1) / 2), c(y1), c((v0 + v1 + 1) / 2)]);
            }
        }
        out
    }

    #[test]
    fn yuyv_extraction_equals_extraction_of_the_whole_converted_frame() {
        yuyv_equals_whole("bricks", None, &[3, 20, 41, 42, 77]);
    }

    /// Under water stripes fade below `min_value`; the curves followed into tiles the
    /// first pass did not convert must come out as from the whole frame.
    #[test]
    fn yuyv_extraction_follows_faint_tails_like_the_whole_frame() {
        let followed = yuyv_equals_whole("pipes", Some(1.5), &[4, 62, 129, 200, 260]);
        assert!(followed > 0, "no curve was followed");
    }

    /// A stripe fading to nothing along its length: the tiles where it is fainter than
    /// `min_value` are neither candidates nor their margin, so the curve is followed
    /// into tiles that only the on-demand conversion gives the frame's pixels.
    #[test]
    fn yuyv_extraction_converts_the_tiles_a_followed_curve_reaches() {
        let (w, h) = (480u32, 270u32);
        let camera = crate::camera::Camera::with_fov(w, h, 1.0);
        let background_rgb = RgbImage::from_pixel(w, h, image::Rgb([40, 40, 40]));
        let frame = RgbImage::from_fn(w, h, |x, y| {
            // Contrast 60 at the left edge, 0 at the right; FWHM 3 px about row 135.3.
            let c = 60.0 * (1.0 - x as f64 / w as f64);
            let d = y as f64 - 135.3 - 0.02 * x as f64;
            let g = 40.0 + c * (-4.0 * 2f64.ln() * d * d / 9.0).exp();
            image::Rgb([40, g.round() as u8, 40])
        });
        let header = DumpHeader {
            fourcc: *b"YUYV",
            width: w,
            height: h,
            bytes_per_line: 2 * w,
            interval_num: 1,
            interval_den: 30,
            device: "test".into(),
            card: "test".into(),
        };
        let background =
            Background::from_image(decode_rgb(&header, &yuyv_of(&background_rgb)).expect("bg"));
        // Tiles activate, and are converted, only where the stripe reaches 30 (up to
        // x ≈ 240, and two tiles beyond); curves go on down to 4 (x ≈ 450).
        let params = ExtractParams {
            low_contrast: 4.0,
            min_value: 30,
            faint_activation: false,
            ..ExtractParams::default()
        };
        let yuyv = yuyv_of(&frame);
        let rgb = decode_rgb(&header, &yuyv).expect("decode");
        let a = Extractor::new(&params, &camera)
            .expect("extractor")
            .extract(&rgb, &background);
        let mut direct = Extractor::new(&params, &camera).expect("extractor");
        let b = direct
            .extract_yuyv(&yuyv, 2 * w as usize, &background)
            .expect("yuyv");
        assert_eq!(a, b);
        // The curve runs well past the converted tiles.
        let right = a
            .iter()
            .flat_map(|c| &c.points_px)
            .map(|p| p[0])
            .fold(0.0f32, f32::max);
        assert!(right > 400.0, "the curve ends at x = {right}");
    }

    /// A built-in scene at 480x270 (seed 4; water of `turbidity` when given), the
    /// header of a YUYV dump of it, and its background as the camera sees it: through
    /// YUYV too.
    fn yuyv_scene(scene: &str, turbidity: Option<f64>) -> (Simulator, DumpHeader, Background) {
        let mut spec = builtin_scene(scene)
            .expect("scene")
            .with_resolution(480, 270);
        if let Some(t) = turbidity {
            spec.water.turbidity = t;
            spec.medium = crate::simulate::Medium::Water;
        }
        let sim = Simulator::new(
            &spec,
            &SimParams {
                seed: 4,
                ..SimParams::default()
            },
        )
        .expect("simulator");
        let camera = sim.camera();
        let header = DumpHeader {
            fourcc: *b"YUYV",
            width: camera.width,
            height: camera.height,
            bytes_per_line: 2 * camera.width,
            interval_num: 1,
            interval_den: 30,
            device: "test".into(),
            card: "test".into(),
        };
        // The background as the camera sees it: through YUYV too.
        let bg_yuyv = yuyv_of(&sim.background());
        let background = Background::from_image(decode_rgb(&header, &bg_yuyv).expect("bg"));
        (sim, header, background)
    }

    /// Extracts `frames` of a scene both ways, asserts equal curves, and returns the
    /// tiles the extraction activated by following curves.
    fn yuyv_equals_whole(scene: &str, turbidity: Option<f64>, frames: &[usize]) -> usize {
        let (sim, header, background) = yuyv_scene(scene, turbidity);
        let camera = sim.camera().clone();
        // YUYV extraction skips the faint-stripe activation (see the module doc).
        let params = ExtractParams {
            faint_activation: false,
            ..ExtractParams::default()
        };
        let mut whole = Extractor::new(&params, &camera).expect("extractor");
        let mut direct = Extractor::new(&ExtractParams::default(), &camera).expect("extractor");
        let (mut total, mut followed) = (0, 0);
        for &i in frames {
            let (frame, _) = sim.render_frame(i);
            let yuyv = yuyv_of(&frame);
            let rgb = decode_rgb(&header, &yuyv).expect("decode");
            let a = whole.extract(&rgb, &background);
            let b = direct
                .extract_yuyv(&yuyv, 2 * camera.width as usize, &background)
                .expect("yuyv");
            assert_eq!(a, b, "frame {i}");
            assert_eq!(whole.stats(), direct.stats(), "frame {i}");
            followed += whole.stats().follow_tiles;
            total += a.len();
        }
        assert!(total >= 5, "the frames hold curves ({total})");
        // Only part of the frame was converted.
        let converted = direct
            .yuv
            .as_ref()
            .map_or(0, |y| y.converted.iter().filter(|c| **c).count());
        let tiles = direct.detector.tiles_x * direct.detector.tiles_y;
        assert!(converted < tiles, "{converted} of {tiles} tiles converted");
        followed
    }

    /// No ridge pixel is detected twice, whatever the follow rounds and the
    /// faint-stripe activation add, and no curve point is in two curves. Once seen
    /// (two curves sharing a tail, on a YUYV-decoded frame) with an early version of
    /// the faint activation; kept as a check over the three scenes' frames decoded
    /// from YUYV, as a camera delivers them, with every stage on.
    #[test]
    fn no_ridge_pixel_is_detected_twice() {
        let mut doubled = Vec::new();
        for (scene, turbidity) in [("pipes", Some(1.5)), ("bricks", None), ("room", None)] {
            let (sim, header, background) = yuyv_scene(scene, turbidity);
            let camera = sim.camera().clone();
            let mut ex = Extractor::new(&ExtractParams::default(), &camera).expect("extractor");
            let mut curves_seen = 0;
            for i in (0..300).step_by(13) {
                let (frame, _) = sim.render_frame(i);
                let rgb = decode_rgb(&header, &yuyv_of(&frame)).expect("decode");
                let curves = ex.extract(&rgb, &background);
                curves_seen += curves.len();
                let mut points: Vec<(u32, u32)> = curves
                    .iter()
                    .flat_map(|c| c.points_px.iter().map(|p| (p[0].to_bits(), p[1].to_bits())))
                    .collect();
                let mut pixels: Vec<u32> = ex.detector.points.iter().map(|p| p.pixel).collect();
                let (n_points, n_pixels) = (points.len(), pixels.len());
                points.sort_unstable();
                points.dedup();
                pixels.sort_unstable();
                pixels.dedup();
                if points.len() != n_points || pixels.len() != n_pixels {
                    doubled.push((scene, i, n_points - points.len(), n_pixels - pixels.len()));
                }
            }
            assert!(curves_seen >= 20, "{scene}: {curves_seen} curves");
        }
        assert!(
            doubled.is_empty(),
            "(scene, frame, points, pixels) doubled: {doubled:?}"
        );
    }
}
