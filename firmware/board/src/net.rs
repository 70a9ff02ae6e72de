//! Ethernet (LAN8742A PHY over RMII) and the embassy-net stack.
//!
//! The MAC's descriptors and packet buffers ([`PacketQueue`], 62 KiB for a whole burst of
//! datagrams) are a `static` in SRAM1 (memory.x's `.sram1`, D2 domain): the Ethernet DMA
//! reaches it (never DTCM), and the AXI SRAM stays for the trajectory buffer, the tasks'
//! inbox and the UDP socket. The data cache is off, so no MPU region is needed.

use core::mem::MaybeUninit;
use core::sync::atomic::{AtomicBool, Ordering};
use embassy_stm32::eth::{Ethernet, GenericPhy, PacketQueue, Sma};
use embassy_stm32::peripherals::{ETH, ETH_SMA};

use embassy_stm32::{Peri, peripherals};

use arm_core::config::HOST_WINDOW;

use crate::Irqs;

/// The Ethernet driver as the stack sees it.
pub type Device = Ethernet<'static, ETH, GenericPhy<Sma<'static, ETH_SMA>>>;

/// Transmit descriptors: a burst of ACK + STATUS + LOCATION + USART_RECV fits without
/// waiting for the MAC; a burst of 40 ACKs (11 bytes each, 1.3 us on the wire at
/// 100 Mbit/s) waits for the MAC for microseconds, which costs nothing.
const TX_PACKETS: usize = 4;
/// Receive descriptors: a whole burst. A host's window is [`HOST_WINDOW`] = 32 datagrams
/// of up to 1472 bytes sent back to back (32 x 123 us = 3.9 ms at 100 Mbit/s), plus 8 for
/// other tools' commands, ARP and the like arriving meanwhile: 40. Each descriptor owns a
/// 1536-byte buffer (embassy-stm32's `RX_BUFFER_SIZE`), so the ring costs
/// 40 x (1536 + 16) = 62,080 bytes (in SRAM1). Sized so that nothing is dropped even if
/// the stack's runner does not get to run during the whole burst (smoltcp and the MAC drop
/// silently; the host would only see a missing ACK).
const RX_PACKETS: usize = HOST_WINDOW + 8;

/// The pins and peripherals the Ethernet uses on the NUCLEO-H743ZI2 (UM2407 table 11:
/// default solder bridges). No other driver may use these.
pub struct EthernetPins {
    /// The MAC.
    pub eth: Peri<'static, ETH>,
    /// Its management interface.
    pub sma: Peri<'static, ETH_SMA>,
    /// RMII_REF_CLK (50 MHz from the PHY).
    pub ref_clk: Peri<'static, peripherals::PA1>,
    /// RMII_CRS_DV.
    pub crs_dv: Peri<'static, peripherals::PA7>,
    /// RMII_RXD0.
    pub rx_d0: Peri<'static, peripherals::PC4>,
    /// RMII_RXD1.
    pub rx_d1: Peri<'static, peripherals::PC5>,
    /// RMII_TXD0.
    pub tx_d0: Peri<'static, peripherals::PG13>,
    /// RMII_TXD1.
    pub tx_d1: Peri<'static, peripherals::PB13>,
    /// RMII_TX_EN.
    pub tx_en: Peri<'static, peripherals::PG11>,
    /// RMII_MDIO.
    pub mdio: Peri<'static, peripherals::PA2>,
    /// RMII_MDC.
    pub mdc: Peri<'static, peripherals::PC1>,
}

/// A locally administered unicast MAC address derived from the chip's 96-bit unique ID, so
/// that two boards on one network never collide.
pub fn mac_address() -> [u8; 6] {
    let uid = embassy_stm32::uid::uid();
    let mut mac = [0x02, 0, 0, 0, 0, 0];
    // Fold the 12 ID bytes into 5: wafer position, wafer number and lot all vary.
    for (i, byte) in uid.iter().enumerate() {
        mac[1 + i % 5] ^= byte;
    }
    mac
}

/// The MAC's descriptor rings and buffers, in SRAM1 (a NOLOAD section: neither zeroed nor
/// initialised at boot; [`device`] initialises it in place, once).
#[unsafe(link_section = ".sram1")]
static mut PACKETS: MaybeUninit<PacketQueue<TX_PACKETS, RX_PACKETS>> = MaybeUninit::uninit();
/// [`PACKETS`] was handed out (in `.bss`: zeroed at boot, unlike SRAM1).
static PACKETS_TAKEN: AtomicBool = AtomicBool::new(false);

/// Brings up the MAC and PHY; the driver for the stack (arm-wiring creates the stack, with
/// the address from `arm_wiring::net::ip_config`). Call once.
pub fn device(pins: EthernetPins) -> Device {
    if PACKETS_TAKEN.swap(true, Ordering::AcqRel) {
        defmt::panic!("net::device called twice"); // safe: boot-time bring-up
    }
    // SRAM1 is clocked for the CPU (and so follows its run mode) only with SRAM1EN set
    // (RM0433, RCC_AHB2ENR); set it before the first access.
    embassy_stm32::pac::RCC
        .ahb2enr()
        .modify(|w| w.set_sram1en(true));
    let packets = &raw mut PACKETS;
    // SAFETY: the only reference to PACKETS ever made (guarded by PACKETS_TAKEN above).
    let packets = unsafe { &mut *packets };
    // 62 KiB: initialised in place (zeroed), never built on the stack first.
    PacketQueue::init(packets);
    // SAFETY: `PacketQueue::init` just initialised it (all zeros is its initial state).
    let packets = unsafe { packets.assume_init_mut() };
    Ethernet::new(
        packets,
        pins.eth,
        Irqs,
        pins.ref_clk,
        pins.crs_dv,
        pins.rx_d0,
        pins.rx_d1,
        pins.tx_d0,
        pins.tx_d1,
        pins.tx_en,
        mac_address(),
        pins.sma,
        pins.mdio,
        pins.mdc,
    )
}
