//! Authenticated sessions (docs/PROTOCOL.md section 13, issues 21 and 30), sans-io: the
//! session table the controller checks envelopes against, HELLO's reply budget, and what
//! the network task needs to seal its frames ([`SealRoutes`]).
//!
//! A host opens a session with HELLO; the controller grants a session id (counted from 1
//! since boot) and tells its boot epoch, which is part of every MAC: the epoch is the
//! stored `auth_epoch`, one more at every boot with a key (stored before any HELLO is
//! answered), so a frame recorded before a reset never verifies after it, although
//! session ids and counters start again. A key's first epoch is random
//! ([`epoch_base`]): a key set again after the settings were lost never repeats the
//! epochs it had. Each session accepts each counter once
//! ([`protocol::auth::ReplayWindow`]), so two hosts holding the key never replay each
//! other: each has its own session.
//!
//! # Proven and unproven sessions (issue 30)
//! HELLO needs no key, so anyone can send it. A session HELLO opened is **unproven** until
//! its first envelope verifies: that proves its host holds the key. Unproven sessions live
//! in a table of their own ([`AUTH_UNPROVEN`]) and never take a proven one's slot
//! ([`AUTH_SESSIONS`]); when one proves, it takes a proven slot (the one used least
//! recently if all are taken: a key holder displaces another key holder, never a
//! stranger). HELLO replies are budgeted per source address ([`HelloBudget`]): a flood
//! from other addresses never spends the budget of the address a key holder says HELLO
//! from. Before issue 30 one table and one global budget of 10 replies/s served both, so
//! a stranger's HELLOs evicted key holders, and a 500/s flood left a holder's HELLO a
//! reply now and then.

use protocol::auth::{AuthKey, MacKey, NONCE_LEN, ReplayWindow};

use crate::controller::ReplyBudget;
use crate::hw::Endpoint;

/// Proven sessions held at once: a few tools on each of a few hosts (an uploader, a
/// watcher, a ROS bridge). A session that proves beyond that takes the proven slot used
/// least recently: its host gets `AUTH_FAILED` and says HELLO again.
pub const AUTH_SESSIONS: usize = 8;

/// Unproven sessions held at once (HELLO answered, no envelope verified yet): room for a
/// HELLO from each of 32 endpoints, so that a host's session outlives, until it proves,
/// the HELLOs of 31 other endpoints; beyond that a HELLO takes the unproven slot of the
/// address holding the most, used least recently. About 60 bytes each.
pub const AUTH_UNPROVEN: usize = 32;

/// Source addresses whose HELLO budgets are kept apart: more than [`AUTH_UNPROVEN`]'s
/// endpoints need. Beyond it the address heard least recently is forgotten.
pub const HELLO_SOURCES: usize = 32;

/// HELLO replies a second to one source address (after a burst of
/// [`HELLO_SOURCE_BURST`]): a host resends its HELLO when the reply is slow, and a tool
/// whose session was taken says HELLO again.
pub const HELLO_REPLIES_PER_SOURCE_PER_S: u32 = 4;

/// HELLO replies to one source address at once, before its rate applies: as many as
/// there are proven sessions, so that every tool on one host can start together.
pub const HELLO_SOURCE_BURST: u32 = 8;
const _: () = assert!(HELLO_SOURCE_BURST as usize == AUTH_SESSIONS);

/// HELLO replies a second in all (and at once): what bounds the 62-byte replies to
/// 19-byte requests a flood from many (forged) addresses can draw, at 8 KB/s. Above the
/// 80 a second twenty flooding addresses get, so that their floods leave other
/// addresses' budgets alone.
pub const HELLO_REPLIES_PER_S: u32 = 128;

/// Bits of an epoch: what the board's settings record stores (a u32 and 3 spare bytes).
/// Epochs wrap within them.
pub const AUTH_EPOCH_BITS: u32 = 56;

/// The epochs' mask ([`AUTH_EPOCH_BITS`]).
pub const AUTH_EPOCH_MASK: u64 = (1 << AUTH_EPOCH_BITS) - 1;

