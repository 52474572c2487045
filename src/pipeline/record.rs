//! [`Record`]: what a scan has seen, its planes, curves and refined crossings, and what
//! the stages after the crossing search read of it: the crossings as the crossing check
//! takes them, the faint curves, the estimator's [`Evidence`] and the extraction's
//! predicted precision. [`super::Scan`] grows a record frame by frame; a record is
//! cloned (its planes shared, not copied) for a live epoch's own thread.

use std::sync::Arc;

use rayon::prelude::*;

use super::anchors::Anchors;
use super::is_faint;
use super::planes::PlaneCurves;
use crate::camera::Camera;
use crate::cloud;
use crate::config::Config;
use crate::extract::Curve;
use crate::intersect::Crossing;
use crate::solve::evidence::{CrossingClass, Evidence, Observation, PlaneSlot, RayModel};

/// What a scan has seen (see the module docs). Every crossing in it is refined.
#[derive(Clone)]
pub struct Record {
    pub(super) frames: usize,
    pub(super) frames_with_curves: usize,
    /// One per laser of a frame with curves, in order; shared with clones.
    pub(super) planes: Vec<Arc<PlaneCurves>>,
    /// Per curve (global id, in plane order): its plane and its index in that plane.
    pub(super) curve_plane: Vec<u32>,
    pub(super) curve_local: Vec<u32>,
    pub(super) anchors: Anchors,
    /// Per plane, the global id of its first curve.
    pub(super) plane_first_curve: Vec<u32>,
    /// Per frame, its first plane and the first crossing its curves added (its planes
    /// and those crossings follow in order).
    pub(super) frame_first_plane: Vec<u32>,
    pub(super) frame_first_crossing: Vec<u32>,
    /// Crossings of planes (`a`, `b` are plane ids) and the curves they are of.
    pub(super) crossings: Vec<Crossing>,
    pub(super) curve_ids: Vec<[u32; 2]>,
    /// Per crossing, the predicted deviation of its position (normalised units) from
    /// its refinement ([`crate::intersect::RefinedCrossing::sigma`]; 0: not refined).
    pub(super) crossing_sigma: Vec<f64>,
    /// Per crossing, as the crossing check takes it ([`Self::curve_crossing`]), made
    /// when it is refined. It depends on the crossing and its two curves alone, none of
    /// which changes after, so it is made once: made at each use, it was 2.4 s of the
    /// 5,400-frame dive's final solve (each point nearest a crossing looked up along its
    /// curve), and twice more for every live epoch.
    pub(super) curve_crossings: Vec<cloud::CurveCrossing>,
}

impl Record {
    pub fn frames(&self) -> usize {
        self.frames
    }

    pub(crate) fn planes(&self) -> &[Arc<PlaneCurves>] {
        &self.planes
    }

    pub fn num_curves(&self) -> usize {
        self.curve_plane.len()
    }

    pub fn num_crossings(&self) -> usize {
        self.crossings.len()
    }

    pub(super) fn curve(&self, cid: u32) -> &Curve {
        let (p, local) = (
            self.curve_plane[cid as usize],
            self.curve_local[cid as usize],
        );
        &self.planes[p as usize].curves[local as usize]
    }

    /// The crossings of curves, with each curve's point nearest the crossing and its
    /// ridge strength there, as the triangulation's crossing check needs them.
    pub(super) fn curve_crossings(&self) -> &[cloud::CurveCrossing] {
        debug_assert_eq!(
            self.curve_crossings.len(),
            self.crossings.len(),
            "crossings not refined"
        );
        &self.curve_crossings
    }

    /// Makes [`Self::curve_crossings`] of the crossings refined since the last call.
    pub(super) fn extend_curve_crossings(&mut self) {
        let made: Vec<cloud::CurveCrossing> = (self.curve_crossings.len()..self.crossings.len())
            .into_par_iter()
            .map(|k| self.curve_crossing(k))
            .collect();
        self.curve_crossings.extend(made);
    }

    /// Crossing `k` as the crossing check takes it.
    pub(super) fn curve_crossing(&self, k: usize) -> cloud::CurveCrossing {
        let (c, [a, b]) = (&self.crossings[k], self.curve_ids[k]);
        let near = |cid: u32| {
            let (p, local) = (
                self.curve_plane[cid as usize],
                self.curve_local[cid as usize],
            );
            self.planes[p as usize].nearest_point(local as usize, c.u)
        };
        let at = [near(a), near(b)];
        let strength = |cid: u32, i: u32| {
            self.curve(cid)
                .strength
                .get(i as usize)
                .copied()
                .unwrap_or(0.0)
        };
        cloud::CurveCrossing {
            a,
            b,
            u: c.u,
            at,
            strength: [strength(a, at[0]), strength(b, at[1])],
        }
    }

