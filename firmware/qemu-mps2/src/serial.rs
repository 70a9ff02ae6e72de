//! The serial pass-through on CMSDK UART 1 (QEMU connects it to a chardev: a socket or a
//! pty for a test to talk to).
//!
//! Receive is interrupt-driven into a ring ([`RX_RING_BYTES`]): a read that is cancelled
//! (the serial task races every read against its batch deadline) loses no byte, it stays in
//! the ring. A read returns once at least one byte is there and the line has then been
//! idle for one byte time, or the buffer is full. Transmit writes the UART's one-byte
//! buffer and waits for its interrupt when it is full.
//!
//! The CMSDK UART only frames 8N1; QEMU's chardev has no framing at all, so any valid
//! setting is accepted (and its byte time used for batching); hardware flow control and
//! baud rates outside the protocol's range are refused.

use core::cell::{Cell, RefCell};
use core::future::poll_fn;
use core::task::Poll;

use arm_core::hw::{SerialError, SerialPort};
use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::waitqueue::AtomicWaker;
use embassy_time::{Duration, Timer};
use heapless::Deque;
use protocol::{UartInit, UartMode};

use crate::mps2::{self, Irq, UART1, read, write};
use crate::uart;

/// Bytes buffered from the line: at 115200 baud 1 KiB is 89 ms, far beyond the serial
/// task's 1 ms batching delay.
pub const RX_RING_BYTES: usize = 1024;

/// The port's state, shared with the interrupts.
struct PortState {
    /// Bytes received and not yet read.
    ring: Deque<u8, RX_RING_BYTES>,
    /// Settings while open.
    open: Option<UartInit>,
    /// Bytes dropped because the ring was full.
    overruns: u32,
}

static PORT: Mutex<CriticalSectionRawMutex, RefCell<PortState>> =
    Mutex::new(RefCell::new(PortState {
        ring: Deque::new(),
        open: None,
        overruns: 0,
    }));
/// Woken when a byte arrives or the port closes.
static RX_WAKER: AtomicWaker = AtomicWaker::new();
/// Woken when the transmit buffer empties.
static TX_WAKER: AtomicWaker = AtomicWaker::new();
/// Overruns already logged.
static LOGGED_OVERRUNS: Mutex<CriticalSectionRawMutex, Cell<u32>> = Mutex::new(Cell::new(0));

/// The pass-through port ([`SerialPort`]).
pub struct QemuSerial {
    _private: (),
}

impl QemuSerial {
    /// The port, closed; its interrupts enabled.
    pub fn new() -> Self {
        write(UART1, uart::CTRL, 0);
        write(UART1, uart::INT, uart::INT_TX | uart::INT_RX);
        mps2::enable(Irq::Uart1Rx, mps2::priority::DRIVERS);
        mps2::enable(Irq::Uart1Tx, mps2::priority::DRIVERS);
        QemuSerial { _private: () }
    }

    fn settings(&self) -> Option<UartInit> {
        PORT.lock(|p| p.borrow().open)
    }
}

impl SerialPort for QemuSerial {
    fn open(&self, init: &UartInit) -> Result<(), SerialError> {
        // The controller refused settings the board's USART cannot make (arm_core::uart)
        // before calling this: the same ones here.
        let ctrl = match init.mode() {
            UartMode::TransmitReceive => uart::CTRL_TX | uart::CTRL_RX | uart::CTRL_RX_IRQ,
            UartMode::ReceiveOnly => uart::CTRL_RX | uart::CTRL_RX_IRQ,
            UartMode::TransmitOnly => uart::CTRL_TX,
        };
        PORT.lock(|p| {
            let mut p = p.borrow_mut();
            p.ring.clear();
            p.open = Some(*init);
            write(UART1, uart::BAUDDIV, uart::divider(init.baud_rate));
            write(UART1, uart::CTRL, ctrl);
        });
        RX_WAKER.wake();
        Ok(())
    }

