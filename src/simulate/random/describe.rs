//! The words and numbers of a drawn scan: the one-line summary and `random.json`
//! ([`Description`]), both computed from the configuration as it stands, so that
//! overrides applied after the draw show.

use std::path::Path;

use serde::{Deserialize, Serialize};

use super::{aim_deg_per_frame, DrawnScan, HandMode, SceneKind, RANDOM_VERSION, V3};
use crate::simulate::scene::{camera_from_spec, LaserColour, Medium};
use crate::simulate::{FrameFormat, SimError};

/// The content of `random.json`: what was drawn, in numbers. Lengths in scene units
/// (metres), angles in degrees, the hand's shares relative to the baseline.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Description {
    pub version: u32,
    pub seed: u64,
    pub kind: SceneKind,
    pub summary: String,
    pub frames: usize,
    pub layout: String,
    pub distance: f64,
    pub primitives: usize,
    pub width: u32,
    pub height: u32,
    pub fx: f64,
    pub cx: f64,
    pub cy: f64,
    /// OpenCV `k1, k2, p1, p2, k3`.
    pub distortion: Vec<f64>,
    /// Laser 0 first.
    pub lasers: [LaserColour; 2],
    pub power: f64,
    pub fan_deg: f64,
    pub hand: HandMode,
    pub baseline: f64,
    pub baseline_direction: [f64; 3],
    pub wobble_share: f64,
    pub drift_share: f64,
    pub drift_correlation_frames: f64,
    /// How far the walk takes the rest centre over the scan.
    pub walk_share: f64,
    pub roll_deg: f64,
    pub roll_amplitude_deg: f64,
    pub roll_swing_deg: f64,
    pub roll_swings: f64,
    pub roll_jitter_deg: f64,
    pub sweep_overscan: f64,
    pub sweep_period_frames: f64,
    pub aim_deg_per_frame: f64,
    pub medium: Medium,
    /// 0 in air.
    pub turbidity: f64,
    pub ambient: f64,
    /// `png`, `jpeg` or `dump`.
    pub encoding: String,
    pub jpeg_quality: Option<u8>,
    pub noise_sigma: f64,
}

impl DrawnScan {
    /// The one-line summary of the configuration as it stands (after any override of
    /// `spec`, `params` or `format`), e.g. `table 0.72 m, 8 boxes 2-5 cm | 1280x720 f
    /// 1130 k1 -0.12 | blue-green | drift 22 % of 0.31 m, roll ±48° x2 | jpeg 88 σ 2.1`.
    pub fn summarise(&self) -> String {
        let d = self.describe();
        let hand = match d.hand {
            HandMode::Standing => format!(
                "standing, wobble {:.0} % of {:.2} m",
                100.0 * d.wobble_share,
                d.baseline
            ),
            HandMode::Drifting => format!(
                "drift {:.0} % of {:.2} m",
                100.0 * d.drift_share,
                d.baseline
            ),
            HandMode::Walking => format!(
                "walk {:.0} % + drift {:.0} % of {:.2} m",
                100.0 * d.walk_share,
                100.0 * d.drift_share,
                d.baseline
            ),
        };
        let encoding = match d.jpeg_quality {
            Some(q) => format!("{} {q}", d.encoding),
            None => d.encoding.clone(),
        };
        format!(
            "{} {:.2} m, {} | {}x{} f {:.0} k1 {:.2} | {}-{} | {hand}, roll ±{:.0}° x{:.0} | {encoding} σ {:.1}",
            self.kind,
            d.distance,
            self.layout,
            d.width,
            d.height,
            d.fx,
            d.distortion.first().copied().unwrap_or(0.0),
            d.lasers[0].name(),
            d.lasers[1].name(),
            d.roll_swing_deg,
            d.roll_swings,
            d.noise_sigma
        )
    }

    /// The configuration in numbers, as `random.json` holds it.
    pub fn describe(&self) -> Description {
        let spec = &self.spec;
        let camera = camera_from_spec(&spec.camera);
        let p = &spec.projector;
        let distance = spec.distance();
        let baseline = p.baseline.unwrap_or(0.2 * distance);
        let per_baseline = |v: f64| if baseline > 0.0 { v / baseline } else { 0.0 };
        let walk = V3::from(p.walk_per_frame).norm() * self.frames.saturating_sub(1) as f64;
        let (encoding, jpeg_quality) = match self.format {
            FrameFormat::Png => ("png", self.params.jpeg_quality),
            FrameFormat::Jpeg { quality, .. } => ("jpeg", Some(quality)),
            FrameFormat::Dump { quality, .. } => ("dump", Some(quality)),
        };
        Description {
            version: RANDOM_VERSION,
            seed: self.seed,
            kind: self.kind,
            summary: self.summary.clone(),
            frames: self.frames,
            layout: self.layout.clone(),
            distance,
            primitives: spec.primitives.len(),
            width: camera.width,
            height: camera.height,
            fx: camera.fx,
            cx: camera.cx,
            cy: camera.cy,
            distortion: camera.distortion.to_vec(),
            lasers: p.colours,
            power: p.power,
            fan_deg: p.fan_deg,
            hand: HandMode::of(p),
            baseline,
            baseline_direction: p.baseline_direction,
            wobble_share: per_baseline(p.wobble.unwrap_or(0.1 * baseline)),
            drift_share: per_baseline(p.drift),
            drift_correlation_frames: p.drift_correlation_frames,
            walk_share: per_baseline(walk),
            roll_deg: p.roll_deg,
            roll_amplitude_deg: p.roll_amplitude_deg,
            roll_swing_deg: p.roll_swing_deg,
            roll_swings: self.frames as f64 / p.roll_swing_period_frames,
            roll_jitter_deg: p.roll_jitter_deg,
            sweep_overscan: p.sweep_overscan,
            sweep_period_frames: p.sweep_period_frames,
            aim_deg_per_frame: aim_deg_per_frame(&camera, p),
            medium: spec.medium,
            turbidity: match spec.medium {
                Medium::Water => spec.water.turbidity,
                Medium::Air => 0.0,
            },
            ambient: spec.light.ambient,
            encoding: encoding.into(),
            jpeg_quality,
            noise_sigma: self.params.noise_sigma,
        }
    }

    /// Writes `random.json` into `dir`.
    pub fn write_description(&self, dir: &Path) -> Result<(), SimError> {
        let path = dir.join("random.json");
        let json =
            serde_json::to_string_pretty(&self.describe()).map_err(|source| SimError::Json {
                path: path.clone(),
                source,
            })?;
        std::fs::write(&path, json).map_err(|source| SimError::Io { path, source })
    }
}
