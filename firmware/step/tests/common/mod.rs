//! Test harness: a recording `StepPins`, a fake tick clock that jumps to each deadline, and
//! an independent model of when every pulse should rise (exact rational time, u128).
#![allow(dead_code)]

use arm_step::{JointMask, MAX_JOINTS, Poll, Segment, StepEngine, StepPins, StepTiming};

/// The board's timing with its opto drivers: 200 MHz timers, 2.5 us STEP high and low,
/// 10 us DIR setup (the drivers' 5 us and the board's interrupt latency).
pub const BOARD_TIMING: StepTiming = StepTiming {
    tick_hz: 200_000_000,
    pulse_width_ticks: 500,
    dir_setup_ticks: 2_000,
    step_low_ticks: 500,
};

/// What happened on a line.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Edge {
    Rise,
    Fall,
    /// STEP lowered by `stop` (may cut a pulse short).
    Cut,
    Dir(bool),
}

/// One recorded line change.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Event {
    pub tick: u64,
    pub joint: usize,
    pub edge: Edge,
}

/// Records every call with the fake clock's current tick and checks the electrical rules
/// as they happen.
#[derive(Debug, Default)]
pub struct Recorder {
    pub now: u64,
    pub events: Vec<Event>,
    pub step_high: [bool; MAX_JOINTS],
    pub dir: [Option<bool>; MAX_JOINTS],
    /// `stop` lowers every line, including low ones.
    pub stopping: bool,
    pub calls: usize,
}

impl StepPins for Recorder {
    fn set_direction(&mut self, joint: usize, positive: bool) {
        assert!(joint < MAX_JOINTS);
        assert!(
            !self.step_high[joint],
            "DIR of joint {joint} changed while STEP high at {}",
            self.now
        );
        self.dir[joint] = Some(positive);
        self.events.push(Event {
            tick: self.now,
            joint,
            edge: Edge::Dir(positive),
        });
        self.calls += 1;
    }

    fn step_high(&mut self, joints: JointMask) {
        assert_ne!(joints, 0, "step_high with an empty mask");
        for joint in 0..MAX_JOINTS {
            if joints & (1 << joint) != 0 {
                assert!(
                    !self.step_high[joint],
                    "joint {joint} raised twice at {}",
                    self.now
                );
                assert!(self.dir[joint].is_some(), "pulse before any DIR on {joint}");
                self.step_high[joint] = true;
                self.events.push(Event {
                    tick: self.now,
                    joint,
                    edge: Edge::Rise,
                });
            }
        }
        self.calls += 1;
    }

    fn step_low(&mut self, joints: JointMask) {
        assert_ne!(joints, 0, "step_low with an empty mask");
        for joint in 0..MAX_JOINTS {
            if joints & (1 << joint) != 0 {
                if !self.step_high[joint] {
                    assert!(
                        self.stopping,
                        "joint {joint} lowered while low at {}",
                        self.now
                    );
                    continue;
                }
                self.step_high[joint] = false;
                self.events.push(Event {
                    tick: self.now,
                    joint,
                    edge: if self.stopping { Edge::Cut } else { Edge::Fall },
                });
            }
        }
        self.calls += 1;
    }
}

impl Recorder {
    /// Rising ticks of one joint, in order, with the DIR level at each.
    pub fn rises(&self, joint: usize) -> Vec<(u64, bool)> {
        let mut dir = None;
        let mut out = Vec::new();
        for event in self.events.iter().filter(|e| e.joint == joint) {
            match event.edge {
                Edge::Dir(level) => dir = Some(level),
                Edge::Rise => out.push((event.tick, dir.expect("DIR set before a pulse"))),
                Edge::Fall | Edge::Cut => {}
            }
        }
        out
    }

    /// Pulses per joint.
    pub fn pulse_counts(&self) -> [usize; MAX_JOINTS] {
        let mut counts = [0; MAX_JOINTS];
        for event in &self.events {
            if event.edge == Edge::Rise {
                counts[event.joint] += 1;
            }
        }
        counts
    }

    /// Signed pulses per joint (what the positions must have moved by).
    pub fn signed_pulses(&self) -> [i32; MAX_JOINTS] {
        let mut moved = [0; MAX_JOINTS];
        for (joint, slot) in moved.iter_mut().enumerate() {
            for (_, positive) in self.rises(joint) {
                *slot += if positive { 1 } else { -1 };
            }
        }
        moved
    }

