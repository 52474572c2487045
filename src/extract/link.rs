//! Linking ridge points into ordered polylines (after Steger 1998, §4) and
//! Douglas–Peucker simplification.
//!
//! From the strongest unused point above the high threshold, the line is followed in
//! both directions: at each step the three neighbour pixels ahead (in the octant of the
//! line direction) are examined, and the one minimising distance plus angle change is
//! taken, provided its direction differs by less than the maximum angle. The trace
//! stops when no neighbour qualifies, when the best neighbour already belongs to a
//! curve (a junction: the crossing of two curves), or when the two diagonal neighbours
//! qualify but the one straight ahead does not (a fork: ambiguous). Where no neighbour
//! qualifies, a gap of up to `MAX_GAP_PX` pixels with no linkable point in it is
//! jumped to a point on the line's course (`bridge`).

use super::detect::{LinePoint, NO_POINT};

/// Reused buffers of the linker.
#[derive(Default)]
pub(crate) struct Linker {
    order: Vec<u32>,
    used: Vec<bool>,
    forward: Vec<u32>,
    backward: Vec<u32>,
    chain: Vec<u32>,
}

/// The linker's thresholds, in the detector's strength unit (grey levels).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Hysteresis {
    /// Points weaker than this are never linked.
    pub low: f32,
    /// A chain seeded at a point at least this strong is kept.
    pub high: f32,
    /// A chain seeded at a weaker point, down to this, is kept when it is at least
    /// `faint_min_length_px` long: a faint stripe is long, while noise and texture
    /// that reach past `low` make short chains.
    pub faint_start: f32,
    pub faint_min_length_px: f32,
}

impl Linker {
    /// Calls `emit(chain)` for each linked chain of point indices, in order along the
    /// line. Seeds need `strength >= high`, or `faint_start` for a long chain; points
    /// with `strength < low` are never used.
    pub fn link(
        &mut self,
        points: &[LinePoint],
        index: &[u32],
        (width, height): (usize, usize),
        thresholds: Hysteresis,
        max_angle_rad: f32,
        mut emit: impl FnMut(&[u32]),
    ) {
        let Hysteresis {
            low,
            high,
            faint_start,
            faint_min_length_px,
        } = thresholds;
        let start = faint_start.min(high);
        self.order.clear();
        self.order
            .extend((0..points.len() as u32).filter(|&i| points[i as usize].strength >= start));
        self.order.sort_unstable_by(|&a, &b| {
            points[b as usize]
                .strength
                .total_cmp(&points[a as usize].strength)
        });
        self.used.clear();
        self.used.resize(points.len(), false);
        let cos_max = max_angle_rad.cos();
        for oi in 0..self.order.len() {
            let seed = self.order[oi];
            if self.used[seed as usize] {
                continue;
            }
            self.used[seed as usize] = true;
            let p = points[seed as usize];
            let dir = (-p.ny, p.nx);
            let grid = Grid {
                points,
                index,
                width,
                height,
                low,
                cos_max,
            };
            trace(&grid, seed, dir, &mut self.used, &mut self.forward);
            trace(
                &grid,
                seed,
                (-dir.0, -dir.1),
                &mut self.used,
                &mut self.backward,
            );
            self.chain.clear();
            self.chain.extend(self.backward.iter().rev());
            self.chain.push(seed);
            self.chain.extend_from_slice(&self.forward);
            if p.strength < high {
                let positions = self.chain.iter().map(|&i| {
                    let q = points[i as usize];
                    [q.x, q.y]
                });
                if linked_length_px(positions) < f64::from(faint_min_length_px) {
                    continue;
                }
            }
            emit(&self.chain);
        }
    }
}

struct Grid<'a> {
    points: &'a [LinePoint],
    index: &'a [u32],
    width: usize,
    height: usize,
    low: f32,
    cos_max: f32,
}

