//! SIGTERM and SIGHUP stop the arm (issue 30): what systemd, `docker stop`, `kill` and a
//! closed terminal send. Python's default for both is to die at once, and a run went on
//! without its script (about 1,500 STEP edges after the signal).
//!
//! - `connect()` and every motion start install [`on_signal`] as Python's handler of
//!   SIGTERM and SIGHUP, but only where the handler is still the default (`SIG_DFL`): a
//!   handler of the user's own (or `SIG_IGN`), set before or after, is left alone. Python
//!   runs signal handlers in the main thread and lets only it set them, so a connection
//!   made and used only from other threads gets none (documented in the README and stub).
//! - Each run and RETURN this process starts is [`register`]ed while it may move the arm
//!   (a run until its thread ends, a RETURN until a wait saw it end or a stop; only while
//!   its connection is open).
//! - The handler runs in the main thread between bytecodes, or within [`crate::SIGNAL_POLL`]
//!   in a wait of ours. It ends every registered run's upload, sends STOPPED to each
//!   controller ([`stop_arm`]: resent until ACKed, 10 copies at most), says so on stderr
//!   (`armctl: SIGTERM: STOPPED sent, the arm is stopped (ACKed ...)`), then ends the
//!   process as the signal would have: the default disposition back and the signal
//!   raised again, so the parent sees death by SIGTERM (`-15` in Python, 143 in a shell).
//!   With nothing moving it only does the last part. A second signal while STOPPED is
//!   being resent ends the process at once (the first copy has gone).
//! - After a fork the child inherits the handler and the list; it stops only motions of
//!   its own process.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, Weak};

use armctl::Client;
use pyo3::prelude::*;

use crate::lock;
use crate::run::{RunState, stop_arm};

/// The signals handled: those that end a process by default and are sent to end it
/// politely. SIGINT is Python's KeyboardInterrupt, which the motion calls handle.
const SIGNALS: [&str; 2] = ["SIGTERM", "SIGHUP"];

/// A motion this process started that may still move the arm.
struct Motion {
    /// Its connection; gone once closed.
    arm: Weak<Client>,
    kind: MotionKind,
    /// The process that started it (a forked child inherits the list).
    pid: u32,
}

/// What kind of motion: how to tell whether it may still move the arm.
pub(crate) enum MotionKind {
    /// A trajectory run: under way until its thread ended.
    Run(Arc<RunState>),
    /// A RETURN: under way while the flag (the Arm's `returning`) is set.
    Return(Arc<AtomicBool>),
}

impl Motion {
    fn under_way(&self) -> bool {
        self.pid == std::process::id()
            && self.arm.strong_count() > 0
            && match &self.kind {
                MotionKind::Run(state) => !state.done.load(Ordering::SeqCst),
                MotionKind::Return(flag) => flag.load(Ordering::SeqCst),
            }
    }

    fn same(&self, other: &Motion) -> bool {
        match (&self.kind, &other.kind) {
            (MotionKind::Run(a), MotionKind::Run(b)) => Arc::ptr_eq(a, b),
            (MotionKind::Return(a), MotionKind::Return(b)) => Arc::ptr_eq(a, b),
            _ => false,
        }
    }
}

/// Motions that may be under way, pruned of ended ones at each registration.
static UNDER_WAY: Mutex<Vec<Motion>> = Mutex::new(Vec::new());

/// The first signal is being handled: a second one ends the process at once.
static TERMINATING: AtomicBool = AtomicBool::new(false);

/// Records a motion just started on `arm`, for the handler to stop (and installs it).
/// Called with the GIL held from the motion's start on, so no handler runs in between.
pub(crate) fn register(py: Python<'_>, arm: &Arc<Client>, kind: MotionKind) {
    install(py);
    let motion = Motion {
        arm: Arc::downgrade(arm),
        kind,
        pid: std::process::id(),
    };
    let mut list = lock(&UNDER_WAY);
    list.retain(Motion::under_way);
    if !list.iter().any(|m| m.same(&motion)) {
        list.push(motion);
    }
}

/// Installs [`on_signal`] for SIGTERM and SIGHUP where Python's handler is the default.
/// Best effort: off the main thread Python refuses (ValueError) and nothing changes.
pub(crate) fn install(py: Python<'_>) {
    let _ = try_install(py);
}

fn try_install(py: Python<'_>) -> PyResult<()> {
    let signal = py.import("signal")?;
    let default = signal.getattr("SIG_DFL")?;
    for name in SIGNALS {
        // Not every platform has SIGHUP.
        let Ok(signum) = signal.getattr(name) else {
            continue;
        };
        let current = signal.call_method1("getsignal", (&signum,))?;
        if current.eq(&default)? {
            let handler = wrap_pyfunction!(on_signal, py)?;
            signal.call_method1("signal", (&signum, handler))?;
        }
    }
    Ok(())
}

/// armctl's handler of SIGTERM and SIGHUP: stops every motion under way (STOPPED resent
/// until ACKed), then dies of the signal. Never returns unless the process survives its
/// own signal (then it exits with 128 + the signal, as a shell reports such a death).
#[pyfunction]
fn on_signal(py: Python<'_>, signum: i32, _frame: Option<Bound<'_, PyAny>>) -> PyResult<()> {
    if !TERMINATING.swap(true, Ordering::SeqCst) {
        stop_everything(py, signum);
    }
    die(py, signum)
}

fn stop_everything(py: Python<'_>, signum: i32) {
    let name = py
        .import("signal")
        .and_then(|s| s.getattr("Signals")?.call1((signum,))?.getattr("name"))
        .and_then(|n| n.extract::<String>())
        .unwrap_or_else(|_| format!("signal {signum}"));
    let mut arms: Vec<Arc<Client>> = Vec::new();
    for motion in lock(&UNDER_WAY).iter().filter(|m| m.under_way()) {
        if let MotionKind::Run(state) = &motion.kind {
            // Its thread sends nothing more.
            state.cancel.cancel();
        }
        if let Some(arm) = motion.arm.upgrade()
            && !arms.iter().any(|a| Arc::ptr_eq(a, &arm))
        {
            arms.push(arm);
        }
    }
    for arm in arms {
        let (outcome, _) = stop_arm(py, &arm);
        eprintln!("armctl: {name}: {outcome}");
    }
}

/// Ends the process as `signum` would have without armctl: default disposition back, the
/// signal raised again.
fn die(py: Python<'_>, signum: i32) -> PyResult<()> {
    let signal = py.import("signal")?;
    signal.call_method1("signal", (signum, signal.getattr("SIG_DFL")?))?;
    signal.call_method1("raise_signal", (signum,))?;
    // Still alive: the signal is blocked or ignored in this thread.
    py.import("os")?.call_method1("_exit", (128 + signum,))?;
    Ok(())
}
