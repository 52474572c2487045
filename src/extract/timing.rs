//! Where an extraction's time goes, stage by stage ([`StageTimes`]): printed by the
//! realistic bench and by `crossline -v extract`, so that a change to a hot loop is
//! judged by the stage it touches rather than by a frame's total, which a shared
//! machine blurs by ±10 %.

use std::time::{Duration, Instant};

/// The last frame's time per stage of [`super::Extractor::extract`], in the order they
/// run. A few `Instant::now` calls a frame: nothing next to a frame's milliseconds.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StageTimes {
    /// The frame's local background (no laser-off frame only).
    pub local: Duration,
    /// Marking the tiles to search (the pixel pass and the faint-stripe blocks).
    pub activate: Duration,
    /// Reading the chroma sampling off the frame (until it is told).
    pub chroma: Duration,
    /// The lasers' responses on their tiles, and each tile's stripe width.
    pub response: Duration,
    /// The detector's passes and its ridge points.
    pub detect: Duration,
    /// Linking for the curves' ends, and the rounds that follow them out.
    pub follow: Duration,
    /// The last link: the points' moves (glow, chroma), undistortion, simplification.
    pub link: Duration,
    /// The checks over all curves (edge fringes, repeats, clipped points).
    pub checks: Duration,
}

impl StageTimes {
    /// The stages' names and times, in order.
    pub fn stages(&self) -> [(&'static str, Duration); 8] {
        [
            ("local background", self.local),
            ("activate", self.activate),
            ("chroma", self.chroma),
            ("response", self.response),
            ("detect", self.detect),
            ("follow", self.follow),
            ("link", self.link),
            ("checks", self.checks),
        ]
    }

    /// The stages' sum.
    pub fn total(&self) -> Duration {
        self.stages().iter().map(|(_, t)| *t).sum()
    }
}

/// A stopwatch read in laps: each [`Lap::next`] is the time since the last.
pub(super) struct Lap(Instant);

impl Lap {
    pub(super) fn start() -> Self {
        Self(Instant::now())
    }

    pub(super) fn next(&mut self) -> Duration {
        let now = Instant::now();
        let lap = now - self.0;
        self.0 = now;
        lap
    }
}
