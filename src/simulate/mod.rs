//! The scan simulator: analytic scenes, the hand-held cross projector's motion, image
//! formation, and exact ground truth (`crossline simulate`).
//!
//! Owns scene files, rendering, and the simulation folder layout that `compare --truth`
//! and every test of the reconstruction read through [`load_sim_dir`]. It must not
//! depend on the reconstruction stages (`extract`, `solve`, ...): it is their truth.
//!
//! Camera and scene are fixed, so every pixel is ray-cast once ([`Simulator::new`]);
//! a frame then costs one pass of plane distances plus shading of the few pixels near
//! each stripe (see [`render`] for the stripe model). Frames are rendered from a seeded,
//! smooth function of the frame index ([`motion`]), so any frame can be rendered alone
//! and the output does not depend on the number of threads.
//!
//! # Scene files (TOML, `version = 1`)
//! Authored in a world frame of the author's choice (z up in the built-ins), in one
//! length unit (metres in the built-ins; water coefficients are per that unit). The
//! built-ins `room`, `pipes` and `bricks` (see [`builtin_scene`], `src/simulate/scenes/`)
//! are complete examples. Unknown keys are errors.
//!
//! | key | type | default | meaning |
//! |---|---|---|---|
//! | `version` | int | 1 | format version |
//! | `name` | string | required | scene name (recorded in `truth.json`) |
//! | `medium` | `"air"` / `"water"` | `"air"` | water enables attenuation, forward scatter, glow |
//! | **`[camera]`** | | | |
//! | `position`, `look_at` | `[x,y,z]` | required | camera centre and a point on the optical axis; their distance is the scene *distance* that defaults scale with |
//! | `up` | `[x,y,z]` | `[0,0,1]` | world direction that appears up in the image |
//! | `width`, `height` | int | 1920, 1080 | resolution, px |
//! | `hfov_deg` | float | | horizontal field of view (gives `fx = fy`) |
//! | `fx`, `fy` | float | | focal lengths, px (`fx` overrides `hfov_deg`; `fy` defaults to `fx`) |
//! | `cx`, `cy` | float | image centre | principal point, px (pixel centres are integers) |
//! | `distortion` | `[float]` | `[]` | OpenCV `k1, k2, p1, p2[, k3[, k4, k5, k6]]` |
//! | `psf_sigma_px` | float | 0.8 | optics blur of the stripe, px |
//! | `readout_frames` | float | 0 | rolling shutter: first row to last row, in frame periods (0: global shutter); row `y` of frame `i` sees the projector at time `i + readout_frames · y / (height − 1)`, and `truth.json` gives the planes of the middle row |
//! | **`[projector]`** | | | |
//! | `baseline` | float | 0.2 × distance | rest distance of the laser centre from the camera centre |
//! | `baseline_direction` | `[x,y,z]` | `[1,0,0]` | direction of that offset in *camera* axes (+X right, +Y down) |
//! | `wobble` | float | 0.1 × baseline | the centre stays within this radius of its (drifting) rest position |
//! | `wobble_period_frames` | float | 50 | period of the slowest wobble term |
//! | `fan_deg` | float | 75 | full opening angle of each laser fan |
//! | `colours` | `[name, name]` | `["red", "green"]` | laser 0 and laser 1: `red`, `green`, `blue` |
//! | `power` | float | 230 | stripe peak, grey levels, on white facing the laser at the scene distance (more saturates) |
//! | `beam_half_thickness` | float | 0.0006 × distance | Gaussian 1σ half thickness of the sheet |
//! | `sweep_period_frames` | float | 40 | period of the horizontal aim sweep (vertical: × golden ratio) |
//! | `sweep_overscan` | float | 1.15 | aim sweep extent relative to the image (> 1: partly off the scene) |
//! | `roll_deg`, `roll_amplitude_deg` | float | 0, 25 | roll of the cross: mean and sinusoidal amplitude |
//! | `roll_period_frames` | float | 33 | period of the roll |
//! | `roll_swing_deg` | float | 0 | amplitude of a slow swing of the roll (added to the above) |
//! | `roll_swing_period_frames` | float | 300 | its period (the scan's length: one swing there and back) |
//! | `roll_jitter_deg` | float | 0 | amplitude of a fast roll jitter (three sinusoids, weights 0.5, 0.3, 0.2) |
//! | `roll_jitter_period_frames` | float | 5 | their periods lie within 0.7-1.3 × this |
//! | `drift` | float | 0 | the rest centre wanders within this radius: a cubic B-spline through seeded control points uniform in the ball (typical excursion about half of it; step per frame at most 2 × drift / correlation) |
//! | `drift_correlation_frames` | float | 40 | spacing of those control points, frames |
//! | `walk_per_frame` | `[x,y,z]` | `[0,0,0]` | steady translation of the rest centre per frame, camera axes (frame 0 at rest) |
//! | **`[light]`** | | | |
//! | `ambient` | float | 110 | grey level of white lit face-on by the ambient light |
//! | `direction` | `[x,y,z]` | `[0.3,-0.5,1]` | world direction towards the ambient light |
//! | `flat_fraction` | float | 0.4 | share of ambient light independent of orientation |
//! | `background` | `[r,g,b]` | `[18,18,22]` | grey levels where a ray leaves the scene (air) |
//! | **`[water]`** | | | (used when `medium = "water"` or `--turbidity` > 0) |
//! | `turbidity` | float | 1 | scales scattering, forward scatter and glow |
//! | `absorption` | `[r,g,b]` | `[0.40,0.06,0.03]` | absorption per unit length (red strongest) |
//! | `scattering` | `[r,g,b]` | `[0.05,0.06,0.08]` | scattering per unit length at turbidity 1 |
//! | `backscatter` | float | 1.5 | glow grey level of a sheet seen face-on at the scene distance |
//! | `forward_scatter` | float | 0.06 | fraction of stripe light blurred per unit path |
//! | `forward_blur_mrad` | float | 4 | angular size of that blur |
//! | `veil` | `[r,g,b]` | `[8,40,48]` | colour of the water column (distant haze) |
//! | **`[[primitive]]`** | | | one table per surface |
//! | `shape` | string | required | `plane` (`point`, `normal`), `rectangle` (`corner`, `edge_u`, `edge_v`), `box` (`center`, `size`, optional `rotation_deg` = `[x,y,z]` Euler angles applied x, then y, then z), `cylinder` (`from`, `to`, `radius`, optional `capped` = true, optional `arc_deg` and `arc_towards` = `[0,0,1]`: only the part of mantle and caps within `arc_deg / 2` of `arc_towards` around the axis, e.g. 180 for a barrel vault), `sphere` (`center`, `radius`) |
//! | `name` | string | | label for error messages |
//! | `albedo` | `[r,g,b]` | `[0.7,0.7,0.7]` | reflectance in `[0, 1]` |
//! | `texture` | `none`/`checker`/`noise` | `noise` | solid texture in world coordinates |
//! | `texture_scale` | float | 0.05 × distance | texture cell size |
//! | `texture_contrast` | float | 0.5 | albedo varies in `[1 − contrast, 1]` × albedo |
//! | `texture_seed` | int | index | seed of the `noise` texture (the primitive's 0-based index by default; equal seeds let the pieces of one wall share one texture) |
//!
//! ```toml
//! name = "wall"
//! [camera]
//! position = [0, 0, 1]
//! look_at = [0, 2, 1]
//! hfov_deg = 70
//! distortion = [-0.1, 0.02, 0, 0, 0]
//! [projector]
//! baseline = 0.3
//! [[primitive]]
//! shape = "plane"
//! point = [0, 2, 0]
//! normal = [0, -1, 0]
//! texture = "checker"
//! ```
//!
//! # Simulation folder (`write_sim_dir`, format version 1)
//! | file | content |
//! |---|---|
//! | `frame_000000.png` … | RGB frames, 8 bit (`.jpg` with `--format jpeg`; one `frames.dump` with `--format dump`) |
//! | `background.png` | the same view with the lasers off (own noise) |
//! | `camera.yml`, `camera_info.yaml` | the camera, OpenCV and ROS formats |
//! | `scene.toml` | the scene as rendered (overrides applied), re-loadable |
//! | `truth.json` | [`Truth`]: version, scene, seed, camera, lasers, per-frame projector pose and planes |
//! | `depth.pfm` | per-pixel Z in camera coordinates, NaN where no surface ([`crate::pfm`]) |
//! | `lit.png` | 8-bit grey: 0 where no unshadowed stripe centre line inside a fan passed within 0.5 px of the pixel centre in any frame; elsewhere the largest peak contrast such a stripe had there (grey levels added to its strongest channel before noise and clipping, clamped to 1..=255). `compare --truth` counts every non-zero pixel as lit, and those of at least 5 × `noise_sigma` as visible. |
//! | `truth.ply` | one point per pixel that sees a surface, camera coordinates, ambient colour |
//! | `random.json` | only with `--random SEED` ([`random::Description`], `version` 1): `seed`, `kind` (`table`, `room`, `clutter`, `underwater`), `summary` (the one line `--describe` prints), `frames`, `layout`, and the drawn numbers: `distance`, camera (`width`, `height`, `fx`, `cx`, `cy`, `distortion`), cross (`lasers`, `power`, `fan_deg`), hand (`hand` = `standing`/`drifting`/`walking`, `baseline`, `baseline_direction`, `wobble_share`, `drift_share`, `walk_share` as fractions of the baseline, `roll_*`, `sweep_*`, `aim_deg_per_frame`), `medium`, `turbidity`, `ambient`, `encoding`, `jpeg_quality`, `noise_sigma` |
//!
//! `truth.json` fields: `version` (1), `scene`, `seed`, `medium`, `turbidity`,
//! `noise_sigma`, `camera` ([`Camera`]), `lasers` (`[{name, rgb}]`, laser 0 first),
//! `fan_deg`, `beam_half_thickness`, `projector_rest_centre`, `wobble`, `frames`
//! (`[{index, projector_centre, planes, axis, roll_rad, fan_dirs}]`; `planes[k] =
//! [a, b, c]` with `aX + bY + cZ = 1` in camera coordinates).

