//! The controller's socket as the simulator gives it: a host UDP socket or embassy-net on a
//! TAP device, with every datagram logged (decoded for the log only) and written to the
//! `--pcap` capture.

use std::io;
use std::net::SocketAddr;
use std::sync::atomic::Ordering;

use arm_core::hw::{Datagrams, Endpoint};

use crate::net::UdpDatagrams;
use crate::tap::{TapDatagrams, TapError};

/// The network the controller's socket is on.
#[derive(Debug)]
pub enum SimNet {
    /// A host UDP socket.
    Udp(&'static UdpDatagrams),
    /// embassy-net on a TAP device.
    Tap(&'static TapDatagrams),
}

/// Errors of [`SimNet`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SimNetError {
    /// Host socket.
    Udp(io::ErrorKind),
    /// embassy-net.
    Tap(TapError),
}

impl Datagrams for SimNet {
    type Error = SimNetError;

    async fn recv(&self, buf: &mut [u8]) -> Result<(usize, Endpoint), Self::Error> {
        let (n, from) = match self {
            SimNet::Udp(udp) => udp.recv(buf).await.map_err(SimNetError::Udp)?,
            SimNet::Tap(tap) => tap.recv(buf).await.map_err(SimNetError::Tap)?,
        };
        log_received(buf.get(..n).unwrap_or_default(), from);
        capture(from, false, buf.get(..n).unwrap_or_default());
        Ok((n, from))
    }

