//! The network side both boards share: the embassy-net stack's resources, the controller's
//! UDP socket and its buffers (zeroed statics, `.bss`), the address configuration and the
//! link watch. The Ethernet driver is the board's.

use arm_core::Bus;
use arm_core::hw::PersistentSettings;
use embassy_net::udp::{PacketMetadata, UdpSocket};
#[cfg(not(feature = "dhcp"))]
use embassy_net::{Ipv4Address, Ipv4Cidr, StaticConfigV4};
use embassy_net::{Stack, StackResources};
use protocol::{MAX_DATAGRAM, PORT};
use static_cell::{ConstStaticCell, StaticCell};

/// Sockets in the stack: the controller's UDP socket, plus DHCP's when enabled.
const SOCKETS: usize = 2;

/// Datagrams the socket's receive side queues: a host's whole window
/// ([`arm_core::config::HOST_WINDOW`] = 32, sent back to back) plus 8 for other tools'
/// commands, the same 40 as the board's Ethernet ring and arm-core's inbox
/// ([`arm_core::bus::INBOX_QUEUE`]), so no stage drops a burst the next one could take.
const UDP_RX_PACKETS: usize = arm_core::bus::INBOX_QUEUE;
/// Receive buffer: 40 full-size datagrams, plus one more because smoltcp's packet ring
/// never splits a datagram across its end (up to one datagram's bytes can sit unused
/// there): 41 x 1472 = 60,352 bytes.
const UDP_RX_BYTES: usize = (UDP_RX_PACKETS + 1) * MAX_DATAGRAM;
/// Datagrams the socket's send side queues: ACKs are small (11 bytes) and the network task
/// waits when this is full (it never drops); 16 keep the MAC busy.
const UDP_TX_PACKETS: usize = 16;
/// Transmit buffer: arm-core's outbox holds 16 frames of at most 260 bytes (USART_RECV):
/// 16 x 260 = 4160 bytes.
const UDP_TX_BYTES: usize = 16 * 260;

/// The UDP socket's buffers: zeroed statics (`.bss`), taken once by [`bind_socket`]. The
/// metadata is filled at run time: `PacketMetadata::EMPTY` has non-zero bytes, which a
/// `const` initialiser would store in flash.
static UDP_RX_META: StaticCell<[PacketMetadata; UDP_RX_PACKETS]> = StaticCell::new();
static UDP_RX: ConstStaticCell<[u8; UDP_RX_BYTES]> = ConstStaticCell::new([0; UDP_RX_BYTES]);
static UDP_TX_META: StaticCell<[PacketMetadata; UDP_TX_PACKETS]> = StaticCell::new();
static UDP_TX: ConstStaticCell<[u8; UDP_TX_BYTES]> = ConstStaticCell::new([0; UDP_TX_BYTES]);

/// The stack's address configuration from the stored settings (PROTOCOL.md, "Finding
/// controllers and setting their address"): the static address `ip`/`prefix_len`, and the
/// stored gateway (none when 0.0.0.0; with one, the board also answers hosts beyond its
/// subnet). A stored DHCP choice (NET_SET `--dhcp`) needs the `dhcp` build: this one logs
/// that and keeps the static address, which NET_SET stores alongside for that fallback.
#[cfg(not(feature = "dhcp"))]
pub fn ip_config(settings: &PersistentSettings) -> embassy_net::Config {
    if settings.dhcp {
        warn!("settings: DHCP stored, but this firmware is built without DHCP: static address");
    }
    let [a, b, c, d] = settings.ip;
    let [g0, g1, g2, g3] = settings.gateway;
    let gateway = (settings.gateway != [0; 4]).then(|| Ipv4Address::new(g0, g1, g2, g3));
    embassy_net::Config::ipv4_static(StaticConfigV4 {
        address: Ipv4Cidr::new(Ipv4Address::new(a, b, c, d), settings.prefix_len),
        dns_servers: heapless::Vec::new(),
        gateway,
    })
}

/// The stack's address configuration: an address (and gateway) from a DHCP server, whatever
/// the stored settings say (the `dhcp` build is DHCP-only).
#[cfg(feature = "dhcp")]
pub fn ip_config(_settings: &PersistentSettings) -> embassy_net::Config {
    embassy_net::Config::dhcpv4(Default::default())
}

/// Creates the stack on `device` with its resources in a static. Call once (the
/// `spawn_controller` of [`crate::controller_tasks!`] does).
pub fn new_stack<D: embassy_net::driver::Driver>(
    device: D,
    config: embassy_net::Config,
    seed: u64,
) -> (Stack<'static>, embassy_net::Runner<'static, D>) {
    static RESOURCES: StaticCell<StackResources<SOCKETS>> = StaticCell::new();
    embassy_net::new(device, config, RESOURCES.init(StackResources::new()), seed)
}

/// The controller's socket, bound to [`PORT`]. Call once.
pub fn bind_socket(stack: Stack<'static>) -> UdpSocket<'static> {
    let mut socket = UdpSocket::new(
        stack,
        UDP_RX_META.init([PacketMetadata::EMPTY; UDP_RX_PACKETS]),
        UDP_RX.take(),
        UDP_TX_META.init([PacketMetadata::EMPTY; UDP_TX_PACKETS]),
        UDP_TX.take(),
    );
    if let Err(e) = socket.bind(PORT) {
        // Only possible with port 0 or a second bind; both are programming errors.
        // With defmt, its panic: core's would link core::fmt into the image.
        #[cfg(feature = "defmt")]
        defmt::panic!("udp bind: {}", e); // safe: boot-time bring-up
        #[cfg(not(feature = "defmt"))]
        panic!("udp bind: {:?}", e); // safe: boot-time bring-up
    }
    socket
}

/// Logs the address once configured, then every link change, forever: a person watching
/// the log sees why the controller went silent.
///
/// Link loss changes nothing in the controller (the policy `firmware/board-logic`'s `net`
/// module documents): a run keeps executing what is buffered and the underrun rule stops
/// it, so the log names the state the link went down in.
pub async fn watch_link(stack: Stack<'static>, bus: &Bus) -> ! {
    stack.wait_link_up().await;
    stack.wait_config_up().await;
    if let Some(config) = stack.config_v4() {
        // Octets, not the address type's Display: with defmt that would link core::fmt.
        let [a, b, c, d] = config.address.address().octets();
        info!(
            "listening on {}.{}.{}.{}/{}:{}",
            a,
            b,
            c,
            d,
            config.address.prefix_len(),
            PORT
        );
    }
    loop {
        stack.wait_link_down().await;
        warn!(
            "ethernet link down in state {:?}: a run keeps executing what is buffered",
            bus.report_settings().state
        );
        stack.wait_link_up().await;
        info!("ethernet link up");
    }
}
