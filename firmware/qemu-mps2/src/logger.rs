//! Text logs on UART 0 (`-serial` of QEMU: a file or stdout), through the `log` crate that
//! arm-core, arm-wiring and embassy-net log to with their `log` feature.
//!
//! Each line is `[seconds.micros] LEVEL message` and is written whole inside a critical
//! section by polling the UART, so lines from interrupts and tasks never interleave and a
//! fault handler can still log.

use core::fmt::Write;

use crate::mps2::{UART0, write};
use crate::uart;

struct Uart0;

impl Write for Uart0 {
    fn write_str(&mut self, s: &str) -> core::fmt::Result {
        uart::write_blocking(UART0, s.as_bytes());
        Ok(())
    }
}

struct Logger;

impl log::Log for Logger {
    fn enabled(&self, metadata: &log::Metadata<'_>) -> bool {
        metadata.level() <= log::max_level()
    }

    fn log(&self, record: &log::Record<'_>) {
        if !self.enabled(record.metadata()) {
            return;
        }
        let us = crate::time_driver::now_cycles() / u64::from(crate::mps2::SYSCLK_HZ / 1_000_000);
        critical_section::with(|_| {
            let _ = write!(
                Uart0,
                "[{:>4}.{:06}] {:<5} {}\r\n",
                us / 1_000_000,
                us % 1_000_000,
                record.level(),
                record.args()
            );
        });
    }

    fn flush(&self) {}
}

static LOGGER: Logger = Logger;

/// Turns UART 0's transmitter on and installs the logger (info and above).
pub fn init() {
    write(UART0, uart::BAUDDIV, uart::divider(115_200));
    write(UART0, uart::CTRL, uart::CTRL_TX);
    if log::set_logger(&LOGGER).is_ok() {
        log::set_max_level(log::LevelFilter::Info);
    }
}

/// Writes `args` as one line, bypassing `log` (the fault handlers).
pub fn raw(args: core::fmt::Arguments<'_>) {
    critical_section::with(|_| {
        let _ = Uart0.write_fmt(args);
        let _ = Uart0.write_str("\r\n");
    });
}
