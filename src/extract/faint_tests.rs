//! The faint-stripe activation ([`super`]) on synthetic frames: stripes at any angle,
//! noise and glow, textured glow, texture in a surface's own colour against a local
//! background, and the ridge flags against the rule as first written.

use super::*;

/// The mid-grey background of most tests.
const GREY: [f64; 3] = [80.0; 3];

/// A frame of `w × h` over a background of colour `surface`, with Gaussian noise of
/// `noise` grey levels in every channel, plus `add(x, y) → [r, g, b]`; and the
/// background.
fn frame_on(
    surface: [f64; 3],
    w: usize,
    h: usize,
    noise: f64,
    seed: u64,
    add: impl Fn(f64, f64) -> [f64; 3],
) -> (Vec<u8>, Vec<u8>) {
    let mut state = seed;
    let mut gauss = move || {
        let mut u = || {
            state = crate::rng::mix64(state.wrapping_add(0x9e37_79b9_7f4a_7c15));
            ((state >> 11) as f64 + 0.5) / (1u64 << 53) as f64
        };
        let (a, b) = (u(), u());
        (-2.0 * a.ln()).sqrt() * (2.0 * std::f64::consts::PI * b).cos()
    };
    let background: Vec<u8> = (0..w * h)
        .flat_map(|_| surface.map(|v| v.round() as u8))
        .collect();
    let mut f = background.clone();
    for y in 0..h {
        for x in 0..w {
            let a = add(x as f64, y as f64);
            for c in 0..3 {
                let v = surface[c] + a[c] + noise * gauss();
                f[3 * (y * w + x) + c] = v.round().clamp(0.0, 255.0) as u8;
            }
        }
    }
    (f, background)
}

const RED_GREEN: [[bool; 3]; 2] = [[true, false, false], [false, true, false]];

fn activate(w: usize, h: usize, f: &[u8], b: &[u8]) -> (Vec<Vec<bool>>, f32) {
    activate_against(w, h, f, b, false)
}

/// As [`activate`], `local` telling whether `b` is a local background.
fn activate_against(w: usize, h: usize, f: &[u8], b: &[u8], local: bool) -> (Vec<Vec<bool>>, f32) {
    let tile = 16;
    let (tx, ty) = (w.div_ceil(tile), h.div_ceil(tile));
    let mut active = vec![vec![false; tx * ty]; 2];
    let mut faint = FaintRidges::default();
    faint.activate(
        f,
        (b, None),
        (w, h),
        (tile, tx),
        &RED_GREEN,
        &mut active,
        local,
    );
    (active, faint.noise)
}

/// The ridge flags are the rule as first written (per block, the channel where the
/// ridge is highest, then its threshold there), on random block sums and
/// thresholds, ties between channels included.
#[test]
fn ridge_flags_follow_the_rule() {
    let (bw, bh) = (70, 41);
    let mut rng = crate::rng::SplitMix64::new(5);
    let mut faint = FaintRidges {
        bw,
        bh,
        flags: vec![0; bw * bh],
        ..FaintRidges::default()
    };
    for s in &mut faint.sums {
        // Few distinct values, so that channels tie.
        *s = (0..bw * bh)
            .map(|_| (rng.next_f64() * 12.0) as i16 * 5 - 30)
            .collect();
    }
    let regions = bw.div_ceil(REGION) * bh.div_ceil(REGION);
    faint.region_threshold = (0..regions)
        .map(|_| [0; 3].map(|_: i16| (rng.next_f64() * 25.0) as i16))
        .collect();
    faint.mark_ridges(false);
    let k = SIDE_BLOCKS;
    let at = |c: usize, x: usize, y: usize| faint.sums[c][y * bw + x];
    let mut set = 0;
    for by in 0..bh {
        for bx in 0..bw {
            let want = if (k..bh - k).contains(&by) && (k..bw - k).contains(&bx) {
                let hx = |c| at(c, bx, by).saturating_sub(at(c, bx - k, by).max(at(c, bx + k, by)));
                let hy = |c| at(c, bx, by).saturating_sub(at(c, bx, by - k).max(at(c, bx, by + k)));
                let h = [0, 1, 2].map(|c| hx(c).max(hy(c)));
                let c = if h[0] >= h[1] && h[0] >= h[2] {
                    0
                } else if h[1] >= h[2] {
                    1
                } else {
                    2
                };
                let t =
                    faint.region_threshold[(by / REGION) * bw.div_ceil(REGION) + bx / REGION][c];
                u8::from(hx(c) >= t) << c | u8::from(hy(c) >= t) << (3 + c)
            } else {
                0
            };
            assert_eq!(faint.flags[by * bw + bx], want, "block ({bx}, {by})");
            set += usize::from(want != 0);
        }
    }
    assert!(set > bw * bh / 10, "{set} blocks flagged");
}

