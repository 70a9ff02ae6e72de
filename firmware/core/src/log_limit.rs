//! Rate limiting for log lines that a datagram can trigger: a host flooding the
//! controller (or resending in a loop) must not turn each datagram into a log line.

/// Length of one counting window, microseconds.
pub const LOG_WINDOW_US: u64 = 1_000_000;

/// What to do with one event (a dropped datagram, a refused command...).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum LogVerdict {
    /// Log this one as the example of a new window; `suppressed` events of the same kind
    /// were counted silently before it (in earlier windows) and should be mentioned.
    Log {
        /// Events not logged since the last logged one.
        suppressed: u32,
    },
    /// Count it, log nothing.
    Silent,
}

/// Counts events of one kind: the first of each [`LOG_WINDOW_US`] window is logged (with
/// the count of those silenced before it), the rest only counted. So a flood costs one
/// line a second, and the count is never lost.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LogLimit {
    window_start_us: Option<u64>,
    suppressed: u32,
}

impl LogLimit {
    /// Nothing seen yet: the first event is logged.
    pub const fn new() -> Self {
        LogLimit {
            window_start_us: None,
            suppressed: 0,
        }
    }

    /// An event at `now_us`: whether to log it.
    pub fn event(&mut self, now_us: u64) -> LogVerdict {
        match self.window_start_us {
            Some(start) if now_us.saturating_sub(start) < LOG_WINDOW_US => {
                self.suppressed = self.suppressed.saturating_add(1);
                LogVerdict::Silent
            }
            _ => {
                self.window_start_us = Some(now_us);
                let suppressed = core::mem::take(&mut self.suppressed);
                LogVerdict::Log { suppressed }
            }
        }
    }

    /// `n` events at once (counted elsewhere): like `n` calls of [`LogLimit::event`],
    /// returning the verdict of the first and counting the rest.
    pub fn events(&mut self, n: u32, now_us: u64) -> LogVerdict {
        if n == 0 {
            return LogVerdict::Silent;
        }
        let verdict = self.event(now_us);
        self.suppressed = self.suppressed.saturating_add(n - 1);
        verdict
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_line_a_second_with_the_count() {
        let mut limit = LogLimit::new();
        assert_eq!(limit.event(0), LogVerdict::Log { suppressed: 0 });
        for t in 1..1000 {
            assert_eq!(limit.event(t * 100), LogVerdict::Silent);
        }
        assert_eq!(
            limit.event(LOG_WINDOW_US),
            LogVerdict::Log { suppressed: 999 }
        );
        assert_eq!(limit.events(5, LOG_WINDOW_US + 1), LogVerdict::Silent);
        assert_eq!(
            limit.events(3, 3 * LOG_WINDOW_US),
            LogVerdict::Log { suppressed: 5 }
        );
        assert_eq!(
            limit.event(5 * LOG_WINDOW_US),
            LogVerdict::Log { suppressed: 2 }
        );
    }
}
