//! Where does extraction miss the laser? Renders frames of a built-in scene, extracts
//! their curves, and reports per frame the share of lit pixels (stripe centre lines)
//! with an extracted point within 2 px, of all and of the visible ones (peak contrast
//! at least 5 × the noise); writes `coverage_NNNNNN.png` overlays (missed visible lit
//! pixels magenta, missed faint ones dark blue, extracted points cyan) and the rendered `frame_NNNNNN.png`.
//!
//! Environment: `MEDIAN=N` (background from N frames, as reconstruct), `TURBIDITY=T`
//! and `SEED=S` (as `simulate`), `PARAMS=low,high,min_value[,line_width]`, `FAINT=0`
//! (no faint-stripe activation),
//! `CROP=x,y,w,h` (a 3× crop of frame and overlay), `POINTS=x,y,w,h` (curve points
//! there, with strengths), `PROFILE=y,x0,x1` / `COLUMN=x,y0,y1` (frame − background
//! along a row / column, beside lit.png).
//!
//! The scene is a built-in's name or a scene TOML file.
//!
//! cargo run --release --example frame_coverage -- room 0 17 42
//! CROP=850,780,400,150 cargo run --release --example frame_coverage -- pipes 80

use crossline::extract::{Background, ExtractParams, Extractor};
use crossline::simulate::{builtin_scene, SimParams, Simulator};
use image::{Rgb, RgbImage};

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let scene = args.first().map(String::as_str).unwrap_or("room");
    // A built-in scene's name, or a scene TOML file.
    let mut spec = match builtin_scene(scene) {
        Some(spec) => spec,
        None => crossline::simulate::load_scene_file(std::path::Path::new(scene))?,
    };
    // TURBIDITY=T, SEED=S: as `simulate --turbidity T --seed S`.
    if let Some(t) = std::env::var("TURBIDITY").ok().and_then(|t| t.parse().ok()) {
        spec.water.turbidity = t;
        spec.medium = crossline::simulate::Medium::Water;
    }
    let mut sim_params = SimParams::default();
    if let Some(seed) = std::env::var("SEED").ok().and_then(|t| t.parse().ok()) {
        sim_params.seed = seed;
    }
    let sim = Simulator::new(&spec, &sim_params)?;
    let cam = sim.camera().clone();
    let (w, h) = (cam.width as usize, cam.height as usize);
    // MEDIAN=N: the temporal median of N frames spread over 200, as reconstruct does.
    let background = match std::env::var("MEDIAN")
        .ok()
        .and_then(|n| n.parse::<usize>().ok())
    {
        Some(n) => {
            let frames: Vec<RgbImage> = (0..n)
                .map(|i| sim.render_frame(i * 200 / n + 200 / (2 * n)).0)
                .collect();
            let refs: Vec<&RgbImage> = frames.iter().collect();
            Background::median_of(&refs)?
        }
        None => Background::from_image(sim.background()),
    };
    // PARAMS=low,high,min_value[,line_width]: other extraction thresholds.
    // FAINT=0: without the faint-stripe activation.
    let mut params = ExtractParams {
        faint_activation: std::env::var("FAINT").map_or(true, |v| v != "0"),
        ..ExtractParams::default()
    };
    if let Ok(p) = std::env::var("PARAMS") {
        let v: Vec<f64> = p.split(',').filter_map(|x| x.parse().ok()).collect();
        params.low_contrast = v[0] as f32;
        params.high_contrast = v[1] as f32;
        params.min_value = v[2] as u8;
        params.line_width_px = v.get(3).copied();
    }
    let mut extractor = Extractor::new(&params, &cam)?;
    for index in args.iter().skip(1).filter_map(|a| a.parse::<usize>().ok()) {
        let mut img = RgbImage::new(cam.width, cam.height);
        let mut lit = vec![0u8; w * h];
        sim.render_frame_into(index, &mut img, Some(&mut lit));
        let curves = extractor.extract(&img, &background);
        let mut near = vec![false; w * h];
        for c in &curves {
            for p in &c.points_px {
                let (x0, y0) = (p[0].round() as i64, p[1].round() as i64);
                for dy in -2..=2 {
                    for dx in -2..=2 {
                        let (x, y) = (x0 + dx, y0 + dy);
                        if x >= 0 && y >= 0 && (x as usize) < w && (y as usize) < h {
                            near[y as usize * w + x as usize] = true;
                        }
                    }
                }
            }
        }
        // POINTS=x,y,w,h: print the curve points inside that rectangle.
        if let Some(r) = std::env::var("POINTS").ok().map(|s| {
            s.split(',')
                .filter_map(|v| v.parse::<f32>().ok())
                .collect::<Vec<_>>()
        }) {
            for (ci, c) in curves.iter().enumerate() {
                for (p, s) in c.points_px.iter().zip(&c.strength) {
                    if p[0] >= r[0] && p[1] >= r[1] && p[0] < r[0] + r[2] && p[1] < r[1] + r[3] {
                        println!(
                            "curve {ci} laser {} ({:.1}, {:.1}) strength {s:.1}",
                            c.laser, p[0], p[1]
                        );
                    }
                }
            }
        }
        // PROFILE=y,x0,x1: the frame minus the background along row y, and lit.png.
        if let Some(r) = std::env::var("PROFILE").ok().map(|s| {
            s.split(',')
                .filter_map(|v| v.parse::<u32>().ok())
                .collect::<Vec<_>>()
        }) {
            for x in r[1]..r[2] {
                let f = img.get_pixel(x, r[0]).0;
                let b = background.image().get_pixel(x, r[0]).0;
                let d: Vec<i32> = (0..3).map(|c| f[c] as i32 - b[c] as i32).collect();
                println!(
                    "x {x}: diff {d:?} lit {}",
                    lit[r[0] as usize * w + x as usize]
                );
            }
        }
        // COLUMN=x,y0,y1: the same down column x.
        if let Some(r) = std::env::var("COLUMN").ok().map(|s| {
            s.split(',')
                .filter_map(|v| v.parse::<u32>().ok())
                .collect::<Vec<_>>()
        }) {
            for y in r[1]..r[2] {
                let f = img.get_pixel(r[0], y).0;
                let b = background.image().get_pixel(r[0], y).0;
                let d: Vec<i32> = (0..3).map(|c| f[c] as i32 - b[c] as i32).collect();
                println!(
                    "y {y}: diff {d:?} lit {}",
                    lit[y as usize * w + r[0] as usize]
                );
            }
        }
        let total = lit.iter().filter(|&&l| l > 0).count();
        let covered = (0..w * h).filter(|&i| lit[i] > 0 && near[i]).count();
        // Visible: the stripe's peak contrast reaches 5 × the sensor noise (as compare).
        let floor = (5.0 * SimParams::default().noise_sigma).max(1.0);
        let seen = |i: usize| lit[i] as f64 >= floor;
        let visible = (0..w * h).filter(|&i| seen(i)).count();
        let covered_visible = (0..w * h).filter(|&i| seen(i) && near[i]).count();
        println!(
            "frame {index}: {} curves, {} points, {:?}, lit {total}, covered {:.1} %, visible {visible}, covered {:.1} %",
            curves.len(),
            curves.iter().map(|c| c.points_px.len()).sum::<usize>(),
            extractor.stats(),
            100.0 * covered as f64 / total.max(1) as f64,
            100.0 * covered_visible as f64 / visible.max(1) as f64
        );
        let mut out = RgbImage::from_fn(cam.width, cam.height, |x, y| {
            let p = img.get_pixel(x, y).0;
            Rgb(p.map(|c| c / 3))
        });
        for i in 0..w * h {
            if lit[i] > 0 && !near[i] {
                // Missed and visible: magenta; missed and too faint to see: dark blue.
                let c = if seen(i) {
                    [255, 0, 255]
                } else {
                    [60, 60, 160]
                };
                out.put_pixel((i % w) as u32, (i / w) as u32, Rgb(c));
            }
        }
        for c in &curves {
            for p in &c.points_px {
                let (x, y) = (p[0].round() as u32, p[1].round() as u32);
                if x < cam.width && y < cam.height {
                    out.put_pixel(x, y, Rgb([0, 255, 255]));
                }
            }
        }
        // CROP=x,y,w,h: also a 3× enlarged crop, the frame brightened 4× above the overlay.
        if let Some(r) = std::env::var("CROP").ok().map(|s| {
            s.split(',')
                .filter_map(|v| v.parse::<u32>().ok())
                .collect::<Vec<_>>()
        }) {
            if let [x0, y0, cw, ch] = r[..] {
                let k = 3;
                let crop = RgbImage::from_fn(cw * k, ch * k * 2, |x, y| {
                    let (sx, sy) = (x0 + x / k, y0 + (y / k) % ch);
                    if sx >= cam.width || sy >= cam.height {
                        return Rgb([0, 0, 0]);
                    }
                    if y / k < ch {
                        Rgb(img.get_pixel(sx, sy).0.map(|c| c.saturating_mul(4)))
                    } else {
                        *out.get_pixel(sx, sy)
                    }
                });
                crop.save(format!("crop_{index:06}.png"))?;
            }
        }
        out.save(format!("coverage_{index:06}.png"))?;
        img.save(format!("frame_{index:06}.png"))?;
    }
    Ok(())
}
