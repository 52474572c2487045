//! The live solver's tests: epochs on the surface, monotone in evidence, frames placed
//! against them, and the final cloud equal to `reconstruct`'s.

use super::*;
use crate::solve::synthetic::{curve_polyline, random_scan, worst_off_surface, ScanSpec};

/// With the focal length estimated (the in-air calibration under water: every
/// normalised point 1.33 times too far out), the streamed cloud lies on the
/// surface. It once came out many times off: the epoch's planes were turned back
/// into the focal-corrected coordinates and met the uncorrected points.
#[test]
fn an_epoch_with_an_estimated_focal_length_lies_on_the_surface() {
    let camera = Camera::with_fov(1200, 900, 2.0 * 0.6f64.atan());
    let scan = random_scan(&ScanSpec::default());
    let lambda = 1.33;
    let mut config = Config::default();
    config.solve.estimate_focal = true;
    let strength = 2.0 * config.solve.min_curve_strength;
    let mut solver = Incremental::new(
        camera.clone(),
        config,
        IncrementalParams {
            min_planes_first_solve: scan.planes.len(),
            solve_growth: 10.0,
            epoch_duty: 1.0,
        },
        ScaleMode::Factor { factor: 1.0 },
    );
    let mut points = Vec::new();
    let mut epochs = 0;
    let mut take = |out: Output| {
        epochs += usize::from(out.epoch.is_some());
        points.extend(out.batches.into_iter().flat_map(|b| b.points));
        epochs
    };
    for k in 0..scan.planes.len() / 2 {
        let curves: Vec<Curve> = (0..2)
            .filter_map(|l| {
                let v = scan.planes[2 * k + l];
                let pts: Vec<[f64; 2]> = curve_polyline(&scan.scene, &v, 1.0 / camera.fx)?
                    .into_iter()
                    .map(|p| [p[0] * lambda, p[1] * lambda])
                    .collect();
                Some(Curve {
                    laser: l as u8,
                    points_px: pts
                        .iter()
                        .map(|p| {
                            let [u, v] = camera.pixel_from_normalized(p[0], p[1]);
                            [u as f32, v as f32]
                        })
                        .collect(),
                    strength: vec![strength; pts.len()],
                    polyline: pts.clone(),
                    points: pts,
                })
            })
            .collect();
        take(solver.add_frame(curves, 0));
    }
    // The solve runs in the background; empty frames poll it (for as long as a loaded
    // machine needs: this is no speed test).
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(300);
    while std::time::Instant::now() < deadline {
        if take(solver.add_frame(Vec::new(), 0)) > 0 {
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(10));
    }
    assert!(points.len() > 1000, "{} points", points.len());
    let xyz: Vec<[f32; 3]> = points.iter().map(|p| p.xyz).collect();
    let worst = worst_off_surface(&scan.scene, &xyz);
    assert!(
        worst < 1e-3,
        "a point {:.3} % off the surface",
        100.0 * worst
    );
}

/// What one epoch sent: its cloud, and the frames placed against it.
#[derive(Default)]
struct Sent {
    cloud: Vec<Point>,
    placed: Vec<Point>,
}

/// Feeds `frames` to `solver` at about 30 fps and returns what each epoch sent.
fn live_epochs(solver: &mut Incremental, frames: Vec<Vec<Curve>>) -> Vec<Sent> {
    let mut epochs: Vec<Sent> = Vec::new();
    let mut solving_for = 0;
    for curves in frames {
        let out = solver.add_frame(curves, 0);
        take(&mut epochs, out);
        // Give the background solve time, as frames at 30 fps would; and once it has
        // had `MAX_BACKLOG` frames' time, wait for it, so that the epochs made do not
        // depend on the machine's load (the tests run side by side).
        std::thread::sleep(std::time::Duration::from_millis(20));
        solving_for = if solver.solving() { solving_for + 1 } else { 0 };
        if solving_for >= MAX_BACKLOG {
            while solver.solving() {
                std::thread::sleep(std::time::Duration::from_millis(5));
            }
        }
    }
    epochs
}

/// Feeds `frames`, waiting for each epoch as soon as it is started: the epochs that the
/// plane counts alone decide, whatever the machine's load.
fn epochs_waited_for(solver: &mut Incremental, frames: Vec<Vec<Curve>>) -> Vec<Sent> {
    let mut epochs: Vec<Sent> = Vec::new();
    for curves in frames {
        let out = solver.add_frame(curves, 0);
        take(&mut epochs, out);
        while solver.solving() {
            std::thread::sleep(std::time::Duration::from_millis(5));
        }
    }
    epochs
}

