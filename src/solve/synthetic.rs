//! Synthetic scans with known planes, for the tests and benches of [`crate::intersect`]
//! and [`crate::solve`] (the full image simulator lives in [`crate::simulate`]).
//!
//! The scene is a polyhedral "room" seen from inside: facets `s_f · X = 1`,
//! visible inverse depth `ρ(u) = max_f s_f · u` (the nearest facet along each ray). A
//! laser plane `v · X = 1` lights the image points with `v · u = ρ(u)`; on facet `f`
//! that is the image line `(v − s_f) · u = 0`, clipped to where `f` is visible and to
//! the image window. Two planes `i, j` cross on facet `f` at
//! `u ∝ (v_i − s_f) × (v_j − s_f)`, if that point is on `f` and in the window: the
//! analytic truth for the crossings.
//!
//! Crosses: a projector centre `P` jittered around a base point at a baseline from the
//! camera, aimed at a random point of the scene, rolled at random; its two planes
//! contain the aim axis and are orthogonal; a plane with normal `n` through `P` is
//! `v = n / (n · P)`.

use crate::intersect::Crossing;
use crate::rng::SplitMix64;
use crate::solve::evidence::{CrossingClass, Evidence, Observation, PlaneSlot, RayModel};
use nalgebra::Vector3;

/// The simulator's SplitMix64 with the draws synthetic scenes need.
#[derive(Clone, Debug)]
pub struct Rng(SplitMix64);

impl Rng {
    pub fn new(seed: u64) -> Self {
        Self(SplitMix64::new(seed ^ 0x9E37_79B9_7F4A_7C15))
    }

    pub fn next_u64(&mut self) -> u64 {
        self.0.next_u64()
    }

    /// Uniform in `[lo, hi)`.
    pub fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        let unit = (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64;
        lo + (hi - lo) * unit
    }

    /// Standard normal (Box–Muller).
    pub fn normal(&mut self) -> f64 {
        let a = self.uniform(f64::MIN_POSITIVE, 1.0);
        let b = self.uniform(0.0, 1.0);
        (-2.0 * a.ln()).sqrt() * (std::f64::consts::TAU * b).cos()
    }

    /// Uniform index in `0..n` (`n > 0`).
    pub fn index(&mut self, n: usize) -> usize {
        (self.next_u64() % n as u64) as usize
    }
}

/// A polyhedral scene seen from inside and the image window.
#[derive(Clone, Debug)]
pub struct Scene {
    /// Facets `s_f · X = 1`.
    pub facets: Vec<Vector3<f64>>,
    /// Normalised image window `[x_min, x_max, y_min, y_max]`.
    pub window: [f64; 4],
}

impl Default for Scene {
    /// A slightly skewed room about 2 wide, 1.6 high and 3 deep around the camera, a 62° × 48° field of view.
    fn default() -> Self {
        Self {
            facets: vec![
                Vector3::new(-1.0, 0.05, 0.02),
                Vector3::new(0.9, -0.05, 0.03),
                Vector3::new(0.03, 0.02, 0.33),
                Vector3::new(0.05, 1.2, 0.02),
                Vector3::new(-0.02, -1.3, 0.01),
            ],
            window: [-0.6, 0.6, -0.45, 0.45],
        }
    }
}

impl Scene {
    /// Visible inverse depth `ρ(u) = max_f s_f · u` at `(x, y)`.
    pub fn inverse_depth(&self, x: f64, y: f64) -> f64 {
        let u = Vector3::new(x, y, 1.0);
        self.facets
            .iter()
            .map(|s| s.dot(&u))
            .fold(f64::NEG_INFINITY, f64::max)
    }

    fn in_window(&self, x: f64, y: f64) -> bool {
        let [x0, x1, y0, y1] = self.window;
        x > x0 && x < x1 && y > y0 && y < y1
    }
}