/// A faint red stripe (peak 8 grey levels, 4σ of the noise, FWHM 2.5 px) activates
/// the tiles along it at every angle, and only red's.
#[test]
fn faint_stripe_activates_its_tiles_at_any_angle() {
    let (w, h) = (256, 256);
    let s = 2.5 / 2.3548;
    for (i, deg) in [0.0f64, 20.0, 45.0, 70.0, 90.0, 135.0]
        .into_iter()
        .enumerate()
    {
        let (sin, cos) = deg.to_radians().sin_cos();
        let stripe = |x: f64, y: f64| {
            let d = (x - 128.0) * sin - (y - 128.0) * cos;
            [8.0 * (-0.5 * d * d / (s * s)).exp(), 0.0, 0.0]
        };
        let (f, b) = frame_on(GREY, w, h, 2.0, i as u64 + 1, stripe);
        let (active, noise) = activate(w, h, &f, &b);
        // Block sums of 16 pixels of σ = 2: σ 8.
        assert!((7.0..9.0).contains(&noise), "noise {noise}");
        // Tiles the line passes through, away from the border.
        let mut line = vec![false; 256];
        for step in -200..=200 {
            let (x, y) = (128.0 + step as f64 * cos, 128.0 + step as f64 * sin);
            let (tx, ty) = ((x / 16.0).floor() as i64, (y / 16.0).floor() as i64);
            if (1..15).contains(&tx) && (1..15).contains(&ty) {
                line[ty as usize * 16 + tx as usize] = true;
            }
        }
        let on = line.iter().filter(|l| **l).count();
        let hit = (0..256).filter(|&t| line[t] && active[0][t]).count();
        assert!(on >= 10, "{deg}°: {on} tiles on the line");
        assert!(
            hit * 10 >= on * 8,
            "{deg}°: {hit} of {on} tiles on the line active"
        );
        assert!(!active[1].iter().any(|a| *a), "{deg}°: green activated");
    }
}

/// Noise alone, and a green glow over half the frame (20 grey levels, a plateau
/// with a soft edge), activate next to nothing.
#[test]
fn noise_and_glow_are_no_ridges() {
    let (w, h) = (512, 512);
    let (f, b) = frame_on(GREY, w, h, 2.0, 7, |x, _| {
        let g = 20.0 * crate::simulate::render::normal_cdf((x - 256.0) / 1.0);
        [0.0, g, 0.0]
    });
    let (active, _) = activate(w, h, &f, &b);
    let count: usize = active
        .iter()
        .map(|a| a.iter().filter(|a| **a).count())
        .sum();
    // 1024 tiles per laser.
    assert!(count <= 4, "{count} tiles activated by noise and glow");
    // The same noise with the thresholds taken from a noise-free estimate is
    // ridges all over: the measured noise is what keeps it quiet.
    let mut faint = FaintRidges::default();
    faint.sum_blocks(&f, (&b, None), w, w / BLOCK, h / BLOCK);
    faint.noise = 0.0;
    faint.region_thresholds(MIN_RIDGE_SUM);
    faint.mark_ridges(false);
    let ridges = faint.flags.iter().filter(|f| **f != 0).count();
    assert!(ridges > 200, "{ridges} ridge blocks at the floor threshold");
}

/// The green sheet's glow on a textured surface (right half: 30 grey levels,
/// modulated ±50 % by blobs of ~20 px) is a field of ridges in green; its regions
/// raise green's threshold, and a faint red stripe across it is still found.
#[test]
fn textured_glow_raises_its_regions_threshold() {
    let (w, h) = (512, 512);
    let s = 2.5 / 2.3548;
    let (f, b) = frame_on(GREY, w, h, 2.0, 11, |x, y| {
        let texture = 1.0 + 0.5 * (x / 3.0).sin() * (y / 4.0).sin();
        let glow = if x >= 256.0 { 30.0 * texture } else { 0.0 };
        let d = y - 200.0 - 0.1 * x;
        [8.0 * (-0.5 * d * d / (s * s)).exp(), glow, 0.0]
    });
    let (active, _) = activate(w, h, &f, &b);
    let tiles = w / 16;
    let green_right = (0..tiles * tiles)
        .filter(|t| t % tiles >= tiles / 2 && active[1][*t])
        .count();
    assert!(
        green_right <= 8,
        "{green_right} of 512 textured tiles active for green"
    );
    // The red stripe: tiles it passes through, away from the border.
    let mut on = 0;
    let mut hit = 0;
    for x in (24..488).step_by(16) {
        let y = 200.0 + 0.1 * x as f64;
        let t = (y / 16.0) as usize * tiles + x / 16;
        on += 1;
        hit += usize::from(active[0][t]);
    }
    assert!(
        hit * 10 >= on * 8,
        "{hit} of {on} tiles of the red stripe active"
    );
    // With the frame's threshold everywhere, the texture activates green widely.
    let mut faint = FaintRidges::default();
    faint.sum_blocks(&f, (&b, None), w, w / BLOCK, h / BLOCK);
    let threshold = faint.threshold();
    faint.region_thresholds(threshold);
    faint.region_threshold.fill([threshold as i16; 3]);
    faint.mark_ridges(false);
    let green_ridges = faint
        .flags
        .iter()
        .filter(|f| **f & (1 << 1 | 8 << 1) != 0)
        .count();
    assert!(
        green_ridges > 500,
        "{green_ridges} green ridge blocks at the frame's threshold"
    );
}

