//! Runs the NUCLEO board's whole step path (`board.rs`: its DMA2 stream interrupts, TIM13's
//! interrupt with the DIR changes and wraps, the step service interrupt that ends the run,
//! the run's start) over fixed
//! trajectories, with the hardware's part simulated in functions named `harness_*`: when
//! each stream's half-transfer/transfer-complete interrupt comes (from the periods the
//! refills wrote), TIM13's counter, wraps and compare matches. An instruction trace (QEMU
//! `-d exec,nochain -singlestep`) counts what runs between the markers: each interrupt is
//! called between `step_cost_on_<kind>` and `step_cost_off`, and run.sh counts the
//! instructions in between that are not the harness's. See run.sh and README.md.
#![no_std]
#![no_main]

mod board;

use core::future::Future;
use core::hint::black_box;
use core::mem::MaybeUninit;
use core::ptr::{addr_of, addr_of_mut};

use arm_core::step_shared::{START_LEAD_US, us_to_ticks};
use arm_step::{MAX_JOINTS, PRELUDE, PulsePeriod, Segment};
use board::{
    BUFFERS, DIER_CC1IE, DMA2_STREAM_HANDLERS, HALF, Run, SR_CC1IF, SR_UIF, STEP, WORDS_PER_PERIOD,
    pac,
};
use cortex_m::peripheral::NVIC;
use cortex_m_rt::entry;
use cortex_m_semihosting::{debug, hprintln};
use embassy_executor::raw;

/// Segments per trajectory: all queued before the measured run.
const SEGMENTS: usize = 10;

/// Step clock ticks (200 MHz) now: the simulated time.
static mut NOW: u64 = 0;
/// Per joint: step clock tick at which the half being played started, and which half.
static mut HALF_START: [u64; MAX_JOINTS] = [0; MAX_JOINTS];
static mut PLAYING: [usize; MAX_JOINTS] = [0; MAX_JOINTS];
/// Per joint: ticks of the prelude (its two periods), noted by the run's start.
static mut PRELUDE_TICKS: [u64; MAX_JOINTS] = [0; MAX_JOINTS];
/// Interrupts run in the current case: TIM13 (wraps, compares, pended), refills, the step
/// service.
static mut COUNTS: [u32; 5] = [0; 5];

/// Called by the run's start (board.rs) with the preludes it loaded: the harness's note of
/// how long they play (not the board's; not counted).
#[unsafe(no_mangle)]
#[inline(never)]
pub extern "C" fn harness_note_prelude(preludes: &[[PulsePeriod; PRELUDE]; MAX_JOINTS]) {
    for (j, prelude) in preludes.iter().enumerate() {
        let mut sum = 0u64;
        for period in prelude {
            sum += period.ticks();
        }
        // SAFETY: single-threaded harness.
        unsafe { (*addr_of_mut!(PRELUDE_TICKS))[j] = sum };
    }
}

// Markers: run.sh counts the instructions between an `on` marker and the next `off`
// (other than the markers' and the harness's own), by kind, and prints them per case at
// each `step_cost_case`.
// Each marker's body differs (a distinct constant), so that LLVM does not merge them into
// one function (the trace names instructions by function).
macro_rules! markers {
    ($($name:ident = $id:literal),*) => {$(
        #[unsafe(no_mangle)]
        #[inline(never)]
        pub extern "C" fn $name() {
            black_box($id);
        }
    )*};
}
markers!(
    step_cost_on_start = 1u32,
    step_cost_on_refill = 2u32,
    step_cost_on_tim13 = 3u32,
    step_cost_off = 4u32,
    step_cost_on_positions = 5u32,
    step_cost_on_service = 6u32
);

/// Ends a case (run.sh prints what it counted since the previous one).
#[unsafe(no_mangle)]
#[inline(never)]
pub extern "C" fn step_cost_case(case: u32) {
    black_box(case);
}

