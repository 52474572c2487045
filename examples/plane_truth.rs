//! Which planes of a cloud are wrong, and did they know it? For every plane (one laser of
//! one frame) of a `reconstruct` cloud of a `crossline simulate` folder: its points, the
//! median signed relative depth error of its points against the truth (after the
//! cloud's best global scale), the median `depth_sigma` its points carry, and the error
//! in units of that deviation. Prints the planes over `LIMIT` (default 2 %) and the
//! `TOP` (default 15) planes of largest error per deviation, then the frames' runs.
//!
//! cargo run --release --example plane_truth -- cloud.ply SIMDIR

use std::collections::BTreeMap;
use std::path::Path;

use crossline::compare::GroundTruth;
use nalgebra::Vector3;

fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let cloud = crossline::ply::read_ply(Path::new(&args[0]))?;
    let sim = crossline::simulate::load_sim_dir(Path::new(&args[1]))?;
    let limit: f64 = std::env::var("LIMIT").map_or(Ok(0.02), |v| v.parse())?;
    let top: usize = std::env::var("TOP").map_or(Ok(15), |v| v.parse())?;
    let (Some(frames), Some(lasers)) = (&cloud.frames, &cloud.lasers) else {
        anyhow::bail!("the cloud has no frame and laser per point");
    };
    let sigmas = cloud.depth_sigmas.clone().unwrap_or_default();
    let ratios: Vec<f64> = cloud
        .points
        .iter()
        .map(|p| {
            let v = Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64);
            match sim.true_depth(&(v / v.z)) {
                Some(z) => z / v.z,
                None => f64::NAN,
            }
        })
        .collect();
    let scale = median(ratios.iter().copied().filter(|r| r.is_finite()).collect());
    let mut by_plane: BTreeMap<(u32, u8), (Vec<f64>, Vec<f64>)> = BTreeMap::new();
    for (i, r) in ratios.iter().enumerate() {
        if !r.is_finite() {
            continue;
        }
        let e = scale / r - 1.0;
        let entry = by_plane.entry((frames[i], lasers[i])).or_default();
        entry.0.push(e);
        entry.1.push(sigmas.get(i).map_or(f64::NAN, |s| *s as f64));
    }
    struct Row {
        frame: u32,
        laser: u8,
        n: usize,
        err: f64,
        sigma: f64,
    }
    let rows: Vec<Row> = by_plane
        .into_iter()
        .map(|((frame, laser), (e, s))| Row {
            frame,
            laser,
            n: e.len(),
            err: median(e),
            sigma: median(s),
        })
        .collect();
    let total: usize = rows.iter().map(|r| r.n).sum();
    println!("{} planes, {total} points, scale {scale:.6}", rows.len());
    let show = |r: &Row| {
        println!(
            "  frame {:4} laser {} points {:6} error {:+8.4} % sigma {:7.4} % z {:7.2}",
            r.frame,
            r.laser,
            r.n,
            100.0 * r.err,
            100.0 * r.sigma,
            r.err.abs() / r.sigma
        );
    };
    let wrong: Vec<&Row> = rows.iter().filter(|r| r.err.abs() > limit).collect();
    let wrong_points: usize = wrong.iter().map(|r| r.n).sum();
    println!(
        "over {:.1} %: {} planes, {wrong_points} points ({:.3} %)",
        100.0 * limit,
        wrong.len(),
        100.0 * wrong_points as f64 / total.max(1) as f64
    );
    for r in &wrong {
        show(r);
    }
    let mut by_z: Vec<&Row> = rows.iter().filter(|r| r.sigma > 0.0).collect();
    by_z.sort_by(|a, b| (b.err.abs() / b.sigma).total_cmp(&(a.err.abs() / a.sigma)));
    println!("largest error per deviation:");
    for r in by_z.iter().take(top) {
        show(r);
    }
    let zs: Vec<f64> = by_z.iter().map(|r| r.err.abs() / r.sigma).collect();
    println!(
        "median z {:.2} (0.67 if honest); over 3: {}",
        median(zs.clone()),
        zs.iter().filter(|z| **z > 3.0).count()
    );
    Ok(())
}