    /// Checks the timing rules per joint over the whole record: pulse width, STEP low at
    /// least one tick, DIR setup before the next rise, ticks never going back.
    pub fn check_timing(&self, timing: &StepTiming) {
        let width = u64::from(timing.pulse_width_ticks.max(1));
        let setup = u64::from(timing.dir_setup_ticks);
        let mut last_tick = 0;
        for event in &self.events {
            assert!(event.tick >= last_tick, "time went back: {event:?}");
            last_tick = event.tick;
        }
        for joint in 0..MAX_JOINTS {
            let mut high_since: Option<u64> = None;
            let mut low_since: Option<u64> = None;
            let mut dir_at: Option<u64> = None;
            for event in self.events.iter().filter(|e| e.joint == joint) {
                match event.edge {
                    Edge::Rise => {
                        assert!(high_since.is_none());
                        if let Some(low) = low_since {
                            assert!(
                                event.tick > low,
                                "joint {joint}: no low time at {}",
                                event.tick
                            );
                        }
                        if let Some(dir) = dir_at {
                            assert!(
                                event.tick >= dir + setup,
                                "joint {joint}: rise at {} only {} after DIR",
                                event.tick,
                                event.tick - dir
                            );
                        }
                        high_since = Some(event.tick);
                    }
                    Edge::Fall => {
                        let rise = high_since.take().expect("fall without rise");
                        low_since = Some(event.tick);
                        assert!(
                            event.tick >= rise + width,
                            "joint {joint}: pulse at {rise} only {} wide",
                            event.tick - rise
                        );
                    }
                    Edge::Cut => {
                        assert!(high_since.take().is_some(), "cut without rise");
                        low_since = Some(event.tick);
                    }
                    Edge::Dir(_) => {
                        assert!(high_since.is_none(), "DIR changed while STEP high");
                        dir_at = Some(event.tick);
                    }
                }
            }
        }
    }
}

/// What a drive loop saw.
#[derive(Debug, Default)]
pub struct Outcome {
    /// Every poll: the tick it ran at and what it returned.
    pub polls: Vec<(u64, Poll)>,
    /// Tick of the poll that reported running dry.
    pub dry_at: Option<u64>,
}

impl Outcome {
    pub fn segments_finished(&self) -> u64 {
        self.polls
            .iter()
            .map(|(_, p)| u64::from(p.segments_finished))
            .sum()
    }
}

/// Polls at `first_poll`, then at each returned deadline plus `latency()`, pushing from
/// `feed` whenever a slot is free (as the controller's task would), until the engine runs
/// dry, `until` is passed, or `max_polls` polls.
pub fn drive<const Q: usize>(
    engine: &mut StepEngine<Q>,
    pins: &mut Recorder,
    first_poll: u64,
    feed: &mut dyn Iterator<Item = Segment>,
    mut latency: impl FnMut() -> u64,
    until: u64,
    max_polls: usize,
) -> Outcome {
    let mut outcome = Outcome::default();
    let mut now = first_poll;
    for _ in 0..max_polls {
        while engine.free_slots() > 0 {
            match feed.next() {
                Some(segment) => assert!(engine.push(segment).is_ok()),
                None => break,
            }
        }
        pins.now = now;
        let poll = engine.poll(now, pins);
        outcome.polls.push((now, poll));
        if poll.ran_dry {
            assert_eq!(poll.next_deadline, None);
            assert!(!engine.is_running());
            outcome.dry_at = Some(now);
            return outcome;
        }
        let deadline = poll.next_deadline.expect("running engine gives a deadline");
        assert!(deadline > now, "deadline {deadline} not after {now}");
        if deadline > until {
            return outcome;
        }
        now = deadline + latency();
    }
    panic!("engine still running after {max_polls} polls");
}

/// The model: ideal rising ticks of each joint, as exact rationals floored, computed with
/// u128 from the cumulative microseconds (independent of the engine's incremental clock).
pub struct Model {
    /// Per joint: (exact numerator, denominator, floor tick, positive) for each pulse.
    pub pulses: Vec<Vec<Ideal>>,
    /// Per segment: its end tick, absolute.
    pub segment_ends: Vec<u64>,
    /// Per segment and joint: the tick of its last pulse there, if it moves.
    pub last_pulse: Vec<[Option<u64>; MAX_JOINTS]>,
}

/// One pulse's ideal time `num / den` ticks and its floor.
#[derive(Clone, Copy, Debug)]
pub struct Ideal {
    pub num: u128,
    pub den: u128,
    pub tick: u64,
    pub positive: bool,
}

impl Ideal {
    /// Whether `tick` is within one tick of the exact ideal time.
    pub fn within_one_tick(&self, tick: u64) -> bool {
        let t = u128::from(tick) * self.den;
        t + self.den > self.num && t < self.num + self.den
    }
}

