//! Harness for the tests of the firmware on QEMU's `mps2-an500` (`tests/tests/qemu.rs`):
//! builds the image (`cargo qemu-fw`), starts `qemu-system-arm` with the LAN9118 on
//! user-mode networking forwarded from a free 127.0.0.1 UDP port, the log UART in a file
//! and the pass-through UART on a free 127.0.0.1 TCP port, and kills QEMU on drop (and,
//! through `PR_SET_PDEATHSIG`, when the test process dies).
//!
//! QEMU's user-mode network sends nothing beyond the host's loopback: the firmware reaches
//! only 10.0.2.2, which QEMU maps to the host.

use std::io::Read;
use std::net::{Ipv4Addr, SocketAddr, SocketAddrV4, TcpListener, TcpStream};
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::{Mutex, MutexGuard};
use std::time::{Duration, Instant};

use armctl::{Client, Options};

/// How long a fresh board gets to answer STATUS (boot takes ~50 ms of emulated time).
const START_TIMEOUT: Duration = Duration::from_secs(20);

/// One board at a time per test process: QEMU emulates on a host core, and timing of a
/// run suffers when the tests' boards compete for the machine's two cores.
static ONE_AT_A_TIME: Mutex<()> = Mutex::new(());

/// The image, built once per test process.
static IMAGE: Mutex<Option<PathBuf>> = Mutex::new(None);

/// Lines in the log that mean the firmware failed.
pub const FAULT_MARKERS: [&str; 4] = ["PANIC", "HARDFAULT", "FAULT:", "FATAL"];

/// `Some(reason)` when QEMU cannot run here: the tests then skip, saying why.
pub fn unavailable() -> Option<String> {
    let found = Command::new("qemu-system-arm")
        .arg("--version")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success());
    (!found).then(|| {
        "SKIPPED: needs qemu-system-arm (Debian: apt-get install -y qemu-system-arm); \
         .ci/run installs it and runs these tests"
            .to_string()
    })
}

/// The repository root (this crate is `tests/`).
fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("tests/ has a parent")
        .to_path_buf()
}

/// The firmware image: `QEMU_FIRMWARE` if set, else built with `cargo qemu-fw` into the
/// test's own target directory (once per process; a no-op when up to date).
pub fn image() -> PathBuf {
    if let Some(path) = std::env::var_os("QEMU_FIRMWARE") {
        return PathBuf::from(path);
    }
    let mut built = IMAGE.lock().unwrap_or_else(|e| e.into_inner());
    if let Some(path) = built.as_ref() {
        return path.clone();
    }
    let exe = std::env::current_exe().expect("test executable path");
    // target/<profile>/deps/<test> -> target
    let target_dir = exe
        .parent()
        .and_then(Path::parent)
        .and_then(Path::parent)
        .expect("target directory")
        .to_path_buf();
    let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
    let status = Command::new(cargo)
        .current_dir(repo_root())
        .args(["build", "--manifest-path", "firmware/qemu-mps2/Cargo.toml"])
        .args([
            "--release",
            "--target",
            "thumbv7em-none-eabihf",
            "--target-dir",
        ])
        .arg(&target_dir)
        .status()
        .expect("run cargo to build the QEMU firmware");
    assert!(status.success(), "building firmware/qemu-mps2 failed");
    let path = target_dir.join("thumbv7em-none-eabihf/release/firmware-qemu");
    *built = Some(path.clone());
    path
}

/// A TCP port free on 127.0.0.1 right now.
fn free_tcp_port() -> u16 {
    TcpListener::bind("127.0.0.1:0")
        .and_then(|s| s.local_addr())
        .map(|a| a.port())
        .expect("no free TCP port on 127.0.0.1")
}

/// A running emulated board, killed on drop.
pub struct QemuBoard {
    /// Where the controller answers (QEMU's host forward of UDP 8510).
    pub addr: SocketAddr,
    /// Where the pass-through UART's chardev listens (TCP on 127.0.0.1).
    pub serial_addr: SocketAddr,
    /// Where QEMU's monitor listens (TCP on 127.0.0.1), for [`QemuBoard::monitor`].
    monitor_addr: SocketAddr,
    child: Option<Child>,
    dir: PathBuf,
    _turn: MutexGuard<'static, ()>,
}

