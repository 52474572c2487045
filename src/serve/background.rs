//! The background policy live: [`crate::extract::rolling`], the one `reconstruct`
//! applies, kept by the extraction workers together. Owns [`LiveBackground`]: the
//! rolling median's samples as the workers decode them, the frames parked until their
//! background is made, and which frames are still in a worker's hands.
//!
//! A frame whose background cannot be made yet (the warm-up's frames, or a frame whose
//! version needs a sample another worker is still decoding) is parked, decoded, and the
//! worker goes on with the ring: a worker never waits for another. Whoever offers the
//! last sample a version needs, or takes the next frame, extracts the parked frames
//! that became ready.
//!
//! # `samples/` in the scan's state directory
//! So that a scan resumed after a crash measures its frames as an uninterrupted one
//! would, every sample's bytes as the camera gave them (an MJPEG frame, a YUYV buffer)
//! are kept in `samples/NNNNNNNNNN.frame` (the frame's number, ten digits; written to a
//! `.tmp` and renamed), and files no later background can need are removed. A resume
//! decodes them with the scan's pixel format. A state directory without `samples/`
//! (from before this format) resumes with its saved `background.png` for every frame.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};

use image::RgbImage;

use crate::capture::dump::{decode_rgb, DumpHeader};
use crate::extract::rolling::{Policy, Rolling};
use crate::extract::Background;
use crate::ring::FrameMeta;

/// A decoded frame (`None`: undecodable) and the background to extract it against.
pub(super) type Ready = (FrameMeta, Option<Arc<RgbImage>>, Arc<Background>);

/// The background the workers share.
pub(super) struct LiveBackground {
    state: Mutex<State>,
    /// Where samples' bytes are kept for a resume (`None`: not kept).
    samples_dir: Option<PathBuf>,
    /// A sample could not be written: warned once, then no more are tried.
    samples_failed: AtomicBool,
}

struct State {
    /// `None` for a fixed background (a resumed scan's).
    rolling: Option<Rolling>,
    fixed: Option<Arc<Background>>,
    /// Frames waiting for their version, by number.
    parked: BTreeMap<u64, (FrameMeta, Option<Arc<RgbImage>>)>,
    /// Frames a worker took from the ring and has not yet decoded and offered.
    in_flight: BTreeMap<u64, usize>,
    /// The first background made, which points take their colour from.
    first: Option<Arc<Background>>,
}

fn lock(m: &Mutex<State>) -> std::sync::MutexGuard<'_, State> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

impl LiveBackground {
    /// The rolling median of [`crate::extract::rolling`], its samples' bytes kept in
    /// `samples_dir` (created) when given.
    pub(super) fn rolling(
        policy: Policy,
        width: u32,
        height: u32,
        samples_dir: Option<PathBuf>,
    ) -> Self {
        let samples_dir = samples_dir.filter(|d| match std::fs::create_dir_all(d) {
            Ok(()) => true,
            Err(e) => {
                tracing::warn!("cannot keep background samples in {}: {e}", d.display());
                false
            }
        });
        Self::with(Some(Rolling::new(policy, width, height)), None, samples_dir)
    }

    /// The background of a scan starting at frame `first_index`: a new scan's rolling
    /// median, or a resumed one's from its kept samples (with its saved background, if
    /// it kept none, for every frame).
    pub(super) fn for_scan(
        policy: Policy,
        header: &DumpHeader,
        samples_dir: &Path,
        saved: Option<RgbImage>,
        first_index: u64,
    ) -> Self {
        let size = (header.width, header.height);
        let Some(saved) = saved else {
            return Self::rolling(policy, size.0, size.1, Some(samples_dir.to_path_buf()));
        };
        let decode = |b: &[u8]| decode_rgb(header, b).ok();
        let first = Background::from_image(saved.clone());
        Self::resume(policy, size, samples_dir, first_index, first, decode)
            .unwrap_or_else(|| Self::fixed(Background::from_image(saved)))
    }

    /// One background for every frame (a resumed scan's saved one).
    pub(super) fn fixed(background: Background) -> Self {
        Self::with(None, Some(Arc::new(background)), None)
    }

