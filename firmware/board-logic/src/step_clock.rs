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
//!
//! [`compare_for`] decides what the compare channel does for an alarm (a DIR change, the
//! run's end).

/// Ticks per wrap of the 16-bit counter.
pub const WRAP: u64 = 1 << 16;

/// The tick: `wraps` counted by the interrupt, the update flag read before the counter
/// (`pending_before`), the counter, the flag read after it (`pending_after`).
pub fn extended_tick(wraps: u64, pending_before: bool, counter: u16, pending_after: bool) -> u64 {
    let uncounted = pending_before || (pending_after && u64::from(counter) < WRAP / 2);
    (wraps + u64::from(uncounted)) * WRAP + u64::from(counter)
}

/// What TIM13's compare channel 1 is set to do for an alarm ([`compare_for`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Compare {
    /// The alarm is at or before now: pend the interrupt, it runs at once.
    Due,
    /// CCR1 = this value (the alarm's low 16 bits), compare interrupt on: the counter
    /// next shows it at the alarm's very tick. The caller still reads the clock again
    /// once CCR1 is written: a counter that passed the value meanwhile matches only a
    /// wrap later, so an alarm found due then is pended.
    Match(u16),
    /// A whole wrap or more away: compare interrupt off (CCR1 would match a wrap early).
    /// A wrap comes first, and its interrupt decides again.
    AfterWrap,
}

/// The rule for TIM13's compare, for an alarm at step clock tick `alarm` with the clock at
/// `now`, applied whenever the alarm is set and at every wrap's interrupt:
///
/// * `alarm <= now`: [`Compare::Due`].
/// * `alarm - now < WRAP`: [`Compare::Match`] of the alarm's low 16 bits. The counter takes
///   that value once per wrap; the first time after `now` is the alarm itself, as the alarm
///   is less than a wrap away. So the compare fires at the alarm, not later, wherever the
///   alarm falls in the current or the next wrap.
/// * otherwise [`Compare::AfterWrap`]: every later wrap's interrupt applies the rule again,
///   and the last wrap before the alarm (at most a wrap before it) finds it less than a wrap
///   away, or due if that interrupt was held off past it: the alarm is never later than
///   the wrap interrupt's own latency.
///
/// The rule before this one (up to the Renode step tests) armed the compare only for an
/// alarm less than *half* a wrap away, and left the rest to the next wrap, which an alarm between half a wrap and a wrap away could
/// precede by up to half a wrap: DIR up to 32,768 ticks (164 us at 200 MHz) late, against a
/// 35 us budget (Renode, `abrupt_reversals_change_dir_within_the_budget`: 152 of 399
/// reversals over it, two pulses made in the wrong direction).
///
/// A compare match that comes early (CCR1 written as the counter reaches it) is harmless:
/// the interrupt acts only on `alarm <= now` and otherwise applies the rule again.
#[allow(
    clippy::cast_possible_truncation,
    reason = "the compare value is the alarm's low 16 bits: TIM13's counter wraps at 2^16"
)]
pub fn compare_for(alarm: u64, now: u64) -> Compare {
    if alarm <= now {
        Compare::Due
    } else if alarm - now < WRAP {
        Compare::Match(alarm as u16)
    } else {
        Compare::AfterWrap
    }
}

/// The timer bus whose clock is wrong ([`check_timer_clocks`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum TimerBus {
    /// APB1's timer clock: TIM2-TIM5 (joints 0-3) and TIM13 (the step clock).
    Apb1,
    /// APB2's timer clock: TIM1, TIM8, TIM16, TIM17 (joints 4-7).
    Apb2,
}

/// A timer bus whose timer clock is not the step clock's rate: every period and pulse its
/// joints make would be off by the ratio.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ClockMismatch {
    /// Which bus.
    pub bus: TimerBus,
    /// The clock its timers actually get.
    pub actual_hz: u32,
}