    async fn send(&self, to: Endpoint, frame: &[u8]) -> Result<(), Self::Error> {
        log_sent(frame, to);
        capture(to, true, frame);
        match self {
            SimNet::Udp(udp) => udp.send(to, frame).await.map_err(SimNetError::Udp),
            SimNet::Tap(tap) => tap.send(to, frame).await.map_err(SimNetError::Tap),
        }
    }
}

/// The `--pcap` capture and the controller's own address in it.
struct Capture {
    log: armctl::pcap::PcapLog,
    local: std::net::SocketAddrV4,
}

/// Set once, when the board is built with `--pcap`.
static CAPTURE: std::sync::OnceLock<Capture> = std::sync::OnceLock::new();

/// Opens the `--pcap` capture; `local` is the controller's address in it.
pub(crate) fn open_capture(
    path: &std::path::Path,
    local: std::net::SocketAddrV4,
) -> io::Result<()> {
    let log = armctl::pcap::PcapLog::create(path)
        .map_err(|e| io::Error::new(e.kind(), format!("--pcap {}: {e}", path.display())))?;
    CAPTURE
        .set(Capture { log, local })
        .map_err(|_| io::Error::other("--pcap: one capture per process"))?;
    log::info!("pcap: writing {}", path.display());
    Ok(())
}

/// Appends a datagram to the `--pcap` capture, if any: one sent to `peer` (`outgoing`) or
/// received from it.
fn capture(peer: Endpoint, outgoing: bool, bytes: &[u8]) {
    if let Some(capture) = CAPTURE.get() {
        let peer = SocketAddr::V4(show(peer));
        let local = SocketAddr::V4(capture.local);
        let (from, to) = if outgoing {
            (local, peer)
        } else {
            (peer, local)
        };
        if let Err(e) = capture.log.record(from, to, bytes) {
            log::warn!("pcap: {e}");
        }
    }
}

fn show(endpoint: Endpoint) -> std::net::SocketAddrV4 {
    crate::net::socket_addr_of(endpoint)
}

/// Debug log of every datagram received (decoded for the log only: the controller
/// decodes it again, its own way).
fn log_received(bytes: &[u8], from: Endpoint) {
    if !log::log_enabled!(log::Level::Debug) {
        return;
    }
    match protocol::Command::decode(bytes) {
        Ok(frame) => log::debug!(
            "<- {} seq {} {}",
            show(from),
            frame.seq,
            frame.body.tag().name()
        ),
        Err(e) => log::debug!("<- {} {} bytes: {e:?}", show(from), bytes.len()),
    }
}

/// Refusals logged at info level: a host resending a refused frame in a loop must not
/// write a line per datagram (the first of each second, with the count of the others).
static REFUSALS_LOGGED: std::sync::Mutex<arm_core::LogLimit> =
    std::sync::Mutex::new(arm_core::LogLimit::new());

/// Microseconds of wall-clock time since the first call (for the log limits).
pub(crate) fn log_time_us() -> u64 {
    static START: std::sync::OnceLock<std::time::Instant> = std::sync::OnceLock::new();
    START
        .get_or_init(std::time::Instant::now)
        .elapsed()
        .as_micros() as u64
}

/// The state an ACK tells, for the log of state changes: none for NOT_OWNER and BAD_CRC,
/// whose state is 0 to a stranger whatever the arm does (issue 21 F11: a refused flood
/// logged "state RUNNING -> NEW" and back for every datagram, 255 lines a second, outside
/// the refusals' rate limit).
fn reported_state(ack: &protocol::Ack) -> Option<u8> {
    match ack.status {
        protocol::StatusCode::NotOwner | protocol::StatusCode::BadCrc => None,
        _ => Some(ack.state as u8),
    }
}

/// The state the controller last reported, for logging its changes.
static REPORTED_STATE: std::sync::atomic::AtomicU8 = std::sync::atomic::AtomicU8::new(u8::MAX);

/// Logs state changes (info), refusals and ACKs (debug) as the controller reports them.
fn log_sent(frame: &[u8], to: Endpoint) {
    let Ok(report) = protocol::Report::decode(frame) else {
        return;
    };
    let state = match report.body {
        protocol::Report::Ack(ack) => {
            let command = protocol::Tag::name_of(ack.acked_tag);
            if ack.status == protocol::StatusCode::Ok {
                log::debug!("-> {} ACK seq {} {command}: OK", show(to), report.seq);
            } else {
                let verdict = REFUSALS_LOGGED
                    .lock()
                    .map(|mut l| l.event(log_time_us()))
                    .unwrap_or(arm_core::LogVerdict::Silent);
                match verdict {
                    arm_core::LogVerdict::Log { suppressed } => log::info!(
                        "-> {} {command} (seq {}) refused: {} ({suppressed} more refusals \
                         since the last such line)",
                        show(to),
                        report.seq,
                        ack.status.name()
                    ),
                    arm_core::LogVerdict::Silent => log::debug!(
                        "-> {} {command} (seq {}) refused: {}",
                        show(to),
                        report.seq,
                        ack.status.name()
                    ),
                }
            }
            reported_state(&ack)
        }
        protocol::Report::Location(location) => Some(location.state),
        protocol::Report::Status(status) => Some(status.state as u8),
        protocol::Report::UsartRecv(bytes) => {
            log::debug!("-> {} USART_RECV {} bytes", show(to), bytes.len());
            None
        }
        protocol::Report::JointDesc(d) => {
            log::debug!("-> {} JOINT_DESC joint {}", show(to), d.joint);
            None
        }
        protocol::Report::Limits(_) => {
            log::debug!("-> {} LIMITS", show(to));
            None
        }
        protocol::Report::StopCause(stop) => {
            log::debug!("-> {} STOP_CAUSE {:?}", show(to), stop.cause);
            None
        }
        protocol::Report::RxCounters(_) => {
            log::debug!("-> {} RX_COUNTERS", show(to));
            None
        }
        protocol::Report::Diag(_) => {
            log::debug!("-> {} DIAG", show(to));
            None
        }
        protocol::Report::Motion(m) => {
            log::debug!(
                "-> {} MOTION {} % flags {:#04x}",
                show(to),
                m.factor_percent,
                m.flags.0
            );
            None
        }
    };
    if let Some(state) = state {
        let before = REPORTED_STATE.swap(state, Ordering::Relaxed);
        if before != state && before != u8::MAX {
            let name = protocol::State::name_of;
            log::info!("state {} -> {}", name(before), name(state));
        }
    }
}

#[cfg(test)]
mod log_tests {
    use protocol::{Ack, State, StatusCode};

    use super::reported_state;

    fn ack(status: StatusCode, state: State) -> Ack {
        Ack {
            acked_tag: 0,
            status,
            state,
            next_seq: 0,
            buffered: 0,
            free: 0,
        }
    }

    #[test]
    fn refusals_to_strangers_tell_no_state_to_the_log() {
        assert_eq!(reported_state(&ack(StatusCode::NotOwner, State::New)), None);
        assert_eq!(reported_state(&ack(StatusCode::BadCrc, State::New)), None);
        assert_eq!(
            reported_state(&ack(StatusCode::Ok, State::Running)),
            Some(State::Running as u8)
        );
        assert_eq!(
            reported_state(&ack(StatusCode::BadState, State::Pending)),
            Some(State::Pending as u8)
        );
    }
}