/// What [`random_scan`] draws.
#[derive(Clone, Debug)]
pub struct ScanSpec {
    pub num_crosses: usize,
    pub seed: u64,
    /// Base projector centre in camera coordinates.
    pub projector_base: Vector3<f64>,
    /// Half-width of the uniform jitter of the projector centre, per axis.
    pub projector_jitter: f64,
    /// Least distance of a laser plane from the camera centre: planes nearly through
    /// it image as lines whatever the depth, and carry no information.
    pub min_plane_offset: f64,
    pub scene: Scene,
}

impl Default for ScanSpec {
    fn default() -> Self {
        Self {
            num_crosses: 50,
            seed: 1,
            projector_base: Vector3::new(0.6, -0.6, 0.3),
            projector_jitter: 0.15,
            min_plane_offset: 0.3,
            scene: Scene::default(),
        }
    }
}

/// A synthetic scan: curve `2k` and `2k + 1` are the two lasers of cross `k`.
#[derive(Clone, Debug)]
pub struct SyntheticScan {
    pub scene: Scene,
    /// True plane of each curve, `v · X = 1`.
    pub planes: Vec<Vector3<f64>>,
    pub partner: Vec<Option<u32>>,
}

/// Random crosses whose curves are single connected polylines in the window.
pub fn random_scan(spec: &ScanSpec) -> SyntheticScan {
    let mut rng = Rng::new(spec.seed);
    let scene = spec.scene.clone();
    let mut planes = Vec::with_capacity(2 * spec.num_crosses);
    let [x0, x1, y0, y1] = scene.window;
    while planes.len() < 2 * spec.num_crosses {
        let j = spec.projector_jitter;
        let p = spec.projector_base
            + Vector3::new(rng.uniform(-j, j), rng.uniform(-j, j), rng.uniform(-j, j));
        let (tx, ty) = (
            rng.uniform(0.8 * x0, 0.8 * x1),
            rng.uniform(0.8 * y0, 0.8 * y1),
        );
        let target = Vector3::new(tx, ty, 1.0) / scene.inverse_depth(tx, ty);
        let axis = (target - p).normalize();
        let e1 = axis.cross(&Vector3::y()).normalize();
        let e2 = axis.cross(&e1);
        let roll = rng.uniform(0.0, std::f64::consts::PI);
        let n1 = e1 * roll.cos() + e2 * roll.sin();
        let n2 = -e1 * roll.sin() + e2 * roll.cos();
        // Planes nearly through the camera centre image as lines of unknown depth.
        if n1.dot(&p).abs() < spec.min_plane_offset || n2.dot(&p).abs() < spec.min_plane_offset {
            continue;
        }
        let (v1, v2) = (n1 / n1.dot(&p), n2 / n2.dot(&p));
        let ok = |v: &Vector3<f64>| curve_polyline(&scene, v, 1.0).is_some_and(|pl| pl.len() >= 2);
        if ok(&v1) && ok(&v2) {
            planes.push(v1);
            planes.push(v2);
        }
    }
    let partner = (0..planes.len()).map(|i| Some((i ^ 1) as u32)).collect();
    SyntheticScan {
        scene,
        planes,
        partner,
    }
}

