//! Scene descriptions and the analytic scene in camera coordinates ([`Scene`]) with
//! exact ray casting. The TOML `SceneSpec`, its defaults and its validation live in
//! [`spec`]; the keys are documented in the parent module.

use nalgebra::{Matrix3, Rotation3, Vector3};

use crate::camera::{Camera, Distortion};

mod spec;
use spec::default_arc_towards;
pub use spec::*;

type V3 = Vector3<f64>;

/// Rays start this far (scene units) beyond their origin, so a surface does not hit itself.
const T_MIN: f64 = 1e-9;

/// The camera model a scene spec describes.
pub fn camera_from_spec(c: &CameraSpec) -> Camera {
    let fx = match (c.fx, c.hfov_deg) {
        (Some(f), _) => f,
        (None, Some(h)) => 0.5 * c.width as f64 / (0.5 * h.to_radians()).tan(),
        (None, None) => c.width as f64, // rejected by validation
    };
    Camera {
        width: c.width,
        height: c.height,
        fx,
        fy: c.fy.unwrap_or(fx),
        cx: c.cx.unwrap_or(0.5 * (c.width as f64 - 1.0)),
        cy: c.cy.unwrap_or(0.5 * (c.height as f64 - 1.0)),
        skew: 0.0,
        distortion: Distortion::from_slice(&c.distortion).unwrap_or_default(),
    }
}

/// A rigid transform `x_out = rotation * x_in + translation`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pose {
    pub rotation: Matrix3<f64>,
    pub translation: V3,
}

impl Pose {
    pub fn apply(&self, p: &V3) -> V3 {
        self.rotation * p + self.translation
    }
    pub fn apply_vector(&self, v: &V3) -> V3 {
        self.rotation * v
    }
    pub fn inverse(&self) -> Pose {
        let rt = self.rotation.transpose();
        Pose {
            rotation: rt,
            translation: -(rt * self.translation),
        }
    }
}

/// The camera's pose in the world from position, look-at point and up vector
/// (OpenCV axes: +X right, +Y down, +Z forward).
pub fn world_from_camera(c: &CameraSpec) -> Pose {
    let pos = V3::from(c.position);
    let z = (V3::from(c.look_at) - pos).normalize();
    let mut x = z.cross(&V3::from(c.up));
    if x.norm() < 1e-9 {
        // Looking along `up`: any right vector will do.
        x = z.cross(&V3::x());
        if x.norm() < 1e-9 {
            x = z.cross(&V3::y());
        }
    }
    let x = x.normalize();
    let y = z.cross(&x);
    Pose {
        rotation: Matrix3::from_columns(&[x, y, z]),
        translation: pos,
    }
}

/// A ray's first intersection with the scene.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Ray parameter: `point = origin + t * dir` (in units of `dir`'s length).
    pub t: f64,
    pub point: V3,
    /// Unit outward surface normal (for planes and rectangles, the normal as given;
    /// open cylinders report the outward radial normal on both sides).
    pub normal: V3,
    /// Index of the primitive in the scene file's order.
    pub primitive: usize,
}

/// Geometry in camera coordinates.
#[derive(Clone, Debug)]
enum Geometry {
    Plane {
        n: V3,
        d: f64,
    },
    Rect {
        o: V3,
        n: V3,
        du: V3,
        dv: V3,
    },
    Box {
        c: V3,
        /// Rows are the box axes: `local = axes * (p - c)`.
        axes: Matrix3<f64>,
        half: V3,
    },
    Cylinder {
        a: V3,
        w: V3,
        len: f64,
        r: f64,
        capped: bool,
        /// Unit direction (normal to the axis) the kept arc is centred on, and the
        /// cosine of its half angle; `None` for the whole circle.
        arc: Option<(V3, f64)>,
    },
    Sphere {
        c: V3,
        r: f64,
    },
}

/// Surface appearance of one primitive.
#[derive(Clone, Debug, PartialEq)]
pub struct Material {
    pub albedo: [f64; 3],
    pub texture: Texture,
    pub texture_scale: f64,
    pub texture_contrast: f64,
    pub texture_seed: u64,
}

