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
use crate::ring::SegmentRing;
use crate::{MAX_JOINTS, Segment, StepTiming, US_PER_S, Warp, WarpError, write_each};

mod fill;
mod joint_stream;
mod period;

use joint_stream::JointStream;
pub use period::{Filled, PulsePeriod, sign_of};

/// Relative ticks of the u32 pulse clock stay below this, so that sums of two never wrap.
const FAST_LIMIT: u64 = 1 << 31;

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
    /// halves) is how far such a joint commits ahead; the trajectory task keeps the queue far
    /// more ahead (the board profile's `lookahead_us`, 50-100 ms), so a segment pushed in time is never
    /// late for it.
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
    /// Trajectory time to controller time, as [`crate::StepEngine`]'s: each pulse's ideal
    /// tick and the run's end go through it; the cruise fast path only runs unwarped.
    warp: Warp,
}

const fn gcd(mut a: u64, mut b: u64) -> u64 {
    while b != 0 {
        let r = a % b;
        a = b;
        b = r;
    }
    a
}

/// `max_period_ticks` raised where needed: splitting a gap needs room for two pulse
/// periods (4 ticks at least).
#[allow(clippy::indexing_slicing, reason = "j < MAX_JOINTS, the loop's bound")]
const fn max_periods(min_period: u32, max_period_ticks: [u32; MAX_JOINTS]) -> [u32; MAX_JOINTS] {
    let mut max_period = max_period_ticks;
    let mut j = 0;
    while j < MAX_JOINTS {
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
    max_period
}

/// The idle value of every [`PulseProducer`] field but the segment ring and the joints'
/// streams (each [`JointStream::IDLE`]), written once for
/// [`PulseProducer::new`] (a struct literal: the compiler checks that no field is missing)
/// and [`PulseProducer::init_in_place`] (the same list, each field written where it lies).
/// `$emit!($($head)* ; field: value, ...)` is called with the list.
macro_rules! with_idle_fields {
    ($timing:expr, $max_period_ticks:expr, $emit:ident!($($head:tt)*)) => {{
        let timing: StepTiming = $timing;
        let g = gcd(timing.tick_hz as u64, US_PER_S);
        let g = if g == 0 { 1 } else { g };
        let min_period = timing.pulse_ticks().saturating_add(timing.low_ticks());
        #[allow(
            clippy::cast_possible_truncation,
            reason = "g = gcd(tick_hz, 1e6) <= 1e6 fits u32"
        )]
        let g32 = g as u32;
        $emit!($($head)* ;
            timing: timing,
            pulse_ticks: timing.pulse_ticks(),
            min_period: min_period,
            setup_ticks: timing.dir_setup_ticks as u64,
            tick_hz: timing.tick_hz as u64,
            tick_scale: timing.tick_hz as u64 / g,
            us_scale: US_PER_S / g,
            gcd: g32,
            idle_short: {
                let short = timing.tick_hz / 10_000;
                let floor = min_period.saturating_mul(2);
                if short < floor { floor } else { short }
            },
            max_period: max_periods(min_period, $max_period_ticks),
            head_ordinal: 0,
            queue_end: QueueEnd::ZERO,
            running: false,
            origin: 0,
            run_end: u64::MAX,
            late_pulses: 0,
            warp: Warp::IDENTITY,
        )
    }};
}

/// `PulseProducer { ring, idle joints, idle fields }`: see `with_idle_fields`.
macro_rules! producer_literal {
    ($ring:expr ; $($field:ident : $value:expr),* $(,)?) => {
        PulseProducer {
            ring: $ring,
            joints: [JointStream::IDLE; MAX_JOINTS],
            $($field: $value),*
        }
    };
}

impl<const QUEUE: usize> PulseProducer<QUEUE> {
    /// An idle producer; `max_period_ticks[j]` is the longest period joint `j`'s timer can
    /// make (2^16 for a 16-bit timer; at least `2 * min_pulse_period_ticks`).
    pub const fn new(timing: StepTiming, max_period_ticks: [u32; MAX_JOINTS]) -> Self {
        with_idle_fields!(
            timing,
            max_period_ticks,
            producer_literal!(SegmentRing::new())
        )
    }