/// Files what one frame's output sent under its epoch.
fn take(epochs: &mut Vec<Sent>, out: Output) {
    if out.epoch.is_some() {
        epochs.push(Sent::default());
    }
    for b in out.batches {
        let e = epochs.last_mut().expect("no points before the first epoch");
        match b.kind {
            BatchKind::Epoch => e.cloud.extend(b.points),
            BatchKind::Arrival | BatchKind::Backlog => e.placed.extend(b.points),
        }
    }
}

/// Frames a test lets arrive while an epoch is made before it waits for the epoch.
const MAX_BACKLOG: usize = 10;

/// Of one epoch's points (one global scale, fitted as the median), how many lie more
/// than `tolerance` (relative depth) off the surface.
fn points_off(scene: &crate::solve::synthetic::Scene, points: &[Point], tolerance: f64) -> usize {
    let ratios: Vec<f64> = points
        .iter()
        .map(|p| {
            let [x, y, z] = p.xyz.map(f64::from);
            scene.inverse_depth(x / z, y / z) * z
        })
        .collect();
    relative_to_median(&ratios)
        .iter()
        .filter(|e| e.abs() > tolerance)
        .count()
}

/// Each of `ratios` over their median, less one: the relative errors after one global
/// scale. Empty for no ratios.
fn relative_to_median(ratios: &[f64]) -> Vec<f64> {
    let mut sorted = ratios.to_vec();
    sorted.sort_by(f64::total_cmp);
    let Some(&s0) = sorted.get(sorted.len() / 2) else {
        return Vec::new();
    };
    ratios.iter().map(|r| r / s0 - 1.0).collect()
}

/// Of one epoch's points, how many lie on planes (one laser of one frame) whose depth
/// is off by more than `tolerance` (relative, after one global scale fitted as the
/// median). A plane's error is measured on the plane itself, not at its noisy
/// points: each point is on its estimated plane, so `Z (v_true · r)` along the point's
/// own ray `r` is the ratio of the true plane's inverse depth to the estimated one's.
/// (The scene's depth at the point would add the point's own noise, which is
/// several per cent where a plane meets the surface at a grazing angle, and is no
/// part of the plane's uncertainty.)
fn points_on_wrong_planes(
    scan: &crate::solve::synthetic::PathScan,
    points: &[Point],
    tolerance: f64,
) -> usize {
    points_on_wrong_planes_of(scan, points, tolerance, points.len())
}

/// [`points_on_wrong_planes`] of `points`, counting only those before `upto` (the
/// global scale still fitted on all of them).
fn points_on_wrong_planes_of(
    scan: &crate::solve::synthetic::PathScan,
    points: &[Point],
    tolerance: f64,
    upto: usize,
) -> usize {
    let ratios: Vec<f64> = points
        .iter()
        .map(|p| {
            let [x, y, z] = p.xyz.map(f64::from);
            let truth = scan.planes[p.frame as usize][usize::from(p.laser)];
            z * truth.dot(&nalgebra::Vector3::new(x / z, y / z, 1.0))
        })
        .collect();
    let mut planes: std::collections::HashMap<(u32, u8), Vec<f64>> = Default::default();
    for (p, e) in points.iter().zip(relative_to_median(&ratios)).take(upto) {
        planes.entry((p.frame, p.laser)).or_default().push(e);
    }
    planes
        .values_mut()
        .filter_map(|e| {
            e.sort_by(f64::total_cmp);
            (e[e.len() / 2].abs() > tolerance).then_some(e.len())
        })
        .sum()
}

/// More evidence never makes an epoch worse: at 0.05 px of noise on every curve
/// point (several times what extraction measures on rendered frames), no epoch has
/// more points on planes that are off by more than three of the depth rule's
/// deviations (the rule keeps a point only where its plane fixes its depth to
/// `max_depth_sigma`) than the epoch before it, and the final cloud has none.
///
/// This test once reported 89 such points in the final cloud: it took a plane's error
/// as the median of its points' error *sizes*, which is the points' own noise on a
/// plane that meets the surface at a grazing angle (1.7 % on one 89-point curve
/// whose plane was right). It now measures the planes themselves.
#[test]
fn epochs_are_monotone_in_evidence() {
    assert_epochs_monotone(0.05);
}

