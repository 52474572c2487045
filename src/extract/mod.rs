//! Laser curve extraction: from a camera frame and a background to sub-pixel, ordered,
//! per-laser curves in distorted pixels and in undistorted normalised coordinates.
//!
//! Owns the background model ([`Background`]), the colour classes ([`colour`]), the
//! Steger ridge detector (`detect`), the linking of ridge points (`link`) and the curves
//! file (`curves`, whose format is documented there). It does not touch camera models
//! (it calls [`Camera::normalized_from_pixel`]) or anything downstream of curves.
//!
//! # Steps of [`Extractor::extract`]
//! 1. *Colour* (input-format specific, RGB here): the positive part of
//!    `frame − background` is classified per pixel through an RGB look-up table built
//!    from HSV limits ([`colour::ColourLut`]); tiles holding a pixel of laser `k`'s
//!    colour become active for laser `k`. Laser `k`'s response is the difference in
//!    `k`'s own channels (the largest of them: red for a red laser, red and green for a
//!    yellow one; [`LaserColour::channels`]) on pixels that are weak, white
//!    (desaturated) or of `k`'s colour, and zero on the other laser's colour where that
//!    is bright enough to be its stripe (`block_contrast`), so the two stripes of the
//!    cross stay apart; dimmer pixels of the other colour (its sheet's glow under
//!    water) count as weak and leave no holes beside the stripe, and since that glow is
//!    in the other laser's channels it neither hides nor fakes `k`'s faint stripe. A
//!    pixel of a hue no laser has counts for `k` (activation and response) when its
//!    light outside `k`'s channels is under `block_contrast`: a faint red stripe on the
//!    green sheet's veil reads orange. A white difference on a pixel grey in the frame
//!    is what changed since the background (a strand moved away, a lamp came on), not
//!    laser light: it keeps only what `k`'s channel has beyond the others
//!    ([`ColourLut::response_off`]). Where the frame lies evenly below its background
//!    over a 32 px cell (`lift_darkened`: the other sheet's glow was in the background
//!    there, not in this frame), the response is taken from the frame lifted by that
//!    much.
//! 2. *Ridges* (per laser, active tiles only): separable Gaussian derivatives, the
//!    Hessian, its eigenvector across the line, the second-order Taylor offset
//!    `t = −(n·∇g)/λ` that must stay in the pixel (`|t·n| ≤ 0.5` in both axes), for
//!    bright lines only (`λ < 0` and the strongest curvature). A point must also stand
//!    out of its flanks, `2.5 σ` to either side across the line, by twice: the bright
//!    edge of a wide glow band also reads as a ridge, with the glow on one flank.
//!    Under water the sheet's glow fills one side of its stripe up to the centre line
//!    and tilts the ridge towards it (0.1–0.3 px); each point keeps what
//!    [`detect::step_shift`] needs to take that off. Against a given background, a
//!    point that is a valley of the background rather than a ridge of the frame (an
//!    object that has moved away since), or no ridge of the laser's own channel in the
//!    difference, is not used ([`valley`]).
//! 3. *Linking* with hysteresis (`low_contrast` to continue, `high_contrast` to start,
//!    or `faint_start_contrast` for a curve at least `faint_min_length_px` long),
//!    gaps of up to 3 px jumped along the line, fragments with less than
//!    `min_curve_length_px` of linked ridge dropped, points undistorted one by
//!    one, Douglas–Peucker simplification in undistorted pixel units. In the last
//!    linking of a frame each point is moved off the glow step under it: the step
//!    measured across the line at four distances, its median over runs of 21 points,
//!    kept where it is a plateau ([`glow::glow_moves`]).
//! 4. *Following*: the tiles half a tile and a tile beyond each curve's ends along its
//!    direction are activated, their points found and everything linked again, for up
//!    to `MAX_FOLLOW_ROUNDS` (32) rounds while curves grow: a stripe fading below
//!    `min_value` (far along the sheet under water) activates no tile of its own, but
//!    hysteresis may follow it down to `low_contrast`.
//!
//! # Without a laser-off frame
//! [`Background::local`] has the extractor estimate each frame's own background
//! ([`local`]: a morphological opening 17 px wide, its noise bias measured per 64 px
//! tile and added back). The excess over it still holds the surfaces' texture. A
//! stripe is located on its laser's own channel, as against a laser-off frame, and a
//! ridge point's strength is scaled by its chromatic share, the part of that channel
//! beyond the largest other one ([`ColourLut::response_local`]: nothing for white or
//! grey), except where its own channel is clipped and the others carry the core; a
//! tile is activated only by pixels whose excess is purer in hue than the surface
//! under them, and the faint-stripe activation counts only the part of a ridge that
//! the surface's own colour does not explain (texture is ridge-like, in that colour).
//!
//! # Checks ([`ExtractStats`], `checks`)
//! Points on a clipped own channel are counted, and a large share is warned about once;
//! a curve of one laser lying along a stronger curve of the other is dropped (one
//! overexposed laser read twice); with two lasers set and only one in the frames, that
//! is said once.
//!
//! # Scale
//! With no `line_width_px` (the default) each active tile measures its stripe's width
//! (FWHM) on the response around it: the pixels at or above half the local maximum
//! form a band whose second moment across is `w² / 12`, whatever its direction. The
//! tile then runs at the smallest scale of [`AUTO_SIGMAS_PX`] with `2√3 σ ≥ w` (Steger's
//! bar condition `σ ≥ (w/2)/√3`, which keeps a clipped flat top a single ridge); the
//! Gaussian stripe's ln-g offset is exact at any `σ`. A stripe on a pedestal (its
//! sheet's glow along one side of it under water) would give the pedestal's width, so
//! the band above 80 % of the maximum is measured too; when it is much narrower than a
//! Gaussian's, the width comes from it. Against a local background, a tile whose band
//! is round rather than a band (a pattern in the laser's own hue spread over the
//! window, `detect::width::MAX_BAND_ROUNDNESS`) or flat-topped where its own channel is not
//! clipped (a patch of a surface in that hue, `detect::width::FLAT_RATIO`) is not searched.
//! A given `line_width_px` forces `σ = max(w / (2√3), 1)`, and `sigma_px` forces `σ`.
//!
//! # Thresholds
//! `high_contrast` and `low_contrast` are absolute, in grey levels (0–255) of the
//! background-subtracted stripe peak: a Gaussian stripe whose full width at half
//! maximum is `w` and whose peak is `c` grey levels above the background gives a
//! Hessian eigenvalue `c · s / (s² + σ²)^{3/2}` (`s` = w / 2.355). Each scale divides
//! its eigenvalues by that factor for the width it is for (`line_width_px`, or
//! `2√3 σ` for the automatic scales), so strengths and thresholds are grey levels at
//! every scale; a stripe narrower than its scale's width reads up to ~1.4× its
//! contrast. [`Curve::strength`] is in the same unit.
//!

