//! k-d tree build and nearest-neighbour distances at 1 M reference points × 1 M query
//! points, the figures behind the "10 M vs 10 M well under a minute" target.
//!
//! `cargo bench --bench compare` (about a minute). The points lie on a wavy surface, as
//! scans do, and the queries are other samples of it moved by up to ±5 mm (0.1 % of its
//! size), like a scan close to its reference.

use criterion::{criterion_group, criterion_main, Criterion};
use crossline::compare::{nearest_distances, no_progress, KdTree, Similarity};

/// SplitMix64 in [0, 1).
fn uniform(state: &mut u64) -> f32 {
    *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = *state;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    ((z ^ (z >> 31)) >> 40) as f32 / (1u64 << 24) as f32
}

fn surface(n: usize, seed: u64, jitter: f32) -> Vec<[f32; 3]> {
    let mut s = seed;
    (0..n)
        .map(|_| {
            let x = uniform(&mut s) * 4.0 - 2.0;
            let y = uniform(&mut s) * 3.0 - 1.5;
            let z = 3.0 + 0.3 * (2.0 * x).sin() * (1.5 * y).cos() + 0.2 * x;
            let j = (uniform(&mut s) - 0.5) * jitter;
            [x, y, z + j]
        })
        .collect()
}

fn bench(c: &mut Criterion) {
    const N: usize = 1_000_000;
    let reference = surface(N, 1, 0.0);
    let queries = surface(N, 2, 0.01);
    let mut group = c.benchmark_group("kdtree_1M");
    group.sample_size(10);
    group.bench_function("build", |b| {
        b.iter(|| KdTree::new(&reference).map(|t| t.len()))
    });
    let tree = KdTree::new(&reference).expect("fewer than 2^32 points");
    let mut out = vec![0f32; N];
    group.bench_function("nearest_distances_1M", |b| {
        b.iter(|| {
            nearest_distances(
                &tree,
                &queries,
                &Similarity::default(),
                &mut out,
                &no_progress,
            );
            out[0]
        })
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
