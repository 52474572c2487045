//! One laser of one frame and the curves that lie on it: the unit the solver gives a
//! plane to. Owns the grouping of a frame's curves into planes and the look-ups that
//! crossings need on a plane's dense points.

use crate::extract::Curve;

/// One laser of one frame: a plane unknown and the curves that lie on it.
pub(crate) struct PlaneCurves {
    pub(crate) frame: u32,
    pub(crate) laser: u8,
    pub(crate) curves: Vec<Curve>,
    /// Per curve, the index in `points` of each polyline vertex.
    vertices: Vec<Vec<usize>>,
    /// Per curve, a bound on the step between consecutive dense points (the nearest-point
    /// searches skip with it: [`crate::intersect::nearest_index`]).
    max_step: Vec<f64>,
}

impl PlaneCurves {
    pub(crate) fn new(frame: u32, laser: u8, curves: Vec<Curve>) -> Self {
        let vertices = curves
            .iter()
            .map(|c| {
                // Polyline vertices are copies of dense points, in order.
                let mut at = 0;
                c.polyline
                    .iter()
                    .map(|v| {
                        if let Some(i) = c.points[at..].iter().position(|p| p == v) {
                            at += i;
                        }
                        at
                    })
                    .collect()
            })
            .collect();
        let max_step = curves
            .iter()
            .map(|c| crate::intersect::max_step(&c.points))
            .collect();
        Self {
            frame,
            laser,
            curves,
            vertices,
            max_step,
        }
    }

    /// The plane unknowns of one frame: its curves grouped by laser, laser 0 first, one
    /// per laser that has curves (curves of a laser beyond the second are dropped).
    /// The live solver and `reconstruct_curves` both group through here, so that they
    /// make the same planes in the same order.
    pub(crate) fn of_frame(frame: u32, curves: Vec<Curve>) -> Vec<PlaneCurves> {
        let mut by_laser: [Vec<Curve>; 2] = [Vec::new(), Vec::new()];
        for c in curves {
            if let Some(slot) = by_laser.get_mut(c.laser as usize) {
                slot.push(c);
            }
        }
        by_laser
            .into_iter()
            .enumerate()
            .filter(|(_, curves)| !curves.is_empty())
            .map(|(laser, curves)| PlaneCurves::new(frame, laser as u8, curves))
            .collect()
    }

    /// The dense points around `u` of the curve (of this plane) whose polyline passes
    /// closest to `u`: the polyline's segment is found first (polylines are short),
    /// then only the dense points between its two vertices, widened by `radius`, are
    /// searched.
    pub(crate) fn dense_near(&self, u: [f64; 2], radius: f64) -> &[[f64; 2]] {
        match self.run_near(u, radius) {
            Some((ci, lo, hi, guess)) => crate::intersect::dense_run_from(
                &self.curves[ci].points[lo..=hi],
                u,
                radius,
                self.max_step[ci],
                guess - lo,
            ),
            None => &[],
        }
    }

    /// Index of the dense point of curve `ci` nearest `u` (searched between the two
    /// vertices of the polyline segment nearest `u`, outwards from where `u` projects
    /// onto the segment: the dense points run along it about evenly).
    pub(crate) fn nearest_point(&self, ci: usize, u: [f64; 2]) -> u32 {
        let Some((_, k)) = self.nearest_segment(ci, u) else {
            return 0;
        };
        let (start, end) = self.segment_span(ci, k);
        let points = &self.curves[ci].points[start..=end];
        let guess = self.projected_index(ci, k, u) - start;
        let nearest = crate::intersect::nearest_index_from(points, u, self.max_step[ci], guess);
        (start + nearest.unwrap_or(0)) as u32
    }

    /// The dense point of curve `ci` where `u` projects onto its polyline segment `k`
    /// (between the segment's two vertices, `u`'s place along it: the dense points run
    /// along a segment about evenly), where the nearest-point searches start.
    fn projected_index(&self, ci: usize, k: usize, u: [f64; 2]) -> usize {
        let (start, end) = self.segment_span(ci, k);
        match &self.curves[ci].polyline[k..] {
            [a, b, ..] => {
                let t = crate::intersect::segment_param(u, *a, *b);
                start + (t * (end - start) as f64).round() as usize
            }
            _ => start,
        }
    }

    /// Curve index, the range of its dense points around `u` (see [`Self::dense_near`]),
    /// and where `u` projects into it ([`Self::projected_index`]).
    fn run_near(&self, u: [f64; 2], radius: f64) -> Option<(usize, usize, usize, usize)> {
        let (_, ci, k) = (0..self.curves.len())
            .filter_map(|ci| self.nearest_segment(ci, u).map(|(d, k)| (d, ci, k)))
            .fold(None, |best: Option<(f64, usize, usize)>, c| match best {
                Some(b) if b.0 <= c.0 => Some(b),
                _ => Some(c),
            })?;
        let points = &self.curves[ci].points;
        if points.is_empty() {
            return None;
        }
        let (start, end) = self.segment_span(ci, k);
        let r2 = radius * radius;
        let d2 = |p: &[f64; 2]| (p[0] - u[0]).powi(2) + (p[1] - u[1]).powi(2);
        let (mut lo, mut hi) = (start, end);
        while lo > 0 && d2(&points[lo - 1]) <= r2 {
            lo -= 1;
        }
        while hi + 1 < points.len() && d2(&points[hi + 1]) <= r2 {
            hi += 1;
        }
        Some((ci, lo, hi, self.projected_index(ci, k, u)))
    }

    /// Distance to `u` and index of the polyline segment of curve `ci` nearest `u`
    /// (the first of equals).
    fn nearest_segment(&self, ci: usize, u: [f64; 2]) -> Option<(f64, usize)> {
        let mut best: Option<(f64, usize)> = None;
        for (k, seg) in self.curves[ci].polyline.windows(2).enumerate() {
            let d = crate::intersect::point_segment_distance(u, seg[0], seg[1]);
            if best.is_none_or(|(b, _)| d < b) {
                best = Some((d, k));
            }
        }
        best
    }

    /// The dense points `start..=end` between the two vertices of segment `k` of curve
    /// `ci` (clamped to the curve).
    fn segment_span(&self, ci: usize, k: usize) -> (usize, usize) {
        let last = self.curves[ci].points.len().saturating_sub(1);
        let start = self.vertices[ci].get(k).copied().unwrap_or(0).min(last);
        let end = self.vertices[ci]
            .get(k + 1)
            .copied()
            .unwrap_or(last)
            .clamp(start, last);
        (start, end)
    }
}
