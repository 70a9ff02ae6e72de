//! [`PulseProducer`]: the step timing of [`crate::StepEngine`], computed ahead of time as
//! timer periods for a DMA stream instead of edges made by an interrupt.
//!
//! Each joint's STEP line is a timer in PWM mode whose period and duty are reloaded by DMA
//! at every update event from a buffer of [`PulsePeriod`]s: a period that starts with a
//! pulse (`high` = pulse width) or without one (`high` = 0, a filler). Rising edges are the
//! starts of pulse periods, so the hardware places every edge; the CPU only fills buffer
//! halves as the stream frees them ([`PulseProducer::fill`]).
//!
//! The timing is the engine's rule, edge for edge (the property test `producer_matches_engine`
//! compares them on more than 10 million pulses): pulse `i` of a segment of `D` ticks and
//! `N` steps rises at `start + floor(i * D / N)`; after a pulse, STEP stays low at least
//! [`StepTiming::low_ticks`]; a DIR change happens when the joint's previous pulse falls
//! (or at the run's start) and the next pulse rises no sooner than `dir_setup_ticks` after
//! it; a pulse that cannot rise at its ideal tick rises at the earliest allowed one and is
//! counted late, never dropped. DIR changes are handed to a callback with their tick: the
//! board makes them with a compare interrupt (one per reversal, never one per step).
//!
//! Per joint and segment, one division sets up the pulse clock (whole ticks per pulse, the
//! fraction and its modulus, reduced by `gcd(tick_hz, 1e6)`); per pulse it only adds.
//! While the segment's ticks and the modulus fit in 31 bits (at whole-MHz tick rates:
//! segments up to 5 s at 200 MHz) the pulses are computed in u32 relative to the segment's
//! start; otherwise a u64 path does the same arithmetic.
//!
//! Gaps longer than a joint's timer can count (`max_period_ticks`: 2^16 for 16-bit timers)
//! are split into filler periods of at least half that length, so a 16-bit timer needs no
//! more CPU at low step rates than it can afford. A joint with nothing queued fills its
//! buffer with idle periods as long as its timer counts, so an idle joint costs a refill
//! every `HALF * 2^16` ticks at most. The run is over at [`PulseProducer::run_end_tick`],
//! known once every pulse is written: the owner stops the streams at that tick.

use crate::engine::QueueEnd;
use crate::ring::{SegmentRing, Slot};
use crate::{JointMask, MAX_JOINTS, Segment, StepTiming};

/// Microseconds per second: segment durations are in microseconds.
const US_PER_S: u64 = 1_000_000;

/// Every joint.
const ALL_JOINTS: JointMask = 0xFF;

/// Relative ticks of the u32 pulse clock stay below this, so that sums of two never wrap.
const FAST_LIMIT: u64 = 1 << 31;

/// One timer period of a joint's STEP output, laid out for the timer's DMA burst
/// (ARR, RCR, CCR1: `DCR.DBA` = ARR, three transfers per update).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PulsePeriod {
    /// Period length in ticks, minus one (ARR).
    pub reload: u32,
    /// Always 0 (RCR: one period per update event; a reserved word on timers that have no
    /// repetition counter).
    pub repetition: u32,
    /// STEP high time from the period's start, ticks (CCR1 in PWM mode 1); 0: no pulse.
    pub high: u32,
}

/// The sign of each pulse in `periods` as [`PulseProducer::fill`] marked them in `signs`
/// (0 for periods without a pulse), starting from `sign` for pulses before the first mark.
pub fn sign_of(periods: &[PulsePeriod], signs: &[i8], mut sign: i8) -> impl Iterator<Item = i8> {
    periods.iter().zip(signs).map(move |(period, &mark)| {
        if mark != 0 {
            sign = mark;
        }
        if period.high != 0 { sign } else { 0 }
    })
}

impl PulsePeriod {
    /// A zeroed period (one tick, no pulse): what a buffer holds before its first fill.
    pub const ZERO: PulsePeriod = PulsePeriod {
        reload: 0,
        repetition: 0,
        high: 0,
    };

    /// Length in ticks.
    pub const fn ticks(&self) -> u64 {
        self.reload as u64 + 1
    }
}

