//! The step task: feeds the engine from `bus.segments`.

use embassy_futures::select::select;

use crate::bus::{Bus, SegmentMsg};
use crate::hw::StepKick;
use crate::step_shared::{PushOutcome, START_LEAD_US, StepBackend, StepShared, us_to_ticks};

/// Moves segments from `bus.segments` into the engine as its queue frees up, starts a
/// pending run with the first one, kicks the step timer, and tells the trajectory task
/// when segments finished (relayed from the interrupt) or the segment channel has room.
pub async fn step_task<const Q: usize, B: StepBackend, K: StepKick>(
    bus: &Bus,
    step: &StepShared<Q, B>,
    kick: &K,
) -> ! {
    let lead = us_to_ticks(u64::from(START_LEAD_US), step.timing().tick_hz);
    let mut held: Option<SegmentMsg> = None;
    loop {
        let mut moved = false;
        loop {
            if held.is_none() {
                held = bus.segments.try_receive().ok();
            }
            let Some(msg) = held else { break };
            match step.push(msg, kick.now_tick() + lead) {
                PushOutcome::Queued => {
                    moved = true;
                    held = None;
                }
                PushOutcome::Stale => held = None,
                PushOutcome::Full => break,
            }
        }
        if moved {
            kick.kick();
        }
        bus.step_progress.signal(());
        if held.is_some() {
            bus.step_wake.wait().await;
        } else {
            select(bus.step_wake.wait(), bus.segments.ready_to_receive()).await;
        }
    }
}
