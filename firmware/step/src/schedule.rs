//! Each joint's next edge tick: which are due, and the earliest.

use crate::{JointMask, MAX_JOINTS};

// `due` and `earliest` handle the eight joints in straight-line code.
const _: () = assert!(MAX_JOINTS == 8);

/// The tick of each joint's next edge (`u64::MAX`: none).
///
/// `poll` asks two things per call: which joints are due, and the earliest edge once they
/// are handled. With one or two joints moving it visits just those; with more, it compares
/// all eight in straight-line code (a handful of instructions each on a Cortex-M, cheaper
/// than looping over a mask or keeping a heap).
#[derive(Clone, Debug)]
pub(crate) struct Edges {
    ticks: [u64; MAX_JOINTS],
}

impl Edges {
    /// No edge scheduled (every joint waiting).
    pub const IDLE: Edges = Edges {
        ticks: [u64::MAX; MAX_JOINTS],
    };

    /// Joint `j`'s next edge.
    #[inline(always)]
    #[allow(
        clippy::indexing_slicing,
        reason = "the joint number is masked to 0..MAX_JOINTS"
    )]
    pub fn get(&self, j: usize) -> u64 {
        self.ticks[j & (MAX_JOINTS - 1)]
    }

    /// Sets joint `j`'s next edge.
    #[inline(always)]
    #[allow(
        clippy::indexing_slicing,
        reason = "the joint number is masked to 0..MAX_JOINTS"
    )]
    pub fn set(&mut self, j: usize, tick: u64) {
        self.ticks[j & (MAX_JOINTS - 1)] = tick;
    }

    /// Joints in `active` whose edge is at or before `now` (the others have no edge).
    /// `few`: visit only the joints in `active` rather than all eight (either is correct).
    #[inline(always)]
    pub fn due(&self, now: u64, active: JointMask, few: bool) -> JointMask {
        if few {
            let mut due = 0;
            let mut rest = active;
            while rest != 0 {
                let j = rest.trailing_zeros() as usize;
                rest &= rest - 1;
                due |= u8::from(self.get(j) <= now) << j;
            }
            due
        } else {
            let [t0, t1, t2, t3, t4, t5, t6, t7] = self.ticks;
            u8::from(t0 <= now)
                | u8::from(t1 <= now) << 1
                | u8::from(t2 <= now) << 2
                | u8::from(t3 <= now) << 3
                | u8::from(t4 <= now) << 4
                | u8::from(t5 <= now) << 5
                | u8::from(t6 <= now) << 6
                | u8::from(t7 <= now) << 7
        }
    }

    /// The earliest edge of the joints in `active` (the others have none). `few` as in
    /// `due`.
    #[inline(always)]
    pub fn earliest(&self, active: JointMask, few: bool) -> u64 {
        if few {
            let mut earliest = u64::MAX;
            let mut rest = active;
            while rest != 0 {
                let j = rest.trailing_zeros() as usize;
                rest &= rest - 1;
                earliest = earliest.min(self.get(j));
            }
            earliest
        } else {
            let [t0, t1, t2, t3, t4, t5, t6, t7] = self.ticks;
            t0.min(t1).min(t2.min(t3)).min(t4.min(t5).min(t6.min(t7)))
        }
    }
}

/// Whether `mask` has two bits set or fewer: then `due` and `earliest` had better visit
/// just those joints.
pub(crate) fn at_most_two(mask: JointMask) -> bool {
    let without_lowest = mask & mask.wrapping_sub(1);
    without_lowest & without_lowest.wrapping_sub(1) == 0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn at_most_two_bits() {
        for mask in 0..=u8::MAX {
            assert_eq!(at_most_two(mask), mask.count_ones() <= 2, "{mask:#010b}");
        }
    }

    #[test]
    fn due_and_earliest_match_a_plain_scan() {
        let mut edges = Edges::IDLE;
        let mut model = [u64::MAX; MAX_JOINTS];
        let mut seed = 0x9e37_79b9_7f4a_7c15_u64;
        for _ in 0..5_000 {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            let active = (seed >> 8) as u8;
            for (j, slot) in model.iter_mut().enumerate() {
                let tick = if active & (1 << j) == 0 {
                    u64::MAX
                } else {
                    (seed >> (j * 3)) % 1_000
                };
                edges.set(j, tick);
                *slot = tick;
            }
            let now = seed % 1_000;
            let due = model
                .iter()
                .enumerate()
                .fold(0u8, |mask, (j, &t)| mask | (u8::from(t <= now) << j));
            let earliest = *model.iter().min().unwrap_or(&u64::MAX);
            for few in [false, true] {
                assert_eq!(edges.due(now, active, few), due);
                assert_eq!(edges.earliest(active, few), earliest);
            }
            for (j, &tick) in model.iter().enumerate() {
                assert_eq!(edges.get(j), tick);
            }
        }
    }
}
