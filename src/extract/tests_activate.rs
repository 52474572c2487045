//! Which tiles the detector searches ([`super::activate`]): a surface's own texture,
//! which a local background leaves in the excess, activates hardly any.

use super::tests_real::{distance_errors, frame};
use super::*;

/// A purple board of 6 px squares (finer than the local background's window, so its
/// squares stay in the excess), its light squares paler than its dark ones, under a
/// blue and a green laser with no laser on. The light squares' excess is a pale
/// purple: a hue between the lasers' that the blue response still reads, and less
/// pure than the surface under it. Before its purity was asked for, it activated a
/// quarter of the frame's tiles (realistic table 18's purple-grey checker activated
/// two thirds, and made that scan 18 % of the realistic bench's time); now at most a
/// tenth, where noise lends a pixel a purer hue. No curve either way, and a blue
/// stripe across the board is still found.
#[test]
fn a_textured_surface_between_the_lasers_hues_activates_few_tiles() {
    let (w, h) = (320u32, 240u32);
    let board = |x: f64, y: f64| {
        if ((x / 6.0) as i64 + (y / 6.0) as i64) % 2 == 0 {
            [148.0, 102.0, 160.0]
        } else {
            [118.0, 80.0, 128.0]
        }
    };
    let camera = Camera::with_fov(w, h, 1.0);
    let params = ExtractParams {
        lasers: LaserColour::named(["blue", "green"]),
        ..ExtractParams::default()
    };
    let mut ex = Extractor::new(&params, &camera).expect("extractor");
    let tiles =
        2 * (w as usize).div_ceil(ex.detector.tile) * (h as usize).div_ceil(ex.detector.tile);
    let bare = ex.extract(&frame((w, h), &board, None, 2.0), &Background::local(w, h));
    let active = ex.stats().active_tiles;
    eprintln!(
        "bare board: {active} of {tiles} tiles active, {} curves",
        bare.len()
    );
    assert!(
        bare.is_empty(),
        "{} curves on a board with no laser",
        bare.len()
    );
    assert!(
        active * 10 <= tiles,
        "{active} of {tiles} tiles active on a board with no laser"
    );
    let (y0, slope) = (110.0, 0.15);
    let stripe = Some((y0, slope, 1.5, 90.0, [0.1, 0.3, 1.0]));
    let curves = ex.extract(
        &frame((w, h), &board, stripe, 2.0),
        &Background::local(w, h),
    );
    let on: usize = distance_errors(&curves, (y0, slope), 20.0, w as f64)
        .iter()
        .filter(|e| e.abs() < 1.0)
        .count();
    assert!(on >= 200, "{on} points on the stripe");
}
