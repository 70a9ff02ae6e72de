//! The small hardware adapters every board uses: time from embassy-time, the UDP socket
//! from embassy-net, and the (absent) encoders.

use arm_core::hw::{Clock, Datagrams, Encoders, Endpoint};
use embassy_futures::select::{Either, select};
use embassy_net::udp::{RecvError, SendError, UdpSocket};
use embassy_net::{IpAddress, IpEndpoint, Ipv4Address};
use embassy_time::{Instant, Timer};

/// While no datagram arrives, a receive wakes its task this often: each wake-up polls the
/// network task's future, whose heartbeat a board's watchdog checks (the NUCLEO's
/// `liveness` wrappers in `firmware/board/src/main.rs`).
const RECEIVE_HEARTBEAT_MS: u64 = 100;

/// [`Clock`] on embassy-time (the board's time driver; microseconds exactly when it ticks
/// at 1 MHz).
#[derive(Clone, Copy, Default)]
pub struct EmbassyClock;

impl Clock for EmbassyClock {
    fn now_us(&self) -> u64 {
        Instant::now().as_micros()
    }

    async fn sleep_until(&self, at_us: u64) {
        Timer::at(Instant::from_micros(at_us)).await
    }
}

/// Why a datagram could not be received or sent (logged by the network task).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DatagramError {
    /// Receiving failed (a datagram longer than the buffer: dropped).
    Recv(RecvError),
    /// Sending failed (no route, no buffer space, not yet configured).
    Send(SendError),
}

/// [`Datagrams`] on the controller's bound embassy-net UDP socket.
pub struct NetSocket {
    socket: UdpSocket<'static>,
}

impl NetSocket {
    /// Wraps a socket already bound to the controller's port.
    pub fn new(socket: UdpSocket<'static>) -> Self {
        NetSocket { socket }
    }
}

/// The IPv4 part of an embassy-net endpoint.
fn to_endpoint(endpoint: IpEndpoint) -> Endpoint {
    // The stack is built with IPv4 only; enabling IPv6 makes this a compile error to fix.
    let IpAddress::Ipv4(ip) = endpoint.addr;
    Endpoint {
        ip: ip.octets(),
        port: endpoint.port,
    }
}

impl Datagrams for NetSocket {
    type Error = DatagramError;

    async fn recv(&self, buf: &mut [u8]) -> Result<(usize, Endpoint), Self::Error> {
        loop {
            // recv_from is cancel-safe (a poll of the socket's queue): nothing is lost when
            // the heartbeat timer wins.
            match select(
                self.socket.recv_from(buf),
                Timer::after_millis(RECEIVE_HEARTBEAT_MS),
            )
            .await
            {
                Either::First(Ok((len, meta))) => return Ok((len, to_endpoint(meta.endpoint))),
                Either::First(Err(e)) => return Err(DatagramError::Recv(e)),
                Either::Second(()) => {}
            }
        }
    }

    async fn send(&self, to: Endpoint, frame: &[u8]) -> Result<(), Self::Error> {
        let [a, b, c, d] = to.ip;
        let remote = IpEndpoint::new(IpAddress::Ipv4(Ipv4Address::new(a, b, c, d)), to.port);
        self.socket
            .send_to(frame, remote)
            .await
            .map_err(DatagramError::Send)
    }
}

/// A board without absolute encoders: RETURN trusts the step count.
#[derive(Clone, Copy, Default)]
pub struct NoEncoders;

impl Encoders for NoEncoders {
    async fn read(&mut self) -> Option<[i32; protocol::MAX_JOINTS]> {
        None
    }
}
