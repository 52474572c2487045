//! The residual blocks of the estimator, each with its analytic Jacobian, and the robust
//! losses they are weighed with. Owns the formulas; the estimator
//! ([`super::estimate`]) owns which terms exist and how they are summed.
//!
//! # Crossing (pixels)
//! Planes `a` and `b`, homogeneous `n · X = d`, meet in a 3D line whose image is the
//! line `l = d_b n_a − d_a n_b` (a point `Z r` on both planes has `l · r = 0`). A
//! crossing at the ray `r` must lie on it; its residual is its image distance from that
//! line in pixels, `e = f λ (l · r) / |l_xy|`, with `f λ` the corrected focal length.
//! With `g = ∂e/∂l`: `∂e/∂n_a = d_b g`, `∂e/∂d_a = −g · n_b`, `∂e/∂n_b = −d_a g`,
//! `∂e/∂d_b = g · n_a`, chained through [`super::pose::PlaneLinearisation`].
//!
//! # Motion of the hand (per triple of consecutive poses, frame steps `h₁`, `h₂`)
//! - centre: the divided second difference `D = 2/(h₁+h₂) ((C₂−C₁)/h₂ − (C₁−C₀)/h₁)`,
//!   scaled by `√((h₁+h₂)/2)` so that a white-noise acceleration gives one spread
//!   whatever the gaps (length per frame²);
//! - rotation: the same of the angular velocities `Ω = log(R_{i+1} R_iᵀ) / h`, in the
//!   middle pose's own axes (radians per frame²): about its two laser normals (the aim)
//!   and about its axis (the roll), which a hand moves differently.
//!
//! Neither term copies a neighbour's plane: a pose is pulled towards the smooth path of
//! its neighbours by as much as the measured spread of the hand's motion allows, and the
//! crossings may overrule it.

use nalgebra::{Matrix3, Vector3};

use super::evidence::Ray;
use super::pose::{left_jacobian_inverse, log_rotation, CrossPose, PlaneLinearisation};

type V3 = Vector3<f64>;

/// A crossing's residual and its derivatives with respect to the local parameters of the
/// poses of planes `a` and `b`, and to the focal scale; and how fast the image line turns
/// with those parameters (`ta`, `tb`: `t̂ · ∂n̂/∂p`, `n̂` the line's unit normal, `t̂`
/// its direction), which is what makes the residual's derivatives depend on where along
/// the line the noisy crossing fell (see [`super::estimate`]).
#[derive(Clone, Copy, Debug)]
pub struct CrossingTerm {
    pub e: f64,
    pub ja: [f64; 6],
    pub jb: [f64; 6],
    pub j_scale: f64,
    pub ta: [f64; 6],
    pub tb: [f64; 6],
}

/// Image lines whose direction part is below this share of their norm come from two
/// planes meeting in a line through the camera centre: the crossing says nothing there.
const MIN_LINE_DIRECTION: f64 = 1e-9;

/// The crossing residual of laser `la` of pose `pa` and laser `lb` of pose `pb` at
/// `ray`, in pixels of a camera of focal length `focal_px · lambda`. `None` where the
/// two planes meet in a line through the camera centre.
pub fn crossing(
    pa: &CrossPose,
    la: usize,
    pb: &CrossPose,
    lb: usize,
    ray: &Ray,
    focal_px: f64,
    lambda: f64,
) -> Option<CrossingTerm> {
    crossing_of(&pa.linearise(la), &pb.linearise(lb), ray, focal_px, lambda)
}

