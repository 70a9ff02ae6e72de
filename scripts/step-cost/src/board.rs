//! The NUCLEO board's step path, copied from the board crate with its registers moved into
//! RAM (QEMU has no STM32 peripherals): the DMA2 stream interrupts' body
//! (`firmware/board/src/step_dma/refill.rs`), the backend (`step_dma/backend.rs`: start,
//! refill, the service's run end, arming the alarm, stop), the step lock
//! (`step_dma/lock.rs`: BASEPRI), the step service interrupt (`step_dma/service.rs`), the
//! stream and timer register code (`step_dma/registers.rs`, `step_dma/stop.rs`), the step
//! clock (`step_timer.rs`: TIM13's interrupt with the lock-free DIR changes, `now_tick`,
//! `arm`, `program_compare`) and the DIR lines (`pins.rs::set_direction`). Each function is
//! the board's, line for line, except:
//! - every register block is at a RAM address (`pac` below) instead of the chip's, through
//!   the same stm32-metapac register types the board uses;
//! - TIM13's SR is rc_w0 (writing 0 clears a flag, 1 leaves it): RAM cannot do that, so each
//!   SR write is a read, an AND and a write ([`write_tim13_sr`]: two instructions more than
//!   the board's single store, counted);
//! - `defmt` logs (only on an underrun, which the harness fails on) are left out;
//! - the service interrupt's e-stop part (`estop::service`: one atomic swap when no edge
//!   came) is left out: the harness has no e-stop input;
//! - the RCC reset of a joint timer writes a RAM stand-in of RCC.
//!
//! The board's own crates do the rest as on the board: arm-core's `StepShared` (its lock
//! and progress), embassy-sync's `Signal` waking a task of a real embassy-executor (the
//! trajectory task's stand-in in `main.rs`), cortex-m's single-core critical section,
//! arm-step's producer and DIR queues. Keep this in step with the board's files.

#![allow(clippy::indexing_slicing, clippy::cast_possible_truncation)]

use core::cell::{Cell, UnsafeCell};
use core::ptr::addr_of;
use core::sync::atomic::{AtomicBool, Ordering, compiler_fence};

use arm_core::profile::{self, BoardProfile};
use arm_core::{StepBackend, StepProgress, StepShared};
use arm_step::{
    DirChange, DirQueues, JointBuffer, MAX_JOINTS, PRELUDE, PulsePeriod, Segment, StepTiming,
    StreamsSlot,
};
use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::blocking_mutex::raw::{CriticalSectionRawMutex, RawMutex};
use embassy_sync::signal::Signal;

/// The register blocks, at RAM addresses (memory.x leaves 0x2030_0000.. to them).
pub mod pac {
    pub use stm32_metapac::{dma, gpio, rcc, timer};
    /// DMA2 (the board's at 0x4002_0400).
    pub const DMA2: dma::Dma = unsafe { dma::Dma::from_ptr(0x2030_0000usize as _) };
    /// TIM13, the step clock (0x4000_1c00).
    pub const TIM13: timer::Tim1ch = unsafe { timer::Tim1ch::from_ptr(0x2030_1000usize as _) };
    /// GPIOD, the DIR lines (0x5802_0c00).
    pub const GPIOD: gpio::Gpio = unsafe { gpio::Gpio::from_ptr(0x2030_2000usize as _) };
    /// The joint timers (TIM2, TIM5, TIM3, TIM4, TIM1, TIM8, TIM16, TIM17): 0x400 apart.
    pub const JOINT_TIMERS: usize = 0x2030_3000;
    /// RCC (0x5802_4400), for the joint timers' resets.
    pub const RCC: rcc::Rcc = unsafe { rcc::Rcc::from_ptr(0x2030_5000usize as _) };
    /// A stand-in for TIM8_UP_TIM13's NVIC line (44 on the H743): QEMU's NVIC has 32 on
    /// mps2, so line 31 (never enabled: the harness reads its pending bit).
    #[derive(Clone, Copy)]
    pub struct Tim13Irq;
    // SAFETY: 31 is an interrupt line of the emulated NVIC.
    unsafe impl cortex_m::interrupt::InterruptNumber for Tim13Irq {
        fn number(self) -> u16 {
            31
        }
    }
    /// A stand-in for the step service's line (TIM7, 55 on the H743): line 30, never
    /// enabled either.
    #[derive(Clone, Copy)]
    pub struct ServiceIrq;
    // SAFETY: 30 is an interrupt line of the emulated NVIC.
    unsafe impl cortex_m::interrupt::InterruptNumber for ServiceIrq {
        fn number(self) -> u16 {
            30
        }
    }
}

