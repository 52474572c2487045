//! What the live daemon asks of a [`Scan`] as it grows: the estimator's evidence so far
//! (an epoch) and the epoch's cloud. The same stages as [`super::reconstruct_scan`], cut where the daemon
//! needs them: nothing here decides anything the offline pipeline does not.

use image::RgbImage;

use super::triangulate::{self, CloudOut};
use super::{Fit, Planes, Scan};
use crate::camera::Camera;
use crate::config::Config;
use crate::solve::evidence::Evidence;
use crate::solve::Calibration;

impl Scan {
    /// The estimator's evidence of the scan so far, and per plane its index in it
    /// (as [`super::reconstruct_scan`] makes them).
    pub fn solve_input(&self, camera: &Camera, config: &Config) -> (Evidence, Vec<Option<u32>>) {
        let curve_crossings = self.curve_crossings();
        let faint = self.faint_curves(config);
        self.evidence(camera, config, &curve_crossings, &faint)
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
        };
        let curve_crossings = self.curve_crossings();
        let faint = self.faint_curves(config);
        let predicted =
            self.predicted_crossing_px(&curve_crossings, &faint, config, camera.fx.max(camera.fy));
        let fit = Fit::of(calibration, predicted);
        let out = triangulate::cloud(self, &planes, &curve_crossings, &faint, colour, config);
        (out, fit)
    }
}