/// The same at 0.3 px of curve noise, where the first epochs see each plane crossed
/// only a few times and the polylines are jagged. It failed once (issue 17: the first
/// epoch kept 1,997 points on planes over 1 % off), because jagged polylines cross
/// several times where their curves cross once and each copy counts as an
/// observation, which makes the deviations 2-3x optimistic (docs/accuracy.md,
/// Uncertainty). It passes since the estimator's later changes: six epochs, none with a
/// point on a plane over the bound, with the motion terms' information counted or not.
/// The driver waits for every epoch ([`epochs_waited_for`]): with the wait only after
/// ten frames, as at 30 fps, the epochs landed where the machine's load let them, and
/// where they landed on 15, 24, 30 and 40 frames (3 of 12 runs with two tests side by
/// side) a frame placed against the fourth was on a wrong plane. That case is held,
/// ignored as known, by
/// [`frames_placed_against_an_epoch_lie_on_right_planes_whatever_the_timing`].
#[test]
fn epochs_are_monotone_in_evidence_at_high_noise() {
    assert_epochs_monotone(0.3);
}

/// [`path_frames`] with `noise_px` of Gaussian noise on every curve point (the
/// polylines are the noisy points).
fn noisy_path_frames(
    camera: &Camera,
    config: &Config,
    noise_px: f64,
) -> (crate::solve::synthetic::PathScan, Vec<Vec<Curve>>) {
    let (scan, frames) = path_frames(camera, config);
    let mut rng = crate::solve::synthetic::Rng::new(5);
    let sigma = noise_px / camera.fx;
    let frames = frames
        .into_iter()
        .map(|curves| {
            curves
                .into_iter()
                .map(|mut c| {
                    for p in &mut c.points {
                        p[0] += sigma * rng.normal();
                        p[1] += sigma * rng.normal();
                    }
                    c.polyline = c.points.clone();
                    c
                })
                .collect()
        })
        .collect();
    (scan, frames)
}

/// The synthetic sweep with `noise_px` on its curves ([`noisy_path_frames`]), a live
/// solver for it (epochs from 30 planes on, every 1.25-fold growth), and the bound on a
/// plane's error the monotonicity tests hold: three of the depth rule's deviations.
fn noisy_sweep(
    noise_px: f64,
) -> (
    crate::solve::synthetic::PathScan,
    Vec<Vec<Curve>>,
    Incremental,
    f64,
) {
    let camera = Camera::with_fov(1200, 900, 2.0 * 0.6f64.atan());
    let mut config = Config::default();
    config.solve.max_anchor_poses = 40;
    let (scan, frames) = noisy_path_frames(&camera, &config, noise_px);
    let bound = 3.0 * config.triangulate.max_depth_sigma;
    let solver = Incremental::new(
        camera,
        config,
        IncrementalParams {
            min_planes_first_solve: 30,
            solve_growth: 1.25,
            epoch_duty: 1.0,
        },
        ScaleMode::Factor { factor: 1.0 },
    );
    (scan, frames, solver, bound)
}

/// The epochs' and final cloud's points on wrong planes (see
/// [`epochs_are_monotone_in_evidence`]) with `noise_px` of Gaussian noise on every
/// curve point.
fn assert_epochs_monotone(noise_px: f64) {
    let (scan, frames, mut solver, bound) = noisy_sweep(noise_px);
    let epochs = epochs_waited_for(&mut solver, frames);
    let failing: Vec<usize> = epochs
        .iter()
        .map(|e| points_on_wrong_planes(&scan, &e.cloud, bound))
        .collect();
    // The frames placed against each epoch, on its scale.
    let placed_wrong: Vec<(usize, usize)> = epochs
        .iter()
        .map(|e| {
            let both: Vec<Point> = e.cloud.iter().chain(&e.placed).copied().collect();
            let wrong = points_on_wrong_planes(&scan, &both, bound)
                - points_on_wrong_planes_of(&scan, &both, bound, e.cloud.len());
            (wrong, e.placed.len())
        })
        .collect();
    eprintln!("epochs' points on wrong planes {failing:?}; placed (wrong, all) {placed_wrong:?}");
    assert!(epochs.len() >= 3, "{} epochs", epochs.len());
    // Frames placed against an epoch are no worse than it: none on a wrong plane
    // where the epoch has none.
    assert!(
        placed_wrong.iter().any(|&(_, all)| all > 0),
        "no frame placed"
    );
    for (e, (&(wrong, all), &own)) in placed_wrong.iter().zip(&failing).enumerate() {
        assert!(
            own > 0 || wrong == 0,
            "epoch {e}: {wrong} of {all} points placed against it on wrong planes, none of its own"
        );
    }
    for (e, pair) in failing.windows(2).enumerate() {
        assert!(
            pair[1] <= pair[0],
            "epoch {} has {} points on planes over {bound}, the one before {} (all: {failing:?})",
            e + 1,
            pair[1],
            pair[0]
        );
    }
    let last = solver.finish().expect("final solve");
    let cloud = &last.cloud;
    let (frames_of, lasers_of) = (cloud.frames.as_ref(), cloud.lasers.as_ref());
    let final_points: Vec<Point> = (0..cloud.len())
        .map(|i| Point {
            xyz: cloud.points[i],
            rgb: [0; 3],
            laser: lasers_of.expect("lasers")[i],
            frame: frames_of.expect("frames")[i],
        })
        .collect();
    assert_eq!(points_on_wrong_planes(&scan, &final_points, bound), 0);
}

