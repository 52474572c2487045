//! Building blocks of the random layouts: palettes and looks, primitive constructors,
//! pointing the camera, and placing objects where random pixels' rays meet the floor.
//! World frame: metres, z up.

use super::{Rng, V3};
use crate::camera::Camera;
use crate::simulate::scene::{
    world_from_camera, CameraSpec, LightSpec, Medium, PrimitiveSpec, ProjectorSpec, SceneSpec,
    Shape, Texture, WaterSpec, SCENE_VERSION,
};

pub(super) fn spec_of(name: &str, camera: CameraSpec, primitives: Vec<PrimitiveSpec>) -> SceneSpec {
    SceneSpec {
        version: SCENE_VERSION,
        name: name.into(),
        medium: Medium::Air,
        camera,
        projector: ProjectorSpec::default(),
        light: LightSpec::default(),
        water: WaterSpec::default(),
        primitives,
    }
}

/// Surface appearance of one primitive.
#[derive(Clone, Copy)]
pub(super) struct Look {
    albedo: [f64; 3],
    texture: Texture,
    scale: f64,
    contrast: f64,
    /// Shared by every primitive of this look, so that the pieces of a wall join.
    seed: u64,
}

pub(super) const NEUTRAL: [[f64; 3]; 5] = [
    [0.8, 0.8, 0.78],
    [0.6, 0.6, 0.6],
    [0.75, 0.7, 0.6],
    [0.5, 0.52, 0.55],
    [0.85, 0.82, 0.75],
];
pub(super) const WOOD: [[f64; 3]; 3] = [[0.6, 0.45, 0.3], [0.5, 0.36, 0.22], [0.72, 0.58, 0.4]];
pub(super) const TOY: [[f64; 3]; 7] = [
    [0.8, 0.15, 0.1],
    [0.15, 0.3, 0.8],
    [0.85, 0.75, 0.15],
    [0.2, 0.6, 0.25],
    [0.85, 0.85, 0.85],
    [0.25, 0.25, 0.25],
    [0.9, 0.5, 0.1],
];
pub(super) const SEA: [[f64; 3]; 6] = [
    [0.6, 0.55, 0.42],
    [0.42, 0.4, 0.36],
    [0.6, 0.36, 0.2],
    [0.75, 0.55, 0.2],
    [0.5, 0.5, 0.5],
    [0.32, 0.42, 0.26],
];

/// A colour of `palette`, varied by ±15 %, with a random texture of about `scale`.
pub(super) fn look(rng: &mut Rng, palette: &[[f64; 3]], scale: f64) -> Look {
    let base = palette[rng.below(palette.len())];
    let albedo = base.map(|a| (a * rng.uniform(0.85, 1.15)).clamp(0.05, 0.95));
    let texture = match rng.below(20) {
        0..=13 => Texture::Noise,
        14..=16 => Texture::Checker,
        _ => Texture::None,
    };
    Look {
        albedo,
        texture,
        scale: scale * rng.uniform(0.6, 1.6),
        contrast: rng.uniform(0.15, 0.6),
        seed: rng.below(1 << 20) as u64,
    }
}

pub(super) fn prim(shape: Shape, name: &str, look: &Look) -> PrimitiveSpec {
    PrimitiveSpec {
        shape,
        name: Some(name.into()),
        point: None,
        normal: None,
        corner: None,
        edge_u: None,
        edge_v: None,
        center: None,
        size: None,
        rotation_deg: None,
        from: None,
        to: None,
        radius: None,
        capped: None,
        arc_deg: None,
        arc_towards: None,
        albedo: look.albedo,
        texture: look.texture,
        texture_scale: Some(look.scale),
        texture_contrast: look.contrast,
        texture_seed: Some(look.seed),
    }
}

pub(super) fn plane(name: &str, point: V3, normal: V3, look: &Look) -> PrimitiveSpec {
    PrimitiveSpec {
        point: Some(point.into()),
        normal: Some(normal.into()),
        ..prim(Shape::Plane, name, look)
    }
}

pub(super) fn rect(name: &str, corner: V3, u: V3, v: V3, look: &Look) -> PrimitiveSpec {
    PrimitiveSpec {
        corner: Some(corner.into()),
        edge_u: Some(u.into()),
        edge_v: Some(v.into()),
        ..prim(Shape::Rectangle, name, look)
    }
}

