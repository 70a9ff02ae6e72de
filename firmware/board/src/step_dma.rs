//! STEP pulses made by timer hardware: one timer per joint in PWM mode, its period and
//! pulse width reloaded at every update event by a DMA stream from a double buffer that
//! the CPU refills half by half.
//!
//! Each joint's timer (see `pins.rs` for the map) runs PWM mode 1 on CH1 (joint 5: CH1N)
//! with ARR and CCR1 preloaded. At each update event its DMA request makes a DMA2 stream
//! write the next [`PulsePeriod`] (ARR, RCR, CCR1) through the timer's DMA burst register
//! (`DCR.DBA` = ARR, three transfers): a period that starts with a pulse of `high` ticks,
//! or none. Rising edges are period starts: placed by the counter to the tick, with no
//! CPU involved. The stream is circular over [`HALF`]` * 2` periods; its half-transfer and
//! transfer-complete interrupts ([`refill`]) refill the half it just left with
//! [`StepStreams::refill`] (arm-step's producer). The CPU's whole share is the producer's
//! arithmetic: 23 to 30 instructions per step (scripts/step-cost).
//!
//! DIR lines change at reversals only, when the joint's previous pulse has fallen, from
//! the step clock's compare interrupt (`step_timer.rs`), and the producer places the next
//! pulse no sooner than the DIR setup time (plus [`DIR_LATENCY_NS`] for the interrupt)
//! after. The run ends at the producer's `run_end_tick`, also from the step clock.
//!
//! Safety: [`stop_all_step_outputs`] forces every STEP output inactive (OCxM = force
//! inactive: the pin goes low at once, whatever the counter does), stops the counters and
//! disables the streams, for the emergency stop, the end of a run, an underrun (a stream
//! that reaches a half its interrupt has not refilled: [`refill`] sees both halves
//! played, or the stream already back in the half it is about to write) and the fault
//! path. The interrupts are bounded: a refill writes one half and returns; nothing
//! re-pends itself, so no step path can starve the tasks.
//!
//! Memory: the buffers are a static in SRAM1 (`.sram1`, zeroed by [`init`]): DMA2 reaches
//! it (never DTCM), and MPU region 0 makes all of SRAM1 non-cacheable, so with the D-cache
//! on the streams read what the refills wrote ([`dma_buffer_region`], `memory.rs`).

use core::cell::UnsafeCell;
use core::mem::MaybeUninit;
use core::ptr::addr_of;

use arm_core::StepShared;
use arm_core::tasks::{StepBackend, StepProgress};
use arm_step::{
    DirChange, JointBuffer, MAX_JOINTS, NUCLEO_STEP_TIMER_MAX_PERIOD_TICKS, PRELUDE, PulsePeriod,
    Segment, StepStreams, StepTiming,
};
use embassy_stm32::interrupt::{InterruptExt, Priority};
use embassy_stm32::{interrupt, pac};

use crate::pins;
use crate::step_timer;

/// Segments held on the interrupts' side (declared once, with its reason, in arm-core).
pub use arm_core::STEP_QUEUE;

/// Periods per buffer half: at 500 kHz a half plays for 128 us, so a refill interrupt may
/// wait that long; 64 keeps the refill's fixed cost (about 250 instructions) to 4 per step.
/// 2 * 64 * 12 bytes per joint.
pub const HALF: usize = 64;

/// The joint timers' input clock (APB1 and APB2 timer clocks, `clocks.rs`).
pub const STEP_TIMER_HZ: u32 = 200_000_000;

/// Longest wait of a DIR change behind its tick: the step clock's interrupt at P0 can be
/// held off by a critical section, the longest being a refill (one half: about 2.5 us at
/// 400 MHz). Added to the driver's DIR setup time, so the driver still sees its setup.
pub const DIR_LATENCY_NS: u32 = 5_000;

/// A driver's timing requirements (its datasheet's figures), in nanoseconds.
#[derive(Clone, Copy, Debug, PartialEq, Eq, defmt::Format)]
pub struct DriverTiming {
    /// Least STEP high time.
    pub high_ns: u32,
    /// Least STEP low time between pulses.
    pub low_ns: u32,
    /// Least time from a DIR change to the next rising STEP edge.
    pub dir_setup_ns: u32,
}

