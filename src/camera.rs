//! The fixed camera: pinhole intrinsics, the OpenCV distortion model, and point-wise
//! (un)distortion.
//!
//! Owns the mapping between pixels and *normalised* image coordinates `(x, y)` of the
//! OpenCV convention (+X right, +Y down, +Z forward; a point `X` in camera coordinates
//! projects to `(X/Z, Y/Z)`). Everything downstream of extraction works in normalised
//! coordinates; only this module knows about pixels and lens distortion.
//!
//! The distortion model is OpenCV's (`cv::projectPoints`): radial `k1, k2, k3` with the
//! optional rational terms `k4, k5, k6`, and tangential `p1, p2`. Undistortion inverts it
//! per point with Newton's method (not with OpenCV's fixed-point loop, which stalls on
//! strong distortion), iterated to convergence.
//!
//! Reading and writing calibration files lives in [`crate::camera_file`].

use nalgebra::{Matrix2, Vector2, Vector3};
use serde::{Deserialize, Serialize};

/// OpenCV distortion coefficients in OpenCV's order `k1, k2, p1, p2, k3, k4, k5, k6`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Distortion {
    pub k1: f64,
    pub k2: f64,
    pub p1: f64,
    pub p2: f64,
    #[serde(default)]
    pub k3: f64,
    #[serde(default)]
    pub k4: f64,
    #[serde(default)]
    pub k5: f64,
    #[serde(default)]
    pub k6: f64,
}

impl Distortion {
    /// From an OpenCV coefficient vector of 4, 5 or 8 entries (extra entries, such as the
    /// thin-prism terms of a 12- or 14-vector, must be zero and are rejected by the file
    /// readers before they get here).
    pub fn from_slice(c: &[f64]) -> Option<Self> {
        let at = |i: usize| c.get(i).copied().unwrap_or(0.0);
        match c.len() {
            4 | 5 | 8 => Some(Self {
                k1: at(0),
                k2: at(1),
                p1: at(2),
                p2: at(3),
                k3: at(4),
                k4: at(5),
                k5: at(6),
                k6: at(7),
            }),
            _ => None,
        }
    }

    /// The coefficients as OpenCV orders them: 5 entries, or 8 when a rational term is set.
    pub fn to_vec(&self) -> Vec<f64> {
        let mut v = vec![self.k1, self.k2, self.p1, self.p2, self.k3];
        if self.is_rational() {
            v.extend([self.k4, self.k5, self.k6]);
        }
        v
    }

    pub fn is_rational(&self) -> bool {
        self.k4 != 0.0 || self.k5 != 0.0 || self.k6 != 0.0
    }

    /// Whether every coefficient is zero. Called once per point undistorted, so it
    /// reads the fields rather than building [`Self::to_vec`] (an allocation per point:
    /// 2-3 % of the extraction's time on distorted cameras).
    pub fn is_zero(&self) -> bool {
        let Self {
            k1,
            k2,
            p1,
            p2,
            k3,
            k4,
            k5,
            k6,
        } = *self;
        [k1, k2, p1, p2, k3, k4, k5, k6].iter().all(|&c| c == 0.0)
    }