pub(super) fn block(
    name: &str,
    center: V3,
    size: V3,
    rotation_deg: V3,
    look: &Look,
) -> PrimitiveSpec {
    PrimitiveSpec {
        center: Some(center.into()),
        size: Some(size.into()),
        rotation_deg: Some(rotation_deg.into()),
        ..prim(Shape::Box, name, look)
    }
}

pub(super) fn cylinder(name: &str, from: V3, to: V3, radius: f64, look: &Look) -> PrimitiveSpec {
    PrimitiveSpec {
        from: Some(from.into()),
        to: Some(to.into()),
        radius: Some(radius),
        ..prim(Shape::Cylinder, name, look)
    }
}

pub(super) fn sphere(name: &str, center: V3, radius: f64, look: &Look) -> PrimitiveSpec {
    PrimitiveSpec {
        center: Some(center.into()),
        radius: Some(radius),
        ..prim(Shape::Sphere, name, look)
    }
}

/// Points the camera from `position` at `look_at`, rolled by up to ±3°.
pub(super) fn aim(rng: &mut Rng, camera: &mut CameraSpec, position: V3, look_at: V3) {
    camera.position = position.into();
    camera.look_at = look_at.into();
    let right = (look_at - position).normalize().cross(&V3::z());
    let roll = rng.uniform(-3.0f64, 3.0).to_radians();
    camera.up = if right.norm() > 1e-6 {
        (V3::z() * roll.cos() + right.normalize() * roll.sin()).into()
    } else {
        [0.0, 1.0, 0.0]
    };
}

/// The least downward pitch (radians) at which every ray of the image's top row points
/// at least `margin` below the horizon (camera without roll).
pub(super) fn floor_pitch(camera: &Camera, margin: f64) -> f64 {
    let rays: Vec<V3> = (0..=32)
        .filter_map(|i| camera.ray_from_pixel(i as f64 / 32.0 * (camera.width as f64 - 1.0), 0.0))
        .map(|r| r.normalize())
        .collect();
    let mut pitch = 0.0;
    while pitch < 85f64.to_radians() {
        // World up in camera axes is (0, -cos, -sin) of the pitch.
        let highest = rays
            .iter()
            .map(|r| -r.y * f64::cos(pitch) - r.z * f64::sin(pitch))
            .fold(-1.0, f64::max);
        if highest < -margin.sin() {
            return pitch;
        }
        pitch += 0.5f64.to_radians();
    }
    pitch
}

/// Where a random pixel's ray (away from the image border by `margin` of its size)
/// meets the plane through `point` with normal `normal`, if it does.
pub(super) fn ground_point(
    rng: &mut Rng,
    camera: &CameraSpec,
    intrinsics: &Camera,
    margin: f64,
    point: V3,
    normal: V3,
) -> Option<V3> {
    let u = rng.uniform(margin, 1.0 - margin) * intrinsics.width as f64;
    let v = rng.uniform(margin, 1.0 - margin) * intrinsics.height as f64;
    let pose = world_from_camera(camera);
    let dir = pose.apply_vector(&intrinsics.ray_from_pixel(u, v)?);
    let origin = V3::from(camera.position);
    let t = normal.dot(&(point - origin)) / normal.dot(&dir);
    (t > 0.0 && t.is_finite()).then(|| origin + dir * t)
}

pub(super) fn count(n: usize, one: &str, many: &str) -> String {
    format!("{n} {}", if n == 1 { one } else { many })
}

/// The non-zero counts, joined by commas.
pub(super) fn counts(items: &[(usize, &str, &str)]) -> String {
    let parts: Vec<String> = items
        .iter()
        .filter(|(n, _, _)| *n > 0)
        .map(|&(n, one, many)| count(n, one, many))
        .collect();
    parts.join(", ")
}

/// Footprints placed so far (centre, radius); `free` says whether a new one fits.
pub(super) struct Footprints(pub(super) Vec<(V3, f64)>);

impl Footprints {
    pub(super) fn free(&self, c: V3, r: f64) -> bool {
        self.0.iter().all(|(p, q)| {
            let d = (c - p).xy().norm();
            d > r + q
        })
    }
}
