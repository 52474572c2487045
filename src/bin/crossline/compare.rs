//! `crossline compare`: accuracy of a reconstructed cloud against a reference cloud or
//! against the simulator's ground truth. The numbers come from `crossline::compare`;
//! this file reads the inputs, draws progress, prints the summary and writes the files,
//! with the truth mode's own part in [`truth`].

mod truth;

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::Context;
use crossline::compare::plot::{self, HistogramStyle, Marker};
use crossline::compare::{self, AlignMode, AlignParams, CompareParams, ErrorStats};
use crossline::ply::{self, Cloud};
use indicatif::{ProgressBar, ProgressStyle};

/// Measure the accuracy of a reconstructed cloud.
///
/// Two modes:
///
///   --reference REF.ply  Distance from every point of CLOUD to the nearest point of
///                        REF (e.g. a LiDAR scan), in the clouds' units, after an
///                        optional alignment. As the paper checks its chapel scan
///                        against a Riegl cloud: a histogram of point-to-point
///                        distances, their statistics and a cloud coloured by distance.
///   --truth SIMDIR       Against a folder written by `crossline simulate`: relative
///                        depth error |s·Z − Z_true| / Z_true along each point's camera
///                        ray after the best global scale s (the one quantity the
///                        self-calibration cannot observe), the laser planes whose
///                        points are wrong together (one plane is one frame's one
///                        laser, from the PLY's `frame` and `laser` properties; it is
///                        wrong when its points' median error is over
///                        --wrong-plane-relative), and coverage of the lit image area.
///
/// Alignment (--reference only): `none` uses the clouds as they are; `scale` fits one
/// global scale about the camera centre (both clouds in the same camera frame: the
/// usual case for a self-calibrated, scale-free reconstruction); `similarity` fits
/// rotation, translation and scale by trimmed ICP (reference in another frame, roughly
/// pre-aligned).
///
/// Files with --out PREFIX: PREFIX_hist.png (histogram of the distances, or of the
/// relative depth errors with --truth), PREFIX_distances.ply (the cloud aligned, or
/// scaled by s, coloured by that value, which is also its `distance` property) and
/// PREFIX_report.json (the --json report, version 1).
///
/// Example:
///
///   crossline compare cloud.ply --reference lidar.ply --align scale --out eval/run1
///   crossline compare cloud.ply --truth sim --json
#[derive(clap::Args)]
#[command(verbatim_doc_comment)]
pub struct Args {
    /// The reconstructed cloud (PLY, ascii or binary).
    cloud: PathBuf,
    /// Reference cloud (PLY) to measure distances to.
    #[arg(
        long,
        value_name = "REF.ply",
        required_unless_present = "truth",
        conflicts_with = "truth"
    )]
    reference: Option<PathBuf>,
    /// Folder written by `crossline simulate` holding the ground truth.
    #[arg(long, value_name = "SIMDIR")]
    truth: Option<PathBuf>,
    /// How to align the cloud to the reference before measuring.
    #[arg(long, value_enum, default_value_t = AlignMode::None)]
    align: AlignMode,
    /// Distances (reference units) whose exceedance is reported, comma separated.
    /// Default: 0.1 %, 0.5 % and 1 % of the reference's bounding-box diagonal.
    #[arg(long, value_delimiter = ',', value_name = "D1,D2,..")]
    thresholds: Vec<f64>,
    /// Alignment keeps pairs closer than 3× this quantile of the pair distances; set it
    /// below the share of the cloud that overlaps the reference.
    #[arg(long, default_value_t = 0.5, value_name = "FRACTION")]
    overlap: f64,
    /// Bars in the histogram.
    #[arg(long, default_value_t = 60)]
    bins: usize,
    /// Relative depth error above which a point is an outlier (--truth; 0.02 = 2 %).
    #[arg(long, default_value_t = 0.02)]
    outlier: f64,
    /// A laser plane (one frame's one laser) is wrong when the median relative depth
    /// error of its points is above this (--truth; 0.02 = 2 %).
    #[arg(long, default_value_t = 0.02, value_name = "FRACTION")]
    wrong_plane_relative: f64,
    /// A lit pixel is covered when a point projects within this many pixels (--truth).
    #[arg(long, default_value_t = 2.0, value_name = "PX")]
    coverage_radius: f64,
    /// Write PREFIX_hist.png, PREFIX_distances.ply and PREFIX_report.json (PREFIX may
    /// include a folder, which must exist).
    #[arg(long, value_name = "PREFIX")]
    out: Option<PathBuf>,
    /// Print the JSON report on stdout instead of the summary.
    #[arg(long)]
    json: bool,
}

pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    if !(args.overlap > 0.0 && args.overlap <= 1.0) {
        anyhow::bail!("--overlap must be in (0, 1], got {}", args.overlap);
    }
    if args
        .thresholds
        .iter()
        .any(|t| !(t.is_finite() && *t >= 0.0))
    {
        anyhow::bail!(
            "--thresholds must be non-negative distances, got {:?}",
            args.thresholds
        );
    }
    let cloud = read(&args.cloud)?;
    match (&args.reference, &args.truth) {
        (Some(reference), _) => run_reference(&args, &cloud, reference),
        (None, Some(dir)) => truth::run(&args, &cloud, dir),
        (None, None) => anyhow::bail!("give --reference REF.ply or --truth SIMDIR"),
    }
}

fn read(path: &Path) -> anyhow::Result<Cloud> {
    let cloud = ply::read_ply(path).with_context(|| format!("reading cloud {}", path.display()))?;
    tracing::debug!("{}: {} points", path.display(), cloud.len());
    Ok(cloud)
}

/// A progress bar on stderr; indicatif draws nothing when stderr is not a terminal.
fn progress_bar() -> ProgressBar {
    let bar = ProgressBar::new(0);
    if let Ok(style) =
        ProgressStyle::with_template("{spinner} {msg:<18} [{bar:30}] {pos}/{len} {elapsed}")
    {
        bar.set_style(style.progress_chars("=> "));
    }
    bar.enable_steady_tick(std::time::Duration::from_millis(200));
    bar
}

fn with_suffix(prefix: &Path, suffix: &str) -> PathBuf {
    let mut s = prefix.as_os_str().to_owned();
    s.push(suffix);
    PathBuf::from(s)
}