    /// Distorted normalised coordinates of the ideal normalised point `(x, y)`.
    #[inline]
    pub fn distort(&self, x: f64, y: f64) -> (f64, f64) {
        let r2 = x * x + y * y;
        let radial = self.radial(r2);
        let xd = x * radial + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x);
        let yd = y * radial + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y;
        (xd, yd)
    }

    #[inline]
    fn radial(&self, r2: f64) -> f64 {
        let num = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
        let den = 1.0 + r2 * (self.k4 + r2 * (self.k5 + r2 * self.k6));
        num / den
    }

    /// Jacobian of [`Self::distort`] with respect to `(x, y)`.
    pub fn jacobian(&self, x: f64, y: f64) -> Matrix2<f64> {
        let r2 = x * x + y * y;
        let num = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
        let den = 1.0 + r2 * (self.k4 + r2 * (self.k5 + r2 * self.k6));
        let dnum = self.k1 + r2 * (2.0 * self.k2 + 3.0 * self.k3 * r2);
        let dden = self.k4 + r2 * (2.0 * self.k5 + 3.0 * self.k6 * r2);
        let radial = num / den;
        // d radial / d r2
        let dradial = (dnum * den - num * dden) / (den * den);
        let (drx, dry) = (2.0 * x * dradial, 2.0 * y * dradial);
        let dxd_dx = radial + x * drx + 2.0 * self.p1 * y + self.p2 * 6.0 * x;
        let dxd_dy = x * dry + 2.0 * self.p1 * x + self.p2 * 2.0 * y;
        let dyd_dx = y * drx + self.p1 * 2.0 * x + 2.0 * self.p2 * y;
        let dyd_dy = radial + y * dry + self.p1 * 6.0 * y + 2.0 * self.p2 * x;
        Matrix2::new(dxd_dx, dxd_dy, dyd_dx, dyd_dy)
    }

    /// Ideal normalised coordinates whose distortion is `(xd, yd)`, by damped Newton
    /// iteration to convergence. `None` when the model cannot be inverted there (beyond
    /// the radius where a strong radial polynomial folds back on itself).
    pub fn undistort(&self, xd: f64, yd: f64) -> Option<(f64, f64)> {
        if self.is_zero() {
            return Some((xd, yd));
        }
        let target = Vector2::new(xd, yd);
        let mut p = target;
        let mut err = {
            let (a, b) = self.distort(p.x, p.y);
            Vector2::new(a, b) - target
        };
        for _ in 0..100 {
            if err.norm() < 1e-15 {
                break;
            }
            let j = self.jacobian(p.x, p.y);
            let step = j.try_inverse()? * err;
            // Backtrack so that the residual never grows: the radial polynomial can
            // overshoot badly far from the centre.
            let mut t = 1.0;
            loop {
                let q = p - step * t;
                let (a, b) = self.distort(q.x, q.y);
                let e = Vector2::new(a, b) - target;
                if e.norm() < err.norm() || t < 1e-6 {
                    p = q;
                    err = e;
                    break;
                }
                t *= 0.5;
            }
        }
        // Accept only a true inverse on the monotonic part of the model: the Jacobian
        // must keep its orientation, or we found a folded-back branch.
        let tol = 1e-10 * (1.0 + target.norm());
        if err.norm() > tol || self.jacobian(p.x, p.y).determinant() <= 0.0 {
            return None;
        }
        Some((p.x, p.y))
    }
}

/// A calibrated pinhole camera with OpenCV distortion.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Camera {
    pub width: u32,
    pub height: u32,
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    /// The `(0, 1)` entry of the camera matrix; almost always zero.
    #[serde(default)]
    pub skew: f64,
    #[serde(default)]
    pub distortion: Distortion,
}

impl Camera {
    /// An undistorted camera with square pixels, principal point at the image centre and
    /// the given horizontal field of view.
    pub fn with_fov(width: u32, height: u32, hfov_rad: f64) -> Self {
        let f = 0.5 * width as f64 / (0.5 * hfov_rad).tan();
        Self {
            width,
            height,
            fx: f,
            fy: f,
            cx: 0.5 * (width as f64 - 1.0),
            cy: 0.5 * (height as f64 - 1.0),
            skew: 0.0,
            distortion: Distortion::default(),
        }
    }

    /// Pixel of an ideal (undistorted) normalised point.
    #[inline]
    pub fn pixel_from_normalized(&self, x: f64, y: f64) -> [f64; 2] {
        let (xd, yd) = self.distortion.distort(x, y);
        [
            self.fx * xd + self.skew * yd + self.cx,
            self.fy * yd + self.cy,
        ]
    }

    /// Distorted normalised coordinates of a pixel (the camera matrix undone, the lens not).
    #[inline]
    pub fn distorted_from_pixel(&self, u: f64, v: f64) -> (f64, f64) {
        let yd = (v - self.cy) / self.fy;
        let xd = (u - self.cx - self.skew * yd) / self.fx;
        (xd, yd)
    }

    /// Ideal normalised coordinates of a pixel, lens distortion removed. `None` outside
    /// the region where the distortion model is invertible.
    #[inline]
    pub fn normalized_from_pixel(&self, u: f64, v: f64) -> Option<[f64; 2]> {
        let (xd, yd) = self.distorted_from_pixel(u, v);
        self.distortion.undistort(xd, yd).map(|(x, y)| [x, y])
    }

    /// Pixel of a point in camera coordinates; `None` behind the camera.
    #[inline]
    pub fn pixel_from_camera(&self, point_in_camera: &Vector3<f64>) -> Option<[f64; 2]> {
        if point_in_camera.z <= 0.0 {
            return None;
        }
        Some(self.pixel_from_normalized(
            point_in_camera.x / point_in_camera.z,
            point_in_camera.y / point_in_camera.z,
        ))
    }

