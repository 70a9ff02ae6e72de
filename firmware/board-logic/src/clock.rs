//! Which oscillator the board runs on.
//!
//! The NUCLEO's 8 MHz HSE is the ST-LINK's MCO output: it exists only while the ST-LINK
//! part of the board is powered (not when the board is fed through the Zio 5 V pin with
//! the ST-LINK cut off, or when the ST-LINK firmware does not start MCO). embassy's clock
//! setup waits for HSE-ready without a limit, so the board asks first, with
//! [`wait_ready`], and falls back to the internal 64 MHz HSI (1 % accuracy, enough for
//! the 115200 baud serial port and the step timing's tolerance) when HSE does not start.

/// Polls of HSE-ready before giving up. The board spaces them 1 us apart: 10 ms, far
/// more than an external clock (bypass mode: ready within a few cycles) or even a crystal
/// (2 ms typical) needs.
pub const HSE_READY_POLLS: u32 = 10_000;

/// The oscillator the PLL runs from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ClockSource {
    /// 8 MHz from the ST-LINK's MCO (HSE bypass).
    Hse,
    /// HSE did not start within [`HSE_READY_POLLS`]: the internal HSI.
    HsiFallback,
}

/// Polls `ready` at most `max_polls` times (calling `between` after each `false`);
/// whether it became true.
pub fn wait_ready(
    mut ready: impl FnMut() -> bool,
    max_polls: u32,
    mut between: impl FnMut(),
) -> bool {
    for _ in 0..max_polls {
        if ready() {
            return true;
        }
        between();
    }
    false
}

/// The source to configure after probing HSE.
pub fn choose_source(hse_ready: bool) -> ClockSource {
    if hse_ready {
        ClockSource::Hse
    } else {
        ClockSource::HsiFallback
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_clock_that_comes_up_is_taken() {
        let mut polls = 0;
        let ok = wait_ready(
            || {
                polls += 1;
                polls == 5
            },
            HSE_READY_POLLS,
            || {},
        );
        assert!(ok);
        assert_eq!(polls, 5);
        assert_eq!(choose_source(ok), ClockSource::Hse);
    }

    #[test]
    fn a_missing_clock_gives_up_after_the_bound() {
        let mut polls = 0;
        let mut waits = 0;
        let ok = wait_ready(
            || {
                polls += 1;
                false
            },
            HSE_READY_POLLS,
            || waits += 1,
        );
        assert!(!ok);
        assert_eq!(polls, HSE_READY_POLLS);
        assert_eq!(waits, HSE_READY_POLLS);
        assert_eq!(choose_source(ok), ClockSource::HsiFallback);
    }
}
