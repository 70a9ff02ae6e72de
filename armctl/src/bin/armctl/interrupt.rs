//! SIGINT (Ctrl-C), SIGTERM and SIGHUP (a closed terminal) during a command that moves the
//! arm (`run`, `return`, `move`, ...): the tool stops what it started, says so, and exits 128
//! plus the signal's number (130 SIGINT, 143 SIGTERM, 129 SIGHUP), as a shell reports it.
//!
//! - [`watch`] is called just before the command sends what starts the motion; until then
//!   a signal ends the tool as usual (nothing to stop). From then on signal-hook's handler
//!   only writes to its pipe; the `signals` thread reads it and sets the library's
//!   [`Cancel`] token, which the upload and the waits look at every 20 ms
//!   ([`armctl::CANCEL_POLL`]).
//! - The command's own flow, once its call returned [`armctl::Error::Interrupted`], sends
//!   STOPPED ([`stop_if_signalled`]: resent every 100 ms until it is ACKed, 10 copies at
//!   most); [`finish`], called by `main` after every online command, sends it if the command
//!   did not, prints one line on stderr (`interrupted (SIGINT): STOPPED sent, the arm is
//!   stopped (ACKed ...)` or `... not ACKed after 10 tries ...`) and gives the exit code.
//! - A second signal ends the wait for the ACK at once (the first copy has always gone);
//!   should the flow not be waiting for one then, the `signals` thread ends the process
//!   itself 100 ms later.

use std::sync::atomic::{AtomicBool, AtomicI32, Ordering};
use std::sync::{Mutex, OnceLock, PoisonError};
use std::time::Duration;

use armctl::{Cancel, Client, StopOutcome, StopRetry};
use signal_hook::consts::{SIGHUP, SIGINT, SIGTERM};
use signal_hook::iterator::Signals;

/// What the signals thread and the command's flow share.
struct Watch {
    /// Set by the first signal: the motion's waits end.
    cancel: Cancel,
    /// The first signal (0: none yet).
    signal: AtomicI32,
    /// A second signal came: stop waiting for STOPPED's ACK.
    again: AtomicBool,
    /// STOPPED's outcome, once it was sent (it is sent once).
    stopped: Mutex<Option<StopOutcome>>,
    /// The line on stderr was printed.
    reported: AtomicBool,
}

static WATCH: OnceLock<Watch> = OnceLock::new();

/// How long the signals thread leaves the flow to end by itself after a second signal.
const SECOND_SIGNAL_GRACE: Duration = Duration::from_millis(100);

/// Starts handling SIGINT, SIGTERM and SIGHUP (once per process): the token the motion's calls
/// look at ([`armctl::RunOptions::cancel`], [`Client::wait_stopped_cancellable`]).
pub fn watch() -> Result<Cancel, String> {
    if let Some(watch) = WATCH.get() {
        return Ok(watch.cancel.clone());
    }
    let mut signals = Signals::new([SIGINT, SIGTERM, SIGHUP])
        .map_err(|e| format!("cannot handle SIGINT, SIGTERM and SIGHUP: {e}"))?;
    let watch = WATCH.get_or_init(|| Watch {
        cancel: Cancel::new(),
        signal: AtomicI32::new(0),
        again: AtomicBool::new(false),
        stopped: Mutex::new(None),
        reported: AtomicBool::new(false),
    });
    std::thread::Builder::new()
        .name("signals".into())
        .spawn(move || {
            for signal in signals.forever() {
                let first = watch
                    .signal
                    .compare_exchange(0, signal, Ordering::SeqCst, Ordering::SeqCst)
                    .is_ok();
                if first {
                    watch.cancel.cancel();
                    continue;
                }
                watch.again.store(true, Ordering::SeqCst);
                // The flow abandons its wait for the ACK and exits by itself; if it is
                // busy elsewhere, end it from here.
                std::thread::sleep(SECOND_SIGNAL_GRACE);
                let acked = lock(&watch.stopped)
                    .as_ref()
                    .is_some_and(StopOutcome::is_acked);
                if !acked {
                    eprintln!(
                        "interrupted again: exiting at once; STOPPED may not have reached the \
                         controller, the arm may still be moving (`armctl stop`)"
                    );
                }
                std::process::exit(exit_code_of(watch.signal.load(Ordering::SeqCst)).into());
            }
        })
        .map_err(|e| format!("cannot start the signal thread: {e}"))?;
    Ok(watch.cancel.clone())
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(PoisonError::into_inner)
}

/// 128 + the signal number, as a shell reports a process the signal ended.
fn exit_code_of(signal: i32) -> u8 {
    u8::try_from(128 + signal).unwrap_or(1)
}

fn signal_name(signal: i32) -> &'static str {
    match signal {
        SIGINT => "SIGINT",
        SIGTERM => "SIGTERM",
        SIGHUP => "SIGHUP",
        _ => "a signal",
    }
}

/// If a signal came: STOPPED, resent until it is ACKed (sent once per process; a second
/// signal ends the wait), and `true`. Call it as soon as the interrupted call returned, before
/// any cleanup that takes time.
pub fn stop_if_signalled(arm: &Client) -> bool {
    let Some(watch) = WATCH.get() else {
        return false;
    };
    if watch.signal.load(Ordering::SeqCst) == 0 {
        return false;
    }
    let mut stopped = lock(&watch.stopped);
    if stopped.is_none() {
        *stopped = Some(
            arm.stop_until_acked(&StopRetry::default(), || watch.again.load(Ordering::SeqCst)),
        );
    }
    true
}

/// After an online command: if a signal came, STOPPED (unless [`stop_if_signalled`] sent it
/// already), the line on stderr that says how it went, and the exit code (130 for SIGINT,
/// 143 for SIGTERM). `None` when no signal came.
pub fn finish(arm: &Client) -> Option<u8> {
    if !stop_if_signalled(arm) {
        return None;
    }
    let watch = WATCH.get()?;
    let signal = watch.signal.load(Ordering::SeqCst);
    if !watch.reported.swap(true, Ordering::SeqCst) {
        let how = if watch.again.load(Ordering::SeqCst) {
            "interrupted twice"
        } else {
            "interrupted"
        };
        if let Some(outcome) = lock(&watch.stopped).as_ref() {
            eprintln!("{how} ({}): {outcome}", signal_name(signal));
        }
    }
    Some(exit_code_of(signal))
}

/// The exit code of a command a signal interrupted ([`finish`] printed why), if one did.
pub fn exit_code() -> Option<u8> {
    let watch = WATCH.get()?;
    match watch.signal.load(Ordering::SeqCst) {
        0 => None,
        signal => Some(exit_code_of(signal)),
    }
}
