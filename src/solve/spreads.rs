//! The spreads the joint estimator weighs its residuals by, measured from the residuals
//! themselves: each residual's size standardised by its own redundancy, from the
//! covariance of the estimate ([`measured_spreads`]). Owns only the measurement; the
//! rounds that repeat the minimisation until the spreads settle are in
//! [`super::estimate`].

use faer::Mat;

use super::estimate::{motion_row, Layout, Spreads, State};
use super::pose::POSE_DOF;

/// Floor of every spread, relative to a typical value of its kind: below it the data
/// would be exact to rounding and the weights unbounded.
const SPREAD_FLOOR: f64 = 1e-6;
/// A residual whose redundancy `1 − w h` is below this is absorbed by the estimate and
/// says nothing of its spread.
pub(super) const MIN_REDUNDANCY: f64 = 0.05;

/// `j Σ jᵀ` over the unknowns `idx`.
fn quadratic_form(cov: &Mat<f64>, idx: &[usize], j: &[f64]) -> f64 {
    let mut s = 0.0;
    for (a, &ia) in idx.iter().enumerate() {
        let col = cov.col_as_slice(ia);
        let mut t = 0.0;
        for (b, &ib) in idx.iter().enumerate() {
            t += col[ib] * j[b];
        }
        s += j[a] * t;
    }
    s
}

/// The spreads the residuals at `state` show, per kind (crossings strong, faint; centre;
/// aim; roll): the median of each residual's size standardised by its own redundancy,
/// `|e| / √(1 − w h)` (`w` its robust weight, `h = jΣjᵀ/σ²` its leverage, so that a
/// residual the estimate absorbs, such as the motion term of a centre nothing else
/// places, does not read as small), times 1.4826, over the residuals not absorbed
/// (`1 − w h` over 0.05). A median, not the weighted mean square of variance component
/// estimation: under Cauchy's weights that shrinks the spread each round (the weights
/// take a share of the Gaussian core too), and the shrunken spread raises the share of
/// outliers, so the scan settled where it started. Also returns each kind's redundancy
/// `Σ (w − w h)` and the number of residuals measured.
pub(super) fn measured_spreads(
    layout: &Layout,
    state: &State,
    spreads: &Spreads,
    cov: &Mat<f64>,
) -> (Spreads, [f64; 5]) {
    let mut standardised: [Vec<f64>; 5] = Default::default();
    let mut redundancy = [0.0; 5];
    let mut add = |kind: usize, e: f64, w: f64, h: f64| {
        let r = 1.0 - w * h;
        redundancy[kind] += w * r;
        if r > MIN_REDUNDANCY {
            standardised[kind].push(e.abs() / r.sqrt());
        }
    };
    let ev = layout.evidence;
    let rays = layout.rays(state.focal_scale);
    let fi = layout.focal_index();
    let closs = layout.crossing_loss();
    for k in 0..ev.crossings.len() {
        let Some(t) = layout.crossing(state, k, &rays) else {
            continue;
        };
        let c = &ev.crossings[k];
        let sigma = spreads.crossing_px[c.class as usize];
        let w = closs.weight(t.e / sigma);
        let (pa, pb) = (
            ev.planes[c.a as usize].pose as usize * POSE_DOF,
            ev.planes[c.b as usize].pose as usize * POSE_DOF,
        );
        let mut idx: Vec<usize> = (pa..pa + 6).chain(pb..pb + 6).collect();
        let mut j: Vec<f64> = t.ja.iter().chain(&t.jb).copied().collect();
        if let Some(f) = fi {
            idx.push(f);
            j.push(t.j_scale);
        }
        let h = quadratic_form(cov, &idx, &j) / (sigma * sigma);
        add(c.class as usize, t.e, w, h);
    }
    let mloss = layout.motion_loss();
    for t in &layout.triples {
        let (cm, rm) = layout.motion_terms(state, t);
        let wc = mloss.weight(cm.r.norm() / spreads.centre);
        let wa = mloss.weight(rm.r.xy().norm() / spreads.aim_rad);
        let wr = mloss.weight(rm.r.z / spreads.roll_rad);
        for row in 0..3 {
            let (idx, jr, jc) = motion_row(t, &cm, &rm, row);
            let cidx = idx.map(|i| i + 3);
            let hc = quadratic_form(cov, &cidx, &jc) / spreads.centre.powi(2);
            add(2, cm.r[row], wc, hc);
            let (kind, w, sigma) = if row == 2 {
                (4, wr, spreads.roll_rad)
            } else {
                (3, wa, spreads.aim_rad)
            };
            let hr = quadratic_form(cov, &idx, &jr) / (sigma * sigma);
            add(kind, rm.r[row], w, hr);
        }
    }
    let mut pick = |kind: usize, old: f64| {
        let values = std::mem::take(&mut standardised[kind]);
        match super::median(values) {
            Some(m) if m > 0.0 => (super::MAD_TO_SIGMA * m).max(SPREAD_FLOOR * old),
            _ => old,
        }
    };
    let next = Spreads {
        crossing_px: [
            pick(0, spreads.crossing_px[0]),
            pick(1, spreads.crossing_px[1]),
        ],
        centre: pick(2, spreads.centre),
        aim_rad: pick(3, spreads.aim_rad),
        roll_rad: pick(4, spreads.roll_rad),
    };
    (next, redundancy)
}

/// The largest relative change of any spread from `a` to `b`.
pub(super) fn relative_change(a: &Spreads, b: &Spreads) -> f64 {
    let pairs = [
        (a.crossing_px[0], b.crossing_px[0]),
        (a.crossing_px[1], b.crossing_px[1]),
        (a.centre, b.centre),
        (a.aim_rad, b.aim_rad),
        (a.roll_rad, b.roll_rad),
    ];
    pairs
        .iter()
        .map(|(x, y)| ((x - y) / x.max(f64::MIN_POSITIVE)).abs())
        .fold(0.0, f64::max)
}
