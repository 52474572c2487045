//! Crossings between laser curves on the fixed image plane.
//!
//! Owns the spatial index over curve segments and the sub-pixel crossing points that
//! feed the coplanarity system of [`crate::solve`]. Curves arrive as polylines in
//! undistorted normalised image coordinates `(x, y)` (the image point `u = (x, y, 1)`);
//! nothing here knows about pixels, planes or frames.
//!
//! # Index
//! A uniform grid over the normalised image plane, cells of side `h`, stored sparsely
//! (a hash map from cell to the segments whose bounding box overlaps it). `h` adapts to
//! the data: the median segment length of the first curve inserted (or of all
//! curves in [`find_crossings`]), so a segment touches O(1) cells and a cell holds the
//! segments of the curves that really pass there. Inserting a curve tests its segments
//! only against segments in the cells they overlap, so the cost grows with the number
//! of real crossings, not with the square of the number of curves.
//!
//! # Crossing point
//! Segments `p + t·r` and `q + s·d` (`t, s ∈ [0, 1)`, the last segment of a polyline
//! closed at 1 so a crossing at a shared vertex is reported once) meet where
//! `t = ((q − p) × d) / (r × d)` and `s = ((q − p) × r) / (r × d)` (`×` the 2D cross
//! product). The sine of the crossing angle is `|r × d| / (|r| |d|)`; crossings below
//! `min_sin_angle` are skipped, since their position along the curves is poorly
//! determined. A pair of segments overlapping several cells is reported only from the
//! cell that contains the crossing point, which is among the cells of both segments.

use std::collections::HashMap;

type CellMap = HashMap<(i32, i32), Vec<u32>>;

/// Grid cell side over the median segment length (1 beat 0.5 and 2 by 15–25 % in the
/// bench of 2000 curves, `cargo bench --bench solve`).
const CELL_PER_SEGMENT: f64 = 1.0;

/// A crossing of two curves on the image plane.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Crossing {
    /// Curve ids, `a < b`.
    pub a: u32,
    pub b: u32,
    /// The crossing in normalised image coordinates.
    pub u: [f64; 2],
    /// Sine of the angle between the two curves at the crossing.
    pub sin_angle: f64,
}

#[derive(Clone, Copy, Debug)]
struct Segment {
    curve: u32,
    p: [f64; 2],
    r: [f64; 2],
    /// Whether the end point `t = 1` belongs to the segment (last of its polyline).
    closed_end: bool,
}

/// Incremental spatial index over the segments of the curves inserted so far.
#[derive(Clone, Debug)]
pub struct SegmentIndex {
    /// Cell side in normalised units; `None` until the first curve fixes it.
    cell: Option<f64>,
    min_sin_angle: f64,
    segments: Vec<Segment>,
    grid: CellMap,
}

fn cross2(a: [f64; 2], b: [f64; 2]) -> f64 {
    a[0] * b[1] - a[1] * b[0]
}

fn median_segment_length<'a>(polylines: impl Iterator<Item = &'a [[f64; 2]]>) -> Option<f64> {
    let mut lengths: Vec<f64> = polylines
        .flat_map(|pl| pl.windows(2))
        .map(|w| (w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1]))
        .filter(|l| *l > 0.0 && l.is_finite())
        .collect();
    if lengths.is_empty() {
        return None;
    }
    let mid = lengths.len() / 2;
    let (_, m, _) = lengths.select_nth_unstable_by(mid, f64::total_cmp);
    Some(*m)
}

impl SegmentIndex {
    /// An empty index whose cell size is set by the first curve inserted.
    pub fn new(min_sin_angle: f64) -> Self {
        Self {
            cell: None,
            min_sin_angle,
            segments: Vec::new(),
            grid: CellMap::default(),
        }
    }

    /// An empty index with cells of side `cell` (normalised units; must be positive).
    pub fn with_cell_size(cell: f64, min_sin_angle: f64) -> Self {
        let mut s = Self::new(min_sin_angle);
        if cell > 0.0 && cell.is_finite() {
            s.cell = Some(cell);
        }
        s
    }

    /// Number of segments stored.
    pub fn num_segments(&self) -> usize {
        self.segments.len()
    }

    fn cell_of(cell: f64, p: [f64; 2]) -> (i32, i32) {
        // Saturating casts: points far outside the image land in border cells, which
        // costs time but never correctness.
        ((p[0] / cell).floor() as i32, (p[1] / cell).floor() as i32)
    }

    /// Adds the curve `curve_id` and returns its crossings with the curves inserted
    /// before (not with itself). Crossings with a curve of the same id are skipped, so
    /// a curve inserted in pieces does not cross itself.
    pub fn insert(&mut self, curve_id: u32, polyline: &[[f64; 2]]) -> Vec<Crossing> {
        let mut out = Vec::new();
        self.insert_into(curve_id, polyline, &mut out);
        out
    }

