//! Triangulation of curve points on their solved laser planes, the rejection of points
//! that cannot be trusted, colour, and the global scale.
//!
//! A curve point with undistorted normalised coordinates `u = (x, y, 1)` on the plane
//! `v · X = 1` lies at depth `Z = 1 / (v · u)` and position `X = Z · u`. The depth is
//! ill-conditioned where the viewing ray grazes the plane (`v · u → 0` relative to
//! `|v| |u|`), and meaningless where `v · u ≤ 0` (behind the camera); both are rejected
//! here.
//!
//! A curve can also be wrong as a whole while its plane is right: the glow of the laser
//! sheet in water seen edge-on, a reflection, a stray light of the laser's colour. Its
//! points then sit on the plane but not on the surface, and the curves it crosses
//! (which do lie on the surface) disagree with it about the depth at the crossing
//! pixels. [`inconsistent_curves`] finds such curves from the solved planes and the
//! crossings, so that their points are left out.
//!
//! Self-calibration leaves one global scale open; [`ScaleMode`] says how the user fixes
//! it, and [`scale_for`] turns that into a factor.

use image::RgbImage;
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use crate::ply::Cloud;

/// What the triangulation keeps.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TriangulateParams {
    /// Rays closer than this angle to their laser plane are dropped (degrees): their
    /// depth error grows as 1/sin of this angle.
    pub min_ray_plane_angle_deg: f64,
    /// Two crossing curves disagree when the depths their planes give at the crossing
    /// differ by more than this share (0.02 = 2 %).
    pub max_crossing_disagreement: f64,
    /// A curve is left out when at least this many of its crossings disagree and they
    /// outnumber those that agree.
    pub min_disagreeing_crossings: u32,
    /// A disagreement between two kept curves is blamed on the weaker ridge at the
    /// crossing when the other is more than this many times as strong there; closer
    /// strengths leave the blame to how often each curve agrees. 0 never looks at
    /// strength.
    pub blame_strength_ratio: f64,
    /// Points left out at each end of every curve: where a stripe ends (an occlusion,
    /// the edge of a surface, the other laser's stripe) the detector's window mixes
    /// the stripe with what lies beyond, and its last point is the worst localised.
    pub curve_end_points: u32,
    /// A self-calibrated point is kept only where one standard deviation of its relative
    /// depth, from the estimator's covariance of its plane, is at most this (0.003 =
    /// 0.3 %): a plane that its crossings fix along one line of a wall gives its points
    /// on that wall, not its stretch onto the next surface.
    pub max_depth_sigma: f64,
}

impl Default for TriangulateParams {
    fn default() -> Self {
        Self {
            min_ray_plane_angle_deg: 0.1,
            max_crossing_disagreement: 0.02,
            min_disagreeing_crossings: 2,
            blame_strength_ratio: 1.5,
            curve_end_points: 1,
            max_depth_sigma: 0.003,
        }
    }
}

/// Counts of what triangulation rejected.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize)]
pub struct TriangulateStats {
    pub kept: usize,
    pub grazing: usize,
    pub behind_camera: usize,
    /// Curves left out because the curves they cross disagree with them.
    pub inconsistent_curves: usize,
    /// Points left out by the crossing check: of those curves, and the stretches of
    /// other curves nearest a disagreement blamed on them.
    pub inconsistent_points: usize,
    /// Points left out at the curves' ends (`curve_end_points`).
    pub curve_ends: usize,
}

impl TriangulateStats {
    pub fn add(&mut self, other: &TriangulateStats) {
        self.kept += other.kept;
        self.grazing += other.grazing;
        self.behind_camera += other.behind_camera;
        self.inconsistent_curves += other.inconsistent_curves;
        self.inconsistent_points += other.inconsistent_points;
        self.curve_ends += other.curve_ends;
    }
}

/// A crossing of two curves (ids into the caller's list of curves) at the undistorted
/// normalised image point `u`, which is near point `at[0]` of curve `a` and point
/// `at[1]` of curve `b`, where their ridges are `strength[0]` and `strength[1]` strong
/// (0 where not known).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CurveCrossing {
    pub a: u32,
    pub b: u32,
    pub u: [f64; 2],
    pub at: [u32; 2],
    pub strength: [f32; 2],
}