    /// Writes [`PulseProducer::new`]'s value at `producer`, field by field (the segment
    /// ring slot by slot): never the whole producer on the stack first.
    ///
    /// # Safety
    /// `producer` is valid for writes and aligned (the storage of a `PulseProducer<QUEUE>`).
    pub(crate) unsafe fn init_in_place(
        producer: *mut Self,
        timing: StepTiming,
        max_period_ticks: [u32; MAX_JOINTS],
    ) {
        // SAFETY: the caller's guarantee; every write is to a field of `producer`: the ring
        // by its own in-place constructor, the joints' streams one by one, the others from
        // the list that `new`'s struct literal proves complete.
        unsafe {
            SegmentRing::init_in_place(&raw mut (*producer).ring);
            write_each(&raw mut (*producer).joints, JointStream::IDLE);
            with_idle_fields!(timing, max_period_ticks, write_fields!(producer));
        }
    }

    /// Sets the time warp of the runs to come (ticks on the run's clock, as the engine's
    /// [`crate::StepEngine::set_warp`]); refused (false) while running.
    pub fn set_warp(&mut self, warp: Warp) -> bool {
        if !self.running {
            self.warp = warp;
            for joint in &mut self.joints {
                joint.cruising = false;
                joint.warped = !warp.is_identity();
            }
        }
        !self.running
    }

    /// The time warp.
    pub fn warp(&self) -> &Warp {
        &self.warp
    }

    /// The earliest controller tick a warp change may take effect at
    /// ([`PulseProducer::change_warp`]): every moving joint's written periods end at its
    /// cursor, and a next rise computed but not written yet is committed too (0 when idle).
    /// A buffer half or two ahead of the hardware: a change waits that long. Of a joint
    /// that waits past the queue, only its last pulse counts (its idle fillers are on
    /// controller time, and a pulse pushed later rises after them whatever the warp).
    pub fn warp_horizon(&self) -> u64 {
        if !self.running {
            return 0;
        }
        self.joints
            .iter()
            .map(|j| match j.next_rise {
                _ if j.waiting => j.seek_at,
                u64::MAX => j.cursor,
                rise => rise.max(j.cursor),
            })
            .max()
            .unwrap_or(0)
    }

    /// Changes the warp during a run (or between runs), as
    /// [`crate::StepEngine::change_warp`]: refused before
    /// [`PulseProducer::warp_horizon`]; phases nothing can still need are forgotten first;
    /// the cruise fast path is left (it runs unwarped only) and the run's end, if known, is
    /// mapped again.
    pub fn change_warp(&mut self, at: u64, target: u64, ramp: u64) -> Result<(), WarpError> {
        if at < self.warp_horizon() {
            return Err(WarpError::Committed);
        }
        if self.running {
            // Never past `at` itself: the change starts from the phase that holds it.
            let needed = self.oldest_needed().min(self.warp.trajectory_tick(at));
            self.warp.forget_before(needed);
        }
        self.warp.change_rate(at, target, ramp)?;
        for joint in &mut self.joints {
            joint.cruising = false;
            joint.warped = true;
        }
        if self.running && self.drained() {
            let last_fall = self.joints.iter().map(|j| j.seek_at).max().unwrap_or(0);
            let end = self.warp.controller_tick(self.origin + self.queue_end.tick);
            self.run_end = end.max(last_fall);
        }
        Ok(())
    }

    /// The oldest trajectory tick the run can still map: each joint's next pulse, or the
    /// start of the segment a joint between pulses goes on from (where the next pushed
    /// one will start if it waits past the queue); the run's end is the latest of all.
    fn oldest_needed(&self) -> u64 {
        let len = u32::try_from(self.ring.len()).unwrap_or(u32::MAX);
        self.joints
            .iter()
            .map(|joint| {
                if joint.parked != u64::MAX {
                    return joint.parked;
                }
                if joint.remaining > 0 {
                    return joint.next_ideal();
                }
                let held = joint.ordinal.wrapping_sub(self.head_ordinal) < len;
                match self.ring.get(joint.slot) {
                    Some(slot) if held => self.origin + slot.start_tick,
                    _ => self.origin + self.queue_end.tick,
                }
            })
            .min()
            .unwrap_or(self.origin)
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
        let end = self
            .ring
            .push_segment(&segment, self.queue_end, self.tick_hz);
        self.queue_end = end.ok_or(segment)?;
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
            joint.parked = u64::MAX;
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
            joint.parked = u64::MAX;
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
        self.joints.each_ref().map(|joint| joint.position)
    }

    /// Overwrites the position counters; refused (false) while running.
    pub fn set_positions(&mut self, positions: [i32; MAX_JOINTS]) -> bool {
        crate::set_positions(self.running, &mut self.joints, positions, |j| {
            &mut j.position
        })
    }
}
