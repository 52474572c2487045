//! `crossline reconstruct`: frames in, coloured point cloud out.

use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{bail, Context};
use crossline::cloud::ScaleMode;
use crossline::config::Config;
use crossline::pipeline::PipelineError;
use crossline::reconstruct::{
    self, PlaneSource, ReconstructError, ReconstructReport, Reconstruction,
};
use nalgebra::Vector3;

/// Recover every laser plane with no knowledge of the projector, and triangulate a
/// dense, coloured point cloud in the camera frame (OpenCV axes).
///
/// The cloud's global scale cannot be known from the images alone. By default the
/// cloud is scaled so that its median depth is 1; --scale multiplies that raw solution
/// by a factor instead, and --known-distance fixes it from two image points on the
/// scanned surface whose distance you know. `crossline compare --align scale` finds it
/// against a reference cloud.
///
/// Example:
///
///   crossline reconstruct --input sim --camera sim/camera.yml --out cloud.ply --report report.json
///   crossline reconstruct --input DIVE.MP4 --start 30 --duration 60 --camera gopro.yml --out dive.ply
#[derive(clap::Args)]
#[command(verbatim_doc_comment)]
pub struct Args {
    /// A folder of frames (.png/.jpg; `frame_*` files only when present), in name
    /// order, a recorded dump (`crossline simulate --format dump` writes one), or a
    /// video file (.mp4, .mov, .mkv, .avi; decoded by FFmpeg, which must be installed).
    #[arg(long, value_name = "DIR|DUMP|VIDEO")]
    input: PathBuf,
    /// Video input only: start this many seconds after the first frame.
    #[arg(long, value_name = "SECONDS")]
    start: Option<f64>,
    /// Video input only: use this many seconds of it (default: to the end).
    #[arg(long, value_name = "SECONDS")]
    duration: Option<f64>,
    /// Camera calibration: OpenCV FileStorage YAML, ROS camera_info YAML, or TOML with a
    /// [camera] table.
    #[arg(long, value_name = "FILE")]
    camera: PathBuf,
    /// Output cloud: binary little-endian PLY (x y z, red green blue, frame, laser), or
    /// E57 for survey tools when the name ends in .e57 (points, colours, metadata).
    #[arg(long, value_name = "FILE")]
    out: PathBuf,
    /// Settings file (see config/crossline.toml for every key and its default).
    #[arg(long, value_name = "FILE")]
    config: Option<PathBuf>,
    /// Laser colours, overriding the config's [[extract.lasers]]: red-green (the
    /// default), blue-green, or one laser: red, green or blue.
    #[arg(long, value_name = "PAIR")]
    lasers: Option<String>,
    /// A laser-off frame of the same view; without it the background is a rolling
    /// temporal median of sampled frames, the one `serve` uses (`[background]`).
    #[arg(long, value_name = "FILE")]
    background: Option<PathBuf>,
    /// Write a JSON report: counts, residuals, focal estimate, time per stage.
    #[arg(long, value_name = "FILE")]
    report: Option<PathBuf>,
    /// Multiply the raw solution by this factor instead of normalising the median depth.
    #[arg(long, value_name = "FACTOR", conflicts_with = "known_distance")]
    scale: Option<f64>,
    /// U1,V1,U2,V2,D: the image points (pixels) (U1,V1) and (U2,V2) lie on the scanned
    /// surface D units apart; the cloud is scaled to match.
    #[arg(long, value_name = "U1,V1,U2,V2,D", allow_hyphen_values = true)]
    known_distance: Option<String>,
    /// Estimate the focal length from the orthogonality of the crosses (e.g. under
    /// water behind a flat port, where it grows by about 1.33).
    #[arg(long)]
    estimate_focal: bool,
    /// Evaluation only: take the laser planes from a simulation's truth.json (in DIR)
    /// instead of self-calibrating, to measure how close self-calibration comes to a
    /// perfectly calibrated projector.
    #[arg(long, value_name = "SIMDIR", conflicts_with = "start_planes")]
    true_planes: Option<PathBuf>,
    /// Evaluation only: self-calibrate, but start from a simulation's true planes (in
    /// DIR/truth.json) instead of the linear start. Every plane is still estimated from
    /// the crossings and triangulated where they determine it: what this leaves out, the
    /// evidence does not fix, whatever a start finds.
    #[arg(long, value_name = "SIMDIR")]
    start_planes: Option<PathBuf>,
}

pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    let camera = crossline::camera_file::load(&args.camera)
        .with_context(|| format!("loading the camera from {}", args.camera.display()))?;
    let mut config = match &args.config {
        Some(path) => crossline::config::load(path)?,
        None => Config::default(),
    };
    if args.estimate_focal {
        config.solve.estimate_focal = true;
    }
    if let Some(name) = &args.lasers {
        config.extract.lasers = crate::extract::lasers_arg(name)?;
    }
    let scale = scale_mode(args.scale, args.known_distance.as_deref())?;
    let window = video_window(args.start, args.duration);
    let (frames, stopped) = reconstruct::FrameSource::open_window(&args.input, window)
        .with_context(|| format!("opening {}", args.input.display()))?;
    if let Some(why) = stopped {
        tracing::warn!("using the {} whole frames before: {why}", frames.len());
    }
    tracing::info!(frames = frames.len(), input = %args.input.display(), "reconstructing");
    let known = match args.true_planes.as_ref().or(args.start_planes.as_ref()) {
        Some(dir) => Some(true_planes(dir, frames.len())?),
        None => None,
    };
    let source = match (&known, args.start_planes.is_some()) {
        (Some(planes), false) => PlaneSource::Known(planes),
        (Some(planes), true) => PlaneSource::StartedFrom(planes),
        (None, _) => PlaneSource::SelfCalibrated,
    };
    let bar = progress_bar(frames.len() as u64);
    let rec = reconstruct::reconstruct_files(
        &frames,
        args.background.as_deref(),
        &camera,
        &config,
        source,
        &scale,
        &|_stage: &str, done: usize, _total: usize| bar.set_position(done as u64),
    );
    bar.finish_and_clear();
    let rec = match rec {
        Ok(rec) => rec,
        // No cloud, but the report of what the solve found.
        Err(ReconstructError::Pipeline(PipelineError::Refused { reason, report })) => {
            if let Some(path) = &args.report {
                write_report(&report, path)?;
            }
            bail!("{reason}");
        }
        // No planes solved: the error, and the report of what was found.
        Err(mut e) => {
            if let (ReconstructError::Pipeline(p), Some(path)) = (&mut e, &args.report) {
                if let Some(report) = p.report_mut() {
                    write_report(report, path)?;
                }
            }
            return Err(e.into());
        }
    };
    let meta = scan_meta(&args.input, &args.camera, &camera, &rec);
    write_outputs_with(&rec, &args.out, args.report.as_deref(), &meta)?;
    print_summary(&rec);
    Ok(ExitCode::SUCCESS)
}

/// The planes of a simulation's truth, per frame and laser.
fn true_planes(dir: &Path, frames: usize) -> anyhow::Result<Vec<[Option<Vector3<f64>>; 2]>> {
    let path = dir.join("truth.json");
    let text =
        std::fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
    let truth: crossline::simulate::Truth =
        serde_json::from_str(&text).with_context(|| format!("parsing {}", path.display()))?;
    if truth.frames.len() != frames {
        bail!(
            "{} describes {} frames but the input has {frames}",
            path.display(),
            truth.frames.len()
        );
    }
    Ok(truth
        .frames
        .iter()
        .map(|f| f.planes.map(|p| Some(Vector3::from(p))))
        .collect())
}

/// The part of a video `--start` and `--duration` select, if they were given.
pub fn video_window(
    start: Option<f64>,
    duration: Option<f64>,
) -> Option<crossline::capture::video::Window> {
    (start.is_some() || duration.is_some()).then(|| crossline::capture::video::Window {
        start_s: start.unwrap_or(0.0),
        duration_s: duration,
    })
}

pub fn scale_mode(scale: Option<f64>, known_distance: Option<&str>) -> anyhow::Result<ScaleMode> {
    Ok(match (scale, known_distance) {
        (Some(factor), _) => ScaleMode::Factor { factor },
        (None, Some(text)) => {
            let v: Vec<f64> = text
                .split(',')
                .map(|x| x.trim().parse::<f64>())
                .collect::<Result<_, _>>()
                .with_context(|| {
                    format!("--known-distance {text}: expected five numbers U1,V1,U2,V2,D")
                })?;
            let [u1, v1, u2, v2, d] = v[..] else {
                bail!(
                    "--known-distance {text}: expected five numbers U1,V1,U2,V2,D, found {}",
                    v.len()
                );
            };
            ScaleMode::KnownDistance {
                a_px: [u1, v1],
                b_px: [u2, v2],
                distance: d,
            }
        }
        (None, None) => ScaleMode::MedianDepth,
    })
}

pub fn progress_bar(len: u64) -> indicatif::ProgressBar {
    if !std::io::stderr().is_terminal() {
        return indicatif::ProgressBar::hidden();
    }
    let bar = indicatif::ProgressBar::new(len);
    if let Ok(style) = indicatif::ProgressStyle::with_template(
        "{spinner} {msg} [{bar:40}] {pos}/{len} frames ({per_sec}, {eta} left)",
    ) {
        bar.set_style(style.progress_chars("=> "));
    }
    bar
}