pub mod motion;
pub mod random;
pub mod realism;
pub mod render;
pub mod scene;

use std::path::{Path, PathBuf};

use image::codecs::png::{CompressionType, FilterType, PngEncoder};
use image::{ImageEncoder, RgbImage};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::camera::Camera;
use crate::pfm::PfmError;
use crate::ply::{Cloud, PlyError};

pub use motion::{Motion, ProjectorPose};
pub use realism::{Checker, Realism};
pub use render::{SimParams, Simulator};
pub use scene::{Hit, LaserColour, Medium, Scene, SceneSpec};

/// Version of `truth.json` and of the folder layout.
pub const TRUTH_VERSION: u32 = 1;

/// Names of the built-in scenes.
pub const BUILTIN_SCENES: [&str; 3] = ["room", "pipes", "bricks"];

#[derive(Debug, thiserror::Error)]
pub enum SimError {
    #[error("{path}:{line}: {message}")]
    Toml {
        path: PathBuf,
        line: usize,
        message: String,
    },
    #[error("{path}: {message}")]
    Invalid { path: PathBuf, message: String },
    #[error("cannot read or write {path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("cannot encode or decode image {path}: {source}")]
    Image {
        path: PathBuf,
        #[source]
        source: image::ImageError,
    },
    #[error("cannot encode JPEG {path}: {message}")]
    Encode { path: PathBuf, message: String },
    #[error("{path}: {source}")]
    Json {
        path: PathBuf,
        #[source]
        source: serde_json::Error,
    },
    #[error(transparent)]
    Pfm(#[from] PfmError),
    #[error(transparent)]
    Ply(#[from] PlyError),
}

/// One laser of the cross.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LaserTruth {
    pub name: String,
    /// Camera channel response to the laser.
    pub rgb: [f64; 3],
}

/// The projector and its planes in one frame (camera coordinates).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FrameTruth {
    pub index: usize,
    pub projector_centre: [f64; 3],
    /// Laser 0 and laser 1 as `[a, b, c]` with `aX + bY + cZ = 1`.
    pub planes: [[f64; 3]; 2],
    /// Unit optical axis of the projector.
    pub axis: [f64; 3],
    /// Roll of laser 0's fan about the axis, radians.
    pub roll_rad: f64,
    /// Unit in-plane fan directions of laser 0 and laser 1.
    pub fan_dirs: [[f64; 3]; 2],
}

