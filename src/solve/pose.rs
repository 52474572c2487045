//! The pose of the hand-held cross projector in one frame, and its two laser planes.
//!
//! Owns the parametrisation the estimator ([`super::estimate`]) works in; knows nothing
//! of crossings or images.
//!
//! A frame's projector is a rotation `R` and a centre `C` (camera coordinates). Laser
//! `k` (0 or 1) is the plane through `C` with unit normal `n_k = R e_k`:
//! `n_k · X = d_k`, `d_k = n_k · C`. The two normals are columns of one rotation, so the
//! planes of a cross are orthogonal by construction (`v_0 · v_1 = 0` for the planes
//! `v_k = n_k / d_k` of `v · X = 1`), and they meet in the projector's axis `R e_2`
//! through `C`. Where `C` lies along that axis no crossing can tell: only the motion of
//! the hand fixes it. The homogeneous form `(n, d)` stays finite for a sheet through the
//! camera centre (`d = 0`), where `v` does not.
//!
//! Updates are left-multiplicative: `R ← exp([δθ]×) R`, `C ← C + δC`; the six local
//! parameters of a pose are `(δθ, δC)`, in that order. Then `δn_k = δθ × n_k` and
//! `δd_k = δθ · (n_k × C) + n_k · δC`.

use nalgebra::{Matrix3, Rotation3, Vector3};

type V3 = Vector3<f64>;

/// Local parameters of one pose.
pub const POSE_DOF: usize = 6;

/// The projector of one frame: rotation (columns: the two laser normals and the axis)
/// and centre, camera coordinates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CrossPose {
    pub rotation: Matrix3<f64>,
    pub centre: V3,
}

/// A homogeneous laser plane `n · X = d` (unit `n`) and its derivatives with respect to
/// the pose's local parameters `(δθ, δC)`.
#[derive(Clone, Copy, Debug)]
pub struct PlaneLinearisation {
    pub n: V3,
    pub d: f64,
    /// `∂n/∂δθ = −[n]×` (`∂n/∂δC = 0`).
    pub dn_dtheta: Matrix3<f64>,
    /// `∂d/∂δθ = (n × C)ᵀ`, as a vector.
    pub dd_dtheta: V3,
    /// `∂d/∂δC = nᵀ`, as a vector.
    pub dd_dcentre: V3,
}

impl CrossPose {
    /// Unit normal of laser `k`'s plane.
    pub fn normal(&self, laser: usize) -> V3 {
        self.rotation.column(laser.min(1)).into_owned()
    }

    /// Unit axis of the projector, where its two planes meet.
    pub fn axis(&self) -> V3 {
        self.rotation.column(2).into_owned()
    }

    /// Laser `k`'s plane as `v` with `v · X = 1`; `None` for a plane through the camera
    /// centre (to rounding).
    pub fn plane(&self, laser: usize) -> Option<V3> {
        let n = self.normal(laser);
        let d = n.dot(&self.centre);
        (d.abs() > 1e-12 * self.centre.norm().max(1e-300)).then(|| n / d)
    }

    /// Laser `k`'s plane `n · X = d` with its derivatives.
    pub fn linearise(&self, laser: usize) -> PlaneLinearisation {
        let n = self.normal(laser);
        PlaneLinearisation {
            n,
            d: n.dot(&self.centre),
            dn_dtheta: -n.cross_matrix(),
            dd_dtheta: n.cross(&self.centre),
            dd_dcentre: n,
        }
    }

    /// Applies the local update `delta = (δθ, δC)`.
    pub fn retract(&mut self, delta: &[f64]) {
        let theta = V3::new(delta[0], delta[1], delta[2]);
        let r = Rotation3::new(theta).into_inner() * self.rotation;
        // Re-orthonormalise against the drift of many small products.
        let mut r = Rotation3::from_matrix_unchecked(r);
        r.renormalize();
        self.rotation = r.into_inner();
        self.centre += V3::new(delta[3], delta[4], delta[5]);
    }

