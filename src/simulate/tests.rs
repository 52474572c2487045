//! Tests of the simulator against analytic truth.

use std::path::Path;

use image::RgbImage;
use nalgebra::Vector3;

use super::scene::camera_from_spec;
use super::*;

type V3 = Vector3<f64>;

/// Camera at the world origin looking along +Z with +Y down: world = camera frame.
fn stripe_scene(extra: &str) -> SceneSpec {
    let text = format!(
        r#"
name = "stripe-test"
[camera]
position = [0, 0, 0]
look_at = [0, 0, 2]
up = [0, -1, 0]
width = 320
height = 240
hfov_deg = 60
distortion = [-0.15, 0.05, 0.001, -0.0005, 0.0]
[projector]
baseline = 0.4
baseline_direction = [1, 0.2, 0]
sweep_overscan = 0.5
power = 150
{extra}
[light]
ambient = 60
[[primitive]]
shape = "plane"
point = [0, 0, 2.2]
normal = [0.2, 0.1, -1]
texture = "none"
[[primitive]]
shape = "sphere"
center = [0.25, 0.15, 1.6]
radius = 0.15
"#
    );
    SceneSpec::from_toml_str(&text, Path::new("stripe-test.toml")).expect("valid test scene")
}

fn quiet() -> SimParams {
    SimParams {
        seed: 7,
        noise_sigma: 0.0,
        jpeg_quality: None,
        realism: crate::simulate::Realism::none(),
    }
}

/// Bilinear sample of channel `c` of `a - b`.
fn diff_at(a: &RgbImage, b: &RgbImage, c: usize, x: f64, y: f64) -> f64 {
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (x - x0, y - y0);
    let px = |xi: i64, yi: i64| -> f64 {
        let (xi, yi) = (xi as u32, yi as u32);
        a.get_pixel(xi, yi)[c] as f64 - b.get_pixel(xi, yi)[c] as f64
    };
    let (xi, yi) = (x0 as i64, y0 as i64);
    (1.0 - fy) * ((1.0 - fx) * px(xi, yi) + fx * px(xi + 1, yi))
        + fy * ((1.0 - fx) * px(xi, yi + 1) + fx * px(xi + 1, yi + 1))
}

/// A point on laser `k`'s true image curve, found on pixel row `y` by bisection on the
/// exact ray cast (independent of the renderer's per-pixel cache).
struct CurvePoint {
    x: f64,
    y: f64,
    /// Unit image normal of the curve.
    normal: [f64; 2],
    /// Pixels from the other laser's curve.
    other_px: f64,
    ray: V3,
}

fn signed(scene: &Scene, cam: &Camera, v: &V3, x: f64, y: f64) -> Option<(f64, usize)> {
    let ray = cam.ray_from_pixel(x, y)?;
    let hit = scene.cast(&V3::zeros(), &ray)?;
    Some((v.dot(&hit.point) - 1.0, hit.primitive))
}

fn curve_points(sim: &Simulator, truth: &FrameTruth, k: usize) -> Vec<CurvePoint> {
    let cam = sim.camera();
    let scene = sim.scene();
    let v = V3::from(truth.planes[k]);
    let other = V3::from(truth.planes[1 - k]);
    let centre = V3::from(truth.projector_centre);
    let axis = V3::from(truth.axis);
    let fan = V3::from(truth.fan_dirs[k]);
    let tan_half = (0.5 * sim.spec().projector.fan_deg.to_radians()).tan();
    let mut out = Vec::new();
    let margin = 10.0;
    for yi in (12..cam.height - 12).step_by(3) {
        let y = yi as f64;
        let mut x = margin;
        let mut prev = signed(scene, cam, &v, x, y);
        while x + 1.0 < cam.width as f64 - margin {
            let next = signed(scene, cam, &v, x + 1.0, y);
            if let (Some((d0, p0)), Some((d1, p1))) = (prev, next) {
                if p0 == 0 && p1 == 0 && d0.signum() != d1.signum() {
                    let (mut lo, mut hi) = (x, x + 1.0);
                    for _ in 0..60 {
                        let mid = 0.5 * (lo + hi);
                        let dm = signed(scene, cam, &v, mid, y).map_or(0.0, |s| s.0);
                        if dm.signum() == d0.signum() {
                            lo = mid;
                        } else {
                            hi = mid;
                        }
                    }
                    let xc = 0.5 * (lo + hi);
                    if let Some(p) = accept(sim, &v, &other, &centre, &axis, &fan, tan_half, xc, y)
                    {
                        out.push(p);
                    }
                }
            }
            prev = next;
            x += 1.0;
        }
    }
    out
}