/// What [`check_crossings`] found: curves to leave out whole, and for the others the
/// stretches to leave out.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CrossingCheck {
    /// Per curve: left out whole.
    pub rejected: Vec<bool>,
    /// Per curve: its judged crossings, `(point index, speaks for the curve)`, in point
    /// order. A disagreement speaks against the curve it is blamed on (the one of
    /// the two that agrees less with the rest of its crossings) and for the other.
    pub marks: Vec<Vec<(u32, bool)>>,
}

impl CrossingCheck {
    /// Whether point `k` of curve `i` is kept: not if the curve is rejected, nor if the
    /// nearest judged crossing along the curve (by point index; ties go to the
    /// earlier) speaks against it. Points of curves with no judged crossing are kept.
    pub fn keeps(&self, i: usize, k: u32) -> bool {
        if self.rejected.get(i).copied().unwrap_or(false) {
            return false;
        }
        let Some(marks) = self.marks.get(i).filter(|m| !m.is_empty()) else {
            return true;
        };
        let after = marks.partition_point(|&(at, _)| at < k);
        let before = after.checked_sub(1).map(|j| marks[j]);
        let next = marks.get(after).copied();
        match (before, next) {
            (Some(b), Some(n)) => {
                if k - b.0 <= n.0 - k {
                    b.1
                } else {
                    n.1
                }
            }
            (Some(m), None) | (None, Some(m)) => m.1,
            (None, None) => true,
        }
    }

    /// Whether any point of curve `i` is left out.
    pub fn partial(&self, i: usize) -> bool {
        !self.rejected.get(i).copied().unwrap_or(false)
            && self
                .marks
                .get(i)
                .is_some_and(|m| m.iter().any(|&(_, ok)| !ok))
    }
}

/// [`inconsistent_curves`], then, among the curves kept, each remaining disagreement
/// blamed on one of the two, so that a curve that runs off the surface part of the way
/// (into the glow of its sheet) loses that stretch and keeps the rest. The blame goes to
/// the weaker ridge at the crossing when the other is more than
/// `blame_strength_ratio` times as strong: a stripe on a surface is sharp, the glow of a
/// sheet in the water or a reflection is dim. Otherwise it goes to the curve whose
/// crossings agree less often (both on a tie).
///
/// On the pipes recording, of the disagreements where exactly one of the two curves
/// was off the surface at the crossing, the weaker ridge was the one off in 90 %; how
/// often the curves agree picked it in 66 %.
pub fn check_crossings(
    planes: &[Option<Vector3<f64>>],
    crossings: &[CurveCrossing],
    needs_support: &[bool],
    params: &TriangulateParams,
) -> CrossingCheck {
    let rejected = inconsistent_curves(planes, crossings, needs_support, params);
    let n = planes.len();
    let judged: Vec<(&CurveCrossing, bool)> = crossings
        .iter()
        .filter(|c| {
            let (a, b) = (c.a as usize, c.b as usize);
            a != b && a < n && b < n && !rejected[a] && !rejected[b]
        })
        .filter_map(|c| {
            Some((
                c,
                agrees(planes[c.a as usize]?, planes[c.b as usize]?, c.u, params),
            ))
        })
        .collect();
    let (mut good, mut total) = (vec![0u32; n], vec![0u32; n]);
    for &(c, ok) in &judged {
        for i in [c.a as usize, c.b as usize] {
            total[i] += 1;
            good[i] += u32::from(ok);
        }
    }
    // good_a / total_a < good_b / total_b, without division.
    let less = |a: usize, b: usize| {
        (good[a] as u64 * total[b] as u64) < (good[b] as u64 * total[a] as u64)
    };
    let mut marks: Vec<Vec<(u32, bool)>> = vec![Vec::new(); n];
    for &(c, ok) in &judged {
        let (a, b) = (c.a as usize, c.b as usize);
        let [sa, sb] = c.strength.map(f64::from);
        let ratio = params.blame_strength_ratio;
        let (blame_a, blame_b) = if ok {
            (false, false)
        } else if ratio > 0.0 && sb > ratio * sa {
            (true, false)
        } else if ratio > 0.0 && sa > ratio * sb {
            (false, true)
        } else if less(a, b) {
            (true, false)
        } else if less(b, a) {
            (false, true)
        } else {
            (true, true)
        };
        marks[a].push((c.at[0], !blame_a));
        marks[b].push((c.at[1], !blame_b));
    }
    for m in &mut marks {
        m.sort_unstable();
    }
    CrossingCheck { rejected, marks }
}

