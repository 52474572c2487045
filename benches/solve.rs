//! Crossing search and the global plane solve on synthetic scans with known planes.
//!
//! `cargo bench --bench solve` (`-- calibrate` for the self-calibration alone). The
//! scans come from `crossline::solve::synthetic`: a room seen from inside, random
//! hand-held crosses, and a smooth hand path.

use criterion::{criterion_group, Criterion};
use crossline::intersect::find_crossings;
use crossline::solve::dense::DenseThreads;
use crossline::solve::synthetic::{
    analytic_crossings, curve_polyline, path_evidence, path_scan, random_scan, PathSpec, ScanSpec,
};
use crossline::solve::{calibrate, solve, Problem, SolveParams};
use std::hint::black_box;

fn crossing_search(c: &mut Criterion) {
    // 2000 curves of about 50 segments each.
    let scan = random_scan(&ScanSpec {
        num_crosses: 1000,
        seed: 1,
        ..ScanSpec::default()
    });
    let polylines: Vec<Vec<[f64; 2]>> = scan
        .planes
        .iter()
        .filter_map(|v| curve_polyline(&scan.scene, v, 0.03))
        .collect();
    let refs: Vec<&[[f64; 2]]> = polylines.iter().map(|p| p.as_slice()).collect();
    let segments: usize = refs.iter().map(|p| p.len() - 1).sum();
    let found = find_crossings(&refs, 0.1).len();
    eprintln!(
        "crossing search: {} curves, {segments} segments, {found} crossings",
        refs.len()
    );
    let mut group = c.benchmark_group("intersect");
    group.sample_size(10);
    group.bench_function("find_crossings_2000_curves", |b| {
        b.iter(|| find_crossings(black_box(&refs), 0.1))
    });
    group.finish();
}

fn global_solve(c: &mut Criterion) {
    // 400 planes, every crossing among them.
    let scan = random_scan(&ScanSpec {
        num_crosses: 200,
        seed: 2,
        ..ScanSpec::default()
    });
    let crossings = analytic_crossings(&scan.scene, &scan.planes, 0.1);
    eprintln!(
        "global solve: {} curves, {} crossings",
        scan.planes.len(),
        crossings.len()
    );
    let problem = Problem {
        focal_px: 1000.0,
        num_curves: scan.planes.len(),
        crossings: &crossings,
        partner: &scan.partner,
    };
    let params = SolveParams::default();
    let mut group = c.benchmark_group("solve");
    group.sample_size(10);
    group.bench_function("solve_400_planes", |b| {
        b.iter(|| solve(black_box(&problem), &params).map(|s| s.global.len()))
    });
    group.finish();
}

/// The self-calibration of a 300-frame hand path over the synthetic room (300 poses, all
/// of them anchors: 1,800 unknowns in the joint estimate), its crossings exact but for
/// 0.1 px of noise; the dense factorisations on one thread and on two
/// (`SolveParams::dense_threads`: the same answer).
fn self_calibration(c: &mut Criterion) {
    const FOCAL_PX: f64 = 1000.0;
    let scan = path_scan(&PathSpec {
        frames: 300,
        ..PathSpec::default()
    });
    let evidence = path_evidence(&scan, FOCAL_PX, 0.1, 3, |_, _| true);
    eprintln!(
        "self-calibration: {} poses, {} crossings",
        evidence.num_poses(),
        evidence.crossings.len()
    );
    let mut group = c.benchmark_group("calibrate");
    group.sample_size(10);
    for threads in [1, 2] {
        let mut params = SolveParams::default();
        params.dense_threads = DenseThreads(threads);
        group.bench_function(format!("path_300_poses_{threads}_threads"), |b| {
            b.iter(|| calibrate(black_box(&evidence), &params).map(|c| c.summary.iterations))
        });
    }
    group.finish();
}

criterion_group!(benches, crossing_search, global_solve, self_calibration);

/// faer's dense kernels on one thread, as the `crossline` binary runs them: on these
/// sizes its parallel kernels spend more time waking threads than computing, so the
/// bench measures what users get.
fn main() {
    faer::set_global_parallelism(faer::Par::Seq);
    benches();
    criterion::Criterion::default()
        .configure_from_args()
        .final_summary();
}
