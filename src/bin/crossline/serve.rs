//! `crossline serve`: the live capture daemon.

use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

use anyhow::{bail, Context};
use crossline::capture::replay::{Rate, ReplaySource};
use crossline::capture::video::is_video;
use crossline::capture::FrameSource;
use crossline::config::Config;
use crossline::serve::{self, ServeOptions};

/// Run the scanner live: capture from a V4L2 camera (or replay a recorded dump or a
/// video file),
/// extract the laser curves on worker threads, solve the planes incrementally, and
/// stream the growing cloud to clients while recording every raw frame.
///
/// Stop it with SIGTERM or Ctrl-C: capture stops, the frames in flight are processed,
/// a final solve runs over every curve, and the cloud (PLY) and a JSON report are
/// written to --out-dir (named after the scan's start time) before it exits 0.
/// State is checkpointed every few seconds: after a crash or kill -9, the next start
/// resumes the unfinished scan of the same input.
///
/// Watch it:   http://127.0.0.1:8080/      (the live view: cloud, status, coverage map)
///             crossline status            (or: socat - UNIX-CONNECT:/run/crossline/status.sock)
/// Fetch it:   crossline tail --out live.ply
///
/// Examples:
///
///   crossline serve --config /etc/crossline/crossline.toml
///   crossline serve --camera cam.yml --device /dev/v4l/by-id/usb-...-video-index0 --out-dir scans
///   crossline serve --camera cam.yml --replay dive.dump --rate max --out-dir reprocessed
///   crossline serve --camera gopro.yml --replay DIVE.MP4 --start 30 --duration 60 --out-dir scans
#[derive(clap::Args)]
#[command(verbatim_doc_comment)]
pub struct Args {
    /// Settings file; its [serve] section configures the daemon (config/crossline.toml
    /// lists every key and its default).
    #[arg(long, value_name = "FILE")]
    config: Option<PathBuf>,
    /// Laser colours, overriding the config's [[extract.lasers]]: red-green (the
    /// default), blue-green, or one laser: red, green or blue.
    #[arg(long, value_name = "PAIR")]
    lasers: Option<String>,
    /// Camera calibration at the capture size (OpenCV FileStorage YAML, ROS
    /// camera_info YAML or TOML). Default: [serve] camera.
    #[arg(long, value_name = "FILE")]
    camera: Option<PathBuf>,
    /// V4L2 device path, e.g. /dev/video0 or /dev/v4l/by-id/... Default: [serve] device.
    #[arg(long, value_name = "PATH", conflicts_with = "replay")]
    device: Option<PathBuf>,
    /// Replay a recorded dump, or a video file (.mp4, .mov, .mkv, .avi; decoded by
    /// FFmpeg, which must be installed), through the identical pipeline instead of a
    /// camera.
    #[arg(long, value_name = "DUMP|VIDEO")]
    replay: Option<PathBuf>,
    /// Video replay only: start this many seconds after the first frame.
    #[arg(long, value_name = "SECONDS", requires = "replay")]
    start: Option<f64>,
    /// Video replay only: replay this many seconds of it (default: to the end).
    #[arg(long, value_name = "SECONDS", requires = "replay")]
    duration: Option<f64>,
    /// Replay pace: `realtime` releases frames at their recorded times (frames the
    /// workers cannot take are dropped, as from a camera); `max` goes as fast as the
    /// pipeline takes them and drops nothing.
    #[arg(long, value_enum, default_value = "realtime", requires = "replay")]
    rate: RateArg,
    /// Where the scan's cloud, report, checkpoint and recordings go. Default: [serve]
    /// out_dir.
    #[arg(long, value_name = "DIR")]
    out_dir: Option<PathBuf>,
    /// Write the final cloud here instead of OUT_DIR/<scan>.ply (E57 when it ends in
    /// .e57).
    #[arg(long, value_name = "FILE")]
    out: Option<PathBuf>,
    /// Write the final report here instead of OUT_DIR/<scan>.json.
    #[arg(long, value_name = "FILE")]
    report: Option<PathBuf>,
    /// Extraction threads (0: one per core). Default: [serve] workers.
    #[arg(long, value_name = "N")]
    workers: Option<usize>,
    /// Status socket path ("" disables). Default: [serve] status_socket.
    #[arg(long, value_name = "PATH")]
    status_socket: Option<String>,
    /// Cloud stream TCP address ("" disables; port 0 picks a free one). Default:
    /// [serve] stream_tcp.
    #[arg(long, value_name = "ADDR")]
    stream_tcp: Option<String>,
    /// Cloud stream Unix socket path ("" disables). Default: [serve] stream_unix.
    #[arg(long, value_name = "PATH")]
    stream_unix: Option<String>,
    /// Live view (a page in the browser) HTTP address ("" disables; port 0 picks a
    /// free one). Default: [serve] http_listen.
    #[arg(long, value_name = "ADDR")]
    http: Option<String>,
    /// Do not record the camera's raw frames.
    #[arg(long)]
    no_record: bool,
    /// Multiply the raw solution by this factor instead of normalising the median depth.
    #[arg(long, value_name = "FACTOR", conflicts_with = "known_distance")]
    scale: Option<f64>,
    /// U1,V1,U2,V2,D: two image points on the surface D units apart fix the scale.
    #[arg(long, value_name = "U1,V1,U2,V2,D", allow_hyphen_values = true)]
    known_distance: Option<String>,
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum RateArg {
    Realtime,
    Max,
}

pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    let mut config = match &args.config {
        Some(path) => crossline::config::load(path)?,
        None => Config::default(),
    };
    if let Some(name) = &args.lasers {
        config.extract.lasers = crate::extract::lasers_arg(name)?;
    }
    let sc = &mut config.serve;
    if let Some(w) = args.workers {
        sc.workers = w;
    }
    if let Some(p) = &args.status_socket {
        sc.status_socket = p.clone();
    }
    if let Some(p) = &args.stream_tcp {
        sc.stream_tcp = p.clone();
    }
    if let Some(p) = &args.stream_unix {
        sc.stream_unix = p.clone();
    }
    if let Some(a) = &args.http {
        sc.http_listen = a.clone();
    }
    if args.no_record {
        sc.record = false;
    }
    let camera_path = match &args.camera {
        Some(p) => p.clone(),
        None if !sc.camera.is_empty() => PathBuf::from(&sc.camera),
        None => bail!("no camera file: pass --camera FILE or set [serve] camera in the config"),
    };
    let camera = crossline::camera_file::load(&camera_path)
        .with_context(|| format!("loading the camera from {}", camera_path.display()))?;
    let scale = crate::reconstruct::scale_mode(args.scale, args.known_distance.as_deref())?;
    let out_dir = args
        .out_dir
        .clone()
        .unwrap_or_else(|| PathBuf::from(&config.serve.out_dir));