impl Model {
    pub fn new(segments: &[Segment], start_tick: u64, tick_hz: u32) -> Self {
        let hz = u128::from(tick_hz);
        let mut pulses = vec![Vec::new(); MAX_JOINTS];
        let mut segment_ends = Vec::new();
        let mut last_pulse = Vec::new();
        let mut cum_us: u128 = 0;
        for segment in segments {
            let dur = u128::from(segment.duration_us);
            let mut last = [None; MAX_JOINTS];
            for joint in 0..MAX_JOINTS {
                let steps = segment.steps[joint];
                let n = u128::from(steps.unsigned_abs());
                for i in 1..=n {
                    // start + (cum + i * dur / n) * hz / 1e6
                    let den = 1_000_000 * n;
                    let num = u128::from(start_tick) * den + (cum_us * n + i * dur) * hz;
                    let tick = (num / den) as u64;
                    pulses[joint].push(Ideal {
                        num,
                        den,
                        tick,
                        positive: steps > 0,
                    });
                    last[joint] = Some(tick);
                }
            }
            cum_us += dur;
            segment_ends.push(start_tick + (cum_us * hz / 1_000_000) as u64);
            last_pulse.push(last);
        }
        Model {
            pulses,
            segment_ends,
            last_pulse,
        }
    }

    /// Asserts that every joint pulsed exactly as the model says: same count, same
    /// direction, each at its ideal tick (floor of the exact time).
    pub fn assert_exact(&self, pins: &Recorder) {
        for joint in 0..MAX_JOINTS {
            let rises = pins.rises(joint);
            let ideal = &self.pulses[joint];
            assert_eq!(rises.len(), ideal.len(), "joint {joint}: pulse count");
            for (k, ((tick, positive), ideal)) in rises.iter().zip(ideal).enumerate() {
                assert_eq!(
                    *positive, ideal.positive,
                    "joint {joint} pulse {k}: direction"
                );
                assert!(
                    ideal.within_one_tick(*tick),
                    "joint {joint} pulse {k}: {tick} vs exact {}/{}",
                    ideal.num,
                    ideal.den
                );
                assert_eq!(*tick, ideal.tick, "joint {joint} pulse {k}: tick");
            }
        }
    }

    /// Asserts that no pulse was dropped or repeated and that each joint's pulses stay in
    /// order, not before their ideal tick (they may be late).
    pub fn assert_complete_in_order(&self, pins: &Recorder) {
        for joint in 0..MAX_JOINTS {
            let rises = pins.rises(joint);
            let ideal = &self.pulses[joint];
            assert_eq!(rises.len(), ideal.len(), "joint {joint}: pulse count");
            let mut previous = None;
            for ((tick, positive), ideal) in rises.iter().zip(ideal) {
                assert_eq!(*positive, ideal.positive, "joint {joint}: direction");
                assert!(*tick >= ideal.tick, "joint {joint}: pulse early");
                if let Some(previous) = previous {
                    assert!(*tick > previous, "joint {joint}: pulses out of order");
                }
                previous = Some(*tick);
            }
        }
    }

    /// Total pulses over all joints.
    pub fn total_pulses(&self) -> usize {
        self.pulses.iter().map(Vec::len).sum()
    }
}

/// Sum of the steps per joint.
pub fn net_steps(segments: &[Segment]) -> [i32; MAX_JOINTS] {
    let mut net = [0; MAX_JOINTS];
    for segment in segments {
        for (slot, steps) in net.iter_mut().zip(segment.steps) {
            *slot += steps;
        }
    }
    net
}

/// A segment moving only `joint`.
pub fn one_joint(duration_us: u32, joint: usize, steps: i32) -> Segment {
    let mut segment = Segment {
        duration_us,
        steps: [0; MAX_JOINTS],
    };
    segment.steps[joint] = steps;
    segment
}

/// Loads `segments` (all must fit), starts at `start_tick` with a first poll
/// `lead` ticks before it, and runs to dry with no latency.
pub fn run_all<const Q: usize>(
    timing: StepTiming,
    segments: &[Segment],
    start_tick: u64,
    lead: u64,
) -> (StepEngine<Q>, Recorder, Outcome) {
    let mut engine = StepEngine::<Q>::new(timing);
    let mut pins = Recorder::default();
    let mut feed = segments.iter().copied();
    engine.start(start_tick);
    let outcome = drive(
        &mut engine,
        &mut pins,
        start_tick - lead,
        &mut feed,
        || 0,
        u64::MAX,
        10_000_000,
    );
    (engine, pins, outcome)
}
