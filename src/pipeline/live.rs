//! What the live daemon asks of a scan's [`Record`] as it grows: the estimator's evidence so far
//! (an epoch) and the epoch's cloud. The same stages as [`super::reconstruct_scan`], cut where the daemon
//! needs them: nothing here decides anything the offline pipeline does not.

use image::RgbImage;

use super::triangulate::{self, CloudOut};
use super::{is_faint, Fit, Planes, Record};
use crate::camera::Camera;
use crate::config::Config;
use crate::solve::estimate::EstimateParams;
use crate::solve::evidence::Evidence;
use crate::solve::outside::{self, Link, OutsideFit};
use crate::solve::pose::CrossPose;
use crate::solve::Calibration;

impl Record {
    /// The estimator's evidence of the scan so far, and per plane its index in it
    /// (as [`super::reconstruct_scan`] makes them).
    pub fn solve_input(&self, camera: &Camera, config: &Config) -> (Evidence, Vec<Option<u32>>) {
        let curve_crossings = self.curve_crossings();
        let faint = self.faint_curves(config);
        self.evidence(camera, config, curve_crossings, &faint)
    }

    /// The cloud of the scan's planes that `calibration` (made on the evidence of the
    /// first `plane_index.len()` planes) determines, before scaling: the offline
    /// triangulation with its crossing check and depth rule; and the planes' fit against
    /// the extraction's predicted precision, for [`super::refusal`].
    pub(crate) fn epoch_cloud(
        &self,
        calibration: &Calibration,
        plane_index: &[Option<u32>],
        camera: &Camera,
        config: &Config,
        colour: Option<&RgbImage>,
    ) -> (CloudOut, Option<Fit>) {
        let mut index = plane_index.to_vec();
        index.resize(self.planes.len(), None);
        let planes = Planes::Calibrated {
            calibration,
            plane_index: &index,
            placed: None,
        };
        let curve_crossings = self.curve_crossings();
        let faint = self.faint_curves(config);
        let predicted =
            self.predicted_crossing_px(curve_crossings, &faint, config, camera.fx.max(camera.fy));
        let fit = Fit::of(calibration, predicted);
        let all = 0..self.planes.len();
        let out = triangulate::cloud(self, &planes, all, curve_crossings, &faint, colour, config);
        (out, fit)
    }
}

/// A frame placed against a calibration made before it: its planes are the scan's from
/// `first` on, of lasers `lasers`, and `fit` is its pose.
#[derive(Clone, Copy)]
pub(crate) struct Placed<'a> {
    pub first: usize,
    pub lasers: &'a [u8],
    pub fit: &'a OutsideFit,
}

impl Placed<'_> {
    /// The fit and laser of plane `i`, if it is the placed frame's.
    pub(crate) fn laser_of(&self, i: usize) -> Option<(&OutsideFit, usize)> {
        let k = i.checked_sub(self.first)?;
        Some((self.fit, usize::from(*self.lasers.get(k)?)))
    }
}

/// A calibration as the frames after it are placed against it: its joint poses, the
/// frame of each, and the estimator's settings.
pub struct Placing {
    joint: Vec<CrossPose>,
    joint_frames: Vec<u32>,
    params: EstimateParams,
}

impl Placing {
    pub fn new(calibration: &Calibration, config: &Config) -> Self {
        let est = &calibration.estimate;
        let order = outside::joint_order(est);
        Self {
            joint: order.iter().map(|&p| est.poses[p]).collect(),
            joint_frames: order
                .iter()
                .map(|&p| calibration.evidence.pose_frames[p])
                .collect(),
            params: config.solve.estimate_params(),
        }
    }

    /// The joint pose nearest in time to `frame`.
    fn nearest(&self, frame: u32) -> Option<CrossPose> {
        let (j, _) = self
            .joint_frames
            .iter()
            .enumerate()
            .min_by_key(|(_, &f)| f.abs_diff(frame))?;
        self.joint.get(j).copied()
    }
}

impl Record {
    /// The points of frame `frame`, which came after `calibration` (made on the evidence
    /// of the first `plane_index.len()` planes): its pose fitted against the
    /// calibration's joint poses from its crossings with their planes, as the offline
    /// estimate fits every frame outside its anchors ([`crate::solve::outside`]); then
    /// the offline triangulation of its planes, with the same depth rule and the
    /// crossing check on its own crossings. `None` when no pose fits.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn frame_cloud(
        &self,
        frame: usize,
        calibration: &Calibration,
        plane_index: &[Option<u32>],
        placing: &Placing,
        config: &Config,
        colour: Option<&RgbImage>,
    ) -> Option<CloudOut> {
        let end_of = |v: &[u32], total: usize| v.get(frame + 1).map_or(total, |&x| x as usize);
        let first = *self.frame_first_plane.get(frame)? as usize;
        let end = end_of(&self.frame_first_plane, self.planes.len());
        let crossings = self.frame_first_crossing[frame] as usize
            ..end_of(&self.frame_first_crossing, self.crossings.len());
        if first == end || crossings.is_empty() {
            return None;
        }
        let curve_crossings = &self.curve_crossings()[crossings.clone()];
        // Faint where it matters: the curves these crossings are of.
        let mut faint = vec![false; self.num_curves()];
        for cc in curve_crossings {
            for cid in [cc.a, cc.b] {
                faint[cid as usize] = is_faint(self.curve(cid), config.solve.min_curve_strength);
            }
        }
        let est = &calibration.estimate;
        let joint_plane = |q: u32| -> Option<(u32, u8)> {
            let i = plane_index.get(q as usize).copied().flatten()?;
            let slot = calibration.evidence.planes.get(i as usize)?;
            Some((est.joint_of_pose[slot.pose as usize]?, slot.laser))
        };
        let ours = |q: u32| (first..end).contains(&(q as usize));
        let links: Vec<Link> = crossings
            .zip(curve_crossings)
            .filter(|(k, _)| self.crossings[*k].sin_angle >= config.solve.min_sin_angle)
            .filter_map(|(k, cc)| {
                let c = &self.crossings[k];
                let (own, other) = match (ours(c.a), ours(c.b)) {
                    (true, true) => (c.a, None),
                    (true, false) => (c.a, Some(joint_plane(c.b)?)),
                    (false, true) => (c.b, Some(joint_plane(c.a)?)),
                    (false, false) => return None,
                };
                let class =
                    Self::class_of(cc, [faint[cc.a as usize], faint[cc.b as usize]], config);
                Some(Link {
                    laser: self.planes[own as usize].laser,
                    other,
                    u: c.u,
                    class,
                })
            })
            .collect();
        let fit = outside::fit_outside(
            &calibration.evidence,
            est,
            &placing.joint,
            &placing.params,
            &links,
            placing.nearest(frame as u32),
        )?;
        let lasers: Vec<u8> = self.planes[first..end].iter().map(|p| p.laser).collect();
        let planes = Planes::Calibrated {
            calibration,
            plane_index,
            placed: Some(Placed {
                first,
                lasers: &lasers,
                fit: &fit,
            }),
        };
        Some(triangulate::cloud(
            self,
            &planes,
            first..end,
            curve_crossings,
            &faint,
            colour,
            config,
        ))
    }
}