/// Whether two solved planes agree about the depth at the crossing `u` (a point behind
/// the camera disagrees).
pub fn agrees(va: Vector3<f64>, vb: Vector3<f64>, u: [f64; 2], params: &TriangulateParams) -> bool {
    let u = Vector3::new(u[0], u[1], 1.0);
    inverse_depths_agree(va.dot(&u), vb.dot(&u), params.max_crossing_disagreement)
}

/// Whether two inverse depths of one ray are both in front of the camera and differ by
/// at most `tolerance` relative to their mean.
pub fn inverse_depths_agree(da: f64, db: f64, tolerance: f64) -> bool {
    da > 0.0 && db > 0.0 && 2.0 * (da - db).abs() <= tolerance * (da + db)
}

/// Which curves to leave out: `planes[i]` is the solved plane of curve `i` (`None` when
/// unsolved). At a crossing both curves see the same ray `u`, so their planes must give
/// the same depth there, `1 / (v_a · u) = 1 / (v_b · u)`; a crossing whose relative
/// depth difference exceeds `max_crossing_disagreement` (or where a plane puts the point
/// behind the camera) is a disagreement.
///
/// A disagreement does not say which of the two curves is wrong. A wrong curve
/// disagrees with most curves it crosses, while each of those disagrees only with it;
/// so curves are removed greedily, the one with the largest excess of disagreements
/// over agreements first, and the counts of its partners updated, until no curve has at
/// least `min_disagreeing_crossings` disagreements outnumbering its agreements. A curve
/// with no judged crossing is kept, nothing speaks against it, unless `needs_support`
/// marks it (a faint curve, which could be glow or a reflection just as well): such a
/// curve must end with at least one agreeing crossing.
pub fn inconsistent_curves(
    planes: &[Option<Vector3<f64>>],
    crossings: &[CurveCrossing],
    needs_support: &[bool],
    params: &TriangulateParams,
) -> Vec<bool> {
    let n = planes.len();
    let mut good = vec![0u32; n];
    let mut bad = vec![0u32; n];
    // Judged crossings per curve: (other curve, agrees).
    let mut judged: Vec<Vec<(u32, bool)>> = vec![Vec::new(); n];
    for c in crossings {
        let (a, b) = (c.a as usize, c.b as usize);
        if a == b || a >= n || b >= n {
            continue;
        }
        let (Some(va), Some(vb)) = (planes[a], planes[b]) else {
            continue;
        };
        let agrees = agrees(va, vb, c.u, params);
        for (i, j) in [(a, b), (b, a)] {
            if agrees {
                good[i] += 1;
            } else {
                bad[i] += 1;
            }
            judged[i].push((j as u32, agrees));
        }
    }
    let min_bad = params.min_disagreeing_crossings.max(1);
    let qualifies = |g: u32, b: u32| b >= min_bad && b > g;
    let key = |g: u32, b: u32| (b as i64 - g as i64, b);
    let mut heap: std::collections::BinaryHeap<((i64, u32), std::cmp::Reverse<u32>)> = (0..n)
        .filter(|&i| qualifies(good[i], bad[i]))
        .map(|i| (key(good[i], bad[i]), std::cmp::Reverse(i as u32)))
        .collect();
    let mut rejected = vec![false; n];
    while let Some((k, std::cmp::Reverse(i))) = heap.pop() {
        let i = i as usize;
        // Stale entries (the counts changed since the push) are skipped; the current
        // key was pushed too.
        if rejected[i] || k != key(good[i], bad[i]) || !qualifies(good[i], bad[i]) {
            continue;
        }
        rejected[i] = true;
        for &(j, agrees) in &judged[i] {
            let j = j as usize;
            if rejected[j] {
                continue;
            }
            if agrees {
                good[j] -= 1;
            } else {
                bad[j] -= 1;
            }
            if qualifies(good[j], bad[j]) {
                heap.push((key(good[j], bad[j]), std::cmp::Reverse(j as u32)));
            }
        }
    }
    for (i, r) in rejected.iter_mut().enumerate() {
        if needs_support.get(i).copied().unwrap_or(false) && good[i] == 0 {
            *r = true;
        }
    }
    rejected
}

