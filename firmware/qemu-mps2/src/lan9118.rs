//! An [`embassy_net_driver::Driver`] for the SMSC LAN9118 (the MPS2 AN500's LAN9220 is
//! register-compatible; QEMU models it in `hw/net/lan9118.c`).
//!
//! The chip has no DMA: frames move through FIFOs by programmed I/O. Receive: the MAC puts
//! each frame's data in the RX data FIFO and a status word (length, error summary) in the RX
//! status FIFO; the driver pops the status, then reads the frame's words. Transmit: the
//! driver writes command A (buffer length, first/last segment), command B (tag, frame
//! length) and the data words into the TX data FIFO; the MAC sends the frame once the last
//! word is in and pushes a status word into the TX status FIFO, which the driver drains to
//! count errors. MAC registers and, through the MAC's MII registers, the internal PHY
//! (address 1) are reached through the indirect `MAC_CSR_CMD`/`MAC_CSR_DATA` interface.
//!
//! Interrupts (IRQ line active high, push-pull): RX status FIFO level (a frame arrived),
//! TX data FIFO available (room for a frame that did not fit), PHY (link change), and the
//! RX/TX error flags. The handler acknowledges what it saw and wakes the stack. A frame
//! with errors, or longer than the driver's buffer, is read and dropped (counted), never
//! handed up.
//!
//! Receive goes through a ring of [`RX_RING`] buffers, as the NUCLEO's DMA ring (issue 30
//! part 4): the interrupt moves each frame from the chip's FIFO into the next free buffer
//! and looks at it there (arm-core's `ingress::stop_in_frame`): a STOPPED halts the steps
//! within microseconds of its arrival, whatever thread mode does. The runner takes frames
//! from the ring as before. With the ring full the interrupt leaves frames in the chip
//! (counted: `full`) and turns its receive interrupt off until the runner frees a buffer;
//! what the chip's own FIFO then cannot hold it drops (its RX_DROP counter).

use core::cell::UnsafeCell;
use core::ptr::{read_volatile, write_volatile};
use core::sync::atomic::{AtomicBool, AtomicU32, AtomicUsize, Ordering};
use core::task::Context;

use embassy_net_driver::{Capabilities, HardwareAddress, LinkState};
use embassy_sync::waitqueue::AtomicWaker;

/// Base of the chip's registers on the AN500 (QEMU `mps2_an500_class_init`:
/// `ethernet_base`; the AN385/AN386 have it at 0x4020_0000 instead).
const BASE: usize = 0xA000_0000;

/// The largest frame handed to or taken from the stack: Ethernet header and 1500 bytes of
/// payload, without the FCS (the MAC adds and checks it).
pub const MTU: usize = MTU_BYTES as usize;
/// [`MTU`] as the chip's length fields count it (a widening cast makes the `usize`).
const MTU_BYTES: u32 = 1514;

/// System control and status registers (datasheet section 5.3), offsets from [`BASE`].
mod reg {
    /// RX data FIFO port (any offset in 0x00..0x20 pops one word).
    pub const RX_DATA_FIFO: usize = 0x00;
    /// TX data FIFO port (0x20..0x40).
    pub const TX_DATA_FIFO: usize = 0x20;
    /// RX status FIFO port (pops).
    pub const RX_STATUS_FIFO: usize = 0x40;
    /// TX status FIFO port (pops).
    pub const TX_STATUS_FIFO: usize = 0x48;
    /// Chip ID (high half) and revision.
    pub const ID_REV: usize = 0x50;
    /// Interrupt pin configuration.
    pub const IRQ_CFG: usize = 0x54;
    /// Interrupt status (write 1 to clear).
    pub const INT_STS: usize = 0x58;
    /// Interrupt enables.
    pub const INT_EN: usize = 0x5C;
    /// Reads 0x87654321: bus and byte order check.
    pub const BYTE_TEST: usize = 0x64;
    /// FIFO level interrupt thresholds.
    pub const FIFO_INT: usize = 0x68;
    /// Receive configuration (alignment, dump).
    pub const RX_CFG: usize = 0x6C;
    /// Transmit configuration.
    pub const TX_CFG: usize = 0x70;
    /// Hardware configuration (soft reset, FIFO sizes).
    pub const HW_CFG: usize = 0x74;
    /// RX FIFO information: status words used (23:16), data bytes used (15:0).
    pub const RX_FIFO_INF: usize = 0x7C;
    /// TX FIFO information: status words used (23:16), data bytes free (15:0).
    pub const TX_FIFO_INF: usize = 0x80;
    /// Power management; bit 0 = device ready.
    pub const PMT_CTRL: usize = 0x84;
    /// Frames the chip dropped for want of room in its RX FIFO (clears on read; QEMU's
    /// model reads 0).
    pub const RX_DROP: usize = 0xA0;
    /// MAC CSR command: busy (31), read (30), MAC register index (7:0).
    pub const MAC_CSR_CMD: usize = 0xA4;
    /// MAC CSR data.
    pub const MAC_CSR_DATA: usize = 0xA8;
}

