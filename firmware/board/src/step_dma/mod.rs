//! STEP pulses made by timer hardware: one timer per joint in PWM mode, its period and
//! pulse width reloaded at every update event by a DMA stream from a double buffer that
//! the CPU refills half by half.
//!
//! Each joint's timer (see `pins.rs` for the map) runs PWM mode 1 on CH1 (joint 5: CH1N)
//! with ARR and CCR1 preloaded. At each update event its DMA request makes a DMA stream
//! (joints 0-3, the APB1 timers: DMA1 streams 0-3; joints 4-7, the APB2 timers: DMA2
//! streams 0-3; `registers::joint_stream`) write the next [`arm_step::PulsePeriod`] (ARR, RCR, CCR1) through the timer's DMA burst register
//! (`DCR.DBA` = ARR, three transfers): a period that starts with a pulse of `high` ticks,
//! or none. Rising edges are period starts: placed by the counter to the tick, with no
//! CPU involved. The stream is circular over [`HALF`]` * 2` periods; its half-transfer and
//! transfer-complete interrupts ([`refill::refill`]) refill the half it just left with
//! [`arm_step::StepStreams::refill`] (arm-step's producer). The CPU's whole share is the producer's
//! arithmetic and the interrupts around it: 38 to 54 instructions per step at 100 kHz per
//! joint (scripts/step-cost: the whole path, TIM13's wraps, DIR alarms and the step
//! service included).
//!
//! DIR lines change at reversals only, when the joint's previous pulse has fallen, from
//! the step clock's compare interrupt (`step_timer.rs`), and the producer places the next
//! pulse no sooner than the DIR setup time (plus the profile's `dir_latency_ns` for the
//! interrupt) after. No step-path section holds that interrupt off (issue 20): the lock
//! around [`STEP`] is BASEPRI at P2 (`lock.rs`), below it, and the interrupt takes its DIR
//! changes from [`DIRS`] (arm-step's lock-free queues) without the lock. The run ends at
//! the producer's `run_end_tick`: the step clock sees it and pends the step service
//! (`service.rs`, P2), which ends it under the lock.
//!
//! Safety: [`stop_all_step_outputs`] freezes every counter and forces its STEP output
//! inactive, except that a pulse under way is left to end at its own width (OCxM =
//! inactive on match, the counter resumed: `stop.rs`), and disables the streams, for STOPPED, the end of a run, an underrun (a stream
//! that reaches a half its interrupt has not refilled: [`refill::refill`] sees both halves
//! played, or the stream already back in the half it is about to write) and the fault
//! path; the wired e-stop input's interrupt, above the step lock, makes the same writes
//! with [`kill_step_outputs`] and leaves the rest to the step service (`crate::estop`'s
//! header has every interleaving). The interrupts are bounded: a refill writes one half and returns; nothing
//! re-pends itself, so no step path can starve the tasks.
//!
//! Memory: the buffers are a static in SRAM2 (`.sram2`, zeroed by [`init`]): DMA1 and DMA2
//! reach it (never DTCM), no other DMA uses it (the Ethernet DMA's descriptors and packets
//! are in SRAM1, so the streams' reads never wait behind it: issue 34), and MPU region 2
//! makes all of SRAM2 non-cacheable, so with the D-cache on the streams read what the
//! refills wrote ([`dma_buffer_region`], `memory.rs`).
//!
//! Files: this one has the board's profile (its figures, from arm-core's `profile`), the buffers and [`init`]; `registers.rs` the
//! joint timers' and streams' registers (loading a run's prelude, where a stream stands);
//! `backend.rs` [`STEP`], [`DIRS`] and its [`backend::BoardSteps`] (arm-core's
//! `StepBackend`: start, stop, positions, the run's end); `lock.rs` the step lock;
//! `refill.rs` the streams' interrupts; `service.rs` the step service interrupt; `stop.rs`
//! [`stop_all_step_outputs`] and [`kill_step_outputs`].

use core::cell::UnsafeCell;

use arm_core::profile::{self, BoardProfile};
use arm_step::{JointBuffer, MAX_JOINTS, StepTiming};
use embassy_stm32::interrupt::InterruptExt;
use embassy_stm32::pac;

mod backend;
mod lock;
mod refill;
mod registers;
mod service;
mod stop;

pub use backend::{DIRS, STEP};
pub use lock::{DIR_PRIORITY, STEP_LOCK_PRIORITY};
pub use service::SERVICE_IRQ;
pub use stop::{kill_handled, kill_step_outputs, stop_all_step_outputs};

use refill::STREAM_IRQS;
use registers::{configure_joint_timer, dmamux_channel, joint_timer};

/// This board's profile (arm-core's `profile`: every per-board figure, with its reason):
/// `--features tmc-drivers` for TMC-class driver timing, otherwise the opto-isolated
/// drivers' (safe for all).
#[cfg(not(feature = "tmc-drivers"))]
pub const PROFILE: BoardProfile = profile::NUCLEO_H743ZI2;
/// This board's profile, built for TMC-class drivers.
#[cfg(feature = "tmc-drivers")]
pub const PROFILE: BoardProfile = profile::NUCLEO_H743ZI2_TMC;

/// Periods per buffer half (the profile's).
pub const HALF: usize = PROFILE.step_buffer_half;

/// Segments the step producer holds: the profile's lookahead in time (50 ms of 200 us
/// points).
pub const STEP_QUEUE: usize = PROFILE.step_queue();

/// The joint timers' input clock (APB1 and APB2 timer clocks, `clocks.rs`).
pub const STEP_TIMER_HZ: u32 = PROFILE.step_timer_hz;

