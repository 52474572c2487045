//! Decoding camera buffers at 1920x1080: MJPEG (with the standard Huffman tables put
//! back when a camera leaves them out) and YUYV, to RGB as the extractor takes it.
//!
//! `cargo bench --bench decode` prints the time per frame.

use criterion::{criterion_group, criterion_main, Criterion};
use crossline::camera::Camera;
use crossline::capture::dump::{decode_rgb, DumpHeader};
use crossline::extract::{Background, ExtractParams, Extractor};
use image::RgbImage;

const W: u32 = 1920;
const H: u32 = 1080;

fn header(fourcc: &[u8; 4], bytes_per_line: u32) -> DumpHeader {
    DumpHeader {
        fourcc: *fourcc,
        width: W,
        height: H,
        bytes_per_line,
        interval_num: 1,
        interval_den: 30,
        device: "bench".into(),
        card: "bench".into(),
    }
}

/// A textured frame (smooth shading plus fine detail, as a camera sees a scene).
fn frame() -> RgbImage {
    RgbImage::from_fn(W, H, |x, y| {
        let (fx, fy) = (x as f32, y as f32);
        let t = 110.0
            + 50.0 * (0.011 * fx).sin() * (0.017 * fy).cos()
            + 20.0 * (0.9 * fx + 0.7 * fy).sin();
        image::Rgb([t as u8, (t * 0.8) as u8, (255.0 - t) as u8])
    })
}

fn yuyv(img: &RgbImage) -> Vec<u8> {
    let mut out = Vec::with_capacity((W * H * 2) as usize);
    for y in 0..H {
        for x in (0..W).step_by(2) {
            let p = img.get_pixel(x, y).0;
            let q = img.get_pixel(x + 1, y).0;
            let luma = |p: [u8; 3]| {
                (16.0 + 0.257 * p[0] as f32 + 0.504 * p[1] as f32 + 0.098 * p[2] as f32) as u8
            };
            let u = 128.0 - 0.148 * p[0] as f32 - 0.291 * p[1] as f32 + 0.439 * p[2] as f32;
            let v = 128.0 + 0.439 * p[0] as f32 - 0.368 * p[1] as f32 - 0.071 * p[2] as f32;
            out.extend_from_slice(&[luma(p), u as u8, luma(q), v as u8]);
        }
    }
    out
}

fn bench(c: &mut Criterion) {
    let img = frame();
    let mut jpeg = Vec::new();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 90)
        .encode_image(&img)
        .expect("encode");
    let mjpg = header(b"MJPG", 0);
    c.bench_function("decode MJPEG 1080p to RGB", |b| {
        b.iter(|| decode_rgb(&mjpg, &jpeg).expect("decode"))
    });
    let raw = yuyv(&img);
    let yuyv_header = header(b"YUYV", 2 * W);
    c.bench_function("decode YUYV 1080p to RGB", |b| {
        b.iter(|| decode_rgb(&yuyv_header, &raw).expect("decode"))
    });
    // A laser-free YUYV frame against its own background: what the daemon spends on
    // the frame's pixels outside the stripes, whole conversion plus extraction versus
    // extraction straight from YUYV.
    let camera = Camera::with_fov(W, H, 1.0);
    let bg = Background::from_image(decode_rgb(&yuyv_header, &raw).expect("decode"));
    let mut ex = Extractor::new(&ExtractParams::default(), &camera).expect("extractor");
    c.bench_function("YUYV 1080p: decode to RGB, then extract", |b| {
        b.iter(|| ex.extract(&decode_rgb(&yuyv_header, &raw).expect("decode"), &bg))
    });
    c.bench_function("YUYV 1080p: extract straight from YUYV", |b| {
        b.iter(|| ex.extract_yuyv(&raw, 2 * W as usize, &bg).expect("yuyv"))
    });
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(20);
    targets = bench
}
criterion_main!(benches);
