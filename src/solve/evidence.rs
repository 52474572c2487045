//! What the estimator ([`super::estimate`]) is given: the frames' poses to find, the
//! laser planes they carry, the crossings that tie planes together, and how a crossing's
//! image point becomes a ray once the focal length is corrected.
//!
//! Owns no algorithm. A *plane* is one laser of one frame; a *pose* is one frame's
//! projector ([`super::pose::CrossPose`]), carrying one or both of its lasers' planes.
//!
//! # Rays and the focal scale
//! Crossings are given in the undistorted normalised coordinates `u` of the camera file.
//! If the true focal length is `λ` times the file's (a flat port under water: about
//! 1.33), the pixel's true distorted normalised coordinates are `δ(u) / λ`, `δ` the
//! file's distortion, and its true ray is `r(λ) = (ū, 1)` with `ū = δ⁻¹(δ(u) / λ)`: the
//! distortion applies at the corrected radius. At `λ = 1`, `r = (u, 1)`.

use nalgebra::{Matrix2, Vector2, Vector3};

use crate::camera::Distortion;

type V3 = Vector3<f64>;

/// Which spread a crossing's residual is weighed by: crossings of two strong ridges,
/// and those where a curve is faint (far along a sheet under water), whose noise is
/// measured apart.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum CrossingClass {
    Strong = 0,
    Faint = 1,
}

/// A crossing of a curve of plane `a` with a curve of plane `b` at the undistorted
/// normalised image point `u`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Observation {
    pub a: u32,
    pub b: u32,
    pub u: [f64; 2],
    /// Sine of the angle between the two curves there.
    pub sin_angle: f64,
    pub class: CrossingClass,
}

/// One laser plane: which pose carries it and which of its two lasers it is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PlaneSlot {
    pub pose: u32,
    pub laser: u8,
}

impl PlaneSlot {
    /// This plane as `poses` (indexed by pose) give it; `None` for a plane through the
    /// camera centre ([`super::pose::CrossPose::plane`]).
    pub fn plane_in(self, poses: &[super::pose::CrossPose]) -> Option<Vector3<f64>> {
        poses[self.pose as usize].plane(usize::from(self.laser))
    }
}

/// The rays of image points at a focal scale `λ` (see the module docs).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RayModel {
    /// The camera file's distortion; `None` for none.
    distortion: Option<Distortion>,
}

/// A ray `(x, y, 1)` and its derivative with respect to the focal scale.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ray {
    pub r: V3,
    pub dr_dscale: V3,
}

impl RayModel {
    pub fn new(distortion: Distortion) -> Self {
        Self {
            distortion: (!distortion.is_zero()).then_some(distortion),
        }
    }

    /// The ray of the undistorted normalised point `u` (camera file coordinates) at focal
    /// scale `lambda`, and `∂r/∂λ`. `None` where the distortion cannot be inverted.
    pub fn ray(&self, u: [f64; 2], lambda: f64) -> Option<Ray> {
        let (dx, dy) = match &self.distortion {
            Some(dist) => dist.distort(u[0], u[1]),
            None => (u[0], u[1]),
        };
        let (x, y) = match &self.distortion {
            _ if lambda == 1.0 => (u[0], u[1]),
            Some(dist) => dist.undistort(dx / lambda, dy / lambda)?,
            None => (dx / lambda, dy / lambda),
        };
        // ū = δ⁻¹(δ(u)/λ): ∂ū/∂λ = J_δ(ū)⁻¹ · (−δ(u)/λ²).
        let rhs = Vector2::new(-dx, -dy) / (lambda * lambda);
        let dxy = match &self.distortion {
            Some(dist) => {
                let j: Matrix2<f64> = dist.jacobian(x, y);
                j.try_inverse()? * rhs
            }
            None => rhs,
        };
        Some(Ray {
            r: V3::new(x, y, 1.0),
            dr_dscale: V3::new(dxy.x, dxy.y, 0.0),
        })
    }
}

