//! The one background policy for frames without a laser-off frame, shared by
//! `reconstruct` and `serve`: a rolling temporal median of sampled frames. Owns the
//! policy ([`BackgroundParams`], [`Policy`]: which frames are samples, which background
//! each frame is measured against) and the state that keeps it ([`Rolling`]).
//!
//! # The policy
//! Frames are numbered from 0 in the order the recording or the stream holds them
//! (live: the frames that reached the ring, so a frame the ring dropped has no number).
//! With `K = median_frames`, `W = warmup_frames`, `S = sample_every`, `P = refresh_every`:
//!
//! - **Samples.** The warm-up's `K` frames spread evenly over frames `0..W`
//!   (frame `(2j + 1)·W / 2K` for `j < K`; all `W` of them if `K > W`), then every
//!   frame from `W` on whose number is a multiple of `S`. A recording or stream of
//!   `n < W` frames spreads them over its `n` instead.
//! - **Versions.** Frames `0..W` are measured against version 0: the median of the
//!   warm-up samples. It is the only one that looks ahead; live, those frames wait for
//!   it. From `W` on the background changes every `P` frames: frames
//!   `W + (v−1)·P .. W + v·P` use version `v`, the median of the `K` latest samples
//!   numbered before `W + (v−1)·P`. A hand-held laser crosses a pixel in few of them, so
//!   the median is the scene without the laser, and a scene that changes (a diver's
//!   light, silt, a moved object) is followed within `K·S + P` frames.
//! - **Missing samples.** A sample that cannot be decoded is left out: the median is of
//!   those there are. With none at all, each frame is measured against its own local
//!   background ([`Background::local`]), as `extract` does without a laser-off frame.
//!
//! Both paths apply it to the same frames in the same order, so a replay without drops
//! extracts the same curves as `reconstruct` of the same recording. A laser-off frame
//! (`--background`) replaces the policy; a resumed live scan keeps the background it
//! saved.

use std::collections::BTreeMap;
use std::sync::Arc;

use image::RgbImage;
use serde::{Deserialize, Serialize};

use super::background::{Background, MAX_MEDIAN_FRAMES};
use super::ExtractError;

/// The `[background]` section of `crossline.toml`: the rolling median's sizes.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct BackgroundParams {
    /// Samples each median is taken over (`K`; odd, at most 31). Nine take the fast
    /// median network; more cost time on every refresh.
    pub median_frames: usize,
    /// The first frames, measured against the median of `median_frames` of them (`W`).
    pub warmup_frames: usize,
    /// From the warm-up on, every this many frames is a sample (`S`).
    pub sample_every: usize,
    /// From the warm-up on, the background is renewed every this many frames (`P`).
    pub refresh_every: usize,
}

impl Default for BackgroundParams {
    fn default() -> Self {
        Self {
            median_frames: 9,
            warmup_frames: 60,
            sample_every: 20,
            refresh_every: 30,
        }
    }
}

/// [`BackgroundParams`] checked: which frames are samples, and which background each
/// frame is measured against.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Policy {
    k: usize,
    w: usize,
    s: usize,
    p: usize,
}

impl Policy {
    pub fn new(params: &BackgroundParams) -> Result<Self, ExtractError> {
        let k = params.median_frames;
        if k == 0 || k > MAX_MEDIAN_FRAMES {
            return Err(ExtractError::Background {
                message: format!("median_frames must be 1..={MAX_MEDIAN_FRAMES}, got {k}"),
            });
        }
        if params.warmup_frames == 0 || params.sample_every == 0 || params.refresh_every == 0 {
            return Err(ExtractError::Background {
                message: "warmup_frames, sample_every and refresh_every must be at least 1".into(),
            });
        }
        Ok(Self {
            k,
            w: params.warmup_frames,
            s: params.sample_every,
            p: params.refresh_every,
        })
    }

    /// Whether frame `i` is kept for a median: every warm-up frame (which of them are
    /// the warm-up's samples depends on whether the stream outlasts the warm-up), then
    /// the samples.
    pub fn is_sample(&self, i: usize) -> bool {
        i < self.w || i.is_multiple_of(self.s)
    }

    /// The warm-up's samples when the stream has `frames` frames (`K` spread evenly
    /// over the first `min(W, frames)`, or all of them if fewer).
    pub fn warmup_samples(&self, frames: usize) -> Vec<usize> {
        let m = self.w.min(frames);
        let k = self.k.min(m);
        (0..k).map(|j| ((2 * j + 1) * m) / (2 * k)).collect()
    }

