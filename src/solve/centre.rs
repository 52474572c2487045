//! A start for scans whose crossings give the linear start nothing to stand on: the
//! hand's centre taken as one point, found by a search over its direction.
//!
//! Owns this start only; [`super::calibrate`] calls it when the linear start fails, and
//! the joint estimator then frees every pose (the hand drifts; the motion terms follow
//! it).
//!
//! The linear start needs curves whose crossings leave one image line (bend): a table
//! top gives few (only the stripes over the objects bend), and a standing hand in a
//! plain room gives few crosses with both planes among them. Yet every laser plane of a
//! hand-held cross passes near the hand. A plane through the point `c` is
//! `v = c/|c|² + P p` with `P` a basis of the directions orthogonal to `c` and `p ∈ R²`,
//! and the coplanarity of a crossing, `(v_a − v_b) · u = 0`, is then homogeneous in the
//! `p`: `(p_a − p_b) · Pᵀu = 0`. Its null space holds the common shift of all `p` (two
//! directions, the projective family `v + w` with `w ⟂ c`), the solution, up to its
//! scale, and for a scene that is one plane (a table top) one more: there every plane
//! through its line on the table and `c` fits, for any table. So the planes are
//! `c/|c|² + P (q + Σ s_j x_j)` over the one or two smallest null vectors `x_j` beyond
//! the shift, and the orthogonality of the crosses fixes `q` and the `s_j` (a small
//! least-squares problem). The global scale is `|c|`, so `c` is searched over
//! directions only: a Fibonacci sphere, each direction scored by the orthogonality it
//! leaves, on every third frame; the best few refined on shrinking caps around them; the
//! best of those solved on every frame.
//!
//! # The twin
//! Planes through one centre have an exact second solution: their reflection through
//! it, `v' = 2c/|c|² − v` (here `p → −p`). It passes through `c` too, meets every
//! crossing as `v` does (`(v'_a − v'_b) · u = −(v_a − v_b) · u`), and keeps every cross
//! orthogonal (`v'_a · v'_b = 4/|c|² − 2(v_a + v_b) · c/|c|² + v_a · v_b = v_a · v_b`).
//! Its depths are `1/Z' = 2 c · u/|c|² − 1/Z`, all positive wherever the lit surface
//! lies beyond the plane halfway from the camera to the hand, which is almost always.
//! So nothing this start sees tells the two apart: which one its search returned was
//! decided by rounding (on a table top, a change of rounding in the eigensolver turned
//! a right cloud into its twin, 96 % of the points on wrong planes, with no check
//! failing). Only the hand's walk, which the joint estimator models, breaks the tie.
//! Both are returned; the caller refines both and its score chooses, or reports the
//! other as a second solution that fits about as well.

use faer::Mat;
use nalgebra::{DMatrix, DVector, Vector3};
use rayon::prelude::*;

use super::dense::DenseThreads;
use super::evidence::{CrossingClass, Evidence};
use super::subspace::{smallest_pairs, Wanted};

type V3 = Vector3<f64>;

/// Directions of the first search.
const SEARCH_DIRECTIONS: usize = 400;
/// Frames used by the search: every this many.
const SEARCH_FRAME_STEP: u32 = 3;
/// Directions refined, and the refinement's rounds.
const REFINED: usize = 3;
const REFINE_ROUNDS: usize = 8;
/// A second null vector counts (a scene that is one plane, where every table through the
/// lines fits) when its eigenvalue, the coplanarity residual it leaves, is within this
/// factor of the solution's own, which is the crossings' noise: relief below the noise
/// does not tell one table from another.
const SECOND_NULL_NOISE: f64 = 2.0;

/// The fixed-centre start: the planes of the best centre and their twin.
#[derive(Clone, Debug)]
pub struct CentreStart {
    /// Per plane of the evidence (`v · r = 1/Z`), the planes the search found and their
    /// reflection through the centre (see the module docs), which fits alike.
    pub twins: [Vec<Option<V3>>; 2],
    /// The RMS orthogonality (cosine) both leave.
    pub orthogonality_rms: f64,
}

