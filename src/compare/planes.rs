//! Accuracy per laser plane: groups a cloud's relative depth errors by the plane that
//! triangulated each point (one frame's one laser) and counts the planes whose median
//! error is over a bound, and the points on them.
//!
//! Self-calibration fails plane by plane: a plane placed a few per cent wrong puts all
//! its points off together, while the cloud-wide median may barely move. This module
//! sees only per-point errors and plane labels; computing the errors (and the global
//! scale they are taken after) is [`super::truth`]'s business.

use serde::Serialize;

use super::stats::median_mut;

/// Which plane each point of a cloud lies on: the `frame` and `laser` properties of the
/// PLY that `reconstruct` writes, parallel to the points.
#[derive(Clone, Copy, Debug)]
pub struct PlaneIds<'a> {
    pub frames: &'a [u32],
    pub lasers: &'a [u8],
}

/// How many planes, and how many of their points, are wrong.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PlaneErrors {
    /// Planes with at least one evaluated point.
    pub planes_evaluated: usize,
    /// Evaluated planes whose median relative error is over the bound.
    pub wrong_planes: usize,
    /// Evaluated points on wrong planes.
    pub points_on_wrong_planes: usize,
    /// `points_on_wrong_planes` over all evaluated points (0 when none).
    pub points_on_wrong_planes_fraction: f64,
}

/// Counts wrong planes: `errors[i]` is point `i`'s relative error (`NaN` where it was not
/// evaluated, which leaves the point out), `ids` its plane. A plane is wrong when the
/// median error of its evaluated points is strictly over `wrong_relative`. `None` when
/// the labels are not parallel to `errors`.
pub fn plane_errors(errors: &[f32], ids: PlaneIds, wrong_relative: f64) -> Option<PlaneErrors> {
    if ids.frames.len() != errors.len() || ids.lasers.len() != errors.len() {
        return None;
    }
    // (plane key, error) of the evaluated points, sorted so each plane is one run.
    let mut keyed: Vec<(u64, f64)> = errors
        .iter()
        .zip(ids.frames.iter().zip(ids.lasers))
        .filter(|(e, _)| e.is_finite())
        .map(|(&e, (&frame, &laser))| ((u64::from(frame) << 8) | u64::from(laser), e as f64))
        .collect();
    keyed.sort_unstable_by_key(|&(key, _)| key);
    let evaluated = keyed.len();
    let mut out = PlaneErrors {
        planes_evaluated: 0,
        wrong_planes: 0,
        points_on_wrong_planes: 0,
        points_on_wrong_planes_fraction: 0.0,
    };
    let mut plane: Vec<f64> = Vec::new();
    for run in keyed.chunk_by(|a, b| a.0 == b.0) {
        plane.clear();
        plane.extend(run.iter().map(|&(_, e)| e));
        out.planes_evaluated += 1;
        if median_mut(&mut plane) > wrong_relative {
            out.wrong_planes += 1;
            out.points_on_wrong_planes += run.len();
        }
    }
    if evaluated > 0 {
        out.points_on_wrong_planes_fraction = out.points_on_wrong_planes as f64 / evaluated as f64;
    }
    Some(out)
}

/// How well the cloud's own uncertainty (its `depth_sigma` property, the part of a
/// point's depth deviation that comes from its plane) predicts the planes' errors: a
/// plane's error is the median of its points' signed relative errors (over hundreds of
/// points, each point's own noise averages out of it), and its *z* that error's size
/// over the median deviation its points were given. An honest deviation gives *z* around
/// 0.67 (the median of a Gaussian's absolute value) and rarely over 3.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct UncertaintyCheck {
    pub planes: usize,
    /// Median of the planes' *z*.
    pub median_z: f64,
    /// Planes whose *z* is over 3, and their points' share of the evaluated points.
    pub planes_over_3: usize,
    pub points_on_planes_over_3_fraction: f64,
}