impl DriverTiming {
    #[cfg_attr(feature = "tmc-drivers", allow(dead_code))]
    /// DM542, TB6600 and other opto-isolated drivers: 2.5 us high, 2.5 us low, 5 us DIR
    /// setup (safe for DRV8825 and A4988 too). 200 kHz per joint.
    pub const OPTO: DriverTiming = DriverTiming {
        high_ns: 2_500,
        low_ns: 2_500,
        dir_setup_ns: 5_000,
    };
    #[cfg_attr(not(feature = "tmc-drivers"), allow(dead_code))]
    /// TMC2209/TMC5160-class drivers: 100 ns high, 100 ns low, 20 ns DIR setup: 5 MHz by
    /// the driver, 1 MHz by the board ([`BOARD_MAX_STEP_RATE_HZ`]).
    pub const TMC: DriverTiming = DriverTiming {
        high_ns: 100,
        low_ns: 100,
        dir_setup_ns: 20,
    };

    /// The step timing on the joint timers' clock (rounded up to whole ticks).
    pub const fn step_timing(&self) -> StepTiming {
        #[allow(
            clippy::cast_possible_truncation,
            reason = "const-evaluated for the drivers' figures: a few thousand ticks"
        )]
        const fn ticks(ns: u32) -> u32 {
            ((ns as u64 * STEP_TIMER_HZ as u64).div_ceil(1_000_000_000)) as u32
        }
        StepTiming {
            tick_hz: STEP_TIMER_HZ,
            pulse_width_ticks: ticks(self.high_ns),
            dir_setup_ticks: ticks(self.dir_setup_ns + DIR_LATENCY_NS),
            step_low_ticks: ticks(self.low_ns),
        }
    }
}

/// The drivers this board is built for: `--features tmc-drivers` for TMC-class timing,
/// otherwise the opto-isolated drivers' (safe for all).
#[cfg(not(feature = "tmc-drivers"))]
pub const DRIVER: DriverTiming = DriverTiming::OPTO;
/// The drivers this board is built for.
#[cfg(feature = "tmc-drivers")]
pub const DRIVER: DriverTiming = DriverTiming::TMC;

/// The step timing of every joint.
pub const STEP_TIMING: StepTiming = DRIVER.step_timing();

/// Per joint ceiling of the board, whatever the drivers allow: a period's DMA burst
/// (three words into an APB timer, with eight streams sharing two DMA controllers) must
/// finish within the shortest period; 1 us periods leave a wide margin. Also the
/// ceiling of the CPU budget per joint (see [`BOARD_STEP_BUDGET_HZ`]).
pub const BOARD_MAX_STEP_RATE_HZ: u32 = 1_000_000;

/// Steps per second over all joints the board takes on: 8 x 500 kHz. At the measured
/// 29.8 instructions per step (scripts/step-cost, the worst of its three trajectories),
/// about 1.3 cycles each on the Cortex-M7 at 400 MHz, that is 4e6 * 29.8 * 1.3 / 400e6 =
/// 39% of the CPU, leaving the rest to the network and the tasks. STATUS reports it at
/// offset 32; points asking for more are refused (docs/PROTOCOL.md).
pub const BOARD_STEP_BUDGET_HZ: u32 = arm_core::config::BOARD_STEP_BUDGET_HZ;

/// Per joint maximum step rate: what the drivers allow, within the board's ceiling.
pub const MAX_STEP_RATE_HZ: u32 = if STEP_TIMING.max_step_rate_hz() < BOARD_MAX_STEP_RATE_HZ {
    STEP_TIMING.max_step_rate_hz()
} else {
    BOARD_MAX_STEP_RATE_HZ
};

// Opto drivers: 200 kHz per joint; TMC: the board's 1 MHz. Both above the protocol's
// usual 100 kHz, and TMC timing gives every joint >= 500 kHz.
const _: () = assert!(MAX_STEP_RATE_HZ >= 100_000);
#[cfg(feature = "tmc-drivers")]
const _: () = assert!(MAX_STEP_RATE_HZ >= 500_000);

