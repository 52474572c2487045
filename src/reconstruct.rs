//! Offline reconstruction: a recording (a folder of frames or a dump) in, a coloured
//! point cloud out.
//!
//! Owns where offline frames come from ([`FrameSource`]) and the wiring of the stages
//! over them: the background ([`crate::extract::Background`]: a laser-off frame, or the
//! per-pixel temporal median of frames sampled over the recording), extraction in
//! parallel over frames ([`crate::extract::Extractor`]), then the stages shared with the
//! live daemon ([`crate::pipeline::reconstruct_curves`]).

use std::path::{Path, PathBuf};
use std::time::Instant;

use image::RgbImage;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::camera::Camera;
use crate::capture::dump::{DumpError, DumpHeader, DumpReader};
use crate::cloud::ScaleMode;
use crate::config::Config;
use crate::extract::{Background, Curve, Extractor};
pub use crate::pipeline::{
    reconstruct_curves, PlaneSource, ReconstructReport, Reconstruction, StageTimes, REPORT_VERSION,
};

#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct BackgroundParams {
    /// Frames sampled evenly over the sequence for the temporal median background
    /// (ignored when a laser-off frame is given). More frames cost time once; an odd
    /// number avoids averaging two middle values.
    pub median_frames: usize,
}

impl Default for BackgroundParams {
    fn default() -> Self {
        Self { median_frames: 25 }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum ReconstructError {
    #[error("cannot list frames in {path}: {source}")]
    List {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("no frames (.png, .jpg, .jpeg) in {0}")]
    NoFrames(PathBuf),
    #[error("cannot decode frame {path}: {source}")]
    Decode {
        path: PathBuf,
        #[source]
        source: image::ImageError,
    },
    #[error("frame {path} is {got_w}x{got_h}, but the camera file says {want_w}x{want_h}")]
    Size {
        path: PathBuf,
        got_w: u32,
        got_h: u32,
        want_w: u32,
        want_h: u32,
    },
    #[error("extraction")]
    Extract(#[from] crate::extract::ExtractError),
    #[error("reading the dump")]
    Dump(#[from] DumpError),
    #[error("internal error: {0}")]
    Internal(&'static str),
    #[error(transparent)]
    Pipeline(#[from] crate::pipeline::PipelineError),
}

/// The frames of a sequence: every `.png`/`.jpg`/`.jpeg` in a folder, in name order. When
/// the folder holds `frame_*` images (as `crossline simulate` writes), only those count,
/// so a background or mask beside them is not taken for a frame.
pub fn list_frames(dir: &Path) -> Result<Vec<PathBuf>, ReconstructError> {
    let entries = std::fs::read_dir(dir).map_err(|source| ReconstructError::List {
        path: dir.to_path_buf(),
        source,
    })?;
    let mut all = Vec::new();
    for entry in entries {
        let path = entry
            .map_err(|source| ReconstructError::List {
                path: dir.to_path_buf(),
                source,
            })?
            .path();
        let is_image = path
            .extension()
            .and_then(|e| e.to_str())
            .is_some_and(|e| matches!(e.to_ascii_lowercase().as_str(), "png" | "jpg" | "jpeg"));
        if is_image && path.is_file() {
            all.push(path);
        }
    }
    all.sort();
    let framed: Vec<PathBuf> = all
        .iter()
        .filter(|p| {
            p.file_name()
                .and_then(|n| n.to_str())
                .is_some_and(|n| n.starts_with("frame_"))
        })
        .cloned()
        .collect();
    let frames = if framed.is_empty() { all } else { framed };
    if frames.is_empty() {
        return Err(ReconstructError::NoFrames(dir.to_path_buf()));
    }
    Ok(frames)
}

/// Where the frames come from: image files, or a recorded dump
/// ([`crate::capture::dump`]).
pub enum FrameSource {
    Files(Vec<PathBuf>),
    Dump {
        path: PathBuf,
        header: DumpHeader,
        offsets: Vec<u64>,
    },
}

impl FrameSource {
    /// A folder of images, or a dump file. A dump cut off or damaged after some whole
    /// frames still opens; the error that stopped the scan is returned beside it.
    pub fn open(input: &Path) -> Result<(Self, Option<DumpError>), ReconstructError> {
        if input.is_dir() {
            return Ok((Self::Files(list_frames(input)?), None));
        }
        let (header, offsets, stopped) = DumpReader::index(input)?;
        if offsets.is_empty() {
            return Err(match stopped {
                Some(e) => e.into(),
                None => ReconstructError::NoFrames(input.to_path_buf()),
            });
        }
        Ok((
            Self::Dump {
                path: input.to_path_buf(),
                header,
                offsets,
            },
            stopped,
        ))
    }

    pub fn len(&self) -> usize {
        match self {
            Self::Files(f) => f.len(),
            Self::Dump { offsets, .. } => offsets.len(),
        }
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Frame `i`, decoded to RGB and checked against the camera's image size.
    pub fn decode(&self, i: usize, camera: &Camera) -> Result<RgbImage, ReconstructError> {
        match self {
            Self::Files(files) => decode(&files[i], camera),
            Self::Dump {
                path,
                header,
                offsets,
            } => {
                let record = DumpReader::read_at(path, offsets[i], i)?;
                let img = crate::capture::dump::decode_rgb(header, &record.payload).map_err(
                    |message| DumpError::Decode {
                        path: path.clone(),
                        index: i,
                        fourcc: String::from_utf8_lossy(&header.fourcc).into_owned(),
                        message,
                    },
                )?;
                check_size(img, path, camera)
            }
        }
    }
}

fn check_size(img: RgbImage, path: &Path, camera: &Camera) -> Result<RgbImage, ReconstructError> {
    if img.width() != camera.width || img.height() != camera.height {
        return Err(ReconstructError::Size {
            path: path.to_path_buf(),
            got_w: img.width(),
            got_h: img.height(),
            want_w: camera.width,
            want_h: camera.height,
        });
    }
    Ok(img)
}

fn decode(path: &Path, camera: &Camera) -> Result<RgbImage, ReconstructError> {
    let img = image::open(path)
        .map_err(|source| ReconstructError::Decode {
            path: path.to_path_buf(),
            source,
        })?
        .into_rgb8();
    check_size(img, path, camera)
}

/// Callbacks for progress on long stages: `(stage, done, total)`.
pub trait Progress: Sync {
    fn update(&self, stage: &str, done: usize, total: usize);
}

impl<F: Fn(&str, usize, usize) + Sync> Progress for F {
    fn update(&self, stage: &str, done: usize, total: usize) {
        self(stage, done, total)
    }
}

/// Runs the whole offline pipeline over image files.
#[allow(clippy::too_many_arguments)]
pub fn reconstruct_files(
    frames: &FrameSource,
    background: Option<&Path>,
    camera: &Camera,
    config: &Config,
    planes: PlaneSource<'_>,
    scale: &ScaleMode,
    progress: &dyn Progress,
) -> Result<Reconstruction, ReconstructError> {
    let t = Instant::now();
    let background = match background {
        Some(path) => Background::from_image(decode(path, camera)?),
        None => {
            let k = config.background.median_frames.clamp(1, frames.len());
            let picks: Vec<usize> = (0..k)
                .map(|i| (i * frames.len()) / k + frames.len() / (2 * k))
                .collect();
            let images = picks
                .par_iter()
                .map(|&i| frames.decode(i, camera))
                .collect::<Result<Vec<_>, _>>()?;
            let refs: Vec<&RgbImage> = images.iter().collect();
            Background::median_of(&refs)?
        }
    };
    let background_s = t.elapsed().as_secs_f64();

    let t = Instant::now();
    // Validate the parameters once; every worker thread then builds its own extractor
    // (they own their scratch buffers), which cannot fail any more.
    Extractor::new(&config.extract, camera)?;
    let done = std::sync::atomic::AtomicUsize::new(0);
    let per_frame: Vec<Vec<Curve>> = (0..frames.len())
        .into_par_iter()
        .map_init(
            || Extractor::new(&config.extract, camera).ok(),
            |extractor, i| {
                let Some(extractor) = extractor.as_mut() else {
                    return Err(ReconstructError::Internal("extractor construction failed"));
                };
                let img = frames.decode(i, camera)?;
                let curves = extractor.extract(&img, &background);
                let n = done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
                progress.update("extract", n, frames.len());
                Ok(curves)
            },
        )
        .collect::<Result<_, ReconstructError>>()?;
    let extract_s = t.elapsed().as_secs_f64();

    let mut rec = reconstruct_curves(
        per_frame,
        camera,
        config,
        planes,
        scale,
        Some(background.image()),
    )?;
    rec.report.seconds.background_s = background_s;
    rec.report.seconds.extract_s = extract_s;
    Ok(rec)
}
