//! Simulated stepper drivers: the STEP/DIR lines the step engine drives, counted and traced.
//!
//! Each rising STEP edge moves the simulated motor one step in the direction its DIR line
//! gives: that is the arm's *physical* position, which the simulated encoders read and the
//! trace records. It is counted independently of the step engine's own position counters,
//! so a test comparing the two checks the engine.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicI64, AtomicU8, AtomicU64, Ordering};

use arm_step::{JointMask, MAX_JOINTS, StepPins};

use crate::clock::SimClock;
use crate::vcd::{Signal, Tracer, Value};

/// What the simulated motors did; shared between the step thread and everyone who looks.
#[derive(Debug, Default)]
pub struct MotorState {
    /// Physical position of each motor in steps (pulses counted with their direction).
    pub position: [AtomicI64; MAX_JOINTS],
    /// Rising STEP edges per joint.
    pub pulses: [AtomicU64; MAX_JOINTS],
    /// DIR line of each joint (true = positive).
    pub direction: [AtomicBool; MAX_JOINTS],
    /// STEP lines currently high.
    pub step_high: AtomicU8,
    /// DIR changes made while that joint's STEP line was high (a driver would miscount).
    pub dir_while_high: AtomicU64,
    /// Simulated nanoseconds of the last rising STEP edge of any joint.
    pub last_pulse_ns: AtomicU64,
}

impl MotorState {
    /// Positions of all joints.
    pub fn positions(&self) -> [i64; MAX_JOINTS] {
        core::array::from_fn(|j| self.position[j].load(Ordering::Relaxed))
    }

    /// Pulse counts of all joints.
    pub fn pulse_counts(&self) -> [u64; MAX_JOINTS] {
        core::array::from_fn(|j| self.pulses[j].load(Ordering::Relaxed))
    }
}

/// When the edges a [`SimSteppers`] makes happen.
#[derive(Clone, Copy, Debug)]
enum EdgeTime {
    /// At the tick the step engine is being polled for (the step thread sets it).
    Tick(u64),
    /// Whenever the call happens (a task stopping the engine).
    Now,
}

/// [`StepPins`] for the simulated drivers.
#[derive(Clone, Debug)]
pub struct SimSteppers {
    motors: Arc<MotorState>,
    tracer: Tracer,
    clock: SimClock,
    time: EdgeTime,
}

impl SimSteppers {
    /// Drivers whose motors are `motors`.
    pub fn new(motors: Arc<MotorState>, tracer: Tracer, clock: SimClock) -> SimSteppers {
        SimSteppers {
            motors,
            tracer,
            clock,
            time: EdgeTime::Now,
        }
    }

    /// The edges of the following calls happen at step timer tick `tick`.
    pub fn set_tick(&mut self, tick: u64) {
        self.time = EdgeTime::Tick(tick);
    }

    /// The edges of the following calls happen when they are made.
    pub fn set_now(&mut self) {
        self.time = EdgeTime::Now;
    }

    /// The motors these drivers move.
    pub fn motors(&self) -> &Arc<MotorState> {
        &self.motors
    }

    fn now_ns(&self) -> u64 {
        match self.time {
            EdgeTime::Tick(tick) => self.clock.tick_to_ns(tick),
            EdgeTime::Now => self.clock.now_ns(),
        }
    }
}

impl StepPins for SimSteppers {
    fn set_direction(&mut self, joint: usize, positive: bool) {
        let Some(direction) = self.motors.direction.get(joint) else {
            return;
        };
        if direction.swap(positive, Ordering::Relaxed) != positive {
            if self.motors.step_high.load(Ordering::Relaxed) & (1 << joint) != 0 {
                self.motors.dir_while_high.fetch_add(1, Ordering::Relaxed);
            }
            self.tracer.record_at(
                self.now_ns(),
                Signal::Dir(joint as u8),
                Value::Bit(positive),
            );
        }
    }

    fn step_high(&mut self, joints: JointMask) {
        let before = self.motors.step_high.fetch_or(joints, Ordering::Relaxed);
        let rising = joints & !before;
        if rising == 0 {
            return;
        }
        let t_ns = self.now_ns();
        for j in 0..MAX_JOINTS {
            if rising & (1 << j) == 0 {
                continue;
            }
            let delta = if self.motors.direction[j].load(Ordering::Relaxed) {
                1
            } else {
                -1
            };
            self.motors.position[j].fetch_add(delta, Ordering::Relaxed);
            self.motors.pulses[j].fetch_add(1, Ordering::Relaxed);
            self.tracer
                .record_at(t_ns, Signal::Step(j as u8), Value::Bit(true));
        }
        self.motors.last_pulse_ns.store(t_ns, Ordering::Relaxed);
    }

    fn step_low(&mut self, joints: JointMask) {
        let before = self.motors.step_low_mask(joints);
        let falling = joints & before;
        if falling == 0 {
            return;
        }
        let t_ns = self.now_ns();
        for j in 0..MAX_JOINTS {
            if falling & (1 << j) != 0 {
                self.tracer
                    .record_at(t_ns, Signal::Step(j as u8), Value::Bit(false));
            }
        }
    }
}

impl MotorState {
    /// Lowers the STEP lines in `joints`; returns the mask before.
    fn step_low_mask(&self, joints: JointMask) -> JointMask {
        self.step_high.fetch_and(!joints, Ordering::Relaxed)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pulses_are_counted_with_direction() {
        let motors = Arc::new(MotorState::default());
        let mut pins = SimSteppers::new(
            motors.clone(),
            Tracer::disabled(),
            SimClock::new(1.0, 1_000_000),
        );
        pins.set_direction(1, true);
        for _ in 0..5 {
            pins.step_high(0b10);
            pins.step_low(0b10);
        }
        pins.set_direction(1, false);
        pins.step_high(0b11);
        // Raising a line already high is no new pulse.
        pins.step_high(0b11);
        pins.step_low(0b11);
        assert_eq!(motors.positions()[1], 4);
        assert_eq!(motors.positions()[0], -1);
        assert_eq!(motors.pulse_counts()[1], 6);
        assert_eq!(motors.dir_while_high.load(Ordering::Relaxed), 0);
        pins.step_high(0b1);
        pins.set_direction(0, true);
        assert_eq!(motors.dir_while_high.load(Ordering::Relaxed), 1);
    }
}
