//! The cloud of a scan: every curve point on its plane, where the plane determines it.
//!
//! Owns the rule that decides which points a plane may give: a point is triangulated
//! only where one standard deviation of its relative depth, from the estimator's own
//! covariance, is at most `[triangulate] max_depth_sigma`. A plane fixed by crossings on
//! one line of a flat wall is known there and nowhere else: its points on that wall are
//! kept, its stretch onto the next surface is not. Before that, the crossing check of
//! [`crate::cloud::check_crossings`] leaves out curves (and stretches) that the curves
//! they cross disagree with; after it, [`crate::cloud::push_curve`] the grazing rays and
//! curve ends.
//!
//! With an estimated focal scale the rays are the corrected ones
//! ([`crate::solve::evidence::RayModel`]), and the cloud is in the true camera's frame.

use image::RgbImage;
use nalgebra::Vector3;
use rayon::prelude::*;

use super::{Planes, Record};
use crate::cloud::{self, CurvePoints, TriangulateStats};
use crate::config::Config;
use crate::ply::Cloud;
use crate::solve::evidence::Ray;

type V3 = Vector3<f64>;

/// A scan's cloud before scaling, and what was left out.
pub(crate) struct CloudOut {
    pub cloud: Cloud,
    /// Distorted pixel of every point.
    pub pixels: Vec<[f32; 2]>,
    pub stats: TriangulateStats,
    /// The rule: the largest relative depth deviation a point may have.
    pub max_depth_sigma: f64,
    /// Points left out because their plane does not determine their depth to
    /// `max_depth_sigma`.
    pub undetermined_points: usize,
    /// Per plane: its plane in the cloud's frame (before scaling), where it gave points
    /// or could have.
    pub planes: Vec<Option<V3>>,
    /// Planes with at least one point in the cloud.
    pub planes_with_points: usize,
}

/// How plane `i` triangulates: its plane on corrected rays, and how to get a point's
/// ray and the point's depth deviation.
struct PlaneRule<'a> {
    planes: &'a Planes<'a>,
}

impl PlaneRule<'_> {
    /// Plane `i` on the corrected rays, if it has one.
    fn plane(&self, i: usize) -> Option<V3> {
        match self.planes {
            Planes::Known(v) => v.get(i).copied().flatten(),
            Planes::Calibrated {
                calibration,
                plane_index,
                placed,
            } => match placed.as_ref().and_then(|p| p.laser_of(i)) {
                Some((fit, laser)) => fit.plane(laser),
                None => calibration.plane((*plane_index.get(i)?)? as usize),
            },
        }
    }

    /// The corrected ray of the undistorted normalised point `u`.
    fn ray(&self, u: [f64; 2]) -> Option<Ray> {
        match self.planes {
            Planes::Known(_) => Some(Ray {
                r: V3::new(u[0], u[1], 1.0),
                dr_dscale: V3::zeros(),
            }),
            Planes::Calibrated { calibration, .. } => calibration.ray(u),
        }
    }

    /// Whether points get a depth deviation (self-calibrated planes do).
    fn has_sigmas(&self) -> bool {
        matches!(self.planes, Planes::Calibrated { .. })
    }

    /// Whether the focal scale moves rays (otherwise a ray is its point).
    fn moves_rays(&self) -> bool {
        match self.planes {
            Planes::Known(_) => false,
            Planes::Calibrated { calibration, .. } => calibration.estimate.focal_scale != 1.0,
        }
    }

    /// One standard deviation of the relative depth along `ray` on plane `i` (0 for known
    /// planes).
    fn depth_sigma(&self, i: usize, ray: &Ray) -> f64 {
        match self.planes {
            Planes::Known(_) => 0.0,
            Planes::Calibrated {
                calibration,
                plane_index,
                placed,
            } => match placed.as_ref().and_then(|p| p.laser_of(i)) {
                Some((fit, laser)) => fit.depth_sigma(laser, ray),
                None => match plane_index.get(i).copied().flatten() {
                    Some(k) => calibration.depth_sigma(k as usize, ray),
                    None => f64::INFINITY,
                },
            },
        }
    }
}