mod activate;
pub mod background;
mod checks;
pub mod chroma;
pub mod colour;
mod curves;
mod detect;
mod faint;
mod glow;
mod link;
pub mod local;
mod response;
pub mod rolling;
pub mod score;
mod timing;
mod valley;
pub mod yuyv;

use image::RgbImage;
use serde::{Deserialize, Serialize};

use crate::camera::Camera;
pub use background::Background;
pub use checks::Presence;
pub use colour::{ColourLut, ColourParams, LaserColour};
pub use curves::{Curve, CurvesFile, CURVES_FILE_VERSION};
use detect::Detector;
use link::Linker;
use response::{response_rgb, DarkCells};
pub use timing::StageTimes;

#[derive(Debug, thiserror::Error)]
pub enum ExtractError {
    #[error("invalid extraction parameter {key}: {message}")]
    Params { key: &'static str, message: String },
    #[error("background: {message}")]
    Background { message: String },
    #[error("frame is {got_width}x{got_height}, expected {width}x{height} ({what})")]
    Size {
        what: &'static str,
        width: u32,
        height: u32,
        got_width: u32,
        got_height: u32,
    },
    #[error("cannot read {path}: {source}")]
    Io {
        path: std::path::PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("curves file {path}: {message}")]
    CurvesFile {
        path: std::path::PathBuf,
        message: String,
    },
}

/// Extraction parameters; every key of the `[extract]` table of `crossline.toml`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ExtractParams {
    /// Stripe width in pixels (full width at half maximum); absent: measured per tile
    /// and the smoothing scale chosen from [`AUTO_SIGMAS_PX`] (see the module doc).
    pub line_width_px: Option<f64>,
    /// Smoothing scale, forcing one scale; derived from the width when absent.
    pub sigma_px: Option<f64>,
    /// A curve starts at points of at least this contrast (grey levels, see module doc).
    pub high_contrast: f32,
    /// A curve continues through points of at least this contrast.
    pub low_contrast: f32,
    /// A curve may also start at a point of this contrast (below `high_contrast`) when
    /// it grows at least `faint_min_length_px` long: faint stripes are long.
    pub faint_start_contrast: f32,
    pub faint_min_length_px: f64,
    /// A pixel of the other laser's colour blocks a laser from this contrast up (the
    /// other laser's stripe for certain); dimmer ones (its tails, its glow under
    /// water) count as weak for both.
    pub block_contrast: f32,
    /// Curves shorter than this (pixels of linked ridge, gaps jumped not counted) are
    /// dropped.
    pub min_curve_length_px: f64,
    /// Douglas–Peucker tolerance in undistorted pixels (normalised × focal length).
    pub dp_tolerance_px: f64,
    /// Largest change of direction between linked neighbours, degrees.
    pub max_link_angle_deg: f64,
    /// Minimum HSV value (0–255) of the difference for a pixel to get a colour class.
    pub min_value: u8,
    /// Minimum HSV saturation (0–1) for a hue to count; below, a bright pixel is white.
    pub min_saturation: f32,
    /// Also activate tiles where a stripe too faint for any pixel to reach `min_value`
    /// runs ([`faint`]: continued ridges of 2×2 block sums, against the noise measured
    /// on the frame). RGB input only: YUYV extraction converts no tile for it.
    pub faint_activation: bool,
    /// Where the frame lies below its background over a 32 px cell (under water, the
    /// other sheet's glow lit that place in most of the background's frames but not in
    /// this one), take the response from the frame lifted by that much
    /// ([`faint::FaintRidges::darkening`]): a stripe there rises above its dark
    /// surroundings, not above the background, and the positive part of the
    /// difference would keep only the little it rises above the background. Needs
    /// `faint_activation` (it measures the cells); RGB input only.
    pub lift_darkened: bool,
    /// One or two lasers; a curve's `laser` indexes this list.
    pub lasers: Vec<LaserColour>,
}

