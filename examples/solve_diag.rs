//! How well does self-calibration solve a simulated sequence? Extracts the curves of a
//! `simulate` folder as `reconstruct` does, caches the crossings, solves, and compares
//! every plane to `truth.json`: depth error at its crossings after the best global
//! scale, and for unsolved planes why (crossings with solved planes, their bend, the
//! partner).
//!
//! cargo run --release --example solve_diag -- /tmp/room200 config.toml

#![allow(clippy::needless_range_loop)]
use crossline::extract::{Background, Extractor};
use crossline::intersect::{Crossing, SegmentIndex};
use crossline::solve::{self, subset::bend, Problem};
use nalgebra::Vector3;
use rayon::prelude::*;
use std::io::Write;
use std::path::Path;

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let dir = Path::new(args.first().map(String::as_str).unwrap_or("/tmp/room200"));
    let config = match args.get(1) {
        Some(p) => crossline::config::load(Path::new(p))?,
        None => crossline::config::Config::default(),
    };
    let sim = crossline::simulate::load_sim_dir(dir)?;
    let cache = dir
        .file_name()
        .map(|n| format!("/tmp/solve-diag-{}.txt", n.to_string_lossy()))
        .unwrap_or_else(|| "/tmp/solve-diag.txt".into());
    // Cache: one line per unknown "frame laser partner", then "a b x y s" per crossing.
    let (unknowns, partner, crossings) = match std::fs::read_to_string(&cache) {
        Ok(text) => parse_cache(&text)?,
        Err(_) => {
            let r = extract(dir, &sim.camera, &config)?;
            let mut f = std::fs::File::create(&cache)?;
            writeln!(f, "{}", r.0.len())?;
            for (i, (fr, l)) in r.0.iter().enumerate() {
                writeln!(f, "{fr} {l} {}", r.1[i].map_or(-1, |p| p as i64))?;
            }
            for c in &r.2 {
                writeln!(
                    f,
                    "{} {} {:e} {:e} {:e}",
                    c.a, c.b, c.u[0], c.u[1], c.sin_angle
                )?;
            }
            r
        }
    };
    let truth: Vec<Vector3<f64>> = unknowns
        .iter()
        .map(|&(fr, l)| Vector3::from(sim.truth.frames[fr as usize].planes[l as usize]))
        .collect();
    let problem = Problem {
        focal_px: 1000.0,
        num_curves: unknowns.len(),
        crossings: &crossings,
        partner: &partner,
    };
    let t = std::time::Instant::now();
    let sol = solve::solve(&problem, &config.solve)?;
    let secs = t.elapsed().as_secs_f64();
    // Per crossing ratio of true to solved inverse depth, for each solved side.
    let ratio = |c: usize, k: &Crossing| {
        sol.planes[c].map(|v| {
            let u = Vector3::new(k.u[0], k.u[1], 1.0);
            let us = Vector3::new(k.u[0] / sol.focal_scale, k.u[1] / sol.focal_scale, 1.0);
            truth[c].dot(&u) / v.dot(&us)
        })
    };
    let mut all = Vec::new();
    for k in &crossings {
        for c in [k.a as usize, k.b as usize] {
            if let Some(r) = ratio(c, k) {
                all.push(r);
            }
        }
    }
    all.sort_by(f64::total_cmp);
    let s = all.get(all.len() / 2).copied().unwrap_or(1.0);
    let n = unknowns.len();
    let mut err = vec![f64::NAN; n];
    let mut by_plane: Vec<Vec<f64>> = vec![Vec::new(); n];
    for k in &crossings {
        for c in [k.a as usize, k.b as usize] {
            if let Some(r) = ratio(c, k) {
                by_plane[c].push((r / s - 1.0).abs());
            }
        }
    }
    for c in 0..n {
        let mut e = std::mem::take(&mut by_plane[c]);
        if !e.is_empty() {
            e.sort_by(f64::total_cmp);
            err[c] = e[e.len() / 2];
        }
    }
    let global: std::collections::HashSet<u32> = sol.global.iter().copied().collect();
    let med = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
    };
    let eg: Vec<f64> = (0..n)
        .filter(|c| global.contains(&(*c as u32)))
        .map(|c| err[c])
        .collect();
    let ee: Vec<f64> = (0..n)
        .filter(|c| !global.contains(&(*c as u32)) && sol.planes[*c].is_some())
        .map(|c| err[c])
        .collect();
    let bad = (0..n).filter(|&c| err[c] > 0.01).count();
    println!(
        "unknowns {n}, crossings {}, solved {} (global {}), solve {secs:.2} s",
        crossings.len(),
        sol.planes.iter().flatten().count(),
        sol.global.len()
    );
    println!(
        "median per-plane depth error: global {:.2e}, extended {:.2e}; planes > 1 %: {bad}",
        med(eg.clone()),
        med(ee.clone())
    );
    let mut worst: Vec<(f64, usize)> = (0..n)
        .filter(|&c| err[c].is_finite())
        .map(|c| (err[c], c))
        .collect();
    worst.sort_by(|a, b| b.0.total_cmp(&a.0));
    for (e, c) in worst.iter().take(5) {
        let pts: Vec<[f64; 2]> = crossings
            .iter()
            .filter(|k| {
                (k.a as usize == *c && sol.planes[k.b as usize].is_some())
                    || (k.b as usize == *c && sol.planes[k.a as usize].is_some())
            })
            .filter(|k| k.sin_angle >= config.solve.min_sin_angle)
            .map(|k| k.u)
            .collect();
        let rej = crossings
            .iter()
            .enumerate()
            .filter(|(i, k)| {
                (k.a as usize == *c || k.b as usize == *c) && sol.rejected_crossings.contains(i)
            })
            .count();
        println!(
            "  worst plane {c}: {e:.2e} global {} crossings {} rejected {rej} bend {:.1e} partner {:?} err {:.1e}",
            global.contains(&(*c as u32)),
            pts.len(),
            bend(pts.iter().copied()),
            partner[*c],
            partner[*c].map_or(f64::NAN, |p| err[p as usize])
        );
    }
    if let Some(c) = std::env::var("PLANE")
        .ok()
        .and_then(|p| p.parse::<usize>().ok())
    {
        for (i, k) in crossings.iter().enumerate() {
            let o = if k.a as usize == c {
                k.b as usize
            } else if k.b as usize == c {
                k.a as usize
            } else {
                continue;
            };
            let u = Vector3::new(k.u[0], k.u[1], 1.0);
            println!(
                "  x {i} u {:.4} {:.4} other {o} true {:.4} other-solved {:?} mine {:?} rej {} sin {:.2}",
                k.u[0], k.u[1],
                1.0 / truth[c].dot(&u),
                sol.planes[o].map(|v| s / v.dot(&u)),
                sol.planes[c].map(|v| s / v.dot(&u)),
                sol.rejected_crossings.contains(&i), k.sin_angle
            );
        }
    }
    if args.iter().any(|a| a == "-f") {
        for c in 0..n {
            if sol.planes[c].is_none() || global.contains(&(c as u32)) {
                continue;
            }
            let (mut tot, mut rej) = (0, 0);
            for (i, k) in crossings.iter().enumerate() {
                let o = if k.a as usize == c {
                    k.b
                } else if k.b as usize == c {
                    k.a
                } else {
                    continue;
                };
                if sol.planes[o as usize].is_some() && k.sin_angle >= config.solve.min_sin_angle {
                    tot += 1;
                    rej += usize::from(sol.rejected_crossings.contains(&i));
                }
            }
            println!("F {c} {:.3} {:.2e}", rej as f64 / tot.max(1) as f64, err[c]);
        }
    }
    // Why the others failed.
    let mut reasons = std::collections::BTreeMap::<String, usize>::new();
    for c in 0..n {
        if sol.planes[c].is_some() {
            continue;
        }
        let pts: Vec<[f64; 2]> = crossings
            .iter()
            .filter(|k| {
                (k.a as usize == c && sol.planes[k.b as usize].is_some())
                    || (k.b as usize == c && sol.planes[k.a as usize].is_some())
            })
            .filter(|k| k.sin_angle >= config.solve.min_sin_angle)
            .map(|k| k.u)
            .collect();
        let total = crossings
            .iter()
            .filter(|k| k.a as usize == c || k.b as usize == c)
            .count();
        let p = partner[c].is_some_and(|p| sol.planes[p as usize].is_some());
        let b = bend(pts.iter().copied());
        let why = format!(
            "solved-crossings {:>3} bend {} partner {}",
            match pts.len() {
                0 => "0".to_string(),
                1 => "1".to_string(),
                2 => "2".to_string(),
                3..=5 => "3-5".to_string(),
                _ => "6+".to_string(),
            },
            if b >= (config.solve.min_curve_bend_px / sim.camera.fx) {
                "ok"
            } else {
                "low"
            },
            p
        );
        if args.iter().any(|a| a == "-v") {
            println!(
                "  unsolved {c}: {} crossings ({total} all), bend {b:.2e}, partner {p}",
                pts.len()
            );
        }
        if p && args.iter().any(|a| a == "-p") {
            let ctx = solve::extend::FitContext {
                focal_scale: sol.focal_scale,
                sigma_img: sol.sigma_img,
                sigma_ortho: sol.orthogonality_rms_deg.to_radians(),
                outlier_k: config.solve.outlier_mad_k,
                min_crossings: 3,
                min_bend: (config.solve.min_curve_bend_px / sim.camera.fx),
                min_sample_spread: 4.0 * sol.sigma_img,
                max_depth_sigma: f64::INFINITY,
                min_sin_angle: config.solve.min_sin_angle,
                parallel: false,
            };
            let known: Vec<(usize, Vector3<f64>)> = crossings
                .iter()
                .enumerate()
                .filter(|(_, k)| k.sin_angle >= config.solve.min_sin_angle)
                .filter_map(|(i, k)| {
                    let o = if k.a as usize == c {
                        k.b
                    } else if k.b as usize == c {
                        k.a
                    } else {
                        return None;
                    };
                    sol.planes[o as usize].map(|v| (i, v))
                })
                .collect();
            let vp = partner[c].and_then(|p| sol.planes[p as usize]);
            let fit = solve::extend::fit_plane(&crossings, &known, vp, &ctx, None);
            println!(
                "  partner-solved {c}: fit {:?}",
                fit.map(|f| (f.inliers, f.outliers.len()))
            );
        }
        *reasons.entry(why).or_default() += 1;
    }
    for (why, count) in reasons {
        println!("unsolved {count:>4}: {why}");
    }
    Ok(())
}

