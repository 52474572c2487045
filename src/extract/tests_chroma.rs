//! The chroma rebuild's pull on ridge centres ([`super::chroma`]): the rebuild read
//! off frames, and stripes in 4:2:0 chroma, repeated and interpolated, centred as in
//! full-resolution chroma.

use super::chroma::{Rebuild, Sampling};
use super::tests_real::{distance_errors, frame, red_green_extractor};
use super::*;
use crate::simulate::realism::subsample_chroma;
use crate::simulate::{encode_jpeg, JpegChroma};

/// `img`'s chroma through 4:2:0 and `rebuild` (none for [`Rebuild::Full`]).
fn rebuilt(mut img: RgbImage, rebuild: Rebuild) -> RgbImage {
    let (w, h) = (img.width() as usize, img.height() as usize);
    if rebuild != Rebuild::Full {
        subsample_chroma(&mut img, (w, h), rebuild == Rebuild::Interpolated);
    }
    img
}

/// A lit room: a surface whose colour varies smoothly, bands of another colour with
/// sharp, slanted edges (so that the edges fall between every pair of pixels), and
/// noise. The edges are what tell the rebuild: smooth chroma satisfies both relations
/// at both phases.
fn room(w: u32, h: u32) -> RgbImage {
    let surface = |x: f64, y: f64| {
        let band = if (0.8 * x + 0.45 * y).rem_euclid(23.0) < 9.0 {
            [50.0, -25.0, 10.0]
        } else {
            [0.0; 3]
        };
        [
            110.0 + 40.0 * (0.05 * x + 0.03 * y).sin() + band[0],
            90.0 + 30.0 * (0.04 * y - 0.02 * x).cos() + band[1],
            80.0 + 20.0 * (0.03 * x).sin() + band[2],
        ]
    };
    frame((w, h), &surface, None, 2.0)
}

#[test]
fn the_chroma_rebuild_is_read_off_the_frame() {
    let (w, h) = (160, 120);
    for rebuild in [Rebuild::Full, Rebuild::Repeated, Rebuild::Interpolated] {
        let mut s = Sampling::UNKNOWN;
        s.read(&rebuilt(room(w, h), rebuild));
        assert_eq!(s.rebuild, [rebuild; 2], "{rebuild:?}");
        assert_eq!((s.told, s.offset), ([true; 2], [0, 0]), "{rebuild:?}");
        // Blocks that start on the second pixel (a frame cropped by one).
        let img = rebuilt(room(w + 1, h + 1), rebuild);
        let cropped = image::imageops::crop_imm(&img, 1, 1, w, h).to_image();
        let mut s = Sampling::UNKNOWN;
        s.read(&cropped);
        assert_eq!(s.rebuild, [rebuild; 2], "{rebuild:?}, cropped");
        if rebuild != Rebuild::Full {
            assert_eq!(s.offset, [1, 1], "{rebuild:?}, cropped");
        }
    }
    // A flat grey frame tells nothing either way.
    let flat = frame((w, h), &|_, _| [90.0; 3], None, 0.3);
    let mut s = Sampling::UNKNOWN;
    s.read(&flat);
    assert_eq!(s.told, [false; 2]);
    assert!(!s.is_subsampled());
}

/// Per phase of the 2 px grid (16 steps), the median signed error (px) of the points
/// on a horizontal red stripe of Gaussian std `s`, the frames' chroma rebuilt as
/// `rebuild`, against a laser-off frame or a `local` background; `sampling`, when
/// given, replaces what the extractor reads off the frames.
fn phase_errors(rebuild: Rebuild, s: f64, sampling: Option<Sampling>, local: bool) -> Vec<f64> {
    let (w, h) = (320u32, 120u32);
    let surface = |_: f64, _: f64| [40.0, 40.0, 40.0];
    let mut ex = red_green_extractor(w, h);
    if let Some(sampling) = sampling {
        ex.sampling.sampling = sampling;
    }
    let off = if local {
        Background::local(w, h)
    } else {
        Background::from_image(rebuilt(frame((w, h), &surface, None, 0.5), rebuild))
    };
    (0..16)
        .map(|k| {
            // Phase 0.5 (k = 4), a stripe on the blocks' centres, gives a flat-topped
            // profile in repeated chroma: left out (see the docs' known limits).
            let line = (60.03 + k as f64 / 8.0, 0.0);
            let stripe = Some((line.0, line.1, s, 150.0, [1.0, 0.1, 0.05]));
            let img = rebuilt(frame((w, h), &surface, stripe, 0.5), rebuild);
            let mut e = distance_errors(&ex.extract(&img, &off), line, 20.0, w as f64);
            e.sort_by(f64::total_cmp);
            e.get(e.len() / 2).copied().unwrap_or(0.0)
        })
        .collect()
}

#[test]
fn a_stripe_in_subsampled_chroma_is_centred_as_in_full_chroma() {
    let worst = |e: &[f64]| e.iter().fold(0f64, |m, v| m.max(v.abs()));
    let full = worst(&phase_errors(Rebuild::Full, 1.0, None, false));
    assert!(full < 0.01, "full chroma: {full:.3} px");
    let mut unread = Sampling::UNKNOWN;
    unread.settle();
    for (rebuild, pull) in [(Rebuild::Repeated, 0.1), (Rebuild::Interpolated, 0.05)] {
        // Taken as full, the rebuild pulls the centres by up to `pull` px.
        let raw = worst(&phase_errors(rebuild, 1.0, Some(unread), false));
        assert!(raw > pull, "{rebuild:?} taken as full: {raw:.3} px");
        // Read off the frames, each point moved back by the model of its rebuild.
        let moved = worst(&phase_errors(rebuild, 1.0, None, false));
        assert!(
            moved < 0.025,
            "{rebuild:?}: {moved:.3} px, {raw:.3} px unmoved"
        );
        // Against a local background the stripe stands on the opening's pedestal,
        // which widens the width read off the point: less of the pull is taken out.
        let raw = worst(&phase_errors(rebuild, 1.0, Some(unread), true));
        let moved = worst(&phase_errors(rebuild, 1.0, None, true));
        eprintln!("{rebuild:?} local: {moved:.3} px, {raw:.3} px unmoved");
        assert!(
            moved < 0.5 * raw,
            "{rebuild:?}, local: {moved:.3} px, {raw:.3} px unmoved"
        );
    }
}

