//! Where the joint estimator ([`super::estimate`]) starts: poses of the projector from
//! planes that a linear solve gave, and first spreads.
//!
//! Owns the turn of planes into poses; the linear solve itself (coplanarity null space,
//! orthogonality over the shift `w`, extension) is [`super::solve`]'s.
//!
//! A pose needs more than its planes: where its centre lies along the axis where the two
//! planes meet, no crossing tells. The hand holds the projector, so the axes of nearby
//! frames pass near one another: the start puts each centre at the point of its axis
//! nearest the least-squares meeting point of the axes of the frames around it. A frame
//! with one plane takes its other normal from the nearest frame with both, and its centre
//! from the neighbours' meeting point, moved onto its plane. A frame with no plane takes
//! the nearest solved frame's pose. Normals are signed so that they turn smoothly from
//! frame to frame (a sheet sweeping through the camera centre flips the sign of `v`).

use nalgebra::{Matrix3, Vector3};

use super::estimate::Spreads;
use super::evidence::Evidence;
use super::pose::{log_rotation, CrossPose};

type V3 = Vector3<f64>;

/// Frames on either side whose axes locate a frame's centre at the start.
const CENTRE_WINDOW_FRAMES: u32 = 15;

/// The start poses for `evidence` from `planes` (per plane, `v · r = 1/Z` on the rays of
/// [`super::evidence::RayModel`]; `None` where unsolved). Also returns per pose whether
/// any of its planes was given. `None` when no plane is given at all.
pub fn poses_from_planes(
    evidence: &Evidence,
    planes: &[Option<V3>],
) -> Option<(Vec<CrossPose>, Vec<bool>)> {
    let by_pose = evidence.planes_of_poses();
    let frames = &evidence.pose_frames;
    let given: Vec<[Option<V3>; 2]> = by_pose
        .iter()
        .map(|slots| slots.map(|s| s.and_then(|i| planes.get(i as usize).copied().flatten())))
        .collect();
    // Axes of the poses with both planes: a point on each and its direction.
    let axes: Vec<Option<(V3, V3)>> = given
        .iter()
        .map(|g| match g {
            [Some(a), Some(b)] => {
                let pose = CrossPose::from_planes([Some(*a), Some(*b)], V3::zeros(), None)?;
                Some((pose.centre, pose.axis()))
            }
            _ => None,
        })
        .collect();
    let all: Vec<(V3, V3)> = axes.iter().flatten().copied().collect();
    let anchor = meeting_point(all.iter(), None).or_else(|| {
        // Parallel axes or none: any given plane's nearest point to the camera.
        given
            .iter()
            .flatten()
            .flatten()
            .next()
            .map(|v| v / v.norm_squared())
    })?;
    let hint = |f: usize| {
        let lo = frames[f].saturating_sub(CENTRE_WINDOW_FRAMES);
        let hi = frames[f] + CENTRE_WINDOW_FRAMES;
        let near = (0..frames.len())
            .filter(|&g| frames[g] >= lo && frames[g] <= hi)
            .filter_map(|g| axes[g].as_ref());
        meeting_point(near, Some(anchor)).unwrap_or(anchor)
    };
    let nearest_both = |f: usize| {
        (0..frames.len())
            .filter(|&g| axes[g].is_some())
            .min_by_key(|&g| frames[g].abs_diff(frames[f]))
    };
    let mut poses: Vec<Option<CrossPose>> = (0..frames.len())
        .map(|f| {
            let other = match given[f] {
                [Some(_), Some(_)] | [None, None] => None,
                [Some(_), None] | [None, Some(_)] => nearest_both(f).and_then(|g| {
                    let k = usize::from(given[f][0].is_some());
                    given[g][k].map(|v| v.normalize())
                }),
            };
            CrossPose::from_planes(given[f], hint(f), other)
        })
        .collect();
    let had: Vec<bool> = poses.iter().map(Option::is_some).collect();
    // Signed to turn smoothly along the placed frames first, so that interpolation
    // between them is between like rotations.
    let placed: Vec<usize> = (0..poses.len()).filter(|&f| had[f]).collect();
    for w in placed.windows(2) {
        if let (Some(prev), Some(next)) = (poses[w[0]], poses[w[1]]) {
            poses[w[1]] = Some(next.aligned_to(&prev));
        }
    }
    // Frames with no plane: between the placed frames around them, by frame index (or
    // carried on from the two nearest on one side): a pose that coincides with a
    // neighbour's would make their crossings meet in no line at all.
    let at = |i: usize| poses[placed[i]].map(|p| (frames[placed[i]] as f64, p));
    let mut filled = poses.clone();
    for f in 0..poses.len() {
        if had[f] {
            continue;
        }
        let after = placed.partition_point(|&g| g < f);
        let (i, j) = match (
            after.checked_sub(1),
            (after < placed.len()).then_some(after),
        ) {
            (Some(b), Some(a)) => (b, a),
            (Some(b), None) if b >= 1 => (b - 1, b),
            (None, Some(a)) if a + 1 < placed.len() => (a, a + 1),
            (Some(b), None) | (None, Some(b)) => (b, b),
            (None, None) => return None,
        };
        let ((ta, pa), (tb, pb)) = (at(i)?, at(j)?);
        let t = if tb > ta {
            (frames[f] as f64 - ta) / (tb - ta)
        } else {
            0.0
        };
        filled[f] = Some(interpolate(&pa, &pb, t));
    }
    let mut out: Vec<CrossPose> = filled.into_iter().flatten().collect();
    for f in 1..out.len() {
        out[f] = out[f].aligned_to(&out[f - 1]);
    }
    Some((out, had))
}

