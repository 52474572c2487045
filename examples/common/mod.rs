//! What the solver's example tools share: a simulation's curves, extracted once as
//! `reconstruct` extracts them and kept in `SIMDIR/.resolve/TAG/curves.log` (the daemon's
//! checkpoint format), and the settings and camera a run uses (`CONFIG`, `FOCAL_OFF`,
//! `ESTIMATE_FOCAL`, `FRAMES`; see `resolve.rs`).

#![allow(dead_code)]

use std::path::Path;
use std::time::Duration;

use anyhow::Context;
use crossline::camera::Camera;
use crossline::config::Config;
use crossline::extract::{Curve, LaserColour};
use crossline::reconstruct::{self, FrameSource};
use crossline::serve::checkpoint::{read_log, CheckpointWriter, FrameCurves};
use crossline::simulate::SimDir;

/// A simulation, its curves, and the camera and settings of the run.
pub struct Run {
    pub sim: SimDir,
    pub camera: Camera,
    pub config: Config,
    pub per_frame: Vec<Vec<Curve>>,
}

/// Loads `sim_dir` and its curves as the environment asks.
pub fn load(sim_dir: &Path) -> anyhow::Result<Run> {
    let sim = crossline::simulate::load_sim_dir(sim_dir)?;
    let mut config = match std::env::var("CONFIG") {
        Ok(path) => crossline::config::load(Path::new(&path))?,
        Err(_) => Config::default(),
    };
    let pair: Vec<&str> = sim.truth.lasers.iter().map(|l| l.name.as_str()).collect();
    config.extract.lasers =
        LaserColour::preset(&pair.join("-")).with_context(|| format!("lasers {pair:?}"))?;
    let mut camera = sim.camera.clone();
    let mut tag = String::from("curves");
    if let Ok(f) = std::env::var("FOCAL_OFF") {
        let f: f64 = f.parse().context("FOCAL_OFF")?;
        camera.fx *= f;
        camera.fy *= f;
        camera.skew *= f;
        config.solve.estimate_focal = true;
        // The curves' normalised coordinates depend on the camera: their own cache.
        tag = format!("curves-focal-{f}");
    }
    if std::env::var("ESTIMATE_FOCAL").is_ok_and(|v| v == "1") {
        config.solve.estimate_focal = true;
    }
    let mut per_frame = curves(sim_dir, &tag, &camera, &config)?;
    if let Ok(n) = std::env::var("FRAMES") {
        per_frame.truncate(n.parse().context("FRAMES")?);
    }
    Ok(Run {
        sim,
        camera,
        config,
        per_frame,
    })
}

/// Every frame's curves: from the cache, or extracted and cached.
fn curves(
    sim_dir: &Path,
    tag: &str,
    camera: &Camera,
    config: &Config,
) -> anyhow::Result<Vec<Vec<Curve>>> {
    let cache = sim_dir.join(".resolve").join(tag);
    let log = cache.join("curves.log");
    if let Ok(bytes) = std::fs::read(&log) {
        let read = read_log(&bytes, &log, camera.width, camera.height)?;
        if read.stopped.is_none() && !read.frames.is_empty() {
            eprintln!(
                "{} frames of curves from {}",
                read.frames.len(),
                log.display()
            );
            return Ok(read.frames.into_iter().map(|f| f.curves).collect());
        }
    }
    let (frames, _) = FrameSource::open(sim_dir)?;
    eprintln!("extracting {} frames", frames.len());
    let mut per_frame = Vec::new();
    reconstruct::extract_frames(
        &frames,
        None,
        camera,
        config,
        &|_: &str, _, _| {},
        &mut |block| per_frame.extend(block),
    )?;
    let _ = std::fs::remove_file(&log);
    let mut writer = CheckpointWriter::open(
        &cache,
        camera.width,
        camera.height,
        Duration::from_secs(3600),
    )?;
    for (i, curves) in per_frame.iter().enumerate() {
        writer.append(&FrameCurves {
            index: i as u64,
            source_position: i as u64,
            sequence: i as u32,
            timestamp_nanos: 0,
            curves: curves.clone(),
        })?;
    }
    writer.sync()?;
    Ok(per_frame)
}