/// The cloud of `scan`'s planes `only` on `planes` (see the module docs), its
/// crossing check on `curve_crossings`.
pub(crate) fn cloud(
    scan: &Record,
    planes: &Planes,
    only: std::ops::Range<usize>,
    curve_crossings: &[cloud::CurveCrossing],
    faint: &[bool],
    colour_source: Option<&RgbImage>,
    config: &Config,
) -> CloudOut {
    let rule = PlaneRule { planes };
    let params = &config.triangulate;
    // The planes that matter: those triangulated and those their crossings are with (a
    // frame placed live needs a few of the scan's thousands).
    let mut needed = vec![false; scan.planes().len()];
    needed[only.clone()].fill(true);
    for c in curve_crossings {
        for cid in [c.a, c.b] {
            needed[scan.curve_plane[cid as usize] as usize] = true;
        }
    }
    let plane_of: Vec<Option<V3>> = needed
        .iter()
        .enumerate()
        .map(|(i, &n)| n.then(|| rule.plane(i)).flatten())
        .collect();
    // The crossing check on the corrected rays.
    let curve_planes: Vec<Option<V3>> = scan
        .curve_plane
        .iter()
        .map(|&p| plane_of[p as usize])
        .collect();
    let moved: Vec<cloud::CurveCrossing>;
    let checked = if rule.moves_rays() {
        moved = curve_crossings
            .iter()
            .map(|c| {
                let mut c = *c;
                if let Some(ray) = rule.ray(c.u) {
                    c.u = [ray.r.x, ray.r.y];
                }
                c
            })
            .collect();
        &moved[..]
    } else {
        curve_crossings
    };
    let check = cloud::check_crossings(&curve_planes, checked, faint, params);
    // Global curve ids of each plane's first curve.
    let mut first = Vec::with_capacity(scan.planes().len());
    let mut next = 0usize;
    for p in scan.planes() {
        first.push(next);
        next += p.curves.len();
    }
    let max_sigma = params.max_depth_sigma;
    let parts: Vec<(Cloud, Vec<[f32; 2]>, TriangulateStats, usize)> = scan.planes()[only.clone()]
        .par_iter()
        .zip(only)
        .map(|(plane, id)| {
            let mut part = Cloud {
                colors: Some(Vec::new()),
                frames: Some(Vec::new()),
                lasers: Some(Vec::new()),
                depth_sigmas: rule.has_sigmas().then(Vec::new),
                ..Default::default()
            };
            let mut pixels = Vec::new();
            let mut stats = TriangulateStats::default();
            let mut undetermined = 0usize;
            let Some(v) = plane_of[id] else {
                return (part, pixels, stats, undetermined);
            };
            let (mut points, mut points_px, mut sigmas) = (Vec::new(), Vec::new(), Vec::new());
            for (k, curve) in plane.curves.iter().enumerate() {
                let i = first[id] + k;
                if check.rejected[i] {
                    stats.inconsistent_curves += 1;
                    stats.inconsistent_points += curve.points.len();
                    continue;
                }
                points.clear();
                points_px.clear();
                sigmas.clear();
                for (j, (p, px)) in curve.points.iter().zip(&curve.points_px).enumerate() {
                    if !check.keeps(i, j as u32) {
                        stats.inconsistent_points += 1;
                        continue;
                    }
                    let Some(ray) = rule.ray(*p) else {
                        undetermined += 1;
                        continue;
                    };
                    let sigma = rule.depth_sigma(id, &ray);
                    if sigma > max_sigma {
                        undetermined += 1;
                        continue;
                    }
                    points.push([ray.r.x, ray.r.y]);
                    points_px.push(*px);
                    sigmas.push(sigma as f32);
                }
                stats.add(&cloud::push_curve(
                    &mut part,
                    Some(&mut pixels),
                    &v,
                    CurvePoints {
                        frame: plane.frame,
                        laser: plane.laser,
                        points: &points,
                        points_px: &points_px,
                        depth_sigmas: Some(&sigmas),
                    },
                    colour_source,
                    params,
                ));
            }
            (part, pixels, stats, undetermined)
        })
        .collect();
    let mut out = CloudOut {
        cloud: Cloud {
            colors: Some(Vec::new()),
            frames: Some(Vec::new()),
            lasers: Some(Vec::new()),
            depth_sigmas: rule.has_sigmas().then(Vec::new),
            ..Default::default()
        },
        pixels: Vec::new(),
        stats: TriangulateStats::default(),
        max_depth_sigma: max_sigma,
        undetermined_points: 0,
        planes: plane_of,
        planes_with_points: 0,
    };
    // Room for every point at once: extended part by part, the 9 M points of the dive
    // were copied again at every doubling.
    let total: usize = parts.iter().map(|p| p.0.points.len()).sum();
    out.cloud.points.reserve_exact(total);
    out.pixels.reserve_exact(total);
    if let Some(v) = out.cloud.frames.as_mut() {
        v.reserve_exact(total);
    }
    if let Some(v) = out.cloud.colors.as_mut() {
        v.reserve_exact(total);
    }
    if let Some(v) = out.cloud.lasers.as_mut() {
        v.reserve_exact(total);
    }
    if let Some(v) = out.cloud.depth_sigmas.as_mut() {
        v.reserve_exact(total);
    }
    for (part, pixels, stats, undetermined) in parts {
        out.planes_with_points += usize::from(!part.points.is_empty());
        out.cloud.points.extend(part.points);
        if let (Some(d), Some(s)) = (out.cloud.frames.as_mut(), part.frames) {
            d.extend(s);
        }
        if let (Some(d), Some(s)) = (out.cloud.colors.as_mut(), part.colors) {
            d.extend(s);
        }
        if let (Some(d), Some(s)) = (out.cloud.lasers.as_mut(), part.lasers) {
            d.extend(s);
        }
        if let (Some(d), Some(s)) = (out.cloud.depth_sigmas.as_mut(), part.depth_sigmas) {
            d.extend(s);
        }
        out.pixels.extend(pixels);
        out.stats.add(&stats);
        out.undetermined_points += undetermined;
    }
    out
}