/// The [`UncertaintyCheck`] of the signed relative `errors` (`NaN` where not evaluated)
/// against `sigmas`, per plane of `ids`. `None` when the lengths differ or nothing is
/// evaluated.
pub fn uncertainty_check(
    errors: &[f32],
    sigmas: &[f32],
    ids: PlaneIds,
) -> Option<UncertaintyCheck> {
    let n = errors.len();
    if sigmas.len() != n || ids.frames.len() != n || ids.lasers.len() != n {
        return None;
    }
    let mut keyed: Vec<(u64, f64, f64)> = (0..n)
        .filter(|&i| errors[i].is_finite() && sigmas[i].is_finite() && sigmas[i] > 0.0)
        .map(|i| {
            let key = (u64::from(ids.frames[i]) << 8) | u64::from(ids.lasers[i]);
            (key, errors[i] as f64, sigmas[i] as f64)
        })
        .collect();
    if keyed.is_empty() {
        return None;
    }
    keyed.sort_unstable_by_key(|k| k.0);
    let evaluated = keyed.len();
    let mut zs = Vec::new();
    let (mut planes_over, mut points_over) = (0usize, 0usize);
    let (mut e, mut s) = (Vec::new(), Vec::new());
    for run in keyed.chunk_by(|a, b| a.0 == b.0) {
        e.clear();
        s.clear();
        e.extend(run.iter().map(|k| k.1));
        s.extend(run.iter().map(|k| k.2));
        let z = median_mut(&mut e).abs() / median_mut(&mut s);
        if z > 3.0 {
            planes_over += 1;
            points_over += run.len();
        }
        zs.push(z);
    }
    Some(UncertaintyCheck {
        planes: zs.len(),
        median_z: median_mut(&mut zs),
        planes_over_3: planes_over,
        points_on_planes_over_3_fraction: points_over as f64 / evaluated as f64,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_uncertainty_check_counts_planes_whose_errors_exceed_their_deviations() {
        // Three planes of 4 points: deviations 1 %; errors 0.5 %, −1 %, and 5 % (wrong by
        // five of its own deviations), each point ±2 % around its plane's error.
        let errors: Vec<f32> = [0.005f32, -0.01, 0.05]
            .iter()
            .flat_map(|&e| [e - 0.02, e, e, e + 0.02])
            .collect();
        let sigmas = vec![0.01f32; 12];
        let frames: Vec<u32> = (0..12).map(|i| i / 4).collect();
        let lasers = vec![0u8; 12];
        let ids = PlaneIds {
            frames: &frames,
            lasers: &lasers,
        };
        let c = uncertainty_check(&errors, &sigmas, ids).expect("check");
        assert_eq!(c.planes, 3);
        assert_eq!(c.planes_over_3, 1);
        assert!((c.median_z - 1.0).abs() < 1e-6, "{c:?}");
        assert!((c.points_on_planes_over_3_fraction - 1.0 / 3.0).abs() < 1e-9);
        assert!(uncertainty_check(&errors[..5], &sigmas, ids).is_none());
    }
    use crate::camera::{Camera, Distortion};
    use crate::compare::truth::{
        evaluate_against_truth, evaluate_cloud_against_truth, GroundTruth, TruthError, TruthParams,
    };
    use nalgebra::Vector3;

    /// A wall `z = 2 + 0.4 x` seen by a distorted 320×240 camera; nothing is lit.
    struct Wall {
        camera: Camera,
        lit: Vec<bool>,
    }

    impl Wall {
        fn new() -> Self {
            let camera = Camera {
                width: 320,
                height: 240,
                fx: 280.0,
                fy: 281.0,
                cx: 158.5,
                cy: 121.0,
                skew: 0.0,
                distortion: Distortion {
                    k1: -0.1,
                    k2: 0.02,
                    ..Default::default()
                },
            };
            Self {
                camera,
                lit: vec![false; 320 * 240],
            }
        }
    }

    impl GroundTruth for Wall {
        fn camera(&self) -> &Camera {
            &self.camera
        }

        fn true_depth(&self, ray: &Vector3<f64>) -> Option<f64> {
            // t·ray on z − 0.4 x = 2, for rays below the wall's top edge y = −0.8.
            let t = 2.0 / (ray.z - 0.4 * ray.x);
            (t > 0.0 && t * ray.y >= -0.8).then_some(t * ray.z)
        }

        fn lit_mask(&self) -> &[bool] {
            &self.lit
        }
    }

    #[test]
    fn counts_the_points_on_wrong_planes_of_a_scaled_cloud() {
        // 20 planes, each a column of 40 points (frame k / 2, laser k % 2), and a 21st of
        // rays that meet no surface. A laser plane whose offset is 1/f of the true one
        // puts every depth on it f too far: planes 0..4 are off by ±3 % (wrong), 4..10
        // by ±0.5 % (not), the rest exact; signs alternate so that the fitted global
        // scale stays the true one.
        let truth = Wall::new();
        let scale = 1.25;
        let (mut points, mut frames, mut lasers) = (Vec::new(), Vec::new(), Vec::new());
        for k in 0..20u32 {
            let sign = if k % 2 == 0 { 1.0 } else { -1.0 };
            let factor = match k {
                0..4 => 1.0 + sign * 0.03,
                4..10 => 1.0 + sign * 0.005,
                _ => 1.0,
            };
            for v in 100..140 {
                let ray = truth
                    .camera
                    .ray_from_pixel(10.0 + 15.0 * k as f64, v as f64)
                    .expect("ray");
                let p = ray * (truth.true_depth(&ray).expect("surface") * factor / scale);
                points.push([p.x as f32, p.y as f32, p.z as f32]);
                frames.push(k / 2);
                lasers.push((k % 2) as u8);
            }
        }
        for i in 0..10 {
            points.push([-0.2 + 0.01 * i as f32, -1.5, 1.0]);
            frames.push(10);
            lasers.push(0);
        }
        let ids = PlaneIds {
            frames: &frames,
            lasers: &lasers,
        };
        let params = TruthParams::default();
        let r = evaluate_cloud_against_truth(&points, Some(ids), &truth, &params).expect("eval");
        assert!((r.scale / scale - 1.0).abs() < 1e-4, "scale {}", r.scale);
        assert_eq!((r.evaluated, r.no_surface), (800, 10));
        assert_eq!(r.planes_evaluated, Some(20));
        assert_eq!(r.wrong_planes, Some(4));
        assert_eq!(r.points_on_wrong_planes, Some(160));
        assert_eq!(r.points_on_wrong_planes_fraction, Some(0.2));
        // A bound under 0.5 % also catches the planes off by that much.
        let tight = TruthParams {
            wrong_plane_relative: 0.004,
            ..params.clone()
        };
        let r = evaluate_cloud_against_truth(&points, Some(ids), &truth, &tight).expect("eval");
        assert_eq!(r.wrong_planes, Some(10));
        assert_eq!(r.points_on_wrong_planes, Some(400));
        assert_eq!(r.points_on_wrong_planes_fraction, Some(0.5));
        // Without labels the counts are null in the report.
        let r = evaluate_against_truth(&points, &truth, &params).expect("eval");
        assert_eq!(r.planes_evaluated, None);
        let json = serde_json::to_value(&r).expect("json");
        for key in [
            "planes_evaluated",
            "wrong_planes",
            "points_on_wrong_planes",
            "points_on_wrong_planes_fraction",
        ] {
            assert!(json[key].is_null(), "{key}: {}", json[key]);
        }
        assert_eq!(json["wrong_plane_relative"], 0.02);
        // Labels must be parallel to the points.
        let short = PlaneIds {
            frames: &frames[1..],
            lasers: &lasers,
        };
        assert!(matches!(
            evaluate_cloud_against_truth(&points, Some(short), &truth, &params),
            Err(TruthError::PlaneIdsLength { .. })
        ));
    }

    #[test]
    fn planes_are_judged_by_their_median() {
        // Plane (0, 0): 0.1 % everywhere; (0, 1): 3 %; (1, 0): 3 % on 3 of 5 points (the
        // median is wrong); (1, 1): 3 % on 2 of 5 (it is not); (2, 0): nothing evaluated.
        let mut errors = Vec::new();
        let mut frames = Vec::new();
        let mut lasers = Vec::new();
        let mut add = |frame: u32, laser: u8, values: &[f32]| {
            errors.extend_from_slice(values);
            frames.extend(std::iter::repeat_n(frame, values.len()));
            lasers.extend(std::iter::repeat_n(laser, values.len()));
        };
        add(0, 0, &[0.001; 4]);
        add(0, 1, &[0.03, 0.03, f32::NAN]);
        add(1, 0, &[0.03, 0.0, 0.03, 0.0, 0.03]);
        add(1, 1, &[0.03, 0.0, 0.03, 0.0, 0.0]);
        add(2, 0, &[f32::NAN; 3]);
        let ids = PlaneIds {
            frames: &frames,
            lasers: &lasers,
        };
        let r = plane_errors(&errors, ids, 0.02).expect("parallel labels");
        assert_eq!(r.planes_evaluated, 4);
        assert_eq!(r.wrong_planes, 2);
        assert_eq!(r.points_on_wrong_planes, 2 + 5);
        assert_eq!(r.points_on_wrong_planes_fraction, 7.0 / 16.0);
        // A bound over every median leaves nothing wrong; a bound equal to a median
        // is not exceeded.
        let none = plane_errors(&errors, ids, 0.05).expect("parallel labels");
        assert_eq!((none.wrong_planes, none.points_on_wrong_planes), (0, 0));
        assert_eq!(
            plane_errors(&errors, ids, 0.03).map(|r| r.wrong_planes),
            Some(0)
        );
    }

    #[test]
    fn the_same_frame_with_another_laser_is_another_plane() {
        let errors = [0.03, 0.03, 0.0, 0.0];
        let r = plane_errors(
            &errors,
            PlaneIds {
                frames: &[7, 7, 7, 7],
                lasers: &[1, 1, 0, 0],
            },
            0.02,
        )
        .expect("parallel labels");
        assert_eq!((r.planes_evaluated, r.wrong_planes), (2, 1));
        assert_eq!(r.points_on_wrong_planes_fraction, 0.5);
    }

    #[test]
    fn empty_and_mismatched_labels() {
        let ids = PlaneIds {
            frames: &[],
            lasers: &[],
        };
        let r = plane_errors(&[], ids, 0.02).expect("parallel labels");
        assert_eq!(r.planes_evaluated, 0);
        assert_eq!(r.points_on_wrong_planes_fraction, 0.0);
        let short = PlaneIds {
            frames: &[0],
            lasers: &[0, 0],
        };
        assert_eq!(plane_errors(&[0.0, 0.0], short, 0.02), None);
    }
}
