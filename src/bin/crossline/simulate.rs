//! `crossline simulate`: render a scan of an analytic scene with exact ground truth.

use std::io::IsTerminal;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use anyhow::{bail, Context};
use crossline::simulate::random::{self, DrawnScan};
use crossline::simulate::{
    builtin_scene, load_scene_file, write_sim_dir_as, FrameFormat, JpegChroma, LaserColour, Medium,
    SceneSpec, SimParams, Simulator, BUILTIN_SCENES,
};

/// Render the image sequence a fixed camera would record of a hand-held cross line
/// laser sweeping a scene, with exact ground truth.
///
/// The scene is a built-in (room: a room corner at ~3.7 m; pipes: an underwater pipe
/// rig at ~2.9 m; bricks: toy bricks on a table at ~0.6 m), a scene TOML file (every
/// key is documented in the `crossline::simulate` module docs; the built-ins are
/// examples, and every run writes its scene as DIR/scene.toml), or a random scan
/// configuration drawn from a seed (--random): a table top, a room, clutter or an
/// underwater scene with a random layout, camera (720p or 1080p, focal length, lens
/// distortion), laser pair, hand path (baseline, wobble, drift or walk, roll swing,
/// aim sweep), light and encoding. The same seed always draws the same
/// configuration, so a set of seeds is a fixed benchmark of scans the algorithms were
/// not tuned on. --describe prints the one-line summary of a draw without rendering.
///
/// DIR receives frame_000000.png..., background.png (lasers off), camera.yml
/// (OpenCV), camera_info.yaml (ROS), scene.toml, truth.json (projector pose and both
/// laser planes per frame, camera coordinates), depth.pfm (per-pixel Z), lit.png
/// (pixels a perfect scanner covers) and truth.ply (dense ground-truth cloud); with
/// --random also random.json (seed, kind, summary and the drawn parameters).
///
/// Examples:
///
///   crossline simulate --scene pipes --frames 120 --turbidity 2 --out sim-pipes
///   crossline simulate --random 7 --describe
///   crossline simulate --random 7 --frames 300 --out sim-7
///   for s in $(seq 1 24); do crossline simulate --random $s --describe; done
#[derive(clap::Args)]
#[command(verbatim_doc_comment)]
pub struct Args {
    /// Built-in scene name (room, pipes, bricks) or path to a scene TOML file.
    #[arg(
        long,
        value_name = "NAME|FILE",
        required_unless_present = "random",
        conflicts_with = "random"
    )]
    scene: Option<String>,
    /// Draw a random scan configuration from seed S instead of a --scene. The flags
    /// below that are given override the draw (--format, --noise, --width, --height,
    /// --colours, --turbidity, --seed, --jpeg-quality); the rest is drawn.
    #[arg(long, value_name = "S")]
    random: Option<u64>,
    /// With --random: print the draw's one-line summary and exit without rendering.
    #[arg(long, requires = "random")]
    describe: bool,
    /// Number of frames to render (with --random, also the scan length that the roll
    /// swings and the walk are drawn for).
    #[arg(long, value_name = "N", default_value_t = 120)]
    frames: usize,
    /// Seed of the projector motion and the sensor noise; the same seed gives the
    /// same images on any number of threads [default: 1, or the --random seed].
    #[arg(long, value_name = "S")]
    seed: Option<u64>,
    /// Output folder (created if missing; existing files are overwritten).
    #[arg(long, value_name = "DIR", required_unless_present = "describe")]
    out: Option<PathBuf>,
    /// Frame file format: `png` (lossless), `jpeg` (frame_NNNNNN.jpg at
    /// --jpeg-quality, default 92: what an MJPEG camera delivers) or `dump` (one
    /// DIR/frames.dump of MJPEG buffers in the recording format, for `reconstruct
    /// --input DIR/frames.dump`) [default: png, or the --random draw's png or jpeg].
    #[arg(long, value_name = "png|jpeg|dump")]
    format: Option<String>,
    /// Water turbidity: > 0 renders under water (attenuation, forward scatter, glow
    /// of the laser sheets) with the scene's scattering scaled by T; 1 is the scene's
    /// nominal water. Overrides the scene's [water] turbidity.
    #[arg(long, value_name = "T")]
    turbidity: Option<f64>,
    /// Standard deviation of the Gaussian sensor noise, grey levels (0 = none)
    /// [default: 2, or the --random draw's].
    #[arg(long, value_name = "SIGMA")]
    noise: Option<f64>,
    /// JPEG quality Q (1-100): with --format png, every image passes through JPEG
    /// compression before it is saved as PNG, to add compression artefacts; with
    /// --format jpeg, the quality of the JPEG frames.
    #[arg(long, value_name = "Q", value_parser = clap::value_parser!(u8).range(1..=100))]
    jpeg_quality: Option<u8>,
    /// Chroma sampling of JPEG frames (--format jpeg or dump): 444 (colour at every
    /// pixel), 422 (per two pixels of a row, as most USB cameras' MJPEG) or 420 (per
    /// 2x2 pixels, as other cameras' MJPEG and most video) [default: 444].
    #[arg(long, value_name = "444|422|420")]
    chroma: Option<String>,
    /// Image width in pixels (overrides the scene; the field of view is kept).
    #[arg(long, value_name = "PX")]
    width: Option<u32>,
    /// Image height in pixels (overrides the scene; default: keeps the aspect ratio).
    #[arg(long, value_name = "PX")]
    height: Option<u32>,
    /// Laser colours, laser 0 first: red-green or blue-green (overrides the scene).
    #[arg(long, value_name = "PAIR")]
    colours: Option<String>,
    /// Rolling shutter: the time from the first row's exposure to the last one's, in
    /// frame periods (overrides the scene; 0 is a global shutter, a webcam at 30 fps
    /// reads out in 0.5-0.9). crossline's estimator assumes a global shutter.
    #[arg(long, value_name = "F")]
    readout_frames: Option<f64>,
    /// Worker threads (default: all cores).
    #[arg(long, value_name = "N")]
    threads: Option<usize>,
}

