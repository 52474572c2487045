//! Writes one realistic frame, its local background and the local excess to /tmp for
//! a look: `cargo run --release --example realistic_debug SEED FRAME`.
use crossline::extract::{Background, ExtractParams, Extractor, LaserColour};
use crossline::simulate::random::draw_realistic;
use crossline::simulate::Simulator;

fn main() {
    let args: Vec<u64> = std::env::args()
        .skip(1)
        .filter_map(|a| a.parse().ok())
        .collect();
    let (seed, index) = (
        args.first().copied().unwrap_or(5),
        args.get(1).copied().unwrap_or(5) as usize,
    );
    let drawn = draw_realistic(seed, 40);
    eprintln!("{:?}", drawn.params.realism);
    let sim = Simulator::new(&drawn.spec, &drawn.params).expect("sim");
    let cam = sim.camera().clone();
    let params = ExtractParams {
        lasers: LaserColour::named(drawn.spec.projector.colours.iter().map(|c| c.name())),
        ..ExtractParams::default()
    };
    let mut ex = Extractor::new(&params, &cam).expect("ex");
    let (img, _) = sim.render_frame(index);
    let curves = ex.extract(&img, &Background::local(cam.width, cam.height));
    img.save("/tmp/rd_frame.png").ok();
    let bg = ex.local_background().clone();
    bg.save("/tmp/rd_local.png").ok();
    let mut exc = img.clone();
    for (e, b) in exc.pixels_mut().zip(bg.pixels()) {
        for c in 0..3 {
            e.0[c] = e.0[c].saturating_sub(b.0[c]).saturating_mul(3);
        }
    }
    let mut ov = img.clone();
    for c in &curves {
        for p in &c.points_px {
            let (x, y) = (p[0].round() as u32, p[1].round() as u32);
            if x < ov.width() && y < ov.height() {
                ov.put_pixel(
                    x,
                    y,
                    image::Rgb(if c.laser == 0 {
                        [255, 0, 255]
                    } else {
                        [0, 255, 255]
                    }),
                );
            }
        }
    }
    exc.save("/tmp/rd_excess.png").ok();
    ov.save("/tmp/rd_overlay.png").ok();
    eprintln!("{} curves, {:?}", curves.len(), ex.stats());
}
