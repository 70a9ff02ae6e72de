//! The first look at a received datagram (issue 18; docs/PROTOCOL.md sections 4 and 7).
//!
//! Whatever reads datagrams first (the simulator's socket reader thread; on the boards and
//! the simulator's TAP mode, the Ethernet driver's receive path, [`GuardedDriver`] with
//! the `net-driver` feature) hands each one to [`Bus::receive_first`] before any queue:
//!
//! - a CRC-valid **STOPPED** halts the step outputs there and then ([`StepHalt`]: the step
//!   backend's stop and a kick of its interrupt, as the trajectory task's own stop does)
//!   and goes onto `bus.estop` for the controller's bookkeeping and ACK. It never waits
//!   behind, or is dropped with, other traffic, and it is not counted against its sender;
//! - anything else is admitted only within its **fair share** by class ([`SourceBudgets`],
//!   issue 30): the owner's address and the sessions that proved the key
//!   ([`TrustedSources`], published by the trajectory task) have [`SOURCE_SHARE`]
//!   datagrams admitted and not yet taken by the controller reserved; all other addresses
//!   together [`STRANGER_POOL`], each [`STRANGER_SHARE`]. So no flood, from however many
//!   addresses, can fill the queues behind (socket, inbox), and the owner's commands wait
//!   behind at most the pool. A host alone is never slowed. What is shed is counted and
//!   logged at most once a second.
//!
//! On the boards the Ethernet receive interrupt looks first (issue 30 part 4, `peek.rs`):
//! it halts for a STOPPED the moment its frame lands in the receive ring, before the
//! runner (in thread mode, behind the ring) gets to it; the runner's look here then
//! routes it for the controller.
//!
//! Halting at the reader is what makes a STOPPED immune to a flood: the queues behind it
//! may hold many datagrams of other hosts, but the pulses have stopped before the
//! STOPPED joins any of them. The controller still handles it in its turn (first, from
//! `estop`), so its state, flags and ACK are those of an ordinary STOPPED.

use heapless::Vec;
use protocol::{MAX_DATAGRAM, Tag, crc8};

use crate::bus::{Bus, Datagram, is_stop, is_valid_frame_of};
use crate::hw::{Endpoint, StepKick};
use crate::log_limit::LogVerdict;
// The fair share itself is sans-io and lives below the bus (which holds it).
pub use crate::source_share::{
    INGRESS_SOURCES, SHARE_HEAL_AFTER_US, SHARE_HEAL_HZ, SOURCE_SHARE, STRANGER_POOL,
    STRANGER_SHARE, SharedBudgets, SourceBudgets, TRUSTED_SOURCES, TrustedSources,
};
use crate::step_shared::{StepBackend, StepShared};

#[cfg(feature = "net-driver")]
mod driver;
mod peek;
#[cfg(feature = "net-driver")]
pub use driver::GuardedDriver;
pub use peek::{MAX_RING, RingPeek, RxRingCounters, StopSignature, stop_in_frame, stop_signature};

/// The UDP port whose datagrams the first look judges: the controller's.
pub const CONTROLLER_PORT: u16 = protocol::PORT;

/// What [`Bus::receive_first`] did with a datagram.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Ingress {
    /// A CRC-valid STOPPED: the step outputs are halted and the frame is on `bus.estop`
    /// (or, that queue being full of STOPPEDs already, dropped: the controller stops
    /// anyway). The caller drops the datagram.
    Stopped,
    /// Within its sender's share: the caller passes it on (socket, inbox).
    Admit,
    /// Over its sender's share: the caller drops it (counted here).
    Shed,
    /// Sent to a broadcast or multicast address and neither DISCOVER nor STOPPED: the
    /// caller drops it (counted here; issue 21 F7). Broadcast is for finding controllers;
    /// a stop is obeyed however it is addressed.
    Ignored,
}

/// Whether an Ethernet frame was sent to a group (broadcast or multicast) address: the
/// I/G bit of its destination MAC, which every broadcast and multicast IP datagram on the
/// link carries, directed subnet broadcasts included.
pub fn to_group(frame: &[u8]) -> bool {
    frame.first().is_some_and(|b| b & 1 == 1)
}