/// The first epoch of a key set now: random, from `entropy` (the chip's RNG, drawn at
/// boot: [`crate::Controller::set_entropy`]) and `n`, the keys set since boot. A key set
/// again (the settings lost, the same key given) starts somewhere in 2^56 epochs, so its
/// epochs repeat an earlier run of them with odds of its boots in 2^56; counting from 1
/// again, every recorded envelope verified again. (SplitMix64's finaliser: every `n`
/// gives another value for one `entropy`.)
pub const fn epoch_base(entropy: u64, n: u32) -> u64 {
    let mut z = entropy.wrapping_add((n as u64 + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15));
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    // Never 0, the epoch of no key.
    let e = z & AUTH_EPOCH_MASK;
    if e == 0 { 1 } else { e }
}

/// The epoch after `epoch` (the next boot's), within [`AUTH_EPOCH_BITS`].
pub const fn next_epoch(epoch: u64) -> u64 {
    epoch.wrapping_add(1) & AUTH_EPOCH_MASK
}

/// One session.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
struct Session {
    id: u32,
    /// The endpoint its last verified frame came from (its HELLO's, until one did): its
    /// replies and reports go there.
    endpoint: Endpoint,
    /// The nonce of the HELLO that opened it: a copy of that HELLO is a resend.
    nonce: [u8; NONCE_LEN],
    window: ReplayWindow,
    last_used_us: u64,
}

/// Why an envelope was refused (each is `AUTH_FAILED` on the wire).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum AuthRefusal {
    /// No session has this id (never granted, taken over, or from before a reset).
    UnknownSession,
    /// The MAC does not verify (another key, another epoch, a changed byte).
    BadMac,
    /// The counter was used already, or is older than the replay window.
    Replayed,
}

/// One source address's HELLO replies.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
struct Source {
    ip: [u8; 4],
    budget: ReplyBudget,
    heard_us: u64,
}

/// HELLO's reply budget: one token bucket per source address ([`HELLO_SOURCES`] of them,
/// [`HELLO_REPLIES_PER_SOURCE_PER_S`]) within one for all ([`HELLO_REPLIES_PER_S`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct HelloBudget {
    sources: [Option<Source>; HELLO_SOURCES],
    all: ReplyBudget,
}

impl HelloBudget {
    /// Every budget full.
    pub const fn new() -> Self {
        HelloBudget {
            sources: [None; HELLO_SOURCES],
            all: ReplyBudget::with(HELLO_REPLIES_PER_S, HELLO_REPLIES_PER_S),
        }
    }

    /// Takes one reply to `ip` at `now_us`, if both its budget and the whole one allow.
    pub fn take(&mut self, ip: [u8; 4], now_us: u64) -> bool {
        let fresh = Source {
            ip,
            budget: ReplyBudget::with(HELLO_REPLIES_PER_SOURCE_PER_S, HELLO_SOURCE_BURST),
            heard_us: now_us,
        };
        let known = self
            .sources
            .iter()
            .position(|s| s.is_some_and(|s| s.ip == ip));
        let index = known.or_else(|| {
            // A free entry, or the one heard least recently.
            self.sources
                .iter()
                .enumerate()
                .min_by_key(|(_, s)| s.map_or(0, |s| s.heard_us.saturating_add(1)))
                .map(|(i, _)| i)
        });
        let Some(entry) = index.and_then(|i| self.sources.get_mut(i)) else {
            return false;
        };
        let source = match entry {
            Some(s) if s.ip == ip => s,
            _ => entry.insert(fresh),
        };
        source.heard_us = now_us;
        // The source's own budget first: a source past it spends nothing of the others'.
        source.budget.take(now_us) && self.all.take(now_us)
    }
}

impl Default for HelloBudget {
    fn default() -> Self {
        Self::new()
    }
}

/// The controller's sessions.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Sessions {
    /// The key, made ready for MACs (its key block compressed once, not per frame).
    key: Option<MacKey>,
    epoch: u64,
    /// The epoch is stored: HELLO may be answered (a reset before the store would give
    /// the next boot the same epoch).
    ready: bool,
    next_id: u32,
    /// Sessions that proved the key (an envelope verified).
    proven: [Option<Session>; AUTH_SESSIONS],
    /// Sessions HELLO opened, none of whose envelopes verified yet.
    unproven: [Option<Session>; AUTH_UNPROVEN],
    /// HELLO's reply budget.
    budget: HelloBudget,
}