impl Default for ExtractParams {
    fn default() -> Self {
        let colour = ColourParams::default();
        Self {
            line_width_px: None,
            sigma_px: None,
            high_contrast: 15.0,
            low_contrast: 6.0,
            faint_start_contrast: 10.0,
            faint_min_length_px: 60.0,
            block_contrast: colour.mask_value as f32,
            min_curve_length_px: 15.0,
            dp_tolerance_px: 0.3,
            max_link_angle_deg: 30.0,
            min_value: colour.min_value,
            faint_activation: true,
            lift_darkened: true,
            min_saturation: colour.min_saturation,
            lasers: vec![LaserColour::red(), LaserColour::green()],
        }
    }
}

impl ExtractParams {
    /// The detector's scales: one when `sigma_px` or `line_width_px` is given, else
    /// the ladder [`AUTO_SIGMAS_PX`], each for the stripes up to `2√3 σ` wide.
    fn scales(&self) -> Vec<detect::Scale> {
        let nominal_width = |sigma: f64| 2.0 * 3f64.sqrt() * sigma;
        let one = |sigma: f64, width: f64| detect::Scale {
            sigma_px: sigma,
            eigenvalue_per_grey_level: eigenvalue_per_grey_level(width, sigma),
            max_width_px: f64::INFINITY,
        };
        match (self.sigma_px, self.line_width_px) {
            (Some(sigma), width) => vec![one(sigma, width.unwrap_or(nominal_width(sigma)))],
            (None, Some(width)) => vec![one((width / (2.0 * 3f64.sqrt())).max(1.0), width)],
            (None, None) => AUTO_SIGMAS_PX
                .iter()
                .map(|&sigma| detect::Scale {
                    sigma_px: sigma,
                    eigenvalue_per_grey_level: eigenvalue_per_grey_level(
                        nominal_width(sigma),
                        sigma,
                    ),
                    max_width_px: nominal_width(sigma),
                })
                .collect(),
        }
    }

