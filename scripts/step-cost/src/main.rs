//! Runs `StepEngine::poll` over fixed trajectories between calls to `step_cost_mark`, so
//! that an instruction trace (QEMU `-d exec,nochain -singlestep`) counted between the marks
//! gives the instructions per step. See run.sh.
#![no_std]
#![no_main]

use core::hint::black_box;

use arm_step::{JointMask, MAX_JOINTS, Segment, StepEngine, StepPins, StepTiming};
use cortex_m_rt::entry;
use cortex_m_semihosting::{debug, hprintln};

/// Segments per trajectory: all queued before the measured run.
const SEGMENTS: usize = 10;

/// Board timing: 10 MHz timer, 2 us pulses, 5 us direction setup.
const TIMING: StepTiming = StepTiming {
    tick_hz: 10_000_000,
    pulse_width_ticks: 20,
    dir_setup_ticks: 50,
};

/// Marks the start and end of a measured run: run.sh counts traced instructions between
/// two executions of this function.
#[unsafe(no_mangle)]
#[inline(never)]
pub extern "C" fn step_cost_mark(case: u32) {
    black_box(case);
}

/// Pins as cheap as a GPIO BSRR write: one volatile-free store each.
struct Pins {
    last: u32,
}

impl StepPins for Pins {
    fn set_direction(&mut self, joint: usize, positive: bool) {
        self.last = (joint as u32) << 1 | u32::from(positive);
    }
    fn step_high(&mut self, joints: JointMask) {
        self.last = u32::from(joints);
    }
    fn step_low(&mut self, joints: JointMask) {
        self.last = u32::from(joints) << 16;
    }
}

/// Runs 1 ms segments (direction reversing each segment) with `steps[j]` pulses per joint,
/// between two marks; returns the steps emitted.
fn measure(case: u32, steps: [i32; MAX_JOINTS]) -> u32 {
    let mut engine = StepEngine::<SEGMENTS>::new(TIMING);
    for k in 0..SEGMENTS {
        let sign = if k % 2 == 0 { 1 } else { -1 };
        let segment = Segment {
            duration_us: 1_000,
            steps: steps.map(|n| n * sign),
        };
        if engine.push(segment).is_err() {
            debug::exit(debug::EXIT_FAILURE);
        }
    }
    let mut pins = Pins { last: 0 };

    step_cost_mark(case);
    engine.start(1_000);
    let mut now = 0;
    while let Some(deadline) = engine.poll(now, &mut pins).next_deadline {
        now = deadline;
    }
    step_cost_mark(case);

    black_box(pins.last);
    // Even segment count, reversing: every joint is back at 0 if every pulse was emitted.
    if engine.positions() != [0; MAX_JOINTS] || engine.late_pulses() != 0 {
        debug::exit(debug::EXIT_FAILURE);
    }
    steps.iter().map(|n| n.unsigned_abs()).sum::<u32>() * SEGMENTS as u32
}

#[entry]
fn main() -> ! {
    let one = measure(1, [100, 0, 0, 0, 0, 0, 0, 0]);
    let eight = measure(2, [100; MAX_JOINTS]);
    let distinct = measure(3, [100, 97, 89, 83, 79, 73, 71, 67]);
    hprintln!("steps: {} {} {}", one, eight, distinct);
    debug::exit(debug::EXIT_SUCCESS);
    loop {}
}

#[panic_handler]
fn panic(_: &core::panic::PanicInfo) -> ! {
    debug::exit(debug::EXIT_FAILURE);
    loop {}
}