/// Follows the line from `start` along `dir`; `out` receives the points after `start`.
fn trace(g: &Grid, start: u32, mut dir: (f32, f32), used: &mut [bool], out: &mut Vec<u32>) {
    out.clear();
    let mut cur = start;
    loop {
        let p = g.points[cur as usize];
        let (px, py) = (
            (p.pixel as usize % g.width) as isize,
            (p.pixel as usize / g.width) as isize,
        );
        // Octant of the direction, and its two neighbours.
        let octant = (dir.1.atan2(dir.0) / std::f32::consts::FRAC_PI_4).round() as i32;
        let mut best: Option<(u32, f32, (f32, f32))> = None;
        let mut qualified = [false; 3];
        for (slot, d) in [octant - 1, octant, octant + 1].into_iter().enumerate() {
            let (ox, oy) = OCTANT_STEPS[d.rem_euclid(8) as usize];
            let (qx, qy) = (px + ox, py + oy);
            if qx < 0 || qy < 0 || qx >= g.width as isize || qy >= g.height as isize {
                continue;
            }
            let qi = g.index[qy as usize * g.width + qx as usize];
            if qi == NO_POINT {
                continue;
            }
            let q = g.points[qi as usize];
            if q.strength < g.low {
                continue;
            }
            let mut qdir = (-q.ny, q.nx);
            let mut cos = qdir.0 * dir.0 + qdir.1 * dir.1;
            if cos < 0.0 {
                qdir = (-qdir.0, -qdir.1);
                cos = -cos;
            }
            if cos < g.cos_max {
                continue;
            }
            let (dx, dy) = (q.x - p.x, q.y - p.y);
            // Never step backwards along the line.
            if dx * dir.0 + dy * dir.1 <= 0.0 {
                continue;
            }
            qualified[slot] = true;
            let cost = (dx * dx + dy * dy).sqrt() + cos.min(1.0).acos();
            if best.is_none_or(|(_, c, _)| cost < c) {
                best = Some((qi, cost, qdir));
            }
        }
        // Candidates on both sides but not straight ahead are two lines leaving
        // this point (a fork): which one continues is ambiguous, so stop here.
        if qualified[0] && qualified[2] && !qualified[1] {
            return;
        }
        let Some((next, _, next_dir)) = best.or_else(|| bridge(g, &p, dir)) else {
            return;
        };
        if used[next as usize] {
            return;
        }
        used[next as usize] = true;
        out.push(next);
        cur = next;
        dir = next_dir;
    }
}

/// Pixels of missing ridge a trace may jump along its direction.
pub(crate) const MAX_GAP_PX: isize = 3;

/// A step between neighbouring points of a chain this long or longer is a jumped gap:
/// linked neighbours are at most a diagonal pixel apart, give or take their sub-pixel
/// offsets across the line; a jump starts at 2 px along it.
const GAP_STEP_PX: f64 = 1.95;

/// Length of the linked ridge through `positions` (pixels, in order along a chain),
/// without the gaps jumped, which no ridge point vouches for.
pub(crate) fn linked_length_px(positions: impl Iterator<Item = [f32; 2]>) -> f64 {
    let mut total = 0.0;
    let mut last: Option<[f32; 2]> = None;
    for p in positions {
        if let Some(q) = last {
            let d = f64::from(p[0] - q[0]).hypot(f64::from(p[1] - q[1]));
            if d < GAP_STEP_PX {
                total += d;
            }
        }
        last = Some(p);
    }
    total
}

/// Where no neighbour continues the line: the nearest point up to `MAX_GAP_PX` pixels
/// further along `dir`, within a pixel of the line through `p` and turning by less
/// than the maximum angle. A faint stripe on a textured surface dips below `low` for
/// a pixel or two where the surface is dark, and the other laser's stripe where it
/// crosses blocks a few pixels of it; without this the curve ends there. Noise
/// fragments joined this way are still short: the extractor measures a curve's length
/// without its gaps ([`super::Curve::linked_length_px`]).
fn bridge(g: &Grid, p: &LinePoint, dir: (f32, f32)) -> Option<(u32, f32, (f32, f32))> {
    let perp = (-dir.1, dir.0);
    let point_at = |x: f32, y: f32| {
        let (qx, qy) = (x.round() as isize, y.round() as isize);
        if qx < 0 || qy < 0 || qx >= g.width as isize || qy >= g.height as isize {
            return None;
        }
        match g.index[qy as usize * g.width + qx as usize] {
            NO_POINT => None,
            qi => Some(qi),
        }
    };
    for step in 2..=MAX_GAP_PX + 1 {
        // Only across a gap: a point strong enough to link in the pixels passed over
        // is another line (a junction), where the trace stops.
        let blocked = (-1..=1).any(|side| {
            let (x, y) = (
                p.x + (step - 1) as f32 * dir.0 + side as f32 * perp.0,
                p.y + (step - 1) as f32 * dir.1 + side as f32 * perp.1,
            );
            point_at(x, y).is_some_and(|qi| g.points[qi as usize].strength >= g.low)
        });
        if blocked {
            return None;
        }
        let mut best: Option<(u32, f32, (f32, f32))> = None;
        for side in -1..=1 {
            let (x, y) = (
                p.x + step as f32 * dir.0 + side as f32 * perp.0,
                p.y + step as f32 * dir.1 + side as f32 * perp.1,
            );
            let Some(qi) = point_at(x, y) else {
                continue;
            };
            let q = g.points[qi as usize];
            let (dx, dy) = (q.x - p.x, q.y - p.y);
            let (along, across) = (dx * dir.0 + dy * dir.1, dx * perp.0 + dy * perp.1);
            let mut qdir = (-q.ny, q.nx);
            let mut cos = qdir.0 * dir.0 + qdir.1 * dir.1;
            if cos < 0.0 {
                qdir = (-qdir.0, -qdir.1);
                cos = -cos;
            }
            if q.strength < g.low
                || cos < g.cos_max
                || f64::from(along) < GAP_STEP_PX
                || across.abs() > 1.0
            {
                continue;
            }
            if best.is_none_or(|(_, a, _)| across.abs() < a) {
                best = Some((qi, across.abs(), qdir));
            }
        }
        if best.is_some() {
            return best;
        }
    }
    None
}