/// The pieces `(start, end)` of the image of plane `v` on each facet.
fn curve_pieces(scene: &Scene, v: &Vector3<f64>) -> Vec<([f64; 2], [f64; 2])> {
    let [x0, x1, y0, y1] = scene.window;
    let mut pieces = Vec::new();
    for (f, s) in scene.facets.iter().enumerate() {
        let d = v - s;
        let g2 = d.x * d.x + d.y * d.y;
        if g2 == 0.0 {
            continue;
        }
        let p0 = [-d.z * d.x / g2, -d.z * d.y / g2];
        let t = [-d.y / g2.sqrt(), d.x / g2.sqrt()];
        let (mut lo, mut hi) = (f64::NEG_INFINITY, f64::INFINITY);
        // Half-planes a·(x, y, 1) >= 0 along p0 + τ t.
        let mut clip = |a: Vector3<f64>| {
            let at0 = a.x * p0[0] + a.y * p0[1] + a.z;
            let slope = a.x * t[0] + a.y * t[1];
            if slope == 0.0 {
                if at0 < 0.0 {
                    hi = f64::NEG_INFINITY;
                }
            } else if slope > 0.0 {
                lo = lo.max(-at0 / slope);
            } else {
                hi = hi.min(-at0 / slope);
            }
        };
        clip(Vector3::new(1.0, 0.0, -x0));
        clip(Vector3::new(-1.0, 0.0, x1));
        clip(Vector3::new(0.0, 1.0, -y0));
        clip(Vector3::new(0.0, -1.0, y1));
        clip(*s);
        for (g, sg) in scene.facets.iter().enumerate() {
            if g != f {
                clip(s - sg);
            }
        }
        if hi - lo > 1e-9 {
            let at = |tau: f64| [p0[0] + tau * t[0], p0[1] + tau * t[1]];
            pieces.push((at(lo), at(hi)));
        }
    }
    pieces
}

/// Largest relative departure of `points` (camera frame) from `scene`, at the global
/// scale of the middle point of the list: 0 when all lie on it up to one scale.
pub fn worst_off_surface(scene: &Scene, points: &[[f32; 3]]) -> f64 {
    let scale: Vec<f64> = points
        .iter()
        .map(|p| {
            let [x, y, z] = p.map(f64::from);
            scene.inverse_depth(x / z, y / z) * z
        })
        .collect();
    let Some(&s0) = scale.get(scale.len() / 2) else {
        return 0.0;
    };
    scale
        .iter()
        .map(|s| (s / s0 - 1.0).abs())
        .fold(0.0, f64::max)
}

/// The image of plane `v` as one polyline with segments no longer than `max_segment`;
/// `None` when it is empty or not one connected path in the window.
pub fn curve_polyline(scene: &Scene, v: &Vector3<f64>, max_segment: f64) -> Option<Vec<[f64; 2]>> {
    let mut pieces = curve_pieces(scene, v);
    let first = pieces.pop()?;
    let mut chain = vec![first.0, first.1];
    let close = |a: [f64; 2], b: [f64; 2]| (a[0] - b[0]).hypot(a[1] - b[1]) < 1e-9;
    while !pieces.is_empty() {
        let head = chain[0];
        let tail = chain[chain.len() - 1];
        let k = pieces.iter().position(|&(a, b)| {
            close(a, tail) || close(b, tail) || close(a, head) || close(b, head)
        })?;
        let (a, b) = pieces.swap_remove(k);
        if close(a, tail) {
            chain.push(b);
        } else if close(b, tail) {
            chain.push(a);
        } else if close(a, head) {
            chain.insert(0, b);
        } else {
            chain.insert(0, a);
        }
    }
    let mut out = vec![chain[0]];
    for w in chain.windows(2) {
        let len = (w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1]);
        let n = (len / max_segment).ceil().max(1.0) as usize;
        for k in 1..=n {
            let t = k as f64 / n as f64;
            out.push([
                w[0][0] + t * (w[1][0] - w[0][0]),
                w[0][1] + t * (w[1][1] - w[0][1]),
            ]);
        }
    }
    Some(out)
}

/// All crossings of the images of `planes` (curve id = index), analytically, skipping
/// angles whose sine is below `min_sin_angle`.
pub fn analytic_crossings(
    scene: &Scene,
    planes: &[Vector3<f64>],
    min_sin_angle: f64,
) -> Vec<Crossing> {
    let mut out = Vec::new();
    for i in 0..planes.len() {
        for j in i + 1..planes.len() {
            for s in &scene.facets {
                let (di, dj) = (planes[i] - s, planes[j] - s);
                let h = di.cross(&dj);
                if h.z.abs() < 1e-300 {
                    continue;
                }
                let u = h / h.z;
                if !scene.in_window(u.x, u.y) || s.dot(&u) < scene.inverse_depth(u.x, u.y) - 1e-12 {
                    continue;
                }
                let sin = h.z.abs() / (di.x.hypot(di.y) * dj.x.hypot(dj.y));
                if sin >= min_sin_angle {
                    out.push(Crossing {
                        a: i as u32,
                        b: j as u32,
                        u: [u.x, u.y],
                        sin_angle: sin,
                    });
                }
            }
        }
    }
    out
}