fn run_reference(args: &Args, cloud: &Cloud, reference_path: &Path) -> anyhow::Result<ExitCode> {
    let reference = read(reference_path)?;
    let params = CompareParams {
        align: args.align,
        align_params: AlignParams {
            keep_fraction: args.overlap,
            ..AlignParams::default()
        },
        thresholds: (!args.thresholds.is_empty()).then(|| args.thresholds.clone()),
    };
    let bar = progress_bar();
    let progress = |stage: &str, done: u64, total: u64| {
        bar.set_message(stage.to_string());
        bar.set_length(total);
        bar.set_position(done);
    };
    let result =
        compare::compare_to_reference(&cloud.points, &reference.points, &params, &progress)
            .with_context(|| {
                format!(
                    "comparing {} with {}",
                    args.cloud.display(),
                    reference_path.display()
                )
            });
    bar.finish_and_clear();
    let result = result?;
    let report = result.report(
        &args.cloud.to_string_lossy(),
        &reference_path.to_string_lossy(),
        reference.len(),
    );
    let json = serde_json::to_string_pretty(&report).context("serialising the report")?;
    if args.json {
        crate::outln!("{json}");
    } else {
        print_reference_summary(args, cloud, &reference, &result, reference_path)?;
    }
    if let Some(prefix) = &args.out {
        let s = &result.stats;
        let title = format!(
            "N={}  MEDIAN={}  RMS={}  ALIGN={}",
            s.count,
            short(s.median),
            short(s.rms),
            mode_name(args.align)
        );
        let t = &result.alignment.transform;
        let comment = format!(
            "crossline compare: distance to {} after --align {} (points aligned)",
            reference_path.display(),
            mode_name(args.align)
        );
        let written = write_plots(
            prefix,
            cloud,
            |p| {
                let m = t.apply(p);
                [m.x as f32, m.y as f32, m.z as f32]
            },
            &result.distances,
            s,
            Labels {
                title,
                x_label: "DISTANCE (SCENE UNITS)".into(),
                comment,
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

struct Labels {
    title: String,
    x_label: String,
    comment: String,
}

/// Writes PREFIX_hist.png (histogram of `values`) and PREFIX_distances.ply (`cloud`
/// moved by `place`, coloured by `values`, which become its `distance` property);
/// returns the two paths for the summary.
fn write_plots(
    prefix: &Path,
    cloud: &Cloud,
    place: impl Fn(&[f32; 3]) -> [f32; 3],
    values: &[f32],
    stats: &ErrorStats,
    labels: Labels,
    bins: usize,
) -> anyhow::Result<String> {
    // The histogram's range and the colour scale end at the 99th percentile, so that a
    // few far outliers do not flatten everything else.
    let x_max = if stats.p99 > 0.0 {
        stats.p99
    } else {
        stats.max.max(f64::MIN_POSITIVE)
    };
    let style = HistogramStyle {
        bins: bins.max(1),
        title: labels.title,
        x_label: labels.x_label,
        ..HistogramStyle::default()
    };
    let markers = [
        Marker {
            label: format!("MEDIAN {}", short(stats.median)),
            value: stats.median,
            colour: [200, 30, 30],
        },
        Marker {
            label: format!("P95 {}", short(stats.p95)),
            value: stats.p95,
            colour: [230, 140, 0],
        },
    ];
    let img = plot::histogram_image(values, x_max, &markers, &style);
    let png = with_suffix(prefix, "_hist.png");
    img.save(&png)
        .with_context(|| format!("writing histogram {}", png.display()))?;
    let coloured = Cloud {
        points: cloud.points.iter().map(place).collect(),
        colors: Some(
            values
                .iter()
                .map(|&d| plot::colour_map(d as f64 / x_max))
                .collect(),
        ),
        frames: cloud.frames.clone(),
        lasers: cloud.lasers.clone(),
        distances: Some(values.to_vec()),
        depth_sigmas: cloud.depth_sigmas.clone(),
    };
    let ply_path = with_suffix(prefix, "_distances.ply");
    let comments = [
        labels.comment,
        format!("colour: viridis over 0 .. {x_max} (p99), grey = none"),
    ];
    ply::write_ply(&ply_path, &coloured, &comments)
        .with_context(|| format!("writing coloured cloud {}", ply_path.display()))?;
    Ok(format!("{}, {}", png.display(), ply_path.display()))
}

fn mode_name(mode: AlignMode) -> &'static str {
    match mode {
        AlignMode::None => "none",
        AlignMode::Scale => "scale",
        AlignMode::Similarity => "similarity",
    }
}

/// A compact number for labels: 4 significant digits, exponent for extremes.
fn short(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return format!("{v}");
    }
    let mag = v.abs().log10().floor();
    if !(-4.0..6.0).contains(&mag) {
        return format!("{v:.3e}").to_uppercase();
    }
    let decimals = (3.0 - mag).max(0.0) as usize;
    format!("{v:.decimals$}")
}

fn print_stats(stats: &ErrorStats, unit: &str) -> anyhow::Result<()> {
    for (name, v) in [
        ("mean", stats.mean),
        ("median", stats.median),
        ("rms", stats.rms),
        ("p95", stats.p95),
        ("p99", stats.p99),
        ("max", stats.max),
    ] {
        crate::outln!("  {name:<10}{:>14}{unit}", short(v));
    }
    for e in &stats.over {
        crate::outln!(
            "  > {:<8}{:>13.3} % of points",
            short(e.threshold),
            100.0 * e.fraction
        );
    }
    Ok(())
}

fn print_reference_summary(
    args: &Args,
    cloud: &Cloud,
    reference: &Cloud,
    result: &compare::ReferenceComparison,
    reference_path: &Path,
) -> anyhow::Result<()> {
    let a = &result.alignment;
    let t = &a.transform;
    crate::outln!(
        "cloud      {} ({} points)",
        args.cloud.display(),
        cloud.len()
    );
    crate::outln!(
        "reference  {} ({} points, bounding-box diagonal {})",
        reference_path.display(),
        reference.len(),
        short(result.reference_diagonal)
    );
    match a.mode {
        AlignMode::None => crate::outln!("alignment  none"),
        mode => {
            crate::outln!(
                "alignment  {}: scale {:.6}, {} iterations, {} pairs kept, pair rms {}",
                mode_name(mode),
                t.scale,
                a.iterations,
                a.pairs,
                short(a.rms)
            );
            if mode == AlignMode::Similarity {
                let r = &t.rotation;
                crate::outln!(
                    "           rotation {:.4}° ; translation ({}, {}, {})",
                    t.angle().to_degrees(),
                    short(t.translation.x),
                    short(t.translation.y),
                    short(t.translation.z)
                );
                for i in 0..3 {
                    crate::outln!(
                        "           [{:>10.6} {:>10.6} {:>10.6}]",
                        r[(i, 0)],
                        r[(i, 1)],
                        r[(i, 2)]
                    );
                }
            }
        }
    }
    crate::outln!(
        "distances  to the nearest reference point, reference units ({} of {} points)",
        result.stats.count,
        cloud.len()
    );
    print_stats(&result.stats, "")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn output_names_and_short_numbers() {
        assert_eq!(
            with_suffix(Path::new("eval/run1"), "_hist.png"),
            PathBuf::from("eval/run1_hist.png")
        );
        assert_eq!(short(0.004946123), "0.004946");
        assert_eq!(short(1234.5678), "1235");
        assert_eq!(short(2.5e-7), "2.500E-7");
        assert_eq!(short(0.0), "0");
    }

    #[test]
    fn reference_mode_writes_histogram_coloured_cloud_and_report() {
        let dir = tempfile::tempdir().expect("temp dir");
        let grid: Vec<[f32; 3]> = (0..60 * 60)
            .map(|i| [(i % 60) as f32 * 0.01, (i / 60) as f32 * 0.01, 2.0])
            .collect();
        // Every other grid point, 1 cm in front of the plane.
        let cloud: Vec<[f32; 3]> = grid.iter().step_by(2).map(|p| [p[0], p[1], 1.99]).collect();
        let write = |name: &str, points: Vec<[f32; 3]>| {
            let path = dir.path().join(name);
            let c = Cloud {
                points,
                ..Cloud::default()
            };
            ply::write_ply(&path, &c, &[]).expect("write");
            path
        };
        let args = Args {
            cloud: write("cloud.ply", cloud.clone()),
            reference: Some(write("ref.ply", grid)),
            truth: None,
            align: AlignMode::None,
            thresholds: vec![0.005, 0.02],
            overlap: 0.5,
            bins: 40,
            outlier: 0.02,
            wrong_plane_relative: 0.02,
            coverage_radius: 2.0,
            out: Some(dir.path().join("run")),
            json: true,
        };
        run(args).expect("compare runs");
        let img = image::open(dir.path().join("run_hist.png"))
            .expect("png")
            .to_rgb8();
        assert_eq!((img.width(), img.height()), (900, 560));
        let coloured = ply::read_ply(&dir.path().join("run_distances.ply")).expect("ply");
        assert_eq!(coloured.len(), cloud.len());
        let d = coloured.distances.expect("distance property");
        assert!(d.iter().all(|&d| (d - 0.01).abs() < 1e-5), "{:?}", &d[..4]);
        assert!(coloured.colors.is_some());
        let text = std::fs::read_to_string(dir.path().join("run_report.json")).expect("json");
        let json: serde_json::Value = serde_json::from_str(&text).expect("valid json");
        assert_eq!(json["version"], 1);
        assert_eq!(json["points"], cloud.len());
        assert!((json["distances"]["median"].as_f64().expect("median") - 0.01).abs() < 1e-5);
        assert_eq!(json["distances"]["over"][0]["fraction"], 1.0);
        assert_eq!(json["distances"]["over"][1]["fraction"], 0.0);
    }
}
