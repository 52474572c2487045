//! Random scan configurations (`crossline simulate --random SEED`): a scene of one of
//! four kinds with a random layout, and a random camera, cross, hand path, light and
//! encoding, all drawn from one seed, so that an algorithm is judged on a distribution
//! of scans rather than on the few it was tuned on.
//!
//! Owns the ranges drawn (listed on [`draw`]) and the `random.json` description
//! ([`Description`], in `describe`). It only builds ordinary [`SceneSpec`]s: whatever it
//! draws can be written as a scene file, and the scan renders as any other scene does;
//! nothing here renders. The layouts of the four kinds are in `layout` and `room`, their
//! building blocks (looks, primitives, placement on the floor) in `parts`.

mod describe;
mod layout;
mod parts;
mod real;
mod room;
#[cfg(test)]
mod tests;

pub use describe::Description;
pub use real::draw_realistic;

use std::fmt;

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use super::motion::SplitMix64;
use super::render::SimParams;
use super::scene::{
    camera_from_spec, mix64, CameraSpec, LaserColour, Medium, ProjectorSpec, Scene, SceneSpec,
};
use super::FrameFormat;
use crate::camera::Camera;

type V3 = Vector3<f64>;

/// Version of `random.json`.
pub const RANDOM_VERSION: u32 = 1;

/// Share of the image that must see a surface; layouts are redrawn until they do.
pub const MIN_SURFACE_FRACTION: f64 = 0.85;

/// The kinds of scene [`draw`] chooses from, with equal probability.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SceneKind {
    /// A table top seen from 0.5-0.9 m, looked down at 35-80° (the horizon never in
    /// view): one plane with 6-10 boxes 2-6 cm high (footprints 3-12 cm, smaller in
    /// narrow views), maybe a cylinder (1/2) and a ball (3/10).
    Table,
    /// A room at 3-10 m: floor, side walls and far wall, a flat ceiling or (2/5) a
    /// barrel vault, 0-3 niches 15-50 cm deep in the far wall, 0-4 furniture boxes
    /// and maybe a pillar; 3/10 are a room's corner (two walls, floor, ceiling).
    Room,
    /// 12-28 boxes (some stacked), upright or lying cylinders and spheres, sized by
    /// the width of the view, on a floor before a back wall (and maybe a side wall) at
    /// 1-5 m, looked down at 15-45°.
    Clutter,
    /// Under water at 1.5-3.5 m, turbidity 0-1.5 (absorption and scattering varied by
    /// up to 25 %): a slightly tilted seabed looked down at (at least 25°, its far
    /// edge no further than about 4 × the camera's height), 1-4 pipes (radius 5-30
    /// cm, 1-4 m long, partly buried, some open), 3-10 rocks and 0-3 blocks.
    Underwater,
}

impl SceneKind {
    pub const ALL: [SceneKind; 4] = [
        SceneKind::Table,
        SceneKind::Room,
        SceneKind::Clutter,
        SceneKind::Underwater,
    ];

    pub fn name(self) -> &'static str {
        match self {
            SceneKind::Table => "table",
            SceneKind::Room => "room",
            SceneKind::Clutter => "clutter",
            SceneKind::Underwater => "underwater",
        }
    }
}

impl fmt::Display for SceneKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// How the hand holding the projector moves.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum HandMode {
    /// The centre wobbles about one rest position.
    Standing,
    /// The rest position itself drifts (10-30 % of the baseline).
    Drifting,
    /// The rest position walks steadily (10-30 % of the baseline over the scan) and
    /// drifts a little.
    Walking,
}

impl HandMode {
    /// The mode a `[projector]` table describes.
    pub fn of(p: &ProjectorSpec) -> HandMode {
        if p.walk_per_frame != [0.0; 3] {
            HandMode::Walking
        } else if p.drift > 0.0 {
            HandMode::Drifting
        } else {
            HandMode::Standing
        }
    }
}

/// One drawn scan configuration: render `spec` with `params` for `frames` frames and
/// store them as `format`.
#[derive(Clone, Debug, PartialEq)]
pub struct DrawnScan {
    pub seed: u64,
    pub kind: SceneKind,
    pub spec: SceneSpec,
    pub params: SimParams,
    pub format: FrameFormat,
    pub frames: usize,
    /// The layout in a few words (`8 boxes 2-5 cm, 1 cylinder`).
    pub layout: String,
    /// One line: scene | camera | lasers | hand | encoding ([`DrawnScan::summarise`]).
    pub summary: String,
}

/// A seeded draw of uniform numbers.
pub(crate) struct Rng(SplitMix64);