/// The content of `truth.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Truth {
    pub version: u32,
    pub scene: String,
    pub seed: u64,
    pub medium: Medium,
    pub turbidity: f64,
    pub noise_sigma: f64,
    pub camera: Camera,
    pub lasers: Vec<LaserTruth>,
    pub fan_deg: f64,
    pub beam_half_thickness: f64,
    /// Rest position of the projector centre (camera coordinates) and the radius it
    /// wobbles within.
    pub projector_rest_centre: [f64; 3],
    pub wobble: f64,
    pub frames: Vec<FrameTruth>,
}

/// A stripe counts as visible where its peak contrast is at least this many times the
/// sensor noise's standard deviation: the Rose criterion of detectability.
pub const VISIBLE_SNR: f64 = 5.0;

/// A simulation folder loaded back.
pub struct SimDir {
    pub truth: Truth,
    pub scene: Scene,
    pub camera: Camera,
    /// Row-major `width * height`.
    pub lit: Vec<bool>,
    /// The lit pixels whose stripe peak contrast reached [`VISIBLE_SNR`] times the
    /// sensor noise in some frame.
    pub visible: Vec<bool>,
    /// Row-major `width * height` Z, NaN where no surface.
    pub depth: Vec<f32>,
}

/// What [`write_sim_dir`] wrote.
#[derive(Clone, Debug, PartialEq)]
pub struct SimSummary {
    pub frames: usize,
    pub surface_pixels: usize,
    pub lit_pixels: usize,
}