/// MAC registers behind `MAC_CSR_CMD` (datasheet section 5.4).
mod mac {
    /// MAC control.
    pub const MAC_CR: u32 = 1;
    /// Address, bytes 4-5.
    pub const ADDRH: u32 = 2;
    /// Address, bytes 0-3.
    pub const ADDRL: u32 = 3;
    /// MII access: PHY address (15:11), register (10:6), write (1), busy (0).
    pub const MII_ACC: u32 = 6;
    /// MII data.
    pub const MII_DATA: u32 = 7;

    /// MAC_CR: full duplex.
    pub const CR_FDPX: u32 = 1 << 20;
    /// MAC_CR: transmitter enable.
    pub const CR_TXEN: u32 = 1 << 3;
    /// MAC_CR: receiver enable.
    pub const CR_RXEN: u32 = 1 << 2;
}

/// PHY registers (datasheet section 5.5).
mod phy {
    /// The internal PHY's address.
    pub const ADDRESS: u32 = 1;
    /// Basic control.
    pub const BCR: u32 = 0;
    /// Basic status.
    pub const BSR: u32 = 1;
    /// Auto-negotiation advertisement.
    pub const ANAR: u32 = 4;
    /// Interrupt source (read clears).
    pub const ISR: u32 = 29;
    /// Interrupt mask.
    pub const IMR: u32 = 30;

    /// BCR: software reset (self-clearing).
    pub const BCR_RESET: u16 = 1 << 15;
    /// BCR: auto-negotiation enable.
    pub const BCR_AUTONEG: u16 = 1 << 12;
    /// BCR: restart auto-negotiation.
    pub const BCR_RESTART_AUTONEG: u16 = 1 << 9;
    /// BSR: link up.
    pub const BSR_LINK: u16 = 1 << 2;
    /// ANAR: 100BASE-TX full/half, 10BASE-T full/half, IEEE 802.3.
    pub const ANAR_ALL: u16 = 0x01E1;
    /// IMR/ISR: link down, auto-negotiation complete, energy on.
    pub const INT_LINK: u16 = (1 << 4) | (1 << 6) | (1 << 7);
}

/// Interrupt bits (INT_STS / INT_EN).
mod int {
    /// TX error.
    pub const TXE: u32 = 1 << 13;
    /// RX error.
    pub const RXE: u32 = 1 << 14;
    /// PHY interrupt.
    pub const PHY: u32 = 1 << 18;
    /// TX data FIFO available (free space above the FIFO_INT level).
    pub const TDFA: u32 = 1 << 9;
    /// RX status FIFO level (more status words than the FIFO_INT level).
    pub const RSFL: u32 = 1 << 3;
}

/// IRQ_CFG: enable the pin, active high, push-pull.
const IRQ_CFG_ENABLED: u32 = (1 << 8) | (1 << 4) | 1;
/// HW_CFG: soft reset (self-clearing).
const HW_CFG_SRST: u32 = 1;
/// TX_CFG: transmitter on, and let the TX status FIFO overrun (statuses are only counted).
const TX_CFG_ON: u32 = (1 << 1) | (1 << 2);
/// TX command A: first and last segment (one buffer per frame).
const CMD_A_FIRST_LAST: u32 = (1 << 13) | (1 << 12);
/// RX status: error summary.
const RX_STATUS_ERROR: u32 = 1 << 15;
/// TX status: error summary.
const TX_STATUS_ERROR: u32 = 1 << 15;
/// FIFO_INT: TX data available level, in 64-byte units: room for a full frame and its
/// two command words.
const FIFO_INT_TX_AVAILABLE: u32 = (MTU_BYTES + 8).div_ceil(64) << 24;
/// Polls of a busy bit before bring-up gives up (each is a register read; the chip answers
/// CSR commands within a microsecond, a soft reset within 100 us).
const BUSY_POLLS: u32 = 100_000;

