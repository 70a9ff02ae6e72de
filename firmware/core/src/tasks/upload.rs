//! The upload task: periodic LOCATION reports.

use embassy_futures::select::{Either, select};
use embassy_sync::blocking_mutex::raw::RawMutex;

use crate::bus::Bus;
use crate::hw::Clock;
use crate::outgoing::Outgoing;
use crate::step_shared::{StepBackend, StepShared};

/// Sends a LOCATION report (positions from the engine, state from `bus.reports`) every
/// upload period while reports are on and an owner exists. The period restarts when the
/// trajectory task changes it. (LOCATION reports on state changes are sent by the
/// trajectory task itself, with the state of that instant.)
pub async fn upload_task<const Q: usize, B: StepBackend, M: RawMutex, C: Clock>(
    bus: &Bus,
    step: &StepShared<Q, B, M>,
    clock: &C,
) -> ! {
    let mut next = clock.now_us();
    loop {
        if bus.report_settings().upload_period_us == 0 {
            // Not published yet (ReportSettings::UNPUBLISHED).
            bus.upload_changed.wait().await;
            next = clock.now_us();
            continue;
        }
        let period = u64::from(bus.report_settings().upload_period_us.max(1));
        next += period;
        let now = clock.now_us();
        if next <= now {
            // Fell behind (a long pause): skip the missed reports.
            next = now + period;
        }
        match select(clock.sleep_until(next), bus.upload_changed.wait()).await {
            Either::First(()) => {
                let settings = bus.report_settings();
                if settings.reports_on && settings.has_location_listener(clock.now_us()) {
                    bus.send(Outgoing::Location(protocol::Location {
                        position: step.positions(),
                        state: settings.state as u8,
                    }));
                }
            }
            Either::Second(()) => next = clock.now_us(),
        }
    }
}
