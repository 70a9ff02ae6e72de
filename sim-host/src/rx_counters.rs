//! Reads a controller's receive-path counters from outside: a look-only STATUS whose
//! request byte asks for the RX_COUNTERS report (docs/PROTOCOL.md, STATUS's request byte
//! bit 3; issue 30). `sim-host flood` prints them after each rate, so the frames a board's
//! MAC dropped with its ring full are seen beside the e-stop figures.

use std::net::{Ipv4Addr, SocketAddr, UdpSocket};
use std::time::{Duration, Instant};

use protocol::{Command, Report, RxCounters, StatusAsk};

/// Tries before giving up (a read-only answer may be refused by its budget, or lost).
const TRIES: u32 = 3;
/// How long each try waits for the report.
const WAIT: Duration = Duration::from_millis(500);

/// The controller's counters, asked from `from` (an address of this machine; the answer
/// is read-only, so it takes nothing); `None` if it does not answer with them (an older
/// controller refuses the request byte; a keyed one wants an envelope).
pub fn read(controller: SocketAddr, from: Ipv4Addr) -> Option<RxCounters> {
    let socket = UdpSocket::bind((from, 0)).ok()?;
    socket.set_read_timeout(Some(WAIT / 5)).ok()?;
    let ask = StatusAsk {
        location: false,
        look_only: true,
        stop_cause: false,
        counters: true,
        diag: false,
        motion: false,
    };
    let mut request = [0u8; 8];
    let mut reply = [0u8; protocol::MAX_DATAGRAM];
    for seq in 0..TRIES {
        let seq = 0x70 + u8::try_from(seq).unwrap_or(0);
        let n = Command::StatusWith(ask).encode(seq, &mut request).ok()?;
        socket.send_to(&request[..n], controller).ok()?;
        let deadline = Instant::now() + WAIT;
        while Instant::now() < deadline {
            let Ok((n, _)) = socket.recv_from(&mut reply) else {
                continue;
            };
            if let Ok(frame) = Report::decode(reply.get(..n).unwrap_or_default())
                && let Report::RxCounters(c) = frame.body
            {
                return Some(c);
            }
        }
    }
    None
}

/// One line of counters for `sim-host flood`.
pub fn line(counters: Option<RxCounters>) -> String {
    match counters {
        Some(c) => format!(
            "receive path (since boot): ring dropped {}, ring full {}, STOPPEDs halted in the receive interrupt {}, shed {}, inbox dropped {}",
            c.ring_dropped, c.ring_full, c.interrupt_stops, c.shed, c.inbox_dropped
        ),
        None => {
            "receive path: no RX_COUNTERS (a controller older than issue 30, or keyed)".to_string()
        }
    }
}
