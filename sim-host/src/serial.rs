//! The pass-through serial port: a pseudo-terminal a user attaches a terminal program to
//! (`--serial pty`), a loopback that echoes what is written (`--serial loopback`), or no
//! port at all (`--serial none`).
//!
//! Received bytes wait in a pipe that a reader thread (pty) or the write path (loopback)
//! fills; a full pipe drops bytes, as a UART overruns. Writes take the line time of the
//! configured baud rate in simulated time.

use std::os::fd::{AsFd, BorrowedFd, OwnedFd};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use arm_core::hw::{Clock, SerialError, SerialPort};
use embassy_futures::select::{Either, select};
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::pipe::Pipe;
use embassy_sync::signal::Signal;
use nix::fcntl::{FcntlArg, OFlag, fcntl};
use nix::poll::{PollFd, PollFlags, PollTimeout, poll};
use nix::pty::{OpenptyResult, openpty};
use nix::sys::termios::{self, SetArg};
use protocol::UartInit;

use crate::clock::SimClock;

/// Bytes received and not yet read: 16 frames of 255 bytes, like a deep DMA ring.
const RX_CAPACITY: usize = 4096;

/// Bytes the pty reader takes at a time before it waits for the line to have carried
/// them: 64 byte times (5.6 ms at 115200 baud), far less than the ring holds.
const PTY_CHUNK: usize = 64;

/// Which simulated port.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum SerialKind {
    /// A pseudo-terminal; its path is printed at start.
    Pty,
    /// What is written is read back.
    Loopback,
    /// No serial port: USART_START is refused.
    None,
}

enum Backend {
    Pty { master: OwnedFd, _slave: OwnedFd },
    Loopback,
    None,
}

/// Byte counts for the log and tests.
#[derive(Debug, Default)]
pub struct SerialCounters {
    /// Bytes written to the line.
    pub written: AtomicU64,
    /// Bytes received from the line.
    pub received: AtomicU64,
    /// Bytes dropped because the receive pipe was full or the port closed.
    pub dropped: AtomicU64,
}

/// [`SerialPort`] for the simulator. `'static` (leaked once at start) because the pty
/// reader thread and the tasks share it.
pub struct SimSerial {
    backend: Backend,
    open: AtomicBool,
    settings: Mutex<Option<UartInit>>,
    rx: Pipe<CriticalSectionRawMutex, RX_CAPACITY>,
    closed: Signal<CriticalSectionRawMutex, ()>,
    clock: SimClock,
    counters: Arc<SerialCounters>,
    pty_path: Option<String>,
}

impl std::fmt::Debug for SimSerial {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SimSerial")
            .field("open", &self.open.load(Ordering::Relaxed))
            .field("pty_path", &self.pty_path)
            .finish()
    }
}

impl SimSerial {
    /// Creates the port (and for a pty, its reader thread).
    pub fn create(kind: SerialKind, clock: SimClock) -> std::io::Result<&'static SimSerial> {
        let (backend, pty_path) = match kind {
            SerialKind::Pty => {
                let (master, slave, path) = open_pty()?;
                (
                    Backend::Pty {
                        master,
                        _slave: slave,
                    },
                    Some(path),
                )
            }
            SerialKind::Loopback => (Backend::Loopback, None),
            SerialKind::None => (Backend::None, None),
        };
        let serial: &'static SimSerial = Box::leak(Box::new(SimSerial {
            backend,
            open: AtomicBool::new(false),
            settings: Mutex::new(None),
            rx: Pipe::new(),
            closed: Signal::new(),
            clock,
            counters: Arc::new(SerialCounters::default()),
            pty_path,
        }));
        if let Backend::Pty { master, .. } = &serial.backend {
            std::thread::Builder::new()
                .name("serial-pty".into())
                .spawn(move || serial.pty_reader(master.as_fd()))?;
        }
        Ok(serial)
    }

    /// The pty's path (`/dev/pts/N`) for a terminal program, with `--serial pty`.
    pub fn pty_path(&self) -> Option<&str> {
        self.pty_path.as_deref()
    }

    /// Byte counters.
    pub fn counters(&self) -> &Arc<SerialCounters> {
        &self.counters
    }

    /// Settings of the open port.
    pub fn settings(&self) -> Option<UartInit> {
        self.settings.lock().ok().and_then(|s| *s)
    }

    /// Simulated nanoseconds one byte takes on the line.
    fn byte_time_ns(&self) -> u64 {
        let init = self.settings().unwrap_or(UartInit {
            baud_rate: 115_200,
            ..UartInit::default()
        });
        u64::from(init.bits_per_byte()) * 1_000_000_000 / u64::from(init.baud_rate.max(1))
    }

    /// Bytes arriving from the line.
    fn receive(&self, bytes: &[u8]) {
        if !self.open.load(Ordering::Relaxed) {
            self.counters
                .dropped
                .fetch_add(bytes.len() as u64, Ordering::Relaxed);
            return;
        }
        let taken = self.rx.try_write(bytes).unwrap_or(0);
        self.counters
            .received
            .fetch_add(taken as u64, Ordering::Relaxed);
        if taken < bytes.len() {
            self.counters
                .dropped
                .fetch_add((bytes.len() - taken) as u64, Ordering::Relaxed);
            log::warn!(
                "serial: receive overrun, {} bytes dropped",
                bytes.len() - taken
            );
        }
    }

    /// Reads the pty at the line's rate: each chunk of [`PTY_CHUNK`] bytes is taken only
    /// once the line could have carried the one before (a byte time each, at the open
    /// port's baud rate). Bytes written faster wait in the pty's own buffer, and the
    /// writer blocks when it is full, as a device waits on a real line; the receive ring
    /// sees no more than the board's UART would (issue 21 F18: read as fast as the pty
    /// gave them, 10,200 bytes at once overran the 4 KiB ring and 6,104 were dropped).
    fn pty_reader(&self, master: BorrowedFd<'_>) {
        let mut buf = [0u8; PTY_CHUNK];
        loop {
            let mut ready = [PollFd::new(master, PollFlags::POLLIN)];
            if !matches!(poll(&mut ready, PollTimeout::from(1000u16)), Ok(n) if n > 0) {
                continue;
            }
            match nix::unistd::read(master, &mut buf) {
                Ok(n) if n > 0 => {
                    let started_ns = self.clock.now_ns();
                    self.receive(&buf[..n]);
                    if self.open.load(Ordering::Relaxed) {
                        let busy_ns = n as u64 * self.byte_time_ns();
                        let free_at = self.clock.real_instant_of_ns(started_ns + busy_ns);
                        let wait = free_at.saturating_duration_since(std::time::Instant::now());
                        if !wait.is_zero() {
                            std::thread::sleep(wait);
                        }
                    }
                }
                // Nothing yet (non-blocking), or an error while no terminal is attached.
                _ => std::thread::sleep(std::time::Duration::from_millis(10)),
            }
        }
    }
}

