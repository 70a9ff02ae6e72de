//! The joint timers' and DMA streams' registers: which timer and stream a joint has, loading
//! a timer with a run's prelude and starting its stream, where a stream stands, its flags.

use core::ptr::addr_of;

use arm_step::{MAX_JOINTS, PRELUDE, PulsePeriod};
use board_logic::step_stream;
use embassy_stm32::pac;

use super::{BUFFERS, HALF};

/// One joint's timer: registers, DMA request, and how its output is enabled.
#[derive(Clone, Copy)]
pub(super) struct JointTimer {
    /// Register block base.
    base: *mut u32,
    /// DMAMUX1 request of its update event.
    pub(super) request: u8,
    /// Advanced-control timer or TIM16/17: has BDTR.MOE.
    pub(super) has_moe: bool,
    /// The STEP output is CH1N (TIM8 on PA5), not CH1.
    pub(super) complementary: bool,
}

/// Register offsets common to every timer used (RM0433, timer register maps).
pub(super) mod reg {
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
    /// Alternate function option register 1 (TIM1, TIM8, TIM16, TIM17 only).
    pub const AF1: usize = 0x60;

    /// CR1: counter enable, update only on overflow (UG makes no DMA request), ARR
    /// preloaded.
    pub const CR1_CEN: u32 = 1 << 0;
    pub const CR1_URS: u32 = 1 << 2;
    pub const CR1_ARPE: u32 = 1 << 7;
    /// DIER: DMA request on update.
    pub const DIER_UDE: u32 = 1 << 8;
    /// EGR: update generation.
    pub const EGR_UG: u32 = 1 << 0;
    /// CCMR1: OC1 preload, PWM mode 1 (active while CNT < CCR1), forced inactive, and
    /// inactive on match (OC1REF low at CNT = CCR1 and never raised again: what a stop
    /// leaves a pulse under way to end on, `stop.rs`).
    pub const CCMR1_OC1PE: u32 = 1 << 3;
    pub const CCMR1_PWM1: u32 = 0b110 << 4;
    pub const CCMR1_FORCE_INACTIVE: u32 = 0b100 << 4;
    pub const CCMR1_INACTIVE_ON_MATCH: u32 = 0b010 << 4;
    /// CCER: CC1 output enable, CC1N output enable.
    pub const CCER_CC1E: u32 = 1 << 0;
    pub const CCER_CC1NE: u32 = 1 << 2;
    /// BDTR: main output enable.
    pub const BDTR_MOE: u32 = 1 << 15;
    /// BDTR: break enable, break active high, off-state in idle (MOE = 0) drives the
    /// outputs to their idle level (CR2.OIS1/OIS1N = 0: low) instead of releasing them.
    /// RM0433 "Using the break function": a break clears MOE at once, asynchronously,
    /// with no CPU; SYSCFG_CFGR.CM7L feeds the Cortex-M7 lockup into it (`init`).
    pub const BDTR_BKE: u32 = 1 << 12;
    pub const BDTR_BKP: u32 = 1 << 13;
    pub const BDTR_OSSI: u32 = 1 << 10;
    /// AF1: the BKIN pin's input. Cleared: the pins that could be BKIN (PA6, PE15, ...)
    /// are used otherwise or not wired; only the system break (lockup) may break.
    pub const AF1_BKINE: u32 = 1 << 0;
    /// DCR: burst from ARR (0x2C / 4 = 11), three transfers (DBL = 2): ARR, RCR, CCR1.
    pub const DCR_ARR_RCR_CCR1: u32 = 11 | (2 << 8);
}

impl JointTimer {
    pub(super) fn write(self, offset: usize, value: u32) {
        // SAFETY: `base` is a timer register block of this chip; `offset` is one of its
        // registers (mod reg); volatile word access is how the hardware is driven.
        unsafe { self.base.byte_add(offset).write_volatile(value) }
    }

