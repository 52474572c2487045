//! The hand-held projector's path: a seeded, smooth function of the frame index, so
//! every frame can be rendered independently (and in parallel) with the same result.

use nalgebra::Vector3;

use super::scene::{mix64, Scene, SceneSpec};
use crate::camera::Camera;

type V3 = Vector3<f64>;

/// A small deterministic generator (SplitMix64).
#[derive(Clone, Debug)]
pub struct SplitMix64(u64);

impl SplitMix64 {
    pub fn new(seed: u64) -> Self {
        Self(seed)
    }

    #[inline]
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in `[0, 1)`.
    pub fn next_f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// The projector in one frame (camera coordinates).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ProjectorPose {
    pub centre: V3,
    /// Unit optical axis (the direction of the cross's centre).
    pub axis: V3,
    /// Unit in-plane fan directions, orthogonal to `axis` and to each other: laser `k`'s
    /// sheet is spanned by `axis` and `fan_dirs[k]`.
    pub fan_dirs: [V3; 2],
    /// Roll of laser 0's fan direction about the axis, from the camera's +X projected
    /// onto the plane normal to the axis (radians).
    pub roll_rad: f64,
}

impl ProjectorPose {
    /// Unit normal of laser `k`'s plane (the other laser's fan direction).
    pub fn normal(&self, k: usize) -> V3 {
        self.fan_dirs[1 - k]
    }

    /// Laser `k`'s plane as `v` with `v · X = 1`.
    pub fn plane(&self, k: usize) -> V3 {
        let n = self.normal(k);
        n / n.dot(&self.centre)
    }
}

/// Seeded motion parameters derived from the scene's `[projector]` table.
#[derive(Clone, Debug)]
pub struct Motion {
    rest_centre: V3,
    wobble: f64,
    wobble_period: f64,
    /// Per axis, three sinusoids: (weight, frequency multiplier, phase).
    wobble_terms: [[(f64, f64, f64); 3]; 3],
    sweep_period: f64,
    overscan: f64,
    sweep_phase: [f64; 2],
    tremor_phase: [f64; 2],
    roll_mean: f64,
    roll_amplitude: f64,
    roll_period: f64,
    roll_phase: f64,
    distance: f64,
}

impl Motion {
    pub fn new(spec: &SceneSpec, seed: u64) -> Motion {
        let p = &spec.projector;
        let distance = spec.distance();
        let baseline = p.baseline.unwrap_or(0.2 * distance);
        let wobble = p.wobble.unwrap_or(0.1 * baseline);
        let dir = V3::from(p.baseline_direction).normalize();
        let mut rng = SplitMix64::new(mix64(seed ^ 0x6d6f_7469_6f6e));
        let tau = std::f64::consts::TAU;
        let mut wobble_terms = [[(0.0, 0.0, 0.0); 3]; 3];
        for axis in wobble_terms.iter_mut() {
            let w = [0.5, 0.3, 0.2];
            let f = [1.0, 1.7 + 0.4 * rng.next_f64(), 2.9 + 0.6 * rng.next_f64()];
            for k in 0..3 {
                axis[k] = (w[k], f[k], tau * rng.next_f64());
            }
        }
        Motion {
            rest_centre: dir * baseline,
            wobble,
            wobble_period: p.wobble_period_frames,
            wobble_terms,
            sweep_period: p.sweep_period_frames,
            overscan: p.sweep_overscan,
            sweep_phase: [tau * rng.next_f64(), tau * rng.next_f64()],
            tremor_phase: [tau * rng.next_f64(), tau * rng.next_f64()],
            roll_mean: p.roll_deg.to_radians(),
            roll_amplitude: p.roll_amplitude_deg.to_radians(),
            roll_period: p.roll_period_frames,
            roll_phase: tau * rng.next_f64(),
            distance,
        }
    }

    /// The configured rest position of the projector centre (camera coordinates).
    pub fn rest_centre(&self) -> V3 {
        self.rest_centre
    }

    /// The configured wobble radius: the centre stays within this distance of rest.
    pub fn wobble(&self) -> f64 {
        self.wobble
    }

    /// The projector pose of frame `index`.
    pub fn pose(&self, index: usize, scene: &Scene, camera: &Camera) -> ProjectorPose {
        let t = index as f64;
        let tau = std::f64::consts::TAU;
        // Each axis stays within wobble/√3, so the offset stays within the wobble radius.
        let mut offset = V3::zeros();
        for (a, terms) in self.wobble_terms.iter().enumerate() {
            let s: f64 = terms
                .iter()
                .map(|&(w, f, ph)| w * (tau * f * t / self.wobble_period + ph).sin())
                .sum();
            offset[a] = s * self.wobble / 3f64.sqrt();
        }
        let centre = self.rest_centre + offset;

        // A Lissajous sweep of the aim over the image, a little beyond its border, plus
        // a faster tremor of a few percent.
        let gold = 1.618_033_988_749_895;
        let sx = (tau * t / self.sweep_period + self.sweep_phase[0]).sin()
            + 0.04 * (tau * 3.1 * t / self.sweep_period + self.tremor_phase[0]).sin();
        let sy = (tau * t / (self.sweep_period * gold) + self.sweep_phase[1]).sin()
            + 0.04 * (tau * 2.3 * t / self.sweep_period + self.tremor_phase[1]).sin();
        let w = camera.width as f64;
        let h = camera.height as f64;
        let px = 0.5 * (w - 1.0) + sx * self.overscan * 0.5 * w;
        let py = 0.5 * (h - 1.0) + sy * self.overscan * 0.5 * h;
        let ray = camera.ray_from_pixel(px, py).unwrap_or_else(|| {
            let (x, y) = camera.distorted_from_pixel(px, py);
            V3::new(x, y, 1.0)
        });
        let aim = scene
            .cast(&V3::zeros(), &ray)
            .map_or_else(|| ray.normalize() * self.distance, |hit| hit.point);
        let mut axis = aim - centre;
        if axis.norm() < 1e-12 * self.distance.max(1e-300) {
            axis = V3::z();
        }
        let axis = axis.normalize();

        let roll = self.roll_mean
            + self.roll_amplitude * (tau * t / self.roll_period + self.roll_phase).sin();
        let mut reference = V3::x() - axis * axis.x;
        if reference.norm() < 1e-6 {
            reference = V3::y() - axis * axis.y;
        }
        let reference = reference.normalize();
        let side = axis.cross(&reference);
        let e0 = reference * roll.cos() + side * roll.sin();
        // Re-orthogonalise so the two sheets are orthogonal to rounding.
        let e0 = (e0 - axis * axis.dot(&e0)).normalize();
        let e1 = axis.cross(&e0).normalize();
        ProjectorPose {
            centre,
            axis,
            fan_dirs: [e0, e1],
            roll_rad: roll,
        }
    }
}