#[allow(clippy::too_many_arguments)]
fn accept(
    sim: &Simulator,
    v: &V3,
    other: &V3,
    centre: &V3,
    axis: &V3,
    fan: &V3,
    tan_half: f64,
    x: f64,
    y: f64,
) -> Option<CurvePoint> {
    let cam = sim.camera();
    let scene = sim.scene();
    let ray = cam.ray_from_pixel(x, y)?;
    let hit = scene.cast(&V3::zeros(), &ray)?;
    let p = hit.point;
    // Inside the fan (with a margin), lit side visible, not shadowed.
    let w = p - centre;
    let wa = w.dot(axis);
    if wa <= 0.0 || w.dot(fan).abs() > 0.9 * wa * tan_half {
        return None;
    }
    if hit.normal.dot(&(centre - p)).signum() != hit.normal.dot(&-p).signum() {
        return None;
    }
    if scene
        .cast(centre, &(p - centre))
        .is_some_and(|h| h.t < 1.0 - 1e-6)
    {
        return None;
    }
    // Only the flat wall, with no edge or other surface within 7 px.
    for dy in [-7.0, 0.0, 7.0] {
        for dx in [-7.0, 0.0, 7.0] {
            let r = cam.ray_from_pixel(x + dx, y + dy)?;
            let h = scene.cast(&V3::zeros(), &r)?;
            if h.primitive != 0 {
                return None;
            }
            let hp = h.point;
            let wq = hp - centre;
            if scene
                .cast(centre, &(hp - centre))
                .is_some_and(|s| s.t < 1.0 - 1e-6)
            {
                return None;
            }
            if wq.dot(fan).abs() > wq.dot(axis) * tan_half {
                return None;
            }
        }
    }
    let e = 1e-3;
    let d = |xx: f64, yy: f64, pl: &V3| -> Option<f64> {
        let r = cam.ray_from_pixel(xx, yy)?;
        Some(pl.dot(&scene.cast(&V3::zeros(), &r)?.point) - 1.0)
    };
    let gx = (d(x + e, y, v)? - d(x - e, y, v)?) / (2.0 * e);
    let gy = (d(x, y + e, v)? - d(x, y - e, v)?) / (2.0 * e);
    let gn = gx.hypot(gy);
    let ox = (d(x + e, y, other)? - d(x - e, y, other)?) / (2.0 * e);
    let oy = (d(x, y + e, other)? - d(x, y - e, other)?) / (2.0 * e);
    let other_px = d(x, y, other)?.abs() / ox.hypot(oy);
    Some(CurvePoint {
        x,
        y,
        normal: [gx / gn, gy / gn],
        other_px,
        ray,
    })
}

#[test]
fn builtin_scenes_parse_and_round_trip_through_toml() {
    for name in BUILTIN_SCENES {
        let spec = builtin_scene(name).unwrap_or_else(|| panic!("built-in {name}"));
        let text = spec.to_toml_string().expect("serialise");
        let back = SceneSpec::from_toml_str(&text, Path::new("rt.toml")).expect("reload");
        assert_eq!(spec, back, "{name}");
    }
    assert!(builtin_scene("nope").is_none());
    // Their scales differ by an order of magnitude.
    let d: Vec<f64> = BUILTIN_SCENES
        .iter()
        .filter_map(|n| builtin_scene(n).map(|s| s.distance()))
        .collect();
    assert!(
        d[0] > 3.0 && (2.0..3.5).contains(&d[1]) && d[2] < 0.8,
        "{d:?}"
    );
}