/// The receive path's waker, woken by the interrupt when a frame arrived.
static RX_WAKER: AtomicWaker = AtomicWaker::new();
/// The transmit path's waker, woken when the TX data FIFO has room again.
static TX_WAKER: AtomicWaker = AtomicWaker::new();
/// The link state's waker, woken on a PHY interrupt.
static LINK_WAKER: AtomicWaker = AtomicWaker::new();
/// Link state as last read from the PHY (by bring-up and the PHY interrupt).
static LINK_UP: AtomicBool = AtomicBool::new(false);

/// Frames dropped on receive (error status, too long for the buffer).
pub static RX_DROPPED: AtomicU32 = AtomicU32::new(0);
/// Frames the MAC reported failed to send.
pub static TX_ERRORS: AtomicU32 = AtomicU32::new(0);

/// Why bring-up failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum InitError {
    /// BYTE_TEST did not read 0x87654321: no chip, or a bus of the wrong width or order.
    NoChip(u32),
    /// A busy bit (device ready, soft reset, MAC CSR, MII) never cleared.
    Timeout(&'static str),
}

fn read(offset: usize) -> u32 {
    // SAFETY: an aligned 32-bit register of the LAN9118, mapped at BASE on this board.
    unsafe { read_volatile((BASE + offset) as *const u32) }
}

fn write(offset: usize, value: u32) {
    // SAFETY: as in `read`.
    unsafe { write_volatile((BASE + offset) as *mut u32, value) }
}

/// Polls until `done` or [`BUSY_POLLS`] reads.
fn wait(what: &'static str, mut done: impl FnMut() -> bool) -> Result<(), InitError> {
    for _ in 0..BUSY_POLLS {
        if done() {
            return Ok(());
        }
    }
    Err(InitError::Timeout(what))
}

fn mac_read(index: u32) -> Result<u32, InitError> {
    wait("MAC CSR", || read(reg::MAC_CSR_CMD) & (1 << 31) == 0)?;
    write(reg::MAC_CSR_CMD, (1 << 31) | (1 << 30) | index);
    wait("MAC CSR", || read(reg::MAC_CSR_CMD) & (1 << 31) == 0)?;
    Ok(read(reg::MAC_CSR_DATA))
}

fn mac_write(index: u32, value: u32) -> Result<(), InitError> {
    wait("MAC CSR", || read(reg::MAC_CSR_CMD) & (1 << 31) == 0)?;
    write(reg::MAC_CSR_DATA, value);
    write(reg::MAC_CSR_CMD, (1 << 31) | index);
    wait("MAC CSR", || read(reg::MAC_CSR_CMD) & (1 << 31) == 0)
}

fn phy_read(register: u32) -> Result<u16, InitError> {
    wait("MII", || mac_read(mac::MII_ACC).is_ok_and(|v| v & 1 == 0))?;
    mac_write(mac::MII_ACC, (phy::ADDRESS << 11) | (register << 6) | 1)?;
    wait("MII", || mac_read(mac::MII_ACC).is_ok_and(|v| v & 1 == 0))?;
    // PHY registers are 16 bits wide: MII_DATA's low half.
    let [low, high, ..] = mac_read(mac::MII_DATA)?.to_le_bytes();
    Ok(u16::from_le_bytes([low, high]))
}

fn phy_write(register: u32, value: u16) -> Result<(), InitError> {
    wait("MII", || mac_read(mac::MII_ACC).is_ok_and(|v| v & 1 == 0))?;
    mac_write(mac::MII_DATA, u32::from(value))?;
    mac_write(mac::MII_ACC, (phy::ADDRESS << 11) | (register << 6) | 2 | 1)?;
    wait("MII", || mac_read(mac::MII_ACC).is_ok_and(|v| v & 1 == 0))
}

/// Reads the link bit; the PHY's interrupt source register is read too, which clears it.
fn refresh_link() -> Result<bool, InitError> {
    phy_read(phy::ISR)?;
    let up = phy_read(phy::BSR)? & phy::BSR_LINK != 0;
    LINK_UP.store(up, Ordering::Release);
    Ok(up)
}

/// Receive buffers between the interrupt and the runner: a burst of 8 frames taken from
/// the chip while thread mode is busy (the chip's FIFO holds more behind them); 8 x 1514
/// bytes of this board's 4 MiB of RAM.
pub const RX_RING: usize = 8;

const _: () = assert!(RX_RING <= arm_core::ingress::MAX_RING);