/// Curves of the synthetic path scan, frame by frame, as extracted.
fn path_frames(
    camera: &Camera,
    config: &Config,
) -> (crate::solve::synthetic::PathScan, Vec<Vec<Curve>>) {
    let scan = crate::solve::synthetic::path_scan(&crate::solve::synthetic::PathSpec {
        frames: 80,
        ..Default::default()
    });
    let strength = 2.0 * config.solve.min_curve_strength;
    let frames = scan
        .planes
        .iter()
        .map(|p| {
            (0..2)
                .filter_map(|l| {
                    let pts = curve_polyline(&scan.scene, &p[l], 1.0 / camera.fx)?;
                    Some(Curve {
                        laser: l as u8,
                        points_px: pts
                            .iter()
                            .map(|q| camera.pixel_from_normalized(q[0], q[1]).map(|c| c as f32))
                            .collect(),
                        strength: vec![strength; pts.len()],
                        polyline: pts.clone(),
                        points: pts,
                    })
                })
                .collect()
        })
        .collect();
    (scan, frames)
}

/// The live solver runs the offline estimator: with anchors thinned as the scan grows,
/// its epochs lie on the surface (but for the few points of the known limit), and its final
/// cloud is `reconstruct`'s of the same curves, point for point.
#[test]
fn live_epochs_lie_on_the_surface_and_the_final_cloud_is_reconstructs() {
    let camera = Camera::with_fov(1200, 900, 2.0 * 0.6f64.atan());
    let mut config = Config::default();
    config.solve.max_anchor_poses = 40;
    let (scan, frames) = path_frames(&camera, &config);
    let mut solver = Incremental::new(
        camera.clone(),
        config.clone(),
        IncrementalParams {
            min_planes_first_solve: 40,
            solve_growth: 1.5,
            epoch_duty: 1.0,
        },
        ScaleMode::Factor { factor: 1.0 },
    );
    let epochs = live_epochs(&mut solver, frames.clone());
    assert!(epochs.len() >= 2, "{} epochs", epochs.len());
    // Nearly every live point on the surface. Not every one: an epoch made on the
    // evidence of a partial sweep (when it is made depends on the machine's load)
    // can place a few of the newest frames a few per cent off (the known limit).
    let (off, all) = epochs.iter().fold((0, 0), |(off, all), e| {
        (
            off + points_off(&scan.scene, &e.cloud, 1e-3),
            all + e.cloud.len(),
        )
    });
    assert!(off * 50 < all, "{off} of {all} live points off the surface");
    let (off, all) = epochs.iter().fold((0, 0), |(off, all), e| {
        let both: Vec<Point> = e.cloud.iter().chain(&e.placed).copied().collect();
        (
            off + points_off(&scan.scene, &both, 1e-3) - points_off(&scan.scene, &e.cloud, 1e-3),
            all + e.placed.len(),
        )
    });
    assert!(all > 0, "no frame placed against an epoch");
    assert!(
        off * 50 < all,
        "{off} of {all} placed points off the surface"
    );
    let live = solver.finish().expect("final solve");
    let offline = crate::pipeline::reconstruct_curves(
        frames,
        &camera,
        &config,
        PlaneSource::SelfCalibrated,
        &ScaleMode::Factor { factor: 1.0 },
        None,
    )
    .expect("offline");
    assert!(live.cloud.len() > 10_000);
    assert_eq!(live.cloud.points, offline.cloud.points);
    assert_eq!(live.planes, offline.planes);
}

