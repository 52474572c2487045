//! Random layouts of the four kinds of scene: the primitives and the camera's pose for
//! given intrinsics. World frame: metres, z up. Objects are placed where random pixels'
//! rays meet the floor, so they lie in the view; each layout is redrawn until most of
//! the image sees a surface. Rooms are in [`super::room`], the building blocks in
//! [`super::parts`]; the camera's intrinsics, the cross, the hand and the light are
//! drawn by the parent module.

use std::f64::consts::TAU;

use super::parts::{
    aim, block, counts, cylinder, floor_pitch, ground_point, look, plane, spec_of, sphere,
    Footprints, NEUTRAL, SEA, TOY, WOOD,
};
use super::room::room;
use super::{surface_fraction, Rng, SceneKind, MIN_SURFACE_FRACTION, V3};
use crate::camera::Camera;
use crate::simulate::scene::{camera_from_spec, CameraSpec, Medium, SceneSpec};

/// Draws a layout of `kind` for a camera of these intrinsics (its pose is part of the
/// layout); returns the scene (default cross, hand and light) and a few words on it.
pub(super) fn draw(kind: SceneKind, rng: &mut Rng, camera: CameraSpec) -> (SceneSpec, String) {
    let intrinsics = camera_from_spec(&camera);
    let attempt = |rng: &mut Rng| {
        let (spec, text) = match kind {
            SceneKind::Table => table(rng, camera.clone(), &intrinsics),
            SceneKind::Room => room(rng, camera.clone(), &intrinsics),
            SceneKind::Clutter => clutter(rng, camera.clone(), &intrinsics),
            SceneKind::Underwater => underwater(rng, camera.clone(), &intrinsics),
        };
        (surface_fraction(&spec, 32, 18), spec, text)
    };
    let mut best = attempt(rng);
    for _ in 1..8 {
        if best.0 >= MIN_SURFACE_FRACTION {
            break;
        }
        let next = attempt(rng);
        if next.0 > best.0 {
            best = next;
        }
    }
    (best.1, best.2)
}

fn table(rng: &mut Rng, mut camera: CameraSpec, intrinsics: &Camera) -> (SceneSpec, String) {
    let d = rng.uniform(0.5, 0.9);
    let lo = floor_pitch(intrinsics, 10f64.to_radians()).max(35f64.to_radians());
    let pitch = rng.uniform(lo, lo.max(80f64.to_radians()));
    let az = rng.uniform(0.0, TAU);
    let look_at = V3::new(rng.uniform(-0.05, 0.05), rng.uniform(-0.05, 0.05), 0.0);
    let forward = V3::new(az.cos(), az.sin(), 0.0);
    let position = look_at - forward * (d * pitch.cos()) + V3::z() * (d * pitch.sin());
    aim(rng, &mut camera, position, look_at);
    let top = look(
        rng,
        &[WOOD[0], WOOD[1], WOOD[2], NEUTRAL[0], NEUTRAL[3]],
        0.02,
    );
    let mut prims = vec![plane("table", V3::zeros(), V3::z(), &top)];
    let mut taken = Footprints(Vec::new());
    let (mut heights, mut extras): (Vec<f64>, Vec<&str>) = (Vec::new(), Vec::new());
    let boxes = rng.int(6, 10);
    // Narrow views see a small patch of table: smaller bricks, so that they all fit.
    let footprint = (d * intrinsics.width as f64 / intrinsics.fx / 0.7).clamp(0.4, 1.0);
    let with_can = rng.chance(0.5);
    let with_ball = rng.chance(0.3);
    for k in 0..boxes + usize::from(with_can) + usize::from(with_ball) {
        for _ in 0..60 {
            let Some(c) = ground_point(rng, &camera, intrinsics, 0.08, V3::zeros(), V3::z()) else {
                continue;
            };
            let colour = look(rng, &TOY, 0.01);
            if k < boxes {
                let (w, l, h) = (
                    rng.uniform(0.03, 0.12) * footprint,
                    rng.uniform(0.03, 0.12) * footprint,
                    rng.uniform(0.02, 0.06),
                );
                let r = 0.5 * w.hypot(l);
                if !taken.free(c, r + 0.01) {
                    continue;
                }
                taken.0.push((c, r));
                heights.push(h);
                let yaw = rng.uniform(0.0, 90.0);
                let size = V3::new(w, l, h);
                prims.push(block(
                    "brick",
                    c + V3::z() * (0.5 * h),
                    size,
                    V3::new(0.0, 0.0, yaw),
                    &colour,
                ));
            } else if with_can && k == boxes {
                let (r, h) = (rng.uniform(0.02, 0.05), rng.uniform(0.04, 0.12));
                if !taken.free(c, r + 0.01) {
                    continue;
                }
                taken.0.push((c, r));
                prims.push(cylinder("can", c, c + V3::z() * h, r, &colour));
                extras.push("1 cylinder");
            } else {
                let r = rng.uniform(0.015, 0.04);
                if !taken.free(c, r + 0.01) {
                    continue;
                }
                taken.0.push((c, r));
                prims.push(sphere("ball", c + V3::z() * r, r, &colour));
                extras.push("1 ball");
            }
            break;
        }
    }
    let cm = |h: f64| (100.0 * h).round();
    let lo_h = heights.iter().copied().fold(f64::INFINITY, f64::min);
    let hi_h = heights.iter().copied().fold(0.0, f64::max);
    let mut text = format!("{} boxes {:.0}-{:.0} cm", heights.len(), cm(lo_h), cm(hi_h));
    for e in extras {
        text += ", ";
        text += e;
    }
    (spec_of("random-table", camera, prims), text)
}