/// The scene in camera coordinates, ready for ray casting.
#[derive(Clone, Debug)]
pub struct Scene {
    pub name: String,
    pub medium: Medium,
    pub world_from_camera: Pose,
    pub materials: Vec<Material>,
    geometry: Vec<Geometry>,
}

impl Scene {
    /// Transforms a validated spec into camera coordinates.
    pub fn from_spec(spec: &SceneSpec) -> Scene {
        let world_from_camera = world_from_camera(&spec.camera);
        let cam = world_from_camera.inverse();
        let pt = |p: [f64; 3]| cam.apply(&V3::from(p));
        let vec = |v: [f64; 3]| cam.apply_vector(&V3::from(v));
        let zero = [0.0; 3];
        let default_scale = 0.05 * spec.distance();
        let mut geometry = Vec::with_capacity(spec.primitives.len());
        let mut materials = Vec::with_capacity(spec.primitives.len());
        for (index, p) in spec.primitives.iter().enumerate() {
            let g = match p.shape {
                Shape::Plane => {
                    let n = vec(p.normal.unwrap_or([0.0, 0.0, 1.0])).normalize();
                    Geometry::Plane {
                        n,
                        d: n.dot(&pt(p.point.unwrap_or(zero))),
                    }
                }
                Shape::Rectangle => {
                    let o = pt(p.corner.unwrap_or(zero));
                    let eu = vec(p.edge_u.unwrap_or([1.0, 0.0, 0.0]));
                    let ev = vec(p.edge_v.unwrap_or([0.0, 1.0, 0.0]));
                    let n = eu.cross(&ev).normalize();
                    // Dual basis: (q - o)·du and (q - o)·dv are the edge coordinates.
                    let a = ev.cross(&n);
                    let b = n.cross(&eu);
                    Geometry::Rect {
                        o,
                        n,
                        du: a / eu.dot(&a),
                        dv: b / ev.dot(&b),
                    }
                }
                Shape::Box => {
                    let [rx, ry, rz] = p.rotation_deg.unwrap_or(zero);
                    let r_world = Rotation3::from_euler_angles(
                        rx.to_radians(),
                        ry.to_radians(),
                        rz.to_radians(),
                    );
                    let r_cam = cam.rotation * r_world.matrix();
                    let s = p.size.unwrap_or([1.0; 3]);
                    Geometry::Box {
                        c: pt(p.center.unwrap_or(zero)),
                        axes: r_cam.transpose(),
                        half: V3::new(0.5 * s[0], 0.5 * s[1], 0.5 * s[2]),
                    }
                }
                Shape::Cylinder => {
                    let a = pt(p.from.unwrap_or(zero));
                    let b = pt(p.to.unwrap_or([0.0, 0.0, 1.0]));
                    let axis = b - a;
                    let w = axis.normalize();
                    let arc = p.arc_deg.filter(|&deg| deg < 360.0).map(|deg| {
                        let t = vec(p.arc_towards.unwrap_or(default_arc_towards()));
                        (
                            (t - w * w.dot(&t)).normalize(),
                            (0.5 * deg).to_radians().cos(),
                        )
                    });
                    Geometry::Cylinder {
                        a,
                        w,
                        len: axis.norm(),
                        r: p.radius.unwrap_or(1.0),
                        capped: p.capped.unwrap_or(true),
                        arc,
                    }
                }
                Shape::Sphere => Geometry::Sphere {
                    c: pt(p.center.unwrap_or(zero)),
                    r: p.radius.unwrap_or(1.0),
                },
            };
            geometry.push(g);
            materials.push(Material {
                albedo: p.albedo,
                texture: p.texture,
                texture_scale: p.texture_scale.unwrap_or(default_scale),
                texture_contrast: p.texture_contrast,
                texture_seed: p.texture_seed.unwrap_or(index as u64),
            });
        }
        Scene {
            name: spec.name.clone(),
            medium: spec.medium,
            world_from_camera,
            materials,
            geometry,
        }
    }

    /// Number of primitives.
    pub fn len(&self) -> usize {
        self.geometry.len()
    }

    pub fn is_empty(&self) -> bool {
        self.geometry.is_empty()
    }