    let stop = Arc::new(AtomicBool::new(false));
    for sig in [signal_hook::consts::SIGTERM, signal_hook::consts::SIGINT] {
        signal_hook::flag::register(sig, stop.clone()).context("installing signal handlers")?;
    }

    let (source, input_id, record): (Box<dyn FrameSource>, String, bool) = match &args.replay {
        Some(path) => {
            let rate = match args.rate {
                RateArg::Realtime => Rate::Realtime,
                RateArg::Max => Rate::Max,
            };
            let window = crate::reconstruct::video_window(args.start, args.duration);
            let src = if is_video(path) {
                ReplaySource::open_video(path, window.unwrap_or_default(), rate)
                    .with_context(|| format!("opening the video {}", path.display()))?
            } else if window.is_some() {
                bail!(
                    "--start and --duration select part of a video file, not of {}",
                    path.display()
                );
            } else {
                ReplaySource::open(path, rate)
                    .with_context(|| format!("opening the replay {}", path.display()))?
            };
            let mut id = std::fs::canonicalize(path)
                .unwrap_or_else(|_| path.clone())
                .display()
                .to_string();
            // Another part of the same video is another scan, not one to resume.
            if let Some(w) = window {
                let duration = w.duration_s.map_or("end".into(), |d| d.to_string());
                id += &format!("#start={},duration={duration}", w.start_s);
            }
            (Box::new(src), format!("replay:{id}"), false)
        }
        None => {
            let device = args
                .device
                .clone()
                .unwrap_or_else(|| PathBuf::from(&config.serve.device));
            let src = crate::device::open_source(&device, &config.serve)?;
            (
                src,
                format!("device:{}", device.display()),
                config.serve.record,
            )
        }
    };
    let opts = ServeOptions {
        camera,
        config,
        scale,
        out_dir,
        cloud_path: args.out.clone(),
        report_path: args.report.clone(),
        input_id,
        record,
        http_listener: None,
    };
    let report = serve::run(source, opts, stop)?;
    eprintln!(
        "crossline: scan {}: {} frames in, {} dropped ({} by the driver), {} processed; {} points in {}",
        report.scan,
        report.frames_in,
        report.frames_dropped_ring,
        report.frames_dropped_driver,
        report.frames_processed,
        report.points,
        report.cloud.display()
    );
    if let Some(e) = &report.solve_error {
        eprintln!("crossline: warning: final solve: {e}");
    }
    if let Some(e) = &report.checkpoint_error {
        eprintln!(
            "crossline: warning: the checkpoint stopped during the scan ({e}); the scan went on, but it could not have been resumed after a crash"
        );
    }
    if let Some(e) = &report.capture_error {
        eprintln!(
            "crossline: error: capture stopped early: {e} (the frames before it were processed and saved)"
        );
        return Ok(ExitCode::FAILURE);
    }
    Ok(ExitCode::SUCCESS)
}