/// Stops every STEP output now, from wherever the datagram was read: no task runs
/// between the STOPPED's arrival and the halt. A board may cut a gripper burst here too
/// (issue 30; the controller cuts it anyway when it handles the STOPPED).
pub trait StepHalt {
    /// No step pulse after this returns (or, for a backend whose lines its interrupt
    /// lowers, after the interrupt this kicks).
    fn halt(&self);
}

/// [`StepHalt`] over the step backend the tasks share and the kick of its interrupt: what
/// the trajectory task's own stop does to the steps.
pub struct HaltSteps<
    'a,
    const Q: usize,
    B,
    K,
    M = embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex,
> {
    /// The step backend.
    pub step: &'a StepShared<Q, B, M>,
    /// Its interrupt.
    pub kick: &'a K,
}

impl<const Q: usize, B: StepBackend, K: StepKick, M: embassy_sync::blocking_mutex::raw::RawMutex>
    StepHalt for HaltSteps<'_, Q, B, K, M>
{
    fn halt(&self) {
        self.step.stop();
        self.kick.kick();
    }
}

impl Bus {
    /// The first look at a datagram from `from`, received at `now_us` and sent to a
    /// broadcast or multicast address if `to_group` (see the module docs): a CRC-valid
    /// STOPPED is put on `estop` and `halt` stops the step outputs; anything else sent to
    /// a group but DISCOVER is ignored; the rest is admitted or shed by its sender's
    /// share. Never waits.
    pub fn receive_first(
        &self,
        from: Endpoint,
        bytes: &[u8],
        to_group: bool,
        now_us: u64,
        halt: &impl StepHalt,
    ) -> Ingress {
        if is_stop(bytes) {
            // The controller ignores STOPPED's data: pass the canonical 3-byte frame, which
            // fits whatever the datagram's length was.
            let seq = bytes.first().copied().unwrap_or(0);
            let body = [seq, Tag::Stopped as u8];
            let mut frame: Vec<u8, MAX_DATAGRAM> = Vec::new();
            let _ = frame.extend_from_slice(&body);
            let _ = frame.push(crc8(&body));
            self.route_stop(Datagram::new(from, frame));
            halt.halt();
            return Ingress::Stopped;
        }
        // A CRC-valid DISCOVER, whatever its length: the controller answers or refuses it
        // by its own rules.
        if to_group && !is_valid_frame_of(bytes, Tag::Discover) {
            let log = self.group_ignored.lock(|c| {
                let (count, mut limit) = c.get();
                let verdict = limit.event(now_us);
                c.set((count.wrapping_add(1), limit));
                verdict
            });
            if let LogVerdict::Log { suppressed } = log {
                let [a, b, c, d] = from.ip;
                warn!(
                    "receive: a command from {}.{}.{}.{} to a broadcast address was ignored ({} more since the last such line)",
                    a, b, c, d, suppressed
                );
            }
            return Ingress::Ignored;
        }
        let verdict = self.budgets.lock(|b| b.borrow_mut().admit(from.ip, now_us));
        match verdict {
            Ok(()) => Ingress::Admit,
            Err(log) => {
                if let LogVerdict::Log { suppressed } = log {
                    let [a, b, c, d] = from.ip;
                    warn!(
                        "receive: a datagram from {}.{}.{}.{} over its share was shed ({} more from any host since the last such line)",
                        a, b, c, d, suppressed
                    );
                }
                Ingress::Shed
            }
        }
    }

    /// A datagram from `ip` was taken by the controller, or dropped by a queue after
    /// [`Bus::receive_first`] admitted it: its slot of the sender's share is free again.
    pub fn release(&self, ip: [u8; 4]) {
        self.budgets.lock(|b| b.borrow_mut().release(ip));
    }

    /// From now on, datagrams from `trusted` (the owner's address and, with a key, those of
    /// the sessions that proved it) take the reserved share of the receive path.
    pub fn set_trusted(&self, trusted: TrustedSources) {
        self.budgets.lock(|b| b.borrow_mut().set_trusted(trusted));
    }

    /// Whether datagrams from `ip` take the reserved share now (the owner's address and,
    /// with a key, those of the sessions that proved it): the board's receive interrupt
    /// never drops theirs to make room in its ring.
    pub fn is_trusted(&self, ip: [u8; 4]) -> bool {
        self.budgets.lock(|b| b.borrow().is_trusted(ip))
    }