/// A built-in scene by name (`room`, `pipes`, `bricks`).
pub fn builtin_scene(name: &str) -> Option<SceneSpec> {
    let text = builtin_scene_text(name)?;
    // The built-ins are tested to parse; a failure here is a bug caught by the tests.
    SceneSpec::from_toml_str(text, Path::new(name)).ok()
}

/// The TOML text of a built-in scene.
pub fn builtin_scene_text(name: &str) -> Option<&'static str> {
    match name {
        "room" => Some(include_str!("scenes/room.toml")),
        "pipes" => Some(include_str!("scenes/pipes.toml")),
        "bricks" => Some(include_str!("scenes/bricks.toml")),
        _ => None,
    }
}

/// Largest scene file read (the built-in scenes are a few kilobytes).
pub const MAX_SCENE_FILE_BYTES: u64 = 4 << 20;

/// Loads a scene file.
pub fn load_scene_file(path: &Path) -> Result<SceneSpec, SimError> {
    let text = crate::config::read_capped(path, MAX_SCENE_FILE_BYTES).map_err(|e| match e {
        Ok(bytes) => SimError::Invalid {
            path: path.to_path_buf(),
            message: format!("{bytes} bytes is not a scene file (at most {MAX_SCENE_FILE_BYTES})"),
        },
        Err(source) => SimError::Io {
            path: path.to_path_buf(),
            source,
        },
    })?;
    SceneSpec::from_toml_str(&text, path)
}

/// The ground truth of a run of `frames` frames (no rendering).
pub fn truth_of(sim: &Simulator, frames: usize) -> Truth {
    let spec = sim.spec();
    Truth {
        version: TRUTH_VERSION,
        scene: spec.name.clone(),
        seed: sim.params().seed,
        medium: spec.medium,
        turbidity: match spec.medium {
            Medium::Water => spec.water.turbidity,
            Medium::Air => 0.0,
        },
        noise_sigma: sim.params().noise_sigma,
        camera: sim.camera().clone(),
        lasers: spec
            .projector
            .colours
            .iter()
            .map(|c| LaserTruth {
                name: c.name().to_string(),
                rgb: c.rgb(),
            })
            .collect(),
        fan_deg: spec.projector.fan_deg,
        beam_half_thickness: sim.beam_half_thickness(),
        projector_rest_centre: sim.motion().rest_centre().into(),
        wobble: sim.motion().wobble(),
        frames: (0..frames).map(|i| sim.frame_truth(i)).collect(),
    }
}

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> SimError + '_ {
    move |source| SimError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// Encodes an image as PNG with fast compression and writes it.
