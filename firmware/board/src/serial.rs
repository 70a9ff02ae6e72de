//! The serial pass-through: USART6 on PC6 (TX) / PC7 (RX) with DMA in both directions.
//!
//! Reception runs continuously into a DMA ring buffer, so a read that is cancelled (the
//! serial task races every read against its 1 ms batch deadline) loses no byte: what
//! arrived stays in the ring for the next read. A read returns as soon as the line goes
//! idle or the ring is half full.
//!
//! `open` and `close` are synchronous and may come while a read or a write is waiting, so
//! they only record the wanted settings and bump a generation count; each half applies
//! the newest settings before its next transfer (the USART's registers are shared, either
//! half can reconfigure it), and a waiting read is woken to do so. A read started on a
//! closed port, or woken by a close, returns [`SerialError::Closed`].

use core::cell::Cell;

use arm_core::hw::SerialError;
use defmt::warn;
use embassy_futures::select::{Either, select};
use embassy_stm32::mode::Async;
use embassy_stm32::usart::{Config, DataBits, Parity, RingBufferedUartRx, StopBits, Uart, UartTx};
use embassy_sync::blocking_mutex::Mutex as BlockingMutex;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::mutex::Mutex;
use embassy_sync::signal::Signal;
use protocol::{UartInit, UartMode, limits};

/// Bytes of the receive DMA ring: at the 4 Mbaud maximum a byte takes 2.5 us, so 1 KiB is
/// 2.5 ms of line time, more than twice the serial task's 1 ms batching delay.
pub const RX_RING_BYTES: usize = 1024;

/// STM32F4 HAL codes in `UartInit` (docs/PROTOCOL.md, "UartInit (28 bytes)").
mod hal {
    /// UART_WORDLENGTH_9B: 9 bits on the line (8 data + parity, or 9 data).
    pub const WORD_9B: u32 = 0x1000;
    /// UART_STOPBITS_2.
    pub const STOP_2: u32 = 0x2000;
    /// UART_PARITY_EVEN.
    pub const PARITY_EVEN: u32 = 0x0400;
    /// UART_PARITY_ODD.
    pub const PARITY_ODD: u32 = 0x0600;
    /// UART_OVERSAMPLING_8.
    pub const OVERSAMPLING_8: u32 = 0x8000;
}

/// The embassy configuration for `init`, or why this board cannot apply it.
///
/// The HAL counts the parity bit in the word length, embassy does not: an 8-bit frame with
/// parity is 7 data bits. Hardware flow control is refused (no RTS/CTS pins are wired).
/// Oversampling is chosen by the driver for the baud rate, so both HAL values are
/// accepted.
pub fn uart_config(init: &UartInit) -> Result<Config, SerialError> {
    if !limits::BAUD_RATE.contains(&init.baud_rate) || init.hw_flow_ctl != 0 {
        return Err(SerialError::Unsupported);
    }
    if init.over_sampling != 0 && init.over_sampling != hal::OVERSAMPLING_8 {
        return Err(SerialError::Unsupported);
    }
    let parity = match init.parity {
        0 => Parity::ParityNone,
        hal::PARITY_EVEN => Parity::ParityEven,
        hal::PARITY_ODD => Parity::ParityOdd,
        _ => return Err(SerialError::Unsupported),
    };
    let with_parity = parity != Parity::ParityNone;
    let data_bits = match (init.word_length, with_parity) {
        (0, false) => DataBits::DataBits8,
        (0, true) => DataBits::DataBits7,
        (hal::WORD_9B, false) => DataBits::DataBits9,
        (hal::WORD_9B, true) => DataBits::DataBits8,
        _ => return Err(SerialError::Unsupported),
    };
    let stop_bits = match init.stop_bits {
        0 => StopBits::STOP1,
        hal::STOP_2 => StopBits::STOP2,
        _ => return Err(SerialError::Unsupported),
    };
    let mut config = Config::default();
    config.baudrate = init.baud_rate;
    config.data_bits = data_bits;
    config.parity = parity;
    config.stop_bits = stop_bits;
    Ok(config)
}

/// What `open`/`close` last asked for.
#[derive(Clone, Copy)]
struct Wanted {
    /// Bumped by every `open` and `close`.
    generation: u32,
    /// The settings of the open port (already checked by [`uart_config`]); `None`: closed.
    open: Option<UartInit>,
}

