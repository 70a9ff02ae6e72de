//! [`PulseProducer::fill`]: a joint's next timer periods, walking the segment queue, with
//! its fast path `cruise`, per-segment setup and the idle-joint shortcut. The step path's
//! hot part: scripts/step-cost counts its instructions.

use super::{FAST_LIMIT, Filled, PulsePeriod, PulseProducer};
use crate::MAX_JOINTS;
use crate::ring::{SegmentRing, Slot};

impl<const QUEUE: usize> PulseProducer<QUEUE> {
    /// Writes joint `joint`'s next `periods.len()` periods. `signs` (same length) gets the
    /// direction of the pulses from each marked period on: +1 or -1 where the writer marks
    /// one, 0 elsewhere; a pulse period with no mark has the sign of the last mark before
    /// it in the slice, and the first pulse period of a fill is always marked
    /// ([`crate::sign_of`] reads it back); `signs` must be all 0 when passed. DIR changes go to
    /// `on_dir(tick, positive)` in order.
    /// Always fills the whole slice (idle periods when the joint has nothing queued); an
    /// idle producer writes idle periods from where it stopped.
    #[allow(
        clippy::indexing_slicing,
        clippy::cast_possible_truncation,
        reason = "j is masked to 0..MAX_JOINTS, the length of joints and max_period; k < len, the slices' length; periods written in one fill are a buffer half's at most"
    )]
    pub fn fill(
        &mut self,
        joint: usize,
        periods: &mut [PulsePeriod],
        signs: &mut [i8],
        on_dir: &mut impl FnMut(u64, bool),
    ) -> Filled {
        let len = periods.len().min(signs.len());
        let periods = &mut periods[..len];
        let signs = &mut signs[..len];
        let j = joint & (MAX_JOINTS - 1);
        if self.joints[j].cruising && self.joints[j].remaining as usize >= len {
            // The common case: a whole buffer half of on-time pulses of one segment.
            let written = self.cruise(j, periods, signs);
            let s = &self.joints[j];
            return Filled {
                pulses: written as u32,
                last_sign: if written > 0 { s.sign } else { 0 },
                end_tick: s.cursor,
                ..Filled::default()
            };
        }
        // Anything but a straight cruise may change what cruising relies on.
        self.joints[j].cruising = false;
        let max = self.max_period[j];
        let mut filled = Filled::default();
        let mut k = 0;
        let mut pulses = 0u32;
        let mut last_sign = 0i8;
        let mut walked = false;
        while k < len {
            let s = &mut self.joints[j];
            if s.next_rise == u64::MAX {
                if s.remaining > 0 || s.parked != u64::MAX {
                    if s.fast
                        && !s.warped
                        && s.open_delta == s.sign
                        && s.earliest <= s.base + u64::from(s.ideal)
                        && s.whole >= self.min_period
                        && s.whole < max
                        && s.base + u64::from(s.ideal) - s.cursor <= u64::from(max)
                    {
                        let written = self.cruise(j, &mut periods[k..], &mut signs[k..]);
                        k += written;
                        pulses += written as u32;
                        if written > 0 {
                            last_sign = self.joints[j].sign;
                        }
                        continue;
                    }
                    s.cruising = false;
                    // Trajectory time: the warp says when it comes.
                    let taken = if s.parked != u64::MAX {
                        core::mem::replace(&mut s.parked, u64::MAX)
                    } else {
                        s.take_ideal()
                    };
                    let ideal = if s.warped {
                        self.warp.warped_tick(taken)
                    } else {
                        taken
                    };
                    if ideal == u64::MAX {
                        // Held for good under this warp: not committed. Short fillers
                        // meanwhile, so that a change (a RESUME) is taken soon after.
                        s.parked = taken;
                        let idle = max.min(self.idle_short);
                        let (written, sign) =
                            Self::close_with_fillers(s, idle, &mut periods[k..], &mut signs[k..]);
                        pulses += written;
                        last_sign = sign;
                        k = len;
                        continue;
                    }
                    let rise = if s.earliest > ideal {
                        self.late_pulses = self.late_pulses.wrapping_add(1);
                        s.earliest
                    } else {
                        ideal
                    };
                    s.next_rise = rise;
                    continue;
                }
                if self.running && !s.waiting {
                    self.seek(j, on_dir);
                    walked = true;
                    continue;
                }
                if self.running && self.held(j) {
                    // More was pushed while the joint waited: go on from here.
                    let s = &mut self.joints[j];
                    s.waiting = false;
                    s.seek_at = s.seek_at.max(s.cursor);
                    s.earliest = s.earliest.max(s.cursor);
                    continue;
                }
                // Waiting while the run may still get segments: short idle periods, so that
                // a segment pushed later is picked up at most two buffer halves of them after
                // the push; their halves are all alike, so refills skip rewriting them
                // (`idle_period`). Idle, no run: the longest span the timer makes. Either way
                // the open period is closed after one idle span.
                let idle = if self.running {
                    max.min(self.idle_short)
                } else {
                    max
                };
                let s = &mut self.joints[j];
                let rest = periods.get_mut(k..).unwrap_or_default();
                rest.fill(PulsePeriod {
                    reload: idle - 1,
                    repetition: 0,
                    high: 0,
                });
                if let Some(first) = rest.first_mut() {
                    first.high = s.open_high;
                }
                if let Some(sign) = signs.get_mut(k) {
                    *sign = s.open_delta;
                }
                filled.uniform_idle = (k == 0 && s.open_high == 0).then_some(idle);
                last_sign = if len - k >= 2 { 0 } else { s.open_delta };
                s.position = s.position.wrapping_add(i32::from(s.open_delta));
                pulses += u32::from(s.open_delta != 0);
                s.cursor += u64::from(idle) * (len - k) as u64;
                s.open_high = 0;
                s.open_delta = 0;
                filled.idle = true;
                k = len;
                continue;
            }
            // Close the open period at `next_rise`, in pieces if the timer cannot count
            // that far.
            let gap = s.next_rise - s.cursor;
            if gap == 0 {
                // A pulse right at the start of an open filler: it becomes a pulse period.
                s.open_high = self.pulse_ticks;
                s.open_delta = s.sign;
                s.earliest = s.next_rise + u64::from(self.min_period);
                s.seek_at = s.next_rise + u64::from(self.pulse_ticks);
                s.next_rise = u64::MAX;
                continue;
            }
            let take = if gap <= u64::from(max) {
                gap
            } else if gap > 2 * u64::from(max) {
                u64::from(max)
            } else {
                gap / 2
            };
            if let (Some(period), Some(sign)) = (periods.get_mut(k), signs.get_mut(k)) {
                *period = PulsePeriod {
                    reload: (take - 1) as u32,
                    repetition: 0,
                    high: s.open_high,
                };
                *sign = s.open_delta;
            }
            s.position = s.position.wrapping_add(i32::from(s.open_delta));
            pulses += u32::from(s.open_delta != 0);
            last_sign = s.open_delta;
            k += 1;
            s.cursor += take;
            if take == gap {
                s.open_high = self.pulse_ticks;
                s.open_delta = s.sign;
                s.earliest = s.next_rise + u64::from(self.min_period);
                s.seek_at = s.next_rise + u64::from(self.pulse_ticks);
                s.next_rise = u64::MAX;
            } else {
                s.open_high = 0;
                s.open_delta = 0;
            }
        }
        let s = &self.joints[j];
        filled.pulses = pulses;
        filled.last_sign = last_sign;
        filled.end_tick = s.cursor;
        filled.idle &= s.waiting || !self.running;
        if walked {
            filled.segments_finished = self.pop_finished();
        }
        filled
    }

    /// Closes joint `s`'s open period and fills `periods` with fillers of `idle` ticks (a
    /// joint whose next pulse the warp holds back); returns the pulses written (the open
    /// one, if any) and the sign of the last period.
    #[cold]
    #[inline(never)]
    fn close_with_fillers(
        s: &mut super::JointStream,
        idle: u32,
        periods: &mut [PulsePeriod],
        signs: &mut [i8],
    ) -> (u32, i8) {
        periods.fill(PulsePeriod {
            reload: idle - 1,
            repetition: 0,
            high: 0,
        });
        if let Some(first) = periods.first_mut() {
            first.high = s.open_high;
        }
        if let Some(sign) = signs.first_mut() {
            *sign = s.open_delta;
        }
        let last_sign = if periods.len() >= 2 { 0 } else { s.open_delta };
        let pulses = u32::from(s.open_delta != 0);
        s.position = s.position.wrapping_add(i32::from(s.open_delta));
        s.cursor += u64::from(idle) * periods.len() as u64;
        s.open_high = 0;
        s.open_delta = 0;
        (pulses, last_sign)
    }

    /// The u32 inner loop for pulses that are all on time: the open period is one of this
    /// segment's pulses, the next pulse is on time, pulses are at least `min_period` apart
    /// (so every later one is on time too) and every gap fits the timer. Each period is
    /// then `whole` ticks plus the carry of the fraction: no comparison with `earliest`,
    /// no late pulse, no split. Returns the periods written.
    #[inline(always)]
    #[allow(
        clippy::indexing_slicing,
        clippy::cast_possible_truncation,
        reason = "j < MAX_JOINTS (masked by the caller); count <= periods.len(); the first gap was checked to fit the timer, ticks relative to base fit the u32 clock (FAST_LIMIT), count is a buffer half's periods at most"
    )]
    fn cruise(&mut self, j: usize, periods: &mut [PulsePeriod], signs: &mut [i8]) -> usize {
        let high = self.pulse_ticks;
        let s = &mut self.joints[j];
        let count = (s.remaining as usize).min(periods.len());
        let (whole_m1, fraction, modulus) = (s.whole - 1, s.fraction, s.modulus);
        let mut remainder = s.remainder;
        // Ticks from the open period's start to the next pulse (checked: fits the timer).
        let first = (s.base + u64::from(s.ideal) - s.cursor) as u32;
        let mut reload = first - 1;
        // Sum of the reloads written (the span is that plus one tick per period).
        let mut reloads = 0u32;
        for period in &mut periods[..count] {
            period.high = high;
            period.reload = reload;
            reloads += reload;
            remainder += fraction;
            reload = whole_m1;
            if remainder >= modulus {
                remainder -= modulus;
                reload += 1;
            }
        }
        let span = reloads + count as u32;
        if let Some(sign) = signs.first_mut() {
            *sign = s.sign;
        }
        s.cruising = s.remaining as usize > count;
        // `count` pulses rose; the last one's period is open. `reload + 1` is the gap
        // from it to the pulse after.
        let cursor = s.cursor + u64::from(span);
        s.cursor = cursor;
        s.ideal = (cursor - s.base) as u32 + reload + 1;
        s.remainder = remainder;
        s.remaining -= count as u32;
        s.position = s.position.wrapping_add(i32::from(s.sign) * count as i32);
        s.earliest = cursor + u64::from(self.min_period);
        s.seek_at = cursor + u64::from(high);
        count
    }

    /// Whether the next fill of `len` periods for joint `joint` is one straight cruise:
    /// on-time pulses of one segment, which mark only the first period's sign.
    #[allow(
        clippy::indexing_slicing,
        reason = "the joint number is masked to 0..MAX_JOINTS"
    )]
    pub fn will_cruise(&self, joint: usize, len: usize) -> bool {
        let s = &self.joints[joint & (MAX_JOINTS - 1)];
        s.cruising && s.remaining as usize >= len
    }

    /// The idle period joint `joint` would write next, if all its next periods are the
    /// same idle one: nothing queued for it, no pulse open, and no run (the timer's longest
    /// period) or waiting in a run (the short one).
    #[allow(
        clippy::indexing_slicing,
        reason = "the joint number is masked to 0..MAX_JOINTS"
    )]
    pub fn idle_period(&self, joint: usize) -> Option<u32> {
        let j = joint & (MAX_JOINTS - 1);
        let s = &self.joints[j];
        let quiet = s.remaining == 0 && s.next_rise == u64::MAX && s.open_high == 0;
        if !quiet {
            return None;
        }
        let max = self.max_period[j];
        if !self.running {
            return Some(max);
        }
        (s.waiting && !self.held(j)).then_some(max.min(self.idle_short))
    }

    /// Moves joint `joint`'s stream `count` periods of `period` ticks on without writing
    /// them: the buffer half already holds them (`period` from
    /// [`PulseProducer::idle_period`]).
    #[allow(
        clippy::indexing_slicing,
        reason = "the joint number is masked to 0..MAX_JOINTS"
    )]
    pub fn skip_idle(&mut self, joint: usize, count: usize, period: u32) {
        let j = joint & (MAX_JOINTS - 1);
        self.joints[j].cursor += u64::from(period) * count as u64;
    }

    /// Whether joint `j` waits for a segment that is now queued.
    #[allow(
        clippy::indexing_slicing,
        reason = "j < MAX_JOINTS (masked by the callers)"
    )]
    fn held(&self, j: usize) -> bool {
        let s = &self.joints[j];
        s.ordinal.wrapping_sub(self.head_ordinal)
            < u32::try_from(self.ring.len()).unwrap_or(u32::MAX)
    }

    /// Moves joint `j` (done with its current segment's pulses) to the next segment where
    /// it moves, setting DIR and its pulse clock there, or marks it waiting (slots are
    /// popped by `pop_finished`).
    #[allow(
        clippy::indexing_slicing,
        reason = "j < MAX_JOINTS (masked by the callers)"
    )]
    fn seek(&mut self, j: usize, on_dir: &mut impl FnMut(u64, bool)) {
        let bit = 1 << j;
        let at = self.joints[j].seek_at;
        loop {
            if !self.held(j) {
                let s = &mut self.joints[j];
                s.waiting = true;
                return;
            }
            let s = &mut self.joints[j];
            let Some(slot) = self.ring.get_mut(s.slot) else {
                s.waiting = true;
                return;
            };
            let steps = slot.steps.get(j).copied().unwrap_or(0);
            let slot = *slot;
            // Done with this slot once its pulses are set up (they are all computed from
            // the joint's own clock from here on).
            if let Some(held) = self.ring.get_mut(s.slot) {
                held.pending &= !bit;
            }
            s.ordinal = s.ordinal.wrapping_add(1);
            s.slot = SegmentRing::<QUEUE>::next_index(s.slot);
            if steps == 0 {
                continue;
            }
            let positive = steps > 0;
            if s.direction != Some(positive) {
                on_dir(at, positive);
                s.direction = Some(positive);
                s.earliest = s.earliest.max(at + self.setup_ticks);
            }
            // The oracle's `seek` happens at `at`: nothing rises before the walk.
            self.begin_segment(j, &slot, steps);
            return;
        }
    }

    /// Sets up joint `j`'s pulse clock for `steps` (non-zero) pulses in `slot`: one
    /// division.
    #[allow(
        clippy::indexing_slicing,
        clippy::cast_possible_truncation,
        reason = "j < MAX_JOINTS (masked by the callers); u32 casts only where checked to fit (travel and modulus <= u32::MAX; the fast clock's values < FAST_LIMIT = 2^31)"
    )]
    fn begin_segment(&mut self, j: usize, slot: &Slot, steps: i32) {
        let n = u64::from(steps.unsigned_abs());
        let base = self.origin + slot.start_tick;
        // Reduced by g = gcd(tick_hz, 1e6): travel = duration * tick_hz / g, modulus =
        // n * 1e6 / g, start remainder = (frac / g) * n (frac is a multiple of g).
        let travel = u64::from(slot.duration_us) * self.tick_scale;
        let modulus = n * self.us_scale;
        let start_remainder = u64::from(slot.start_frac / self.gcd) * n;
        let (whole, fraction) = if travel <= u64::from(u32::MAX) && modulus <= u64::from(u32::MAX) {
            let (t, m) = (travel as u32, modulus as u32);
            (u64::from(t / m), u64::from(t % m))
        } else {
            (travel / modulus, travel % modulus)
        };
        let s = &mut self.joints[j];
        s.cruising = false;
        s.remaining = steps.unsigned_abs();
        s.sign = if steps > 0 { 1 } else { -1 };
        s.base = base;
        // First pulse: base + whole + carry of (start_remainder + fraction).
        let mut remainder = start_remainder + fraction;
        let mut first = whole;
        if remainder >= modulus {
            remainder -= modulus;
            first += 1;
        }
        let span = slot.end_tick - slot.start_tick + 1;
        let earliest_rel = s.earliest.saturating_sub(base);
        let bound = 2 * span + earliest_rel + (n + 1) * u64::from(self.min_period);
        // remainder + fraction < 2 * modulus must not wrap either.
        s.fast = modulus < FAST_LIMIT && bound < FAST_LIMIT;
        if s.fast {
            s.ideal = first as u32;
            s.whole = whole as u32;
            s.fraction = fraction as u32;
            s.remainder = remainder as u32;
            s.modulus = modulus as u32;
        } else {
            s.wide_ideal = base + first;
            s.wide_whole = whole;
            s.wide_fraction = fraction;
            s.wide_remainder = remainder;
            s.wide_modulus = modulus;
        }
    }

    /// Drops the queue's oldest slots that every joint has gone through.
    fn pop_finished(&mut self) -> u32 {
        let mut finished = 0;
        while let Some(front) = self.ring.front() {
            if front.pending != 0 {
                break;
            }
            self.ring.pop_front();
            self.head_ordinal = self.head_ordinal.wrapping_add(1);
            finished += 1;
        }
        if self.running && self.ring.is_empty() && self.joints.iter().all(|j| j.waiting) {
            // Each waiting joint's `seek_at` is the fall of its last pulse. The run goes
            // on (a push before this tick continues it); the owner ends it here.
            let last_fall = self.joints.iter().map(|j| j.seek_at).max().unwrap_or(0);
            let end = self.warp.controller_tick(self.origin + self.queue_end.tick);
            self.run_end = end.max(last_fall);
        }
        finished
    }
}