/// One joint's timer: registers, DMA request, and how its output is enabled.
#[derive(Clone, Copy)]
struct JointTimer {
    /// Register block base.
    base: *mut u32,
    /// DMAMUX1 request of its update event.
    request: u8,
    /// Advanced-control timer or TIM16/17: has BDTR.MOE.
    has_moe: bool,
    /// The STEP output is CH1N (TIM8 on PA5), not CH1.
    complementary: bool,
}

/// Register offsets common to every timer used (RM0433, timer register maps).
mod reg {
    pub const CR1: usize = 0x00;
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

    /// CR1: counter enable, update only on overflow (UG makes no DMA request), ARR
    /// preloaded.
    pub const CR1_CEN: u32 = 1 << 0;
    pub const CR1_URS: u32 = 1 << 2;
    pub const CR1_ARPE: u32 = 1 << 7;
    /// DIER: DMA request on update.
    pub const DIER_UDE: u32 = 1 << 8;
    /// EGR: update generation.
    pub const EGR_UG: u32 = 1 << 0;
    /// CCMR1: OC1 preload, PWM mode 1 (active while CNT < CCR1), forced inactive.
    pub const CCMR1_OC1PE: u32 = 1 << 3;
    pub const CCMR1_PWM1: u32 = 0b110 << 4;
    pub const CCMR1_FORCE_INACTIVE: u32 = 0b100 << 4;
    /// CCER: CC1 output enable, CC1N output enable.
    pub const CCER_CC1E: u32 = 1 << 0;
    pub const CCER_CC1NE: u32 = 1 << 2;
    /// BDTR: main output enable.
    pub const BDTR_MOE: u32 = 1 << 15;
    /// DCR: burst from ARR (0x2C / 4 = 11), three transfers (DBL = 2): ARR, RCR, CCR1.
    pub const DCR_ARR_RCR_CCR1: u32 = 11 | (2 << 8);
}

impl JointTimer {
    fn write(self, offset: usize, value: u32) {
        // SAFETY: `base` is a timer register block of this chip; `offset` is one of its
        // registers (mod reg); volatile word access is how the hardware is driven.
        unsafe { self.base.byte_add(offset).write_volatile(value) }
    }

    fn read(self, offset: usize) -> u32 {
        // SAFETY: as in `write`.
        unsafe { self.base.byte_add(offset).read_volatile() }
    }

    /// Address of the DMA burst register, the stream's peripheral address.
    #[allow(
        clippy::cast_possible_truncation,
        reason = "addresses are 32 bits on this chip"
    )]
    fn dmar(self) -> u32 {
        self.base as u32 + reg::DMAR as u32
    }
}

/// The timer of joint `joint` (pins.rs has the map and the reasons).
fn joint_timer(joint: usize) -> JointTimer {
    // (Joints 0 and 1 have 32-bit counters: NUCLEO_STEP_TIMER_MAX_PERIOD_TICKS.)
    let t = |base: *mut (), request, has_moe| JointTimer {
        base: base.cast(),
        request,
        has_moe,
        complementary: false,
    };
    match joint {
        0 => t(pac::TIM2.as_ptr(), 22, false),
        1 => t(pac::TIM5.as_ptr(), 59, false),
        2 => t(pac::TIM3.as_ptr(), 27, false),
        3 => t(pac::TIM4.as_ptr(), 32, false),
        4 => t(pac::TIM1.as_ptr(), 15, true),
        5 => JointTimer {
            complementary: true,
            ..t(pac::TIM8.as_ptr(), 51, true)
        },
        6 => t(pac::TIM16.as_ptr(), 110, true),
        _ => t(pac::TIM17.as_ptr(), 112, true),
    }
}

/// Words the stream moves per period (ARR, RCR, CCR1).
const WORDS_PER_PERIOD: usize = 3;
/// Words in one joint's whole circular buffer.
const BUFFER_WORDS: usize = 2 * HALF * WORDS_PER_PERIOD;

/// Every joint's DMA buffer. Written by the refills (inside [`STEP`]'s critical section,
/// for the half the stream is not reading) and read by the DMA.
struct Buffers(UnsafeCell<[JointBuffer<HALF>; MAX_JOINTS]>);

// SAFETY: every CPU access happens inside STEP's critical section; the DMA reads the other
// half (the refill checks where the stream is before it writes).
unsafe impl Sync for Buffers {}