// ---- step_dma/mod.rs ----

/// The board's profile.
pub const PROFILE: BoardProfile = profile::NUCLEO_H743ZI2;
/// Periods per buffer half.
pub const HALF: usize = PROFILE.step_buffer_half;
/// Segments the step producer holds: the profile's lookahead, as on the board.
pub const STEP_QUEUE: usize = PROFILE.step_queue();
/// The step timing of every joint.
pub const STEP_TIMING: StepTiming = PROFILE.step_timing();
/// The longest period of each joint's timer.
pub const MAX_PERIOD_TICKS: [u32; MAX_JOINTS] = PROFILE.step_timer_max_period_ticks;

/// Every joint's DMA buffer.
pub struct Buffers(pub UnsafeCell<[JointBuffer<HALF>; MAX_JOINTS]>);
// SAFETY: as on the board: every CPU access is inside STEP's lock.
unsafe impl Sync for Buffers {}
/// The DMA buffers.
pub static BUFFERS: Buffers = Buffers(UnsafeCell::new([JointBuffer::ZERO; MAX_JOINTS]));

/// The bus's `step_progress` (arm-core's Bus), which the trajectory task waits on.
pub static STEP_PROGRESS: Signal<CriticalSectionRawMutex, ()> = Signal::new();

// ---- step_dma/lock.rs ----

/// The DIR interrupt's priority (the board's `DIR_PRIORITY`, P1 with 4 priority bits).
pub const DIR_PRIORITY: u8 = 0x10;
/// The step lock's level (the board's `STEP_LOCK_PRIORITY`, P2).
pub const STEP_LOCK_PRIORITY: u8 = 0x20;

/// The board's `StepLock`: BASEPRI raised to P2 while held.
pub struct StepLock(());

// SAFETY: as on the board (here every context is the harness's one thread).
unsafe impl RawMutex for StepLock {
    const INIT: Self = StepLock(());

    fn lock<R>(&self, f: impl FnOnce() -> R) -> R {
        let old = cortex_m::register::basepri::read();
        cortex_m::register::basepri_max::write(STEP_LOCK_PRIORITY);
        compiler_fence(Ordering::SeqCst);
        let r = f();
        compiler_fence(Ordering::SeqCst);
        // SAFETY: restores the caller's mask.
        unsafe { cortex_m::register::basepri::write(old) };
        r
    }
}

/// step_dma::init's part that the step path depends on.
pub fn init() {
    STEP.with_engine(|steps| steps.streams.init(STEP_TIMING, MAX_PERIOD_TICKS));
}

// ---- step_dma/registers.rs ----

#[derive(Clone, Copy)]
struct JointTimer {
    base: *mut u32,
    has_moe: bool,
    complementary: bool,
}

mod reg {
    pub const CR1: usize = 0x00;
    pub const CR2: usize = 0x04;
    pub const DIER: usize = 0x0C;
    pub const SR: usize = 0x10;
    pub const EGR: usize = 0x14;
    pub const CCMR1: usize = 0x18;
    pub const CCER: usize = 0x20;
    pub const CNT: usize = 0x24;
    pub const PSC: usize = 0x28;
    pub const ARR: usize = 0x2C;
    pub const CCR1: usize = 0x34;
    pub const BDTR: usize = 0x44;
    pub const DCR: usize = 0x48;
    pub const DMAR: usize = 0x4C;
    pub const AF1: usize = 0x60;
    pub const CR1_CEN: u32 = 1 << 0;
    pub const CR1_URS: u32 = 1 << 2;
    pub const CR1_ARPE: u32 = 1 << 7;
    pub const DIER_UDE: u32 = 1 << 8;
    pub const EGR_UG: u32 = 1 << 0;
    pub const CCMR1_OC1PE: u32 = 1 << 3;
    pub const CCMR1_PWM1: u32 = 0b110 << 4;
    pub const CCMR1_FORCE_INACTIVE: u32 = 0b100 << 4;
    pub const CCER_CC1E: u32 = 1 << 0;
    pub const CCER_CC1NE: u32 = 1 << 2;
    pub const BDTR_MOE: u32 = 1 << 15;
    pub const BDTR_BKE: u32 = 1 << 12;
    pub const BDTR_BKP: u32 = 1 << 13;
    pub const BDTR_OSSI: u32 = 1 << 10;
    pub const AF1_BKINE: u32 = 1 << 0;
    pub const DCR_ARR_RCR_CCR1: u32 = 11 | (2 << 8);
}