#[test]
fn motion_keeps_orthogonal_planes_baseline_and_rolls() {
    for (name, seed) in [("room", 1u64), ("pipes", 2), ("bricks", 3)] {
        let spec = builtin_scene(name).expect("built-in");
        let scene = Scene::from_spec(&spec);
        let cam = camera_from_spec(&spec.camera);
        let motion = Motion::new(&spec, seed);
        let baseline = spec.projector.baseline.unwrap_or(0.2 * spec.distance());
        let wobble = spec.projector.wobble.unwrap_or(0.1 * baseline);
        let (mut roll_lo, mut roll_hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for i in 0..150 {
            let p = motion.pose(i, &scene, &cam);
            let (n0, n1) = (p.normal(0), p.normal(1));
            assert!(n0.dot(&n1).abs() < 1e-12, "planes orthogonal");
            assert!(p.axis.dot(&n0).abs() < 1e-12 && p.axis.dot(&n1).abs() < 1e-12);
            for k in 0..2 {
                assert!((p.plane(k).dot(&p.centre) - 1.0).abs() < 1e-12);
                // The plane meets the scene near the aim: the axis lies in both planes.
            }
            let off = (p.centre - motion.rest_centre()).norm();
            assert!(
                off <= wobble * (1.0 + 1e-12),
                "{name}: wobble {off} > {wobble}"
            );
            let r = p.centre.norm();
            assert!(
                (r - baseline).abs() <= wobble * (1.0 + 1e-12),
                "{name}: |C| = {r}"
            );
            roll_lo = roll_lo.min(p.roll_rad);
            roll_hi = roll_hi.max(p.roll_rad);
            // The measured roll agrees with the fan direction.
            let mut reference = V3::x() - p.axis * p.axis.x;
            reference.normalize_mut();
            let measured = p
                .axis
                .cross(&reference)
                .dot(&p.fan_dirs[0])
                .atan2(reference.dot(&p.fan_dirs[0]));
            assert!((measured - p.roll_rad).abs() < 1e-9);
        }
        let span = (roll_hi - roll_lo).to_degrees();
        assert!(span > 30.0, "{name}: roll spans {span} degrees");
    }
}

#[test]
fn different_seeds_move_differently_same_seed_identically() {
    let spec = builtin_scene("room").expect("room");
    let scene = Scene::from_spec(&spec);
    let cam = camera_from_spec(&spec.camera);
    let a = Motion::new(&spec, 1).pose(5, &scene, &cam);
    let b = Motion::new(&spec, 1).pose(5, &scene, &cam);
    let c = Motion::new(&spec, 2).pose(5, &scene, &cam);
    assert_eq!(a, b);
    assert!((a.centre - c.centre).norm() > 1e-6);
    assert!((a.axis - c.axis).norm() > 1e-6);
}

#[test]
fn frames_are_identical_on_one_and_two_threads() {
    let spec = stripe_scene("").with_resolution(96, 72);
    let params = SimParams {
        noise_sigma: 3.0,
        ..quiet()
    };
    let render = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("pool");
        pool.install(|| {
            let sim = Simulator::new(&spec, &params).expect("sim");
            let mut out: Vec<Vec<u8>> = (0..3).map(|i| sim.render_frame(i).0.into_raw()).collect();
            out.push(sim.background().into_raw());
            out
        })
    };
    let one = render(1);
    let two = render(2);
    assert_eq!(one, two);
    // Noise differs between frames and from the background.
    assert_ne!(one[0], one[3]);
    let other_seed = Simulator::new(
        &spec,
        &SimParams {
            seed: 8,
            ..params.clone()
        },
    )
    .expect("sim")
    .render_frame(0)
    .0
    .into_raw();
    assert_ne!(one[0], other_seed);
}

#[test]
fn stripe_centres_lie_on_the_true_curves() {
    let spec = stripe_scene("");
    let sim = Simulator::new(&spec, &quiet()).expect("sim");
    let bg = sim.background();
    let mut checked = 0;
    let mut worst: f64 = 0.0;
    for frame in [0, 3, 7, 12] {
        let (img, truth) = sim.render_frame(frame);
        for k in 0..2 {
            // Laser 0 is red, laser 1 green.
            let ch = k;
            for p in curve_points(&sim, &truth, k) {
                if p.other_px < 10.0 {
                    continue;
                }
                let (mut sw, mut swx) = (0.0, 0.0);
                let n = 101;
                for i in 0..n {
                    let s = -5.0 + 10.0 * i as f64 / (n - 1) as f64;
                    let val = diff_at(&img, &bg, ch, p.x + s * p.normal[0], p.y + s * p.normal[1])
                        .max(0.0);
                    sw += val;
                    swx += val * s;
                }
                assert!(sw > 100.0, "stripe visible at ({}, {})", p.x, p.y);
                let off = swx / sw;
                worst = worst.max(off.abs());
                checked += 1;
            }
        }
    }
    eprintln!("stripe centres: worst offset {worst:.4} px over {checked} samples");
    assert!(checked > 100, "only {checked} curve samples");
    assert!(
        worst < 0.05,
        "worst stripe centre offset {worst} px over {checked} samples"
    );
}

