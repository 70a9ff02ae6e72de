//! The arm controller firmware for the NUCLEO-H743ZI2 (STM32H743ZI, Cortex-M7 at 400 MHz).
//!
//! The controller speaks the UDP protocol of `docs/PROTOCOL.md` on port 8510 over the
//! board's Ethernet (LAN8742A PHY, RMII), at the persisted static address (192.168.1.30/24
//! by default) or from DHCP with the `dhcp` feature.
//!
//! # Design
//!
//! Work is split by how late it may be:
//!
//! - The step timer interrupt (TIM2, 32-bit, 200 MHz, highest priority) raises and lowers
//!   the STEP lines at the step engine's deadlines. Nothing else may delay it, so nothing
//!   else runs at its priority and it never waits for anything.
//! - Everything else is async tasks on the thread-mode executor: the network stack's
//!   runner, and the task that reads datagrams, decodes them with the `protocol` crate and
//!   answers. Network input is decoded into typed commands and every error becomes an ACK
//!   status; it can never panic or block the step interrupt.
//!
//! Peripherals the tasks own live in `StaticCell`s, initialised once in `main`; every task
//! gets `'static` references or owned drivers, so no task borrows from `main`'s stack.
//!
//! # Stage
//!
//! This is the networking skeleton: STATUS is answered with an ACK and a STATUS report, every
//! other frame with a valid CRC with an ACK whose status says why it was not executed.

#![no_std]
#![no_main]

mod clocks;
mod net;

use defmt::{info, warn};
use embassy_executor::Spawner;
use embassy_net::Stack;
use embassy_net::udp::{PacketMetadata, UdpSocket};
use embassy_stm32::rng::Rng;
use embassy_stm32::{bind_interrupts, eth, peripherals, rng};
use protocol::{
    Ack, Command, MAX_DATAGRAM, PORT, Report, State, StatusCode, StatusFlags, StatusReport,
};
use static_cell::StaticCell;
use {defmt_rtt as _, panic_probe as _};

bind_interrupts!(
    /// Interrupt handlers of the embassy drivers.
    pub struct Irqs {
        ETH => eth::InterruptHandler;
        RNG => rng::InterruptHandler<peripherals::RNG>;
    }
);

/// The controller's address until persisted settings are read (PROTOCOL.md section 1).
const DEFAULT_IP: [u8; 4] = [192, 168, 1, 30];
/// Prefix length of [`DEFAULT_IP`]'s subnet.
const DEFAULT_PREFIX_LEN: u8 = 24;
/// Joints reported until persisted settings are read.
const DEFAULT_JOINTS: u8 = protocol::limits::DEFAULT_JOINTS;

/// Datagrams the socket queues in each direction.
const UDP_PACKETS: usize = 8;
/// Receive buffer: a host streams PENDING frames (up to 1395 bytes) ahead of the ACKs, and
/// four full-size datagrams cover a burst while the task is answering the previous one.
const UDP_RX_BYTES: usize = 4 * MAX_DATAGRAM;
/// Transmit buffer: an ACK, a STATUS report, a LOCATION report and a full USART_RECV report
/// (260 bytes) together take well under two full datagrams.
const UDP_TX_BYTES: usize = 2 * MAX_DATAGRAM;

/// The UDP socket's buffers, in one static so that the socket can be `'static`.
struct UdpBuffers {
    rx_meta: [PacketMetadata; UDP_PACKETS],
    rx: [u8; UDP_RX_BYTES],
    tx_meta: [PacketMetadata; UDP_PACKETS],
    tx: [u8; UDP_TX_BYTES],
}

static UDP_BUFFERS: StaticCell<UdpBuffers> = StaticCell::new();

#[embassy_executor::task]
async fn net_task(mut runner: net::Runner) -> ! {
    runner.run().await
}