/// [`crossing`] of two planes already linearised.
pub fn crossing_of(
    a: &PlaneLinearisation,
    b: &PlaneLinearisation,
    ray: &Ray,
    focal_px: f64,
    lambda: f64,
) -> Option<CrossingTerm> {
    let line = image_line(a, b, ray, focal_px, lambda)?;
    let (l, m) = (line.l, line.m);
    let (ja, jb) = chain(a, b, &line.g);
    // The line's turn: φ = t̂ · l_xy / m with t̂ held, ∂φ/∂l = (t̂, 0) / m.
    let turn = V3::new(-l.y / (m * m), l.x / (m * m), 0.0);
    let (ta, tb) = chain(a, b, &turn);
    let j_scale = line.s / m * l.dot(&ray.dr_dscale) + line.e / lambda;
    Some(CrossingTerm {
        e: line.e,
        ja,
        jb,
        j_scale,
        ta,
        tb,
    })
}

/// The residual of [`crossing_of`] and its derivatives with respect to plane `a`'s pose
/// alone (`e` and `ja`, to the same bits): what a fit of that pose, the other held,
/// needs at every step. A third of the work of the whole term.
pub fn crossing_residual(
    a: &PlaneLinearisation,
    b: &PlaneLinearisation,
    ray: &Ray,
    focal_px: f64,
    lambda: f64,
) -> Option<(f64, [f64; 6])> {
    let line = image_line(a, b, ray, focal_px, lambda)?;
    Some((line.e, chain_first(a, b, &line.g)))
}

/// The residual of [`crossing_of`] alone, to the same bits: what a cost needs.
pub fn crossing_error(
    a: &PlaneLinearisation,
    b: &PlaneLinearisation,
    ray: &Ray,
    focal_px: f64,
    lambda: f64,
) -> Option<f64> {
    image_line(a, b, ray, focal_px, lambda).map(|line| line.e)
}

/// The image line `l` where two planes meet, `m = |l_xy|`, the corrected focal length
/// `s`, the residual `e` at a ray and its gradient `g = ∂e/∂l`.
struct ImageLine {
    l: V3,
    m: f64,
    s: f64,
    e: f64,
    g: V3,
}

fn image_line(
    a: &PlaneLinearisation,
    b: &PlaneLinearisation,
    ray: &Ray,
    focal_px: f64,
    lambda: f64,
) -> Option<ImageLine> {
    let l = a.n * b.d - b.n * a.d;
    let m = l.x.hypot(l.y);
    if m.is_nan() || m <= MIN_LINE_DIRECTION * l.norm() {
        return None;
    }
    let s = focal_px * lambda;
    let r = &ray.r;
    let q = l.dot(r);
    let e = s * q / m;
    let g = V3::new(
        s * (r.x / m - q * l.x / (m * m * m)),
        s * (r.y / m - q * l.y / (m * m * m)),
        s * r.z / m,
    );
    Some(ImageLine { l, m, s, e, g })
}

/// The derivatives of a function of the line `l = d_b n_a − d_a n_b` with gradient `g`
/// (`∂/∂l`) with respect to the local parameters of the poses of planes `a` and `b`:
/// `∂/∂n_a = d_b g`, `∂/∂d_a = −g · n_b`, `∂/∂n_b = −d_a g`, `∂/∂d_b = g · n_a`, then
/// `∂/∂θ = (∂n/∂θ)ᵀ ∂/∂n + ∂/∂d ∂d/∂θ` and `∂/∂C = ∂/∂d ∂d/∂C`.
fn chain(a: &PlaneLinearisation, b: &PlaneLinearisation, g: &V3) -> ([f64; 6], [f64; 6]) {
    let ddb = g.dot(&a.n);
    let tb = b.dn_dtheta.transpose() * (g * (-a.d)) + b.dd_dtheta * ddb;
    let cb = b.dd_dcentre * ddb;
    (chain_first(a, b, g), [tb.x, tb.y, tb.z, cb.x, cb.y, cb.z])
}

/// The first half of [`chain`]: the derivatives with respect to plane `a`'s pose.
fn chain_first(a: &PlaneLinearisation, b: &PlaneLinearisation, g: &V3) -> [f64; 6] {
    let dda = -g.dot(&b.n);
    let ta = a.dn_dtheta.transpose() * (g * b.d) + a.dd_dtheta * dda;
    let ca = a.dd_dcentre * dda;
    [ta.x, ta.y, ta.z, ca.x, ca.y, ca.z]
}