/// Ticks of periods `from..to` of joint `joint`'s half `half`.
#[unsafe(no_mangle)]
#[inline(never)]
pub extern "C" fn harness_ticks(joint: usize, half: usize, from: usize, to: usize) -> u64 {
    // SAFETY: single-threaded harness; the DMA's part (reading the buffers).
    let buffer = unsafe { &(*BUFFERS.0.get())[joint & 7] };
    buffer.periods[half & 1][from..to]
        .iter()
        .map(PulsePeriod::ticks)
        .sum()
}

/// When joint `joint`'s next half/complete interrupt comes: the DMA has transferred the
/// half's last period at the update that starts its second to last.
fn harness_event_tick(joint: usize) -> u64 {
    // SAFETY: single-threaded harness.
    unsafe { HALF_START[joint] + harness_ticks(joint, PLAYING[joint], 0, HALF - 1) }
}

/// TIM13's next compare match, if its interrupt is enabled.
fn harness_compare_tick(now: u64) -> Option<u64> {
    let dier = pac::TIM13.dier().read().0;
    if dier & DIER_CC1IE == 0 {
        return None;
    }
    let ccr = u64::from(pac::TIM13.ccr(0).read().ccr());
    let mut t = (now & !0xFFFF) | ccr;
    if t <= now {
        t += 1 << 16;
    }
    Some(t)
}

fn harness_set_now(now: u64) {
    // SAFETY: single-threaded harness.
    unsafe { NOW = now };
    pac::TIM13.cnt().write(|w| w.set_cnt(now as u16));
}

/// Runs TIM13's interrupt with `flags` raised in SR, then again while it is pended.
#[unsafe(no_mangle)]
#[inline(never)]
pub extern "C" fn harness_tim13(flags: u32) {
    if flags != 0 {
        let sr = pac::TIM13.sr();
        sr.write_value(pac::timer::regs::Sr1ch(sr.read().0 | flags));
        // SAFETY: single-threaded harness.
        unsafe { COUNTS[usize::from(flags & SR_UIF == 0)] += 1 };
        step_cost_on_tim13();
        board::tim8_up_tim13();
        step_cost_off();
    }
    harness_pended();
}

/// Runs TIM13's interrupt as long as the step path pends it, then the step service if
/// it was pended (TIM13, P1, comes first, as on the board).
#[unsafe(no_mangle)]
#[inline(never)]
pub extern "C" fn harness_pended() {
    loop {
        if NVIC::is_pending(pac::Tim13Irq) {
            NVIC::unpend(pac::Tim13Irq);
            // SAFETY: single-threaded harness.
            unsafe { COUNTS[2] += 1 };
            step_cost_on_tim13();
            board::tim8_up_tim13();
            step_cost_off();
        } else if NVIC::is_pending(pac::ServiceIrq) {
            NVIC::unpend(pac::ServiceIrq);
            // SAFETY: single-threaded harness.
            unsafe { COUNTS[4] += 1 };
            step_cost_on_service();
            board::tim7();
            step_cost_off();
        } else {
            break;
        }
    }
}

/// Joint `joint`'s half/complete interrupt: flags and NDTR as the stream leaves them.
#[unsafe(no_mangle)]
#[inline(never)]
pub extern "C" fn harness_refill(joint: usize) {
    // SAFETY: single-threaded harness.
    let (half, start) = unsafe { (PLAYING[joint], HALF_START[joint]) };
    // The half being played lasts this long (read before its refill rewrites it).
    let played = harness_ticks(joint, half, 0, HALF);
    let n = joint % 4;
    let mut isr = pac::dma::regs::Ixr(0);
    if half == 0 {
        isr.set_htif(n, true);
    } else {
        isr.set_tcif(n, true);
    }
    let isr_reg = pac::DMA2.isr(joint / 4).as_ptr().cast::<u32>();
    // SAFETY: the RAM stand-in of DMA2's interrupt status register.
    unsafe { isr_reg.write_volatile(isr.0) };
    // HT: the stream is in half 1; TC: it has wrapped to the buffer's start.
    let remaining = if half == 0 {
        board::BUFFER_WORDS - HALF * WORDS_PER_PERIOD
    } else {
        board::BUFFER_WORDS
    };
    pac::DMA2
        .st(joint)
        .ndtr()
        .write(|w| w.set_ndt(remaining as u16));
    // SAFETY: single-threaded harness.
    unsafe { COUNTS[3] += 1 };
    step_cost_on_refill();
    DMA2_STREAM_HANDLERS[joint]();
    step_cost_off();
    // SAFETY: as above (the handler cleared the flags through IFCR).
    unsafe { isr_reg.write_volatile(0) };
    // SAFETY: single-threaded harness.
    unsafe {
        HALF_START[joint] = start + played;
        PLAYING[joint] = half ^ 1;
    }
    harness_pended();
}

