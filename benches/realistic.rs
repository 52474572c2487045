//! Extraction on simulated realistic frames (`simulate::random::draw_realistic`: lit
//! rooms with white and grey structures, clipping, halos, 4:2:0 chroma, moving
//! objects), scored against the simulator's truth with and without a laser-off frame.
//!
//! `cargo bench --bench realistic` prints, per background policy, the recall of lit
//! pixels within 1 px, the median and p90 sub-pixel error, the share of points more
//! than 2 px from any stripe, and the time per frame on one core (scaled to 1080p by
//! pixel count). `REALISTIC_SCANS` (default 12) and `REALISTIC_FRAMES` (default 3)
//! set how many scans are drawn (seeds 1..; under water skipped) and frames of each;
//! `REALISTIC_POLICY` (one of the names below) runs that policy alone, for profiling;
//! `REALISTIC_DUMP=DIR` writes each frame, its laser-off frame, its local background,
//! its lit mask, its curves, its stray points and each point's signed distance from
//! its stripe (`*-err.txt`: curve, laser, x, y, distance px, strength; the chroma
//! phase study of `docs/extraction.md` reads it) there;
//! `REALISTIC_VERBOSE=1` prints each frame's scores (its scan and index, recall, stray
//! points, median error), the time of each of its extractions (ms, at its own size)
//! and the extractor's counters; `REALISTIC_SEEDS=3,5` runs those scans alone;
//! `REALISTIC_REPEAT=N` (default 2) extracts each frame N times: the time is given for
//! the first extraction (which holds a scan's one-time work: reading the chroma
//! sampling off the frames, growing the buffers) and for the others (a frame of a long
//! recording; the frame stays in the caches), and a profile of a large N is the
//! extraction's rather than the simulator's. Then each stage's time
//! (`Extractor::stage_times`), its mean over all extractions at 1080p.
//! The policies: `laser-off` (the simulator's background), `local` (none given: the
//! extractor's local background), `black` (none given, as before the local one) and
//! `clean` (the simulator's laser-off view without sensor noise or JPEG, which no
//! camera gives: what a background measured with the lasers off could give at best; as
//! stale as the laser-off frame where the scene changed after it).

use std::time::Instant;

use crossline::extract::chroma::Rebuild;
use crossline::extract::score::Score;
use crossline::extract::{Background, ExtractParams, Extractor, LaserColour};
use crossline::simulate::random::draw_realistic;
use crossline::simulate::{FrameFormat, Medium, Simulator};