    /// As [`Self::insert`], appending to `out`.
    pub fn insert_into(&mut self, curve_id: u32, polyline: &[[f64; 2]], out: &mut Vec<Crossing>) {
        let cell = match self.cell {
            Some(c) => c,
            None => match median_segment_length(std::iter::once(polyline)) {
                Some(m) => {
                    self.cell = Some(CELL_PER_SEGMENT * m);
                    CELL_PER_SEGMENT * m
                }
                None => return,
            },
        };
        let n_seg = polyline.len().saturating_sub(1);
        let mut new_segments = Vec::with_capacity(n_seg);
        for (k, w) in polyline.windows(2).enumerate() {
            let r = [w[1][0] - w[0][0], w[1][1] - w[0][1]];
            if !(r[0].is_finite() && r[1].is_finite() && w[0][0].is_finite() && w[0][1].is_finite())
            {
                continue;
            }
            new_segments.push(Segment {
                curve: curve_id,
                p: w[0],
                r,
                closed_end: k + 1 == n_seg,
            });
        }
        for seg in &new_segments {
            let (c0, c1) = Self::bbox_cells(cell, seg);
            for cx in c0.0..=c1.0 {
                for cy in c0.1..=c1.1 {
                    let Some(list) = self.grid.get(&(cx, cy)) else {
                        continue;
                    };
                    for &other in list {
                        let o = &self.segments[other as usize];
                        if o.curve == curve_id {
                            continue;
                        }
                        if let Some(c) = self.intersect(seg, o) {
                            // Clamped to the cells both boxes share, so rounding of
                            // `u` at a cell border can neither lose nor double it.
                            let (o0, o1) = Self::bbox_cells(cell, o);
                            let cu = Self::cell_of(cell, c.u);
                            let home = (
                                cu.0.clamp(c0.0.max(o0.0), c1.0.min(o1.0)),
                                cu.1.clamp(c0.1.max(o0.1), c1.1.min(o1.1)),
                            );
                            if home == (cx, cy) {
                                out.push(c);
                            }
                        }
                    }
                }
            }
        }
        for seg in new_segments {
            let id = self.segments.len() as u32;
            let (c0, c1) = Self::bbox_cells(cell, &seg);
            for cx in c0.0..=c1.0 {
                for cy in c0.1..=c1.1 {
                    self.grid.entry((cx, cy)).or_default().push(id);
                }
            }
            self.segments.push(seg);
        }
    }

    fn bbox_cells(cell: f64, s: &Segment) -> ((i32, i32), (i32, i32)) {
        let q = [s.p[0] + s.r[0], s.p[1] + s.r[1]];
        let lo = [s.p[0].min(q[0]), s.p[1].min(q[1])];
        let hi = [s.p[0].max(q[0]), s.p[1].max(q[1])];
        (Self::cell_of(cell, lo), Self::cell_of(cell, hi))
    }

    fn intersect(&self, s1: &Segment, s2: &Segment) -> Option<Crossing> {
        let denom = cross2(s1.r, s2.r);
        let len = s1.r[0].hypot(s1.r[1]) * s2.r[0].hypot(s2.r[1]);
        if len == 0.0 {
            return None;
        }
        let sin_angle = denom.abs() / len;
        if sin_angle < self.min_sin_angle || denom == 0.0 {
            return None;
        }
        let qp = [s2.p[0] - s1.p[0], s2.p[1] - s1.p[1]];
        let t = cross2(qp, s2.r) / denom;
        let s = cross2(qp, s1.r) / denom;
        let inside = |x: f64, closed: bool| x >= 0.0 && (x < 1.0 || (closed && x <= 1.0));
        if !(inside(t, s1.closed_end) && inside(s, s2.closed_end)) {
            return None;
        }
        let u = [s1.p[0] + t * s1.r[0], s1.p[1] + t * s1.r[1]];
        let (a, b) = if s1.curve < s2.curve {
            (s1.curve, s2.curve)
        } else {
            (s2.curve, s1.curve)
        };
        Some(Crossing { a, b, u, sin_angle })
    }
}

