//! What decoding a camera buffer does to its chroma, known from the buffer itself.
//!
//! A camera that sends MJPEG samples its colour per two pixels along one axis (4:2:2)
//! or both (4:2:0), and says so in each JPEG's frame header (its components' sampling
//! factors); a YUYV camera sends one chroma pair per two pixels of a row. How our
//! decoders rebuild the chroma at every pixel is ours to know: zune-jpeg interpolates
//! between the blocks' centres (3/4 of the own block, 1/4 of the next: libjpeg's
//! "fancy upsampling"), and [`super::dump::yuyv_row_to_rgb`] repeats a pair's chroma over
//! its two pixels. In both the first block starts at pixel 0.
//!
//! The extractor needs this to take a narrow stripe's centre back off the chroma
//! blocks' pull (`extract::chroma`). Read here, it is exact from the first frame and
//! the same for every frame of a stream, whichever worker extracts it; frames whose
//! origin is not known (a PNG, a video through FFmpeg) are read by the extractor off
//! their pixels instead.

use super::dump::DumpHeader;

/// How one axis's chroma was rebuilt from its blocks.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Rebuild {
    /// Chroma at every pixel (4:4:4), or no evidence of blocks.
    Full,
    /// Each block's chroma repeated over its two pixels.
    Repeated,
    /// Interpolated between the blocks' centres (3/4 of the own block, 1/4 of the next).
    Interpolated,
}

/// The usual name of a sampling (`4:2:0`, `4:2:2`, `4:4:0`), or `None` for full
/// colour.
pub fn subsampling_name(rebuild: [Rebuild; 2]) -> Option<&'static str> {
    match rebuild.map(|r| r != Rebuild::Full) {
        [true, true] => Some("4:2:0"),
        [true, false] => Some("4:2:2"),
        [false, true] => Some("4:4:0"),
        [false, false] => None,
    }
}

/// Says once, for a user, that the frames' colour comes per two pixels and what that
/// costs; nothing for full colour.
pub fn tell_user(rebuild: [Rebuild; 2]) {
    if let Some(name) = subsampling_name(rebuild) {
        tracing::info!(
            "the frames' colour is sampled {name} (their buffers say so): the stripes' centres \
             are corrected for it, but the depth error is larger than with full colour \
             (docs/extraction.md); use a full-colour camera mode if there is one"
        );
    }
}

/// How [`super::dump::decode_rgb`] rebuilds the chroma of `payload`, a buffer in
/// `header`'s pixel format, along x and then y; `None` where the bytes do not say (a
/// JPEG without a readable frame header, or with sampling factors other than equal or
/// doubled, which the decoder rebuilds otherwise).
pub fn of_buffer(header: &DumpHeader, payload: &[u8]) -> Option<[Rebuild; 2]> {
    match &header.fourcc {
        b"MJPG" | b"JPEG" => of_jpeg(payload),
        b"YUYV" => Some([Rebuild::Repeated, Rebuild::Full]),
        b"RGB3" => Some([Rebuild::Full; 2]),
        _ => None,
    }
}

/// How zune-jpeg rebuilds the chroma of the JPEG `bytes` along x and then y:
/// interpolated along an axis where the chroma components are sampled at half the luma's
/// rate, full where at the same rate (and for a greyscale JPEG, which has none).
pub fn of_jpeg(bytes: &[u8]) -> Option<[Rebuild; 2]> {
    let factors = sampling_factors(bytes)?;
    let [luma, cb, cr] = match factors.as_slice() {
        [_] => return Some([Rebuild::Full; 2]),
        &[l, b, r] => [l, b, r],
        _ => return None,
    };
    if cb != cr {
        return None;
    }
    let axis = |l: u8, c: u8| match (l, c) {
        (l, c) if l == c => Some(Rebuild::Full),
        (l, c) if l == 2 * c => Some(Rebuild::Interpolated),
        _ => None,
    };
    Some([axis(luma.0, cb.0)?, axis(luma.1, cb.1)?])
}

