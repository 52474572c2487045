//! Which extracted curves lie off the scanned surface? Extracts the curves of a
//! `simulate` folder's `frames.dump` as `reconstruct` does (temporal median
//! background), triangulates every point with its frame's TRUE plane and compares its
//! depth to the scene's: a point more than 2 % off is not on the surface (the sheet's
//! glow in the water, a reflection, the other laser). Prints, for strong curves (a
//! point of strength ≥ `solve.min_curve_strength`) and faint ones, how many points are
//! off, and the worst strong curves.
//!
//! cargo run --release --example curve_truth -- target/bench-accuracy/sim-turbid-300 [config.toml]

use crossline::compare::GroundTruth;
use crossline::extract::{Background, Curve, Extractor};
use crossline::reconstruct::FrameSource;
use image::RgbImage;
use nalgebra::Vector3;
use rayon::prelude::*;
use std::path::Path;

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let dir = Path::new(args.first().map(String::as_str).unwrap_or("/tmp/sim"));
    let config = match args.get(1) {
        Some(p) => crossline::config::load(Path::new(p))?,
        None => crossline::config::Config::default(),
    };
    let sim = crossline::simulate::load_sim_dir(dir)?;
    let camera = sim.camera.clone();
    let (frames, _) = FrameSource::open(&dir.join("frames.dump"))?;
    let k = config.background.median_frames.clamp(1, frames.len());
    let images = (0..k)
        .into_par_iter()
        .map(|i| frames.decode((i * frames.len()) / k + frames.len() / (2 * k), &camera))
        .collect::<Result<Vec<_>, _>>()?;
    let refs: Vec<&RgbImage> = images.iter().collect();
    let background = Background::median_of(&refs)?;
    let per_frame: Vec<Vec<Curve>> = (0..frames.len())
        .into_par_iter()
        .map_init(
            || Extractor::new(&config.extract, &camera).expect("extractor"),
            |ex, i| ex.extract(&frames.decode(i, &camera).expect("frame"), &background),
        )
        .collect();
    let strong = config.solve.min_curve_strength;
    // (frame, laser, points, off, max strength, first point)
    let mut rows = Vec::new();
    for (f, curves) in per_frame.iter().enumerate() {
        let Some(truth) = sim.truth.frames.get(f) else {
            continue;
        };
        for c in curves {
            let v = Vector3::from(truth.planes[c.laser as usize]);
            let off = c
                .points
                .iter()
                .filter(|p| {
                    let u = Vector3::new(p[0], p[1], 1.0);
                    let z = 1.0 / v.dot(&u);
                    match sim.true_depth(&u) {
                        Some(zt) => !(z > 0.0 && ((z - zt) / zt).abs() <= 0.02),
                        None => true,
                    }
                })
                .count();
            let max = c.strength.iter().cloned().fold(0.0f32, f32::max);
            rows.push((f, c.laser, c.points.len(), off, max, c.points_px[0]));
        }
    }
    for (name, is_strong) in [("strong", true), ("faint", false)] {
        let sel: Vec<_> = rows
            .iter()
            .filter(|r| (r.4 >= strong) == is_strong)
            .collect();
        let points: usize = sel.iter().map(|r| r.2).sum();
        let off: usize = sel.iter().map(|r| r.3).sum();
        let mostly_off = sel.iter().filter(|r| 2 * r.3 > r.2).count();
        println!(
            "{name}: {} curves, {points} points, {off} off the surface ({:.2} %), {mostly_off} curves mostly off",
            sel.len(),
            100.0 * off as f64 / points.max(1) as f64
        );
    }
    rows.sort_by_key(|r| std::cmp::Reverse(r.3));
    for r in rows.iter().filter(|r| r.4 >= strong).take(15) {
        println!(
            "frame {} laser {}: {} points, {} off, max strength {:.0}, starts at ({:.0}, {:.0})",
            r.0, r.1, r.2, r.3, r.4, r.5[0], r.5[1]
        );
    }
    Ok(())
}