/// In SRAM1 (`.sram1`, NOLOAD: zeroed by [`init`]), which MPU region 0 makes
/// non-cacheable (`memory.rs`): the DMA never reads a period still in the D-cache.
#[unsafe(link_section = ".sram1.step_buffers")]
static BUFFERS: Buffers = Buffers(UnsafeCell::new([JointBuffer::ZERO; MAX_JOINTS]));

/// Address and length of the step DMA buffers (inside SRAM1, MPU region 0; logged at
/// debug level by [`init`]).
pub fn dma_buffer_region() -> (usize, usize) {
    (
        BUFFERS.0.get() as usize,
        core::mem::size_of::<[JointBuffer<HALF>; MAX_JOINTS]>(),
    )
}

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

/// The producer and its buffers' bookkeeping.
type Streams = StepStreams<STEP_QUEUE, HALF>;

/// [`Streams`] once [`init`] has made them. Not an `Option`: its `None` would use a niche
/// of the streams' fields and not be all zeros, and the static holding it would go to
/// .data (a 14 KiB image in flash, copied at boot) instead of .bss.
pub struct StreamsSlot {
    ready: bool,
    value: MaybeUninit<Streams>,
}

impl StreamsSlot {
    const EMPTY: StreamsSlot = StreamsSlot {
        ready: false,
        value: MaybeUninit::uninit(),
    };

    /// Builds the idle streams in the slot, once (in place: never on the stack).
    fn init(&mut self) {
        if !self.ready {
            StepStreams::init_in_place(
                &mut self.value,
                STEP_TIMING,
                NUCLEO_STEP_TIMER_MAX_PERIOD_TICKS,
            );
            self.ready = true;
        }
    }

    fn as_mut(&mut self) -> Option<&mut Streams> {
        // SAFETY: `ready` is set only after `value` was written.
        self.ready.then(|| unsafe { self.value.assume_init_mut() })
    }

    fn as_ref(&self) -> Option<&Streams> {
        // SAFETY: as in `as_mut`.
        self.ready.then(|| unsafe { self.value.assume_init_ref() })
    }
}