    /// The version frame `i` is measured against.
    pub fn version_of(&self, i: usize) -> usize {
        if i < self.w {
            0
        } else {
            1 + (i - self.w) / self.p
        }
    }

    /// Every frame of version `v` is numbered below this; for `v ≥ 1`, also the first
    /// frame of version `v + 1`.
    pub fn end_of(&self, v: usize) -> usize {
        self.w + v * self.p
    }

    /// The first frame of version `v`.
    pub fn start_of(&self, v: usize) -> usize {
        if v == 0 {
            0
        } else {
            self.end_of(v - 1)
        }
    }

    /// The samples version `v` is the median of (those that exist), oldest first, in a
    /// stream that outlasts the warm-up.
    pub fn samples_of(&self, v: usize) -> Vec<usize> {
        let warmup = self.warmup_samples(self.w);
        if v == 0 {
            return warmup;
        }
        let before = self.start_of(v);
        // Rolling samples: multiples of S in W..before; the rest from the warm-up.
        let first_rolling = self.w.div_ceil(self.s) * self.s;
        let mut out: Vec<usize> = (first_rolling..before)
            .step_by(self.s)
            .rev()
            .take(self.k)
            .collect();
        for &i in warmup.iter().rev() {
            if out.len() == self.k {
                break;
            }
            out.push(i);
        }
        out.reverse();
        out
    }
}

/// The rolling median's state: the samples offered so far that a later version can
/// use, and the versions made of them. Samples may be offered in any order (live
/// workers decode in parallel); a version is made once every sample it needs has been
/// offered or lies past the end [`Rolling::end_at`] announced.
pub struct Rolling {
    policy: Policy,
    size: (u32, u32),
    /// Offered samples by frame number (`None`: it could not be decoded).
    samples: BTreeMap<usize, Option<Arc<RgbImage>>>,
    versions: BTreeMap<usize, Arc<Background>>,
    /// Frames from here on will never be offered.
    end: usize,
    /// Version 0 is made: the warm-up's other frames are let go.
    warmup_done: bool,
}

impl Rolling {
    pub fn new(policy: Policy, width: u32, height: u32) -> Self {
        Self {
            policy,
            size: (width, height),
            samples: BTreeMap::new(),
            versions: BTreeMap::new(),
            end: usize::MAX,
            warmup_done: false,
        }
    }

    pub fn policy(&self) -> &Policy {
        &self.policy
    }

    /// Offers frame `i` (`None`: undecodable). Only samples are kept (shared, not
    /// copied). A frame offered again is ignored.
    pub fn offer(&mut self, i: usize, image: Option<&Arc<RgbImage>>) {
        if self.policy.is_sample(i) && !self.done_with(i) {
            let size = self.size;
            self.samples
                .entry(i)
                .or_insert_with(|| image.filter(|im| im.dimensions() == size).cloned());
        }
    }

    /// A warm-up frame offered after version 0 was made from others.
    fn done_with(&self, i: usize) -> bool {
        let p = &self.policy;
        i < p.w && self.warmup_done && !p.samples_of(0).contains(&i)
    }

    /// The samples version `v` is made of, and whether every one of them has come (or
    /// lies past the end). Version 0 of a stream whose end is not known yet waits for
    /// every warm-up frame: only then is it known whether the stream outlasts the
    /// warm-up.
    fn wanted(&self, v: usize) -> (Vec<usize>, bool) {
        let came = |i: &usize| *i >= self.end || self.samples.contains_key(i);
        if v == 0 {
            let m = self.policy.w.min(self.end);
            let samples = self.policy.warmup_samples(m);
            // Which frames are the samples is known once the stream's end is, or once
            // it has outlasted the warm-up.
            let known = self.end != usize::MAX || (0..m).all(|i| came(&i));
            let all = known && samples.iter().all(came);
            (samples, all)
        } else {
            let wanted = self.policy.samples_of(v);
            let all = wanted.iter().all(came);
            (wanted, all)
        }
    }

    /// The recording or stream has `frames` frames: a sample from there on will never
    /// come, and versions are made without it.
    pub fn end_at(&mut self, frames: usize) {
        self.end = self.end.min(frames);
    }

