//! The owner rule and who gets LOCATION reports (see "Who gets which report" in
//! [`crate::controller`]), and the DISCOVER_REPLY that tells a host who owns the arm.

use protocol::{DiscoverReply, MoreFlags, OwnerState, State};

use super::{Controller, Owner};
use crate::config::OWNER_TIMEOUT_US;
use crate::hw::Endpoint;
use crate::plant::Plant;
use crate::reports::{Keep, LOCATION_LISTENERS, Listener};

impl<const CAP: usize> Controller<CAP> {
    /// The DISCOVER_REPLY for a host at `asker`: changes nothing.
    pub(super) fn discovery(&self, asker: [u8; 4], now_us: u64) -> DiscoverReply {
        // An owner silent for 5 s with the arm not running has lost the arm already.
        let owner = self.owner.filter(|o| {
            self.state == State::Running
                || now_us.saturating_sub(o.last_heard_us) < OWNER_TIMEOUT_US
        });
        let net = self.settings.net();
        DiscoverReply {
            mac: self.mac,
            net,
            version: protocol::VERSION,
            joints: self.settings.joints,
            state: self.state,
            owner: match owner {
                None => OwnerState::Free,
                Some(o) if o.ip == asker => OwnerState::Asker,
                Some(_) => OwnerState::Other,
            },
            owner_ip: owner.map_or([0; 4], |o| o.ip),
            pending_reset: net != self.booted_net,
        }
    }

    /// The endpoint that started the upload or run, while the arm is not STOPPED.
    fn running_claimer(&self) -> Option<Endpoint> {
        self.location_claimer
            .filter(|_| self.state != State::Stopped)
    }

    /// The run it claimed ended by itself (completion or underrun): the claimer, which
    /// kept its reports however long it was silent, is counted as heard now (the last
    /// datagram's time), so that the end-of-run report reaches it and its reports end 5 s
    /// later unless it speaks (issue 21 F4: while another tool on its machine polled, a
    /// silent uploader lost its reports the instant the run ended, its end-of-run report
    /// with them).
    pub(super) fn claimer_heard_at_run_end(&mut self) {
        let Some(claimer) = self.location_claimer else {
            return;
        };
        let now = self.last_handled_us;
        for listener in self.listeners.iter_mut().flatten() {
            if listener.to == claimer {
                listener.heard_us = listener.heard_us.max(now);
            }
        }
    }

    /// How long `to`, a listener, keeps its reports: for the whole run if it started the
    /// upload or run under way; else, if nothing runs and it was heard most recently,
    /// [`crate::reports::KEEPER_SILENCE_US`] (so that a host with one socket that only
    /// listens gets its reports, as the manual has it, but one datagram buys a bounded
    /// volume of them: issue 21 F6, it was for ever); else 5 s.
    pub(super) fn keep_of(&self, to: Endpoint) -> Keep {
        if let Some(claimer) = self.running_claimer() {
            return if claimer == to {
                Keep::Running
            } else {
                Keep::Other
            };
        }
        let latest = self
            .listeners
            .iter()
            .flatten()
            .max_by_key(|l| l.heard_us)
            .map(|l| l.to);
        if latest == Some(to) {
            Keep::Keeper
        } else {
            Keep::Other
        }
    }

    /// `from`, an owner endpoint whose command was executed, gets LOCATION reports from
    /// now on: it takes a free slot, or that of a listener silent for 5 s, or else that of
    /// the one heard least recently (never the claimer's while something runs).
    pub(super) fn listen(&mut self, from: Endpoint, now_us: u64) {
        // `from` is the one heard most recently from now on.
        let keeper = self.running_claimer().unwrap_or(from);
        let protected = |l: &Listener| l.to == keeper;
        let claimer = self.running_claimer();
        let keep = |l: &Listener| match claimer {
            Some(c) if c == l.to => Keep::Running,
            _ if protected(l) => Keep::Keeper,
            _ => Keep::Other,
        };
        for slot in self.listeners.iter_mut() {
            if slot.is_some_and(|l| now_us >= l.until_us(keep(&l))) {
                *slot = None;
            }
        }
        let fresh = Listener {
            to: from,
            heard_us: now_us,
        };
        if let Some(slot) = self.listeners.iter_mut().flatten().find(|l| l.to == from) {
            *slot = fresh;
            return;
        }
        if let Some(slot) = self.listeners.iter_mut().find(|l| l.is_none()) {
            *slot = Some(fresh);
            return;
        }
        let oldest = self
            .listeners
            .iter_mut()
            .filter(|l| l.is_some_and(|l| !protected(&l)))
            .min_by_key(|l| l.map_or(0, |l| l.heard_us));
        if let Some(slot) = oldest {
            *slot = Some(fresh);
        }
    }

    /// `from` becomes the owner (the first host, or a new one after the owner's 5 s of
    /// silence, not while running): every report goes to it, and an upload the old owner
    /// had not started is dropped, so that the new owner's RUNING cannot run half of it.
    pub(super) fn take_over(&mut self, from: Endpoint, now_us: u64, plant: &mut impl Plant) {
        self.owner = Some(Owner {
            ip: from.ip,
            last_heard_us: now_us,
        });
        self.listeners = [None; LOCATION_LISTENERS];
        self.listeners[0] = Some(Listener {
            to: from,
            heard_us: now_us,
        });
        self.location_claimer = Some(from);
        self.serial_to = Some(from);
        self.uploader = None;
        if matches!(self.state, State::New | State::Pending) {
            plant.stop();
            self.buffer.clear();
            self.return_plan = None;
            self.return_pending = false;
            self.state = State::Stopped;
            self.more_flags.set(MoreFlags::UPLOAD_DROPPED, true);
            warn!("owner hand-over: the old owner's unstarted upload was dropped");
        }
    }
}
