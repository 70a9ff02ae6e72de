//! A joint's position over time, kept in at most [`TRACK_BUCKETS`] time buckets (minimum,
//! maximum and last position each) however long the trace is.

/// Time buckets a [`Track`] keeps at most: about one per pixel column of the plot (its
/// plot area is 760 px wide), so that a trace of any length draws as a small SVG.
pub const TRACK_BUCKETS: u64 = 1024;

/// One time bucket of a [`Track`]: what the position did between `first_tick` and
/// `last_tick` (the times of its first and last step).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Bucket {
    /// Index of the bucket: it covers ticks `index * width ..  (index + 1) * width`.
    pub index: u64,
    /// Time of the first step in the bucket, ticks.
    pub first_tick: u64,
    /// Time of the last step in the bucket, ticks.
    pub last_tick: u64,
    /// Position before the first step.
    pub enter: i64,
    /// Lowest position in the bucket.
    pub min: i64,
    /// Highest position in the bucket.
    pub max: i64,
    /// Position after the last step.
    pub last: i64,
}

/// A joint's position over time, reduced to at most [`TRACK_BUCKETS`] buckets. Buckets
/// with no step are not stored: the position is flat there.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Track {
    /// Ticks per bucket (a power of two).
    pub width: u64,
    /// Buckets with at least one step, in time order.
    pub buckets: Vec<Bucket>,
}

impl Default for Track {
    fn default() -> Track {
        Track {
            width: 1,
            buckets: Vec::new(),
        }
    }
}

impl Track {
    /// Records a step at `tick` from `before` to `after`. Ticks never decrease.
    pub(super) fn step(&mut self, tick: u64, before: i64, after: i64) {
        while tick / self.width >= TRACK_BUCKETS {
            self.coarsen();
        }
        let index = tick / self.width;
        match self.buckets.last_mut() {
            Some(bucket) if bucket.index == index => {
                bucket.last_tick = tick;
                bucket.min = bucket.min.min(after);
                bucket.max = bucket.max.max(after);
                bucket.last = after;
            }
            _ => self.buckets.push(Bucket {
                index,
                first_tick: tick,
                last_tick: tick,
                enter: before,
                min: before.min(after),
                max: before.max(after),
                last: after,
            }),
        }
    }

    /// Doubles the bucket width, merging neighbours.
    fn coarsen(&mut self) {
        self.width = self.width.saturating_mul(2);
        let mut merged: Vec<Bucket> = Vec::with_capacity(self.buckets.len());
        for mut bucket in self.buckets.drain(..) {
            bucket.index /= 2;
            match merged.last_mut() {
                Some(previous) if previous.index == bucket.index => {
                    previous.last_tick = bucket.last_tick;
                    previous.min = previous.min.min(bucket.min);
                    previous.max = previous.max.max(bucket.max);
                    previous.last = bucket.last;
                }
                _ => merged.push(bucket),
            }
        }
        self.buckets = merged;
    }

    /// The polyline that draws the track from tick 0 (position 0) to `end_tick`:
    /// `(tick, position)` corners, no two alike in a row. Within a bucket the line goes
    /// from the entering position through the extremes to the last one.
    pub fn points(&self, end_tick: u64) -> Vec<(u64, i64)> {
        let mut points = vec![(0, 0)];
        let mut push = |point: (u64, i64)| {
            if points.last() != Some(&point) {
                points.push(point);
            }
        };
        let mut position = 0;
        for bucket in &self.buckets {
            push((bucket.first_tick, bucket.enter));
            let middle = bucket.first_tick + (bucket.last_tick - bucket.first_tick) / 2;
            let (low, high) = (bucket.enter.min(bucket.last), bucket.enter.max(bucket.last));
            // Extremes beyond the ends: a move and back inside one bucket.
            if bucket.enter <= bucket.last {
                if bucket.min < low {
                    push((middle, bucket.min));
                }
                if bucket.max > high {
                    push((middle, bucket.max));
                }
            } else {
                if bucket.max > high {
                    push((middle, bucket.max));
                }
                if bucket.min < low {
                    push((middle, bucket.min));
                }
            }
            push((bucket.last_tick, bucket.last));
            position = bucket.last;
        }
        let last_tick = self.buckets.last().map_or(0, |b| b.last_tick);
        push((end_tick.max(last_tick), position));
        points
    }
}
