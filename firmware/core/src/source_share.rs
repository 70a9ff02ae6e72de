//! The shares of the receive path (issues 18 and 30, [`crate::ingress`]): datagrams admitted
//! and not yet handled, bounded by class and, within a class, by source address. Sans-io,
//! and below the bus that holds it, so that the bus and the first look
//! ([`crate::ingress`]) do not import each other.
//!
//! Two classes (issue 30: per address alone, 20 strangers took all of the inbox, because
//! each new address got a whole share and 8 slots cannot remember 20 addresses):
//!
//! - **trusted**: the owner's address and, with a key, the addresses of sessions that sent
//!   a valid envelope ([`TrustedSources`], published by the trajectory task). Together at
//!   most [`SOURCE_SHARE`] in flight, a share no number of other sources can take.
//! - **strangers**: every other address. Together at most [`STRANGER_POOL`] in flight, each
//!   at most [`STRANGER_SHARE`] of it (remembered for [`INGRESS_SOURCES`] addresses; one
//!   forgotten may pass its own bound again, never the pool's).
//!
//! Both fit the inbox together, so its strangers' part never crowds out the owner's
//! commands, which wait behind at most [`STRANGER_POOL`] of theirs. While nobody is trusted
//! (no owner yet, or after RELEASE) there is no one to keep room for: strangers share the
//! whole inbox, each at most [`SOURCE_SHARE`], so the first host's window is taken whole.
//!
//! A class's count goes down as the controller takes its datagrams (work-conserving: a
//! host alone is never slowed), and heals with time for those lost downstream once
//! nothing of it was taken for a while ([`SHARE_HEAL_AFTER_US`]). A release counts
//! against the class the address is in at that moment: an address that becomes trusted
//! takes its remembered count along; one that stops being trusted (a new owner after 5 s
//! of silence, or RELEASE, so seldom with anything in flight) leaves its count in the
//! trusted class until it heals, and its releases go to the pool, which saturates at zero.

use core::cell::RefCell;

use embassy_sync::blocking_mutex::Mutex;
// The bus's mutex kind ([`crate::bus::Cs`]), named directly: this module sits below the bus.
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex as Cs;

use crate::auth::AUTH_SESSIONS;
use crate::bus::INBOX_QUEUE;
use crate::config::HOST_WINDOW;
use crate::log_limit::{LogLimit, LogVerdict};

/// Untrusted source addresses whose own share is remembered at once: a cell has a few
/// hosts (a panel, a monitor, a second tool). A new address beyond these takes the slot of
/// the one heard least recently, starting with nothing in flight; the pool still bounds
/// them all ([`STRANGER_POOL`]). 8 slots are 320 bytes (all the shares, 448).
pub const INGRESS_SOURCES: usize = 8;

/// Datagrams of the trusted class admitted and not yet handled (in the socket or the
/// inbox) at most: a host's whole window ([`HOST_WINDOW`] = 32) plus 4 for its other
/// tools' polls. While nobody is trusted, it is also each address's bound.
pub const SOURCE_SHARE: u64 = HOST_WINDOW as u64 + 4;

/// Datagrams of all the untrusted sources together admitted and not yet handled at most
/// while someone is trusted (issue 30): what the inbox ([`INBOX_QUEUE`] = 40) holds beyond
/// the trusted class's [`SOURCE_SHARE`], so however many strangers flood, the owner's
/// window always fits and its commands wait behind at most these 4 of theirs. Enough for
/// the strangers a cell has (a monitor's STATUS, a panel): each needs one at a time.
pub const STRANGER_POOL: u64 = INBOX_QUEUE as u64 - SOURCE_SHARE;

/// Datagrams of one untrusted address in flight at most while someone is trusted: half
/// the pool, so one flooding stranger alone never takes all of it from another.
pub const STRANGER_SHARE: u64 = STRANGER_POOL / 2;

/// Addresses of the trusted class at most: the owner's and one per authenticated session.
pub const TRUSTED_SOURCES: usize = 1 + AUTH_SESSIONS;

/// Share returned per second to a class or source whose count has not gone down for
/// [`SHARE_HEAL_AFTER_US`]: an admitted datagram the network stack drops before the
/// controller sees it (a full socket, a bad IP checksum) would otherwise hold its slot of
/// the share forever. 1,000 a second heal a whole share in 36 ms.
pub const SHARE_HEAL_HZ: u64 = 1_000;