    /// Z (camera coordinates) of the first surface along the ray from the camera centre,
    /// or `None` when the ray leaves the scene.
    pub fn ray_depth(&self, ray_in_camera: &V3) -> Option<f64> {
        self.cast(&V3::zeros(), ray_in_camera).map(|h| h.point.z)
    }

    /// First intersection of the ray `origin + t * dir`, `t > 0`, with the scene.
    pub fn cast(&self, origin: &V3, dir: &V3) -> Option<Hit> {
        let len = dir.norm();
        if len == 0.0 || !len.is_finite() {
            return None;
        }
        let d = dir / len;
        let mut best: Option<(f64, V3, usize)> = None;
        for (i, g) in self.geometry.iter().enumerate() {
            let t_max = best.map_or(f64::INFINITY, |b| b.0);
            if let Some((t, n)) = intersect(g, origin, &d, t_max) {
                best = Some((t, n, i));
            }
        }
        best.map(|(t, normal, primitive)| Hit {
            t: t / len,
            point: origin + d * t,
            normal,
            primitive,
        })
    }

    /// Whether any surface lies on `origin + t * dir` for `0 < t < t_max` (shadow rays:
    /// stops at the first blocker instead of finding the nearest).
    pub fn occluded(&self, origin: &V3, dir: &V3, t_max: f64) -> bool {
        let len = dir.norm();
        if len == 0.0 || !len.is_finite() {
            return false;
        }
        let d = dir / len;
        let t_max = t_max * len;
        self.geometry
            .iter()
            .any(|g| intersect(g, origin, &d, t_max).is_some())
    }

    /// Albedo times texture at a hit, per channel, in `[0, 1]`.
    pub fn reflectance(&self, hit: &Hit) -> [f64; 3] {
        let m = &self.materials[hit.primitive];
        let p = self.world_from_camera.apply(&hit.point) / m.texture_scale;
        let f = match m.texture {
            Texture::None => 1.0,
            Texture::Checker => {
                // Offset by a quarter cell so that axis-aligned faces do not sit on a
                // cell boundary.
                let s = (p.x + 0.25).floor() + (p.y + 0.25).floor() + (p.z + 0.25).floor();
                if s.rem_euclid(2.0) < 0.5 {
                    1.0
                } else {
                    0.0
                }
            }
            Texture::Noise => fbm(&p, m.texture_seed),
        };
        let k = 1.0 - m.texture_contrast * (1.0 - f);
        m.albedo.map(|a| a * k)
    }
}