/// A half of the port and the settings generation it last applied.
struct Half<T> {
    io: T,
    applied: u32,
}

/// The pass-through port ([`arm_core::hw::SerialPort`]).
pub struct BoardSerial {
    tx: Mutex<CriticalSectionRawMutex, Half<UartTx<'static, Async>>>,
    rx: Mutex<CriticalSectionRawMutex, Half<RingBufferedUartRx<'static>>>,
    wanted: BlockingMutex<CriticalSectionRawMutex, Cell<Wanted>>,
    /// Raised by `open`/`close`: a waiting read re-checks the settings.
    changed: Signal<CriticalSectionRawMutex, ()>,
}

impl BoardSerial {
    /// Splits the UART; reception starts into `ring` with the first read after an `open`.
    pub fn new(uart: Uart<'static, Async>, ring: &'static mut [u8; RX_RING_BYTES]) -> Self {
        let (tx, rx) = uart.split();
        BoardSerial {
            tx: Mutex::new(Half { io: tx, applied: 0 }),
            rx: Mutex::new(Half {
                io: rx.into_ring_buffered(ring),
                applied: 0,
            }),
            wanted: BlockingMutex::new(Cell::new(Wanted {
                generation: 0,
                open: None,
            })),
            changed: Signal::new(),
        }
    }

    fn wanted(&self) -> Wanted {
        self.wanted.lock(|w| w.get())
    }

    fn set_wanted(&self, open: Option<UartInit>) {
        self.wanted.lock(|w| {
            let generation = w.get().generation.wrapping_add(1);
            w.set(Wanted { generation, open });
        });
        self.changed.signal(());
    }
}

impl arm_core::hw::SerialPort for BoardSerial {
    fn open(&self, init: &UartInit) -> Result<(), SerialError> {
        uart_config(init)?;
        self.set_wanted(Some(*init));
        Ok(())
    }

    fn close(&self) {
        self.set_wanted(None);
    }

    async fn read(&self, buf: &mut [u8]) -> Result<usize, SerialError> {
        let mut rx = self.rx.lock().await;
        loop {
            // Reset before looking, so that an open or close from now on wakes the wait.
            self.changed.reset();
            let wanted = self.wanted();
            let Some(init) = wanted.open else {
                return Err(SerialError::Closed);
            };
            if rx.applied != wanted.generation {
                let config = uart_config(&init)?;
                rx.io
                    .set_config(&config)
                    .map_err(|_| SerialError::Unsupported)?;
                rx.applied = wanted.generation;
                // Bytes from before this open belong to no one: drop them.
                drain(&mut rx.io);
            }
            match select(rx.io.read(buf), self.changed.wait()).await {
                Either::First(Ok(n)) => return Ok(n),
                Either::First(Err(e)) => {
                    warn!("serial receive: {}", e);
                    return Err(SerialError::Line);
                }
                // Reopened or closed while waiting: look again.
                Either::Second(()) => {}
            }
        }
    }

    async fn write(&self, bytes: &[u8]) -> Result<(), SerialError> {
        let mut tx = self.tx.lock().await;
        let wanted = self.wanted();
        let Some(init) = wanted.open else {
            return Err(SerialError::Closed);
        };
        if init.mode() == UartMode::ReceiveOnly {
            return Err(SerialError::Unsupported);
        }
        if tx.applied != wanted.generation {
            let config = uart_config(&init)?;
            tx.io
                .set_config(&config)
                .map_err(|_| SerialError::Unsupported)?;
            tx.applied = wanted.generation;
        }
        tx.io.write(bytes).await.map_err(|e| {
            warn!("serial transmit: {}", e);
            SerialError::Line
        })
    }
}

/// Reads and discards what the ring holds now, without waiting for more.
fn drain(rx: &mut RingBufferedUartRx<'static>) {
    let mut scratch = [0u8; 64];
    // Bounded: the ring holds RX_RING_BYTES at most, and more may keep arriving.
    for _ in 0..RX_RING_BYTES / scratch.len() + 1 {
        match embassy_futures::poll_once(rx.read(&mut scratch)) {
            core::task::Poll::Ready(Ok(n)) if n > 0 => {}
            _ => return,
        }
    }
}