/// Where a ray `u = (x, y, 1)` meets the plane `v · X = 1`, or why it is refused.
#[inline]
pub fn triangulate(
    plane: &Vector3<f64>,
    x: f64,
    y: f64,
    min_sin: f64,
) -> Result<Vector3<f64>, Rejection> {
    let u = Vector3::new(x, y, 1.0);
    let dot = plane.dot(&u);
    if dot <= 0.0 {
        return Err(Rejection::BehindCamera);
    }
    if dot < min_sin * plane.norm() * u.norm() {
        return Err(Rejection::Grazing);
    }
    Ok(u / dot)
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Rejection {
    BehindCamera,
    Grazing,
}

/// The points of one extracted curve, as triangulation needs them.
#[derive(Clone, Copy, Debug)]
pub struct CurvePoints<'a> {
    pub frame: u32,
    pub laser: u8,
    /// Undistorted normalised coordinates.
    pub points: &'a [[f64; 2]],
    /// The same points in distorted pixels (for colour).
    pub points_px: &'a [[f32; 2]],
    /// Per point, one standard deviation of its relative depth, kept with the point in
    /// the cloud's `depth_sigmas` when given.
    pub depth_sigmas: Option<&'a [f32]>,
}

/// Appends the points of one curve to `cloud`, coloured from `colour_source` (the
/// laser-free background) at each point's distorted pixel, and each kept point's
/// distorted pixel to `pixels` when given.
pub fn push_curve(
    cloud: &mut Cloud,
    mut pixels: Option<&mut Vec<[f32; 2]>>,
    plane: &Vector3<f64>,
    curve: CurvePoints<'_>,
    colour_source: Option<&RgbImage>,
    params: &TriangulateParams,
) -> TriangulateStats {
    let CurvePoints {
        frame,
        laser,
        points,
        points_px,
        depth_sigmas,
    } = curve;
    let min_sin = params.min_ray_plane_angle_deg.to_radians().sin();
    let mut stats = TriangulateStats::default();
    let (n, trim) = (points.len(), params.curve_end_points as usize);
    let inner = if n > 2 * trim { trim..n - trim } else { 0..0 };
    stats.curve_ends = n - inner.len();
    for (i, &[x, y]) in points.iter().enumerate().take(inner.end).skip(inner.start) {
        match triangulate(plane, x, y, min_sin) {
            Ok(p) => {
                cloud.points.push([p.x as f32, p.y as f32, p.z as f32]);
                let px = points_px.get(i).copied().unwrap_or([f32::NAN; 2]);
                if let Some(pixels) = pixels.as_deref_mut() {
                    pixels.push(px);
                }
                if let Some(colors) = cloud.colors.as_mut() {
                    colors.push(match colour_source {
                        Some(img) if px[0].is_finite() => sample_rgb(img, px[0], px[1]),
                        _ => [255, 255, 255],
                    });
                }
                if let Some(frames) = cloud.frames.as_mut() {
                    frames.push(frame);
                }
                if let Some(lasers) = cloud.lasers.as_mut() {
                    lasers.push(laser);
                }
                if let (Some(out), Some(sigmas)) = (cloud.depth_sigmas.as_mut(), depth_sigmas) {
                    out.push(sigmas.get(i).copied().unwrap_or(f32::NAN));
                }
                stats.kept += 1;
            }
            Err(Rejection::Grazing) => stats.grazing += 1,
            Err(Rejection::BehindCamera) => stats.behind_camera += 1,
        }
    }
    stats
}

