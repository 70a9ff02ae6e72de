//! When the independent watchdog (IWDG) is fed: only while the step producer and the
//! network task are both alive. Each has a [`Heartbeat`] that counts the polls of its
//! task's future ([`Beating`] wraps the future); the watchdog task wakes both tasks every
//! [`CHECK_PERIOD_MS`] (they wait on a signal or a receive that a spurious wake-up does
//! not disturb) and feeds the IWDG only if every heartbeat moved since its last check
//! ([`Liveness::check`]). A task stuck in a loop stops the whole executor, a task stuck
//! waiting stops its heartbeat: either way the IWDG is not fed and resets the board
//! [`IWDG_TIMEOUT_MS`] later.

use core::future::Future;
use core::pin::Pin;
use core::sync::atomic::{AtomicU32, Ordering};
use core::task::{Context, Poll};

/// IWDG timeout: a hung task resets the board within this time plus one check period.
/// Long enough for the slowest thing the executor does without yielding (a flash word
/// write of the settings, tens of microseconds; sector erases are asynchronous), short
/// enough that an arm whose controller hung is reset before a host's 1 s STATUS poll
/// would give up twice.
pub const IWDG_TIMEOUT_MS: u32 = 1_000;

/// How often the watchdog task checks the heartbeats: four checks per timeout, so one
/// late check does not cost a reset.
pub const CHECK_PERIOD_MS: u32 = 250;

/// A check that wakes this much after it was due says the executor or the time driver
/// stalled (nothing else delays a timer wake-up by milliseconds): the watchdog task logs it
/// with its size. The IWDG resets only after three quarters of a second more, so without
/// this line a stall that misses the reset leaves no trace; 100 ms is ten times the longest
/// thing a task does without yielding (see [`IWDG_TIMEOUT_MS`]) and a tenth of the timeout.
pub const LATE_CHECK_LOG_MS: u64 = 100;

/// How many milliseconds after `due_ms` a check that woke at `woke_ms` came, if that is
/// worth a log line ([`LATE_CHECK_LOG_MS`] or more).
pub fn late_check(due_ms: u64, woke_ms: u64) -> Option<u64> {
    let late = woke_ms.saturating_sub(due_ms);
    (late >= LATE_CHECK_LOG_MS).then_some(late)
}

/// Consecutive failed checks that are tolerated before the IWDG is left to expire: a task
/// busy for one period (a burst of frames) is not a hang.
pub const MISSED_CHECKS_ALLOWED: u32 = 1;

/// A task's liveness counter, bumped on every poll of its future.
#[derive(Debug, Default)]
pub struct Heartbeat(AtomicU32);

impl Heartbeat {
    /// A counter at 0 (`const`: put it in a `static`).
    pub const fn new() -> Self {
        Heartbeat(AtomicU32::new(0))
    }
    /// Counts one sign of life.
    pub fn beat(&self) {
        self.0.fetch_add(1, Ordering::Relaxed);
    }
    /// Signs of life so far (wrapping).
    pub fn count(&self) -> u32 {
        self.0.load(Ordering::Relaxed)
    }
}

/// A future that beats `heartbeat` every time it is polled, then polls `inner`.
pub struct Beating<'a, F> {
    heartbeat: &'a Heartbeat,
    inner: F,
}

impl<'a, F: Future> Beating<'a, F> {
    /// Wraps `inner`.
    pub fn new(heartbeat: &'a Heartbeat, inner: F) -> Self {
        Beating { heartbeat, inner }
    }
}

impl<F: Future> Future for Beating<'_, F> {
    type Output = F::Output;

    fn poll(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<F::Output> {
        // SAFETY: `inner` is structurally pinned: it is never moved out of `self`.
        let this = unsafe { self.get_unchecked_mut() };
        this.heartbeat.beat();
        // SAFETY: see above; `this` came from a pinned reference.
        unsafe { Pin::new_unchecked(&mut this.inner) }.poll(cx)
    }
}

/// The feed decision over `N` heartbeats.
#[derive(Debug)]
pub struct Liveness<const N: usize> {
    last: [u32; N],
    missed: u32,
}