    /// The background of version `v`, made now if every sample it needs is in (or lies
    /// past the end); `None` while one is still to come.
    pub fn version(&mut self, v: usize) -> Option<Arc<Background>> {
        if let Some(b) = self.versions.get(&v) {
            return Some(b.clone());
        }
        let (wanted, all_came) = self.wanted(v);
        if !all_came {
            return None;
        }
        let images: Vec<&RgbImage> = wanted
            .iter()
            .filter_map(|i| self.samples.get(i).and_then(|s| s.as_deref()))
            .collect();
        // The previous version, when made of the same samples, is reused.
        let same_as_before = v > 0 && self.policy.samples_of(v - 1) == wanted;
        let made = match self.versions.get(&(v.wrapping_sub(1))) {
            Some(prev) if same_as_before => prev.clone(),
            _ => Arc::new(Background::median_of(&images).unwrap_or_else(|_| {
                tracing::warn!(
                    "no background for frames from {} on: none of its samples could be \
                     decoded; each frame is measured against its own local background",
                    self.policy.start_of(v)
                );
                Background::local(self.size.0, self.size.1)
            })),
        };
        self.versions.insert(v, made.clone());
        if v == 0 {
            // The warm-up frames that are not its samples are needed no more.
            let w = self.policy.w;
            self.samples.retain(|&i, _| i >= w || wanted.contains(&i));
            self.warmup_done = true;
        }
        Some(made)
    }

    /// No frame before `frame` will ask for its background any more: drops the samples
    /// and versions only those frames needed (keeping the version before, which the
    /// next may reuse).
    pub fn forget_before(&mut self, frame: usize) {
        let keep_from = self.policy.version_of(frame).saturating_sub(1);
        self.versions = self.versions.split_off(&keep_from);
        let Some(&oldest) = self.policy.samples_of(keep_from).first() else {
            return;
        };
        // Until version 0 is made, every warm-up frame may be one of its samples.
        let oldest = if self.warmup_done { oldest } else { 0 };
        self.samples = self.samples.split_off(&oldest);
    }

    /// The oldest sample held (those before it are no longer needed).
    pub fn oldest_sample(&self) -> Option<usize> {
        self.samples.keys().next().copied()
    }

    /// Samples and versions held (for the tests of bounded memory).
    pub fn held(&self) -> (usize, usize) {
        (self.samples.len(), self.versions.len())
    }
}

