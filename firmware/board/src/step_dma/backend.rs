//! [`BoardSteps`], the board's [`StepBackend`]: arm-step's producer and the DMA buffers
//! driving the joint timers, and [`STEP`], where the tasks and the step interrupts share it
//! behind the step lock (`lock.rs`: BASEPRI at P2, which leaves the DIR interrupt and the
//! e-stop input running). The DIR changes the producer writes go to [`DIRS`], which the
//! step clock's interrupt reads without the lock.

use arm_core::StepShared;
use arm_core::{StepBackend, StepProgress};
use core::sync::atomic::Ordering;

use arm_step::{DirQueues, MAX_JOINTS, PRELUDE, PulsePeriod, Segment, StepTiming, StreamsSlot};

use super::lock::StepLock;
use super::registers::{
    StreamPosition, broken, configure_joint_timer, joint_timer, load_joint, reg, reset_joint_timer,
    stream_position,
};
use super::stop::{KILL, stop_all_step_outputs};
use super::{BUFFERS, HALF, STEP_QUEUE, STEP_TIMING};
use crate::pins;
use crate::step_timer;

/// What the board's step hardware is doing.
#[derive(Clone, Copy, Debug, PartialEq, Eq, defmt::Format)]
enum Run {
    /// Timers stopped, STEP outputs forced low.
    Idle,
    /// A run's start under way, one joint's buffers per piece (timers stopped): joints
    /// below `next` are primed.
    Priming {
        /// The next joint to prime (`MAX_JOINTS`: all primed, the timers start next).
        next: usize,
    },
    /// Timers running since step clock tick `origin`.
    Running {
        /// Step clock tick at which the joint timers started (their tick 0).
        origin: u64,
    },
}

/// The board's [`StepBackend`]: arm-step's producer and buffers driving the timers.
pub struct BoardSteps {
    /// Built by [`super::init`] (an empty slot before, so that the static is all zeros:
    /// .bss, not a 14 KiB .data image copied from flash at boot).
    pub(super) streams: StreamsSlot<STEP_QUEUE, HALF>,
    run: Run,
    /// Per joint: the stream has transferred at least one period (it left the prelude).
    started: [bool; MAX_JOINTS],
    /// Segments finished while priming the run, reported with the next progress.
    primed_finished: u32,
    /// The preludes primed for the run's start (for the timers' registers).
    prelude: [[PulsePeriod; PRELUDE]; MAX_JOINTS],
}

/// The backend shared by the tasks and the step interrupts. Its initial value is all zero
/// bytes (the streams' slot is empty and uninitialised, [`Run::Idle`] is discriminant 0), so
/// it is `.bss`, with nothing in flash and nothing built at boot: `scripts/fw-size.sh` fails
/// if a non-zero byte ever sends its 15 KiB to `.data`. (Built at run time it would pass
/// through `main`'s stack twice: a 31 KB frame.)
pub static STEP: StepShared<STEP_QUEUE, BoardSteps, StepLock> =
    StepShared::with_backend(BoardSteps::new());

/// Every joint's DIR changes, from the producer (refills and the run's start, under the
/// step lock) to the step clock's interrupt (TIM13, which makes them without the lock):
/// arm-step's lock-free queues. The run's start also consumes the changes at tick 0,
/// before it arms the step clock; a stop clears them after disarming it.
pub static DIRS: DirQueues = DirQueues::new();

impl BoardSteps {
    /// Idle, without streams (set by [`super::init`]).
    pub const fn new() -> Self {
        BoardSteps {
            streams: StreamsSlot::EMPTY,
            run: Run::Idle,
            started: [false; MAX_JOINTS],
            primed_finished: 0,
            prelude: [[PulsePeriod::ZERO; PRELUDE]; MAX_JOINTS],
        }
    }
}

impl StepBackend for BoardSteps {
    fn timing(&self) -> StepTiming {
        STEP_TIMING
    }

    fn push(&mut self, segment: Segment) -> Result<(), Segment> {
        self.streams.push(segment)
    }

    fn queued(&self) -> usize {
        self.streams.queued()
    }

    /// Begins a run's start: the producer's new run from `at_tick` (the DIR queues
    /// cleared); the pieces follow ([`BoardSteps::continue_start`]).
    ///
    /// Under the step lock (BASEPRI: the DIR interrupt and the e-stop input run on). The
    /// start is split so that no lock section holds the refills, embassy-time and the
    /// drivers off for the whole priming (issue 20: up to 228 us for 8 joints at 1 kHz in
    /// one section): one joint's prelude and buffer halves per piece, then one piece that
    /// loads and starts the timers.
    fn start(&mut self, at_tick: u64) {
        if self.run != Run::Idle {
            return;
        }
        let Some(streams) = self.streams.get_mut() else {
            return;
        };
        // The segments start this long after the timers' tick 0 (the time the priming
        // takes comes out of the run's start lead, START_LEAD_US).
        let now = step_timer::now_tick();
        // The step clock is disarmed while idle: it does not read DIRS, which this clears.
        streams.prime_begin_shared(at_tick.saturating_sub(now), &DIRS);
        self.primed_finished = 0;
        self.run = Run::Priming { next: 0 };
    }