    fn validate(&self) -> Result<(), ExtractError> {
        let bad = |key, message: String| Err(ExtractError::Params { key, message });
        if let Some(w) = self.line_width_px {
            if !(w.is_finite() && (0.5..=100.0).contains(&w)) {
                return bad("line_width_px", format!("expected 0.5..=100, got {w}"));
            }
        }
        if let Some(s) = self.sigma_px {
            if !(s.is_finite() && (0.5..=50.0).contains(&s)) {
                return bad("sigma_px", format!("expected 0.5..=50, got {s}"));
            }
        }
        if !(self.low_contrast >= 0.0 && self.high_contrast >= self.low_contrast) {
            return bad(
                "low_contrast",
                format!(
                    "expected 0 <= low_contrast <= high_contrast, got {} and {}",
                    self.low_contrast, self.high_contrast
                ),
            );
        }
        if !(self.faint_start_contrast >= self.low_contrast && self.faint_min_length_px >= 0.0) {
            return bad(
                "faint_start_contrast",
                format!(
                    "expected low_contrast <= faint_start_contrast and faint_min_length_px >= 0, got {} (low {}) and {}",
                    self.faint_start_contrast, self.low_contrast, self.faint_min_length_px
                ),
            );
        }
        if !(self.block_contrast > 0.0 && self.block_contrast <= 255.0) {
            return bad(
                "block_contrast",
                format!("expected in (0, 255], got {}", self.block_contrast),
            );
        }
        if self.min_curve_length_px.is_nan() || self.min_curve_length_px < 0.0 {
            return bad("min_curve_length_px", "expected >= 0".into());
        }
        if self.dp_tolerance_px.is_nan() || self.dp_tolerance_px < 0.0 {
            return bad("dp_tolerance_px", "expected >= 0".into());
        }
        if !(self.max_link_angle_deg > 0.0 && self.max_link_angle_deg < 90.0) {
            return bad("max_link_angle_deg", "expected in (0, 90)".into());
        }
        if !(0.0..=1.0).contains(&self.min_saturation) {
            return bad("min_saturation", "expected in [0, 1]".into());
        }
        if self.lasers.is_empty() || self.lasers.len() > 2 {
            return bad(
                "lasers",
                format!("expected one or two lasers, got {}", self.lasers.len()),
            );
        }
        for l in &self.lasers {
            if l.hue_deg.iter().any(|h| !(0.0..=360.0).contains(h)) {
                return bad(
                    "lasers.hue_deg",
                    format!("laser {:?}: hues must be in [0, 360]", l.name),
                );
            }
        }
        Ok(())
    }
}

/// Rounds of following curves into the tiles ahead of their ends: each round reaches
/// up to one tile further, so a faint tail is followed for up to this many tiles.
const MAX_FOLLOW_ROUNDS: usize = 32;

/// Smoothing scales (px) of the automatic width: each takes the stripes up to
/// `2√3 σ` wide (Steger's bar condition `σ ≥ w_half / √3`), so FWHM ≤ 3.5, 4.5, 5.9,
/// 7.6, 9.7, 12.1 and 15.6 px; wider stripes get the last scale. Steps of ~1.3 keep
/// the chosen scale (and its cost, which grows with σ) close to the least that works.
pub const AUTO_SIGMAS_PX: [f64; 7] = [1.0, 1.3, 1.7, 2.2, 2.8, 3.5, 4.5];

/// Hessian eigenvalue at scale `sigma` of a Gaussian stripe `width` px wide (FWHM) and
/// one grey level high.
fn eigenvalue_per_grey_level(width: f64, sigma: f64) -> f64 {
    let s = width / (8.0 * 2f64.ln()).sqrt();
    s / (s * s + sigma * sigma).powf(1.5)
}

