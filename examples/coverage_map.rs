//! Where does a cloud miss the lit area of a simulation? Projects the cloud's points
//! into the camera and writes `coverage_map.png`: covered lit pixels green, missed
//! visible ones magenta, missed faint ones dark blue, points outside the lit area grey.
//! `MIN_CONTRAST=C` shows only the misses where the stripe's peak contrast reached C.
//! The cloud must be at the truth's scale: pass the scale `compare --truth` printed.
//!
//! `CROP=x,y,w,h` also writes that part, twice the size, to `coverage_crop.png`.
//!
//! cargo run --release --example coverage_map -- cloud.ply SIMDIR SCALE

use image::{Rgb, RgbImage};
use nalgebra::Vector3;
use std::path::Path;

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let cloud = crossline::ply::read_ply(Path::new(&args[0]))?;
    let sim = crossline::simulate::load_sim_dir(Path::new(&args[1]))?;
    let cam = &sim.camera;
    let (w, h) = (cam.width as usize, cam.height as usize);
    let mut near = vec![false; w * h];
    for p in &cloud.points {
        let v = Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64);
        let Some([u, vv]) = cam.pixel_from_camera(&v) else {
            continue;
        };
        let (cu, cv) = (u.round() as i64, vv.round() as i64);
        for y in cv - 2..=cv + 2 {
            for x in cu - 2..=cu + 2 {
                if x >= 0 && y >= 0 && (x as usize) < w && (y as usize) < h {
                    let (dx, dy) = (x as f64 - u, y as f64 - vv);
                    if dx * dx + dy * dy <= 4.0 {
                        near[y as usize * w + x as usize] = true;
                    }
                }
            }
        }
    }
    // MIN_CONTRAST=C: only misses where the stripe's peak contrast reached C are magenta.
    let contrast = image::open(Path::new(&args[1]).join("lit.png"))?.to_luma8();
    let min_contrast: u8 = std::env::var("MIN_CONTRAST")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(0);
    let img = RgbImage::from_fn(cam.width, cam.height, |x, y| {
        let i = y as usize * w + x as usize;
        let shown = sim.visible[i] && contrast.as_raw()[i] >= min_contrast;
        Rgb(match (sim.lit[i], shown, near[i]) {
            (true, _, true) => [0, 200, 0],
            (true, true, false) => [255, 0, 255],
            (true, false, false) => [50, 50, 140],
            (false, _, true) => [90, 90, 90],
            _ => [0, 0, 0],
        })
    });
    img.save("coverage_map.png")?;
    // CROP=x,y,w,h: that part of the map, twice the size, in coverage_crop.png.
    if let Some(r) = std::env::var("CROP").ok().map(|s| {
        s.split(',')
            .filter_map(|v| v.parse::<u32>().ok())
            .collect::<Vec<_>>()
    }) {
        let crop = image::imageops::crop_imm(&img, r[0], r[1], r[2], r[3]).to_image();
        image::imageops::resize(&crop, 2 * r[2], 2 * r[3], image::imageops::Nearest)
            .save("coverage_crop.png")?;
    }
    let vis = sim.visible.iter().filter(|v| **v).count();
    let cov = (0..w * h).filter(|&i| sim.visible[i] && near[i]).count();
    println!(
        "visible {vis}, covered {:.1} %",
        100.0 * cov as f64 / vis as f64
    );
    // Where the misses lie by the stripe's peak contrast (lit.png): visible pixels
    // per contrast band, and the share of them covered.
    println!("peak contrast | visible | covered");
    for (lo, hi) in [
        (0, 15),
        (15, 20),
        (20, 25),
        (25, 30),
        (30, 40),
        (40, 60),
        (60, 256),
    ] {
        let band: Vec<usize> = (0..w * h)
            .filter(|&i| {
                let c = contrast.as_raw()[i] as u32;
                sim.visible[i] && c >= lo && c < hi
            })
            .collect();
        let covered = band.iter().filter(|&&i| near[i]).count();
        println!(
            "{lo:>4}..{hi:<4} | {:>7} | {:.1} %",
            band.len(),
            100.0 * covered as f64 / band.len().max(1) as f64
        );
    }
    Ok(())
}
