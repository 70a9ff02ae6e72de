//! [`StepEngine`]: the segment queue, each joint's walk through it, and `poll`.

use crate::joint::Joint;
use crate::ring::SegmentRing;
use crate::schedule::{Edges, at_most_two};
use crate::{
    ALL_JOINTS, JointMask, MAX_JOINTS, Poll, Segment, StepPins, StepTiming, US_PER_S, Warp,
    WarpError,
};

/// The set bits of a joint mask, lowest first.
#[derive(Clone, Copy)]
struct Joints(JointMask);

impl Iterator for Joints {
    type Item = usize;

    #[inline(always)]
    fn next(&mut self) -> Option<usize> {
        if self.0 == 0 {
            return None;
        }
        // `& 7`: a no-op (the mask is not empty) that lets the compiler drop bounds checks.
        let joint = self.0.trailing_zeros() as usize & (MAX_JOINTS - 1);
        self.0 &= self.0 - 1;
        Some(joint)
    }
}

/// The end of the queue on the run's timeline: the cumulative duration of every segment
/// pushed since the run began, kept as whole seconds plus microseconds so that converting
/// it to ticks never overflows and never rounds twice.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct QueueEnd {
    seconds: u64,
    micros: u32,
    /// `floor(cum_us * tick_hz / 1e6)`.
    pub tick: u64,
    /// `(cum_us * tick_hz) mod 1e6`.
    pub frac: u32,
}

impl QueueEnd {
    /// The start of a run's timeline.
    pub(crate) const ZERO: QueueEnd = QueueEnd {
        seconds: 0,
        micros: 0,
        tick: 0,
        frac: 0,
    };

    /// The end after one more segment of `duration_us`.
    pub(crate) fn after(self, duration_us: u32, tick_hz: u64) -> Self {
        let micros = u64::from(self.micros) + u64::from(duration_us);
        let seconds = self.seconds + micros / US_PER_S;
        let micros = micros % US_PER_S;
        // micros < 1e6 and tick_hz < 2^32: no overflow.
        let scaled = micros * tick_hz;
        QueueEnd {
            seconds,
            micros: micros as u32,
            tick: seconds * tick_hz + scaled / US_PER_S,
            frac: (scaled % US_PER_S) as u32,
        }
    }
}

/// The step pulse scheduler. `QUEUE` = segments held on the interrupt's side.
///
/// Each joint walks the queue on its own: once it has emitted its last pulse of a segment
/// (and that pulse has ended) it moves on, so it may set its DIR line for a later segment
/// early. A segment's slot is freed once the timeline has passed its end and every joint is
/// done with it (its last pulse has fallen): usually `pulse_width_ticks` after its end,
/// while the next segment already runs. Streaming therefore needs `QUEUE >= 2`: with one
/// slot, the next segment can only be pushed after the run has gone dry.
///
/// The engine is not shared: the owner serialises `push`/`start`/`stop` with the timer
/// interrupt's `poll` (a critical section around each call).
#[derive(Debug)]
pub struct StepEngine<const QUEUE: usize> {
    timing: StepTiming,
    /// STEP high time, ticks (at least one).
    pulse_ticks: u64,
    /// Least STEP low time, ticks (at least one).
    low_ticks: u64,
    /// Least time from a DIR change to the next rising edge, ticks.
    setup_ticks: u64,
    tick_hz: u64,
    ring: SegmentRing<QUEUE>,
    /// Ordinal (wrapping) of the ring's oldest slot.
    head_ordinal: u32,
    joints: [Joint; MAX_JOINTS],
    /// Tick of each joint's next edge: STEP falling if its line is high, else the next
    /// rising edge; `u64::MAX` while it waits for a segment.
    edges: Edges,
    /// The earliest of `edges` as of the end of the last `poll` (`u64::MAX`: none): a poll
    /// before it has no edge to make.
    next_edge: u64,
    /// Joints whose STEP line is high.
    high: JointMask,
    /// Joints that have walked past every queued segment.
    waiting: JointMask,
    /// At most two joints are not waiting (kept up to date with `waiting`, which changes
    /// about once per segment): `poll` then visits those alone instead of all eight.
    few_moving: bool,
    /// Segments were pushed since the last `poll`: waiting joints may go on.
    pushed: bool,
    running: bool,
    /// Tick where the run's first segment starts.
    origin: u64,
    /// Absolute end tick of the oldest held segment while running (`u64::MAX` if none),
    /// cached so that `poll` checks the timeline with one comparison.
    head_end: u64,
    queue_end: QueueEnd,
    late_pulses: u32,
    /// Trajectory time to controller time: pulses and segment ends are placed on
    /// trajectory ticks and happen when the warp reaches them (HOLD, RESUME, override).
    warp: Warp,
}