impl Sessions {
    /// No session, no epoch yet.
    pub const fn new() -> Self {
        Sessions {
            key: None,
            epoch: 0,
            ready: false,
            next_id: 1,
            proven: [None; AUTH_SESSIONS],
            unproven: [None; AUTH_UNPROVEN],
            budget: HelloBudget::new(),
        }
    }

    /// Starts epoch `epoch` (stored) with `key`: every session is dropped, HELLO is
    /// answered. (Session ids go on counting: a reply of the ended sessions never names a
    /// new one.)
    pub fn start_epoch(&mut self, epoch: u64, key: &AuthKey) {
        self.key = Some(MacKey::new(key));
        self.epoch = epoch;
        self.ready = true;
        self.drop_sessions();
    }

    /// Every session dropped, in place (the tables are a few KB: no copy of them on the
    /// stack).
    fn drop_sessions(&mut self) {
        self.proven.fill(None);
        self.unproven.fill(None);
    }

    /// The key made ready, once an epoch started.
    pub fn mac_key(&self) -> Option<&MacKey> {
        self.key.as_ref()
    }

    /// Drops every session and stops answering HELLO (the key was cleared).
    pub fn close(&mut self) {
        self.key = None;
        self.epoch = 0;
        self.ready = false;
        self.drop_sessions();
    }

    /// The epoch in the MACs.
    pub fn epoch(&self) -> u64 {
        self.epoch
    }

    /// Whether HELLO is answered.
    pub fn ready(&self) -> bool {
        self.ready
    }

    /// Answers a HELLO from `from` with `nonce` at `now_us`: the session granted, or
    /// `None` past `from`'s address's reply budget ([`HelloBudget`]; no reply at all).
    pub fn hello(&mut self, from: Endpoint, nonce: [u8; NONCE_LEN], now_us: u64) -> Option<u32> {
        self.budget
            .take(from.ip, now_us)
            .then(|| self.open(from, nonce, now_us))
    }

    /// Grants an unproven session to `from` for a HELLO with `nonce` at `now_us`
    /// (no budget: [`Sessions::hello`] has it).
    ///
    /// A copy of the HELLO that opened `from`'s session (same endpoint, same nonce: a host
    /// resends its HELLO when the reply is slow) gets that session again. Opening another
    /// one left the host, which had taken the first reply, sealing in a session that was
    /// gone: `AUTH_FAILED` for its next command, and a HELLO more (issue 19's soak).
    ///
    /// Another HELLO from an endpoint ends its earlier unproven session; its proven one
    /// ends only when the new one proves (a HELLO from a forged source must not end a key
    /// holder's session).
    pub fn open(&mut self, from: Endpoint, nonce: [u8; NONCE_LEN], now_us: u64) -> u32 {
        if let Some(s) = self
            .proven
            .iter_mut()
            .chain(self.unproven.iter_mut())
            .flatten()
            .find(|s| s.endpoint == from && s.nonce == nonce)
        {
            s.last_used_us = now_us;
            return s.id;
        }
        for slot in self.unproven.iter_mut() {
            if slot.is_some_and(|s| s.endpoint == from) {
                *slot = None;
            }
        }
        let id = self.next_id;
        self.next_id = self.next_id.wrapping_add(1).max(1);
        let session = Session {
            id,
            endpoint: from,
            nonce,
            window: ReplayWindow::new(),
            last_used_us: now_us,
        };
        let slot = self.unproven_slot();
        if let Some(slot) = self.unproven.get_mut(slot) {
            *slot = Some(session);
        }
        id
    }

    /// The unproven slot a new session takes: a free one, or else the one used least
    /// recently among those of the address holding the most (so that a flood from a few
    /// addresses ends its own sessions, not the one other hosts just opened).
    fn unproven_slot(&self) -> usize {
        if let Some(free) = self.unproven.iter().position(Option::is_none) {
            return free;
        }
        let held_by = |ip: [u8; 4]| {
            self.unproven
                .iter()
                .flatten()
                .filter(|s| s.endpoint.ip == ip)
                .count()
        };
        self.unproven
            .iter()
            .enumerate()
            .filter_map(|(i, s)| s.map(|s| (i, s)))
            .max_by_key(|(_, s)| (held_by(s.endpoint.ip), u64::MAX - s.last_used_us))
            .map_or(0, |(i, _)| i)
    }