#[test]
fn true_planes_triangulate_the_true_depth() {
    let spec = stripe_scene("");
    let sim = Simulator::new(&spec, &quiet()).expect("sim");
    let depth = sim.depth();
    let cam = sim.camera().clone();
    let mut checked = 0;
    for frame in [1, 5] {
        let truth = sim.frame_truth(frame);
        for k in 0..2 {
            let v = V3::from(truth.planes[k]);
            for p in curve_points(&sim, &truth, k) {
                // u from the camera's undistortion of the sub-pixel curve point.
                let z_tri = 1.0 / v.dot(&p.ray);
                let z = sim.scene().ray_depth(&p.ray).expect("surface");
                assert!(((z_tri - z) / z).abs() < 1e-6, "{z_tri} vs {z}");
                // The depth map at the nearest pixel centre is that pixel's exact depth.
                let (xi, yi) = (p.x.round(), p.y.round());
                let r = cam.ray_from_pixel(xi, yi).expect("ray");
                let zp = sim.scene().ray_depth(&r).expect("surface");
                let dm = depth[yi as usize * cam.width as usize + xi as usize] as f64;
                assert!(((dm - zp) / zp).abs() < 1e-6, "{dm} vs {zp}");
                checked += 1;
            }
        }
    }
    assert!(checked > 50, "only {checked} samples");
}

#[test]
fn water_dims_red_and_adds_glow_in_front_of_surfaces() {
    let air = stripe_scene("");
    let mut water = air.clone();
    water.medium = Medium::Water;
    let sa = Simulator::new(&air, &quiet()).expect("air");
    let sw = Simulator::new(&water, &quiet()).expect("water");
    let (fa, _) = sa.render_frame(2);
    let (fw, _) = sw.render_frame(2);
    let (ba, bw) = (sa.background(), sw.background());
    let sum = |f: &RgbImage, b: &RgbImage, c: usize| -> f64 {
        f.pixels()
            .zip(b.pixels())
            .map(|(p, q)| (p[c] as f64 - q[c] as f64).max(0.0))
            .sum()
    };
    // Red laser light is attenuated much more than green.
    let red_ratio = sum(&fw, &bw, 0) / sum(&fa, &ba, 0);
    let green_ratio = sum(&fw, &bw, 1) / sum(&fa, &ba, 1);
    assert!(
        red_ratio < green_ratio,
        "red {red_ratio} green {green_ratio}"
    );
    // Glow: in water, many more pixels brighten than the stripes cover.
    let count = |f: &RgbImage, b: &RgbImage| {
        f.pixels()
            .zip(b.pixels())
            .filter(|(p, q)| p[1] as i32 - q[1] as i32 >= 2)
            .count()
    };
    assert!(count(&fw, &bw) > 3 * count(&fa, &ba));
}

/// A laser is one wavelength: water dims all of its light by that wavelength's
/// coefficient, so its stripe keeps the hue it has in air however far it travels (with
/// per-channel attenuation, a far red stripe turns yellow through its green crosstalk,
/// which water passes 10 times better than red).
#[test]
fn water_dims_a_laser_without_changing_its_hue() {
    let hue = |medium: Medium| {
        let mut spec = stripe_scene("");
        spec.projector.power = 1500.0;
        spec.medium = medium;
        let sim = Simulator::new(&spec, &quiet()).expect("sim");
        let bg = sim.background().clone();
        let mut ratios = Vec::new();
        for i in 0..6 {
            let (f, _) = sim.render_frame(i);
            for (p, q) in f.pixels().zip(bg.pixels()) {
                let d = [0, 1, 2].map(|c| p[c] as f64 - q[c] as f64);
                if d[0] >= 40.0 && d[0] < 250.0 && d[0] > 3.0 * d[1] {
                    ratios.push(d[1] / d[0]);
                }
            }
        }
        assert!(ratios.len() > 50, "{medium:?}: {} red pixels", ratios.len());
        ratios.sort_by(f64::total_cmp);
        ratios[ratios.len() / 2]
    };
    let (air, water) = (hue(Medium::Air), hue(Medium::Water));
    assert!(
        (water - air).abs() < 0.03,
        "green / red of the red stripe: air {air:.3}, water {water:.3}"
    );
}

#[test]
fn sim_dir_round_trip() {
    let dir = tempfile::tempdir().expect("tmp");
    let spec = stripe_scene("").with_resolution(80, 60);
    let sim = Simulator::new(&spec, &SimParams::default()).expect("sim");
    let calls = std::sync::atomic::AtomicUsize::new(0);
    let summary = write_sim_dir(&sim, 4, dir.path(), |_| {
        calls.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    })
    .expect("write");
    assert_eq!(calls.into_inner(), 4);
    assert_eq!(summary.frames, 4);
    assert!(summary.lit_pixels > 0);
    for name in [
        "frame_000000.png",
        "frame_000003.png",
        "background.png",
        "camera.yml",
        "camera_info.yaml",
        "scene.toml",
        "truth.json",
        "depth.pfm",
        "lit.png",
        "truth.ply",
    ] {
        assert!(dir.path().join(name).is_file(), "{name}");
    }
    let loaded = load_sim_dir(dir.path()).expect("load");
    assert_eq!(loaded.truth.frames.len(), 4);
    assert_eq!(loaded.truth.frames[2], sim.frame_truth(2));
    assert_eq!(&loaded.camera, sim.camera());
    assert_eq!(
        loaded.lit.iter().filter(|&&l| l).count(),
        summary.lit_pixels
    );
    assert_eq!(loaded.depth.len(), 80 * 60);
    let expect = sim.depth();
    for (a, b) in loaded.depth.iter().zip(&expect) {
        assert!(a == b || (a.is_nan() && b.is_nan()));
    }
    // The scene re-loaded from scene.toml casts like the original.
    let r = V3::new(0.05, -0.02, 1.0);
    assert_eq!(loaded.scene.ray_depth(&r), sim.scene().ray_depth(&r));
    // Lit pixels see a surface.
    for (l, d) in loaded.lit.iter().zip(&loaded.depth) {
        assert!(!*l || d.is_finite());
    }
}