impl QemuBoard {
    /// Boots the image and waits until it answers STATUS.
    pub fn start() -> QemuBoard {
        let image = image();
        let turn = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
        let mut last_error = String::new();
        // A port found free can be taken before QEMU binds it: try a few.
        for _ in 0..5 {
            let port = crate::free_port();
            let serial_port = free_tcp_port();
            let monitor_port = free_tcp_port();
            let monitor_addr = SocketAddr::V4(SocketAddrV4::new(Ipv4Addr::LOCALHOST, monitor_port));
            let addr = SocketAddr::V4(SocketAddrV4::new(Ipv4Addr::LOCALHOST, port));
            let serial_addr = SocketAddr::V4(SocketAddrV4::new(Ipv4Addr::LOCALHOST, serial_port));
            let dir =
                std::env::temp_dir().join(format!("qemu-tests-{}-{port}", std::process::id()));
            let _ = std::fs::create_dir_all(&dir);
            let log_path = dir.join("uart0.log");
            let mut command = Command::new("qemu-system-arm");
            command
                .args(["-M", "mps2-an500", "-display", "none", "-monitor"])
                .arg(format!("tcp:127.0.0.1:{monitor_port},server=on,wait=off"))
                .args(["-semihosting-config", "enable=on,target=native"])
                .arg("-kernel")
                .arg(&image)
                .arg("-nic")
                .arg(format!(
                    "user,model=lan9118,hostfwd=udp:127.0.0.1:{port}-:8510"
                ))
                .arg("-serial")
                .arg(format!("file:{}", log_path.display()))
                .arg("-serial")
                .arg(format!("tcp:127.0.0.1:{serial_port},server=on,wait=off"))
                .stdin(Stdio::null())
                .stdout(Stdio::null())
                .stderr(Stdio::from(
                    std::fs::File::create(dir.join("qemu.stderr")).expect("QEMU stderr file"),
                ));
            // SAFETY: prctl is async-signal-safe; it only asks the kernel to kill QEMU with
            // SIGKILL when this (the test) process dies, so no QEMU outlives a test run.
            unsafe {
                command.pre_exec(|| {
                    if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGKILL) != 0 {
                        return Err(std::io::Error::last_os_error());
                    }
                    Ok(())
                });
            }
            let mut child = command
                .spawn()
                .unwrap_or_else(|e| panic!("cannot start qemu-system-arm: {e}"));
            let started = Instant::now();
            while started.elapsed() < START_TIMEOUT {
                if let Ok(Some(status)) = child.try_wait() {
                    last_error = format!(
                        "QEMU exited with {status}:\n{}\n{}",
                        std::fs::read_to_string(dir.join("qemu.stderr")).unwrap_or_default(),
                        std::fs::read_to_string(&log_path).unwrap_or_default()
                    );
                    break;
                }
                let quick = Options {
                    ack_timeout: Duration::from_millis(200),
                    attempts: 2,
                    ..Options::default()
                };
                if Client::connect_with(addr, quick).is_ok() {
                    return QemuBoard {
                        addr,
                        serial_addr,
                        monitor_addr,
                        child: Some(child),
                        dir,
                        _turn: turn,
                    };
                }
            }
            let _ = child.kill();
            let _ = child.wait();
            if last_error.is_empty() {
                last_error = format!(
                    "the board did not answer on {addr} in {START_TIMEOUT:?}:\n{}",
                    std::fs::read_to_string(&log_path).unwrap_or_default()
                );
            }
            let _ = std::fs::remove_dir_all(&dir);
        }
        panic!("{last_error}");
    }

    /// A client with the given options.
    pub fn connect_with(&self, options: Options) -> Client {
        Client::connect_with(self.addr, options).unwrap_or_else(|e| {
            panic!("connect to the board at {}: {e}\n{}", self.addr, self.log())
        })
    }

    /// The firmware's log (UART 0) so far, and QEMU's own messages.
    pub fn log(&self) -> String {
        format!(
            "--- firmware log (UART 0) ---\n{}--- QEMU stderr ---\n{}",
            self.firmware_log(),
            std::fs::read_to_string(self.dir.join("qemu.stderr")).unwrap_or_default()
        )
    }

    /// The firmware's log (UART 0) alone, as far as QEMU has written it: its last line may
    /// still be being written (no newline yet). Read lines from this, not from
    /// [`QemuBoard::log`], where the heading that follows would end such a half line.
    pub fn firmware_log(&self) -> String {
        std::fs::read_to_string(self.dir.join("uart0.log")).unwrap_or_default()
    }

    /// Panics with the log if the firmware faulted or QEMU is gone: a panic, a HardFault
    /// (stack overflow included), an unexpected interrupt, or an exit.
    pub fn assert_healthy(&mut self) {
        let log = self.log();
        if let Some(marker) = FAULT_MARKERS.iter().find(|m| log.contains(*m)) {
            panic!("the firmware reported {marker}:\n{log}");
        }
        if let Some(child) = self.child.as_mut()
            && let Ok(Some(status)) = child.try_wait()
        {
            panic!("QEMU exited with {status}:\n{log}");
        }
    }

    /// Runs one command on QEMU's monitor (e.g. `set_link lan9118.0 off`: the NIC's link
    /// as its PHY reports it).
    pub fn monitor(&self, command: &str) {
        use std::io::Write;
        let mut stream = TcpStream::connect(self.monitor_addr)
            .unwrap_or_else(|e| panic!("QEMU monitor {}: {e}", self.monitor_addr));
        let _ = stream.set_read_timeout(Some(Duration::from_millis(200)));
        stream
            .write_all(format!("{command}\n").as_bytes())
            .expect("write to QEMU's monitor");
        // Wait for the prompt after the command: it has run.
        let mut seen = Vec::new();
        let mut buf = [0u8; 1024];
        let deadline = Instant::now() + Duration::from_secs(5);
        while Instant::now() < deadline {
            if let Ok(n) = stream.read(&mut buf) {
                seen.extend_from_slice(&buf[..n]);
                let text = String::from_utf8_lossy(&seen);
                if text.matches("(qemu)").count() >= 2 {
                    return;
                }
            }
        }
        panic!(
            "QEMU's monitor did not run {command:?}: {}",
            String::from_utf8_lossy(&seen)
        );
    }

    /// Connects to the pass-through UART's chardev, as the device on the serial line.
    pub fn serial_device(&self) -> TcpStream {
        let deadline = Instant::now() + Duration::from_secs(5);
        loop {
            match TcpStream::connect(self.serial_addr) {
                Ok(stream) => return stream,
                Err(e) if Instant::now() > deadline => {
                    panic!("serial chardev {}: {e}\n{}", self.serial_addr, self.log())
                }
                Err(_) => std::thread::sleep(Duration::from_millis(20)),
            }
        }
    }
}

