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
//! [`RingPeek`] counts each STOPPED once however often the interrupt looks at its buffer:
//! sans-io, so the bookkeeping is tested on the host.
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

/// Receive buffers the interrupt keeps track of: at most 64. The NUCLEO's ring has 40
/// (`RX_PACKETS`); the QEMU board's 8 (`RX_RING`; its interrupt fills them itself, so it
/// needs no [`RingPeek`]).
pub const MAX_RING: usize = 64;

/// What tells two STOPPEDs apart: sender address and port, seq and CRC.
pub type StopSignature = u64;

/// The [`StopSignature`] of an Ethernet II frame carrying a CRC-valid STOPPED to UDP
/// `port` ([`stop_in_frame`]), `None` for any other frame.
pub fn stop_signature(frame: &[u8], port: u16) -> Option<StopSignature> {
    let (from, payload) = udp_payload(frame, port)?;
    if !is_stop(payload) {
        return None;
    }
    let [a, b, c, d] = from.ip;
    let [p0, p1] = from.port.to_be_bytes();
    let seq = payload.first().copied().unwrap_or(0);
    let crc = payload.last().copied().unwrap_or(0);
    Some(u64::from_be_bytes([a, b, c, d, p0, p1, seq, crc]))
}

/// Which STOPPEDs in a receive ring of `N` buffers the interrupt has halted for.
///
/// The interrupt looks at every buffer the driver owns (filled, not yet taken by the
/// runner) each time it runs, not only at those it saw filled: when the ring was full,
/// the runner's giving a buffer back lets the MAC fill it again at once, before the
/// interrupt ran (on Renode within the runner's own register write), so "seen filled
/// before" does not mean "the same frame". The halt is idempotent; this keeps the count
/// right: a STOPPED is counted once per buffer it lands in ([`RingPeek::stop_at`]), and a
/// buffer the hardware owns again is forgotten ([`RingPeek::given_back`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RingPeek<const N: usize> {
    /// The STOPPED last counted in each buffer.
    counted: [Option<StopSignature>; N],
}

impl<const N: usize> Default for RingPeek<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> RingPeek<N> {
    /// Nothing counted yet.
    pub const fn new() -> Self {
        RingPeek { counted: [None; N] }
    }

    /// Buffer `index` is the hardware's again (the runner took its frame).
    pub fn given_back(&mut self, index: usize) {
        if let Some(c) = self.counted.get_mut(index) {
            *c = None;
        }
    }

    /// Buffer `index` holds the STOPPED `signature` (the caller halts the steps either
    /// way): whether it is a new one, to count.
    pub fn stop_at(&mut self, index: usize, signature: StopSignature) -> bool {
        match self.counted.get_mut(index) {
            Some(c) if *c != Some(signature) => {
                *c = Some(signature);
                true
            }
            _ => false,
        }
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
