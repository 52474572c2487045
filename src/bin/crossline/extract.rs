//! `crossline extract`: the laser curves of one frame, as a curves file (JSON, format in
//! `crossline::extract`) and an overlay image.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{bail, Context};
use crossline::camera::Camera;
use crossline::capture::chroma::Rebuild;
use crossline::extract::{Background, Curve, CurvesFile, ExtractParams, Extractor, LaserColour};
use image::RgbImage;

/// Extract the laser curves of one frame.
///
/// The background (a laser-off frame) is subtracted first; without one, each frame is
/// measured against its own local background (a robust estimate wider than the
/// stripe), and a ridge counts by the part of its light that has the laser's colour
/// (white and grey texture counts for nothing). One frame cannot tell a stripe from a
/// thin thing of the laser's own colour (a blue box's rim under a blue laser): give a
/// laser-off frame where the view has such things.
#[derive(clap::Args)]
pub struct Args {
    /// The frame (PNG or JPEG).
    #[arg(long)]
    input: PathBuf,
    /// A laser-off frame of the same view. Without it, the frame's own local
    /// background: on the simulator's realistic frames, 1.9 % of the points were false
    /// (things of a laser's own colour) against 0.2 % with one.
    #[arg(long)]
    background: Option<PathBuf>,
    /// Camera calibration; without it, an undistorted 60° camera of the frame's size.
    #[arg(long)]
    camera: Option<PathBuf>,
    /// crossline.toml whose [extract] table sets the extraction parameters.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Where to write the curves (JSON).
    #[arg(long, default_value = "curves.json")]
    out: PathBuf,
    /// Where to write an overlay: the frame darkened, curves in their laser's colour.
    #[arg(long)]
    overlay: Option<PathBuf>,
    /// Overlay: the frame as it is on the left, the curves drawn on it on the right.
    #[arg(long)]
    side_by_side: bool,
    /// Laser colours, overriding the config: red-green, blue-green, red, green or blue.
    #[arg(long)]
    lasers: Option<String>,
    /// Stripe width in pixels (full width at half maximum), overriding the config; by
    /// default the width is measured per tile.
    #[arg(long)]
    line_width_px: Option<f64>,
}

/// The lasers of a `--lasers NAME` option (a preset of [`LaserColour::preset`]).
pub fn lasers_arg(name: &str) -> anyhow::Result<Vec<LaserColour>> {
    LaserColour::preset(name).with_context(|| {
        format!("--lasers {name:?}: expected red-green, blue-green, red, green or blue")
    })
}

pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    let mut params = match &args.config {
        Some(path) => load_params(path)?,
        None => ExtractParams::default(),
    };
    if let Some(name) = &args.lasers {
        params.lasers = lasers_arg(name)?;
    }
    if let Some(w) = args.line_width_px {
        params.line_width_px = Some(w);
    }
    let (frame, chroma) = load_rgb(&args.input)?;
    let background = match &args.background {
        Some(path) => Background::from_image(load_rgb(path)?.0),
        None => Background::local(frame.width(), frame.height()),
    };
    let camera = match &args.camera {
        Some(path) => {
            let camera = crossline::camera_file::load(path)
                .with_context(|| format!("loading the camera from {}", path.display()))?;
            if (camera.width, camera.height) != frame.dimensions() {
                bail!(
                    "{} is {}x{}, but the camera file {} is for {}x{}",
                    args.input.display(),
                    frame.width(),
                    frame.height(),
                    path.display(),
                    camera.width,
                    camera.height
                );
            }
            camera
        }
        None => Camera::with_fov(frame.width(), frame.height(), 60f64.to_radians()),
    };
    let mut extractor = Extractor::new(&params, &camera).context("extraction parameters")?;
    // A JPEG says how its colour was sampled; a PNG's is read off its pixels.
    if let Some(rebuild) = chroma {
        extractor.know_chroma(rebuild);
    }
    let curves = extractor
        .try_extract(&frame, &background)
        .with_context(|| format!("extracting {}", args.input.display()))?;
    let points: usize = curves.iter().map(|c| c.points_px.len()).sum();
    let stats = extractor.stats();
    tracing::debug!("time per stage: {:?}", extractor.stage_times());
    tracing::info!(
        "{}: {} curves, {} points ({} on a clipped channel){}",
        args.input.display(),
        curves.len(),
        points,
        stats.clipped_points,
        if background.is_local() {
            ", against the frame's local background"
        } else {
            ""
        }
    );
    if let Some(path) = &args.overlay {
        let overlay = draw_overlay(&frame, &curves, &params.lasers, args.side_by_side);
        overlay
            .save(path)
            .with_context(|| format!("writing overlay {}", path.display()))?;
    }
    let file = CurvesFile::new(frame.width(), frame.height(), &params.lasers, curves);
    std::fs::write(&args.out, file.to_json())
        .with_context(|| format!("writing curves {}", args.out.display()))?;
    Ok(ExitCode::SUCCESS)
}

