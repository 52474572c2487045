//! Image formation: a per-pixel cache of the fixed view (ray-cast once), then per frame
//! the two laser stripes, water glow, sensor noise and quantisation.
//!
//! The stripe is an image-space Gaussian across the plane's image curve: for a pixel
//! whose surface point `P` lies at signed distance `d = n·P − h` from a laser plane,
//! `I ∝ exp(−d² / (2 (b² + g² σ_psf²)))`, where `b` is the beam half thickness and `g`
//! the length of `∇_pixel d` (metres per pixel along the curve normal). In pixel units
//! that is a profile of variance `(b/g)² + σ_psf²` centred exactly on the curve `d = 0`.
//! Only pixels within 4σ are shaded: fan test, a shadow ray to the projector, Lambert
//! incidence, inverse-square fall-off, albedo × texture.
//!
//! Under water: attenuation `exp(-c (|P - C| + |P|))`, per channel for the ambient light
//! and by the coefficient of its wavelength's channel for a laser (one wavelength: water
//! and surface dim it, they do not change its hue); forward scatter mixes
//! in a wider, dimmer copy of the same profile (blur `forward_blur_mrad`), so centres stay
//! exact; backscatter adds glow where a camera ray crosses a sheet in front of its
//! surface (`∝ 1/|cos|`, attenuated, clipped, its edge at the stripe's centre line as
//! soft as the stripe), up to where the sheet first meets a surface (a per-frame table
//! of 4096 sheet rays; nothing can hide the glow from the camera, as it lies in front
//! of the pixel's first surface).

use std::sync::Arc;

use image::RgbImage;
use nalgebra::{Matrix2, Matrix3x2, Vector3};
use rayon::prelude::*;

use super::motion::{Motion, ProjectorPose, SplitMix64};
use super::realism::{self, Realism};
use super::scene::{camera_from_spec, mix64, Medium, Scene, SceneSpec};
use super::{FrameTruth, SimError};
use crate::camera::Camera;

type V3 = Vector3<f64>;

/// Settings of one simulation run that are not part of the scene.
#[derive(Clone, Debug, PartialEq)]
pub struct SimParams {
    pub seed: u64,
    /// Standard deviation of the Gaussian sensor noise, grey levels.
    pub noise_sigma: f64,
    /// Pass every image through a JPEG encoder of this quality (1-100).
    pub jpeg_quality: Option<u8>,
    /// Effects of real frames (lit rooms, clipping, chroma subsampling, ...); none by
    /// default.
    pub realism: Realism,
}

impl Default for SimParams {
    fn default() -> Self {
        Self {
            seed: 1,
            noise_sigma: 2.0,
            jpeg_quality: None,
            realism: Realism::none(),
        }
    }
}

/// What the fixed camera sees at one pixel, computed once per scene.
#[derive(Clone, Copy, Debug, Default)]
struct Pixel {
    /// Surface point (camera coordinates); for misses, a point far along the ray.
    p: [f64; 3],
    /// Distance of `p` from the camera.
    range: f32,
    /// `∂P/∂u` and `∂P/∂v` on the local tangent plane (scene units per pixel).
    j: [f32; 6],
    /// Squared Frobenius norm of `j`: an upper bound of `g²` for any plane.
    jf2: f32,
    /// Unit surface normal facing the camera.
    normal: [f32; 3],
    /// Albedo times texture.
    refl: [f32; 3],
    hit: bool,
}

/// The part of [`Pixel`] every frame reads for every pixel, packed so a frame streams
/// 32 bytes per pixel instead of a hundred.
#[derive(Clone, Copy, Debug, Default)]
struct Hot {
    p: [f32; 3],
    /// `Pixel::jf2`, or -1 where the ray leaves the scene.
    jf2: f32,
    ambient: [f32; 3],
    range: f32,
}

/// Laser `k` in one frame.
struct LaserFrame {
    n: V3,
    h: f64,
    centre: V3,
    axis: V3,
    fan_dir: V3,
    colour: [f64; 3],
    /// The channel the laser's wavelength falls in: its light is one wavelength, so the
    /// surface reflects and the water attenuates all of it by that channel's factors,
    /// and the camera's channels keep their fixed ratio (`colour`) to it.
    main: usize,
    /// Under water: how far the sheet's light travels before it meets a surface, in
    /// `REACH_BINS` bins of `tan(angle in the fan)`; the water behind is dark. (With
    /// a rolling shutter, shared by `REACH_ROWS` rows: it only shapes the glow.)
    reach: Arc<Vec<f64>>,
}

/// Row `y`'s lasers of [`Simulator::row_lasers`] (one pair: every row's).
fn row_of(lasers: Option<&[[LaserFrame; 2]]>, y: usize) -> Option<&[LaserFrame; 2]> {
    lasers.and_then(|l| l.get(y.min(l.len().saturating_sub(1))))
}