/// All crossings between the given curves (curve id = index in `polylines`), skipping
/// those at an angle whose sine is below `min_sin_angle`. Sorted by `(a, b)` and then
/// by position, so the output does not depend on the grid.
pub fn find_crossings(polylines: &[&[[f64; 2]]], min_sin_angle: f64) -> Vec<Crossing> {
    let cell =
        median_segment_length(polylines.iter().copied()).map_or(1.0, |m| CELL_PER_SEGMENT * m);
    let mut index = SegmentIndex::with_cell_size(cell, min_sin_angle);
    let mut out = Vec::new();
    for (id, pl) in polylines.iter().enumerate() {
        index.insert_into(id as u32, pl, &mut out);
    }
    out.sort_by(|p, q| {
        (p.a, p.b)
            .cmp(&(q.a, q.b))
            .then(p.u[0].total_cmp(&q.u[0]))
            .then(p.u[1].total_cmp(&q.u[1]))
    });
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::solve::synthetic::{analytic_crossings, curve_polyline, random_scan, ScanSpec};

    #[test]
    fn two_lines_cross_at_the_analytic_point() {
        // y = 0.3 x + 0.1 and y = -2 x + 0.5 meet at x = 0.4 / 2.3.
        let line = |m: f64, c: f64| -> Vec<[f64; 2]> {
            (0..=20)
                .map(|k| {
                    let x = -0.5 + k as f64 * 0.05;
                    [x, m * x + c]
                })
                .collect()
        };
        let (l0, l1) = (line(0.3, 0.1), line(-2.0, 0.5));
        let c = find_crossings(&[&l0, &l1], 0.05);
        assert_eq!(c.len(), 1);
        let x = 0.4 / 2.3;
        assert!((c[0].u[0] - x).abs() < 1e-12 && (c[0].u[1] - (0.3 * x + 0.1)).abs() < 1e-12);
        assert_eq!((c[0].a, c[0].b), (0, 1));
        let sin_true = ((-2.0f64).atan() - 0.3f64.atan()).sin().abs();
        assert!((c[0].sin_angle - sin_true).abs() < 1e-12);
        // A shallow-angle threshold above the true angle removes it.
        assert!(find_crossings(&[&l0, &l1], sin_true + 0.01).is_empty());
    }

    #[test]
    fn crossing_at_a_shared_vertex_is_reported_once() {
        let a = [[-1.0, 0.0], [0.0, 0.0], [1.0, 0.0]];
        let b = [[0.0, -1.0], [0.0, 0.0], [0.0, 1.0]];
        let c = find_crossings(&[&a, &b], 0.1);
        assert_eq!(c.len(), 1, "{c:?}");
        assert_eq!(c[0].u, [0.0, 0.0]);
    }

    #[test]
    fn polylines_of_a_synthetic_scan_cross_where_the_planes_meet_on_the_surface() {
        let scan = random_scan(&ScanSpec {
            num_crosses: 25,
            seed: 7,
            ..ScanSpec::default()
        });
        let polylines: Vec<Vec<[f64; 2]>> = scan
            .planes
            .iter()
            .map(|v| curve_polyline(&scan.scene, v, 0.02).expect("one polyline"))
            .collect();
        let refs: Vec<&[[f64; 2]]> = polylines.iter().map(|p| p.as_slice()).collect();
        let min_sin = 0.05;
        let mut found = find_crossings(&refs, min_sin);
        let mut truth = analytic_crossings(&scan.scene, &scan.planes, min_sin);
        assert!(truth.len() > 200, "only {} crossings", truth.len());
        let key = |c: &Crossing| (c.a, c.b, (c.u[0] * 1e6) as i64, (c.u[1] * 1e6) as i64);
        found.sort_by_key(key);
        truth.sort_by_key(key);
        // Angles right at the threshold may fall either way; there are none in practice.
        assert_eq!(found.len(), truth.len());
        for (f, t) in found.iter().zip(&truth) {
            assert_eq!((f.a, f.b), (t.a, t.b));
            let d = (f.u[0] - t.u[0]).hypot(f.u[1] - t.u[1]);
            assert!(d < 1e-9, "crossing {f:?} vs analytic {t:?}");
            assert!((f.sin_angle - t.sin_angle).abs() < 1e-9);
        }
    }

    #[test]
    fn incremental_insert_returns_crossings_with_earlier_curves_only() {
        let h = [[-1.0, 0.1], [1.0, 0.1]];
        let v1 = [[0.2, -1.0], [0.2, 1.0]];
        let v2 = [[-0.3, -1.0], [-0.3, 1.0]];
        let mut index = SegmentIndex::with_cell_size(0.25, 0.1);
        assert!(index.insert(5, &h).is_empty());
        let c = index.insert(2, &v1);
        assert_eq!(c.len(), 1);
        assert_eq!((c[0].a, c[0].b), (2, 5));
        assert!((c[0].u[0] - 0.2).abs() < 1e-15 && (c[0].u[1] - 0.1).abs() < 1e-15);
        let c = index.insert(9, &v2);
        assert_eq!(c.len(), 1, "parallel verticals do not cross");
        assert_eq!((c[0].a, c[0].b), (5, 9));
        assert_eq!(index.num_segments(), 3);
    }
}
