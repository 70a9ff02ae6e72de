//! Stopping what a call started (issue 18): a cancellation token the long waits check, and
//! STOPPED resent until it is ACKed.
//!
//! - [`Cancel`]: set it (from a signal thread, a GUI, another thread) and
//!   [`Client::run_trajectory`] (through [`RunOptions::cancel`](crate::RunOptions::cancel))
//!   or [`Client::wait_stopped_cancellable`] returns [`Error::Interrupted`](crate::Error::Interrupted)
//!   within [`CANCEL_POLL`]; no wait of theirs blocks longer without checking it. The token
//!   only ends the call: it sends nothing.
//! - [`Client::stop_until_acked`]: then STOPPED, the same frame every [`StopRetry::interval`]
//!   until it is ACKed, [`StopRetry::tries`] times at most; a caller's `give_up` (a second
//!   Ctrl-C) ends the wait early. The first copy always goes.
//!
//! The `armctl` tool sets the token from SIGINT/SIGTERM (signal-hook's pipe and a thread,
//! never inside the handler) and sends the STOPPED from its own flow once the call has
//! returned; the Python module does the same on a KeyboardInterrupt or any exception in a
//! motion call or a `with` block.

use std::fmt;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::RecvTimeoutError;
use std::time::{Duration, Instant};

use protocol::{Ack, Command, MAX_DATAGRAM, StatusCode, Tag};

use crate::client::{Client, Event};

/// The longest a cancellable wait blocks without looking at its [`Cancel`].
pub const CANCEL_POLL: Duration = Duration::from_millis(20);

/// A cancellation token: cheap to clone (clones share it), set once, never reset.
#[derive(Clone, Debug, Default)]
pub struct Cancel(Arc<AtomicBool>);

impl Cancel {
    /// A token not yet cancelled.
    pub fn new() -> Cancel {
        Cancel::default()
    }

    /// Cancels every call that watches this token (or a clone of it). Async-signal-safe
    /// (one atomic store), though the tool sets it from a thread rather than a handler.
    pub fn cancel(&self) {
        self.0.store(true, Ordering::SeqCst);
    }

    /// Whether [`Cancel::cancel`] was called.
    pub fn is_cancelled(&self) -> bool {
        self.0.load(Ordering::SeqCst)
    }
}

/// How [`Client::stop_until_acked`] resends STOPPED.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct StopRetry {
    /// Between copies, when no ACK came.
    pub interval: Duration,
    /// Copies at most (the first included; at least 1).
    pub tries: u32,
}

impl Default for StopRetry {
    /// Every 100 ms, 10 copies: about a second.
    fn default() -> Self {
        StopRetry {
            interval: Duration::from_millis(100),
            tries: 10,
        }
    }
}

/// What [`Client::stop_until_acked`] achieved.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StopOutcome {
    /// The controller ACKed the STOPPED (`ack.status` OK, `ack.state` STOPPED: the arm is
    /// stopped).
    Acked {
        /// The ACK.
        ack: Ack,
        /// Copies sent.
        tries: u32,
        /// From the first copy to the ACK.
        waited: Duration,
    },
    /// No ACK after every copy: the arm may still be moving.
    NotAcked {
        /// Copies sent.
        tries: u32,
        /// From the first copy to the end of the last wait.
        waited: Duration,
    },
    /// `give_up` said stop waiting (a second Ctrl-C) before an ACK came.
    Abandoned {
        /// Copies sent.
        tries: u32,
        /// From the first copy to giving up.
        waited: Duration,
    },
}

impl StopOutcome {
    /// Whether the controller ACKed the STOPPED with OK: the arm is stopped.
    pub fn is_acked(&self) -> bool {
        matches!(self, StopOutcome::Acked { ack, .. } if ack.status == StatusCode::Ok)
    }

    /// Copies of STOPPED sent.
    pub fn tries(&self) -> u32 {
        match *self {
            StopOutcome::Acked { tries, .. }
            | StopOutcome::NotAcked { tries, .. }
            | StopOutcome::Abandoned { tries, .. } => tries,
        }
    }
}

fn copies(n: u32) -> String {
    if n == 1 {
        "1 try".into()
    } else {
        format!("{n} tries")
    }
}

