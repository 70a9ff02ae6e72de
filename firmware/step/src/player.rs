//! [`StreamPlayer`]: the joint timers and DMA streams of the board, in software, for the
//! targets that have none (sim-host, the QEMU board): it plays the periods that
//! [`StepStreams`] writes into each joint's double buffer and refills each half as the
//! "timer" leaves it, exactly where the board's DMA raises its half-transfer and
//! transfer-complete interrupts.
//!
//! It does not run per edge: its owner calls [`StreamPlayer::advance`] now and then (at
//! [`StreamPlayer::next_due`], the next half boundary or the run's end, at DIR changes,
//! when kicked), and it walks every period that started since, handing each STEP edge and
//! DIR change to a [`TimedStepPins`] with the tick the producer computed for it. The
//! edges are those the board's timers make from the same buffers, tick for tick (the
//! tests compare them with [`crate::StepEngine`]'s); only when the lines see them
//! depends on how often the owner plays.
//!
//! An emergency stop ([`StreamPlayer::stop`]) plays the edges up to the stop's tick, lets
//! a pulse in progress fall at its own width (its rise counted it; a driver may miss one cut
//! shorter: docs/PROTOCOL.md, STOPPED, and docs/BOARD.md, "A stop never cuts a pulse
//! short", as the NUCLEO does) and drops the rest, taking back the pulses written but never
//! played ([`StepStreams::unwind`]), as the board does with the streams' positions.

use crate::producer::PulsePeriod;
use crate::stream::{JointBuffer, PRELUDE, Refill, StepStreams};
use crate::{DirChange, MAX_JOINTS};

/// The STEP and DIR lines a [`StreamPlayer`] drives: every change comes with its tick
/// (run ticks: the streams' tick 0 is the run's start). Changes of one joint come in
/// tick order; [`StreamPlayer::advance`] plays the joints one after the other, [`StreamPlayer::advance_halting`] all in tick order.
pub trait TimedStepPins {
    /// Joint `joint`'s STEP line rises at `tick`.
    fn step_high(&mut self, joint: usize, tick: u64);
    /// Joint `joint`'s STEP line falls at `tick` (the pulse's end, or cut by a stop).
    fn step_low(&mut self, joint: usize, tick: u64);
    /// Joint `joint`'s DIR line is set at `tick` (true = positive steps).
    fn set_direction(&mut self, joint: usize, positive: bool, tick: u64);
}

/// [`TimedStepPins`] that may ask [`StreamPlayer::advance_halting`] to play nothing after
/// a tick (a limit switch the played edges closed).
pub trait HaltingStepPins: TimedStepPins {
    /// The tick after which nothing is to be played, once known.
    fn halt_tick(&self) -> Option<u64>;
}

/// Where one joint's software timer is.
#[derive(Clone, Copy, Debug)]
struct JointPlay {
    /// Index of the next period to start: 0 and 1 the prelude, then the buffer circularly
    /// (period `n >= PRELUDE` is buffer entry `(n - PRELUDE) % (2 * HALF)`).
    next: u64,
    /// Run tick at which period `next` starts.
    at: u64,
    /// Run tick at which the pulse in progress falls; 0: STEP is low (a pulse rises at
    /// tick 0 at the earliest and is at least one tick long).
    fall: u64,
    /// Run tick at which the timer enters its next half, where the board's stream raises
    /// its half/complete interrupt (the refill of the half it leaves).
    boundary: u64,
}

impl JointPlay {
    /// All zeros (see [`StreamPlayer`]); nothing plays until `prime`.
    const IDLE: JointPlay = JointPlay {
        next: 0,
        at: 0,
        fall: 0,
        boundary: 0,
    };
}

/// What one [`StreamPlayer::advance`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Advance {
    /// Segments the refills finished (their slots are free).
    pub segments_finished: u32,
    /// The run reached its end (every pulse played, the last segment over): the producer
    /// has ended it ([`crate::PulseProducer::end_run`]); the owner stops playing.
    pub ended: bool,
}