    fn close(&self) {
        PORT.lock(|p| {
            let mut p = p.borrow_mut();
            p.open = None;
            p.ring.clear();
            write(UART1, uart::CTRL, 0);
        });
        RX_WAKER.wake();
        TX_WAKER.wake();
    }

    async fn read(&self, buf: &mut [u8]) -> Result<usize, SerialError> {
        // At least one byte.
        poll_fn(|cx| {
            RX_WAKER.register(cx.waker());
            PORT.lock(|p| {
                let p = p.borrow();
                match p.open {
                    None => Poll::Ready(Err(SerialError::Closed)),
                    Some(_) if p.ring.is_empty() => Poll::Pending,
                    Some(_) => Poll::Ready(Ok(())),
                }
            })
        })
        .await?;
        // Then until the line is idle for a byte time or `buf` would be full.
        let byte_us = self
            .settings()
            .map_or(100, |init| arm_core::serial::byte_time_us(&init).max(1));
        loop {
            let before = PORT.lock(|p| p.borrow().ring.len());
            if before >= buf.len() {
                break;
            }
            Timer::after(Duration::from_micros(u64::from(byte_us))).await;
            let after = PORT.lock(|p| p.borrow().ring.len());
            if after == before {
                break;
            }
        }
        let (n, overruns) = PORT.lock(|p| {
            let mut p = p.borrow_mut();
            if p.open.is_none() {
                return (None, p.overruns);
            }
            let mut n = 0;
            // `zip` asks `buf` first: no byte leaves the ring once `buf` is full.
            for (slot, b) in buf
                .iter_mut()
                .zip(core::iter::from_fn(|| p.ring.pop_front()))
            {
                *slot = b;
                n += 1;
            }
            (Some(n), p.overruns)
        });
        let logged = LOGGED_OVERRUNS.lock(|l| l.replace(overruns));
        if overruns != logged {
            log::warn!(
                "serial: {} bytes lost (receive ring full)",
                overruns - logged
            );
        }
        n.ok_or(SerialError::Closed)
    }

    async fn write(&self, bytes: &[u8]) -> Result<(), SerialError> {
        for &b in bytes {
            poll_fn(|cx| {
                if self.settings().is_none() {
                    return Poll::Ready(Err(SerialError::Closed));
                }
                TX_WAKER.register(cx.waker());
                let sent = critical_section::with(|_| {
                    if read(UART1, uart::STATE) & uart::STATE_TX_FULL == 0 {
                        write(UART1, uart::DATA, u32::from(b));
                        true
                    } else {
                        // Wake on the buffer emptying.
                        write(
                            UART1,
                            uart::CTRL,
                            read(UART1, uart::CTRL) | uart::CTRL_TX_IRQ,
                        );
                        false
                    }
                });
                if sent {
                    Poll::Ready(Ok(()))
                } else {
                    Poll::Pending
                }
            })
            .await?;
        }
        Ok(())
    }
}

/// UART 1 received a byte.
pub fn on_rx_interrupt() {
    PORT.lock(|p| {
        let mut p = p.borrow_mut();
        write(UART1, uart::INT, uart::INT_RX);
        while read(UART1, uart::STATE) & uart::STATE_RX_FULL != 0 {
            // The received byte is DATA's low 8 bits.
            let [byte, ..] = read(UART1, uart::DATA).to_le_bytes();
            if p.ring.push_back(byte).is_err() {
                p.overruns = p.overruns.wrapping_add(1);
            }
        }
    });
    RX_WAKER.wake();
}

/// UART 1's transmit buffer emptied.
pub fn on_tx_interrupt() {
    critical_section::with(|_| {
        write(UART1, uart::INT, uart::INT_TX);
        write(
            UART1,
            uart::CTRL,
            read(UART1, uart::CTRL) & !uart::CTRL_TX_IRQ,
        );
    });
    TX_WAKER.wake();
}