    fn starting(&self) -> bool {
        matches!(self.run, Run::Priming { .. })
    }

    /// The next piece of the start: one joint primed, or, once all are, the first DIR
    /// levels set and every timer loaded and started.
    ///
    /// The timers are loaded joint by joint and then started, each step a critical
    /// section of under two hundred instructions that first checks [`KILL`]: the e-stop
    /// input's interrupt may come anywhere in between, and once it has forced the outputs
    /// off, none of them may be turned on again. If it came, the start is taken back:
    /// nothing played (no counter ran), so every pulse written is unwound and the run
    /// stays idle.
    #[allow(
        clippy::indexing_slicing,
        reason = "joint < MAX_JOINTS (checked, or enumerate over [_; MAX_JOINTS]): the step path's arrays"
    )]
    fn continue_start(&mut self) {
        let Run::Priming { next } = self.run else {
            return;
        };
        let Some(streams) = self.streams.get_mut() else {
            return;
        };
        if next < MAX_JOINTS {
            // SAFETY: inside STEP's lock with every stream disabled (not running): no one
            // else touches the buffers.
            let buffer = unsafe { &mut (*BUFFERS.0.get())[next] };
            let primed = streams.prime_joint_shared(next, &mut self.prelude[next], buffer, &DIRS);
            self.primed_finished += primed.segments_finished;
            self.run = Run::Priming { next: next + 1 };
            if primed.dir_overflow {
                self.stop();
            }
            return;
        }
        // DIR levels for tick 0 (the run's start): now, before any pulse, as the queues'
        // consumer (the step clock is not armed yet).
        for joint in 0..MAX_JOINTS {
            while let Some(change) = DIRS.peek(joint) {
                if change.tick > 0 {
                    break;
                }
                pins::set_direction(joint, change.positive);
                DIRS.pop(joint);
            }
        }
        for joint in 0..MAX_JOINTS {
            if broken(joint) {
                defmt::warn!("joint {}: its timer's break had cleared the output", joint);
            }
        }
        let mut origin = None;
        let loaded = self.prelude.iter().enumerate().all(|(joint, prelude)| {
            let mut configured = true;
            let unkilled = unless_killed(|| {
                // A fresh timer for every run (issue 20): nothing left from the last one.
                reset_joint_timer(joint);
                match configure_joint_timer(joint) {
                    // The switch from forced-inactive to PWM (load_joint) relies on the
                    // first period having no pulse: one there would rise at the switch,
                    // before the timers start together (issue 34; arm-step's streams test
                    // the_first_prelude_period_has_no_pulse shows the producer never
                    // makes one). Checked, not assumed: the run is refused.
                    Ok(()) if prelude[0].high != 0 => {
                        defmt::error!(
                            "joint {} prelude starts with a pulse ({} ticks): run not started",
                            joint,
                            prelude[0].high
                        );
                        configured = false;
                    }
                    Ok(()) => load_joint(joint, prelude),
                    // Fails loudly (issue 34): no run on a timer that did not take its
                    // output enable or break; stopped as for a kill during the start.
                    Err(e) => {
                        defmt::error!("step timer not configured, run not started: {}", e);
                        configured = false;
                    }
                }
            });
            unkilled && configured
        });
        if loaded {
            unless_killed(|| {
                for joint in 0..MAX_JOINTS {
                    let timer = joint_timer(joint);
                    timer.write(reg::CR1, reg::CR1_URS | reg::CR1_ARPE | reg::CR1_CEN);
                }
                // The step clock runs on; its tick at the joint timers' start is their
                // tick 0. It is read after the counters started, so the DIR alarms (on
                // the step clock) fire a few ticks late rather than early: never while
                // STEP is still high (the DIR setup includes the profile's
                // dir_latency_ns for this and the interrupt's latency).
                origin = Some(step_timer::now_tick());
            });
        }
        let Some(origin) = origin else {
            // The e-stop input opened during the start (its interrupt forced every output
            // off), or a timer did not take its configuration: no counter ran, so nothing
            // played.
            self.stop();
            return;
        };
        step_timer::start_run(origin);
        self.run = Run::Running { origin };
        self.started = [false; MAX_JOINTS];
        self.arm_alarm();
    }

    #[allow(
        clippy::indexing_slicing,
        reason = "joint < MAX_JOINTS (the DMA streams' numbers, or enumerate over [_; MAX_JOINTS]) and half < 2: the step path's arrays"
    )]
    fn stop(&mut self) {
        let stopped = stop_all_step_outputs();
        let Some(streams) = self.streams.get_mut() else {
            return;
        };
        if let Run::Priming { next } = self.run {
            // SAFETY: inside STEP's lock, streams disabled.
            let buffers = unsafe { &*BUFFERS.0.get() };
            // No timer ran: every pulse written for the joints primed so far is unplayed.
            for (joint, buffer) in buffers.iter().enumerate().take(next) {
                streams.unwind_unstarted(joint, buffer);
            }
        } else if self.run != Run::Idle {
            // SAFETY: inside STEP's lock, streams disabled.
            let buffers = unsafe { &*BUFFERS.0.get() };
            for (joint, position) in stopped.iter().enumerate() {
                let first_unplayed = first_unplayed(self.started[joint], *position);
                match first_unplayed {
                    Some(index) if position.preload_evicted => {
                        streams.unwind_evicted(joint, &buffers[joint], index / HALF)
                    }
                    _ => streams.unwind(
                        joint,
                        &buffers[joint],
                        first_unplayed,
                        position.other_half_played,
                    ),
                }
            }
        }
        streams.producer().stop();
        self.run = Run::Idle;
        // Disarmed first: from here on the step clock's interrupt does not read DIRS.
        step_timer::disarm();
        DIRS.clear();
    }

    /// The pulses played so far: the producer's count less what the streams have not
    /// played yet (read from the streams' positions, within a period).
    #[allow(
        clippy::indexing_slicing,
        reason = "joint < MAX_JOINTS (the DMA streams' numbers, or enumerate over [_; MAX_JOINTS]) and half < 2: the step path's arrays"
    )]
    fn positions(&self) -> [i32; MAX_JOINTS] {
        let Some(streams) = self.streams.get() else {
            return [0; MAX_JOINTS];
        };
        let mut positions = streams.producer_ref().positions();
        if let Run::Priming { next } = self.run {
            // SAFETY: inside STEP's lock; only read.
            let buffers = unsafe { &*BUFFERS.0.get() };
            for (joint, buffer) in buffers.iter().enumerate().take(next) {
                positions[joint] -= streams.unstarted_steps(joint, buffer);
            }
        } else if self.run != Run::Idle {
            // SAFETY: inside STEP's lock; only read.
            let buffers = unsafe { &*BUFFERS.0.get() };
            for (joint, position) in positions.iter_mut().enumerate() {
                let at = stream_position(joint);
                let first_unplayed = self.first_unplayed(joint, at);
                *position -= match first_unplayed {
                    Some(index) if at.preload_evicted => {
                        streams.unplayed_evicted(joint, &buffers[joint], index / HALF)
                    }
                    _ => streams.unplayed_steps(
                        joint,
                        &buffers[joint],
                        first_unplayed,
                        at.other_half_played,
                    ),
                };
            }
        }
        positions
    }

    fn set_positions(&mut self, positions: [i32; MAX_JOINTS]) -> bool {
        self.run == Run::Idle
            && self
                .streams
                .get_mut()
                .is_some_and(|s| s.producer().set_positions(positions))
    }

    /// HOLD, RESUME and OVERRIDE (issue 32): the producer takes the warp on the run's
    /// clock (tick 0 = the joint timers' start, `origin` on the step clock), as the
    /// simulator's backend does. The change goes in at the first tick after what it has
    /// written (a buffer half or two ahead of the timers), never before now; while the
    /// start is priming (no timer counts yet) at that first tick. The pulses of a ramp are
    /// then placed by the warp's inversion in the refills (their cost: `scripts/step-cost`,
    /// README).
    fn change_rate(&mut self, now_tick: u64, rate: u64, accel: u32, speed: u32) -> bool {
        let now = match self.run {
            Run::Running { origin } => now_tick.saturating_sub(origin),
            Run::Priming { .. } => 0,
            Run::Idle => return false,
        };
        let Some(streams) = self.streams.get_mut() else {
            return false;
        };
        let producer = streams.producer();
        let ramp = arm_step::ramp_for(accel, speed, STEP_TIMING.tick_hz);
        let at = now.max(producer.warp_horizon());
        producer.change_warp(at, rate, ramp).is_ok()
    }

    fn set_start_rate(&mut self, _at_tick: u64, rate: u64) -> bool {
        // The run's clock starts at 0 (the timers' start): the rate from there.
        let Some(streams) = self.streams.get_mut() else {
            return false;
        };
        self.run == Run::Idle
            && arm_step::Warp::steady(0, rate).is_ok_and(|warp| streams.producer().set_warp(warp))
    }

    fn warp_budget_hz(&self) -> u32 {
        super::PROFILE.warp_budget_hz
    }

    fn rate_now(&self, now_tick: u64) -> Option<(u64, bool)> {
        let tick = match self.run {
            Run::Running { origin } => now_tick.saturating_sub(origin),
            Run::Priming { .. } => 0,
            Run::Idle => return None,
        };
        let warp = self.streams.get()?.producer_ref().warp();
        Some((warp.rate(tick), warp.ramping(tick)))
    }
}