/// Bilinear colour at a sub-pixel position (pixel centres at integer coordinates),
/// clamped at the border.
pub fn sample_rgb(img: &RgbImage, u: f32, v: f32) -> [u8; 3] {
    crate::sample::rgb_f32(img, u, v).map(|c| c.round().clamp(0.0, 255.0) as u8)
}

/// How the one global scale that self-calibration cannot know is fixed.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "mode", rename_all = "kebab-case")]
pub enum ScaleMode {
    /// Scale the cloud so that its median depth is 1 (the default; say so in reports).
    MedianDepth,
    /// Multiply the solver's cloud by a factor.
    Factor { factor: f64 },
    /// Two image points (distorted pixels) on the scanned surface are `distance` apart.
    KnownDistance {
        a_px: [f64; 2],
        b_px: [f64; 2],
        distance: f64,
    },
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum ScaleError {
    #[error("the cloud is empty: nothing to scale")]
    Empty,
    #[error("no reconstructed point within {radius_px} px of image point ({u:.1}, {v:.1}); pick a point on a scanned part of the surface")]
    NoPointNear { u: f64, v: f64, radius_px: f64 },
    #[error("the two known-distance points coincide in the cloud")]
    Degenerate,
    #[error("scale factor must be a positive finite number, found {0}")]
    BadFactor(f64),
}

/// The factor that turns the solver's cloud into the user's units.
///
/// `pixels` holds each cloud point's distorted pixel position (needed for
/// [`ScaleMode::KnownDistance`], which takes the median position of the points within a
/// few pixels of each image point).
pub fn scale_for(mode: &ScaleMode, cloud: &Cloud, pixels: &[[f32; 2]]) -> Result<f64, ScaleError> {
    match mode {
        ScaleMode::Factor { factor } => {
            if factor.is_finite() && *factor > 0.0 {
                Ok(*factor)
            } else {
                Err(ScaleError::BadFactor(*factor))
            }
        }
        ScaleMode::MedianDepth => {
            let mut z: Vec<f32> = cloud.points.iter().map(|p| p[2]).collect();
            if z.is_empty() {
                return Err(ScaleError::Empty);
            }
            let mid = z.len() / 2;
            let (_, m, _) = z.select_nth_unstable_by(mid, f32::total_cmp);
            Ok(1.0 / *m as f64)
        }
        ScaleMode::KnownDistance {
            a_px,
            b_px,
            distance,
        } => {
            if !(distance.is_finite() && *distance > 0.0) {
                return Err(ScaleError::BadFactor(*distance));
            }
            let a = point_near(cloud, pixels, *a_px)?;
            let b = point_near(cloud, pixels, *b_px)?;
            let d = (a - b).norm();
            if d <= f64::EPSILON * a.norm().max(1.0) {
                return Err(ScaleError::Degenerate);
            }
            Ok(distance / d)
        }
    }
}

fn point_near(
    cloud: &Cloud,
    pixels: &[[f32; 2]],
    at: [f64; 2],
) -> Result<Vector3<f64>, ScaleError> {
    for radius_px in [2.0, 5.0, 10.0] {
        let mut near: Vec<Vector3<f64>> = pixels
            .iter()
            .zip(&cloud.points)
            .filter(|(px, _)| (px[0] as f64 - at[0]).hypot(px[1] as f64 - at[1]) <= radius_px)
            .map(|(_, p)| Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64))
            .collect();
        if near.len() >= 3 || (radius_px >= 10.0 && !near.is_empty()) {
            // Component-wise median: robust to a stray point of another surface.
            let mut out = Vector3::zeros();
            for k in 0..3 {
                near.sort_by(|a, b| a[k].total_cmp(&b[k]));
                out[k] = near[near.len() / 2][k];
            }
            return Ok(out);
        }
    }
    Err(ScaleError::NoPointNear {
        u: at[0],
        v: at[1],
        radius_px: 10.0,
    })
}

