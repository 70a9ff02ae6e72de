//! `--tap IFACE`: the controller's socket on embassy-net over a Linux TAP device, the same
//! network stack the board runs over its Ethernet MAC.

use std::net::Ipv4Addr;

use arm_core::Bus;
use arm_core::hw::{Datagrams, Endpoint};
use arm_core::ingress::GuardedDriver;

use crate::app::SimHalt;
use crate::clock::SimClock;
use embassy_executor::Spawner;
use embassy_net::udp::{PacketMetadata, RecvError, SendError, UdpSocket};
use embassy_net::{Config, IpAddress, IpEndpoint, Ipv4Cidr, StackResources, StaticConfigV4};
use embassy_net_tuntap::TunTapDevice;
use static_cell::StaticCell;

/// Sockets in the stack: the controller's UDP socket and DHCP's.
const SOCKETS: usize = 3;
/// Datagrams the socket's receive side queues: a host's whole window (32, back to back)
/// plus 8 for other tools' commands, as on the board ([`arm_core::bus::INBOX_QUEUE`]).
const RX_PACKETS: usize = arm_core::bus::INBOX_QUEUE;
/// Receive payload bytes: [`RX_PACKETS`] full-size datagrams, plus one because smoltcp's
/// packet ring never splits a datagram across its end.
const RX_PAYLOAD_BYTES: usize = (RX_PACKETS + 1) * protocol::MAX_DATAGRAM;
/// Datagrams queued to send (ACKs and reports are small; the network task waits when full).
const TX_PACKETS: usize = 16;
/// Payload bytes queued to send: [`TX_PACKETS`] full-size datagrams.
const TX_PAYLOAD_BYTES: usize = TX_PACKETS * protocol::MAX_DATAGRAM;

/// How the TAP interface gets its address.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TapAddress {
    /// Static address and prefix length.
    Static(Ipv4Addr, u8),
    /// From a DHCP server on the link.
    Dhcp,
}

impl TapAddress {
    /// Parses `a.b.c.d/len` or `dhcp`.
    pub fn parse(s: &str) -> Result<TapAddress, String> {
        if s.eq_ignore_ascii_case("dhcp") {
            return Ok(TapAddress::Dhcp);
        }
        let (ip, prefix) = s.split_once('/').unwrap_or((s, "24"));
        let ip: Ipv4Addr = ip.parse().map_err(|_| format!("bad address: {ip}"))?;
        let prefix: u8 = prefix
            .parse()
            .ok()
            .filter(|p| *p <= 32)
            .ok_or_else(|| format!("bad prefix length: {prefix}"))?;
        Ok(TapAddress::Static(ip, prefix))
    }
}

/// Why the TAP socket failed an operation.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TapError {
    /// Receive failed.
    Recv(RecvError),
    /// Send failed.
    Send(SendError),
}

/// [`Datagrams`] over embassy-net's UDP socket.
pub struct TapDatagrams {
    socket: UdpSocket<'static>,
}

impl std::fmt::Debug for TapDatagrams {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TapDatagrams").finish()
    }
}

/// The TAP device behind the controller's first look at each frame (issue 18): as the
/// board's Ethernet driver, a STOPPED halts the steps before embassy-net sees it.
pub type GuardedTap = GuardedDriver<'static, TunTapDevice, SimHalt, SimClock>;

#[embassy_executor::task]
async fn net_task(mut runner: embassy_net::Runner<'static, GuardedTap>) -> ! {
    runner.run().await
}