/// The pose a fraction `t` of the way from `a` to `b` (beyond them for `t` outside
/// `[0, 1]`): the rotation along the geodesic, the centre along the line.
pub(super) fn interpolate(a: &CrossPose, b: &CrossPose, t: f64) -> CrossPose {
    let step = log_rotation(&(b.rotation * a.rotation.transpose())) * t;
    let mut pose = CrossPose {
        rotation: nalgebra::Rotation3::new(step).into_inner() * a.rotation,
        centre: a.centre + (b.centre - a.centre) * t,
    };
    // The same pose when a and b coincide: nudge it by a hundredth of a degree, so that
    // its planes are never exactly those of its neighbour.
    if step.norm() < 1e-12 && t != 0.0 {
        pose.retract(&[1.7e-4 * t, 0.0, 0.0, 0.0, 0.0, 0.0]);
    }
    pose
}

/// The least-squares meeting point of lines `(point, unit direction)`, pulled weakly
/// towards `anchor` where given (so that nearly parallel lines still give a point);
/// `None` when the lines do not fix one.
fn meeting_point<'a>(lines: impl Iterator<Item = &'a (V3, V3)>, anchor: Option<V3>) -> Option<V3> {
    let mut a = Matrix3::zeros();
    let mut b = V3::zeros();
    let mut count = 0usize;
    for (p, d) in lines {
        let proj = Matrix3::identity() - d * d.transpose();
        a += proj;
        b += proj * p;
        count += 1;
    }
    if count == 0 {
        return anchor;
    }
    if let Some(x) = anchor {
        let eps = 1e-3 * count as f64;
        a += Matrix3::identity() * eps;
        b += x * eps;
    }
    let eig = a.symmetric_eigen();
    let (lo, hi) = eig
        .eigenvalues
        .iter()
        .fold((f64::INFINITY, 0.0f64), |(lo, hi), &l| {
            (lo.min(l), hi.max(l))
        });
    if lo.is_nan() || lo <= 1e-6 * hi {
        return None;
    }
    a.cholesky().map(|c| c.solve(&b))
}

/// First spreads of the motion terms: the robust spread of the second differences of
/// the start poses (at least `floor` times a typical value), and `crossing_px` for the
/// crossings (faint ones twice that).
pub fn start_spreads(evidence: &Evidence, poses: &[CrossPose], crossing_px: f64) -> Spreads {
    let f = &evidence.pose_frames;
    let mut centre = Vec::new();
    let mut aim = Vec::new();
    let mut roll = Vec::new();
    for i in 2..poses.len() {
        let t = [&poses[i - 2], &poses[i - 1], &poses[i]];
        let (h1, h2) = ((f[i - 1] - f[i - 2]) as f64, (f[i] - f[i - 1]) as f64);
        centre.push(super::terms::centre_motion(t, h1, h2).r.norm());
        let r = super::terms::rotation_motion(t, h1, h2).r;
        aim.push(r.xy().norm());
        roll.push(r.z.abs());
    }
    let scale = super::estimate::centre_scale(poses);
    let spread = |x: Vec<f64>, typical: f64| {
        super::median(x)
            .map(|m| super::MAD_TO_SIGMA * m)
            .unwrap_or(typical)
            .max(1e-3 * typical)
    };
    // Typical steps: a hand moves its centre by a few per cent of its distance, and its
    // aim by about a degree, from frame to frame.
    let typical_turn = 1f64.to_radians();
    Spreads {
        crossing_px: [crossing_px, 2.0 * crossing_px],
        centre: spread(centre, 0.01 * scale),
        aim_rad: spread(aim, typical_turn),
        roll_rad: spread(roll, typical_turn),
    }
}

/// Angle (radians) between two poses' rotations.
pub fn rotation_distance(a: &CrossPose, b: &CrossPose) -> f64 {
    log_rotation(&(a.rotation * b.rotation.transpose())).norm()
}