#[test]
fn lit_pixels_lie_within_half_a_pixel_of_a_true_curve() {
    let spec = stripe_scene("").with_resolution(160, 120);
    let sim = Simulator::new(&spec, &quiet()).expect("sim");
    let cam = sim.camera().clone();
    let (w, h) = (cam.width as usize, cam.height as usize);
    let mut lit = vec![0u8; w * h];
    let mut img = RgbImage::new(1, 1);
    let truth = sim.render_frame_into(4, &mut img, Some(&mut lit));
    let mut n = 0;
    for y in 1..h - 1 {
        for x in 1..w - 1 {
            if lit[y * w + x] == 0 {
                continue;
            }
            n += 1;
            // Some laser's signed distance changes sign within 0.75 px of this centre
            // (enough to reach a curve 0.5 px away along any normal).
            let near = (0..2).any(|k| {
                let v = V3::from(truth.planes[k]);
                let s = |dx: f64, dy: f64| {
                    signed(sim.scene(), &cam, &v, x as f64 + dx, y as f64 + dy).map(|s| s.0)
                };
                let c = s(0.0, 0.0).unwrap_or(f64::NAN);
                [(0.75, 0.0), (-0.75, 0.0), (0.0, 0.75), (0.0, -0.75)]
                    .iter()
                    .any(|&(dx, dy)| s(dx, dy).is_some_and(|o| o.signum() != c.signum()))
            });
            assert!(near, "lit pixel ({x}, {y}) is far from both curves");
        }
    }
    assert!(n > 50, "{n} lit pixels");

    // The lit value is the stripe's peak contrast: with no noise, what the frame adds to
    // the background's strongest channel at a pixel within 0.5 px of the centre line
    // (a little less off the line, more where the two stripes overlap).
    let background = sim.background();
    let (mut close, mut unclipped) = (0, 0);
    for i in (0..w * h).filter(|&i| lit[i] > 0) {
        let (f, b) = (
            &img.as_raw()[3 * i..3 * i + 3],
            &background.as_raw()[3 * i..3 * i + 3],
        );
        if f.iter().any(|&c| c >= 250) {
            continue;
        }
        unclipped += 1;
        let added = (0..3)
            .map(|c| f[c] as f64 - b[c] as f64)
            .fold(0.0, f64::max);
        let peak = lit[i] as f64;
        close += usize::from((added - peak).abs() <= 0.3 * peak + 1.0);
    }
    assert!(unclipped > 50, "{unclipped} unclipped lit pixels");
    assert!(
        close * 10 >= unclipped * 9,
        "{close} of {unclipped} near their peak"
    );
}

#[test]
fn resolution_override_keeps_the_field_of_view() {
    let spec = builtin_scene("pipes").expect("pipes");
    let small = spec.clone().with_resolution(480, 270);
    let a = camera_from_spec(&spec.camera);
    let b = camera_from_spec(&small.camera);
    assert!((a.fx / a.width as f64 - b.fx / b.width as f64).abs() < 1e-12);
    // The image corner sees the same direction.
    let ra = a.ray_from_pixel(-0.5, -0.5).expect("ray");
    let rb = b.ray_from_pixel(-0.5, -0.5).expect("ray");
    assert!((ra - rb).norm() < 1e-9);
}

#[test]
fn jpeg_artefacts_change_the_image_but_not_much() {
    let spec = stripe_scene("").with_resolution(96, 72);
    let clean = Simulator::new(&spec, &quiet()).expect("sim");
    let jpeg = Simulator::new(
        &spec,
        &SimParams {
            jpeg_quality: Some(60),
            ..quiet()
        },
    )
    .expect("sim");
    let (a, _) = clean.render_frame(3);
    let (b, _) = jpeg.render_frame(3);
    assert_eq!(a.dimensions(), b.dimensions());
    let diffs: Vec<f64> = a
        .as_raw()
        .iter()
        .zip(b.as_raw())
        .map(|(&x, &y)| (x as f64 - y as f64).abs())
        .collect();
    let mean = diffs.iter().sum::<f64>() / diffs.len() as f64;
    assert!(mean > 0.1 && mean < 8.0, "mean JPEG difference {mean}");
}