/// With a rolling shutter under water, rows that share one sheet reach.
const REACH_ROWS: usize = 64;

const REACH_BINS: usize = 4096;

struct Water {
    /// Attenuation per unit length, per channel.
    c: [f64; 3],
    /// Fraction of laser light scattered forward per unit path length.
    forward: f64,
    /// Glow grey level face-on at the reference distance.
    backscatter: f64,
    /// Variance of the forward-scatter blur, px².
    halo2: f64,
    /// `exp(-c * L)` per channel, tabulated over path length `L` (linear interpolation:
    /// three `exp` per pixel and laser would dominate the frame time).
    atten: Vec<[f64; 3]>,
    atten_step: f64,
}

impl Water {
    const LUT_LEN: usize = 4096;

    fn new(c: [f64; 3], forward: f64, backscatter: f64, halo2: f64, max_path: f64) -> Water {
        let atten_step = max_path / (Self::LUT_LEN - 1) as f64;
        let atten = (0..Self::LUT_LEN)
            .map(|i| c.map(|ck| (-ck * i as f64 * atten_step).exp()))
            .collect();
        Water {
            c,
            forward,
            backscatter,
            halo2,
            atten,
            atten_step,
        }
    }

    /// Transmission along a path of length `l`, per channel.
    #[inline]
    fn transmission(&self, l: f64) -> [f64; 3] {
        let x = (l / self.atten_step).max(0.0);
        let i = x as usize;
        if i + 1 >= self.atten.len() {
            return self.c.map(|ck| (-ck * l).exp());
        }
        let f = x - i as f64;
        let (a, b) = (self.atten[i], self.atten[i + 1]);
        [0, 1, 2].map(|k| a[k] + (b[k] - a[k]) * f)
    }
}

/// The renderer of one scene: owns the fixed view and renders any frame on demand.
pub struct Simulator {
    spec: SceneSpec,
    params: SimParams,
    camera: Camera,
    scene: Scene,
    motion: Motion,
    pixels: Vec<Pixel>,
    hot: Vec<Hot>,
    colours: [[f64; 3]; 2],
    beam2: f64,
    psf2: f64,
    tan_half_fan: f64,
    power: f64,
    reference_distance: f64,
    water: Option<Water>,
    gauss: Vec<f32>,
    /// Blooming halo ([`Realism::bloom`]): share of the peak and variance, px².
    bloom: (f64, f64),
}

const GAUSS_BITS: u32 = 12;

impl Simulator {
    /// Validates the spec (it may have been built or changed in code) and ray-casts the
    /// fixed view.
    pub fn new(spec: &SceneSpec, params: &SimParams) -> Result<Simulator, SimError> {
        if let Err((_, message)) = spec.validate() {
            return Err(SimError::Invalid {
                path: spec.name.clone().into(),
                message,
            });
        }
        if !(params.noise_sigma >= 0.0 && params.noise_sigma.is_finite()) {
            return Err(SimError::Invalid {
                path: spec.name.clone().into(),
                message: format!("noise sigma {} must be >= 0", params.noise_sigma),
            });
        }
        let camera = camera_from_spec(&spec.camera);
        let scene = Scene::from_spec(spec);
        let motion = Motion::new(spec, params.seed);
        let distance = spec.distance();
        let p = &spec.projector;
        let water = (spec.medium == Medium::Water).then(|| {
            let w = &spec.water;
            let t = w.turbidity.max(0.0);
            let blur_px = w.forward_blur_mrad * 1e-3 * camera.fx * t.sqrt();
            Water::new(
                [0, 1, 2].map(|k| w.absorption[k] + t * w.scattering[k]),
                w.forward_scatter * t,
                w.backscatter * t,
                blur_px * blur_px,
                // Longest path: projector to a far point and back to the camera.
                12.0 * distance,
            )
        });
        let mut sim = Simulator {
            spec: spec.clone(),
            params: params.clone(),
            scene,
            motion,
            pixels: Vec::new(),
            hot: Vec::new(),
            colours: p.colours.map(|c| c.rgb()),
            beam2: p.beam_half_thickness.unwrap_or(0.0006 * distance).powi(2),
            psf2: spec.camera.psf_sigma_px.powi(2),
            tan_half_fan: (0.5 * p.fan_deg.to_radians()).tan(),
            power: p.power,
            reference_distance: distance,
            water,
            gauss: gaussian_table(),
            bloom: params.realism.bloom.map_or((0.0, 0.0), |(a, s)| (a, s * s)),
            camera,
        };
        sim.cache_view();
        sim.apply_realism();
        Ok(sim)
    }

    pub fn camera(&self) -> &Camera {
        &self.camera
    }

    pub fn scene(&self) -> &Scene {
        &self.scene
    }