/// A motion residual (3 components) and its 3×3 derivatives with respect to the
/// rotation or centre part of each of the three poses.
#[derive(Clone, Copy, Debug)]
pub struct MotionTerm {
    pub r: V3,
    pub j: [Matrix3<f64>; 3],
}

/// Weights of the divided second difference over steps `h1`, `h2` (see the module
/// docs), times `√((h₁+h₂)/2)`.
fn second_difference_weights(h1: f64, h2: f64) -> [f64; 3] {
    let c = 2.0 / (h1 + h2) * ((h1 + h2) / 2.0).sqrt();
    [c / h1, -c * (1.0 / h1 + 1.0 / h2), c / h2]
}

/// The centre term of three consecutive poses `frames` steps `h1`, `h2` apart
/// (derivatives with respect to each pose's `δC`).
pub fn centre_motion(poses: [&CrossPose; 3], h1: f64, h2: f64) -> MotionTerm {
    let w = second_difference_weights(h1, h2);
    let r = poses[0].centre * w[0] + poses[1].centre * w[1] + poses[2].centre * w[2];
    MotionTerm {
        r,
        j: w.map(|wi| Matrix3::identity() * wi),
    }
}

/// The rotation term of three consecutive poses, in the middle pose's axes (`r.x`,
/// `r.y`: about its laser normals, the aim; `r.z`: about its axis, the roll), with its
/// derivatives with respect to each pose's `δθ`.
pub fn rotation_motion(poses: [&CrossPose; 3], h1: f64, h2: f64) -> MotionTerm {
    let [p0, p1, p2] = poses;
    let m01 = p1.rotation * p0.rotation.transpose();
    let m12 = p2.rotation * p1.rotation.transpose();
    let (w01, w12) = (log_rotation(&m01), log_rotation(&m12));
    let (j01, j12) = (left_jacobian_inverse(&w01), left_jacobian_inverse(&w12));
    let c = 2.0 / (h1 + h2) * ((h1 + h2) / 2.0).sqrt();
    let d = (w12 / h2 - w01 / h1) * c;
    let rt = p1.rotation.transpose();
    // ∂ω₀₁/∂δ₀ = −J⁻¹ M₀₁, ∂ω₀₁/∂δ₁ = J⁻¹; the same for ω₁₂; then into pose 1's
    // axes, whose own turn moves the projection by Rᵀ[D]×.
    let d0 = (j01 * m01) * (c / h1);
    let d1 = -(j12 * m12) * (c / h2) - j01 * (c / h1);
    let d2 = j12 * (c / h2);
    MotionTerm {
        r: rt * d,
        j: [rt * d0, rt * d1 + rt * d.cross_matrix(), rt * d2],
    }
}

/// A robust loss `ρ(x)` of a residual in units of its spread, `ρ(x) ≈ x²` near 0.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Loss {
    /// `c² ln(1 + x²/c²)`: gross outliers fade out (wrong crossings).
    Cauchy(f64),
    /// `x²` within `k`, linear beyond: a convex guard against the odd jerk of the hand.
    Huber(f64),
}

impl Loss {
    /// `ρ(x)`.
    pub fn cost(self, x: f64) -> f64 {
        match self {
            Loss::Cauchy(c) => c * c * (x * x / (c * c)).ln_1p(),
            Loss::Huber(k) => {
                let a = x.abs();
                if a <= k {
                    x * x
                } else {
                    2.0 * k * a - k * k
                }
            }
        }
    }

    /// The weight `ρ'(x) / 2x` of iteratively reweighted least squares.
    pub fn weight(self, x: f64) -> f64 {
        match self {
            Loss::Cauchy(c) => 1.0 / (1.0 + x * x / (c * c)),
            Loss::Huber(k) => {
                let a = x.abs();
                if a <= k {
                    1.0
                } else {
                    k / a
                }
            }
        }
    }
}

