//! Scoring extracted curves against a simulated frame's truth, for benchmarks and
//! tests: recall of lit pixels, sub-pixel error, and points off every stripe. The same
//! metric as the issue-19 comparison with the ImageJ Steger port.
//!
//! Reads the simulator ([`Simulator::stripe_distance_px`] and the lit mask of
//! [`Simulator::render_frame_into`]); changes nothing.

use super::Curve;
use crate::simulate::Simulator;

/// Points within this distance (px) of a lit pixel's centre find it.
pub const RECALL_RADIUS_PX: f64 = 1.0;
/// Points further than this (px) from both stripes are stray.
pub const STRAY_PX: f64 = 2.0;

/// Sums over frames; [`Score::add`] one frame at a time.
#[derive(Clone, Debug, Default)]
pub struct Score {
    /// Visible lit pixels (peak contrast at least the given level) and those found.
    pub lit: usize,
    pub found: usize,
    /// All curve points, and those further than [`STRAY_PX`] from both stripes.
    pub points: usize,
    pub stray: usize,
    /// Distances (px) of the non-stray points from their own laser's stripe.
    pub errors_px: Vec<f64>,
}

impl Score {
    /// Adds frame `index`'s `curves` (lasers indexed as the simulator's), with its
    /// `lit` mask (peak contrast per pixel, 0 off the stripes); lit pixels of at least
    /// `min_contrast` count for recall.
    pub fn add(
        &mut self,
        sim: &Simulator,
        index: usize,
        lit: &[u8],
        min_contrast: u8,
        curves: &[Curve],
    ) {
        let cam = sim.camera();
        let (w, h) = (cam.width as usize, cam.height as usize);
        let pose = sim.pose(index);
        let mut near = vec![false; w * h];
        for c in curves {
            for p in &c.points_px {
                let (x, y) = (p[0] as f64, p[1] as f64);
                for v in
                    (y - 1.0).floor().max(0.0) as usize..=((y + 1.0).ceil() as usize).min(h - 1)
                {
                    for u in
                        (x - 1.0).floor().max(0.0) as usize..=((x + 1.0).ceil() as usize).min(w - 1)
                    {
                        if (u as f64 - x).hypot(v as f64 - y) <= RECALL_RADIUS_PX {
                            near[v * w + u] = true;
                        }
                    }
                }
                self.points += 1;
                let d = |k: usize| sim.stripe_distance_px(&pose, k, x, y).map(f64::abs);
                let own = d(c.laser as usize);
                let other = d(1 - c.laser.min(1) as usize);
                let best = own.into_iter().chain(other).fold(f64::INFINITY, f64::min);
                if best > STRAY_PX {
                    self.stray += 1;
                } else if let Some(e) = own.filter(|&e| e <= STRAY_PX) {
                    self.errors_px.push(e);
                }
            }
        }
        for (l, n) in lit.iter().zip(&near) {
            if *l >= min_contrast.max(1) {
                self.lit += 1;
                self.found += usize::from(*n);
            }
        }
    }

    /// Share of visible lit pixels with a point within [`RECALL_RADIUS_PX`].
    pub fn recall(&self) -> f64 {
        self.found as f64 / self.lit.max(1) as f64
    }

    /// Share of points further than [`STRAY_PX`] from both stripes.
    pub fn stray_share(&self) -> f64 {
        self.stray as f64 / self.points.max(1) as f64
    }

    /// Quantile `q` (0-1) of the sub-pixel errors, px.
    pub fn error_quantile(&self, q: f64) -> f64 {
        if self.errors_px.is_empty() {
            return f64::NAN;
        }
        let mut e = self.errors_px.clone();
        let i = ((q * (e.len() - 1) as f64).round() as usize).min(e.len() - 1);
        *e.select_nth_unstable_by(i, f64::total_cmp).1
    }
}