/// Nearest intersection with `T_MIN < t < t_max` along a unit direction: `(t, normal)`.
fn intersect(g: &Geometry, o: &V3, d: &V3, t_max: f64) -> Option<(f64, V3)> {
    let ok = |t: f64| t > T_MIN && t < t_max;
    match g {
        Geometry::Plane { n, d: off } => {
            let den = n.dot(d);
            if den == 0.0 {
                return None;
            }
            let t = (off - n.dot(o)) / den;
            ok(t).then_some((t, *n))
        }
        Geometry::Rect { o: c, n, du, dv } => {
            let den = n.dot(d);
            if den == 0.0 {
                return None;
            }
            let t = (n.dot(c) - n.dot(o)) / den;
            if !ok(t) {
                return None;
            }
            let q = o + d * t - c;
            let (s, r) = (q.dot(du), q.dot(dv));
            ((0.0..=1.0).contains(&s) && (0.0..=1.0).contains(&r)).then_some((t, *n))
        }
        Geometry::Box { c, axes, half } => {
            let lo = axes * (o - c);
            let ld = axes * d;
            let mut t_near = f64::NEG_INFINITY;
            let mut t_far = f64::INFINITY;
            let (mut ax_near, mut ax_far) = (0, 0);
            for k in 0..3 {
                if ld[k] == 0.0 {
                    if lo[k].abs() > half[k] {
                        return None;
                    }
                    continue;
                }
                let t1 = (-half[k] - lo[k]) / ld[k];
                let t2 = (half[k] - lo[k]) / ld[k];
                let (a, b) = if t1 < t2 { (t1, t2) } else { (t2, t1) };
                if a > t_near {
                    t_near = a;
                    ax_near = k;
                }
                if b < t_far {
                    t_far = b;
                    ax_far = k;
                }
            }
            if t_near > t_far {
                return None;
            }
            let row = |k: usize| V3::new(axes[(k, 0)], axes[(k, 1)], axes[(k, 2)]);
            if ok(t_near) {
                // Entering through the face whose normal opposes the ray.
                let s = if ld[ax_near] > 0.0 { -1.0 } else { 1.0 };
                Some((t_near, row(ax_near) * s))
            } else if t_near <= T_MIN && ok(t_far) {
                // Inside: leaving through the face along the ray.
                let s = if ld[ax_far] > 0.0 { 1.0 } else { -1.0 };
                Some((t_far, row(ax_far) * s))
            } else {
                None
            }
        }
        Geometry::Cylinder {
            a,
            w,
            len,
            r,
            capped,
            arc,
        } => {
            // Whether the radial offset from the axis lies within the kept arc.
            let in_arc = |radial: &V3| {
                arc.is_none_or(|(towards, cos_half)| {
                    radial.dot(&towards) >= cos_half * radial.norm()
                })
            };
            let oc = o - a;
            let dw = d.dot(w);
            let ow = oc.dot(w);
            let dp = d - w * dw;
            let op = oc - w * ow;
            let mut best: Option<(f64, V3)> = None;
            let qa = dp.norm_squared();
            if qa > 0.0 {
                let qb = dp.dot(&op);
                let qc = op.norm_squared() - r * r;
                let disc = qb * qb - qa * qc;
                if disc >= 0.0 {
                    let sq = disc.sqrt();
                    for t in [(-qb - sq) / qa, (-qb + sq) / qa] {
                        let s = ow + t * dw;
                        let radial = op + dp * t;
                        if ok(t) && (0.0..=*len).contains(&s) && in_arc(&radial) {
                            best = Some((t, radial / *r));
                            break;
                        }
                    }
                }
            }
            if *capped && dw != 0.0 {
                for (s0, sign) in [(0.0, -1.0), (*len, 1.0)] {
                    let t = (s0 - ow) / dw;
                    if ok(t) && best.is_none_or(|b| t < b.0) {
                        let radial = op + dp * t;
                        if radial.norm_squared() <= r * r && in_arc(&radial) {
                            best = Some((t, w * sign));
                        }
                    }
                }
            }
            best
        }
        Geometry::Sphere { c, r } => {
            let oc = o - c;
            let b = oc.dot(d);
            let cc = oc.norm_squared() - r * r;
            let disc = b * b - cc;
            if disc < 0.0 {
                return None;
            }
            let sq = disc.sqrt();
            for t in [-b - sq, -b + sq] {
                if ok(t) {
                    let p = o + d * t;
                    return Some((t, (p - c) / *r));
                }
            }
            None
        }
    }
}

pub(crate) use crate::rng::mix64;