    pub fn spec(&self) -> &SceneSpec {
        &self.spec
    }

    pub fn params(&self) -> &SimParams {
        &self.params
    }

    pub fn motion(&self) -> &Motion {
        &self.motion
    }

    /// Beam half thickness in scene units.
    pub fn beam_half_thickness(&self) -> f64 {
        self.beam2.sqrt()
    }

    /// The projector pose of frame `index`: with a rolling shutter, when its middle
    /// row is exposed (the planes `truth.json` gives).
    pub fn pose(&self, index: usize) -> ProjectorPose {
        let middle = 0.5 * self.spec.camera.readout_frames.max(0.0);
        self.motion
            .pose_at(index as f64 + middle, &self.scene, &self.camera)
    }

    /// The projector pose that row `y` of frame `index` sees: under a rolling shutter,
    /// at time `index + readout_frames · y / (height − 1)`; otherwise frame `index`'s.
    pub fn row_pose(&self, index: usize, y: u32) -> ProjectorPose {
        let readout = self.spec.camera.readout_frames.max(0.0);
        let h = self.camera.height.max(2) - 1;
        let t = index as f64 + readout * f64::from(y.min(h)) / f64::from(h);
        self.motion.pose_at(t, &self.scene, &self.camera)
    }

    /// The lasers row by row as frame `index` exposes them: one pair for every row
    /// under a global shutter; under a rolling shutter, row `y`'s at time
    /// `index + readout_frames · y / (height − 1)`.
    fn row_lasers(&self, index: usize) -> Vec<[LaserFrame; 2]> {
        let h = self.camera.height;
        if self.spec.camera.readout_frames <= 0.0 || h < 2 {
            let pose = self.row_pose(index, 0);
            let reach = [0, 1].map(|k| self.reach_of(&pose, k));
            return vec![self.laser_pair(&pose, &reach)];
        }
        let rows = REACH_ROWS as u32;
        let blocks: Vec<[Arc<Vec<f64>>; 2]> = (0..h.div_ceil(rows))
            .map(|b| {
                let pose = self.row_pose(index, (b * rows + rows / 2).min(h - 1));
                [0, 1].map(|k| self.reach_of(&pose, k))
            })
            .collect();
        (0..h)
            .into_par_iter()
            .map(|y| self.laser_pair(&self.row_pose(index, y), &blocks[(y / rows) as usize]))
            .collect()
    }

    /// Under water, how far laser `k`'s sheet reaches ([`Self::sheet_reach`]).
    fn reach_of(&self, pose: &ProjectorPose, k: usize) -> Arc<Vec<f64>> {
        Arc::new(match self.water {
            Some(_) => self.sheet_reach(pose, k),
            None => Vec::new(),
        })
    }

    fn laser_pair(&self, pose: &ProjectorPose, reach: &[Arc<Vec<f64>>; 2]) -> [LaserFrame; 2] {
        [0, 1].map(|k| LaserFrame {
            n: pose.normal(k),
            h: pose.normal(k).dot(&pose.centre),
            centre: pose.centre,
            axis: pose.axis,
            fan_dir: pose.fan_dirs[k],
            colour: self.laser_colour(k),
            main: main_channel(self.colours[k]),
            reach: reach[k].clone(),
        })
    }

    /// The ground truth of frame `index` (no rendering).
    pub fn frame_truth(&self, index: usize) -> FrameTruth {
        let pose = self.pose(index);
        FrameTruth {
            index,
            projector_centre: pose.centre.into(),
            planes: [pose.plane(0).into(), pose.plane(1).into()],
            axis: pose.axis.into(),
            roll_rad: pose.roll_rad,
            fan_dirs: [pose.fan_dirs[0].into(), pose.fan_dirs[1].into()],
        }
    }

    /// Signed distance (px, along the image normal of the curve) of the image point
    /// `(x, y)` from laser `k`'s plane curve in `pose`, from the surface's tangent plane
    /// at the nearest pixel; `None` where that pixel sees no surface or the plane runs
    /// along the ray. The truth a sub-pixel ridge point is scored against.
    pub fn stripe_distance_px(
        &self,
        pose: &ProjectorPose,
        k: usize,
        x: f64,
        y: f64,
    ) -> Option<f64> {
        let (w, h) = (self.camera.width as i64, self.camera.height as i64);
        let (u, v) = (x.round() as i64, y.round() as i64);
        if u < 0 || v < 0 || u >= w || v >= h {
            return None;
        }
        let px = &self.pixels[(v * w + u) as usize];
        if !px.hit {
            return None;
        }
        let n = pose.normal(k);
        let hk = n.dot(&pose.centre);
        let d = n.dot(&V3::from(px.p)) - hk;
        let j = &px.j;
        let gu = n.x * j[0] as f64 + n.y * j[1] as f64 + n.z * j[2] as f64;
        let gv = n.x * j[3] as f64 + n.y * j[4] as f64 + n.z * j[5] as f64;
        let g = gu.hypot(gv);
        (g > 0.0).then(|| (d + gu * (x - u as f64) + gv * (y - v as f64)) / g)
    }

