//! How faint a stripe does extraction find? Renders a slanted red stripe (Gaussian
//! profile of FWHM `W` px, peak `C` grey levels) over a mid-grey background with
//! Gaussian sensor noise (`NOISE`, default 2), and a green veil of `VEIL` grey levels
//! (the other sheet's glow under water), and prints for each contrast the share of the
//! stripe's length with an extracted point within 1 px, and the points found off it
//! (noise taken for stripes). `PARAMS=low,high[,min_value]` sets the thresholds.
//!
//! W=2.5 NOISE=2 VEIL=0 cargo run --release --example faint_stripe -- 6 8 10 12 15 20

use crossline::camera::Camera;
use crossline::extract::{Background, ExtractParams, Extractor};
use image::{Rgb, RgbImage};

fn main() -> anyhow::Result<()> {
    let env = |k: &str, d: f64| {
        std::env::var(k)
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(d)
    };
    let (w, h) = (640u32, 480u32);
    let fwhm = env("W", 2.5);
    let noise = env("NOISE", 2.0);
    let veil = env("VEIL", 0.0);
    let s = fwhm / 2.3548;
    let cam = Camera::with_fov(w, h, 60f64.to_radians());
    let base = RgbImage::from_pixel(w, h, Rgb([60, 70, 65]));
    // PARAMS=low,high[,min_value]: the hysteresis thresholds and activation level.
    let mut params = ExtractParams::default();
    if let Ok(p) = std::env::var("PARAMS") {
        let v: Vec<f64> = p.split(',').filter_map(|x| x.parse().ok()).collect();
        params.low_contrast = v[0] as f32;
        params.high_contrast = v[1] as f32;
        if let Some(m) = v.get(2) {
            params.min_value = *m as u8;
        }
    }
    let mut ex = Extractor::new(&params, &cam)?;
    let bg = Background::from_image(base.clone());
    // Line y = 100 + 0.3 x, from x = 40 to 600.
    let (slope, y0) = (0.3f64, 100.0f64);
    let norm = (1.0 + slope * slope).sqrt();
    let mut seed = 0x9e3779b97f4a7c15u64;
    let mut gauss = move || {
        // Box–Muller on a 64-bit LCG.
        let mut u = || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((seed >> 11) as f64 + 0.5) / (1u64 << 53) as f64
        };
        let (a, b) = (u(), u());
        (-2.0 * a.ln()).sqrt() * (2.0 * std::f64::consts::PI * b).cos()
    };
    for c in std::env::args()
        .skip(1)
        .filter_map(|a| a.parse::<f64>().ok())
    {
        let mut found = 0usize;
        let mut total = 0usize;
        let mut false_points = 0usize;
        for trial in 0..10 {
            let img = RgbImage::from_fn(w, h, |x, y| {
                let (xf, yf) = (x as f64, y as f64);
                let d = (yf - (y0 + 10.0 * trial as f64) - slope * xf) / norm;
                let on = (40.0..600.0).contains(&xf);
                let stripe = if on {
                    c * (-0.5 * d * d / (s * s)).exp()
                } else {
                    0.0
                };
                let p = base.get_pixel(x, y).0;
                let ch = |v: u8, add: f64| (v as f64 + add).round().clamp(0.0, 255.0) as u8;
                Rgb([
                    ch(p[0], stripe + noise * gauss()),
                    ch(p[1], veil + noise * gauss()),
                    ch(p[2], noise * gauss()),
                ])
            });
            let curves = ex.extract(&img, &bg);
            let mut hit = vec![false; w as usize];
            for cv in &curves {
                for p in &cv.points_px {
                    let yl = y0 + 10.0 * trial as f64 + slope * p[0] as f64;
                    if ((p[1] as f64 - yl) / norm).abs() <= 1.0 {
                        hit[p[0].round().clamp(0.0, w as f32 - 1.0) as usize] = true;
                    } else {
                        false_points += 1;
                    }
                }
            }
            total += 560;
            found += hit[40..600].iter().filter(|h| **h).count();
        }
        println!(
            "contrast {c:>5}: {:.1} % of the stripe found, {false_points} points off it",
            100.0 * found as f64 / total as f64
        );
    }
    Ok(())
}