/// The trajectory task's stand-in, on a real embassy executor: waits on the bus's
/// `step_progress` and collects the progress, so that each refill that finishes a segment
/// wakes a task through the executor's waker, as on the board.
async fn trajectory_task() {
    loop {
        board::STEP_PROGRESS.wait().await;
        STEP.take_progress();
    }
}

static mut EXECUTOR: MaybeUninit<raw::Executor> = MaybeUninit::uninit();
static mut TASK_SPACE: MaybeUninit<[u64; 32]> = MaybeUninit::uninit();

fn harness_spawn<F: Future + 'static>(future: impl FnOnce() -> F) {
    assert!(size_of::<raw::TaskStorage<F>>() <= size_of::<[u64; 32]>());
    // SAFETY: once, at boot; the space is 8-aligned and large enough (asserted).
    unsafe {
        let executor = (*addr_of_mut!(EXECUTOR)).write(raw::Executor::new(usize::MAX as *mut ()));
        let storage = addr_of_mut!(TASK_SPACE).cast::<raw::TaskStorage<F>>();
        storage.write(raw::TaskStorage::new());
        let token = (*storage).spawn(future).expect("spawn");
        executor.spawner().spawn(token);
    }
}

/// Polls the executor (the board's thread mode between interrupts).
#[unsafe(no_mangle)]
#[inline(never)]
pub extern "C" fn harness_poll_tasks() {
    // SAFETY: initialised by harness_spawn; not re-entered.
    unsafe { (*addr_of!(EXECUTOR)).assume_init_ref().poll() };
}

/// The pender of embassy's cortex-m executors (thread mode: `sev`).
#[unsafe(export_name = "__pender")]
fn pender(context: *mut ()) {
    if context as usize == usize::MAX {
        cortex_m::asm::sev();
    }
}

/// One run: the start, then every interrupt in time order until the run's end.
#[unsafe(no_mangle)]
#[inline(never)]
pub extern "C" fn harness_run() {
    // SAFETY: single-threaded harness.
    let start_now = unsafe { NOW };
    let lead = us_to_ticks(START_LEAD_US.into(), board::STEP_TIMING.tick_hz);
    step_cost_on_start();
    STEP.start(start_now + lead);
    step_cost_off();
    harness_pended();
    harness_poll_tasks();
    let origin = match STEP.with_engine(|s| s.run) {
        Run::Running { origin } => origin,
        Run::Idle | Run::Priming { .. } => {
            hprintln!("the run did not start");
            debug::exit(debug::EXIT_FAILURE);
            return;
        }
    };
    for j in 0..MAX_JOINTS {
        // SAFETY: single-threaded harness.
        unsafe {
            PLAYING[j] = 0;
            HALF_START[j] = origin + PRELUDE_TICKS[j];
        }
    }
    while STEP.with_engine(|s| s.run) != Run::Idle {
        // SAFETY: single-threaded harness.
        let now = unsafe { NOW };
        let wrap = (now / (1 << 16) + 1) << 16;
        let compare = harness_compare_tick(now).unwrap_or(u64::MAX);
        let (joint, refill) = (0..MAX_JOINTS)
            .map(|j| (j, harness_event_tick(j)))
            .min_by_key(|&(_, t)| t)
            .unwrap_or((0, u64::MAX));
        let timer = wrap.min(compare);
        if timer <= refill {
            harness_set_now(timer);
            let mut flags = 0;
            if timer == wrap {
                flags |= SR_UIF;
            }
            if timer == compare {
                flags |= SR_CC1IF;
            }
            harness_tim13(flags);
        } else {
            harness_set_now(refill);
            harness_refill(joint);
            // A LOCATION report's read of the positions mid-run (the trajectory task's,
            // every report period on the board): timed for its masked span only, not
            // counted per step.
            step_cost_on_positions();
            black_box(STEP.positions());
            step_cost_off();
        }
        harness_poll_tasks();
    }
}

