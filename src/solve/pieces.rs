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
//! order in which they complete; on a one-thread pool (a live epoch) they run in
//! sequence.

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
    // FIFO: with two threads, `L` and `S₀` are taken first and `S₁` after.
    rayon::scope_fifo(|s| {
        s.spawn_fifo(move |s| {
            let linear = pieces.linear();
            lock(st).linear = Some(linear);
            advance(s, st, pieces);
        });
        for k in 0..2 {
            s.spawn_fifo(move |s| {
                let screen = pieces.screen(k);
                lock(st).screens[k] = Some(screen);
                advance(s, st, pieces);
            });
        }
    });
    let state = state
        .into_inner()
        .expect("no piece panicked holding the state");
    (state.linear.expect("the linear piece ran"), state.twins)
}

fn lock<P: Pieces>(st: &Mutex<State<P>>) -> std::sync::MutexGuard<'_, State<P>> {
    st.lock().expect("no piece panicked holding the state")
}

/// Makes `B` once it can be made, and spawns each `R_k` whose screen and `B` are known.
fn advance<'s, P: Pieces>(scope: &rayon::ScopeFifo<'s>, st: &'s Mutex<State<P>>, pieces: &'s P) {
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
        return;
    };
    for k in 0..2 {
        let Some(screen) = g.screens[k].as_ref().filter(|_| !g.started[k]) else {
            continue;
        };
        let loses = screen
            .as_ref()
            .zip(best)
            .is_some_and(|(h, best)| pieces.loses(h, best));
        g.started[k] = true;
        scope.spawn_fifo(move |_| {
            let found = pieces.refine_twin(k, loses);
            lock(st).twins[k] = found;
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::{AtomicBool, Ordering};
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
    }

    impl Numbers {
        fn new(screens: [Option<i64>; 2], linear: bool) -> Self {
            Self {
                screens,
                linear,
                wait: false,
                twin0_began: AtomicBool::new(false),
                screen1_saw_twin0: AtomicBool::new(false),
            }
        }
    }

    impl Pieces for Numbers {
        type Estimate = u32;
        type Screen = i64;
        fn linear(&self) -> Option<Result<Vec<u32>, SolveError>> {
            self.linear.then(|| Ok(vec![10, 11]))
        }
        fn screen(&self, twin: usize) -> Option<i64> {
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
            if twin == 0 {
                self.twin0_began.store(true, Ordering::SeqCst);
            }
            if loses {
                Vec::new()
            } else {
                vec![20 + twin as u32]
            }
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
        for threads in [1, 2] {
            for (screens, linear, want) in &cases {
                let pieces = Numbers::new(*screens, *linear);
                let (found, twins) = on_threads(threads, || run(&pieces));
                assert_eq!(
                    &twins, want,
                    "{screens:?} linear {linear}, {threads} threads"
                );
                assert_eq!(found.is_some(), *linear);
            }
        }
    }
}
