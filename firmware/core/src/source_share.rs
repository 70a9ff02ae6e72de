//! The fair share of the receive path (issue 18, [`crate::ingress`]): per source address,
//! datagrams admitted and not yet handled. Sans-io, and below the bus that holds it, so
//! that the bus and the first look ([`crate::ingress`]) do not import each other.

use core::cell::RefCell;

use embassy_sync::blocking_mutex::Mutex;
// The bus's mutex kind ([`crate::bus::Cs`]), named directly: this module sits below the bus.
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex as Cs;

use crate::auth::AUTH_SESSIONS;
use crate::config::HOST_WINDOW;
use crate::log_limit::{LogLimit, LogVerdict};

/// Source addresses whose share is tracked at once. A cell has a few hosts (the owner's
/// machine, a panel, a second tool); a new address beyond these takes the slot of the one
/// heard least recently, starting with its full share. 8 slots are 192 bytes.
pub const INGRESS_SOURCES: usize = 8;

/// Datagrams of one source address admitted and not yet handled (in the socket or the
/// inbox) at most: a host's whole window ([`HOST_WINDOW`] = 32) plus 4 for its other
/// tools' polls. The inbox holds [`crate::bus::INBOX_QUEUE`] = 40, so however one host
/// floods, 4 slots stay free for the others and the owner's commands wait behind at most
/// 36 of the flood's. A host alone is never slowed: its share comes back as fast as the
/// controller handles its datagrams (work-conserving, unlike a fixed rate).
pub const SOURCE_SHARE: u64 = HOST_WINDOW as u64 + 4;

/// Datagrams of all the untrusted sources together admitted and not yet handled at most
/// while someone is trusted (issue 30): what the inbox ([`crate::bus::INBOX_QUEUE`] = 40)
/// holds beyond the trusted class's [`SOURCE_SHARE`], so however many strangers flood, the
/// owner's window always fits and its commands wait behind at most these 4 of theirs.
pub const STRANGER_POOL: u64 = crate::bus::INBOX_QUEUE as u64 - SOURCE_SHARE;

/// Share returned per second regardless of handling: an admitted datagram the network
/// stack drops before the controller sees it (a full socket, a bad IP checksum) would
/// otherwise hold its slot of the share forever. 1,000 a second heal a whole share in
/// 36 ms, and add at most that to a flooder's throughput.
pub const SHARE_HEAL_HZ: u64 = 1_000;

/// Credit units per datagram: credit is kept in millionths of a datagram, so that the
/// healing ([`SHARE_HEAL_HZ`] per second) is a whole number per microsecond.
const CREDIT_PER_DATAGRAM: u64 = 1_000_000;

/// Addresses of the trusted class at most: the owner's and one per authenticated session.
pub const TRUSTED_SOURCES: usize = 1 + AUTH_SESSIONS;

/// The source addresses whose datagrams take the reserved share: the owner's and, with a
/// key, those of the sessions that sent a valid envelope. Published by the trajectory
/// task after every event ([`crate::Bus::set_trusted`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TrustedSources {
    ips: [Option<[u8; 4]>; TRUSTED_SOURCES],
}

impl TrustedSources {
    /// Nobody: no owner, no session.
    pub const NONE: TrustedSources = TrustedSources {
        ips: [None; TRUSTED_SOURCES],
    };

    /// Adds `ip` (once; beyond [`TRUSTED_SOURCES`] addresses it is not added).
    pub fn add(&mut self, ip: [u8; 4]) {
        if self.contains(ip) {
            return;
        }
        if let Some(free) = self.ips.iter_mut().find(|s| s.is_none()) {
            *free = Some(ip);
        }
    }

    /// Whether datagrams from `ip` take the reserved share.
    pub fn contains(&self, ip: [u8; 4]) -> bool {
        self.ips.contains(&Some(ip))
    }

    /// Whether nobody is trusted.
    pub fn is_empty(&self) -> bool {
        self.ips.iter().all(Option::is_none)
    }
}

