//! What did the estimator know about particular frames? Self-calibrates a simulation's
//! cached curves (see `common`) and prints, for the frames named in `POSES` (e.g.
//! `POSES=296,297,161`), each plane's verdict, whether its pose is an anchor, its error
//! at its crossings against the truth (after one global scale over every crossing), its
//! deviation there, and its crossings: with which frames, their weights and residuals,
//! and how their true 3D points spread (collinear? on one 3D plane?).
//!
//! cargo run --release --example pose_diag -- SIMDIR

mod common;

use std::path::Path;

use crossline::compare::GroundTruth;
use crossline::pipeline::Scan;
use crossline::solve;
use nalgebra::{Matrix3, Vector3};

type V3 = Vector3<f64>;

fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let run = common::load(Path::new(&args[0]))?;
    let wanted: Vec<u32> = std::env::var("POSES")
        .unwrap_or_default()
        .split(',')
        .filter_map(|s| s.trim().parse().ok())
        .collect();
    let mut scan = Scan::new(&run.camera, &run.config);
    for curves in run.per_frame.clone() {
        scan.add_frame(curves);
    }
    scan.refine_crossings(&run.camera, &run.config);
    let (ev, _) = scan.snapshot().solve_input(&run.camera, &run.config);
    let t = std::time::Instant::now();
    let cal = if std::env::var("PLANES").is_ok_and(|v| v == "start") {
        let start: Vec<Option<V3>> = ev
            .planes
            .iter()
            .map(|slot| {
                let frame = ev.pose_frames[slot.pose as usize] as usize;
                Some(V3::from(
                    run.sim.truth.frames[frame].planes[usize::from(slot.laser)],
                ))
            })
            .collect();
        solve::calibrate_from(&ev, &run.config.solve, Some(&start))?
    } else {
        solve::calibrate(&ev, &run.config.solve)?
    };
    eprintln!(
        "cost {:.1} under its own spreads {:?}",
        cal.estimate.cost, cal.estimate.spreads
    );
    if std::env::var("COMPARE").is_ok_and(|v| v == "1") {
        let start: Vec<Option<V3>> = ev
            .planes
            .iter()
            .map(|slot| {
                let frame = ev.pose_frames[slot.pose as usize] as usize;
                Some(V3::from(
                    run.sim.truth.frames[frame].planes[usize::from(slot.laser)],
                ))
            })
            .collect();
        let oracle = solve::calibrate_from(&ev, &run.config.solve, Some(&start))?;
        let p = solve::estimate::EstimateParams::default();
        for (name, sp) in [
            ("self", &cal.estimate.spreads),
            ("oracle", &oracle.estimate.spreads),
        ] {
            eprintln!(
                "under the {name} spreads: self {:.1}, oracle {:.1}",
                solve::estimate::cost_at(&ev, &cal.estimate, sp, &p),
                solve::estimate::cost_at(&ev, &oracle.estimate, sp, &p)
            );
        }
        eprintln!("oracle spreads {:?}", oracle.estimate.spreads);
        eprintln!(
            "scores: self {:.1}, oracle {:.1}",
            solve::choose::score(&ev, &cal.estimate, &p),
            solve::choose::score(&ev, &oracle.estimate, &p)
        );
        // Where the two differ: each crossing's Cauchy cost (at its own estimate's
        // spreads, scale 3), summed per pose of its first plane, in blocks of 10 frames.
        let cauchy = |x: f32| {
            let x = x as f64;
            if x.is_nan() {
                0.0
            } else {
                9.0 * (x * x / 9.0).ln_1p()
            }
        };
        let mut block = vec![(0.0, 0.0); ev.num_poses() / 10 + 1];
        for (k, c) in ev.crossings.iter().enumerate() {
            for p in [c.a, c.b] {
                let f = ev.pose_frames[ev.planes[p as usize].pose as usize] as usize / 10;
                block[f].0 += 0.5 * cauchy(cal.estimate.crossing_residuals[k]);
                block[f].1 += 0.5 * cauchy(oracle.estimate.crossing_residuals[k]);
            }
        }
        for (b, (a, o)) in block.iter().enumerate() {
            eprintln!(
                "  frames {:3}-: crossings' cost self {a:9.1} oracle {o:9.1} diff {:+9.1}",
                10 * b,
                a - o
            );
        }
    }
    eprintln!("calibrated in {:.1} s", t.elapsed().as_secs_f64());
    let est = &cal.estimate;
    let truth_plane = |i: usize| -> V3 {
        let slot = ev.planes[i];
        let frame = ev.pose_frames[slot.pose as usize] as usize;
        V3::from(run.sim.truth.frames[frame].planes[usize::from(slot.laser)])
    };
    // One global scale: the median ratio of true to estimated inverse depth.
    let ratios: Vec<f64> = ev
        .crossings
        .iter()
        .filter_map(|c| {
            let v = cal.plane(c.a as usize)?;
            let ray = cal.ray(c.u)?;
            let r0 = run.camera.fx.max(1.0); // unused guard
            let _ = r0;
            Some(truth_plane(c.a as usize).dot(&V3::new(c.u[0], c.u[1], 1.0)) / v.dot(&ray.r))
        })
        .filter(|r| r.is_finite())
        .collect();
    let scale = median(ratios);
    println!(
        "{} poses, {} planes, {} crossings; scale {scale:.6}; summary {:?}",
        ev.num_poses(),
        ev.planes.len(),
        ev.crossings.len(),
        cal.summary.alternatives
    );
    {
        // How far the estimate is a common shift of the truth: v_est ≈ s v_true + w.
        let mut a = nalgebra::Matrix4::<f64>::zeros();
        let mut b = nalgebra::Vector4::<f64>::zeros();
        let mut pairs = Vec::new();
        for i in 0..ev.planes.len() {
            if let Some(v) = cal.plane(i) {
                let l = est.focal_scale;
                let ve = V3::new(v.x * l, v.y * l, v.z);
                let vt = truth_plane(i);
                let wgt = 1.0 / ve.norm_squared().max(1e-300);
                for k in 0..3 {
                    let mut row = nalgebra::Vector4::<f64>::zeros();
                    row[0] = vt[k];
                    row[1 + k] = 1.0;
                    a += row * row.transpose() * wgt;
                    b += row * ve[k] * wgt;
                }
                pairs.push((ve, vt));
            }
        }
        if let Some(x) = a.cholesky().map(|c| c.solve(&b)) {
            let w = V3::new(x[1], x[2], x[3]);
            let res: Vec<f64> = pairs
                .iter()
                .map(|(ve, vt)| (ve - vt * x[0] - w).norm() / ve.norm())
                .collect();
            let norms: Vec<f64> = pairs.iter().map(|(ve, _)| ve.norm()).collect();
            println!(
                "as a shift of the truth: s {:.4}, |w| {:.4} of a median |v| {:.4}; \
                 median residual {:.4} of |v|",
                x[0],
                w.norm(),
                median(norms),
                median(res)
            );
        }
    }
    if std::env::var("TURNS").is_ok_and(|v| v == "1") {
        // Per frame, each laser's turn from the truth (degrees), as one line per 10.
        let by_pose = ev.planes_of_poses();
        let mut line = String::new();
        for (p, slots) in by_pose.iter().enumerate() {
            let frame = ev.pose_frames[p];
            let turn = |s: Option<u32>| {
                s.and_then(|i| {
                    let v = cal.plane(i as usize)?;
                    let l = est.focal_scale;
                    let ve = V3::new(v.x * l, v.y * l, v.z);
                    let vt = truth_plane(i as usize);
                    Some(
                        ve.normalize()
                            .dot(&vt.normalize())
                            .abs()
                            .min(1.0)
                            .acos()
                            .to_degrees(),
                    )
                })
                .map_or("  -  ".to_string(), |a| format!("{a:5.1}"))
            };
            line += &format!(" {frame:3}:{}/{}", turn(slots[0]), turn(slots[1]));
            if p % 8 == 7 {
                println!("{line}");
                line.clear();
            }
        }
        println!("{line}");
    }
    for (i, slot) in ev.planes.iter().enumerate() {
        let frame = ev.pose_frames[slot.pose as usize];
        if !wanted.contains(&frame) {
            continue;
        }
        let vt = truth_plane(i);
        let v = cal.plane(i);
        let mut errs = Vec::new();
        let mut sig = Vec::new();
        let mut lines = Vec::new();
        let mut pts: Vec<V3> = Vec::new();
        for (k, c) in ev.crossings.iter().enumerate() {
            if c.a as usize != i && c.b as usize != i {
                continue;
            }
            let other = if c.a as usize == i { c.b } else { c.a } as usize;
            let oslot = ev.planes[other];
            let u = V3::new(c.u[0], c.u[1], 1.0);
            let ray = cal.ray(c.u);
            let e = match (v, &ray) {
                (Some(v), Some(ray)) => v.dot(&ray.r) * scale / vt.dot(&u) - 1.0,
                _ => f64::NAN,
            };
            if let Some(ray) = &ray {
                sig.push(cal.depth_sigma(i, ray));
            }
            errs.push(e);
            let z = run.sim.true_depth(&u);
            if let Some(z) = z {
                pts.push(u * z);
            }
            let mismatch = vt.dot(&u) / truth_plane(other).dot(&u) - 1.0;
            lines.push(format!(
                "    x {:+.4} {:+.4} with frame {:4} laser {} weight {:.2} residual {:+7.2} \
                 plane err {:+.4} % truth mismatch {:+.4} %{}",
                c.u[0],
                c.u[1],
                ev.pose_frames[oslot.pose as usize],
                oslot.laser,
                est.crossing_weights[k],
                est.crossing_residuals[k],
                100.0 * e,
                100.0 * mismatch,
                if ev.is_anchor(oslot.pose as usize) {
                    ""
                } else {
                    " (not anchor)"
                }
            ));
        }
        // How the crossings' true points spread: singular values of their scatter.
        let spread = if pts.len() >= 3 {
            let mean = pts.iter().sum::<V3>() / pts.len() as f64;
            let mut m = Matrix3::zeros();
            for p in &pts {
                let d = p - mean;
                m += d * d.transpose();
            }
            let mut s: Vec<f64> = m
                .symmetric_eigenvalues()
                .iter()
                .map(|x| (x.max(0.0) / pts.len() as f64).sqrt())
                .collect();
            s.sort_by(|a, b| b.total_cmp(a));
            format!("{:.4} {:.4} {:.5} m", s[0], s[1], s[2])
        } else {
            "-".into()
        };
        let angle = v.map_or(f64::NAN, |v| {
            // The estimate's rays are at its focal scale; compare the normals in the
            // camera file's normalised coordinates (λ = 1 unless estimated).
            let l = est.focal_scale;
            let ve = V3::new(v.x * l, v.y * l, v.z);
            (ve.normalize().dot(&vt.normalize()).abs().min(1.0))
                .acos()
                .to_degrees()
        });
        let pose = &est.poses[slot.pose as usize];
        let tc = V3::from(run.sim.truth.frames[frame as usize].projector_centre);
        println!(
            "  turn {angle:.3}° from the true plane; centre est {:?} true {:?} (scaled)",
            (pose.centre / scale)
                .as_slice()
                .iter()
                .map(|x| (x * 1e3).round() / 1e3)
                .collect::<Vec<_>>(),
            tc.as_slice()
                .iter()
                .map(|x| (x * 1e3).round() / 1e3)
                .collect::<Vec<_>>()
        );
        println!(
            "frame {frame} laser {} anchor {} verdict {:?}: {} crossings, error {:+.4} % \
             (median at them), sigma {:.4} %, true points spread {spread}",
            slot.laser,
            ev.is_anchor(slot.pose as usize),
            cal.verdicts[i],
            errs.len(),
            100.0 * median(errs.clone()),
            100.0 * median(sig.clone()),
        );
        if std::env::var("LIST").is_ok_and(|v| v == "1") {
            for l in lines {
                println!("{l}");
            }
        }
    }
    Ok(())
}
