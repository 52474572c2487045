//! The scene file (`SceneSpec`, TOML, version [`SCENE_VERSION`]): its sections, their
//! defaults, and its validation with file, line and key in every error. The keys are
//! documented in `simulate`'s module docs; the geometry it describes is `scene.rs`.

use std::path::Path;

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use super::super::SimError;
use crate::camera::Distortion;

type V3 = Vector3<f64>;

/// Version of the scene file format that this code reads and writes.
pub const SCENE_VERSION: u32 = 1;

/// A scene file as written: world frame (any handedness of the author's choosing, but
/// usually z up), camera pose, projector settings and primitives.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneSpec {
    #[serde(default = "default_version")]
    pub version: u32,
    pub name: String,
    #[serde(default)]
    pub medium: Medium,
    pub camera: CameraSpec,
    #[serde(default)]
    pub projector: ProjectorSpec,
    #[serde(default)]
    pub light: LightSpec,
    #[serde(default)]
    pub water: WaterSpec,
    #[serde(default, rename = "primitive")]
    pub primitives: Vec<PrimitiveSpec>,
}

fn default_version() -> u32 {
    SCENE_VERSION
}

#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Medium {
    #[default]
    Air,
    Water,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraSpec {
    pub position: [f64; 3],
    pub look_at: [f64; 3],
    #[serde(default = "default_up")]
    pub up: [f64; 3],
    #[serde(default = "default_width")]
    pub width: u32,
    #[serde(default = "default_height")]
    pub height: u32,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub hfov_deg: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fx: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fy: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cx: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cy: Option<f64>,
    #[serde(default)]
    pub distortion: Vec<f64>,
    #[serde(default = "default_psf")]
    pub psf_sigma_px: f64,
    /// Rolling shutter: the time from the first row's exposure to the last one's, in
    /// frame periods (0: a global shutter; a webcam at 30 fps reads out in 0.5-0.9).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub readout_frames: f64,
}

fn is_zero(x: &f64) -> bool {
    *x == 0.0
}

fn default_up() -> [f64; 3] {
    [0.0, 0.0, 1.0]
}
fn default_width() -> u32 {
    1920
}
fn default_height() -> u32 {
    1080
}
fn default_psf() -> f64 {
    0.8
}

/// Laser colours the projector can carry.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum LaserColour {
    Red,
    Green,
    Blue,
}

