//! Step pulse timing, in two forms that give the same edges:
//!
//! - [`PulseProducer`] / [`StepStreams`]: what the board runs. Each joint's STEP line is a
//!   timer whose periods a DMA stream reloads from a double buffer; the producer computes
//!   those periods (one division per segment, additions per pulse) when a buffer half is
//!   freed. Where there is no such timer (sim-host, the QEMU board), [`StreamPlayer`]
//!   plays the same buffers in software, refilling at the same points.
//! - [`StepEngine`]: edges made by an interrupt at each deadline, kept as the test oracle
//!   (`tests/producer.rs` compares the two on more than 10 million pulses).
//!
//! Both take a [`Warp`] (HOLD, RESUME, speed override: a monotone map from controller to
//! trajectory time): pulses are placed on trajectory time by the rule below and rise when
//! the warp reaches them (see `warp.rs`).
//!
//! The rule both follow:
//!
//! The trajectory is handed over as [`Segment`]s (a duration and a signed step count per
//! joint). Segment `k` starts at `start_tick + floor(cum_us_k * tick_hz / 1e6)`, where
//! `cum_us_k` is the sum of the earlier durations, so segments chain with no gap and no
//! rounding error accumulates, even when the tick rate is not a multiple of 1 MHz. Pulse `i`
//! (1..=N) of a joint moving `N` steps in a segment of `D` ticks rises at `S + floor(i * D /
//! N)`, where `S` and `D` are the segment's exact (rational) start and length in ticks: the
//! floor of the pulse's exact time, so every pulse is less than one tick after its ideal
//! time and the last one lands exactly on the segment's end tick. (When the segment bounds
//! fall on whole ticks, as at any whole-MHz tick rate, this is the integer formula with
//! `S` and `D` in ticks.) It is computed incrementally with a remainder, one u64 division
//! per segment and joint, none per pulse.
//!
//! Direction lines change only while STEP is low, right after the joint's previous pulse
//! ends, and the next pulse is never raised sooner than `dir_setup_ticks` after the change,
//! nor sooner than `step_low_ticks` after the previous pulse ended: if a segment asks for
//! more than [`StepTiming::max_step_rate_hz`] (or reverses at a rate that leaves no room
//! for the setup time), pulses are delayed (and counted, [`StepEngine::late_pulses`]),
//! never dropped.
//!
//! The engine is sans-io: the timer interrupt calls [`StepEngine::poll`] with the current
//! tick and a [`StepPins`] implementation, and re-arms its compare register for the
//! returned deadline. `poll` does no allocation and no division per pulse; its cost per
//! edge barely depends on how many joints move (a small tournament tree keeps the next
//! deadline).
#![no_std]
#![warn(missing_docs)]
// Tests index and unwrap freely: a failing test is meant to panic.
#![cfg_attr(not(test), warn(clippy::indexing_slicing, clippy::unwrap_used))]
#![cfg_attr(not(test), warn(clippy::cast_possible_truncation))]

/// Writes each `field: value` through the pointer `$slot`, where the field lies: the
/// in-place constructors (`StepStreams::init_in_place`, `PulseProducer::init_in_place`),
/// called with their `with_idle_fields` lists. Unsafe: `$slot` must be valid for writes.
macro_rules! write_fields {
    ($slot:expr ; $($field:ident : $value:expr),* $(,)?) => {{
        $( (&raw mut (*$slot).$field).write($value); )*
    }};
}

/// Writes `value` into every element of `array`, element by element (never a whole array
/// on the stack first).
///
/// # Safety
/// `array` is valid for writes and aligned.
pub(crate) unsafe fn write_each<T: Copy, const N: usize>(array: *mut [T; N], value: T) {
    let first = array.cast::<T>();
    for i in 0..N {
        // SAFETY: the caller's guarantee; `i < N`, inside the array.
        unsafe { first.add(i).write(value) };
    }
}

mod dir_queue;
mod engine;
mod joint;
mod player;
mod producer;
mod ring;
mod schedule;
mod stream;
mod warp;

pub use dir_queue::DirQueues;
pub use engine::StepEngine;
pub use player::{Advance, HaltingStepPins, StreamPlayer, TimedStepPins};
pub use producer::{Filled, PulsePeriod, PulseProducer, sign_of};
pub use stream::{DirChange, JointBuffer, PRELUDE, Refill, StepStreams, StreamsSlot};
pub use warp::{MAX_RATE, RATE_ONE, WARP_PHASES, Warp, WarpError, ramp_for};

/// Joints the engine drives.
pub const MAX_JOINTS: usize = 8;

/// The NUCLEO-H743ZI2's step timers: the longest period each joint's timer makes, 2^32
/// ticks for TIM2 and TIM5 (32-bit, joints 0-1: 21 s at 200 MHz), 2^16 for the 16-bit ones
/// (joints 2-7: 328 us; longer gaps are split into periods without a pulse). The board
/// builds its [`StepStreams`] with it; sim-host and the benchmarks (step-cost, the
/// scheduler bench) run the board's ranges.
pub const NUCLEO_STEP_TIMER_MAX_PERIOD_TICKS: [u32; MAX_JOINTS] = [
    u32::MAX,
    u32::MAX,
    1 << 16,
    1 << 16,
    1 << 16,
    1 << 16,
    1 << 16,
    1 << 16,
];

