//! Random rooms and room corners at 3-10 m: floor, walls, a flat ceiling or a barrel
//! vault (a half cylinder seen from inside), niches recessed into the far wall, a few
//! large boxes and maybe a pillar. World frame: metres, z up, the camera near y = 0
//! looking towards the far wall at y = depth.

use super::parts::{
    aim, block, count, cylinder, ground_point, look, plane, rect, spec_of, Footprints, Look,
    NEUTRAL, TOY, WOOD,
};
use super::{Rng, V3};
use crate::camera::Camera;
use crate::simulate::scene::{CameraSpec, PrimitiveSpec, SceneSpec};

/// A rectangular recess in the far wall: left edge, width, sill height, height, depth.
struct Niche {
    x: f64,
    w: f64,
    z: f64,
    h: f64,
    depth: f64,
}

/// The wall `y = y` over `x0..x1`, `0..top` as rectangles around the niches, and each
/// niche as a back and four sides. Pieces overlap by `eps` so that no ray slips
/// between them.
fn wall_with_niches(
    y: f64,
    x0: f64,
    x1: f64,
    top: f64,
    niches: &[Niche],
    eps: f64,
    look: &Look,
) -> Vec<PrimitiveSpec> {
    let mut xs: Vec<f64> = vec![x0, x1];
    for n in niches {
        xs.extend([n.x, n.x + n.w]);
    }
    xs.sort_by(f64::total_cmp);
    xs.dedup();
    let mut out = Vec::new();
    for col in xs.windows(2) {
        let (a, b) = (col[0], col[1]);
        let mid = 0.5 * (a + b);
        let mut zs = vec![0.0];
        for n in niches.iter().filter(|n| n.x < mid && mid < n.x + n.w) {
            zs.extend([n.z, n.z + n.h]);
        }
        zs.push(top);
        for span in zs.chunks(2) {
            let (z0, z1) = (span[0] - eps, span[1] + eps);
            let corner = V3::new(a - eps, y, z0);
            out.push(rect(
                "wall",
                corner,
                V3::x() * (b - a + 2.0 * eps),
                V3::z() * (z1 - z0),
                look,
            ));
        }
    }
    for n in niches {
        let (w, h, dd) = (n.w + 2.0 * eps, n.h + 2.0 * eps, n.depth + eps);
        let c = V3::new(n.x - eps, y, n.z - eps);
        out.push(rect(
            "niche back",
            c + V3::y() * n.depth,
            V3::x() * w,
            V3::z() * h,
            look,
        ));
        out.push(rect("niche side", c, V3::y() * dd, V3::z() * h, look));
        out.push(rect(
            "niche side",
            c + V3::x() * n.w,
            V3::y() * dd,
            V3::z() * h,
            look,
        ));
        out.push(rect("niche sill", c, V3::x() * w, V3::y() * dd, look));
        out.push(rect(
            "niche lintel",
            c + V3::z() * n.h,
            V3::x() * w,
            V3::y() * dd,
            look,
        ));
    }
    out
}