    /// The viewing ray `(x, y, 1)` of a pixel in camera coordinates (not unit length).
    #[inline]
    pub fn ray_from_pixel(&self, u: f64, v: f64) -> Option<Vector3<f64>> {
        self.normalized_from_pixel(u, v)
            .map(|[x, y]| Vector3::new(x, y, 1.0))
    }

    pub fn contains_pixel(&self, u: f64, v: f64) -> bool {
        u >= -0.5 && v >= -0.5 && u < self.width as f64 - 0.5 && v < self.height as f64 - 0.5
    }

    /// The same camera with its focal lengths multiplied by `factor` (a flat port under
    /// water multiplies them by about the refractive index of water).
    pub fn with_focal_scaled(&self, factor: f64) -> Self {
        Self {
            fx: self.fx * factor,
            fy: self.fy * factor,
            skew: self.skew * factor,
            ..self.clone()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn wide() -> Camera {
        Camera {
            width: 1920,
            height: 1080,
            fx: 1100.0,
            fy: 1105.0,
            cx: 955.3,
            cy: 541.7,
            skew: 0.0,
            distortion: Distortion {
                k1: -0.28,
                k2: 0.09,
                p1: 0.0012,
                p2: -0.0007,
                k3: -0.012,
                ..Default::default()
            },
        }
    }

    #[test]
    fn distortion_round_trip_over_the_whole_image_within_1e6_px() {
        let cams = [
            wide(),
            Camera {
                distortion: Distortion {
                    k1: 0.12,
                    k2: -0.05,
                    p1: -0.002,
                    p2: 0.001,
                    k3: 0.01,
                    k4: 0.05,
                    k5: 0.0,
                    k6: 0.01,
                },
                ..wide()
            },
        ];
        for cam in &cams {
            let mut worst: f64 = 0.0;
            for v in (0..cam.height).step_by(7) {
                for u in (0..cam.width).step_by(7) {
                    let (u, v) = (u as f64 + 0.25, v as f64 + 0.75);
                    let [x, y] = cam.normalized_from_pixel(u, v).expect("invertible");
                    let [u2, v2] = cam.pixel_from_normalized(x, y);
                    worst = worst.max((u2 - u).hypot(v2 - v));
                }
            }
            assert!(worst < 1e-6, "worst round trip error {worst} px");
        }
    }

    #[test]
    fn jacobian_matches_finite_differences() {
        let d = Distortion {
            k1: 0.1,
            k2: -0.03,
            p1: 0.001,
            p2: -0.002,
            k3: 0.004,
            k4: 0.02,
            k5: -0.01,
            k6: 0.003,
        };
        let (x, y) = (0.31, -0.22);
        let j = d.jacobian(x, y);
        let h = 1e-7;
        let (a, b) = d.distort(x + h, y);
        let (c, e) = d.distort(x - h, y);
        assert!(((a - c) / (2.0 * h) - j[(0, 0)]).abs() < 1e-6);
        assert!(((b - e) / (2.0 * h) - j[(1, 0)]).abs() < 1e-6);
        let (a, b) = d.distort(x, y + h);
        let (c, e) = d.distort(x, y - h);
        assert!(((a - c) / (2.0 * h) - j[(0, 1)]).abs() < 1e-6);
        assert!(((b - e) / (2.0 * h) - j[(1, 1)]).abs() < 1e-6);
    }

    #[test]
    fn undistort_refuses_the_folded_branch() {
        // k1 < 0 alone folds back at r^2 = -1/(3 k1): beyond it there is no inverse.
        let d = Distortion {
            k1: -0.5,
            ..Default::default()
        };
        let r_fold = (1.0f64 / 1.5).sqrt();
        let rd_max = r_fold * (1.0 - 0.5 * r_fold * r_fold);
        assert!(d.undistort(rd_max * 0.99, 0.0).is_some());
        assert!(d.undistort(rd_max * 1.05, 0.0).is_none());
    }

    #[test]
    fn projection_of_camera_points() {
        let cam = wide();
        let p = Vector3::new(0.4, -0.3, 2.0);
        let px = cam.pixel_from_camera(&p).expect("in front");
        let ray = cam.ray_from_pixel(px[0], px[1]).expect("ray");
        assert!((ray * 2.0 - p).norm() < 1e-9);
        assert!(cam
            .pixel_from_camera(&Vector3::new(0.0, 0.0, -1.0))
            .is_none());
    }
}