    /// The pose whose laser `k` lies on `planes[k]` where given (`v · X = 1`), the two
    /// normals made orthogonal (each turned by half their departure from 90°), and
    /// whose centre is the point of the axis nearest `centre_hint`. With one plane, the
    /// other normal is `other_normal_hint` made orthogonal to it, and the centre is the
    /// hint's foot on the plane. `None` without any plane, or for normals (nearly)
    /// parallel.
    pub fn from_planes(
        planes: [Option<V3>; 2],
        centre_hint: V3,
        other_normal_hint: Option<V3>,
    ) -> Option<CrossPose> {
        let unit = |v: V3| {
            let l = v.norm();
            (l.is_finite() && l > 0.0).then(|| (v / l, 1.0 / l))
        };
        match planes {
            [Some(a), Some(b)] => {
                let ((n0, d0), (n1, d1)) = (unit(a)?, unit(b)?);
                let (n0, n1) = orthogonalise(n0, n1)?;
                let axis = n0.cross(&n1);
                // The axis: n0·X = d0, n1·X = d1; its point nearest the hint.
                let on_axis = n0 * d0 + n1 * d1;
                let centre = on_axis + axis * axis.dot(&(centre_hint - on_axis));
                Some(CrossPose {
                    rotation: Matrix3::from_columns(&[n0, n1, axis]),
                    centre,
                })
            }
            [Some(_), None] | [None, Some(_)] => {
                let k = usize::from(planes[0].is_none());
                let (n, d) = unit(planes[k]?)?;
                let hint = other_normal_hint.unwrap_or_else(|| any_orthogonal(&n));
                let mut other = hint - n * n.dot(&hint);
                if other.norm() < 1e-6 {
                    other = any_orthogonal(&n);
                }
                let other = other.normalize();
                let (n0, n1) = if k == 0 { (n, other) } else { (other, n) };
                let centre = centre_hint + n * (d - n.dot(&centre_hint));
                Some(CrossPose {
                    rotation: Matrix3::from_columns(&[n0, n1, n0.cross(&n1)]),
                    centre,
                })
            }
            [None, None] => None,
        }
    }

    /// The same planes with laser `k`'s normal (and offset) negated where that brings
    /// the normal closer to `reference`'s: the sign of a normal is free, but the motion
    /// terms compare rotations of consecutive frames, which must not flip.
    pub fn aligned_to(&self, reference: &CrossPose) -> CrossPose {
        let mut n0 = self.normal(0);
        let mut n1 = self.normal(1);
        if n0.dot(&reference.normal(0)) < 0.0 {
            n0 = -n0;
        }
        if n1.dot(&reference.normal(1)) < 0.0 {
            n1 = -n1;
        }
        CrossPose {
            rotation: Matrix3::from_columns(&[n0, n1, n0.cross(&n1)]),
            centre: self.centre,
        }
    }
}

/// Two unit vectors made orthogonal symmetrically: each turned by half the departure
/// from 90° within their common plane. `None` when (nearly) parallel.
fn orthogonalise(a: V3, b: V3) -> Option<(V3, V3)> {
    let s = (a + b).normalize();
    let t = a - b;
    if !(t.norm() > 1e-9 && (a + b).norm() > 1e-9) {
        return None;
    }
    let t = (t - s * s.dot(&t)).normalize();
    let h = std::f64::consts::FRAC_1_SQRT_2;
    Some(((s + t) * h, (s - t) * h))
}

/// Some unit vector orthogonal to the unit `n`.
fn any_orthogonal(n: &V3) -> V3 {
    let pick = if n.x.abs() < 0.9 { V3::x() } else { V3::y() };
    (pick - n * n.dot(&pick)).normalize()
}

/// `log(R)` of a rotation matrix, as the rotation vector: the angle from `atan2` of the
/// sine and cosine parts, so that rounding near the identity (a trace a hair over 3,
/// where `acos` gives NaN) and near a half turn stay finite.
pub fn log_rotation(r: &Matrix3<f64>) -> V3 {
    let v = V3::new(
        r[(2, 1)] - r[(1, 2)],
        r[(0, 2)] - r[(2, 0)],
        r[(1, 0)] - r[(0, 1)],
    ) * 0.5;
    let sin = v.norm();
    let cos = 0.5 * (r.trace() - 1.0);
    let theta = sin.atan2(cos);
    if sin < 1e-9 {
        if cos > 0.0 {
            // θ ≈ sin θ: first order is exact to rounding.
            return v;
        }
        // A half turn: the axis is the column of (R + I) / 2 of largest norm.
        let s = (r + Matrix3::identity()) * 0.5;
        let col = (0..3)
            .map(|i| s.column(i).into_owned())
            .max_by(|a, b| a.norm().total_cmp(&b.norm()))
            .unwrap_or_else(V3::x);
        return col.normalize() * theta;
    }
    v * (theta / sin)
}

