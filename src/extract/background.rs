//! The background the laser is measured against: a laser-off frame, the per-pixel
//! median of frames (the hand-held laser moves, so the median of a few spread-out
//! frames has no laser in it), or each frame's own local background. Which frames a
//! median is taken of is the policy of [`super::rolling`].

use image::RgbImage;

use super::ExtractError;

/// Most frames a median is taken over (the per-pixel sort runs on a stack array).
pub const MAX_MEDIAN_FRAMES: usize = 31;

/// The background image the extractor subtracts.
#[derive(Clone, Debug)]
pub struct Background {
    image: RgbImage,
    /// No laser-off frame: the extractor estimates each frame's own
    /// ([`super::local`]); `image` is black.
    local: bool,
    /// New for each background made, kept by its clones: the image cannot change, so
    /// what an extractor derives from it once holds while the id does ([`Self::id`]).
    id: u64,
}

/// The next [`Background::id`].
static NEXT_ID: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);

impl Background {
    /// A laser-off frame.
    pub fn from_image(image: RgbImage) -> Self {
        Self {
            image,
            local: false,
            id: NEXT_ID.fetch_add(1, std::sync::atomic::Ordering::Relaxed),
        }
    }

    /// No laser-off frame: each frame is measured against its own local background
    /// (a robust estimate wider than the stripe, [`super::local`]), computed by the
    /// extractor per frame. What to use when no background is known.
    pub fn local(width: u32, height: u32) -> Self {
        Self {
            local: true,
            ..Self::black(width, height)
        }
    }

    /// Whether this is [`Self::local`].
    pub fn is_local(&self) -> bool {
        self.local
    }

    /// No background: a black image (the frame itself is the difference).
    pub fn black(width: u32, height: u32) -> Self {
        Self::from_image(RgbImage::new(width, height))
    }

    /// The per-pixel, per-channel median of `frames` (1 to [`MAX_MEDIAN_FRAMES`] of the
    /// same size; for an even count, the lower median).
    pub fn median_of(frames: &[&RgbImage]) -> Result<Self, ExtractError> {
        let first = frames.first().ok_or(ExtractError::Background {
            message: "no frames to take the median of".into(),
        })?;
        check_frames(frames, first.dimensions())?;
        let mut image = RgbImage::new(first.width(), first.height());
        median_into(frames.iter().copied(), frames.len(), &mut image);
        Ok(Self::from_image(image))
    }

    pub fn image(&self) -> &RgbImage {
        &self.image
    }

    /// Tells this background's pixels from any other's: unique to each background
    /// made (a laser-off frame, a median, a rolling median's update), kept by clones.
    /// The extractor keeps the background's block sums while it holds
    /// ([`super::faint`]).
    pub fn id(&self) -> u64 {
        self.id
    }
}

fn check_frames(frames: &[&RgbImage], size: (u32, u32)) -> Result<(), ExtractError> {
    if frames.len() > MAX_MEDIAN_FRAMES {
        return Err(ExtractError::Background {
            message: format!(
                "at most {MAX_MEDIAN_FRAMES} frames for a median, got {}",
                frames.len()
            ),
        });
    }
    if let Some((i, f)) = frames
        .iter()
        .enumerate()
        .find(|(_, f)| f.dimensions() != size)
    {
        return Err(ExtractError::Background {
            message: format!(
                "frame {i} is {}x{}, expected {}x{} like frame 0",
                f.width(),
                f.height(),
                size.0,
                size.1
            ),
        });
    }
    Ok(())
}

/// Median of nine images with the 19 compare-exchanges of Paeth's median-of-nine
/// network ([`median9_block`]), [`MEDIAN_BLOCK`] samples at once. The rolling
/// background's every version waits for it (offline, both extraction threads idle
/// meanwhile: 178 versions over a 5,400-frame recording), so it is kept short: 3.3 ms
/// at 1080p on one core, where blocks of 64 copied into a stack array took 10.5 ms. Two
/// threads gave no more (the nine frames are read from memory once).
fn median9_into(raws: &[&[u8]], out: &mut RgbImage) {
    let out: &mut [u8] = out;
    let mut whole = out.chunks_exact_mut(MEDIAN_BLOCK);
    let mut from = 0;
    for o in &mut whole {
        let block: [&[u8; MEDIAN_BLOCK]; 9] = std::array::from_fn(|j| {
            raws[j][from..from + MEDIAN_BLOCK]
                .try_into()
                .expect("a whole block")
        });
        median9_block(block, o);
        from += MEDIAN_BLOCK;
    }
    // The tail, padded.
    let rest = whole.into_remainder();
    if !rest.is_empty() {
        let m = rest.len();
        let padded: [[u8; MEDIAN_BLOCK]; 9] = std::array::from_fn(|j| {
            let mut b = [0u8; MEDIAN_BLOCK];
            b[..m].copy_from_slice(&raws[j][from..from + m]);
            b
        });
        let mut o = [0u8; MEDIAN_BLOCK];
        median9_block(std::array::from_fn(|j| &padded[j]), &mut o);
        rest.copy_from_slice(&o[..m]);
    }
}