type Extracted = (Vec<(u32, u8)>, Vec<Option<u32>>, Vec<Crossing>);

fn parse_cache(text: &str) -> anyhow::Result<Extracted> {
    let mut lines = text.lines();
    let n: usize = lines.next().unwrap_or("0").trim().parse()?;
    let mut unknowns = Vec::new();
    let mut partner = Vec::new();
    for _ in 0..n {
        let f: Vec<i64> = lines
            .next()
            .unwrap_or("")
            .split_whitespace()
            .map(str::parse)
            .collect::<Result<_, _>>()?;
        unknowns.push((f[0] as u32, f[1] as u8));
        partner.push((f[2] >= 0).then_some(f[2] as u32));
    }
    let mut crossings = Vec::new();
    for l in lines {
        let f: Vec<&str> = l.split_whitespace().collect();
        crossings.push(Crossing {
            a: f[0].parse()?,
            b: f[1].parse()?,
            u: [f[2].parse()?, f[3].parse()?],
            sin_angle: f[4].parse()?,
        });
    }
    Ok((unknowns, partner, crossings))
}

fn extract(
    dir: &Path,
    camera: &crossline::camera::Camera,
    config: &crossline::config::Config,
) -> anyhow::Result<Extracted> {
    let frames = crossline::reconstruct::list_frames(dir)?;
    let k = config.background.median_frames.clamp(1, frames.len());
    let images: Vec<image::RgbImage> = (0..k)
        .into_par_iter()
        .map(|i| {
            image::open(&frames[(i * frames.len()) / k + frames.len() / (2 * k)])
                .map(|im| im.into_rgb8())
        })
        .collect::<Result<_, _>>()?;
    let refs: Vec<&image::RgbImage> = images.iter().collect();
    let background = Background::median_of(&refs)?;
    let per_frame: Vec<Vec<crossline::extract::Curve>> = frames
        .par_iter()
        .map(|p| -> anyhow::Result<_> {
            let mut ex = Extractor::new(&config.extract, camera)?;
            Ok(ex.extract(&image::open(p)?.into_rgb8(), &background))
        })
        .collect::<Result<_, _>>()?;
    let mut unknowns = Vec::new();
    let mut polys: Vec<Vec<Vec<[f64; 2]>>> = Vec::new();
    for (fr, curves) in per_frame.into_iter().enumerate() {
        for laser in 0..2u8 {
            let c: Vec<Vec<[f64; 2]>> = curves
                .iter()
                .filter(|c| c.laser == laser)
                .map(|c| c.polyline.clone())
                .collect();
            if !c.is_empty() {
                unknowns.push((fr as u32, laser));
                polys.push(c);
            }
        }
    }
    let partner = (0..unknowns.len())
        .map(|i| {
            let other = |j: usize| {
                unknowns
                    .get(j)
                    .filter(|q| q.0 == unknowns[i].0 && q.1 != unknowns[i].1)
                    .map(|_| j as u32)
            };
            other(i + 1).or_else(|| i.checked_sub(1).and_then(other))
        })
        .collect();
    let mut index = SegmentIndex::new(config.solve.min_sin_angle);
    let mut crossings = Vec::new();
    for (id, p) in polys.iter().enumerate() {
        for poly in p {
            crossings.extend(index.insert(id as u32, poly));
        }
    }
    Ok((unknowns, partner, crossings))
}