fn env_usize(key: &str, default: usize) -> usize {
    std::env::var(key)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

fn main() {
    // One core: the time per frame is per core.
    rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build_global()
        .ok();
    let scans = env_usize("REALISTIC_SCANS", 12);
    let repeat = env_usize("REALISTIC_REPEAT", 2).max(1);
    let frames = env_usize("REALISTIC_FRAMES", 3);
    let policies = ["laser-off", "local", "black", "clean"];
    let only = std::env::var("REALISTIC_POLICY").ok();
    let seeds: Option<Vec<u64>> = std::env::var("REALISTIC_SEEDS")
        .ok()
        .map(|v| v.split(',').filter_map(|s| s.trim().parse().ok()).collect());
    let mut scores: Vec<Score> = policies.iter().map(|_| Score::default()).collect();
    // Per policy: the first extraction of each frame, and the mean of the others.
    let mut millis = vec![[0.0f64; 2]; policies.len()];
    // Per policy, per stage: the extractions' times (all of them), and their count.
    let mut stages = vec![[0.0f64; 8]; policies.len()];
    let mut extractions = vec![0usize; policies.len()];
    let mut megapixels = 0.0;
    let (mut done, mut ran) = (0, 0);
    let mut seed = 0;
    while done < scans {
        seed += 1;
        let mut drawn = draw_realistic(seed, 40);
        if let FrameFormat::Jpeg { quality, .. } = drawn.format {
            drawn.params.jpeg_quality = Some(quality);
        }
        if drawn.spec.medium == Medium::Water {
            continue;
        }
        done += 1;
        if seeds.as_ref().is_some_and(|s| !s.contains(&seed)) {
            continue;
        }
        ran += 1;
        let Ok(sim) = Simulator::new(&drawn.spec, &drawn.params) else {
            continue;
        };
        let cam = sim.camera().clone();
        let params = ExtractParams {
            lasers: LaserColour::named(drawn.spec.projector.colours.iter().map(|c| c.name())),
            ..ExtractParams::default()
        };
        let Ok(mut extractor) = Extractor::new(&params, &cam) else {
            continue;
        };
        // A camera's JPEG bytes say how their colour was sampled, and the pipeline
        // tells the extractor (`capture::chroma`): frames that are one JPEG round trip
        // are told; the others (PNG, and 4:2:0 repeated after the round trip, as
        // FFmpeg converts a video) are read off their pixels, as there.
        let r = &drawn.params.realism;
        if drawn.params.jpeg_quality.is_some() && (!r.chroma_420 || r.chroma_interpolated) {
            extractor.know_chroma(if r.chroma_420 {
                [Rebuild::Interpolated; 2]
            } else {
                [Rebuild::Full; 2]
            });
        }
        let off = Background::from_image(sim.background());
        let local = Background::local(cam.width, cam.height);
        let black = Background::black(cam.width, cam.height);
        // The laser-off view, noise-free and uncompressed: a second render, made only
        // when its policy runs (a profile of another policy should not hold it).
        let clean = if only.as_deref().is_none_or(|p| p == "clean") {
            let mut p = drawn.params.clone();
            p.noise_sigma = 0.0;
            p.jpeg_quality = None;
            match Simulator::new(&drawn.spec, &p) {
                Ok(s) => Some(Background::from_image(s.background())),
                Err(_) => continue,
            }
        } else {
            None
        };
        let min_contrast = (5.0 * drawn.params.noise_sigma).round() as u8;
        for f in 0..frames {
            let index = 5 + f * 13;
            let mut img = image::RgbImage::new(cam.width, cam.height);
            let mut lit = vec![0u8; (cam.width * cam.height) as usize];
            sim.render_frame_into(index, &mut img, Some(&mut lit));
            megapixels += (cam.width * cam.height) as f64 / 1e6;
            let backgrounds = [Some(&off), Some(&local), Some(&black), clean.as_ref()];
            for (k, bg) in backgrounds.into_iter().enumerate() {
                let Some(bg) = bg.filter(|_| only.as_deref().is_none_or(|p| p == policies[k]))
                else {
                    continue;
                };
                let mut curves = Vec::new();
                let mut times = Vec::new();
                for _ in 0..repeat {
                    let t = Instant::now();
                    curves = extractor.extract(&img, bg);
                    times.push(t.elapsed().as_secs_f64() * 1e3);
                    let scale = 1920.0 * 1080.0 / f64::from(cam.width * cam.height);
                    for (s, (_, d)) in stages[k].iter_mut().zip(extractor.stage_times().stages()) {
                        *s += d.as_secs_f64() * 1e3 * scale;
                    }
                    extractions[k] += 1;
                }
                millis[k][0] += times[0];
                if repeat > 1 {
                    millis[k][1] += times[1..].iter().sum::<f64>() / (repeat - 1) as f64;
                }
                if std::env::var_os("REALISTIC_VERBOSE").is_some() {
                    let mut one = Score::default();
                    one.add(&sim, index, &lit, min_contrast, &curves);
                    eprintln!(
                        "  scan {seed} frame {index} {}: recall {:.3} stray {}/{} median error {:.4} px, ms {:.1?} {:?}",
                        policies[k],
                        one.recall(),
                        one.stray,
                        one.points,
                        one.error_quantile(0.5),
                        times,
                        extractor.stats()
                    );
                }
                scores[k].add(&sim, index, &lit, min_contrast, &curves);
                if let Some(dir) = std::env::var_os("REALISTIC_DUMP") {
                    // The frame, its lit mask and the curves, to look at.
                    let dir = std::path::Path::new(&dir);
                    let stem = format!("{seed:03}-{index:03}");
                    img.save(dir.join(format!("{stem}.png"))).ok();
                    off.image().save(dir.join(format!("{stem}-off.png"))).ok();
                    if bg.is_local() {
                        let local = extractor.local_background();
                        local.save(dir.join(format!("{stem}-localbg.png"))).ok();
                    }
                    image::GrayImage::from_raw(cam.width, cam.height, lit.clone())
                        .map(|m| m.save(dir.join(format!("{stem}-lit.png"))));
                    let file = crossline::extract::CurvesFile::new(
                        cam.width,
                        cam.height,
                        &params.lasers,
                        curves.clone(),
                    );
                    let pose = sim.pose(index);
                    let stray: Vec<String> = curves
                        .iter()
                        .flat_map(|c| c.points_px.iter().map(move |p| (c.laser, p)))
                        .filter(|(_, p)| {
                            let (x, y) = (p[0] as f64, p[1] as f64);
                            (0..2)
                                .filter_map(|j| sim.stripe_distance_px(&pose, j, x, y))
                                .all(|e| e.abs() > 2.0)
                        })
                        .map(|(l, p)| format!("{l} {} {}", p[0], p[1]))
                        .collect();
                    // Each point's signed distance from its own stripe.
                    let errs: Vec<String> = curves
                        .iter()
                        .enumerate()
                        .flat_map(|(ci, c)| {
                            c.points_px
                                .iter()
                                .zip(&c.strength)
                                .map(move |(p, s)| (ci, c.laser, p, s))
                        })
                        .filter_map(|(ci, l, p, s)| {
                            let e = sim.stripe_distance_px(
                                &pose,
                                l as usize,
                                p[0] as f64,
                                p[1] as f64,
                            )?;
                            Some(format!("{ci} {l} {} {} {e} {s}", p[0], p[1]))
                        })
                        .collect();
                    std::fs::write(
                        dir.join(format!("{stem}-{}-err.txt", policies[k])),
                        errs.join("\n"),
                    )
                    .ok();
                    std::fs::write(
                        dir.join(format!("{stem}-{}-stray.txt", policies[k])),
                        stray.join("\n"),
                    )
                    .ok();
                    std::fs::write(
                        dir.join(format!("{stem}-{}.json", policies[k])),
                        file.to_json(),
                    )
                    .ok();
                }
            }
        }
        let r = &drawn.params.realism;
        let chroma = match (r.chroma_420, r.chroma_interpolated) {
            (false, _) => "4:4:4",
            (true, false) => "4:2:0 repeated",
            (true, true) => "4:2:0 interpolated",
        };
        eprintln!("scan {seed}: {} | {chroma}", drawn.summary);
    }
    let per_1080p = 1920.0 * 1080.0 / 1e6;
    println!("{ran} realistic scans x {frames} frames (air), one core");
    println!(
        "| background | recall ≤1 px | sub-px median / p90 | stray > 2 px | ms per 1080p frame: first / again |"
    );
    println!("|---|---|---|---|---|");
    for (k, name) in policies.iter().enumerate() {
        let s = &scores[k];
        println!(
            "| {name} | {:.1} % | {:.4} / {:.3} px | {:.2} % | {:.1} / {} |",
            100.0 * s.recall(),
            s.error_quantile(0.5),
            s.error_quantile(0.9),
            100.0 * s.stray_share(),
            millis[k][0] / megapixels * per_1080p,
            if repeat > 1 {
                format!("{:.1}", millis[k][1] / megapixels * per_1080p)
            } else {
                "-".into()
            },
        );
    }
    // Where the time went: each stage's mean over all extractions, at 1080p.
    let names = crossline::extract::StageTimes::default()
        .stages()
        .map(|(n, _)| n);
    println!(
        "ms per 1080p frame by stage, all extractions: {}",
        names.join(" / ")
    );
    for (k, name) in policies.iter().enumerate() {
        if extractions[k] > 0 {
            let each: Vec<String> = stages[k]
                .iter()
                .map(|s| format!("{:.2}", s / extractions[k] as f64))
                .collect();
            println!("  {name}: {}", each.join(" / "));
        }
    }
}