impl JointTimer {
    fn write(self, offset: usize, value: u32) {
        // SAFETY: a word of the RAM stand-in of this timer's block.
        unsafe { self.base.byte_add(offset).write_volatile(value) }
    }
    fn read(self, offset: usize) -> u32 {
        // SAFETY: as in `write`.
        unsafe { self.base.byte_add(offset).read_volatile() }
    }
    fn dmar(self) -> u32 {
        self.base as u32 + reg::DMAR as u32
    }
}

/// The board's `joint_timer`: a match on the joint (the board's also yields its DMA
/// request, used only at boot).
fn joint_timer(joint: usize) -> JointTimer {
    let t = |n: usize, has_moe| JointTimer {
        base: (pac::JOINT_TIMERS + n * 0x400) as *mut u32,
        has_moe,
        complementary: false,
    };
    match joint {
        0 => t(0, false),
        1 => t(1, false),
        2 => t(2, false),
        3 => t(3, false),
        4 => t(4, true),
        5 => JointTimer {
            complementary: true,
            ..t(5, true)
        },
        6 => t(6, true),
        _ => t(7, true),
    }
}

/// The board's `reset_joint_timer` (on the RAM stand-in of RCC).
fn reset_joint_timer(joint: usize) {
    let rcc = pac::RCC;
    let pulse = |on: bool| match joint {
        0 => rcc.apb1lrstr().modify(|w| w.set_tim2rst(on)),
        1 => rcc.apb1lrstr().modify(|w| w.set_tim5rst(on)),
        2 => rcc.apb1lrstr().modify(|w| w.set_tim3rst(on)),
        3 => rcc.apb1lrstr().modify(|w| w.set_tim4rst(on)),
        4 => rcc.apb2rstr().modify(|w| w.set_tim1rst(on)),
        5 => rcc.apb2rstr().modify(|w| w.set_tim8rst(on)),
        6 => rcc.apb2rstr().modify(|w| w.set_tim16rst(on)),
        _ => rcc.apb2rstr().modify(|w| w.set_tim17rst(on)),
    };
    pulse(true);
    pulse(false);
}

/// The board's `configure_joint_timer`.
fn configure_joint_timer(joint: usize) {
    let timer = joint_timer(joint);
    timer.write(reg::CR1, reg::CR1_URS | reg::CR1_ARPE);
    timer.write(reg::CR2, 0);
    timer.write(reg::PSC, 0);
    timer.write(reg::CCMR1, reg::CCMR1_FORCE_INACTIVE);
    timer.write(
        reg::CCER,
        if timer.complementary {
            reg::CCER_CC1NE
        } else {
            reg::CCER_CC1E
        },
    );
    if timer.has_moe {
        timer.write(reg::AF1, timer.read(reg::AF1) & !reg::AF1_BKINE);
        timer.write(
            reg::BDTR,
            reg::BDTR_MOE | reg::BDTR_BKE | reg::BDTR_BKP | reg::BDTR_OSSI,
        );
    }
}

/// Words the stream moves per period (ARR, RCR, CCR1).
pub const WORDS_PER_PERIOD: usize = 3;
/// Words in one joint's whole circular buffer.
pub const BUFFER_WORDS: usize = 2 * HALF * WORDS_PER_PERIOD;

#[derive(Clone, Copy, Debug, Default)]
struct StreamPosition {
    next: usize,
    other_half_played: bool,
    preload_evicted: bool,
}

fn stream_position(joint: usize) -> StreamPosition {
    let remaining = pac::DMA2.st(joint).ndtr().read().ndt() as usize;
    let done = BUFFER_WORDS.saturating_sub(remaining) / WORDS_PER_PERIOD;
    let flags = pac::DMA2.isr(joint / 4).read();
    let n = joint % 4;
    let next = done % (2 * HALF);
    let preload = (next + 2 * HALF - 1) % (2 * HALF);
    let unplayed_half = preload / HALF;
    let (own_flag, other_flag) = if unplayed_half == 0 {
        (flags.htif(n), flags.tcif(n))
    } else {
        (flags.tcif(n), flags.htif(n))
    };
    StreamPosition {
        next,
        other_half_played: other_flag,
        preload_evicted: preload % HALF == HALF - 1 && !own_flag,
    }
}