/// What one [`PulseProducer::fill`] wrote.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Filled {
    /// Pulses written (periods with `high > 0`).
    pub pulses: u32,
    /// Position change of the last period written (its pulse's sign, 0 for none): what
    /// a stop must take back if that period never started after its buffer half was
    /// refilled over (`StepStreams` keeps it).
    pub last_sign: i8,
    /// Segments every joint has now been through (their slots are free).
    pub segments_finished: u32,
    /// Tick at which the written periods end (where the next fill continues).
    pub end_tick: u64,
    /// Whether the joint has nothing left to do in the queued segments: the written periods
    /// after its last pulse are idle fillers.
    pub idle: bool,
    /// Every period written is the same idle period, of this many ticks: a buffer half
    /// that holds these needs no rewrite while the joint would write the same
    /// ([`PulseProducer::idle_period`], [`PulseProducer::skip_idle`]).
    pub uniform_idle: Option<u32>,
}

/// One joint's stream: its walk through the queue, its pulse clock, and the open period
/// (started at `cursor`, not written yet because its end is not known).
#[derive(Clone, Copy, Debug)]
struct JointStream {
    /// Ordinal (wrapping) of the segment this joint works on or waits for.
    ordinal: u32,
    /// Ring index of that segment.
    slot: usize,
    /// Walked past every queued segment: writes idle fillers until more are pushed.
    waiting: bool,
    /// The last `cruise` stopped at the end of the buffer with pulses left, so the next
    /// fill can go straight on cruising (its conditions still hold).
    cruising: bool,
    /// Pulses still to compute in the current segment.
    remaining: u32,
    /// u32 clock usable (modulus and the segment's relative ticks fit).
    fast: bool,
    /// Tick the u32 clock counts from (floor of the segment's start).
    base: u64,
    /// u32 clock: next pulse's ideal tick relative to `base`, whole ticks per pulse,
    /// fraction, remainder, modulus.
    ideal: u32,
    whole: u32,
    fraction: u32,
    remainder: u32,
    modulus: u32,
    /// u64 clock (absolute ideal tick), used when the u32 one does not fit.
    wide_ideal: u64,
    wide_whole: u64,
    wide_fraction: u64,
    wide_remainder: u64,
    wide_modulus: u64,
    /// -1 or +1.
    sign: i8,
    /// Steps, counted per pulse written.
    position: i32,
    /// DIR level last handed out (`None`: never since boot).
    direction: Option<bool>,
    /// No rising edge before this tick.
    earliest: u64,
    /// Start of the open period.
    cursor: u64,
    /// `high` of the open period (pulse width, or 0 for a filler).
    open_high: u32,
    /// Position change of the open period (its pulse's sign, 0 for a filler).
    open_delta: i8,
    /// Rising edge that ends the open period, once computed (`u64::MAX`: not yet).
    next_rise: u64,
    /// When the joint moves on to its next segment: the fall of its last pulse, or the
    /// run's start.
    seek_at: u64,
}

impl JointStream {
    const IDLE: JointStream = JointStream {
        ordinal: 0,
        slot: 0,
        waiting: true,
        cruising: false,
        remaining: 0,
        fast: false,
        base: 0,
        ideal: 0,
        whole: 0,
        fraction: 0,
        remainder: 0,
        modulus: 1,
        wide_ideal: 0,
        wide_whole: 0,
        wide_fraction: 0,
        wide_remainder: 0,
        wide_modulus: 1,
        sign: 1,
        position: 0,
        direction: None,
        earliest: 0,
        cursor: 0,
        open_high: 0,
        open_delta: 0,
        next_rise: u64::MAX,
        seek_at: 0,
    };

    /// Ideal tick of the next pulse (absolute), advancing the clock past it.
    #[inline]
    fn take_ideal(&mut self) -> u64 {
        self.remaining -= 1;
        if self.fast {
            let ideal = self.base + u64::from(self.ideal);
            self.ideal += self.whole;
            self.remainder += self.fraction;
            if self.remainder >= self.modulus {
                self.remainder -= self.modulus;
                self.ideal += 1;
            }
            ideal
        } else {
            let ideal = self.wide_ideal;
            self.wide_ideal += self.wide_whole;
            self.wide_remainder += self.wide_fraction;
            if self.wide_remainder >= self.wide_modulus {
                self.wide_remainder -= self.wide_modulus;
                self.wide_ideal += 1;
            }
            ideal
        }
    }
}

