//! CMSDK APB UART registers (ARM DDI 0479, QEMU `hw/char/cmsdk-apb-uart.c`).

use crate::mps2::{SYSCLK_HZ, read, write};

/// Data (one byte).
pub const DATA: usize = 0x00;
/// State: TX full (0), RX full (1).
pub const STATE: usize = 0x04;
/// Control: TX enable (0), RX enable (1), TX interrupt (2), RX interrupt (3).
pub const CTRL: usize = 0x08;
/// Interrupt status / clear: TX (0), RX (1).
pub const INT: usize = 0x0C;
/// Baud rate divider (at least 16).
pub const BAUDDIV: usize = 0x10;

/// STATE: the transmit buffer is full.
pub const STATE_TX_FULL: u32 = 1;
/// STATE: a received byte waits.
pub const STATE_RX_FULL: u32 = 1 << 1;
/// CTRL: transmitter on.
pub const CTRL_TX: u32 = 1;
/// CTRL: receiver on.
pub const CTRL_RX: u32 = 1 << 1;
/// CTRL: interrupt when the transmit buffer empties.
pub const CTRL_TX_IRQ: u32 = 1 << 2;
/// CTRL: interrupt when a byte arrives.
pub const CTRL_RX_IRQ: u32 = 1 << 3;
/// INT: transmit.
pub const INT_TX: u32 = 1;
/// INT: receive.
pub const INT_RX: u32 = 1 << 1;

/// The divider for `baud` (the UART samples at SYSCLK / divider), at least 16.
pub fn divider(baud: u32) -> u32 {
    (SYSCLK_HZ / baud.max(1)).max(16)
}

/// Writes `bytes` by polling (the log; interrupts may be off).
pub fn write_blocking(base: usize, bytes: &[u8]) {
    for &b in bytes {
        while read(base, STATE) & STATE_TX_FULL != 0 {}
        write(base, DATA, u32::from(b));
    }
}
