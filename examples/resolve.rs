//! Re-solve a simulation without extracting it again: the solver's test loop.
//!
//! Extracts the curves of a `crossline simulate` folder as `reconstruct` does (the same
//! background policy and extractor, through `reconstruct::extract_frames`), keeps them in
//! `SIMDIR/.resolve/*/curves.log` (the daemon's checkpoint format), and on later runs reads
//! them back, so that a change to the stages after extraction is tried on a 300-frame
//! scan in the time of its solve. Writes `OUT.ply` and `OUT-report.json` as
//! `reconstruct --out OUT.ply --report OUT-report.json` would; `crossline compare OUT.ply
//! --truth SIMDIR` then measures it. Delete `SIMDIR/.resolve` after changing extraction.
//!
//! Environment: `CONFIG` (a crossline.toml), `FOCAL_OFF=F` (the camera's fx, fy and skew
//! multiplied by F, with `--estimate-focal`, as `benches/generality.sh` does),
//! `ESTIMATE_FOCAL=1`, `FRAMES=N` (the first N frames only), `PLANES=true|start` (the simulation's true planes, or the
//! self-calibration started from them).
//!
//! cargo run --release --example resolve -- target/bench-generality/sim-5 /tmp/self

mod common;

use std::path::{Path, PathBuf};

use crossline::cloud::ScaleMode;
use crossline::pipeline::PlaneSource;
use nalgebra::Vector3;

fn main() -> anyhow::Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()),
        )
        .with_writer(std::io::stderr)
        .init();
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [sim_dir, out] = &args[..] else {
        anyhow::bail!("usage: resolve SIMDIR OUT (writes OUT.ply and OUT-report.json)");
    };
    let common::Run {
        sim,
        camera,
        config,
        per_frame,
    } = common::load(Path::new(sim_dir))?;
    let known: Vec<[Option<Vector3<f64>>; 2]> = sim
        .truth
        .frames
        .iter()
        .map(|f| f.planes.map(|p| Some(Vector3::from(p))))
        .collect();
    let source = match std::env::var("PLANES").as_deref() {
        Ok("true") => PlaneSource::Known(&known),
        Ok("start") => PlaneSource::StartedFrom(&known),
        _ => PlaneSource::SelfCalibrated,
    };
    let t = std::time::Instant::now();
    let rec = crossline::pipeline::reconstruct_curves(
        per_frame,
        &camera,
        &config,
        source,
        &ScaleMode::MedianDepth,
        None,
    )?;
    eprintln!(
        "solved in {:.1} s: {} points, {} warnings",
        t.elapsed().as_secs_f64(),
        rec.report.points,
        rec.report.warnings.len()
    );
    let ply = PathBuf::from(format!("{out}.ply"));
    crossline::ply::write_ply(&ply, &rec.cloud, &["crossline resolve example".into()])?;
    let json = serde_json::to_string_pretty(&rec.report)?;
    std::fs::write(format!("{out}-report.json"), json + "\n")?;
    Ok(())
}
