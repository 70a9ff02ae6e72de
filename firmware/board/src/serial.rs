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
use arm_core::uart::{self, uart_frame};
use defmt::warn;
use embassy_futures::select::{Either, select};
use embassy_stm32::mode::Async;
use embassy_stm32::usart::{Config, DataBits, Parity, RingBufferedUartRx, StopBits, Uart, UartTx};
use embassy_sync::blocking_mutex::Mutex as BlockingMutex;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::mutex::Mutex;
use embassy_sync::signal::Signal;
use protocol::{UartInit, UartMode};

/// Bytes of the transmit staging buffer: writes are copied here (non-cacheable SRAM1, see
/// `memory.rs`) chunk by chunk before the DMA reads them, since the caller's bytes live in
/// cacheable AXI SRAM. 256 bytes: a whole USART_SEND payload at once.
pub const TX_STAGING_BYTES: usize = 256;

/// Bytes of the receive DMA ring: at the 4 Mbaud maximum a byte takes 2.5 us, so 1 KiB is
/// 2.5 ms of line time, more than twice the serial task's 1 ms batching delay.
pub const RX_RING_BYTES: usize = 1024;

/// The embassy configuration for `init`, or why this board cannot apply it (the mapping
/// of the HAL codes is `arm_core::uart::uart_frame`, which the controller checks first,
/// tested on the host).
pub fn uart_config(init: &UartInit) -> Result<Config, SerialError> {
    let frame = uart_frame(init)?;
    let mut config = Config::default();
    config.baudrate = frame.baud_rate;
    config.data_bits = match frame.data_bits {
        uart::DataBits::Seven => DataBits::DataBits7,
        uart::DataBits::Eight => DataBits::DataBits8,
        uart::DataBits::Nine => DataBits::DataBits9,
    };
    config.parity = match frame.parity {
        uart::Parity::None => Parity::ParityNone,
        uart::Parity::Even => Parity::ParityEven,
        uart::Parity::Odd => Parity::ParityOdd,
    };
    config.stop_bits = match frame.stop_bits {
        uart::StopBits::One => StopBits::STOP1,
        uart::StopBits::Two => StopBits::STOP2,
    };
    Ok(config)
}

/// What `open`/`close` last asked for.
#[derive(Clone, Copy)]
struct Wanted {
    /// Bumped by every `open` and `close`.
    generation: u32,
    /// The settings of the open port (already checked by the controller); `None`: closed.
    open: Option<UartInit>,
}

/// The transmit half and its DMA-visible staging buffer.
struct TxStaged {
    uart: UartTx<'static, Async>,
    staging: &'static mut [u8; TX_STAGING_BYTES],
}

/// A half of the port and the settings generation it last applied.
struct Half<T> {
    io: T,
    applied: u32,
}

/// The pass-through port ([`arm_core::hw::SerialPort`]).
pub struct BoardSerial {
    tx: Mutex<CriticalSectionRawMutex, Half<TxStaged>>,
    rx: Mutex<CriticalSectionRawMutex, Half<RingBufferedUartRx<'static>>>,
    wanted: BlockingMutex<CriticalSectionRawMutex, Cell<Wanted>>,
    /// Raised by `open`/`close`: a waiting read re-checks the settings.
    changed: Signal<CriticalSectionRawMutex, ()>,
}

impl BoardSerial {
    /// Splits the UART; reception starts into `ring` with the first read after an `open`.
    /// `ring` and `staging` are DMA buffers: they must be in non-cacheable memory.
    pub fn new(
        uart: Uart<'static, Async>,
        ring: &'static mut [u8; RX_RING_BYTES],
        staging: &'static mut [u8; TX_STAGING_BYTES],
    ) -> Self {
        let (tx, rx) = uart.split();
        BoardSerial {
            tx: Mutex::new(Half {
                io: TxStaged { uart: tx, staging },
                applied: 0,
            }),
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
        // The controller refused settings this USART cannot make (`arm_core::uart`)
        // before calling this; each half maps them with `uart_config` when it applies them.
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
                .uart
                .set_config(&config)
                .map_err(|_| SerialError::Unsupported)?;
            tx.applied = wanted.generation;
        }
        let TxStaged { uart, staging } = &mut tx.io;
        for chunk in bytes.chunks(TX_STAGING_BYTES) {
            #[allow(
                clippy::indexing_slicing,
                reason = "a chunk is at most TX_STAGING_BYTES, the staging buffer's length"
            )]
            let staged = &mut staging[..chunk.len()];
            staged.copy_from_slice(chunk);
            uart.write(staged).await.map_err(|e| {
                warn!("serial transmit: {}", e);
                SerialError::Line
            })?;
        }
        Ok(())
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