/// The board's step hardware in software: every joint's prelude (the two periods the
/// timer's registers take) and double buffer, and where its timer is. `HALF` = periods
/// per buffer half, as [`StepStreams`]'.
///
/// [`StreamPlayer::IDLE`] is all zero bytes, so that a static holding it (the buffers are
/// `12 * 2 * HALF` bytes per joint) is `.bss`, not an image in flash copied at boot.
#[derive(Debug)]
pub struct StreamPlayer<const HALF: usize> {
    prelude: [[PulsePeriod; PRELUDE]; MAX_JOINTS],
    buffers: [JointBuffer<HALF>; MAX_JOINTS],
    joints: [JointPlay; MAX_JOINTS],
    /// Between [`StreamPlayer::prime`] and the run's end or stop.
    playing: bool,
}

impl<const HALF: usize> StreamPlayer<HALF> {
    /// Nothing primed, nothing playing.
    pub const IDLE: Self = StreamPlayer {
        prelude: [[PulsePeriod::ZERO; PRELUDE]; MAX_JOINTS],
        buffers: [JointBuffer::ZERO; MAX_JOINTS],
        joints: [JointPlay::IDLE; MAX_JOINTS],
        playing: false,
    };

    /// Whether a run is playing (primed, not ended or stopped).
    pub fn is_playing(&self) -> bool {
        self.playing
    }