/// Samples per block of [`median9_into`]: one SSE2 register, so that the nine inputs
/// and the network's every compare-exchange stay in registers (blocks of 64, kept in
/// a stack array, went through memory at every exchange).
const MEDIAN_BLOCK: usize = 16;

/// The median of nine blocks into `out` (its first `MEDIAN_BLOCK` samples), by Paeth's
/// network, written out so that every index is a constant.
fn median9_block(block: [&[u8; MEDIAN_BLOCK]; 9], out: &mut [u8]) {
    type V = [u8; MEDIAN_BLOCK];
    #[inline(always)]
    fn sort2(a: &mut V, b: &mut V) {
        let (lo, hi) = (*a, *b);
        for i in 0..MEDIAN_BLOCK {
            a[i] = lo[i].min(hi[i]);
            b[i] = lo[i].max(hi[i]);
        }
    }
    let [mut p0, mut p1, mut p2, mut p3, mut p4, mut p5, mut p6, mut p7, mut p8] =
        block.map(|b| *b);
    sort2(&mut p1, &mut p2);
    sort2(&mut p4, &mut p5);
    sort2(&mut p7, &mut p8);
    sort2(&mut p0, &mut p1);
    sort2(&mut p3, &mut p4);
    sort2(&mut p6, &mut p7);
    sort2(&mut p1, &mut p2);
    sort2(&mut p4, &mut p5);
    sort2(&mut p7, &mut p8);
    sort2(&mut p0, &mut p3);
    sort2(&mut p5, &mut p8);
    sort2(&mut p4, &mut p7);
    sort2(&mut p3, &mut p6);
    sort2(&mut p1, &mut p4);
    sort2(&mut p2, &mut p5);
    sort2(&mut p4, &mut p7);
    sort2(&mut p4, &mut p2);
    sort2(&mut p6, &mut p4);
    sort2(&mut p4, &mut p2);
    out[..MEDIAN_BLOCK].copy_from_slice(&p4);
}

/// Per-sample median of `n` (≤ [`MAX_MEDIAN_FRAMES`]) equally sized images into `out`.
fn median_into<'a>(
    frames: impl Iterator<Item = &'a RgbImage> + Clone,
    n: usize,
    out: &mut RgbImage,
) {
    let raws: [&[u8]; MAX_MEDIAN_FRAMES] = {
        let mut r: [&[u8]; MAX_MEDIAN_FRAMES] = [&[]; MAX_MEDIAN_FRAMES];
        for (slot, f) in r.iter_mut().zip(frames) {
            *slot = f.as_raw();
        }
        r
    };
    let raws = &raws[..n];
    if n == 9 {
        median9_into(raws, out);
        return;
    }
    let mut values = [0u8; MAX_MEDIAN_FRAMES];
    for (i, o) in out.iter_mut().enumerate() {
        let vals = &mut values[..n];
        for (v, raw) in vals.iter_mut().zip(raws) {
            *v = raw[i];
        }
        // Insertion sort: n is small and the array lives on the stack.
        for a in 1..n {
            let mut b = a;
            while b > 0 && vals[b - 1] > vals[b] {
                vals.swap(b - 1, b);
                b -= 1;
            }
        }
        *o = vals[(n - 1) / 2];
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn flat(v: [u8; 3]) -> RgbImage {
        RgbImage::from_pixel(4, 3, image::Rgb(v))
    }

    #[test]
    fn median_of_nine_network_equals_the_sort() {
        let mut state = 12345u64;
        let mut next = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 33) as u8
        };
        let frames: Vec<RgbImage> = (0..9)
            .map(|_| RgbImage::from_fn(37, 11, |_, _| image::Rgb([next(), next(), next()])))
            .collect();
        let refs: Vec<&RgbImage> = frames.iter().collect();
        let fast = Background::median_of(&refs).expect("median");
        for (i, v) in fast.image().as_raw().iter().enumerate() {
            let mut vals: Vec<u8> = frames.iter().map(|f| f.as_raw()[i]).collect();
            vals.sort_unstable();
            assert_eq!(*v, vals[4], "sample {i}");
        }
    }

    #[test]
    fn median_removes_a_moving_bright_pixel() {
        let mut a = flat([10, 20, 30]);
        let mut b = flat([12, 18, 30]);
        let c = flat([11, 22, 31]);
        a.put_pixel(1, 1, image::Rgb([255, 0, 0]));
        b.put_pixel(2, 1, image::Rgb([255, 0, 0]));
        let bg = Background::median_of(&[&a, &b, &c]).expect("median");
        assert_eq!(bg.image().get_pixel(0, 0).0, [11, 20, 30]);
        assert_eq!(bg.image().get_pixel(1, 1).0, [12, 18, 30]);
        assert_eq!(bg.image().get_pixel(2, 1).0, [11, 20, 30]);
    }

    #[test]
    fn median_rejects_empty_and_mismatched() {
        assert!(Background::median_of(&[]).is_err());
        let a = flat([0; 3]);
        let b = RgbImage::new(5, 3);
        let err = Background::median_of(&[&a, &b]).expect_err("size mismatch");
        assert!(err.to_string().contains("frame 1 is 5x3"), "{err}");
    }
}
