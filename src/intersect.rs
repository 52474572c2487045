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

/// Cells along the larger image side of [`SegmentIndex::for_image`].
pub const IMAGE_CELLS: f64 = 48.0;
/// Most grid cells one segment may cover; longer ones are left out and counted
/// ([`SegmentIndex::segments_too_long`]). An image is `IMAGE_CELLS²` cells.
pub const MAX_CELLS_PER_SEGMENT: i64 = 1 << 20;

/// Incremental spatial index over the segments of the curves inserted so far.
#[derive(Clone, Debug)]
pub struct SegmentIndex {
    /// Cell side in normalised units; `None` until the first curve fixes it.
    cell: Option<f64>,
    min_sin_angle: f64,
    segments: Vec<Segment>,
    grid: CellMap,
    segments_too_long: u64,
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
            segments_too_long: 0,
        }
    }

    /// Segments left out because they covered more than [`MAX_CELLS_PER_SEGMENT`].
    pub fn segments_too_long(&self) -> u64 {
        self.segments_too_long
    }

    /// An empty index with cells of side `cell` (normalised units; must be positive).
    pub fn with_cell_size(cell: f64, min_sin_angle: f64) -> Self {
        let mut s = Self::new(min_sin_angle);
        if cell > 0.0 && cell.is_finite() {
            s.cell = Some(cell);
        }
        s
    }

    /// An empty index for curves on an image of `width`×`height` pixels with focal
    /// length `focal_px`: cells of [`IMAGE_CELLS`]-th of the larger image side. Fixing
    /// the cell from the image, rather than from the first curve, keeps one short,
    /// finely simplified first curve from making cells so small that every later long
    /// segment spans thousands of them.
    pub fn for_image(width: u32, height: u32, focal_px: f64, min_sin_angle: f64) -> Self {
        let cell = f64::from(width.max(height)) / IMAGE_CELLS / focal_px;
        Self::with_cell_size(cell, min_sin_angle)
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
        let Some((cell, segments)) = self.segments_of(curve_id, polyline) else {
            return;
        };
        self.query_segments(cell, curve_id, &segments, out);
        self.add_segments(cell, segments);
    }

    /// The crossings of `polyline` (as curve `curve_id`) with the curves inserted so far,
    /// appended to `out`, without inserting it.
    pub fn query_into(&mut self, curve_id: u32, polyline: &[[f64; 2]], out: &mut Vec<Crossing>) {
        if let Some((cell, segments)) = self.segments_of(curve_id, polyline) {
            self.query_segments(cell, curve_id, &segments, out);
        }
    }

    /// Inserts curve `curve_id` without looking for its crossings.
    pub fn add(&mut self, curve_id: u32, polyline: &[[f64; 2]]) {
        if let Some((cell, segments)) = self.segments_of(curve_id, polyline) {
            self.add_segments(cell, segments);
        }
    }

    /// The cell size (fixed by the first curve if not yet) and the curve's segments,
    /// those too long to index counted and left out.
    fn segments_of(&mut self, curve_id: u32, polyline: &[[f64; 2]]) -> Option<(f64, Vec<Segment>)> {
        let cell = match self.cell {
            Some(c) => c,
            None => {
                let m = median_segment_length(std::iter::once(polyline))?;
                self.cell = Some(CELL_PER_SEGMENT * m);
                CELL_PER_SEGMENT * m
            }
        };
        let n_seg = polyline.len().saturating_sub(1);
        let mut new_segments = Vec::with_capacity(n_seg);
        for (k, w) in polyline.windows(2).enumerate() {
            let r = [w[1][0] - w[0][0], w[1][1] - w[0][1]];
            if !(r[0].is_finite() && r[1].is_finite() && w[0][0].is_finite() && w[0][1].is_finite())
            {
                continue;
            }
            let seg = Segment {
                curve: curve_id,
                p: w[0],
                r,
                closed_end: k + 1 == n_seg,
            };
            // A segment over more cells than a whole image has (cells far too small
            // for it: an absurd focal length) would be walked cell by cell for ever.
            let (c0, c1) = Self::bbox_cells(cell, &seg);
            let cells =
                (i64::from(c1.0) - i64::from(c0.0) + 1) * (i64::from(c1.1) - i64::from(c0.1) + 1);
            if cells > MAX_CELLS_PER_SEGMENT {
                self.segments_too_long += 1;
                continue;
            }
            new_segments.push(seg);
        }
        Some((cell, new_segments))
    }

    fn query_segments(
        &self,
        cell: f64,
        curve_id: u32,
        segments: &[Segment],
        out: &mut Vec<Crossing>,
    ) {
        for seg in segments {
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
    }

    fn add_segments(&mut self, cell: f64, segments: Vec<Segment>) {
        for seg in segments {
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

/// Settings of the crossing stage: the `[intersect]` table of `crossline.toml`.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct IntersectParams {
    /// Crossings found on the simplified polylines are refined from the dense curve
    /// points within this radius (pixels); 0 keeps the polyline crossings.
    pub refine_radius_px: f64,
}

impl Default for IntersectParams {
    fn default() -> Self {
        Self {
            refine_radius_px: 6.0,
        }
    }
}

/// A curve's dense points near a crossing, fitted by a quadratic in a local frame:
/// `p(t) = origin + t·dir + (c0 + c1·t + c2·t²)·normal`.
#[derive(Clone, Copy, Debug)]
struct LocalQuadratic {
    origin: [f64; 2],
    dir: [f64; 2],
    normal: [f64; 2],
    c: [f64; 3],
    /// Length unit of the fit's scaled parameter, and the inverse of its normal matrix
    /// there: the fitted offset's variance at `t` is `noise² · bᵀ M⁻¹ b`,
    /// `b = (1, t/scale, (t/scale)²)`.
    scale: f64,
    m_inv: nalgebra::Matrix3<f64>,
    /// The points' scatter about the fit (variance, normal direction): residual sum of
    /// squares over `n − 3`.
    noise2: f64,
}

impl LocalQuadratic {
    /// Least-squares fit to `points` (at least 5, spread along the curve); `None` when
    /// they are too few or degenerate.
    fn fit(points: &[[f64; 2]]) -> Option<Self> {
        if points.len() < 5 {
            return None;
        }
        let n = points.len() as f64;
        let (mut mx, mut my) = (0.0, 0.0);
        for p in points {
            mx += p[0];
            my += p[1];
        }
        let origin = [mx / n, my / n];
        // Principal direction of the points.
        let (mut sxx, mut sxy, mut syy) = (0.0, 0.0, 0.0);
        for p in points {
            let (dx, dy) = (p[0] - origin[0], p[1] - origin[1]);
            sxx += dx * dx;
            sxy += dx * dy;
            syy += dy * dy;
        }
        let theta = 0.5 * (2.0 * sxy).atan2(sxx - syy);
        let dir = [theta.cos(), theta.sin()];
        let normal = [-dir[1], dir[0]];
        // Normal equations of s = c0 + c1 t + c2 t², in scaled t for conditioning.
        let scale = (sxx + syy).sqrt() / n.sqrt();
        if scale <= 0.0 {
            return None;
        }
        let mut m = nalgebra::Matrix3::<f64>::zeros();
        let mut r = nalgebra::Vector3::<f64>::zeros();
        for p in points {
            let (dx, dy) = (p[0] - origin[0], p[1] - origin[1]);
            let t = (dx * dir[0] + dy * dir[1]) / scale;
            let s = dx * normal[0] + dy * normal[1];
            let b = nalgebra::Vector3::new(1.0, t, t * t);
            m += b * b.transpose();
            r += b * s;
        }
        let m_inv = m.try_inverse()?;
        let c = m_inv * r;
        let rss: f64 = points
            .iter()
            .map(|p| {
                let (dx, dy) = (p[0] - origin[0], p[1] - origin[1]);
                let t = (dx * dir[0] + dy * dir[1]) / scale;
                let s = dx * normal[0] + dy * normal[1];
                (s - (c[0] + t * (c[1] + t * c[2]))).powi(2)
            })
            .sum();
        Some(Self {
            origin,
            dir,
            normal,
            c: [c[0], c[1] / scale, c[2] / (scale * scale)],
            scale,
            m_inv,
            noise2: rss / (n - 3.0),
        })
    }

    /// Variance of the fitted curve's position (across it) at `t`, from the points'
    /// own scatter about the fit.
    fn position_variance(&self, t: f64) -> f64 {
        let ts = t / self.scale;
        let b = nalgebra::Vector3::new(1.0, ts, ts * ts);
        self.noise2 * (b.transpose() * self.m_inv * b)[0]
    }

    fn at(&self, t: f64) -> [f64; 2] {
        let s = self.c[0] + t * (self.c[1] + t * self.c[2]);
        [
            self.origin[0] + t * self.dir[0] + s * self.normal[0],
            self.origin[1] + t * self.dir[1] + s * self.normal[1],
        ]
    }

    fn tangent(&self, t: f64) -> [f64; 2] {
        let ds = self.c[1] + 2.0 * self.c[2] * t;
        [
            self.dir[0] + ds * self.normal[0],
            self.dir[1] + ds * self.normal[1],
        ]
    }

    fn param_of(&self, p: [f64; 2]) -> f64 {
        (p[0] - self.origin[0]) * self.dir[0] + (p[1] - self.origin[1]) * self.dir[1]
    }
}

/// Where `p` projects onto the segment `a`–`b`, as the fraction of the way from `a`
/// (clamped to the segment; 0 on a segment of no length).
pub fn segment_param(p: [f64; 2], a: [f64; 2], b: [f64; 2]) -> f64 {
    let (ex, ey) = (b[0] - a[0], b[1] - a[1]);
    let len2 = ex * ex + ey * ey;
    if len2 > 0.0 {
        (((p[0] - a[0]) * ex + (p[1] - a[1]) * ey) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    }
}

/// Distance from `p` to the segment `a`–`b`.
pub fn point_segment_distance(p: [f64; 2], a: [f64; 2], b: [f64; 2]) -> f64 {
    let t = segment_param(p, a, b);
    let (ex, ey) = (b[0] - a[0], b[1] - a[1]);
    (p[0] - a[0] - t * ex).hypot(p[1] - a[1] - t * ey)
}

/// The longest step between consecutive `points`, rounded up a little, so that it
/// bounds every step for [`nearest_index`] whatever the rounding.
pub fn max_step(points: &[[f64; 2]]) -> f64 {
    let m = points
        .windows(2)
        .map(|w| (w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1]))
        .fold(0.0, f64::max);
    m * (1.0 + 1e-9) + 1e-12
}

/// Index of the point of `points` nearest `near` (the first of equals, as
/// `Iterator::min_by` gives), where no two consecutive points are further apart than
/// `max_step` ([`max_step`]). Exact, but it skips what cannot win: the distance to
/// `near` changes by at most `max_step` a point, so from a point `d` away, with `best`
/// found so far, the next `(d − best) / max_step` points are further than `best`. On a
/// run of dense points along a stripe that is a few dozen looks instead of hundreds.
pub fn nearest_index(points: &[[f64; 2]], near: [f64; 2], max_step: f64) -> Option<usize> {
    nearest_index_from(points, near, max_step, 0)
}

/// [`nearest_index`], searched outwards from the index `guess` (clamped): the same
/// answer for any guess, found in fewer looks the nearer the guess is. Each way from
/// the guess skips as [`nearest_index`] does, so a guess at the nearest point costs a
/// few looks where a search from one end walks every point up to it (most of the time
/// the crossing check spent finding the curves' points at 1.7 M crossings).
pub fn nearest_index_from(
    points: &[[f64; 2]],
    near: [f64; 2],
    max_step: f64,
    guess: usize,
) -> Option<usize> {
    let d2 = |p: &[f64; 2]| (p[0] - near[0]).powi(2) + (p[1] - near[1]).powi(2);
    // Points closer to one `d` away than (d − best) / max_step are all further than
    // best; a margin keeps rounding on the safe side.
    let g = guess.min(points.len().checked_sub(1)?);
    let mut best = Best::new(d2(&points[g]), g, max_step);
    // Onwards: a later point must be strictly nearer to win (the first of equals).
    let mut i = g + 1;
    while i < points.len() {
        let di2 = d2(&points[i]);
        if di2 < best.d2 {
            best = Best::new(di2, i, max_step);
        }
        i += best.skip(di2, max_step);
    }
    // Backwards: an earlier point wins a tie.
    let mut i = g;
    while i > 0 {
        let di2 = d2(&points[i - 1]);
        if di2 <= best.d2 {
            best = Best::new(di2, i - 1, max_step);
        }
        i = i.saturating_sub(best.skip(di2, max_step));
    }
    Some(best.index)
}

/// The nearest point so far of [`nearest_index_from`]'s search: its squared distance,
/// index, distance, and the squared distance within which a point skips none.
struct Best {
    d2: f64,
    index: usize,
    d: f64,
    /// `(d + max_step)²`: a point no further than this is at most `max_step` beyond
    /// the best, so [`Self::skip`] gives 1 without a square root (its rounding is far
    /// inside the skip's margin of 1e-9).
    within2: f64,
}

impl Best {
    fn new(d2: f64, index: usize, max_step: f64) -> Self {
        let d = d2.sqrt();
        Self {
            d2,
            index,
            d,
            within2: (d + max_step) * (d + max_step),
        }
    }

    /// How many points the search may step over from a point `di2` (squared) away:
    /// `(dᵢ − d) / max_step` of them are all further than the best. The quotient is
    /// positive, so truncation is its floor (a libm call on this target otherwise: 6 %
    /// of the extraction's samples went to this search, a tenth of them to `floor`).
    fn skip(&self, di2: f64, max_step: f64) -> usize {
        if max_step.is_nan() || max_step <= 0.0 || di2 <= self.within2 {
            return 1;
        }
        let di = di2.sqrt();
        let gap = di - self.d - 1e-9 * (1.0 + di);
        if gap > max_step {
            ((gap / max_step) as usize).max(1)
        } else {
            1
        }
    }
}

/// The dense points of a curve within `radius` of `near`, as one contiguous run along
/// the curve around its point closest to `near` (so a curve passing twice near the same
/// place contributes only the pass that crosses there). `max_step` bounds the steps
/// between consecutive points ([`max_step`]).
pub fn dense_run(points: &[[f64; 2]], near: [f64; 2], radius: f64, max_step: f64) -> &[[f64; 2]] {
    dense_run_from(points, near, radius, max_step, 0)
}

/// [`dense_run`], its closest point searched outwards from the index `guess`
/// ([`nearest_index_from`]: the same run for any guess, found in fewer looks the nearer
/// the guess is).
pub fn dense_run_from(
    points: &[[f64; 2]],
    near: [f64; 2],
    radius: f64,
    max_step: f64,
    guess: usize,
) -> &[[f64; 2]] {
    let d2 = |p: &[f64; 2]| (p[0] - near[0]).powi(2) + (p[1] - near[1]).powi(2);
    let Some(closest) = nearest_index_from(points, near, max_step, guess) else {
        return &[];
    };
    let r2 = radius * radius;
    if d2(&points[closest]) > r2 {
        return &[];
    }
    let mut lo = closest;
    while lo > 0 && d2(&points[lo - 1]) <= r2 {
        lo -= 1;
    }
    let mut hi = closest;
    while hi + 1 < points.len() && d2(&points[hi + 1]) <= r2 {
        hi += 1;
    }
    &points[lo..=hi]
}

/// Refines a crossing found on simplified polylines from the curves' dense points: a
/// local quadratic is fitted to each curve's points within `radius` of the crossing and
/// the two fits are intersected (Newton's method from `u`). Douglas–Peucker polylines
/// are off their curve by up to their tolerance; the dense points are not, so this
/// brings crossings to the detector's own sub-pixel accuracy.
///
/// With the point comes its predicted precision: the standard deviation of its position,
/// `√(σa² + σb²) / sin θ`, where `σa`, `σb` are the two fits' position deviations at the
/// crossing (each from its points' scatter about the fit and the fit's leverage there)
/// and `θ` the angle between them: what the extraction itself says about where the
/// crossing is, whatever planes are later fitted to it. Steger points a pixel apart
/// share part of their noise, so this reads low; the estimator's check
/// ([`crate::pipeline`]) measures its ratio to the residuals of true planes.
///
/// `None` when a fit is impossible (too few points) or the refined point moves more
/// than `radius` (the fits do not meet near the crossing): keep `u` then.
pub fn refine_crossing(
    a: &[[f64; 2]],
    b: &[[f64; 2]],
    u: [f64; 2],
    radius: f64,
) -> Option<RefinedCrossing> {
    let fa = LocalQuadratic::fit(dense_run(a, u, radius, max_step(a)))?;
    let fb = LocalQuadratic::fit(dense_run(b, u, radius, max_step(b)))?;
    let (mut t, mut s) = (fa.param_of(u), fb.param_of(u));
    for _ in 0..8 {
        let (pa, pb) = (fa.at(t), fb.at(s));
        let (ta, tb) = (fa.tangent(t), fb.tangent(s));
        // pa(t) − pb(s) = 0: Jacobian [ta, −tb].
        let (ex, ey) = (pa[0] - pb[0], pa[1] - pb[1]);
        let det = ta[0] * (-tb[1]) - (-tb[0]) * ta[1];
        if det.abs() < 1e-12 {
            return None;
        }
        let dt = (ex * (-tb[1]) - (-tb[0]) * ey) / det;
        let ds = (ta[0] * ey - ta[1] * ex) / det;
        t -= dt;
        s -= ds;
        if dt.abs() + ds.abs() < 1e-15 {
            break;
        }
    }
    let p = fa.at(t);
    let q = fb.at(s);
    let moved = (p[0] - u[0]).hypot(p[1] - u[1]);
    if !moved.is_finite()
        || moved > radius
        || (p[0] - q[0]).hypot(p[1] - q[1]) > 1e-9 * (1.0 + radius)
    {
        return None;
    }
    let (ta, tb) = (fa.tangent(t), fb.tangent(s));
    let sin = cross2(ta, tb).abs() / (ta[0].hypot(ta[1]) * tb[0].hypot(tb[1]));
    let sigma = ((fa.position_variance(t) + fb.position_variance(s)).max(0.0)).sqrt() / sin;
    Some(RefinedCrossing {
        u: p,
        sigma: if sigma.is_finite() { sigma } else { 0.0 },
    })
}

/// A crossing moved onto the dense points ([`refine_crossing`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RefinedCrossing {
    /// Normalised image coordinates.
    pub u: [f64; 2],
    /// Predicted standard deviation of its position, normalised units (0: unknown).
    pub sigma: f64,
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::solve::synthetic::{analytic_crossings, curve_polyline, random_scan, ScanSpec};

    /// The skipping search finds the very point a full scan finds, the first of equals,
    /// on walks that wander back, stall, repeat points and jump.
    #[test]
    fn nearest_index_is_the_full_scans_answer() {
        let mut rng = crate::rng::SplitMix64::new(7);
        for case in 0..400 {
            let n = 1 + (rng.next_u64() % 300) as usize;
            let mut p = [0.0f64, 0.0];
            let mut heading = 0.0f64;
            let points: Vec<[f64; 2]> = (0..n)
                .map(|_| {
                    heading += (rng.next_f64() - 0.5) * if case % 3 == 0 { 3.0 } else { 0.3 };
                    let step = match rng.next_u64() % 10 {
                        0 => 0.0,
                        1 => 5.0 * rng.next_f64(),
                        _ => 0.5 + 0.7 * rng.next_f64(),
                    };
                    p = [p[0] + step * heading.cos(), p[1] + step * heading.sin()];
                    // Integer grids make exact ties.
                    if case % 5 == 0 {
                        [p[0].round(), p[1].round()]
                    } else {
                        p
                    }
                })
                .collect();
            let m = max_step(&points);
            for _ in 0..20 {
                let k = (rng.next_u64() % n as u64) as usize;
                let near = [
                    points[k][0] + 20.0 * (rng.next_f64() - 0.5),
                    points[k][1] + 20.0 * (rng.next_f64() - 0.5),
                ];
                let d2 = |q: &[f64; 2]| (q[0] - near[0]).powi(2) + (q[1] - near[1]).powi(2);
                let full = (0..n).min_by(|&i, &j| d2(&points[i]).total_cmp(&d2(&points[j])));
                assert_eq!(nearest_index(&points, near, m), full, "case {case}");
                let guess = (rng.next_u64() % (n as u64 + 2)) as usize;
                assert_eq!(
                    nearest_index_from(&points, near, m, guess),
                    full,
                    "case {case}, from {guess}"
                );
            }
        }
        // Out and straight back, the way back a little closer: the return must not be
        // skipped past its nearest point.
        for (step, off) in [(1.0, 0.2), (0.7, 0.01), (1.3, 0.0)] {
            let out = (0..40).map(|k| [-10.0 + step * k as f64, 0.3]);
            let back = (0..40).map(|k| [-10.0 + step * (39 - k) as f64, 0.3 - off]);
            let points: Vec<[f64; 2]> = out.chain(back).collect();
            for x in [-3.0, 0.0, 0.35, 7.0] {
                let near = [x, 0.0];
                let d2 = |q: &[f64; 2]| (q[0] - near[0]).powi(2) + (q[1] - near[1]).powi(2);
                let full =
                    (0..points.len()).min_by(|&i, &j| d2(&points[i]).total_cmp(&d2(&points[j])));
                assert_eq!(nearest_index(&points, near, max_step(&points)), full);
                let whole = dense_run(&points, near, 2.5, max_step(&points));
                for guess in [0, 20, 39, 40, 41, 60, 79] {
                    let from = nearest_index_from(&points, near, max_step(&points), guess);
                    assert_eq!(from, full, "from {guess}");
                    // The run about the nearest point is the same from any guess.
                    let run = dense_run_from(&points, near, 2.5, max_step(&points), guess);
                    assert_eq!(
                        (run.as_ptr(), run.len()),
                        (whole.as_ptr(), whole.len()),
                        "run from {guess}"
                    );
                }
            }
        }
        assert_eq!(nearest_index(&[], [0.0, 0.0], 1.0), None);
        assert_eq!(nearest_index_from(&[], [0.0, 0.0], 1.0, 3), None);
    }

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

    #[test]
    fn refined_crossings_reach_the_dense_curves_accuracy() {
        // Two circles of known intersection, densely sampled at 1 px steps (f = 1000),
        // then simplified like the extractor does: the polyline crossing is off by up
        // to the tolerance, the refined one is exact to the fit's model error.
        let f = 1000.0;
        let circle = |cx: f64, cy: f64, r: f64, a0: f64, a1: f64| -> Vec<[f64; 2]> {
            let n = ((a1 - a0) * r * f).abs().ceil() as usize;
            (0..=n)
                .map(|i| {
                    let a = a0 + (a1 - a0) * i as f64 / n as f64;
                    [cx + r * a.cos(), cy + r * a.sin()]
                })
                .collect()
        };
        let a = circle(0.0, 0.0, 0.3, -0.5, 1.5);
        let b = circle(0.35, 0.1, 0.25, 1.2, 4.2);
        // Analytic intersection of the two circles (the one inside both arcs).
        let (d, r0, r1) = ((0.35f64).hypot(0.1), 0.3, 0.25);
        let l = (r0 * r0 - r1 * r1 + d * d) / (2.0 * d);
        let h = (r0 * r0 - l * l).sqrt();
        let (ex, ey) = (0.35 / d, 0.1 / d);
        let candidates = [
            [l * ex - h * ey, l * ey + h * ex],
            [l * ex + h * ey, l * ey - h * ex],
        ];
        // Every 25th point: chords of 25 px on radii of 250-300 px stand off the arc
        // by up to 0.3 px, like a Douglas-Peucker polyline of that tolerance.
        let simplify = |pts: &[[f64; 2]]| -> Vec<[f64; 2]> {
            let mut out: Vec<[f64; 2]> = pts.iter().step_by(25).copied().collect();
            if let Some(last) = pts.last() {
                out.push(*last);
            }
            out
        };
        let (pa, pb) = (simplify(&a), simplify(&b));
        let found = find_crossings(&[&pa, &pb], 0.1);
        assert_eq!(found.len(), 1, "{found:?}");
        let u = found[0].u;
        let truth = *candidates
            .iter()
            .min_by(|p, q| {
                (p[0] - u[0])
                    .hypot(p[1] - u[1])
                    .total_cmp(&(q[0] - u[0]).hypot(q[1] - u[1]))
            })
            .expect("two candidates");
        let before = (u[0] - truth[0]).hypot(u[1] - truth[1]) * f;
        let refined = refine_crossing(&a, &b, u, 6.0 / f).expect("refines").u;
        let after = (refined[0] - truth[0]).hypot(refined[1] - truth[1]) * f;
        assert!(
            after < 0.002,
            "refined crossing off by {after} px (polyline: {before} px)"
        );
        assert!(
            after < before,
            "refinement made it worse: {after} vs {before} px"
        );
    }

    /// With independent noise on the dense points, the predicted deviation of a refined
    /// crossing matches the scatter of the crossing over many noise draws, at 90° and
    /// at a shallow angle (where it is twice as large, from `1 / sin θ`).
    #[test]
    fn the_predicted_precision_of_a_crossing_matches_its_scatter() {
        use crate::solve::synthetic::Rng;
        let f = 1000.0;
        let noise_px = 0.1;
        let mut rng = Rng::new(11);
        for angle in [std::f64::consts::FRAC_PI_2, std::f64::consts::FRAC_PI_6] {
            let (c, s) = (angle.cos(), angle.sin());
            let (mut sq, mut predicted) = (0.0, Vec::new());
            let draws = 400;
            for _ in 0..draws {
                let mut line = |dir: [f64; 2]| -> Vec<[f64; 2]> {
                    (-20..=20)
                        .map(|i| {
                            let (t, e) = (i as f64 / f, noise_px * rng.normal() / f);
                            [t * dir[0] - e * dir[1], t * dir[1] + e * dir[0]]
                        })
                        .collect()
                };
                let (a, b) = (line([1.0, 0.0]), line([c, s]));
                let r = refine_crossing(&a, &b, [0.0, 0.0], 6.0 / f).expect("refines");
                sq += (r.u[0] * r.u[0] + r.u[1] * r.u[1]) * f * f;
                predicted.push(r.sigma * f);
            }
            let measured = (sq / draws as f64).sqrt();
            predicted.sort_by(f64::total_cmp);
            let typical = predicted[draws / 2];
            assert!(
                (typical / measured - 1.0).abs() < 0.2,
                "angle {angle}: predicted {typical} px, measured {measured} px"
            );
        }
    }

    #[test]
    fn refinement_refuses_curves_that_do_not_meet_nearby() {
        let line = |y: f64| -> Vec<[f64; 2]> { (0..40).map(|i| [i as f64 * 1e-3, y]).collect() };
        // Parallel dense runs: no intersection.
        assert!(refine_crossing(&line(0.0), &line(0.001), [0.02, 0.0], 0.006).is_none());
        // Too few points near the crossing.
        let vertical: Vec<[f64; 2]> = (0..3).map(|i| [0.02, i as f64 * 1e-3]).collect();
        assert!(refine_crossing(&line(0.0), &vertical, [0.02, 0.0], 0.006).is_none());
    }

    #[test]
    fn an_absurd_focal_length_leaves_segments_out_instead_of_spinning() {
        // fx = 1e300 makes cells of 1e-299: each segment would cover 2^64 cells.
        let mut index = SegmentIndex::for_image(1920, 1080, 1e300, 0.1);
        let a = [[-0.5, 0.0], [0.5, 0.0]];
        let b = [[0.0, -0.5], [0.0, 0.5]];
        assert!(index.insert(0, &a).is_empty());
        assert!(index.insert(1, &b).is_empty());
        assert_eq!(index.segments_too_long(), 2);
        // The same curves with a sane focal length cross once, nothing left out.
        let mut index = SegmentIndex::for_image(1920, 1080, 1400.0, 0.1);
        assert!(index.insert(0, &a).is_empty());
        assert_eq!(index.insert(1, &b).len(), 1);
        assert_eq!(index.segments_too_long(), 0);
    }
}