    /// Starts a run as the board does ([`StepStreams::prime`]: the segments from run tick
    /// `at_tick`, every joint's prelude and both halves written) with every joint's timer
    /// at run tick 0. The DIR levels of tick 0 are made by the first `advance`.
    #[allow(
        clippy::indexing_slicing,
        reason = "j enumerates the [_; MAX_JOINTS] arrays"
    )]
    pub fn prime<const Q: usize>(
        &mut self,
        streams: &mut StepStreams<Q, HALF>,
        at_tick: u64,
    ) -> Refill {
        let [b0, b1, b2, b3, b4, b5, b6, b7] = &mut self.buffers;
        let primed = streams.prime(
            at_tick,
            &mut self.prelude,
            &mut [b0, b1, b2, b3, b4, b5, b6, b7],
        );
        for j in 0..MAX_JOINTS {
            // The first refill is due where the timer leaves half 0 for half 1.
            let mut boundary = 0;
            for n in 0..(PRELUDE + HALF) as u64 {
                boundary += self.period(j, n).ticks();
            }
            self.joints[j] = JointPlay {
                boundary,
                ..JointPlay::IDLE
            };
        }
        self.playing = !primed.dir_overflow;
        primed
    }

    /// Period `n` of joint `j`'s stream.
    #[allow(
        clippy::indexing_slicing,
        clippy::cast_possible_truncation,
        reason = "j < MAX_JOINTS (callers' loops); n < PRELUDE or e < 2 * HALF (reduced modulo it), so the indices are inside the arrays"
    )]
    fn period(&self, j: usize, n: u64) -> PulsePeriod {
        if n < PRELUDE as u64 {
            return self.prelude[j][n as usize];
        }
        let e = ((n - PRELUDE as u64) % (2 * HALF) as u64) as usize;
        self.buffers[j].periods[e / HALF][e % HALF]
    }

    /// Plays every joint up to run tick `t` (but not past the run's end): edges, DIR
    /// changes, refills of the halves the timers left; ends the run at its end.
    pub fn advance<const Q: usize>(
        &mut self,
        streams: &mut StepStreams<Q, HALF>,
        t: u64,
        pins: &mut impl TimedStepPins,
    ) -> Advance {
        if !self.playing {
            return Advance::default();
        }
        let end = streams.producer_ref().run_end_tick();
        let until = end.map_or(t, |end| t.min(end));
        let mut advance = Advance::default();
        for j in 0..MAX_JOINTS {
            advance.segments_finished += self.play_joint(streams, j, until, pins);
        }
        // A refill may have found the end (it is then at or before `t`: nothing queued
        // is left to play after it).
        if let Some(end) = streams.producer_ref().run_end_tick()
            && t >= end
        {
            streams.producer().end_run();
            self.playing = false;
            advance.ended = true;
        }
        advance
    }

    /// Plays joint `j` up to run tick `t`; returns segments finished by its refills.
    fn play_joint<const Q: usize>(
        &mut self,
        streams: &mut StepStreams<Q, HALF>,
        j: usize,
        t: u64,
        pins: &mut impl TimedStepPins,
    ) -> u32 {
        let mut finished = 0;
        while self.next_event(streams, j) <= t {
            finished += self.play_event(streams, j, pins);
        }
        finished
    }

    /// Run tick of joint `j`'s next change: the earliest of the pulse's fall, a DIR
    /// change, the next period's start.
    #[allow(
        clippy::indexing_slicing,
        reason = "j < MAX_JOINTS (the callers' loops)"
    )]
    fn next_event<const Q: usize>(&self, streams: &StepStreams<Q, HALF>, j: usize) -> u64 {
        let play = self.joints[j];
        let fall = if play.fall == 0 { u64::MAX } else { play.fall };
        let dir_at = streams.next_dir_change(j).map_or(u64::MAX, |d| d.tick);
        fall.min(dir_at).min(play.at)
    }

    /// Plays joint `j`'s next change ([`Self::next_event`]); returns segments finished by
    /// its refill, if it made one.
    #[allow(
        clippy::indexing_slicing,
        clippy::cast_possible_truncation,
        reason = "j < MAX_JOINTS (the callers' loops); the half is 0 or 1 (reduced modulo 2)"
    )]
    fn play_event<const Q: usize>(
        &mut self,
        streams: &mut StepStreams<Q, HALF>,
        j: usize,
        pins: &mut impl TimedStepPins,
    ) -> u32 {
        let mut finished = 0;
        let play = self.joints[j];
        let dir = streams.next_dir_change(j);
        // The earliest of: the pulse's fall, a DIR change, the next period's start
        // (a fall and a rise at one tick: the fall first, as a timer that ends one
        // period and starts the next).
        let fall = if play.fall == 0 { u64::MAX } else { play.fall };
        let dir_at = dir.map_or(u64::MAX, |d| d.tick);
        let next = fall.min(dir_at).min(play.at);
        if fall == next {
            pins.step_low(j, fall);
            self.joints[j].fall = 0;
        } else if let Some(DirChange { tick, positive }) = dir.filter(|_| dir_at == next) {
            pins.set_direction(j, positive, tick);
            streams.pop_dir_change(j);
        } else {
            let period = self.period(j, play.next);
            if period.high != 0 {
                pins.step_high(j, play.at);
                self.joints[j].fall = play.at + u64::from(period.high);
            }
            self.joints[j].at = play.at + period.ticks();
            self.joints[j].next = play.next + 1;
            let n = play.next;
            if n >= PRELUDE as u64 && (n - PRELUDE as u64).is_multiple_of(HALF as u64) {
                // Entering a half: the one before is free (the DMA has read it all),
                // except at the run's start (the prelude before it).
                let entered = ((n - PRELUDE as u64) / HALF as u64 % 2) as usize;
                if n >= (PRELUDE + HALF) as u64 {
                    let freed = 1 - entered;
                    let refill = streams.refill(j, freed, &mut self.buffers[j].periods[freed]);
                    finished += refill.segments_finished;
                }
                // The half entered was written before: its end is known.
                let half = &self.buffers[j].periods[entered];
                let boundary = play.at + half.iter().map(PulsePeriod::ticks).sum::<u64>();
                self.joints[j].boundary = boundary;
                let quiet = half.iter().all(|period| period.high == 0);
                let dir_at = streams.next_dir_change(j).map_or(u64::MAX, |d| d.tick);
                if quiet && dir_at >= boundary {
                    // No edge on this joint until the half's end (an idle joint's
                    // fillers): its periods are played at once. Positions and a stop
                    // see the same (they have no pulse), and the next refill is still
                    // made at the boundary.
                    self.joints[j].next = n + HALF as u64;
                    self.joints[j].at = boundary;
                }
            }
        }
        finished
    }

    /// [`Self::advance`] with every joint's changes played in tick order (the earliest
    /// change of any joint first), asking `pins` after each whether to stop early
    /// ([`HaltingStepPins::halt_tick`]): a model whose inputs depend on the joints'
    /// positions (the simulator's limit switches, issue 33) then plays nothing after
    /// the tick a switch closed at, on any joint. Returns what [`Self::advance`] does and
    /// the halt tick if `pins` asked for one; the owner then [`Self::stop`]s at it (which
    /// plays nothing more: every change up to it is played, and none after).
    pub fn advance_halting<const Q: usize>(
        &mut self,
        streams: &mut StepStreams<Q, HALF>,
        t: u64,
        pins: &mut impl HaltingStepPins,
    ) -> (Advance, Option<u64>) {
        if !self.playing {
            return (Advance::default(), None);
        }
        let end = streams.producer_ref().run_end_tick();
        let mut until = end.map_or(t, |end| t.min(end));
        let mut advance = Advance::default();
        let mut halt = None;
        loop {
            if let Some(h) = pins.halt_tick() {
                halt = Some(h);
                until = until.min(h);
            }
            let next = (0..MAX_JOINTS)
                .map(|j| (self.next_event(streams, j), j))
                .min()
                .filter(|&(at, _)| at <= until);
            let Some((_, j)) = next else { break };
            advance.segments_finished += self.play_event(streams, j, pins);
        }
        if let Some(end) = streams.producer_ref().run_end_tick()
            && t.min(halt.unwrap_or(u64::MAX)) >= end
        {
            streams.producer().end_run();
            self.playing = false;
            advance.ended = true;
        }
        (advance, halt)
    }

    /// Run tick at which the player must be advanced next: the first half boundary (a
    /// refill) of any joint, or the run's end.
    pub fn next_due<const Q: usize>(&self, streams: &StepStreams<Q, HALF>) -> Option<u64> {
        if !self.playing {
            return None;
        }
        let end = streams.producer_ref().run_end_tick().unwrap_or(u64::MAX);
        Some(self.joints.iter().map(|j| j.boundary).fold(end, u64::min))
    }

    /// Run tick of the earliest DIR change waiting to be made, if any.
    pub fn next_dir_change<const Q: usize>(&self, streams: &StepStreams<Q, HALF>) -> Option<u64> {
        if !self.playing {
            return None;
        }
        (0..MAX_JOINTS)
            .filter_map(|j| streams.next_dir_change(j).map(|d| d.tick))
            .min()
    }

    /// Emergency stop at run tick `t`: plays every edge up to `t`, lowers a STEP line
    /// still high at `t` at the pulse's own end (after `t`: a stop never cuts a pulse
    /// short), takes back the pulses written but not played, and stops the producer
    /// (queue and DIR changes dropped). Nothing rises after `t`, and nothing is played
    /// after this until the next [`StreamPlayer::prime`]. Returns the run tick from which
    /// every STEP line is low: `t`, or the last kept pulse's fall.
    #[allow(
        clippy::indexing_slicing,
        reason = "j enumerates the [_; MAX_JOINTS] arrays"
    )]
    pub fn stop<const Q: usize>(
        &mut self,
        streams: &mut StepStreams<Q, HALF>,
        t: u64,
        pins: &mut impl TimedStepPins,
    ) -> u64 {
        if !self.playing {
            streams.producer().stop();
            streams.clear_dir_changes();
            return t;
        }
        self.advance(streams, t, pins);
        self.playing = false;
        let mut quiet = t;
        for j in 0..MAX_JOINTS {
            // `advance` played every fall at or before `t`: one still due is after it.
            let fall = self.joints[j].fall;
            if fall != 0 {
                pins.step_low(j, fall);
                quiet = quiet.max(fall);
            }
            let (first_unplayed, stale) = self.unplayed_from(j);
            streams.unwind(j, &self.buffers[j], first_unplayed, stale);
            self.joints[j] = JointPlay::IDLE;
        }
        streams.producer().stop();
        streams.clear_dir_changes();
        quiet
    }

    /// The positions the played pulses make: the producer's count less what the buffers
    /// hold that has not started yet (as on the board); when no run plays, the producer's
    /// positions are the played ones.
    #[allow(
        clippy::indexing_slicing,
        reason = "j enumerates the [_; MAX_JOINTS] arrays"
    )]
    pub fn positions<const Q: usize>(&self, streams: &StepStreams<Q, HALF>) -> [i32; MAX_JOINTS] {
        let mut positions = streams.producer_ref().positions();
        if !self.playing {
            return positions;
        }
        for (j, position) in positions.iter_mut().enumerate() {
            let (first_unplayed, stale) = self.unplayed_from(j);
            *position -= streams.unplayed_steps(j, &self.buffers[j], first_unplayed, stale);
        }
        positions
    }

    /// For joint `j`'s stream: the buffer index of the next period to start (`None`
    /// while in the prelude) and whether the half before it is stale (played, and its
    /// refill, due when that period starts, not done: it is the first of a half).
    #[allow(
        clippy::indexing_slicing,
        clippy::cast_possible_truncation,
        reason = "j < MAX_JOINTS (the callers' loops); the index is reduced modulo 2 * HALF"
    )]
    fn unplayed_from(&self, j: usize) -> (Option<usize>, bool) {
        let next = self.joints[j].next;
        let first = (next >= PRELUDE as u64)
            .then(|| ((next - PRELUDE as u64) % (2 * HALF) as u64) as usize);
        let stale =
            next >= (PRELUDE + HALF) as u64 && (next - PRELUDE as u64).is_multiple_of(HALF as u64);
        (first, stale)
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use std::vec::Vec;

    use super::*;
    use crate::{JointMask, Segment, StepEngine, StepPins, StepTiming};

    /// The board's timing (200 MHz, opto drivers, 10 us DIR setup).
    const TIMING: StepTiming = StepTiming {
        tick_hz: 200_000_000,
        pulse_width_ticks: 500,
        dir_setup_ticks: 2_000,
        step_low_ticks: 500,
    };
    const HALF: usize = 8;
    const Q: usize = 16;
    /// 16-bit timers for joints 2-7, as the board's.
    const MAX_PERIOD: [u32; MAX_JOINTS] = crate::NUCLEO_STEP_TIMER_MAX_PERIOD_TICKS;

    /// Every line change, with its tick; checks that ticks of a joint never go back.
    #[derive(Default)]
    struct Lines {
        rises: [Vec<u64>; MAX_JOINTS],
        falls: [Vec<u64>; MAX_JOINTS],
        dirs: [Vec<(u64, bool)>; MAX_JOINTS],
        high: JointMask,
        dir: JointMask,
        pulses: [i32; MAX_JOINTS],
        last: [u64; MAX_JOINTS],
        /// Ask for a halt at the rise that makes this joint's pulse count this.
        halt_at_rise: Option<(usize, usize)>,
        halt: Option<u64>,
    }

    impl HaltingStepPins for Lines {
        fn halt_tick(&self) -> Option<u64> {
            self.halt
        }
    }

    impl Lines {
        fn at(&mut self, joint: usize, tick: u64) {
            assert!(
                tick >= self.last[joint],
                "joint {joint}: {tick} after {}",
                self.last[joint]
            );
            self.last[joint] = tick;
        }
    }

    impl TimedStepPins for Lines {
        fn step_high(&mut self, joint: usize, tick: u64) {
            self.at(joint, tick);
            assert_eq!(self.high & (1 << joint), 0, "joint {joint} raised twice");
            self.high |= 1 << joint;
            self.pulses[joint] += if self.dir & (1 << joint) != 0 { 1 } else { -1 };
            self.rises[joint].push(tick);
            if self.halt.is_none() && self.halt_at_rise == Some((joint, self.rises[joint].len())) {
                self.halt = Some(tick);
            }
        }
        fn step_low(&mut self, joint: usize, tick: u64) {
            self.at(joint, tick);
            self.high &= !(1 << joint);
            self.falls[joint].push(tick);
        }
        fn set_direction(&mut self, joint: usize, positive: bool, tick: u64) {
            self.at(joint, tick);
            assert_eq!(
                self.high & (1 << joint),
                0,
                "joint {joint}: DIR while STEP high"
            );
            if positive {
                self.dir |= 1 << joint;
            } else {
                self.dir &= !(1 << joint);
            }
            self.dirs[joint].push((tick, positive));
        }
    }

    /// The engine's edges, on the same clock (the oracle).
    #[derive(Default)]
    struct EngineLines {
        now: u64,
        rises: [Vec<u64>; MAX_JOINTS],
    }

    impl StepPins for EngineLines {
        fn set_direction(&mut self, _joint: usize, _positive: bool) {}
        fn step_high(&mut self, joints: JointMask) {
            for (j, rises) in self.rises.iter_mut().enumerate() {
                if joints & (1 << j) != 0 {
                    rises.push(self.now);
                }
            }
        }
        fn step_low(&mut self, _joints: JointMask) {}
    }

    /// Segments that move every joint: reversals, pauses, fast and slow joints, gaps
    /// longer than a 16-bit timer. `sparse`: only joint 0 moves in every segment, joint 3
    /// in every fifth, the others never (idle joints' halves of fillers).
    fn segments(sparse: bool) -> Vec<Segment> {
        let mut segments = Vec::new();
        let mut state = 0x9e37_79b9_u32;
        for k in 0..40u32 {
            let mut steps = [0; MAX_JOINTS];
            for (j, s) in steps.iter_mut().enumerate() {
                state ^= state << 13;
                state ^= state >> 17;
                state ^= state << 5;
                let sign = if (k as usize / 7 + j).is_multiple_of(2) {
                    1
                } else {
                    -1
                };
                *s = sign * (state % (30 * (j as u32 + 1))) as i32;
            }
            if k % 9 == 4 {
                steps = [0; MAX_JOINTS];
            }
            if sparse {
                for (j, s) in steps.iter_mut().enumerate() {
                    if !(j == 0 || j == 3 && k % 5 == 0) {
                        *s = 0;
                    }
                }
            }
            segments.push(Segment {
                duration_us: 1_000 + (k % 5) * 700,
                steps,
            });
        }
        segments
    }

    fn engine_rises(segments: &[Segment], at: u64) -> [Vec<u64>; MAX_JOINTS] {
        let mut engine = StepEngine::<64>::new(TIMING);
        for s in segments {
            engine.push(*s).unwrap();
        }
        engine.start(at);
        let mut lines = EngineLines::default();
        let mut deadline = Some(0);
        while let Some(now) = deadline {
            lines.now = now;
            deadline = engine.poll(now, &mut lines).next_deadline;
        }
        lines.rises
    }

    /// Plays `segments` from run tick `at`, pushing them as the queue frees slots and
    /// advancing in steps of `step` ticks (or at each `next_due` if `step` is 0).
    fn play(segments: &[Segment], at: u64, step: u64) -> (Lines, [i32; MAX_JOINTS]) {
        play_with(segments, at, step, false)
    }

    /// [`play`], through [`StreamPlayer::advance_halting`] if `halting` (no halt asked).
    fn play_with(
        segments: &[Segment],
        at: u64,
        step: u64,
        halting: bool,
    ) -> (Lines, [i32; MAX_JOINTS]) {
        let mut streams = StepStreams::<Q, HALF>::new(TIMING, MAX_PERIOD);
        let mut player = StreamPlayer::<HALF>::IDLE;
        let mut pending = segments.iter();
        let mut fill = |streams: &mut StepStreams<Q, HALF>| {
            while streams.producer_ref().free_slots() > 0 {
                match pending.next() {
                    Some(s) => streams.producer().push(*s).unwrap(),
                    None => break,
                }
            }
        };
        fill(&mut streams);
        assert!(!player.prime(&mut streams, at).dir_overflow);
        let mut lines = Lines::default();
        let mut t = 0;
        for _ in 0..1_000_000 {
            let next = if step == 0 {
                player.next_due(&streams).unwrap()
            } else {
                t + step
            };
            t = next;
            let advance = if halting {
                let (advance, halt) = player.advance_halting(&mut streams, t, &mut lines);
                assert_eq!(halt, None);
                advance
            } else {
                player.advance(&mut streams, t, &mut lines)
            };
            fill(&mut streams);
            if advance.ended {
                let positions = streams.producer_ref().positions();
                return (lines, positions);
            }
        }
        panic!("the run never ended");
    }

    #[test]
    fn plays_the_engines_edges_however_often_it_is_advanced() {
        for sparse in [false, true] {
            let segments = segments(sparse);
            let oracle = engine_rises(&segments, 3_000);
            let pulses: usize = oracle.iter().map(Vec::len).sum();
            assert!(
                pulses > if sparse { 500 } else { 10_000 },
                "{pulses} pulses"
            );
            plays_as_the_engine(&segments, &oracle);
        }
    }

    #[test]
    fn advance_halting_without_a_halt_plays_the_engines_edges() {
        for sparse in [false, true] {
            let segments = segments(sparse);
            let oracle = engine_rises(&segments, 3_000);
            for step in [0, 997, 1_000_000] {
                let (lines, positions) = play_with(&segments, 3_000, step, true);
                assert_eq!(&lines.rises, &oracle, "advanced every {step} ticks");
                assert_eq!(lines.pulses, positions, "advanced every {step} ticks");
            }
        }
    }

    /// Issue 33's limit stop in the simulator: a halt asked at one joint's edge plays no
    /// edge of any joint after that tick, however far the advance was asked to go (joint
    /// by joint, a later joint's edges would have been played past it).
    #[test]
    fn advance_halting_plays_nothing_after_the_halt_on_any_joint() {
        let segments = segments(false);
        let oracle = engine_rises(&segments[..Q], 0);
        for (joint, rise) in [(0, 5), (3, 40), (7, 100), (2, 1)] {
            let (mut streams, mut player) = primed(&segments);
            let mut lines = Lines {
                halt_at_rise: Some((joint, rise)),
                ..Lines::default()
            };
            let (_, halt) = player.advance_halting(&mut streams, 10_000_000, &mut lines);
            let halt = halt.expect("the halt was asked for");
            assert_eq!(halt, oracle[joint][rise - 1], "joint {joint}'s rise {rise}");
            // No rise after the halt; the pulse that closed the switch (it rose at the halt)
            // keeps its width, as every other: a stop never cuts a pulse short.
            let quiet = player.stop(&mut streams, halt, &mut lines);
            assert_eq!(quiet, halt + 500);
            for (j, rises) in oracle.iter().enumerate() {
                let expected: Vec<u64> = rises.iter().copied().filter(|&r| r <= halt).collect();
                assert_eq!(lines.rises[j], expected, "halt at {halt}, joint {j}");
                assert!(lines.last[j] <= quiet);
                for (rise, fall) in lines.rises[j].iter().zip(&lines.falls[j]) {
                    assert_eq!(fall - rise, 500, "halt at {halt}, joint {j}: a pulse cut");
                }
            }
            assert_eq!(lines.high, 0);
            assert_eq!(player.positions(&streams), lines.pulses);
            assert_eq!(streams.producer_ref().positions(), lines.pulses);
        }
    }

    fn plays_as_the_engine(segments: &[Segment], oracle: &[Vec<u64>; MAX_JOINTS]) {
        for step in [0, 997, 20_000, 1_000_000] {
            let (lines, positions) = play(segments, 3_000, step);
            assert_eq!(&lines.rises, oracle, "advanced every {step} ticks");
            assert_eq!(lines.pulses, positions, "advanced every {step} ticks");
            assert_eq!(lines.high, 0, "a STEP line left high");
            for j in 0..MAX_JOINTS {
                assert_eq!(lines.falls[j].len(), lines.rises[j].len());
                for (rise, fall) in lines.rises[j].iter().zip(&lines.falls[j]) {
                    assert_eq!(fall - rise, 500);
                }
            }
        }
    }

    /// Streams holding the first `Q` of `segments`, and a player that primed them at tick 0.
    fn primed(segments: &[Segment]) -> (StepStreams<Q, HALF>, StreamPlayer<HALF>) {
        let mut streams = StepStreams::<Q, HALF>::new(TIMING, MAX_PERIOD);
        for s in &segments[..Q] {
            streams.producer().push(*s).unwrap();
        }
        let mut player = StreamPlayer::<HALF>::IDLE;
        player.prime(&mut streams, 0);
        (streams, player)
    }

    #[test]
    fn next_due_is_a_half_boundary_or_the_end() {
        let segments = segments(false);
        let (mut streams, mut player) = primed(&segments);
        // Just before the first boundary nothing is refilled; at it, the refill happens.
        let due = player.next_due(&streams).unwrap();
        let mut lines = Lines::default();
        player.advance(&mut streams, due - 1, &mut lines);
        assert!(
            player
                .joints
                .iter()
                .all(|j| j.next <= (PRELUDE + HALF) as u64)
        );
        assert_eq!(player.next_due(&streams), Some(due));
        player.advance(&mut streams, due, &mut lines);
        assert!(player.next_due(&streams).unwrap() > due);
        assert!(
            player
                .joints
                .iter()
                .any(|j| j.next == (PRELUDE + HALF) as u64 + 1)
        );
    }

    #[test]
    fn a_stop_plays_up_to_its_tick_and_a_high_pulse_keeps_its_width() {
        for sparse in [false, true] {
            stops_as_the_engine(&segments(sparse));
        }
    }

    fn stops_as_the_engine(segments: &[Segment]) {
        let oracle = engine_rises(&segments[..Q], 0);
        // Some stops land while joint 0's pulse is high: 250, 1 and 499 ticks into its 500.
        let mid_pulse = [oracle[0][3] + 250, oracle[0][40] + 1, oracle[0][41] + 499];
        let mut kept = 0;
        for stop_at in [0, 250, 1_000_000, 1_234_567, 1_500_000, 2_000_000]
            .into_iter()
            .chain(mid_pulse)
        {
            let (mut streams, mut player) = primed(segments);
            let mut lines = Lines::default();
            player.advance(&mut streams, stop_at / 2, &mut lines);
            let quiet = player.stop(&mut streams, stop_at, &mut lines);
            assert_eq!(lines.high, 0, "stop at {stop_at}: a STEP line left high");
            for (j, rises) in oracle.iter().enumerate() {
                let expected: Vec<u64> = rises.iter().copied().filter(|&r| r <= stop_at).collect();
                assert_eq!(lines.rises[j], expected, "stop at {stop_at}, joint {j}");
                // Every pulse keeps its width, one high at the stop too: none is cut.
                assert_eq!(lines.falls[j].len(), lines.rises[j].len());
                for (rise, fall) in lines.rises[j].iter().zip(&lines.falls[j]) {
                    assert_eq!(
                        fall - rise,
                        500,
                        "stop at {stop_at}, joint {j}: a pulse cut"
                    );
                    kept += usize::from(*fall > stop_at);
                }
                assert!(lines.last[j] <= quiet);
            }
            let last_fall = lines.falls.iter().flatten().copied().max().unwrap_or(0);
            assert_eq!(
                quiet,
                stop_at.max(last_fall),
                "stop at {stop_at}: STEP low from"
            );
            assert_eq!(streams.producer_ref().positions(), lines.pulses);
            assert!(!streams.producer_ref().is_running());
            assert!(!player.is_playing());
            assert_eq!(player.positions(&streams), lines.pulses);
            // Nothing more plays.
            let before = lines.rises.clone();
            player.advance(&mut streams, stop_at + 10_000_000, &mut lines);
            assert_eq!(lines.rises, before);
        }
        assert!(kept >= mid_pulse.len(), "{kept} pulses high at a stop");
    }

    #[test]
    fn positions_while_playing_count_the_played_pulses() {
        for sparse in [false, true] {
            positions_count_the_played_pulses(&segments(sparse));
        }
    }

    fn positions_count_the_played_pulses(segments: &[Segment]) {
        let (mut streams, mut player) = primed(segments);
        let mut lines = Lines::default();
        for t in (0..3_000_000).step_by(77_777) {
            player.advance(&mut streams, t, &mut lines);
            assert_eq!(player.positions(&streams), lines.pulses, "at {t}");
        }
    }

    #[test]
    fn an_idle_joints_halves_are_played_whole() {
        let segments = segments(true);
        let (mut streams, mut player) = primed(&segments);
        let mut lines = Lines::default();
        // (Past the prelude's two idle periods of 100 us.)
        for t in (100_000..2_000_000).step_by(33_333) {
            player.advance(&mut streams, t, &mut lines);
            for j in [1, 2, 4, 5, 6, 7] {
                let next = player.joints[j].next;
                assert!(
                    next >= PRELUDE as u64 && (next - PRELUDE as u64).is_multiple_of(HALF as u64),
                    "joint {j} at {t}: period {next} is not the first of a half"
                );
            }
        }
        // Joints 0 and 3 moved meanwhile.
        assert!(lines.rises[0].len() > 50 && lines.rises[3].len() > 10);
    }
}
