//! A fixed ring of queued segments (no dependencies, no allocation).

use crate::engine::QueueEnd;
use crate::{ALL_JOINTS, JointMask, MAX_JOINTS, Segment, write_each};

/// One queued segment and its place on the run's timeline, worked out when it is pushed so
/// that the interrupt never divides by 1_000_000.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Slot {
    /// Signed steps per joint.
    pub steps: [i32; MAX_JOINTS],
    /// Segment length, microseconds.
    pub duration_us: u32,
    /// `(cum_us * tick_hz) mod 1_000_000`: the fraction of a tick (in millionths) by which
    /// the exact start lies after `start_tick`.
    pub start_frac: u32,
    /// `floor(cum_us * tick_hz / 1_000_000)`: start tick relative to the run's start.
    pub start_tick: u64,
    /// Start tick of the next segment, relative to the run's start.
    pub end_tick: u64,
    /// Joints that have not finished their pulses in this segment yet.
    pub pending: JointMask,
}

impl Slot {
    /// An unused slot.
    pub const EMPTY: Slot = Slot {
        steps: [0; MAX_JOINTS],
        duration_us: 0,
        start_frac: 0,
        start_tick: 0,
        end_tick: 0,
        pending: 0,
    };
}

/// `QUEUE` slots used as a FIFO. Slots are addressed by index (`0..QUEUE`) so that each
/// joint can keep its own place in the queue.
#[derive(Debug)]
pub(crate) struct SegmentRing<const QUEUE: usize> {
    slots: [Slot; QUEUE],
    /// Index of the oldest held slot.
    head: usize,
    /// Slots held.
    len: usize,
}

impl<const QUEUE: usize> SegmentRing<QUEUE> {
    pub const fn new() -> Self {
        Self {
            slots: [Slot::EMPTY; QUEUE],
            head: 0,
            len: 0,
        }
    }

    /// Writes [`SegmentRing::new`]'s value at `ring`, slot by slot (never the whole ring
    /// on the stack first).
    ///
    /// # Safety
    /// `ring` is valid for writes and aligned (the storage of a `SegmentRing<QUEUE>`).
    pub unsafe fn init_in_place(ring: *mut Self) {
        // Every field is listed here: a field added to the ring fails to compile until it
        // is written below too.
        #[allow(dead_code, reason = "only compiled, never called")]
        fn every_field_is_written<const Q: usize>(ring: &SegmentRing<Q>) {
            let SegmentRing {
                slots: _,
                head: _,
                len: _,
            } = ring;
        }
        // SAFETY: the caller's guarantee; every write is to a field of `ring`, and every
        // field (every slot) is written.
        unsafe {
            write_each(&raw mut (*ring).slots, Slot::EMPTY);
            (&raw mut (*ring).head).write(0);
            (&raw mut (*ring).len).write(0);
        }
    }

    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Index of the slot after `index`.
    pub fn next_index(index: usize) -> usize {
        if index + 1 >= QUEUE { 0 } else { index + 1 }
    }

    /// Index of the oldest held slot (where the next pushed slot goes if the ring is empty).
    pub fn head_index(&self) -> usize {
        self.head
    }

    /// Appends `segment`, to start at `start` (the queue's end, on a timeline of `tick_hz`);
    /// the queue's new end, or `None` if the ring is full.
    pub fn push_segment(
        &mut self,
        segment: &Segment,
        start: QueueEnd,
        tick_hz: u64,
    ) -> Option<QueueEnd> {
        let end = start.after(segment.duration_us, tick_hz);
        let slot = Slot {
            steps: segment.steps,
            duration_us: segment.duration_us,
            start_frac: start.frac,
            start_tick: start.tick,
            end_tick: end.tick,
            pending: ALL_JOINTS,
        };
        self.push_back(slot).ok().map(|()| end)
    }

    /// Appends `slot`; gives it back if the ring is full.
    pub fn push_back(&mut self, slot: Slot) -> Result<(), Slot> {
        if self.len >= QUEUE {
            return Err(slot);
        }
        let mut tail = self.head + self.len;
        if tail >= QUEUE {
            tail -= QUEUE;
        }
        match self.slots.get_mut(tail) {
            Some(free) => {
                *free = slot;
                self.len += 1;
                Ok(())
            }
            None => Err(slot),
        }
    }

    /// The oldest held slot.
    pub fn front(&self) -> Option<&Slot> {
        if self.len == 0 {
            None
        } else {
            self.slots.get(self.head)
        }
    }

    /// Drops the oldest held slot.
    pub fn pop_front(&mut self) {
        if self.len > 0 {
            self.head = Self::next_index(self.head);
            self.len -= 1;
        }
    }

    /// Drops every slot.
    pub fn clear(&mut self) {
        self.head = 0;
        self.len = 0;
    }

    /// Slot at ring index `index` (held or not: callers track holding by ordinal).
    pub fn get(&self, index: usize) -> Option<&Slot> {
        self.slots.get(index)
    }

    /// Slot at ring index `index` (held or not: callers track holding by ordinal).
    pub fn get_mut(&mut self, index: usize) -> Option<&mut Slot> {
        self.slots.get_mut(index)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn slot(tag: u32) -> Slot {
        Slot {
            duration_us: tag,
            ..Slot::EMPTY
        }
    }

    #[test]
    fn fifo_order_across_wrap() {
        let mut ring = SegmentRing::<3>::new();
        for round in 0..5u32 {
            assert!(ring.push_back(slot(round * 10)).is_ok());
            assert!(ring.push_back(slot(round * 10 + 1)).is_ok());
            assert_eq!(ring.len(), 2);
            assert_eq!(ring.front().map(|s| s.duration_us), Some(round * 10));
            ring.pop_front();
            assert_eq!(ring.front().map(|s| s.duration_us), Some(round * 10 + 1));
            ring.pop_front();
            assert!(ring.is_empty());
            assert_eq!(ring.front(), None);
        }
    }

    #[test]
    fn full_ring_gives_the_slot_back() {
        let mut ring = SegmentRing::<2>::new();
        assert!(ring.push_back(slot(1)).is_ok());
        assert!(ring.push_back(slot(2)).is_ok());
        assert_eq!(ring.push_back(slot(3)), Err(slot(3)));
        ring.pop_front();
        assert!(ring.push_back(slot(3)).is_ok());
        assert_eq!(ring.front().map(|s| s.duration_us), Some(2));
    }

    #[test]
    fn zero_capacity_never_holds() {
        let mut ring = SegmentRing::<0>::new();
        assert_eq!(ring.push_back(slot(1)), Err(slot(1)));
        ring.pop_front();
        assert!(ring.is_empty());
        assert_eq!(SegmentRing::<0>::next_index(0), 0);
    }

    #[test]
    fn next_index_wraps() {
        assert_eq!(SegmentRing::<4>::next_index(2), 3);
        assert_eq!(SegmentRing::<4>::next_index(3), 0);
        assert_eq!(SegmentRing::<1>::next_index(0), 0);
    }
}