/// The final solve supersedes a running epoch's: that one is told to stop, so that
/// the two do not share the CPU (on a one-CPU machine the final cloud came minutes
/// late), and the final cloud is still made.
#[test]
fn the_final_solve_stops_an_epoch_still_running() {
    let camera = Camera::with_fov(1200, 900, 2.0 * 0.6f64.atan());
    let config = Config::default();
    let (_, frames) = path_frames(&camera, &config);
    let planes: usize = frames.iter().map(Vec::len).sum();
    let mut solver = Incremental::new(
        camera,
        config,
        IncrementalParams {
            min_planes_first_solve: planes,
            solve_growth: 10.0,
            epoch_duty: 1.0,
        },
        ScaleMode::Factor { factor: 1.0 },
    );
    for curves in frames {
        solver.add_frame(curves, 0);
    }
    let running = solver
        .pending
        .as_ref()
        .expect("a solve started")
        .cancel
        .clone();
    assert!(!running.is_cancelled());
    let rec = solver.finish().expect("final solve");
    assert!(
        running.is_cancelled(),
        "the epoch's solve was not told to stop"
    );
    assert!(rec.cloud.len() > 10_000, "{} points", rec.cloud.len());
}

/// After an epoch, the next waits out the duty rule's rest even when the planes have
/// grown past the growth that triggers it; at a duty of 1 it starts at once.
#[test]
fn epochs_rest_so_their_thread_keeps_to_its_duty() {
    let camera = Camera::with_fov(1200, 900, 2.0 * 0.6f64.atan());
    let config = Config::default();
    let (_, frames) = path_frames(&camera, &config);
    let half = frames.len() / 2;
    let run = |duty: f64| {
        let mut solver = Incremental::new(
            camera.clone(),
            config.clone(),
            IncrementalParams {
                min_planes_first_solve: 40,
                solve_growth: 1.05,
                epoch_duty: duty,
            },
            ScaleMode::Factor { factor: 1.0 },
        );
        let mut frames = frames.clone().into_iter();
        while solver.pending.is_none() {
            solver.add_frame(frames.next().expect("an epoch started"), 0);
        }
        // Its answer, however long a loaded machine takes (no speed test).
        let deadline = Instant::now() + Duration::from_secs(300);
        while solver.pending.is_some() && Instant::now() < deadline {
            std::thread::sleep(Duration::from_millis(10));
            solver.add_frame(Vec::new(), 0);
        }
        assert!(solver.pending.is_none(), "the first epoch never answered");
        assert_eq!(solver.epoch(), 1, "the first epoch was not adopted");
        let started = Instant::now();
        for curves in frames.by_ref().take(half) {
            solver.add_frame(curves, 0);
        }
        (solver, started)
    };
    let (resting, started) = run(0.001);
    // The planes grew past the trigger: only the rest held the next epoch back. (Not
    // asked of the eager run: an epoch it started late moved its trigger on.)
    assert!(resting.scan.planes().len() >= resting.next_solve_at);
    let rest_until = resting.rest_until.expect("a rest after the first epoch");
    assert!(
        Instant::now() < rest_until,
        "the rest ({:?} from the frames fed) has passed already",
        rest_until - started
    );
    assert!(
        resting.pending.is_none(),
        "an epoch started during the rest"
    );
    assert_eq!(resting.counts.global_solves, 1);
    let (eager, _) = run(1.0);
    assert!(eager.rest_until.is_some_and(|t| t <= Instant::now()));
    assert!(
        eager.pending.is_some() || eager.counts.global_solves >= 2,
        "no epoch started without a rest"
    );
}

/// Until an epoch is adopted the user sees nothing: a failed try is followed by the
/// next without a rest, whatever the duty (the 200-frame demo once showed no live epoch:
/// its first try failed and the rest outlasted the replay).
#[test]
fn a_failed_first_epoch_is_tried_again_without_a_rest() {
    let camera = Camera::with_fov(1200, 900, 2.0 * 0.6f64.atan());
    let config = Config::default();
    let (_, frames) = path_frames(&camera, &config);
    let mut solver = Incremental::new(
        camera,
        config,
        IncrementalParams {
            min_planes_first_solve: 2,
            solve_growth: 1.05,
            epoch_duty: 0.001,
        },
        ScaleMode::Factor { factor: 1.0 },
    );
    // One frame's two planes: the solve cannot be made, and says so.
    solver.add_frame(frames[0].clone(), 0);
    assert!(solver.pending.is_some(), "no epoch tried");
    let deadline = Instant::now() + Duration::from_secs(300);
    while solver.pending.is_some() && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(5));
        solver.add_frame(Vec::new(), 0);
    }
    assert_eq!(solver.counts.failed_global_solves, 1);
    assert_eq!(solver.epoch(), 0);
    assert!(
        solver.rest_until.is_none(),
        "a rest before any epoch was adopted"
    );
    solver.add_frame(frames[1].clone(), 0);
    assert!(solver.pending.is_some(), "the next try waited");
}