impl<const QUEUE: usize> StepEngine<QUEUE> {
    /// An idle engine with an empty queue, all positions 0.
    pub const fn new(timing: StepTiming) -> Self {
        Self {
            timing,
            pulse_ticks: timing.pulse_ticks() as u64,
            low_ticks: timing.low_ticks() as u64,
            setup_ticks: timing.dir_setup_ticks as u64,
            tick_hz: timing.tick_hz as u64,
            ring: SegmentRing::new(),
            head_ordinal: 0,
            joints: [Joint::IDLE; MAX_JOINTS],
            edges: Edges::IDLE,
            next_edge: u64::MAX,
            high: 0,
            waiting: ALL_JOINTS,
            few_moving: true,
            pushed: false,
            running: false,
            origin: 0,
            head_end: u64::MAX,
            queue_end: QueueEnd {
                seconds: 0,
                micros: 0,
                tick: 0,
                frac: 0,
            },
            late_pulses: 0,
            warp: Warp::IDENTITY,
        }
    }

    /// Sets the time warp of the runs to come (ticks on the run's clock); refused (false)
    /// while running.
    pub fn set_warp(&mut self, warp: Warp) -> bool {
        if !self.running {
            self.warp = warp;
        }
        !self.running
    }

    /// The time warp.
    pub fn warp(&self) -> &Warp {
        &self.warp
    }

    /// The earliest controller tick a warp change may take effect at
    /// ([`StepEngine::change_warp`]): the latest rise scheduled under the current warp (0
    /// when idle). Falling edges are on controller time and do not count, nor does a rise
    /// the warp holds back for good (`u64::MAX`: it is mapped again at the change).
    pub fn warp_horizon(&self) -> u64 {
        if !self.running {
            return 0;
        }
        let rising = !self.waiting & !self.high;
        Joints(rising)
            .map(|j| self.edges.get(j))
            .filter(|&tick| tick != u64::MAX)
            .max()
            .unwrap_or(0)
    }