/// What one check found.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Verdict {
    /// Every task beat: feed the IWDG.
    Feed,
    /// Task `index` did not beat, but within [`MISSED_CHECKS_ALLOWED`]: feed, and log.
    Late {
        /// The heartbeat that did not move.
        index: usize,
    },
    /// Task `index` is hung: do not feed, the IWDG resets the board.
    Hung {
        /// The heartbeat that did not move.
        index: usize,
    },
}

impl Verdict {
    /// Whether the IWDG is to be fed.
    pub fn feed(self) -> bool {
        !matches!(self, Verdict::Hung { .. })
    }
}

impl<const N: usize> Liveness<N> {
    /// Starts from the counters as they are now.
    pub fn new(now: [u32; N]) -> Self {
        Liveness {
            last: now,
            missed: 0,
        }
    }

    /// Compares `now` with the counters at the previous check. Once a task is reported
    /// hung, it stays hung (the IWDG is never fed again).
    pub fn check(&mut self, now: [u32; N]) -> Verdict {
        let stuck = now
            .iter()
            .zip(&self.last)
            .position(|(now, last)| now == last);
        self.last = now;
        match stuck {
            None if self.missed <= MISSED_CHECKS_ALLOWED => {
                self.missed = 0;
                Verdict::Feed
            }
            None => Verdict::Hung { index: 0 },
            Some(index) => {
                self.missed = self.missed.saturating_add(1);
                if self.missed <= MISSED_CHECKS_ALLOWED {
                    Verdict::Late { index }
                } else {
                    Verdict::Hung { index }
                }
            }
        }
    }
}

// The IWDG must outlast the checks it tolerates.
const _: () = assert!((MISSED_CHECKS_ALLOWED + 1) * CHECK_PERIOD_MS < IWDG_TIMEOUT_MS);

#[cfg(test)]
mod tests {
    use super::*;
    use core::task::Waker;

    #[test]
    fn fed_while_both_beat() {
        let mut l = Liveness::new([0, 0]);
        assert_eq!(l.check([1, 5]), Verdict::Feed);
        assert_eq!(l.check([2, 6]), Verdict::Feed);
    }

    #[test]
    fn one_late_check_is_tolerated_two_are_a_hang() {
        let mut l = Liveness::new([0, 0]);
        assert_eq!(l.check([1, 0]), Verdict::Late { index: 1 });
        assert_eq!(l.check([2, 1]), Verdict::Feed);
        assert_eq!(l.check([2, 2]), Verdict::Late { index: 0 });
        assert_eq!(l.check([2, 3]), Verdict::Hung { index: 0 });
        assert!(!l.check([2, 3]).feed());
    }

    #[test]
    fn a_check_late_by_a_tenth_of_the_timeout_is_logged() {
        assert_eq!(late_check(1_000, 1_000), None);
        assert_eq!(late_check(1_000, 1_099), None);
        assert_eq!(late_check(1_000, 1_100), Some(100));
        assert_eq!(late_check(1_000, 1_640), Some(640));
        // A clock read before the due time (a wake-up counted early) is not late.
        assert_eq!(late_check(1_000, 900), None);
    }

    #[test]
    fn a_hang_is_final() {
        let mut l = Liveness::new([0]);
        l.check([0]);
        assert!(!l.check([0]).feed());
        assert!(
            !l.check([1]).feed(),
            "a task that comes back does not undo the reset"
        );
    }

    #[test]
    fn counters_wrap() {
        let mut l = Liveness::new([u32::MAX]);
        assert_eq!(l.check([0]), Verdict::Feed);
    }

    #[test]
    fn beating_counts_polls() {
        let heartbeat = Heartbeat::new();
        let mut polls = 0;
        let inner = core::future::poll_fn(|_| {
            polls += 1;
            if polls == 3 {
                Poll::Ready(7)
            } else {
                Poll::Pending
            }
        });
        let mut fut = core::pin::pin!(Beating::new(&heartbeat, inner));
        let mut cx = Context::from_waker(Waker::noop());
        assert!(fut.as_mut().poll(&mut cx).is_pending());
        assert!(fut.as_mut().poll(&mut cx).is_pending());
        assert_eq!(fut.as_mut().poll(&mut cx), Poll::Ready(7));
        assert_eq!(heartbeat.count(), 3);
    }
}
