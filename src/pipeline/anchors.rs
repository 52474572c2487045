//! Which frames are *anchors*: the bounded set of crosses whose planes the joint
//! estimator solves together, and whose curves every other curve is crossed with.
//!
//! Owns the schedule and nothing else. A scan's crossing graph is nearly complete (a
//! stripe over the whole image crosses the other laser's stripes of most frames), so
//! crossing every curve with every other, and solving every pose jointly, grow as the
//! square and the cube of the frames. With anchors, each new frame is crossed with the
//! anchors' curves only, the anchors are solved jointly, and every other pose is fitted
//! on its own against them ([`crate::solve::calibrate`]): the work per frame stays
//! bounded however long the recording grows.
//!
//! # The schedule
//! Frames with curves are counted `k = 0, 1, …` as they arrive; frame `k` is an anchor
//! while `k` is a multiple of the *stride*, which starts at 1. When the anchors would
//! exceed `max`, the stride doubles and every other anchor stops being one. The anchors
//! are therefore always spread evenly over the whole recording so far, between `max/2`
//! and `max` of them, and an anchor that stays one was one from its arrival: every
//! crossing of its curves with later and earlier curves is found. The schedule depends
//! on nothing but the order of the frames, so the live daemon and `reconstruct` choose
//! the same anchors from the same recording.

/// The anchor schedule (see the module docs).
#[derive(Clone, Debug)]
pub struct Anchors {
    max: usize,
    stride: u64,
    /// Frames with curves so far.
    counted: u64,
    /// Per frame, its count `k` when it had curves.
    count_of_frame: Vec<Option<u64>>,
}

/// What [`Anchors::next_frame`] decided.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Admission {
    /// The frame is an anchor now.
    pub anchor: bool,
    /// The stride doubled: some earlier anchors stopped being ones.
    pub thinned: bool,
}

impl Anchors {
    /// A schedule of at most `max` anchors (at least 2).
    pub fn new(max: usize) -> Self {
        Self {
            max: max.max(2),
            stride: 1,
            counted: 0,
            count_of_frame: Vec::new(),
        }
    }

    /// Number of anchors now.
    pub fn len(&self) -> usize {
        self.counted.div_ceil(self.stride) as usize
    }

    pub fn is_empty(&self) -> bool {
        self.counted == 0
    }

    /// Admits the next frame, with or without curves.
    pub fn next_frame(&mut self, has_curves: bool) -> Admission {
        if !has_curves {
            self.count_of_frame.push(None);
            return Admission {
                anchor: false,
                thinned: false,
            };
        }
        let k = self.counted;
        self.counted += 1;
        self.count_of_frame.push(Some(k));
        let mut thinned = false;
        while self.len() > self.max {
            self.stride *= 2;
            thinned = true;
        }
        Admission {
            anchor: k.is_multiple_of(self.stride),
            thinned,
        }
    }

    /// Whether `frame` is an anchor now.
    pub fn is_anchor(&self, frame: u32) -> bool {
        self.count_of_frame
            .get(frame as usize)
            .copied()
            .flatten()
            .is_some_and(|k| k.is_multiple_of(self.stride))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn anchors_stay_bounded_spread_and_never_return() {
        let mut a = Anchors::new(8);
        let mut was_dropped = vec![false; 1000];
        for f in 0..1000u32 {
            // Every seventh frame has no laser.
            let adm = a.next_frame(f % 7 != 3);
            assert!(
                a.len() <= 8 && (f < 20 || a.len() > 4),
                "{} at {f}",
                a.len()
            );
            assert_eq!(adm.anchor, a.is_anchor(f));
            for g in 0..=f {
                if was_dropped[g as usize] {
                    assert!(!a.is_anchor(g), "frame {g} came back");
                }
            }
            for g in 0..f {
                if !a.is_anchor(g) {
                    was_dropped[g as usize] = true;
                }
            }
        }
        let anchors: Vec<u32> = (0..1000).filter(|&f| a.is_anchor(f)).collect();
        // Spread over the whole recording, not bunched at its start.
        assert_eq!(anchors[0], 0);
        assert!(*anchors.last().expect("anchors") > 600, "{anchors:?}");
        assert!(!a.is_anchor(3), "a frame without curves is never an anchor");
    }
}