    /// Changes the warp during a run (or between runs): from controller tick `at` the rate
    /// ramps to `target` with slope `ramp` ([`Warp::change_rate`]). Refused
    /// ([`WarpError::Committed`]) before [`StepEngine::warp_horizon`]: what is scheduled
    /// stays. Phases no pulse or segment end can still need are forgotten first. Poll again
    /// after a change: the next segment end may have moved.
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
        if self.running {
            self.head_end = self.front_end();
            // A rise the old warp put at "never" (held for good) was not committed: map it
            // again (after `at`, as the maps agree up to it).
            for j in Joints(!self.waiting & !self.high) {
                if self.edges.get(j) != u64::MAX {
                    continue;
                }
                if let Some(joint) = self.joints.get(j).filter(|joint| joint.remaining > 0) {
                    self.edges
                        .set(j, joint.next_rise(&mut self.late_pulses, &self.warp));
                }
            }
            self.next_edge = self.edges.earliest(!self.waiting, self.few_moving);
        }
        Ok(())
    }

    /// The oldest trajectory tick the run can still map: the oldest held segment's end
    /// (its end is mapped to free it), each joint's next pulse, or the start of the segment
    /// a joint between pulses goes on from (where the next pushed one will start if it
    /// waits past the queue).
    fn oldest_needed(&self) -> u64 {
        let front_end = self.ring.front().map_or(u64::MAX, |front| front.end_tick);
        let len = u32::try_from(self.ring.len()).unwrap_or(u32::MAX);
        let joints = self.joints.iter().map(|joint| {
            if joint.remaining > 0 {
                return joint.ideal;
            }
            let held = joint.ordinal.wrapping_sub(self.head_ordinal) < len;
            match self.ring.get(joint.slot) {
                Some(slot) if held => self.origin + slot.start_tick,
                _ => self.origin + self.queue_end.tick,
            }
        });
        joints.fold(self.origin.saturating_add(front_end), u64::min)
    }

    /// The timing this engine was built with.
    pub fn timing(&self) -> StepTiming {
        self.timing
    }

    /// Queues a segment behind the others; `Err(segment)` back if `QUEUE` are already held.
    ///
    /// While running, joints that wait at the end of the queue pick the segment up at the
    /// next `poll`. That poll comes at the latest when the segment before it ends, so no
    /// kick is needed for timing; kicking lets those joints set their DIR lines early.
    pub fn push(&mut self, segment: Segment) -> Result<(), Segment> {
        let end = self
            .ring
            .push_segment(&segment, self.queue_end, self.tick_hz);
        let end = end.ok_or(segment)?;
        self.queue_end = end;
        self.pushed = true;
        if self.running && self.ring.len() == 1 {
            self.head_end = self.warp.controller_tick(self.origin + end.tick);
        }
        Ok(())
    }

    /// Slots free for `push`.
    pub fn free_slots(&self) -> usize {
        QUEUE - self.ring.len()
    }

    /// Segments held (queued or running).
    pub fn queued(&self) -> usize {
        self.ring.len()
    }

    /// Starts running the queue; the first queued segment starts at `at_tick`, each later
    /// one exactly where the previous ended (cumulative microseconds -> ticks, no drift).
    /// No-op if already running.
    ///
    /// DIR lines are written at the next `poll`: leave `dir_setup_ticks` plus the interrupt
    /// latency between that `poll` and `at_tick`, or the first pulses come late. Starting
    /// with an empty queue runs dry at the next `poll`.
    pub fn start(&mut self, at_tick: u64) {
        if self.running {
            return;
        }
        self.running = true;
        self.origin = at_tick;
        let head = self.ring.head_index();
        for joint in &mut self.joints {
            joint.ordinal = self.head_ordinal;
            joint.slot = head;
            joint.remaining = 0;
        }
        self.edges = Edges::IDLE;
        self.next_edge = u64::MAX;
        self.waiting = ALL_JOINTS;
        self.few_moving = true;
        self.pushed = true;
        self.head_end = self.front_end();
    }

    /// Emergency stop: lowers every STEP line now, drops all queued segments, goes idle.
    /// Positions keep exactly the pulses that were emitted.
    pub fn stop(&mut self, pins: &mut impl StepPins) {
        pins.step_low(ALL_JOINTS);
        self.high = 0;
        self.ring.clear();
        self.head_ordinal = 0;
        for joint in &mut self.joints {
            joint.remaining = 0;
        }
        self.edges = Edges::IDLE;
        self.next_edge = u64::MAX;
        self.waiting = ALL_JOINTS;
        self.few_moving = true;
        self.end_run();
    }

    /// Whether a run is under way.
    pub fn is_running(&self) -> bool {
        self.running
    }

    /// Pulses raised later than their ideal tick because the STEP/DIR timing left no room
    /// (a host asking for more than `max_step_rate_hz`, or `poll` called late). Such
    /// pulses are delayed, never dropped.
    pub fn late_pulses(&self) -> u32 {
        self.late_pulses
    }

    /// Position of each joint in steps, counted per pulse actually emitted.
    pub fn positions(&self) -> [i32; MAX_JOINTS] {
        self.joints.each_ref().map(|joint| joint.position)
    }

    /// Overwrites the position counters (calibration); refused (false) while running.
    pub fn set_positions(&mut self, positions: [i32; MAX_JOINTS]) -> bool {
        crate::set_positions(self.running, &mut self.joints, positions, |j| {
            &mut j.position
        })
    }

    /// Emits every edge due at or before `now_tick` (STEP low after pulse width, DIR
    /// changes, STEP high for due pulses), and reports finished segments / running dry.
    /// Running dry = the end of the last queued segment passed with nothing queued after
    /// it: the engine goes idle and needs `start` again.
    ///
    /// Each call lowers and raises each line at most once, so a late call (interrupt
    /// latency) emits the pulses it missed one by one on the following calls, in order,
    /// each with its full pulse width. The returned deadline is always after `now_tick`.
    pub fn poll(&mut self, now_tick: u64, pins: &mut impl StepPins) -> Poll {
        if !self.running {
            return Poll::default();
        }
        let now = now_tick;

        // Which joints have an edge due.
        let waiting = self.waiting;
        let due = if self.next_edge <= now {
            self.edges.due(now, !waiting, self.few_moving)
        } else {
            0
        };
        let falls = due & self.high;
        let mut rises = due & !self.high;

        // Falling edges first: a DIR line may change only once its STEP line is low.
        if falls != 0 {
            pins.step_low(falls);
            self.high &= !falls;
            for j in Joints(falls) {
                self.after_fall(j, now, pins);
            }
        }

        if self.pushed {
            self.pushed = false;
            for j in Joints(self.waiting) {
                self.seek(j, now, pins);
                if self.edges.get(j) <= now {
                    rises |= 1 << j;
                }
            }
        }

        if rises != 0 {
            pins.step_high(rises);
            self.high |= rises;
            let fall_at = now + self.pulse_ticks;
            for j in Joints(rises) {
                if let Some(joint) = self.joints.get_mut(j) {
                    joint.rise();
                }
                self.edges.set(j, fall_at);
            }
        }
        if self.waiting != waiting {
            self.few_moving = at_most_two(!self.waiting);
        }
        self.next_edge = self.edges.earliest(!self.waiting, self.few_moving);
        let mut next = self.next_edge;

        // Free the segments that are over for the timeline and for every joint.
        let mut finished = 0;
        if self.head_end > now {
            next = next.min(self.head_end);
        } else {
            while let Some(front) = self.ring.front() {
                let end = self.warp.controller_tick(self.origin + front.end_tick);
                if end > now {
                    next = next.min(end);
                    break;
                }
                if front.pending != 0 {
                    break;
                }
                self.ring.pop_front();
                self.head_ordinal = self.head_ordinal.wrapping_add(1);
                finished += 1;
            }
            self.head_end = self.front_end();
        }
        if self.ring.is_empty() {
            // Every joint is past every segment, so every STEP line is low.
            self.end_run();
            return Poll {
                next_deadline: None,
                segments_finished: finished,
                ran_dry: true,
            };
        }
        Poll {
            next_deadline: Some(next),
            segments_finished: finished,
            ran_dry: false,
        }
    }

    /// Absolute end tick of the oldest held segment, `u64::MAX` if none.
    fn front_end(&self) -> u64 {
        match self.ring.front() {
            Some(front) => self.warp.controller_tick(self.origin + front.end_tick),
            None => u64::MAX,
        }
    }

    /// Joint `j`'s STEP line just fell at `now`: schedule its next pulse, or move it on to
    /// the next segment.
    fn after_fall(&mut self, j: usize, now: u64, pins: &mut impl StepPins) {
        let Some(joint) = self.joints.get_mut(j) else {
            return;
        };
        joint.earliest = now + self.low_ticks;
        if joint.remaining > 0 {
            self.edges
                .set(j, joint.next_rise(&mut self.late_pulses, &self.warp));
            return;
        }
        if let Some(slot) = self.ring.get_mut(joint.slot) {
            slot.pending &= !(1 << j);
        }
        joint.ordinal = joint.ordinal.wrapping_add(1);
        joint.slot = SegmentRing::<QUEUE>::next_index(joint.slot);
        self.seek(j, now, pins);
    }

    /// Moves joint `j` (not in a pulse, done with every earlier segment) through the
    /// segments where it does not move, to the first where it does, and sets up its
    /// direction and first pulse there; or marks it waiting at the end of the queue.
    fn seek(&mut self, j: usize, now: u64, pins: &mut impl StepPins) {
        let bit = 1 << j;
        let Some(joint) = self.joints.get_mut(j) else {
            return;
        };
        loop {
            let held = joint.ordinal.wrapping_sub(self.head_ordinal)
                < u32::try_from(self.ring.len()).unwrap_or(u32::MAX);
            let slot = match self.ring.get_mut(joint.slot) {
                Some(slot) if held => slot,
                _ => {
                    self.edges.set(j, u64::MAX);
                    self.waiting |= bit;
                    return;
                }
            };
            let steps = slot.steps.get(j).copied().unwrap_or(0);
            if steps != 0 {
                let positive = steps > 0;
                if joint.direction != Some(positive) {
                    pins.set_direction(j, positive);
                    joint.direction = Some(positive);
                    joint.earliest = joint.earliest.max(now + self.setup_ticks);
                }
                joint.begin_segment(
                    self.origin + slot.start_tick,
                    slot.start_frac,
                    u64::from(slot.duration_us) * self.tick_hz,
                    steps,
                );
                self.edges
                    .set(j, joint.next_rise(&mut self.late_pulses, &self.warp));
                self.waiting &= !bit;
                return;
            }
            slot.pending &= !bit;
            joint.ordinal = joint.ordinal.wrapping_add(1);
            joint.slot = SegmentRing::<QUEUE>::next_index(joint.slot);
        }
    }

    /// Back to idle; the next pushed segment starts a new timeline.
    fn end_run(&mut self) {
        self.running = false;
        self.head_end = u64::MAX;
        self.pushed = false;
        self.queue_end = QueueEnd::default();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn joint_bits_in_order() {
        let mut bits = [0usize; 8];
        let mut count = 0;
        for (slot, j) in bits.iter_mut().zip(Joints(0b1010_0101)) {
            *slot = j;
            count += 1;
        }
        assert_eq!(&bits[..count], &[0, 2, 5, 7]);
        assert_eq!(Joints(0).next(), None);
    }

    #[test]
    fn queue_end_converts_without_drift() {
        let mut end = QueueEnd::default();
        let mut total_us = 0u64;
        for duration in [1u32, 999_999, 3_000_000_000, 7, 123_456] {
            end = end.after(duration, 2_999_999);
            total_us += u64::from(duration);
            let exact = u128::from(total_us) * 2_999_999;
            assert_eq!(u128::from(end.tick), exact / 1_000_000);
            assert_eq!(u128::from(end.frac), exact % 1_000_000);
        }
    }
}