/// Counts of the last frame, for logs and benchmarks.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ExtractStats {
    /// Active tiles summed over the lasers.
    pub active_tiles: usize,
    /// Ridge points found, summed over the lasers.
    pub ridge_points: usize,
    /// Tiles activated by following curves out of the active ones, summed over the
    /// lasers and rounds.
    pub follow_tiles: usize,
    /// Points of the curves, and those measured where their laser's own channel is
    /// clipped (through the other channels, [`ColourLut::response_raw`]).
    pub points: usize,
    pub clipped_points: usize,
    /// Points of curves dropped as another laser's stripe seen a second time.
    pub repeated_points: usize,
    /// Points of curves dropped as running along an edge of the scene (without a
    /// laser-off frame: chroma fringes).
    pub fringe_points: usize,
    /// Active tiles, summed over the lasers, not searched because what stands out
    /// there is a pattern or a flat-topped patch, not a stripe (without a laser-off
    /// frame: texture in the laser's hue).
    pub round_tiles: usize,
    /// Ridge points, summed over the lasers, not used because they are a valley of the
    /// given background rather than a ridge of the frame: something that lay there when
    /// the background was taken has moved away since ([`valley`]).
    pub moved_points: usize,
}

/// The per-frame extractor; owns and reuses all its scratch buffers.
pub struct Extractor {
    params: ExtractParams,
    camera: Camera,
    lut: ColourLut,
    detector: Detector,
    linker: Linker,
    active: Vec<Vec<bool>>,
    /// Per tile: holds a white (bright, desaturated) pixel; scratch of the activation.
    white: Vec<bool>,
    grown: Vec<bool>,
    /// No lens distortion: points skip the undistortion.
    undistorted_camera: bool,
    stats: ExtractStats,
    times: StageTimes,
    /// The background in YUV and the scratch frame of [`Self::extract_yuyv`].
    yuv: Option<yuyv::BackgroundYuv>,
    /// Scratch of the faint-stripe activation ([`faint`]).
    faint: faint::FaintRidges,
    /// How far the frame lies below its background, per cell
    /// ([`faint::FaintRidges::darkening`]).
    dark: DarkCells,
    /// The frame being extracted came from YUYV: only some tiles hold its pixels, so
    /// the faint-stripe activation is skipped ([`yuyv`]).
    yuyv_frame: bool,
    /// The local background ([`Background::local`]) and its scratch.
    local: local::LocalBackground,
    local_image: RgbImage,
    /// The frame being extracted is measured against its local background.
    local_active: bool,
    presence: checks::Presence,
    repeat_scratch: Vec<u8>,
    /// How the frames' chroma was sampled, as far as the frames have told.
    sampling: chroma::Reader,
    /// Per ridge point of the laser being linked: its move off the chroma rebuild's
    /// pull ([`chroma::point_moves`]); empty for full chroma.
    chroma_moves: Vec<f32>,
}

impl Extractor {
    /// An extractor for frames of the camera's size.
    pub fn new(params: &ExtractParams, camera: &Camera) -> Result<Self, ExtractError> {
        params.validate()?;
        if camera.width == 0 || camera.height == 0 {
            return Err(ExtractError::Params {
                key: "camera",
                message: "image size is zero".into(),
            });
        }
        let lut = ColourLut::new(
            &params.lasers,
            &ColourParams {
                min_value: params.min_value,
                min_saturation: params.min_saturation,
                mask_value: params.block_contrast.round().clamp(1.0, 255.0) as u8,
            },
        );
        let detector = Detector::new(
            camera.width as usize,
            camera.height as usize,
            &params.scales(),
        );
        let tiles = detector.tiles_x * detector.tiles_y;
        Ok(Self {
            undistorted_camera: camera.distortion.is_zero(),
            active: vec![vec![false; tiles]; params.lasers.len()],
            white: vec![false; tiles],
            grown: vec![false; tiles],
            params: params.clone(),
            camera: camera.clone(),
            lut,
            detector,
            linker: Linker::default(),
            stats: ExtractStats::default(),
            times: StageTimes::default(),
            yuv: None,
            faint: faint::FaintRidges::default(),
            dark: DarkCells::default(),
            yuyv_frame: false,
            local: local::LocalBackground::new(local::DEFAULT_RADIUS_PX),
            local_image: RgbImage::new(0, 0),
            local_active: false,
            presence: checks::Presence::default(),
            repeat_scratch: Vec::new(),
            sampling: chroma::Reader::default(),
            chroma_moves: Vec::new(),
        })
    }