impl Rng {
    pub(crate) fn new(seed: u64) -> Rng {
        Rng(SplitMix64::new(mix64(seed ^ 0x7261_6e64_6f6d_7363)))
    }

    /// Uniform in `[lo, hi)`.
    pub(crate) fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.0.next_f64()
    }

    /// Uniform in `0..n` (`n > 0`).
    pub(crate) fn below(&mut self, n: usize) -> usize {
        ((self.0.next_f64() * n as f64) as usize).min(n.saturating_sub(1))
    }

    /// Uniform in `lo..=hi`.
    pub(crate) fn int(&mut self, lo: usize, hi: usize) -> usize {
        lo + self.below(hi - lo + 1)
    }

    pub(crate) fn chance(&mut self, p: f64) -> bool {
        self.0.next_f64() < p
    }
}

/// Draws scan configuration `seed` of `frames` frames. The same seed always gives the
/// same configuration. Ranges (uniform unless said otherwise):
///
/// - kind: table, room, clutter, underwater (each 1/4; the layouts of each are on
///   [`SceneKind`]);
/// - camera: 1280x720 or 1920x1080, `f` 800-2000 px, `k1` -0.3..0.1 (limited so the
///   lens model stays invertible 10 % beyond the image corner), `k2` small and mostly
///   against `k1`, `p1`, `p2` within ±5e-4, principal point within 1.5 % of the
///   centre, optics blur 0.6-1.1 px, camera roll within ±3°;
/// - lasers: red-green or blue-green, fan 60-90°, beam half thickness 0.04-0.09 % of
///   the distance, power 150-350 in air; under water enough for 180-400 grey levels
///   of the weaker laser on white at the scene distance after attenuation (at most
///   10000: the seabed beyond is dimmer still);
/// - hand: baseline 28-50 % of the distance on a table, 12-30 % elsewhere, within
///   0.2-1.5 m, in a random direction kept clear of surfaces; standing (wobble
///   4-12 % of the baseline), drifting (drift 10-30 %, wobble 2-6 %) or walking (walk
///   10-30 % over the scan, drift 3-10 %, wobble 2-6 %), drift correlated over 25-60
///   frames; roll mean ±45°, a sinusoid of 0-15° (period 20-60 frames), a swing of
///   15-60° once or twice per scan, a jitter of 0.5-3° (periods 3-7 frames); the aim
///   sweeps 1.0-1.3 × the image at 0.8-2° a frame ([`aim_deg_per_frame`]);
/// - light: ambient 60-130 grey levels, from at least 25° up and within 80° of the
///   camera's back (seen from above), flat share 0.35-0.8, background 5-30 (air);
/// - encoding: PNG (40 %) or JPEG at quality 80-95, noise σ 1.5-3 grey levels.
pub fn draw(seed: u64, frames: usize) -> DrawnScan {
    let mut rng = Rng::new(seed);
    let kind = SceneKind::ALL[rng.below(4)];
    let camera = draw_camera(&mut rng);
    let (mut spec, layout) = layout::draw(kind, &mut rng, camera);
    draw_lasers(&mut rng, &mut spec);
    draw_light(&mut rng, &mut spec);
    draw_hand(&mut rng, kind, frames, &mut spec);
    let noise_sigma = rng.uniform(1.5, 3.0);
    let format = if rng.chance(0.4) {
        FrameFormat::Png
    } else {
        FrameFormat::Jpeg {
            quality: rng.int(80, 95) as u8,
            chroma: super::JpegChroma::Full,
        }
    };
    let mut drawn = DrawnScan {
        seed,
        kind,
        spec,
        params: SimParams {
            seed,
            noise_sigma,
            jpeg_quality: None,
            realism: super::Realism::none(),
        },
        format,
        frames,
        layout,
        summary: String::new(),
    };
    drawn.summary = drawn.summarise();
    drawn
}

