//! The client's receiving side: the thread that reads every datagram from the controller
//! and hands ACKs to whoever waits for their seq, and reports to their subscribers.

use std::collections::HashMap;
use std::net::UdpSocket;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{self, Receiver, Sender};
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::time::Duration;

use protocol::{Ack, LimitsReport, Location, MAX_DATAGRAM, Report, StatusReport};

use super::auth::Opened;
use crate::pcap::PcapLog;

/// What a waiter for ACKs hears from the receiver thread.
#[derive(Clone, Copy, Debug)]
pub(crate) enum Event {
    /// The ACK of a seq.
    Ack(u8, Ack),
    /// The system reported the controller's port unreachable (ICMP): nothing listens there.
    Refused,
    /// The HELLO waited for opened a session.
    Hello,
    /// The HELLO_REPLY waited for does not verify: another key.
    WrongKey,
}

/// Where the ACKs of a seq go.
type AckSender = Sender<Event>;

/// Where the receiver thread delivers what arrives.
#[derive(Default)]
pub(crate) struct Shared {
    pub(super) shutdown: AtomicBool,
    /// Who (waiter id) waits for the ACK of which seq.
    pub(super) waiters: Mutex<HashMap<u8, (u64, AckSender)>>,
    /// Source of waiter ids.
    pub(super) next_waiter: AtomicU64,
    pub(super) locations: Mutex<Vec<Sender<Location>>>,
    pub(super) serial: Mutex<Vec<Sender<Vec<u8>>>>,
    pub(super) statuses: Mutex<Vec<Sender<StatusReport>>>,
    /// LIMITS reports (the answers to LIMITS_GET, issue 23).
    pub(super) limits: Mutex<Vec<Sender<LimitsReport>>>,
    /// STOP_CAUSE reports (STATUS's request byte bit 2, issue 31).
    pub(super) stops: Mutex<Vec<Sender<protocol::StopReport>>>,
    /// RX_COUNTERS reports (STATUS's request byte bit 3, issue 30), for `Client::diag`.
    pub(super) rx_counters: Mutex<Vec<Sender<protocol::RxCounters>>>,
    /// DIAG reports (STATUS's request byte bit 6, issue 34), for `Client::diag`.
    pub(super) diags: Mutex<Vec<Sender<protocol::Diag>>>,
    /// MOTION reports (STATUS's request byte bit 4, issue 32).
    pub(super) motions: Mutex<Vec<Sender<protocol::MotionReport>>>,
    /// JOINT_DESC reports' subscribers (issue 31).
    pub(super) descs: Mutex<Vec<Sender<protocol::JointDescSet>>>,
    pub(super) last_location: Mutex<Option<Location>>,
    pub(super) last_status: Mutex<Option<StatusReport>>,
    /// Datagrams that did not decode as a report.
    pub(super) undecodable: AtomicU64,
    /// ACKs `AUTH_FAILED` received (an envelope refused: its session was gone).
    pub(super) auth_failed: AtomicU64,
    /// Where every datagram sent and received is written ([`Client::capture`]).
    pub(super) pcap: Mutex<Option<Arc<PcapLog>>>,
    /// With a key: the session, and sealing and opening.
    pub(super) auth: Mutex<Option<super::auth::HostAuth>>,
    /// Where the answers to the HELLO under way go (HELLO_REPLY, or an ACK refusing the
    /// HELLO): matched by tag and nonce, not by seq, because a HELLO takes no seq of its
    /// own ([`super::Client::hello`]).
    pub(super) hello: Mutex<Option<AckSender>>,
}

/// Locks a mutex even if a thread panicked while holding it: the data here (channel lists,
/// last reports) stays consistent whatever happened.
pub(crate) fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(PoisonError::into_inner)
}

/// Sends to every subscriber and forgets the ones that hung up.
fn fan_out<T: Clone>(subs: &Mutex<Vec<Sender<T>>>, value: &T) {
    lock(subs).retain(|s| s.send(value.clone()).is_ok());
}