/// `img` through a camera's MJPEG: encoded with `chroma` as the simulator's dumps are
/// (each block's chroma averaged, as libjpeg and cameras do), decoded as a recording's
/// frame is; and what the bytes say of the decoder's rebuild.
fn through_mjpeg(
    img: &RgbImage,
    chroma: JpegChroma,
    quality: u8,
) -> (RgbImage, Option<[Rebuild; 2]>) {
    let bytes = encode_jpeg(img, quality, chroma).expect("encode");
    let (w, h) = img.dimensions();
    let header = crate::capture::dump::DumpHeader {
        fourcc: *b"MJPG",
        width: w,
        height: h,
        bytes_per_line: 0,
        interval_num: 1,
        interval_den: 30,
        device: "test".into(),
        card: "test".into(),
    };
    let rgb = crate::capture::dump::decode_rgb(&header, &bytes).expect("decode");
    (rgb, crate::capture::chroma::of_buffer(&header, &bytes))
}

/// What a JPEG's header says of its decoder is what its pixels show: zune-jpeg
/// interpolates, from the first pixel.
#[test]
fn the_rebuild_a_jpeg_declares_is_the_one_its_pixels_show() {
    for sampling in [JpegChroma::Half420, JpegChroma::Half422, JpegChroma::Full] {
        let img = crate::capture::dump::tests::textured_image();
        let (rgb, declared) = through_mjpeg(&img, sampling, 100);
        let declared = declared.expect("a JPEG's header says");
        let mut read = Sampling::UNKNOWN;
        read.read(&rgb);
        for (axis, &rebuild) in declared.iter().enumerate() {
            // The pattern's pixel-aligned edges leave a full axis untold, as they leave
            // a 4:4:4 JPEG (see `HOLDS`); a subsampled one tells.
            let interpolated = rebuild == Rebuild::Interpolated;
            assert!(read.told[axis] || !interpolated, "{sampling:?}: {read:?}");
            if read.told[axis] {
                assert_eq!(read.rebuild[axis], rebuild, "{sampling:?}, {axis}");
                assert_eq!(read.offset[axis], 0, "{sampling:?}, {axis}");
            }
        }
    }
}

/// A stripe in a dark, flat frame from a 4:2:0 MJPEG camera (quality 90): its pixels
/// cannot tell the extractor how the chroma was sampled, its JPEG's header can. Told
/// so, the points are centred from the first frame as well as those of a 4:4:4 JPEG
/// (whose quantisation is the floor here: 0.02-0.03 px); taken as full, they are
/// pulled towards the blocks (measured 0.037, 0.024 and 0.118 px).
#[test]
fn a_dark_mjpeg_frame_is_centred_by_what_its_header_says() {
    use JpegChroma as S;
    let (w, h) = (320u32, 120u32);
    let surface = |_: f64, _: f64| [12.0, 12.0, 12.0];
    let worst = |sampling: S, know: bool| {
        (0..16)
            .map(|k| {
                let mut ex = red_green_extractor(w, h);
                let line = (60.03 + k as f64 / 8.0, 0.0);
                let stripe = Some((line.0, line.1, 1.0, 150.0, [1.0, 0.1, 0.05]));
                let (img, declared) =
                    through_mjpeg(&frame((w, h), &surface, stripe, 0.5), sampling, 90);
                let (off, _) = through_mjpeg(&frame((w, h), &surface, None, 0.5), sampling, 90);
                if know {
                    ex.know_chroma(declared.expect("declared"));
                } else {
                    ex.sampling.sampling.settle();
                }
                let curves = ex.extract(&img, &Background::from_image(off));
                let mut e = distance_errors(&curves, line, 20.0, w as f64);
                e.sort_by(f64::total_cmp);
                e.get(e.len() / 2).copied().unwrap_or(0.0).abs()
            })
            .fold(0f64, f64::max)
    };
    // Its pixels: a dark frame and one straight stripe leave the sampling untold.
    let mut ex = red_green_extractor(w, h);
    let stripe = Some((60.3, 0.0, 1.0, 150.0, [1.0, 0.1, 0.05]));
    let (img, _) = through_mjpeg(&frame((w, h), &surface, stripe, 0.5), S::Half420, 90);
    ex.extract(&img, &Background::local(w, h));
    assert!(
        !ex.sampling.sampling.is_told(),
        "{:?}",
        ex.sampling.sampling
    );
    let floor = worst(S::Full, true);
    let (told, full) = (worst(S::Half420, true), worst(S::Half420, false));
    eprintln!("4:2:0 told {told:.4} px, taken as full {full:.4} px; 4:4:4 {floor:.4} px");
    assert!(
        told < 2.0 * floor,
        "told: {told:.3} px, 4:4:4 {floor:.3} px"
    );
    assert!(
        full > 2.0 * told,
        "taken as full: {full:.3} px, told {told:.3}"
    );
}