fn draw_camera(rng: &mut Rng) -> CameraSpec {
    let (width, height) = if rng.chance(0.5) {
        (1280u32, 720u32)
    } else {
        (1920, 1080)
    };
    let f = rng.uniform(800.0, 2000.0);
    let corner = (0.5 * width as f64).hypot(0.5 * height as f64) / f;
    let mut distortion = vec![0.0; 5];
    for _ in 0..32 {
        let k1 = rng.uniform(-0.3, 0.1);
        let k2 = (-k1 * rng.uniform(0.0, 0.3) + rng.uniform(-0.01, 0.01)).clamp(-0.1, 0.1);
        if invertible_beyond(k1, k2, 1.1 * corner) {
            distortion = vec![k1, k2, 0.0, 0.0, 0.0];
            break;
        }
    }
    distortion[2] = rng.uniform(-5e-4, 5e-4);
    distortion[3] = rng.uniform(-5e-4, 5e-4);
    CameraSpec {
        position: [0.0; 3],
        look_at: [0.0, 1.0, 0.0],
        up: [0.0, 0.0, 1.0],
        width,
        height,
        hfov_deg: None,
        fx: Some(f),
        fy: None,
        cx: Some(0.5 * (width as f64 - 1.0) + rng.uniform(-0.015, 0.015) * width as f64),
        cy: Some(0.5 * (height as f64 - 1.0) + rng.uniform(-0.015, 0.015) * height as f64),
        distortion,
        psf_sigma_px: rng.uniform(0.6, 1.1),
        // A global shutter: the estimator has no model of a rolling one yet (see
        // docs/accuracy.md), and drawing it would change every configuration's stream.
        readout_frames: 0.0,
    }
}

/// Whether `r (1 + k1 r² + k2 r⁴)` rises steadily (slope above 0.2) until it reaches
/// the distorted radius `target`: the lens model then inverts over the whole image.
fn invertible_beyond(k1: f64, k2: f64, target: f64) -> bool {
    let mut r: f64 = 0.0;
    while r < 4.0 {
        let r2 = r * r;
        if 1.0 + 3.0 * k1 * r2 + 5.0 * k2 * r2 * r2 < 0.2 {
            return false;
        }
        if r * (1.0 + k1 * r2 + k2 * r2 * r2) >= target {
            return true;
        }
        r += 0.005;
    }
    false
}

fn draw_lasers(rng: &mut Rng, spec: &mut SceneSpec) {
    let d = spec.distance();
    let p = &mut spec.projector;
    p.colours = if rng.chance(0.5) {
        [LaserColour::Red, LaserColour::Green]
    } else {
        [LaserColour::Blue, LaserColour::Green]
    };
    p.fan_deg = rng.uniform(60.0, 90.0);
    p.beam_half_thickness = Some(d * rng.uniform(0.0004, 0.0009));
    p.power = match spec.medium {
        Medium::Air => rng.uniform(150.0, 350.0),
        Medium::Water => {
            let w = &spec.water;
            let c = [0, 1, 2].map(|k| w.absorption[k] + w.turbidity * w.scattering[k]);
            // The weaker laser in its own main channel, out to the scene and back.
            let weakest = p
                .colours
                .iter()
                .map(|colour| {
                    let rgb = colour.rgb();
                    let k = (0..3).fold(0, |b, k| if rgb[k] > rgb[b] { k } else { b });
                    (-c[k] * 2.0 * d).exp()
                })
                .fold(1.0, f64::min);
            (rng.uniform(180.0, 400.0) / weakest).min(10000.0)
        }
    };
}

fn draw_light(rng: &mut Rng, spec: &mut SceneSpec) {
    let l = &mut spec.light;
    l.ambient = rng.uniform(60.0, 130.0);
    // From the camera's side (a lamp in the room, a diver's light), so that what the
    // camera looks at is not all in the shade.
    let forward = V3::from(spec.camera.look_at) - V3::from(spec.camera.position);
    let mut back = V3::new(-forward.x, -forward.y, 0.0);
    if back.norm() < 1e-9 {
        back = V3::x();
    }
    let back = back.normalize();
    let side = V3::z().cross(&back);
    let az = rng.uniform(-80f64, 80.0).to_radians();
    let elevation = rng.uniform(25f64, 90.0).to_radians();
    l.direction = (back * (elevation.cos() * az.cos())
        + side * (elevation.cos() * az.sin())
        + V3::z() * elevation.sin())
    .into();
    l.flat_fraction = rng.uniform(0.35, 0.8);
    let grey = rng.uniform(5.0, 30.0);
    l.background = [0, 1, 2].map(|_| (grey + rng.uniform(-3.0, 3.0)).max(0.0));
}

