//! Realistic effects drawn for a scan ([`draw_realistic`]): the lit room's white and
//! grey structures, clipping, halos, chroma subsampling, a moving object, drawn from
//! their own stream of the seed, so that [`super::draw`] and every configuration it
//! gives stay as they were.

use super::{draw, DrawnScan, Rng};
use crate::simulate::realism::{Checker, Realism};
use crate::simulate::scene::Medium;

/// Scan configuration `seed` as [`draw`] gives it, with realistic effects:
///
/// - a checkerboard target (1/2) over 15-35 % of the image's width and height,
///   squares 16-60 px, dark 20-70 and light 170-250 grey levels, tinted warm (blue
///   0.75-0.95, green 0.88-1);
/// - 0-20 white specular spots (std 1-4 px) and 0-6 bright grey-white lines 100-400
///   px long (std 0.8-1.8 px, 150-250 grey levels);
/// - a patch of laser 0's own colour (1/3) over 10-25 % of the image;
/// - the lasers 1-3 × brighter (the own channel clips above ~1.3), crosstalk into the
///   other channels of 2-10 %, a blooming halo (1/3) of 5-15 % of the peak and std
///   4-10 px;
/// - 4:2:0 chroma (1/2), rebuilt as JPEG decoders do (interpolated) or by repeating
///   each block (1/2 each);
/// - a moving dark strand (1/3) between the background and the sweep.
///
/// Under water the scene is left as drawn (its light is its own).
pub fn draw_realistic(seed: u64, frames: usize) -> DrawnScan {
    let mut drawn = draw(seed, frames);
    if drawn.spec.medium == Medium::Water {
        return drawn;
    }
    let mut rng = Rng::new(seed ^ 0x7265_616c_6973_7469);
    let mut r = Realism::none();
    if rng.chance(0.5) {
        let (x0, y0) = (rng.uniform(0.0, 0.6), rng.uniform(0.0, 0.6));
        r.checker = Some(Checker {
            rect: [
                x0,
                y0,
                x0 + rng.uniform(0.15, 0.35),
                y0 + rng.uniform(0.15, 0.35),
            ],
            square_px: rng.uniform(16.0, 60.0),
            dark: rng.uniform(20.0, 70.0),
            light: rng.uniform(170.0, 250.0),
            tint: [1.0, rng.uniform(0.88, 1.0), rng.uniform(0.75, 0.95)],
        });
    }
    r.specular_spots = rng.int(0, 20);
    r.bright_lines = rng.int(0, 6);
    if rng.chance(1.0 / 3.0) {
        let rgb = drawn.spec.projector.colours[0].rgb();
        let (x0, y0) = (rng.uniform(0.0, 0.75), rng.uniform(0.0, 0.75));
        let level = rng.uniform(90.0, 180.0);
        r.coloured_patch = Some((
            [
                x0,
                y0,
                x0 + rng.uniform(0.1, 0.25),
                y0 + rng.uniform(0.1, 0.25),
            ],
            rgb.map(|c| level * (0.25 + 0.75 * c)),
        ));
    }
    r.laser_gain = rng.uniform(1.0, 3.0);
    r.crosstalk = rng.uniform(0.02, 0.1);
    if rng.chance(1.0 / 3.0) {
        r.bloom = Some((rng.uniform(0.05, 0.15), rng.uniform(4.0, 10.0)));
    }
    r.chroma_420 = rng.chance(0.5);
    r.moving_object = rng.chance(1.0 / 3.0);
    // Drawn last, so that the draws above are those of the scans before it existed.
    r.chroma_interpolated = r.chroma_420 && rng.chance(0.5);
    drawn.params.realism = r;
    drawn
}