    /// The class of a crossing (see [`Self::evidence`]).
    pub(super) fn class_of(
        cc: &cloud::CurveCrossing,
        faint: [bool; 2],
        config: &Config,
    ) -> CrossingClass {
        let min_local = config.solve.min_crossing_strength;
        let strong =
            !faint[0] && !faint[1] && cc.strength.iter().all(|s| *s >= min_local || *s == 0.0);
        if strong {
            CrossingClass::Strong
        } else {
            CrossingClass::Faint
        }
    }

    /// The precision the extraction predicts for the strong crossings, pixels: the median
    /// over the crossings above `solve.min_sin_angle` of class strong ([`Self::class_of`])
    /// of each refined crossing's predicted deviation
    /// ([`crate::intersect::refine_crossing`]). The estimator's evidence keeps only those
    /// tied to an anchor of them; the prediction takes all, since it is a property of the
    /// curves. `None` without refined strong crossings.
    pub(super) fn predicted_crossing_px(
        &self,
        curve_crossings: &[cloud::CurveCrossing],
        faint: &[bool],
        config: &Config,
        focal_px: f64,
    ) -> Option<f64> {
        let sigmas: Vec<f64> = self
            .crossings
            .iter()
            .zip(curve_crossings)
            .zip(&self.crossing_sigma)
            .filter(|((c, cc), sigma)| {
                **sigma > 0.0
                    && c.sin_angle >= config.solve.min_sin_angle
                    && Self::class_of(cc, [faint[cc.a as usize], faint[cc.b as usize]], config)
                        == CrossingClass::Strong
            })
            .map(|(_, sigma)| sigma * focal_px)
            .collect();
        crate::solve::median(sigmas)
    }

    /// Per curve, whether it is faint: no point reaches `solve.min_curve_strength`.
    pub(super) fn faint_curves(&self, config: &Config) -> Vec<bool> {
        self.planes
            .iter()
            .flat_map(|p| &p.curves)
            .map(|c| is_faint(c, config.solve.min_curve_strength))
            .collect()
    }

    /// The estimator's evidence: a pose per frame with a crossing, its planes, and every
    /// crossing at an angle above `solve.min_sin_angle`, of class strong where both
    /// curves are strong (`min_curve_strength`) and both ridges at least
    /// `min_crossing_strength` there, faint otherwise. Also returns, per plane, its index
    /// in the evidence (`None` for planes without a crossing).
    pub(super) fn evidence(
        &self,
        camera: &Camera,
        config: &Config,
        curve_crossings: &[cloud::CurveCrossing],
        faint: &[bool],
    ) -> (Evidence, Vec<Option<u32>>) {
        let frame_of = |plane: u32| self.planes[plane as usize].frame;
        // A crossing of two frames neither of which is an anchor (any more) ties two
        // poses that are each fitted on their own: it is left to the crossing check.
        let tied = |c: &Crossing| {
            let (fa, fb) = (frame_of(c.a), frame_of(c.b));
            fa == fb || self.anchors.is_anchor(fa) || self.anchors.is_anchor(fb)
        };
        let mut used = vec![false; self.planes.len()];
        for c in &self.crossings {
            if c.sin_angle >= config.solve.min_sin_angle && tied(c) {
                used[c.a as usize] = true;
                used[c.b as usize] = true;
            }
        }
        let mut pose_of_frame: Vec<Option<u32>> = vec![None; self.frames];
        let mut pose_frames = Vec::new();
        let mut slots = Vec::new();
        let mut plane_index = vec![None; self.planes.len()];
        for (i, p) in self.planes.iter().enumerate() {
            if !used[i] {
                continue;
            }
            let pose = *pose_of_frame[p.frame as usize].get_or_insert_with(|| {
                pose_frames.push(p.frame);
                (pose_frames.len() - 1) as u32
            });
            plane_index[i] = Some(slots.len() as u32);
            slots.push(PlaneSlot {
                pose,
                laser: p.laser,
            });
        }
        let crossings = self
            .crossings
            .iter()
            .zip(curve_crossings)
            .filter(|(c, _)| c.sin_angle >= config.solve.min_sin_angle && tied(c))
            .filter_map(|(c, cc)| {
                Some(Observation {
                    a: plane_index[c.a as usize]?,
                    b: plane_index[c.b as usize]?,
                    u: c.u,
                    sin_angle: c.sin_angle,
                    class: Self::class_of(cc, [faint[cc.a as usize], faint[cc.b as usize]], config),
                })
            })
            .collect();
        let anchors = pose_frames
            .iter()
            .map(|&f| self.anchors.is_anchor(f))
            .collect();
        let evidence = Evidence {
            anchors,
            pose_frames,
            planes: slots,
            crossings,
            focal_px: camera.fx.max(camera.fy),
            rays: RayModel::new(camera.distortion),
        };
        (evidence, plane_index)
    }
}