    /// A resumed scan: the rolling median with the samples kept in `dir` (decoded by
    /// `decode`) for the frames before `first_index`, and `first` (the saved
    /// background) as the first background. `None` when `dir` does not exist.
    pub(super) fn resume(
        policy: Policy,
        size: (u32, u32),
        dir: &Path,
        first_index: u64,
        first: Background,
        decode: impl Fn(&[u8]) -> Option<RgbImage>,
    ) -> Option<Self> {
        let entries = std::fs::read_dir(dir).ok()?;
        let live = Self::rolling(policy, size.0, size.1, Some(dir.to_path_buf()));
        {
            let mut s = lock(&live.state);
            s.first = Some(Arc::new(first));
            let r = s.rolling.as_mut()?;
            for path in entries.flatten().map(|e| e.path()) {
                let Some(i) = sample_number(&path).filter(|&i| i < first_index) else {
                    continue;
                };
                let image = std::fs::read(&path)
                    .ok()
                    .and_then(|b| decode(&b))
                    .map(Arc::new);
                if image.is_none() {
                    tracing::warn!("background sample {} is unreadable", path.display());
                }
                r.offer(i as usize, image.as_ref());
            }
            // A sample before the resume that is not on disk will not come again.
            for i in (0..first_index as usize).filter(|&i| policy.is_sample(i)) {
                r.offer(i, None);
            }
            r.forget_before(first_index as usize);
        }
        Some(live)
    }

    fn with(
        rolling: Option<Rolling>,
        fixed: Option<Arc<Background>>,
        samples_dir: Option<PathBuf>,
    ) -> Self {
        Self {
            state: Mutex::new(State {
                rolling,
                first: fixed.clone(),
                fixed,
                parked: BTreeMap::new(),
                in_flight: BTreeMap::new(),
            }),
            samples_dir,
            samples_failed: AtomicBool::new(false),
        }
    }

    /// Keeps frame `i`'s bytes for a resume if it is a sample, and removes the kept
    /// samples no later background needs. A failure is warned about once; the scan goes
    /// on (a resume then lacks those samples).
    pub(super) fn keep_sample(&self, i: u64, bytes: &[u8]) {
        let Some(dir) = &self.samples_dir else {
            return;
        };
        let oldest_needed = {
            let s = lock(&self.state);
            match s.rolling.as_ref() {
                Some(r) if r.policy().is_sample(i as usize) => r.oldest_sample(),
                _ => return,
            }
        };
        if self.samples_failed.load(Ordering::Relaxed) {
            return;
        }
        let path = dir.join(format!("{i:010}.frame"));
        let tmp = path.with_extension("tmp");
        let written = std::fs::write(&tmp, bytes).and_then(|()| std::fs::rename(&tmp, &path));
        if let Err(e) = written {
            tracing::warn!("cannot keep background sample {}: {e}", path.display());
            self.samples_failed.store(true, Ordering::Relaxed);
            return;
        }
        let Some(oldest) = oldest_needed else { return };
        if let Ok(entries) = std::fs::read_dir(dir) {
            for old in entries.flatten().map(|e| e.path()) {
                if sample_number(&old).is_some_and(|n| (n as usize) < oldest) {
                    let _ = std::fs::remove_file(old);
                }
            }
        }
    }

    /// The first background made, if any yet.
    pub(super) fn first(&self) -> Option<Arc<Background>> {
        lock(&self.state).first.clone()
    }

    /// A worker took frame `i` from the ring.
    pub(super) fn begin(&self, i: u64) {
        *lock(&self.state).in_flight.entry(i).or_default() += 1;
    }

    /// Frame `i`'s background, if it is made and the frame is no sample (a sample must
    /// be decoded to RGB and offered: [`Self::arrive`]). For extracting straight from
    /// the camera's buffer; the frame is then done with.
    pub(super) fn ready_without_decoding(&self, i: u64) -> Option<Arc<Background>> {
        let mut s = lock(&self.state);
        let bg = match s.rolling.as_mut() {
            None => s.fixed.clone(),
            Some(r) if r.policy().is_sample(i as usize) => None,
            Some(r) => {
                let v = r.policy().version_of(i as usize);
                r.version(v)
            }
        }?;
        s.done(i);
        Some(bg)
    }

