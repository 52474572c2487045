//! The `--truth` mode of `crossline compare`: evaluates a cloud against a folder written
//! by `crossline simulate` and prints the summary; the numbers come from
//! `crossline::compare::truth` and `crossline::compare::planes`.

use std::path::Path;
use std::process::ExitCode;

use anyhow::Context;
use crossline::compare::{self, AlignMode, GroundTruth, PlaneIds, TruthModeReport, TruthParams};
use crossline::ply::Cloud;

use super::{print_stats, short, with_suffix, write_plots, Args, Labels};

pub(super) fn run(args: &Args, cloud: &Cloud, dir: &Path) -> anyhow::Result<ExitCode> {
    if args.align != AlignMode::None {
        tracing::warn!("--align is ignored with --truth: the best scale is always fitted");
    }
    if !(args.wrong_plane_relative.is_finite() && args.wrong_plane_relative >= 0.0) {
        anyhow::bail!(
            "--wrong-plane-relative must be a non-negative fraction, got {}",
            args.wrong_plane_relative
        );
    }
    let truth = load_truth(dir)?;
    let params = TruthParams {
        outlier_relative: args.outlier,
        coverage_radius_px: args.coverage_radius,
        wrong_plane_relative: args.wrong_plane_relative,
    };
    let planes = match (&cloud.frames, &cloud.lasers) {
        (Some(frames), Some(lasers)) => Some(PlaneIds { frames, lasers }),
        _ => None,
    };
    let mut report =
        compare::evaluate_cloud_against_truth(&cloud.points, planes, truth.as_ref(), &params)
            .with_context(|| {
                format!(
                    "evaluating {} against {}",
                    args.cloud.display(),
                    dir.display()
                )
            })?;
    if let (Some(ids), Some(sigmas)) = (planes, &cloud.depth_sigmas) {
        report.uncertainty =
            compare::planes::uncertainty_check(&report.per_point_signed, sigmas, ids);
    }
    let full = TruthModeReport::new(
        &args.cloud.to_string_lossy(),
        &dir.to_string_lossy(),
        report,
    );
    let json = serde_json::to_string_pretty(&full).context("serialising the report")?;
    if args.json {
        crate::outln!("{json}");
    } else {
        let r = &full.truth;
        crate::outln!("cloud      {} ({} points)", args.cloud.display(), r.points);
        crate::outln!("truth      {}", dir.display());
        crate::outln!(
            "points     {} evaluated, {} with no surface on their ray, {} invalid",
            r.evaluated,
            r.no_surface,
            r.invalid
        );
        crate::outln!(
            "scale      {:.6} (median start {:.6})",
            r.scale,
            r.scale_median
        );
        crate::outln!(
            "outliers   {:.3} % over {} % relative depth error",
            100.0 * r.outlier_fraction,
            100.0 * r.outlier_relative
        );
        crate::outln!("relative depth error |s·Z − Z_true| / Z_true");
        print_stats(&r.relative_error, "")?;
        print_planes(r, cloud)?;
        if let Some(u) = &r.uncertainty {
            crate::outln!(
                "deviation  planes' errors in their own depth_sigma: median {:.2} (0.67 if \
                 honest); {} of {} planes over 3, carrying {:.3} % of the points",
                u.median_z,
                u.planes_over_3,
                u.planes,
                100.0 * u.points_on_planes_over_3_fraction
            );
        }
        crate::outln!(
            "coverage   {:.2} % of {} lit pixels have a point within {} px",
            100.0 * r.coverage.fraction,
            r.coverage.lit_pixels,
            r.coverage.radius_px
        );
        if let Some(v) = &r.coverage_visible {
            crate::outln!(
                "           {:.2} % of the {} where the stripe was visible (peak >= 5 x noise)",
                100.0 * v.fraction,
                v.lit_pixels
            );
        }
    }
    if let Some(prefix) = &args.out {
        let r = &full.truth;
        let scale = r.scale as f32;
        let written = write_plots(
            prefix,
            cloud,
            |p| p.map(|c| c * scale),
            &r.per_point,
            &r.relative_error,
            Labels {
                title: format!(
                    "N={}  MEDIAN={}  SCALE={}",
                    r.evaluated,
                    short(r.relative_error.median),
                    short(r.scale)
                ),
                x_label: "RELATIVE DEPTH ERROR".into(),
                comment: format!(
                    "crossline compare: relative depth error against {} (points scaled by {})",
                    dir.display(),
                    r.scale
                ),
            },
            args.bins,
        )?;
        let json_path = with_suffix(prefix, "_report.json");
        std::fs::write(&json_path, format!("{json}\n"))
            .with_context(|| format!("writing report {}", json_path.display()))?;
        if !args.json {
            crate::outln!("wrote      {written}, {}", json_path.display());
        }
    }
    Ok(ExitCode::SUCCESS)
}

/// The wrong-plane counts of the summary, or why there are none.
fn print_planes(r: &compare::TruthReport, cloud: &Cloud) -> anyhow::Result<()> {
    let bound = 100.0 * r.wrong_plane_relative;
    match (
        r.planes_evaluated,
        r.wrong_planes,
        r.points_on_wrong_planes,
        r.points_on_wrong_planes_fraction,
    ) {
        (Some(planes), Some(wrong), Some(points), Some(fraction)) => {
            crate::outln!(
                "planes     {wrong} of {planes} wrong (median error over {bound} %), \
                 carrying {points} points: {:.3} % of the evaluated",
                100.0 * fraction
            );
        }
        _ => {
            let missing = match (cloud.frames.is_some(), cloud.lasers.is_some()) {
                (false, false) => "`frame` and `laser` properties",
                (false, true) => "`frame` property",
                _ => "`laser` property",
            };
            crate::outln!(
                "planes     not evaluated: the cloud has no per-point {missing} \
                 (the PLY that `reconstruct` writes has both)"
            );
        }
    }
    Ok(())
}

/// The ground truth of a folder written by `crossline simulate`.
fn load_truth(dir: &Path) -> anyhow::Result<Box<dyn GroundTruth>> {
    let sim = crossline::simulate::load_sim_dir(dir)
        .with_context(|| format!("loading the simulation truth from {}", dir.display()))?;
    Ok(Box::new(sim))
}