/// The planes of the best fixed centre and their twin; `None` when no direction gives
/// planes. Gives up (`None`) once `cancel` is set.
pub fn fixed_centre_start(evidence: &Evidence, cancel: &super::Cancel) -> Option<CentreStart> {
    let sub = Sample::new(evidence, |f| f % SEARCH_FRAME_STEP == 0);
    // Each direction is scored on its own (in parallel, in order: the answer does not
    // depend on the number of threads).
    let mut scored: Vec<(f64, V3)> = fibonacci(SEARCH_DIRECTIONS)
        .into_par_iter()
        .filter_map(|c| {
            if cancel.is_cancelled() {
                return None;
            }
            sub.score(&c).map(|s| (s, c))
        })
        .collect();
    if cancel.is_cancelled() {
        return None;
    }
    scored.sort_by(|a, b| a.0.total_cmp(&b.0));
    scored.truncate(REFINED);
    // Refine each on shrinking caps of directions around it.
    let step0 = (4.0 * std::f64::consts::PI / SEARCH_DIRECTIONS as f64).sqrt();
    for entry in &mut scored {
        let mut step = step0;
        for _ in 0..REFINE_ROUNDS {
            if cancel.is_cancelled() {
                return None;
            }
            let ring: Vec<(Option<f64>, V3)> = cap(&entry.1, step)
                .into_par_iter()
                .map(|c| (sub.score(&c), c))
                .collect();
            for (s, c) in ring {
                if let Some(s) = s {
                    if s < entry.0 {
                        *entry = (s, c);
                    }
                }
            }
            step *= 0.4;
        }
    }
    let (_, c) = scored.into_iter().min_by(|a, b| a.0.total_cmp(&b.0))?;
    let all = Sample::new(evidence, |_| true);
    let (planes, score) = all.planes(&c)?;
    let twin = |reflect: bool| {
        let mut out = vec![None; evidence.planes.len()];
        for (k, &i) in all.planes.iter().enumerate() {
            out[i] = Some(if reflect {
                2.0 * c - planes[k]
            } else {
                planes[k]
            });
        }
        out
    };
    tracing::debug!(centre_direction = ?c, orthogonality_rms = score, "fixed-centre start");
    Some(CentreStart {
        twins: [twin(false), twin(true)],
        orthogonality_rms: score,
    })
}

/// The planes and crossings of some frames, in local indices.
struct Sample {
    /// Evidence plane of each local plane.
    planes: Vec<usize>,
    /// Crossings among the local planes (local a, local b, u).
    crossings: Vec<(usize, usize, V3)>,
    /// Crosses: local indices of the two planes of one pose.
    crosses: Vec<(usize, usize)>,
}

impl Sample {
    fn new(evidence: &Evidence, keep_frame: impl Fn(u32) -> bool) -> Self {
        // Only planes with two crossings among the kept frames: one without any adds a
        // free direction to the null space, and would be taken for the solution.
        let kept =
            |i: u32| keep_frame(evidence.pose_frames[evidence.planes[i as usize].pose as usize]);
        let mut count = vec![0usize; evidence.planes.len()];
        for c in &evidence.crossings {
            if c.class == CrossingClass::Strong && kept(c.a) && kept(c.b) {
                count[c.a as usize] += 1;
                count[c.b as usize] += 1;
            }
        }
        let mut local = vec![None; evidence.planes.len()];
        let mut planes = Vec::new();
        for i in 0..evidence.planes.len() {
            if count[i] >= 2 {
                local[i] = Some(planes.len());
                planes.push(i);
            }
        }
        let crossings = evidence
            .crossings
            .iter()
            .filter(|c| c.class == CrossingClass::Strong)
            .filter_map(|c| {
                Some((
                    local[c.a as usize]?,
                    local[c.b as usize]?,
                    V3::new(c.u[0], c.u[1], 1.0),
                ))
            })
            .collect();
        let crosses = evidence
            .planes_of_poses()
            .iter()
            .filter_map(|p| match p {
                [Some(a), Some(b)] => Some((local[*a as usize]?, local[*b as usize]?)),
                _ => None,
            })
            .collect();
        Self {
            planes,
            crossings,
            crosses,
        }
    }