impl Shared {
    /// A new registration for ACKs, with an id of its own.
    pub(super) fn waiter(&self) -> AckWaiter<'_> {
        let (tx, rx) = mpsc::channel();
        AckWaiter {
            shared: self,
            id: self.next_waiter.fetch_add(1, Ordering::Relaxed),
            seqs: Vec::new(),
            tx,
            rx,
        }
    }

    /// Tells every waiter that the controller's port was reported unreachable.
    fn refused(&self) {
        for (_, waiter) in lock(&self.waiters).values() {
            let _ = waiter.send(Event::Refused);
        }
        if let Some(waiter) = lock(&self.hello).as_ref() {
            let _ = waiter.send(Event::Refused);
        }
    }

    fn deliver(&self, datagram: &[u8]) {
        let opened = lock(&self.auth).as_mut().map(|a| a.open(datagram));
        let inner;
        let datagram = match opened {
            None => datagram,
            Some(Opened::Frame(bytes)) => {
                inner = bytes;
                &inner[..]
            }
            Some(Opened::Hello) | Some(Opened::WrongKey) => {
                let event = match opened {
                    Some(Opened::Hello) => Event::Hello,
                    _ => Event::WrongKey,
                };
                if let Some(waiter) = lock(&self.hello).as_ref() {
                    let _ = waiter.send(event);
                }
                return;
            }
            Some(Opened::Dropped) => {
                self.undecodable.fetch_add(1, Ordering::Relaxed);
                return;
            }
        };
        let Ok(frame) = Report::decode(datagram) else {
            self.undecodable.fetch_add(1, Ordering::Relaxed);
            return;
        };
        match frame.body {
            Report::Ack(ack) if ack.acked_tag == protocol::Tag::Hello as u8 => {
                if let Some(waiter) = lock(&self.hello).as_ref() {
                    let _ = waiter.send(Event::Ack(frame.seq, ack));
                }
            }
            Report::Ack(ack) => {
                if ack.status == protocol::StatusCode::AuthFailed {
                    self.auth_failed.fetch_add(1, Ordering::Relaxed);
                }
                if let Some((_, waiter)) = lock(&self.waiters).get(&frame.seq) {
                    let _ = waiter.send(Event::Ack(frame.seq, ack));
                }
            }
            Report::Location(location) => {
                *lock(&self.last_location) = Some(location);
                fan_out(&self.locations, &location);
            }
            Report::UsartRecv(bytes) => fan_out(&self.serial, &bytes.to_vec()),
            Report::Status(status) => {
                *lock(&self.last_status) = Some(status);
                fan_out(&self.statuses, &status);
            }
            Report::Limits(limits) => fan_out(&self.limits, &limits),
            Report::StopCause(stop) => fan_out(&self.stops, &stop),
            // Asked for by `Client::diag` (STATUS's request byte bits 3 and 6).
            Report::RxCounters(counters) => fan_out(&self.rx_counters, &counters),
            Report::Diag(diag) => fan_out(&self.diags, &diag),
            Report::JointDesc(desc) => fan_out(&self.descs, &desc),
            Report::Motion(motion) => fan_out(&self.motions, &motion),
        }
    }
}

/// The receiver thread: every datagram from the controller to its waiter or subscribers,
/// until `shutdown`.
pub(super) fn receive_loop(socket: UdpSocket, shared: Arc<Shared>) {
    let mut buf = [0u8; MAX_DATAGRAM + 1];
    let ends = socket.peer_addr().ok().zip(socket.local_addr().ok());
    while !shared.shutdown.load(Ordering::Relaxed) {
        match socket.recv(&mut buf) {
            Ok(n) => {
                if let (Some(pcap), Some((from, to))) = (lock(&shared.pcap).as_ref(), ends) {
                    let _ = pcap.record(from, to, &buf[..n]);
                }
                shared.deliver(&buf[..n])
            }
            // The poll timeout: check for shutdown.
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) => {}
            // ICMP "port unreachable": nothing listens on the controller's port (yet).
            // Waiters decide what it means; keep listening, without spinning.
            Err(e) if e.kind() == std::io::ErrorKind::ConnectionRefused => {
                shared.refused();
                std::thread::sleep(Duration::from_millis(1));
            }
            Err(_) => std::thread::sleep(Duration::from_millis(1)),
        }
    }
}

/// A registration for the ACKs of some seqs; removes them on drop (only those still its
/// own: after 256 frames a seq may have gone to another waiter, e.g. a STOPPED sent from
/// another thread during an upload).
pub(crate) struct AckWaiter<'a> {
    shared: &'a Shared,
    id: u64,
    seqs: Vec<u8>,
    tx: Sender<Event>,
    pub(crate) rx: Receiver<Event>,
}

impl AckWaiter<'_> {
    pub(crate) fn expect(&mut self, seq: u8) {
        lock(&self.shared.waiters).insert(seq, (self.id, self.tx.clone()));
        self.seqs.push(seq);
    }
}

impl Drop for AckWaiter<'_> {
    fn drop(&mut self) {
        let mut waiters = lock(&self.shared.waiters);
        for seq in &self.seqs {
            if waiters.get(seq).is_some_and(|(id, _)| *id == self.id) {
                waiters.remove(seq);
            }
        }
    }
}