fn clear_stream_flags(joint: usize) {
    let n = joint % 4;
    pac::DMA2.ifcr(joint / 4).write(|w| {
        w.set_feif(n, true);
        w.set_dmeif(n, true);
        w.set_teif(n, true);
        w.set_htif(n, true);
        w.set_tcif(n, true);
    });
}

fn load_joint(joint: usize, prelude: &[PulsePeriod; PRELUDE]) {
    let timer = joint_timer(joint);
    let [first, second] = prelude;
    timer.write(reg::CR1, reg::CR1_URS | reg::CR1_ARPE);
    timer.write(reg::DIER, 0);
    timer.write(reg::CNT, 0);
    timer.write(reg::ARR, first.reload);
    timer.write(reg::CCR1, first.high);
    timer.write(reg::CCMR1, reg::CCMR1_OC1PE | reg::CCMR1_PWM1);
    timer.write(reg::EGR, reg::EGR_UG);
    timer.write(reg::ARR, second.reload);
    timer.write(reg::CCR1, second.high);
    timer.write(reg::SR, 0);
    timer.write(reg::DCR, reg::DCR_ARR_RCR_CCR1);

    let stream = pac::DMA2.st(joint);
    stream.cr().modify(|w| w.set_en(false));
    clear_stream_flags(joint);
    stream.par().write_value(timer.dmar());
    // SAFETY: only the address is taken.
    let buffer = unsafe { addr_of!((*BUFFERS.0.get())[joint]) };
    stream.m0ar().write_value(buffer as u32);
    stream.ndtr().write(|w| w.set_ndt(BUFFER_WORDS as u16));
    stream.cr().write(|w| {
        w.set_dir(pac::dma::vals::Dir::MEMORY_TO_PERIPHERAL);
        w.set_circ(true);
        w.set_minc(true);
        w.set_pinc(false);
        w.set_psize(pac::dma::vals::Size::BITS32);
        w.set_msize(pac::dma::vals::Size::BITS32);
        w.set_pl(pac::dma::vals::Pl::VERY_HIGH);
        w.set_htie(true);
        w.set_tcie(true);
        w.set_teie(true);
    });
    stream.cr().modify(|w| w.set_en(true));
    timer.write(reg::DIER, reg::DIER_UDE);
}

// ---- step_dma/stop.rs ----

static KILL: AtomicBool = AtomicBool::new(false);

fn outputs_off() {
    for joint in 0..MAX_JOINTS {
        let timer = joint_timer(joint);
        timer.write(reg::CR1, reg::CR1_URS | reg::CR1_ARPE);
        timer.write(reg::CCMR1, reg::CCMR1_FORCE_INACTIVE);
    }
    for joint in 0..MAX_JOINTS {
        joint_timer(joint).write(reg::DIER, 0);
        disable_stream(joint);
    }
}

// registers.rs's disable_stream, with board-logic's step_stream::tcif_from_disable inlined.
fn disable_stream(joint: usize) {
    let stream = pac::DMA2.st(joint);
    let n = joint % 4;
    let ndtr = stream.ndtr().read().ndt();
    let tcif = pac::DMA2.isr(joint / 4).read().tcif(n);
    stream.cr().modify(|w| w.set_en(false));
    for _ in 0..1_000 {
        if !stream.cr().read().en() {
            break;
        }
    }
    let ndtr_after = stream.ndtr().read().ndt();
    if !tcif && ndtr_after <= ndtr {
        pac::DMA2.ifcr(joint / 4).write(|w| w.set_tcif(n, true));
    }
}

fn stop_all_step_outputs() -> [StreamPosition; MAX_JOINTS] {
    outputs_off();
    let mut positions = [StreamPosition::default(); MAX_JOINTS];
    for (joint, position) in positions.iter_mut().enumerate() {
        *position = stream_position(joint);
        clear_stream_flags(joint);
    }
    positions
}

// ---- pins.rs ----

fn set_direction(joint: usize, positive: bool) {
    if joint >= MAX_JOINTS {
        return;
    }
    let bit = 1u32 << joint;
    let bsrr = if positive { bit } else { bit << 16 };
    pac::GPIOD.bsrr().write_value(pac::gpio::regs::Bsrr(bsrr));
}

// ---- step_dma/backend.rs ----