/// Runs `segments` segments of `duration_us` (direction reversing each segment) with
/// `steps[j]` pulses per joint per segment; returns the steps made.
fn measure(case: u32, duration_us: u32, steps: [i32; MAX_JOINTS]) -> u32 {
    // SAFETY: single-threaded harness.
    unsafe { COUNTS = [0; 5] };
    for k in 0..SEGMENTS {
        let sign = if k % 2 == 0 { 1 } else { -1 };
        let segment = Segment {
            duration_us,
            steps: steps.map(|n| n * sign),
        };
        if !STEP.push(segment, 0) {
            hprintln!("queue full");
            debug::exit(debug::EXIT_FAILURE);
        }
    }
    harness_run();
    let (positions, late) = STEP.with_engine(|s| {
        let p = s.streams.get().expect("initialised").producer_ref();
        (p.positions(), p.late_pulses())
    });
    // Even segment count, reversing: every joint is back at 0 if every pulse was written.
    // (Late pulses are expected: at 100 kHz a reversal's first pulse waits for the board's
    // DIR setup: its driver's 5 us plus the profile's DIR interrupt latency budget.)
    if positions != [0; MAX_JOINTS] {
        hprintln!(
            "case {}: positions {:?}, late pulses {}",
            case,
            positions,
            late
        );
        debug::exit(debug::EXIT_FAILURE);
    }
    let total = steps.iter().map(|n| n.unsigned_abs()).sum::<u32>() * SEGMENTS as u32;
    // SAFETY: single-threaded harness.
    let [wraps, compares, pended, refills, services] = unsafe { COUNTS };
    step_cost_case(case);
    if case > 0 {
        hprintln!(
            "case {} steps {} refills {} wraps {} compares {} pended {} late {} services {}",
            case,
            total,
            refills,
            wraps,
            compares,
            pended,
            late,
            services
        );
    }
    total
}

#[entry]
fn main() -> ! {
    // For run.sh: whether the step lock's BASEPRI level masks the DIR interrupt (NVIC
    // priorities: a lower number is more urgent; BASEPRI masks its level and below).
    hprintln!(
        "levels step-lock {} dir {}",
        board::STEP_LOCK_PRIORITY,
        board::DIR_PRIORITY
    );
    board::init();
    harness_spawn(trajectory_task);
    harness_poll_tasks();
    harness_set_now(1_000);
    // A first run, not measured: a board that has run before holds idle periods in its
    // idle joints' buffers and does not write them again.
    measure(0, 1_000, [100, 0, 0, 0, 0, 0, 0, 0]);
    // 100 kHz per joint: 100 steps per 1 ms segment.
    measure(1, 1_000, [100, 0, 0, 0, 0, 0, 0, 0]);
    measure(2, 1_000, [100; MAX_JOINTS]);
    measure(3, 1_000, [100, 97, 89, 83, 79, 73, 71, 67]);
    // About 1 kHz per joint: 100 steps per 100 ms segment.
    measure(4, 100_000, [100, 0, 0, 0, 0, 0, 0, 0]);
    measure(5, 100_000, [100; MAX_JOINTS]);
    measure(6, 100_000, [100, 97, 89, 83, 79, 73, 71, 67]);
    debug::exit(debug::EXIT_SUCCESS);
    loop {
        cortex_m::asm::wfi();
    }
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    hprintln!("panic: {}", info);
    debug::exit(debug::EXIT_FAILURE);
    loop {
        cortex_m::asm::wfi();
    }
}
