//! Offline reconstruction: a recording (a folder of frames, a dump or a video file) in,
//! a coloured point cloud out.
//!
//! Owns where offline frames come from ([`FrameSource`]; a video file is decoded in
//! order, in passes, where files and dumps are read at random) and the wiring of the
//! stages over them: the background ([`crate::extract::Background`]: a laser-off frame, or the
//! per-pixel temporal median of frames sampled over the recording), extraction in
//! parallel over frames ([`crate::extract::Extractor`]), then the stages shared with the
//! live daemon ([`crate::pipeline::reconstruct_curves`]).

use std::path::{Path, PathBuf};

use image::RgbImage;
use rayon::prelude::*;

use crate::camera::Camera;
use crate::capture::chroma::{self, Rebuild};
use crate::capture::dump::{DumpError, DumpHeader, DumpReader};
use crate::capture::video::{self, VideoError, VideoFile, Window};
use crate::cloud::ScaleMode;
use crate::config::Config;
use crate::extract::Curve;
use streamed::{check_video_size, video_image};

mod extraction;
mod streamed;

pub use extraction::{extract_frames, Extracted};

pub use crate::pipeline::{
    reconstruct_curves, reconstruct_scan, PlaneSource, ReconstructReport, Reconstruction, Scan,
    StageTimes, REPORT_VERSION,
};

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
    #[error("cannot decode frame {path}: {message}")]
    Damaged { path: PathBuf, message: String },
    #[error("{path} is named like a frame but is not a readable file: {why}")]
    NotAFile { path: PathBuf, why: String },
    #[error("frame {path} is {got_w}x{got_h}, but the camera file says {want_w}x{want_h}")]
    Size {
        path: PathBuf,
        got_w: u32,
        got_h: u32,
        want_w: u32,
        want_h: u32,
    },
    #[error("{path} is {got_w}x{got_h} video, but the camera file is for {want_w}x{want_h}: calibrate the camera at the size the video was recorded")]
    VideoSize {
        path: PathBuf,
        got_w: u32,
        got_h: u32,
        want_w: u32,
        want_h: u32,
    },
    #[error(transparent)]
    Video(#[from] VideoError),
    #[error("--start and --duration select part of a video file, not of {0}")]
    WindowNotVideo(PathBuf),
    #[error("extraction")]
    Extract(#[from] crate::extract::ExtractError),
    #[error("reading the dump")]
    Dump(#[from] DumpError),
    #[error("internal error: {0}")]
    Internal(&'static str),
    #[error("cannot start a thread: {0}")]
    Thread(#[source] std::io::Error),
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
        if !is_image {
            continue;
        }
        // A directory, a dangling link or a link loop named like a frame is refused
        // rather than skipped unseen: a frame would silently be missing from the scan.
        match std::fs::metadata(&path) {
            Ok(m) if m.is_file() => all.push(path),
            Ok(_) => {
                return Err(ReconstructError::NotAFile {
                    path,
                    why: "it is a directory or a special file".into(),
                })
            }
            Err(e) => {
                return Err(ReconstructError::NotAFile {
                    path,
                    why: e.to_string(),
                })
            }
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

/// Where the frames come from: image files, a recorded dump
/// ([`crate::capture::dump`]) or a video file ([`crate::capture::video`]).
pub enum FrameSource {
    Files(Vec<PathBuf>),
    Dump {
        path: PathBuf,
        header: DumpHeader,
        offsets: Vec<u64>,
    },
    Video(VideoFile),
}

impl FrameSource {
    /// A folder of images, a dump file, or a video file (by its extension, see
    /// [`video::VIDEO_EXTENSIONS`]). A dump cut off or damaged after some whole frames
    /// still opens; the error that stopped the scan is returned beside it. (A cut-off
    /// video is warned about as it is probed.)
    pub fn open(input: &Path) -> Result<(Self, Option<DumpError>), ReconstructError> {
        Self::open_window(input, None)
    }

    /// [`FrameSource::open`], keeping only `window` of a video file (an error for
    /// other inputs).
    pub fn open_window(
        input: &Path,
        window: Option<Window>,
    ) -> Result<(Self, Option<DumpError>), ReconstructError> {
        if video::is_video(input) && !input.is_dir() {
            let file = VideoFile::probe(input, window.unwrap_or_default())?;
            if file.frames.is_empty() {
                return Err(ReconstructError::NoFrames(input.to_path_buf()));
            }
            return Ok((Self::Video(file), None));
        }
        if window.is_some() {
            return Err(ReconstructError::WindowNotVideo(input.to_path_buf()));
        }
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
            Self::Video(v) => v.frames.len(),
        }
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// How decoding these frames rebuilds their chroma ([`crate::capture::chroma`]), from
    /// the first of their first few frames whose bytes say: a dump's buffers, or JPEG
    /// files. `None` for PNG files and videos (FFmpeg's conversion is not ours), whose
    /// sampling the extractors read off the pixels.
    pub fn chroma(&self) -> Option<[Rebuild; 2]> {
        const LOOKED_AT: usize = 8;
        match self {
            Self::Video(_) => None,
            Self::Files(files) => files.iter().take(LOOKED_AT).find_map(|path| {
                let bytes = std::fs::read(path).ok()?;
                (image::guess_format(&bytes).ok()? == image::ImageFormat::Jpeg)
                    .then(|| chroma::of_jpeg(&bytes))
                    .flatten()
            }),
            Self::Dump {
                path,
                header,
                offsets,
            } => offsets
                .iter()
                .take(LOOKED_AT)
                .enumerate()
                .find_map(|(i, &at)| {
                    let record = DumpReader::read_at(path, at, i).ok()?;
                    chroma::of_buffer(header, &record.payload)
                }),
        }
    }

    /// Frame `i`, decoded to RGB and checked against the camera's image size. (A video
    /// is decoded from its start to frame `i`: slow, for single frames only.)
    pub fn decode(&self, i: usize, camera: &Camera) -> Result<RgbImage, ReconstructError> {
        match self {
            Self::Video(file) => {
                check_video_size(file, camera)?;
                let mut reader = file.reader()?;
                while let Some(frame) = reader.next_frame()? {
                    if frame.position == i {
                        return video_image(file, frame.rgb);
                    }
                }
                Err(ReconstructError::NoFrames(file.path.clone()))
            }
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
    let bytes = std::fs::read(path).map_err(|source| ReconstructError::Decode {
        path: path.to_path_buf(),
        source: image::ImageError::IoError(source),
    })?;
    let format = image::guess_format(&bytes).map_err(|source| ReconstructError::Decode {
        path: path.to_path_buf(),
        source,
    })?;
    // The JPEG decoder fills a cut-off scan with grey and says nothing.
    if format == image::ImageFormat::Jpeg && !crate::capture::dump::jpeg_is_complete(&bytes) {
        return Err(ReconstructError::Damaged {
            path: path.to_path_buf(),
            message: "the JPEG is cut off (no end-of-image marker)".into(),
        });
    }
    let img = image::load_from_memory_with_format(&bytes, format)
        .map_err(|source| ReconstructError::Decode {
            path: path.to_path_buf(),
            source,
        })?
        .into_rgb8();
    check_size(img, path, camera)
}

impl FrameSource {
    /// A pass over the frames in order, block by block ([`FramePass::map_frames`]).
    fn pass<'a>(&'a self, camera: &'a Camera) -> Result<FramePass<'a>, ReconstructError> {
        Ok(match self {
            Self::Video(file) => FramePass::Video(streamed::VideoPass::new(file, camera)?),
            _ => FramePass::Random(self, camera),
        })
    }
}

/// Frames of a [`FrameSource`] taken in ascending order, in blocks.
enum FramePass<'a> {
    /// Files and dumps: any frame decodes on its own, in parallel.
    Random(&'a FrameSource, &'a Camera),
    /// A video: one FFmpeg pass, a few frames ahead of the workers.
    Video(streamed::VideoPass<'a>),
}

impl FramePass<'_> {
    /// Whether any frame can be read again, in any order (not a video's one pass).
    pub fn random_access(&self) -> bool {
        matches!(self, Self::Random(..))
    }

    /// `f(state, i, frame i)` for every `i` of `wanted` (ascending, after those of any
    /// earlier call), in parallel, the results in that order; each thread's `state` comes
    /// from `init` and is reused. A video ends at its last whole frame: the result may
    /// then be shorter than `wanted`.
    pub fn map_frames<S: Send, T: Send>(
        &mut self,
        wanted: &[usize],
        init: impl Fn() -> S + Sync + Send,
        f: impl Fn(&mut S, usize, Result<RgbImage, ReconstructError>) -> Result<T, ReconstructError>
            + Sync
            + Send,
    ) -> Result<Vec<T>, ReconstructError> {
        match self {
            Self::Video(pass) => pass.map_frames(wanted, init, f),
            Self::Random(source, camera) => wanted
                .par_iter()
                .map_init(&init, |s, &i| f(s, i, source.decode(i, camera)))
                .collect(),
        }
    }
}

impl ReconstructError {
    /// True for a frame whose bytes could be read but not decoded: such a frame is
    /// skipped and counted (in `reconstruct` as in `serve`), the rest of the scan
    /// goes on.
    pub fn is_undecodable_frame(&self) -> bool {
        matches!(
            self,
            Self::Decode {
                source: image::ImageError::Decoding(_)
                    | image::ImageError::Unsupported(_)
                    | image::ImageError::Limits(_),
                ..
            } | Self::Damaged { .. }
                | Self::Dump(DumpError::Decode { .. })
        )
    }
}

/// Frames skipped because they could not be decoded: counted, the first one warned
/// about as it happens, the total at the end.
#[derive(Default)]
struct Skipped {
    frames: std::sync::Mutex<Vec<(usize, String)>>,
}

impl Skipped {
    /// Passes `result` on, or records an undecodable frame and returns `None`.
    fn filter<T>(
        &self,
        i: usize,
        result: Result<T, ReconstructError>,
    ) -> Result<Option<T>, ReconstructError> {
        match result {
            Ok(v) => Ok(Some(v)),
            Err(e) if e.is_undecodable_frame() => {
                let mut frames = self.frames.lock().unwrap_or_else(|e| e.into_inner());
                if frames.is_empty() {
                    tracing::warn!("skipping frame {i}: {e}");
                } else {
                    tracing::debug!("skipping frame {i}: {e}");
                }
                frames.push((i, e.to_string()));
                Ok(None)
            }
            Err(e) => Err(e),
        }
    }

    fn count(&self) -> usize {
        self.frames.lock().unwrap_or_else(|e| e.into_inner()).len()
    }
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

/// Runs the whole offline pipeline over a recording: [`extract_frames`], with the
/// crossing search ([`Scan::add_frame`], [`Scan::refine_crossings`]) on its own thread
/// block by block beside it, then the stages shared with the daemon
/// ([`reconstruct_scan`]). The scan is built as the daemon builds it, frame by frame in
/// frame order, so the cloud is the one [`reconstruct_curves`] makes of the same curves.
/// Beside the extraction the search fills the time its workers wait at each block's end
/// (9 % of it on the 5,400-frame room), instead of running after it.
pub fn reconstruct_files(
    frames: &FrameSource,
    background: Option<&Path>,
    camera: &Camera,
    config: &Config,
    planes: PlaneSource<'_>,
    scale: &ScaleMode,
    progress: &dyn Progress,
) -> Result<Reconstruction, ReconstructError> {
    let (extracted, scan, build_s) = std::thread::scope(|s| {
        // Two blocks queued at most: the search keeps up with the extraction easily.
        let (tx, rx) = crossbeam_channel::bounded::<Vec<Vec<Curve>>>(2);
        let search = std::thread::Builder::new()
            .name("scan".into())
            .spawn_scoped(s, move || {
                let mut scan = Scan::new(camera, config);
                for block in rx {
                    for curves in block {
                        scan.add_frame(curves);
                    }
                    scan.refine_crossings(camera, config);
                }
                scan
            })
            .map_err(ReconstructError::Thread)?;
        // A send fails only if the search thread died; its join below says so.
        let extracted = extract_frames(frames, background, camera, config, progress, &mut |b| {
            let _ = tx.send(b);
        });
        drop(tx);
        let t = std::time::Instant::now();
        let scan = search
            .join()
            .map_err(|_| ReconstructError::Internal("the crossing search thread panicked"))?;
        Ok::<_, ReconstructError>((extracted?, scan, t.elapsed().as_secs_f64()))
    })?;
    let with_extraction = |report: &mut ReconstructReport| {
        report.frames_skipped = extracted.frames_skipped;
        report.seconds.background_s = extracted.background_s;
        report.seconds.extract_s = extracted.extract_s;
    };
    let colour = Some(extracted.background.image());
    match reconstruct_scan(&scan, build_s, camera, config, planes, scale, colour) {
        Ok(mut rec) => {
            with_extraction(&mut rec.report);
            Ok(rec)
        }
        Err(mut e) => {
            if let Some(report) = e.report_mut() {
                with_extraction(report);
            }
            Err(e.into())
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camera(width: u32, height: u32) -> Camera {
        Camera {
            width,
            height,
            fx: 100.0,
            fy: 100.0,
            cx: 16.0,
            cy: 12.0,
            skew: 0.0,
            distortion: Default::default(),
        }
    }

    #[test]
    fn a_cut_off_jpeg_frame_is_skipped_and_counted_not_used() {
        let dir = tempfile::tempdir().expect("tempdir");
        let img = crate::capture::dump::tests::textured_image();
        let whole = dir.path().join("frame_000000.jpg");
        img.save(&whole).expect("save");
        let bytes = std::fs::read(&whole).expect("read");
        let third = &bytes[..bytes.len() / 3];
        let scan = crate::capture::dump::jpeg_segments(&bytes)
            .expect("segments")
            .1;
        assert!(scan < third.len(), "scan at {scan} of {}", third.len());
        let cut = dir.path().join("frame_000001.jpg");
        std::fs::write(&cut, third).expect("cut");
        let cam = camera(320, 240);
        let frames = FrameSource::Files(list_frames(dir.path()).expect("list"));
        let skipped = Skipped::default();
        assert!(skipped
            .filter(0, frames.decode(0, &cam))
            .expect("ok")
            .is_some());
        let err = frames.decode(1, &cam).expect_err("cut off");
        assert!(err.is_undecodable_frame(), "{err}");
        assert!(err.to_string().contains("cut off"), "{err}");
        // The policy shared with serve: skip, count, go on.
        assert!(skipped
            .filter(1, frames.decode(1, &cam))
            .expect("skipped")
            .is_none());
        assert_eq!(skipped.count(), 1);
        // A wrong camera is not a damaged frame: it stops the run.
        let wrong = camera(64, 48);
        let err = skipped
            .filter(0, frames.decode(0, &wrong))
            .expect_err("size");
        assert!(matches!(err, ReconstructError::Size { .. }), "{err}");
    }

    #[test]
    fn a_directory_or_a_link_loop_named_like_a_frame_is_an_error() {
        let dir = tempfile::tempdir().expect("tempdir");
        RgbImage::new(4, 4)
            .save(dir.path().join("frame_000000.png"))
            .expect("save");
        std::fs::create_dir(dir.path().join("frame_000050.png")).expect("mkdir");
        let err = list_frames(dir.path()).expect_err("a directory");
        assert!(err.to_string().contains("frame_000050.png"), "{err}");
        std::fs::remove_dir(dir.path().join("frame_000050.png")).expect("rmdir");
        let looped = dir.path().join("frame_000051.png");
        std::os::unix::fs::symlink(&looped, &looped).expect("symlink");
        let err = list_frames(dir.path()).expect_err("a link loop");
        assert!(matches!(err, ReconstructError::NotAFile { .. }), "{err}");
        std::fs::remove_file(&looped).expect("rm");
        assert_eq!(list_frames(dir.path()).expect("list").len(), 1);
    }
}
