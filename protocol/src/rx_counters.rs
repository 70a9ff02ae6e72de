//! RX_COUNTERS (0x24, controller to host; issue 30 part 4): what the controller's receive
//! path dropped or did, asked for by bit 3 of STATUS's request byte (docs/PROTOCOL.md,
//! STATUS and RX_COUNTERS). A report of its own rather than STATUS fields: every host
//! decodes STATUS as exactly 36 bytes, so it cannot grow, and these counters are for a
//! person looking into lost frames, not for every poll.

use crate::codec::{Writer, u32_le};

/// The receive path's counters, each wrapping, counted since boot.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct RxCounters {
    /// Frames the Ethernet MAC dropped because its receive ring was full (0 in the
    /// simulator).
    pub ring_dropped: u32,
    /// Times the MAC found its receive ring full.
    pub ring_full: u32,
    /// STOPPEDs the Ethernet receive interrupt stopped the steps for, before any queue.
    pub interrupt_stops: u32,
    /// Datagrams dropped over their sender's fair share (section 7).
    pub shed: u32,
    /// Datagrams dropped because the controller's inbox was full.
    pub inbox_dropped: u32,
    /// Datagrams ignored because they were sent to a broadcast or multicast address.
    pub group_ignored: u32,
}

impl RxCounters {
    pub(crate) fn read(b: &[u8]) -> RxCounters {
        RxCounters {
            ring_dropped: u32_le(b, 0),
            ring_full: u32_le(b, 4),
            interrupt_stops: u32_le(b, 8),
            shed: u32_le(b, 12),
            inbox_dropped: u32_le(b, 16),
            group_ignored: u32_le(b, 20),
        }
    }

    pub(crate) fn write(&self, w: &mut Writer<'_>, at: usize) {
        w.u32(at, self.ring_dropped);
        w.u32(at + 4, self.ring_full);
        w.u32(at + 8, self.interrupt_stops);
        w.u32(at + 12, self.shed);
        w.u32(at + 16, self.inbox_dropped);
        w.u32(at + 20, self.group_ignored);
    }
}