    /// Datagrams [`Bus::receive_first`] ignored so far because they were sent to a
    /// broadcast or multicast address (wrapping).
    pub fn ignored_group_datagrams(&self) -> u32 {
        self.group_ignored.lock(|c| c.get().0)
    }

    /// Datagrams [`Bus::receive_first`] shed so far (wrapping).
    pub fn shed(&self) -> u32 {
        self.budgets.lock(|b| b.borrow().shed())
    }

    /// The board's receive interrupt saw the MAC drop `dropped` frames and find the ring
    /// full `full` times, and halted the steps for `stops` STOPPEDs, since its last call
    /// (added, wrapping; see [`RxRingCounters`]).
    pub fn count_rx_ring(&self, dropped: u32, full: u32, stops: u32) {
        self.rx_ring.lock(|c| {
            let RxRingCounters {
                dropped: d,
                full: f,
                stops: s,
            } = c.get();
            c.set(RxRingCounters {
                dropped: d.wrapping_add(dropped),
                full: f.wrapping_add(full),
                stops: s.wrapping_add(stops),
            });
        });
    }

    /// What the board's receive interrupt counted so far ([`Bus::count_rx_ring`]); all
    /// zero on a controller without one (the simulator).
    pub fn rx_ring(&self) -> RxRingCounters {
        self.rx_ring.lock(|c| c.get())
    }

    /// The receive path's counters as the RX_COUNTERS report tells them (docs/PROTOCOL.md,
    /// STATUS's request byte bit 2).
    pub fn rx_counters(&self) -> protocol::RxCounters {
        let ring = self.rx_ring();
        protocol::RxCounters {
            ring_dropped: ring.dropped,
            ring_full: ring.full,
            interrupt_stops: ring.stops,
            shed: self.shed(),
            inbox_dropped: self.inbox_drops(),
            group_ignored: self.ignored_group_datagrams(),
        }
    }
}

/// Where an IPv4/UDP datagram to `port` sits in an Ethernet II frame: its sender and its
/// payload. `None` for anything else (ARP, other ports, IP options beyond the header
/// length, fragments), which the caller passes on untouched. The MAC has checked the
/// frame's FCS; lengths are checked here, so a short or lying frame is never read past.
pub fn udp_payload(frame: &[u8], port: u16) -> Option<(Endpoint, &[u8])> {
    /// Where the IPv4 header starts: after the Ethernet II header.
    const IP_AT: usize = 14;
    // The Ethernet II header and the fixed part of the IPv4 header (20 bytes), as one
    // array taken apart by a pattern: no index can fail.
    let (eth_ip, _) = frame.split_first_chunk::<{ IP_AT + 20 }>()?;
    let [
        ..,
        type0,
        type1,
        version_ihl,
        _tos,
        len0,
        len1,
        _id0,
        _id1,
        frag0,
        frag1,
        _ttl,
        protocol,
        _sum0,
        _sum1,
        src0,
        src1,
        src2,
        src3,
        _dst0,
        _dst1,
        _dst2,
        _dst3,
    ] = *eth_ip;
    let header_len = usize::from(version_ihl & 0x0F) * 4;
    let total_len = usize::from(u16::from_be_bytes([len0, len1]));
    // Fragments (MF set or an offset) are not ours to read: smoltcp drops them too.
    let fragment = u16::from_be_bytes([frag0, frag1]) & 0x3FFF;
    if [type0, type1] != [0x08, 0x00]
        || version_ihl >> 4 != 4
        || header_len < 20
        || protocol != 17
        || fragment != 0
    {
        return None;
    }
    let udp = frame
        .get(IP_AT..IP_AT.checked_add(total_len)?)?
        .get(header_len..)?;
    let (&[sport0, sport1, dport0, dport1, ulen0, ulen1, _, _], _) =
        udp.split_first_chunk::<8>()?;
    let udp_len = usize::from(u16::from_be_bytes([ulen0, ulen1]));
    if u16::from_be_bytes([dport0, dport1]) != port {
        return None;
    }
    Some((
        Endpoint {
            ip: [src0, src1, src2, src3],
            port: u16::from_be_bytes([sport0, sport1]),
        },
        udp.get(8..udp_len)?,
    ))
}