/// One tracked source's share.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct Source {
    ip: [u8; 4],
    /// Millionths of a datagram it may still have admitted.
    credit: u64,
    /// When `credit` was last healed; also when it was last heard.
    at_us: u64,
    in_use: bool,
}

/// The fair share of the receive path: per source address, datagrams admitted and not yet
/// handled at most [`SOURCE_SHARE`] (returned by [`SourceBudgets::release`] as the
/// controller takes each one, and healed at [`SHARE_HEAL_HZ`]), for [`INGRESS_SOURCES`]
/// addresses; and the count of datagrams shed.
#[derive(Clone, Copy, Debug)]
pub struct SourceBudgets {
    sources: [Source; INGRESS_SOURCES],
    trusted: TrustedSources,
    shed: u32,
    log: LogLimit,
}

impl Default for SourceBudgets {
    fn default() -> Self {
        Self::new()
    }
}

const FULL_SHARE: u64 = SOURCE_SHARE * CREDIT_PER_DATAGRAM;

impl SourceBudgets {
    /// No source heard yet.
    pub const fn new() -> Self {
        SourceBudgets {
            sources: [Source {
                ip: [0; 4],
                credit: 0,
                at_us: 0,
                in_use: false,
            }; INGRESS_SOURCES],
            trusted: TrustedSources::NONE,
            shed: 0,
            log: LogLimit::new(),
        }
    }

    /// Whether a datagram from `ip` arriving at `now_us` is within its share (it then
    /// holds one slot of it until [`SourceBudgets::release`]). A refusal is counted in
    /// [`SourceBudgets::shed`] and returns the log verdict for it.
    pub fn admit(&mut self, ip: [u8; 4], now_us: u64) -> Result<(), LogVerdict> {
        let slot = match self.sources.iter().position(|s| s.in_use && s.ip == ip) {
            Some(i) => i,
            None => {
                // A free slot, else the source heard least recently.
                let i = self
                    .sources
                    .iter()
                    .enumerate()
                    .min_by_key(|(_, s)| (s.in_use, s.at_us))
                    .map_or(0, |(i, _)| i);
                if let Some(s) = self.sources.get_mut(i) {
                    *s = Source {
                        ip,
                        credit: FULL_SHARE,
                        at_us: now_us,
                        in_use: true,
                    };
                }
                i
            }
        };
        let Some(source) = self.sources.get_mut(slot) else {
            return Ok(());
        };
        let elapsed = now_us.saturating_sub(source.at_us);
        source.credit = source
            .credit
            .saturating_add(elapsed.saturating_mul(SHARE_HEAL_HZ))
            .min(FULL_SHARE);
        source.at_us = source.at_us.max(now_us);
        if source.credit >= CREDIT_PER_DATAGRAM {
            source.credit -= CREDIT_PER_DATAGRAM;
            Ok(())
        } else {
            self.shed = self.shed.wrapping_add(1);
            Err(self.log.event(now_us))
        }
    }

    /// The controller took (or a queue dropped) a datagram from `ip`: its slot of the
    /// share is free again.
    pub fn release(&mut self, ip: [u8; 4]) {
        if let Some(s) = self.sources.iter_mut().find(|s| s.in_use && s.ip == ip) {
            s.credit = s.credit.saturating_add(CREDIT_PER_DATAGRAM).min(FULL_SHARE);
        }
    }

    /// From now on, datagrams from `trusted` take the reserved share.
    pub fn set_trusted(&mut self, trusted: TrustedSources) {
        self.trusted = trusted;
    }

    /// Datagrams shed so far (wrapping).
    pub fn shed(&self) -> u32 {
        self.shed
    }
}

/// The receive path's shares, in the [`crate::bus::Bus`] (filled by whoever reads datagrams first).
pub type SharedBudgets = Mutex<Cs, RefCell<SourceBudgets>>;
