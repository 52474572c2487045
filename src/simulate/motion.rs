//! The hand-held projector's path: a seeded, smooth function of the frame index, so
//! every frame can be rendered independently (and in parallel) with the same result.
//!
//! The centre is a rest position that may drift (a smooth seeded spline) and walk (a
//! steady translation), plus a wobble about it; the axis aims at a Lissajous sweep over
//! the image; the cross rolls about the axis by a sinusoid, a slow swing and a fast
//! jitter. Terms with zero amplitude contribute exactly nothing, so scenes that do not
//! set them move as they did before those terms existed.

use nalgebra::Vector3;

use super::scene::{mix64, Scene, SceneSpec};
use crate::camera::Camera;

type V3 = Vector3<f64>;

pub use crate::rng::SplitMix64;

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
    drift: f64,
    drift_correlation: f64,
    /// Hash salt of the drift's control points.
    drift_salt: u64,
    walk_per_frame: V3,
    roll_swing: f64,
    roll_swing_period: f64,
    roll_swing_phase: f64,
    roll_jitter: f64,
    /// Three sinusoids: (weight, period in frames, phase).
    roll_jitter_terms: [(f64, f64, f64); 3],
}

/// Salt of the hand-path terms added after the first version (drift, walk, roll swing
/// and jitter): their own stream, so scenes without them move exactly as before.
const HAND_SALT: u64 = 0x6861_6e64_7061_7468;

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
        // Drawn from their own stream, after everything above, so that the older
        // terms keep their values.
        let mut hand = SplitMix64::new(mix64(seed ^ HAND_SALT));
        let drift_salt = hand.next_u64();
        let roll_swing_phase = tau * hand.next_f64();
        let mut roll_jitter_terms = [(0.0, 0.0, 0.0); 3];
        for (k, term) in roll_jitter_terms.iter_mut().enumerate() {
            let weight = [0.5, 0.3, 0.2][k];
            let period = p.roll_jitter_period_frames * (0.7 + 0.6 * hand.next_f64());
            *term = (weight, period, tau * hand.next_f64());
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
            drift: p.drift,
            drift_correlation: p.drift_correlation_frames,
            drift_salt,
            walk_per_frame: V3::from(p.walk_per_frame),
            roll_swing: p.roll_swing_deg.to_radians(),
            roll_swing_period: p.roll_swing_period_frames,
            roll_swing_phase,
            roll_jitter: p.roll_jitter_deg.to_radians(),
            roll_jitter_terms,
        }
    }

    /// The radius the rest centre drifts within.
    pub fn drift(&self) -> f64 {
        self.drift
    }

    /// Where the rest centre has wandered to in frame `index`: the configured rest
    /// position plus the drift and the walk (the wobble is about this point).
    pub fn rest_centre_at(&self, index: usize) -> V3 {
        self.rest_centre_at_time(index as f64)
    }

    /// [`Self::rest_centre_at`] at time `t`, in frames (continuous).
    fn rest_centre_at_time(&self, t: f64) -> V3 {
        let mut c = self.rest_centre;
        if self.drift > 0.0 {
            c += self.drift_offset(t);
        }
        if self.walk_per_frame != V3::zeros() {
            c += self.walk_per_frame * t;
        }
        c
    }

    /// A uniform cubic B-spline through control points one correlation length apart,
    /// each uniform in the ball of radius `drift`. Its weights are non-negative and sum
    /// to one, so the path stays within the ball; its speed is at most the largest step
    /// between neighbouring control points over the spacing, `2 drift / correlation`.
    fn drift_offset(&self, t: f64) -> V3 {
        let u = t / self.drift_correlation;
        let i = u.floor();
        let f = u - i;
        let f2 = f * f;
        let f3 = f2 * f;
        let weights = [
            (1.0 - f).powi(3) / 6.0,
            (3.0 * f3 - 6.0 * f2 + 4.0) / 6.0,
            (-3.0 * f3 + 3.0 * f2 + 3.0 * f + 1.0) / 6.0,
            f3 / 6.0,
        ];
        let base = i as i64 - 1;
        weights
            .iter()
            .enumerate()
            .map(|(k, w)| self.drift_control(base + k as i64) * *w)
            .sum::<V3>()
            * self.drift
    }

    /// Control point `j` of the drift, uniform in the unit ball (rejection sampling).
    fn drift_control(&self, j: i64) -> V3 {
        let mut rng = SplitMix64::new(mix64(
            self.drift_salt ^ (j as u64).wrapping_mul(0xD6E8_FEB8_6659_FD93),
        ));
        for _ in 0..64 {
            let p = V3::new(rng.next_f64(), rng.next_f64(), rng.next_f64()) * 2.0 - V3::repeat(1.0);
            if p.norm_squared() <= 1.0 {
                return p;
            }
        }
        // Unreachable in practice (each try succeeds with probability 0.52).
        V3::zeros()
    }

    /// The roll of laser 0's fan in frame `index` (radians): the sinusoidal roll, the
    /// slow swing and the fast jitter.
    fn roll_at(&self, t: f64) -> f64 {
        let tau = std::f64::consts::TAU;
        let mut roll = self.roll_mean
            + self.roll_amplitude * (tau * t / self.roll_period + self.roll_phase).sin();
        if self.roll_swing != 0.0 {
            roll +=
                self.roll_swing * (tau * t / self.roll_swing_period + self.roll_swing_phase).sin();
        }
        if self.roll_jitter != 0.0 {
            roll += self.roll_jitter
                * self
                    .roll_jitter_terms
                    .iter()
                    .map(|&(w, period, phase)| w * (tau * t / period + phase).sin())
                    .sum::<f64>();
        }
        roll
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
        self.pose_at(index as f64, scene, camera)
    }

    /// The projector pose at time `t`, in frames: the path is smooth in time, so a
    /// rolling shutter's rows see it between frames.
    pub fn pose_at(&self, t: f64, scene: &Scene, camera: &Camera) -> ProjectorPose {
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
        let centre = self.rest_centre_at_time(t) + offset;

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

        let roll = self.roll_at(t);
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::simulate::builtin_scene;
    use crate::simulate::scene::camera_from_spec;

    fn poses(spec: &SceneSpec, seed: u64, frames: usize) -> Vec<ProjectorPose> {
        let scene = Scene::from_spec(spec);
        let cam = camera_from_spec(&spec.camera);
        let motion = Motion::new(spec, seed);
        (0..frames).map(|i| motion.pose(i, &scene, &cam)).collect()
    }

    /// Poses of the built-ins at 320 px wide, seed 3, as the simulator computed them
    /// before drift, walk, roll swing and jitter existed (from its `truth.json`).
    #[test]
    fn default_motion_is_unchanged() {
        #[allow(clippy::type_complexity)]
        let before: [(&str, usize, [f64; 3], [f64; 3], f64); 6] = [
            (
                "room",
                0,
                [
                    0.7353391577731058,
                    -0.023513981514284684,
                    0.008869508522325173,
                ],
                [0.5309832472618442, -0.4123771617811944, 0.7402714823418188],
                -0.3668664029641531,
            ),
            (
                "room",
                7,
                [
                    0.7656402123999108,
                    -0.03102476151619809,
                    -0.030761309399856187,
                ],
                [0.18500040136260962, -0.39075391952596483, 0.901712939837712],
                0.143059095821868,
            ),
            (
                "pipes",
                0,
                [
                    0.4712885068926367,
                    0.12792922812812918,
                    0.005938929599381147,
                ],
                [0.541953153226544, -0.3286308764623086, 0.7734911290657579],
                -0.3668664029641531,
            ),
            (
                "pipes",
                7,
                [
                    0.49157777430386196,
                    0.12290008885220119,
                    -0.020597449165383384,
                ],
                [
                    0.26602812553971456,
                    -0.33782365426736305,
                    0.9028312217902474,
                ],
                0.143059095821868,
            ),
            (
                "bricks",
                0,
                [
                    0.2105609135691666,
                    -0.1364962961844034,
                    0.0029694647996905735,
                ],
                [
                    0.01990813088548009,
                    0.014368315097703626,
                    0.9996985634909652,
                ],
                -0.3668664029641531,
            ),
            (
                "bricks",
                7,
                [
                    0.22070554727477923,
                    -0.13901086582236738,
                    -0.010298724582691692,
                ],
                [
                    -0.17122304853747203,
                    0.050858622948601766,
                    0.9839187304454096,
                ],
                0.143059095821868,
            ),
        ];
        for (name, index, centre, axis, roll) in before {
            let spec = builtin_scene(name)
                .expect("built-in")
                .with_resolution(320, 180);
            let p = poses(&spec, 3, index + 1)[index];
            assert!(
                (p.centre - V3::from(centre)).norm() < 1e-12,
                "{name} {index}: {p:?}"
            );
            assert!(
                (p.axis - V3::from(axis)).norm() < 1e-12,
                "{name} {index}: {p:?}"
            );
            assert!((p.roll_rad - roll).abs() < 1e-12, "{name} {index}: {p:?}");
        }
    }

    fn still_room() -> SceneSpec {
        let mut spec = builtin_scene("room").expect("room");
        spec.projector.wobble = Some(0.0);
        spec.projector.roll_amplitude_deg = 0.0;
        spec
    }

    #[test]
    fn drift_stays_within_its_amplitude_and_is_smooth() {
        let mut spec = still_room();
        let drift = 0.15;
        let corr = 30.0;
        spec.projector.drift = drift;
        spec.projector.drift_correlation_frames = corr;
        let motion = Motion::new(&spec, 5);
        let rest = motion.rest_centre();
        let ps = poses(&spec, 5, 600);
        let (mut far, mut max_step, mut sum_step) = (0.0f64, 0.0f64, 0.0);
        for (i, p) in ps.iter().enumerate() {
            assert!(
                (p.centre - motion.rest_centre_at(i)).norm() < 1e-15,
                "no wobble"
            );
            let off = (p.centre - rest).norm();
            assert!(off <= drift * (1.0 + 1e-12), "frame {i}: {off} > {drift}");
            far = far.max(off);
            if i > 0 {
                let step = (p.centre - ps[i - 1].centre).norm();
                max_step = max_step.max(step);
                sum_step += step;
            }
        }
        assert!(max_step <= 2.0 * drift / corr, "step {max_step}");
        // It does wander: far from rest at times, and a few mm a frame on average.
        assert!(far > 0.5 * drift, "farthest {far}");
        let mean_step = sum_step / 599.0;
        assert!(mean_step > 0.1 * drift / corr, "mean step {mean_step}");
        // Smooth: the step changes little from one frame to the next.
        for i in 2..ps.len() {
            let acc = (ps[i].centre - 2.0 * ps[i - 1].centre + ps[i - 2].centre).norm();
            assert!(acc <= 8.0 * drift / (corr * corr), "frame {i}: {acc}");
        }
        // Another seed drifts elsewhere.
        let other = poses(&spec, 6, 20);
        assert!((other[10].centre - ps[10].centre).norm() > 1e-4);
    }

    #[test]
    fn walk_translates_the_rest_centre_steadily() {
        let mut spec = still_room();
        spec.projector.walk_per_frame = [0.001, -0.002, 0.0005];
        let ps = poses(&spec, 2, 50);
        let rest = Motion::new(&spec, 2).rest_centre();
        for (i, p) in ps.iter().enumerate() {
            let expected = rest + V3::new(0.001, -0.002, 0.0005) * i as f64;
            assert!((p.centre - expected).norm() < 1e-12, "frame {i}");
        }
    }

    #[test]
    fn roll_swing_reaches_its_amplitude_and_jitter_is_fast() {
        let mut spec = still_room();
        spec.projector.roll_deg = 10.0;
        spec.projector.roll_swing_deg = 50.0;
        spec.projector.roll_swing_period_frames = 120.0;
        let ps = poses(&spec, 4, 120);
        let dev: Vec<f64> = ps.iter().map(|p| p.roll_rad.to_degrees() - 10.0).collect();
        let hi = dev.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
        let lo = dev.iter().cloned().fold(f64::INFINITY, f64::min);
        assert!((49.5..=50.0 + 1e-9).contains(&hi), "{hi}");
        assert!((-50.0 - 1e-9..=-49.5).contains(&lo), "{lo}");
        // Slow: under 3° a frame (2π 50 / 120 = 2.6).
        for w in dev.windows(2) {
            assert!((w[1] - w[0]).abs() < 2.7);
        }

        let mut spec = still_room();
        spec.projector.roll_jitter_deg = 3.0;
        spec.projector.roll_jitter_period_frames = 5.0;
        let ps = poses(&spec, 4, 200);
        let roll: Vec<f64> = ps.iter().map(|p| p.roll_rad.to_degrees()).collect();
        assert!(roll.iter().all(|r| r.abs() <= 3.0 + 1e-9));
        let mean_step = roll.windows(2).map(|w| (w[1] - w[0]).abs()).sum::<f64>() / 199.0;
        assert!(mean_step > 0.8, "jitter moves {mean_step}° a frame");
    }
}