    /// Per-pixel Z (camera coordinates), NaN where the ray leaves the scene; row-major.
    pub fn depth(&self) -> Vec<f32> {
        self.pixels
            .iter()
            .map(|p| if p.hit { p.p[2] as f32 } else { f32::NAN })
            .collect()
    }

    /// Hit points and their ambient colours, one per pixel that sees a surface.
    pub fn surface_points(&self) -> (Vec<[f32; 3]>, Vec<[u8; 3]>) {
        self.pixels
            .iter()
            .zip(self.hot.iter().map(|h| h.ambient))
            .filter(|(p, _)| p.hit)
            .map(|(p, a)| {
                (
                    p.p.map(|v| v as f32),
                    a.map(|v| v.round().clamp(0.0, 255.0) as u8),
                )
            })
            .unzip()
    }

    /// Frame `index` with its ground truth.
    pub fn render_frame(&self, index: usize) -> (RgbImage, FrameTruth) {
        let mut img = RgbImage::new(self.camera.width, self.camera.height);
        let truth = self.render_frame_into(index, &mut img, None);
        (img, truth)
    }

    /// Renders frame `index` into `img` (resized if needed). When `lit` is given
    /// (`width * height` entries; ignored otherwise), pixels whose centre lies within
    /// 0.5 px of an unshadowed stripe centre line inside the fan are raised to the
    /// stripe's peak contrast there (grey levels, 1..=255; see `lit.png`).
    pub fn render_frame_into(
        &self,
        index: usize,
        img: &mut RgbImage,
        lit: Option<&mut [u8]>,
    ) -> FrameTruth {
        let lasers = self.row_lasers(index);
        self.render(img, Some(&lasers), index as u64, lit);
        let pose = self.pose(index);
        FrameTruth {
            index,
            projector_centre: pose.centre.into(),
            planes: [pose.plane(0).into(), pose.plane(1).into()],
            axis: pose.axis.into(),
            roll_rad: pose.roll_rad,
            fan_dirs: [pose.fan_dirs[0].into(), pose.fan_dirs[1].into()],
        }
    }

    /// Laser `k`'s light per channel: its colour times the power, with the realistic
    /// gain, crosstalk and on/off of [`Realism`].
    fn laser_colour(&self, k: usize) -> [f64; 3] {
        let r = &self.params.realism;
        if !r.laser_on(k) {
            return [0.0; 3];
        }
        let c = self.colours[k];
        let main = c.iter().copied().fold(0.0, f64::max);
        c.map(|v| v.max(r.crosstalk * main) * self.power * r.gain())
    }

    /// Draws the realistic decorations of the view into its ambient image.
    fn apply_realism(&mut self) {
        let r = &self.params.realism;
        if r.checker.is_none()
            && r.specular_spots == 0
            && r.bright_lines == 0
            && r.coloured_patch.is_none()
        {
            return;
        }
        let size = (self.camera.width as usize, self.camera.height as usize);
        let mut ambient: Vec<[f32; 3]> = self.hot.iter().map(|h| h.ambient).collect();
        realism::decorate_ambient(r, self.params.seed, size, &mut ambient);
        for (h, a) in self.hot.iter_mut().zip(ambient) {
            h.ambient = a;
        }
    }

    /// The view with the lasers off, with its own sensor noise.
    pub fn background(&self) -> RgbImage {
        let mut img = RgbImage::new(self.camera.width, self.camera.height);
        self.render(&mut img, None, u64::MAX, None);
        img
    }