/// Multiplies every point by `factor` (about the camera centre).
pub fn apply_scale(cloud: &mut Cloud, factor: f64) {
    let f = factor as f32;
    for p in &mut cloud.points {
        p[0] *= f;
        p[1] *= f;
        p[2] *= f;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn empty_cloud() -> Cloud {
        Cloud {
            colors: Some(vec![]),
            frames: Some(vec![]),
            lasers: Some(vec![]),
            ..Default::default()
        }
    }

    #[test]
    fn points_land_on_their_plane_at_the_right_depth() {
        // Plane through (0, 0, 2) with normal (0.3, -0.2, 1): v = n / (n . p0).
        let n = Vector3::new(0.3, -0.2, 1.0);
        let v = n / n.dot(&Vector3::new(0.0, 0.0, 2.0));
        for &(x, y) in &[(0.0, 0.0), (0.4, -0.3), (-0.2, 0.25)] {
            let p = triangulate(&v, x, y, 0.0).expect("in front");
            assert!((v.dot(&p) - 1.0).abs() < 1e-12);
            assert!((p.x / p.z - x).abs() < 1e-12 && (p.y / p.z - y).abs() < 1e-12);
        }
        assert_eq!(
            triangulate(&-v, 0.0, 0.0, 0.0),
            Err(Rejection::BehindCamera)
        );
    }

    /// `n` planes of a 1-unit-deep scene, each turned 0.3 rad further about the optical
    /// axis.
    fn fan(n: usize) -> Vec<Option<Vector3<f64>>> {
        (0..n)
            .map(|i| {
                let t = i as f64 * 0.3;
                Some(Vector3::new(t.cos() * 0.4, t.sin() * 0.4, 1.0))
            })
            .collect()
    }

    /// Where the planes of curves `a` and `b` meet on the image row through `x`.
    fn agreeing(planes: &[Option<Vector3<f64>>], a: u32, b: u32, x: f64) -> CurveCrossing {
        let d = planes[a as usize].expect("solved") - planes[b as usize].expect("solved");
        CurveCrossing {
            a,
            b,
            u: [x, -(d.z + d.x * x) / d.y],
            at: [0, 0],
            strength: [0.0; 2],
        }
    }

    #[test]
    fn a_curve_off_its_surface_is_found_by_the_curves_it_crosses() {
        // Six curves on planes of a 1-unit-deep scene; curve 5 is the glow of its sheet
        // in front of the surface: its plane is right, but where it crosses the others
        // its pixels are not where that plane meets theirs.
        let planes: Vec<Option<Vector3<f64>>> = fan(6).into_iter().chain([None]).collect();
        let mut crossings = Vec::new();
        for a in 0..5u32 {
            for b in a + 1..5 {
                crossings.push(agreeing(&planes, a, b, 0.05 * (a + b) as f64 - 0.2));
            }
        }
        for a in 0..5u32 {
            let mut c = agreeing(&planes, a, 5, 0.1 * a as f64 - 0.2);
            c.u[1] += 0.3;
            crossings.push(c);
            // Crossings with an unsolved curve are not judged.
            crossings.push(CurveCrossing {
                a,
                b: 6,
                u: [0.0, 0.0],
                at: [0, 0],
                strength: [0.0; 2],
            });
        }
        let params = TriangulateParams::default();
        let out = inconsistent_curves(&planes, &crossings, &[], &params);
        assert_eq!(out, [false, false, false, false, false, true, false]);
        // A faint curve needs an agreeing crossing: curve 6 has none (its only
        // partners are unsolved... it is unsolved itself), curve 0 has several.
        let mut faint = vec![false; 7];
        faint[0] = true;
        faint[6] = true;
        let out = inconsistent_curves(&planes, &crossings, &faint, &params);
        assert_eq!(out, [false, false, false, false, false, true, true]);

        // Within the tolerance nothing goes; one disagreement alone is not enough.
        let loose = TriangulateParams {
            max_crossing_disagreement: 10.0,
            ..params.clone()
        };
        assert!(!inconsistent_curves(&planes, &crossings, &[], &loose).contains(&true));
        let few: Vec<CurveCrossing> = crossings
            .iter()
            .copied()
            .filter(|c| c.b != 5 || c.a == 0)
            .collect();
        assert!(!inconsistent_curves(&planes, &few, &[], &params).contains(&true));
    }

    /// A disagreement costs the weaker ridge at the crossing its stretch when the other
    /// is clearly stronger there, though the weaker curve agrees more often elsewhere;
    /// with strengths close together, the curve that agrees less often loses it.
    #[test]
    fn a_disagreement_is_blamed_on_the_clearly_weaker_ridge() {
        let planes = fan(5);
        // Curve 0 agrees with 2; curve 1 with 2, 3 and 4; 0 and 1 disagree at point 50
        // of each.
        let mut crossings = vec![
            agreeing(&planes, 0, 2, -0.1),
            agreeing(&planes, 1, 2, 0.0),
            agreeing(&planes, 1, 3, 0.1),
            agreeing(&planes, 1, 4, 0.2),
        ];
        for (c, at) in crossings.iter_mut().zip([10, 10, 90, 95]) {
            c.at = [at, 0];
        }
        let mut bad = agreeing(&planes, 0, 1, 0.05);
        bad.u[1] += 0.3;
        bad.at = [50, 50];
        let blamed = |strength: [f32; 2]| {
            let mut all = crossings.clone();
            all.push(CurveCrossing { strength, ..bad });
            let check = check_crossings(&planes, &all, &[], &TriangulateParams::default());
            assert!(!check.rejected.contains(&true), "{check:?}");
            [!check.keeps(0, 50), !check.keeps(1, 50)]
        };
        assert_eq!(blamed([0.0, 0.0]), [true, false]);
        assert_eq!(blamed([100.0, 80.0]), [true, false]);
        assert_eq!(blamed([100.0, 20.0]), [false, true]);
        assert_eq!(blamed([20.0, 100.0]), [true, false]);
    }

    #[test]
    fn a_curve_that_runs_off_the_surface_loses_that_stretch() {
        // Curves 0..5 on the surface cross each other; curve 5 agrees with 0, 1 and 2
        // near its start (points 10, 20, 30) and runs into the water near its end,
        // where it crosses 3 and 4 (points 80, 90).
        let planes = fan(6);
        let mut crossings = Vec::new();
        for a in 0..5u32 {
            for b in a + 1..5 {
                crossings.push(agreeing(&planes, a, b, 0.05 * (a + b) as f64 - 0.2));
            }
        }
        for (a, at) in [(0u32, 10u32), (1, 20), (2, 30), (3, 80), (4, 90)] {
            let mut c = agreeing(&planes, a, 5, 0.1 * a as f64 - 0.2);
            c.at = [50, at];
            if a >= 3 {
                c.u[0] += 0.6;
            }
            crossings.push(c);
        }
        let check = check_crossings(&planes, &crossings, &[], &TriangulateParams::default());
        assert!(!check.rejected.contains(&true), "{check:?}");
        assert!((0..5).all(|i| !check.partial(i)), "{check:?}");
        assert!(check.partial(5));
        for k in [0, 10, 50, 55] {
            assert!(check.keeps(5, k), "point {k}");
        }
        for k in [56, 80, 85, 200] {
            assert!(!check.keeps(5, k), "point {k}");
        }
        assert!(check.keeps(3, 50) && check.keeps(0, 0));
    }

    #[test]
    fn grazing_rays_are_refused() {
        // A plane containing nearly the ray (1, 0, 1): v = (a, 0, c) with a + c tiny.
        let v = Vector3::new(-1.0, 0.0, 1.0 + 1e-3);
        assert_eq!(
            triangulate(&v, 1.0, 0.0, 3f64.to_radians().sin()),
            Err(Rejection::Grazing)
        );
        assert!(triangulate(&v, -1.0, 0.0, 3f64.to_radians().sin()).is_ok());
    }

    #[test]
    fn push_curve_keeps_attributes_aligned_and_counts_rejections() {
        let v = Vector3::new(0.0, 0.0, 0.5);
        let mut cloud = empty_cloud();
        let img = RgbImage::from_pixel(4, 4, image::Rgb([10, 20, 30]));
        let mut pixels = Vec::new();
        let stats = push_curve(
            &mut cloud,
            Some(&mut pixels),
            &v,
            CurvePoints {
                frame: 7,
                laser: 1,
                points: &[[0.0, 0.0], [0.1, 0.1]],
                points_px: &[[1.0, 1.0], [2.5, 2.5]],
                depth_sigmas: None,
            },
            Some(&img),
            &TriangulateParams {
                curve_end_points: 0,
                ..TriangulateParams::default()
            },
        );
        assert_eq!(stats.kept, 2);
        assert_eq!(pixels, vec![[1.0, 1.0], [2.5, 2.5]]);
        assert_eq!(cloud.points[1], [0.2, 0.2, 2.0]);
        assert_eq!(cloud.colors.as_deref(), Some(&[[10, 20, 30]; 2][..]));
        assert_eq!(cloud.frames.as_deref(), Some(&[7, 7][..]));
        assert_eq!(cloud.lasers.as_deref(), Some(&[1, 1][..]));

        // The default leaves one point out at each end, with its pixel; a curve of
        // two points is all ends.
        let points: Vec<[f64; 2]> = (0..5).map(|i| [0.01 * i as f64, 0.0]).collect();
        let px: Vec<[f32; 2]> = (0..5).map(|i| [i as f32, 0.0]).collect();
        let mut cloud = empty_cloud();
        let mut pixels = Vec::new();
        let params = TriangulateParams::default();
        let curve = |n: usize| CurvePoints {
            frame: 0,
            laser: 0,
            points: &points[..n],
            points_px: &px[..n],
            depth_sigmas: None,
        };
        let stats = push_curve(&mut cloud, Some(&mut pixels), &v, curve(5), None, &params);
        assert_eq!((stats.kept, stats.curve_ends), (3, 2));
        assert_eq!(pixels, vec![[1.0, 0.0], [2.0, 0.0], [3.0, 0.0]]);
        assert_eq!(cloud.points[0], [0.02, 0.0, 2.0]);
        let stats = push_curve(&mut cloud, None, &v, curve(2), None, &params);
        assert_eq!((stats.kept, stats.curve_ends), (0, 2));
    }

    #[test]
    fn scale_modes() {
        let mut cloud = empty_cloud();
        cloud.points = vec![[0.0, 0.0, 2.0], [0.0, 0.0, 4.0], [1.0, 0.0, 8.0]];
        let s = scale_for(&ScaleMode::MedianDepth, &cloud, &[]).expect("median");
        assert!((s - 0.25).abs() < 1e-12);
        // Known distance between the first two points, seen at pixels (10,10), (50,10).
        let pixels = [[10.0, 10.0], [50.0, 10.0], [90.0, 10.0]];
        let s = scale_for(
            &ScaleMode::KnownDistance {
                a_px: [10.5, 10.0],
                b_px: [49.0, 10.5],
                distance: 0.5,
            },
            &cloud,
            &pixels,
        )
        .expect("known distance");
        assert!((s - 0.25).abs() < 1e-12);
        assert!(matches!(
            scale_for(
                &ScaleMode::KnownDistance {
                    a_px: [300.0, 300.0],
                    b_px: [10.0, 10.0],
                    distance: 1.0
                },
                &cloud,
                &pixels
            ),
            Err(ScaleError::NoPointNear { .. })
        ));
        assert_eq!(
            scale_for(&ScaleMode::Factor { factor: -1.0 }, &cloud, &pixels),
            Err(ScaleError::BadFactor(-1.0))
        );
        apply_scale(&mut cloud, 0.5);
        assert_eq!(cloud.points[2], [0.5, 0.0, 4.0]);
    }

    #[test]
    fn bilinear_colour() {
        let mut img = RgbImage::new(2, 1);
        img.put_pixel(0, 0, image::Rgb([0, 100, 200]));
        img.put_pixel(1, 0, image::Rgb([100, 200, 0]));
        assert_eq!(sample_rgb(&img, 0.5, 0.0), [50, 150, 100]);
        assert_eq!(sample_rgb(&img, -3.0, 9.0), [0, 100, 200]);
    }
}