fn draw_hand(rng: &mut Rng, kind: SceneKind, frames: usize, spec: &mut SceneSpec) {
    let d = spec.distance();
    let share = match kind {
        SceneKind::Table => rng.uniform(0.28, 0.5),
        _ => rng.uniform(0.12, 0.3),
    };
    let mut baseline = (d * share).clamp(0.2, 1.5);
    let mode = [HandMode::Standing, HandMode::Drifting, HandMode::Walking][rng.below(3)];
    let (wobble, drift, walk) = match mode {
        HandMode::Standing => (rng.uniform(0.04, 0.12), 0.0, 0.0),
        HandMode::Drifting => (rng.uniform(0.02, 0.06), rng.uniform(0.1, 0.3), 0.0),
        HandMode::Walking => (
            rng.uniform(0.02, 0.06),
            rng.uniform(0.03, 0.1),
            rng.uniform(0.1, 0.3),
        ),
    };
    let scene = Scene::from_spec(spec);
    let camera = camera_from_spec(&spec.camera);
    let steps = frames.saturating_sub(1).max(1) as f64;
    let tau = std::f64::consts::TAU;
    let (mut dir, mut walk_dir) = (V3::x(), V3::x());
    // A direction whose whole reach is clear of surfaces (a projector behind a wall
    // lights nothing); shorter baselines when none is.
    'search: for _ in 0..4 {
        for _ in 0..12 {
            let a = rng.uniform(0.0, tau);
            dir = V3::new(a.cos(), a.sin(), rng.uniform(-0.3, 0.3)).normalize();
            let b = rng.uniform(0.0, tau);
            walk_dir = V3::new(b.cos(), rng.uniform(-0.2, 0.2), b.sin()).normalize();
            let rest = dir * baseline;
            let reach = (drift + wobble) * baseline + 0.05 * d;
            let end = rest + walk_dir * walk * baseline;
            let clear = |p: V3| !scene.occluded(&V3::zeros(), &p, 1.0);
            let ok = [rest, end].iter().all(|&c| {
                clear(c)
                    && [V3::x(), V3::y(), V3::z(), -V3::x(), -V3::y(), -V3::z()]
                        .iter()
                        .all(|&e| clear(c + e * reach))
            });
            if ok {
                break 'search;
            }
        }
        baseline = (baseline * 0.75).max(0.2);
    }
    let p = &mut spec.projector;
    p.baseline = Some(baseline);
    p.baseline_direction = dir.into();
    p.wobble = Some(wobble * baseline);
    p.wobble_period_frames = rng.uniform(30.0, 90.0);
    p.drift = drift * baseline;
    p.drift_correlation_frames = rng.uniform(25.0, 60.0);
    p.walk_per_frame = if walk > 0.0 {
        (walk_dir * walk * baseline / steps).into()
    } else {
        [0.0; 3]
    };
    p.roll_deg = rng.uniform(-45.0, 45.0);
    p.roll_amplitude_deg = rng.uniform(0.0, 15.0);
    p.roll_period_frames = rng.uniform(20.0, 60.0);
    let swings = rng.int(1, 2);
    p.roll_swing_deg = rng.uniform(15.0, 60.0);
    p.roll_swing_period_frames = frames.max(1) as f64 / swings as f64;
    p.roll_jitter_deg = rng.uniform(0.5, 3.0);
    p.roll_jitter_period_frames = rng.uniform(3.0, 7.0);
    p.sweep_overscan = rng.uniform(1.0, 1.3);
    let target = rng.uniform(0.8, 2.0);
    // The speed is inversely proportional to the period.
    p.sweep_period_frames = 1.0;
    p.sweep_period_frames = aim_deg_per_frame(&camera, p) / target;
}

/// The root mean square angular speed of the aim's Lissajous sweep, degrees per frame,
/// from the sweep's extent on the image (pinhole angles) and its period.
pub fn aim_deg_per_frame(camera: &Camera, p: &ProjectorSpec) -> f64 {
    let gold = 1.618_033_988_749_895;
    let ax = (p.sweep_overscan * 0.5 * camera.width as f64 / camera.fx).atan();
    let ay = (p.sweep_overscan * 0.5 * camera.height as f64 / camera.fy).atan();
    let omega = std::f64::consts::TAU / p.sweep_period_frames;
    (omega * (0.5 * ax * ax + 0.5 * (ay / gold).powi(2)).sqrt()).to_degrees()
}

/// The share of a grid of `nx × ny` pixels whose rays meet a surface.
pub fn surface_fraction(spec: &SceneSpec, nx: usize, ny: usize) -> f64 {
    let scene = Scene::from_spec(spec);
    let camera = camera_from_spec(&spec.camera);
    let mut hits = 0;
    for j in 0..ny {
        for i in 0..nx {
            let u = (i as f64 + 0.5) / nx as f64 * camera.width as f64 - 0.5;
            let v = (j as f64 + 0.5) / ny as f64 * camera.height as f64 - 0.5;
            let hit = camera
                .ray_from_pixel(u, v)
                .and_then(|ray| scene.cast(&V3::zeros(), &ray));
            hits += usize::from(hit.is_some());
        }
    }
    hits as f64 / (nx * ny) as f64
}