/// The board's [`StepBackend`]: arm-step's producer and buffers driving the timers.
pub struct BoardSteps {
    /// Set by [`init`]; `None` before (so that the static is all zeros: .bss, not a
    /// 14 KiB .data image copied from flash at boot).
    streams: StreamsSlot,
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
    /// Idle, without streams (set by [`init`]).
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
        match self.streams.as_mut() {
            Some(streams) => streams.producer().push(segment),
            None => Err(segment),
        }
    }

    fn queued(&self) -> usize {
        self.streams
            .as_ref()
            .map_or(0, |s| s.producer_ref().queued())
    }

    /// Primes every joint's prelude and buffer (the producer's work for the run's first
    /// 2 * HALF periods), sets the first DIR levels and starts all timers together.
    fn start(&mut self, at_tick: u64) {
        if self.run != Run::Idle {
            return;
        }
        let Some(streams) = self.streams.as_mut() else {
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
            load_joint(joint, prelude);
        }
        for joint in 0..MAX_JOINTS {
            let timer = joint_timer(joint);
            timer.write(reg::CR1, reg::CR1_URS | reg::CR1_ARPE | reg::CR1_CEN);
        }
        // The step clock runs on; its tick at the joint timers' start is their tick 0.
        // It is read after the counters started, so the DIR alarms (on the step clock)
        // fire a few ticks late rather than early: never while STEP is still high (the
        // DIR setup includes DIR_LATENCY_NS for this and the interrupt's latency).
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
        let Some(streams) = self.streams.as_mut() else {
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
        let Some(streams) = self.streams.as_ref() else {
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
                .as_mut()
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
    fn refill(&mut self, joint: usize, half: usize) -> StepProgress {
        if self.run == Run::Idle {
            return StepProgress::default();
        }
        let Some(streams) = self.streams.as_mut() else {
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
        let Some(streams) = self.streams.as_mut() else {
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
        let Some(streams) = self.streams.as_ref() else {
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

/// Where a stream stood when it was stopped.
#[derive(Clone, Copy, Debug, Default)]
pub struct StreamPosition {
    /// Index (0..2*HALF) of the next period the stream would have transferred.
    pub next: usize,
    /// The half other than the one of the first unplayed period (`next - 1`, in the
    /// preload register) was played and not refilled yet (its interrupt was pending).
    pub other_half_played: bool,
    /// The first unplayed period (`next - 1`) is the last of its half and that half was
    /// refilled since: the period lives on only in the preload register.
    pub preload_evicted: bool,
}

/// Stops every step timer and DMA stream and forces every STEP output low, in one
/// critical section: no STEP edge after this returns. For the emergency stop, the end of
/// a run, an underrun and the fault path (callable from any context, also a fault
/// handler: it only writes registers). Returns where each stream stood.
pub fn stop_all_step_outputs() -> [StreamPosition; MAX_JOINTS] {
    critical_section::with(|_| {
        // Outputs first: forced inactive is immediate, whatever the counter does.
        for joint in 0..MAX_JOINTS {
            let timer = joint_timer(joint);
            timer.write(reg::CCMR1, reg::CCMR1_FORCE_INACTIVE);
        }
        let mut positions = [StreamPosition::default(); MAX_JOINTS];
        for (joint, position) in positions.iter_mut().enumerate() {
            let timer = joint_timer(joint);
            timer.write(reg::CR1, reg::CR1_URS | reg::CR1_ARPE);
            timer.write(reg::DIER, 0);
            pac::DMA2.st(joint).cr().modify(|w| w.set_en(false));
            *position = stream_position(joint);
            clear_stream_flags(joint);
        }
        positions
    })
}

/// The first period of a stream that has not started, from where it stands (`None`: the
/// prelude's second period has not either); `started`: it has left the prelude.
fn first_unplayed(started: bool, at: StreamPosition) -> Option<usize> {
    // The period in the preload register (the one before `next`) has not started either.
    (started || at.next > 0).then_some((at.next + 2 * HALF - 1) % (2 * HALF))
}

/// Where joint `joint`'s stream stands (running or stopped).
fn stream_position(joint: usize) -> StreamPosition {
    let remaining = pac::DMA2.st(joint).ndtr().read().ndt() as usize;
    let done = BUFFER_WORDS.saturating_sub(remaining) / WORDS_PER_PERIOD;
    let flags = pac::DMA2.isr(joint / 4).read();
    let n = joint % 4;
    let next = done % (2 * HALF);
    // The first unplayed period is the one in the preload register (next - 1); the other
    // half than its own is stale if its refill is still pending (HT: half 0 played, TC:
    // half 1 played).
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
        // The half's end was read (its flag was raised); not pending any more: refilled.
        preload_evicted: preload % HALF == HALF - 1 && !own_flag,
    }
}

/// Clears every interrupt flag of DMA2 stream `joint`.
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

/// Loads joint `joint`'s timer with the prelude (period 0 active, period 1 preloaded) and
/// enables its stream; the counter is started by the caller.
#[allow(
    clippy::indexing_slicing,
    clippy::cast_possible_truncation,
    reason = "joint < MAX_JOINTS (start's loop); BUFFER_WORDS fits 16 bits (const assert) and addresses are 32 bits"
)]
fn load_joint(joint: usize, prelude: &[PulsePeriod; PRELUDE]) {
    let timer = joint_timer(joint);
    let [first, second] = prelude;
    timer.write(reg::CR1, reg::CR1_URS | reg::CR1_ARPE);
    timer.write(reg::DIER, 0);
    timer.write(reg::CNT, 0);
    timer.write(reg::ARR, first.reload);
    timer.write(reg::CCR1, first.high);
    timer.write(reg::CCMR1, reg::CCMR1_OC1PE | reg::CCMR1_PWM1);
    // Loads ARR/CCR1 into the active registers (URS: no DMA request for this one).
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

const _: () = assert!(BUFFER_WORDS <= u16::MAX as usize);

/// One-time set-up: clocks of the joint timers and DMA2, every timer's output forced
/// inactive (STEP low) and enabled, DMAMUX routes, the streams' interrupts at P1 (below
/// the step clock's P0, which makes the DIR changes). Call before the STEP pins are
/// switched to their timers.
pub fn init() {
    // SAFETY: before any stream runs or any refill can touch them: `.sram1` is NOLOAD,
    // so the buffers are zeroed here, not by the reset handler.
    // `JointBuffer::ZERO` is all zero bytes.
    unsafe { BUFFERS.0.get().write_bytes(0, 1) };
    let (start, len) = dma_buffer_region();
    defmt::debug!(
        "step DMA buffers at {=usize:#x}, {=usize} bytes",
        start,
        len
    );
    STEP.with_engine(|steps| steps.streams.init());
    pac::RCC.apb1lenr().modify(|w| {
        w.set_tim2en(true);
        w.set_tim3en(true);
        w.set_tim4en(true);
        w.set_tim5en(true);
    });
    pac::RCC.apb2enr().modify(|w| {
        w.set_tim1en(true);
        w.set_tim8en(true);
        w.set_tim16en(true);
        w.set_tim17en(true);
    });
    pac::RCC.ahb1enr().modify(|w| w.set_dma2en(true));
    for joint in 0..MAX_JOINTS {
        let timer = joint_timer(joint);
        timer.write(reg::CR1, reg::CR1_URS | reg::CR1_ARPE);
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
            timer.write(reg::BDTR, reg::BDTR_MOE);
        }
        // DMA2 stream `joint` is DMAMUX1 channel 8 + joint.
        pac::DMAMUX1
            .ccr(8 + joint)
            .write(|w| w.set_dmareq_id(timer.request));
    }
    for irq in STREAM_IRQS {
        irq.set_priority(Priority::P1);
        // SAFETY: the handlers below only touch STEP (critical section) and DMA2's flags.
        unsafe { irq.enable() };
    }
}

/// The streams' interrupts, joint order.
const STREAM_IRQS: [interrupt::Interrupt; MAX_JOINTS] = [
    interrupt::DMA2_STREAM0,
    interrupt::DMA2_STREAM1,
    interrupt::DMA2_STREAM2,
    interrupt::DMA2_STREAM3,
    interrupt::DMA2_STREAM4,
    interrupt::DMA2_STREAM5,
    interrupt::DMA2_STREAM6,
    interrupt::DMA2_STREAM7,
];

/// The body of joint `joint`'s stream interrupt: refill the half the stream left, or stop
/// everything on an underrun or a transfer error.
fn refill(joint: usize) {
    let n = joint % 4;
    let flags = pac::DMA2.isr(joint / 4).read();
    clear_stream_flags(joint);
    let (half_played, full_played) = (flags.htif(n), flags.tcif(n));
    let remaining = pac::DMA2.st(joint).ndtr().read().ndt() as usize;
    let next = BUFFER_WORDS.saturating_sub(remaining) / WORDS_PER_PERIOD;
    // HT: half 0 played, the stream is in half 1. TC: half 1 played, back in half 0.
    let half = usize::from(full_played);
    let in_half = next / HALF;
    let underrun = flags.teif(n) || (half_played && full_played) || in_half == half;
    STEP.on_interrupt(&crate::BUS.step_wake, |steps| {
        if !half_played && !full_played {
            return ((), StepProgress::default());
        }
        if underrun {
            // The stream reached periods that were never refilled: stop as for STOPPED;
            // the controller sees the run end early (STATUS underrun flag).
            defmt::warn!("step stream {} underrun", joint);
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

#[interrupt]
fn DMA2_STREAM0() {
    refill(0);
}
#[interrupt]
fn DMA2_STREAM1() {
    refill(1);
}
#[interrupt]
fn DMA2_STREAM2() {
    refill(2);
}
#[interrupt]
fn DMA2_STREAM3() {
    refill(3);
}
#[interrupt]
fn DMA2_STREAM4() {
    refill(4);
}
#[interrupt]
fn DMA2_STREAM5() {
    refill(5);
}
#[interrupt]
fn DMA2_STREAM6() {
    refill(6);
}
#[interrupt]
fn DMA2_STREAM7() {
    refill(7);
}

/// Counter of each joint timer (for debugging with a probe).
#[allow(dead_code)]
pub fn counters() -> [u32; MAX_JOINTS] {
    core::array::from_fn(|j| joint_timer(j).read(reg::CNT))
}