/// The evidence of one scan.
#[derive(Clone, Debug, Default)]
pub struct Evidence {
    /// Per pose, the index of its frame (the time, in frames, that the motion terms
    /// measure steps in). Increasing.
    pub pose_frames: Vec<u32>,
    /// Per pose, whether it is an *anchor*: the anchors are estimated jointly, every
    /// other pose on its own against them (see [`super::calibrate`]). Empty: every pose
    /// is one. Every crossing ties an anchor's plane, or a pose's own two planes.
    pub anchors: Vec<bool>,
    pub planes: Vec<PlaneSlot>,
    pub crossings: Vec<Observation>,
    /// Focal length (pixels) of the camera file, so that residuals are in pixels.
    pub focal_px: f64,
    pub rays: RayModel,
}

impl Evidence {
    pub fn num_poses(&self) -> usize {
        self.pose_frames.len()
    }

    /// Whether pose `p` is an anchor (see [`Self::anchors`]).
    pub fn is_anchor(&self, p: usize) -> bool {
        self.anchors
            .get(p)
            .copied()
            .unwrap_or(self.anchors.is_empty())
    }

    /// Per pose, its planes by laser.
    pub fn planes_of_poses(&self) -> Vec<[Option<u32>; 2]> {
        let mut out = vec![[None; 2]; self.num_poses()];
        for (i, p) in self.planes.iter().enumerate() {
            out[p.pose as usize][usize::from(p.laser.min(1))] = Some(i as u32);
        }
        out
    }

    /// Checks the indices: every plane's pose exists, every crossing's planes exist,
    /// frames increase. Returns what is wrong.
    pub fn validate(&self) -> Result<(), String> {
        if !(self.focal_px.is_finite() && self.focal_px > 0.0) {
            return Err(format!("focal length {} px is not positive", self.focal_px));
        }
        if self.pose_frames.windows(2).any(|w| w[1] <= w[0]) {
            return Err("pose frames do not increase".into());
        }
        let poses = self.num_poses();
        if !self.anchors.is_empty() && self.anchors.len() != poses {
            return Err(format!(
                "{} anchor flags for {poses} poses",
                self.anchors.len()
            ));
        }
        if let Some(p) = self.planes.iter().find(|p| p.pose as usize >= poses) {
            return Err(format!("plane of pose {} beyond {poses} poses", p.pose));
        }
        let planes = self.planes.len();
        if let Some(c) = self
            .crossings
            .iter()
            .find(|c| c.a as usize >= planes || c.b as usize >= planes || c.a == c.b)
        {
            return Err(format!(
                "crossing of planes {} and {} (of {planes})",
                c.a, c.b
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_ray_at_a_focal_scale_applies_the_distortion_at_the_corrected_radius() {
        let dist = Distortion::from_slice(&[-0.25, 0.08, 0.001, -0.0005, 0.0]).expect("5 terms");
        let model = RayModel::new(dist);
        // A true point, seen by a camera 1.25 times longer than the file says.
        let lambda = 1.25;
        let truth = [0.21, -0.13];
        let (tx, ty) = dist.distort(truth[0], truth[1]);
        // The file's normalisation: distorted coordinates λ times too large, then
        // undistorted with the same coefficients.
        let (fx, fy) = dist
            .undistort(tx * lambda, ty * lambda)
            .expect("invertible");
        let ray = model.ray([fx, fy], lambda).expect("ray");
        assert!((ray.r.x - truth[0]).abs() < 1e-10 && (ray.r.y - truth[1]).abs() < 1e-10);
        // The derivative, by central differences.
        let h = 1e-6;
        let plus = model.ray([fx, fy], lambda + h).expect("ray").r;
        let minus = model.ray([fx, fy], lambda - h).expect("ray").r;
        let numeric = (plus - minus) / (2.0 * h);
        assert!(
            (numeric - ray.dr_dscale).norm() < 1e-7,
            "{numeric} vs {}",
            ray.dr_dscale
        );
        // At scale 1 the ray is the point itself.
        let at_one = model.ray([fx, fy], 1.0).expect("ray").r;
        assert_eq!([at_one.x, at_one.y], [fx, fy]);
    }
}
