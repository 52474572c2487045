//! `crossline demo`: the whole product on a built-in scene, no camera needed.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use crossline::cloud::ScaleMode;
use crossline::compare::{evaluate_against_truth, TruthParams};
use crossline::config::Config;
use crossline::reconstruct::{self, PlaneSource};
use crossline::simulate::{builtin_scene, load_sim_dir, write_sim_dir, SimParams, Simulator};

/// Simulate a scan of a built-in scene, reconstruct it with no knowledge of the
/// projector, and measure the cloud against the simulator's ground truth.
///
/// Writes DIR/sim/ (the simulated frames and truth), DIR/cloud.ply, DIR/report.json.
/// The same steps by hand:
///
///   crossline simulate --scene room --frames 200 --out DIR/sim
///   crossline reconstruct --input DIR/sim --camera DIR/sim/camera.yml --out DIR/cloud.ply
///   crossline compare DIR/cloud.ply --truth DIR/sim
#[derive(clap::Args)]
#[command(verbatim_doc_comment)]
pub struct Args {
    /// Built-in scene: room (a room corner, ~3.7 m), pipes (under water, ~2.9 m),
    /// bricks (table top, ~0.6 m).
    #[arg(long, default_value = "room")]
    scene: String,
    /// Frames to simulate (30 per second of a real scan).
    #[arg(long, default_value_t = 200)]
    frames: usize,
    /// Output folder.
    #[arg(long, default_value = "out/demo", value_name = "DIR")]
    out: PathBuf,
    /// Seed of the projector motion and sensor noise.
    #[arg(long, default_value_t = 1)]
    seed: u64,
}

pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    let spec = builtin_scene(&args.scene).with_context(|| {
        format!(
            "--scene {}: not a built-in scene (room, pipes, bricks)",
            args.scene
        )
    })?;
    let sim_dir = args.out.join("sim");
    let sim = Simulator::new(
        &spec,
        &SimParams {
            seed: args.seed,
            ..SimParams::default()
        },
    )?;
    println!(
        "1/3 simulating {} frames of `{}` into {}",
        args.frames,
        args.scene,
        sim_dir.display()
    );
    let bar = crate::reconstruct::progress_bar(args.frames as u64);
    write_sim_dir(&sim, args.frames, &sim_dir, |n| bar.set_position(n as u64))
        .with_context(|| format!("writing the simulation to {}", sim_dir.display()))?;
    bar.finish_and_clear();

    println!("2/3 reconstructing without knowledge of the projector");
    let camera = crossline::camera_file::load(&sim_dir.join("camera.yml"))?;
    let frames = reconstruct::FrameSource::Files(reconstruct::list_frames(&sim_dir)?);
    let bar = crate::reconstruct::progress_bar(frames.len() as u64);
    let rec = reconstruct::reconstruct_files(
        &frames,
        None,
        &camera,
        &Config::default(),
        PlaneSource::SelfCalibrated,
        &ScaleMode::MedianDepth,
        &|_: &str, done: usize, _: usize| bar.set_position(done as u64),
    )?;
    bar.finish_and_clear();
    let cloud_path = args.out.join("cloud.ply");
    crate::reconstruct::write_outputs(&rec, &cloud_path, Some(&args.out.join("report.json")))?;
    crate::reconstruct::print_summary(&rec);

    println!("3/3 comparing with the simulator's ground truth");
    let truth = load_sim_dir(&sim_dir)?;
    let report = evaluate_against_truth(&rec.cloud.points, &truth, &TruthParams::default())?;
    let e = &report.relative_error;
    println!(
        "relative depth error after the best global scale: median {:.3} %, p95 {:.3} %, {:.2} % of points over {:.0} %",
        100.0 * e.median,
        100.0 * e.p95,
        100.0 * report.outlier_fraction,
        100.0 * report.outlier_relative
    );
    println!(
        "coverage: {:.1} % of the lit image area has a point within {} px",
        100.0 * report.coverage.fraction,
        report.coverage.radius_px
    );
    println!(
        "cloud: {} ({} points; open it in CloudCompare, MeshLab or Open3D)",
        cloud_path.display(),
        rec.cloud.len()
    );
    Ok(ExitCode::SUCCESS)
}