#[test]
fn blue_green_lasers_light_the_blue_and_green_channels() {
    let mut spec = stripe_scene("colours = [\"blue\", \"green\"]").with_resolution(160, 120);
    spec.projector.power = 150.0;
    let sim = Simulator::new(&spec, &quiet()).expect("sim");
    let bg = sim.background();
    let (img, _) = sim.render_frame(2);
    let gain = |c: usize| -> f64 {
        img.pixels()
            .zip(bg.pixels())
            .map(|(p, q)| (p[c] as f64 - q[c] as f64).max(0.0))
            .sum()
    };
    assert!(gain(2) > 5.0 * gain(0), "blue {} red {}", gain(2), gain(0));
    assert!(gain(1) > 5.0 * gain(0));
}

#[test]
fn gaussian_noise_has_the_requested_sigma() {
    let spec = stripe_scene("").with_resolution(128, 96);
    let noisy = |seed: u64| {
        Simulator::new(
            &spec,
            &SimParams {
                seed,
                noise_sigma: 4.0,
                ..quiet()
            },
        )
        .expect("sim")
        .background()
    };
    let clean = Simulator::new(&spec, &quiet()).expect("sim").background();
    let (a, b) = (noisy(7), noisy(8));
    // The difference of two independent noisy images: no rounding bias of a clean
    // reference, variance 2σ² plus twice the quantisation variance 1/12.
    let d: Vec<f64> = a
        .as_raw()
        .iter()
        .zip(b.as_raw())
        .zip(clean.as_raw())
        .filter(|(_, &c)| c > 12 && c < 240)
        .map(|((&x, &y), _)| x as f64 - y as f64)
        .collect();
    let n = d.len() as f64;
    let mean = d.iter().sum::<f64>() / n;
    let var = d.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n;
    let sigma = ((var - 2.0 / 12.0) / 2.0).sqrt();
    assert!(mean.abs() < 0.15, "mean {mean}");
    assert!((sigma - 4.0).abs() < 0.15, "sigma {sigma}");
}

#[test]
fn glow_appears_exactly_where_a_camera_ray_crosses_a_lit_sheet() {
    let mut spec = stripe_scene("").with_resolution(160, 120);
    spec.medium = Medium::Water;
    spec.water.backscatter = 100.0;
    let with = Simulator::new(&spec, &quiet()).expect("sim");
    spec.water.backscatter = 0.0;
    let without = Simulator::new(&spec, &quiet()).expect("sim");
    let cam = with.camera().clone();
    let scene = with.scene();
    let tan_half = (0.5 * spec.projector.fan_deg.to_radians()).tan();
    let (mut glowing, mut dark, mut soft) = (0, 0, 0);
    for frame in 0..16 {
        let (a, truth) = with.render_frame(frame);
        let (b, _) = without.render_frame(frame);
        let centre = V3::from(truth.projector_centre);
        let axis = V3::from(truth.axis);
        for y in (0..cam.height).step_by(3) {
            'pixel: for x in (0..cam.width).step_by(3) {
                let ray = cam.ray_from_pixel(x as f64, y as f64).expect("ray");
                let Some(hit) = scene.cast(&V3::zeros(), &ray) else {
                    continue;
                };
                let (p, q) = (a.get_pixel(x, y), b.get_pixel(x, y));
                let diff: i32 = (0..3).map(|c| p[c] as i32 - q[c] as i32).sum();
                let mut predicted = false;
                for k in 0..2 {
                    // The camera ray meets sheet k at X = λ P (v·X = 1).
                    let v = V3::from(truth.planes[k]);
                    let lambda = 1.0 / v.dot(&hit.point);
                    // The surface point's distance from the sheet, against a few pixels'
                    // footprint there.
                    let off = (v.dot(&hit.point) - 1.0).abs() / v.norm();
                    let near = off < 0.05 * hit.point.norm();
                    if near || (lambda - 1.0).abs() < 0.02 || lambda.abs() < 0.02 {
                        // Just past the sheet's edge on the surface: the glow's edge
                        // is as soft as the stripe, so some reaches beyond it.
                        soft += usize::from(near && lambda > 1.0 && diff > 0);
                        continue 'pixel;
                    }
                    if !(lambda > 0.0 && lambda < 1.0) {
                        continue;
                    }
                    let w = hit.point * lambda - centre;
                    let ratio = w.dot(&V3::from(truth.fan_dirs[k])).abs() / w.dot(&axis);
                    if w.dot(&axis) <= 0.0 {
                        continue;
                    }
                    if (ratio - tan_half).abs() < 0.02 {
                        continue 'pixel;
                    }
                    if ratio > tan_half {
                        continue;
                    }
                    // Lit unless the sheet met a surface before X.
                    match scene.cast(&centre, &w) {
                        Some(h) if (h.t - 1.0).abs() < 0.02 => continue 'pixel,
                        Some(h) if h.t < 1.0 => {}
                        _ => predicted = true,
                    }
                }
                if predicted {
                    assert!(diff > 0, "no glow at ({x}, {y}) in frame {frame}");
                    glowing += 1;
                } else {
                    assert_eq!(diff, 0, "glow at ({x}, {y}) in frame {frame}");
                    dark += 1;
                }
            }
        }
    }
    assert!(
        glowing > 100 && dark > 100 && soft > 10,
        "{glowing} glowing, {dark} dark, {soft} lit just past the edge"
    );
}

