//! The safety stop: every STEP output low, every counter and stream stopped.

use arm_step::MAX_JOINTS;

use super::registers::{
    StreamPosition, clear_stream_flags, disable_stream, joint_timer, reg, stream_position,
};

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
            // Not a bare EN clear: that sets TCIF, which stream_position would read as
            // "half 1 played" (disable_stream).
            disable_stream(joint);
            *position = stream_position(joint);
            clear_stream_flags(joint);
        }
        positions
    })
}
