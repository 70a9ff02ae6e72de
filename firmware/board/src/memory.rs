//! Caches, the MPU, and the memory every DMA touches.
//!
//! The D-cache is on. AXI SRAM (statics, the trajectory buffer, the tasks' futures) is
//! cached write-through (MPU region 1): loads hit the cache, every store also reaches the
//! RAM at once, so the settings marker surviving a reset (`settings.rs`) never misses a
//! write still sitting in a dirty cache line. defmt's RTT control block and buffer are in
//! SRAM1 (memory.x `.rtt`, copied there by `pre_init.rs`): the probe writes
//! the read pointer behind the cache, and a CPU reading it from a cache line would see a
//! full buffer forever (issue 20). The logger never waits for the probe either
//! (defmt-rtt's `disable-blocking-mode`): a log line that does not fit is dropped, so no
//! log call can hold the CPU, with interrupts masked, while the step DMA replays its
//! buffer. The DMA engines do not see the cache at all, so every buffer a DMA
//! reads or writes lives in SRAM1 or SRAM2 (D2 domain, 128 KiB each at 0x3000_0000 and
//! 0x3002_0000), which MPU regions 0 and 2 make normal, non-cacheable, shareable memory: no
//! cache maintenance is needed anywhere, and a buffer put there by mistake is merely slower,
//! never stale. The step streams' buffers have SRAM2 to themselves (issue 34): the Ethernet
//! DMA's bursts into SRAM1 never hold up a step burst's memory read.
//!
//! | buffer | size | DMA |
//! |---|---|---|
//! | Ethernet descriptors and packet buffers ([`DmaBuffers::eth`]), a burst of 40 datagrams (`net.rs`) | ~62 KiB | ETH DMA |
//! | serial receive ring ([`DmaBuffers::serial_rx`]) | 1 KiB | DMA1 stream 5 |
//! | serial transmit staging ([`DmaBuffers::serial_tx`]) | 256 B | DMA1 stream 4 |
//! | SRAM2: step streams, per joint 2 halves of 64 periods (ARR, RCR, CCR1), `step_dma/mod.rs` `BUFFERS` (a `.sram2` static, zeroed by `step_dma::init`) | 12 KiB | DMA1 streams 0-3 (joints 0-3), DMA2 streams 0-3 (joints 4-7) |
//!
//! Anything new that a DMA touches goes into [`DmaBuffers`] (or another `.sram1`/`.sram2`
//! static): those output sections (memory.x) are NOLOAD, so they are initialised at run
//! time.
//! The encoder bus (UART4) is interrupt-driven (no DMA) and needs nothing.

use core::mem::MaybeUninit;
use core::ptr::addr_of_mut;
use core::sync::atomic::{AtomicBool, Ordering};

use cortex_m::peripheral::{CPUID, MPU, SCB};
use embassy_stm32::eth::PacketQueue;
use embassy_stm32::pac;

use crate::net::{RX_PACKETS, TX_PACKETS};
use crate::serial::{RX_RING_BYTES, TX_STAGING_BYTES};

/// Start of AXI SRAM (memory.x `RAM`).
const AXI_SRAM_BASE: u32 = 0x2400_0000;
/// log2 of AXI SRAM's size (512 KiB).
const AXI_SRAM_SIZE_LOG2: u32 = 19;
/// Start of SRAM1 (memory.x `SRAM1`).
const SRAM1_BASE: u32 = 0x3000_0000;
/// log2 of SRAM1's size (128 KiB): the MPU region covers it whole.
const SRAM1_SIZE_LOG2: u32 = 17;
/// Start of SRAM2 (memory.x `SRAM2`): the step streams' buffers.
const SRAM2_BASE: u32 = 0x3002_0000;
/// log2 of SRAM2's size (128 KiB): MPU region 2 covers it whole (the base is a multiple
/// of the size, as the MPU requires).
const SRAM2_SIZE_LOG2: u32 = 17;

/// Every buffer a DMA engine touches.
pub struct DmaBuffers {
    /// Ethernet descriptors and packet buffers.
    pub eth: PacketQueue<TX_PACKETS, RX_PACKETS>,
    /// The serial port's receive ring.
    pub serial_rx: [u8; RX_RING_BYTES],
    /// The serial port's transmit staging buffer.
    pub serial_tx: [u8; TX_STAGING_BYTES],
}

#[unsafe(link_section = ".sram1.dma_buffers")]
static mut DMA_BUFFERS: MaybeUninit<DmaBuffers> = MaybeUninit::uninit();
static DMA_BUFFERS_TAKEN: AtomicBool = AtomicBool::new(false);

