//! `crossline demo`: the whole product on a built-in scene, no camera needed.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use crossline::cloud::ScaleMode;
use crossline::compare::{evaluate_against_truth, TruthParams};
use crossline::config::Config;
use crossline::reconstruct::{self, PlaneSource};
use crossline::simulate::{
    builtin_scene, load_sim_dir, write_sim_dir_as, FrameFormat, JpegChroma, SimParams, Simulator,
};

/// Simulate a scan of a built-in scene, reconstruct it with no knowledge of the
/// projector, measure the cloud against the simulator's ground truth, then replay the
/// same recording through the live daemon.
///
/// Writes DIR/sim/ (the simulated recording, `frames.dump`, as an MJPEG camera would
/// deliver it, and the truth), DIR/cloud.ply, DIR/report.json, and DIR/live/ (the
/// daemon's cloud and report). The same steps by hand:
///
///   crossline simulate --scene room --frames 200 --format dump --out DIR/sim
///   crossline reconstruct --input DIR/sim/frames.dump --camera DIR/sim/camera.yml --out DIR/cloud.ply
///   crossline compare DIR/cloud.ply --truth DIR/sim
///   crossline serve --replay DIR/sim/frames.dump --rate max --camera DIR/sim/camera.yml --out-dir DIR/live
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
        "1/4 simulating {} frames of `{}` into {}",
        args.frames,
        args.scene,
        sim_dir.display()
    );
    let bar = crate::reconstruct::progress_bar(args.frames as u64);
    write_sim_dir_as(
        &sim,
        args.frames,
        &sim_dir,
        FrameFormat::Dump {
            quality: 95,
            chroma: JpegChroma::Full,
        },
        |n| bar.set_position(n as u64),
    )
    .with_context(|| format!("writing the simulation to {}", sim_dir.display()))?;
    bar.finish_and_clear();

    println!("2/4 reconstructing without knowledge of the projector");
    let camera = crossline::camera_file::load(&sim_dir.join("camera.yml"))?;
    let dump = sim_dir.join("frames.dump");
    let (frames, _) = reconstruct::FrameSource::open(&dump)?;
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

    println!("3/4 comparing with the simulator's ground truth");
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
        "coverage: {:.1} % of the lit image area has a point within {} px{}",
        100.0 * report.coverage.fraction,
        report.coverage.radius_px,
        report
            .coverage_visible
            .as_ref()
            .map(|v| format!(
                " ({:.1} % of its part where the stripe was visible)",
                100.0 * v.fraction
            ))
            .unwrap_or_default()
    );
    println!(
        "cloud: {} ({} points; open it in CloudCompare, MeshLab or Open3D)",
        cloud_path.display(),
        rec.cloud.len()
    );

    println!("4/4 replaying the recording through the live daemon (crossline serve)");
    let live = args.out.join("live");
    let _ = std::fs::remove_dir_all(&live);
    let mut config = Config::default();
    config.serve.status_socket.clear();
    config.serve.stream_tcp.clear();
    // The live view: on its usual port, or on any free one when that is taken.
    let http = std::net::TcpListener::bind(&config.serve.http_listen)
        .or_else(|_| std::net::TcpListener::bind("127.0.0.1:0"))
        .context("binding a port for the live view")?;
    println!(
        "live view, while the replay runs: http://{}/",
        http.local_addr().context("the live view's address")?
    );
    let source = crossline::capture::replay::ReplaySource::open(
        &dump,
        crossline::capture::replay::Rate::Max,
    )?;
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let served = crossline::serve::run(
        Box::new(source),
        crossline::serve::ServeOptions {
            camera,
            config,
            scale: ScaleMode::MedianDepth,
            out_dir: live.clone(),
            cloud_path: Some(live.join("cloud.ply")),
            report_path: Some(live.join("report.json")),
            input_id: format!("demo:{}", dump.display()),
            record: false,
            http_listener: Some(http),
        },
        stop,
    )?;
    let live_cloud = crossline::ply::read_ply(&served.cloud)?;
    let live_eval = evaluate_against_truth(&live_cloud.points, &truth, &TruthParams::default())?;
    println!(
        "daemon: {} frames, {} epochs of the growing cloud, final cloud {} ({} points): median {:.3} %, coverage {:.1} %",
        served.frames_processed,
        served.epochs,
        served.cloud.display(),
        served.points,
        100.0 * live_eval.relative_error.median,
        100.0 * live_eval.coverage.fraction
    );
    Ok(ExitCode::SUCCESS)
}