    /// The planes through the unit `c` (see the module docs) and the RMS cosine of their
    /// crosses.
    fn planes(&self, c: &V3) -> Option<(Vec<V3>, f64)> {
        let n = self.planes.len();
        if n < 6 || self.crosses.len() < 4 {
            return None;
        }
        let e1 = if c.x.abs() < 0.9 { V3::x() } else { V3::y() };
        let e1 = (e1 - c * c.dot(&e1)).normalize();
        let e2 = c.cross(&e1);
        let dim = 2 * n;
        let mut m = Mat::<f64>::zeros(dim, dim);
        for &(a, b, u) in &self.crossings {
            let w = 1.0 / u.norm_squared();
            let g = [e1.dot(&u), e2.dot(&u)];
            for i in 0..2 {
                for j in 0..2 {
                    let x = w * g[i] * g[j];
                    m[(2 * a + i, 2 * a + j)] += x;
                    m[(2 * b + i, 2 * b + j)] += x;
                    m[(2 * a + i, 2 * b + j)] -= x;
                    m[(2 * b + i, 2 * a + j)] -= x;
                }
            }
        }
        // The common shift of every p is null: move it to the mean eigenvalue.
        let rho = (0..dim).map(|i| m[(i, i)]).sum::<f64>() / dim as f64;
        if !(rho > 0.0 && rho.is_finite()) {
            return None;
        }
        for i in 0..dim {
            for j in 0..dim {
                if i % 2 == j % 2 {
                    m[(i, j)] += rho / n as f64;
                }
            }
        }
        let pairs = smallest_pairs(&m, Wanted::SmallestTwo, DenseThreads::default())?;
        let second_null = pairs.values[1] < SECOND_NULL_NOISE * pairs.values[0];
        let xs: Vec<&Vec<f64>> = if second_null {
            pairs.vectors.iter().collect()
        } else {
            vec![&pairs.vectors[0]]
        };
        let plane = |theta: &[f64], i: usize| {
            let mut p = [theta[0], theta[1]];
            for (j, x) in xs.iter().enumerate() {
                p[0] += theta[2 + j] * x[2 * i];
                p[1] += theta[2 + j] * x[2 * i + 1];
            }
            c + e1 * p[0] + e2 * p[1]
        };
        // The null vectors' entries at each cross's two planes, gathered once: the
        // residuals are evaluated some thousands of times per direction, and read
        // them from contiguous columns, with the same arithmetic as `plane`'s (so the
        // same bits).
        let columns = cross_columns(&xs, &self.crosses);
        let frame = (*c, e1, e2);
        let residuals = |theta: &[f64]| -> DVector<f64> {
            match &columns[..] {
                [x] => cross_cosines::<1>(theta, [x], frame),
                [x, y] => cross_cosines::<2>(theta, [x, y], frame),
                _ => unreachable!("one or two null vectors"),
            }
        };
        let k = 2 + xs.len();
        let scale = (n as f64).sqrt();
        let mut best: Option<(f64, Vec<f64>)> = None;
        for s1 in [0.5, 2.0, 8.0, -0.5, -2.0, -8.0] {
            let mut theta = vec![0.0; k];
            theta[2] = s1 * scale;
            let (t, cost) = levenberg_marquardt(&residuals, theta);
            if cost.is_finite() && best.as_ref().is_none_or(|b| cost < b.0) {
                best = Some((cost, t));
            }
        }
        let (cost, theta) = best?;
        let planes = (0..n).map(|i| plane(&theta, i)).collect();
        Some((planes, (cost / self.crosses.len() as f64).sqrt()))
    }

    fn score(&self, c: &V3) -> Option<f64> {
        self.planes(c).map(|(_, s)| s)
    }
}

/// Per null vector of `xs`, its entries at the two planes of each of `crosses`: the
/// columns `[x_a, y_a, x_b, y_b]` that [`cross_cosines`] reads.
fn cross_columns(xs: &[&Vec<f64>], crosses: &[(usize, usize)]) -> Vec<[Vec<f64>; 4]> {
    let at = |x: &[f64], pick: fn(&(usize, usize)) -> usize, half: usize| -> Vec<f64> {
        crosses.iter().map(|c| x[2 * pick(c) + half]).collect()
    };
    xs.iter()
        .map(|x| {
            [
                at(x, |c| c.0, 0),
                at(x, |c| c.0, 1),
                at(x, |c| c.1, 0),
                at(x, |c| c.1, 1),
            ]
        })
        .collect()
}

/// The cosine of each cross (see [`Sample::planes`]) for the unknowns `theta`: `q` and
/// the weights of the `N` null vectors, whose entries at the crosses' planes `x` holds
/// (`[x_a, y_a, x_b, y_b]` per vector, a column each).
fn cross_cosines<const N: usize>(
    theta: &[f64],
    x: [&[Vec<f64>; 4]; N],
    (c, e1, e2): (V3, V3, V3),
) -> DVector<f64> {
    let n = x[0][0].len();
    let mut out = DVector::zeros(n);
    for (i, r) in out.iter_mut().enumerate() {
        let mut pa = [theta[0], theta[1]];
        let mut pb = [theta[0], theta[1]];
        for (j, x) in x.iter().enumerate() {
            pa[0] += theta[2 + j] * x[0][i];
            pa[1] += theta[2 + j] * x[1][i];
            pb[0] += theta[2 + j] * x[2][i];
            pb[1] += theta[2 + j] * x[3][i];
        }
        let va = c + e1 * pa[0] + e2 * pa[1];
        let vb = c + e1 * pb[0] + e2 * pb[1];
        *r = va.dot(&vb) / (va.norm() * vb.norm()).max(f64::MIN_POSITIVE);
    }
    out
}