    /// Frame `meta.index`, decoded (`None`: undecodable): offered to the median, then
    /// returned with its background, or parked until that is made.
    pub(super) fn arrive(&self, meta: FrameMeta, image: Option<RgbImage>) -> Option<Ready> {
        let mut s = lock(&self.state);
        let i = meta.index;
        let image = image.map(Arc::new);
        if let Some(r) = s.rolling.as_mut() {
            r.offer(i as usize, image.as_ref());
        }
        s.parked.insert(i, (meta, image));
        s.done(i);
        s.take(Some(i))
    }

    /// A parked frame whose background is made, if any.
    pub(super) fn take_ready(&self) -> Option<Ready> {
        lock(&self.state).take(None)
    }

    /// The stream ended after `frames` frames: no sample will come from there on.
    pub(super) fn end_at(&self, frames: u64) {
        if let Some(r) = lock(&self.state).rolling.as_mut() {
            r.end_at(frames as usize);
        }
    }

    /// Whether frames are still parked or in a worker's hands.
    pub(super) fn pending(&self) -> bool {
        let s = lock(&self.state);
        !s.parked.is_empty() || !s.in_flight.is_empty()
    }
}

/// The frame number of a kept sample's file name.
fn sample_number(path: &Path) -> Option<u64> {
    if path.extension()? != "frame" {
        return None;
    }
    path.file_stem()?.to_str()?.parse().ok()
}

impl State {
    fn done(&mut self, i: u64) {
        if let Some(n) = self.in_flight.get_mut(&i) {
            *n -= 1;
            if *n == 0 {
                self.in_flight.remove(&i);
            }
        }
    }

    /// Frame `only` (or the oldest parked frame) if its background is made.
    fn take(&mut self, only: Option<u64>) -> Option<Ready> {
        let i = match only {
            Some(i) => i,
            None => *self.parked.keys().next()?,
        };
        let bg = match self.rolling.as_mut() {
            None => self.fixed.clone(),
            Some(r) => {
                let v = r.policy().version_of(i as usize);
                r.version(v)
            }
        }?;
        self.first.get_or_insert_with(|| bg.clone());
        let (meta, image) = self.parked.remove(&i)?;
        self.forget(i);
        Some((meta, image, bg))
    }

