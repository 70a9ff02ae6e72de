//! The fault path of the board: panics (Rust's and defmt's), HardFaults (bus, memory and
//! usage faults escalate to it) and interrupts without a handler all end in [`fault`],
//! which runs board-logic's [`enter_safe_state`] on [`BoardSafeState`]: every step timer
//! and DMA stream stopped, STEP low, gripper timer stopped and its pin low, ENABLE lines
//! per [`ENABLE_POLICY`] (hold: drivers energised), a defmt log line, then a system reset.
//! The order and the reasons are in board-logic's `fault` module, where a recording fake
//! checks them on the host.
//!
//! What the RTT log shows (then the boot banner again after the reset):
//! `ERROR fault: Panic (drivers holding, steps and gripper stopped)` preceded by the panic
//! message, or `ERROR fault: HardFault { pc: .., cfsr: .., hfsr: .., bfar: .. } ...`.

use core::panic::PanicInfo;
use core::sync::atomic::{AtomicBool, Ordering};

use board_logic::fault::{ENABLE_POLICY, EnablePolicy, FaultKind, SafeStateHw, enter_safe_state};
use cortex_m::peripheral::{NVIC, SCB};
use cortex_m_rt::{ExceptionFrame, exception};
use embassy_stm32::pac;
use embassy_stm32::pac::gpio::regs::Bsrr;

use crate::pins::STEP_LINES;

/// Set by the first fault; a fault while it is set skips the log.
static IN_FAULT: AtomicBool = AtomicBool::new(false);

/// The ENABLE lines, (port, pin): joints 0..7 then the gripper (PF0 PF1 PF2 PF7 PF8 PF9
/// PG0 PG1, PE3; `pins.rs`). Active low (`pins::ENABLE_ACTIVE_LOW`).
const ENABLE_LINES: [(pac::gpio::Gpio, u8); 9] = [
    (pac::GPIOF, 0),
    (pac::GPIOF, 1),
    (pac::GPIOF, 2),
    (pac::GPIOF, 7),
    (pac::GPIOF, 8),
    (pac::GPIOF, 9),
    (pac::GPIOG, 0),
    (pac::GPIOG, 1),
    (pac::GPIOE, 3),
];

/// The gripper's PWM output: PE5 (TIM15_CH1).
const GRIPPER_PWM_PIN: usize = 5;

/// The hook that stops all step output: every joint timer's counter frozen and its output
/// forced inactive (or left to end a pulse under way), its DMA stream disabled ([`crate::step_dma::stop_all_step_outputs`]),
/// and the step clock's interrupt (DIR changes, end of run) masked.
pub fn stop_all_step_output() {
    crate::step_dma::stop_all_step_outputs();
    NVIC::mask(pac::Interrupt::TIM8_UP_TIM13);
    NVIC::unpend(pac::Interrupt::TIM8_UP_TIM13);
}

/// [`SafeStateHw`] with direct register writes (no driver state: usable from any fault).
pub struct BoardSafeState<'a> {
    /// The panic being handled, for the log.
    pub panic: Option<&'a PanicInfo<'a>>,
}

impl SafeStateHw for BoardSafeState<'_> {
    fn mask_interrupts(&mut self) {
        cortex_m::interrupt::disable();
    }

    fn stop_all_step_output(&mut self) {
        stop_all_step_output();
    }

    fn force_step_low(&mut self) {
        // The timers already hold their outputs inactive; as plain outputs at 0 the lines
        // stay low whatever happens to the timers until the reset.
        for (port, pin) in STEP_LINES {
            port.bsrr().write_value(Bsrr(1 << (pin + 16)));
            port.moder()
                .modify(|w| w.set_moder(pin, pac::gpio::vals::Moder::OUTPUT));
        }
    }

    fn stop_gripper(&mut self) {
        let tim = pac::TIM15;
        tim.cr1().modify(|w| w.set_cen(false));
        tim.dier().write(|_| {});
        tim.ccmr_output()
            .modify(|w| w.set_ocm(0, pac::timer::vals::Ocm::FORCE_INACTIVE));
        NVIC::mask(pac::Interrupt::TIM15);
        // And take the pin from the timer: a plain output, low.
        pac::GPIOE
            .bsrr()
            .write_value(Bsrr(1 << (GRIPPER_PWM_PIN + 16)));
        pac::GPIOE
            .moder()
            .modify(|w| w.set_moder(GRIPPER_PWM_PIN, pac::gpio::vals::Moder::OUTPUT));
    }

    fn stop_dma_streams(&mut self) {
        for dma in [pac::DMA1, pac::DMA2] {
            for stream in 0..8 {
                dma.st(stream).cr().modify(|w| w.set_en(false));
            }
        }
    }

    fn apply_enable_policy(&mut self, policy: EnablePolicy) {
        let enabled = matches!(policy, EnablePolicy::HoldAll);
        // Active low: enabled = reset the bit (BSRR upper half).
        let shift = if enabled == crate::pins::ENABLE_ACTIVE_LOW {
            16
        } else {
            0
        };
        for (port, pin) in ENABLE_LINES {
            port.bsrr().write_value(Bsrr(1 << (u32::from(pin) + shift)));
        }
    }

    fn log(&mut self, fault: &FaultKind) {
        // The location only: formatting the message would link core::fmt's machinery
        // (kilobytes of flash) for a line that the source location already pins down.
        if let Some(location) = self.panic.and_then(|info| info.location()) {
            defmt::error!("panic at {}:{}", location.file(), location.line());
        }
        defmt::error!(
            "fault: {} (steps and gripper stopped, ENABLE {}); resetting",
            fault,
            ENABLE_POLICY
        );
    }

    fn reset(&mut self) {
        SCB::sys_reset();
    }
}

/// The fault path: safe state, log, reset.
pub fn fault(kind: FaultKind, panic: Option<&PanicInfo<'_>>) -> ! {
    let reentered = IN_FAULT.swap(true, Ordering::AcqRel);
    enter_safe_state(&mut BoardSafeState { panic }, &kind, reentered);
    SCB::sys_reset()
}

#[panic_handler]
fn panic(info: &PanicInfo<'_>) -> ! {
    fault(FaultKind::Panic, Some(info))
}

/// `defmt::panic!` and friends log their message, then come here.
#[defmt::panic_handler]
fn defmt_panic() -> ! {
    fault(FaultKind::Panic, None)
}

#[exception]
unsafe fn HardFault(frame: &ExceptionFrame) -> ! {
    // SAFETY: reads of the system control block's fault status registers.
    let scb = unsafe { &*SCB::PTR };
    fault(
        FaultKind::HardFault {
            pc: frame.pc(),
            cfsr: scb.cfsr.read(),
            hfsr: scb.hfsr.read(),
            bfar: scb.bfar.read(),
        },
        None,
    )
}

#[exception]
unsafe fn DefaultHandler(irqn: i16) {
    fault(FaultKind::UnexpectedInterrupt { irqn }, None)
}
