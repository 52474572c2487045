//! Which extracted curves lie off the scanned surface? Extracts the curves of a
//! `simulate` folder's `frames.dump` as `reconstruct` does (temporal median
//! background), triangulates every point with its frame's TRUE plane and compares its
//! depth to the scene's: a point more than 2 % off is not on the surface (the sheet's
//! glow in the water, a reflection, the other laser). Prints, for strong curves (a
//! point of strength ≥ `solve.min_curve_strength`) and faint ones, how many points are
//! off, and the worst strong curves.
//!
//! It also prints how much of the visible lit area extraction alone reaches, by the
//! stripe's peak contrast: pixels within 2 px of an extracted point, of one on the
//! surface by its true plane, and (`CLOUD=cloud.ply`, reconstruct's output) of one
//! whose frame and laser have points in that cloud, so that a cloud's coverage loss
//! splits into extraction, off-surface curves, unsolved planes and the rest; and the
//! signed depth error of the strong points on their true planes, per laser.
//!
//! With `MISSING=1` (and `CLOUD`), it also lists the planes that have points on the
//! surface but none in the cloud, most points first.
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
    let strong_min = strong;
    // Relative depth error of a point on plane `v` against the scene; `None` where
    // the plane puts it behind the camera or its ray meets no surface.
    let error_on = |v: &Vector3<f64>, p: &[f64; 2]| -> Option<f64> {
        let u = Vector3::new(p[0], p[1], 1.0);
        let z = 1.0 / v.dot(&u);
        let zt = sim.true_depth(&u)?;
        (z > 0.0).then(|| (z - zt) / zt)
    };
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
                .filter(|p| !error_on(&v, p).is_some_and(|r| r.abs() <= 0.02))
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
    // Where extraction alone reaches: visible lit pixels within 2 px of an extracted
    // point (on the surface by its true plane, and all), per peak contrast band.
    let (w, h) = (camera.width as usize, camera.height as usize);
    // CLOUD=path: a third column, extracted points of planes the cloud has points of.
    let solved: Option<std::collections::HashSet<(u32, u8)>> = match std::env::var("CLOUD") {
        Ok(p) => {
            let cloud = crossline::ply::read_ply(Path::new(&p))?;
            let (f, l) = (
                cloud.frames.unwrap_or_default(),
                cloud.lasers.unwrap_or_default(),
            );
            Some(f.into_iter().zip(l).collect())
        }
        Err(_) => None,
    };
    if let (Some(sv), Ok(_)) = (solved.as_ref(), std::env::var("MISSING")) {
        // (points on the surface, frame, laser, strong curves, partner in the cloud)
        let mut miss: Vec<(usize, usize, u8, usize, bool)> = Vec::new();
        for (f, curves) in per_frame.iter().enumerate() {
            let Some(truth) = sim.truth.frames.get(f) else {
                continue;
            };
            for l in 0..2u8 {
                if sv.contains(&(f as u32, l)) {
                    continue;
                }
                let v = Vector3::from(truth.planes[l as usize]);
                let (mut on, mut strong) = (0, 0);
                for c in curves.iter().filter(|c| c.laser == l) {
                    on += c
                        .points
                        .iter()
                        .filter(|p| error_on(&v, p).is_some_and(|r| r.abs() <= 0.02))
                        .count();
                    strong += usize::from(
                        c.strength.iter().cloned().fold(0.0f32, f32::max) >= strong_min,
                    );
                }
                if on > 0 {
                    miss.push((on, f, l, strong, sv.contains(&(f as u32, 1 - l))));
                }
            }
        }
        miss.sort_unstable_by(|a, b| b.cmp(a));
        let total: usize = miss.iter().map(|m| m.0).sum();
        println!(
            "planes missing from the cloud with points on the surface: {} ({} points)",
            miss.len(),
            total
        );
        for m in miss.iter().take(40) {
            println!(
                "  frame {} laser {}: {} points on the surface, {} strong curves, partner solved {}",
                m.1, m.2, m.0, m.3, m.4
            );
        }
    }
    let mut near = [vec![false; w * h], vec![false; w * h], vec![false; w * h]];
    for (f, curves) in per_frame.iter().enumerate() {
        let Some(truth) = sim.truth.frames.get(f) else {
            continue;
        };
        for c in curves {
            let v = Vector3::from(truth.planes[c.laser as usize]);
            let has_plane = solved
                .as_ref()
                .is_none_or(|s| s.contains(&(f as u32, c.laser)));
            for (p, px) in c.points.iter().zip(&c.points_px) {
                let on = error_on(&v, p).is_some_and(|r| r.abs() <= 0.02);
                let (cu, cv) = (px[0].round() as i64, px[1].round() as i64);
                for y in (cv - 2).max(0)..=(cv + 2).min(h as i64 - 1) {
                    for x in (cu - 2).max(0)..=(cu + 2).min(w as i64 - 1) {
                        let (dx, dy) = (x as f32 - px[0], y as f32 - px[1]);
                        if dx * dx + dy * dy <= 4.0 {
                            let i = y as usize * w + x as usize;
                            near[0][i] = true;
                            near[1][i] |= on;
                            near[2][i] |= on && has_plane;
                        }
                    }
                }
            }
        }
    }
    let contrast = image::open(dir.join("lit.png"))?.to_luma8();
    println!("peak contrast | visible | extracted | on the surface | and a plane in CLOUD");
    for (lo, hi) in [
        (0, 15),
        (15, 20),
        (20, 25),
        (25, 30),
        (30, 40),
        (40, 60),
        (60, 256),
        (0, 256),
    ] {
        let band: Vec<usize> = (0..w * h)
            .filter(|&i| {
                let c = contrast.as_raw()[i] as u32;
                sim.visible[i] && c >= lo && c < hi
            })
            .collect();
        let share = |m: &[bool]| {
            100.0 * band.iter().filter(|&&i| m[i]).count() as f64 / band.len().max(1) as f64
        };
        println!(
            "{lo:>4}..{hi:<4} | {:>7} | {:.1} % | {:.1} % | {:.1} %",
            band.len(),
            share(&near[0]),
            share(&near[1]),
            share(&near[2])
        );
    }
    {
        // Signed relative depth error on the true planes of the strong points on the
        // surface (within 2 %), per laser: a systematic error of the stripe centres
        // shows as a median away from zero (under water, towards the camera).
        for laser in 0..2u8 {
            let mut e = Vec::new();
            for (f, curves) in per_frame.iter().enumerate() {
                let Some(truth) = sim.truth.frames.get(f) else {
                    continue;
                };
                for c in curves.iter().filter(|c| c.laser == laser) {
                    let v = Vector3::from(truth.planes[laser as usize]);
                    for (p, s) in c.points.iter().zip(&c.strength) {
                        if *s < strong {
                            continue;
                        }
                        if let Some(r) = error_on(&v, p).filter(|r| r.abs() < 0.02) {
                            e.push(r);
                        }
                    }
                }
            }
            e.sort_by(f64::total_cmp);
            let n = e.len();
            if n > 0 {
                println!("laser {laser}: {n} points, signed error p10 {:.4} % median {:.4} % p90 {:.4} %", 100.0*e[n/10], 100.0*e[n/2], 100.0*e[9*n/10]);
            }
        }
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
