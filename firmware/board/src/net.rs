//! Ethernet (LAN8742A PHY over RMII) and the embassy-net stack.
//!
//! Bring-up never blocks the rest of the board: before touching the MAC, [`phy_clock_present`]
//! checks that the PHY drives the 50 MHz RMII reference clock (without it the MAC's DMA
//! software reset never completes and embassy's driver would spin forever). A missing or
//! dead PHY is retried every `RETRY_SECONDS` by the bring-up task in `main.rs` while the
//! steps, gripper, serial port and watchdog run normally.
//!
//! [`Lan8742a`] replaces embassy's `GenericPhy`: its reset is bounded (no panic when the PHY
//! does not answer on MDIO), it advertises every mode, and on each link-up it reads the
//! negotiated speed and duplex (register 31) and sets the MAC to match, instead of forcing
//! 100 Mbit/s full duplex (a 10 Mbit/s or half-duplex partner would see collisions and CRC
//! errors).
//!
//! The MAC's descriptors and packet buffers ([`PacketQueue`]) are in SRAM1, non-cacheable
//! (see `memory.rs`): the Ethernet DMA cannot reach DTCM and does not see the D-cache.
//!
//! [`RxPeek`] is the last part of the `ETH` interrupt (after embassy's, which wakes the
//! runner and clears the receive flag; [`RxFlags`] reads the drop flags before that): it
//! looks at every receive buffer the DMA has just filled and halts the steps for a
//! STOPPED there (arm-core's `ingress::stop_in_frame`; issue 30 part 4), whatever
//! thread mode is doing, and counts the frames the MAC dropped because the ring was full.
//! It also keeps the ring from filling ([`make_room`]): while the stack's runner does not
//! take the frames (a flood it cannot keep up with, or thread mode busy with a window of
//! keyed PENDINGs), it drops the oldest ones it has looked at, so the MAC always has a
//! descriptor for the next frame and no STOPPED is lost for want of one. The ring is
//! embassy-stm32's, patched for this (`vendor/NOTE-UPSTREAM.md`): the driver's read index
//! is shared, and the interrupt leaves the ring alone while the driver holds a frame.

use core::cell::UnsafeCell;
use core::future::Future;
use core::pin::Pin;
use core::sync::atomic::{AtomicU32, Ordering, fence};
use core::task::Context;

use board_logic::net::{LinkMode, REF_CLK_SAMPLES, link_mode, ref_clock_running};
use defmt::{info, warn};
use embassy_stm32::eth::{Ethernet, PacketQueue, Phy, Sma, StationManagement};
use embassy_stm32::gpio::{Input, Pull};
use embassy_stm32::peripherals::{ETH, ETH_SMA};
use embassy_stm32::{Peri, pac, peripherals};
use embassy_time::{Duration, Instant, Timer};

use arm_core::config::HOST_WINDOW;
use arm_core::ingress::{CONTROLLER_PORT, MAX_RING, RingPeek, StepHalt, stop_signature};
use embassy_stm32::interrupt::typelevel::{ETH as EthIrq, Handler};

use crate::Irqs;

/// The Ethernet driver as the stack sees it.
pub type Device = Ethernet<'static, ETH, Lan8742a>;

/// Transmit descriptors: a burst of ACK + STATUS + LOCATION + USART_RECV fits without
/// waiting for the MAC; a burst of 40 ACKs (11 bytes each, 1.3 us on the wire at
/// 100 Mbit/s) waits for the MAC for microseconds, which costs nothing.
pub const TX_PACKETS: usize = 4;
/// Receive descriptors: a whole burst. A host's window is [`HOST_WINDOW`] = 32 datagrams
/// of up to 1472 bytes sent back to back (32 x 123 us = 3.9 ms at 100 Mbit/s), plus 8 for
/// other tools' commands, ARP and the like arriving meanwhile: 40. Each descriptor owns a
/// 1536-byte buffer (embassy-stm32's `RX_BUFFER_SIZE`), so the ring costs
/// 40 x (1536 + 16) = 62,080 bytes (in SRAM1, see `memory.rs`). Sized so that nothing is
/// dropped even if the stack's runner does not get to run during the whole burst (smoltcp
/// and the MAC drop silently; the host would only see a missing ACK).
pub const RX_PACKETS: usize = HOST_WINDOW + 8;

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
    let (_, folded) = mac.split_at_mut(1);
    for chunk in uid.chunks(folded.len()) {
        for (folded_byte, byte) in folded.iter_mut().zip(chunk) {
            *folded_byte ^= byte;
        }
    }
    mac
}

