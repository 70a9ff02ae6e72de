//! Ethernet (LAN8742A PHY over RMII) and the embassy-net stack.
//!
//! The MAC's descriptors and packet buffers ([`PacketQueue`]) are a `static` in `.bss`, which
//! memory.x puts in AXI SRAM: the Ethernet DMA cannot reach DTCM.

use embassy_stm32::eth::{Ethernet, GenericPhy, PacketQueue, Sma};
use embassy_stm32::peripherals::{ETH, ETH_SMA};
use embassy_stm32::{Peri, peripherals};
use static_cell::StaticCell;

use crate::Irqs;

/// The Ethernet driver as the stack sees it.
pub type Device = Ethernet<'static, ETH, GenericPhy<Sma<'static, ETH_SMA>>>;

/// Transmit descriptors: a burst of ACK + STATUS + LOCATION + USART_RECV fits without
/// waiting for the MAC.
const TX_PACKETS: usize = 4;
/// Receive descriptors: a host streaming PENDING frames back to back (each up to 1395 bytes)
/// keeps a few in flight; more cost 1.5 KiB each.
const RX_PACKETS: usize = 4;

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

/// Brings up the MAC and PHY; the driver for the stack (arm-wiring creates the stack, with
/// the address from `arm_wiring::net::ip_config`). Call once.
pub fn device(pins: EthernetPins) -> Device {
    static PACKETS: StaticCell<PacketQueue<TX_PACKETS, RX_PACKETS>> = StaticCell::new();

    Ethernet::new(
        PACKETS.init(PacketQueue::new()),
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