/// The pulse-time producer. `QUEUE` = segments held, as [`crate::StepEngine`].
///
/// Not shared: the owner serialises `push`/`start`/`stop` with the refills (a critical
/// section around each call, or one owner).
#[derive(Debug)]
pub struct PulseProducer<const QUEUE: usize> {
    timing: StepTiming,
    pulse_ticks: u32,
    /// Pulse width plus the least low time: the closest two pulses of one joint may be.
    min_period: u32,
    setup_ticks: u64,
    tick_hz: u64,
    /// `tick_hz / gcd(tick_hz, 1e6)` and `1e6 / gcd`: the pulse clock's reduced units.
    tick_scale: u64,
    us_scale: u64,
    /// `gcd(tick_hz, 1e6)`.
    gcd: u32,
    /// Idle period of a joint that waits for segments while its run goes on: 100 us (at
    /// least two pulse periods). Two buffer halves of them (12.8 ms with 64-period
    /// halves) is how far such a joint commits ahead; the step task keeps the queue far
    /// more ahead (64 segments), so a segment pushed in time is never late for it.
    idle_short: u32,
    /// Longest period each joint's timer can make.
    max_period: [u32; MAX_JOINTS],
    ring: SegmentRing<QUEUE>,
    head_ordinal: u32,
    queue_end: QueueEnd,
    running: bool,
    origin: u64,
    /// Where the last run ends (its last segment's end, or its last pulse's fall if
    /// later), once every pulse of it is written; `u64::MAX` before.
    run_end: u64,
    joints: [JointStream; MAX_JOINTS],
    late_pulses: u32,
}

const fn gcd(mut a: u64, mut b: u64) -> u64 {
    while b != 0 {
        let r = a % b;
        a = b;
        b = r;
    }
    a
}

impl<const QUEUE: usize> PulseProducer<QUEUE> {
    /// An idle producer; `max_period_ticks[j]` is the longest period joint `j`'s timer can
    /// make (2^16 for a 16-bit timer; at least `2 * min_pulse_period_ticks`).
    pub const fn new(timing: StepTiming, max_period_ticks: [u32; MAX_JOINTS]) -> Self {
        let g = gcd(timing.tick_hz as u64, US_PER_S);
        let g = if g == 0 { 1 } else { g };
        let min_period = timing.pulse_ticks().saturating_add(timing.low_ticks());
        let mut max_period = max_period_ticks;
        let mut j = 0;
        while j < MAX_JOINTS {
            // Splitting needs room for two pulse periods; 2 ticks at least.
            let floor = if min_period < 2 {
                4
            } else {
                min_period.saturating_mul(2)
            };
            if max_period[j] < floor {
                max_period[j] = floor;
            }
            j += 1;
        }
        Self {
            timing,
            pulse_ticks: timing.pulse_ticks(),
            min_period,
            setup_ticks: timing.dir_setup_ticks as u64,
            tick_hz: timing.tick_hz as u64,
            tick_scale: timing.tick_hz as u64 / g,
            us_scale: US_PER_S / g,
            gcd: g as u32,
            idle_short: {
                let short = timing.tick_hz / 10_000;
                let floor = min_period.saturating_mul(2);
                if short < floor { floor } else { short }
            },
            max_period,
            ring: SegmentRing::new(),
            head_ordinal: 0,
            queue_end: QueueEnd::ZERO,
            running: false,
            origin: 0,
            run_end: u64::MAX,
            joints: [JointStream::IDLE; MAX_JOINTS],
            late_pulses: 0,
        }
    }

    /// The timing this producer was built with.
    pub fn timing(&self) -> StepTiming {
        self.timing
    }

    /// Longest period joint `joint`'s timer makes.
    pub fn max_period_ticks(&self, joint: usize) -> u32 {
        self.max_period.get(joint).copied().unwrap_or(u32::MAX)
    }

    /// Queues a segment behind the others; `Err(segment)` back if `QUEUE` are held.
    pub fn push(&mut self, segment: Segment) -> Result<(), Segment> {
        let start = self.queue_end;
        let end = start.after(segment.duration_us, self.tick_hz);
        let slot = Slot {
            steps: segment.steps,
            duration_us: segment.duration_us,
            start_frac: start.frac,
            start_tick: start.tick,
            end_tick: end.tick,
            pending: ALL_JOINTS,
        };
        if self.ring.push_back(slot).is_err() {
            return Err(segment);
        }
        self.queue_end = end;
        // More to come: the run does not end where it would have.
        self.run_end = u64::MAX;
        Ok(())
    }

    /// Slots free for `push`.
    pub fn free_slots(&self) -> usize {
        QUEUE - self.ring.len()
    }

    /// Segments held (queued, or not yet gone through by every joint).
    pub fn queued(&self) -> usize {
        self.ring.len()
    }

