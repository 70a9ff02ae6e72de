//! Harness for the end-to-end tests: finds (or builds) the `sim-host` and `armctl`
//! binaries, starts a simulated controller on a free 127.0.0.1 port, and kills it on drop.
//!
//! The binaries are `SIM_HOST_BIN` / `ARMCTL_BIN` when set, else `target/<profile>/sim-host`
//! and `armctl` next to the test executable (`current_exe()/../../`), brought up to date
//! with `cargo build -p <package>` once per test process.

/// The firmware on QEMU's mps2-an500 (tests/tests/qemu.rs).
pub mod qemu;

use std::net::{Ipv4Addr, SocketAddr, SocketAddrV4, UdpSocket};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::{Condvar, Mutex};
use std::time::{Duration, Instant};

use armctl::{Controller, Options};

/// How long a fresh sim-host gets to answer STATUS.
const START_TIMEOUT: Duration = Duration::from_secs(10);

/// Simulators running at once in one test process: each runs real-time step threads,
/// and the machine (and CI's) has two cores.
const MAX_SIMULATORS: usize = 3;

/// Simulators running now, and a wake-up for a free slot.
static RUNNING: (Mutex<usize>, Condvar) = (Mutex::new(0), Condvar::new());

/// A slot among [`MAX_SIMULATORS`]; freed on drop.
struct Slot;

impl Slot {
    fn take() -> Slot {
        let (count, freed) = &RUNNING;
        let mut running = count.lock().unwrap_or_else(|e| e.into_inner());
        while *running >= MAX_SIMULATORS {
            running = freed.wait(running).unwrap_or_else(|e| e.into_inner());
        }
        *running += 1;
        Slot
    }
}

impl Drop for Slot {
    fn drop(&mut self) {
        let (count, freed) = &RUNNING;
        let mut running = count.lock().unwrap_or_else(|e| e.into_inner());
        *running = running.saturating_sub(1);
        freed.notify_one();
    }
}

/// Packages already built by this test process.
static BUILT: Mutex<Vec<String>> = Mutex::new(Vec::new());

/// `target/<profile>/` of the running test executable (`target/<profile>/deps/test-…`).
fn profile_dir() -> Option<PathBuf> {
    let exe = std::env::current_exe().ok()?;
    let deps = exe.parent()?;
    Some(deps.parent()?.to_path_buf())
}

/// Path of binary `name` of package `package`. Unless `env` names it, the package is built
/// once per test process (`cargo build -p`, a no-op when up to date) into the test's own
/// target directory, so that a stale binary is never tested.
pub fn binary(name: &str, package: &str, env: &str) -> PathBuf {
    if let Some(path) = std::env::var_os(env) {
        return PathBuf::from(path);
    }
    let dir = profile_dir().expect("cannot locate the test executable's target directory");
    let path = dir.join(format!("{name}{}", std::env::consts::EXE_SUFFIX));
    let mut built = BUILT.lock().unwrap_or_else(|e| e.into_inner());
    if !built.iter().any(|p| p == package) {
        let ok = build(package, &dir);
        assert!(
            ok || path.exists(),
            "cargo build -p {package} failed and {} does not exist (or set {env})",
            path.display()
        );
        built.push(package.to_string());
    }
    path
}

/// Runs `cargo build -p package` for the profile of `profile_dir`; whether it succeeded.
fn build(package: &str, profile_dir: &Path) -> bool {
    let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
    let Some(target_dir) = profile_dir.parent() else {
        return false;
    };
    let mut command = Command::new(cargo);
    command
        .args(["build", "-p", package, "--target-dir"])
        .arg(target_dir);
    if profile_dir.file_name().is_some_and(|n| n == "release") {
        command.arg("--release");
    }
    command.status().is_ok_and(|s| s.success())
}

/// The simulator binary.
pub fn sim_host_bin() -> PathBuf {
    binary("sim-host", "sim-host", "SIM_HOST_BIN")
}

/// The armctl binary.
pub fn armctl_bin() -> PathBuf {
    binary("armctl", "armctl", "ARMCTL_BIN")
}

/// A UDP port free on 127.0.0.1 right now (for sim-host and QEMU's host forward).
fn free_port() -> u16 {
    UdpSocket::bind("127.0.0.1:0")
        .and_then(|s| s.local_addr())
        .map(|a| a.port())
        .expect("no free UDP port on 127.0.0.1")
}

/// A running sim-host, killed on drop.
pub struct SimHost {
    /// Where it listens.
    pub addr: SocketAddr,
    /// `None` once [`SimHost::terminate`] has waited for it.
    child: Option<Child>,
    dir: PathBuf,
    /// Dropped after the process is killed (fields drop after `Drop::drop`).
    _slot: Slot,
}