    pub fn params(&self) -> &ExtractParams {
        &self.params
    }

    pub fn stats(&self) -> ExtractStats {
        self.stats
    }

    /// Where the last frame's extraction spent its time, stage by stage.
    pub fn stage_times(&self) -> StageTimes {
        self.times
    }

    /// Takes the frames to come as their decoder rebuilt their chroma, from their bytes
    /// ([`crate::capture::chroma`]), instead of reading it off their pixels: exact from
    /// the first frame, and the same in every worker.
    pub fn know_chroma(&mut self, rebuild: [chroma::Rebuild; 2]) {
        self.sampling.know(rebuild);
    }

    /// The curves of `frame` against `background`. A frame with no laser gives no
    /// curves. Frames or backgrounds not of the camera's size are a caller's bug: they
    /// are logged and give no curves (see [`Self::try_extract`]).
    pub fn extract(&mut self, frame: &RgbImage, background: &Background) -> Vec<Curve> {
        match self.try_extract(frame, background) {
            Ok(curves) => curves,
            Err(e) => {
                tracing::error!("extract: {e}");
                Vec::new()
            }
        }
    }

    /// As [`Self::extract`], with a size mismatch returned as an error.
    pub fn try_extract(
        &mut self,
        frame: &RgbImage,
        background: &Background,
    ) -> Result<Vec<Curve>, ExtractError> {
        let (w, h) = (self.camera.width, self.camera.height);
        for (what, img) in [("frame", frame), ("background", background.image())] {
            if img.dimensions() != (w, h) {
                return Err(ExtractError::Size {
                    what,
                    width: w,
                    height: h,
                    got_width: img.width(),
                    got_height: img.height(),
                });
            }
        }
        if background.is_local() {
            let mut image = std::mem::take(&mut self.local_image);
            let mut lap = timing::Lap::start();
            self.local.estimate_into(frame, &mut image);
            let opening = lap.next();
            self.local_active = true;
            let curves = self.extract_from(&mut WholeFrame(frame), &image, None);
            self.local_active = false;
            self.times.local = opening;
            self.local_image = image;
            return curves;
        }
        self.extract_from(
            &mut WholeFrame(frame),
            background.image(),
            Some(background.id()),
        )
    }

    /// The local background of the last frame extracted against
    /// [`Background::local`] (empty before).
    pub fn local_background(&self) -> &RgbImage {
        &self.local_image
    }

    /// The curves of `src`'s frame (of the camera's size) against `background`, whose
    /// [`Background::id`] is `background_id` (`None` for one made for this frame).
    fn extract_from(
        &mut self,
        src: &mut dyn TileFrame,
        background: &RgbImage,
        background_id: Option<u64>,
    ) -> Result<Vec<Curve>, ExtractError> {
        let mut lap = timing::Lap::start();
        self.activate_rgb(src.frame(), (background, background_id), self.local_active);
        self.times = StageTimes {
            activate: lap.next(),
            ..StageTimes::default()
        };
        let sampling = self.sampling.sampling(src.frame());
        self.times.chroma = lap.next();
        let mut curves = Vec::new();
        self.stats = ExtractStats::default();
        self.detector.texture_kept = self.local_active;
        for laser in 0..self.params.lasers.len() {
            self.detector.prepare(
                &self.active[laser],
                &mut response_rgb(
                    &self.lut,
                    laser as u8,
                    src.frame(),
                    background,
                    &self.dark,
                    self.local_active,
                ),
            );
            self.times.response += lap.next();
            self.detector
                .detect(&self.active[laser], self.params.low_contrast);
            self.veto_valleys(laser, src.frame(), background, 0);
            self.times.detect += lap.next();
            let first = curves.len();
            self.link_into(laser as u8, &mut curves, false);
            self.follow_curves(laser, src, background, &mut curves, first);
            self.times.follow += lap.next();
            // Linked once more, the points moved off the glow under them and off the
            // chroma rebuild's pull: the rounds above only need where the curves end.
            chroma::point_moves(
                &sampling,
                &self.detector.points,
                (src.frame(), background),
                self.params.lasers[laser].channels(),
                &mut self.chroma_moves,
            );
            curves.truncate(first);
            self.link_into(laser as u8, &mut curves, true);
            self.times.link += lap.next();
            self.stats.round_tiles += self.detector.round_tiles;
            self.stats.active_tiles += self.active[laser].iter().filter(|a| **a).count();
            self.stats.ridge_points += self.detector.points.len();
        }
        if self.local_active {
            // With a laser-off frame, a fringe is in the background too and never
            // becomes a ridge; a stripe along a real edge would only be lost.
            self.stats.fringe_points = checks::drop_edge_fringes(&mut curves, src.frame());
        }
        if self.params.lasers.len() > 1 {
            let size = (self.detector.width, self.detector.height);
            self.stats.repeated_points =
                checks::drop_repeats(&mut curves, size, &mut self.repeat_scratch);
        }
        self.stats.points = curves.iter().map(|c| c.points_px.len()).sum();
        self.stats.clipped_points = checks::clipped_points(&self.lut, src.frame(), &curves);
        self.presence
            .observe(&self.params.lasers, &curves, self.stats.clipped_points);
        self.times.checks = lap.next();
        Ok(curves)
    }

