//! Simulator speed: one 1920x1080 frame of the `room` scene (render only, and render +
//! PNG encoding as `crossline simulate` does), on all cores.
//!
//! `cargo bench --bench simulate`

use criterion::{criterion_group, criterion_main, Criterion};
use crossline::simulate::{builtin_scene, write_png_fast, SimParams, Simulator};

fn bench(c: &mut Criterion) {
    let Some(spec) = builtin_scene("room") else {
        return;
    };
    let Ok(sim) = Simulator::new(&spec, &SimParams::default()) else {
        return;
    };
    let mut img = image::RgbImage::new(1, 1);
    let mut group = c.benchmark_group("simulate");
    group.sample_size(10);
    let mut i = 0;
    group.bench_function("room 1920x1080 render", |b| {
        b.iter(|| {
            i += 1;
            sim.render_frame_into(i, &mut img, None)
        })
    });
    let dir = std::env::temp_dir().join("crossline-bench-simulate");
    let _ = std::fs::create_dir_all(&dir);
    let path = dir.join("frame.png");
    group.bench_function("room 1920x1080 render + png", |b| {
        b.iter(|| {
            i += 1;
            sim.render_frame_into(i, &mut img, None);
            write_png_fast(&path, &img)
        })
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
