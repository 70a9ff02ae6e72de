//! The step timer and the step output of the emulated board.
//!
//! The CMSDK dual timer's first counter is a one-shot compare channel: loaded with the
//! SYSCLK cycles to the engine's next deadline, it interrupts at zero, and the interrupt
//! runs arm-core's [`on_step_timer`] exactly as the NUCLEO's TIM2 interrupt does (kicks pend
//! it). Its time base is the time driver's 64-bit SYSCLK count, so step ticks are 40 ns.
//!
//! The STEP/DIR lines are a memory fake, [`StepLines`]: the edges the engine writes set and
//! clear bits in it, and each rising edge moves that joint's pulse counter in its DIR
//! direction, so the pulses "output" can be compared with the engine's positions. Only this
//! file and the pin writer are specific to the emulated board; the engine and its sharing
//! with the tasks are arm-core's.

use core::sync::atomic::{AtomicI32, AtomicU8, Ordering};

use arm_core::StepShared;
use arm_core::hw::StepKick;
use arm_core::on_step_timer;
use arm_step::{JointMask, StepPins, StepTiming};
use cortex_m::peripheral::NVIC;

use crate::mps2::{self, DUALTIMER, Irq, SYSCLK_HZ, write};
use crate::time_driver::now_cycles;

// Segments the engine holds on the interrupt's side (declared once, in arm-core).
use arm_core::STEP_QUEUE;

/// SYSCLK cycles per microsecond.
const CYCLES_PER_US: u32 = SYSCLK_HZ / 1_000_000;

/// Driver timing as the NUCLEO's default (opto-isolated drivers): 2.5 us STEP high,
/// 2.5 us low, 5 us DIR setup.
pub const STEP_TIMING: StepTiming = StepTiming {
    tick_hz: SYSCLK_HZ,
    pulse_width_ticks: 5 * CYCLES_PER_US / 2,
    dir_setup_ticks: 5 * CYCLES_PER_US,
    step_low_ticks: 5 * CYCLES_PER_US / 2,
};

// The driver timing must leave room for the controller's advertised step rate.
const _: () = assert!(STEP_TIMING.max_step_rate_hz() >= arm_core::config::BOARD_MAX_STEP_RATE_HZ);

/// The step engine shared by the interrupt and the tasks.
pub static STEP: StepShared<STEP_QUEUE> = StepShared::new(STEP_TIMING);

/// Dual timer registers (first counter).
mod reg {
    /// Value loaded into the counter when written.
    pub const LOAD: usize = 0x00;
    /// Control: one-shot (0), 32-bit (1), interrupt enable (5), enable (7).
    pub const CONTROL: usize = 0x08;
    /// Interrupt clear (any write).
    pub const INTCLR: usize = 0x0C;
}
const CONTROL_ONE_SHOT_32: u32 = 1 | (1 << 1) | (1 << 5) | (1 << 7);

/// Deadlines farther than this are armed at this distance and looked at again (the
/// counter is 32 bits: 171 s).
const MAX_ARMED_CYCLES: u64 = u32::MAX as u64;
/// Engine polls in one interrupt before it pends itself again (as on the NUCLEO).
const MAX_POLLS_PER_INTERRUPT: u32 = 8;

/// The STEP and DIR lines as memory: what a logic analyser on the NUCLEO would see, plus a
/// signed count of the rising STEP edges per joint.
pub struct StepLines {
    /// Bit j = STEP line of joint j high.
    pub step: AtomicU8,
    /// Bit j = DIR line of joint j high (positive).
    pub dir: AtomicU8,
    /// Rising STEP edges per joint, +1 with DIR high, -1 with DIR low.
    pub pulses: [AtomicI32; arm_step::MAX_JOINTS],
}

/// The lines the step interrupt writes.
pub static LINES: StepLines = StepLines {
    step: AtomicU8::new(0),
    dir: AtomicU8::new(0),
    pulses: [const { AtomicI32::new(0) }; arm_step::MAX_JOINTS],
};

/// [`StepPins`] onto [`LINES`].
struct LineWriter;

impl StepPins for LineWriter {
    fn set_direction(&mut self, joint: usize, positive: bool) {
        let bit = 1u8 << (joint & 7);
        if positive {
            LINES.dir.fetch_or(bit, Ordering::Relaxed);
        } else {
            LINES.dir.fetch_and(!bit, Ordering::Relaxed);
        }
    }

    fn step_high(&mut self, joints: JointMask) {
        let rising = joints & !LINES.step.fetch_or(joints, Ordering::Relaxed);
        let dir = LINES.dir.load(Ordering::Relaxed);
        for (j, pulses) in LINES.pulses.iter().enumerate() {
            if rising & (1 << j) != 0 {
                let step = if dir & (1 << j) != 0 { 1 } else { -1 };
                pulses.fetch_add(step, Ordering::Relaxed);
            }
        }
    }

    fn step_low(&mut self, joints: JointMask) {
        LINES.step.fetch_and(!joints, Ordering::Relaxed);
        if joints == 0xFF {
            // Only a stop lowers every line at once.
            crate::marks::step_output_stopped();
        }
    }
}

/// Handle on the step timer ([`StepKick`]).
#[derive(Clone, Copy)]
pub struct StepTimer {
    _private: (),
}

impl StepKick for StepTimer {
    fn kick(&self) {
        NVIC::pend(Irq::DualTimer);
    }

    fn now_tick(&self) -> u64 {
        now_cycles()
    }
}

/// Stops the counter and enables its interrupt at the highest priority.
pub fn init() -> StepTimer {
    write(DUALTIMER, reg::CONTROL, 0);
    write(DUALTIMER, reg::INTCLR, 1);
    mps2::enable(Irq::DualTimer, mps2::priority::STEP);
    StepTimer { _private: () }
}

/// Arms the counter for `deadline`; true if it has already passed (poll again now).
fn arm(deadline: Option<u64>) -> bool {
    write(DUALTIMER, reg::CONTROL, 0);
    write(DUALTIMER, reg::INTCLR, 1);
    let Some(deadline) = deadline else {
        return false;
    };
    let now = now_cycles();
    if deadline <= now {
        return true;
    }
    let cycles = (deadline - now).min(MAX_ARMED_CYCLES) as u32;
    write(DUALTIMER, reg::LOAD, cycles);
    write(DUALTIMER, reg::CONTROL, CONTROL_ONE_SHOT_32);
    false
}

/// The step timer interrupt: a deadline, or a kick.
pub fn on_interrupt() {
    for _ in 0..MAX_POLLS_PER_INTERRUPT {
        let next = on_step_timer(&STEP, now_cycles(), &mut LineWriter, &crate::BUS.step_wake);
        if !arm(next) {
            return;
        }
    }
    NVIC::pend(Irq::DualTimer);
}