    /// Follows laser `laser`'s curves (from `first` in `curves`, linked for their
    /// ends) out of the active tiles, up to [`MAX_FOLLOW_ROUNDS`] rounds while they
    /// grow: a stripe fading below `min_value` (a faint tail under water) activates no
    /// tile of its own.
    fn follow_curves(
        &mut self,
        laser: usize,
        src: &mut dyn TileFrame,
        background: &RgbImage,
        curves: &mut Vec<Curve>,
        first: usize,
    ) {
        for _ in 0..MAX_FOLLOW_ROUNDS {
            if !self.tiles_ahead(laser, &curves[first..]) {
                break;
            }
            self.stats.follow_tiles += self.grown.iter().filter(|g| **g).count();
            src.ensure(&self.grown, self.detector.tiles_x, self.detector.tiles_y);
            self.detector.extend(
                &self.grown,
                &mut response_rgb(
                    &self.lut,
                    laser as u8,
                    src.frame(),
                    background,
                    &self.dark,
                    self.local_active,
                ),
            );
            let from = self.detector.points.len();
            self.detector
                .detect_more(&self.grown, self.params.low_contrast);
            self.veto_valleys(laser, src.frame(), background, from);
            for (a, g) in self.active[laser].iter_mut().zip(&self.grown) {
                *a |= *g;
            }
            curves.truncate(first);
            self.link_into(laser as u8, curves, false);
        }
    }

    /// Against a given background, takes laser `laser`'s ridge points from `from` on
    /// out of the linking where they are a valley of the background rather than a
    /// ridge of the frame: something moved away since ([`valley`]).
    fn veto_valleys(&mut self, laser: usize, frame: &RgbImage, background: &RgbImage, from: usize) {
        if self.local_active {
            return;
        }
        self.stats.moved_points += valley::veto_background_valleys(
            &mut self.detector.points[from..],
            (frame, background),
            &self.lut,
            laser as u8,
        );
    }

    /// Whether the extractor (or one sharing its warnings) has told that one of its
    /// two lasers is not in the frames.
    pub fn one_laser_absent(&self) -> bool {
        self.presence.absent_told()
    }

    /// The counters of the one-time warnings (saturated stripes, a laser missing):
    /// give them to the other extractors of the same run
    /// ([`Extractor::sharing_warnings`]) and each warning comes once per run.
    pub fn warnings(&self) -> Presence {
        self.presence.clone()
    }

    /// This extractor, counting into `presence` (from [`Extractor::warnings`]).
    pub fn sharing_warnings(mut self, presence: Presence) -> Self {
        self.presence = presence;
        self
    }

