//! [`DirQueues`]: every joint's DIR changes, handed from the producer (the refills, under
//! the step lock) to the interrupt that makes them (the board's step clock), with no lock
//! between the two (issue 20: "DIR never late, by construction").
//!
//! One single-producer single-consumer ring per joint, in atomics only: the producer
//! writes an entry's two words, then publishes it by storing `tail` (release); the consumer
//! reads `tail` (acquire), then the entry, and frees it by storing `head` (release), which
//! the producer reads (acquire) before it reuses a slot. Each index is written by one side
//! only, so neither side ever waits for the other: the consumer can preempt the producer
//! anywhere (or the reverse) and sees either the entry whole or not at all. On a single
//! core the orderings cost a `dmb` each; no read-modify-write is needed.
//!
//! [`DirQueues::clear`] writes `head`, the consumer's index: it may only be called while
//! the consumer does not run (on the board: with the step clock's alarm disarmed, which is
//! the only thing that makes the interrupt look at the queues).

use core::sync::atomic::{AtomicU32, Ordering};

use crate::MAX_JOINTS;
use crate::stream::{DIR_RING, DirChange};

/// Bit of an entry's high word that holds the level (ticks stay below 2^63).
const LEVEL: u32 = 1 << 31;

/// Indices run over `0..2 * DIR_RING`, so that a full ring (`tail - head == DIR_RING`)
/// differs from an empty one (`tail == head`) without a separate count.
const INDEX_SPAN: u32 = 2 * RING;

/// [`DIR_RING`] as the indices' type.
#[allow(
    clippy::cast_possible_truncation,
    reason = "DIR_RING is a few hundred (asserted below)"
)]
const RING: u32 = DIR_RING as u32;
const _: () = assert!(DIR_RING < 1 << 16);

/// One joint's ring.
struct DirQueue {
    /// Entry `i` is words `2i` (tick, low half) and `2i + 1` (tick, high half, and the
    /// level in bit 31).
    words: [AtomicU32; 2 * DIR_RING],
    /// Next entry to make: the consumer's.
    head: AtomicU32,
    /// Next entry to write: the producer's.
    tail: AtomicU32,
}

impl DirQueue {
    const fn empty() -> DirQueue {
        DirQueue {
            words: [const { AtomicU32::new(0) }; 2 * DIR_RING],
            head: AtomicU32::new(0),
            tail: AtomicU32::new(0),
        }
    }

    // Indices stay below INDEX_SPAN: a conditional subtraction, not a division (the
    // refills and the DIR interrupt run these).
    fn len(head: u32, tail: u32) -> u32 {
        if tail >= head {
            tail - head
        } else {
            tail + INDEX_SPAN - head
        }
    }

    fn slot(index: u32) -> usize {
        (if index >= RING { index - RING } else { index }) as usize * 2
    }

    fn next(index: u32) -> u32 {
        if index + 1 == INDEX_SPAN {
            0
        } else {
            index + 1
        }
    }
}

/// Every joint's DIR changes waiting to be made, oldest first; shared by reference
/// between the producer and the consumer (put it in a `static`: [`DirQueues::new`] is
/// `const`).
pub struct DirQueues {
    joints: [DirQueue; MAX_JOINTS],
}

impl Default for DirQueues {
    fn default() -> Self {
        Self::new()
    }
}

impl DirQueues {
    /// Empty queues.
    pub const fn new() -> Self {
        DirQueues {
            joints: [const { DirQueue::empty() }; MAX_JOINTS],
        }
    }

