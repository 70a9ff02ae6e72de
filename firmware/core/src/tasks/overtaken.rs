//! The e-stop path's ordering: a STOPPED taken from `bus.estop` before datagrams queued
//! ahead of it in the inbox, and how those overtaken datagrams are handled so that the
//! result is that of arrival order (see the crate docs, "The e-stop path").

use super::trajectory::{deliver, publish};
use crate::bus::{Bus, Datagram};
use crate::controller::Controller;
use crate::hw::Clock;
use crate::outgoing::Outgoing;
use crate::plant::Plant;
use crate::response::Deferred;

/// Handles `first`, an inbox datagram overtaken by an executed STOPPED, then the queued
/// datagrams that arrived before the last executed STOPPED, in arrival order (same ACKs,
/// same duplicate memory), applying each executed STOPPED after the datagram it followed
/// ([`Controller::stop_after_overtaken`]). All without a wait: a run one of them starts
/// is stopped before its first pulse (the engine starts `START_LEAD_US` after RUNING). Returns the deferred
/// work still to do: a settings write (an encoder read would start a cancelled RETURN).
pub(super) fn handle_overtaken<const CAP: usize, C: Clock>(
    controller: &mut Controller<CAP>,
    bus: &Bus,
    first: Datagram,
    clock: &C,
    plant: &mut impl Plant,
    stops: &OvertakingStops,
) -> Option<Deferred> {
    let mut save = None;
    let mut next = Some(first);
    while let Some(datagram) = next.take() {
        let response = controller.handle(datagram.from, &datagram.bytes, clock.now_us(), plant);
        publish(bus, controller);
        deliver(bus, &response);
        if let Some(Deferred::SaveSettings(settings)) = response.deferred {
            save = Some(settings);
        }
        let next_stamp = bus.inbox.peek_with(|queued| queued.stops_before);
        // An executed STOPPED arrived between this datagram and the next: apply it now.
        if stops.executed_between(datagram.stops_before, next_stamp) {
            let location = controller.stop_after_overtaken(plant);
            publish(bus, controller);
            if let Some(location) = location {
                bus.send(Outgoing::Location(location));
            }
        }
        // The next one was overtaken too: handle it before anything else.
        if next_stamp.is_some_and(|stamp| stops.executed_between(stamp, None)) {
            next = bus.inbox.try_receive().ok();
        }
    }
    save.map(Deferred::SaveSettings)
}

/// STOPPED window of [`OvertakingStops`]: how many of the latest STOPPEDs taken it tells
/// apart. Older ones count as executed (a stop is the safe side); only a flood of more
/// than this many STOPPEDs while a datagram waits in the inbox gets there.
pub const STOP_MEMORY: u32 = 128;

/// The STOPPEDs the trajectory task took from `bus.estop` (each numbered by
/// [`Bus::route`] as it arrived: the stamps of [`Datagram::stops_before`]) and which of
/// them the controller executed. A datagram stamped `s` arrived before STOPPED number
/// `s`; it was overtaken by those numbered `s` and up that were taken before it. Only an
/// executed STOPPED (ACK `OK`, not a duplicate) stops what it overtook: a refused or
/// repeated one did nothing in arrival order either.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct OvertakingStops {
    /// STOPPEDs taken (wrapping): the next one taken is number `taken`.
    taken: u32,
    /// Bit `i`: STOPPED number `taken - 1 - i` was executed.
    executed: u128,
}

impl OvertakingStops {
    /// None taken yet.
    pub const fn new() -> Self {
        OvertakingStops {
            taken: 0,
            executed: 0,
        }
    }

    /// The next STOPPED from `bus.estop` was handled; `executed` if it did stop.
    pub fn took(&mut self, executed: bool) {
        self.taken = self.taken.wrapping_add(1);
        self.executed = (self.executed << 1) | u128::from(executed);
    }

    /// Whether an executed STOPPED numbered `from` up to (not including) `to` (`None`:
    /// every one taken) was taken.
    pub fn executed_between(&self, from: u32, to: Option<u32>) -> bool {
        // Stops taken with a number >= from (wrapping counters, small differences).
        let since_from = self.taken.wrapping_sub(from) as i32;
        let since_to = to.map_or(0, |to| (self.taken.wrapping_sub(to) as i32).max(0));
        if since_from <= since_to {
            return false;
        }
        if since_from as u32 > STOP_MEMORY {
            return true;
        }
        // Bits since_to..since_from stand for numbers from..to.
        let below = |n: i32| 1u128.checked_shl(n as u32).map_or(u128::MAX, |bit| bit - 1);
        self.executed & below(since_from) & !below(since_to) != 0
    }
}