/// A sum of [`Loss::cost`] over many residuals, with Cauchy's logarithms taken of
/// products: `Σ c² ln(1 + aᵢ) = c² ln Π(1 + aᵢ)`, one `ln` per [`CostSum::RUN`] terms
/// (or sooner, before the product could overflow). In the fits of single poses the
/// `ln_1p` per crossing was the largest item of a 5,400-frame solve. The sum differs
/// from the term-by-term one in rounding only (`1 + a` drops what of `a` is below
/// 10⁻¹⁶; relative to a cost that is 10⁻¹³ or less).
#[derive(Clone, Copy, Debug)]
pub struct CostSum {
    loss: Loss,
    sum: f64,
    product: f64,
    terms: u32,
}

impl CostSum {
    /// Terms multiplied together before one logarithm.
    const RUN: u32 = 16;
    /// A product past this is taken in at once: one more factor cannot overflow it
    /// unless its own `a` is beyond 10²⁰⁸, a residual of 10¹⁰⁴ spreads.
    const LARGE: f64 = 1e100;

    pub fn new(loss: Loss) -> Self {
        Self {
            loss,
            sum: 0.0,
            product: 1.0,
            terms: 0,
        }
    }

    /// Adds `ρ(x)`.
    pub fn add(&mut self, x: f64) {
        match self.loss {
            Loss::Cauchy(c) => {
                self.product *= 1.0 + x * x / (c * c);
                self.terms += 1;
                if self.terms == Self::RUN || self.product > Self::LARGE {
                    self.sum += self.product.ln();
                    (self.product, self.terms) = (1.0, 0);
                }
            }
            Loss::Huber(_) => self.sum += self.loss.cost(x),
        }
    }

    /// The sum so far.
    pub fn total(&self) -> f64 {
        match self.loss {
            Loss::Cauchy(c) => c * c * (self.sum + self.product.ln()),
            Loss::Huber(_) => self.sum,
        }
    }
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;
    use nalgebra::Rotation3;

    /// A pose of a family turned and moved with `seed` (also the fits' tests').
    pub(in crate::solve) fn pose(seed: f64) -> CrossPose {
        CrossPose {
            rotation: Rotation3::from_euler_angles(0.3 + seed, -0.7 * seed, 1.1).into_inner(),
            centre: V3::new(0.4 + 0.1 * seed, -0.2, 0.1 * seed),
        }
    }

    fn perturbed(p: &CrossPose, j: usize, h: f64) -> CrossPose {
        let mut d = [0.0; 6];
        d[j] = h;
        let mut q = *p;
        q.retract(&d);
        q
    }

    /// The sum of Cauchy's costs by products is the term-by-term sum to rounding,
    /// from residuals of a thousandth of a spread to 10⁸ spreads (products that would
    /// overflow without the early logarithm), and Huber's is the same sum.
    #[test]
    fn a_cost_summed_by_products_is_the_sum_of_the_costs() {
        let mut rng = crate::rng::SplitMix64::new(11);
        for loss in [Loss::Cauchy(3.0), Loss::Cauchy(0.5), Loss::Huber(2.0)] {
            for n in [0usize, 1, 15, 16, 17, 200, 5000] {
                let xs: Vec<f64> = (0..n)
                    .map(|_| {
                        let magnitude = 10f64.powf(-3.0 + 11.0 * rng.next_f64());
                        if rng.next_f64() < 0.5 {
                            -magnitude
                        } else {
                            magnitude
                        }
                    })
                    .collect();
                let mut sum = CostSum::new(loss);
                xs.iter().for_each(|&x| sum.add(x));
                let direct: f64 = xs.iter().map(|&x| loss.cost(x)).sum();
                let total = sum.total();
                assert!(total.is_finite(), "{loss:?} over {n}: {total}");
                assert!(
                    (total - direct).abs() <= 1e-12 * direct,
                    "{loss:?} over {n}: {total} against {direct}"
                );
            }
        }
        let mut sum = CostSum::new(Loss::Cauchy(3.0));
        sum.add(f64::INFINITY);
        assert_eq!(sum.total(), f64::INFINITY);
    }