/// A sphere seen from outside, a scanned object: its curves are strongly curved in the
/// image, so every crossing of a curve is well off the line of the others.
#[derive(Clone, Debug)]
pub struct SphereScene {
    pub centre: Vector3<f64>,
    pub radius: f64,
    /// Normalised image window `[x_min, x_max, y_min, y_max]`.
    pub window: [f64; 4],
}

impl Default for SphereScene {
    fn default() -> Self {
        Self {
            centre: Vector3::new(0.05, -0.02, 2.0),
            radius: 0.7,
            window: [-0.6, 0.6, -0.45, 0.45],
        }
    }
}

impl SphereScene {
    /// The point of the sphere seen along the ray `(x, y, 1)`, if it hits.
    pub fn point(&self, x: f64, y: f64) -> Option<Vector3<f64>> {
        let r = Vector3::new(x, y, 1.0);
        // |s r − C|² = R²: s² |r|² − 2 s r·C + |C|² − R² = 0, the nearer root.
        let (a, b, c) = (
            r.norm_squared(),
            -2.0 * r.dot(&self.centre),
            self.centre.norm_squared() - self.radius * self.radius,
        );
        let disc = b * b - 4.0 * a * c;
        (disc >= 0.0).then(|| r * ((-b - disc.sqrt()) / (2.0 * a)))
    }
}

/// Random crosses aimed at the sphere, as [`random_scan`] does for the room.
pub fn random_sphere_scan(
    spec: &ScanSpec,
    sphere: &SphereScene,
) -> (Vec<Vector3<f64>>, Vec<Option<u32>>) {
    let mut rng = Rng::new(spec.seed);
    let mut planes = Vec::with_capacity(2 * spec.num_crosses);
    let [x0, x1, y0, y1] = sphere.window;
    while planes.len() < 2 * spec.num_crosses {
        let j = spec.projector_jitter;
        let p = spec.projector_base
            + Vector3::new(rng.uniform(-j, j), rng.uniform(-j, j), rng.uniform(-j, j));
        let (tx, ty) = (rng.uniform(x0, x1), rng.uniform(y0, y1));
        let Some(target) = sphere.point(tx, ty) else {
            continue;
        };
        let axis = (target - p).normalize();
        let e1 = axis.cross(&Vector3::y()).normalize();
        let e2 = axis.cross(&e1);
        let roll = rng.uniform(0.0, std::f64::consts::PI);
        let n1 = e1 * roll.cos() + e2 * roll.sin();
        let n2 = -e1 * roll.sin() + e2 * roll.cos();
        if n1.dot(&p).abs() < spec.min_plane_offset || n2.dot(&p).abs() < spec.min_plane_offset {
            continue;
        }
        planes.push(n1 / n1.dot(&p));
        planes.push(n2 / n2.dot(&p));
    }
    let partner = (0..planes.len()).map(|i| Some((i ^ 1) as u32)).collect();
    (planes, partner)
}

