//! The refinements of a scan's two starts, each begun as soon as what it needs is known.
//!
//! Owns the order of five pieces of work ([`run`]); what each piece does is
//! [`super::calibrate`]'s and [`super::screen`]'s.
//! - `L`: the linear start refined at every shift its crosses leave open;
//! - `S₀`, `S₁`: the screens of the centre start's two twins, each refined on every
//!   other anchor ([`super::screen::on_half`]);
//! - `B`: the best of `L`'s estimates refitted on that half, against the first screen
//!   there is (`S₀`'s, or `S₁`'s where `S₀` gives none);
//! - `R₀`, `R₁`: the twins refined on all the anchors, each once its own screen and `B`
//!   have said whether it competes.
//!
//! Run as joins in stages (`L` beside `S₀` and `S₁`, then both `R`s), the screen that
//! came third ran alone on one core while the other waited for it (1.5 s of the
//! 5,400-frame dive's solve at one core busy), and the twin that refined longer ran
//! alone after the other. Here each piece is spawned by whichever piece completes what
//! it needs, `L` and `S₀` first, so that `R₀` can begin beside `S₁`. The answers land
//! in fixed slots, so the result is the one the pieces make in sequence, whatever the
//! order in which they complete. Where the caller spares no core ([`Pieces::side_by_side`]
//! false: a live epoch beside the extraction, which on a table top's replay dropped 3
//! frames of 300 with its twins side by side) they run in sequence on the calling
//! thread, with the same answer.

use std::sync::Mutex;

use super::SolveError;

/// The pieces (see the module docs); `Estimate` is what a refinement gives, `Screen` a
/// twin's screen.
pub(super) trait Pieces: Sync {
    type Estimate: Send;
    type Screen: Send;
    /// `L`: `None` when there is no linear start to refine.
    fn linear(&self) -> Option<Result<Vec<Self::Estimate>, SolveError>>;
    /// `S_k`: twin `k`'s screen, `None` where it is not screened.
    fn screen(&self, twin: usize) -> Option<Self::Screen>;
    /// `B`: the best of the linear start's estimates scored on the screen's half.
    fn best_on_half(&self, screen: &Self::Screen, linear: &[Self::Estimate]) -> Option<f64>;
    /// Whether a twin whose screen is `screen` loses to `best` on the half.
    fn loses(&self, screen: &Self::Screen, best: f64) -> bool;
    /// `R_k`: twin `k` refined, told whether it lost on the half (then it is left out).
    fn refine_twin(&self, twin: usize, loses: bool) -> Vec<Self::Estimate>;
    /// Whether the pieces may run side by side on the pool's threads.
    fn side_by_side(&self) -> bool;
}

/// The linear start's refinement as [`Pieces::linear`] gives it.
pub(super) type Linear<E> = Option<Result<Vec<E>, SolveError>>;

/// What is known so far; each slot is `Some` once its piece has completed.
struct State<P: Pieces> {
    linear: Option<Linear<P::Estimate>>,
    screens: [Option<Option<P::Screen>>; 2],
    best: Option<Option<f64>>,
    started: [bool; 2],
    twins: [Vec<P::Estimate>; 2],
}

/// Runs the pieces (see the module docs): the linear start's refinement, and each twin's
/// estimates (empty where it lost on the half or did not refine).
pub(super) fn run<P: Pieces>(pieces: &P) -> (Linear<P::Estimate>, [Vec<P::Estimate>; 2]) {
    let state = Mutex::new(State::<P> {
        linear: None,
        screens: [None, None],
        best: None,
        started: [false; 2],
        twins: [Vec::new(), Vec::new()],
    });
    let st = &state;
    let refine = move |k: usize, loses: bool| {
        let found = pieces.refine_twin(k, loses);
        lock(st).twins[k] = found;
    };
    if pieces.side_by_side() {
        // FIFO: with two threads, `L` and `S₀` are taken first and `S₁` after.
        rayon::scope_fifo(|s| {
            s.spawn_fifo(move |s| {
                let linear = pieces.linear();
                lock(st).linear = Some(linear);
                for (k, loses) in ready(st, pieces) {
                    s.spawn_fifo(move |_| refine(k, loses));
                }
            });
            for k in 0..2 {
                s.spawn_fifo(move |s| {
                    let screen = pieces.screen(k);
                    lock(st).screens[k] = Some(screen);
                    for (k, loses) in ready(st, pieces) {
                        s.spawn_fifo(move |_| refine(k, loses));
                    }
                });
            }
        });
    } else {
        lock(st).linear = Some(pieces.linear());
        for k in 0..2 {
            let screen = pieces.screen(k);
            lock(st).screens[k] = Some(screen);
        }
        for (k, loses) in ready(st, pieces) {
            refine(k, loses);
        }
    }
    let state = state
        .into_inner()
        .expect("no piece panicked holding the state");
    (state.linear.expect("the linear piece ran"), state.twins)
}