    /// Checks an envelope's session and counter, its MAC already verified by `mac_ok`
    /// (called only for a known session); on success the counter is used up and the
    /// session follows `from`. An unproven session's first verified envelope proves it:
    /// it takes a proven slot (its endpoint's earlier session ends).
    pub fn accept(
        &mut self,
        session: u32,
        counter: u64,
        mac_ok: impl FnOnce() -> bool,
        from: Endpoint,
        now_us: u64,
    ) -> Result<(), AuthRefusal> {
        let proven = self
            .proven
            .iter()
            .position(|s| s.is_some_and(|s| s.id == session));
        let unproven = self
            .unproven
            .iter()
            .position(|s| s.is_some_and(|s| s.id == session));
        let slot = match (proven, unproven) {
            (Some(i), _) => self.proven.get_mut(i),
            (None, Some(i)) => self.unproven.get_mut(i),
            (None, None) => None,
        };
        let Some(Some(s)) = slot else {
            return Err(AuthRefusal::UnknownSession);
        };
        if !s.window.is_fresh(counter) {
            return Err(AuthRefusal::Replayed);
        }
        if !mac_ok() {
            return Err(AuthRefusal::BadMac);
        }
        s.window.accept(counter);
        let opened_at = s.endpoint;
        s.endpoint = from;
        s.last_used_us = now_us;
        if let Some(i) = unproven
            && proven.is_none()
        {
            self.prove(i, opened_at);
        }
        Ok(())
    }

    /// The addresses of the sessions that proved the key (issue 30: they share the owner's
    /// reserved part of the receive path, [`crate::source_share`]).
    pub fn proven_ips(&self) -> impl Iterator<Item = [u8; 4]> + '_ {
        self.proven.iter().flatten().map(|s| s.endpoint.ip)
    }

    /// Moves unproven session `i`, opened by `opened_at`, to a proven slot.
    fn prove(&mut self, i: usize, opened_at: Endpoint) {
        let Some(session) = self.unproven.get_mut(i).and_then(Option::take) else {
            return;
        };
        // The host's new HELLO replaced its earlier session.
        for slot in self.proven.iter_mut() {
            if slot.is_some_and(|s| s.endpoint == opened_at || s.endpoint == session.endpoint) {
                *slot = None;
            }
        }
        let slot = self
            .proven
            .iter_mut()
            .min_by_key(|s| s.map_or(0, |s| s.last_used_us.saturating_add(1)));
        if let Some(slot) = slot {
            *slot = Some(session);
        }
    }

    /// The routes the network task seals with (`keyed`: a key is set): the proven
    /// sessions' (an unproven one's only reply, HELLO_REPLY, names its session itself).
    pub fn routes(&self, keyed: bool) -> SealRoutes {
        SealRoutes {
            key: self.key.filter(|_| self.ready && keyed),
            epoch: self.epoch,
            sessions: self.proven.map(|s| s.map(|s| (s.endpoint, s.id))),
        }
    }
}

impl Default for Sessions {
    fn default() -> Self {
        Self::new()
    }
}

/// What sealing needs: published by the trajectory task with the report settings.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SealRoutes {
    /// The key made ready; `None`: no key, frames go out plain, as before issue 21.
    pub key: Option<MacKey>,
    /// The boot epoch.
    pub epoch: u64,
    /// Each session's endpoint and id.
    pub sessions: [Option<(Endpoint, u32)>; AUTH_SESSIONS],
}

impl SealRoutes {
    /// No key.
    pub const NONE: SealRoutes = SealRoutes {
        key: None,
        epoch: 0,
        sessions: [None; AUTH_SESSIONS],
    };

    /// The session whose replies go to `to`.
    pub fn session_of(&self, to: Endpoint) -> Option<u32> {
        self.sessions
            .iter()
            .flatten()
            .find(|(e, _)| *e == to)
            .map(|(_, id)| *id)
    }
}

#[cfg(test)]
// Small test counts and wrapping nonce bytes.
#[allow(clippy::cast_possible_truncation)]
mod tests {
    use super::*;

    const A: Endpoint = Endpoint {
        ip: [127, 0, 0, 1],
        port: 1,
    };