pub fn write_png_fast(path: &Path, img: &RgbImage) -> Result<(), SimError> {
    let mut buf = Vec::with_capacity(img.as_raw().len() / 2);
    PngEncoder::new_with_quality(&mut buf, CompressionType::Fast, FilterType::Sub)
        .write_image(
            img.as_raw(),
            img.width(),
            img.height(),
            image::ExtendedColorType::Rgb8,
        )
        .map_err(|source| SimError::Image {
            path: path.to_path_buf(),
            source,
        })?;
    std::fs::write(path, &buf).map_err(io_err(path))
}

/// How frames are stored.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FrameFormat {
    /// Lossless `frame_NNNNNN.png`.
    Png,
    /// `frame_NNNNNN.jpg` at this quality (1-100) and chroma sampling: what an MJPEG
    /// camera delivers, and ten times smaller, for fixtures.
    Jpeg { quality: u8, chroma: JpegChroma },
    /// One `frames.dump` in the recording format ([`crate::capture::dump`]), MJPEG
    /// buffers at this quality and chroma sampling, 30 frames per second of driver time.
    Dump { quality: u8, chroma: JpegChroma },
}

/// How a JPEG frame's colour is sampled.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum JpegChroma {
    /// At every pixel (4:4:4).
    #[default]
    Full,
    /// Per two pixels of a row (4:2:2), as most USB cameras' MJPEG.
    Half422,
    /// Per 2×2 pixels (4:2:0), as other cameras' MJPEG and most video.
    Half420,
}

impl JpegChroma {
    /// `444`, `422` or `420`.
    pub fn parse(s: &str) -> Option<Self> {
        match s {
            "444" | "4:4:4" => Some(Self::Full),
            "422" | "4:2:2" => Some(Self::Half422),
            "420" | "4:2:0" => Some(Self::Half420),
            _ => None,
        }
    }
}

/// Encodes an image as JPEG and writes it.
pub fn write_jpeg(
    path: &Path,
    img: &RgbImage,
    quality: u8,
    chroma: JpegChroma,
) -> Result<(), SimError> {
    let buf = encode_jpeg(img, quality, chroma).map_err(|message| SimError::Encode {
        path: path.to_path_buf(),
        message,
    })?;
    std::fs::write(path, &buf).map_err(io_err(path))
}

/// JPEG bytes of `img` at `quality` (clamped to 1-100) with `chroma`. In full chroma
/// by the `image` crate's encoder (the frames of every figure before subsampling was
/// added); subsampled by jpeg-encoder, each block's chroma averaged as libjpeg and
/// cameras do.
pub fn encode_jpeg(img: &RgbImage, quality: u8, chroma: JpegChroma) -> Result<Vec<u8>, String> {
    let mut buf = Vec::with_capacity(img.as_raw().len() / 8);
    let quality = quality.clamp(1, 100);
    let sampling = match chroma {
        JpegChroma::Full => {
            image::codecs::jpeg::JpegEncoder::new_with_quality(&mut buf, quality)
                .encode_image(img)
                .map_err(|e| e.to_string())?;
            return Ok(buf);
        }
        JpegChroma::Half422 => jpeg_encoder::SamplingFactor::R_4_2_2,
        JpegChroma::Half420 => jpeg_encoder::SamplingFactor::R_4_2_0,
    };
    let (w, h) = (
        u16::try_from(img.width()).map_err(|_| "wider than 65535 px".to_string())?,
        u16::try_from(img.height()).map_err(|_| "taller than 65535 px".to_string())?,
    );
    let mut enc = jpeg_encoder::Encoder::new(&mut buf, quality);
    enc.set_sampling_factor(sampling);
    enc.set_chroma_subsampling_method(jpeg_encoder::ChromaSubsamplingMethod::Average);
    enc.encode(img.as_raw(), w, h, jpeg_encoder::ColorType::Rgb)
        .map_err(|e| e.to_string())?;
    Ok(buf)
}