    fn render(
        &self,
        img: &mut RgbImage,
        lasers: Option<&[[LaserFrame; 2]]>,
        key: u64,
        lit: Option<&mut [u8]>,
    ) {
        let (w, h) = (self.camera.width as usize, self.camera.height as usize);
        if img.width() != self.camera.width || img.height() != self.camera.height {
            *img = RgbImage::new(self.camera.width, self.camera.height);
        }
        let frame_key = mix64(self.params.seed ^ mix64(key));
        let buf: &mut [u8] = img;
        match lit.filter(|l| l.len() == w * h) {
            Some(lit) => buf
                .par_chunks_mut(3 * w)
                .zip(lit.par_chunks_mut(w))
                .enumerate()
                .for_each(|(y, (row, lit_row))| {
                    self.render_row(y, row, Some(lit_row), row_of(lasers, y), frame_key)
                }),
            None => buf
                .par_chunks_mut(3 * w)
                .enumerate()
                .for_each(|(y, row)| self.render_row(y, row, None, row_of(lasers, y), frame_key)),
        }
        debug_assert_eq!(buf.len(), 3 * w * h);
        let r = &self.params.realism;
        if r.moving_object {
            realism::draw_moving_object(self.params.seed, key, buf, (w, h));
        }
        // A 4:2:0 JPEG whose decoder interpolates is a camera's MJPEG as zune-jpeg or
        // libjpeg decodes it: one real round trip, the chroma averaged per block,
        // quantised at block resolution (a chroma DCT block spans 16×16 pixels) and
        // rebuilt. Repeated chroma is a conversion outside the JPEG decoder (FFmpeg's,
        // a YUYV pair), after a 4:4:4 round trip; so is either rebuild of PNG frames.
        let jpeg_420 = r.chroma_420 && r.chroma_interpolated;
        let chroma = if jpeg_420 {
            super::JpegChroma::Half420
        } else {
            super::JpegChroma::Full
        };
        if let Some(q) = self.params.jpeg_quality {
            jpeg_round_trip(img, q, chroma);
        }
        if r.chroma_420 && !(jpeg_420 && self.params.jpeg_quality.is_some()) {
            realism::subsample_chroma(&mut *img, (w, h), r.chroma_interpolated);
        }
    }

    fn render_row(
        &self,
        y: usize,
        row: &mut [u8],
        mut lit_row: Option<&mut [u8]>,
        lasers: Option<&[LaserFrame; 2]>,
        frame_key: u64,
    ) {
        let w = self.camera.width as usize;
        let mut rng = SplitMix64::new(mix64(
            frame_key ^ (y as u64).wrapping_mul(0xA24B_AED4_963E_E407),
        ));
        let sigma = self.params.noise_sigma as f32;
        let mut bits = 0u64;
        let mut left = 0u32;
        let mask = (1u64 << GAUSS_BITS) - 1;
        let hot_row = &self.hot[y * w..(y + 1) * w];
        for (x, hot) in hot_row.iter().enumerate() {
            let mut v = hot.ambient.map(|a| a as f64);
            if let Some(lasers) = lasers {
                for laser in lasers {
                    if hot.jf2 >= 0.0 {
                        let peak = self.add_stripe(y * w + x, hot, laser, &mut v);
                        if peak > 0.0 {
                            if let Some(l) = lit_row.as_deref_mut() {
                                l[x] = l[x].max(peak.round().clamp(1.0, 255.0) as u8);
                            }
                        }
                    }
                    if let Some(water) = &self.water {
                        self.add_glow(y * w + x, hot, laser, water, &mut v);
                    }
                }
            }
            for c in 0..3 {
                let mut val = v[c] as f32;
                if sigma > 0.0 {
                    if left == 0 {
                        bits = rng.next_u64();
                        left = 64 / GAUSS_BITS;
                    }
                    val += sigma * self.gauss[(bits & mask) as usize];
                    bits >>= GAUSS_BITS;
                    left -= 1;
                }
                row[3 * x + c] = (val + 0.5).clamp(0.0, 255.0) as u8;
            }
        }
    }