/// The receive ring: the interrupt fills buffer `filled % RX_RING` and then counts it in
/// `filled`; the runner reads buffer `taken % RX_RING` while `taken != filled` and then
/// counts it in `taken`. Single producer (the Ethernet interrupt, which never preempts
/// itself), single consumer (the runner): a buffer is only ever touched by one side.
struct RxRing {
    frames: UnsafeCell<[[u8; MTU]; RX_RING]>,
    lens: [AtomicUsize; RX_RING],
    filled: AtomicUsize,
    taken: AtomicUsize,
}

// SAFETY: see `RxRing`: the counters hand each buffer from one side to the other.
unsafe impl Sync for RxRing {}

static RX: RxRing = RxRing {
    frames: UnsafeCell::new([[0; MTU]; RX_RING]),
    lens: [const { AtomicUsize::new(0) }; RX_RING],
    filled: AtomicUsize::new(0),
    taken: AtomicUsize::new(0),
};

/// The chip, brought up and ready for the stack.
pub struct Lan9118 {
    mac_address: [u8; 6],
    tx: [u8; MTU],
}

impl Lan9118 {
    /// Resets and configures the chip: MAC address (the one loaded from the EEPROM if valid,
    /// else `fallback_mac`), PHY auto-negotiation, MAC receive and transmit on, interrupts
    /// enabled at the chip. The caller enables the chip's NVIC line.
    pub fn new(fallback_mac: [u8; 6]) -> Result<Self, InitError> {
        let test = read(reg::BYTE_TEST);
        if test != 0x8765_4321 {
            return Err(InitError::NoChip(test));
        }
        wait("device ready", || read(reg::PMT_CTRL) & 1 != 0)?;
        write(reg::HW_CFG, read(reg::HW_CFG) | HW_CFG_SRST);
        wait("soft reset", || read(reg::HW_CFG) & HW_CFG_SRST == 0)?;

        let low = mac_read(mac::ADDRL)?.to_le_bytes();
        let high = mac_read(mac::ADDRH)?.to_le_bytes();
        let loaded = [low[0], low[1], low[2], low[3], high[0], high[1]];
        let valid = loaded != [0; 6] && loaded != [0xFF; 6] && loaded[0] & 1 == 0;
        let mac_address = if valid { loaded } else { fallback_mac };
        let [a, b, c, d, e, f] = mac_address;
        mac_write(mac::ADDRL, u32::from_le_bytes([a, b, c, d]))?;
        mac_write(mac::ADDRH, u32::from_le_bytes([e, f, 0, 0]))?;

        phy_write(phy::BCR, phy::BCR_RESET)?;
        wait("PHY reset", || {
            phy_read(phy::BCR).is_ok_and(|v| v & phy::BCR_RESET == 0)
        })?;
        phy_write(phy::ANAR, phy::ANAR_ALL)?;
        phy_write(phy::BCR, phy::BCR_AUTONEG | phy::BCR_RESTART_AUTONEG)?;
        phy_write(phy::IMR, phy::INT_LINK)?;
        refresh_link()?;

        // Own address and broadcast only (promiscuous off), full duplex.
        mac_write(mac::MAC_CR, mac::CR_FDPX | mac::CR_TXEN | mac::CR_RXEN)?;
        write(reg::TX_CFG, TX_CFG_ON);
        // Frames start word-aligned at offset 0, end padding to 4 bytes.
        write(reg::RX_CFG, 0);
        // RX status level 0: interrupt on every frame. TX level: room for a full frame.
        write(reg::FIFO_INT, FIFO_INT_TX_AVAILABLE);
        write(reg::INT_STS, u32::MAX);
        write(reg::INT_EN, int::RSFL | int::PHY | int::RXE | int::TXE);
        write(reg::IRQ_CFG, IRQ_CFG_ENABLED);
        Ok(Lan9118 {
            mac_address,
            tx: [0; MTU],
        })
    }

    /// The chip ID and revision (ID_REV).
    pub fn id_rev() -> u32 {
        read(reg::ID_REV)
    }

    /// The address the MAC filters on.
    pub fn mac_address(&self) -> [u8; 6] {
        self.mac_address
    }