    /// Drops the samples and versions no frame still to extract can need (`taken` was
    /// just given its background). A frame a worker has taken from the ring but not yet
    /// registered ([`LiveBackground::begin`]) is at most a few frames older than any
    /// registered one: one version's margin.
    fn forget(&mut self, taken: u64) {
        let Some(r) = self.rolling.as_mut() else {
            return;
        };
        let oldest = [self.parked.keys().next(), self.in_flight.keys().next()]
            .into_iter()
            .flatten()
            .fold(taken, |a, &b| a.min(b));
        let p = *r.policy();
        let v = p.version_of(oldest as usize).saturating_sub(1);
        r.forget_before(p.start_of(v));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn meta(index: u64) -> FrameMeta {
        FrameMeta {
            index,
            ..FrameMeta::default()
        }
    }

    fn policy() -> Policy {
        Policy::new(&crate::extract::rolling::tests::params()).expect("valid")
    }

    /// Frame `i` of a scene whose brightness steps up every 40 frames.
    fn frame(i: u64) -> RgbImage {
        RgbImage::from_pixel(4, 3, image::Rgb([(10 + 40 * (i / 40)) as u8; 3]))
    }

    /// Feeds frames `order` as the workers would (begin, decode, arrive), and returns
    /// each frame's background's first pixel.
    fn backgrounds(order: &[u64], total: u64) -> BTreeMap<u64, u8> {
        let live = LiveBackground::rolling(policy(), 4, 3, None);
        let mut got = BTreeMap::new();
        let mut keep = |(m, _, bg): Ready| {
            got.insert(m.index, bg.image().get_pixel(0, 0).0[0]);
        };
        for &i in order {
            live.begin(i);
            if let Some(r) = live.arrive(meta(i), Some(frame(i))) {
                keep(r);
            }
            while let Some(r) = live.take_ready() {
                keep(r);
            }
        }
        live.end_at(total);
        while let Some(r) = live.take_ready() {
            keep(r);
        }
        assert!(!live.pending(), "frames left parked");
        got
    }

    #[test]
    fn every_frame_gets_the_same_background_in_any_arrival_order() {
        let n = 300;
        let in_order: Vec<u64> = (0..n).collect();
        // Two workers: pairs swapped, and one frame in ten arriving 3 frames late.
        let mut shuffled = in_order.clone();
        for pair in shuffled.chunks_mut(2) {
            pair.reverse();
        }
        for k in (5..n as usize - 4).step_by(10) {
            shuffled[k..k + 4].rotate_left(1);
        }
        let a = backgrounds(&in_order, n);
        let b = backgrounds(&shuffled, n);
        assert_eq!(a.len(), n as usize);
        assert_eq!(a, b);
        // And it is the offline policy's: frame 200's version is the median of the
        // nine samples before frame 175.
        let mut offline = Rolling::new(policy(), 4, 3);
        for i in 0..n {
            offline.offer(i as usize, Some(&Arc::new(frame(i))));
        }
        let v = policy().version_of(200);
        let want = offline
            .version(v)
            .expect("all offered")
            .image()
            .get_pixel(0, 0)
            .0[0];
        assert_eq!(a[&200], want);
        // Samples 90..=170: three of 90, four of 130, two of 170.
        assert_eq!(want, 130);
    }

    #[test]
    fn undecodable_warm_up_frames_fall_back_to_the_local_background() {
        let live = LiveBackground::rolling(policy(), 64, 48, None);
        for i in 0..2 {
            live.begin(i);
            assert!(live.arrive(meta(i), None).is_none(), "parked");
        }
        live.end_at(2);
        let (m, image, bg) = live.take_ready().expect("ready once the stream ended");
        assert_eq!((m.index, image.is_none()), (0, true));
        assert!(bg.is_local());
        assert_eq!(bg.image().dimensions(), (64, 48));
        assert!(live.take_ready().is_some() && !live.pending());
    }

    #[test]
    fn held_samples_stay_bounded_over_a_long_stream() {
        let live = LiveBackground::rolling(policy(), 4, 3, None);
        for i in 0..3000 {
            live.begin(i);
            live.arrive(meta(i), Some(frame(i)));
            while live.take_ready().is_some() {}
        }
        let s = lock(&live.state);
        let (samples, versions) = s.rolling.as_ref().expect("rolling").held();
        assert!(
            samples <= 16 && versions <= 3,
            "{samples} samples, {versions} versions"
        );
    }

    #[test]
    fn a_resume_from_kept_samples_measures_frames_as_an_uninterrupted_run() {
        let dir = tempfile::tempdir().expect("tempdir");
        let samples = dir.path().join("samples");
        let decode = |b: &[u8]| RgbImage::from_raw(4, 3, b.to_vec());
        let run = |live: &LiveBackground, frames: std::ops::Range<u64>| {
            let mut got = BTreeMap::new();
            for i in frames {
                live.begin(i);
                let image = frame(i);
                live.keep_sample(i, image.as_raw());
                for (m, _, bg) in live.arrive(meta(i), Some(image)).into_iter() {
                    got.insert(m.index, bg.image().get_pixel(0, 0).0[0]);
                }
                while let Some((m, _, bg)) = live.take_ready() {
                    got.insert(m.index, bg.image().get_pixel(0, 0).0[0]);
                }
            }
            got
        };
        let whole = run(&LiveBackground::rolling(policy(), 4, 3, None), 0..400);
        // Killed after frame 229; frames from 200 on were not checkpointed.
        let first = run(
            &LiveBackground::rolling(policy(), 4, 3, Some(samples.clone())),
            0..230,
        );
        let kept = std::fs::read_dir(&samples).expect("samples").count();
        // The nine a median needs, the two renewals' margin (six), and the newest two.
        assert!(kept <= 9 + 6 + 2, "{kept} sample files kept");
        let bg = Background::from_image(frame(0));
        let resumed = LiveBackground::resume(policy(), (4, 3), &samples, 200, bg, decode)
            .expect("a samples directory");
        let second = run(&resumed, 200..400);
        assert_eq!(first.range(..200).count(), 200);
        for i in 200..400 {
            assert_eq!(second[&i], whole[&i], "frame {i}");
        }
        // Without the samples, the resume is not possible this way.
        let gone = dir.path().join("none");
        let bg = Background::from_image(frame(0));
        assert!(LiveBackground::resume(policy(), (4, 3), &gone, 200, bg, decode).is_none());
    }
}