    /// Adds laser `l`'s stripe at pixel `px`. Where the pixel centre lies within 0.5 px
    /// of the lit centre line, returns the stripe's peak contrast there (grey levels
    /// added to its strongest channel at the centre line, before noise and clipping);
    /// elsewhere 0.
    #[inline]
    fn add_stripe(&self, i: usize, hot: &Hot, l: &LaserFrame, v: &mut [f64; 3]) -> f64 {
        let halo2 = self.water.as_ref().map_or(0.0, |w| w.halo2);
        // The sharp stripe is cut at 4σ, the faint forward-scatter halo at 3σ. This first
        // test uses the single-precision copy, with a margin for its rounding.
        let (bloom, bloom2) = self.bloom;
        let window2 = 16.0 * self.beam2
            + hot.jf2 as f64
                * (16.0 * self.psf2 + 9.0 * halo2.max(bloom2 * f64::from(u8::from(bloom > 0.0))));
        let d_approx =
            l.n.x * hot.p[0] as f64 + l.n.y * hot.p[1] as f64 + l.n.z * hot.p[2] as f64 - l.h;
        let beyond = d_approx.abs() - 1e-6 * hot.range as f64;
        if beyond > 0.0 && beyond * beyond > window2 {
            return 0.0;
        }
        let px = &self.pixels[i];
        let p = V3::new(px.p[0], px.p[1], px.p[2]);
        let d = l.n.dot(&p) - l.h;
        let d2 = d * d;
        if d2 > window2 {
            return 0.0;
        }
        let j = &px.j;
        let gu = l.n.x * j[0] as f64 + l.n.y * j[1] as f64 + l.n.z * j[2] as f64;
        let gv = l.n.x * j[3] as f64 + l.n.y * j[4] as f64 + l.n.z * j[5] as f64;
        let g2 = gu * gu + gv * gv;
        let s2 = self.beam2 + g2 * self.psf2;
        let e = d2 / (2.0 * s2);
        let s2h = s2 + g2 * halo2;
        let eh = d2 / (2.0 * s2h);
        let s2b = s2 + g2 * bloom2;
        let eb = d2 / (2.0 * s2b);
        if e > 8.0 && (halo2 == 0.0 || eh > 4.5) && (bloom == 0.0 || eb > 4.5) {
            return 0.0;
        }
        // Inside the fan and in front of the projector.
        let w = p - l.centre;
        let wa = w.dot(&l.axis);
        if wa <= 0.0 || w.dot(&l.fan_dir).abs() > wa * self.tan_half_fan {
            return 0.0;
        }
        // The lit side must be the side the camera sees.
        let to_c = l.centre - p;
        let nrm = V3::new(
            px.normal[0] as f64,
            px.normal[1] as f64,
            px.normal[2] as f64,
        );
        let ndc = nrm.dot(&to_c);
        if ndc <= 0.0 {
            return 0.0;
        }
        if self.scene.occluded(&l.centre, &(p - l.centre), 1.0 - 1e-6) {
            return 0.0;
        }
        let dist = to_c.norm();
        let cos = ndc / dist;
        let fall = (self.reference_distance / dist).powi(2) * cos;
        let mut profile = (-e).exp();
        let mut peak_profile = 1.0;
        let mut atten = [1.0; 3];
        if let Some(water) = &self.water {
            let path = dist + hot.range as f64;
            let f = 1.0 - (-water.forward * path).exp();
            profile = (1.0 - f) * profile + f * (s2 / s2h).sqrt() * (-eh).exp();
            peak_profile = (1.0 - f) + f * (s2 / s2h).sqrt();
            atten = water.transmission(path);
        }
        if bloom > 0.0 {
            profile += bloom * (-eb).exp();
        }
        let mut peak: f64 = 0.0;
        let mono = fall * px.refl[l.main] as f64 * atten[l.main];
        for (vc, colour) in v.iter_mut().zip(l.colour) {
            let gain = mono * colour;
            *vc += gain * profile;
            peak = peak.max(gain * peak_profile);
        }
        if d2 < 0.25 * g2 {
            peak
        } else {
            0.0
        }
    }

    /// Distance from the projector to the first surface along laser `k`'s sheet, per
    /// bin of `tan` of the fan angle (infinite where the sheet leaves the scene).
    fn sheet_reach(&self, pose: &ProjectorPose, k: usize) -> Vec<f64> {
        let step = 2.0 * self.tan_half_fan / REACH_BINS as f64;
        (0..REACH_BINS)
            .map(|i| {
                let t = -self.tan_half_fan + (i as f64 + 0.5) * step;
                let dir = pose.axis + pose.fan_dirs[k] * t;
                self.scene
                    .cast(&pose.centre, &dir)
                    .map_or(f64::INFINITY, |h| (h.point - pose.centre).norm())
            })
            .collect()
    }

    /// Backscatter: the sheet lights the water column in front of the surface.
    ///
    /// The glow ends where the sheet meets the surface, at the stripe's centre line, and
    /// its edge is as soft as the stripe: a ray near the line crosses part of the
    /// sheet's thickness in front of the surface, the rest behind it, and the lens
    /// blurs both alike. So the glow is scaled by `Φ(d / s)`, `d` the surface point's
    /// distance from the sheet on the glow side and `s²` the stripe's own variance
    /// there (`b² + g² σ_psf²`, [`Self::add_stripe`]).
    #[inline]
    fn add_glow(&self, i: usize, px: &Hot, l: &LaserFrame, water: &Water, v: &mut [f64; 3]) {
        if water.backscatter <= 0.0 {
            return;
        }
        // The camera ray `λ p` meets the sheet at λ = h / (n·p); in front of the surface
        // means 0 < λ < 1.
        let p = V3::new(px.p[0] as f64, px.p[1] as f64, px.p[2] as f64);
        let np = l.n.dot(&p);
        let lambda = l.h / np;
        // NaN (a ray parallel to the sheet) fails too.
        if lambda.is_nan() || lambda <= 0.0 {
            return;
        }
        let edge = if px.jf2 < 0.0 {
            // The ray leaves the scene: no surface, no edge.
            f64::from(u8::from(lambda < 1.0))
        } else {
            let d = (np - l.h) * l.h.signum();
            let window2 = 16.0 * (self.beam2 + px.jf2 as f64 * self.psf2);
            if d * d > window2 {
                f64::from(u8::from(d > 0.0))
            } else {
                let j = &self.pixels[i].j;
                let gu = l.n.x * j[0] as f64 + l.n.y * j[1] as f64 + l.n.z * j[2] as f64;
                let gv = l.n.x * j[3] as f64 + l.n.y * j[4] as f64 + l.n.z * j[5] as f64;
                let s2 = self.beam2 + (gu * gu + gv * gv) * self.psf2;
                normal_cdf(d / s2.sqrt())
            }
        };
        if edge <= 0.0 {
            return;
        }
        let lambda = lambda.min(1.0);
        let x = p * lambda;
        let w = x - l.centre;
        let wa = w.dot(&l.axis);
        let wf = w.dot(&l.fan_dir);
        if wa <= 0.0 || wf.abs() > wa * self.tan_half_fan {
            return;
        }
        let range = px.range as f64;
        let dist = w.norm();
        // Sheet light stops at the first surface it meets (the sheet's own shadow).
        let bin = ((wf / wa + self.tan_half_fan) / (2.0 * self.tan_half_fan) * REACH_BINS as f64)
            as usize;
        if l.reach
            .get(bin.min(REACH_BINS - 1))
            .is_some_and(|&r| dist > r)
        {
            return;
        }
        // Path length through the sheet ∝ 1/|cos|, bounded where the ray runs along it.
        let path = (range / np.abs()).min(6.0);
        let g = water.backscatter * (self.reference_distance / dist) * path / self.power;
        let tr = water.transmission(dist + lambda * range);
        for (vc, colour) in v.iter_mut().zip(l.colour) {
            *vc += edge * (g * colour * tr[l.main]).min(60.0);
        }
    }