/// An image file in RGB, and for a JPEG how its colour was sampled (its header says,
/// [`crossline::capture::chroma::of_jpeg`]); the file is read once for both.
fn load_rgb(path: &Path) -> anyhow::Result<(RgbImage, Option<[Rebuild; 2]>)> {
    let context = || format!("reading image {}", path.display());
    let bytes = std::fs::read(path).with_context(context)?;
    let rgb = image::load_from_memory(&bytes)
        .with_context(context)?
        .to_rgb8();
    Ok((rgb, crossline::capture::chroma::of_jpeg(&bytes)))
}

/// The `[extract]` table of a crossline.toml (defaults for absent keys).
fn load_params(path: &Path) -> anyhow::Result<ExtractParams> {
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("reading config {}", path.display()))?;
    parse_params(&text).with_context(|| format!("config {}", path.display()))
}

fn parse_params(text: &str) -> anyhow::Result<ExtractParams> {
    #[derive(serde::Deserialize)]
    struct File {
        #[serde(default)]
        extract: ExtractParams,
    }
    // Other tables belong to other stages; only [extract] is checked strictly here.
    let table: toml::Table = toml::from_str(text)?;
    let extract = toml::Table::from_iter(
        table
            .get("extract")
            .map(|v| ("extract".to_string(), v.clone())),
    );
    let file: File = extract.try_into().context("[extract]")?;
    Ok(file.extract)
}

/// Half width (px) of the overlay's curves: at least 1 (lines 3 px wide, visible at
/// full size), and a pixel more per 1000 px of the frame's larger side.
fn overlay_half_width(frame: &RgbImage) -> i64 {
    1 + frame.width().max(frame.height()) as i64 / 1000
}

