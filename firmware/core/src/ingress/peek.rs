//! The boards' look at STOPPED in the Ethernet receive interrupt (issue 30 part 4).
//!
//! [`GuardedDriver`](super::GuardedDriver) looks at each datagram when embassy-net's
//! runner takes it from the receive ring: in thread mode, behind the ring, and only
//! while a transmit descriptor is free. While the trajectory task works through a burst
//! (a keyed 12-point PENDING is ~133k instructions), a flood can fill the ring meanwhile,
//! and the MAC then drops the STOPPED that arrives behind it. So the boards' Ethernet
//! interrupt looks first: at each receive buffer the moment the MAC has filled it, it asks
//! [`stop_in_frame`] whether the frame is a STOPPED for the controller and, if so, halts
//! the steps there (the board's [`StepHalt`](super::StepHalt)). The frame stays in the
//! ring: the runner still takes it as before, and its look routes the STOPPED to the
//! controller (`bus.estop`) for the bookkeeping and the ACK, halting again (harmless).
//!
//! What is recognised is exactly what [`Bus::receive_first`](crate::Bus::receive_first)
//! halts for: a CRC-valid plain STOPPED, from any sender, whatever its data, to the
//! controller's port, however addressed. With a key set this is the rule too
//! (docs/PROTOCOL.md section 13: STOPPED passes plain); a STOPPED sealed in an envelope
//! gets no early look (verifying its MAC needs the controller's sessions) and stops the
//! arm when the controller handles it, as before.
//!
//! [`RingPeek`] says which buffers are newly filled, from what the interrupt reads of the
//! ring's ownership bits: sans-io, so the bookkeeping is tested on the host.
//! [`RxRingCounters`] holds what the boards count about their receive ring (frames the MAC
//! dropped for want of a free buffer, the times it found none, STOPPEDs the interrupt
//! halted for).

use super::udp_payload;
use crate::bus::is_stop;

/// Whether an Ethernet II frame carries a CRC-valid STOPPED to UDP `port` (see the module
/// docs). Reads only within `frame` (lengths are checked, never trusted), never panics;
/// costs the header parse and, only for a frame whose tag byte is STOPPED's, the CRC.
pub fn stop_in_frame(frame: &[u8], port: u16) -> bool {
    udp_payload(frame, port).is_some_and(|(_, payload)| is_stop(payload))
}

/// Receive buffers the interrupt keeps track of: at most 64 (one bit each). The NUCLEO's
/// ring has 40 (`RX_PACKETS`); the QEMU board's 8 (`RX_RING`; its interrupt fills them
/// itself, so it needs no [`RingPeek`]).
pub const MAX_RING: usize = 64;

/// Which receive buffers of a ring of `n` the interrupt has looked at since the MAC (or
/// the board's interrupt, on a chip without DMA) last filled them.
///
/// The interrupt reads each buffer's ownership and calls [`RingPeek::newly_filled`]: a
/// buffer the driver owns (filled, not yet taken by the runner) and not looked at yet is
/// to be looked at now; a buffer the hardware owns again (the runner gave it back) is
/// forgotten. Each fill raises the interrupt and the runner gives a buffer back only in
/// thread mode, below it, so a fill is seen before its buffer can go round again; should
/// the interrupt ever be held off that long, the runner's own look still halts for the
/// STOPPED (later, as before this).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RingPeek {
    /// Bit `i`: buffer `i` was seen filled and looked at.
    seen: u64,
}

impl Default for RingPeek {
    fn default() -> Self {
        Self::new()
    }
}

impl RingPeek {
    /// Nothing looked at yet.
    pub const fn new() -> Self {
        RingPeek { seen: 0 }
    }

    /// Buffer `index` is `filled` (owned by the driver, holding a frame) or not (owned by
    /// the hardware): whether to look at its frame now. An index at or beyond
    /// [`MAX_RING`] is never looked at.
    pub fn newly_filled(&mut self, index: usize, filled: bool) -> bool {
        let Some(bit) = u32::try_from(index).ok().and_then(|i| 1u64.checked_shl(i)) else {
            return false;
        };
        let new = filled && self.seen & bit == 0;
        if filled {
            self.seen |= bit;
        } else {
            self.seen &= !bit;
        }
        new
    }
}

/// What a board counts about its receive ring (all wrapping), for the log and STATUS's
/// receive counters.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RxRingCounters {
    /// Frames the Ethernet MAC dropped because every receive buffer was full (the NUCLEO:
    /// the MTL receive queue's overflow and missed-packet counters and the DMA's missed
    /// frame counter; the QEMU board: frames the chip's FIFO had no room for).
    pub dropped: u32,
    /// Times the MAC found no free receive buffer (the NUCLEO's DMA "receive buffer
    /// unavailable"; the QEMU board: a frame left in the chip because the ring was full).
    pub full: u32,
    /// STOPPEDs the receive interrupt halted the steps for.
    pub stops: u32,
}

impl RxRingCounters {
    /// All zero (a `const`, for the bus's all-zero initial value).
    pub const ZERO: RxRingCounters = RxRingCounters {
        dropped: 0,
        full: 0,
        stops: 0,
    };
}
