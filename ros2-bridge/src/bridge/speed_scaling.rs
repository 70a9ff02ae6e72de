//! Speed scaling (issue 32), as the Universal Robots driver offers it: a `std_msgs/Float64`
//! input, a **fraction** (1.0 the trajectory's own speed; UR's speed slider takes
//! 0.01..1.0), sent to the controller as OVERRIDE, and the state the controller reports,
//! published in **percent** as UR's `speed_scaling_state_broadcaster` does.
//!
//! The factor is the controller's, not the bridge's: OVERRIDE time-scales what remains of
//! the run under way (ramped within the joints' accelerations) and every run after it, so
//! a goal in flight and the next goals take it without the bridge replanning anything.
//! The state is read back (the MOTION report) rather than echoed, so it shows a factor
//! set by another tool (`armctl override`), the ramp, and 0 while held.
//!
//! The feedback's `desired` follows the same time scale: the bridge integrates the rate
//! it reads (`Clock`), since the controller's trajectory time is no longer wall time.

use std::sync::atomic::{AtomicU32, Ordering};
use std::time::Instant;

/// The input's range: OVERRIDE takes 1..200 percent (docs/PROTOCOL.md, OVERRIDE).
pub const FACTOR_RANGE: std::ops::RangeInclusive<f64> = 0.01..=2.0;

/// The OVERRIDE percent for a speed scaling input, or why it is refused (not a number,
/// or outside [`FACTOR_RANGE`]: 0 would be a hold, which is the hold service's).
pub fn override_percent(factor: f64) -> Result<u8, String> {
    if !factor.is_finite() || !FACTOR_RANGE.contains(&factor) {
        return Err(format!(
            "speed scaling {factor} refused: a fraction from {} to {} (1.0 = the \
             trajectory's speed; to stop along the path call the hold service)",
            FACTOR_RANGE.start(),
            FACTOR_RANGE.end()
        ));
    }
    // In range, so 1..=200 after rounding.
    Ok((factor * 100.0).round().clamp(1.0, 200.0) as u8)
}

/// The controller's rate now, tenths of a percent (MOTION `rate`), shared between the
/// thread that reads it and the feedback, and the trajectory time it implies.
#[derive(Debug)]
pub struct Rate(AtomicU32);

impl Default for Rate {
    fn default() -> Rate {
        Rate(AtomicU32::new(1000))
    }
}

impl Rate {
    /// Stores the rate a MOTION report gave.
    pub fn set(&self, permille: u16) {
        self.0.store(u32::from(permille), Ordering::Relaxed);
    }

    /// The rate, tenths of a percent (1000 until a MOTION report says otherwise).
    pub fn permille(&self) -> u32 {
        self.0.load(Ordering::Relaxed)
    }
}

/// Trajectory time under a changing rate: wall time since the run started, each span
/// weighted by the rate read last (so it lags the controller by at most one reading).
#[derive(Debug, Default)]
pub struct Clock {
    last: Option<Instant>,
    trajectory_us: f64,
}

impl Clock {
    /// Advances to `now` at `permille` (the rate over the span since the last call) once
    /// `running` (the controller reported RUNNING); returns the trajectory time, us.
    pub fn advance(&mut self, now: Instant, running: bool, permille: u32) -> i64 {
        if running {
            if let Some(last) = self.last {
                let wall = now.saturating_duration_since(last).as_secs_f64() * 1e6;
                self.trajectory_us += wall * f64::from(permille) / 1000.0;
            }
            self.last = Some(now);
        }
        self.trajectory_us as i64
    }
}

#[cfg(test)]
mod tests {
    use std::time::Duration;

    use super::*;

    #[test]
    fn factors_become_override_percent() {
        assert_eq!(override_percent(1.0), Ok(100));
        assert_eq!(override_percent(0.5), Ok(50));
        assert_eq!(override_percent(0.01), Ok(1));
        assert_eq!(override_percent(0.254), Ok(25));
        assert_eq!(override_percent(2.0), Ok(200));
        for bad in [0.0, -0.5, 0.004, 2.01, f64::NAN, f64::INFINITY] {
            let e = override_percent(bad).unwrap_err();
            assert!(e.contains("0.01 to 2"), "{e}");
        }
    }

    #[test]
    fn the_clock_runs_at_the_rate() {
        let t0 = Instant::now();
        let mut clock = Clock::default();
        let ms = |n| t0 + Duration::from_millis(n);
        assert_eq!(clock.advance(ms(0), false, 1000), 0);
        assert_eq!(clock.advance(ms(50), true, 1000), 0);
        assert_eq!(clock.advance(ms(150), true, 1000), 100_000);
        assert_eq!(clock.advance(ms(350), true, 500), 200_000);
        assert_eq!(clock.advance(ms(1350), true, 0), 200_000);
        assert_eq!(clock.advance(ms(1360), true, 2000), 220_000);
    }
}