#[test]
fn a_barrel_vault_seen_from_inside_is_shaded_and_lit() {
    let text = r#"
name = "vault-test"
[camera]
position = [0, 0, 1.5]
look_at = [0, 4, 2.6]
width = 160
height = 90
hfov_deg = 80
[projector]
baseline = 0.4
sweep_overscan = 0.7
[[primitive]]
name = "vault"
shape = "cylinder"
from = [0, -2, 2.2]
to = [0, 8, 2.2]
radius = 2.5
capped = false
arc_deg = 180
[[primitive]]
shape = "plane"
point = [0, 0, 0]
normal = [0, 0, 1]
[[primitive]]
shape = "plane"
point = [-2.5, 0, 0]
normal = [1, 0, 0]
[[primitive]]
shape = "plane"
point = [2.5, 0, 0]
normal = [-1, 0, 0]
[[primitive]]
shape = "plane"
point = [0, 8, 0]
normal = [0, -1, 0]
"#;
    let spec = SceneSpec::from_toml_str(text, Path::new("vault.toml")).expect("valid");
    let sim = Simulator::new(&spec, &quiet()).expect("sim");
    let cam = sim.camera().clone();
    let (w, h) = (cam.width as usize, cam.height as usize);
    let mut on_vault = vec![false; w * h];
    for y in 0..h {
        for x in 0..w {
            let ray = cam.ray_from_pixel(x as f64, y as f64).expect("ray");
            let hit = sim.scene().cast(&V3::zeros(), &ray).expect("closed room");
            on_vault[y * w + x] = hit.primitive == 0;
            // Below the springing line the side walls show, not the cut-away half;
            // above it the vault hides them.
            let z = sim.scene().world_from_camera.apply(&hit.point).z;
            match hit.primitive {
                0 => assert!(z > 2.2 - 1e-9, "pixel {x},{y}: vault at z {z}"),
                2 | 3 => assert!(z < 2.2 + 1e-9, "pixel {x},{y}: wall at z {z}"),
                _ => {}
            }
        }
    }
    let vault_pixels = on_vault.iter().filter(|&&v| v).count();
    assert!(vault_pixels > w * h / 5, "{vault_pixels}");
    // The vault is shaded like any surface (its normal faces the camera: no darker than
    // the flat ambient share on the darkest texture, 110 × 0.4 × 0.7 × 0.5), and the
    // stripes reach it from the projector inside.
    let bg = sim.background();
    let mut lit = vec![0u8; w * h];
    let mut img = RgbImage::new(cam.width, cam.height);
    for i in 0..8 {
        sim.render_frame_into(i, &mut img, Some(&mut lit));
    }
    let lit_on_vault = (0..w * h).filter(|&i| on_vault[i] && lit[i] > 20).count();
    assert!(lit_on_vault > 50, "{lit_on_vault} lit vault pixels");
    let dark = (0..w * h)
        .filter(|&i| on_vault[i] && bg.as_raw()[3 * i + 1] < 14)
        .count();
    assert!(
        dark < vault_pixels / 20,
        "{dark} of {vault_pixels} vault pixels dark"
    );
}