pub(super) fn room(
    rng: &mut Rng,
    mut camera: CameraSpec,
    intrinsics: &Camera,
) -> (SceneSpec, String) {
    let d = rng.uniform(3.0, 10.0);
    let corner = rng.chance(0.3);
    let vault = !corner && rng.chance(0.4);
    let (y_c, z_c) = (rng.uniform(0.3, 1.0), rng.uniform(1.2, 1.9));
    let (width, x_c) = if corner {
        let x_c = rng.uniform(0.35, 0.7) * d;
        // The far wall runs on past the view; there is no right-hand wall.
        (x_c + 3.0 * d, x_c)
    } else {
        let w = rng.uniform((0.45 * d).max(3.0), d.max(4.5)).min(14.0);
        (w, rng.uniform(0.3, 0.7) * w)
    };
    let (ceiling, spring) = if vault {
        let s = rng.uniform(2.2, 3.2);
        (s + 0.5 * width, s)
    } else {
        let h = rng.uniform(2.5, 2.5 + 0.25 * d);
        (h, h)
    };
    let z_t = rng.uniform(0.25, 0.6) * ceiling.min(4.0);
    let mut x_t = if corner {
        rng.uniform(0.0, 0.15) * x_c
    } else {
        rng.uniform(0.15, 0.85) * width
    };
    if d * d < (x_t - x_c).powi(2) + (z_t - z_c).powi(2) + 1.0 {
        x_t = x_c;
    }
    let depth = y_c + (d * d - (x_t - x_c).powi(2) - (z_t - z_c).powi(2)).sqrt();
    aim(
        rng,
        &mut camera,
        V3::new(x_c, y_c, z_c),
        V3::new(x_t, depth, z_t),
    );

    let walls = look(rng, &NEUTRAL, 0.3);
    let floor = look(rng, &[WOOD[0], WOOD[1], NEUTRAL[1], NEUTRAL[3]], 0.4);
    let mut prims = vec![plane("floor", V3::zeros(), V3::z(), &floor)];
    prims.push(plane("left wall", V3::zeros(), V3::x(), &walls));
    if !corner {
        prims.push(plane("right wall", V3::x() * width, -V3::x(), &walls));
    }
    if vault {
        let mut v = cylinder(
            "vault",
            V3::new(0.5 * width, -1.0, spring),
            V3::new(0.5 * width, depth + 1.0, spring),
            0.5 * width,
            &look(rng, &NEUTRAL, 0.3),
        );
        v.capped = Some(false);
        v.arc_deg = Some(180.0);
        v.arc_towards = Some([0.0, 0.0, 1.0]);
        prims.push(v);
    } else {
        prims.push(plane(
            "ceiling",
            V3::z() * ceiling,
            -V3::z(),
            &look(rng, &NEUTRAL, 0.3),
        ));
    }
    let mut niches: Vec<Niche> = Vec::new();
    let span_end = if corner { x_c + d } else { width };
    for _ in 0..[0, 1, 1, 2, 3][rng.below(5)] {
        let w = rng.uniform(0.4, 1.6f64.min(0.25 * span_end));
        let h = rng.uniform(0.5, 1.6);
        let z = rng.uniform(0.2, 1.5).min(spring - 0.2 - h).max(0.05);
        let x = rng.uniform(0.3, (span_end - 0.3 - w).max(0.31));
        let clear = niches
            .iter()
            .all(|n| x + w + 0.2 < n.x || n.x + n.w + 0.2 < x);
        if clear && z + h < spring - 0.1 {
            niches.push(Niche {
                x,
                w,
                z,
                h,
                depth: rng.uniform(0.15, 0.5),
            });
        }
    }
    prims.extend(wall_with_niches(
        depth,
        0.0,
        width,
        ceiling,
        &niches,
        1e-4 * d,
        &walls,
    ));

    let mut taken = Footprints(vec![(V3::new(x_c, y_c, 0.0), 1.0)]);
    let mut boxes = 0;
    for _ in 0..rng.int(0, 4) {
        for _ in 0..20 {
            let Some(c) = ground_point(rng, &camera, intrinsics, 0.1, V3::zeros(), V3::z()) else {
                continue;
            };
            let (w, l) = (rng.uniform(0.4, 1.6), rng.uniform(0.3, 0.8));
            let r = 0.5 * w.hypot(l);
            let inside = c.x > r + 0.1 && c.x < width - r - 0.1 && c.y < depth - r - 0.1;
            if !inside || !taken.free(c, r + 0.2) {
                continue;
            }
            taken.0.push((c, r));
            let h = rng.uniform(0.4, 2.0).min(spring - 0.1);
            let yaw = rng.uniform(-25.0, 25.0);
            let colour = look(rng, &[WOOD[0], WOOD[2], NEUTRAL[0], TOY[1], TOY[5]], 0.1);
            prims.push(block(
                "furniture",
                c + V3::z() * (0.5 * h),
                V3::new(w, l, h),
                V3::new(0.0, 0.0, yaw),
                &colour,
            ));
            boxes += 1;
            break;
        }
    }
    let mut pillar = false;
    if rng.chance(0.3) {
        let r = rng.uniform(0.12, 0.35);
        if let Some(c) = ground_point(rng, &camera, intrinsics, 0.15, V3::zeros(), V3::z()) {
            if c.x > r && c.x < width - r && c.y < depth - r && taken.free(c, r + 0.3) {
                prims.push(cylinder(
                    "pillar",
                    c,
                    c + V3::z() * ceiling,
                    r,
                    &look(rng, &NEUTRAL, 0.2),
                ));
                pillar = true;
            }
        }
    }
    let mut text = if corner {
        "corner".to_string()
    } else {
        format!(
            "{:.1} x {:.1} x {:.1} m{}",
            width,
            depth,
            ceiling,
            if vault { ", vault" } else { "" }
        )
    };
    if !niches.is_empty() {
        text += &format!(", {}", count(niches.len(), "niche", "niches"));
    }
    if boxes > 0 {
        text += &format!(", {}", count(boxes, "box", "boxes"));
    }
    if pillar {
        text += ", pillar";
    }
    (spec_of("random-room", camera, prims), text)
}