fn lock<P: Pieces>(st: &Mutex<State<P>>) -> std::sync::MutexGuard<'_, State<P>> {
    st.lock().expect("no piece panicked holding the state")
}

/// Makes `B` once it can be made, and marks as started each twin whose screen and `B`
/// are known: those twins, and whether each lost on the half.
fn ready<P: Pieces>(st: &Mutex<State<P>>, pieces: &P) -> Vec<(usize, bool)> {
    let mut g = lock(st);
    if g.best.is_none() {
        // The first screen there is: `S₀`'s, or `S₁`'s where `S₀` has none.
        let first = match &g.screens {
            [Some(Some(h)), _] => Some(Some(h)),
            [Some(None), Some(h)] => Some(h.as_ref()),
            _ => None,
        };
        if let (Some(first), Some(linear)) = (first, &g.linear) {
            let found = match linear {
                Some(Ok(found)) => &found[..],
                _ => &[],
            };
            // Made under the lock (a refit on half the anchors, about 0.1 s on the dive):
            // a piece that completes meanwhile waits for it, and nothing else needs it.
            let best = first.and_then(|h| pieces.best_on_half(h, found));
            g.best = Some(best);
        }
    }
    let Some(best) = g.best else {
        return Vec::new();
    };
    let mut out = Vec::new();
    for k in 0..2 {
        let Some(screen) = g.screens[k].as_ref().filter(|_| !g.started[k]) else {
            continue;
        };
        let loses = screen
            .as_ref()
            .zip(best)
            .is_some_and(|(h, best)| pieces.loses(h, best));
        out.push((k, loses));
    }
    for &(k, _) in &out {
        g.started[k] = true;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
    use std::time::{Duration, Instant};

    /// Pieces of numbers: the linear start gives `[10, 11]`, twin `k`'s screen is
    /// `screens[k]`, `B` is the screen plus the linear start's first, a twin loses when
    /// its screen exceeds `B` by 100, and twin `k` refines to `[20 + k]`.
    struct Numbers {
        screens: [Option<i64>; 2],
        linear: bool,
        /// Twin 1's screen waits for twin 0's refinement to begin.
        wait: bool,
        twin0_began: AtomicBool,
        screen1_saw_twin0: AtomicBool,
        side_by_side: bool,
        /// Each piece takes 20 ms, counted in `running` (the most at once in `most`).
        dwell: bool,
        running: AtomicUsize,
        most: AtomicUsize,
    }

    impl Numbers {
        fn new(screens: [Option<i64>; 2], linear: bool) -> Self {
            Self {
                screens,
                linear,
                wait: false,
                twin0_began: AtomicBool::new(false),
                screen1_saw_twin0: AtomicBool::new(false),
                side_by_side: true,
                dwell: false,
                running: AtomicUsize::new(0),
                most: AtomicUsize::new(0),
            }
        }

        /// A piece's own time, where the pieces dwell.
        fn dwell(&self) {
            if self.dwell {
                let now = self.running.fetch_add(1, Ordering::SeqCst) + 1;
                self.most.fetch_max(now, Ordering::SeqCst);
                std::thread::sleep(Duration::from_millis(20));
                self.running.fetch_sub(1, Ordering::SeqCst);
            }
        }
    }

    impl Pieces for Numbers {
        type Estimate = u32;
        type Screen = i64;
        fn linear(&self) -> Option<Result<Vec<u32>, SolveError>> {
            self.dwell();
            self.linear.then(|| Ok(vec![10, 11]))
        }
        fn screen(&self, twin: usize) -> Option<i64> {
            self.dwell();
            if twin == 1 && self.wait {
                let until = Instant::now() + Duration::from_secs(5);
                while !self.twin0_began.load(Ordering::SeqCst) && Instant::now() < until {
                    std::thread::sleep(Duration::from_millis(1));
                }
                let saw = self.twin0_began.load(Ordering::SeqCst);
                self.screen1_saw_twin0.store(saw, Ordering::SeqCst);
            }
            self.screens[twin]
        }
        fn best_on_half(&self, screen: &i64, linear: &[u32]) -> Option<f64> {
            linear.first().map(|&l| (*screen + i64::from(l)) as f64)
        }
        fn loses(&self, screen: &i64, best: f64) -> bool {
            *screen as f64 - best >= 100.0
        }
        fn refine_twin(&self, twin: usize, loses: bool) -> Vec<u32> {
            self.dwell();
            if twin == 0 {
                self.twin0_began.store(true, Ordering::SeqCst);
            }
            if loses {
                Vec::new()
            } else {
                vec![20 + twin as u32]
            }
        }
        fn side_by_side(&self) -> bool {
            self.side_by_side
        }
    }

    fn on_threads<T: Send>(n: usize, f: impl FnOnce() -> T + Send) -> T {
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build()
            .expect("pool")
            .install(f)
    }

    /// With two threads, twin 0 refines while twin 1 is still screened: staged joins
    /// made it wait for the last screen.
    #[test]
    fn a_twin_refines_beside_the_other_twins_screen() {
        let pieces = Numbers {
            wait: true,
            ..Numbers::new([Some(0), Some(0)], true)
        };
        let (linear, twins) = on_threads(2, || run(&pieces));
        assert!(pieces.screen1_saw_twin0.load(Ordering::SeqCst));
        assert_eq!(linear.expect("refined").expect("ok"), vec![10, 11]);
        assert_eq!(twins, [vec![20], vec![21]]);
    }

    /// The verdicts are those made in sequence, on one thread or two: `B` is made on
    /// `S₀`'s screen, or `S₁`'s where `S₀` gives none; a losing twin gives nothing;
    /// without a linear start nothing loses.
    #[test]
    fn the_answer_is_the_one_made_in_sequence() {
        // (screens, linear start) -> twins' estimates.
        type Case = ([Option<i64>; 2], bool, [Vec<u32>; 2]);
        let cases: [Case; 5] = [
            // B = 0 + 10: twin 1 (200) loses, twin 0 (0) does not.
            ([Some(0), Some(200)], true, [vec![20], vec![]]),
            // No screen 0: B = 200 + 10 from twin 1's; twin 1 does not lose to it.
            ([None, Some(200)], true, [vec![20], vec![21]]),
            // B = 150 + 10: twin 0 does not lose to its own half; twin 1 (300) does.
            ([Some(150), Some(300)], true, [vec![20], vec![]]),
            ([None, None], true, [vec![20], vec![21]]),
            ([Some(0), Some(500)], false, [vec![20], vec![21]]),
        ];
        for (threads, side_by_side) in [(1, true), (2, true), (2, false)] {
            for (screens, linear, want) in &cases {
                let pieces = Numbers {
                    side_by_side,
                    ..Numbers::new(*screens, *linear)
                };
                let (found, twins) = on_threads(threads, || run(&pieces));
                assert_eq!(
                    &twins, want,
                    "{screens:?} linear {linear}, {threads} threads, side by side {side_by_side}"
                );
                assert_eq!(found.is_some(), *linear);
            }
        }
    }

    /// Where the caller spares no core, one piece runs at a time even on two threads;
    /// where it does, they overlap.
    #[test]
    fn pieces_run_one_at_a_time_where_no_core_is_spared() {
        for side_by_side in [false, true] {
            let pieces = Numbers {
                side_by_side,
                dwell: true,
                ..Numbers::new([Some(0), Some(0)], true)
            };
            let (_, twins) = on_threads(2, || run(&pieces));
            assert_eq!(twins, [vec![20], vec![21]]);
            let most = pieces.most.load(Ordering::SeqCst);
            if side_by_side {
                assert_eq!(most, 2, "side by side");
            } else {
                assert_eq!(most, 1, "in sequence");
            }
        }
    }
}