/// Under a rolling shutter each row sees the projector when it is exposed: every lit
/// pixel lies on its own row's planes, and on a fast sweep many rows far from the
/// middle miss the middle row's planes (those of `truth.json`) by more than a pixel.
#[test]
fn a_rolling_shutter_exposes_each_row_at_its_own_time() {
    let mut spec = stripe_scene("").with_resolution(160, 120);
    spec.camera.readout_frames = 1.0;
    let sim = Simulator::new(&spec, &quiet()).expect("sim");
    let cam = sim.camera().clone();
    let (w, h) = (cam.width as usize, cam.height as usize);
    let mut lit = vec![0u8; w * h];
    let mut img = RgbImage::new(1, 1);
    let index = 4;
    let truth = sim.render_frame_into(index, &mut img, Some(&mut lit));
    let middle = sim.pose(index);
    assert_eq!(V3::from(truth.planes[0]), middle.plane(0));
    let near_curve = |planes: [V3; 2], x: usize, y: usize| {
        (0..2).any(|k| {
            let s = |dx: f64, dy: f64| {
                signed(sim.scene(), &cam, &planes[k], x as f64 + dx, y as f64 + dy).map(|s| s.0)
            };
            let c = s(0.0, 0.0).unwrap_or(f64::NAN);
            [(0.75, 0.0), (-0.75, 0.0), (0.0, 0.75), (0.0, -0.75)]
                .iter()
                .any(|&(dx, dy)| s(dx, dy).is_some_and(|o| o.signum() != c.signum()))
        })
    };
    let (mut n, mut off_middle) = (0, 0);
    for y in 1..h - 1 {
        let row = sim.row_pose(index, y as u32);
        for x in 1..w - 1 {
            if lit[y * w + x] == 0 {
                continue;
            }
            n += 1;
            assert!(
                near_curve([row.plane(0), row.plane(1)], x, y),
                "lit pixel ({x}, {y}) is far from its row's curves"
            );
            let edge_row = y < h / 4 || y >= 3 * h / 4;
            off_middle +=
                usize::from(edge_row && !near_curve([middle.plane(0), middle.plane(1)], x, y));
        }
    }
    assert!(n > 50, "{n} lit pixels");
    assert!(
        off_middle * 10 > n,
        "{off_middle} of {n} lit pixels off the middle row's curves"
    );
    // A global shutter: every row sees the frame's pose.
    spec.camera.readout_frames = 0.0;
    let global = Simulator::new(&spec, &quiet()).expect("sim");
    assert_eq!(
        global.row_pose(index, 0),
        global.row_pose(index, h as u32 - 1)
    );
}

/// The simulator's JPEG frames carry the chroma sampling asked for, in their header
/// (which the extractor reads) and in their pixels (which the decoder rebuilds).
#[test]
fn jpeg_frames_are_sampled_as_asked() {
    use crate::capture::chroma::{of_jpeg, Rebuild};
    let img = RgbImage::from_fn(64, 48, |x, y| {
        let v = if (x / 3 + y / 5) % 2 == 0 { 200 } else { 40 };
        image::Rgb([v, 255 - v, 90])
    });
    for (chroma, want) in [
        (JpegChroma::Full, [Rebuild::Full; 2]),
        (JpegChroma::Half422, [Rebuild::Interpolated, Rebuild::Full]),
        (JpegChroma::Half420, [Rebuild::Interpolated; 2]),
    ] {
        let bytes = encode_jpeg(&img, 95, chroma).expect("encode");
        assert_eq!(of_jpeg(&bytes), Some(want), "{chroma:?}");
        let decoded = image::load_from_memory(&bytes).expect("decode").to_rgb8();
        assert_eq!(decoded.dimensions(), img.dimensions());
    }
    assert_eq!(JpegChroma::parse("4:2:0"), Some(JpegChroma::Half420));
    assert_eq!(JpegChroma::parse("411"), None);
}

/// A frame drawn as an interpolated 4:2:0 JPEG is what a camera's 4:2:0 JPEG of the
/// same light decodes to: one real round trip, the chroma quantised per 16×16 pixels
/// (not a 4:4:4 JPEG whose chroma is subsampled afterwards).
#[test]
fn an_interpolated_420_jpeg_frame_is_one_real_round_trip() {
    let spec = stripe_scene("");
    let clean = Simulator::new(&spec, &quiet()).expect("sim");
    let mut params = quiet();
    params.jpeg_quality = Some(88);
    params.realism.chroma_420 = true;
    params.realism.chroma_interpolated = true;
    let camera_like = Simulator::new(&spec, &params).expect("sim");
    let (light, _) = clean.render_frame(3);
    let bytes = encode_jpeg(&light, 88, JpegChroma::Half420).expect("encode");
    let want = image::load_from_memory(&bytes).expect("decode").to_rgb8();
    let (got, _) = camera_like.render_frame(3);
    assert!(got == want, "not the camera's 4:2:0 JPEG of the frame");
}
