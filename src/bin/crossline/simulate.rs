//! `crossline simulate`: render a scan of an analytic scene with exact ground truth.

use std::io::IsTerminal;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use anyhow::{bail, Context};
use crossline::simulate::{
    builtin_scene, load_scene_file, write_sim_dir_as, FrameFormat, LaserColour, Medium, SimParams,
    Simulator, BUILTIN_SCENES,
};

/// Render the image sequence a fixed camera would record of a hand-held cross line
/// laser sweeping a scene, with exact ground truth.
///
/// The scene is a built-in (room: a room corner at ~3.7 m; pipes: an underwater pipe
/// rig at ~2.9 m; bricks: toy bricks on a table at ~0.6 m) or a scene TOML file (every
/// key is documented in the `crossline::simulate` module docs; the built-ins are
/// examples, and every run writes its scene as DIR/scene.toml).
///
/// DIR receives frame_000000.png..., background.png (lasers off), camera.yml
/// (OpenCV), camera_info.yaml (ROS), scene.toml, truth.json (projector pose and both
/// laser planes per frame, camera coordinates), depth.pfm (per-pixel Z), lit.png
/// (pixels a perfect scanner covers) and truth.ply (dense ground-truth cloud).
///
/// Example:
///
///   crossline simulate --scene pipes --frames 120 --turbidity 2 --out sim-pipes
#[derive(clap::Args)]
#[command(verbatim_doc_comment)]
pub struct Args {
    /// Built-in scene name (room, pipes, bricks) or path to a scene TOML file.
    #[arg(long, value_name = "NAME|FILE")]
    scene: String,
    /// Number of frames to render.
    #[arg(long, value_name = "N", default_value_t = 120)]
    frames: usize,
    /// Seed of the projector motion and the sensor noise; the same seed gives the
    /// same images on any number of threads.
    #[arg(long, value_name = "S", default_value_t = 1)]
    seed: u64,
    /// Output folder (created if missing; existing files are overwritten).
    #[arg(long, value_name = "DIR")]
    out: PathBuf,
    /// Frame file format: `png` (lossless), `jpeg` (frame_NNNNNN.jpg at
    /// --jpeg-quality, default 92: what an MJPEG camera delivers) or `dump` (one
    /// DIR/frames.dump of MJPEG buffers in the recording format, for `reconstruct
    /// --input DIR/frames.dump`).
    #[arg(long, default_value = "png", value_name = "png|jpeg|dump")]
    format: String,
    /// Water turbidity: > 0 renders under water (attenuation, forward scatter, glow
    /// of the laser sheets) with the scene's scattering scaled by T; 1 is the scene's
    /// nominal water. Overrides the scene's [water] turbidity.
    #[arg(long, value_name = "T")]
    turbidity: Option<f64>,
    /// Standard deviation of the Gaussian sensor noise, grey levels (0 = none).
    #[arg(long, value_name = "SIGMA", default_value_t = 2.0)]
    noise: f64,
    /// JPEG quality Q (1-100): with --format png, every image passes through JPEG
    /// compression before it is saved as PNG, to add compression artefacts; with
    /// --format jpeg, the quality of the JPEG frames.
    #[arg(long, value_name = "Q", value_parser = clap::value_parser!(u8).range(1..=100))]
    jpeg_quality: Option<u8>,
    /// Image width in pixels (overrides the scene; the field of view is kept).
    #[arg(long, value_name = "PX")]
    width: Option<u32>,
    /// Image height in pixels (overrides the scene; default: keeps the aspect ratio).
    #[arg(long, value_name = "PX")]
    height: Option<u32>,
    /// Laser colours, laser 0 first: red-green or blue-green (overrides the scene).
    #[arg(long, value_name = "PAIR")]
    colours: Option<String>,
    /// Worker threads (default: all cores).
    #[arg(long, value_name = "N")]
    threads: Option<usize>,
}

pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    let format = match args.format.as_str() {
        "png" => FrameFormat::Png,
        "jpeg" | "jpg" => FrameFormat::Jpeg {
            quality: args.jpeg_quality.unwrap_or(92),
        },
        "dump" => FrameFormat::Dump {
            quality: args.jpeg_quality.unwrap_or(92),
        },
        other => bail!("--format {other}: expected png, jpeg or dump"),
    };
    let mut spec = match builtin_scene(&args.scene) {
        Some(spec) => spec,
        None => {
            let path = PathBuf::from(&args.scene);
            if !path.exists() {
                bail!(
                    "--scene {}: neither a built-in scene ({}) nor an existing file",
                    args.scene,
                    BUILTIN_SCENES.join(", ")
                );
            }
            load_scene_file(&path).context("loading the scene")?
        }
    };
    if args.width.is_some() || args.height.is_some() {
        let c = &spec.camera;
        let w = args.width.unwrap_or(c.width);
        let h = args.height.unwrap_or_else(|| {
            ((c.height as f64 * w as f64 / c.width as f64).round() as u32).max(1)
        });
        if w == 0 || h == 0 {
            bail!("--width and --height must be positive");
        }
        spec = spec.with_resolution(w, h);
    }
    if let Some(pair) = &args.colours {
        spec.projector.colours = match pair.as_str() {
            "red-green" => [LaserColour::Red, LaserColour::Green],
            "blue-green" => [LaserColour::Blue, LaserColour::Green],
            other => bail!("--colours {other}: expected red-green or blue-green"),
        };
    }
    if let Some(t) = args.turbidity {
        if !(t >= 0.0 && t.is_finite()) {
            bail!("--turbidity {t}: expected a number >= 0");
        }
        spec.water.turbidity = t;
        if t > 0.0 {
            spec.medium = Medium::Water;
        }
    }
    if !(args.noise >= 0.0 && args.noise.is_finite()) {
        bail!("--noise {}: expected a number >= 0", args.noise);
    }
    let params = SimParams {
        seed: args.seed,
        noise_sigma: args.noise,
        // With JPEG frames the compression happens once, when they are written.
        jpeg_quality: match format {
            FrameFormat::Png => args.jpeg_quality,
            FrameFormat::Jpeg { .. } | FrameFormat::Dump { .. } => None,
        },
    };
    let mut pool = rayon::ThreadPoolBuilder::new();
    if let Some(n) = args.threads {
        pool = pool.num_threads(n);
    }
    let pool = pool.build().context("starting worker threads")?;

    let start = Instant::now();
    let bar = if std::io::stderr().is_terminal() {
        let bar = indicatif::ProgressBar::new(args.frames as u64);
        if let Ok(style) = indicatif::ProgressStyle::with_template(
            "{msg} [{bar:40}] {pos}/{len} frames, {per_sec}, eta {eta}",
        ) {
            bar.set_style(style.progress_chars("=> "));
        }
        bar.set_message("rendering");
        bar
    } else {
        indicatif::ProgressBar::hidden()
    };
    let summary = pool.install(|| {
        let sim = Simulator::new(&spec, &params).context("preparing the scene")?;
        tracing::debug!("scene ray-cast in {:.2} s", start.elapsed().as_secs_f64());
        write_sim_dir_as(&sim, args.frames, &args.out, format, |n| {
            bar.set_position(n as u64)
        })
        .with_context(|| format!("writing the simulation to {}", args.out.display()))
    })?;
    bar.finish_and_clear();
    let secs = start.elapsed().as_secs_f64();
    tracing::info!(
        "{} frames of scene {} ({}x{}) in {:.1} s ({:.1} frames/s) to {}; {} surface pixels, {} lit",
        summary.frames,
        spec.name,
        spec.camera.width,
        spec.camera.height,
        secs,
        summary.frames as f64 / secs.max(1e-9),
        args.out.display(),
        summary.surface_pixels,
        summary.lit_pixels
    );
    Ok(ExitCode::SUCCESS)
}
