//! Extraction on real-camera effects (issue 19): no laser-off frame, white and grey
//! structures, clipped channels, wide stripes, one laser of two, realistic simulated
//! scans scored against truth.

use super::score::Score;
use super::*;
use crate::simulate::random::draw_realistic;
use crate::simulate::{FrameFormat, Medium, Simulator};

/// Deterministic noise in [-1, 1) (sum of two uniforms, std ~0.41).
fn noise(i: u64) -> f64 {
    let mut z = i.wrapping_mul(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    ((z >> 40) as f64 / (1u64 << 24) as f64) + ((z & 0xFF_FFFF) as f64 / (1u64 << 24) as f64) - 1.0
}

/// A frame of `surface(x, y)` plus a straight stripe `y = y0 + slope x` of Gaussian std
/// `s`, `peak` grey levels times `rgb`, noise of std ~`sigma`, clipped to 0-255.
pub(super) fn frame(
    (w, h): (u32, u32),
    surface: &dyn Fn(f64, f64) -> [f64; 3],
    stripe: Option<(f64, f64, f64, f64, [f64; 3])>,
    sigma: f64,
) -> RgbImage {
    RgbImage::from_fn(w, h, |x, y| {
        let (xf, yf) = (x as f64, y as f64);
        let mut v = surface(xf, yf);
        if let Some((y0, slope, s, peak, rgb)) = stripe {
            let d = (yf - y0 - slope * xf) / slope.hypot(1.0);
            let g = peak * (-0.5 * d * d / (s * s)).exp();
            for (c, k) in v.iter_mut().zip(rgb) {
                *c += k * g;
            }
        }
        let i = 3 * (y as u64 * w as u64 + x as u64);
        image::Rgb([0, 1, 2].map(|c| {
            (v[c] + sigma / 0.41 * noise(i + c as u64))
                .round()
                .clamp(0.0, 255.0) as u8
        }))
    })
}

pub(super) fn distance_errors(
    curves: &[Curve],
    (y0, slope): (f64, f64),
    margin: f64,
    w: f64,
) -> Vec<f64> {
    curves
        .iter()
        .flat_map(|c| c.points_px.iter())
        .filter(|p| p[0] as f64 > margin && (p[0] as f64) < w - margin)
        .map(|p| (p[1] as f64 - y0 - slope * p[0] as f64) / slope.hypot(1.0))
        .collect()
}

/// An extractor for a red and a green laser, with the default settings, for frames of
/// `w × h` from a camera without distortion.
pub(super) fn red_green_extractor(w: u32, h: u32) -> Extractor {
    let params = ExtractParams {
        lasers: LaserColour::named(["red", "green"]),
        ..ExtractParams::default()
    };
    Extractor::new(&params, &Camera::with_fov(w, h, 1.0)).expect("extractor")
}

/// A checkerboard of 37 px squares, `light` and `dark`, as a surface for [`frame`].
fn checkerboard(light: [f64; 3], dark: [f64; 3]) -> impl Fn(f64, f64) -> [f64; 3] {
    move |x, y| {
        if ((x / 37.0) as i64 + (y / 37.0) as i64) % 2 == 0 {
            light
        } else {
            dark
        }
    }
}

/// A board in the green laser's own hue, its 12 px squares narrower than the local
/// background's window and turned 30°: with no laser, no curve against the local
/// background (the squares stay in the response, and the widest scale blurs them into
/// ridges along their diagonals); a green stripe across it, of three times the board's
/// contrast, is still found.
#[test]
fn a_board_in_the_lasers_own_hue_is_no_stripe() {
    let (w, h) = (320u32, 240u32);
    let (c, s) = (30f64.to_radians().cos(), 30f64.to_radians().sin());
    let board = move |x: f64, y: f64| {
        let (u, v) = (c * x + s * y, -s * x + c * y);
        if ((u / 12.0).floor() as i64 + (v / 12.0).floor() as i64).rem_euclid(2) == 0 {
            [22.0, 50.0, 22.0]
        } else {
            [10.0, 20.0, 10.0]
        }
    };
    let camera = Camera::with_fov(w, h, 1.0);
    let mut ex = Extractor::new(&ExtractParams::default(), &camera).expect("extractor");
    let bare = ex.extract(&frame((w, h), &board, None, 2.0), &Background::local(w, h));
    let lengths: Vec<f64> = bare.iter().map(Curve::length_px).collect();
    assert!(bare.is_empty(), "curves on the bare board: {lengths:?}");
    assert!(ex.stats().round_tiles > 0);
    let (y0, slope) = (100.0, 0.2);
    let stripe = Some((y0, slope, 1.5, 90.0, [0.3, 1.0, 0.3]));
    let curves = ex.extract(
        &frame((w, h), &board, stripe, 2.0),
        &Background::local(w, h),
    );
    let mut e: Vec<f64> = distance_errors(&curves, (y0, slope), 30.0, w as f64)
        .iter()
        .map(|v| v.abs())
        .collect();
    e.sort_by(f64::total_cmp);
    assert!(e.len() >= 150, "{} points of the stripe", e.len());
    assert!(e[e.len() / 2] < 0.1, "median error {} px", e[e.len() / 2]);
    assert!(
        e[e.len() * 9 / 10] < 2.0,
        "points off the stripe: {:?}",
        &e[e.len() * 9 / 10..]
    );
}

/// A strip of a surface in the green laser's own hue, 9 px wide with sharp sides (a
/// square of a green checker cut by an object's silhouette): against the local
/// background it is a bar of the laser's hue whose two sides are alike, as a stripe's
/// are, and its band is long. Only its profile, a flat top where a beam's is a bell,
/// tells it apart: no curve.
#[test]
fn a_flat_bar_in_the_lasers_own_hue_is_no_stripe() {
    let (w, h) = (320u32, 240u32);
    let (c, s) = (20f64.to_radians().cos(), 20f64.to_radians().sin());
    let bar = move |x: f64, y: f64| {
        let d = (-s * (x - 160.0) + c * (y - 120.0)).abs();
        // Sharp sides: from inside to outside over one pixel.
        let inside = (5.0 - d).clamp(0.0, 1.0);
        [
            40.0 - 15.0 * inside,
            30.0 + 30.0 * inside,
            28.0 - 3.0 * inside,
        ]
    };
    let camera = Camera::with_fov(w, h, 1.0);
    let mut ex = Extractor::new(&ExtractParams::default(), &camera).expect("extractor");
    let curves = ex.extract(&frame((w, h), &bar, None, 2.0), &Background::local(w, h));
    let lengths: Vec<f64> = curves.iter().map(Curve::length_px).collect();
    assert!(curves.is_empty(), "curves on the bar: {lengths:?}");
    assert!(ex.stats().round_tiles > 0);
}

/// A face of a box in the green laser's own hue, 13 px wide with sharp sides, shaded
/// along its length (brighter where it faces the lamp): its tiles' half-maximum bands
/// take the brightest part for the top, so they do not read as flat, and its centre is
/// a ridge with dark flanks at the scale of its width. Each point's own profile, a
/// flat top where a beam's is a bell, tells it apart: no point on it (96, in 3 curves,
/// without the test). A beam of the same width and shading in the same frame, 80 px
/// below, is found where it is above the noise (183 points; 189 without the test).
#[test]
fn a_shaded_face_in_the_lasers_own_hue_is_no_stripe() {
    let (w, h) = (320u32, 240u32);
    let shade = |x: f64| 0.6 + 0.4 * (x / 23.0).sin();
    let face_and_beam = move |x: f64, y: f64| {
        let d = (y - 80.0 - 0.15 * x).abs();
        let face = (6.5 - d).clamp(0.0, 1.0);
        // 13 px FWHM: s = 5.5 px.
        let d = y - 160.0 - 0.15 * x;
        let beam = (-0.5 * d * d / (5.5 * 5.5)).exp();
        let v = (face + beam) * shade(x);
        [12.0 + 6.0 * v, 14.0 + 45.0 * v, 12.0 + 6.0 * v]
    };
    let camera = Camera::with_fov(w, h, 1.0);
    let mut ex = Extractor::new(&ExtractParams::default(), &camera).expect("extractor");
    let img = frame((w, h), &face_and_beam, None, 2.0);
    let curves = ex.extract(&img, &Background::local(w, h));
    let e = distance_errors(&curves, (160.0, 0.15), 20.0, w as f64);
    let on_beam = e.iter().filter(|d| d.abs() <= 1.0).count();
    let on_face = e.iter().filter(|d| (d.abs() - 80.0).abs() <= 8.0).count();
    assert!(on_face < 10, "{on_face} points on the face");
    assert!(
        on_beam >= 170,
        "{on_beam} of {} points on the beam",
        e.len()
    );
}

/// A warm-lit checkerboard, bright white squares (tinted as under a lamp, so their
/// hue is red's), with no laser: no curve without a laser-off frame. Against black
/// (no background, as before the local one) its squares' edges are curves.
#[test]
fn checkerboard_without_laser_gives_no_curve() {
    let (w, h) = (320u32, 240u32);
    let board = checkerboard([250.0, 215.0, 180.0], [40.0, 38.0, 36.0]);
    let img = frame((w, h), &board, None, 2.0);
    let camera = Camera::with_fov(w, h, 1.0);
    let mut ex = Extractor::new(&ExtractParams::default(), &camera).expect("extractor");
    let black = ex.extract(&img, &Background::black(w, h));
    let local = ex.extract(&img, &Background::local(w, h));
    eprintln!(
        "checkerboard: {} curves against black, {} against the local background",
        black.len(),
        local.len()
    );
    assert!(
        !black.is_empty(),
        "the board should be a trap without the local background"
    );
    assert!(
        local.is_empty(),
        "{} curves on a board with no laser",
        local.len()
    );
}

/// A cream-and-dark checkerboard through 4:2:0 chroma (as in MJPEG), blue and green
/// lasers. Chroma averaged over 2x2 pixels leaves a one-pixel pure-blue line on the
/// cream side of every edge that cuts a block: no curve without a laser-off frame. A
/// blue stripe across the same board is still found, within 0.1 px on average.
#[test]
fn chroma_fringes_of_a_board_are_not_stripes() {
    let (w, h) = (320u32, 240u32);
    let board = checkerboard([235.0, 225.0, 190.0], [30.0, 28.0, 26.0]);
    let camera = Camera::with_fov(w, h, 1.0);
    let params = ExtractParams {
        lasers: LaserColour::named(["blue", "green"]),
        ..ExtractParams::default()
    };
    let mut ex = Extractor::new(&params, &camera).expect("extractor");
    let subsampled = |mut img: RgbImage| {
        crate::simulate::realism::subsample_chroma(&mut img, (w as usize, h as usize), false);
        img
    };
    let bare = subsampled(frame((w, h), &board, None, 2.0));
    let curves = ex.extract(&bare, &Background::local(w, h));
    let points: usize = curves.iter().map(|c| c.points_px.len()).sum();
    assert!(
        curves.is_empty(),
        "{} curves ({points} points) on a board with no laser",
        curves.len()
    );
    let (y0, slope) = (118.4, 0.09);
    let stripe = (y0, slope, 1.5, 90.0, [0.05, 0.25, 1.0]);
    let lit = subsampled(frame((w, h), &board, Some(stripe), 2.0));
    let curves = ex.extract(&lit, &Background::local(w, h));
    let blue: Vec<Curve> = curves.into_iter().filter(|c| c.laser == 0).collect();
    let e = distance_errors(&blue, (y0, slope), 20.0, w as f64);
    let near = e.iter().filter(|d| d.abs() <= 1.0).count();
    let mean = e.iter().filter(|d| d.abs() <= 1.0).sum::<f64>() / near.max(1) as f64;
    assert!(
        near >= 250,
        "{near} of {} blue points on the stripe",
        e.len()
    );
    assert!(mean.abs() <= 0.1, "mean offset {mean}");
}

/// A red stripe so bright that red clips over ~10 px, its core still in green and
/// blue (crosstalk) on a grey surface: found within 0.1 px, its clipped share counted.
#[test]
fn stripe_clipped_in_its_own_channel_is_found() {
    let (w, h) = (200u32, 120u32);
    let surface = |_: f64, _: f64| [70.0, 70.0, 70.0];
    let (y0, slope) = (55.3, 0.07);
    let stripe = (y0, slope, 3.0, 2000.0, [1.0, 0.08, 0.06]);
    let img = frame((w, h), &surface, Some(stripe), 2.0);
    let bg = frame((w, h), &surface, None, 2.0);
    let camera = Camera::with_fov(w, h, 1.0);
    let mut ex = Extractor::new(&ExtractParams::default(), &camera).expect("extractor");
    for background in [Background::from_image(bg), Background::local(w, h)] {
        let curves = ex.extract(&img, &background);
        let e = distance_errors(&curves, (y0, slope), 20.0, w as f64);
        let mean = e.iter().sum::<f64>() / e.len().max(1) as f64;
        let worst = e.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        let stats = ex.stats();
        eprintln!(
            "clipped: {} points, mean {mean:.4}, worst {worst:.4}, {stats:?}",
            e.len()
        );
        assert!(e.len() >= 150, "{} points", e.len());
        assert!(
            mean.abs() <= 0.1 && worst <= 0.3,
            "mean {mean} worst {worst}"
        );
        assert!(curves.iter().all(|c| c.laser == 0), "seen as green");
        assert!(stats.clipped_points * 2 > stats.points, "{stats:?}");
    }
}

/// A stripe 20 px wide (FWHM) with no width given: one curve across the frame.
#[test]
fn wide_stripe_is_one_curve() {
    let (w, h) = (320u32, 160u32);
    let surface = |_: f64, _: f64| [30.0, 30.0, 30.0];
    let s = 20.0 / (8.0 * 2f64.ln()).sqrt();
    let (y0, slope) = (70.4, -0.1);
    let img = frame(
        (w, h),
        &surface,
        Some((y0, slope, s, 120.0, [1.0, 0.06, 0.02])),
        2.0,
    );
    let bg = frame((w, h), &surface, None, 2.0);
    let camera = Camera::with_fov(w, h, 1.0);
    let mut ex = Extractor::new(&ExtractParams::default(), &camera).expect("extractor");
    for background in [Background::from_image(bg), Background::local(w, h)] {
        let curves = ex.extract(&img, &background);
        let lengths: Vec<f64> = curves.iter().map(Curve::length_px).collect();
        eprintln!("wide stripe: curves {lengths:?}");
        assert_eq!(curves.len(), 1, "lengths {lengths:?}");
        assert!(lengths[0] > 0.8 * w as f64, "lengths {lengths:?}");
        let e = distance_errors(&curves, (y0, slope), 30.0, w as f64);
        let worst = e.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        assert!(worst <= 0.3, "worst {worst}");
    }
}

/// One red laser, overexposed, with the default red/green setting: no green curve
/// along the red one, and the absence of green told. The frames alternate between two
/// extractors of one run (as `reconstruct` splits them among its workers), each seeing
/// fewer frames than the warning waits for: it is told through the counters they share.
#[test]
fn one_laser_with_two_expected_is_not_doubled() {
    let (w, h) = (240u32, 160u32);
    let surface = |_: f64, _: f64| [60.0, 60.0, 60.0];
    let camera = Camera::with_fov(w, h, 1.0);
    let first = Extractor::new(&ExtractParams::default(), &camera).expect("extractor");
    let second = Extractor::new(&ExtractParams::default(), &camera)
        .expect("extractor")
        .sharing_warnings(first.warnings());
    let mut extractors = [first, second];
    let mut greens = 0;
    for i in 0..12 {
        let ex = &mut extractors[i % 2];
        let y0 = 40.0 + 6.3 * i as f64;
        // Crosstalk so strong that the core is bright green too.
        let img = frame(
            (w, h),
            &surface,
            Some((y0, 0.05, 2.5, 1500.0, [1.0, 0.35, 0.1])),
            2.0,
        );
        let curves = ex.extract(&img, &Background::local(w, h));
        assert!(
            curves.iter().any(|c| c.laser == 0),
            "frame {i}: red not found"
        );
        greens += curves.iter().filter(|c| c.laser == 1).count();
    }
    assert_eq!(greens, 0, "green curves invented");
    assert!(extractors.iter().all(Extractor::one_laser_absent));
}

/// A realistic scan ([`draw_realistic`]) in air, and an extractor for its lasers
/// against the local background (no laser-off frame).
struct Realistic {
    sim: Simulator,
    ex: Extractor,
    noise_sigma: f64,
}

impl Realistic {
    /// Scan `seed`; `None` under water.
    fn in_air(seed: u64) -> Option<Self> {
        let mut drawn = draw_realistic(seed, 40);
        if drawn.spec.medium == Medium::Water {
            return None;
        }
        if let FrameFormat::Jpeg { quality, .. } = drawn.format {
            drawn.params.jpeg_quality = Some(quality);
        }
        let sim = Simulator::new(&drawn.spec, &drawn.params).expect("sim");
        let params = ExtractParams {
            lasers: LaserColour::named(drawn.spec.projector.colours.iter().map(|c| c.name())),
            ..ExtractParams::default()
        };
        let ex = Extractor::new(&params, sim.camera()).expect("extractor");
        Some(Self {
            sim,
            ex,
            noise_sigma: drawn.params.noise_sigma,
        })
    }

    /// Renders frame `index`, extracts it against its local background, and scores it.
    fn extract_into(&mut self, index: usize, score: &mut Score) {
        let cam = self.sim.camera();
        let mut img = RgbImage::new(cam.width, cam.height);
        let mut lit = vec![0u8; (cam.width * cam.height) as usize];
        self.sim.render_frame_into(index, &mut img, Some(&mut lit));
        let curves = self
            .ex
            .extract(&img, &Background::local(cam.width, cam.height));
        let threshold = (5.0 * self.noise_sigma) as u8;
        score.add(&self.sim, index, &lit, threshold, &curves);
    }
}

/// Realistic simulated scans (lit rooms, clutter and tables; none under water) with
/// no laser-off frame: recall of lit pixels within 1 px, points off every stripe. The
/// bounds guard what the local background gives today: on these four frames recall
/// 0.925 and stray 0.046 (2026-12-06; 0.069 before the flat-top test). White things on
/// a coloured surface and laser-hued texture narrower than a beam still read as
/// stripe. The aim is 0.95 and 0.005 (`cargo bench --bench realistic` prints
/// both policies).
#[test]
fn realistic_frames_without_background() {
    let mut score = Score::default();
    let mut scans = 0;
    let mut seed = 100;
    while scans < 2 {
        seed += 1;
        let Some(mut scan) = Realistic::in_air(seed) else {
            continue;
        };
        scans += 1;
        for index in [9, 22] {
            scan.extract_into(index, &mut score);
        }
    }
    eprintln!(
        "realistic, no background: recall {:.3}, median error {:.4} px, stray {:.4}",
        score.recall(),
        score.error_quantile(0.5),
        score.stray_share()
    );
    assert!(score.recall() >= 0.9, "recall {}", score.recall());
    assert!(score.stray_share() <= 0.06, "stray {}", score.stray_share());
}

/// Realistic table 18's frame 18: a box in the blue laser's own hue, checkered with
/// squares foreshortened below the local background's window, and no laser-off frame.
/// The squares the opening's window does not fit leak into the excess as bands of the
/// laser's hue along their edges, offset from the edge by its blur: sampled two pixels
/// to either side, the step across such a band caught about half of the edge's
/// contrast, less than the band's strength, and 30 % of the frame's points were such
/// bands. Sampled four pixels out, the step is the edge's whole contrast. And realistic
/// room 1's frame 5: a fringe beside a narrow feature, whose far side four pixels out
/// is the same surface again, is caught only at two: the check takes the larger step.
#[test]
fn fringes_and_bands_along_edges_are_not_stripes() {
    // (seed, frame, largest stray share): table 18 had 412 of 1,392 points stray with
    // the step at 2 px alone and has 190 of 1,170 now (the rest are other mechanisms:
    // docs/extraction.md); room 1 had 32 of 1,803 with the step at 4 px alone and has
    // 2 of 1,773 now. Recall 0.709 and 0.981 either way.
    for (seed, frame, most, recall) in [(18, 18, 0.2, 0.7), (1, 5, 0.01, 0.97)] {
        assert_realistic_frame(seed, frame, most, recall);
    }
}

/// Realistic table 16 (boxes in the blue laser's own hue, faces narrower than the local
/// background's window, no laser-off frame) and clutter 14 (green and red boxes): the
/// faces' centres are ridges with dark flanks at the scale of their width, and their
/// flat tops alone tell them from beams (`detect/profile.rs`). Without that test, 179
/// of 1,764 points of table 16's frame 5 and 292 of 2,234 of clutter 14's were stray;
/// with it, 3 of 1,588 and 47 of 1,989, at the same recall (0.939 and 0.896).
#[test]
fn faces_of_the_lasers_own_hue_in_realistic_scenes_are_not_stripes() {
    for (seed, frame, most, recall) in [(16, 5, 0.01, 0.9), (14, 5, 0.03, 0.88)] {
        assert_realistic_frame(seed, frame, most, recall);
    }
}

/// Realistic scan `seed` in air, frame `frame` against the local background: recall at
/// least `recall`, at most `most` of the points stray.
fn assert_realistic_frame(seed: u64, frame: usize, most: f64, recall: f64) {
    let mut scan = Realistic::in_air(seed).expect("in air");
    let mut score = Score::default();
    scan.extract_into(frame, &mut score);
    eprintln!(
        "scan {seed}, frame {frame}: recall {:.3}, stray {} of {}",
        score.recall(),
        score.stray,
        score.points
    );
    assert!(
        score.recall() >= recall,
        "scan {seed}: recall {}",
        score.recall()
    );
    assert!(
        score.stray_share() <= most,
        "scan {seed}: stray {} of {}",
        score.stray,
        score.points
    );
}

/// 4:2:0 chroma (MJPEG) spreads a stripe's colour over 2×2 blocks; only its luma stays
/// sharp. Against a local background the stripe is located on its own channel, which
/// keeps that luma, and told from the surface by its colour: the centre is as good as
/// against the true laser-off frame (0.063 px rms here, the noise's). Own minus
/// foreign, all colour, followed the blocks: 0.267 px.
#[test]
fn a_stripe_in_subsampled_chroma_is_located_on_its_own_channel() {
    let (w, h) = (320u32, 120u32);
    let rms = |e: &[f64]| (e.iter().map(|e| e * e).sum::<f64>() / e.len() as f64).sqrt();
    let mut ex = red_green_extractor(w, h);
    let surface = |_: f64, _: f64| [60.0; 3];
    // Which channel locates the stripe, with the rebuild's pull left in for both
    // (its model is held by `tests_chroma`).
    ex.sampling.sampling.settle();
    let off = Background::from_image(frame((w, h), &surface, None, 0.0));
    let (mut local, mut truth) = (Vec::new(), Vec::new());
    for y0 in [40.0, 40.25, 40.5, 40.75] {
        let line = (y0, 0.07);
        let stripe = Some((line.0, line.1, 1.0, 120.0, [0.1, 1.0, 0.1]));
        let mut img = frame((w, h), &surface, stripe, 1.5);
        crate::simulate::realism::subsample_chroma(&mut img, (w as usize, h as usize), false);
        let e = distance_errors(
            &ex.extract(&img, &Background::local(w, h)),
            line,
            20.0,
            320.0,
        );
        assert!(e.len() >= 260, "y0 {y0}: {} points", e.len());
        local.extend(e);
        truth.extend(distance_errors(&ex.extract(&img, &off), line, 20.0, 320.0));
    }
    let (local, truth) = (rms(&local), rms(&truth));
    assert!(
        local < 1.1 * truth,
        "rms {local:.4} px against a local background, {truth:.4} px against the truth"
    );
}

/// A stripe too faint for any pixel to reach `min_value` (a green one of 11 grey
/// levels, 5σ) across a dark red surface with a grain in its own colour (lines 3 px
/// wide, 20 % brighter, every 37 px), blue and green lasers: against the local
/// background the faint search finds it (no point without it), and the grain gives no
/// curve. (Under a red laser the same grain would be a red line on a red surface, which
/// one frame does not tell from a stripe.)
#[test]
fn a_faint_stripe_on_a_grained_surface_is_found_against_a_local_background() {
    let (w, h) = (320u32, 240u32);
    let surface = |x: f64, y: f64| {
        let grain = if (x + 0.3 * y).rem_euclid(37.0) < 3.0 {
            1.2
        } else {
            1.0
        };
        [60.0 * grain, 18.0 * grain, 12.0 * grain]
    };
    let line = (150.0, -0.25);
    let stripe = Some((line.0, line.1, 1.2, 11.0, [0.0, 1.0, 0.0]));
    let params = ExtractParams {
        lasers: LaserColour::named(["blue", "green"]),
        ..ExtractParams::default()
    };
    let camera = Camera::with_fov(w, h, 1.0);
    let mut ex = Extractor::new(&params, &camera).expect("extractor");
    let img = frame((w, h), &surface, stripe, 2.0);
    let curves = ex.extract(&img, &Background::local(w, h));
    let e = distance_errors(&curves, line, 20.0, w as f64);
    let on = e.iter().filter(|d| d.abs() <= 1.0).count();
    let off = e.iter().filter(|d| d.abs() > 2.0).count();
    assert!(on >= 200, "{on} points on the stripe ({} in all)", e.len());
    assert!(off <= 5, "{off} points off the stripe");
}