/// Inverse of the left Jacobian of SO(3) at `omega`: `log(exp(ε) exp(ω)) ≈ ω +
/// J_l⁻¹(ω) ε` for small `ε`. In the cotangent form, finite up to a half turn.
pub fn left_jacobian_inverse(omega: &V3) -> Matrix3<f64> {
    let theta = omega.norm();
    let w = omega.cross_matrix();
    if theta < 1e-6 {
        return Matrix3::identity() - 0.5 * w + (1.0 / 12.0) * w * w;
    }
    let half = 0.5 * theta;
    let coef = (1.0 - half * half.cos() / half.sin()) / (theta * theta);
    Matrix3::identity() - 0.5 * w + coef * w * w
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pose() -> CrossPose {
        let r = Rotation3::from_euler_angles(0.3, -0.7, 1.1).into_inner();
        CrossPose {
            rotation: r,
            centre: V3::new(0.4, -0.2, 0.1),
        }
    }

    #[test]
    fn the_two_planes_are_orthogonal_and_pass_through_the_centre() {
        let p = pose();
        let (v0, v1) = (p.plane(0).expect("plane"), p.plane(1).expect("plane"));
        assert!(v0.dot(&v1).abs() < 1e-12);
        assert!((v0.dot(&p.centre) - 1.0).abs() < 1e-12);
        assert!((v1.dot(&p.centre) - 1.0).abs() < 1e-12);
        // Any point of the axis through the centre is on both.
        let x = p.centre + 2.5 * p.axis();
        assert!((v0.dot(&x) - 1.0).abs() < 1e-12 && (v1.dot(&x) - 1.0).abs() < 1e-12);
    }

    #[test]
    fn the_linearisation_matches_finite_differences() {
        let p = pose();
        for laser in 0..2 {
            let lin = p.linearise(laser);
            for j in 0..6 {
                let h = 1e-7;
                let mut delta = [0.0; 6];
                delta[j] = h;
                let mut q = p;
                q.retract(&delta);
                let dn = (q.normal(laser) - lin.n) / h;
                let dd = (q.normal(laser).dot(&q.centre) - lin.d) / h;
                let (want_dn, want_dd) = if j < 3 {
                    (lin.dn_dtheta.column(j).into_owned(), lin.dd_dtheta[j])
                } else {
                    (V3::zeros(), lin.dd_dcentre[j - 3])
                };
                assert!(
                    (dn - want_dn).norm() < 1e-5,
                    "laser {laser} param {j}: {dn} vs {want_dn}"
                );
                assert!(
                    (dd - want_dd).abs() < 1e-5,
                    "laser {laser} param {j}: {dd} vs {want_dd}"
                );
            }
        }
    }

    #[test]
    fn a_pose_is_recovered_from_its_planes() {
        let p = pose();
        let hint = p.centre + 0.3 * p.axis() + V3::new(0.01, 0.02, -0.01);
        let q = CrossPose::from_planes([p.plane(0), p.plane(1)], hint, None).expect("pose");
        for k in 0..2 {
            let (a, b) = (p.plane(k).expect("plane"), q.plane(k).expect("plane"));
            assert!((a - b).norm() < 1e-12 * a.norm());
        }
        // The centre is on the axis, nearest the hint.
        let off = q.centre - p.centre;
        assert!(off.cross(&p.axis()).norm() < 1e-12);
        // Slightly non-orthogonal planes are turned by half the departure each.
        let tilt = Rotation3::new(p.axis() * 0.01).into_inner();
        let v1 = tilt * p.normal(1) / p.normal(1).dot(&p.centre);
        let q = CrossPose::from_planes([p.plane(0), Some(v1)], p.centre, None).expect("pose");
        let turned = q.normal(0).angle(&p.normal(0));
        assert!((turned - 0.005).abs() < 1e-6, "{turned}");
    }

    #[test]
    fn one_plane_takes_the_other_normal_from_the_hint() {
        let p = pose();
        let q = CrossPose::from_planes(
            [None, p.plane(1)],
            p.centre + V3::new(0.05, 0.0, 0.0),
            Some(p.normal(0) + V3::new(0.0, 0.01, 0.0)),
        )
        .expect("pose");
        let (a, b) = (p.plane(1).expect("plane"), q.plane(1).expect("plane"));
        assert!((a - b).norm() < 1e-12 * a.norm());
        assert!(q.normal(0).angle(&p.normal(0)) < 0.02);
    }

    #[test]
    fn the_log_is_finite_and_right_near_the_identity_and_a_half_turn() {
        for angle in [0.0, 1e-12, 1e-7, 0.3, 2.0, std::f64::consts::PI - 1e-10] {
            let axis = V3::new(0.3, -0.5, 0.8).normalize();
            let r = Rotation3::new(axis * angle).into_inner();
            // A rotation a hair off orthonormal, as products of many leave it.
            let r = r * (1.0 + 1e-15);
            let w = log_rotation(&r);
            assert!(w.iter().all(|x| x.is_finite()), "{angle}: {w}");
            let back = Rotation3::new(w).into_inner();
            assert!((back - r).norm() < 1e-9, "{angle}: {w}");
        }
    }

    #[test]
    fn the_left_jacobian_inverse_linearises_the_log() {
        let omega = V3::new(0.2, -0.4, 0.3);
        let eps = V3::new(1e-6, -2e-6, 0.5e-6);
        let r = Rotation3::new(eps).into_inner() * Rotation3::new(omega).into_inner();
        let got = log_rotation(&r) - omega;
        let want = left_jacobian_inverse(&omega) * eps;
        assert!((got - want).norm() < 1e-10, "{got} vs {want}");
    }
}