/// The step timing of every joint: the profile's driver timing on [`STEP_TIMER_HZ`], its
/// DIR setup lengthened by the profile's `dir_latency_ns` (the step clock's interrupt,
/// which changes DIR, can be held off by a short critical section and runs its own
/// joints one after the other).
pub const STEP_TIMING: StepTiming = PROFILE.step_timing();

/// The longest period of each joint's stream: its timer's range (2^32 ticks for TIM2 and
/// TIM5, 2^16 for the 16-bit ones), capped at 2^16 so that a speed change (issue 32) waits
/// for at most two buffer halves of 328 us periods (`profile::STREAM_PERIOD_CAP_NS`).
pub const MAX_PERIOD_TICKS: [u32; MAX_JOINTS] = PROFILE.stream_period_ticks();

/// Every joint's DMA buffer. Written by the refills (inside [`STEP`]'s lock,
/// for the half the stream is not reading) and read by the DMA.
struct Buffers(UnsafeCell<[JointBuffer<HALF>; MAX_JOINTS]>);

// SAFETY: every CPU access happens inside STEP's lock; the DMA reads the other
// half (the refill checks where the stream is before it writes).
unsafe impl Sync for Buffers {}

/// In SRAM2 (`.sram2`, NOLOAD: zeroed by [`init`]), which MPU region 2 makes
/// non-cacheable (`memory.rs`): the DMA never reads a period still in the D-cache, and
/// never waits for the Ethernet DMA (SRAM1).
#[unsafe(link_section = ".sram2.step_buffers")]
static BUFFERS: Buffers = Buffers(UnsafeCell::new([JointBuffer::ZERO; MAX_JOINTS]));

/// Address and length of the step DMA buffers (inside SRAM2, MPU region 2; logged at
/// debug level by [`init`]).
pub fn dma_buffer_region() -> (usize, usize) {
    (
        BUFFERS.0.get() as usize,
        core::mem::size_of::<[JointBuffer<HALF>; MAX_JOINTS]>(),
    )
}

/// SYSCFG_CFGR (RM0433 SYSCFG register map: offset 0x18 from SYSCFG's base), which the
/// PAC does not describe.
const SYSCFG_CFGR_OFFSET: usize = 0x18;
/// SYSCFG_CFGR.CM7L: the Cortex-M7 LOCKUP output drives the break input of TIM1, TIM8,
/// TIM15, TIM16 and TIM17. Write-once: only a reset clears it.
const SYSCFG_CFGR_CM7L: u32 = 1 << 6;

/// Routes a core lockup (a fault while entering HardFault: no handler runs, the IWDG
/// resets only after its timeout) to the break inputs: joints 4-7 (TIM1, TIM8, TIM16,
/// TIM17) stop pulsing at once, in hardware. Joints 0-3 (TIM2-TIM5) have no break
/// input: their streams replay until the IWDG resets the chip (docs/BOARD.md).
fn route_lockup_to_timer_breaks() {
    pac::RCC.apb4enr().modify(|w| w.set_syscfgen(true));
    let cfgr = pac::SYSCFG
        .as_ptr()
        .cast::<u8>()
        .wrapping_add(SYSCFG_CFGR_OFFSET)
        .cast::<u32>();
    // SAFETY: SYSCFG_CFGR of this chip; a volatile read-modify-write of one register
    // before any timer runs.
    unsafe { cfgr.write_volatile(cfgr.read_volatile() | SYSCFG_CFGR_CM7L) };
}

/// One-time set-up: clocks of the joint timers, DMA1 and DMA2, every timer's output forced
/// inactive (STEP low) and enabled, DMAMUX routes, the streams' and the step service's
/// interrupts at P2 (the step lock's level, below the step clock's P1, which makes the
/// DIR changes). Call before the STEP pins are switched to their timers.
pub fn init() {
    // SAFETY: before any stream runs or any refill can touch them: `.sram2` is NOLOAD,
    // so the buffers are zeroed here, not by the reset handler.
    // `JointBuffer::ZERO` is all zero bytes.
    unsafe { BUFFERS.0.get().write_bytes(0, 1) };
    let (start, len) = dma_buffer_region();
    defmt::debug!(
        "step DMA buffers at {=usize:#x}, {=usize} bytes",
        start,
        len
    );
    STEP.with_engine(|steps| steps.streams.init(STEP_TIMING, MAX_PERIOD_TICKS));
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
    pac::RCC.ahb1enr().modify(|w| {
        w.set_dma1en(true);
        w.set_dma2en(true);
    });
    for joint in 0..MAX_JOINTS {
        if let Err(e) = configure_joint_timer(joint) {
            // Loud, not fatal (issue 34): every run's start checks again and refuses, so
            // no STEP output is trusted to a timer that did not take CCER or BDTR; the rest
            // of the controller (network, gripper, serial) stays up to be looked at.
            // Renode's stock timers (tests/tests/renode.rs) have no BDTR and log this.
            defmt::error!(
                "step timer did not take its configuration: {}; runs will be refused",
                e
            );
        }
        pac::DMAMUX1
            .ccr(dmamux_channel(joint))
            .write(|w| w.set_dmareq_id(joint_timer(joint).request));
    }
    route_lockup_to_timer_breaks();
    for irq in STREAM_IRQS {
        irq.set_priority(STEP_LOCK_PRIORITY);
        // SAFETY: the handlers only touch STEP (its lock, at their level) and their
        // streams' flags.
        unsafe { irq.enable() };
    }
    service::init();
}