/// All crossings of the images of `planes` on the sphere (curve id = index): the points
/// where the line of each pair of planes meets the visible hemisphere, in the window.
pub fn sphere_crossings(
    sphere: &SphereScene,
    planes: &[Vector3<f64>],
    min_sin_angle: f64,
) -> Vec<Crossing> {
    let [x0, x1, y0, y1] = sphere.window;
    let mut out = Vec::new();
    for i in 0..planes.len() {
        for j in i + 1..planes.len() {
            let (vi, vj) = (planes[i], planes[j]);
            let d = vi.cross(&vj);
            if d.norm_squared() < 1e-300 {
                continue;
            }
            // A point on both planes: the one in the span of vi, vj.
            let g = nalgebra::Matrix2::new(vi.dot(&vi), vi.dot(&vj), vi.dot(&vj), vj.dot(&vj));
            let Some(ab) = g.lu().solve(&nalgebra::Vector2::new(1.0, 1.0)) else {
                continue;
            };
            let x0p = vi * ab.x + vj * ab.y;
            let q = x0p - sphere.centre;
            let (a, b, c) = (
                d.norm_squared(),
                2.0 * d.dot(&q),
                q.norm_squared() - sphere.radius * sphere.radius,
            );
            let disc = b * b - 4.0 * a * c;
            if disc < 0.0 {
                continue;
            }
            for sgn in [-1.0, 1.0] {
                let x = x0p + d * ((-b + sgn * disc.sqrt()) / (2.0 * a));
                // Only the hemisphere facing the camera is seen.
                if x.z <= 0.0 || (x - sphere.centre).dot(&x) >= 0.0 {
                    continue;
                }
                let u = [x.x / x.z, x.y / x.z];
                if !(u[0] > x0 && u[0] < x1 && u[1] > y0 && u[1] < y1) {
                    continue;
                }
                // Image tangents of both curves at u.
                let tangent = |v: Vector3<f64>| {
                    let t = v.cross(&(x - sphere.centre));
                    [
                        (t.x * x.z - x.x * t.z) / (x.z * x.z),
                        (t.y * x.z - x.y * t.z) / (x.z * x.z),
                    ]
                };
                let (ta, tb) = (tangent(vi), tangent(vj));
                let sin = (ta[0] * tb[1] - ta[1] * tb[0]).abs()
                    / (ta[0].hypot(ta[1]) * tb[0].hypot(tb[1]));
                if sin >= min_sin_angle {
                    out.push(Crossing {
                        a: i as u32,
                        b: j as u32,
                        u,
                        sin_angle: sin,
                    });
                }
            }
        }
    }
    out
}

/// What [`path_scan`] draws: a hand-held projector moving smoothly over `frames`
/// frames, aimed on a Lissajous sweep over the window, its roll swinging.
#[derive(Clone, Debug)]
pub struct PathSpec {
    pub frames: usize,
    pub seed: u64,
    /// Centre of the hand's path, camera coordinates.
    pub centre: Vector3<f64>,
    /// Amplitude of the smooth drift of the centre, per axis.
    pub drift: f64,
    /// Period of the drift's slowest term, frames.
    pub drift_period: f64,
    /// Period of the horizontal aim sweep, frames (vertical: × golden ratio).
    pub sweep_period: f64,
    /// Share of the window the aim sweeps over (1: to its edges).
    pub sweep_extent: f64,
    /// Amplitude of the roll's swing, radians, and its period in frames.
    pub roll_amplitude: f64,
    pub roll_period: f64,
    pub scene: Scene,
}

impl Default for PathSpec {
    fn default() -> Self {
        Self {
            frames: 60,
            seed: 1,
            centre: Vector3::new(0.6, -0.5, 0.2),
            drift: 0.05,
            drift_period: 40.0,
            sweep_period: 37.0,
            sweep_extent: 0.8,
            roll_amplitude: 0.8,
            roll_period: 45.0,
            scene: Scene::default(),
        }
    }
}

/// A scan by a moving hand: per frame, the true projector centre and both planes
/// (plane `2f + k` is laser `k` of frame `f`).
#[derive(Clone, Debug)]
pub struct PathScan {
    pub scene: Scene,
    pub centres: Vec<Vector3<f64>>,
    pub planes: Vec<[Vector3<f64>; 2]>,
}

