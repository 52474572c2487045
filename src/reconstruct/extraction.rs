//! Extraction over a recording: the background policy applied block by block, then
//! every frame's curves in parallel. Owns [`extract_frames`] and its result; the policy
//! itself is [`crate::extract::rolling`], the one `serve` applies too.

use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Instant;

use image::RgbImage;
use rayon::prelude::*;

use super::{decode, FrameSource, Progress, ReconstructError, Skipped};
use crate::camera::Camera;
use crate::config::Config;
use crate::extract::rolling::{Policy, Rolling};
use crate::extract::{Background, Curve, Extractor};

/// What extracting a recording gave besides its curves (those go to the caller's sink
/// block by block, in frame order: [`extract_frames`]).
pub struct Extracted {
    /// The first frames' background: the laser-off frame, or the rolling median's
    /// first version. Points take their colour from it.
    pub background: Arc<Background>,
    /// Frames that could not be decoded and were skipped.
    pub frames_skipped: usize,
    /// Seconds spent making the rolling median's versions.
    pub background_s: f64,
    pub extract_s: f64,
}

/// Offers the warm-up's decoded `frames` (`images[k]` is frame `frames[k]`, `None`
/// where undecodable) and makes version `v` of the background from them; the time it
/// takes is added to `seconds`.
fn warm_up(
    rolling: &mut Rolling,
    v: usize,
    frames: &[usize],
    images: &[Option<Arc<RgbImage>>],
    seconds: &mut f64,
) -> Result<Arc<Background>, ReconstructError> {
    for (&i, image) in frames.iter().zip(images) {
        rolling.offer(i, image.as_ref());
    }
    let t = Instant::now();
    let bg = rolling.version(v).ok_or(ReconstructError::Internal(
        "the warm-up background lacks a sample after its frames were offered",
    ))?;
    *seconds += t.elapsed().as_secs_f64();
    Ok(bg)
}

/// An extractor lent from a pool for one rayon split of a block, given back when
/// dropped. Rayon calls `map_init`'s init once per split, a few times per block, and a
/// new extractor allocates and zeroes its full-frame scratch (perf on the 600-frame
/// room: 9 % of the extraction's samples in `alloc_zeroed` under `Detector::new`). The
/// pool keeps about one per thread for the whole recording. A reused extractor gives
/// what a new one does (`curves_do_not_depend_on_stale_response`).
struct Lent<'a> {
    extractor: Option<Extractor>,
    pool: &'a Mutex<Vec<Extractor>>,
}

impl Drop for Lent<'_> {
    fn drop(&mut self) {
        if let Some(ex) = self.extractor.take() {
            self.pool.lock().unwrap_or_else(|e| e.into_inner()).push(ex);
        }
    }
}

/// One block's frames: their curves, and the images of the policy's samples.
type Block = Vec<(Vec<Curve>, Option<Arc<RgbImage>>)>;