/// Most frames one run renders (the truth of each is kept in memory).
const MAX_FRAMES: usize = 1_000_000;

/// The scene named by --scene: a built-in or a file.
fn load_scene(name: &str) -> anyhow::Result<SceneSpec> {
    if let Some(spec) = builtin_scene(name) {
        return Ok(spec);
    }
    let path = PathBuf::from(name);
    if !path.exists() {
        bail!(
            "--scene {name}: neither a built-in scene ({}) nor an existing file",
            BUILTIN_SCENES.join(", ")
        );
    }
    load_scene_file(&path).context("loading the scene")
}

pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    if args.describe && args.random.is_none() {
        bail!("--describe describes a --random draw: give --random SEED");
    }
    if !(1..=MAX_FRAMES).contains(&args.frames) {
        bail!("--frames {}: expected 1 to {MAX_FRAMES}", args.frames);
    }
    let mut drawn: Option<DrawnScan> = args.random.map(|seed| random::draw(seed, args.frames));
    let chroma = match args.chroma.as_deref() {
        None => JpegChroma::Full,
        Some(s) => JpegChroma::parse(s)
            .with_context(|| format!("--chroma {s}: expected 444, 422 or 420"))?,
    };
    let format = match args.format.as_deref() {
        Some("png") => FrameFormat::Png,
        Some("jpeg" | "jpg") => FrameFormat::Jpeg {
            quality: args.jpeg_quality.unwrap_or(92),
            chroma,
        },
        Some("dump") => FrameFormat::Dump {
            quality: args.jpeg_quality.unwrap_or(92),
            chroma,
        },
        Some(other) => bail!("--format {other}: expected png, jpeg or dump"),
        None => match drawn.as_ref().map(|d| d.format) {
            Some(FrameFormat::Jpeg { quality, .. }) => FrameFormat::Jpeg {
                quality: args.jpeg_quality.unwrap_or(quality),
                chroma,
            },
            Some(other) => other,
            None => FrameFormat::Png,
        },
    };
    if args.chroma.is_some() && format == FrameFormat::Png {
        bail!("--chroma samples JPEG frames: give --format jpeg or dump");
    }
    let mut spec = match (&drawn, &args.scene) {
        (Some(d), _) => d.spec.clone(),
        (None, Some(name)) => load_scene(name)?,
        // clap requires one of the two.
        (None, None) => bail!("give --scene or --random"),
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
    if let Some(f) = args.readout_frames {
        if !(0.0..=1.0).contains(&f) {
            bail!("--readout-frames {f}: expected a share of the frame period, 0 to 1");
        }
        spec.camera.readout_frames = f;
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
    let noise = args
        .noise
        .or(drawn.as_ref().map(|d| d.params.noise_sigma))
        .unwrap_or(2.0);
    if !(noise >= 0.0 && noise.is_finite()) {
        bail!("--noise {noise}: expected a number >= 0");
    }
    let params = SimParams {
        seed: args
            .seed
            .or(drawn.as_ref().map(|d| d.params.seed))
            .unwrap_or(1),
        noise_sigma: noise,
        // With JPEG frames the compression happens once, when they are written.
        jpeg_quality: match format {
            FrameFormat::Png => args.jpeg_quality,
            FrameFormat::Jpeg { .. } | FrameFormat::Dump { .. } => None,
        },
        realism: drawn
            .as_ref()
            .map_or_else(crossline::simulate::Realism::none, |d| {
                d.params.realism.clone()
            }),
    };
    if let Some(d) = &mut drawn {
        d.spec = spec.clone();
        d.params = params.clone();
        d.format = format;
        d.summary = d.summarise();
        if args.describe {
            println!("{}", d.summary);
            return Ok(ExitCode::SUCCESS);
        }
    }
    let Some(out) = args.out else {
        bail!("--out DIR is required");
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
        write_sim_dir_as(&sim, args.frames, &out, format, |n| {
            bar.set_position(n as u64)
        })
        .with_context(|| format!("writing the simulation to {}", out.display()))
    })?;
    bar.finish_and_clear();
    if let Some(d) = &drawn {
        d.write_description(&out)
            .with_context(|| format!("writing {}", out.join("random.json").display()))?;
        tracing::info!("random scan {}: {}", d.seed, d.summary);
    }
    let secs = start.elapsed().as_secs_f64();
    tracing::info!(
        "{} frames of scene {} ({}x{}) in {:.1} s ({:.1} frames/s) to {}; {} surface pixels, {} lit",
        summary.frames,
        spec.name,
        spec.camera.width,
        spec.camera.height,
        secs,
        summary.frames as f64 / secs.max(1e-9),
        out.display(),
        summary.surface_pixels,
        summary.lit_pixels
    );
    Ok(ExitCode::SUCCESS)
}