    /// The fits of one pose take the residual and its first half of derivatives alone;
    /// they must be the whole term's to the bit, or a fit would stop elsewhere.
    #[test]
    fn the_residual_alone_is_the_whole_terms_to_the_bit() {
        for k in 0..50 {
            let s = 0.13 * k as f64;
            let (pa, pb) = (pose(s), pose(0.4 - 0.7 * s));
            let ray = Ray {
                r: V3::new(0.12 - 0.01 * s, -0.08 + 0.02 * s, 1.0),
                dr_dscale: V3::new(-0.1, 0.07, 0.0),
            };
            let (la, lb) = (k % 2, (k / 2) % 2);
            let (a, b) = (pa.linearise(la), pb.linearise(lb));
            let whole = crossing(&pa, la, &pb, lb, &ray, 1200.0, 1.1);
            let alone = crossing_residual(&a, &b, &ray, 1200.0, 1.1);
            let error = crossing_error(&a, &b, &ray, 1200.0, 1.1);
            assert_eq!(
                whole.map(|t| t.e.to_bits()),
                error.map(f64::to_bits),
                "case {k}"
            );
            match (whole, alone) {
                (Some(t), Some((e, ja))) => {
                    assert_eq!(t.e.to_bits(), e.to_bits(), "case {k}");
                    assert_eq!(t.ja.map(f64::to_bits), ja.map(f64::to_bits), "case {k}");
                }
                (None, None) => {}
                (t, r) => panic!("case {k}: {t:?} against {r:?}"),
            }
        }
    }

    #[test]
    fn the_crossing_jacobian_matches_finite_differences() {
        let (pa, pb) = (pose(0.0), pose(0.4));
        let ray = Ray {
            r: V3::new(0.12, -0.08, 1.0),
            dr_dscale: V3::new(-0.1, 0.07, 0.0),
        };
        let (f, lambda) = (1200.0, 1.1);
        let t = crossing(&pa, 0, &pb, 1, &ray, f, lambda).expect("term");
        let h = 1e-7;
        for j in 0..6 {
            let ea = crossing(&perturbed(&pa, j, h), 0, &pb, 1, &ray, f, lambda)
                .expect("t")
                .e;
            let eb = crossing(&pa, 0, &perturbed(&pb, j, h), 1, &ray, f, lambda)
                .expect("t")
                .e;
            let (na, nb) = ((ea - t.e) / h, (eb - t.e) / h);
            assert!(
                (na - t.ja[j]).abs() < 1e-4 * (1.0 + na.abs()),
                "a {j}: {na} vs {}",
                t.ja[j]
            );
            assert!(
                (nb - t.jb[j]).abs() < 1e-4 * (1.0 + nb.abs()),
                "b {j}: {nb} vs {}",
                t.jb[j]
            );
        }
        // The line's turn: the angle of its normal, by finite differences.
        let angle = |pa: &CrossPose, pb: &CrossPose| {
            let (a, b) = (pa.linearise(0), pb.linearise(1));
            let l = a.n * b.d - b.n * a.d;
            l.y.atan2(l.x)
        };
        for j in 0..6 {
            let na = (angle(&perturbed(&pa, j, h), &pb) - angle(&pa, &pb)) / h;
            let nb = (angle(&pa, &perturbed(&pb, j, h)) - angle(&pa, &pb)) / h;
            assert!(
                (na - t.ta[j]).abs() < 1e-4 * (1.0 + na.abs()),
                "turn a {j}: {na} vs {}",
                t.ta[j]
            );
            assert!(
                (nb - t.tb[j]).abs() < 1e-4 * (1.0 + nb.abs()),
                "turn b {j}: {nb} vs {}",
                t.tb[j]
            );
        }
        let moved = Ray {
            r: ray.r + ray.dr_dscale * h,
            ..ray
        };
        let es = crossing(&pa, 0, &pb, 1, &moved, f, lambda + h)
            .expect("t")
            .e;
        let ns = (es - t.e) / h;
        assert!(
            (ns - t.j_scale).abs() < 1e-4 * (1.0 + ns.abs()),
            "{ns} vs {}",
            t.j_scale
        );
    }

