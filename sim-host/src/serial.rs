//! The pass-through serial port: a pseudo-terminal a user attaches a terminal program to
//! (`--serial pty`), a loopback that echoes what is written (`--serial loopback`), or no
//! port at all (`--serial none`).
//!
//! Received bytes wait in a pipe that a reader thread (pty) or the write path (loopback)
//! fills; a full pipe drops bytes, as a UART overruns. Writes take the line time of the
//! configured baud rate in simulated time.

use std::os::fd::{AsRawFd, FromRawFd, OwnedFd};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use arm_core::hw::{Clock, SerialError, SerialPort};
use embassy_futures::select::{Either, select};
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::pipe::Pipe;
use embassy_sync::signal::Signal;
use protocol::UartInit;

use crate::clock::SimClock;

/// Bytes received and not yet read: 16 frames of 255 bytes, like a deep DMA ring.
const RX_CAPACITY: usize = 4096;

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
            let fd = master.as_raw_fd();
            std::thread::Builder::new()
                .name("serial-pty".into())
                .spawn(move || serial.pty_reader(fd))?;
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

    fn pty_reader(&self, fd: i32) {
        let mut buf = [0u8; 512];
        loop {
            let mut poll = libc::pollfd {
                fd,
                events: libc::POLLIN,
                revents: 0,
            };
            // SAFETY: one valid pollfd; the fd lives as long as `self` ('static).
            let ready = unsafe { libc::poll(&mut poll, 1, 1000) };
            if ready <= 0 {
                continue;
            }
            // SAFETY: reading into a buffer we own, of its length.
            let n = unsafe { libc::read(fd, buf.as_mut_ptr().cast(), buf.len()) };
            if n > 0 {
                self.receive(&buf[..n as usize]);
            } else {
                std::thread::sleep(std::time::Duration::from_millis(10));
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
        let mut n = match select(self.rx.read(buf), self.closed.wait()).await {
            Either::First(n) => n,
            Either::Second(()) => return Err(SerialError::Closed),
        };
        // Then what follows until the line has been idle for one byte time.
        while n < buf.len() {
            let idle_at = (self.clock.now_ns() + self.byte_time_ns()).div_ceil(1000);
            let more = select(self.rx.read(&mut buf[n..]), self.clock.sleep_until(idle_at));
            match more.await {
                Either::First(m) => n += m,
                Either::Second(()) => break,
            }
        }
        Ok(n)
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
        // SAFETY: writing from a slice we borrow, of its length, to an open fd.
        let n = unsafe { libc::write(master.as_raw_fd(), rest.as_ptr().cast(), rest.len()) };
        if n <= 0 {
            counters
                .dropped
                .fetch_add(rest.len() as u64, Ordering::Relaxed);
            log::debug!("serial: pty full or closed, {} bytes dropped", rest.len());
            return;
        }
        rest = &rest[n as usize..];
    }
}

/// Opens a pseudo-terminal in raw mode; returns master, slave (kept open so that reads on
/// the master do not fail while no terminal is attached) and the slave's path.
fn open_pty() -> std::io::Result<(OwnedFd, OwnedFd, String)> {
    let mut master: libc::c_int = -1;
    let mut slave: libc::c_int = -1;
    // SAFETY: openpty writes two fds; name, termios and winsize may be null.
    let rc = unsafe {
        libc::openpty(
            &mut master,
            &mut slave,
            std::ptr::null_mut(),
            std::ptr::null(),
            std::ptr::null(),
        )
    };
    if rc != 0 {
        return Err(std::io::Error::last_os_error());
    }
    // SAFETY: openpty succeeded: both fds are open and ours.
    let (master, slave) = unsafe { (OwnedFd::from_raw_fd(master), OwnedFd::from_raw_fd(slave)) };
    // SAFETY: termios is plain data; tcgetattr fills it from an open tty fd.
    unsafe {
        let mut termios: libc::termios = std::mem::zeroed();
        if libc::tcgetattr(slave.as_raw_fd(), &mut termios) == 0 {
            libc::cfmakeraw(&mut termios);
            libc::tcsetattr(slave.as_raw_fd(), libc::TCSANOW, &termios);
        }
        let flags = libc::fcntl(master.as_raw_fd(), libc::F_GETFL);
        libc::fcntl(master.as_raw_fd(), libc::F_SETFL, flags | libc::O_NONBLOCK);
    }
    let mut name = [0 as libc::c_char; 128];
    // SAFETY: ttyname_r writes a NUL-terminated name into our buffer of its length.
    let rc = unsafe { libc::ttyname_r(slave.as_raw_fd(), name.as_mut_ptr(), name.len()) };
    let path = if rc == 0 {
        // SAFETY: ttyname_r succeeded, so `name` holds a NUL-terminated string.
        unsafe { std::ffi::CStr::from_ptr(name.as_ptr()) }
            .to_string_lossy()
            .into_owned()
    } else {
        "(unknown pty)".to_string()
    };
    Ok((master, slave, path))
}
