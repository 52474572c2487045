//! Where does a cloud miss the lit area of a simulation? Projects the cloud's points
//! into the camera and writes `coverage_map.png`: covered lit pixels green, missed
//! visible ones magenta, missed faint ones dark blue, points outside the lit area grey.
//! The cloud must be at the truth's scale: pass the scale `compare --truth` printed.
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
    let img = RgbImage::from_fn(cam.width, cam.height, |x, y| {
        let i = y as usize * w + x as usize;
        Rgb(match (sim.lit[i], sim.visible[i], near[i]) {
            (true, _, true) => [0, 200, 0],
            (true, true, false) => [255, 0, 255],
            (true, false, false) => [50, 50, 140],
            (false, _, true) => [90, 90, 90],
            _ => [0, 0, 0],
        })
    });
    img.save("coverage_map.png")?;
    let vis = sim.visible.iter().filter(|v| **v).count();
    let cov = (0..w * h).filter(|&i| sim.visible[i] && near[i]).count();
    println!(
        "visible {vis}, covered {:.1} %",
        100.0 * cov as f64 / vis as f64
    );
    Ok(())
}