fn clutter(rng: &mut Rng, mut camera: CameraSpec, intrinsics: &Camera) -> (SceneSpec, String) {
    let d = rng.uniform(1.0, 5.0);
    // Looking down at the clutter: the optical axis meets the floor or an object low
    // on it, and the wall behind fills the top of the view.
    let pitch = rng.uniform(15f64, 45.0).to_radians();
    let z_c = d * pitch.sin() + rng.uniform(0.0, 0.3);
    let yaw = rng.uniform(-20f64, 20.0).to_radians();
    let ahead = V3::new(yaw.sin(), yaw.cos(), 0.0);
    let look_at = ahead * (d * pitch.cos()) + V3::z() * (z_c - d * pitch.sin());
    aim(rng, &mut camera, V3::z() * z_c, look_at);
    let wall_y = look_at.y + rng.uniform(0.3, 1.5) * d.max(1.0) / 2.0;
    let mut prims = vec![
        plane(
            "floor",
            V3::zeros(),
            V3::z(),
            &look(rng, &[WOOD[1], NEUTRAL[1], NEUTRAL[3]], 0.2),
        ),
        plane(
            "back wall",
            V3::y() * wall_y,
            -V3::y(),
            &look(rng, &NEUTRAL, 0.25),
        ),
    ];
    if rng.chance(0.5) {
        let half_width = wall_y * (0.5 * intrinsics.width as f64 / intrinsics.fx);
        let side = if rng.chance(0.5) { 1.0 } else { -1.0 };
        let x = side * rng.uniform(0.6, 1.2) * half_width;
        prims.push(plane(
            "side wall",
            V3::x() * x,
            -V3::x() * side,
            &look(rng, &NEUTRAL, 0.25),
        ));
    }
    // Object sizes scale with the width of the view at the scene distance.
    let s = (0.45 * d * intrinsics.width as f64 / intrinsics.fx).clamp(0.3, 2.0);
    let mut taken = Footprints(vec![(V3::z() * z_c, 0.3 * d)]);
    let mut tops: Vec<(V3, f64)> = Vec::new();
    let (mut boxes, mut cylinders, mut spheres) = (0, 0, 0);
    for _ in 0..rng.int(12, 28) {
        let kind = rng.below(20);
        let colour = look(rng, &TOY, 0.05 * s);
        if kind < 3 && !tops.is_empty() {
            // Stacked on an earlier box.
            let (top, room) = tops[rng.below(tops.len())];
            let (w, l, h) = (
                room * rng.uniform(0.4, 0.9),
                room * rng.uniform(0.4, 0.9),
                rng.uniform(0.08, 0.4) * s,
            );
            prims.push(block(
                "stacked box",
                top + V3::z() * (0.5 * h),
                V3::new(w, l, h),
                V3::new(0.0, 0.0, rng.uniform(0.0, 90.0)),
                &colour,
            ));
            boxes += 1;
            continue;
        }
        for _ in 0..30 {
            let Some(c) = ground_point(rng, &camera, intrinsics, 0.05, V3::zeros(), V3::z()) else {
                continue;
            };
            let (a, b, h) = (
                rng.uniform(0.06, 0.45) * s,
                rng.uniform(0.06, 0.45) * s,
                rng.uniform(0.06, 0.7) * s,
            );
            let r = match kind {
                0..=9 => 0.5 * a.hypot(b),
                10..=15 => 0.5 * a.max(h),
                _ => 0.5 * a,
            };
            if c.y > wall_y - r || !taken.free(c, r + 0.02) {
                continue;
            }
            taken.0.push((c, r));
            if kind < 10 {
                let yaw = rng.uniform(0.0, 90.0);
                prims.push(block(
                    "box",
                    c + V3::z() * (0.5 * h),
                    V3::new(a, b, h),
                    V3::new(0.0, 0.0, yaw),
                    &colour,
                ));
                tops.push((c + V3::z() * h, a.min(b)));
                boxes += 1;
            } else if kind < 16 {
                let radius = 0.25 * a;
                let mut cyl = if rng.chance(0.6) {
                    cylinder("upright cylinder", c, c + V3::z() * h, radius, &colour)
                } else {
                    let t = rng.uniform(0.0, TAU);
                    let half = V3::new(t.cos(), t.sin(), 0.0) * (0.5 * h.max(2.0 * radius));
                    let axis = c + V3::z() * radius;
                    cylinder("lying cylinder", axis - half, axis + half, radius, &colour)
                };
                cyl.capped = Some(rng.chance(0.8));
                prims.push(cyl);
                cylinders += 1;
            } else {
                prims.push(sphere("ball", c + V3::z() * (0.5 * a), 0.5 * a, &colour));
                spheres += 1;
            }
            break;
        }
    }
    let text = counts(&[
        (boxes, "box", "boxes"),
        (cylinders, "cylinder", "cylinders"),
        (spheres, "sphere", "spheres"),
    ]);
    (spec_of("random-clutter", camera, prims), text)
}

