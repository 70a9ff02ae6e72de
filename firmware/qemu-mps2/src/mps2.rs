//! The MPS2 AN500 memory map and interrupt numbers (QEMU `hw/arm/mps2.c`, ARM AN500), and
//! the interrupt vector table.

use cortex_m::interrupt::InterruptNumber;

/// SYSCLK, which clocks the APB peripherals (timers, UARTs).
pub const SYSCLK_HZ: u32 = 25_000_000;

/// CMSDK APB timer 0: the free-running time base.
pub const TIMER0: usize = 0x4000_0000;
/// CMSDK APB timer 1: embassy-time's alarm.
pub const TIMER1: usize = 0x4000_1000;
/// CMSDK APB dual timer: the step timer (its first counter).
pub const DUALTIMER: usize = 0x4000_2000;
/// CMSDK APB UART 0: the log.
pub const UART0: usize = 0x4000_4000;
/// CMSDK APB UART 1: the serial pass-through.
pub const UART1: usize = 0x4000_5000;

/// External interrupts of the AN500 this firmware uses (NVIC numbers).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u16)]
pub enum Irq {
    /// UART 1 receive.
    Uart1Rx = 2,
    /// UART 1 transmit.
    Uart1Tx = 3,
    /// Timer 0 (time base wrap).
    Timer0 = 8,
    /// Timer 1 (alarm).
    Timer1 = 9,
    /// Dual timer (step timer).
    DualTimer = 10,
    /// The LAN9118 Ethernet controller.
    Ethernet = 13,
}

// SAFETY: every value is an interrupt number the AN500's NVIC has (it has 32).
unsafe impl InterruptNumber for Irq {
    fn number(self) -> u16 {
        self as u16
    }
}

/// Priorities (upper bits of the 8-bit field; QEMU implements all 8, the AN500 FPGA 3):
/// the step timer above time, time above the drivers.
pub mod priority {
    /// Step timer: edges at exact ticks; nothing may delay it.
    pub const STEP: u8 = 0x00;
    /// embassy-time's time base and alarm.
    pub const TIME: u8 = 0x40;
    /// Ethernet and the serial port: driver bookkeeping; their tasks wait anyway.
    pub const DRIVERS: u8 = 0x60;
}

/// Enables `irq` at `priority`.
pub fn enable(irq: Irq, priority: u8) {
    // SAFETY: called during bring-up, before the executor runs; the NVIC registers
    // touched are those of `irq` alone.
    unsafe {
        let mut nvic = cortex_m::Peripherals::steal().NVIC;
        nvic.set_priority(irq, priority);
        cortex_m::peripheral::NVIC::unmask(irq);
    }
}

/// One entry of the vector table.
#[derive(Clone, Copy)]
pub union Vector {
    handler: unsafe extern "C" fn(),
    reserved: usize,
}

unsafe extern "C" {
    fn DefaultHandler();
}

extern "C" fn uart1_rx() {
    crate::serial::on_rx_interrupt();
}

extern "C" fn uart1_tx() {
    crate::serial::on_tx_interrupt();
}

extern "C" fn timer0() {
    crate::time_driver::on_wrap_interrupt();
}

extern "C" fn timer1() {
    crate::time_driver::on_alarm_interrupt();
}

extern "C" fn dualtimer() {
    crate::step_out::on_interrupt();
}

extern "C" fn ethernet() {
    crate::lan9118::on_interrupt();
}

const fn handler(f: unsafe extern "C" fn()) -> Vector {
    Vector { handler: f }
}

/// Unused lines go to cortex-m-rt's `DefaultHandler` (which the fault module makes fatal).
const DEFAULT: Vector = Vector {
    handler: DefaultHandler,
};

/// The external interrupt vectors (cortex-m-rt's `device` feature: the board provides them).
#[unsafe(link_section = ".vector_table.interrupts")]
#[unsafe(no_mangle)]
pub static __INTERRUPTS: [Vector; 32] = {
    let mut table = [DEFAULT; 32];
    #[allow(
        clippy::indexing_slicing,
        reason = "const initialiser: an index past the table is a compile error"
    )]
    {
        table[Irq::Uart1Rx as usize] = handler(uart1_rx);
        table[Irq::Uart1Tx as usize] = handler(uart1_tx);
        table[Irq::Timer0 as usize] = handler(timer0);
        table[Irq::Timer1 as usize] = handler(timer1);
        table[Irq::DualTimer as usize] = handler(dualtimer);
        table[Irq::Ethernet as usize] = handler(ethernet);
    }
    let _ = Vector { reserved: 0 };
    table
};

/// A 32-bit peripheral register at `base + offset`.
pub fn read(base: usize, offset: usize) -> u32 {
    // SAFETY: callers pass the base of a peripheral of this board and one of its register
    // offsets: an aligned, mapped 32-bit register.
    unsafe { core::ptr::read_volatile((base + offset) as *const u32) }
}

/// Writes the 32-bit peripheral register at `base + offset`.
pub fn write(base: usize, offset: usize, value: u32) {
    // SAFETY: as in `read`.
    unsafe { core::ptr::write_volatile((base + offset) as *mut u32, value) }
}
