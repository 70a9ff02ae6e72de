//! Counted gripper pulses in bursts of the repetition counter (TIM15's RCR has 8 bits).
//!
//! Up to 256 pulses are one burst (one-pulse mode, no interrupt). More are bursts of 256,
//! with the last 257..=512 split in two halves so that no burst is shorter than 128
//! periods: the update interrupt at the end of burst k (burst k + 1 is running) has at
//! least 128 periods to load the size of burst k + 2.

/// Periods per burst at most: the repetition counter of TIM15 has 8 bits.
pub const MAX_BURST: u32 = 256;

/// The size of the next burst when `remaining` pulses are not yet loaded: full bursts,
/// and the last 257..=512 split in two halves so that the final burst, which the
/// interrupt must see start before it ends, is never short.
pub const fn next_burst(remaining: u32) -> u32 {
    if remaining <= MAX_BURST {
        remaining
    } else if remaining <= 2 * MAX_BURST {
        remaining - remaining / 2
    } else {
        MAX_BURST
    }
}

/// The repetition counter value (RCR) for a burst of `burst` periods (1..=256).
pub const fn rcr_for(burst: u32) -> u8 {
    (burst.saturating_sub(1) & 0xFF) as u8
}

// Checked at compile time for every count up to four full bursts and then some: the bursts
// add up to the count, each fits the repetition counter, and when the interrupt is needed
// (more than one burst) no burst is shorter than half a full one.
const _: () = {
    let mut count = 1;
    while count <= 4 * MAX_BURST + 3 {
        let mut remaining = count;
        while remaining > 0 {
            let burst = next_burst(remaining);
            assert!(burst >= 1 && burst <= MAX_BURST);
            assert!(count <= MAX_BURST || burst >= MAX_BURST / 2);
            remaining -= burst;
        }
        count += 1;
    }
};

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn bursts(count: u32) -> std::vec::Vec<u32> {
        let mut out = std::vec::Vec::new();
        let mut remaining = count;
        while remaining > 0 {
            let b = next_burst(remaining);
            out.push(b);
            remaining -= b;
        }
        out
    }

    #[test]
    fn small_counts_are_one_burst() {
        assert_eq!(bursts(1), [1]);
        assert_eq!(bursts(256), [256]);
    }

    #[test]
    fn the_last_two_bursts_share_the_remainder() {
        assert_eq!(bursts(257), [129, 128]);
        assert_eq!(bursts(512), [256, 256]);
        assert_eq!(bursts(513), [256, 129, 128]);
        assert_eq!(bursts(1000), [256, 256, 244, 244]);
    }

    #[test]
    fn rcr_is_burst_minus_one() {
        assert_eq!(rcr_for(1), 0);
        assert_eq!(rcr_for(256), 255);
    }

    proptest! {
        #[test]
        fn bursts_add_up_and_fit(count in 1u32..2_000_000) {
            let b = bursts(count);
            prop_assert_eq!(b.iter().map(|&x| u64::from(x)).sum::<u64>(), u64::from(count));
            for &x in &b {
                prop_assert!((1..=MAX_BURST).contains(&x));
                prop_assert!(b.len() == 1 || x >= MAX_BURST / 2);
            }
        }
    }
}