impl LaserColour {
    /// Response of the camera's R, G, B channels to this laser (crosstalk included).
    pub fn rgb(self) -> [f64; 3] {
        match self {
            LaserColour::Red => [1.0, 0.06, 0.02],
            LaserColour::Green => [0.08, 1.0, 0.12],
            LaserColour::Blue => [0.03, 0.15, 1.0],
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            LaserColour::Red => "red",
            LaserColour::Green => "green",
            LaserColour::Blue => "blue",
        }
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ProjectorSpec {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub baseline: Option<f64>,
    #[serde(default = "default_baseline_direction")]
    pub baseline_direction: [f64; 3],
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub wobble: Option<f64>,
    #[serde(default = "default_wobble_period")]
    pub wobble_period_frames: f64,
    #[serde(default = "default_fan")]
    pub fan_deg: f64,
    #[serde(default = "default_colours")]
    pub colours: [LaserColour; 2],
    #[serde(default = "default_power")]
    pub power: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub beam_half_thickness: Option<f64>,
    #[serde(default = "default_sweep_period")]
    pub sweep_period_frames: f64,
    #[serde(default = "default_overscan")]
    pub sweep_overscan: f64,
    #[serde(default)]
    pub roll_deg: f64,
    #[serde(default = "default_roll_amplitude")]
    pub roll_amplitude_deg: f64,
    #[serde(default = "default_roll_period")]
    pub roll_period_frames: f64,
    /// The rest centre wanders within this radius (0: it stays put).
    #[serde(default)]
    pub drift: f64,
    #[serde(default = "default_drift_correlation")]
    pub drift_correlation_frames: f64,
    /// Steady translation of the rest centre per frame, camera axes.
    #[serde(default)]
    pub walk_per_frame: [f64; 3],
    #[serde(default)]
    pub roll_swing_deg: f64,
    #[serde(default = "default_roll_swing_period")]
    pub roll_swing_period_frames: f64,
    #[serde(default)]
    pub roll_jitter_deg: f64,
    #[serde(default = "default_roll_jitter_period")]
    pub roll_jitter_period_frames: f64,
}

fn default_baseline_direction() -> [f64; 3] {
    [1.0, 0.0, 0.0]
}
fn default_wobble_period() -> f64 {
    50.0
}
fn default_fan() -> f64 {
    75.0
}
fn default_colours() -> [LaserColour; 2] {
    [LaserColour::Red, LaserColour::Green]
}
fn default_power() -> f64 {
    230.0
}
fn default_sweep_period() -> f64 {
    40.0
}
fn default_overscan() -> f64 {
    1.15
}
fn default_roll_amplitude() -> f64 {
    25.0
}
fn default_roll_period() -> f64 {
    33.0
}
fn default_drift_correlation() -> f64 {
    40.0
}
fn default_roll_swing_period() -> f64 {
    300.0
}
fn default_roll_jitter_period() -> f64 {
    5.0
}

impl Default for ProjectorSpec {
    fn default() -> Self {
        Self {
            baseline: None,
            baseline_direction: default_baseline_direction(),
            wobble: None,
            wobble_period_frames: default_wobble_period(),
            fan_deg: default_fan(),
            colours: default_colours(),
            power: default_power(),
            beam_half_thickness: None,
            sweep_period_frames: default_sweep_period(),
            sweep_overscan: default_overscan(),
            roll_deg: 0.0,
            roll_amplitude_deg: default_roll_amplitude(),
            roll_period_frames: default_roll_period(),
            drift: 0.0,
            drift_correlation_frames: default_drift_correlation(),
            walk_per_frame: [0.0; 3],
            roll_swing_deg: 0.0,
            roll_swing_period_frames: default_roll_swing_period(),
            roll_jitter_deg: 0.0,
            roll_jitter_period_frames: default_roll_jitter_period(),
        }
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LightSpec {
    #[serde(default = "default_ambient")]
    pub ambient: f64,
    #[serde(default = "default_light_direction")]
    pub direction: [f64; 3],
    #[serde(default = "default_flat")]
    pub flat_fraction: f64,
    #[serde(default = "default_background")]
    pub background: [f64; 3],
}

fn default_ambient() -> f64 {
    110.0
}
fn default_light_direction() -> [f64; 3] {
    [0.3, -0.5, 1.0]
}
fn default_flat() -> f64 {
    0.4
}
fn default_background() -> [f64; 3] {
    [18.0, 18.0, 22.0]
}

impl Default for LightSpec {
    fn default() -> Self {
        Self {
            ambient: default_ambient(),
            direction: default_light_direction(),
            flat_fraction: default_flat(),
            background: default_background(),
        }
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WaterSpec {
    #[serde(default = "default_turbidity")]
    pub turbidity: f64,
    #[serde(default = "default_absorption")]
    pub absorption: [f64; 3],
    #[serde(default = "default_scattering")]
    pub scattering: [f64; 3],
    #[serde(default = "default_backscatter")]
    pub backscatter: f64,
    #[serde(default = "default_forward")]
    pub forward_scatter: f64,
    #[serde(default = "default_blur")]
    pub forward_blur_mrad: f64,
    #[serde(default = "default_veil")]
    pub veil: [f64; 3],
}

fn default_turbidity() -> f64 {
    1.0
}
fn default_absorption() -> [f64; 3] {
    [0.40, 0.06, 0.03]
}
fn default_scattering() -> [f64; 3] {
    [0.05, 0.06, 0.08]
}
fn default_backscatter() -> f64 {
    1.5
}
fn default_forward() -> f64 {
    0.06
}
fn default_blur() -> f64 {
    4.0
}
fn default_veil() -> [f64; 3] {
    [8.0, 40.0, 48.0]
}

impl Default for WaterSpec {
    fn default() -> Self {
        Self {
            turbidity: default_turbidity(),
            absorption: default_absorption(),
            scattering: default_scattering(),
            backscatter: default_backscatter(),
            forward_scatter: default_forward(),
            forward_blur_mrad: default_blur(),
            veil: default_veil(),
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Shape {
    Plane,
    Rectangle,
    Box,
    Cylinder,
    Sphere,
}

#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Texture {
    None,
    Checker,
    #[default]
    Noise,
}

/// One `[[primitive]]` table. Which geometric keys apply depends on `shape`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PrimitiveSpec {
    pub shape: Shape,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub name: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub point: Option<[f64; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub normal: Option<[f64; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub corner: Option<[f64; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub edge_u: Option<[f64; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub edge_v: Option<[f64; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub center: Option<[f64; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub size: Option<[f64; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rotation_deg: Option<[f64; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub from: Option<[f64; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub to: Option<[f64; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub radius: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub capped: Option<bool>,
    /// Cylinders only: keep the part of the mantle (and caps) within `arc_deg / 2` of
    /// `arc_towards` around the axis (a barrel vault is the upper half).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub arc_deg: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub arc_towards: Option<[f64; 3]>,
    #[serde(default = "default_albedo")]
    pub albedo: [f64; 3],
    #[serde(default)]
    pub texture: Texture,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub texture_scale: Option<f64>,
    #[serde(default = "default_contrast")]
    pub texture_contrast: f64,
    /// Seed of the noise texture (default: the primitive's index), so that the pieces
    /// of one surface can share one texture.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub texture_seed: Option<u64>,
}

pub(super) fn default_arc_towards() -> [f64; 3] {
    [0.0, 0.0, 1.0]
}
fn default_albedo() -> [f64; 3] {
    [0.7, 0.7, 0.7]
}
fn default_contrast() -> f64 {
    0.5
}

impl SceneSpec {
    /// Parses a scene file's text; `origin` names the file in errors (a built-in's name
    /// for built-ins).
    pub fn from_toml_str(text: &str, origin: &Path) -> Result<SceneSpec, SimError> {
        let spec: SceneSpec = toml::from_str(text).map_err(|e| {
            let (line, col, line_text) = match e.span() {
                Some(span) => locate(text, span.start),
                None => (0, 0, String::new()),
            };
            let at = if line_text.is_empty() {
                String::new()
            } else {
                format!(" (at `{}`)", crate::truncate_echo(line_text.trim()))
            };
            SimError::Toml {
                path: origin.to_path_buf(),
                line,
                message: format!("column {col}: {}{at}", crate::truncate_echo(e.message())),
            }
        })?;
        if let Err((section, message)) = spec.validate() {
            return Err(match section_line(text, section) {
                Some(line) => SimError::Toml {
                    path: origin.to_path_buf(),
                    line,
                    message,
                },
                None => SimError::Invalid {
                    path: origin.to_path_buf(),
                    message,
                },
            });
        }
        Ok(spec)
    }

    /// The scene file text (re-loadable with [`Self::from_toml_str`]).
    pub fn to_toml_string(&self) -> Result<String, SimError> {
        toml::to_string(self).map_err(|e| SimError::Invalid {
            path: self.name.clone().into(),
            message: format!("cannot write the scene as TOML: {e}"),
        })
    }

    /// Distance from the camera to its `look_at` point: the scale that every derived
    /// default is relative to.
    pub fn distance(&self) -> f64 {
        (V3::from(self.camera.look_at) - V3::from(self.camera.position)).norm()
    }

    /// The same scene at another resolution: focal lengths and principal point scale
    /// with the width (an explicit `hfov_deg` stays as it is).
    pub fn with_resolution(mut self, width: u32, height: u32) -> SceneSpec {
        let c = &mut self.camera;
        let s = width as f64 / c.width as f64;
        c.fx = c.fx.map(|f| f * s);
        c.fy = c.fy.map(|f| f * s);
        c.cx = c.cx.map(|x| (x + 0.5) * s - 0.5);
        c.cy =
            c.cy.map(|y| (y + 0.5) * s - 0.5 + 0.5 * (height as f64 - c.height as f64 * s));
        c.width = width;
        c.height = height;
        self
    }

    /// Checks what serde cannot: required keys per shape, ranges, consistency. The error
    /// names the table it is about, so the caller can give its line.
    pub(crate) fn validate(&self) -> Result<(), (Section, String)> {
        let bad = |message: String| {
            let section = match message.split_once(']') {
                Some(("[camera", _)) => Section::Table("[camera]"),
                Some(("[projector", _)) => Section::Table("[projector]"),
                _ => Section::Top,
            };
            (section, message)
        };
        if self.version != SCENE_VERSION {
            return Err(bad(format!(
                "key `version` is {}, expected {SCENE_VERSION}",
                self.version
            )));
        }
        // Every number finite first: a NaN position or focal length would render
        // nothing and write a camera file crossline itself refuses.
        if let Some(key) = toml::Value::try_from(self)
            .ok()
            .and_then(|v| non_finite(&v, ""))
        {
            return Err(bad(format!("`{key}` must be a finite number")));
        }
        let c = &self.camera;
        if c.width == 0 || c.height == 0 {
            return Err(bad("[camera] `width` and `height` must be positive".into()));
        }
        if c.width > MAX_SIDE
            || c.height > MAX_SIDE
            || u64::from(c.width) * u64::from(c.height) > MAX_PIXELS
        {
            return Err(bad(format!(
                "[camera] image {}x{} is too large to render (at most {MAX_SIDE} a side, {MAX_PIXELS} pixels)",
                c.width, c.height
            )));
        }
        if !(0.0..=1.0).contains(&c.readout_frames) {
            return Err(bad(format!(
                "[camera] `readout_frames` = {}, expected 0 (global shutter) to 1 frame period",
                c.readout_frames
            )));
        }
        if let Some(fx) = c.fx {
            let side = f64::from(c.width.max(c.height));
            if !(fx >= (0.01 * side).max(1.0) && fx <= (1000.0 * side).min(1e6)) {
                return Err(bad(format!(
                    "[camera] `fx` = {fx}, expected {} to {} px for a {}x{} image",
                    (0.01 * side).max(1.0),
                    (1000.0 * side).min(1e6),
                    c.width,
                    c.height
                )));
            }
        }
        if self.distance() <= 0.0 {
            return Err(bad("[camera] `look_at` must differ from `position`".into()));
        }
        if c.hfov_deg.is_none() && c.fx.is_none() {
            return Err(bad(
                "[camera] needs `hfov_deg` or `fx` (focal length in pixels)".into(),
            ));
        }
        if let Some(h) = c.hfov_deg {
            if !(h > 0.0 && h < 179.0) {
                return Err(bad(format!(
                    "[camera] `hfov_deg` = {h}, expected 0 < hfov_deg < 179"
                )));
            }
        }
        if !c.distortion.is_empty() && Distortion::from_slice(&c.distortion).is_none() {
            return Err(bad(format!(
                "[camera] `distortion` has {} entries, expected 4, 5 or 8 (k1, k2, p1, p2[, k3[, k4, k5, k6]])",
                c.distortion.len()
            )));
        }
        let p = &self.projector;
        if !(p.fan_deg > 0.0 && p.fan_deg < 180.0) {
            return Err(bad(format!(
                "[projector] `fan_deg` = {}, expected 0 < fan_deg < 180",
                p.fan_deg
            )));
        }
        if p.colours[0] == p.colours[1] {
            return Err(bad(
                "[projector] `colours` must name two different colours".into()
            ));
        }
        if V3::from(p.baseline_direction).norm() == 0.0 {
            return Err(bad("[projector] `baseline_direction` is zero".into()));
        }
        for (key, v) in [
            ("sweep_period_frames", p.sweep_period_frames),
            ("roll_period_frames", p.roll_period_frames),
            ("wobble_period_frames", p.wobble_period_frames),
            ("drift_correlation_frames", p.drift_correlation_frames),
            ("roll_swing_period_frames", p.roll_swing_period_frames),
            ("roll_jitter_period_frames", p.roll_jitter_period_frames),
        ] {
            if v <= 0.0 {
                return Err(bad(format!("[projector] `{key}` must be positive")));
            }
        }
        if !(p.drift >= 0.0 && p.drift.is_finite()) {
            return Err(bad(format!(
                "[projector] `drift` = {}, expected >= 0",
                p.drift
            )));
        }
        if p.walk_per_frame.iter().any(|v| !v.is_finite()) {
            return Err(bad("[projector] `walk_per_frame` must be finite".into()));
        }
        if self.primitives.is_empty() {
            return Err(bad("the scene has no [[primitive]]".into()));
        }
        for (i, prim) in self.primitives.iter().enumerate() {
            validate_primitive(prim).map_err(|m| {
                (
                    Section::Primitive(i),
                    format!(
                        "[[primitive]] #{} ({:?}): {m}",
                        i + 1,
                        prim.name.as_deref().unwrap_or(shape_name(prim.shape))
                    ),
                )
            })?;
        }
        Ok(())
    }
}

/// Largest image side and pixel count a scene renders (8K is 33 M pixels).
pub const MAX_SIDE: u32 = 16384;
pub const MAX_PIXELS: u64 = 1 << 26;

/// The dotted key of the first float in `v` that is NaN or infinite.
fn non_finite(v: &toml::Value, key: &str) -> Option<String> {
    let join = |k: &str| {
        if key.is_empty() {
            k.to_string()
        } else {
            format!("{key}.{k}")
        }
    };
    match v {
        toml::Value::Float(f) if !f.is_finite() => Some(key.to_string()),
        toml::Value::Table(t) => t.iter().find_map(|(k, v)| non_finite(v, &join(k))),
        toml::Value::Array(a) => a.iter().find_map(|v| non_finite(v, key)),
        _ => None,
    }
}

fn shape_name(s: Shape) -> &'static str {
    match s {
        Shape::Plane => "plane",
        Shape::Rectangle => "rectangle",
        Shape::Box => "box",
        Shape::Cylinder => "cylinder",
        Shape::Sphere => "sphere",
    }
}

fn validate_primitive(p: &PrimitiveSpec) -> Result<(), String> {
    let given: [(&str, bool); 13] = [
        ("point", p.point.is_some()),
        ("normal", p.normal.is_some()),
        ("corner", p.corner.is_some()),
        ("edge_u", p.edge_u.is_some()),
        ("edge_v", p.edge_v.is_some()),
        ("center", p.center.is_some()),
        ("size", p.size.is_some()),
        ("rotation_deg", p.rotation_deg.is_some()),
        ("from", p.from.is_some()),
        ("to", p.to.is_some()),
        ("radius", p.radius.is_some() || p.capped.is_some()),
        ("arc_deg", p.arc_deg.is_some()),
        ("arc_towards", p.arc_towards.is_some()),
    ];
    let (required, optional): (&[&str], &[&str]) = match p.shape {
        Shape::Plane => (&["point", "normal"], &[]),
        Shape::Rectangle => (&["corner", "edge_u", "edge_v"], &[]),
        Shape::Box => (&["center", "size"], &["rotation_deg"]),
        Shape::Cylinder => (&["from", "to", "radius"], &["arc_deg", "arc_towards"]),
        Shape::Sphere => (&["center", "radius"], &[]),
    };
    let name = shape_name(p.shape);
    for (key, present) in given {
        let allowed = required.contains(&key) || optional.contains(&key);
        if present && !allowed {
            let key = if key == "radius" && p.radius.is_none() {
                "capped"
            } else {
                key
            };
            return Err(format!("key `{key}` does not apply to shape \"{name}\""));
        }
        if !present && required.contains(&key) {
            return Err(format!(
                "missing key `{key}` (shape \"{name}\" needs {})",
                required.join(", ")
            ));
        }
    }
    if p.capped.is_some() && p.shape != Shape::Cylinder {
        return Err(format!("key `capped` does not apply to shape \"{name}\""));
    }
    if let Some(a) = p.arc_deg {
        if !(a > 0.0 && a <= 360.0) {
            return Err(format!("`arc_deg` = {a}, expected 0 < arc_deg <= 360"));
        }
    }
    if let (Some(a), Some(b), Some(deg)) = (p.from, p.to, p.arc_deg) {
        let axis = V3::from(b) - V3::from(a);
        let towards = V3::from(p.arc_towards.unwrap_or(default_arc_towards()));
        let across = axis.normalize().cross(&towards).norm();
        if deg < 360.0 && a != b && (across.is_nan() || across <= 1e-6 * towards.norm()) {
            return Err("`arc_towards` is zero or parallel to the axis".into());
        }
    }
    if let Some(r) = p.radius {
        if r <= 0.0 {
            return Err(format!("`radius` = {r}, expected > 0"));
        }
    }
    if let Some(s) = p.size {
        if s.iter().any(|&v| v <= 0.0) {
            return Err("`size` entries must be > 0".into());
        }
    }
    if let Some(n) = p.normal {
        if V3::from(n).norm() == 0.0 {
            return Err("`normal` is zero".into());
        }
    }
    if let (Some(u), Some(v)) = (p.edge_u, p.edge_v) {
        if V3::from(u).cross(&V3::from(v)).norm() == 0.0 {
            return Err("`edge_u` and `edge_v` are parallel or zero".into());
        }
    }
    if let (Some(a), Some(b)) = (p.from, p.to) {
        if a == b {
            return Err("`from` equals `to`".into());
        }
    }
    if p.albedo.iter().any(|&a| !(0.0..=1.0).contains(&a)) {
        return Err("`albedo` entries must lie in [0, 1]".into());
    }
    if !(0.0..=1.0).contains(&p.texture_contrast) {
        return Err("`texture_contrast` must lie in [0, 1]".into());
    }
    if let Some(s) = p.texture_scale {
        if s <= 0.0 {
            return Err("`texture_scale` must be > 0".into());
        }
    }
    Ok(())
}

/// Where in the file a validation error belongs.
#[derive(Clone, Copy, Debug)]
pub(crate) enum Section {
    Top,
    Table(&'static str),
    /// The n-th `[[primitive]]` (0-based).
    Primitive(usize),
}

/// 1-based line of a section's header in the scene text.
fn section_line(text: &str, section: Section) -> Option<usize> {
    let (header, nth) = match section {
        Section::Top => return None,
        Section::Table(h) => (h, 0),
        Section::Primitive(i) => ("[[primitive]]", i),
    };
    text.lines()
        .enumerate()
        .filter(|(_, l)| l.trim() == header)
        .nth(nth)
        .map(|(i, _)| i + 1)
}

/// 1-based line, 1-based column and text of the line holding byte `offset`.
fn locate(text: &str, offset: usize) -> (usize, usize, String) {
    let offset = offset.min(text.len());
    let before = &text[..offset];
    let line = before.matches('\n').count() + 1;
    let start = before.rfind('\n').map_or(0, |p| p + 1);
    let col = offset - start + 1;
    let line_text = text[start..].lines().next().unwrap_or("").to_string();
    (line, col, line_text)
}
