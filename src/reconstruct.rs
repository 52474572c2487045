//! Offline reconstruction: a sequence of frames in, a coloured point cloud out.
//!
//! This module only wires the stages together; each stage lives in its own module and
//! the live daemon reuses them:
//!
//! 1. background ([`crate::extract::Background`]): a laser-off frame, or the per-pixel
//!    temporal median of frames sampled over the sequence;
//! 2. extract ([`crate::extract::Extractor`]): both laser curves of every frame, in
//!    parallel over frames;
//! 3. intersect ([`crate::intersect`]): crossings between curves of different planes;
//! 4. solve ([`crate::solve`]): every plane, up to one global scale;
//! 5. triangulate ([`crate::cloud`]): points, colour from the background, scale.
//!
//! A *plane* here is one laser of one frame: when occlusion splits a laser's stripe
//! into several curves, the pieces share one plane unknown.

use std::path::{Path, PathBuf};
use std::time::Instant;

use image::RgbImage;
use nalgebra::Vector3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::camera::Camera;
use crate::capture::dump::{DumpError, DumpHeader, DumpReader};
use crate::cloud::{self, CurvePoints, ScaleMode, TriangulateStats};
use crate::config::Config;
use crate::extract::{Background, Curve, Extractor};
use crate::intersect::{Crossing, SegmentIndex};
use crate::ply::Cloud;
use crate::solve::{self, Problem, Solution};

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
    #[error("solving the planes")]
    Solve(#[from] solve::SolveError),
    #[error("reading the dump")]
    Dump(#[from] DumpError),
    #[error("internal error: {0}")]
    Internal(&'static str),
    #[error("fixing the scale")]
    Scale(#[from] cloud::ScaleError),
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

/// Seconds spent in each stage.
#[derive(Clone, Debug, Default, Serialize)]
pub struct StageTimes {
    pub background_s: f64,
    pub extract_s: f64,
    pub intersect_s: f64,
    pub solve_s: f64,
    pub triangulate_s: f64,
}

/// What a reconstruction found; serialised as the `--report` JSON (with `version`).
/// Within a version keys are only ever added (`crossings_in_solve`,
/// `crossings_off_surface`, `planes_too_uncertain`, `planes_from_faint_crossings`, the
/// `triangulation.inconsistent_*` counts, `triangulation.curve_ends` and
/// `joint_refinement` came later in version 1); readers should ignore keys they do not
/// know.
#[derive(Clone, Debug, Serialize)]
pub struct ReconstructReport {
    pub version: u32,
    pub frames: usize,
    pub frames_with_laser: usize,
    pub curves: usize,
    pub planes: usize,
    pub crossings: usize,
    /// Crossings of two strong curves, which shape the planes
    /// (`solve.min_curve_strength`).
    pub crossings_in_solve: usize,
    /// Of those, the crossings taken out before the second solve because the first
    /// one showed their curves (or stretches of them) off the surface, their crossings
    /// disagreeing together (see `cloud::check_crossings`).
    pub crossings_off_surface: usize,
    pub planes_in_global_solve: usize,
    pub planes_solved: usize,
    pub rejected_crossings: usize,
    pub rejected_planes: usize,
    /// Planes whose turn about their 3D line came from the neighbouring frames
    /// (`solve.motion_prior_max_gap`), or from their own crossings a pixel or less
    /// off one line where those disagree with the neighbours.
    pub planes_fixed_by_motion: usize,
    /// Extended planes dropped because their crossings fixed them too loosely
    /// (`solve.uncertain_plane_ratio`); the motion prior may have given them a plane
    /// again.
    pub planes_too_uncertain: usize,
    /// Planes with no crossing in the solve (all their curves faint, far along the
    /// sheet under water), fitted afterwards from their crossings of any strength with
    /// the solved planes.
    pub planes_from_faint_crossings: usize,
    /// The refinement of every plane together (`solve.joint_refinement_steps`): planes,
    /// crossings and crosses it used, its accepted steps and its cost before and after
    /// (squared residuals in units of their own spread, Huber's loss). `null` when
    /// skipped (true planes, 0 steps, too little to refine).
    pub joint_refinement: Option<solve::joint::JointFit>,
    pub residual_rms: f64,
    pub orthogonality_rms_deg: f64,
    pub focal_scale: f64,
    pub focal_scale_std: Option<f64>,
    pub focal_px: [f64; 2],
    pub scale_mode: ScaleMode,
    pub scale_factor: f64,
    pub points: usize,
    pub triangulation: TriangulateStats,
    pub seconds: StageTimes,
}

/// Version of the report JSON.
pub const REPORT_VERSION: u32 = 1;

/// A finished reconstruction.
pub struct Reconstruction {
    pub cloud: Cloud,
    /// Distorted pixel of every cloud point.
    pub pixels: Vec<[f32; 2]>,
    pub report: ReconstructReport,
    /// Per plane: the solved plane in the output's (scaled) camera frame.
    pub planes: Vec<Option<Vector3<f64>>>,
}

/// A plane whose curves the crossing check leaves out, in whole or in part, may be the
/// one at fault: fitted from some of its curves' crossings only, it can be turned about
/// the 3D line through them and miss its other curves by a few percent, while those
/// curves are on the surface. Each such plane is refitted from the crossings of all its
/// curves with the solved curves the check keeps, faint ones included (far along a
/// sheet, where a plane fitted from the strong curves near its start is extrapolated,
/// they are the ones that tell), and the refit is kept when more of those crossings
/// agree with it (`max_crossing_disagreement`) than with the plane it replaces.
/// `check` is the crossing check of `sol`'s planes; `curve_ids[k]` the two curves of
/// `crossings[k]`. Returns the number of planes refitted.
fn rescue_disputed_planes(
    sol: &mut Solution,
    crossings: &[Crossing],
    curve_ids: &[[u32; 2]],
    check: &cloud::CrossingCheck,
    params: &cloud::TriangulateParams,
) -> usize {
    let Some(ctx) = sol.fit_context else {
        return 0;
    };
    let given = sol.given_planes();
    // Per plane, its crossings with kept curves of other solved planes:
    // (crossing index, the other plane).
    let mut known: Vec<Vec<(usize, Vector3<f64>)>> = vec![Vec::new(); given.len()];
    let mut disputed = vec![false; given.len()];
    for (k, c) in crossings.iter().enumerate() {
        if c.sin_angle < ctx.min_sin_angle {
            continue;
        }
        let [ca, cb] = curve_ids[k];
        for (mine, other, p, q) in [(ca, cb, c.a, c.b), (cb, ca, c.b, c.a)] {
            disputed[p as usize] |= check.rejected[mine as usize] || check.partial(mine as usize);
            if check.rejected[other as usize] {
                continue;
            }
            if let Some(vq) = given.get(q as usize).copied().flatten() {
                known[p as usize].push((k, vq));
            }
        }
    }
    let agreeing = |v: &Vector3<f64>, known: &[(usize, Vector3<f64>)]| {
        known
            .iter()
            .filter(|(k, vq)| cloud::agrees(*v, *vq, crossings[*k].u, params))
            .count()
    };
    let lambda = sol.focal_scale;
    let mut rescued = 0;
    for p in 0..given.len() {
        let Some(old) = given[p] else { continue };
        if !disputed[p] || known[p].len() < ctx.min_crossings.max(3) {
            continue;
        }
        let Some(v) = most_agreeing_plane(crossings, &known[p], params.max_crossing_disagreement)
        else {
            continue;
        };
        if agreeing(&v, &known[p]) > agreeing(&old, &known[p]) {
            sol.planes[p] = Some(Vector3::new(v.x * lambda, v.y * lambda, v.z));
            rescued += 1;
        }
    }
    rescued
}

/// The plane that the most of the crossings `known` (crossing index, the other curve's
/// plane) agree with, each giving the inverse depth `v_q · u` at its `u`: the best of
/// the extension's minimal samples of three ([`solve::extend::samples`]) by the number
/// agreeing within `tolerance` (relative depth), refitted by least squares on those.
/// `None` when no sample is well conditioned.
fn most_agreeing_plane(
    crossings: &[Crossing],
    known: &[(usize, Vector3<f64>)],
    tolerance: f64,
) -> Option<Vector3<f64>> {
    let rows: Vec<(Vector3<f64>, f64)> = known
        .iter()
        .map(|(k, vq)| {
            let u = Vector3::new(crossings[*k].u[0], crossings[*k].u[1], 1.0);
            (u, vq.dot(&u))
        })
        .filter(|(_, d)| *d > 0.0)
        .collect();
    let n = rows.len();
    if n < 3 {
        return None;
    }
    let agrees = |v: &Vector3<f64>, (u, d): &(Vector3<f64>, f64)| {
        cloud::inverse_depths_agree(v.dot(u), *d, tolerance)
    };
    let fit = |idx: &mut dyn Iterator<Item = usize>| -> Option<Vector3<f64>> {
        let (mut a, mut b) = (nalgebra::Matrix3::zeros(), Vector3::zeros());
        for i in idx {
            let (u, d) = &rows[i];
            let w = 1.0 / (d * d);
            a += u * u.transpose() * w;
            b += u * (d * w);
        }
        let eig = nalgebra::SymmetricEigen::new(a);
        let (lo, hi) = eig
            .eigenvalues
            .iter()
            .fold((f64::INFINITY, 0.0f64), |(lo, hi), &l| {
                (lo.min(l), hi.max(l))
            });
        (lo > 1e-9 * hi).then(|| a.cholesky().map(|c| c.solve(&b)))?
    };
    let mut best: Option<(usize, Vector3<f64>)> = None;
    for t in solve::extend::samples::<3>(n) {
        let Some(v) = fit(&mut t.into_iter()) else {
            continue;
        };
        let count = rows.iter().filter(|r| agrees(&v, r)).count();
        if best.is_none_or(|(c, _)| count > c) {
            best = Some((count, v));
        }
    }
    let (_, v) = best?;
    let inliers: Vec<usize> = (0..n).filter(|&i| agrees(&v, &rows[i])).collect();
    fit(&mut inliers.into_iter()).or(Some(v))
}

/// Whether no point of `curve` reaches `min_strength` (curves read without strengths
/// count as strong).
pub(crate) fn is_faint(curve: &Curve, min_strength: f32) -> bool {
    !curve.strength.is_empty() && !curve.strength.iter().any(|&s| s >= min_strength)
}

/// One laser of one frame: a plane unknown and the curves that lie on it.
pub(crate) struct PlaneCurves {
    pub(crate) frame: u32,
    pub(crate) laser: u8,
    pub(crate) curves: Vec<Curve>,
    /// Per curve, the index in `points` of each polyline vertex.
    vertices: Vec<Vec<usize>>,
}

impl PlaneCurves {
    pub(crate) fn new(frame: u32, laser: u8, curves: Vec<Curve>) -> Self {
        let vertices = curves
            .iter()
            .map(|c| {
                // Polyline vertices are copies of dense points, in order.
                let mut at = 0;
                c.polyline
                    .iter()
                    .map(|v| {
                        if let Some(i) = c.points[at..].iter().position(|p| p == v) {
                            at += i;
                        }
                        at
                    })
                    .collect()
            })
            .collect();
        Self {
            frame,
            laser,
            curves,
            vertices,
        }
    }

    /// The plane unknowns of one frame: its curves grouped by laser, laser 0 first, one
    /// per laser that has curves (curves of a laser beyond the second are dropped).
    /// The live solver and `reconstruct_curves` both group through here, so that they
    /// make the same planes in the same order.
    pub(crate) fn of_frame(frame: u32, curves: Vec<Curve>) -> Vec<PlaneCurves> {
        let mut by_laser: [Vec<Curve>; 2] = [Vec::new(), Vec::new()];
        for c in curves {
            if let Some(slot) = by_laser.get_mut(c.laser as usize) {
                slot.push(c);
            }
        }
        by_laser
            .into_iter()
            .enumerate()
            .filter(|(_, curves)| !curves.is_empty())
            .map(|(laser, curves)| PlaneCurves::new(frame, laser as u8, curves))
            .collect()
    }

    /// The dense points around `u` of the curve (of this plane) whose polyline passes
    /// closest to `u`: the polyline's segment is found first (polylines are short),
    /// then only the dense points between its two vertices, widened by `radius`, are
    /// searched.
    pub(crate) fn dense_near(&self, u: [f64; 2], radius: f64) -> &[[f64; 2]] {
        match self.run_near(u, radius) {
            Some((ci, lo, hi)) => {
                crate::intersect::dense_run(&self.curves[ci].points[lo..=hi], u, radius)
            }
            None => &[],
        }
    }

    /// Index of the dense point of curve `ci` nearest `u` (searched between the two
    /// vertices of the polyline segment nearest `u`).
    pub(crate) fn nearest_point(&self, ci: usize, u: [f64; 2]) -> u32 {
        let Some((_, k)) = self.nearest_segment(ci, u) else {
            return 0;
        };
        let (start, end) = self.segment_span(ci, k);
        let points = &self.curves[ci].points;
        let d2 = |p: &[f64; 2]| (p[0] - u[0]).powi(2) + (p[1] - u[1]).powi(2);
        (start..=end)
            .min_by(|&i, &j| d2(&points[i]).total_cmp(&d2(&points[j])))
            .unwrap_or(start) as u32
    }

    /// Curve index and the range of its dense points around `u` (see [`Self::dense_near`]).
    fn run_near(&self, u: [f64; 2], radius: f64) -> Option<(usize, usize, usize)> {
        let (_, ci, k) = (0..self.curves.len())
            .filter_map(|ci| self.nearest_segment(ci, u).map(|(d, k)| (d, ci, k)))
            .fold(None, |best: Option<(f64, usize, usize)>, c| match best {
                Some(b) if b.0 <= c.0 => Some(b),
                _ => Some(c),
            })?;
        let points = &self.curves[ci].points;
        if points.is_empty() {
            return None;
        }
        let (start, end) = self.segment_span(ci, k);
        let r2 = radius * radius;
        let d2 = |p: &[f64; 2]| (p[0] - u[0]).powi(2) + (p[1] - u[1]).powi(2);
        let (mut lo, mut hi) = (start, end);
        while lo > 0 && d2(&points[lo - 1]) <= r2 {
            lo -= 1;
        }
        while hi + 1 < points.len() && d2(&points[hi + 1]) <= r2 {
            hi += 1;
        }
        Some((ci, lo, hi))
    }

    /// Distance to `u` and index of the polyline segment of curve `ci` nearest `u`
    /// (the first of equals).
    fn nearest_segment(&self, ci: usize, u: [f64; 2]) -> Option<(f64, usize)> {
        let mut best: Option<(f64, usize)> = None;
        for (k, seg) in self.curves[ci].polyline.windows(2).enumerate() {
            let d = crate::intersect::point_segment_distance(u, seg[0], seg[1]);
            if best.is_none_or(|(b, _)| d < b) {
                best = Some((d, k));
            }
        }
        best
    }

    /// The dense points `start..=end` between the two vertices of segment `k` of curve
    /// `ci` (clamped to the curve).
    fn segment_span(&self, ci: usize, k: usize) -> (usize, usize) {
        let last = self.curves[ci].points.len().saturating_sub(1);
        let start = self.vertices[ci].get(k).copied().unwrap_or(0).min(last);
        let end = self.vertices[ci]
            .get(k + 1)
            .copied()
            .unwrap_or(last)
            .clamp(start, last);
        (start, end)
    }
}

/// Where the planes come from.
#[derive(Clone, Copy, Debug)]
pub enum PlaneSource<'a> {
    /// Self-calibration from the crossings (the product).
    SelfCalibrated,
    /// Known planes per frame and laser (e.g. a simulation's truth): the same pipeline
    /// with a perfectly calibrated projector, the yardstick of the self-calibration.
    Known(&'a [[Option<Vector3<f64>>; 2]]),
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
    let mut times = StageTimes::default();
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
    times.background_s = t.elapsed().as_secs_f64();

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
    times.extract_s = t.elapsed().as_secs_f64();

    let mut rec = reconstruct_curves(
        per_frame,
        camera,
        config,
        planes,
        scale,
        Some(background.image()),
    )?;
    rec.report.seconds.background_s = times.background_s;
    rec.report.seconds.extract_s = times.extract_s;
    Ok(rec)
}

/// The stages after extraction: from each frame's curves to the scaled cloud.
pub fn reconstruct_curves(
    per_frame: Vec<Vec<Curve>>,
    camera: &Camera,
    config: &Config,
    source: PlaneSource<'_>,
    scale: &ScaleMode,
    colour_source: Option<&RgbImage>,
) -> Result<Reconstruction, ReconstructError> {
    let mut times = StageTimes::default();
    let frames = per_frame.len();
    let frames_with_laser = per_frame.iter().filter(|c| !c.is_empty()).count();

    // Group curves into plane unknowns: one per (frame, laser).
    let planes: Vec<PlaneCurves> = per_frame
        .into_iter()
        .enumerate()
        .flat_map(|(frame, curves)| PlaneCurves::of_frame(frame as u32, curves))
        .collect();
    let curves_total: usize = planes.iter().map(|p| p.curves.len()).sum();
    let partner: Vec<Option<u32>> = (0..planes.len())
        .map(|i| {
            let p = &planes[i];
            let other = |j: usize| {
                planes
                    .get(j)
                    .filter(|q| q.frame == p.frame && q.laser != p.laser)
                    .map(|_| j as u32)
            };
            other(i + 1).or_else(|| i.checked_sub(1).and_then(other))
        })
        .collect();

    let t = Instant::now();
    let mut index = SegmentIndex::for_image(
        camera.width,
        camera.height,
        camera.fx.max(camera.fy),
        config.solve.min_sin_angle,
    );
    // Curves are indexed one by one (global ids in plane order, so `a < b` holds for
    // their planes too); the solver sees crossings of planes, the consistency check of
    // the cloud crossings of curves. Curves of one plane do not constrain it.
    let mut curve_plane: Vec<u32> = Vec::with_capacity(curves_total);
    let mut curve_local: Vec<u32> = Vec::with_capacity(curves_total);
    let mut crossings: Vec<Crossing> = Vec::new();
    let mut curve_ids: Vec<[u32; 2]> = Vec::new();
    let mut fresh = Vec::new();
    for (id, plane) in planes.iter().enumerate() {
        for (local, curve) in plane.curves.iter().enumerate() {
            let cid = curve_plane.len() as u32;
            curve_plane.push(id as u32);
            curve_local.push(local as u32);
            fresh.clear();
            index.insert_into(cid, &curve.polyline, &mut fresh);
            for c in &fresh {
                let (pa, pb) = (curve_plane[c.a as usize], curve_plane[c.b as usize]);
                if pa != pb {
                    crossings.push(Crossing { a: pa, b: pb, ..*c });
                    curve_ids.push([c.a, c.b]);
                }
            }
        }
    }
    let radius = config.intersect.refine_radius_px / camera.fx.max(camera.fy);
    if radius > 0.0 {
        crossings.par_iter_mut().for_each(|c| {
            let a = planes[c.a as usize].dense_near(c.u, radius);
            let b = planes[c.b as usize].dense_near(c.u, radius);
            if let Some(u) = crate::intersect::refine_crossing(a, b, c.u, radius) {
                c.u = u;
            }
        });
    }
    let at = |cid: u32, u: [f64; 2]| {
        let (p, local) = (curve_plane[cid as usize], curve_local[cid as usize]);
        planes[p as usize].nearest_point(local as usize, u)
    };
    // The ridge strength of curve `cid` at its point `at`.
    let local_strength = |cid: u32, at: u32| {
        let (p, local) = (curve_plane[cid as usize], curve_local[cid as usize]);
        planes[p as usize].curves[local as usize]
            .strength
            .get(at as usize)
            .copied()
    };
    let curve_crossings: Vec<cloud::CurveCrossing> = crossings
        .par_iter()
        .zip(&curve_ids)
        .map(|(c, &[a, b])| {
            let at = [at(a, c.u), at(b, c.u)];
            cloud::CurveCrossing {
                a,
                b,
                u: c.u,
                at,
                strength: [
                    local_strength(a, at[0]).unwrap_or(0.0),
                    local_strength(b, at[1]).unwrap_or(0.0),
                ],
            }
        })
        .collect();
    // The self-calibration sees only the crossings of strong curves (faint ones, with
    // no point reaching `solve.min_curve_strength`, could be glow or reflections just
    // as well) where both are at least `solve.min_crossing_strength` strong (not on a
    // faint stretch that hangs on a strong one); the rest is triangulated on the planes
    // these give.
    let min_strength = config.solve.min_curve_strength;
    let faint: Vec<bool> = planes
        .iter()
        .flat_map(|p| &p.curves)
        .map(|c| is_faint(c, min_strength))
        .collect();
    let min_local = config.solve.min_crossing_strength;
    // Indices into `crossings` of the strong ones.
    let strong_idx: Vec<usize> = curve_crossings
        .iter()
        .enumerate()
        .filter(|(_, cc)| {
            !faint[cc.a as usize]
                && !faint[cc.b as usize]
                && local_strength(cc.a, cc.at[0]).is_none_or(|s| s >= min_local)
                && local_strength(cc.b, cc.at[1]).is_none_or(|s| s >= min_local)
        })
        .map(|(k, _)| k)
        .collect();
    let strong: Vec<Crossing> = strong_idx.iter().map(|&k| crossings[k]).collect();
    let mut recheck_dropped = 0;
    times.intersect_s = t.elapsed().as_secs_f64();

    let t = Instant::now();
    // Each curve's plane, from the planes of (frame, laser), in the coordinates of
    // the curves' points (see [`Solution::given_planes`]).
    let planes_of_curves = |planes: &[Option<Vector3<f64>>]| -> Vec<Option<Vector3<f64>>> {
        curve_plane
            .iter()
            .map(|&p| planes.get(p as usize).copied().flatten())
            .collect()
    };
    let problem = Problem {
        num_curves: planes.len(),
        crossings: &strong,
        partner: &partner,
        focal_px: camera.fx.max(camera.fy),
    };
    let mut motion_fill = solve::motion::MotionFill::default();
    let mut joint = None;
    let mut faint_planes = 0;
    let solution: Solution = match source {
        PlaneSource::SelfCalibrated => {
            let mut sol = solve::solve(&problem, &config.solve)?;
            // Consensus of whole curves, then a re-solve: a curve off the surface (the
            // glow of its sheet in turbid water, a reflection) has crossings that are
            // each only a little off, too little for the solver's per-crossing
            // rejection, but its crossings disagree together. Those curves, and the
            // stretches of curves that run off the surface, leave the solve.
            let check = cloud::check_crossings(
                &planes_of_curves(&sol.given_planes()),
                &curve_crossings,
                &faint,
                &config.triangulate,
            );
            let agreed_idx: Vec<usize> = strong_idx
                .iter()
                .copied()
                .filter(|&k| {
                    let cc = &curve_crossings[k];
                    check.keeps(cc.a as usize, cc.at[0]) && check.keeps(cc.b as usize, cc.at[1])
                })
                .collect();
            // The crossings of the final solve, and their indices into `crossings`;
            // `None`: the strong ones.
            let mut resolved: Option<Vec<Crossing>> = None;
            let mut solved_idx = strong_idx.clone();
            if agreed_idx.len() < strong_idx.len() {
                let dropped = strong_idx.len() - agreed_idx.len();
                tracing::debug!(dropped, "re-solving without off-surface curves");
                let agreed: Vec<Crossing> = agreed_idx.iter().map(|&k| crossings[k]).collect();
                let second = solve::solve(
                    &Problem {
                        crossings: &agreed,
                        ..problem
                    },
                    &config.solve,
                );
                // The second solve starts afresh and may fall into another solution of
                // the orthogonality fit; it is kept only if it fits at least about as
                // well as the first.
                match second {
                    Ok(second) if !fits_worse(&second, &sol) => {
                        sol = second;
                        solved_idx = agreed_idx;
                        resolved = Some(agreed);
                        recheck_dropped = dropped;
                    }
                    Ok(second) => tracing::warn!(
                        first_orthogonality_rms_deg = sol.orthogonality_rms_deg,
                        second_orthogonality_rms_deg = second.orthogonality_rms_deg,
                        "the re-solve without the off-surface curves fits worse; \
                         keeping the first solution"
                    ),
                    Err(e) => tracing::warn!(
                        "the re-solve without the off-surface curves failed ({e}); \
                         keeping the first solution"
                    ),
                }
            }
            let problem = Problem {
                crossings: resolved.as_deref().unwrap_or(&strong),
                ..problem
            };
            // Every plane solved so far refined together; the planes given afterwards
            // (the motion prior's, from faint crossings, refitted) follow them.
            joint = solve::joint::refine_jointly(
                &problem,
                &sol.not_rejected(problem.crossings.len()),
                &mut sol,
                config.solve.joint_refinement_steps,
                config.solve.estimate_focal,
            );
            tracing::debug!(?joint, "planes refined together");
            let sequence: Vec<(u32, u8)> = planes.iter().map(|p| (p.frame, p.laser)).collect();
            motion_fill = solve::motion::fill_and_extend(
                &problem,
                &mut sol,
                &sequence,
                config.solve.motion_prior_max_gap,
            );
            tracing::debug!(?motion_fill, "motion prior");
            // Planes of faint curves only (the far end of a sweep under water) get no
            // crossing in the solve. They are fitted from all their crossings with the
            // solved planes, faint ones included, under the same checks as any
            // extended plane; the crossings the solve rejected or dropped as off the
            // surface stay out.
            let mut usable = vec![true; crossings.len()];
            for &k in &strong_idx {
                usable[k] = false;
            }
            for &k in &solved_idx {
                usable[k] = true;
            }
            for &j in &sol.rejected_crossings {
                if let Some(&k) = solved_idx.get(j) {
                    usable[k] = false;
                }
            }
            let all = Problem {
                crossings: &crossings,
                ..problem
            };
            let (extended, filled) = solve::motion::extend_from(
                &all,
                &usable,
                &mut sol,
                &sequence,
                config.solve.motion_prior_max_gap,
            );
            faint_planes = extended + filled;
            tracing::debug!(extended, filled, "planes from faint crossings");
            let check = cloud::check_crossings(
                &planes_of_curves(&sol.given_planes()),
                &curve_crossings,
                &faint,
                &config.triangulate,
            );
            let rescued = rescue_disputed_planes(
                &mut sol,
                &crossings,
                &curve_ids,
                &check,
                &config.triangulate,
            );
            tracing::debug!(rescued, "planes refitted where their curves were disputed");
            if let Some(warning) = solve::orthogonality_warning(sol.orthogonality_rms_deg) {
                tracing::warn!("{warning}");
            }
            if let Some(warning) = solve::focal_warning(sol.focal_scale, sol.focal_scale_std) {
                tracing::warn!("{warning}");
            }
            sol
        }
        PlaneSource::Known(known) => Solution {
            planes: planes
                .iter()
                .map(|p| {
                    known
                        .get(p.frame as usize)
                        .and_then(|f| f[p.laser as usize & 1])
                })
                .collect(),
            ..Solution::empty()
        },
    };
    times.solve_s = t.elapsed().as_secs_f64();

    // The curves' points are in the file's normalised coordinates `(x, y)`; with a
    // focal estimate λ the true rays are (x/λ, y/λ, 1). Points are triangulated on the
    // planes in the file's coordinates, then scaled by 1/λ in X and Y.
    let lambda = solution.focal_scale;
    let given = solution.given_planes();
    let t = Instant::now();
    let mut cloud = Cloud {
        colors: Some(Vec::new()),
        frames: Some(Vec::new()),
        lasers: Some(Vec::new()),
        ..Default::default()
    };
    let mut pixels: Vec<[f32; 2]> = Vec::new();
    let mut stats = TriangulateStats::default();
    let curve_planes = planes_of_curves(&given);
    // Faint curves must be confirmed by a crossing that agrees.
    let check =
        cloud::check_crossings(&curve_planes, &curve_crossings, &faint, &config.triangulate);
    let mut cid = 0;
    let (mut kept_points, mut kept_px) = (Vec::new(), Vec::new());
    for (id, plane) in planes.iter().enumerate() {
        let first = cid;
        cid += plane.curves.len();
        let Some(v) = given.get(id).copied().flatten() else {
            continue;
        };
        for (k, curve) in plane.curves.iter().enumerate() {
            let i = first + k;
            if check.rejected[i] {
                stats.inconsistent_curves += 1;
                stats.inconsistent_points += curve.points.len();
                continue;
            }
            let (points, points_px) = if check.partial(i) {
                kept_points.clear();
                kept_px.clear();
                for (j, (p, px)) in curve.points.iter().zip(&curve.points_px).enumerate() {
                    if check.keeps(i, j as u32) {
                        kept_points.push(*p);
                        kept_px.push(*px);
                    }
                }
                stats.inconsistent_points += curve.points.len() - kept_points.len();
                (&kept_points[..], &kept_px[..])
            } else {
                (&curve.points[..], &curve.points_px[..])
            };
            stats.add(&cloud::push_curve(
                &mut cloud,
                Some(&mut pixels),
                &v,
                CurvePoints {
                    frame: plane.frame,
                    laser: plane.laser,
                    points,
                    points_px,
                },
                colour_source,
                &config.triangulate,
            ));
        }
    }
    if lambda != 1.0 {
        let inv = (1.0 / lambda) as f32;
        for p in &mut cloud.points {
            p[0] *= inv;
            p[1] *= inv;
        }
    }
    let factor = cloud::scale_for(scale, &cloud, &pixels)?;
    cloud::apply_scale(&mut cloud, factor);
    times.triangulate_s = t.elapsed().as_secs_f64();

    // Planes in the output frame: X' = f·diag(1/λ,1/λ,1)·X, so v' = diag(λ,λ,1)·v / f
    // for a plane v of the file's coordinates.
    let out_planes = given
        .iter()
        .map(|p| p.map(|v| Vector3::new(v.x * lambda, v.y * lambda, v.z) / factor))
        .collect();
    let report = ReconstructReport {
        version: REPORT_VERSION,
        frames,
        frames_with_laser,
        curves: curves_total,
        planes: planes.len(),
        crossings: crossings.len(),
        crossings_in_solve: strong.len(),
        crossings_off_surface: recheck_dropped,
        planes_in_global_solve: solution.global.len(),
        planes_solved: solution.planes.iter().filter(|p| p.is_some()).count(),
        rejected_crossings: solution.rejected_crossings.len(),
        rejected_planes: solution.rejected_curves.len(),
        planes_fixed_by_motion: motion_fill.filled,
        joint_refinement: joint,
        planes_too_uncertain: solution.uncertain_planes,
        planes_from_faint_crossings: faint_planes,
        residual_rms: solution.residual_rms,
        orthogonality_rms_deg: solution.orthogonality_rms_deg,
        focal_scale: lambda,
        focal_scale_std: solution.focal_scale_std,
        focal_px: [camera.fx * lambda, camera.fy * lambda],
        scale_mode: scale.clone(),
        scale_factor: factor,
        points: cloud.len(),
        triangulation: stats,
        seconds: times,
    };
    Ok(Reconstruction {
        cloud,
        pixels,
        report,
        planes: out_planes,
    })
}

/// Whether solution `a` fits clearly worse than `b`: its crosses further from
/// orthogonal (by more than twice and 0.05°), or its crossings' residuals more than
/// twice as large.
fn fits_worse(a: &Solution, b: &Solution) -> bool {
    a.orthogonality_rms_deg > 2.0 * b.orthogonality_rms_deg + 0.05
        || a.residual_rms > 2.0 * b.residual_rms
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::solve::synthetic::{
        curve_polyline, random_scan, worst_off_surface, ScanSpec, Scene,
    };

    /// The image of plane `v` on `scene` as an extracted curve of constant strength.
    fn curve(camera: &Camera, scene: &Scene, v: &Vector3<f64>, laser: u8, strength: f32) -> Curve {
        let points = curve_polyline(scene, v, 1.0 / camera.fx).unwrap_or_default();
        Curve {
            laser,
            points_px: points
                .iter()
                .map(|p| camera.pixel_from_normalized(p[0], p[1]).map(|c| c as f32))
                .collect(),
            strength: vec![strength; points.len()],
            polyline: points.clone(),
            points,
        }
    }

    /// Plane 0 has two curves, on two walls; the others each have one curve per wall and
    /// cross its curves where the planes meet on that wall. A plane 0 turned about its
    /// line on the first wall misses the second wall's crossings by percents
    /// (fitted from the first wall's crossings alone, as a re-solve can leave it); the
    /// rescue refits it from all of them. A right plane is left as it is.
    #[test]
    fn a_plane_turned_about_one_of_its_curves_is_refitted_from_all_of_them() {
        let walls = [Vector3::new(0.0, 0.0, 0.5), Vector3::new(0.0, 0.5, 0.45)];
        let planes: Vec<Vector3<f64>> = (0..7)
            .map(|i| {
                let t = i as f64 * 0.45;
                Vector3::new(1.2 * t.cos(), 1.2 * t.sin(), 0.2 + 0.05 * i as f64)
            })
            .collect();
        // Curves: plane 0 on wall 0 and wall 1, then planes 1..7 on wall 0 and wall 1.
        let mut curve_plane = vec![0u32, 0];
        let mut curve_wall = vec![0usize, 1];
        for p in 1..7u32 {
            curve_plane.extend([p, p]);
            curve_wall.extend([0, 1]);
        }
        let (mut crossings, mut curve_ids, mut curve_crossings) = (vec![], vec![], vec![]);
        for a in 0..curve_plane.len() {
            for b in a + 1..curve_plane.len() {
                let (pa, pb) = (curve_plane[a] as usize, curve_plane[b] as usize);
                if pa == pb || curve_wall[a] != curve_wall[b] {
                    continue;
                }
                let s = walls[curve_wall[a]];
                let u = (planes[pa] - s).cross(&(planes[pb] - s));
                let u = [u.x / u.z, u.y / u.z];
                crossings.push(Crossing {
                    a: pa as u32,
                    b: pb as u32,
                    u,
                    sin_angle: 1.0,
                });
                curve_ids.push([a as u32, b as u32]);
                curve_crossings.push(cloud::CurveCrossing {
                    a: a as u32,
                    b: b as u32,
                    u,
                    at: [0, 0],
                    strength: [100.0; 2],
                });
            }
        }
        let turned = planes[0] + 0.5 * (planes[0] - walls[0]);
        let ctx = crate::solve::extend::FitContext::for_tests(1e-6, 1e-3);
        let solution = |p0: Vector3<f64>| Solution {
            planes: std::iter::once(Some(p0))
                .chain(planes[1..].iter().map(|v| Some(*v)))
                .collect(),
            fit_context: Some(ctx),
            ..Solution::empty()
        };
        let faint = vec![false; curve_plane.len()];
        let params = cloud::TriangulateParams::default();
        // The check of `sol`'s planes, then the rescue.
        let rescue = |sol: &mut Solution| {
            let planes_of_curves: Vec<_> = curve_plane
                .iter()
                .map(|&p| sol.planes[p as usize])
                .collect();
            let check =
                cloud::check_crossings(&planes_of_curves, &curve_crossings, &faint, &params);
            let n = rescue_disputed_planes(sol, &crossings, &curve_ids, &check, &params);
            (check, n)
        };
        // The turned plane holds on the first wall and misses the second by 2-50 %.
        let mut sol = solution(turned);
        let (check, rescued) = rescue(&mut sol);
        assert!(!check.rejected[0] && check.rejected[1], "{check:?}");
        assert_eq!(rescued, 1);
        let v = sol.planes[0].expect("solved");
        assert!(
            (v - planes[0]).norm() < 1e-9 * planes[0].norm(),
            "{v} vs {}",
            planes[0]
        );
        // Right planes are not touched.
        let mut sol = solution(planes[0]);
        assert_eq!(rescue(&mut sol).1, 0);
        assert_eq!(sol.planes[0], Some(planes[0]));
    }

    /// The plane most crossings agree with, against a minority from another plane.
    #[test]
    fn the_most_agreeing_plane_outvotes_a_minority() {
        let truth = Vector3::new(0.4, -0.3, 0.8);
        let other = Vector3::new(0.1, 0.5, 1.1);
        let mut crossings = Vec::new();
        let mut known = Vec::new();
        for i in 0..20 {
            let t = i as f64;
            let u = [0.3 * (0.7 * t).sin(), 0.25 * (1.3 * t).cos()];
            let uu = Vector3::new(u[0], u[1], 1.0);
            // The other curve's plane gives the inverse depth of `truth` (or, for every
            // third crossing, of `other`) at `u`.
            let target = if i % 3 == 0 { other } else { truth };
            let d = target.dot(&uu);
            crossings.push(Crossing {
                a: 0,
                b: 1,
                u,
                sin_angle: 1.0,
            });
            known.push((i, Vector3::new(0.0, 0.0, d)));
        }
        let v = most_agreeing_plane(&crossings, &known, 0.02).expect("plane");
        assert!((v - truth).norm() < 1e-9, "{v}");
        assert_eq!(most_agreeing_plane(&crossings, &known[..2], 0.02), None);
    }

    /// The consensus re-solve is kept unless it fits clearly worse than the first: a
    /// turbid recording once re-solved to crosses 10.5° off orthogonal (0.06° at
    /// first) and a cloud 7 % off.
    #[test]
    fn a_re_solve_that_fits_worse_is_not_kept() {
        let fit = |ortho_deg: f64, residual: f64| Solution {
            orthogonality_rms_deg: ortho_deg,
            residual_rms: residual,
            ..Solution::empty()
        };
        let first = fit(0.06, 4e-5);
        assert!(!fits_worse(&fit(0.04, 3e-5), &first));
        assert!(!fits_worse(&fit(0.1, 5e-5), &first));
        assert!(fits_worse(&fit(10.5, 2.6e-3), &first));
        assert!(fits_worse(&fit(0.2, 4e-5), &first));
        assert!(fits_worse(&fit(0.06, 9e-5), &first));
    }

    /// Under water behind a flat port the camera file's (in-air) focal length is about
    /// 1.33 times too short: every normalised point is 1.33 times too far out. With
    /// the focal length estimated, the cloud must still lie on the surface, in the
    /// true camera's frame, and the output planes must hold their points.
    #[test]
    fn an_estimated_focal_length_gives_the_true_cloud() {
        let camera = Camera::with_fov(1200, 900, 2.0 * 0.6f64.atan());
        let scan = random_scan(&ScanSpec::default());
        let strong = Config::default().solve.min_curve_strength;
        let lambda = 1.33;
        let per_frame: Vec<Vec<Curve>> = (0..scan.planes.len() / 2)
            .map(|k| {
                (0..2)
                    .map(|l| {
                        let mut c = curve(
                            &camera,
                            &scan.scene,
                            &scan.planes[2 * k + l],
                            l as u8,
                            2.0 * strong,
                        );
                        for p in c.points.iter_mut().chain(c.polyline.iter_mut()) {
                            *p = [p[0] * lambda, p[1] * lambda];
                        }
                        c
                    })
                    .collect()
            })
            .collect();
        let mut config = Config::default();
        config.solve.estimate_focal = true;
        let rec = reconstruct_curves(
            per_frame,
            &camera,
            &config,
            PlaneSource::SelfCalibrated,
            &ScaleMode::Factor { factor: 1.0 },
            None,
        )
        .expect("solves");
        let r = &rec.report;
        assert!((r.focal_scale - lambda).abs() < 1e-4, "{r:?}");
        assert!(r.points > 1000, "{r:?}");
        let worst = worst_off_surface(&scan.scene, &rec.cloud.points);
        assert!(
            worst < 1e-3,
            "a point {:.3} % off the surface",
            100.0 * worst
        );
        // Each point on its output plane (same frame and laser).
        let frames = rec.cloud.frames.as_deref().unwrap_or_default();
        let lasers = rec.cloud.lasers.as_deref().unwrap_or_default();
        for (i, p) in rec.cloud.points.iter().enumerate().step_by(97) {
            let plane = (frames[i] * 2 + lasers[i] as u32) as usize;
            let v = rec.planes[plane].expect("plane of a point");
            let x = Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64);
            assert!(
                (v.dot(&x) - 1.0).abs() < 1e-4,
                "point {i}: v·X = {}",
                v.dot(&x)
            );
        }
    }

    #[test]
    fn faint_and_stray_curves_neither_shape_the_planes_nor_reach_the_cloud() {
        let camera = Camera::with_fov(1200, 900, 2.0 * 0.6f64.atan());
        let scan = random_scan(&ScanSpec::default());
        let strong = Config::default().solve.min_curve_strength;
        let mut per_frame: Vec<Vec<Curve>> = (0..scan.planes.len() / 2)
            .map(|k| {
                (0..2)
                    .map(|l| {
                        curve(
                            &camera,
                            &scan.scene,
                            &scan.planes[2 * k + l],
                            l as u8,
                            2.0 * strong,
                        )
                    })
                    .collect()
            })
            .collect();
        // Frame 10's second laser runs onto a dim surface: the second half of its curve
        // is found only at low contrast, as a curve of its own, which must be
        // confirmed by an agreeing crossing, and is.
        let whole = per_frame[10].pop().expect("two curves");
        let half = whole.points.len() / 2;
        let piece = |range: std::ops::Range<usize>, strength: f32| Curve {
            laser: 1,
            points: whole.points[range.clone()].to_vec(),
            points_px: whole.points_px[range.clone()].to_vec(),
            polyline: whole.points[range.clone()].to_vec(),
            strength: vec![strength; range.len()],
        };
        per_frame[10].push(piece(0..half, 2.0 * strong));
        per_frame[10].push(piece(half..whole.points.len(), 0.5 * strong));
        // Frames 3 and 7 carry a stray piece of curve on their first laser's plane that
        // is not on the surface (the glow of the sheet in front of it): one strong, one
        // faint.
        let mut front = scan.scene.clone();
        for f in &mut front.facets {
            *f *= 1.4;
        }
        for (frame, strength) in [(3, 2.0 * strong), (7, 0.5 * strong)] {
            let mut stray = curve(&camera, &front, &scan.planes[2 * frame], 0, strength);
            let third = stray.points.len() / 3;
            stray.points.truncate(third);
            stray.points_px.truncate(third);
            stray.strength.truncate(third);
            stray.polyline.truncate(third);
            per_frame[frame].push(stray);
        }
        // Frame 20's first curve fades along its second half: those crossings do not
        // shape the planes, though its strong half does.
        let fading = &mut per_frame[20][0].strength;
        let n = fading.len();
        fading[n / 2..].fill(0.25 * strong);
        // Frame 30's cross is faint all over (far along the sheets under water): no
        // crossing of it is in the solve, and its planes come from its faint
        // crossings with the solved planes afterwards.
        for c in &mut per_frame[30] {
            c.strength.fill(0.5 * strong);
        }

        let run = |per_frame: Vec<Vec<Curve>>, config: &Config| {
            reconstruct_curves(
                per_frame,
                &camera,
                config,
                PlaneSource::SelfCalibrated,
                &ScaleMode::Factor { factor: 1.0 },
                None,
            )
            .expect("solves")
        };
        let mut ungated = Config::default();
        ungated.solve.min_crossing_strength = 0.0;
        let without_local_gate = run(per_frame.clone(), &ungated).report;
        let rec = run(per_frame, &Config::default());
        let r = &rec.report;
        assert_eq!(r.triangulation.inconsistent_curves, 2, "{r:?}");
        // The strong stray's crossings shaped the first solve only.
        assert!(r.crossings_off_surface > 0, "{r:?}");
        assert!(r.crossings_off_surface < r.crossings_in_solve / 10, "{r:?}");
        assert!(r.crossings_in_solve < without_local_gate.crossings_in_solve);
        assert!(without_local_gate.crossings_in_solve < r.crossings);
        assert_eq!(without_local_gate.crossings, r.crossings);
        // Every point lies on the surface (up to the one global scale).
        assert!(worst_off_surface(&scan.scene, &rec.cloud.points) < 1e-3);
        let frames = rec.cloud.frames.as_deref().unwrap_or_default();
        let lasers = rec.cloud.lasers.as_deref().unwrap_or_default();
        let faint_kept = (0..frames.len())
            .filter(|&i| frames[i] == 10 && lasers[i] == 1)
            .count();
        // Both pieces, but for the points left out at their ends.
        let ends = 2 * 2 * Config::default().triangulate.curve_end_points as usize;
        assert_eq!(faint_kept, whole.points.len() - ends);
        assert_eq!(r.planes_from_faint_crossings, 2, "{r:?}");
        for laser in 0..2 {
            let kept = (0..frames.len())
                .filter(|&i| frames[i] == 30 && lasers[i] == laser)
                .count();
            assert!(kept > 0, "faint cross, laser {laser}");
        }
    }
}