#[embassy_executor::task]
async fn command_task(socket: UdpSocket<'static>) -> ! {
    let mut datagram = [0u8; MAX_DATAGRAM];
    let mut reply = [0u8; MAX_DATAGRAM];
    // The seq of the controller's own reports (PROTOCOL.md section 4).
    let mut report_seq: u8 = 0;
    loop {
        let (len, meta) = match socket.recv_from(&mut datagram).await {
            Ok(received) => received,
            Err(e) => {
                warn!("udp receive: {}", e);
                continue;
            }
        };
        let Some(bytes) = datagram.get(..len) else {
            continue;
        };
        let (seq, tag, status, wants_status) = match Command::decode(bytes) {
            Ok(frame) => {
                let tag = frame.body.tag() as u8;
                match frame.body {
                    Command::Status => (frame.seq, tag, StatusCode::Ok, true),
                    // Not executed at this stage: say so rather than claim success.
                    _ => (frame.seq, tag, StatusCode::Unsupported, false),
                }
            }
            Err(e) => match e.status() {
                Some(status) => (e.seq, e.tag, status, false),
                None => continue,
            },
        };
        let ack = Report::Ack(Ack {
            acked_tag: tag,
            status,
            state: State::Stopped,
            next_seq: 0,
            buffered: 0,
            free: 0,
        });
        send(&socket, &ack, seq, &mut reply, meta.endpoint).await;
        if wants_status {
            let status = Report::Status(skeleton_status());
            send(&socket, &status, report_seq, &mut reply, meta.endpoint).await;
            report_seq = report_seq.wrapping_add(1);
        }
    }
}

/// Encodes `report` and sends it; failures are logged and dropped (the host retries).
async fn send(
    socket: &UdpSocket<'static>,
    report: &Report<'_>,
    seq: u8,
    buf: &mut [u8],
    to: embassy_net::IpEndpoint,
) {
    match report.encode(seq, buf) {
        Ok(n) => {
            if let Err(e) = socket.send_to(buf.get(..n).unwrap_or(&[]), to).await {
                warn!("udp send: {}", e);
            }
        }
        Err(e) => warn!("encode: {}", e),
    }
}

/// The STATUS report of the skeleton: idle, no trajectory buffer yet.
fn skeleton_status() -> StatusReport {
    StatusReport {
        version: protocol::VERSION,
        joints: DEFAULT_JOINTS,
        state: State::Stopped,
        flags: StatusFlags::default(),
        upload_period_us: protocol::limits::DEFAULT_UPLOAD_PERIOD_US,
        pwm_timer_clock_hz: embassy_stm32::rcc::frequency::<peripherals::TIM1>().0,
        ..StatusReport::default()
    }
}

#[embassy_executor::main]
async fn main(spawner: Spawner) -> ! {
    let p = embassy_stm32::init(clocks::config());
    info!("arm controller starting");

    // The TCP/IP stack wants a random seed (initial sequence numbers, DHCP transaction IDs).
    let mut rng = Rng::new(p.RNG, Irqs);
    let seed = rng.next_u64();

    let pins = net::EthernetPins {
        eth: p.ETH,
        sma: p.ETH_SMA,
        ref_clk: p.PA1,
        crs_dv: p.PA7,
        rx_d0: p.PC4,
        rx_d1: p.PC5,
        tx_d0: p.PG13,
        tx_d1: p.PB13,
        tx_en: p.PG11,
        mdio: p.PA2,
        mdc: p.PC1,
    };
    let (stack, runner) = net::init(pins, net::ip_config(DEFAULT_IP, DEFAULT_PREFIX_LEN), seed);
    spawner.spawn(defmt::unwrap!(net_task(runner)));

    let buffers = UDP_BUFFERS.init(UdpBuffers {
        rx_meta: [PacketMetadata::EMPTY; UDP_PACKETS],
        rx: [0; UDP_RX_BYTES],
        tx_meta: [PacketMetadata::EMPTY; UDP_PACKETS],
        tx: [0; UDP_TX_BYTES],
    });
    let socket = bind_socket(stack, buffers);
    spawner.spawn(defmt::unwrap!(command_task(socket)));

    stack.wait_config_up().await;
    if let Some(config) = stack.config_v4() {
        info!("listening on {}:{}", config.address, PORT);
    }
    loop {
        // The link can drop and come back; log it so a person at the probe can see why the
        // controller went silent.
        stack.wait_link_down().await;
        warn!("ethernet link down");
        stack.wait_link_up().await;
        info!("ethernet link up");
    }
}

/// The controller's socket, bound to [`PORT`].
fn bind_socket(stack: Stack<'static>, buffers: &'static mut UdpBuffers) -> UdpSocket<'static> {
    let mut socket = UdpSocket::new(
        stack,
        &mut buffers.rx_meta,
        &mut buffers.rx,
        &mut buffers.tx_meta,
        &mut buffers.tx,
    );
    if let Err(e) = socket.bind(PORT) {
        // Only possible with port 0 or a second bind; both are programming errors.
        defmt::panic!("udp bind: {}", e);
    }
    socket
}