/// How long a count that is not zero must go without a release before it heals: the
/// controller takes a whole inbox in a few milliseconds, so 50 ms without one means its
/// datagrams were lost downstream (or the controller is stalled, when healing only lets
/// the queues fill). Healing only then, never while releases come, keeps the count from
/// drifting below what is really queued (issue 30: healed all the time, a pool that the
/// flood kept full let in 1,000 datagrams a second more than it released, until the inbox
/// was full again). What it does not heal: a few datagrams lost while the class's others
/// keep flowing, which narrow its share until a pause; on the boards, losses downstream
/// need frames the stack refuses (bad checksums, another IP address).
pub const SHARE_HEAL_AFTER_US: u64 = 50_000;

/// Credit units per datagram: counts are kept in millionths of a datagram, so that the
/// healing ([`SHARE_HEAL_HZ`] per second) is a whole number per microsecond.
const CREDIT_PER_DATAGRAM: u64 = 1_000_000;

// Both classes' datagrams fit the inbox together: nothing admitted is dropped there.
const _: () = assert!(SOURCE_SHARE + STRANGER_POOL <= INBOX_QUEUE as u64);
const _: () = assert!(STRANGER_SHARE >= 1);

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

    /// The trusted addresses.
    pub fn iter(&self) -> impl Iterator<Item = [u8; 4]> + '_ {
        self.ips.iter().flatten().copied()
    }
}

/// Datagrams admitted and not yet handled, in millionths, less what healing took.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct InFlight {
    used: u64,
    /// When `used` was last seen to have gone down by a release, or zero; healing counts
    /// from [`SHARE_HEAL_AFTER_US`] after it.
    progress_us: u64,
    /// Released since the last heal (a release knows no time: the next look stamps it).
    released: bool,
}

impl InFlight {
    const NONE: InFlight = InFlight {
        used: 0,
        progress_us: 0,
        released: false,
    };

    fn heal(&mut self, now_us: u64) {
        if core::mem::take(&mut self.released) || self.used == 0 {
            self.progress_us = self.progress_us.max(now_us);
            return;
        }
        let stalled_from = self.progress_us.saturating_add(SHARE_HEAL_AFTER_US);
        if now_us > stalled_from {
            let healed = (now_us - stalled_from).saturating_mul(SHARE_HEAL_HZ);
            self.used = self.used.saturating_sub(healed);
            // Healed up to now: the next heal counts from here.
            self.progress_us = now_us - SHARE_HEAL_AFTER_US;
        }
    }

    /// Whether one more datagram stays within `limit`.
    fn has_room(&self, limit: u64) -> bool {
        self.used.saturating_add(CREDIT_PER_DATAGRAM) <= limit.saturating_mul(CREDIT_PER_DATAGRAM)
    }

    fn take(&mut self, units: u64, now_us: u64) {
        if self.used == 0 {
            self.progress_us = self.progress_us.max(now_us);
        }
        self.used = self.used.saturating_add(units);
    }

    fn give_back(&mut self, units: u64) {
        self.used = self.used.saturating_sub(units);
        self.released = true;
    }
}

/// One remembered untrusted source.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct Source {
    ip: [u8; 4],
    in_flight: InFlight,
    /// When it was last heard.
    heard_us: u64,
    in_use: bool,
}

/// The shares of the receive path (see the module docs): the trusted class at most
/// [`SOURCE_SHARE`] in flight, the strangers together at most [`STRANGER_POOL`] (each
/// [`STRANGER_SHARE`]) while someone is trusted; a datagram's slot is returned by
/// [`SourceBudgets::release`] as the controller takes it, and healed at [`SHARE_HEAL_HZ`].
/// Also counts the datagrams shed.
#[derive(Clone, Copy, Debug)]
pub struct SourceBudgets {
    trusted: TrustedSources,
    trusted_in_flight: InFlight,
    pool: InFlight,
    sources: [Source; INGRESS_SOURCES],
    shed: u32,
    log: LogLimit,
}

impl Default for SourceBudgets {
    fn default() -> Self {
        Self::new()
    }
}

impl SourceBudgets {
    /// No source heard yet, nobody trusted.
    pub const fn new() -> Self {
        SourceBudgets {
            trusted: TrustedSources::NONE,
            trusted_in_flight: InFlight::NONE,
            pool: InFlight::NONE,
            sources: [Source {
                ip: [0; 4],
                in_flight: InFlight::NONE,
                heard_us: 0,
                in_use: false,
            }; INGRESS_SOURCES],
            shed: 0,
            log: LogLimit::new(),
        }
    }