    /// Ray-casts every pixel once: hit point, tangent-plane Jacobian, normal,
    /// reflectance and ambient colour.
    fn cache_view(&mut self) {
        let (w, h) = (self.camera.width as usize, self.camera.height as usize);
        let mut pixels = vec![Pixel::default(); w * h];
        let mut ambient = vec![[0.0f32; 3]; w * h];
        let cam = &self.camera;
        let scene = &self.scene;
        let light = &self.spec.light;
        let light_dir = scene
            .world_from_camera
            .inverse()
            .apply_vector(&V3::from(light.direction))
            .normalize();
        let far = 4.0 * self.reference_distance;
        let water = self.water.as_ref();
        let veil = self.spec.water.veil;
        // d(xd, yd)/d(u, v) of the camera matrix inverse.
        let k_inv = Matrix2::new(
            1.0 / cam.fx,
            -cam.skew / (cam.fx * cam.fy),
            0.0,
            1.0 / cam.fy,
        );
        pixels
            .par_chunks_mut(w)
            .zip(ambient.par_chunks_mut(w))
            .enumerate()
            .for_each(|(y, (prow, arow))| {
                for x in 0..w {
                    let (u, v) = (x as f64, y as f64);
                    let background = match water {
                        Some(_) => veil,
                        None => light.background,
                    };
                    arow[x] = background.map(|c| c as f32);
                    let Some([nx, ny]) = cam.normalized_from_pixel(u, v) else {
                        // Beyond the invertible part of the lens model: nothing seen.
                        prow[x].p = [0.0, 0.0, far];
                        prow[x].range = far as f32;
                        continue;
                    };
                    let ray = V3::new(nx, ny, 1.0);
                    let Some(hit) = scene.cast(&V3::zeros(), &ray) else {
                        let p = ray.normalize() * far;
                        prow[x].p = p.into();
                        prow[x].range = far as f32;
                        continue;
                    };
                    let mut n = hit.normal;
                    if n.dot(&ray) > 0.0 {
                        n = -n;
                    }
                    let t = hit.t;
                    let nr = n.dot(&ray);
                    // dP/dr on the tangent plane, then dr/d(pixel) through the lens.
                    let dp_dr = (nalgebra::Matrix3::identity() - ray * n.transpose() / nr) * t;
                    let jd = cam.distortion.jacobian(nx, ny);
                    let dxy_duv = jd.try_inverse().unwrap_or_else(Matrix2::identity) * k_inv;
                    let dr_duv = Matrix3x2::new(
                        dxy_duv[(0, 0)],
                        dxy_duv[(0, 1)],
                        dxy_duv[(1, 0)],
                        dxy_duv[(1, 1)],
                        0.0,
                        0.0,
                    );
                    let jm = dp_dr * dr_duv;
                    let refl = scene.reflectance(&hit);
                    let shade = light.ambient
                        * (light.flat_fraction
                            + (1.0 - light.flat_fraction) * n.dot(&light_dir).max(0.0));
                    let range = hit.point.norm();
                    let amb = [0, 1, 2].map(|c| {
                        let a = shade * refl[c];
                        match water {
                            Some(wt) => {
                                let tr = (-wt.c[c] * range).exp();
                                a * tr + veil[c] * (1.0 - tr)
                            }
                            None => a,
                        }
                    });
                    arow[x] = amb.map(|a| a as f32);
                    prow[x] = Pixel {
                        p: hit.point.into(),
                        range: range as f32,
                        j: [
                            jm[(0, 0)] as f32,
                            jm[(1, 0)] as f32,
                            jm[(2, 0)] as f32,
                            jm[(0, 1)] as f32,
                            jm[(1, 1)] as f32,
                            jm[(2, 1)] as f32,
                        ],
                        jf2: jm.norm_squared() as f32,
                        normal: [n.x as f32, n.y as f32, n.z as f32],
                        refl: refl.map(|r| r as f32),
                        hit: true,
                    };
                }
            });
        self.hot = pixels
            .iter()
            .zip(&ambient)
            .map(|(p, a)| Hot {
                p: p.p.map(|v| v as f32),
                jf2: if p.hit { p.jf2 } else { -1.0 },
                ambient: *a,
                range: p.range,
            })
            .collect();
        self.pixels = pixels;
    }
}

