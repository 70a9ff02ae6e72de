//! The trajectory buffer: points received and not yet finished, stored compactly.

use protocol::MAX_JOINTS;

/// A trajectory point as the controller keeps it: what defines the motion and nothing
/// else (36 bytes instead of the wire's 116).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct StoredPoint {
    /// Segment length, microseconds (>= 1).
    pub duration_us: u32,
    /// Absolute joint positions at the end of the segment, steps.
    pub position: [i32; MAX_JOINTS],
}

const _: () = assert!(core::mem::size_of::<StoredPoint>() == 36);

/// A ring of [`StoredPoint`]s with room for `CAP` (compile time) of which `capacity`
/// (run time, `1..=CAP`) are used.
///
/// The points held are, oldest first: those handed to the step engine ("fed") and not yet
/// finished, then those waiting to be fed. A slot becomes free when its point finishes.
pub struct TrajectoryBuffer<const CAP: usize> {
    points: [StoredPoint; CAP],
    capacity: usize,
    /// Slot of the oldest point held.
    head: usize,
    /// Points held.
    len: usize,
    /// Points held that were fed to the engine (always the oldest ones).
    fed: usize,
}

impl<const CAP: usize> TrajectoryBuffer<CAP> {
    /// An empty buffer using `capacity` slots (clamped to `1..=CAP`).
    pub const fn new(capacity: usize) -> Self {
        TrajectoryBuffer {
            points: [StoredPoint {
                duration_us: 0,
                position: [0; MAX_JOINTS],
            }; CAP],
            capacity: Self::clamp_capacity(capacity),
            head: 0,
            len: 0,
            fed: 0,
        }
    }

    /// Builds an empty buffer in place at `slot`, as [`TrajectoryBuffer::new`] would: the
    /// points are zeroed where they lie, never built on the stack first (8192 points are
    /// 288 KiB, more than a board's stack).
    ///
    /// # Safety
    /// `slot` is valid for writes of `Self` and properly aligned; whatever it held is
    /// overwritten without being dropped.
    pub unsafe fn init_in_place(slot: *mut Self, capacity: usize) {
        // SAFETY: `slot` is valid for writes (the caller's contract); a `StoredPoint` is
        // plain integers, for which all-zero bytes are a valid value (`new`'s points).
        unsafe {
            (&raw mut (*slot).points).write_bytes(0, 1);
            (&raw mut (*slot).capacity).write(Self::clamp_capacity(capacity));
            (&raw mut (*slot).head).write(0);
            (&raw mut (*slot).len).write(0);
            (&raw mut (*slot).fed).write(0);
        }
    }

    /// `capacity` clamped to `1..=CAP`.
    const fn clamp_capacity(capacity: usize) -> usize {
        let capacity = if capacity > CAP { CAP } else { capacity };
        if capacity == 0 { 1 } else { capacity }
    }

    /// Empties the buffer and uses `capacity` slots (clamped to `1..=CAP`) from now on.
    pub fn set_capacity(&mut self, capacity: usize) {
        self.clear();
        self.capacity = capacity.clamp(1, CAP.max(1));
    }

    /// Slots in use by design.
    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// Points held (received, not finished).
    pub fn buffered(&self) -> usize {
        self.len
    }

    /// Free slots.
    pub fn free(&self) -> usize {
        self.capacity - self.len
    }

    /// Points held but not yet fed to the engine.
    pub fn unfed(&self) -> usize {
        self.len - self.fed
    }

    /// Points fed to the engine and not yet finished.
    pub fn in_flight(&self) -> usize {
        self.fed
    }

    /// Drops every point.
    pub fn clear(&mut self) {
        self.head = 0;
        self.len = 0;
        self.fed = 0;
    }

    fn slot(&self, i: usize) -> usize {
        (self.head + i) % self.capacity
    }

    /// Appends a point; `false` (nothing changed) when full.
    pub fn push(&mut self, point: StoredPoint) -> bool {
        if self.len >= self.capacity {
            return false;
        }
        let at = self.slot(self.len);
        match self.points.get_mut(at) {
            Some(slot) => {
                *slot = point;
                self.len += 1;
                true
            }
            None => false,
        }
    }

    /// The oldest point not yet fed.
    pub fn next_unfed(&self) -> Option<StoredPoint> {
        if self.fed >= self.len {
            return None;
        }
        self.points.get(self.slot(self.fed)).copied()
    }

    /// The `i`-th point held, oldest first (fed ones first).
    pub fn held(&self, i: usize) -> Option<StoredPoint> {
        if i >= self.len {
            return None;
        }
        self.points.get(self.slot(i)).copied()
    }

    /// Marks the point [`next_unfed`](Self::next_unfed) returned as fed.
    pub fn mark_fed(&mut self) {
        if self.fed < self.len {
            self.fed += 1;
        }
    }

    /// Frees the slots of the `n` oldest fed points (their segments finished); returns how
    /// many were freed (at most the points in flight).
    pub fn finish(&mut self, n: usize) -> usize {
        let n = n.min(self.fed);
        self.head = self.slot(n);
        self.len -= n;
        self.fed -= n;
        n
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn point(d: u32) -> StoredPoint {
        StoredPoint {
            duration_us: d,
            position: [d as i32; MAX_JOINTS],
        }
    }

    #[test]
    fn wraps_and_frees_only_finished_points() {
        let mut b = TrajectoryBuffer::<4>::new(3);
        assert_eq!(b.capacity(), 3);
        assert!(b.push(point(1)) && b.push(point(2)) && b.push(point(3)));
        assert!(!b.push(point(4)), "full at the run-time capacity");
        assert_eq!(b.next_unfed(), Some(point(1)));
        b.mark_fed();
        assert_eq!(b.finish(5), 1, "only fed points finish");
        assert_eq!((b.buffered(), b.free(), b.unfed()), (2, 1, 2));
        assert!(b.push(point(4)));
        let mut order = [0; 3];
        for o in &mut order {
            *o = b.next_unfed().map_or(0, |p| p.duration_us);
            b.mark_fed();
        }
        assert_eq!(order, [2, 3, 4]);
        assert_eq!(b.next_unfed(), None);
        assert_eq!(b.finish(3), 3);
        assert_eq!(b.buffered(), 0);
    }

    #[test]
    fn capacity_is_clamped() {
        assert_eq!(TrajectoryBuffer::<4>::new(100).capacity(), 4);
        assert_eq!(TrajectoryBuffer::<4>::new(0).capacity(), 1);
        let mut b = TrajectoryBuffer::<4>::new(4);
        assert!(b.push(point(1)));
        b.set_capacity(2);
        assert_eq!((b.capacity(), b.buffered(), b.free()), (2, 0, 2));
        b.set_capacity(9);
        assert_eq!(b.capacity(), 4);
    }
}
