//! The safety stop: every STEP output low, every counter and stream stopped.
//!
//! Two forms. [`kill_step_outputs`] is the wired e-stop input's (EXTI0, P0, above the step
//! lock): register accesses only, no step state touched, and [`KILL`] set first, so that a
//! run's start it preempted cannot turn an output back on (`backend.rs`: every write
//! that enables a timer or stream for a run is made in a short critical section that
//! checks [`KILL`] first; the stop's own resumed counters can end a pulse, never start
//! one). [`stop_all_step_outputs`] is everyone else's (the stop under the step
//! lock, the end of a run, an underrun, the fault path): the same writes, then where each
//! stream stood, then its flags cleared.

use core::sync::atomic::{AtomicBool, Ordering};

use arm_step::MAX_JOINTS;

use embassy_stm32::pac;

use super::registers::{
    StreamPosition, clear_stream_flags, disable_stream, joint_timer, reg, stream_position,
};
use crate::pins::STEP_LINES;

/// Set by [`kill_step_outputs`] (the e-stop input opened) until the service interrupt has
/// halted the step backend under the step lock (`super::service`). While set, no
/// timer or stream is enabled.
pub(super) static KILL: AtomicBool = AtomicBool::new(false);

/// Every joint's STEP output stopped: no pulse starts once this returns, and a pulse under
/// way ends at its own width; then every DMA stream stopped.
///
/// Per joint: its counter frozen (CEN cleared) and its update DMA request off, so that no
/// period starts and the stream does not move on while the output changes (a period
/// started in between would be counted as played with no rising edge, or made with no
/// count: Renode showed joints one step ahead of their pins when the outputs were forced
/// first and the counters stopped after). Then, if its STEP pin is high, a pulse is under
/// way: it was counted as made when it rose, so it must last the drivers' least high time
/// (cut short, a driver may miss it and the arm is a step off what the controller counts;
/// a stop landing mid-pulse did that before). Its output is switched to "inactive on
/// match" (RM0433, OCxM = 0010: low when the counter reaches CCR1, never raised again by
/// the counter) and the counter resumes: the pulse falls at its own CCR1, by the timer
/// (with the CPU masked or faulted too), as wide as it was to be plus the few instructions
/// the counter was frozen, and no later period rises. A joint whose pin is low is forced
/// inactive, its counter left frozen.
///
/// The e-stop input's interrupt may preempt this between any two writes and make the same
/// ones; each joint ends either forced low, or resumed in "inactive on match" with its pin
/// falling at its CCR1: never a rise.
fn outputs_off() {
    for joint in 0..MAX_JOINTS {
        let timer = joint_timer(joint);
        timer.write(reg::CR1, reg::CR1_URS | reg::CR1_ARPE);
        timer.write(reg::DIER, 0);
        // Read back: both writes have reached the timer (on APB) before the pin (on AHB4)
        // is read; a posted write landing after that read could let a pulse rise unseen.
        let _ = timer.read(reg::DIER);
        if step_pin_high(joint) {
            timer.write(reg::CCMR1, reg::CCMR1_OC1PE | reg::CCMR1_INACTIVE_ON_MATCH);
            timer.write(reg::CR1, reg::CR1_URS | reg::CR1_ARPE | reg::CR1_CEN);
        } else {
            timer.write(reg::CCMR1, reg::CCMR1_FORCE_INACTIVE);
        }
    }
    for joint in 0..MAX_JOINTS {
        // Not a bare EN clear: that sets TCIF, which stream_position would read as "half 1
        // played" (disable_stream). Made twice when the e-stop input's stop preempts this
        // one: the second finds the stream off and its flags as the first left them, or
        // clears the TCIF the first one's disable set once the first one resumes.
        disable_stream(joint);
    }
}

/// Joint `joint`'s STEP pin is high (its input data register: the pin itself, whichever
/// timer output drives it).
#[allow(
    clippy::indexing_slicing,
    reason = "joint < MAX_JOINTS (outputs_off's loop)"
)]
fn step_pin_high(joint: usize) -> bool {
    let (port, pin) = STEP_LINES[joint];
    port.idr().read().idr(pin) == pac::gpio::vals::Idr::HIGH
}

/// The e-stop input's stop, from its interrupt (P0): [`KILL`] set, then every output off.
/// Leaves the streams' positions and flags as they are, for the halt under the step lock
/// that follows (the service interrupt) to take back the unplayed pulses from them.
pub fn kill_step_outputs() {
    KILL.store(true, Ordering::SeqCst);
    outputs_off();
}

/// The e-stop input's stop has been handled under the step lock (the backend halted: no
/// run starts until the input closes): outputs may be enabled again.
pub fn kill_handled() {
    KILL.store(false, Ordering::SeqCst);
}

/// Stops every step timer and DMA stream and takes every STEP output low: no rising STEP
/// edge after this returns, and a pulse under way falls at its own width, at most one
/// pulse width later ([`outputs_off`]). For the stop under the step lock, the end of a run, an underrun and
/// the fault path (callable from any context: it only writes registers). Returns where
/// each stream stood.
///
/// Not a critical section (issue 20: it was 649 instructions with every interrupt
/// masked): nothing that enables an output runs meanwhile, because its callers hold the
/// step lock (which excludes the run's start and the refills) or have masked every
/// interrupt (the fault path); the e-stop input's interrupt may preempt it and make the
/// same writes, which changes nothing.
pub fn stop_all_step_outputs() -> [StreamPosition; MAX_JOINTS] {
    outputs_off();
    let mut positions = [StreamPosition::default(); MAX_JOINTS];
    for (joint, position) in positions.iter_mut().enumerate() {
        *position = stream_position(joint);
        clear_stream_flags(joint);
    }
    positions
}