/// The channel a laser's light is in: the largest of its camera response.
fn main_channel(colour: [f64; 3]) -> usize {
    (0..3).fold(0, |m, c| if colour[c] > colour[m] { c } else { m })
}

fn jpeg_round_trip(img: &mut RgbImage, quality: u8, chroma: super::JpegChroma) {
    let Ok(buf) = super::encode_jpeg(img, quality, chroma) else {
        return;
    };
    if let Ok(decoded) = image::load_from_memory_with_format(&buf, image::ImageFormat::Jpeg) {
        *img = decoded.to_rgb8();
    }
}

/// `2^GAUSS_BITS` equiprobable standard-normal quantiles, rescaled to unit variance.
fn gaussian_table() -> Vec<f32> {
    let n = 1usize << GAUSS_BITS;
    let mut t: Vec<f64> = (0..n)
        .map(|i| inverse_normal_cdf((i as f64 + 0.5) / n as f64))
        .collect();
    let var = t.iter().map(|v| v * v).sum::<f64>() / n as f64;
    let s = 1.0 / var.sqrt();
    t.iter_mut().for_each(|v| *v *= s);
    t.into_iter().map(|v| v as f32).collect()
}

/// Acklam's rational approximation of the standard normal quantile (|error| < 1.2e-9).
fn inverse_normal_cdf(p: f64) -> f64 {
    const A: [f64; 6] = [
        -3.969_683_028_665_376e1,
        2.209_460_984_245_205e2,
        -2.759_285_104_469_687e2,
        1.383_577_518_672_69e2,
        -3.066_479_806_614_716e1,
        2.506_628_277_459_239,
    ];
    const B: [f64; 5] = [
        -5.447_609_879_822_406e1,
        1.615_858_368_580_409e2,
        -1.556_989_798_598_866e2,
        6.680_131_188_771_972e1,
        -1.328_068_155_288_572e1,
    ];
    const C: [f64; 6] = [
        -7.784_894_002_430_293e-3,
        -3.223_964_580_411_365e-1,
        -2.400_758_277_161_838,
        -2.549_732_539_343_734,
        4.374_664_141_464_968,
        2.938_163_982_698_783,
    ];
    const D: [f64; 4] = [
        7.784_695_709_041_462e-3,
        3.224_671_290_700_398e-1,
        2.445_134_137_142_996,
        3.754_408_661_907_416,
    ];
    let lo = 0.02425;
    if p < lo {
        let q = (-2.0 * p.ln()).sqrt();
        (((((C[0] * q + C[1]) * q + C[2]) * q + C[3]) * q + C[4]) * q + C[5])
            / ((((D[0] * q + D[1]) * q + D[2]) * q + D[3]) * q + 1.0)
    } else if p <= 1.0 - lo {
        let q = p - 0.5;
        let r = q * q;
        (((((A[0] * r + A[1]) * r + A[2]) * r + A[3]) * r + A[4]) * r + A[5]) * q
            / (((((B[0] * r + B[1]) * r + B[2]) * r + B[3]) * r + B[4]) * r + 1.0)
    } else {
        -inverse_normal_cdf(1.0 - p)
    }
}

/// The standard normal distribution function `Φ(u)` (Abramowitz & Stegun 7.1.26,
/// |error| < 1.5e-7).
pub(crate) fn normal_cdf(u: f64) -> f64 {
    let x = u.abs() * std::f64::consts::FRAC_1_SQRT_2;
    let k = 1.0 / (1.0 + 0.327_591_1 * x);
    let poly = k
        * (0.254_829_592
            + k * (-0.284_496_736
                + k * (1.421_413_741 + k * (-1.453_152_027 + k * 1.061_405_429))));
    let half_erfc = 0.5 * poly * (-x * x).exp();
    if u >= 0.0 {
        1.0 - half_erfc
    } else {
        half_erfc
    }
}