/// Whether the PHY drives RMII_REF_CLK: samples the pin as an input (pull-down) at
/// irregular intervals and looks for both levels. Leaves the pin for the MAC.
pub fn phy_clock_present(ref_clk: Peri<'_, peripherals::PA1>) -> bool {
    let input = Input::new(ref_clk, Pull::Down);
    let (mut highs, mut lows) = (0u32, 0u32);
    for i in 0..REF_CLK_SAMPLES {
        if input.is_high() {
            highs += 1;
        } else {
            lows += 1;
        }
        // Irregular spacing: a sampling rate locked to the 50 MHz clock cannot fake "stuck".
        cortex_m::asm::delay(i % 7);
    }
    ref_clock_running(highs, lows)
}

/// Brings up the MAC and PHY; the driver for the stack (arm-wiring creates the stack, with
/// the address from `arm_wiring::net::ip_config`). Call once, after [`phy_clock_present`]
/// said yes.
pub fn device(
    pins: EthernetPins,
    packets: &'static mut PacketQueue<TX_PACKETS, RX_PACKETS>,
) -> Device {
    let phy = Lan8742a::new(Sma::new(pins.sma, pins.mdio, pins.mdc));
    let device = Ethernet::new_with_phy(
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
        phy,
    );
    find_receive_ring();
    // The DMA's "receive buffer unavailable" raises the interrupt too (an abnormal one),
    // so that the frames the MAC drops meanwhile are counted ([`RxPeek`]).
    pac::ETH.ethernet_dma().dmacier().modify(|w| {
        w.set_rbue(true);
        w.set_aie(true);
    });
    device
}

/// Bytes of each receive buffer: embassy-stm32 0.6's `RX_BUFFER_SIZE` (private to it):
/// descriptor `i` always gets buffer `i` of one array, so buffer `i` is at
/// `first + i * RX_BUFFER_BYTES` ([`find_receive_ring`] checks that on every descriptor).
const RX_BUFFER_BYTES: usize = 1536;
/// SRAM1, where `memory.rs` puts the ring: a buffer address outside it is not believed.
const SRAM1: core::ops::Range<usize> = 0x3000_0000..0x3002_0000;
/// Receive descriptor bits (RM0433 "Receive normal descriptor (write-back format)"): the
/// DMA owns it; context descriptor; first and last descriptor of a frame; error summary;
/// frame length.
const RDES3_OWN: u32 = 1 << 31;
const RDES3_CTXT: u32 = 1 << 30;
const RDES3_FD: u32 = 1 << 29;
const RDES3_LD: u32 = 1 << 28;
const RDES3_ES: u32 = 1 << 15;
const RDES3_PL: u32 = 0x7FFF;
/// The receive descriptor ring's address, 0 until [`find_receive_ring`] found it.
static RX_DESCRIPTORS: AtomicU32 = AtomicU32::new(0);
/// The first receive buffer's address, 0 until [`find_receive_ring`] found the ring.
static RX_BUFFERS: AtomicU32 = AtomicU32::new(0);

const _: () = assert!(
    RX_PACKETS <= MAX_RING,
    "RingPeek tracks at most MAX_RING buffers"
);

/// Finds where embassy's driver put the receive descriptors (the DMA's list address) and
/// their buffers (each descriptor in read format holds its buffer's address, which the
/// write-back overwrites: read them now, before the link is up), for [`RxPeek`]. Leaves
/// the interrupt's look off, with a log line, if the layout is not the expected one.
fn find_receive_ring() {
    let dma = pac::ETH.ethernet_dma();
    let descriptors = dma.dmacrx_dlar().read().0;
    let ring = usize::from(dma.dmacrx_rlr().read().rdrl()) + 1;
    let word = |i: usize, w: usize| {
        // SAFETY: within the descriptor ring the DMA was given (`ring` descriptors of 16
        // bytes at `descriptors`, embassy's `rx_desc`), a volatile read of a word.
        unsafe { core::ptr::read_volatile((descriptors as usize + i * 16 + w * 4) as *const u32) }
    };
    let mut first = None;
    let mut consistent = ring == RX_PACKETS;
    for i in 0..ring {
        if word(i, 3) & RDES3_OWN == 0 {
            continue; // written back already: its address is gone
        }
        let at = (word(i, 0) as usize).wrapping_sub(i * RX_BUFFER_BYTES);
        consistent &= *first.get_or_insert(at) == at;
    }
    match first {
        Some(at)
            if consistent
                && SRAM1.contains(&at)
                && at + RX_PACKETS * RX_BUFFER_BYTES <= SRAM1.end =>
        {
            RX_BUFFERS.store(u32::try_from(at).unwrap_or(0), Ordering::Relaxed);
            RX_DESCRIPTORS.store(descriptors, Ordering::Release);
        }
        _ => warn!("ethernet: receive ring not as expected: no STOPPED look in the interrupt"),
    }
}

