//! The step clock's 64-bit tick from TIM13's 16-bit counter and the wraps its update
//! interrupt has counted (`firmware/board/src/step_timer.rs`), including a wrap whose
//! interrupt has not run yet.
//!
//! The update flag (UIF) is read before and after the counter. Set before: the wrap came
//! before the counter was read, whatever its value, so this holds while the interrupt is
//! held off for up to a whole wrap (327.68 us at 200 MHz). Set only after: the wrap came
//! between the two reads, a few cycles, and the counter tells on which side. Until issue
//! 20 the flag was read once, after the counter, and a small counter taken to mean "after
//! the wrap": right only while the interrupt ran within half a wrap (164 us), which the
//! run's start broke (scripts/step-cost: up to 189 us with interrupts masked for 8 joints
//! at 1 kHz, reading the clock at its end).

/// Ticks per wrap of the 16-bit counter.
pub const WRAP: u64 = 1 << 16;

/// The tick: `wraps` counted by the interrupt, the update flag read before the counter
/// (`pending_before`), the counter, the flag read after it (`pending_after`).
pub fn extended_tick(wraps: u64, pending_before: bool, counter: u16, pending_after: bool) -> u64 {
    let uncounted = pending_before || (pending_after && u64::from(counter) < WRAP / 2);
    (wraps + u64::from(uncounted)) * WRAP + u64::from(counter)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_wrap_pending_since_before_the_read_counts_whatever_the_counter() {
        // 200 us after a wrap whose interrupt is held off: counter 40,000 (past half a
        // wrap). The tick is 3 wraps plus 40,000; the rule before issue 20 said 2 wraps.
        assert_eq!(extended_tick(2, true, 40_000, true), 3 * WRAP + 40_000);
        assert_eq!(extended_tick(2, true, 5, true), 3 * WRAP + 5);
    }

    #[test]
    fn a_wrap_between_the_reads_counts_only_if_the_counter_is_past_it() {
        // Counter read just after the wrap: small.
        assert_eq!(extended_tick(7, false, 3, true), 8 * WRAP + 3);
        // Counter read just before it: near the top.
        assert_eq!(extended_tick(7, false, 65_533, true), 7 * WRAP + 65_533);
    }

    #[test]
    fn no_pending_wrap_is_the_count_and_the_counter() {
        assert_eq!(extended_tick(0, false, 0, false), 0);
        assert_eq!(extended_tick(9, false, 65_535, false), 9 * WRAP + 65_535);
    }

    #[test]
    fn the_tick_never_goes_back_across_a_held_off_wrap() {
        // Readings every 1,000 ticks through a wrap whose interrupt runs 50,000 ticks late.
        let mut last = 0;
        for t in (3 * WRAP - 10_000..3 * WRAP + 60_000).step_by(1_000) {
            let counter = (t % WRAP) as u16;
            let wrapped = t >= 3 * WRAP;
            let isr_ran = t >= 3 * WRAP + 50_000;
            let wraps = if isr_ran { 3 } else { 2 };
            let pending = wrapped && !isr_ran;
            let tick = extended_tick(wraps, pending, counter, pending);
            assert_eq!(tick, t, "at {t}");
            assert!(tick >= last);
            last = tick;
        }
    }
}
