//! Ridges of the difference that are not the laser's: valleys of the background, and
//! slopes that the colour test made into ridges. What moved away since the background
//! was taken.
//!
//! Against a laser-off frame (or the rolling median), `frame − background` is the
//! laser's light only where nothing else changed. A dark object that lay in the
//! background and has moved since (a hair, a cable, a fish) leaves a valley in the
//! background, and the difference has a ridge there in the colour of the surface under
//! it. On a surface of the laser's hue (a green sphere under a green laser, a brown
//! floor under a red one) that ridge has the laser's hue too, and no colour test can
//! refuse it. Where it lies tells it apart: a stripe is a ridge of the frame itself,
//! while the moved object's ridge is a valley of the background over a frame that is
//! flat there.
//!
//! So each ridge point reads, in its laser's own channels and across the line at the
//! detector's flank distance, the frame's rise from each flank to the centre,
//! `f(c) − f(flank)`, and the background's fall, `b(flank) − b(c)`; their sum is the
//! difference's rise. The point is not used (its strength is set to zero, under any
//! linking threshold) when
//! - on both sides the background's fall is larger than the frame's rise: more than
//!   half of the difference's ridge is the background's valley. Both sides, because a
//!   stripe beside a bright edge of the scene has that edge on one flank, in the
//!   background and the frame alike: a valley on one side only is an edge;
//! - or the difference falls towards either flank: no ridge of the laser's own
//!   channel at all. A grey surface's excess (the same moved strand over a grey floor)
//!   is refused by the colour test, but where it fades into the noise at its edges the
//!   noise lends it a hue, and the response, gated by colour, has ridges there that
//!   the own channel does not.
//!
//! Each of the three places is the mean of five samples one pixel apart along the
//! line, so the noise of each side's test is under the frame's noise σ, against the
//! 5 σ or more of a faint stripe's rise. A clipped own channel at the centre is left
//! alone: the frame is flat there by clipping, not by absence. A faint stripe over a
//! corner of a high-contrast pattern (a checkerboard) loses a few points, where the
//! pattern is a valley across the line on both sides; on the realistic bench that is
//! 0.5 % of one frame's recall, and nothing overall.
//!
//! Not run against a local background: the opening keeps the frame's narrow valleys,
//! so the difference is nought there and has no ridge to test.

use image::RgbImage;

use super::colour::ColourLut;
use super::detect::LinePoint;

/// Samples averaged along the line at each of the three places.
const ALONG: [f32; 5] = [-2.0, -1.0, 0.0, 1.0, 2.0];

/// The largest of the channels in `channels` of `image` at `(x, y)`, bilinear between
/// pixel centres, the border repeated.
fn own_at(image: &RgbImage, channels: [bool; 3], x: f32, y: f32) -> f32 {
    let (w, h) = (image.width() as isize, image.height() as isize);
    let raw = image.as_raw();
    let (xf, yf) = (x.floor(), y.floor());
    let (fx, fy) = (x - xf, y - yf);
    let (x0, y0) = (xf as isize, yf as isize);
    let px = |xx: isize, yy: isize| -> f32 {
        let i = 3 * (yy.clamp(0, h - 1) * w + xx.clamp(0, w - 1)) as usize;
        let mut own = 0u8;
        for (c, on) in channels.iter().enumerate() {
            if *on {
                own = own.max(raw[i + c]);
            }
        }
        f32::from(own)
    };
    (px(x0, y0) * (1.0 - fx) + px(x0 + 1, y0) * fx) * (1.0 - fy)
        + (px(x0, y0 + 1) * (1.0 - fx) + px(x0 + 1, y0 + 1) * fx) * fy
}

/// `image`'s own channels across the line at `p` (normal `n`): `[centre, behind,
/// ahead]`, the flanks `flank_px` either side, each place the mean of [`ALONG`]
/// samples along the line.
fn across(image: &RgbImage, channels: [bool; 3], p: &LinePoint) -> [f32; 3] {
    let mean = |d: f32| -> f32 {
        let (cx, cy) = (p.x + d * p.nx, p.y + d * p.ny);
        ALONG
            .iter()
            .map(|&s| own_at(image, channels, cx - s * p.ny, cy + s * p.nx))
            .sum::<f32>()
            / ALONG.len() as f32
    };
    [mean(0.0), mean(-p.flank_px), mean(p.flank_px)]
}

/// Sets the strength of each point of `points` (laser `laser`, its own channels as in
/// `lut`) to zero where its ridge is mostly a valley of `background` rather than a
/// ridge of `frame`; returns how many were.
pub(crate) fn veto_background_valleys(
    points: &mut [LinePoint],
    (frame, background): (&RgbImage, &RgbImage),
    lut: &ColourLut,
    laser: u8,
) -> usize {
    let channels = lut.channels()[usize::from(laser)];
    let raw = frame.as_raw();
    let mut vetoed = 0;
    for p in points.iter_mut().filter(|p| p.strength > 0.0) {
        if lut.own_clipped(laser, &raw[3 * p.pixel as usize..]) {
            continue;
        }
        let [fc, f0, f1] = across(frame, channels, p);
        let [bc, b0, b1] = across(background, channels, p);
        // Per side: the background's rise from the centre against the frame's fall.
        let (rise, fall) = ([fc - f0, fc - f1], [b0 - bc, b1 - bc]);
        let not_a_ridge = rise[0] + fall[0] <= 0.0 || rise[1] + fall[1] <= 0.0;
        if not_a_ridge || (fall[0] > rise[0] && fall[1] > rise[1]) {
            p.strength = 0.0;
            vetoed += 1;
        }
    }
    vetoed
}