/// What the board's step hardware is doing.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Run {
    /// Timers stopped.
    Idle,
    /// A run's start under way: joints below `next` primed.
    Priming {
        /// The next joint to prime.
        next: usize,
    },
    /// Timers running since step clock tick `origin`.
    Running {
        /// Step clock tick of the joint timers' tick 0.
        origin: u64,
    },
}

/// The board's `BoardSteps`.
pub struct BoardSteps {
    pub(crate) streams: StreamsSlot<STEP_QUEUE, HALF>,
    pub(crate) run: Run,
    started: [bool; MAX_JOINTS],
    primed_finished: u32,
    prelude: [[PulsePeriod; PRELUDE]; MAX_JOINTS],
}

/// The board's `STEP`.
pub static STEP: StepShared<STEP_QUEUE, BoardSteps, StepLock> =
    StepShared::with_backend(BoardSteps {
        streams: StreamsSlot::EMPTY,
        run: Run::Idle,
        started: [false; MAX_JOINTS],
        primed_finished: 0,
        prelude: [[PulsePeriod::ZERO; PRELUDE]; MAX_JOINTS],
    });

/// The board's `DIRS`.
pub static DIRS: DirQueues = DirQueues::new();

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

    fn start(&mut self, at_tick: u64) {
        if self.run != Run::Idle {
            return;
        }
        let Some(streams) = self.streams.get_mut() else {
            return;
        };
        let now = now_tick();
        streams.prime_begin_shared(at_tick.saturating_sub(now), &DIRS);
        self.primed_finished = 0;
        self.run = Run::Priming { next: 0 };
    }

    fn starting(&self) -> bool {
        matches!(self.run, Run::Priming { .. })
    }

    fn continue_start(&mut self) {
        let Run::Priming { next } = self.run else {
            return;
        };
        let Some(streams) = self.streams.get_mut() else {
            return;
        };
        if next < MAX_JOINTS {
            // SAFETY: inside STEP's lock with every stream disabled.
            let buffer = unsafe { &mut (*BUFFERS.0.get())[next] };
            let primed = streams.prime_joint_shared(next, &mut self.prelude[next], buffer, &DIRS);
            self.primed_finished += primed.segments_finished;
            self.run = Run::Priming { next: next + 1 };
            if primed.dir_overflow {
                self.stop();
            }
            return;
        }
        for joint in 0..MAX_JOINTS {
            while let Some(change) = DIRS.peek(joint) {
                if change.tick > 0 {
                    break;
                }
                set_direction(joint, change.positive);
                DIRS.pop(joint);
            }
        }
        // (The board's `broken` check with its warning: a register read per joint, left
        // out with the log.)
        let mut origin = None;
        let loaded = self.prelude.iter().enumerate().all(|(joint, prelude)| {
            unless_killed(|| {
                reset_joint_timer(joint);
                configure_joint_timer(joint);
                load_joint(joint, prelude);
            })
        });
        // (Not on the board: tells the harness how long the preludes play; not counted.)
        crate::harness_note_prelude(&self.prelude);
        if loaded {
            unless_killed(|| {
                for joint in 0..MAX_JOINTS {
                    let timer = joint_timer(joint);
                    timer.write(reg::CR1, reg::CR1_URS | reg::CR1_ARPE | reg::CR1_CEN);
                }
                origin = Some(now_tick());
            });
        }
        let Some(origin) = origin else {
            self.stop();
            return;
        };
        start_run(origin);
        self.run = Run::Running { origin };
        self.started = [false; MAX_JOINTS];
        self.arm_alarm();
    }

    fn stop(&mut self) {
        let stopped = stop_all_step_outputs();
        let Some(streams) = self.streams.get_mut() else {
            return;
        };
        if let Run::Priming { next } = self.run {
            // SAFETY: inside STEP's lock, streams disabled.
            let buffers = unsafe { &*BUFFERS.0.get() };
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
        disarm();
        DIRS.clear();
    }

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
                let first_unplayed = first_unplayed(self.started[joint], at);
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
    fn refill(&mut self, joint: usize, half: usize) -> StepProgress {
        if !matches!(self.run, Run::Running { .. }) {
            return StepProgress::default();
        }
        let Some(streams) = self.streams.get_mut() else {
            return StepProgress::default();
        };
        self.started[joint] = true;
        // SAFETY: inside STEP's lock; the stream reads the other half.
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

    fn on_service(&mut self, now: u64) -> StepProgress {
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
            stop_all_step_outputs();
            streams.producer().end_run();
            self.run = Run::Idle;
            disarm();
            return StepProgress {
                segments_finished: core::mem::take(&mut self.primed_finished),
                ran_dry: true,
            };
        }
        self.arm_alarm();
        StepProgress::default()
    }

    fn arm_alarm(&mut self) {
        if !matches!(self.run, Run::Running { .. }) {
            return;
        }
        let Some(streams) = self.streams.get() else {
            return;
        };
        arm(DIRS.earliest(), streams.producer_ref().run_end_tick());
    }
}