impl SerialPort for SimSerial {
    fn open(&self, init: &UartInit) -> Result<(), SerialError> {
        if matches!(self.backend, Backend::None) {
            return Err(SerialError::Unsupported);
        }
        if let Ok(mut settings) = self.settings.lock() {
            *settings = Some(*init);
        }
        self.rx.clear();
        self.closed.reset();
        self.open.store(true, Ordering::Relaxed);
        log::info!(
            "serial: open at {} baud, mode {:?}{}",
            init.baud_rate,
            init.mode(),
            self.pty_path
                .as_deref()
                .map(|p| format!(" on {p}"))
                .unwrap_or_else(|| " (loopback)".into())
        );
        Ok(())
    }

    fn close(&self) {
        if self.open.swap(false, Ordering::Relaxed) {
            log::info!("serial: closed");
        }
        self.closed.signal(());
    }

    async fn read(&self, buf: &mut [u8]) -> Result<usize, SerialError> {
        if !self.open.load(Ordering::Relaxed) {
            return Err(SerialError::Closed);
        }
        if buf.is_empty() {
            return Ok(0);
        }
        // What the ring holds now, and no more: the serial task batches by the line's idle
        // time itself. Returning at once keeps this read cancel-safe (the trait asks it):
        // it used to go on reading until the line was idle, and when the task's own
        // deadline dropped it there, the bytes it had taken were lost, uncounted (issue
        // 21 F18: 64-192 of 10,200 under load).
        match select(self.rx.read(buf), self.closed.wait()).await {
            Either::First(n) => Ok(n),
            Either::Second(()) => Err(SerialError::Closed),
        }
    }

    async fn write(&self, bytes: &[u8]) -> Result<(), SerialError> {
        if !self.open.load(Ordering::Relaxed) {
            return Err(SerialError::Closed);
        }
        // The bytes take their time on the line.
        let done_at = self.clock.now_ns() + self.byte_time_ns() * bytes.len() as u64;
        match &self.backend {
            Backend::Loopback => self.receive(bytes),
            Backend::Pty { master, .. } => write_nonblocking(master, bytes, &self.counters),
            Backend::None => return Err(SerialError::Closed),
        }
        self.counters
            .written
            .fetch_add(bytes.len() as u64, Ordering::Relaxed);
        self.clock.sleep_until(done_at.div_ceil(1000)).await;
        Ok(())
    }
}

/// Writes to the pty master without ever blocking the executor: with nobody attached the
/// pty's buffer fills and the rest is dropped, as bytes sent down an unconnected line.
fn write_nonblocking(master: &OwnedFd, bytes: &[u8], counters: &SerialCounters) {
    let mut rest = bytes;
    while !rest.is_empty() {
        match nix::unistd::write(master, rest) {
            Ok(n) if n > 0 => rest = &rest[n..],
            _ => {
                counters
                    .dropped
                    .fetch_add(rest.len() as u64, Ordering::Relaxed);
                log::debug!("serial: pty full or closed, {} bytes dropped", rest.len());
                return;
            }
        }
    }
}

/// Opens a pseudo-terminal in raw mode; returns master (non-blocking), slave (kept open so
/// that reads on the master do not fail while no terminal is attached) and the slave's path.
fn open_pty() -> std::io::Result<(OwnedFd, OwnedFd, String)> {
    let OpenptyResult { master, slave } = openpty(None, None)?;
    // Raw: the bridge passes bytes, not lines; no echo, no CR/LF translation.
    if let Ok(mut termios) = termios::tcgetattr(&slave) {
        termios::cfmakeraw(&mut termios);
        termios::tcsetattr(&slave, SetArg::TCSANOW, &termios)?;
    }
    let flags = OFlag::from_bits_truncate(fcntl(&master, FcntlArg::F_GETFL)?);
    fcntl(&master, FcntlArg::F_SETFL(flags | OFlag::O_NONBLOCK))?;
    let path = nix::unistd::ttyname(&slave).map_or_else(
        |_| "(unknown pty)".to_string(),
        |p| p.to_string_lossy().into_owned(),
    );
    Ok((master, slave, path))
}