/// State only the `ETH` interrupt touches (it never preempts itself).
struct EthInterruptOnly(UnsafeCell<RingPeek<RX_PACKETS>>);

// SAFETY: only `RxPeek::on_interrupt` uses it, and an interrupt never preempts itself.
unsafe impl Sync for EthInterruptOnly {}

static PEEK: EthInterruptOnly = EthInterruptOnly(UnsafeCell::new(RingPeek::new()));

/// The first part of the `ETH` interrupt (bound before embassy's handler, whose
/// flag-clearing `modify` clears every flag it reads set): the receive-side flags and drop
/// counters, kept for [`RxPeek`], which runs after embassy's handler.
pub struct RxFlags;

/// What [`RxFlags`] read for [`RxPeek`] in the same interrupt: drops, then the "receive
/// buffer unavailable" flag. Only the `ETH` interrupt touches it (atomics for `static`).
static RX_DROPS: [AtomicU32; 2] = [AtomicU32::new(0), AtomicU32::new(0)];

impl Handler<EthIrq> for RxFlags {
    unsafe fn on_interrupt() {
        let dma = pac::ETH.ethernet_dma();
        // Reading these counters clears them (RM0433): each drop is counted once.
        let full = u32::from(dma.dmacsr().read().rbu());
        let missed = pac::ETH.ethernet_mtl().mtlrx_qmpocr().read();
        let dropped = u32::from(missed.ovfpktcnt())
            + u32::from(missed.mispktcnt())
            + u32::from(dma.dmacmfcr().read().mfc());
        RX_DROPS[0].store(dropped, Ordering::Relaxed);
        RX_DROPS[1].store(full, Ordering::Relaxed);
    }
}

/// The `ETH` interrupt's look at STOPPED, bound *after* embassy's handler: that one clears
/// the receive flag, so a frame landing while this looks raises the interrupt again and
/// is looked at then. (Bound before it, the look ran first and the flag was cleared after
/// it: a frame that landed during the look was never looked at; the runner's first look
/// took it, `renode.rs` saw it once as 4 of 5 STOPPEDs halted by the interrupt.)
///
/// At P4, the lowest level: the e-stop input, the DIR changes, the step refills and the
/// time driver all preempt it, and it takes no lock they wait for but the step lock of
/// the halt itself (as the runner's look did). Its cost is 40 descriptor reads and, per
/// frame waiting in the ring, the header parse (tens of instructions) and, for a STOPPED
/// only, its CRC; with the ring nearly full, one or two frames dropped ([`make_room`]).
pub struct RxPeek;

impl Handler<EthIrq> for RxPeek {
    unsafe fn on_interrupt() {
        let dropped = RX_DROPS[0].swap(0, Ordering::Relaxed);
        let full = RX_DROPS[1].swap(0, Ordering::Relaxed);
        let (stops, free) = peek_filled_buffers();
        let made_room = make_room(free);
        let dropped = dropped + made_room;
        if dropped | full | stops != 0 {
            crate::BUS.count_rx_ring(dropped, full, stops);
        }
    }
}

