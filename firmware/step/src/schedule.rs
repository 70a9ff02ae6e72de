//! Each joint's next edge tick, and the earliest of them in O(log joints).

use crate::{JointMask, MAX_JOINTS};

/// Nodes of the tree: leaves at `MAX_JOINTS..2 * MAX_JOINTS`, node `i`'s parent at `i / 2`,
/// the root at 1 (index 0 unused).
const NODES: usize = 2 * MAX_JOINTS;

/// Inner levels between a leaf and the root.
const LEVELS: u32 = MAX_JOINTS.trailing_zeros();

// `due` compares the eight leaves in straight-line code.
const _: () = assert!(MAX_JOINTS == 8);

/// A tournament tree over the joints' next edge ticks: each inner node holds the earlier of
/// its two children, so the root is the next deadline. `poll` changes a few joints' edges
/// per call; refreshing their paths costs `log2(MAX_JOINTS)` comparisons each, where a
/// full scan would cost `MAX_JOINTS`.
#[derive(Clone, Debug)]
pub(crate) struct EdgeTree {
    nodes: [u64; NODES],
}

impl EdgeTree {
    /// No edge scheduled (every joint waiting).
    pub const IDLE: EdgeTree = EdgeTree {
        nodes: [u64::MAX; NODES],
    };

    /// Joint `j`'s next edge (`u64::MAX`: none).
    #[inline(always)]
    pub fn get(&self, j: usize) -> u64 {
        self.nodes[(MAX_JOINTS + j) & (NODES - 1)]
    }

    /// Sets joint `j`'s next edge. The tree is stale until `refresh`.
    #[inline(always)]
    pub fn set(&mut self, j: usize, tick: u64) {
        self.nodes[(MAX_JOINTS + j) & (NODES - 1)] = tick;
    }

    /// The earliest edge of all joints, as of the last `refresh`.
    #[inline(always)]
    pub fn earliest(&self) -> u64 {
        self.nodes[1]
    }

    /// Joints whose edge is at or before `now`, looking only at the joints in `active`
    /// (the others have no edge).
    #[inline(always)]
    pub fn due(&self, now: u64, active: JointMask) -> JointMask {
        let mut due = 0;
        if at_most_two(active) {
            // Few joints moving: visit just those.
            let mut rest = active;
            while rest != 0 {
                let j = rest.trailing_zeros() as usize;
                rest &= rest - 1;
                due |= u8::from(self.get(j) <= now) << j;
            }
        } else {
            // Straight-line compare of every leaf: a handful of instructions each.
            let [l0, l1, l2, l3, l4, l5, l6, l7] = self.leaves();
            due = u8::from(l0 <= now)
                | u8::from(l1 <= now) << 1
                | u8::from(l2 <= now) << 2
                | u8::from(l3 <= now) << 3
                | u8::from(l4 <= now) << 4
                | u8::from(l5 <= now) << 5
                | u8::from(l6 <= now) << 6
                | u8::from(l7 <= now) << 7;
        }
        due
    }

    /// The leaves, one per joint.
    #[inline(always)]
    fn leaves(&self) -> [u64; MAX_JOINTS] {
        let mut leaves = [0; MAX_JOINTS];
        leaves.copy_from_slice(&self.nodes[MAX_JOINTS..]);
        leaves
    }

    /// Brings the inner nodes up to date after `set` on the joints in `changed`.
    #[inline(always)]
    pub fn refresh(&mut self, changed: JointMask) {
        if at_most_two(changed) {
            // Walk up from each changed leaf, carrying the path's minimum.
            let mut rest = changed;
            while rest != 0 {
                let j = rest.trailing_zeros() as usize;
                rest &= rest - 1;
                let mut node = (MAX_JOINTS + j) & (NODES - 1);
                let mut earliest = self.nodes[node];
                for _ in 0..LEVELS {
                    earliest = earliest.min(self.nodes[node ^ 1]);
                    node >>= 1;
                    self.nodes[node] = earliest;
                }
            }
        } else {
            for node in (1..MAX_JOINTS).rev() {
                let left = self.nodes[(2 * node) & (NODES - 1)];
                let right = self.nodes[(2 * node + 1) & (NODES - 1)];
                self.nodes[node] = left.min(right);
            }
        }
    }
}

/// Whether `mask` has two bits set or fewer (`count_ones` is a dozen instructions on a
/// Cortex-M, this is four).
#[inline(always)]
fn at_most_two(mask: JointMask) -> bool {
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
    fn root_is_the_minimum_after_any_updates() {
        let mut tree = EdgeTree::IDLE;
        assert_eq!(tree.earliest(), u64::MAX);
        let mut model = [u64::MAX; MAX_JOINTS];
        let mut seed = 0x9e37_79b9_7f4a_7c15_u64;
        for _ in 0..2_000 {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            // One to eight joints change at a time.
            let changed = (seed >> 8) as u8 | 1;
            for (j, slot) in model.iter_mut().enumerate() {
                if changed & (1 << j) != 0 {
                    let tick = if seed.is_multiple_of(5) {
                        u64::MAX
                    } else {
                        (seed >> (j * 3)) % 1_000
                    };
                    tree.set(j, tick);
                    *slot = tick;
                }
            }
            tree.refresh(changed);
            assert_eq!(tree.earliest(), *model.iter().min().unwrap_or(&u64::MAX));
            for (j, &tick) in model.iter().enumerate() {
                assert_eq!(tree.get(j), tick);
            }
            let now = seed % 1_000;
            let expected = model
                .iter()
                .enumerate()
                .fold(0u8, |mask, (j, &t)| mask | (u8::from(t <= now) << j));
            assert_eq!(tree.due(now, 0xFF), expected);
            assert_eq!(tree.due(now, 0b1000_0010), expected & 0b1000_0010);
        }
    }
}