fn unless_killed(enable: impl FnOnce()) -> bool {
    critical_section::with(|_| {
        if KILL.load(Ordering::SeqCst) {
            return false;
        }
        enable();
        true
    })
}

fn first_unplayed(started: bool, at: StreamPosition) -> Option<usize> {
    (started || at.next > 0).then_some((at.next + 2 * HALF - 1) % (2 * HALF))
}

// ---- step_dma/refill.rs ----

fn refill(joint: usize) {
    let n = joint % 4;
    let flags = pac::DMA2.isr(joint / 4).read();
    clear_stream_flags(joint);
    let (half_played, full_played) = (flags.htif(n), flags.tcif(n));
    let remaining = pac::DMA2.st(joint).ndtr().read().ndt() as usize;
    let next = BUFFER_WORDS.saturating_sub(remaining) / WORDS_PER_PERIOD;
    let half = usize::from(full_played);
    let in_half = next / HALF;
    let underrun = flags.teif(n) || (half_played && full_played) || in_half == half;
    STEP.on_interrupt(&STEP_PROGRESS, |steps| {
        if !half_played && !full_played {
            return ((), StepProgress::default());
        }
        if underrun {
            steps.stop();
            return (
                (),
                StepProgress {
                    segments_finished: 0,
                    ran_dry: true,
                },
            );
        }
        ((), steps.refill(joint, half))
    });
}

/// The DMA2 stream interrupt handlers (the board's `#[interrupt] fn DMA2_STREAMn`), in
/// joint order: the harness calls them through this table as the NVIC would.
pub static DMA2_STREAM_HANDLERS: [extern "C" fn(); MAX_JOINTS] = [
    dma2_stream0,
    dma2_stream1,
    dma2_stream2,
    dma2_stream3,
    dma2_stream4,
    dma2_stream5,
    dma2_stream6,
    dma2_stream7,
];

macro_rules! stream_handlers {
    ($($name:ident = $joint:literal),*) => {$(
        #[unsafe(no_mangle)]
        extern "C" fn $name() {
            refill($joint);
        }
    )*};
}
stream_handlers!(
    dma2_stream0 = 0,
    dma2_stream1 = 1,
    dma2_stream2 = 2,
    dma2_stream3 = 3,
    dma2_stream4 = 4,
    dma2_stream5 = 5,
    dma2_stream6 = 6,
    dma2_stream7 = 7
);

// ---- step_dma/service.rs ----

/// The board's `#[interrupt] fn TIM7` (the step service), less `estop::service`.
#[unsafe(no_mangle)]
pub extern "C" fn tim7() {
    STEP.on_interrupt(&STEP_PROGRESS, |steps| ((), steps.on_service(now_tick())));
}

// ---- step_timer.rs ----

#[derive(Clone, Copy)]
struct ClockState {
    wraps: u64,
    alarm: u64,
    origin: u64,
    end: u64,
}

static CLOCK: Mutex<CriticalSectionRawMutex, Cell<ClockState>> =
    Mutex::new(Cell::new(ClockState {
        wraps: 0,
        alarm: u64::MAX,
        origin: 0,
        end: u64::MAX,
    }));

/// Ticks per wrap of the 16-bit counter.
pub const WRAP: u64 = 1 << 16;
/// SR bits: update, CC1.
pub const SR_UIF: u32 = 1 << 0;
/// SR: compare 1.
pub const SR_CC1IF: u32 = 1 << 1;
const DIER_UIE: u32 = 1 << 0;
/// DIER: compare 1 interrupt.
pub const DIER_CC1IE: u32 = 1 << 1;

/// TIM13's SR write with the hardware's rc_w0 effect (see the module's note).
#[inline(always)]
fn write_tim13_sr(value: u32) {
    let sr = pac::TIM13.sr();
    let now = sr.read().0;
    sr.write_value(pac::timer::regs::Sr1ch(now & value));
}