/// Looks at every receive buffer the driver owns (see `RingPeek` for why every one, not
/// only those seen filled: a buffer given back while the ring was full is refilled at
/// once); halts the steps for a STOPPED. How many new STOPPEDs, and how many descriptors
/// the DMA owns (free for the next frames).
fn peek_filled_buffers() -> (u32, usize) {
    let descriptors = RX_DESCRIPTORS.load(Ordering::Acquire) as usize;
    let buffers = RX_BUFFERS.load(Ordering::Relaxed) as usize;
    if descriptors == 0 {
        return (0, RX_PACKETS);
    }
    let mut free = 0;
    // SAFETY: see `EthInterruptOnly`.
    let ring = unsafe { &mut *PEEK.0.get() };
    let mut stops = 0;
    for i in 0..RX_PACKETS {
        // SAFETY: descriptor `i` of the ring `find_receive_ring` checked; volatile.
        let rdes3 = unsafe { core::ptr::read_volatile((descriptors + i * 16 + 12) as *const u32) };
        if rdes3 & RDES3_OWN != 0 {
            ring.given_back(i);
            free += 1;
            continue;
        }
        if rdes3 & (RDES3_FD | RDES3_LD | RDES3_ES | RDES3_CTXT) != RDES3_FD | RDES3_LD {
            continue;
        }
        // The frame's bytes are read after its descriptor said it is complete.
        fence(Ordering::SeqCst);
        let len = (rdes3 & RDES3_PL) as usize;
        // SAFETY: buffer `i` (`RX_BUFFER_BYTES` in SRAM1, checked by `find_receive_ring`)
        // is the driver's while its descriptor says so: the DMA no longer writes it, and
        // the runner only reads it, in thread mode, below this interrupt. Read-only here.
        let frame = unsafe {
            core::slice::from_raw_parts(
                (buffers + i * RX_BUFFER_BYTES) as *const u8,
                len.min(RX_BUFFER_BYTES),
            )
        };
        if let Some(signature) = stop_signature(frame, CONTROLLER_PORT) {
            crate::BoardHalt.halt();
            if ring.stop_at(i, signature) {
                stops += 1;
            }
        }
    }
    (stops, free)
}

/// Descriptors the interrupt keeps free for the next frames: with one, the frame that
/// lands while the interrupt runs has room too.
const RX_FREE_RESERVE: usize = 2;

/// Keeps [`RX_FREE_RESERVE`] descriptors free while the stack's runner does not take the
/// frames (a flood it cannot keep up with, or thread mode busy): drops the oldest frames
/// the driver has not taken yet (patched embassy-stm32, `vendor/NOTE-UPSTREAM.md`), so
/// the MAC never drops a frame for want of a descriptor and this interrupt sees every
/// frame that lands, a STOPPED among them. Frames stay in order; the newest are kept (a
/// STOPPED that lands next has room). A STOPPED dropped here (looked at and halted for
/// when it landed) still reaches the controller: it is routed to the e-stop queue as the
/// runner's look would (`Bus::receive_first`), so it is ACKed and the state is STOPPED.
/// A datagram from a trusted source (the owner, a session that proved the key:
/// `Bus::is_trusted`) is never dropped here: the drops stop at it until the runner takes
/// it, and the MAC's receive FIFO holds what lands meanwhile (without this, on Renode at
/// 25 MIPS under the flood, the owner's commands went unanswered 5 times in 20 runs).
/// How many frames it dropped.
fn make_room(free: usize) -> u32 {
    if RX_DESCRIPTORS.load(Ordering::Relaxed) == 0 {
        return 0;
    }
    let mut dropped = 0;
    for _ in free..RX_FREE_RESERVE {
        // SAFETY: called from the ETH interrupt only, which the runner (thread mode) never
        // preempts and which never preempts itself; single core.
        let done = unsafe {
            embassy_stm32::eth::rx_drop_oldest(|frame| {
                let Some((from, payload)) =
                    frame.and_then(|f| arm_core::ingress::udp_payload(f, CONTROLLER_PORT))
                else {
                    return false;
                };
                if arm_core::bus::is_stop(payload) {
                    let now_us = Instant::now().as_micros();
                    crate::BUS.receive_first(from, payload, false, now_us, &crate::BoardHalt);
                    return false;
                }
                crate::BUS.is_trusted(from.ip)
            })
        };
        if done != embassy_stm32::eth::RxOldest::Dropped {
            break;
        }
        dropped += 1;
    }
    dropped
}