fn lattice(i: i64, j: i64, k: i64, salt: u64) -> f64 {
    let h = mix64(
        (i as u64).wrapping_mul(0x8CB9_2BA7_2F3D_8DD7)
            ^ (j as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
            ^ (k as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
            ^ salt.wrapping_mul(0x1656_67B1_9E37_79F9),
    );
    (h >> 11) as f64 / (1u64 << 53) as f64
}

/// Smooth value noise in `[0, 1]`.
fn value_noise(p: &V3, salt: u64) -> f64 {
    let (fx, fy, fz) = (p.x.floor(), p.y.floor(), p.z.floor());
    let (i, j, k) = (fx as i64, fy as i64, fz as i64);
    let s = |t: f64| t * t * (3.0 - 2.0 * t);
    let (u, v, w) = (s(p.x - fx), s(p.y - fy), s(p.z - fz));
    let lerp = |a: f64, b: f64, t: f64| a + (b - a) * t;
    let mut c = [0.0; 8];
    for (n, cn) in c.iter_mut().enumerate() {
        *cn = lattice(
            i + (n & 1) as i64,
            j + ((n >> 1) & 1) as i64,
            k + ((n >> 2) & 1) as i64,
            salt,
        );
    }
    let x0 = lerp(c[0], c[1], u);
    let x1 = lerp(c[2], c[3], u);
    let x2 = lerp(c[4], c[5], u);
    let x3 = lerp(c[6], c[7], u);
    lerp(lerp(x0, x1, v), lerp(x2, x3, v), w)
}

/// Three octaves of value noise, stretched to use most of `[0, 1]`.
fn fbm(p: &V3, salt: u64) -> f64 {
    let mut sum = 0.0;
    let mut amp = 0.5;
    let mut q = *p;
    for o in 0..3 {
        sum += amp * value_noise(&q, salt.wrapping_add(o));
        q *= 2.03;
        amp *= 0.5;
    }
    ((sum / 0.875 - 0.5) * 1.6 + 0.5).clamp(0.0, 1.0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    /// A scene whose camera sits at the world origin looking along world +Z with world
    /// +Y down, so world and camera coordinates coincide.
    fn scene_of(prims: &str) -> Scene {
        let text = format!(
            "name = \"t\"\n[camera]\nposition = [0, 0, 0]\nlook_at = [0, 0, 1]\nup = [0, -1, 0]\nhfov_deg = 60\n{prims}"
        );
        let spec = SceneSpec::from_toml_str(&text, Path::new("test.toml")).expect("valid");
        let s = Scene::from_spec(&spec);
        assert!(
            (s.world_from_camera.rotation - Matrix3::identity()).norm() < 1e-12,
            "camera frame is the world frame"
        );
        s
    }

    fn close(a: &V3, b: [f64; 3]) -> bool {
        (a - V3::from(b)).norm() < 1e-9
    }

    #[test]
    fn plane_and_rectangle() {
        let s = scene_of(
            "[[primitive]]\nshape = \"plane\"\npoint = [0, 0, 5]\nnormal = [0, 0, -1]\n\
             [[primitive]]\nshape = \"rectangle\"\ncorner = [-1, -1, 2]\nedge_u = [2, 0, 0]\nedge_v = [0, 1, 0]\n",
        );
        // Through the rectangle (y in [-1, 0]) at z = 2.
        let h = s.cast(&V3::zeros(), &V3::new(0.1, -0.2, 1.0)).expect("hit");
        assert_eq!(h.primitive, 1);
        assert!(close(&h.point, [0.2, -0.4, 2.0]));
        assert!((h.t - 2.0).abs() < 1e-12);
        assert!(close(&h.normal, [0.0, 0.0, 1.0]));
        // Below the rectangle: the plane at z = 5.
        let h = s.cast(&V3::zeros(), &V3::new(0.0, 0.1, 1.0)).expect("hit");
        assert_eq!(h.primitive, 0);
        assert!(close(&h.point, [0.0, 0.5, 5.0]));
        assert!((s.ray_depth(&V3::new(0.3, 0.3, 1.0)).expect("hit") - 5.0).abs() < 1e-12);
        // Away from the plane: nothing.
        assert!(s.cast(&V3::zeros(), &V3::new(0.0, 0.0, -1.0)).is_none());
        // Parallel to the plane.
        assert!(s.cast(&V3::new(0.0, 0.0, 1.0), &V3::x()).is_none());
    }

    #[test]
    fn rotated_box_outside_and_inside() {
        // A unit cube at z = 4 turned 45° about the viewing axis (world z = camera z).
        let s = scene_of(
            "[[primitive]]\nshape = \"box\"\ncenter = [0, 0, 4]\nsize = [1, 1, 1]\nrotation_deg = [0, 0, 45]\n",
        );
        let h = s.cast(&V3::zeros(), &V3::z()).expect("hit");
        assert!(close(&h.point, [0.0, 0.0, 3.5]));
        assert!(close(&h.normal, [0.0, 0.0, -1.0]));
        // Along +x at z = 4 from the side: the corner of the turned square at x = -√2/2.
        let h = s.cast(&V3::new(-3.0, 0.0, 4.0), &V3::x()).expect("hit");
        assert!((h.point.x + 0.5f64.sqrt()).abs() < 1e-9);
        // x = 0.6 misses an axis-aligned cube but hits the turned one (|x| < 0.707).
        assert!(s.cast(&V3::new(0.6, 0.0, 0.0), &V3::z()).is_some());
        assert!(s.cast(&V3::new(0.75, 0.0, 0.0), &V3::z()).is_none());
        // From inside: the far face, normal pointing out along the ray.
        let h = s.cast(&V3::new(0.0, 0.0, 4.0), &V3::z()).expect("hit");
        assert!(close(&h.point, [0.0, 0.0, 4.5]));
        assert!(close(&h.normal, [0.0, 0.0, 1.0]));
        // Behind the ray origin.
        assert!(s.cast(&V3::new(0.0, 0.0, 6.0), &V3::z()).is_none());
    }

    #[test]
    fn capped_and_open_cylinders() {
        // Axis along world x from x = -1 to 1, radius 0.5, at z = 3.
        let s = scene_of(
            "[[primitive]]\nshape = \"cylinder\"\nfrom = [-1, 0, 3]\nto = [1, 0, 3]\nradius = 0.5\n",
        );
        let h = s.cast(&V3::zeros(), &V3::z()).expect("hit");
        assert!(close(&h.point, [0.0, 0.0, 2.5]));
        assert!(close(&h.normal, [0.0, 0.0, -1.0]));
        // Along the axis from outside: the cap at x = -1.
        let h = s.cast(&V3::new(-5.0, 0.1, 3.0), &V3::x()).expect("hit");
        assert!(close(&h.point, [-1.0, 0.1, 3.0]));
        assert!(close(&h.normal, [-1.0, 0.0, 0.0]));
        // Beyond the finite length: miss.
        assert!(s.cast(&V3::new(1.2, 0.0, 0.0), &V3::z()).is_none());

        let s = scene_of(
            "[[primitive]]\nshape = \"cylinder\"\nfrom = [-1, 0, 3]\nto = [1, 0, 3]\nradius = 0.5\ncapped = false\n",
        );
        // Open: along the axis passes straight through.
        assert!(s.cast(&V3::new(-5.0, 0.1, 3.0), &V3::x()).is_none());
        // Looking into the open end at an angle: hits the inside wall.
        let dir = V3::new(1.0, 0.0, 0.25);
        let h = s.cast(&V3::new(-2.0, 0.0, 3.0), &dir).expect("inner wall");
        // z = 3 + 0.25 (x + 2) reaches the wall z = 3.5 at x = 0.
        assert!(close(&h.point, [0.0, 0.0, 3.5]));
        assert!(close(&h.normal, [0.0, 0.0, 1.0]));
    }

    #[test]
    fn half_cylinder_vault_seen_from_inside() {
        // World = camera frame (+Y down): a vault of radius 2 along +Z over a floor 1
        // below the camera, kept where the radial direction points up (-Y).
        let s = scene_of(
            "[[primitive]]\nshape = \"cylinder\"\nfrom = [0, 0, -1]\nto = [0, 0, 10]\nradius = 2\narc_deg = 180\narc_towards = [0, -1, 0]\n\
             [[primitive]]\nshape = \"plane\"\npoint = [0, 1, 0]\nnormal = [0, -1, 0]\n",
        );
        let h = s
            .cast(&V3::zeros(), &V3::new(0.0, -1.0, 0.0))
            .expect("vault");
        assert_eq!(h.primitive, 0);
        assert!(close(&h.point, [0.0, -2.0, 0.0]));
        // Above the springing line: the vault; below it the lower half is cut away and
        // the ray goes on to the floor.
        let h = s
            .cast(&V3::zeros(), &V3::new(1.0, -0.1, 0.0))
            .expect("vault");
        assert_eq!(h.primitive, 0);
        assert!((h.point.norm() - 2.0).abs() < 1e-12);
        let h = s
            .cast(&V3::zeros(), &V3::new(0.0, 1.0, 0.3))
            .expect("floor");
        assert_eq!(h.primitive, 1);
        let h = s
            .cast(&V3::zeros(), &V3::new(1.0, 0.1, 0.0))
            .expect("floor");
        assert_eq!(h.primitive, 1);
        assert!(close(&h.point, [10.0, 1.0, 0.0]));
        // Caps are cut the same way.
        let s = scene_of(
            "[[primitive]]\nshape = \"cylinder\"\nfrom = [0, 0, 2]\nto = [0, 0, 4]\nradius = 1\narc_deg = 180\narc_towards = [0, -1, 0]\n",
        );
        let h = s.cast(&V3::new(0.0, -0.5, 0.0), &V3::z()).expect("cap");
        assert!(close(&h.point, [0.0, -0.5, 2.0]));
        assert!(s.cast(&V3::new(0.0, 0.5, 0.0), &V3::z()).is_none());
        // A full arc is the whole cylinder.
        let full = scene_of(
            "[[primitive]]\nshape = \"cylinder\"\nfrom = [0, 0, 2]\nto = [0, 0, 4]\nradius = 1\narc_deg = 360\n",
        );
        assert!(full.cast(&V3::new(0.0, 0.5, 0.0), &V3::z()).is_some());
    }

    #[test]
    fn arc_keys_are_checked() {
        let base = "name = \"t\"\n[camera]\nposition = [0, 0, 0]\nlook_at = [0, 1, 0]\nhfov_deg = 60\n[[primitive]]\n";
        let bad = [
            "shape = \"cylinder\"\nfrom = [0, 0, 0]\nto = [0, 0, 1]\nradius = 1\narc_deg = 0\n",
            "shape = \"cylinder\"\nfrom = [0, 0, 0]\nto = [0, 0, 1]\nradius = 1\narc_deg = 400\n",
            // Along the axis: no direction around it.
            "shape = \"cylinder\"\nfrom = [0, 0, 0]\nto = [0, 0, 1]\nradius = 1\narc_deg = 90\n",
            "shape = \"sphere\"\ncenter = [0, 2, 0]\nradius = 1\narc_deg = 90\n",
        ];
        for prim in bad {
            let text = format!("{base}{prim}");
            let e = SceneSpec::from_toml_str(&text, Path::new("a.toml")).expect_err(prim);
            assert!(e.to_string().contains("arc"), "{e}");
        }
        let ok = format!("{base}shape = \"cylinder\"\nfrom = [0, 0, 0]\nto = [1, 0, 0]\nradius = 1\narc_deg = 90\n");
        let spec = SceneSpec::from_toml_str(&ok, Path::new("a.toml")).expect("valid");
        let text = spec.to_toml_string().expect("toml");
        assert_eq!(
            SceneSpec::from_toml_str(&text, Path::new("b.toml")).expect("reload"),
            spec
        );
    }

    #[test]
    fn sphere_nearest_hit_and_inside() {
        let s = scene_of(
            "[[primitive]]\nshape = \"sphere\"\ncenter = [0, 0, 6]\nradius = 1\n\
             [[primitive]]\nshape = \"sphere\"\ncenter = [0, 0, 3]\nradius = 0.5\n",
        );
        // The nearer sphere wins although it is listed second.
        let h = s.cast(&V3::zeros(), &V3::new(0.0, 0.0, 2.0)).expect("hit");
        assert_eq!(h.primitive, 1);
        assert!(close(&h.point, [0.0, 0.0, 2.5]));
        assert!((h.t - 1.25).abs() < 1e-12, "t is in units of dir");
        // Tangent offset ray: x = 0.3 hits the small sphere at z = 3 - sqrt(0.25 - 0.09).
        let h = s.cast(&V3::new(0.3, 0.0, 0.0), &V3::z()).expect("hit");
        assert!((h.point.z - (3.0 - 0.16f64.sqrt())).abs() < 1e-12);
        // From inside the big sphere: its far side.
        let h = s.cast(&V3::new(0.0, 0.0, 6.0), &V3::y()).expect("hit");
        assert!(close(&h.point, [0.0, 1.0, 6.0]));
        // Shadow queries stop short of t_max.
        assert!(s.occluded(&V3::zeros(), &V3::new(0.0, 0.0, 4.0), 0.7));
        assert!(!s.occluded(&V3::zeros(), &V3::new(0.0, 0.0, 4.0), 0.6));
        assert!(!s.occluded(&V3::new(0.0, 0.0, 8.0), &V3::z(), 100.0));
        // Misses.
        assert!(s.cast(&V3::zeros(), &V3::new(1.0, 0.0, 0.1)).is_none());
        assert!(s.cast(&V3::new(0.0, 0.0, 8.0), &V3::z()).is_none());
    }

    #[test]
    fn unknown_key_and_wrong_type_name_key_and_line() {
        let text = "name = \"t\"\n[camera]\nposition = [0, 0, 0]\nlook_at = [0, 1, 0]\nhfov_deg = 60\nfocal = 3\n";
        let e = SceneSpec::from_toml_str(text, Path::new("my.toml")).expect_err("unknown key");
        let m = e.to_string();
        assert!(m.contains("my.toml:6"), "{m}");
        assert!(m.contains("focal"), "{m}");

        let text =
            "name = \"t\"\n[camera]\nposition = [0, 0, 0]\nlook_at = [0, 1, 0]\nhfov_deg = 60\n\
                    [[primitive]]\nshape = \"sphere\"\ncenter = [0, 2, 0]\nradius = \"big\"\n";
        let m = SceneSpec::from_toml_str(text, Path::new("my.toml"))
            .expect_err("wrong type")
            .to_string();
        assert!(m.contains("my.toml:9"), "{m}");
        assert!(m.contains("radius"), "{m}");

        let text =
            "name = \"t\"\n[camera]\nposition = [0, 0, 0]\nlook_at = [0, 1, 0]\nhfov_deg = 60\n\
                    [[primitive]]\nshape = \"sphere\"\ncenter = [0, 2, 0]\n";
        let m = SceneSpec::from_toml_str(text, Path::new("my.toml"))
            .expect_err("missing radius")
            .to_string();
        assert!(m.contains("radius") && m.contains("my.toml:6"), "{m}");
    }

    #[test]
    fn textures_vary_and_stay_in_range() {
        let s = scene_of(
            "[[primitive]]\nshape = \"plane\"\npoint = [0, 0, 5]\nnormal = [0, 0, -1]\ntexture_scale = 0.2\ntexture_contrast = 0.6\nalbedo = [1, 0.5, 0.25]\n",
        );
        let mut lo = f64::INFINITY;
        let mut hi = f64::NEG_INFINITY;
        for i in 0..200 {
            let x = -0.5 + i as f64 * 0.005;
            let h = s.cast(&V3::zeros(), &V3::new(x, 0.1, 1.0)).expect("hit");
            let r = s.reflectance(&h);
            assert!((r[1] - 0.5 * r[0]).abs() < 1e-12);
            lo = lo.min(r[0]);
            hi = hi.max(r[0]);
        }
        assert!(lo >= 0.4 - 1e-12 && hi <= 1.0);
        assert!(hi - lo > 0.2, "texture visible: {lo}..{hi}");
    }

    #[test]
    fn non_finite_numbers_and_huge_images_are_refused() {
        let spec = crate::simulate::builtin_scene("bricks").expect("bricks");
        let mut nan = spec.clone();
        nan.camera.fx = Some(f64::NAN);
        let err = nan.validate().expect_err("nan fx").1;
        assert!(err.contains("camera.fx"), "{err}");
        let mut nan = spec.clone();
        nan.camera.position[1] = f64::NAN;
        let err = nan.validate().expect_err("nan position").1;
        assert!(err.contains("camera.position"), "{err}");
        let mut neg = spec.clone();
        neg.camera.fx = Some(-100.0);
        assert!(neg.validate().is_err());
        let huge = spec.clone().with_resolution(100_000, 100_000);
        let err = huge.validate().expect_err("huge").1;
        assert!(err.contains("too large"), "{err}");
        // A readout is a share of the frame period.
        for bad in [-0.1, 1.5] {
            let mut slow = spec.clone();
            slow.camera.readout_frames = bad;
            let err = slow.validate().expect_err("readout").1;
            assert!(err.contains("readout_frames"), "{err}");
        }
        let mut rolling = spec.clone();
        rolling.camera.readout_frames = 0.7;
        assert!(rolling.validate().is_ok());
    }

    #[test]
    fn a_long_bad_line_is_echoed_shortened() {
        let deep = format!(
            "version = 1\nx = {}{}\n",
            "[".repeat(10_000),
            "]".repeat(10_000)
        );
        let err = SceneSpec::from_toml_str(&deep, Path::new("deep.toml")).expect_err("deep");
        assert!(
            err.to_string().len() < 1000,
            "{} bytes",
            err.to_string().len()
        );
    }
}
