//! Runs the board's whole per-step CPU path over fixed trajectories between calls to
//! `step_cost_mark`: the run's start ([`StepStreams::prime`]), then each joint's DMA
//! half/complete interrupt body ([`refill_isr`]: flags, [`StepStreams::refill`], progress)
//! in the order the hardware would raise them, so that an instruction trace (QEMU `-d
//! exec,nochain -singlestep`) counted between the marks gives the instructions per step.
//! The bookkeeping that stands in for the hardware (which half ends first, in simulated
//! time) lives in functions named `harness_*`, which run.sh leaves out of the count.
//! See run.sh.
#![no_std]
#![no_main]

use core::hint::black_box;
use core::ptr::{addr_of_mut, read_volatile, write_volatile};

use arm_step::{
    JointBuffer, MAX_JOINTS, NUCLEO_STEP_TIMER_MAX_PERIOD_TICKS, PRELUDE, PulsePeriod, Segment,
    StepStreams, StepTiming,
};
use cortex_m_rt::entry;
use cortex_m_semihosting::{debug, hprintln};

/// Segments per trajectory: all queued before the measured run.
const SEGMENTS: usize = 10;

/// Periods per DMA buffer half, as on the board.
const HALF: usize = arm_step::NUCLEO_STEP_BUFFER_HALF;

/// Board timing: 200 MHz timer clock, 2.5 us STEP high, 2.5 us low, 5 us DIR setup.
const TIMING: StepTiming = StepTiming {
    tick_hz: 200_000_000,
    pulse_width_ticks: 500,
    dir_setup_ticks: 1_000,
    step_low_ticks: 500,
};

static mut STREAMS: StepStreams<SEGMENTS, HALF> =
    StepStreams::new(TIMING, NUCLEO_STEP_TIMER_MAX_PERIOD_TICKS);
static mut BUFFERS: [JointBuffer<HALF>; MAX_JOINTS] = [JointBuffer::ZERO; MAX_JOINTS];
static mut PRELUDES: [[PulsePeriod; PRELUDE]; MAX_JOINTS] =
    [[PulsePeriod::ZERO; PRELUDE]; MAX_JOINTS];

/// Stand-ins for the DMA stream's interrupt status and flag-clear registers and the step
/// task's wake-up: read and written volatile, as the board's registers are.
static mut DMA_FLAGS: [u32; MAX_JOINTS] = [0; MAX_JOINTS];
static mut DMA_CLEAR: u32 = 0;
static mut WAKE: u32 = 0;
/// Stand-in for the compare register the board arms at the run's end tick.
static mut RUN_END_ALARM: u64 = u64::MAX;

/// DMA flags as the board reads them: half transfer (half 0 played), transfer complete
/// (half 1 played).
const HTIF: u32 = 1 << 4;
const TCIF: u32 = 1 << 5;

/// Marks the start and end of a measured run: run.sh counts traced instructions between
/// two executions of this function.
#[unsafe(no_mangle)]
#[inline(never)]
pub extern "C" fn step_cost_mark(case: u32) {
    black_box(case);
}

/// The body of joint `joint`'s DMA stream interrupt, as the board runs it
/// (`firmware/board/src/step_dma/refill.rs`): read and clear the flags, refill the half the DMA
/// left, wake the trajectory task when segments finished, arm the run's end once it is known.
#[unsafe(no_mangle)]
#[inline(never)]
pub extern "C" fn refill_isr(joint: usize) {
    let j = joint & (MAX_JOINTS - 1);
    // SAFETY: single-threaded harness; the board serialises the same way (one priority).
    unsafe {
        let flags = read_volatile(addr_of_mut!(DMA_FLAGS[j]));
        write_volatile(addr_of_mut!(DMA_CLEAR), flags);
        let half = usize::from(flags & TCIF != 0);
        let streams = &mut *addr_of_mut!(STREAMS);
        let buffer = &mut *addr_of_mut!(BUFFERS[j]);
        let refill = streams.refill(j, half, &mut buffer.periods[half]);
        if refill.segments_finished > 0 {
            write_volatile(addr_of_mut!(WAKE), 1);
        }
        if refill.dir_overflow {
            debug::exit(debug::EXIT_FAILURE);
        }
        if let Some(end) = streams.producer_ref().run_end_tick() {
            write_volatile(addr_of_mut!(RUN_END_ALARM), end);
        }
    }
}

