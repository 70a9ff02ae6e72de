//! The network side both boards share: the embassy-net stack's resources, the controller's
//! UDP socket and its buffers (zeroed statics, `.bss`), the address configuration and the
//! link watch. The Ethernet driver is the board's.

use arm_core::Bus;
use embassy_net::udp::{PacketMetadata, UdpSocket};
#[cfg(not(feature = "dhcp"))]
use embassy_net::{Ipv4Address, Ipv4Cidr, StaticConfigV4};
use embassy_net::{Stack, StackResources};
use protocol::{MAX_DATAGRAM, PORT};
use static_cell::{ConstStaticCell, StaticCell};

/// Sockets in the stack: the controller's UDP socket, plus DHCP's when enabled.
const SOCKETS: usize = 2;

/// Datagrams the socket queues in each direction.
const UDP_PACKETS: usize = 8;
/// Receive buffer: a host keeps a window of PENDING frames (up to 1395 bytes each; armctl
/// sends 4) in flight; four full-size datagrams cover it while the stack waits for the
/// network task.
const UDP_RX_BYTES: usize = 4 * MAX_DATAGRAM;
/// Transmit buffer: arm-core's outbox holds 16 frames of at most 260 bytes (USART_RECV);
/// 4 KiB takes a whole outbox burst.
const UDP_TX_BYTES: usize = 4096;

/// The UDP socket's buffers: zeroed statics (`.bss`), taken once by [`bind_socket`]. The
/// metadata is filled at run time: `PacketMetadata::EMPTY` has non-zero bytes, which a
/// `const` initialiser would store in flash.
static UDP_RX_META: StaticCell<[PacketMetadata; UDP_PACKETS]> = StaticCell::new();
static UDP_RX: ConstStaticCell<[u8; UDP_RX_BYTES]> = ConstStaticCell::new([0; UDP_RX_BYTES]);
static UDP_TX_META: StaticCell<[PacketMetadata; UDP_PACKETS]> = StaticCell::new();
static UDP_TX: ConstStaticCell<[u8; UDP_TX_BYTES]> = ConstStaticCell::new([0; UDP_TX_BYTES]);

/// The stack's address configuration: the static address `ip`/`prefix_len`, no gateway
/// (replies go to hosts on the same subnet, as the protocol expects).
#[cfg(not(feature = "dhcp"))]
pub fn ip_config(ip: [u8; 4], prefix_len: u8) -> embassy_net::Config {
    let [a, b, c, d] = ip;
    embassy_net::Config::ipv4_static(StaticConfigV4 {
        address: Ipv4Cidr::new(Ipv4Address::new(a, b, c, d), prefix_len),
        dns_servers: heapless::Vec::new(),
        gateway: None,
    })
}

/// The stack's address configuration: an address from a DHCP server (the persisted static
/// address is not used in this build).
#[cfg(feature = "dhcp")]
pub fn ip_config(_ip: [u8; 4], _prefix_len: u8) -> embassy_net::Config {
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
        UDP_RX_META.init([PacketMetadata::EMPTY; UDP_PACKETS]),
        UDP_RX.take(),
        UDP_TX_META.init([PacketMetadata::EMPTY; UDP_PACKETS]),
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