    /// Starts a run: the first queued segment starts at `at_tick`, and every joint's
    /// stream starts at `stream_tick` (`<= at_tick`): the tick the timers start, where
    /// the first DIR levels are set (as the engine sets them at its first `poll`). Ticks
    /// are on the same clock as the previous run's (see [`PulseProducer::start_new_clock`]).
    /// No-op if already running.
    pub fn start(&mut self, at_tick: u64, stream_tick: u64) {
        if self.running {
            return;
        }
        self.running = true;
        self.origin = at_tick;
        self.run_end = u64::MAX;
        let head = self.ring.head_index();
        let ordinal = self.head_ordinal;
        for joint in &mut self.joints {
            joint.ordinal = ordinal;
            joint.slot = head;
            joint.remaining = 0;
            joint.waiting = false;
            joint.cruising = false;
            joint.cursor = stream_tick;
            joint.open_high = 0;
            joint.open_delta = 0;
            joint.next_rise = u64::MAX;
            joint.seek_at = stream_tick;
            // Pulses rise at or after `at_tick >= stream_tick` anyway; this keeps a stale
            // bound from an earlier run from lying before the stream (the least low time
            // after the last run's last pulse still holds, as in the engine).
            joint.earliest = joint.earliest.max(stream_tick);
        }
    }

    /// Starts a run on a new clock (the board restarts its timers at 0 for every run):
    /// `start(at_tick, 0)` with what the previous run required of the next pulse
    /// (the least low time after its last pulse) taken as over, which the caller
    /// guarantees (the board starts runs at least a millisecond after the last ended).
    pub fn start_new_clock(&mut self, at_tick: u64) {
        if self.running {
            return;
        }
        for joint in &mut self.joints {
            joint.earliest = 0;
        }
        self.start(at_tick, 0);
    }

    /// Emergency stop: drops every segment, goes idle. The positions stay those of the
    /// pulses written: the owner corrects them for the periods the hardware did not play
    /// ([`PulseProducer::unwind`]).
    pub fn stop(&mut self) {
        self.ring.clear();
        self.head_ordinal = 0;
        for joint in &mut self.joints {
            joint.remaining = 0;
            joint.waiting = true;
            joint.cruising = false;
            joint.next_rise = u64::MAX;
        }
        self.running = false;
        self.queue_end = QueueEnd::ZERO;
    }

    /// Takes back pulses that were written but never played (after a stop): `steps` is
    /// the signed sum of their position changes.
    pub fn unwind(&mut self, joint: usize, steps: i32) {
        if let Some(j) = self.joints.get_mut(joint) {
            j.position = j.position.wrapping_sub(steps);
        }
    }

    /// Whether a run is under way.
    pub fn is_running(&self) -> bool {
        self.running
    }

    /// Whether every joint has written every pulse of every queued segment (the run is
    /// over once the hardware has played them).
    pub fn drained(&self) -> bool {
        self.ring.is_empty() && self.joints.iter().all(|j| j.waiting)
    }

    /// Where the run ends (the end of its last segment, or its last pulse's fall if later),
    /// once every pulse of the queued segments has been written; `None` while pulses are
    /// still to come. The engine runs dry at the same tick. A segment pushed before the
    /// hardware gets there continues the run (the end is `None` again); otherwise the
    /// owner stops the hardware there and calls [`PulseProducer::end_run`].
    pub fn run_end_tick(&self) -> Option<u64> {
        (self.running && self.run_end != u64::MAX).then_some(self.run_end)
    }

    /// The run is over (its end tick passed with nothing more queued): idle, the next
    /// pushed segment starts a new timeline.
    pub fn end_run(&mut self) {
        self.running = false;
        self.run_end = u64::MAX;
        self.queue_end = QueueEnd::ZERO;
    }

    /// Pulses placed later than their ideal tick (see [`crate::StepEngine::late_pulses`]).
    pub fn late_pulses(&self) -> u32 {
        self.late_pulses
    }

    /// Position of each joint in steps, counted per pulse written.
    pub fn positions(&self) -> [i32; MAX_JOINTS] {
        let mut positions = [0; MAX_JOINTS];
        for (position, joint) in positions.iter_mut().zip(&self.joints) {
            *position = joint.position;
        }
        positions
    }

    /// Overwrites the position counters; refused (false) while running.
    pub fn set_positions(&mut self, positions: [i32; MAX_JOINTS]) -> bool {
        if self.running {
            return false;
        }
        for (joint, position) in self.joints.iter_mut().zip(positions) {
            joint.position = position;
        }
        true
    }