    /// Pops the next good frame into `rx`; its length. Frames with errors or longer
    /// than [`MTU`] are read and dropped.
    fn pop_frame(rx: &mut [u8; MTU]) -> Option<usize> {
        loop {
            let statuses = (read(reg::RX_FIFO_INF) >> 16) & 0xFF;
            if statuses == 0 {
                return None;
            }
            let status = read(reg::RX_STATUS_FIFO);
            // The length counts the 4-byte FCS, which follows the data in the FIFO.
            let with_fcs = ((status >> 16) & 0x3FFF) as usize;
            let words = with_fcs.div_ceil(4);
            let len = with_fcs.saturating_sub(4);
            let good = status & RX_STATUS_ERROR == 0 && (14..=MTU).contains(&len);
            if !good {
                for _ in 0..words {
                    read(reg::RX_DATA_FIFO);
                }
                RX_DROPPED.fetch_add(1, Ordering::Relaxed);
                continue;
            }
            let mut chunks = rx.chunks_mut(4);
            for _ in 0..words {
                let word = read(reg::RX_DATA_FIFO).to_le_bytes();
                // The last word(s) hold the FCS: nothing to copy once the buffer ends.
                if let Some(chunk) = chunks.next() {
                    for (byte, &from_fifo) in chunk.iter_mut().zip(&word) {
                        *byte = from_fifo;
                    }
                }
            }
            return Some(len);
        }
    }

    /// Whether the TX data FIFO takes a full frame now; if not, arms the TX-available
    /// interrupt, which wakes `cx`.
    fn tx_room(cx: &mut Context) -> bool {
        // Drain the TX status FIFO: counts failed frames, keeps it from filling.
        while (read(reg::TX_FIFO_INF) >> 16) & 0xFF != 0 {
            if read(reg::TX_STATUS_FIFO) & TX_STATUS_ERROR != 0 {
                TX_ERRORS.fetch_add(1, Ordering::Relaxed);
            }
        }
        let needed = MTU_BYTES + 8 + 3;
        if read(reg::TX_FIFO_INF) & 0xFFFF >= needed {
            return true;
        }
        TX_WAKER.register(cx.waker());
        critical_section::with(|_| write(reg::INT_EN, read(reg::INT_EN) | int::TDFA));
        // Room may have come before the interrupt was armed.
        read(reg::TX_FIFO_INF) & 0xFFFF >= needed
    }
}

/// Moves frames from the chip into the ring while it has room, looking at each
/// (interrupt only); a STOPPED halts the steps. With the ring full, turns the receive
/// interrupt off (the runner turns it on again as it frees a buffer), or the chip's
/// level-triggered line would hold the CPU here.
fn fill_ring() {
    let (mut full, mut stops) = (0, 0);
    loop {
        let filled = RX.filled.load(Ordering::Relaxed);
        if filled.wrapping_sub(RX.taken.load(Ordering::Acquire)) >= RX_RING {
            if (read(reg::RX_FIFO_INF) >> 16) & 0xFF != 0 {
                full += 1;
            }
            write(reg::INT_EN, read(reg::INT_EN) & !(int::RSFL | int::RXE));
            break;
        }
        let slot = filled % RX_RING;
        // SAFETY: buffer `slot` is not the runner's (`filled - taken < RX_RING`), and only
        // this interrupt fills buffers.
        let Some(rx) = (unsafe { (*RX.frames.get()).get_mut(slot) }) else {
            break;
        };
        let Some(len) = Lan9118::pop_frame(rx) else {
            break;
        };
        if rx.get(..len).is_some_and(|frame| {
            arm_core::ingress::stop_in_frame(frame, arm_core::ingress::CONTROLLER_PORT)
        }) {
            arm_core::ingress::StepHalt::halt(&crate::BoardHalt);
            crate::step_out::note_stop_seen();
            stops += 1;
        }
        if let Some(l) = RX.lens.get(slot) {
            l.store(len, Ordering::Relaxed);
        }
        RX.filled.store(filled.wrapping_add(1), Ordering::Release);
    }
    let dropped = read(reg::RX_DROP);
    if dropped | full | stops != 0 {
        crate::BUS.count_rx_ring(dropped, full, stops);
    }
}

/// A received frame, in the ring.
pub struct RxToken {
    slot: usize,
}

impl embassy_net_driver::RxToken for RxToken {
    fn consume<R, F: FnOnce(&mut [u8]) -> R>(self, f: F) -> R {
        let len = RX
            .lens
            .get(self.slot)
            .map_or(0, |l| l.load(Ordering::Relaxed));
        // SAFETY: buffer `slot` is the runner's until `taken` moves past it (below); the
        // interrupt does not touch it meanwhile.
        let frame = unsafe { (*RX.frames.get()).get_mut(self.slot) };
        let result = f(frame
            .and_then(|frame| frame.get_mut(..len))
            .unwrap_or_default());
        RX.taken.fetch_add(1, Ordering::Release);
        // A buffer is free: let the interrupt move what waits in the chip (pended, as the
        // chip raises RSFL only when a frame arrives).
        critical_section::with(|_| {
            write(reg::INT_EN, read(reg::INT_EN) | int::RSFL | int::RXE);
        });
        if (read(reg::RX_FIFO_INF) >> 16) & 0xFF != 0 {
            cortex_m::peripheral::NVIC::pend(crate::mps2::Irq::Ethernet);
        }
        result
    }
}