/// The step clock's tick.
pub fn now_tick() -> u64 {
    CLOCK.lock(|cell| tick_at(cell.get().wraps))
}

fn tick_at(wraps: u64) -> u64 {
    // board-logic's step_clock::extended_tick, inlined (this crate builds alone).
    let pending_before = pac::TIM13.sr().read().0 & SR_UIF != 0;
    let counter = u64::from(pac::TIM13.cnt().read().cnt());
    let pending_after = pac::TIM13.sr().read().0 & SR_UIF != 0;
    let uncounted = pending_before || (pending_after && counter < WRAP / 2);
    (wraps + u64::from(uncounted)) * WRAP + counter
}

fn start_run(origin: u64) {
    CLOCK.lock(|cell| {
        let mut state = cell.get();
        state.origin = origin;
        state.alarm = u64::MAX;
        state.end = u64::MAX;
        cell.set(state);
    });
}

fn arm(earliest_dir: Option<u64>, end: Option<u64>) {
    CLOCK.lock(|cell| {
        let mut state = cell.get();
        state.end = end.unwrap_or(u64::MAX);
        let next = earliest_dir.unwrap_or(u64::MAX).min(state.end);
        if next != u64::MAX {
            state.alarm = state.alarm.min(state.origin.saturating_add(next));
        }
        cell.set(state);
        program_compare(state);
    });
}

fn disarm() {
    CLOCK.lock(|cell| {
        let mut state = cell.get();
        state.alarm = u64::MAX;
        state.end = u64::MAX;
        cell.set(state);
        pac::TIM13
            .dier()
            .write_value(pac::timer::regs::Dier1ch(DIER_UIE));
    });
}

fn program_compare(state: ClockState) {
    let regs = pac::TIM13;
    let alarm = state.alarm;
    if alarm == u64::MAX {
        regs.dier().write_value(pac::timer::regs::Dier1ch(DIER_UIE));
        return;
    }
    let now = tick_at(state.wraps);
    if alarm <= now {
        cortex_m::peripheral::NVIC::pend(pac::Tim13Irq);
        return;
    }
    // board-logic's step_clock::compare_for: armed whenever less than a whole wrap away.
    if alarm - now < WRAP {
        regs.ccr(0).write(|w| w.set_ccr(alarm as u16));
        write_tim13_sr(!SR_CC1IF & 0xFFFF);
        regs.dier()
            .write_value(pac::timer::regs::Dier1ch(DIER_UIE | DIER_CC1IE));
        if tick_at(state.wraps) >= alarm {
            cortex_m::peripheral::NVIC::pend(pac::Tim13Irq);
        }
    } else {
        regs.dier().write_value(pac::timer::regs::Dier1ch(DIER_UIE));
    }
}

/// The board's `#[interrupt] fn TIM8_UP_TIM13`.
#[unsafe(no_mangle)]
pub extern "C" fn tim8_up_tim13() {
    let regs = pac::TIM13;
    let flags = regs.sr().read().0;
    write_tim13_sr(!(flags & (SR_UIF | SR_CC1IF)) & 0xFFFF);
    let due = CLOCK.lock(|cell| {
        let mut state = cell.get();
        if flags & SR_UIF != 0 {
            state.wraps += 1;
        }
        let now = tick_at(state.wraps);
        let due = state.alarm <= now;
        if due {
            state.alarm = u64::MAX;
        }
        cell.set(state);
        due.then_some((now, state.origin, state.end))
    });
    if let Some((now, origin, end)) = due {
        let at = now.saturating_sub(origin);
        for joint in 0..MAX_JOINTS {
            while let Some(DirChange { tick, positive }) = DIRS.peek(joint) {
                if tick > at {
                    break;
                }
                set_direction(joint, positive);
                DIRS.pop(joint);
            }
        }
        let mut next = DIRS.earliest().unwrap_or(u64::MAX);
        if end <= at {
            cortex_m::peripheral::NVIC::pend(pac::ServiceIrq);
        } else {
            next = next.min(end);
        }
        CLOCK.lock(|cell| {
            let mut state = cell.get();
            if next != u64::MAX {
                state.alarm = state.alarm.min(origin.saturating_add(next));
            }
            cell.set(state);
        });
    }
    CLOCK.lock(|cell| program_compare(cell.get()));
}