/// The final solve's rule: the cold starts' answer stands, and the last epoch's planes
/// start a second solve only where the first gives no cloud and there is an epoch.
#[test]
fn the_final_solve_starts_from_the_last_epoch_only_where_the_cold_one_gives_no_cloud() {
    use std::cell::Cell;
    let warm_runs = Cell::new(0);
    let warm = |answer: u32| {
        let runs = &warm_runs;
        move || {
            runs.set(runs.get() + 1);
            Ok::<u32, PipelineError>(answer)
        }
    };
    let failed = || Err(PipelineError::Solve(solve::SolveError::Degenerate("test")));
    // A cloud from the cold starts: `reconstruct`'s, the epoch not asked.
    assert_eq!(cold_then_warm(|| Ok(1), Some(warm(2))).ok(), Some(1));
    assert_eq!(warm_runs.get(), 0);
    // No cloud from them: the epoch's.
    assert_eq!(cold_then_warm(failed, Some(warm(2))).ok(), Some(2));
    assert_eq!(warm_runs.get(), 1);
    // No epoch: the failure stands.
    let none: Option<fn() -> Result<u32, PipelineError>> = None;
    assert!(matches!(
        cold_then_warm(failed, none),
        Err(PipelineError::Solve(_))
    ));
    // A failure the planes are not to blame for (the scale) is not solved again.
    let scale = || Err(PipelineError::Scale(cloud::ScaleError::Empty));
    assert!(matches!(
        cold_then_warm(scale, Some(warm(2))),
        Err(PipelineError::Scale(_))
    ));
    assert_eq!(warm_runs.get(), 1);
}

/// Feeds `frames` and makes an epoch on exactly the first `at[k]` frames, waiting for
/// each: the epochs a run makes when its timing puts them there.
fn epochs_at(solver: &mut Incremental, frames: Vec<Vec<Curve>>, at: &[usize]) -> Vec<Sent> {
    let mut epochs: Vec<Sent> = Vec::new();
    for (i, curves) in frames.into_iter().enumerate() {
        solver.next_solve_at = usize::MAX;
        let out = solver.add_frame(curves, 0);
        take(&mut epochs, out);
        if at.contains(&(i + 1)) {
            solver.next_solve_at = 0;
            solver.maybe_start_solve(0);
            while solver.solving() {
                std::thread::sleep(std::time::Duration::from_millis(5));
            }
        }
    }
    epochs
}

/// [`epochs_are_monotone_in_evidence_at_high_noise`] with its epochs where a loaded
/// machine made them in 3 of 12 runs (on 15, 24, 30 and 40 frames): frame 56, placed
/// against the 40-frame epoch, lies 1.15 % off (255 points) at a depth deviation of
/// 0.065 % (median). Its laser-1 curve runs along an anchor's (frame 11's) and, at
/// 0.3 px of noise, crosses it 70 times, each an observation: a third of its 174
/// crossings reject the fit. The scan's own rate of rejected crossings is 21 % at this
/// noise, so a verdict on that share does not single it out (tried). Known, not fixed:
/// docs/accuracy.md, "Uncertainty".
#[test]
#[ignore = "known: a frame whose curve runs along an anchor's is placed 1.15 % off (docs/accuracy.md, Uncertainty)"]
fn frames_placed_against_an_epoch_lie_on_right_planes_whatever_the_timing() {
    let (scan, frames, mut solver, bound) = noisy_sweep(0.3);
    let epochs = epochs_at(&mut solver, frames, &[15, 24, 30, 40]);
    assert_eq!(epochs.len(), 4);
    for (k, e) in epochs.iter().enumerate().skip(1) {
        let both: Vec<Point> = e.cloud.iter().chain(&e.placed).copied().collect();
        let wrong = points_on_wrong_planes(&scan, &both, bound)
            - points_on_wrong_planes_of(&scan, &both, bound, e.cloud.len());
        assert_eq!(
            wrong,
            0,
            "epoch {k}: {wrong} of {} placed points on wrong planes",
            e.placed.len()
        );
    }
}
