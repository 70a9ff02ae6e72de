//! One joint's walk through the segment queue and its pulse timing.

use crate::Warp;

/// Where one joint is: which segment it works on, its STEP line's next edge, and the
/// incremental pulse clock of that segment.
///
/// Pulse `i` of `n` in a segment whose exact start is `start + frac / 1e6` ticks and whose
/// exact length is `duration_us * tick_hz / 1e6` ticks rises at the floor of its exact time:
/// `start + floor((frac * n + i * duration_us * tick_hz) / (1e6 * n))`. Stepping `i` adds
/// `whole` ticks and `fraction` to a remainder kept below `modulus = 1e6 * n`: no division
/// per pulse, no rounding error, and pulse `n` lands exactly on the segment's end tick.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Joint {
    /// Ordinal (wrapping) of the segment this joint works on, or waits for if it is not
    /// queued yet.
    pub ordinal: u32,
    /// Ring index of that segment.
    pub slot: usize,
    /// Ideal tick of the next pulse to raise.
    pub ideal: u64,
    /// Whole ticks between two pulses.
    pub whole: u64,
    /// Fractional part of the pulse spacing, in units of `1 / modulus` tick.
    pub fraction: u64,
    /// Remainder accumulated so far, `< modulus`.
    pub remainder: u64,
    /// `1_000_000 * n`.
    pub modulus: u64,
    /// Pulses still to raise in this segment.
    pub remaining: u32,
    /// +1 or -1: what one pulse does to `position`.
    pub sign: i32,
    /// Steps, counted per pulse emitted.
    pub position: i32,
    /// Level last written to the DIR line (`None`: not written since boot).
    pub direction: Option<bool>,
    /// No rising edge before this tick: STEP must stay low one tick at least, and
    /// `dir_setup_ticks` after a DIR change.
    pub earliest: u64,
}

impl Joint {
    /// A joint at position 0 that waits for a segment.
    pub const IDLE: Joint = Joint {
        ordinal: 0,
        slot: 0,
        ideal: 0,
        whole: 0,
        fraction: 0,
        remainder: 0,
        modulus: 1,
        remaining: 0,
        sign: 1,
        position: 0,
        direction: None,
        earliest: 0,
    };

    /// Sets up the pulse clock for a segment starting exactly at `start + start_frac / 1e6`
    /// ticks, `travel / 1e6` ticks long (`travel = duration_us * tick_hz`), with `steps`
    /// (non-zero) pulses. One u64 division per segment.
    pub fn begin_segment(&mut self, start: u64, start_frac: u32, travel: u64, steps: i32) {
        let n = u64::from(steps.unsigned_abs());
        let modulus = 1_000_000 * n;
        let whole = travel / modulus;
        self.whole = whole;
        self.fraction = travel - whole * modulus;
        self.modulus = modulus;
        // frac < 1e6, so the remainder starts below the modulus.
        self.remainder = u64::from(start_frac) * n;
        self.ideal = start;
        self.remaining = steps.unsigned_abs();
        self.sign = if steps > 0 { 1 } else { -1 };
        self.advance_ideal();
    }

    /// Moves `ideal` to the next pulse.
    #[inline(always)]
    pub fn advance_ideal(&mut self) {
        self.ideal += self.whole;
        self.remainder += self.fraction;
        let carry = self.remainder >= self.modulus;
        self.remainder -= if carry { self.modulus } else { 0 };
        self.ideal += u64::from(carry);
    }

    /// Tick of the next rising edge: the ideal tick (through `warp`), or `earliest` if the STEP/DIR timing
    /// does not allow it: a delayed pulse, counted in `late`, never a dropped one.
    #[inline(always)]
    pub fn next_rise(&self, late: &mut u32, warp: &Warp) -> u64 {
        // The ideal tick is trajectory time: the warp says when it comes.
        let ideal = warp.controller_tick(self.ideal);
        let is_late = self.earliest > ideal;
        *late = late.wrapping_add(u32::from(is_late));
        if is_late { self.earliest } else { ideal }
    }

    /// Books a rising edge made now.
    #[inline(always)]
    pub fn rise(&mut self) {
        self.position = self.position.wrapping_add(self.sign);
        // Never 0 here: a joint with no pulse left has no rising edge.
        self.remaining = self.remaining.wrapping_sub(1);
        self.advance_ideal();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Rising ticks of a whole segment by stepping the incremental clock.
    fn pulses(start: u64, start_frac: u32, travel: u64, steps: i32) -> [u64; 64] {
        let mut joint = Joint::IDLE;
        joint.begin_segment(start, start_frac, travel, steps);
        let mut out = [0; 64];
        for tick in out.iter_mut().take(steps.unsigned_abs() as usize) {
            *tick = joint.ideal;
            joint.rise();
        }
        assert_eq!(joint.remaining, 0);
        out
    }

    #[test]
    fn incremental_clock_matches_exact_floor() {
        for &(start, frac, travel, steps) in &[
            (0u64, 0u32, 1_000 * 1_000_000u64, 7i32),
            (10, 999_999, 333 * 2_999_999, 13),
            (5, 123_456, 1_000 * 3_000_000, -64),
            (0, 0, 1, 3),
        ] {
            let ticks = pulses(start, frac, travel, steps);
            let n = u128::from(steps.unsigned_abs());
            for i in 1..=n {
                let exact = (u128::from(frac) * n + i * u128::from(travel)) / (1_000_000 * n);
                assert_eq!(u128::from(ticks[i as usize - 1]), u128::from(start) + exact);
            }
        }
    }

    #[test]
    fn late_rise_is_counted_and_moved() {
        let mut joint = Joint::IDLE;
        joint.begin_segment(100, 0, 10 * 1_000_000, 1);
        assert_eq!(joint.ideal, 110);
        let mut late = 0;
        joint.earliest = 105;
        assert_eq!(
            (joint.next_rise(&mut late, &Warp::IDENTITY), late),
            (110, 0)
        );
        joint.earliest = 111;
        assert_eq!(
            (joint.next_rise(&mut late, &Warp::IDENTITY), late),
            (111, 1)
        );
    }
}
