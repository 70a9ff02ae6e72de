//! The safety stop: every STEP output low, every counter and stream stopped.
//!
//! Two forms. [`kill_step_outputs`] is the wired e-stop input's (EXTI0, P0, above the step
//! lock): register writes only, no step state touched, and [`KILL`] set first, so that a
//! run's start it preempted cannot turn an output back on (`backend.rs`: every write
//! that enables a timer or stream is made in a short critical section that checks
//! [`KILL`] first). [`stop_all_step_outputs`] is everyone else's (the stop under the step
//! lock, the end of a run, an underrun, the fault path): the same writes, then where each
//! stream stood, then its flags cleared.

use core::sync::atomic::{AtomicBool, Ordering};

use arm_step::MAX_JOINTS;

use super::registers::{
    StreamPosition, clear_stream_flags, disable_stream, joint_timer, reg, stream_position,
};

/// Set by [`kill_step_outputs`] (the e-stop input opened) until the service interrupt has
/// halted the step backend under the step lock (`super::service`). While set, no
/// timer or stream is enabled.
pub(super) static KILL: AtomicBool = AtomicBool::new(false);

/// Every joint's counter stopped and its STEP output forced inactive (the pin goes low at
/// once, whatever the counter does), then every update DMA request and stream stopped.
fn outputs_off() {
    // Each joint's counter stopped, then its output forced inactive, before the next
    // joint's: two stores per joint. The counter first, so that no period starts once the
    // output is forced: a period started there would be counted as played (the stream
    // moved on) with no rising edge (Renode: joints 3-5 one step ahead of their pins when
    // the outputs were all forced first and the counters stopped after, joint by joint,
    // between DMA reads). A pulse under way when the counter stops has risen, and ends at
    // the force, one store later.
    for joint in 0..MAX_JOINTS {
        let timer = joint_timer(joint);
        timer.write(reg::CR1, reg::CR1_URS | reg::CR1_ARPE);
        timer.write(reg::CCMR1, reg::CCMR1_FORCE_INACTIVE);
    }
    for joint in 0..MAX_JOINTS {
        joint_timer(joint).write(reg::DIER, 0);
        // Not a bare EN clear: that sets TCIF, which stream_position would read as "half 1
        // played" (disable_stream). Made twice when the e-stop input's stop preempts this
        // one: the second finds the stream off and its flags as the first left them, or
        // clears the TCIF the first one's disable set once the first one resumes.
        disable_stream(joint);
    }
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

/// Stops every step timer and DMA stream and forces every STEP output low: no STEP edge
/// after this returns. For the stop under the step lock, the end of a run, an underrun and
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