    /// Whether a datagram from `ip` arriving at `now_us` is within its class's share and
    /// its own (it then holds one slot of them until [`SourceBudgets::release`]). A refusal
    /// is counted in [`SourceBudgets::shed`] and returns the log verdict for it.
    pub fn admit(&mut self, ip: [u8; 4], now_us: u64) -> Result<(), LogVerdict> {
        let admitted = if self.trusted.contains(ip) {
            let class = &mut self.trusted_in_flight;
            class.heal(now_us);
            let room = class.has_room(SOURCE_SHARE);
            if room {
                class.take(CREDIT_PER_DATAGRAM, now_us);
            }
            room
        } else {
            let (pool_limit, own_limit) = if self.trusted.is_empty() {
                (INBOX_QUEUE as u64, SOURCE_SHARE)
            } else {
                (STRANGER_POOL, STRANGER_SHARE)
            };
            self.pool.heal(now_us);
            let pool_room = self.pool.has_room(pool_limit);
            // (`remembered` always finds a slot: the table is not empty.)
            let room = self.remembered(ip, now_us).is_some_and(|source| {
                source.heard_us = source.heard_us.max(now_us);
                source.in_flight.heal(now_us);
                let room = pool_room && source.in_flight.has_room(own_limit);
                if room {
                    source.in_flight.take(CREDIT_PER_DATAGRAM, now_us);
                }
                room
            });
            if room {
                self.pool.take(CREDIT_PER_DATAGRAM, now_us);
            }
            room
        };
        if admitted {
            Ok(())
        } else {
            self.shed = self.shed.wrapping_add(1);
            Err(self.log.event(now_us))
        }
    }

    /// `ip`'s remembered share: its slot, else a free one, else that of the source heard
    /// least recently, started afresh.
    fn remembered(&mut self, ip: [u8; 4], now_us: u64) -> Option<&mut Source> {
        match self.sources.iter().position(|s| s.in_use && s.ip == ip) {
            Some(i) => self.sources.get_mut(i),
            None => {
                let slot = self
                    .sources
                    .iter_mut()
                    .min_by_key(|s| (s.in_use, s.heard_us))?;
                *slot = Source {
                    ip,
                    in_flight: InFlight {
                        progress_us: now_us,
                        ..InFlight::NONE
                    },
                    heard_us: now_us,
                    in_use: true,
                };
                Some(slot)
            }
        }
    }

    /// The controller took (or a queue dropped) a datagram from `ip`: its slot of the
    /// share is free again.
    pub fn release(&mut self, ip: [u8; 4]) {
        if self.trusted.contains(ip) {
            self.trusted_in_flight.give_back(CREDIT_PER_DATAGRAM);
            return;
        }
        self.pool.give_back(CREDIT_PER_DATAGRAM);
        if let Some(s) = self.sources.iter_mut().find(|s| s.in_use && s.ip == ip) {
            s.in_flight.give_back(CREDIT_PER_DATAGRAM);
        }
    }

    /// Whether datagrams from `ip` take the reserved share now.
    pub fn is_trusted(&self, ip: [u8; 4]) -> bool {
        self.trusted.contains(ip)
    }

    /// From now on, datagrams from `trusted` take the reserved share. An address that
    /// joins it takes its remembered datagrams in flight from the strangers' pool along.
    pub fn set_trusted(&mut self, trusted: TrustedSources) {
        if trusted == self.trusted {
            return;
        }
        for ip in trusted.iter().filter(|ip| !self.trusted.contains(*ip)) {
            if let Some(s) = self.sources.iter_mut().find(|s| s.in_use && s.ip == ip) {
                let moved = s.in_flight.used;
                self.pool.give_back(moved);
                self.trusted_in_flight.used = self.trusted_in_flight.used.saturating_add(moved);
                *s = Source::default();
            }
        }
        self.trusted = trusted;
    }

    /// Datagrams shed so far (wrapping).
    pub fn shed(&self) -> u32 {
        self.shed
    }
}

/// The receive path's shares, in the [`crate::bus::Bus`] (filled by whoever reads datagrams first).
pub type SharedBudgets = Mutex<Cs, RefCell<SourceBudgets>>;