/// Room for one frame in the TX data FIFO.
pub struct TxToken<'a> {
    buf: &'a mut [u8; MTU],
}

impl embassy_net_driver::TxToken for TxToken<'_> {
    fn consume<R, F: FnOnce(&mut [u8]) -> R>(self, len: usize, f: F) -> R {
        let len = len.min(MTU);
        #[allow(
            clippy::indexing_slicing,
            reason = "`len` is clamped to MTU, the buffer's length"
        )]
        let frame = &mut self.buf[..len];
        let result = f(frame);
        #[allow(
            clippy::cast_possible_truncation,
            reason = "`len` is clamped to MTU (1514): it fits the 11-bit length fields"
        )]
        let len_field = len as u32;
        write(reg::TX_DATA_FIFO, CMD_A_FIRST_LAST | len_field);
        // Command B: packet tag (unused, 0) and frame length.
        write(reg::TX_DATA_FIFO, len_field);
        for chunk in frame.chunks(4) {
            // The last chunk may be short: zero padding.
            let mut word = [0u8; 4];
            for (byte, &from_frame) in word.iter_mut().zip(chunk) {
                *byte = from_frame;
            }
            write(reg::TX_DATA_FIFO, u32::from_le_bytes(word));
        }
        crate::marks::qemu_mark_frame_sent();
        result
    }
}

impl embassy_net_driver::Driver for Lan9118 {
    type RxToken<'a> = RxToken;
    type TxToken<'a> = TxToken<'a>;

    fn receive(&mut self, cx: &mut Context) -> Option<(RxToken, TxToken<'_>)> {
        // Register first: a frame arriving after the check below wakes this context.
        RX_WAKER.register(cx.waker());
        if !Self::tx_room(cx) {
            return None;
        }
        let taken = RX.taken.load(Ordering::Relaxed);
        if RX.filled.load(Ordering::Acquire) == taken {
            return None;
        }
        Some((
            RxToken {
                slot: taken % RX_RING,
            },
            TxToken { buf: &mut self.tx },
        ))
    }

    fn transmit(&mut self, cx: &mut Context) -> Option<TxToken<'_>> {
        Self::tx_room(cx).then_some(TxToken { buf: &mut self.tx })
    }

    fn link_state(&mut self, cx: &mut Context) -> LinkState {
        LINK_WAKER.register(cx.waker());
        if LINK_UP.load(Ordering::Acquire) {
            LinkState::Up
        } else {
            LinkState::Down
        }
    }

    fn capabilities(&self) -> Capabilities {
        let mut caps = Capabilities::default();
        caps.max_transmission_unit = MTU;
        caps.max_burst_size = Some(1);
        caps
    }

    fn hardware_address(&self) -> HardwareAddress {
        HardwareAddress::Ethernet(self.mac_address)
    }
}

/// The chip's interrupt: acknowledges what it saw, wakes the stack's paths concerned. The
/// FIFOs themselves are serviced by the runner task.
pub fn on_interrupt() {
    crate::marks::qemu_mark_nic_irq();
    let pending = read(reg::INT_STS) & read(reg::INT_EN);
    write(reg::INT_STS, pending);
    if pending & (int::RSFL | int::RXE) != 0 || (read(reg::RX_FIFO_INF) >> 16) & 0xFF != 0 {
        fill_ring();
        RX_WAKER.wake();
    }
    if pending & int::TDFA != 0 {
        // Level-triggered on the free space: off until the next shortage.
        write(reg::INT_EN, read(reg::INT_EN) & !int::TDFA);
        TX_WAKER.wake();
        RX_WAKER.wake();
    }
    if pending & int::TXE != 0 {
        TX_ERRORS.fetch_add(1, Ordering::Relaxed);
    }
    if pending & int::PHY != 0 {
        let was_up = LINK_UP.load(Ordering::Acquire);
        match refresh_link() {
            Ok(up) if up != was_up => LINK_WAKER.wake(),
            Ok(_) => {}
            Err(_) => log::warn!("PHY did not answer its interrupt"),
        }
    }
}