#[cfg(test)]
mod tests {
    use image::RgbImage;

    use crate::camera::Camera;
    use crate::extract::{Background, Curve, ExtractParams, Extractor, LaserColour};

    const SIZE: u32 = 96;

    /// A frame of `surface` (per pixel, before noise) with a red stripe of peak `peak`
    /// (std 1.2 px) across it at `y = 60.3`, and noise of σ 1.5 from `seed`.
    fn render(surface: &dyn Fn(f64, f64) -> [f64; 3], peak: f64, seed: u64) -> RgbImage {
        let mut state = seed;
        let mut noise = move || {
            // Sum of four uniforms, scaled to σ 1.5: enough of a normal for a test.
            (0..4)
                .map(|_| {
                    state = state
                        .wrapping_mul(6_364_136_223_846_793_005)
                        .wrapping_add(1);
                    (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
                })
                .sum::<f64>()
                * 1.5
                * 3f64.sqrt()
        };
        RgbImage::from_fn(SIZE, SIZE, |x, y| {
            let (xf, yf) = (f64::from(x), f64::from(y));
            let d = yf - 60.3;
            let g = peak * (-0.5 * d * d / (1.2 * 1.2)).exp();
            let v = surface(xf, yf);
            let lit = [v[0] + g, v[1] + 0.05 * g, v[2] + 0.05 * g];
            image::Rgb(lit.map(|c| (c + noise()).round().clamp(0.0, 255.0) as u8))
        })
    }

    fn extract(frame: &RgbImage, background: RgbImage) -> (Vec<Curve>, Extractor) {
        let params = ExtractParams {
            min_curve_length_px: 5.0,
            lasers: LaserColour::preset("red-green").expect("preset"),
            ..ExtractParams::default()
        };
        let camera = Camera::with_fov(SIZE, SIZE, 1.0);
        let mut ex = Extractor::new(&params, &camera).expect("extractor");
        let curves = ex.extract(frame, &Background::from_image(background));
        (curves, ex)
    }

    /// Points of `curves` within 0.5 px of the stripe, and those more than 3 px off it.
    fn on_and_off(curves: &[Curve]) -> (usize, usize) {
        let points = curves.iter().flat_map(|c| c.points_px.iter());
        let off = points.clone().filter(|p| (p[1] - 60.3).abs() > 3.0).count();
        let on = points.filter(|p| (p[1] - 60.3).abs() < 0.5).count();
        (on, off)
    }

    /// A dark strand lay across a brown floor in the laser-off frame and has moved away
    /// since. The floor shows through brighter than the background there, brown in the
    /// difference: a hue the red laser's range holds, so the colour test lets it
    /// through. It is a valley of the background, not a ridge of the frame, and gives
    /// no point; the stripe across it is found.
    #[test]
    fn a_strand_that_moved_off_a_floor_of_the_lasers_hue_gives_no_curve() {
        let floor = [110.0, 72.0, 58.0];
        let strand = move |x: f64, y: f64| {
            let d = x - (30.0 + 0.3 * y);
            let shade = 1.0 - 0.8 * (-0.5 * d * d / (1.2 * 1.2)).exp();
            floor.map(|c| c * shade)
        };
        let background = render(&strand, 0.0, 7);
        let frame = render(&move |_, _| floor, 70.0, 8);
        let (curves, ex) = extract(&frame, background);
        let (on, off) = on_and_off(&curves);
        assert!(on >= 70, "{on} points on the stripe");
        assert_eq!(off, 0, "{off} points off the stripe: {curves:?}");
        assert!(ex.stats().moved_points > 0, "{:?}", ex.stats());
    }

    /// The valley must be on both sides: a faint stripe just on the dark side of a
    /// bright edge of the scene has the bright flank in the background and in the frame
    /// alike, and the difference's ridge is the stripe's. Weighed over both flanks at
    /// once, the edge's half step reads as a valley deeper than the frame's ridge.
    #[test]
    fn a_stripe_beside_an_edge_of_the_scene_is_kept() {
        // Vertical step at x = 47.5 and a horizontal one just above the stripe, so the
        // stripe runs along the dark side of the latter.
        let scene = |x: f64, y: f64| {
            let v = if y >= 62.0 || x >= 47.5 { 170.0 } else { 40.0 };
            [v, v, v]
        };
        let background = render(&scene, 0.0, 7);
        let frame = render(&scene, 30.0, 8);
        let (curves, ex) = extract(&frame, background);
        let (on, _) = on_and_off(&curves);
        assert!(on >= 70, "{on} points on the stripe, {:?}", ex.stats());
    }
}