/// The background policy and extraction over a recording: the laser-off frame
/// `background`, or else the rolling temporal median ([`crate::extract::rolling`]),
/// taken block by block (a block is the frames of one version of the median), every
/// frame of a block in parallel. Undecodable frames are skipped and counted, with no
/// curves. Each block's curves, one `Vec` per frame in frame order, go to `sink` as soon
/// as the block is done, so that what consumes them (the crossing search) runs beside
/// the next block's extraction.
pub fn extract_frames(
    frames: &FrameSource,
    background: Option<&Path>,
    camera: &Camera,
    config: &Config,
    progress: &dyn Progress,
    sink: &mut dyn FnMut(Vec<Vec<Curve>>),
) -> Result<Extracted, ReconstructError> {
    let t = Instant::now();
    let fixed = background
        .map(|p| decode(p, camera).map(|i| Arc::new(Background::from_image(i))))
        .transpose()?;
    let policy = Policy::new(&config.background)?;
    let mut rolling = Rolling::new(policy, camera.width, camera.height);
    rolling.end_at(frames.len());
    // Validate the parameters once; the extractors the pool lends out (each owns its
    // scratch buffers) are then built without fail, and count into this one's one-time
    // warnings, so that each is given once per run.
    let warnings = Extractor::new(&config.extract, camera)?.warnings();
    let (n, done, skipped) = (frames.len(), AtomicUsize::new(0), Skipped::default());
    let mut pass = frames.pass(camera)?;
    let chroma = frames.chroma();
    tracing::debug!("the frames' chroma as their bytes say (x, y): {chroma:?}");
    if let Some(rebuild) = chroma {
        crate::capture::chroma::tell_user(rebuild);
    }
    let (mut extracted, mut first_bg, mut background_s) = (0, None, 0.0);
    let mut v = 0;
    let extractors = Mutex::new(Vec::new());
    while extracted < n {
        let wanted: Vec<usize> = (policy.start_of(v)..policy.end_of(v).min(n)).collect();
        let extract_one = |lent: &mut Lent, image: Option<&RgbImage>, bg: &Background| {
            let ex = lent
                .extractor
                .as_mut()
                .ok_or(ReconstructError::Internal("extractor construction failed"))?;
            let curves = image.map_or_else(Vec::new, |img| ex.extract(img, bg));
            progress.update("extract", done.fetch_add(1, Ordering::Relaxed) + 1, n);
            Ok::<_, ReconstructError>(curves)
        };
        let init = || {
            let spare = extractors.lock().unwrap_or_else(|e| e.into_inner()).pop();
            Lent {
                extractor: spare.or_else(|| {
                    Extractor::new(&config.extract, camera).ok().map(|ex| {
                        let mut ex = ex.sharing_warnings(warnings.clone());
                        if let Some(rebuild) = chroma {
                            ex.know_chroma(rebuild);
                        }
                        ex
                    })
                }),
                pool: &extractors,
            }
        };
        let t_bg = Instant::now();
        let ready = fixed.clone().or_else(|| rolling.version(v));
        background_s += t_bg.elapsed().as_secs_f64();
        let block: Block = match ready {
            Some(bg) => {
                first_bg.get_or_insert_with(|| bg.clone());
                pass.map_frames(&wanted, init, |ex, i, r| {
                    let image = skipped.filter(i, r)?;
                    let curves = extract_one(ex, image.as_ref(), &bg)?;
                    Ok((curves, image.filter(|_| policy.is_sample(i)).map(Arc::new)))
                })?
            }
            // The warm-up of a recording read at random: its samples alone are decoded
            // first (K frames held, not the block's W), then the block like any other.
            None if pass.random_access() => {
                let samples = policy.warmup_samples(wanted.len());
                let images = pass.map_frames(
                    &samples,
                    || (),
                    |_, _, r| match r {
                        Ok(image) => Ok(Some(Arc::new(image))),
                        // Counted when the block reads it.
                        Err(e) if e.is_undecodable_frame() => Ok(None),
                        Err(e) => Err(e),
                    },
                )?;
                let bg = warm_up(&mut rolling, v, &samples, &images, &mut background_s)?;
                drop(images);
                first_bg.get_or_insert_with(|| bg.clone());
                pass.map_frames(&wanted, init, |ex, i, r| {
                    let image = skipped.filter(i, r)?;
                    Ok((extract_one(ex, image.as_ref(), &bg)?, None))
                })?
            }
            // The warm-up of a video (one pass): its own samples make its background, so
            // the block is decoded first and held.
            None => {
                let images = pass.map_frames(
                    &wanted,
                    || (),
                    |_, i, r| Ok(skipped.filter(i, r)?.map(Arc::new)),
                )?;
                if images.len() < wanted.len() {
                    rolling.end_at(wanted[0] + images.len());
                }
                let bg = warm_up(&mut rolling, v, &wanted, &images, &mut background_s)?;
                first_bg.get_or_insert_with(|| bg.clone());
                images
                    .into_par_iter()
                    .map_init(init, |ex, image| {
                        Ok((extract_one(ex, image.as_deref(), &bg)?, None))
                    })
                    .collect::<Result<_, ReconstructError>>()?
            }
        };
        let ended = block.len() < wanted.len();
        let mut curves_of_block = Vec::with_capacity(wanted.len());
        // (The warm-up's samples were offered before its block; offering again is a
        // no-op.)
        for (&i, (curves, sample)) in wanted.iter().zip(block) {
            rolling.offer(i, sample.as_ref());
            curves_of_block.push(curves);
        }
        extracted += curves_of_block.len();
        rolling.forget_before(policy.end_of(v));
        if ended {
            // A video cut off: the frames it promised and did not hold have no curves.
            curves_of_block.resize_with(curves_of_block.len() + n - extracted, Vec::new);
            extracted = n;
        }
        sink(curves_of_block);
        v += 1;
    }
    let frames_skipped = skipped.count();
    if frames_skipped > 0 {
        tracing::warn!("{frames_skipped} of {n} frames could not be decoded and were skipped");
    }
    let background =
        first_bg.unwrap_or_else(|| Arc::new(Background::local(camera.width, camera.height)));
    Ok(Extracted {
        background,
        frames_skipped,
        background_s,
        extract_s: t.elapsed().as_secs_f64() - background_s,
    })
}