/// The LAN8742A's MDIO address on the NUCLEO-H743ZI2 (PHYAD0 strapped low).
const PHY_ADDRESS: u8 = 0;
/// Basic control register and its bits.
const BCR: u8 = 0;
const BCR_RESET: u16 = 1 << 15;
const BCR_AUTONEG: u16 = 1 << 12;
const BCR_RESTART_AUTONEG: u16 = 1 << 9;
/// Basic status register: link up.
const BSR: u8 = 1;
const BSR_LINK_UP: u16 = 1 << 2;
/// PHY identifier 1: 0x0007 for every Microchip/SMSC PHY.
const PHY_ID1: u8 = 2;
const PHY_ID1_MICROCHIP: u16 = 0x0007;
/// Auto-negotiation advertisement: 10/100, half/full, IEEE 802.3 selector.
const ANAR: u8 = 4;
const ANAR_ALL_MODES: u16 = 0x01E1;
/// PHY special control/status (speed indication).
const PSCSR: u8 = 31;
/// Polls of BCR_RESET after a reset: the LAN8742A needs under 1 ms; 10 ms at most.
const RESET_POLLS: u32 = 10;
/// Link status poll period (the driver polls on every wake-up of the runner).
const POLL_PERIOD: Duration = Duration::from_millis(500);
/// Between two attempts at a PHY that did not answer.
const REDETECT_PERIOD: Duration = Duration::from_secs(5);

/// The NUCLEO's PHY ([`Phy`] for embassy's Ethernet driver).
pub struct Lan8742a {
    sm: Sma<'static, ETH_SMA>,
    /// The PHY answered its reset.
    present: bool,
    /// The mode the MAC is set to (`None`: link down).
    mode: Option<LinkMode>,
    next_poll: Instant,
    next_redetect: Instant,
}

impl Lan8742a {
    fn new(sm: Sma<'static, ETH_SMA>) -> Self {
        Lan8742a {
            sm,
            present: false,
            mode: None,
            next_poll: Instant::from_ticks(0),
            next_redetect: Instant::from_ticks(0),
        }
    }

    /// Resets the PHY, bounded; whether it answered like a LAN8742A.
    fn try_reset(&mut self) -> bool {
        if self.sm.smi_read(PHY_ADDRESS, PHY_ID1) != PHY_ID1_MICROCHIP {
            return false;
        }
        self.sm.smi_write(PHY_ADDRESS, BCR, BCR_RESET);
        for _ in 0..RESET_POLLS {
            embassy_time::block_for(Duration::from_millis(1));
            if self.sm.smi_read(PHY_ADDRESS, BCR) & BCR_RESET == 0 {
                return true;
            }
        }
        false
    }

    fn start_autonegotiation(&mut self) {
        self.sm.smi_write(PHY_ADDRESS, ANAR, ANAR_ALL_MODES);
        self.sm
            .smi_write(PHY_ADDRESS, BCR, BCR_AUTONEG | BCR_RESTART_AUTONEG);
    }
}

/// Sets the MAC's speed and duplex (MACCR FES, DM).
fn set_mac_mode(mode: LinkMode) {
    pac::ETH.ethernet_mac().maccr().modify(|w| {
        w.set_fes(mode.fast);
        w.set_dm(mode.full_duplex);
    });
}

impl Phy for Lan8742a {
    fn phy_reset(&mut self) {
        self.present = self.try_reset();
        if !self.present {
            warn!("ethernet: the PHY does not answer on MDIO; retrying every 5 s");
        }
    }

    fn phy_init(&mut self) {
        if self.present {
            self.start_autonegotiation();
        }
    }

    fn poll_link(&mut self, cx: &mut Context) -> bool {
        let now = Instant::now();
        if now < self.next_poll {
            // Woken early by traffic: report the last state; the poll timer is armed.
            return self.mode.is_some();
        }
        self.next_poll = now + POLL_PERIOD;
        // Be polled again then: polling a timer once registers the runner's waker in the
        // time queue, which wakes it at the deadline even after the timer is dropped (what
        // embassy's GenericPhy does too).
        let mut timer = Timer::at(self.next_poll);
        let _ = Future::poll(Pin::new(&mut timer), cx);

        if !self.present {
            if now >= self.next_redetect {
                self.next_redetect = now + REDETECT_PERIOD;
                self.present = self.try_reset();
                if self.present {
                    info!("ethernet: PHY found");
                    self.start_autonegotiation();
                }
            }
            return false;
        }
        let up = self.sm.smi_read(PHY_ADDRESS, BSR) & BSR_LINK_UP != 0;
        let mode = if up {
            link_mode(self.sm.smi_read(PHY_ADDRESS, PSCSR))
        } else {
            None
        };
        if mode != self.mode {
            if let Some(m) = mode {
                set_mac_mode(m);
                info!(
                    "ethernet: link {} Mbit/s {} duplex",
                    if m.fast { 100 } else { 10 },
                    if m.full_duplex { "full" } else { "half" }
                );
            }
            self.mode = mode;
        }
        mode.is_some()
    }
}