    /// `n` other hosts (127.0.1.x), each with a HELLO; `prove`: each sends an envelope too.
    fn others(s: &mut Sessions, n: u8, prove: bool, now_us: u64) {
        for i in 0..n {
            let e = Endpoint {
                ip: [127, 0, 1, i],
                port: 9,
            };
            let id = s.open(e, [i; NONCE_LEN], now_us);
            if prove {
                assert_eq!(s.accept(id, 1, || true, e, now_us), Ok(()));
            }
        }
    }

    #[test]
    fn each_counter_passes_once_per_session_and_sessions_are_apart() {
        let a = A;
        let b = Endpoint { port: 2, ..a };
        let mut s = Sessions::new();
        s.start_epoch(3, &AuthKey([1; 32]));
        let sa = s.open(a, [1; NONCE_LEN], 0);
        let sb = s.open(b, [2; NONCE_LEN], 0);
        assert_ne!(sa, sb);
        assert_eq!(s.accept(sa, 1, || true, a, 1), Ok(()));
        assert_eq!(s.accept(sa, 1, || true, a, 2), Err(AuthRefusal::Replayed));
        assert_eq!(s.accept(sb, 1, || true, b, 2), Ok(()));
        assert_eq!(s.accept(sb, 2, || false, b, 2), Err(AuthRefusal::BadMac));
        assert_eq!(
            s.accept(sb, 2, || true, b, 2),
            Ok(()),
            "a bad MAC uses no counter"
        );
        assert_eq!(
            s.accept(99, 1, || true, a, 2),
            Err(AuthRefusal::UnknownSession)
        );
        assert_eq!(s.routes(true).session_of(b), Some(sb));
        // As many key holders as there are proven slots, each proving the key: the
        // slot used least recently (a's) goes to one of them.
        others(&mut s, AUTH_SESSIONS as u8, true, 10);
        assert_eq!(
            s.accept(sa, 2, || true, a, 30),
            Err(AuthRefusal::UnknownSession)
        );
    }

    /// Issue 30: HELLOs without the key, however many, never take a proven session's
    /// slot; an unproven session is not routed to until it proves.
    #[test]
    fn hellos_without_the_key_never_take_a_proven_session() {
        let mut s = Sessions::new();
        s.start_epoch(3, &AuthKey([1; 32]));
        let sa = s.open(A, [1; NONCE_LEN], 0);
        assert_eq!(s.routes(true).session_of(A), None, "not proven yet");
        assert_eq!(s.accept(sa, 1, || true, A, 1), Ok(()));
        assert_eq!(s.routes(true).session_of(A), Some(sa));
        // Four times as many HELLOs as there are unproven slots, from 128 addresses.
        for round in 0..4u8 {
            for i in 0..(AUTH_UNPROVEN as u8) {
                let e = Endpoint {
                    ip: [10, round, 0, i],
                    port: 7,
                };
                s.open(e, [i; NONCE_LEN], 10 + u64::from(i));
            }
        }
        // Even one forged from a's own endpoint: a's session goes on.
        let forged = s.open(A, [0xEE; NONCE_LEN], 50);
        assert_eq!(s.accept(sa, 2, || true, A, 60), Ok(()));
        assert_eq!(s.routes(true).session_of(A), Some(sa));
        // The forger cannot prove it (no key: the MAC fails).
        assert_eq!(
            s.accept(forged, 1, || false, A, 61),
            Err(AuthRefusal::BadMac)
        );
        assert_eq!(s.accept(sa, 3, || true, A, 62), Ok(()));
    }

    /// Issue 30: a host's unproven session outlives the HELLOs of other addresses (a
    /// flood from fewer endpoints than unproven slots), so it can prove it.
    #[test]
    fn a_flood_of_hellos_leaves_a_new_session_time_to_prove() {
        let mut s = Sessions::new();
        s.start_epoch(3, &AuthKey([1; 32]));
        let sa = s.open(A, [1; NONCE_LEN], 0);
        // 20 flooding endpoints, 50 HELLOs each, each with a new nonce.
        for n in 0..50u8 {
            for i in 0..20u8 {
                let e = Endpoint {
                    ip: [127, 0, 0, 10 + i],
                    port: 7,
                };
                s.open(e, [n; NONCE_LEN], 1 + u64::from(n));
            }
        }
        assert_eq!(s.accept(sa, 1, || true, A, 100), Ok(()));
        // Beyond the slots (more endpoints than AUTH_UNPROVEN), an address holding
        // several loses one of its own first.
        let mut s = Sessions::new();
        s.start_epoch(3, &AuthKey([1; 32]));
        let sa = s.open(A, [1; NONCE_LEN], 0);
        for n in 0..(2 * AUTH_UNPROVEN as u16) {
            let e = Endpoint {
                ip: [127, 0, 0, 2],
                port: 100 + n,
            };
            s.open(e, [1; NONCE_LEN], 1 + u64::from(n));
        }
        assert_eq!(s.accept(sa, 1, || true, A, 100), Ok(()));
    }