    /// Writes joint `joint`'s next `periods.len()` periods. `signs` (same length) gets the
    /// direction of the pulses from each marked period on: +1 or -1 where the writer marks
    /// one, 0 elsewhere; a pulse period with no mark has the sign of the last mark before
    /// it in the slice, and the first pulse period of a fill is always marked
    /// ([`sign_of`] reads it back); `signs` must be all 0 when passed. DIR changes go to
    /// `on_dir(tick, positive)` in order.
    /// Always fills the whole slice (idle periods when the joint has nothing queued); an
    /// idle producer writes idle periods from where it stopped.
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
                if s.remaining > 0 {
                    if s.fast
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
                    let ideal = s.take_ideal();
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
                if self.running {
                    // Waiting while the run may still get segments: short idle periods, so
                    // that a segment pushed later is picked up at most two buffer halves of
                    // them after the push. Their halves are all alike, so refills skip
                    // rewriting them (`idle_period`).
                    let short = max.min(self.idle_short);
                    let s = &mut self.joints[j];
                    let idle = PulsePeriod {
                        reload: short - 1,
                        repetition: 0,
                        high: 0,
                    };
                    let rest = periods.get_mut(k..).unwrap_or_default();
                    for period in rest.iter_mut() {
                        *period = idle;
                    }
                    if let Some(first) = rest.first_mut() {
                        first.high = s.open_high;
                    }
                    if let Some(sign) = signs.get_mut(k) {
                        *sign = s.open_delta;
                    }
                    filled.uniform_idle = (k == 0 && s.open_high == 0).then_some(short);
                    last_sign = if len - k >= 2 { 0 } else { s.open_delta };
                    s.position = s.position.wrapping_add(i32::from(s.open_delta));
                    pulses += u32::from(s.open_delta != 0);
                    s.cursor += u64::from(short) * (len - k) as u64;
                    s.open_high = 0;
                    s.open_delta = 0;
                    filled.idle = true;
                    k = len;
                    continue;
                }
                // Idle, no run: close the open period after the longest span the timer
                // makes, then idle periods.
                let idle = max;
                let s = &mut self.joints[j];
                let mut period = PulsePeriod {
                    reload: idle - 1,
                    repetition: 0,
                    high: s.open_high,
                };
                if let (Some(first), Some(sign)) = (periods.get_mut(k), signs.get_mut(k)) {
                    *first = period;
                    *sign = s.open_delta;
                }
                filled.uniform_idle = (k == 0 && s.open_high == 0).then_some(max);
                last_sign = if len - k >= 2 { 0 } else { s.open_delta };
                s.position = s.position.wrapping_add(i32::from(s.open_delta));
                pulses += u32::from(s.open_delta != 0);
                period.high = 0;
                for rest in periods.get_mut(k + 1..).unwrap_or_default() {
                    *rest = period;
                }
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

    /// The u32 inner loop for pulses that are all on time: the open period is one of this
    /// segment's pulses, the next pulse is on time, pulses are at least `min_period` apart
    /// (so every later one is on time too) and every gap fits the timer. Each period is
    /// then `whole` ticks plus the carry of the fraction: no comparison with `earliest`,
    /// no late pulse, no split. Returns the periods written.
    #[inline(always)]
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
    pub fn will_cruise(&self, joint: usize, len: usize) -> bool {
        let s = &self.joints[joint & (MAX_JOINTS - 1)];
        s.cruising && s.remaining as usize >= len
    }

    /// The idle period joint `joint` would write next, if all its next periods are the
    /// same idle one: nothing queued for it, no pulse open, and no run (the timer's longest
    /// period) or waiting in a run (the short one).
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
    pub fn skip_idle(&mut self, joint: usize, count: usize, period: u32) {
        let j = joint & (MAX_JOINTS - 1);
        self.joints[j].cursor += u64::from(period) * count as u64;
    }

    /// Whether joint `j` waits for a segment that is now queued.
    fn held(&self, j: usize) -> bool {
        let s = &self.joints[j];
        s.ordinal.wrapping_sub(self.head_ordinal) < self.ring.len() as u32
    }

    /// Moves joint `j` (done with its current segment's pulses) to the next segment where
    /// it moves, setting DIR and its pulse clock there, or marks it waiting (slots are
    /// popped by `pop_finished`).
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
            self.run_end = (self.origin + self.queue_end.tick).max(last_fall);
        }
        finished
    }
}
