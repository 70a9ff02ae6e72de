//! [`BoardSteps`], the board's [`StepBackend`]: arm-step's producer and the DMA buffers
//! driving the joint timers, and [`STEP`], where the tasks and the step interrupts share it.

use arm_core::StepShared;
use arm_core::{StepBackend, StepProgress};
use arm_step::{DirChange, MAX_JOINTS, PRELUDE, PulsePeriod, Segment, StepTiming, StreamsSlot};

use super::registers::{
    StreamPosition, broken, configure_joint_timer, joint_timer, load_joint, reg, reset_joint_timer,
    stream_position,
};
use super::stop::stop_all_step_outputs;
use super::{BUFFERS, HALF, STEP_QUEUE, STEP_TIMING};
use crate::pins;
use crate::step_timer;

/// What the board's step hardware is doing.
#[derive(Clone, Copy, Debug, PartialEq, Eq, defmt::Format)]
enum Run {
    /// Timers stopped, STEP outputs forced low.
    Idle,
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
    /// The run's end (timeline ticks) has been handed to the step clock.
    end_armed: bool,
    /// Segments finished while priming the run, reported with the next progress.
    primed_finished: u32,
}

/// The backend shared by the tasks and the step interrupts. Its initial value is all zero
/// bytes (the streams' slot is empty and uninitialised, [`Run::Idle`] is discriminant 0), so
/// it is `.bss`, with nothing in flash and nothing built at boot: `scripts/fw-size.sh` fails
/// if a non-zero byte ever sends its 15 KiB to `.data`. (Built at run time it would pass
/// through `main`'s stack twice: a 31 KB frame.)
pub static STEP: StepShared<STEP_QUEUE, BoardSteps> = StepShared::with_backend(BoardSteps::new());

impl BoardSteps {
    /// Idle, without streams (set by [`super::init`]).
    pub const fn new() -> Self {
        BoardSteps {
            streams: StreamsSlot::EMPTY,
            run: Run::Idle,
            started: [false; MAX_JOINTS],
            end_armed: false,
            primed_finished: 0,
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

    /// Primes every joint's prelude and buffer (the producer's work for the run's first
    /// 2 * HALF periods), sets the first DIR levels and starts all timers together.
    fn start(&mut self, at_tick: u64) {
        if self.run != Run::Idle {
            return;
        }
        let Some(streams) = self.streams.get_mut() else {
            return;
        };
        let now = step_timer::now_tick();
        let mut prelude = [[PulsePeriod::ZERO; PRELUDE]; MAX_JOINTS];
        // SAFETY: inside STEP's critical section with every stream disabled (Idle): no
        // one else touches the buffers.
        let buffers = unsafe { &mut *BUFFERS.0.get() };
        let [b0, b1, b2, b3, b4, b5, b6, b7] = buffers;
        let primed = streams.prime(
            at_tick.saturating_sub(now),
            &mut prelude,
            &mut [b0, b1, b2, b3, b4, b5, b6, b7],
        );
        if primed.dir_overflow {
            streams.producer().stop();
            return;
        }
        // DIR levels for tick 0 (the run's start): now, before any pulse.
        for joint in 0..MAX_JOINTS {
            while let Some(change) = streams.next_dir_change(joint) {
                if change.tick > 0 {
                    break;
                }
                pins::set_direction(joint, change.positive);
                streams.pop_dir_change(joint);
            }
        }
        for (joint, prelude) in prelude.iter().enumerate() {
            if broken(joint) {
                defmt::warn!("joint {}: its timer's break had cleared the output", joint);
            }
            // A fresh timer for every run (issue 20): nothing left from the last one.
            reset_joint_timer(joint);
            configure_joint_timer(joint);
            load_joint(joint, prelude);
        }
        for joint in 0..MAX_JOINTS {
            let timer = joint_timer(joint);
            timer.write(reg::CR1, reg::CR1_URS | reg::CR1_ARPE | reg::CR1_CEN);
        }
        // The step clock runs on; its tick at the joint timers' start is their tick 0.
        // It is read after the counters started, so the DIR alarms (on the step clock)
        // fire a few ticks late rather than early: never while STEP is still high (the
        // DIR setup includes the profile's dir_latency_ns for this and the interrupt's latency).
        let origin = step_timer::now_tick();
        self.run = Run::Running { origin };
        self.primed_finished = primed.segments_finished;
        self.started = [false; MAX_JOINTS];
        self.end_armed = false;
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
        if self.run != Run::Idle {
            // SAFETY: inside STEP's critical section, streams disabled.
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
        streams.clear_dir_changes();
        self.run = Run::Idle;
        step_timer::disarm();
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
        if self.run != Run::Idle {
            // SAFETY: inside STEP's critical section; only read.
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
        if self.run == Run::Idle {
            return StepProgress::default();
        }
        let Some(streams) = self.streams.get_mut() else {
            return StepProgress::default();
        };
        self.started[joint] = true;
        // SAFETY: inside STEP's critical section; the stream reads the other half (checked
        // by the caller).
        let buffer = unsafe { &mut (*BUFFERS.0.get())[joint] };
        let refill = streams.refill(joint, half, &mut buffer.periods[half]);
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

    /// The step clock's alarm: makes the DIR changes that are due and ends the run when
    /// its end is reached. `now` = step clock tick.
    pub fn on_alarm(&mut self, now: u64) -> StepProgress {
        let Run::Running { origin } = self.run else {
            return StepProgress::default();
        };
        let Some(streams) = self.streams.get_mut() else {
            return StepProgress::default();
        };
        let at = now.saturating_sub(origin);
        for joint in 0..MAX_JOINTS {
            while let Some(DirChange { tick, positive }) = streams.next_dir_change(joint) {
                if tick > at {
                    break;
                }
                pins::set_direction(joint, positive);
                streams.pop_dir_change(joint);
            }
        }
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

    /// Arms the step clock at the earliest pending DIR change or the run's end.
    fn arm_alarm(&mut self) {
        let Run::Running { origin } = self.run else {
            return;
        };
        let Some(streams) = self.streams.get() else {
            return;
        };
        let mut next = u64::MAX;
        for joint in 0..MAX_JOINTS {
            if let Some(change) = streams.next_dir_change(joint) {
                next = next.min(change.tick);
            }
        }
        if let Some(end) = streams.producer_ref().run_end_tick() {
            next = next.min(end);
            self.end_armed = true;
        }
        if next != u64::MAX {
            step_timer::arm(origin + next);
        }
    }
}

/// The first period of a stream that has not started, from where it stands (`None`: the
/// prelude's second period has not either); `started`: it has left the prelude.
fn first_unplayed(started: bool, at: StreamPosition) -> Option<usize> {
    // The period in the preload register (the one before `next`) has not started either.
    (started || at.next > 0).then_some((at.next + 2 * HALF - 1) % (2 * HALF))
}