/// Renders frames in parallel, in ordered batches, and appends them to one dump as
/// MJPEG buffers; returns the lit mask.
fn write_dump(
    sim: &Simulator,
    frames: usize,
    path: &Path,
    (quality, chroma): (u8, JpegChroma),
    progress: &(impl Fn(usize) + Sync),
) -> Result<Vec<u8>, SimError> {
    use crate::capture::dump::{DumpHeader, DumpWriter};
    let cam = sim.camera();
    let n = (cam.width * cam.height) as usize;
    let dump_err = |e: crate::capture::dump::DumpError| SimError::Invalid {
        path: path.to_path_buf(),
        message: e.to_string(),
    };
    let header = DumpHeader {
        fourcc: *b"MJPG",
        width: cam.width,
        height: cam.height,
        bytes_per_line: 0,
        interval_num: 1,
        interval_den: 30,
        device: "crossline simulate".into(),
        card: sim.spec().name.clone(),
    };
    let mut writer = DumpWriter::create(path, &header).map_err(dump_err)?;
    let mut lit = vec![0u8; n];
    let batch = 2 * rayon::current_num_threads().max(1);
    for start in (0..frames).step_by(batch) {
        let rendered = (start..(start + batch).min(frames))
            .into_par_iter()
            .map(|i| {
                let mut img = RgbImage::new(cam.width, cam.height);
                let mut frame_lit = vec![0u8; n];
                sim.render_frame_into(i, &mut img, Some(&mut frame_lit));
                let jpeg =
                    encode_jpeg(&img, quality, chroma).map_err(|message| SimError::Encode {
                        path: path.to_path_buf(),
                        message,
                    })?;
                Ok((i, jpeg, frame_lit))
            })
            .collect::<Result<Vec<_>, SimError>>()?;
        for (i, jpeg, frame_lit) in rendered {
            let timestamp_nanos = i as u64 * 1_000_000_000 / 30;
            writer
                .write_frame(i as u32, timestamp_nanos, 0, &jpeg)
                .map_err(dump_err)?;
            lit.iter_mut()
                .zip(&frame_lit)
                .for_each(|(x, y)| *x = (*x).max(*y));
            progress(i + 1);
        }
    }
    writer.finish().map_err(dump_err)?;
    Ok(lit)
}

/// Renders `frames` frames and writes the whole simulation folder (see the module doc)
/// with PNG frames. `progress` is called (from any thread) with the number of frames
/// written so far.
pub fn write_sim_dir(
    sim: &Simulator,
    frames: usize,
    out: &Path,
    progress: impl Fn(usize) + Sync,
) -> Result<SimSummary, SimError> {
    write_sim_dir_as(sim, frames, out, FrameFormat::Png, progress)
}