/// The start of a run as the board does it: prime every joint's prelude and halves.
#[unsafe(no_mangle)]
#[inline(never)]
pub extern "C" fn run_start(
    streams: &mut StepStreams<SEGMENTS, HALF>,
    preludes: &mut [[PulsePeriod; PRELUDE]; MAX_JOINTS],
    buffers: &mut [JointBuffer<HALF>; MAX_JOINTS],
) {
    let [b0, b1, b2, b3, b4, b5, b6, b7] = buffers;
    let primed = streams.prime(1_000, preludes, &mut [b0, b1, b2, b3, b4, b5, b6, b7]);
    if primed.dir_overflow {
        debug::exit(debug::EXIT_FAILURE);
    }
}

/// Ticks a buffer half lasts (the hardware's part: how long the timer plays it).
#[unsafe(no_mangle)]
#[inline(never)]
pub extern "C" fn harness_half_ticks(joint: usize, half: usize) -> u64 {
    // SAFETY: single-threaded harness.
    let buffer = unsafe { &*addr_of_mut!(BUFFERS[joint & 7]) };
    buffer.periods[half & 1]
        .iter()
        .map(PulsePeriod::ticks)
        .sum()
}

/// The joint whose playing half ends first (the next interrupt the hardware raises), and
/// sets its DMA flag; `MAX_JOINTS` once the run's end alarm comes first.
#[unsafe(no_mangle)]
#[inline(never)]
pub extern "C" fn harness_next(ends: &[u64; MAX_JOINTS], playing: &[usize; MAX_JOINTS]) -> usize {
    let mut best = 0;
    for j in 1..MAX_JOINTS {
        if ends[j] < ends[best] {
            best = j;
        }
    }
    // SAFETY: single-threaded harness.
    if ends[best] > unsafe { read_volatile(addr_of_mut!(RUN_END_ALARM)) } {
        return MAX_JOINTS;
    }
    let flag = if playing[best] == 0 { HTIF } else { TCIF };
    // SAFETY: single-threaded harness.
    unsafe { write_volatile(addr_of_mut!(DMA_FLAGS[best]), flag) };
    best
}

/// The run: prime, then interrupts in hardware order until the run is over.
#[unsafe(no_mangle)]
#[inline(never)]
pub extern "C" fn harness_run(case: u32) {
    // SAFETY: single-threaded harness.
    let streams = unsafe { &mut *addr_of_mut!(STREAMS) };
    let preludes = unsafe { &mut *addr_of_mut!(PRELUDES) };
    let buffers = unsafe { &mut *addr_of_mut!(BUFFERS) };
    step_cost_mark(case);
    run_start(streams, preludes, buffers);
    let mut playing = [0usize; MAX_JOINTS];
    let mut ends = [0u64; MAX_JOINTS];
    for (j, end) in ends.iter_mut().enumerate() {
        let prelude: u64 = preludes[j].iter().map(PulsePeriod::ticks).sum();
        *end = prelude + harness_half_ticks(j, 0);
    }
    loop {
        let j = harness_next(&ends, &playing);
        if j >= MAX_JOINTS {
            break;
        }
        refill_isr(j);
        playing[j] ^= 1;
        ends[j] += harness_half_ticks(j, playing[j]);
    }
    step_cost_mark(case);
    // The board's step clock ends the run at its end tick.
    streams.producer().end_run();
}

/// Runs 1 ms segments (direction reversing each segment) with `steps[j]` pulses per joint,
/// between two marks; returns the steps made.
fn measure(case: u32, steps: [i32; MAX_JOINTS]) -> u32 {
    // SAFETY: single-threaded harness.
    let streams = unsafe { &mut *addr_of_mut!(STREAMS) };
    unsafe { *addr_of_mut!(RUN_END_ALARM) = u64::MAX };
    for k in 0..SEGMENTS {
        let sign = if k % 2 == 0 { 1 } else { -1 };
        let segment = Segment {
            duration_us: 1_000,
            steps: steps.map(|n| n * sign),
        };
        if streams.producer().push(segment).is_err() {
            debug::exit(debug::EXIT_FAILURE);
        }
    }
    harness_run(case);
    let producer = streams.producer_ref();
    // Even segment count, reversing: every joint is back at 0 if every pulse was written.
    if producer.positions() != [0; MAX_JOINTS] || producer.late_pulses() != 0 {
        debug::exit(debug::EXIT_FAILURE);
    }
    steps.iter().map(|n| n.unsigned_abs()).sum::<u32>() * SEGMENTS as u32
}

#[entry]
fn main() -> ! {
    // A first run, not measured: a board that has run before holds idle periods in its
    // idle joints' buffers and does not write them again (the first run after boot
    // writes them once, about 320 instructions per idle buffer half).
    measure(0, [100, 0, 0, 0, 0, 0, 0, 0]);
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