impl SimHost {
    /// Starts a sim-host with extra arguments (`--joints`, `--loss` ...) on a free port and
    /// waits until it answers STATUS.
    pub fn start(args: &[&str]) -> SimHost {
        SimHost::launch(args, false)
    }

    /// As [`SimHost::start`], with `--trace` writing to [`SimHost::trace`].
    pub fn start_traced(args: &[&str]) -> SimHost {
        SimHost::launch(args, true)
    }

    fn launch(args: &[&str], traced: bool) -> SimHost {
        let bin = sim_host_bin();
        let slot = Slot::take();
        let mut last_error = String::new();
        // A port found free can be taken before the simulator binds it: try a few.
        for _ in 0..5 {
            let port = free_port();
            let addr = SocketAddr::V4(SocketAddrV4::new(Ipv4Addr::LOCALHOST, port));
            let dir =
                std::env::temp_dir().join(format!("system-tests-{}-{port}", std::process::id()));
            let _ = std::fs::create_dir_all(&dir);
            let log = std::fs::File::create(dir.join("sim-host.log")).ok();
            let mut child = Command::new(&bin)
                .arg("--bind")
                .arg(addr.to_string())
                .arg("--settings")
                .arg(dir.join("settings.txt"))
                .args(["--log-level", "warn"])
                .args(if traced {
                    vec!["--trace".into(), dir.join("run.vcd").into_os_string()]
                } else {
                    Vec::new()
                })
                .args(args)
                .stdin(Stdio::null())
                .stdout(Stdio::null())
                .stderr(log.map_or_else(Stdio::null, Stdio::from))
                .spawn()
                .unwrap_or_else(|e| panic!("cannot start {}: {e}", bin.display()));
            let started = Instant::now();
            while started.elapsed() < START_TIMEOUT {
                if let Ok(Some(status)) = child.try_wait() {
                    last_error = format!(
                        "sim-host exited with {status}: {}",
                        std::fs::read_to_string(dir.join("sim-host.log")).unwrap_or_default()
                    );
                    break;
                }
                let quick = Options {
                    ack_timeout: Duration::from_millis(100),
                    attempts: 2,
                    ..Options::default()
                };
                if Controller::connect_with(addr, quick).is_ok() {
                    return SimHost {
                        addr,
                        child: Some(child),
                        dir,
                        _slot: slot,
                    };
                }
                // A port nobody listens on yet is refused at once on loopback: do not spin.
                std::thread::sleep(Duration::from_millis(20));
            }
            let _ = child.kill();
            let _ = child.wait();
            if last_error.is_empty() {
                last_error = format!("sim-host did not answer on {addr} in {START_TIMEOUT:?}");
            }
        }
        panic!("{last_error}");
    }

    /// A client with options suited to loopback.
    pub fn connect(&self) -> Controller {
        self.connect_with(Options::default())
    }

    /// A client with the given options.
    pub fn connect_with(&self, options: Options) -> Controller {
        Controller::connect_with(self.addr, options)
            .unwrap_or_else(|e| panic!("connect to sim-host at {}: {e}", self.addr))
    }

    /// The simulator's log so far (warnings and errors).
    pub fn log(&self) -> String {
        std::fs::read_to_string(self.dir.join("sim-host.log")).unwrap_or_default()
    }

    /// A scratch directory of this simulator's own.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// The VCD trace of a simulator started with [`SimHost::start_traced`]; complete once
    /// [`SimHost::terminate`] has returned.
    pub fn trace(&self) -> PathBuf {
        self.dir.join("run.vcd")
    }

    /// SIGTERM, then waits (bounded) for a clean exit, so that the trace is flushed.
    pub fn terminate(&mut self) {
        let mut child = self.child.take().expect("sim-host still running");
        let sent = Command::new("kill")
            .args(["-TERM", &child.id().to_string()])
            .status()
            .expect("run kill");
        assert!(sent.success(), "kill -TERM failed");
        let asked = Instant::now();
        loop {
            if let Some(status) = child.try_wait().expect("wait for sim-host") {
                assert!(status.success(), "sim-host exited with {status}");
                return;
            }
            if asked.elapsed() > START_TIMEOUT {
                let _ = child.kill();
                let _ = child.wait();
                panic!("sim-host did not exit within {START_TIMEOUT:?} of SIGTERM");
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }
}

impl Drop for SimHost {
    fn drop(&mut self) {
        if let Some(mut child) = self.child.take() {
            let _ = child.kill();
            let _ = child.wait();
        }
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}