/// Levenberg–Marquardt with forward-difference derivatives, for a handful of unknowns.
fn levenberg_marquardt(
    residuals: &dyn Fn(&[f64]) -> DVector<f64>,
    mut theta: Vec<f64>,
) -> (Vec<f64>, f64) {
    let k = theta.len();
    let mut r = residuals(&theta);
    let mut cost = r.norm_squared();
    let mut mu = 1e-3;
    for _ in 0..100 {
        let mut jac = DMatrix::zeros(r.len(), k);
        for j in 0..k {
            let h = 1e-7 * (1.0 + theta[j].abs());
            let mut t = theta.clone();
            t[j] += h;
            let rj = residuals(&t);
            for i in 0..r.len() {
                jac[(i, j)] = (rj[i] - r[i]) / h;
            }
        }
        let jtj = jac.transpose() * &jac;
        let g = jac.transpose() * &r;
        let mut improved = false;
        while mu < 1e10 {
            let mut a = jtj.clone();
            for d in 0..k {
                a[(d, d)] += mu * jtj[(d, d)].max(1e-12);
            }
            let Some(step) = a.cholesky().map(|ch| ch.solve(&(-&g))) else {
                mu *= 10.0;
                continue;
            };
            let trial: Vec<f64> = theta.iter().zip(step.iter()).map(|(t, s)| t + s).collect();
            let rt = residuals(&trial);
            let ct = rt.norm_squared();
            if ct.is_finite() && ct < cost {
                improved = cost - ct > 1e-12 * cost;
                theta = trial;
                r = rt;
                cost = ct;
                mu = (mu * 0.3).max(1e-12);
                break;
            }
            mu *= 10.0;
        }
        if !improved {
            break;
        }
    }
    (theta, cost)
}

/// `n` directions spread evenly over the sphere.
fn fibonacci(n: usize) -> Vec<V3> {
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    (0..n)
        .map(|i| {
            let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
            let r = (1.0 - z * z).sqrt();
            let phi = golden * i as f64;
            V3::new(r * phi.cos(), r * phi.sin(), z)
        })
        .collect()
}