    pub(super) fn read(self, offset: usize) -> u32 {
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
pub(super) fn joint_timer(joint: usize) -> JointTimer {
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

/// Puts joint `joint`'s timer through its RCC reset: every register back to its reset
/// value, including state no register shows (a DMA burst cut in the middle, the prescaler
/// and repetition counters), before [`configure_joint_timer`] and a run's prelude.
///
/// The release is read back (issue 34): the RCC write may still be on its way through the
/// bus bridges when the timer writes that follow land, and a timer still in reset ignores
/// them (CCER and BDTR are written only in [`configure_joint_timer`], which checks them).
pub(super) fn reset_joint_timer(joint: usize) {
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
    let in_reset = || match joint {
        0 => rcc.apb1lrstr().read().tim2rst(),
        1 => rcc.apb1lrstr().read().tim5rst(),
        2 => rcc.apb1lrstr().read().tim3rst(),
        3 => rcc.apb1lrstr().read().tim4rst(),
        4 => rcc.apb2rstr().read().tim1rst(),
        5 => rcc.apb2rstr().read().tim8rst(),
        6 => rcc.apb2rstr().read().tim16rst(),
        _ => rcc.apb2rstr().read().tim17rst(),
    };
    pulse(true);
    pulse(false);
    // The read-back: the release has reached the RCC. Bounded (a register that never
    // reads back is caught by configure_joint_timer's check).
    for _ in 0..RESET_READBACKS {
        if !in_reset() {
            break;
        }
    }
}

/// Reads of the RCC reset register after the release before [`reset_joint_timer`] gives
/// up: the first read normally returns it released (the read itself waits for the write
/// ahead of it on the same bus); the bound only keeps a broken chip from hanging the step
/// lock.
const RESET_READBACKS: u32 = 8;

/// A joint timer that did not take its configuration: its output enable (CCER) or, on
/// the timers with a break input, its main output and break (BDTR) read back otherwise
/// than written (a timer still in reset, or unclocked). The run does not start.
#[derive(Clone, Copy, Debug, PartialEq, Eq, defmt::Format)]
pub struct TimerNotConfigured {
    /// The joint.
    pub joint: usize,
    /// CCER as read back.
    pub ccer: u32,
    /// BDTR as read back (0 on the timers without one).
    pub bdtr: u32,
}

/// Joint `joint`'s timer at rest: counter stopped, no prescaler, STEP output forced
/// inactive (low) and enabled; on the timers with a break input, the main output on,
/// the lockup break armed, and the idle state low. CCER and BDTR are read back (issue
/// 34): a timer that did not take them would not pulse, or would not break on a lockup.
pub(super) fn configure_joint_timer(joint: usize) -> Result<(), TimerNotConfigured> {
    let timer = joint_timer(joint);
    timer.write(reg::CR1, reg::CR1_URS | reg::CR1_ARPE);
    timer.write(reg::CR2, 0);
    timer.write(reg::PSC, 0);
    timer.write(reg::CCMR1, reg::CCMR1_FORCE_INACTIVE);
    let ccer = if timer.complementary {
        reg::CCER_CC1NE
    } else {
        reg::CCER_CC1E
    };
    timer.write(reg::CCER, ccer);
    let bdtr = if timer.has_moe {
        timer.write(reg::AF1, timer.read(reg::AF1) & !reg::AF1_BKINE);
        let bdtr = reg::BDTR_MOE | reg::BDTR_BKE | reg::BDTR_BKP | reg::BDTR_OSSI;
        timer.write(reg::BDTR, bdtr);
        bdtr
    } else {
        0
    };
    let read_ccer = timer.read(reg::CCER);
    let read_bdtr = if timer.has_moe {
        timer.read(reg::BDTR)
    } else {
        0
    };
    // BDTR's low bits (dead time, lock) are not written here: compare the bits set.
    if read_ccer != ccer || read_bdtr & bdtr != bdtr {
        return Err(TimerNotConfigured {
            joint,
            ccer: read_ccer,
            bdtr: read_bdtr,
        });
    }
    Ok(())
}

/// Whether joint `joint`'s timer has had a break (its main output cleared by hardware).
pub(super) fn broken(joint: usize) -> bool {
    let timer = joint_timer(joint);
    timer.has_moe && timer.read(reg::BDTR) & reg::BDTR_MOE == 0
}

/// Joints per DMA controller: joints 0-3 (TIM2, TIM5, TIM3, TIM4, on APB1) on DMA1, joints
/// 4-7 (TIM1, TIM8, TIM16, TIM17, on APB2) on DMA2 (issue 34). Split by timer bus, each
/// controller writes its bursts through its own AHB-to-APB bridge, so neither waits for the
/// other's, and a burst waits behind at most three others (RM0433 "DMA arbitration": every
/// stream at very high priority, the lower number first), not seven: the profile's
/// `min_dma_period_ns` derivation (`arm_core::profile`).
pub(super) const JOINTS_PER_DMA: usize = 4;

/// Joint `joint`'s DMA controller and stream number (stream `joint % 4`: the step streams
/// are each controller's lowest, so they win ties with the serial port's DMA1 streams 4-5).
pub(super) fn joint_stream(joint: usize) -> (pac::dma::Dma, usize) {
    let dma = if joint < JOINTS_PER_DMA {
        pac::DMA1
    } else {
        pac::DMA2
    };
    (dma, joint % JOINTS_PER_DMA)
}

/// DMAMUX1 channel of joint `joint`'s stream (channels 0-7 feed DMA1 streams 0-7, 8-15
/// DMA2's: RM0433 "DMAMUX mapping").
pub(super) fn dmamux_channel(joint: usize) -> usize {
    let (_, stream) = joint_stream(joint);
    if joint < JOINTS_PER_DMA {
        stream
    } else {
        8 + stream
    }
}

const _: () = assert!(2 * JOINTS_PER_DMA == MAX_JOINTS);
// The profile's DMA timing model (`arm_core::profile::StepDma`, the step-rate ceiling and
// the shortest period derived from it) describes this split and this burst.
const _: () = assert!(super::PROFILE.step_dma.controllers == 2);
const _: () = assert!(super::PROFILE.step_dma.streams_per_controller as usize == JOINTS_PER_DMA);
const _: () = assert!(WORDS_PER_PERIOD == arm_core::profile::DMA_WORDS_PER_PERIOD as usize);

/// Words the stream moves per period (ARR, RCR, CCR1).
pub(super) use board_logic::step_stream::WORDS_PER_PERIOD;
/// Words in one joint's whole circular buffer.
pub(super) const BUFFER_WORDS: usize = 2 * HALF * WORDS_PER_PERIOD;

/// Where a stream stood when it was stopped (board-logic's `step_stream`).
pub use board_logic::step_stream::StreamPosition;

/// Where joint `joint`'s stream stands (running, or stopped by [`disable_stream`]):
/// board-logic's `step_stream::stream_position` of its NDTR and flags.
pub(super) fn stream_position(joint: usize) -> StreamPosition {
    let (dma, n) = joint_stream(joint);
    let remaining = dma.st(n).ndtr().read().ndt() as usize;
    let flags = dma.isr(n / 4).read();
    let n = n % 4;
    step_stream::stream_position::<HALF>(remaining, flags.htif(n), flags.tcif(n))
}

/// Reads of EN after clearing it before [`disable_stream`] gives up waiting: the transfer
/// under way is one word (direct mode), tens of cycles even behind other bus masters; the
/// bound only keeps the stop (also a fault handler's) from hanging on a broken stream.
const DISABLE_WAIT_READS: u32 = 1_000;

/// Disables joint `joint`'s stream (its timer already stopped: no new request) and leaves
/// its flags as its transfers set them, for [`stream_position`].
///
/// RM0433 (Rev 7) 15.3, "DMA transfer suspension": clearing EN lets the transfer under way
/// complete, then sets TCIF "to indicate the end of transfer", then EN reads 0 and NDTR
/// holds the items left. Read after that, TCIF would say "half 1 played, not refilled" when
/// it was not, and the stop would keep half 1's pulses as made (Renode's RM0433 DMA model:
/// joint 0 +124 reported for +60 made). So NDTR and TCIF are read before EN is cleared, and
/// once EN reads 0 a TCIF that no transfer set (board-logic's
/// `step_stream::tcif_from_disable`) is cleared; HTIF is never set by a disable.
pub(super) fn disable_stream(joint: usize) {
    let (dma, number) = joint_stream(joint);
    let stream = dma.st(number);
    let n = number % 4;
    // NDTR before TCIF: see tcif_from_disable.
    let ndtr = stream.ndtr().read().ndt();
    let tcif = dma.isr(number / 4).read().tcif(n);
    stream.cr().modify(|w| w.set_en(false));
    for _ in 0..DISABLE_WAIT_READS {
        if !stream.cr().read().en() {
            break;
        }
    }
    let ndtr_after = stream.ndtr().read().ndt();
    if step_stream::tcif_from_disable(step_stream::BeforeDisable { ndtr, tcif }, ndtr_after) {
        dma.ifcr(number / 4).write(|w| w.set_tcif(n, true));
    }
}

/// Clears every interrupt flag of joint `joint`'s stream.
pub(super) fn clear_stream_flags(joint: usize) {
    let (dma, number) = joint_stream(joint);
    let n = number % 4;
    dma.ifcr(number / 4).write(|w| {
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
pub(super) fn load_joint(joint: usize, prelude: &[PulsePeriod; PRELUDE]) {
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

    let (dma, number) = joint_stream(joint);
    let stream = dma.st(number);
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

/// The DIAG report's DMA slack (issue 34, `crate::diag`): joint `joint`'s timer counter
/// against the reload of the period it plays (arm-core's `DmaSlack::playing` of `next`,
/// the period the stream's next burst reads), before the refill overwrites it.
#[allow(
    clippy::indexing_slicing,
    reason = "playing() < 2 * HALF and joint < MAX_JOINTS (the refill's)"
)]
pub(super) fn sample_slack(joint: usize, next: usize) {
    let playing = arm_core::diag::DmaSlack::playing(next, 2 * HALF);
    let counter = joint_timer(joint).read(reg::CNT);
    // SAFETY: a volatile read of one period the stream played; the refills (this
    // interrupt's level) are the only writers and this one writes after.
    let reload = unsafe {
        addr_of!((*BUFFERS.0.get())[joint].periods[playing / HALF][playing % HALF].reload)
            .read_volatile()
    };
    crate::diag::refill_looked(reload, counter);
}

/// Counter of each joint timer (for debugging with a probe).
#[allow(dead_code)]
pub fn counters() -> [u32; MAX_JOINTS] {
    core::array::from_fn(|j| joint_timer(j).read(reg::CNT))
}
