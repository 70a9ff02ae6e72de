//! The trajectory buffer: points received and not yet finished, stored compactly.
//!
//! It also keeps two summaries of the points it holds that the controller asks for after
//! every finished segment (issue 32's underrun watch, HOLD, RESUME and OVERRIDE ramps):
//! the sum of their durations (exact, kept as points come and go) and each joint's
//! fastest step rate between consecutive held points ([`TrajectoryBuffer::peak_rates`]:
//! never below the exact maximum, equal to it after each rescan). Scanning the points
//! instead was O(points held) per segment: 8,192 on the NUCLEO, a livelock that the IWDG
//! reset (commit ce553d6). The rescan runs only once as many points have finished as are
//! held, so its cost is at most one point per point finished (amortised O(1));
//! [`TrajectoryBuffer::scanned`] counts it for the tests.

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
    /// Sum of the held points' durations, us.
    total_us: u64,
    /// Per joint, steps/s: at least the fastest rate between consecutive held points
    /// (exact after a rescan; the points pushed since only raise it, those finished since
    /// do not lower it until the next rescan).
    peak: [u64; MAX_JOINTS],
    /// Points finished since the last rescan of `peak`.
    finished_since_scan: usize,
    /// Points visited by rescans since the buffer was made (the tests bound the work).
    scanned: u64,
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
            total_us: 0,
            peak: [0; MAX_JOINTS],
            finished_since_scan: 0,
            scanned: 0,
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
            (&raw mut (*slot).total_us).write(0);
            (&raw mut (*slot).peak).write([0; MAX_JOINTS]);
            (&raw mut (*slot).finished_since_scan).write(0);
            (&raw mut (*slot).scanned).write(0);
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
        self.total_us = 0;
        self.peak = [0; MAX_JOINTS];
        self.finished_since_scan = 0;
    }

    /// Sum of the held points' durations, us (exact).
    pub fn duration_sum_us(&self) -> u64 {
        self.total_us
    }

    /// Per joint, steps/s: at least the fastest rate between consecutive held points (the
    /// oldest held point only starts the differences), equal to it after each rescan (see
    /// the module header). A bound from above is on the safe side for its users: a ramp
    /// sloped for a faster joint speed is gentler.
    pub fn peak_rates(&self) -> [u64; MAX_JOINTS] {
        self.peak
    }

    /// Points visited by the rescans of [`Self::peak_rates`] so far (at most one per
    /// point finished).
    pub fn scanned(&self) -> u64 {
        self.scanned
    }

    /// Raises `peak` by the rates of `to` after `from`.
    fn raise_peak(peak: &mut [u64; MAX_JOINTS], from: &StoredPoint, to: &StoredPoint) {
        let d = u64::from(to.duration_us.max(1));
        for ((p, &a), &b) in peak.iter_mut().zip(&from.position).zip(&to.position) {
            let steps = (i64::from(b) - i64::from(a)).unsigned_abs();
            *p = (*p).max(steps.saturating_mul(1_000_000) / d);
        }
    }

    /// Recomputes `peak` exactly from the points held.
    fn rescan(&mut self) {
        let mut peak = [0; MAX_JOINTS];
        let mut previous = self.held(0);
        for i in 1..self.len {
            let Some(point) = self.held(i) else { break };
            if let Some(from) = &previous {
                Self::raise_peak(&mut peak, from, &point);
            }
            previous = Some(point);
        }
        self.scanned += self.len as u64;
        self.peak = peak;
        self.finished_since_scan = 0;
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
        let last = self.len.checked_sub(1).and_then(|i| self.held(i));
        match self.points.get_mut(at) {
            Some(slot) => {
                *slot = point;
                self.len += 1;
                self.total_us += u64::from(point.duration_us);
                if let Some(last) = last {
                    Self::raise_peak(&mut self.peak, &last, &point);
                }
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
        for i in 0..n {
            let d = self.held(i).map_or(0, |p| u64::from(p.duration_us));
            self.total_us = self.total_us.saturating_sub(d);
        }
        self.head = self.slot(n);
        self.len -= n;
        self.fed -= n;
        // Once as many points finished as are held, the bound is rescanned: the scan's
        // len points are paid for by the finished ones (amortised O(1) per point).
        self.finished_since_scan += n;
        if self.finished_since_scan >= self.len {
            self.rescan();
        }
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

    /// The full scans the summaries replace: durations of all held points, and each
    /// joint's fastest rate between consecutive held points.
    fn full_scan<const C: usize>(b: &TrajectoryBuffer<C>) -> (u64, [u64; MAX_JOINTS]) {
        let mut total = 0;
        let mut peak = [0u64; MAX_JOINTS];
        for i in 0..b.buffered() {
            let p = b.held(i).unwrap();
            total += u64::from(p.duration_us);
            if i > 0 {
                let q = b.held(i - 1).unwrap();
                for ((peak, &to), &from) in peak.iter_mut().zip(&p.position).zip(&q.position) {
                    let steps = (i64::from(to) - i64::from(from)).unsigned_abs();
                    *peak = (*peak).max(steps * 1_000_000 / u64::from(p.duration_us.max(1)));
                }
            }
        }
        (total, peak)
    }

    /// Issue 32's cost guard: the duration sum equals the full scan after every push and
    /// finish, the peak rates are never below the full scan's and equal to it right after
    /// a rescan, and the rescans visit at most one point per point finished (amortised
    /// O(1) per segment, where the scan was O(points held)).
    #[test]
    fn summaries_match_the_full_scan_at_amortised_constant_cost() {
        let mut b = TrajectoryBuffer::<64>::new(50);
        let mut seed = 0x2545_f491_4f6c_dd1du64;
        let mut next = move || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            seed
        };
        let (mut position, mut finished, mut exact_checks) = ([0i32; MAX_JOINTS], 0u64, 0);
        for _ in 0..20_000 {
            let r = next();
            if r % 3 != 0 {
                let d = 1 + (next() % 5_000) as u32;
                for (j, p) in position.iter_mut().enumerate() {
                    *p += i32::try_from(next() % (50 + 40 * j as u64)).unwrap() - 20;
                }
                b.push(StoredPoint {
                    duration_us: d,
                    position,
                });
                while b.next_unfed().is_some() && next() % 2 == 0 {
                    b.mark_fed();
                }
            } else {
                let scanned = b.scanned();
                finished += b.finish((next() % 6) as usize) as u64;
                let (_, exact) = full_scan(&b);
                if b.scanned() != scanned || b.buffered() == 0 {
                    assert_eq!(b.peak_rates(), exact, "exact after a rescan");
                    exact_checks += 1;
                }
            }
            let (total, exact) = full_scan(&b);
            assert_eq!(b.duration_sum_us(), total);
            for (j, (&peak, &exact)) in b.peak_rates().iter().zip(&exact).enumerate() {
                assert!(peak >= exact, "joint {j}: never below the scan");
            }
            assert!(
                b.scanned() <= finished,
                "{} visited for {finished} finished",
                b.scanned()
            );
        }
        assert!(
            exact_checks > 100 && finished > 1_000,
            "{exact_checks} {finished}"
        );
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