    /// Links the detector's points into `curves` of `laser`. With `last`, each point is
    /// moved off the glow step under it ([`glow::glow_moves`]) and off the chroma
    /// rebuild's pull, undistorted, and its curve simplified; without, the curves hold
    /// their pixel points alone, which is all the follow rounds read (where the curves
    /// end), so that each point is undistorted (a Newton iteration) once a frame.
    fn link_into(&mut self, laser: u8, curves: &mut Vec<Curve>, last: bool) {
        let det = &self.detector;
        let camera = &self.camera;
        let params = &self.params;
        let undistorted_camera = self.undistorted_camera;
        let chroma_moves = &self.chroma_moves;
        self.linker.link(
            &det.points,
            &det.index,
            (det.width, det.height),
            link::Hysteresis {
                low: params.low_contrast,
                high: params.high_contrast,
                faint_start: params.faint_start_contrast,
                faint_min_length_px: params.faint_min_length_px as f32,
            },
            params.max_link_angle_deg.to_radians() as f32,
            |chain| {
                let mut curve = Curve {
                    laser,
                    points_px: Vec::with_capacity(chain.len()),
                    points: Vec::with_capacity(if last { chain.len() } else { 0 }),
                    strength: Vec::with_capacity(chain.len()),
                    polyline: Vec::new(),
                };
                if !last {
                    for &i in chain {
                        let p = &det.points[i as usize];
                        curve.points_px.push([p.x, p.y]);
                        curve.strength.push(p.strength);
                    }
                    if curve.points_px.len() >= 2
                        && curve.linked_length_px() >= params.min_curve_length_px
                    {
                        curves.push(curve);
                    }
                    return;
                }
                let mut moves = glow::glow_moves(det, chain);
                if !chroma_moves.is_empty() {
                    for (m, &i) in moves.iter_mut().zip(chain) {
                        *m += chroma_moves[i as usize];
                    }
                }
                for (&i, &shift) in chain.iter().zip(&moves) {
                    let mut p = det.points[i as usize];
                    p.x += shift * p.nx;
                    p.y += shift * p.ny;
                    let (u, v) = (p.x as f64, p.y as f64);
                    let normalized = if undistorted_camera {
                        let (x, y) = camera.distorted_from_pixel(u, v);
                        Some([x, y])
                    } else {
                        camera.normalized_from_pixel(u, v)
                    };
                    if let Some(n) = normalized {
                        curve.points_px.push([p.x, p.y]);
                        curve.points.push(n);
                        curve.strength.push(p.strength);
                    }
                }
                if curve.points.len() < 2 || curve.linked_length_px() < params.min_curve_length_px {
                    return;
                }
                let scaled: Vec<[f64; 2]> = curve
                    .points
                    .iter()
                    .map(|p| [p[0] * camera.fx, p[1] * camera.fy])
                    .collect();
                curve.polyline = link::douglas_peucker(&scaled, params.dp_tolerance_px)
                    .into_iter()
                    .map(|i| curve.points[i])
                    .collect();
                curves.push(curve);
            },
        );
    }
}

/// The tiles within `r` tiles of tile `t` (itself included) on a `tiles_x` × `tiles_y`
/// grid.
pub(crate) fn tiles_near(
    t: usize,
    r: usize,
    tiles_x: usize,
    tiles_y: usize,
) -> impl Iterator<Item = usize> {
    let (tx, ty) = (t % tiles_x, t / tiles_x);
    (ty.saturating_sub(r)..(ty + r + 1).min(tiles_y)).flat_map(move |y| {
        (tx.saturating_sub(r)..(tx + r + 1).min(tiles_x)).map(move |x| y * tiles_x + x)
    })
}

/// The frame an extraction reads: whole (RGB input), or converted tile by tile where
/// a stripe can be (YUYV input, see [`yuyv`]).
pub(crate) trait TileFrame {
    fn frame(&self) -> &RgbImage;
    /// Makes the tiles marked in `tiles` (`tiles_x` × `tiles_y` of the detector), and
    /// the tiles next to them, hold the frame's own pixels: the detector's kernels
    /// reach one tile beyond the tiles it runs on.
    fn ensure(&mut self, tiles: &[bool], tiles_x: usize, tiles_y: usize);
}

/// An RGB frame, whole.
struct WholeFrame<'a>(&'a RgbImage);

impl TileFrame for WholeFrame<'_> {
    fn frame(&self) -> &RgbImage {
        self.0
    }
    fn ensure(&mut self, _: &[bool], _: usize, _: usize) {}
}

#[cfg(test)]
mod tests;
#[cfg(test)]
mod tests_activate;
#[cfg(test)]
mod tests_chroma;
#[cfg(test)]
mod tests_real;