fn underwater(rng: &mut Rng, mut camera: CameraSpec, intrinsics: &Camera) -> (SceneSpec, String) {
    let d = rng.uniform(1.5, 3.5);
    // Looking down at the seabed: the top of the image sees it at most about 4 times
    // the camera's height away, not a far seabed lost in the haze.
    let lo = floor_pitch(intrinsics, 15f64.to_radians()).max(25f64.to_radians());
    let pitch = rng.uniform(lo, lo.max(75f64.to_radians()));
    let z_c = d * pitch.sin();
    aim(rng, &mut camera, V3::z() * z_c, V3::y() * (d * pitch.cos()));
    let normal = V3::new(rng.uniform(-0.06, 0.06), rng.uniform(-0.06, 0.06), 1.0).normalize();
    let mut prims = vec![plane(
        "seabed",
        V3::zeros(),
        normal,
        &look(rng, &SEA[..2], 0.08),
    )];
    let mut taken = Footprints(vec![(V3::z() * z_c, 0.25 * d)]);
    let mut place = |rng: &mut Rng, r: f64| {
        for _ in 0..30 {
            let c = ground_point(rng, &camera, intrinsics, 0.1, V3::zeros(), normal)?;
            if taken.free(c, r) {
                taken.0.push((c, r));
                return Some(c);
            }
        }
        None
    };
    let (mut pipes, mut rocks, mut blocks) = (0, 0, 0);
    for _ in 0..rng.int(1, 4) {
        let (r, len) = (rng.uniform(0.05, 0.3), rng.uniform(1.0, 4.0));
        let Some(c) = place(rng, 0.3 * len) else {
            continue;
        };
        let t = rng.uniform(0.0, TAU);
        let half = V3::new(t.cos(), t.sin(), 0.0) * (0.5 * len);
        let axis = c + V3::z() * (r * rng.uniform(0.2, 1.0));
        let mut pipe = cylinder(
            "pipe",
            axis - half,
            axis + half,
            r,
            &look(rng, &SEA[2..5], 0.1),
        );
        pipe.capped = Some(rng.chance(0.6));
        prims.push(pipe);
        pipes += 1;
    }
    for _ in 0..rng.int(3, 10) {
        let r = rng.uniform(0.04, 0.15) * d;
        let Some(c) = place(rng, r) else { continue };
        prims.push(sphere(
            "rock",
            c + V3::z() * (r * rng.uniform(-0.5, 0.4)),
            r,
            &look(rng, &SEA[..2], 0.05),
        ));
        rocks += 1;
    }
    for _ in 0..rng.int(0, 3) {
        let size = V3::new(
            rng.uniform(0.2, 0.8),
            rng.uniform(0.2, 0.8),
            rng.uniform(0.2, 0.8),
        );
        let Some(c) = place(rng, 0.5 * size.x.hypot(size.y)) else {
            continue;
        };
        let rot = V3::new(
            rng.uniform(-15.0, 15.0),
            rng.uniform(-15.0, 15.0),
            rng.uniform(0.0, 90.0),
        );
        let centre = c + V3::z() * (size.z * rng.uniform(0.1, 0.45));
        prims.push(block(
            "block",
            centre,
            size,
            rot,
            &look(rng, &SEA[1..], 0.06),
        ));
        blocks += 1;
    }
    let mut spec = spec_of("random-underwater", camera, prims);
    spec.medium = Medium::Water;
    let w = &mut spec.water;
    w.turbidity = rng.uniform(0.0, 1.5);
    w.absorption = w.absorption.map(|a| a * rng.uniform(0.8, 1.25));
    w.scattering = w.scattering.map(|a| a * rng.uniform(0.8, 1.25));
    w.backscatter *= rng.uniform(0.6, 1.4);
    w.veil = [
        rng.uniform(4.0, 12.0),
        rng.uniform(25.0, 55.0),
        rng.uniform(30.0, 60.0),
    ];
    let objects = counts(&[
        (pipes, "pipe", "pipes"),
        (rocks, "rock", "rocks"),
        (blocks, "block", "blocks"),
    ]);
    let text = format!("turbidity {:.2}, {objects}", spec.water.turbidity);
    (spec, text)
}