/// Clocks SRAM1-3 (they are allocated to the CPU, so the D2 domain follows its run
/// mode; RM0433 RCC_AHB2ENR). Idempotent.
fn clock_d2_srams() {
    pac::RCC.ahb2enr().modify(|w| {
        w.set_sram1en(true);
        w.set_sram2en(true);
        w.set_sram3en(true);
    });
}

/// The DMA buffers, initialised in place; `None` after the first call.
pub fn take_dma_buffers() -> Option<&'static mut DmaBuffers> {
    if DMA_BUFFERS_TAKEN.swap(true, Ordering::AcqRel) {
        return None;
    }
    clock_d2_srams();
    // SAFETY: the flag above hands the static out once; every field is written before
    // the reference is made.
    unsafe {
        let p = addr_of_mut!(DMA_BUFFERS).cast::<DmaBuffers>();
        // 62 KiB: initialised in place, never built on the stack first.
        PacketQueue::init(
            &mut *addr_of_mut!((*p).eth).cast::<MaybeUninit<PacketQueue<TX_PACKETS, RX_PACKETS>>>(),
        );
        addr_of_mut!((*p).serial_rx).write([0; RX_RING_BYTES]);
        addr_of_mut!((*p).serial_tx).write([0; TX_STAGING_BYTES]);
        Some(&mut *p)
    }
}

/// RASR: execute never.
const RASR_XN: u32 = 1 << 28;
/// RASR AP = 0b011: read/write for privileged and unprivileged code.
const RASR_AP_FULL: u32 = 0b011 << 24;
/// RASR TEX = 0b001, C = 0, B = 0: normal memory, not cacheable.
const RASR_NORMAL_NON_CACHEABLE: u32 = 0b001 << 19;
/// RASR TEX = 0b000, C = 1, B = 0: normal memory, write-through, no write-allocate.
const RASR_NORMAL_WRITE_THROUGH: u32 = 1 << 17;
/// RASR S: shareable (with the DMA masters).
const RASR_SHAREABLE: u32 = 1 << 18;
/// RASR ENABLE.
const RASR_ENABLE: u32 = 1;
/// MPU_CTRL: enable, and keep the default memory map for everything no region covers.
const MPU_CTRL_ENABLE_PRIVDEFENA: u32 = 0b101;

/// Clocks SRAM1-3 (so the D2 domain follows the CPU), makes SRAM1 and SRAM2 non-cacheable
/// with MPU regions 0 and 2 and AXI SRAM write-through with region 1, then turns on both
/// caches. Call once, early in `main`, before any DMA starts.
pub fn enable_caches(mpu: &mut MPU, scb: &mut SCB, cpuid: &mut CPUID) {
    clock_d2_srams();
    let sram1 = RASR_XN
        | RASR_AP_FULL
        | RASR_NORMAL_NON_CACHEABLE
        | RASR_SHAREABLE
        | ((SRAM1_SIZE_LOG2 - 1) << 1)
        | RASR_ENABLE;
    let sram2 = RASR_XN
        | RASR_AP_FULL
        | RASR_NORMAL_NON_CACHEABLE
        | RASR_SHAREABLE
        | ((SRAM2_SIZE_LOG2 - 1) << 1)
        | RASR_ENABLE;
    let axi = RASR_XN
        | RASR_AP_FULL
        | RASR_NORMAL_WRITE_THROUGH
        | ((AXI_SRAM_SIZE_LOG2 - 1) << 1)
        | RASR_ENABLE;
    cortex_m::asm::dmb();
    // SAFETY: the regions are set up before the MPU (and the cache) is enabled, with the
    // default map kept for everything else; nothing runs from RAM (XN).
    unsafe {
        mpu.ctrl.write(0);
        mpu.rnr.write(0);
        mpu.rbar.write(SRAM1_BASE);
        mpu.rasr.write(sram1);
        mpu.rnr.write(1);
        mpu.rbar.write(AXI_SRAM_BASE);
        mpu.rasr.write(axi);
        mpu.rnr.write(2);
        mpu.rbar.write(SRAM2_BASE);
        mpu.rasr.write(sram2);
        mpu.ctrl.write(MPU_CTRL_ENABLE_PRIVDEFENA);
    }
    cortex_m::asm::dsb();
    cortex_m::asm::isb();
    scb.enable_icache();
    scb.enable_dcache(cpuid);
}