    /// Producer: queues a change of `joint` at `tick`; false if its ring is full (or the
    /// joint does not exist).
    #[allow(
        clippy::cast_possible_truncation,
        clippy::indexing_slicing,
        reason = "the tick is split into its two 32-bit halves; slot() < 2 * DIR_RING - 1"
    )]
    pub fn push(&self, joint: usize, tick: u64, positive: bool) -> bool {
        let Some(q) = self.joints.get(joint) else {
            return false;
        };
        let tail = q.tail.load(Ordering::Relaxed);
        let head = q.head.load(Ordering::Acquire);
        if DirQueue::len(head, tail) >= RING {
            return false;
        }
        let at = DirQueue::slot(tail);
        let high = (tick >> 32) as u32 & !LEVEL;
        q.words[at].store(tick as u32, Ordering::Relaxed);
        q.words[at + 1].store(high | if positive { LEVEL } else { 0 }, Ordering::Relaxed);
        q.tail.store(DirQueue::next(tail), Ordering::Release);
        true
    }

    /// Consumer: the oldest change of `joint` not made yet.
    #[allow(clippy::indexing_slicing, reason = "slot() < 2 * DIR_RING - 1")]
    pub fn peek(&self, joint: usize) -> Option<DirChange> {
        let q = self.joints.get(joint)?;
        let head = q.head.load(Ordering::Relaxed);
        let tail = q.tail.load(Ordering::Acquire);
        if head == tail {
            return None;
        }
        let at = DirQueue::slot(head);
        let low = q.words[at].load(Ordering::Relaxed);
        let high = q.words[at + 1].load(Ordering::Relaxed);
        Some(DirChange {
            tick: (u64::from(high & !LEVEL) << 32) | u64::from(low),
            positive: high & LEVEL != 0,
        })
    }

    /// Consumer: drops the oldest change of `joint` (made).
    pub fn pop(&self, joint: usize) {
        if let Some(q) = self.joints.get(joint) {
            let head = q.head.load(Ordering::Relaxed);
            if head != q.tail.load(Ordering::Acquire) {
                q.head.store(DirQueue::next(head), Ordering::Release);
            }
        }
    }

    /// The earliest queued change of any joint (its tick), read from either side: a
    /// consumer running meanwhile can only make the true earliest later.
    #[allow(clippy::indexing_slicing, reason = "slot() < 2 * DIR_RING - 1")]
    pub fn earliest(&self) -> Option<u64> {
        let mut earliest = u64::MAX;
        for q in &self.joints {
            let head = q.head.load(Ordering::Relaxed);
            if head != q.tail.load(Ordering::Acquire) {
                let at = DirQueue::slot(head);
                let low = q.words[at].load(Ordering::Relaxed);
                let high = q.words[at + 1].load(Ordering::Relaxed) & !LEVEL;
                earliest = earliest.min((u64::from(high) << 32) | u64::from(low));
            }
        }
        (earliest != u64::MAX).then_some(earliest)
    }

    /// Drops every queued change. Only while the consumer does not run (see the module
    /// header): it writes the consumer's index.
    pub fn clear(&self) {
        for q in &self.joints {
            q.head
                .store(q.tail.load(Ordering::Acquire), Ordering::Release);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn changes_come_out_in_order_with_their_levels_and_full_is_refused() {
        let queues = DirQueues::new();
        assert_eq!(queues.peek(3), None);
        // Around the index wrap several times.
        let mut next_out = 0u64;
        let mut next_in = 0u64;
        for round in 0..5 {
            while queues.push(3, (1 << 40) + next_in * 7, next_in.is_multiple_of(3)) {
                next_in += 1;
            }
            assert_eq!(
                next_in - next_out,
                DIR_RING as u64,
                "round {round}: full at DIR_RING"
            );
            for _ in 0..DIR_RING - 1 - round {
                let change = queues.peek(3).expect("queued");
                assert_eq!(change.tick, (1 << 40) + next_out * 7);
                assert_eq!(change.positive, next_out.is_multiple_of(3));
                queues.pop(3);
                next_out += 1;
            }
        }
        assert_eq!(queues.peek(2), None, "other joints untouched");
        assert!(!queues.push(MAX_JOINTS, 1, true));
        queues.clear();
        assert_eq!(queues.peek(3), None);
        assert!(queues.push(3, 5, false));
        assert!(queues.push(6, 2, true));
        assert_eq!(queues.earliest(), Some(2));
    }
}