impl fmt::Display for StopOutcome {
    /// One line for a user: `STOPPED sent, the arm is stopped (ACKed after 1 try, 0.4 ms)`,
    /// `STOPPED sent, not ACKed after 10 tries (1.0 s): the arm may still be moving ...`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let ms = |d: &Duration| d.as_secs_f64() * 1e3;
        match self {
            StopOutcome::Acked { ack, tries, waited } if ack.status == StatusCode::Ok => {
                write!(
                    f,
                    "STOPPED sent, the arm is stopped (ACKed after {}, {:.1} ms; state {})",
                    copies(*tries),
                    ms(waited),
                    ack.state.name()
                )
            }
            StopOutcome::Acked { ack, tries, .. } => write!(
                f,
                "STOPPED sent, ACKed with {} (state {}) after {}: the controller did not \
                 take it; the arm may still be moving (send STOPPED again: `armctl stop`)",
                ack.status.name(),
                ack.state.name(),
                copies(*tries)
            ),
            StopOutcome::NotAcked { tries, waited } => write!(
                f,
                "STOPPED sent, not ACKed after {} ({:.1} s): the arm may still be moving; \
                 check the controller (`armctl status`) and the link",
                copies(*tries),
                waited.as_secs_f64()
            ),
            StopOutcome::Abandoned { tries, waited } => write!(
                f,
                "STOPPED sent, not ACKed after {} ({:.0} ms) when the wait was abandoned: \
                 the arm may still be moving (`armctl stop`)",
                copies(*tries),
                ms(waited)
            ),
        }
    }
}

impl Client {
    /// STOPPED, resent (the same frame, as for any command) every `retry.interval` until
    /// an ACK comes, `retry.tries` copies at most: the e-stop a host sends when it stops
    /// what it started. Never waits behind an upload. `give_up` is asked at least every
    /// [`CANCEL_POLL`] once the first copy has gone; `true` ends the wait
    /// ([`StopOutcome::Abandoned`]). A copy the system cannot send (nothing listens on a
    /// loopback port) counts as sent: the next may reach a controller that is back.
    ///
    /// Every STOPPED is obeyed, from any host (docs/PROTOCOL.md), so this works whoever
    /// owns the controller.
    pub fn stop_until_acked(
        &self,
        retry: &StopRetry,
        mut give_up: impl FnMut() -> bool,
    ) -> StopOutcome {
        let mut buf = [0u8; MAX_DATAGRAM];
        let seq = self.alloc_seq();
        let Ok(len) = Command::Stopped.encode(seq, &mut buf) else {
            // STOPPED has no data: it always fits.
            return StopOutcome::NotAcked {
                tries: 0,
                waited: Duration::ZERO,
            };
        };
        let frame = &buf[..len];
        let mut waiter = self.waiter();
        waiter.expect(seq);
        let started = Instant::now();
        let mut tries = 0;
        while tries < retry.tries.max(1) {
            let _ = self.send_bytes(frame);
            tries += 1;
            let next = Instant::now() + retry.interval;
            loop {
                if give_up() {
                    return StopOutcome::Abandoned {
                        tries,
                        waited: started.elapsed(),
                    };
                }
                let left = next.saturating_duration_since(Instant::now());
                if left.is_zero() {
                    break;
                }
                match waiter.rx.recv_timeout(left.min(CANCEL_POLL)) {
                    Ok(Event::Ack(_, ack)) if ack.acked_tag != Tag::Stopped as u8 => {}
                    // Damaged on the way: again at once.
                    Ok(Event::Ack(_, ack)) if ack.status == StatusCode::BadCrc => break,
                    Ok(Event::Ack(_, ack)) => {
                        return StopOutcome::Acked {
                            ack,
                            tries,
                            waited: started.elapsed(),
                        };
                    }
                    // "Port unreachable": the next copy may find the controller back.
                    Ok(Event::Refused | Event::Hello | Event::WrongKey)
                    | Err(RecvTimeoutError::Timeout) => {}
                    Err(RecvTimeoutError::Disconnected) => break,
                }
            }
        }
        StopOutcome::NotAcked {
            tries,
            waited: started.elapsed(),
        }
    }
}