/// Opens `iface`, starts embassy-net on it, waits for its address and binds the
/// controller's port.
pub async fn start(
    spawner: Spawner,
    iface: &str,
    address: TapAddress,
    mac: [u8; 6],
    seed: u64,
    guard: (&'static Bus, SimHalt, &'static SimClock),
) -> Result<&'static TapDatagrams, String> {
    let mut device =
        TunTapDevice::new(iface).map_err(|e| format!("cannot open TAP {iface}: {e}"))?;
    // Its own MAC: several simulators on one bridge must not share one.
    device.set_hardware_address(mac);
    let (bus, halt, clock) = guard;
    let device = GuardedDriver::new(device, bus, halt, clock, protocol::PORT);
    let config = match address {
        TapAddress::Static(ip, prefix) => Config::ipv4_static(StaticConfigV4 {
            address: Ipv4Cidr::new(ip, prefix),
            dns_servers: heapless::Vec::new(),
            gateway: None,
        }),
        TapAddress::Dhcp => Config::dhcpv4(Default::default()),
    };
    static RESOURCES: StaticCell<StackResources<SOCKETS>> = StaticCell::new();
    let resources = RESOURCES
        .try_init(StackResources::new())
        .ok_or("the TAP stack can be started once")?;
    let (stack, runner) = embassy_net::new(device, config, resources, seed);
    let token = net_task(runner).map_err(|e| format!("cannot spawn the network stack: {e:?}"))?;
    spawner.spawn(token);
    log::info!("tap: {iface} up, waiting for an address ({address:?})");
    stack.wait_config_up().await;
    if let Some(v4) = stack.config_v4() {
        log::info!("tap: address {}", v4.address);
    }

    static RX_META: StaticCell<[PacketMetadata; RX_PACKETS]> = StaticCell::new();
    static TX_META: StaticCell<[PacketMetadata; TX_PACKETS]> = StaticCell::new();
    static RX_BUFFER: StaticCell<[u8; RX_PAYLOAD_BYTES]> = StaticCell::new();
    static TX_BUFFER: StaticCell<[u8; TX_PAYLOAD_BYTES]> = StaticCell::new();
    let mut socket = UdpSocket::new(
        stack,
        RX_META.init([PacketMetadata::EMPTY; RX_PACKETS]),
        RX_BUFFER.init([0; RX_PAYLOAD_BYTES]),
        TX_META.init([PacketMetadata::EMPTY; TX_PACKETS]),
        TX_BUFFER.init([0; TX_PAYLOAD_BYTES]),
    );
    socket
        .bind(protocol::PORT)
        .map_err(|e| format!("cannot bind UDP port {}: {e:?}", protocol::PORT))?;
    log::info!("tap: listening on UDP port {}", protocol::PORT);
    static SOCKET: StaticCell<TapDatagrams> = StaticCell::new();
    Ok(SOCKET.init(TapDatagrams { socket }))
}

impl Datagrams for TapDatagrams {
    type Error = TapError;

    async fn recv(&self, buf: &mut [u8]) -> Result<(usize, Endpoint), Self::Error> {
        loop {
            let (n, meta) = self.socket.recv_from(buf).await.map_err(TapError::Recv)?;
            // The controller speaks IPv4 only; anything else is not for it.
            #[allow(unreachable_patterns, irrefutable_let_patterns)]
            if let IpAddress::Ipv4(ip) = meta.endpoint.addr {
                let from = Endpoint {
                    ip: ip.octets(),
                    port: meta.endpoint.port,
                };
                return Ok((n, from));
            }
        }
    }

    async fn send(&self, to: Endpoint, frame: &[u8]) -> Result<(), Self::Error> {
        let endpoint = IpEndpoint::new(IpAddress::Ipv4(Ipv4Addr::from(to.ip)), to.port);
        self.socket
            .send_to(frame, endpoint)
            .await
            .map_err(TapError::Send)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn addresses_parse() {
        assert_eq!(
            TapAddress::parse("192.168.7.2/24"),
            Ok(TapAddress::Static(Ipv4Addr::new(192, 168, 7, 2), 24))
        );
        assert_eq!(TapAddress::parse("DHCP"), Ok(TapAddress::Dhcp));
        assert!(TapAddress::parse("192.168.7.2/40").is_err());
        assert!(TapAddress::parse("nonsense").is_err());
    }
}