/// Both timer buses must clock their timers at `step_hz` (issue 34: APB1 was checked,
/// APB2, which clocks joints 4-7, was not). APB1 first.
pub fn check_timer_clocks(apb1_hz: u32, apb2_hz: u32, step_hz: u32) -> Result<(), ClockMismatch> {
    for (bus, actual_hz) in [(TimerBus::Apb1, apb1_hz), (TimerBus::Apb2, apb2_hz)] {
        if actual_hz != step_hz {
            return Err(ClockMismatch { bus, actual_hz });
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn both_timer_buses_are_checked() {
        const HZ: u32 = 200_000_000;
        assert_eq!(check_timer_clocks(HZ, HZ, HZ), Ok(()));
        // APB2 at half (its prescaler changed alone): joints 4-7 would run at half speed.
        assert_eq!(
            check_timer_clocks(HZ, HZ / 2, HZ),
            Err(ClockMismatch {
                bus: TimerBus::Apb2,
                actual_hz: HZ / 2
            })
        );
        assert_eq!(
            check_timer_clocks(HZ / 2, HZ, HZ).map_err(|e| e.bus),
            Err(TimerBus::Apb1)
        );
    }

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

    /// When an alarm set at tick `set_at` fires, on a model of TIM13 (the counter is the
    /// tick's low 16 bits; the compare interrupt runs at the first tick after the decision
    /// whose low bits match; every wrap's interrupt runs `latency` ticks after the wrap and
    /// decides again; the interrupt fires the alarm once `alarm <= now`).
    fn fires_at(rule: fn(u64, u64) -> Compare, set_at: u64, alarm: u64, latency: u64) -> u64 {
        let next_wrap_irq = |t: u64| (t / WRAP + 1) * WRAP + latency;
        let mut t = set_at;
        for _ in 0..1_000 {
            match rule(alarm, t) {
                Compare::Due => return t,
                Compare::Match(value) => {
                    let mut matched = t - t % WRAP + u64::from(value);
                    if matched <= t {
                        matched += WRAP;
                    }
                    let wrap = next_wrap_irq(t);
                    // Whichever interrupt comes first looks at the alarm.
                    t = matched.min(wrap);
                }
                Compare::AfterWrap => t = next_wrap_irq(t),
            }
        }
        panic!("the alarm at {alarm}, set at {set_at}, never fired");
    }

    /// The greatest lateness of `rule` over alarms set at every phase of a wrap and due up
    /// to three wraps later, with wrap interrupts `latency` ticks late.
    fn worst_lateness(rule: fn(u64, u64) -> Compare, latency: u64) -> u64 {
        let mut worst = 0;
        for set_at in (5 * WRAP..6 * WRAP).step_by(97) {
            for distance in (0..3 * WRAP).step_by(101).chain([WRAP - 1, WRAP, WRAP + 1]) {
                let alarm = set_at + distance;
                let fired = fires_at(rule, set_at, alarm, latency);
                assert!(
                    fired >= alarm,
                    "set at {set_at}: {alarm} fired early at {fired}"
                );
                worst = worst.max(fired - alarm);
            }
        }
        worst
    }

    /// The rule before the fix: the compare armed only within half a wrap.
    fn half_wrap_rule(alarm: u64, now: u64) -> Compare {
        if alarm <= now {
            Compare::Due
        } else if alarm - now < WRAP / 2 {
            Compare::Match((alarm % WRAP) as u16)
        } else {
            Compare::AfterWrap
        }
    }

    #[test]
    fn the_half_wrap_rule_fired_up_to_half_a_wrap_late() {
        // What Renode showed (DIR up to 32,780 ticks late): the reproduction.
        let worst = worst_lateness(half_wrap_rule, 0);
        eprintln!("the half-wrap rule: up to {worst} ticks late");
        assert!(worst > WRAP / 2 - 200, "worst {worst}");
    }

    #[test]
    fn an_alarm_fires_at_its_tick_or_within_the_wrap_interrupts_latency() {
        assert_eq!(worst_lateness(compare_for, 0), 0);
        // A wrap interrupt held off (a critical section): late by no more than that, and
        // only for an alarm within that hold-off after the wrap.
        for latency in [1, 500, 7_000] {
            let worst = worst_lateness(compare_for, latency);
            assert!(worst <= latency, "latency {latency}: worst {worst}");
        }
    }

    #[test]
    fn the_compare_value_is_the_alarms_low_bits_within_a_wrap() {
        let now = 7 * WRAP + 60_000;
        assert_eq!(compare_for(now, now), Compare::Due);
        assert_eq!(compare_for(now - 1, now), Compare::Due);
        assert_eq!(compare_for(now + 1, now), Compare::Match(60_001));
        // In the next wrap: the low bits are below the counter's, matched after the wrap.
        assert_eq!(compare_for(now + 10_000, now), Compare::Match(4_464));
        assert_eq!(compare_for(now + WRAP - 1, now), Compare::Match(59_999));
        assert_eq!(compare_for(now + WRAP, now), Compare::AfterWrap);
        assert_eq!(compare_for(u64::MAX, now), Compare::AfterWrap);
    }
}