/// [`Rolling`] shared between threads.
pub type SharedRolling = std::sync::Mutex<Rolling>;

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// The sizes the tests' numbers are worked out for (not the defaults, which may be
    /// tuned).
    pub(crate) fn params() -> BackgroundParams {
        BackgroundParams {
            median_frames: 9,
            warmup_frames: 25,
            sample_every: 10,
            refresh_every: 30,
        }
    }

    fn policy() -> Policy {
        Policy::new(&params()).expect("valid")
    }

    #[test]
    fn the_warm_up_is_sampled_evenly_then_every_sample_every_th_frame() {
        let p = policy();
        assert!(
            (0..25).all(|i| p.is_sample(i)),
            "every warm-up frame is kept"
        );
        let warm = p.samples_of(0);
        assert_eq!(warm, p.warmup_samples(25));
        assert_eq!(warm.len(), 9);
        assert_eq!(p.warmup_samples(12), [0, 2, 3, 4, 6, 7, 8, 10, 11]);
        assert!(warm.windows(2).all(|w| w[1] - w[0] >= 2), "{warm:?}");
        let rolling: Vec<usize> = (25..100).filter(|&i| p.is_sample(i)).collect();
        assert_eq!(rolling, vec![30, 40, 50, 60, 70, 80, 90]);
    }

    #[test]
    fn versions_look_only_back_after_the_warm_up() {
        let p = policy();
        for i in 0..2000 {
            let v = p.version_of(i);
            assert!(
                p.start_of(v) <= i && i < p.end_of(v),
                "frame {i} version {v}"
            );
            let samples = p.samples_of(v);
            assert_eq!(samples.len(), 9, "version {v}");
            assert!(samples.iter().all(|&s| p.is_sample(s)));
            if v > 0 {
                assert!(samples.iter().all(|&s| s < p.start_of(v)), "version {v}");
            }
        }
        // Version 2 (frames 55..85) rolls in the three samples before frame 55.
        assert_eq!(p.samples_of(2)[6..], [30, 40, 50]);
        assert_eq!(p.samples_of(1), p.samples_of(0));
    }

    fn flat(v: u8) -> Arc<RgbImage> {
        Arc::new(RgbImage::from_pixel(3, 2, image::Rgb([v; 3])))
    }

    #[test]
    fn a_version_waits_for_its_samples_in_any_order_then_follows_the_scene() {
        let p = policy();
        let mut r = Rolling::new(p, 3, 2);
        // Warm-up frames offered last-first: version 0 is ready only with all 25 (only
        // then is it known that the stream outlasts the warm-up).
        for (n, i) in (0..25).rev().enumerate() {
            assert!(r.version(0).is_none(), "after {n} frames");
            r.offer(i, Some(&flat(10)));
        }
        assert_eq!(r.held().0, 25);
        assert_eq!(
            r.version(0).expect("ready").image().get_pixel(0, 0).0,
            [10; 3]
        );
        assert_eq!(r.held().0, 9, "the warm-up's other frames are let go");
        // The scene brightens from frame 30: version 2 has 3 of 9 bright samples (the
        // median stays), version 4 (frames 115..) has 9 of 9.
        for i in (30..200).step_by(10) {
            r.offer(i, Some(&flat(200)));
        }
        assert_eq!(
            r.version(2).expect("ready").image().get_pixel(0, 0).0,
            [10; 3]
        );
        assert_eq!(
            r.version(4).expect("ready").image().get_pixel(0, 0).0,
            [200; 3]
        );
        // Version 7 needs sample 200, not yet offered.
        assert!(r.version(7).is_none());
        r.offer(200, None);
        assert!(r.version(7).is_some(), "an undecodable sample is left out");
    }

    #[test]
    fn a_known_end_makes_version_0_from_its_samples_alone() {
        let p = policy();
        // A recording of 100 frames: the nine samples of the first 25 are enough.
        let mut r = Rolling::new(p, 3, 2);
        r.end_at(100);
        for (n, &i) in p.warmup_samples(25).iter().enumerate() {
            assert!(r.version(0).is_none(), "after {n} samples");
            r.offer(i, Some(&flat(10)));
        }
        assert_eq!(
            r.version(0).expect("ready").image().get_pixel(0, 0).0,
            [10; 3]
        );
        // One of 12 frames: the samples spread over those 12, the others never offered.
        let mut r = Rolling::new(p, 3, 2);
        r.end_at(12);
        let samples = p.warmup_samples(12);
        for &i in &samples[1..] {
            r.offer(i, Some(&flat(5)));
        }
        assert!(r.version(0).is_none(), "a sample is missing");
        r.offer(samples[0], Some(&flat(5)));
        assert_eq!(
            r.version(0).expect("ready").image().get_pixel(1, 1).0,
            [5; 3]
        );
    }

    #[test]
    fn a_short_stream_makes_a_version_of_what_came_or_a_local_one() {
        let p = policy();
        let mut r = Rolling::new(p, 3, 2);
        // Three frames, the first and last undecodable: spread over those three.
        r.offer(0, None);
        r.offer(1, Some(&flat(7)));
        r.offer(2, None);
        assert!(r.version(0).is_none());
        r.end_at(3);
        assert_eq!(p.warmup_samples(3), [0, 1, 2]);
        assert_eq!(
            r.version(0).expect("ended").image().get_pixel(1, 1).0,
            [7; 3]
        );
        let mut empty = Rolling::new(p, 3, 2);
        empty.end_at(0);
        assert!(empty.version(0).expect("finished").is_local());
    }

    #[test]
    fn more_samples_than_warm_up_frames_take_every_warm_up_frame() {
        let params = BackgroundParams {
            median_frames: 31,
            ..params()
        };
        let p = Policy::new(&params).expect("valid");
        assert_eq!(p.samples_of(0), (0..25).collect::<Vec<_>>());
        // Later versions take 31: the rolling samples, then the latest warm-up frames.
        assert_eq!(p.samples_of(2).len(), 28);
        assert_eq!(p.samples_of(12).len(), 31);
    }

    #[test]
    fn bad_sizes_are_refused() {
        for (k, w, s, p) in [
            (0, 25, 10, 30),
            (32, 40, 10, 30),
            (9, 0, 10, 30),
            (9, 25, 0, 30),
        ] {
            let params = BackgroundParams {
                median_frames: k,
                warmup_frames: w,
                sample_every: s,
                refresh_every: p,
            };
            assert!(Policy::new(&params).is_err(), "{params:?}");
        }
    }
}