/// The (horizontal, vertical) sampling factors of each component of the JPEG `bytes`'
/// frame header (the first SOF marker before the first scan); `None` if there is none.
fn sampling_factors(bytes: &[u8]) -> Option<Vec<(u8, u8)>> {
    if bytes.get(..2)? != [0xFF, 0xD8] {
        return None;
    }
    let mut i = 2;
    loop {
        // A marker: 0xFF, any fill bytes 0xFF, then its code.
        if *bytes.get(i)? != 0xFF {
            return None;
        }
        while *bytes.get(i)? == 0xFF {
            i += 1;
        }
        let code = *bytes.get(i)?;
        i += 1;
        match code {
            // Markers without a segment: restart, temporary.
            0x01 | 0xD0..=0xD7 => continue,
            // A scan (or the image's end) before any frame header.
            0xDA | 0xD9 => return None,
            _ => {}
        }
        let len = usize::from(u16::from_be_bytes([*bytes.get(i)?, *bytes.get(i + 1)?]));
        let segment = bytes.get(i + 2..i + len)?;
        // SOF0-SOF15 but DHT (C4), JPG (C8) and DAC (CC).
        if (0xC0..=0xCF).contains(&code) && !matches!(code, 0xC4 | 0xC8 | 0xCC) {
            let n = usize::from(*segment.get(5)?);
            return (0..n)
                .map(|k| {
                    let hv = *segment.get(6 + 3 * k + 1)?;
                    Some((hv >> 4, hv & 0x0F))
                })
                .collect();
        }
        i += len;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A textured 320x240 frame as JPEG with `sampling`.
    pub(crate) fn jpeg(sampling: jpeg_encoder::SamplingFactor) -> Vec<u8> {
        let img = crate::capture::dump::tests::textured_image();
        let mut out = Vec::new();
        let mut enc = jpeg_encoder::Encoder::new(&mut out, 90);
        enc.set_sampling_factor(sampling);
        enc.encode(
            img.as_raw(),
            img.width() as u16,
            img.height() as u16,
            jpeg_encoder::ColorType::Rgb,
        )
        .expect("encode");
        out
    }

    #[test]
    fn a_jpeg_tells_which_axes_its_decoder_interpolates() {
        use jpeg_encoder::SamplingFactor as S;
        use Rebuild::{Full, Interpolated};
        for (sampling, want) in [
            (S::R_4_4_4, [Full, Full]),
            (S::R_4_2_2, [Interpolated, Full]),
            (S::R_4_2_0, [Interpolated, Interpolated]),
            (S::R_4_4_0, [Full, Interpolated]),
        ] {
            assert_eq!(of_jpeg(&jpeg(sampling)), Some(want), "{sampling:?}");
        }
        // 4:1:1 is rebuilt otherwise; not a JPEG; cut off before its frame header.
        assert_eq!(of_jpeg(&jpeg(S::R_4_1_1)), None);
        assert_eq!(of_jpeg(b"\x89PNG\r\n"), None);
        let whole = jpeg(S::R_4_2_0);
        assert_eq!(of_jpeg(&whole[..20]), None);
    }

    #[test]
    fn samplings_have_their_names() {
        use Rebuild::{Full, Interpolated, Repeated};
        assert_eq!(subsampling_name([Interpolated; 2]), Some("4:2:0"));
        assert_eq!(subsampling_name([Repeated, Full]), Some("4:2:2"));
        assert_eq!(subsampling_name([Full, Interpolated]), Some("4:4:0"));
        assert_eq!(subsampling_name([Full; 2]), None);
    }

    #[test]
    fn yuyv_repeats_along_rows_and_packed_rgb_is_full() {
        let mut header = crate::capture::dump::tests::header();
        header.fourcc = *b"YUYV";
        assert_eq!(
            of_buffer(&header, &[]),
            Some([Rebuild::Repeated, Rebuild::Full])
        );
        header.fourcc = *b"RGB3";
        assert_eq!(of_buffer(&header, &[]), Some([Rebuild::Full; 2]));
        header.fourcc = *b"MJPG";
        assert_eq!(
            of_buffer(&header, &jpeg(jpeg_encoder::SamplingFactor::R_4_2_2)),
            Some([Rebuild::Interpolated, Rebuild::Full])
        );
    }
}
