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
        // Each joint's counter stopped, then its output forced inactive (low at once,
        // whatever the counter does), before the next joint's: two stores per joint. The
        // counter first, so that no period starts once the output is forced: a period
        // started there would be counted as played (the stream moved on) with no rising
        // edge (Renode: joints 3-5 one step ahead of their pins when the outputs were all
        // forced first and the counters stopped after, joint by joint, between DMA
        // reads). A pulse under way when the counter stops has risen, and ends at the
        // force, one store later.
        for joint in 0..MAX_JOINTS {
            let timer = joint_timer(joint);
            timer.write(reg::CR1, reg::CR1_URS | reg::CR1_ARPE);
            timer.write(reg::CCMR1, reg::CCMR1_FORCE_INACTIVE);
        }
        let mut positions = [StreamPosition::default(); MAX_JOINTS];
        for (joint, position) in positions.iter_mut().enumerate() {
            let timer = joint_timer(joint);
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
