//! Authenticated sessions (docs/PROTOCOL.md section 13, issue 21), sans-io: the session
//! table the controller checks envelopes against, and what the network task needs to
//! seal its frames ([`SealRoutes`]).
//!
//! A host opens a session with HELLO; the controller grants a session id (counted from 1
//! since boot) and tells its boot epoch, which is part of every MAC: the epoch is the
//! stored `auth_epoch`, one more at every boot with a key (stored before any HELLO is
//! answered), so a frame recorded before a reset never verifies after it, although
//! session ids and counters start again. Each session accepts each counter once
//! ([`protocol::auth::ReplayWindow`]), so two hosts holding the key never replay each
//! other: each has its own session.

use protocol::auth::{AuthKey, MacKey, NONCE_LEN, ReplayWindow};

use crate::hw::Endpoint;

/// Sessions held at once: a few tools on each of a few hosts (an uploader, a watcher, a
/// ROS bridge). A HELLO beyond that takes the slot used least recently: its host gets
/// `AUTH_FAILED` and says HELLO again.
pub const AUTH_SESSIONS: usize = 8;

/// One session.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
struct Session {
    id: u32,
    /// The endpoint its last verified frame came from: its replies and reports go there.
    endpoint: Endpoint,
    /// The nonce of the HELLO that opened it: a copy of that HELLO is a resend.
    nonce: [u8; NONCE_LEN],
    window: ReplayWindow,
    last_used_us: u64,
    /// A valid envelope came in it: its host holds the key (a HELLO alone needs none).
    proved: bool,
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
    slots: [Option<Session>; AUTH_SESSIONS],
}

impl Sessions {
    /// No session, no epoch yet.
    pub const fn new() -> Self {
        Sessions {
            key: None,
            epoch: 0,
            ready: false,
            next_id: 1,
            slots: [None; AUTH_SESSIONS],
        }
    }

    /// Starts epoch `epoch` (stored) with `key`: every session is dropped, HELLO is
    /// answered.
    pub fn start_epoch(&mut self, epoch: u64, key: &AuthKey) {
        *self = Sessions {
            key: Some(MacKey::new(key)),
            epoch,
            ready: true,
            ..Sessions::new()
        };
    }

    /// The key made ready, once an epoch started.
    pub fn mac_key(&self) -> Option<&MacKey> {
        self.key.as_ref()
    }

    /// Drops every session and stops answering HELLO (the key was cleared).
    pub fn close(&mut self) {
        *self = Sessions::new();
    }

    /// The epoch in the MACs.
    pub fn epoch(&self) -> u64 {
        self.epoch
    }

    /// Whether HELLO is answered.
    pub fn ready(&self) -> bool {
        self.ready
    }

    /// Grants a session to `from` for a HELLO with `nonce` at `now_us` (the slot used
    /// least recently goes).
    ///
    /// A copy of the HELLO that opened `from`'s session (same endpoint, same nonce: a host
    /// resends its HELLO when the reply is slow) gets that session again. Opening another
    /// one left the host, which had taken the first reply, sealing in a session that was
    /// gone: `AUTH_FAILED` for its next command, and a HELLO more (issue 19's soak).
    pub fn open(&mut self, from: Endpoint, nonce: [u8; NONCE_LEN], now_us: u64) -> u32 {
        if let Some(s) = self
            .slots
            .iter_mut()
            .flatten()
            .find(|s| s.endpoint == from && s.nonce == nonce)
        {
            s.last_used_us = now_us;
            return s.id;
        }
        // Another HELLO from an endpoint ends its earlier session: its replies must be
        // sealed in the new one, which the host now expects.
        for slot in self.slots.iter_mut() {
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
            proved: false,
        };
        let slot = self
            .slots
            .iter_mut()
            .min_by_key(|s| s.map_or(0, |s| s.last_used_us.saturating_add(1)));
        if let Some(slot) = slot {
            *slot = Some(session);
        }
        id
    }

    /// Checks an envelope's session and counter, its MAC already verified by `mac_ok`
    /// (called only for a known session); on success the counter is used up and the
    /// session follows `from`.
    pub fn accept(
        &mut self,
        session: u32,
        counter: u64,
        mac_ok: impl FnOnce() -> bool,
        from: Endpoint,
        now_us: u64,
    ) -> Result<(), AuthRefusal> {
        let Some(s) = self.slots.iter_mut().flatten().find(|s| s.id == session) else {
            return Err(AuthRefusal::UnknownSession);
        };
        if !s.window.is_fresh(counter) {
            return Err(AuthRefusal::Replayed);
        }
        if !mac_ok() {
            return Err(AuthRefusal::BadMac);
        }
        s.window.accept(counter);
        s.endpoint = from;
        s.last_used_us = now_us;
        s.proved = true;
        Ok(())
    }

    /// The addresses of the sessions that sent a valid envelope (issue 30: they share the
    /// owner's reserved part of the receive path, [`crate::source_share`]).
    pub fn proven_ips(&self) -> impl Iterator<Item = [u8; 4]> + '_ {
        self.slots
            .iter()
            .flatten()
            .filter(|s| s.proved)
            .map(|s| s.endpoint.ip)
    }

    /// The routes the network task seals with (`keyed`: a key is set).
    pub fn routes(&self, keyed: bool) -> SealRoutes {
        SealRoutes {
            key: self.key.filter(|_| self.ready && keyed),
            epoch: self.epoch,
            sessions: self.slots.map(|s| s.map(|s| (s.endpoint, s.id))),
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
mod tests {
    use super::*;

    #[test]
    fn each_counter_passes_once_per_session_and_sessions_are_apart() {
        let a = Endpoint {
            ip: [127, 0, 0, 1],
            port: 1,
        };
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
        for port in (100u16..).take(AUTH_SESSIONS) {
            s.open(Endpoint { port, ..a }, [3; NONCE_LEN], 10 + u64::from(port));
        }
        assert_eq!(
            s.accept(sa, 2, || true, a, 30),
            Err(AuthRefusal::UnknownSession)
        );
    }

    #[test]
    fn a_resent_hello_gets_the_session_it_opened_and_a_new_one_replaces_it() {
        let a = Endpoint {
            ip: [127, 0, 0, 1],
            port: 1,
        };
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
        // A new HELLO from the endpoint ends its session.
        let second = s.open(a, [8; NONCE_LEN], 5);
        assert_ne!(second, first);
        assert_eq!(
            s.accept(first, 3, || true, a, 6),
            Err(AuthRefusal::UnknownSession)
        );
        assert_eq!(s.accept(second, 1, || true, a, 6), Ok(()));
    }
}