    /// Issue 30: HELLO's replies are budgeted per source address: a flood from twenty
    /// other addresses leaves a key holder's address its own.
    #[test]
    fn a_hello_flood_from_other_addresses_leaves_a_holders_budget_alone() {
        let mut s = Sessions::new();
        s.start_epoch(3, &AuthKey([1; 32]));
        let mut holder_replies = 0;
        let mut flood_replies = 0u32;
        // 10 s at 500 HELLOs/s from 20 addresses; the holder says HELLO once a second.
        for ms in 0..10_000u64 {
            let now = 1_000_000 + ms * 1_000;
            let e = Endpoint {
                ip: [127, 0, 0, 10 + (ms % 20) as u8],
                port: 7,
            };
            let nonce = [(ms % 251) as u8; NONCE_LEN];
            flood_replies += u32::from(s.hello(e, nonce, now).is_some());
            if ms % 2 == 0 {
                flood_replies += u32::from(s.hello(e, [1; NONCE_LEN], now + 500).is_some());
            }
            if ms % 1_000 == 999 {
                let nonce = [(ms / 1_000) as u8; NONCE_LEN];
                holder_replies += usize::from(s.hello(A, nonce, now + 700).is_some());
            }
        }
        assert_eq!(holder_replies, 10, "every HELLO of the holder answered");
        // 20 addresses at their rate after their burst, within the whole budget.
        let most = 20 * (HELLO_SOURCE_BURST + HELLO_REPLIES_PER_SOURCE_PER_S * 10);
        assert!(flood_replies <= most, "{flood_replies} > {most}");
    }

    #[test]
    fn a_resent_hello_gets_the_session_it_opened_and_a_new_one_replaces_it_once_proven() {
        let a = A;
        let mut s = Sessions::new();
        s.start_epoch(3, &AuthKey([1; 32]));
        let first = s.open(a, [7; NONCE_LEN], 0);
        assert_eq!(s.accept(first, 1, || true, a, 1), Ok(()));
        // The same HELLO again (its reply was slow): the same session, its counters kept.
        assert_eq!(s.open(a, [7; NONCE_LEN], 2), first);
        assert_eq!(s.accept(first, 2, || true, a, 3), Ok(()));
        assert_eq!(
            s.accept(first, 1, || true, a, 3),
            Err(AuthRefusal::Replayed)
        );
        // The same nonce from another endpoint is another host's HELLO.
        let b = Endpoint { port: 2, ..a };
        assert_ne!(s.open(b, [7; NONCE_LEN], 4), first);
        // A new HELLO from the endpoint: its earlier session ends when the new one
        // proves (issue 30; until then a forged HELLO would end it).
        let second = s.open(a, [8; NONCE_LEN], 5);
        assert_ne!(second, first);
        assert_eq!(s.routes(true).session_of(a), Some(first));
        assert_eq!(s.accept(second, 1, || true, a, 6), Ok(()));
        assert_eq!(s.routes(true).session_of(a), Some(second));
        assert_eq!(
            s.accept(first, 3, || true, a, 6),
            Err(AuthRefusal::UnknownSession)
        );
    }

    #[test]
    fn epoch_bases_differ_and_stay_within_the_stored_bits() {
        let bases: std::vec::Vec<u64> = (0..100).map(|n| epoch_base(0x1234, n)).collect();
        for (i, b) in bases.iter().enumerate() {
            assert!(*b != 0 && *b <= AUTH_EPOCH_MASK);
            assert!(!bases[..i].contains(b));
        }
        assert_ne!(epoch_base(1, 0), epoch_base(2, 0));
        assert_eq!(next_epoch(AUTH_EPOCH_MASK), 0);
    }
}