/// Boots the image with QEMU's `-append CMDLINE` (the firmware reads it through
/// semihosting) and no network, and waits at most `timeout` for QEMU to exit; returns
/// whether it exited with success (`None`: still running, killed) and the firmware's log.
pub fn run_to_exit(cmdline: &str, timeout: Duration) -> (Option<bool>, String) {
    let image = image();
    let _turn = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let dir = std::env::temp_dir().join(format!(
        "qemu-tests-{}-exit-{}",
        std::process::id(),
        free_tcp_port()
    ));
    let _ = std::fs::create_dir_all(&dir);
    let log_path = dir.join("uart0.log");
    let mut command = Command::new("qemu-system-arm");
    command
        .args(["-M", "mps2-an500", "-display", "none", "-monitor", "none"])
        .args(["-semihosting-config", "enable=on,target=native"])
        .arg("-kernel")
        .arg(&image)
        .args(["-append", cmdline, "-nic", "user,model=lan9118"])
        .arg("-serial")
        .arg(format!("file:{}", log_path.display()))
        .args(["-serial", "null"])
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::null());
    // SAFETY: as in `QemuBoard::start`.
    unsafe {
        command.pre_exec(|| {
            if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGKILL) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
    let mut child = command.spawn().expect("start qemu-system-arm");
    let started = Instant::now();
    let exited = loop {
        if let Ok(Some(status)) = child.try_wait() {
            break Some(status.success());
        }
        if started.elapsed() > timeout {
            let _ = child.kill();
            let _ = child.wait();
            break None;
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    let log = std::fs::read_to_string(&log_path).unwrap_or_default();
    let _ = std::fs::remove_dir_all(&dir);
    (exited, log)
}

impl Drop for QemuBoard {
    fn drop(&mut self) {
        if let Some(mut child) = self.child.take() {
            let _ = child.kill();
            let _ = child.wait();
        }
        if std::thread::panicking() {
            // Keep the log next to the failure message.
            eprintln!("{}", self.log());
        }
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

/// Echoes what the controller writes on the pass-through UART back to it (a loopback
/// device on the serial line), until the stream closes or `for_at_most` elapsed.
pub fn echo(mut stream: TcpStream, for_at_most: Duration) -> std::thread::JoinHandle<usize> {
    std::thread::spawn(move || {
        use std::io::Write;
        let _ = stream.set_read_timeout(Some(Duration::from_millis(50)));
        let started = Instant::now();
        let mut total = 0;
        let mut buf = [0u8; 512];
        while started.elapsed() < for_at_most {
            match stream.read(&mut buf) {
                Ok(0) => break,
                Ok(n) => {
                    total += n;
                    if stream.write_all(&buf[..n]).is_err() {
                        break;
                    }
                }
                Err(_) => continue,
            }
        }
        total
    })
}