/// The NUCLEO-H743ZI2's periods per DMA buffer half (the `HALF` of its [`StepStreams`]): at
/// 500 kHz a half plays for 128 us, so a refill interrupt may wait that long; 64 keeps the
/// refill's fixed cost (about 250 instructions) to 4 per step. 2 * 64 * 12 bytes per joint.
/// sim-host and step-cost play the board's halves.
pub const NUCLEO_STEP_BUFFER_HALF: usize = 64;

/// Bit `j` = joint `j`.
pub type JointMask = u8;

/// Every joint.
const ALL_JOINTS: JointMask = 0xFF;

/// Microseconds per second: segment durations are in microseconds.
const US_PER_S: u64 = 1_000_000;

/// One trajectory segment as the engine sees it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Segment {
    /// Length in microseconds (>= 1).
    pub duration_us: u32,
    /// Signed steps per joint; the sign is the direction (positive = DIR high).
    pub steps: [i32; MAX_JOINTS],
}

/// Sets each joint's step counter (`counter`) to `positions`, unless a run is under way
/// (then false): `set_positions` of [`StepEngine`] and [`PulseProducer`].
fn set_positions<J>(
    running: bool,
    joints: &mut [J; MAX_JOINTS],
    positions: [i32; MAX_JOINTS],
    counter: fn(&mut J) -> &mut i32,
) -> bool {
    if !running {
        for (joint, position) in joints.iter_mut().zip(positions) {
            *counter(joint) = position;
        }
    }
    !running
}

/// Timer resolution and driver timing requirements.
///
/// The driver's datasheet gives three figures: the least STEP high time, the least STEP
/// low time between two pulses, and the DIR setup time before a rising edge. Only the
/// first two limit the step rate ([`StepTiming::max_step_rate_hz`]); the setup time is
/// waited for after a DIR change only. Typical values: DM542/TB6600-class opto-isolated
/// drivers 2.5 us high, 2.5 us low, 5 us setup; TMC/DRV-class drivers 100 ns, 100 ns, 20 ns.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct StepTiming {
    /// Step timer ticks per second.
    pub tick_hz: u32,
    /// How long STEP stays high, ticks.
    pub pulse_width_ticks: u32,
    /// Least time from a DIR change to the next rising STEP edge, ticks.
    pub dir_setup_ticks: u32,
    /// Least time STEP stays low between two pulses, ticks (at least one is kept).
    pub step_low_ticks: u32,
}

impl StepTiming {
    /// STEP high time the engine uses: `pulse_width_ticks`, but at least one tick.
    pub const fn pulse_ticks(&self) -> u32 {
        if self.pulse_width_ticks == 0 {
            1
        } else {
            self.pulse_width_ticks
        }
    }

    /// Least STEP low time between two pulses of one joint, ticks: `step_low_ticks`, but
    /// at least one (a driver must see two separate pulses).
    pub const fn low_ticks(&self) -> u32 {
        if self.step_low_ticks == 0 {
            1
        } else {
            self.step_low_ticks
        }
    }

    /// Shortest spacing of two pulses of one joint that is always honoured on time: the
    /// pulse width, then STEP low for the least low time. (After a DIR change the next
    /// pulse also waits for the setup time: a reversal at the highest rate may make a
    /// pulse late, never lost.)
    pub const fn min_pulse_period_ticks(&self) -> u64 {
        self.pulse_ticks() as u64 + self.low_ticks() as u64
    }

    /// Highest per-joint step rate the driver timing allows: `tick_hz` over the pulse width
    /// plus the least low time.
    #[allow(clippy::cast_possible_truncation, reason = "at most tick_hz, a u32")]
    pub const fn max_step_rate_hz(&self) -> u32 {
        (self.tick_hz as u64 / self.min_pulse_period_ticks()) as u32
    }
}

/// The step, direction lines. Called from the step timer interrupt: must not block.
pub trait StepPins {
    /// Sets joint `joint`'s DIR line (true = positive steps).
    fn set_direction(&mut self, joint: usize, positive: bool);
    /// Raises STEP on every joint in `joints`.
    fn step_high(&mut self, joints: JointMask);
    /// Lowers STEP on every joint in `joints`.
    fn step_low(&mut self, joints: JointMask);
}

/// What one [`StepEngine::poll`] did and what the interrupt must do next.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Poll {
    /// Tick at which `poll` must be called again; `None`: nothing to do until `start`.
    pub next_deadline: Option<u64>,
    /// Segments whose end time passed during this call (their slots are free now).
    pub segments_finished: u32,
    /// The engine ran out of segments during this call and is idle now.
    pub ran_dry: bool,
}