/// What an E57 output says besides the points: the input, the camera, the scale, and
/// the input's modification time as the end of its acquisition (a recording is last
/// written as it stops).
pub fn scan_meta(
    input: &Path,
    camera_path: &Path,
    camera: &crossline::camera::Camera,
    rec: &Reconstruction,
) -> crossline::e57::ScanMeta {
    let name = input
        .file_stem()
        .map_or_else(|| "scan".into(), |s| s.to_string_lossy().into_owned());
    crossline::e57::ScanMeta {
        name,
        description: format!(
            "crossline reconstruct of {}; scale {:?}, factor {}",
            input.display(),
            rec.report.scale_mode,
            rec.report.scale_factor
        ),
        sensor_model: Some(format!(
            "camera {}x{} calibrated in {}",
            camera.width,
            camera.height,
            camera_path.display()
        )),
        acquisition_start: None,
        acquisition_end: std::fs::metadata(input).and_then(|m| m.modified()).ok(),
        coordinate_metadata: Some(
            "camera frame, OpenCV axes (x right, y down, z forward); one global scale \
             (see the description's scale mode)"
                .into(),
        ),
    }
}

pub fn write_outputs(
    rec: &Reconstruction,
    out: &Path,
    report: Option<&Path>,
) -> anyhow::Result<()> {
    write_outputs_with(rec, out, report, &crossline::e57::ScanMeta::default())
}

/// The cloud (PLY, or E57 with `meta` when `out` ends in .e57) and the report.
pub fn write_outputs_with(
    rec: &Reconstruction,
    out: &Path,
    report: Option<&Path>,
    meta: &crossline::e57::ScanMeta,
) -> anyhow::Result<()> {
    let comments = [
        "generated by crossline reconstruct".to_string(),
        format!(
            "scale {:?} factor {}",
            rec.report.scale_mode, rec.report.scale_factor
        ),
    ];
    let written: anyhow::Result<()> = if crossline::e57::is_e57(out) {
        crossline::e57::write_e57(out, &rec.cloud, meta).map_err(Into::into)
    } else {
        crossline::ply::write_ply(out, &rec.cloud, &comments).map_err(Into::into)
    };
    written.with_context(|| format!("writing the cloud to {}", out.display()))?;
    if let Some(path) = report {
        write_report(&rec.report, path)?;
    }
    Ok(())
}

fn write_report(report: &ReconstructReport, path: &Path) -> anyhow::Result<()> {
    let json = serde_json::to_string_pretty(report)?;
    std::fs::write(path, json + "\n")
        .with_context(|| format!("writing the report to {}", path.display()))
}

pub fn print_summary(rec: &Reconstruction) {
    let r = &rec.report;
    println!(
        "frames {} (with laser {}), curves {}, planes {}, crossings {} ({} strong, {} faint)",
        r.frames,
        r.frames_with_laser,
        r.curves,
        r.planes,
        r.crossings,
        r.crossings_strong,
        r.crossings_faint
    );
    if let Some(c) = &r.calibration {
        println!(
            "planes: {} determined, {} disputed by their own crossings, {} without a \
             crossing; {} gave points ({} in the start, {} in its global subset); {} of \
             {} crossings outlying; {} estimator steps",
            c.planes_determined,
            c.planes_disputed,
            r.planes - c.planes_determined - c.planes_disputed,
            r.planes_solved,
            c.planes_in_start,
            c.planes_in_global_start,
            c.crossings_outlying,
            c.crossings,
            c.iterations
        );
        if let Some(s) = &c.spreads {
            println!(
                "spreads: crossings {:.3} px (faint {:.3} px), hand centre {:.2e} and turn \
                 {:.3}° aim, {:.3}° roll per frame²",
                s.crossing_px[0],
                s.crossing_px[1],
                s.centre,
                s.aim_rad.to_degrees(),
                s.roll_rad.to_degrees()
            );
        }
    }
    println!(
        "focal scale {:.4}{}",
        r.focal_scale,
        r.focal_scale_std
            .map(|s| format!(" ± {s:.4}"))
            .unwrap_or_default()
    );
    let scale_note = match r.scale_mode {
        ScaleMode::MedianDepth => {
            " (median depth normalised to 1: use --scale or --known-distance for real units)"
        }
        _ => "",
    };
    println!(
        "points {}, scale factor {:.6}{scale_note}",
        r.points, r.scale_factor
    );
    let t = &r.triangulation;
    println!(
        "left out: {} points whose depth their plane does not fix to {:.2} % (one \
         deviation), {} curves and {} points that their crossings disagree with, {} \
         grazing, {} behind the camera, {} at curve ends",
        r.points_undetermined,
        100.0 * r.max_depth_sigma,
        t.inconsistent_curves,
        t.inconsistent_points,
        t.grazing,
        t.behind_camera,
        t.curve_ends
    );
    let s = &r.seconds;
    println!(
        "seconds: background {:.2}, extract {:.2}, intersect {:.2}, solve {:.2}, triangulate {:.2}",
        s.background_s, s.extract_s, s.intersect_s, s.solve_s, s.triangulate_s
    );
}