/// Pixel steps of the eight octants, counter-clockwise from +x in image axes
/// (octant 2 is +y, down).
const OCTANT_STEPS: [(isize, isize); 8] = [
    (1, 0),
    (1, 1),
    (0, 1),
    (-1, 1),
    (-1, 0),
    (-1, -1),
    (0, -1),
    (1, -1),
];

/// Indices of the points kept by Douglas–Peucker with tolerance `tol` (same units as
/// the points), first and last always kept, in order.
pub fn douglas_peucker(points: &[[f64; 2]], tol: f64) -> Vec<usize> {
    let n = points.len();
    if n <= 2 {
        return (0..n).collect();
    }
    let mut keep = vec![false; n];
    keep[0] = true;
    keep[n - 1] = true;
    let mut stack = vec![(0usize, n - 1)];
    while let Some((a, b)) = stack.pop() {
        if b <= a + 1 {
            continue;
        }
        let (pa, pb) = (points[a], points[b]);
        let (ex, ey) = (pb[0] - pa[0], pb[1] - pa[1]);
        let len = (ex * ex + ey * ey).sqrt();
        let mut worst = (0.0, a);
        for (i, p) in points.iter().enumerate().take(b).skip(a + 1) {
            let (vx, vy) = (p[0] - pa[0], p[1] - pa[1]);
            let d = if len > 0.0 {
                (vx * ey - vy * ex).abs() / len
            } else {
                (vx * vx + vy * vy).sqrt()
            };
            if d > worst.0 {
                worst = (d, i);
            }
        }
        if worst.0 > tol {
            keep[worst.1] = true;
            stack.push((a, worst.1));
            stack.push((worst.1, b));
        }
    }
    (0..n).filter(|&i| keep[i]).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Seeds at 2, links down to 1; no faint seeds.
    const HYSTERESIS: Hysteresis = Hysteresis {
        low: 1.0,
        high: 2.0,
        faint_start: 2.0,
        faint_min_length_px: 0.0,
    };

    #[test]
    fn douglas_peucker_keeps_corners_only() {
        // An L of 21 points: straight, a right-angle corner, straight.
        let mut pts: Vec<[f64; 2]> = (0..=10).map(|i| [i as f64, 0.0]).collect();
        pts.extend((1..=10).map(|i| [10.0, i as f64]));
        assert_eq!(douglas_peucker(&pts, 0.3), vec![0, 10, 20]);
        // A gentle arc of sagitta 1 needs inner points at tolerance 0.3, none at 2.
        let arc: Vec<[f64; 2]> = (0..=20)
            .map(|i| {
                let x = i as f64 - 10.0;
                [x, 1.0 - x * x / 100.0]
            })
            .collect();
        assert!(douglas_peucker(&arc, 0.2).len() > 3);
        assert_eq!(douglas_peucker(&arc, 2.0), vec![0, 20]);
        // Every dropped point stays within tolerance of the kept polyline.
        let kept = douglas_peucker(&arc, 0.2);
        for w in kept.windows(2) {
            let (a, b) = (arc[w[0]], arc[w[1]]);
            for p in &arc[w[0]..=w[1]] {
                let (ex, ey) = (b[0] - a[0], b[1] - a[1]);
                let d = ((p[0] - a[0]) * ey - (p[1] - a[1]) * ex).abs() / ex.hypot(ey);
                assert!(d <= 0.2 + 1e-12);
            }
        }
    }

    fn point_at(x: usize, y: usize, w: usize, angle: f32, strength: f32) -> LinePoint {
        // Normal perpendicular to the direction `angle`.
        LinePoint {
            x: x as f32,
            y: y as f32,
            nx: -angle.sin(),
            ny: angle.cos(),
            strength,
            pixel: (y * w + x) as u32,
            ridge: [0.0, 1.0, 0.0, -1.0],
            flank_px: 2.0,
            sigma: 1.0,
        }
    }

    #[test]
    fn stops_at_a_fork() {
        // A horizontal line from x = 0 to 10 on row 10 that forks into two diagonals.
        let (w, h) = (24, 21);
        let mut points = Vec::new();
        let mut index = vec![NO_POINT; w * h];
        let mut add = |x: usize, y: usize, angle: f32, s: f32, points: &mut Vec<LinePoint>| {
            index[y * w + x] = points.len() as u32;
            points.push(point_at(x, y, w, angle, s));
        };
        for x in 0..=10 {
            add(x, 10, 0.0, 10.0, &mut points);
        }
        for k in 1..=8 {
            add(10 + k, 10 - k, -0.3, 5.0, &mut points);
            add(10 + k, 10 + k, 0.3, 5.0, &mut points);
        }
        let mut chains: Vec<Vec<u32>> = Vec::new();
        Linker::default().link(&points, &index, (w, h), HYSTERESIS, 0.9, |c| {
            chains.push(c.to_vec())
        });
        // The stem stops at the fork; each branch is its own chain.
        let stem: Vec<f32> = chains[0].iter().map(|&i| points[i as usize].x).collect();
        assert_eq!(stem.len(), 11, "{stem:?}");
        assert_eq!(chains.len(), 3);
        assert!(chains[1..].iter().all(|c| c.len() == 8));
    }

    #[test]
    fn links_two_crossing_lines_into_separate_chains() {
        let (w, h) = (20, 20);
        let mut points = Vec::new();
        let mut index = vec![NO_POINT; w * h];
        // A horizontal line on row 10 and a vertical one on column 5.
        for x in 0..w {
            index[10 * w + x] = points.len() as u32;
            points.push(point_at(x, 10, w, 0.0, 10.0));
        }
        for y in 0..h {
            if y != 10 {
                index[y * w + 5] = points.len() as u32;
                points.push(point_at(5, y, w, std::f32::consts::FRAC_PI_2, 5.0));
            }
        }
        let mut chains: Vec<Vec<u32>> = Vec::new();
        Linker::default().link(&points, &index, (w, h), HYSTERESIS, 0.5, |c| {
            chains.push(c.to_vec())
        });
        // The horizontal line first (strongest), whole and in order.
        let xs: Vec<f32> = chains[0].iter().map(|&i| points[i as usize].x).collect();
        assert!(xs.windows(2).all(|p| (p[1] - p[0]).abs() == 1.0), "{xs:?}");
        assert_eq!(xs.len(), w);
        // The vertical line is cut at the crossing into two pieces, all points used.
        assert_eq!(chains.len(), 3);
        let vertical: usize = chains[1..].iter().map(|c| c.len()).sum();
        assert_eq!(vertical, h - 1);
    }

    /// A chain that never reaches `high` is kept when it is long enough, and a short
    /// one is not; a strong chain of any length is.
    #[test]
    fn faint_chains_are_kept_only_when_long() {
        let (w, h) = (100, 12);
        let mut points = Vec::new();
        let mut index = vec![NO_POINT; w * h];
        // Row 2: 80 px at strength 1.5; row 6: 30 px at 1.5; row 10: 5 px at 3.
        for (row, len, strength) in [(2, 80, 1.5), (6, 30, 1.5), (10, 5, 3.0)] {
            for x in 0..len {
                index[row * w + x] = points.len() as u32;
                points.push(point_at(x, row, w, 0.0, strength));
            }
        }
        let lengths = |faint_start: f32| {
            let mut lengths: Vec<usize> = Vec::new();
            let thresholds = Hysteresis {
                faint_start,
                faint_min_length_px: 50.0,
                ..HYSTERESIS
            };
            Linker::default().link(&points, &index, (w, h), thresholds, 0.5, |c| {
                lengths.push(c.len())
            });
            lengths.sort_unstable();
            lengths
        };
        assert_eq!(lengths(1.2), vec![5, 80]);
        // Without faint seeds only the strong chain.
        assert_eq!(lengths(2.0), vec![5]);
    }

    /// A line with a gap of up to `MAX_GAP_PX` pixels is one chain; a longer gap ends
    /// it.
    #[test]
    fn gaps_of_a_few_pixels_are_jumped() {
        let (w, h) = (60, 5);
        let chains_with_gap = |gap: usize| {
            let mut points = Vec::new();
            let mut index = vec![NO_POINT; w * h];
            for x in (0..50).filter(|x| !(20..20 + gap).contains(x)) {
                index[2 * w + x] = points.len() as u32;
                points.push(point_at(x, 2, w, 0.0, 10.0));
            }
            let mut lengths: Vec<usize> = Vec::new();
            Linker::default().link(&points, &index, (w, h), HYSTERESIS, 0.5, |c| {
                lengths.push(c.len())
            });
            lengths.sort_unstable();
            lengths
        };
        assert_eq!(chains_with_gap(1), vec![49]);
        assert_eq!(
            chains_with_gap(MAX_GAP_PX as usize),
            vec![50 - MAX_GAP_PX as usize]
        );
        assert_eq!(chains_with_gap(MAX_GAP_PX as usize + 1), vec![20, 26]);
    }
}
