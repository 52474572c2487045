//! Where does extraction miss the laser? Renders frames of a built-in scene, extracts
//! their curves, and reports per frame the share of lit pixels (stripe centre lines)
//! with an extracted point within 2 px, of all and of the visible ones (peak contrast
//! at least 5 × the noise); writes `coverage_NNNNNN.png` overlays (missed visible lit
//! pixels magenta, missed faint ones dark blue, extracted points cyan) and the rendered `frame_NNNNNN.png`.
//!
//! cargo run --release --example frame_coverage -- room 0 17 42

use crossline::extract::{Background, ExtractParams, Extractor};
use crossline::simulate::{builtin_scene, SimParams, Simulator};
use image::{Rgb, RgbImage};

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let scene = args.first().map(String::as_str).unwrap_or("room");
    let spec = builtin_scene(scene).ok_or_else(|| anyhow::anyhow!("no scene {scene}"))?;
    let sim = Simulator::new(&spec, &SimParams::default())?;
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
    let mut extractor = Extractor::new(&ExtractParams::default(), &cam)?;
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
        let total = lit.iter().filter(|&&l| l > 0).count();
        let covered = (0..w * h).filter(|&i| lit[i] > 0 && near[i]).count();
        // Visible: the stripe's peak contrast reaches 5 × the sensor noise (as compare).
        let floor = (5.0 * SimParams::default().noise_sigma).max(1.0);
        let seen = |i: usize| lit[i] as f64 >= floor;
        let visible = (0..w * h).filter(|&i| seen(i)).count();
        let covered_visible = (0..w * h).filter(|&i| seen(i) && near[i]).count();
        println!(
            "frame {index}: {} curves, {} points, lit {total}, covered {:.1} %, visible {visible}, covered {:.1} %",
            curves.len(),
            curves.iter().map(|c| c.points_px.len()).sum::<usize>(),
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
        out.save(format!("coverage_{index:06}.png"))?;
        img.save(format!("frame_{index:06}.png"))?;
    }
    Ok(())
}
