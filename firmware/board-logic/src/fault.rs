//! The one fault path: a panic and a HardFault (and any fault escalated to it) both end
//! here, and it brings the arm to a safe state before the reset.
//!
//! The order is the point, and it is fixed by [`enter_safe_state`]:
//!
//! 1. mask interrupts: from here nothing (step interrupt, gripper reload, DMA completion)
//!    can raise a STEP line or restart a timer behind our back;
//! 2. stop all step output: every step timer and the DMA streams that feed it (one hook,
//!    [`SafeStateHw::stop_all_step_output`]), so no new edge is made;
//! 3. force every STEP line low: a pulse cut in its high phase must not stay high (a
//!    driver would count it, or see a stuck line);
//! 4. stop the gripper timer and force its output low (a multi-burst move would otherwise
//!    pulse forever);
//! 5. stop every other DMA stream (serial): nothing writes memory during the reset;
//! 6. apply the ENABLE policy ([`ENABLE_POLICY`]);
//! 7. log what happened (defmt over RTT: slow, so after the outputs are safe);
//! 8. reset.
//!
//! A second fault inside the path (a bus fault while logging, say) re-enters it: the
//! outputs are made safe again (idempotent register writes) and the board resets without
//! logging.

/// What the fault path does with the drivers' ENABLE lines.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum EnablePolicy {
    /// Every driver enabled (holding torque, no steps): a joint under load keeps its
    /// position instead of dropping. This is also the state the firmware boots in
    /// (`Controller::new`: drivers enabled), so the ENABLE lines do not change between the
    /// fault and the restart, except for the milliseconds of the reset itself, where the
    /// pins float (see docs/BOARD.md: pull-downs hold active-low ENABLE inputs enabled).
    HoldAll,
    /// Every driver disabled (motors free): for arms where a powered but uncommanded
    /// driver is the greater hazard. Not this board's choice.
    ReleaseAll,
}

/// The board's ENABLE policy on a fault: hold (see [`EnablePolicy::HoldAll`]).
pub const ENABLE_POLICY: EnablePolicy = EnablePolicy::HoldAll;

/// What went wrong.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FaultKind {
    /// A Rust panic (its message is logged by the panic handler itself).
    Panic,
    /// A HardFault (or a bus, memory-management or usage fault escalated to it).
    HardFault {
        /// The faulting instruction's address (the stacked PC).
        pc: u32,
        /// SCB CFSR: which fault, why.
        cfsr: u32,
        /// SCB HFSR.
        hfsr: u32,
        /// SCB BFAR: the bus fault's data address, when CFSR's BFARVALID is set.
        bfar: u32,
    },
    /// The watchdog task found a task hung (board-logic `watchdog`): the safe state now,
    /// rather than an IWDG reset that leaves the outputs to float.
    TaskHung {
        /// Which heartbeat stopped (the board's list: 0 trajectory task, 1 network task).
        task: u8,
    },
    /// An interrupt with no handler fired (cortex-m-rt's default handler would spin).
    UnexpectedInterrupt {
        /// Its number (negative: a system exception).
        irqn: i16,
    },
}

/// The register writes of the fault path, in the board's terms. Every method must be safe
/// to call from any context, with interrupts masked, more than once.
pub trait SafeStateHw {
    /// Masks every interrupt (PRIMASK).
    fn mask_interrupts(&mut self);
    /// Stops every step timer and the DMA streams that feed it: no new STEP edge (the
    /// NUCLEO: `step_dma::stop_all_step_outputs`).
    fn stop_all_step_output(&mut self);
    /// Drives every STEP line low.
    fn force_step_low(&mut self);
    /// Stops the gripper timer and its interrupt; its output low.
    fn stop_gripper(&mut self);
    /// Disables every other DMA stream.
    fn stop_dma_streams(&mut self);
    /// Sets the ENABLE lines as `policy` says.
    fn apply_enable_policy(&mut self, policy: EnablePolicy);
    /// Logs the fault.
    fn log(&mut self, fault: &FaultKind);
    /// Resets the chip (on the board this never returns).
    fn reset(&mut self);
}