    #[test]
    fn a_crossing_on_both_planes_has_no_residual() {
        let (pa, pb) = (pose(0.0), pose(0.4));
        let (va, vb) = (pa.plane(0).expect("plane"), pb.plane(1).expect("plane"));
        // A point on both planes: the intersection line's point in their span.
        let g = nalgebra::Matrix2::new(va.dot(&va), va.dot(&vb), va.dot(&vb), vb.dot(&vb));
        let ab = g
            .lu()
            .solve(&nalgebra::Vector2::new(1.0, 1.0))
            .expect("solvable");
        let x = va * ab.x + vb * ab.y + va.cross(&vb) * 0.3;
        let ray = Ray {
            r: x / x.z,
            dr_dscale: V3::zeros(),
        };
        let t = crossing(&pa, 0, &pb, 1, &ray, 1000.0, 1.0).expect("term");
        assert!(t.e.abs() < 1e-9, "{}", t.e);
    }

    #[test]
    fn the_motion_jacobians_match_finite_differences() {
        let poses = [pose(0.0), pose(0.05), pose(0.12)];
        let (h1, h2) = (1.0, 2.0);
        fn refs(p: &[CrossPose; 3]) -> [&CrossPose; 3] {
            [&p[0], &p[1], &p[2]]
        }
        let rot = rotation_motion(refs(&poses), h1, h2);
        let cen = centre_motion(refs(&poses), h1, h2);
        let h = 1e-7;
        for i in 0..3 {
            for j in 0..6 {
                let mut q = poses;
                q[i] = perturbed(&poses[i], j, h);
                let (term, base) = if j < 3 {
                    (rotation_motion(refs(&q), h1, h2), &rot)
                } else {
                    (centre_motion(refs(&q), h1, h2), &cen)
                };
                let numeric = (term.r - base.r) / h;
                let analytic = base.j[i].column(j % 3).into_owned();
                assert!(
                    (numeric - analytic).norm() < 1e-5 * (1.0 + numeric.norm()),
                    "pose {i} param {j}: {numeric} vs {analytic}"
                );
            }
        }
        // A uniform motion has no second difference, whatever the steps.
        let step = Rotation3::new(V3::new(0.01, -0.02, 0.015)).into_inner();
        let r0 = poses[0].rotation;
        let uniform = [
            poses[0],
            CrossPose {
                rotation: step * r0,
                centre: poses[0].centre + V3::new(0.01, 0.0, 0.0),
            },
            CrossPose {
                rotation: step * step * step * r0,
                centre: poses[0].centre + V3::new(0.03, 0.0, 0.0),
            },
        ];
        assert!(rotation_motion(refs(&uniform), 1.0, 2.0).r.norm() < 1e-12);
        assert!(centre_motion(refs(&uniform), 1.0, 2.0).r.norm() < 1e-12);
    }

    #[test]
    fn losses_are_quadratic_near_zero_and_weigh_outliers_down() {
        for loss in [Loss::Cauchy(2.0), Loss::Huber(2.0)] {
            assert!((loss.cost(0.1) - 0.01).abs() < 1e-4);
            assert!((loss.weight(0.0) - 1.0).abs() < 1e-12);
            assert!(loss.weight(10.0) < 0.25);
        }
    }
}