/// [`write_sim_dir`] with a choice of frame format.
pub fn write_sim_dir_as(
    sim: &Simulator,
    frames: usize,
    out: &Path,
    format: FrameFormat,
    progress: impl Fn(usize) + Sync,
) -> Result<SimSummary, SimError> {
    std::fs::create_dir_all(out).map_err(io_err(out))?;
    let cam = sim.camera();
    let write = |name: &str, text: &str| {
        let p = out.join(name);
        std::fs::write(&p, text).map_err(io_err(&p))
    };
    write("camera.yml", &crate::camera_file::to_opencv_yaml(cam))?;
    write(
        "camera_info.yaml",
        &crate::camera_file::to_ros_yaml(cam, "crossline_sim"),
    )?;
    write("scene.toml", &sim.spec().to_toml_string()?)?;
    write_png_fast(&out.join("background.png"), &sim.background())?;

    let n = (cam.width * cam.height) as usize;
    let done = std::sync::atomic::AtomicUsize::new(0);
    let lit = if let FrameFormat::Dump { quality, chroma } = format {
        write_dump(
            sim,
            frames,
            &out.join("frames.dump"),
            (quality, chroma),
            &progress,
        )?
    } else {
        (0..frames)
            .into_par_iter()
            .try_fold(
                || (vec![0u8; n], RgbImage::new(cam.width, cam.height)),
                |(mut lit, mut img), i| {
                    sim.render_frame_into(i, &mut img, Some(&mut lit));
                    match format {
                        FrameFormat::Png => {
                            write_png_fast(&out.join(format!("frame_{i:06}.png")), &img)?
                        }
                        FrameFormat::Jpeg { quality, chroma } => write_jpeg(
                            &out.join(format!("frame_{i:06}.jpg")),
                            &img,
                            quality,
                            chroma,
                        )?,
                        FrameFormat::Dump { .. } => {}
                    }
                    let d = done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
                    progress(d);
                    Ok::<_, SimError>((lit, img))
                },
            )
            .map(|r| r.map(|(lit, _)| lit))
            .try_reduce(
                || vec![0u8; n],
                |mut a, b| {
                    a.iter_mut().zip(&b).for_each(|(x, y)| *x = (*x).max(*y));
                    Ok(a)
                },
            )?
    };

    let truth = truth_of(sim, frames);
    let p = out.join("truth.json");
    let json = serde_json::to_string_pretty(&truth).map_err(|source| SimError::Json {
        path: p.clone(),
        source,
    })?;
    std::fs::write(&p, json).map_err(io_err(&p))?;

    crate::pfm::write_pfm(&out.join("depth.pfm"), cam.width, cam.height, &sim.depth())?;

    let lit_img = image::GrayImage::from_raw(cam.width, cam.height, lit).ok_or_else(|| {
        SimError::Invalid {
            path: out.join("lit.png"),
            message: "lit mask has the wrong size (bug)".into(),
        }
    })?;
    let lit_pixels = lit_img.as_raw().iter().filter(|&&v| v > 0).count();
    let p = out.join("lit.png");
    lit_img
        .save(&p)
        .map_err(|source| SimError::Image { path: p, source })?;

    let (points, colors) = sim.surface_points();
    let surface_pixels = points.len();
    let cloud = Cloud {
        points,
        colors: Some(colors),
        ..Default::default()
    };
    crate::ply::write_ply(
        &out.join("truth.ply"),
        &cloud,
        &[format!(
            "crossline simulate ground truth: scene {}, camera coordinates",
            sim.spec().name
        )],
    )?;
    Ok(SimSummary {
        frames,
        surface_pixels,
        lit_pixels,
    })
}

/// Loads a simulation folder written by [`write_sim_dir`].
pub fn load_sim_dir(dir: &Path) -> Result<SimDir, SimError> {
    let p = dir.join("truth.json");
    let text = std::fs::read_to_string(&p).map_err(io_err(&p))?;
    let truth: Truth = serde_json::from_str(&text).map_err(|source| SimError::Json {
        path: p.clone(),
        source,
    })?;
    if truth.version != TRUTH_VERSION {
        return Err(SimError::Invalid {
            path: p,
            message: format!(
                "key `version` is {}, expected {TRUTH_VERSION}",
                truth.version
            ),
        });
    }
    let spec = load_scene_file(&dir.join("scene.toml"))?;
    let scene = Scene::from_spec(&spec);
    let camera = truth.camera.clone();
    let (w, h) = (camera.width, camera.height);

    let p = dir.join("lit.png");
    let lit_img = image::open(&p)
        .map_err(|source| SimError::Image {
            path: p.clone(),
            source,
        })?
        .to_luma8();
    if lit_img.dimensions() != (w, h) {
        return Err(SimError::Invalid {
            path: p,
            message: format!(
                "mask is {}x{}, the camera is {w}x{h}",
                lit_img.width(),
                lit_img.height()
            ),
        });
    }
    // Any non-zero value is lit; the value is the stripe's peak contrast (files of
    // older versions hold 255 only, which reads as visible everywhere).
    let lit = lit_img.as_raw().iter().map(|&v| v > 0).collect();
    let floor = (VISIBLE_SNR * truth.noise_sigma).max(1.0);
    let visible = lit_img
        .as_raw()
        .iter()
        .map(|&v| v as f64 >= floor)
        .collect();

    let p = dir.join("depth.pfm");
    let depth = crate::pfm::read_pfm(&p)?;
    if (depth.width, depth.height) != (w, h) {
        return Err(SimError::Invalid {
            path: p,
            message: format!(
                "depth map is {}x{}, the camera is {w}x{h}",
                depth.width, depth.height
            ),
        });
    }
    Ok(SimDir {
        truth,
        scene,
        camera,
        lit,
        visible,
        depth: depth.data,
    })
}

#[cfg(test)]
mod tests;
