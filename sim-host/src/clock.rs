//! Simulated time: the real monotonic clock, optionally sped up by `--time-scale`.
//!
//! Everything in the controller sees time through one [`SimClock`]: the tasks through the
//! `Clock` trait, the step "interrupt" thread through [`SimClock::now_tick`]. So with a
//! time scale of 10, a 2 s trajectory runs in 0.2 s of wall time and every pulse still
//! lands on its exact tick in simulated time.
//!
//! A [`SimClock::virtual_time`] clock does not follow the wall clock at all: it stands
//! still until its owner advances it ([`SimClock::advance_ns`]), so that a test drives the
//! whole simulated controller on time it controls (`crate::virtual_board`, issue 19).

use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use arm_core::hw::Clock;

/// Fixed-point denominator of the time scale (1/1000 resolution).
const SCALE_DEN: u128 = 1000;

/// Monotonic simulated time since boot.
#[derive(Clone, Copy, Debug)]
pub struct SimClock {
    origin: Instant,
    /// Time scale times [`SCALE_DEN`].
    scale_milli: u128,
    tick_hz: u32,
    /// Virtual time: the simulated nanoseconds, advanced only by the test.
    virtual_ns: Option<&'static AtomicU64>,
}

impl SimClock {
    /// A clock starting now, running `time_scale` times faster than real time, whose step
    /// timer ticks at `tick_hz` simulated hertz.
    pub fn new(time_scale: f64, tick_hz: u32) -> SimClock {
        let scale_milli = (time_scale * SCALE_DEN as f64).round().max(1.0) as u128;
        SimClock {
            origin: Instant::now(),
            scale_milli,
            tick_hz: tick_hz.max(1),
            virtual_ns: None,
        }
    }

    /// A clock at 0 that moves only when [`SimClock::advance_ns`] moves it (one small
    /// leak per clock: tests make a handful).
    pub fn virtual_time(tick_hz: u32) -> SimClock {
        SimClock {
            virtual_ns: Some(Box::leak(Box::new(AtomicU64::new(0)))),
            ..SimClock::new(1.0, tick_hz)
        }
    }

    /// Whether this clock is virtual.
    pub fn is_virtual(&self) -> bool {
        self.virtual_ns.is_some()
    }

    /// Moves a virtual clock on by `ns` (no effect on a real one).
    pub fn advance_ns(&self, ns: u64) {
        if let Some(now) = self.virtual_ns {
            now.fetch_add(ns, Ordering::AcqRel);
        }
    }

    /// The time scale this clock runs at.
    pub fn time_scale(&self) -> f64 {
        self.scale_milli as f64 / SCALE_DEN as f64
    }

    /// Step timer ticks per simulated second.
    pub fn tick_hz(&self) -> u32 {
        self.tick_hz
    }

    /// Simulated nanoseconds at the real instant `at`.
    pub fn sim_ns_at(&self, at: Instant) -> u64 {
        let real_ns = at.saturating_duration_since(self.origin).as_nanos();
        (real_ns * self.scale_milli / SCALE_DEN) as u64
    }

    /// Simulated nanoseconds since boot.
    pub fn now_ns(&self) -> u64 {
        match self.virtual_ns {
            Some(now) => now.load(Ordering::Acquire),
            None => self.sim_ns_at(Instant::now()),
        }
    }

    /// The real instant at which simulated time reaches `sim_ns` (rounded up).
    pub fn real_instant_of_ns(&self, sim_ns: u64) -> Instant {
        let real_ns = (u128::from(sim_ns) * SCALE_DEN).div_ceil(self.scale_milli);
        self.origin + Duration::from_nanos(real_ns.min(u128::from(u64::MAX)) as u64)
    }

    /// Simulated nanoseconds of step timer tick `tick`.
    pub fn tick_to_ns(&self, tick: u64) -> u64 {
        (u128::from(tick) * 1_000_000_000 / u128::from(self.tick_hz)) as u64
    }

    /// The step timer tick that is current at simulated nanosecond `ns`.
    pub fn ns_to_tick(&self, ns: u64) -> u64 {
        (u128::from(ns) * u128::from(self.tick_hz) / 1_000_000_000) as u64
    }

    /// Current step timer tick.
    pub fn now_tick(&self) -> u64 {
        self.ns_to_tick(self.now_ns())
    }

    /// Real instant of step timer tick `tick`.
    pub fn real_instant_of_tick(&self, tick: u64) -> Instant {
        // Round the tick's time up so that waking at this instant never sees an earlier tick.
        let ns = (u128::from(tick) * 1_000_000_000).div_ceil(u128::from(self.tick_hz));
        self.real_instant_of_ns(ns.min(u128::from(u64::MAX)) as u64)
    }
}

impl Clock for SimClock {
    fn now_us(&self) -> u64 {
        self.now_ns() / 1000
    }

    async fn sleep_until(&self, at_us: u64) {
        if self.is_virtual() {
            // Ready once the test has moved the clock there; until then each poll asks to
            // be polled again (the virtual board polls in a loop, advancing time).
            let at_ns = at_us.saturating_mul(1000);
            std::future::poll_fn(|cx| {
                if self.now_ns() >= at_ns {
                    std::task::Poll::Ready(())
                } else {
                    cx.waker().wake_by_ref();
                    std::task::Poll::Pending
                }
            })
            .await;
            return;
        }
        let target = self.real_instant_of_ns(at_us.saturating_mul(1000));
        loop {
            let now = Instant::now();
            if now >= target {
                break;
            }
            // embassy-time's std driver keeps its own origin: convert by the remaining time.
            let remaining = target - now;
            let micros = (remaining.as_micros() as u64).max(1);
            embassy_time::Timer::after(embassy_time::Duration::from_micros(micros)).await;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scaled_time_runs_faster() {
        let clock = SimClock::new(10.0, 1_000_000);
        let start = clock.origin;
        let later = start + Duration::from_millis(5);
        assert_eq!(clock.sim_ns_at(later), 50_000_000);
        assert_eq!(clock.real_instant_of_ns(50_000_000), later);
    }

    #[test]
    fn ticks_round_trip() {
        let clock = SimClock::new(1.0, 3_000_000);
        for tick in [0u64, 1, 2, 3, 1000, 2_999_999, 3_000_001] {
            let at = clock.real_instant_of_tick(tick);
            assert!(clock.ns_to_tick(clock.sim_ns_at(at)) >= tick, "tick {tick}");
            assert_eq!(clock.ns_to_tick(clock.tick_to_ns(tick) + 1), tick);
        }
    }
}