/// Against a local background a surface's texture stays in the excess: here a
/// dark red surface with a grain of thin lines 20 % brighter (a ridge in red of
/// six times the noise, continued across the frame), and a faint green stripe
/// (peak 12 grey levels, 6σ: the grain's green part raises green's threshold)
/// across it. Taken as it is, the grain activates red's tiles all over (325 of
/// 1,024); with the surface's colour taken out of each ridge, none, and the green
/// stripe's tiles are still found.
#[test]
fn texture_in_the_surfaces_colour_is_no_faint_stripe_against_a_local_background() {
    let (w, h) = (512, 512);
    let surface = [60.0, 18.0, 12.0];
    let s = 2.5 / 2.3548;
    let (f, b) = frame_on(surface, w, h, 2.0, 13, |x, y| {
        // Lines 3 px wide every 37 px, slanted.
        let grain = if (x + 0.3 * y).rem_euclid(37.0) < 3.0 {
            0.2
        } else {
            0.0
        };
        let d = y - 300.0 + 0.6 * x;
        let green = 12.0 * (-0.5 * d * d / (s * s)).exp();
        [
            grain * surface[0],
            grain * surface[1] + green,
            grain * surface[2],
        ]
    });
    let tiles = w / 16;
    let on_stripe = |t: usize| {
        let (cx, cy) = (
            (t % tiles) as f64 * 16.0 + 8.0,
            (t / tiles) as f64 * 16.0 + 8.0,
        );
        ((cy - 300.0 + 0.6 * cx) / (1.0f64 + 0.36).sqrt()).abs() < 24.0
    };
    let red = |active: &[Vec<bool>]| active[0].iter().filter(|a| **a).count();
    let (taken, _) = activate_against(w, h, &f, &b, false);
    assert!(
        red(&taken) > 100,
        "{} red tiles from the grain as it is",
        red(&taken)
    );
    let (active, _) = activate_against(w, h, &f, &b, true);
    assert!(
        red(&active) <= 4,
        "{} red tiles from the grain",
        red(&active)
    );
    let green_off = (0..tiles * tiles)
        .filter(|&t| active[1][t] && !on_stripe(t))
        .count();
    assert!(green_off <= 4, "{green_off} green tiles off the stripe");
    // The tiles the stripe's line passes through, away from the border.
    let mut line = vec![false; tiles * tiles];
    for x in 16..w - 16 {
        let y = 300.0 - 0.6 * x as f64;
        if (16.0..h as f64 - 16.0).contains(&y) {
            line[(y / 16.0) as usize * tiles + x / 16] = true;
        }
    }
    let on = line.iter().filter(|l| **l).count();
    let hit = (0..tiles * tiles)
        .filter(|&t| line[t] && active[1][t])
        .count();
    assert!(
        on >= 20 && hit * 10 >= on * 8,
        "{hit} of {on} tiles of the stripe active"
    );
}

/// A background's block sums are kept while its id holds and made again when it
/// changes: two frames against one laser-off frame, then against another, give the
/// sums of a scratch that never keeps any.
#[test]
fn a_backgrounds_sums_are_kept_while_its_id_holds() {
    let (w, h) = (128, 96);
    let stripe = |y0: f64| {
        move |x: f64, y: f64| {
            let d = y - y0 - 0.2 * x;
            [40.0 * (-0.5 * d * d).exp(), 0.0, 0.0]
        }
    };
    let (f1, b1) = frame_on(GREY, w, h, 2.0, 3, stripe(20.0));
    let (f2, _) = frame_on(GREY, w, h, 2.0, 4, stripe(50.0));
    let (_, b2) = frame_on([90.0, 30.0, 60.0], w, h, 2.0, 5, stripe(0.0));
    let (mut kept, mut fresh) = (FaintRidges::default(), FaintRidges::default());
    for (f, b, id) in [
        (&f1, &b1, Some(1)),
        (&f2, &b1, Some(1)),
        (&f1, &b2, Some(2)),
        (&f2, &b2, Some(2)),
        (&f1, &b1, None),
    ] {
        kept.sum_blocks(f, (b, id), w, w / BLOCK, h / BLOCK);
        fresh.sum_blocks(f, (b, None), w, w / BLOCK, h / BLOCK);
        assert_eq!(kept.sums, fresh.sums, "background {id:?}");
        assert_eq!(kept.surface, fresh.surface, "background {id:?}");
        assert_eq!(kept.surface_of, id);
    }
}