/// The frame at 40 % brightness with each curve drawn in its laser's display colour,
/// [`overlay_half_width`] thick; with `side_by_side`, the frame as it is to its left.
fn draw_overlay(
    frame: &RgbImage,
    curves: &[Curve],
    lasers: &[LaserColour],
    side_by_side: bool,
) -> RgbImage {
    let mut out = frame.clone();
    for p in out.pixels_mut() {
        for c in p.0.iter_mut() {
            *c = (*c as u16 * 2 / 5) as u8;
        }
    }
    let (w, h) = (out.width() as i64, out.height() as i64);
    let r = overlay_half_width(frame);
    for curve in curves {
        let colour = lasers
            .get(curve.laser as usize)
            .map_or([255, 255, 255], |l| l.display_rgb);
        for seg in curve.points_px.windows(2) {
            let (a, b) = (seg[0], seg[1]);
            let steps = ((b[0] - a[0]).abs().max((b[1] - a[1]).abs()).ceil() as usize).max(1);
            for i in 0..=steps {
                let t = i as f32 / steps as f32;
                let x = (a[0] + t * (b[0] - a[0])).round() as i64;
                let y = (a[1] + t * (b[1] - a[1])).round() as i64;
                for yy in y - r..=y + r {
                    for xx in x - r..=x + r {
                        if (0..w).contains(&xx) && (0..h).contains(&yy) {
                            out.put_pixel(xx as u32, yy as u32, image::Rgb(colour));
                        }
                    }
                }
            }
        }
    }
    if !side_by_side {
        return out;
    }
    let mut both = RgbImage::new(2 * frame.width(), frame.height());
    image::imageops::replace(&mut both, frame, 0, 0);
    image::imageops::replace(&mut both, &out, frame.width() as i64, 0);
    both
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_camera_file_is_used_and_must_match_the_frame() {
        let sim = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/sim-bricks");
        let dir = tempfile::tempdir().expect("tempdir");
        // Frame 40 of the recorded fixture, as a PNG.
        let (frames, _) = crossline::reconstruct::FrameSource::open(&sim.join("frames.dump"))
            .expect("fixture dump");
        let camera = crossline::camera_file::load(&sim.join("camera.yml")).expect("camera");
        let frame = dir.path().join("frame.png");
        frames
            .decode(40, &camera)
            .expect("decode")
            .save(&frame)
            .expect("png");
        let args = |camera: PathBuf| Args {
            input: frame.clone(),
            background: Some(sim.join("background.png")),
            camera: Some(camera),
            config: None,
            out: dir.path().join("curves.json"),
            overlay: None,
            side_by_side: false,
            lasers: None,
            line_width_px: None,
        };
        run(args(sim.join("camera.yml"))).expect("extract with the camera file");
        let file = CurvesFile::load(&dir.path().join("curves.json")).expect("curves file");
        assert!(!file.curves.is_empty());
        // Undistorted points come from the file's intrinsics, not a default camera.
        let c = &file.curves[0];
        let back = camera.pixel_from_normalized(c.points[0][0], c.points[0][1]);
        let px = c.points_px[0];
        assert!(
            (back[0] - f64::from(px[0])).abs() < 1e-3 && (back[1] - f64::from(px[1])).abs() < 1e-3,
            "{back:?} vs {px:?}"
        );
        // A camera file for another size is refused, naming both.
        let other = dir.path().join("other.yml");
        let text = std::fs::read_to_string(sim.join("camera.yml")).expect("camera text");
        std::fs::write(&other, text.replace("image_width: 480", "image_width: 640"))
            .expect("write");
        let err = format!("{:#}", run(args(other)).expect_err("size mismatch"));
        assert!(err.contains("480x270") && err.contains("640x270"), "{err}");
    }

    #[test]
    fn real_pair_writes_curves_and_overlay() {
        let fixtures = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/real");
        let dir = tempfile::tempdir().expect("tempdir");
        let args = Args {
            input: fixtures.join("laser.png"),
            background: Some(fixtures.join("laser_background.png")),
            camera: None,
            config: None,
            out: dir.path().join("curves.json"),
            overlay: Some(dir.path().join("overlay.png")),
            side_by_side: false,
            lasers: Some("red".into()),
            line_width_px: None,
        };
        run(args).expect("extract");
        let file = CurvesFile::load(&dir.path().join("curves.json")).expect("curves file");
        assert_eq!((file.width, file.height), (960, 1280));
        assert_eq!(file.lasers, vec!["red".to_string()]);
        let length: f64 = file.curves.iter().map(|c| c.length_px()).sum();
        assert!(length > 1000.0, "{length}");
        let overlay = image::open(dir.path().join("overlay.png"))
            .expect("overlay")
            .to_rgb8();
        assert_eq!(overlay.dimensions(), (960, 1280));
        // A curve point is drawn in red on the darkened frame.
        let p = file.curves[0].points_px[0];
        let px = overlay
            .get_pixel(p[0].round() as u32, p[1].round() as u32)
            .0;
        assert_eq!(px, LaserColour::red().display_rgb);
        // Drawn thick enough to see: the pixels a line width beside it too.
        let r = overlay_half_width(&overlay) as u32;
        assert!(r >= 1);
        let (x, y) = (p[0].round() as u32, p[1].round() as u32);
        let beside = [
            (x + r, y),
            (x.saturating_sub(r), y),
            (x, y + r),
            (x, y.saturating_sub(r)),
        ];
        assert!(
            beside
                .iter()
                .all(|&(u, v)| overlay.get_pixel(u, v).0 == LaserColour::red().display_rgb),
            "curve drawn one pixel thin"
        );
    }

    #[test]
    fn side_by_side_overlay_holds_the_frame_and_the_curves() {
        let frame = RgbImage::from_pixel(40, 30, image::Rgb([100, 100, 100]));
        let curve = Curve {
            laser: 0,
            points_px: vec![[5.0, 15.0], [35.0, 15.0]],
            points: vec![[0.0, 0.0]; 2],
            strength: vec![50.0; 2],
            polyline: Vec::new(),
        };
        let out = draw_overlay(&frame, &[curve], &[LaserColour::red()], true);
        assert_eq!(out.dimensions(), (80, 30));
        assert_eq!(out.get_pixel(20, 15).0, [100, 100, 100]);
        assert_eq!(out.get_pixel(60, 14).0, LaserColour::red().display_rgb);
        assert_eq!(out.get_pixel(60, 16).0, LaserColour::red().display_rgb);
        assert_eq!(out.get_pixel(60, 5).0, [40, 40, 40]);
    }

    #[test]
    fn lasers_option_names_a_preset_or_says_what_it_expects() {
        let lasers = lasers_arg("blue-green").expect("a preset");
        assert_eq!(lasers.len(), 2);
        assert_eq!(lasers[0].name, "blue");
        let err = format!("{:#}", lasers_arg("purple").expect_err("no such preset"));
        assert!(
            err.contains("\"purple\"") && err.contains("blue-green"),
            "{err}"
        );
    }

    #[test]
    fn config_extract_table() {
        let p = parse_params("[solve]\nx = 1\n[extract]\nline_width_px = 7.0\n").expect("parse");
        assert_eq!(p.line_width_px, Some(7.0));
        let p = parse_params("[solve]\nx = 1\n").expect("parse");
        assert_eq!(p, ExtractParams::default());
        let err = parse_params("[extract]\nline_width = 7.0\n").expect_err("unknown key");
        assert!(format!("{err:#}").contains("line_width"), "{err:#}");
    }
}