impl PathScan {
    /// Every plane in order, `2f + k`.
    pub fn flat_planes(&self) -> Vec<Vector3<f64>> {
        self.planes.iter().flat_map(|p| p.iter().copied()).collect()
    }
}

/// A smooth, seeded hand path over `spec.scene` (see [`PathSpec`]).
pub fn path_scan(spec: &PathSpec) -> PathScan {
    let mut rng = Rng::new(spec.seed);
    let tau = std::f64::consts::TAU;
    let phase: Vec<f64> = (0..9).map(|_| rng.uniform(0.0, tau)).collect();
    let [x0, x1, y0, y1] = spec.scene.window;
    let (cx, cy) = (0.5 * (x0 + x1), 0.5 * (y0 + y1));
    let (hx, hy) = (0.5 * (x1 - x0), 0.5 * (y1 - y0));
    let mut centres = Vec::with_capacity(spec.frames);
    let mut planes = Vec::with_capacity(spec.frames);
    for f in 0..spec.frames {
        let t = f as f64;
        let drift = Vector3::new(
            (tau * t / spec.drift_period + phase[0]).sin()
                + 0.4 * (tau * 1.7 * t / spec.drift_period + phase[1]).sin(),
            (tau * 0.8 * t / spec.drift_period + phase[2]).sin(),
            (tau * 1.3 * t / spec.drift_period + phase[3]).sin(),
        ) * (spec.drift / 1.4);
        let c = spec.centre + drift;
        let gold = 1.618_033_988_749_895;
        let tx = cx + spec.sweep_extent * hx * (tau * t / spec.sweep_period + phase[4]).sin();
        let ty =
            cy + spec.sweep_extent * hy * (tau * t / (gold * spec.sweep_period) + phase[5]).sin();
        let target = Vector3::new(tx, ty, 1.0) / spec.scene.inverse_depth(tx, ty);
        let axis = (target - c).normalize();
        let e1 = axis.cross(&Vector3::y()).normalize();
        let e2 = axis.cross(&e1);
        let roll = phase[6] + spec.roll_amplitude * (tau * t / spec.roll_period + phase[7]).sin();
        let n0 = e1 * roll.cos() + e2 * roll.sin();
        let n1 = axis.cross(&n0);
        centres.push(c);
        planes.push([n0 / n0.dot(&c), n1 / n1.dot(&c)]);
    }
    PathScan {
        scene: spec.scene.clone(),
        centres,
        planes,
    }
}

/// The evidence of `scan` for a camera of focal length `focal_px`: every frame a pose,
/// both lasers planes, every analytic crossing (moved by Gaussian noise of `noise_px`
/// pixels), kept where `keep` says (given the observation and its true 3D point).
pub fn path_evidence(
    scan: &PathScan,
    focal_px: f64,
    noise_px: f64,
    seed: u64,
    keep: impl Fn(&Observation, &Vector3<f64>) -> bool,
) -> Evidence {
    let planes = scan.flat_planes();
    let mut rng = Rng::new(seed);
    let crossings = analytic_crossings(&scan.scene, &planes, 0.1)
        .into_iter()
        .filter_map(|c| {
            let o = Observation {
                a: c.a,
                b: c.b,
                u: [
                    c.u[0] + noise_px / focal_px * rng.normal(),
                    c.u[1] + noise_px / focal_px * rng.normal(),
                ],
                sin_angle: c.sin_angle,
                class: CrossingClass::Strong,
            };
            let r = Vector3::new(c.u[0], c.u[1], 1.0);
            let x = r / planes[c.a as usize].dot(&r);
            keep(&o, &x).then_some(o)
        })
        .collect();
    Evidence {
        pose_frames: (0..scan.planes.len() as u32).collect(),
        anchors: Vec::new(),
        planes: (0..planes.len())
            .map(|i| PlaneSlot {
                pose: (i / 2) as u32,
                laser: (i % 2) as u8,
            })
            .collect(),
        crossings,
        focal_px,
        rays: RayModel::default(),
    }
}