/// Brings the outputs to the safe state, logs and resets (see the module documentation).
/// `reentered`: a fault happened while the path was already running (the board keeps
/// that flag in an atomic); the log is skipped.
pub fn enter_safe_state(hw: &mut impl SafeStateHw, fault: &FaultKind, reentered: bool) {
    hw.mask_interrupts();
    hw.stop_all_step_output();
    hw.force_step_low();
    hw.stop_gripper();
    hw.stop_dma_streams();
    hw.apply_enable_policy(ENABLE_POLICY);
    if !reentered {
        hw.log(fault);
    }
    hw.reset();
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::vec::Vec;

    #[derive(Debug, Clone, Copy, PartialEq, Eq)]
    enum Call {
        Mask,
        StopSteps,
        StepLow,
        StopGripper,
        StopDma,
        Enable(EnablePolicy),
        Log(FaultKind),
        Reset,
    }

    /// Records the calls, and the output state a scope on the board would see.
    #[derive(Default)]
    struct Recorder {
        calls: Vec<Call>,
        masked: bool,
        step_timer_running: bool,
        step_high: bool,
        gripper_running: bool,
    }

    impl Recorder {
        fn running() -> Self {
            Recorder {
                step_timer_running: true,
                step_high: true,
                gripper_running: true,
                ..Recorder::default()
            }
        }
    }

    impl SafeStateHw for Recorder {
        fn mask_interrupts(&mut self) {
            self.masked = true;
            self.calls.push(Call::Mask);
        }
        fn stop_all_step_output(&mut self) {
            self.step_timer_running = false;
            self.calls.push(Call::StopSteps);
        }
        fn force_step_low(&mut self) {
            // A running timer would raise the line again: it must be stopped first.
            assert!(
                !self.step_timer_running,
                "STEP lowered while the step timer runs"
            );
            self.step_high = false;
            self.calls.push(Call::StepLow);
        }
        fn stop_gripper(&mut self) {
            self.gripper_running = false;
            self.calls.push(Call::StopGripper);
        }
        fn stop_dma_streams(&mut self) {
            self.calls.push(Call::StopDma);
        }
        fn apply_enable_policy(&mut self, policy: EnablePolicy) {
            self.calls.push(Call::Enable(policy));
        }
        fn log(&mut self, fault: &FaultKind) {
            // Logging is slow: every output is already safe.
            assert!(self.masked && !self.step_high && !self.gripper_running);
            self.calls.push(Call::Log(*fault));
        }
        fn reset(&mut self) {
            self.calls.push(Call::Reset);
        }
    }

    #[test]
    fn a_panic_stops_steps_then_gripper_then_logs_then_resets() {
        let mut hw = Recorder::running();
        enter_safe_state(&mut hw, &FaultKind::Panic, false);
        assert_eq!(
            hw.calls,
            [
                Call::Mask,
                Call::StopSteps,
                Call::StepLow,
                Call::StopGripper,
                Call::StopDma,
                Call::Enable(EnablePolicy::HoldAll),
                Call::Log(FaultKind::Panic),
                Call::Reset,
            ]
        );
    }

    #[test]
    fn a_hard_fault_takes_the_same_path_with_its_registers() {
        let fault = FaultKind::HardFault {
            pc: 0x0800_1234,
            cfsr: 0x0000_8200,
            hfsr: 0x4000_0000,
            bfar: 0x081C_0040,
        };
        let mut hw = Recorder::running();
        enter_safe_state(&mut hw, &fault, false);
        assert_eq!(hw.calls[..6], Recorder::running_then_safe()[..]);
        assert_eq!(hw.calls[6..], [Call::Log(fault), Call::Reset]);
    }

    impl Recorder {
        fn running_then_safe() -> [Call; 6] {
            [
                Call::Mask,
                Call::StopSteps,
                Call::StepLow,
                Call::StopGripper,
                Call::StopDma,
                Call::Enable(ENABLE_POLICY),
            ]
        }
    }

    #[test]
    fn a_fault_inside_the_path_makes_outputs_safe_again_and_resets_without_logging() {
        let mut hw = Recorder::running();
        enter_safe_state(&mut hw, &FaultKind::Panic, true);
        assert_eq!(hw.calls[..6], Recorder::running_then_safe()[..]);
        assert_eq!(hw.calls[6..], [Call::Reset]);
    }

    #[test]
    fn the_policy_holds_the_drivers() {
        assert_eq!(ENABLE_POLICY, EnablePolicy::HoldAll);
    }
}