impl BoardSteps {
    /// The first period of `joint`'s stream that has not started, from where the stream
    /// stands (`None`: the prelude's second period has not either).
    #[allow(
        clippy::indexing_slicing,
        reason = "joint < MAX_JOINTS (the DMA streams' numbers, or enumerate over [_; MAX_JOINTS]) and half < 2: the step path's arrays"
    )]
    fn first_unplayed(&self, joint: usize, at: StreamPosition) -> Option<usize> {
        first_unplayed(self.started[joint], at)
    }

    /// Refills the half of `joint`'s buffer its stream just left.
    #[allow(
        clippy::indexing_slicing,
        reason = "joint < MAX_JOINTS (the DMA streams' numbers, or enumerate over [_; MAX_JOINTS]) and half < 2: the step path's arrays"
    )]
    pub(super) fn refill(&mut self, joint: usize, half: usize) -> StepProgress {
        if !matches!(self.run, Run::Running { .. }) {
            return StepProgress::default();
        }
        let Some(streams) = self.streams.get_mut() else {
            return StepProgress::default();
        };
        self.started[joint] = true;
        // SAFETY: inside STEP's lock; the stream reads the other half (checked
        // by the caller).
        let buffer = unsafe { &mut (*BUFFERS.0.get())[joint] };
        let refill = streams.refill_shared(joint, half, &mut buffer.periods[half], &DIRS);
        if refill.dir_overflow {
            self.stop();
            return StepProgress {
                segments_finished: 0,
                ran_dry: true,
            };
        }
        self.arm_alarm();
        StepProgress {
            segments_finished: refill.segments_finished
                + core::mem::take(&mut self.primed_finished),
            ran_dry: false,
        }
    }

    /// The step service interrupt's work (`service.rs`), pended by the step clock when the
    /// run's end it was given has come: ends the run if nothing was pushed since (every
    /// pulse played, the last segment over), else hands the step clock the new end.
    /// `now` = step clock tick.
    pub fn on_service(&mut self, now: u64) -> StepProgress {
        let Run::Running { origin } = self.run else {
            return StepProgress::default();
        };
        let Some(streams) = self.streams.get_mut() else {
            return StepProgress::default();
        };
        let at = now.saturating_sub(origin);
        if let Some(end) = streams.producer_ref().run_end_tick()
            && at >= end
        {
            // Every pulse played and the last segment over: outputs low, streams off.
            stop_all_step_outputs();
            streams.producer().end_run();
            self.run = Run::Idle;
            step_timer::disarm();
            return StepProgress {
                segments_finished: core::mem::take(&mut self.primed_finished),
                ran_dry: true,
            };
        }
        self.arm_alarm();
        StepProgress::default()
    }

    /// Hands the step clock the earliest queued DIR change and the run's end (if known).
    fn arm_alarm(&mut self) {
        if !matches!(self.run, Run::Running { .. }) {
            return;
        }
        let Some(streams) = self.streams.get() else {
            return;
        };
        step_timer::arm(DIRS.earliest(), streams.producer_ref().run_end_tick());
    }
}

/// Runs `enable` (writes that turn a timer or stream on) in a critical section, unless the
/// e-stop input's interrupt has forced the outputs off ([`KILL`]); false if it had. Inside
/// the section the interrupt cannot come, so an output is never turned on after it.
fn unless_killed(enable: impl FnOnce()) -> bool {
    critical_section::with(|_| {
        if KILL.load(Ordering::SeqCst) {
            return false;
        }
        enable();
        true
    })
}

/// The first period of a stream that has not started, from where it stands (`None`: the
/// prelude's second period has not either); `started`: it has left the prelude.
fn first_unplayed(started: bool, at: StreamPosition) -> Option<usize> {
    // The period in the preload register (the one before `next`) has not started either.
    (started || at.next > 0).then_some((at.next + 2 * HALF - 1) % (2 * HALF))
}