/// Directions around `c` on a ring and its centre, `step` radians apart.
fn cap(c: &V3, step: f64) -> Vec<V3> {
    let e1 = if c.x.abs() < 0.9 { V3::x() } else { V3::y() };
    let e1 = (e1 - c * c.dot(&e1)).normalize();
    let e2 = c.cross(&e1);
    let mut out = Vec::new();
    for i in -2i32..=2 {
        for j in -2i32..=2 {
            if i != 0 || j != 0 {
                let d = c + (e1 * i as f64 + e2 * j as f64) * (0.5 * step);
                out.push(d.normalize());
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::solve::evidence::{Observation, PlaneSlot, RayModel};
    use crate::solve::synthetic::{analytic_crossings, path_scan, PathSpec, Scene};

    /// The crosses' cosines from the gathered columns are, to the bit, those of the
    /// planes `c + P p` each made on its own from the null vectors' entries, with one
    /// null vector and with two.
    #[test]
    fn gathered_cosines_are_the_planes_own() {
        let c = V3::new(0.3, -0.2, 0.9).normalize();
        let (e1, e2) = (V3::x(), c.cross(&V3::x()).normalize());
        let n = 9;
        let x: Vec<Vec<f64>> = (0..2)
            .map(|j| (0..2 * n).map(|i| ((i * 7 + j * 3) as f64).sin()).collect())
            .collect();
        let crosses = [(0, 1), (2, 5), (4, 3), (8, 6), (7, 0)];
        let theta = [0.11, -0.07, 0.5, -1.3];
        for m in 1..=2 {
            let xs: Vec<&Vec<f64>> = x.iter().take(m).collect();
            let got = match &cross_columns(&xs, &crosses)[..] {
                [a] => cross_cosines::<1>(&theta, [a], (c, e1, e2)),
                [a, b] => cross_cosines::<2>(&theta, [a, b], (c, e1, e2)),
                _ => unreachable!("one or two vectors"),
            };
            let plane = |i: usize| {
                let mut p = [theta[0], theta[1]];
                for (j, x) in x.iter().take(m).enumerate() {
                    p[0] += theta[2 + j] * x[2 * i];
                    p[1] += theta[2 + j] * x[2 * i + 1];
                }
                c + e1 * p[0] + e2 * p[1]
            };
            for (k, &(a, b)) in crosses.iter().enumerate() {
                let (va, vb) = (plane(a), plane(b));
                let want = va.dot(&vb) / (va.norm() * vb.norm()).max(f64::MIN_POSITIVE);
                assert_eq!(got[k].to_bits(), want.to_bits(), "{m} vectors, cross {k}");
            }
        }
    }

    /// A table top with a shallow crease (half a degree): the curves barely bend, so the
    /// linear start has little to stand on; the fixed centre finds the planes. (On a table
    /// that is one exact plane the start is not determined; on steeper folds the search
    /// can settle in a wrong basin: the joint estimator and the generality bench judge it.)
    #[test]
    fn a_standing_hand_over_a_table_is_found_from_its_centre() {
        let table = Scene {
            facets: vec![V3::new(0.02, -1.1, 0.6), V3::new(0.03, -1.1, 0.6)],
            window: [-0.5, 0.5, -0.4, 0.4],
        };
        let spec = PathSpec {
            frames: 60,
            drift: 0.0,
            centre: V3::new(0.35, -0.25, 0.05),
            scene: table,
            ..PathSpec::default()
        };
        let scan = path_scan(&spec);
        let planes = scan.flat_planes();
        let crossings: Vec<Observation> = analytic_crossings(&scan.scene, &planes, 0.1)
            .into_iter()
            .map(|c| Observation {
                a: c.a,
                b: c.b,
                u: c.u,
                sin_angle: c.sin_angle,
                class: CrossingClass::Strong,
            })
            .collect();
        let ev = Evidence {
            pose_frames: (0..60).collect(),
            anchors: Vec::new(),
            planes: (0..120)
                .map(|i| PlaneSlot {
                    pose: i / 2,
                    laser: (i % 2) as u8,
                })
                .collect(),
            crossings,
            focal_px: 1000.0,
            rays: RayModel::default(),
        };
        let start = fixed_centre_start(&ev, &Default::default()).expect("a start");
        assert!(
            start.orthogonality_rms < 1e-3,
            "orthogonality {}",
            start.orthogonality_rms
        );
        // Each twin's worst relative depth error at the crossings, after its one global
        // scale: one twin is the truth; the other is another scene.
        let worst = |found: &[Option<V3>]| {
            let ratios: Vec<f64> = ev
                .crossings
                .iter()
                .map(|c| {
                    let u = V3::new(c.u[0], c.u[1], 1.0);
                    let v = found[c.a as usize].expect("plane");
                    planes[c.a as usize].dot(&u) / v.dot(&u)
                })
                .collect();
            let s = crate::solve::median(ratios.clone()).expect("crossings");
            ratios
                .iter()
                .map(|r| (r / s - 1.0).abs())
                .fold(0.0, f64::max)
        };
        let [a, b] = &start.twins;
        let (right, twin) = if worst(a) < worst(b) { (a, b) } else { (b, a) };
        assert!(
            worst(right) < 1e-3,
            "worst relative depth error {}",
            worst(right)
        );
        assert!(
            worst(twin) > 0.05,
            "the twin is the same scene: {}",
            worst(twin)
        );
        // The twin fits the evidence exactly as well: each crossing's coplanarity
        // residual and each cross's cosine are the right twin's, up to sign.
        let plane = |found: &[Option<V3>], i: usize| found[i].expect("every plane");
        let cosine = |found: &[Option<V3>], i: usize| {
            let (va, vb) = (plane(found, 2 * i), plane(found, 2 * i + 1));
            va.dot(&vb).abs()
        };
        for i in 0..60 {
            let (r, t) = (cosine(right, i), cosine(twin, i));
            assert!((r - t).abs() <= 1e-9 * (1.0 + r), "cross {i}: {r} vs {t}");
        }
        let coplanarity = |found: &[Option<V3>], a: u32, b: u32, u: &V3| {
            (plane(found, a as usize) - plane(found, b as usize)).dot(u)
        };
        for c in &ev.crossings {
            let u = V3::new(c.u[0], c.u[1], 1.0);
            let (r, t) = (
                coplanarity(right, c.a, c.b, &u),
                coplanarity(twin, c.a, c.b, &u),
            );
            assert!((r + t).abs() <= 1e-9, "crossing residuals {r} and {t}");
        }
    }
}
