//! The tool's stdout. Every `print!` and `println!` of this binary comes here (main.rs
//! defines them over std's), so that a reader that went away (`armctl status | head -n 1`)
//! does not panic the tool ("failed printing to stdout: Broken pipe", issue 31).
//!
//! A write that meets a closed pipe is dropped, and so is everything printed after it;
//! the command still finishes what it started (a move is not cut short by its reader
//! leaving), and then the tool ends as other Unix tools do on a closed pipe: killed by
//! SIGPIPE, nothing on stderr (141 in a shell). A command that fails says why and exits 1
//! as usual. Any other write error (a full disk) is said once on stderr and exits 1.

use std::io::Write;
use std::sync::atomic::{AtomicU8, Ordering};

/// stdout takes what is printed.
const OPEN: u8 = 0;
/// Its reader went away: nothing more is written.
const CLOSED: u8 = 1;
/// A write failed otherwise (said on stderr): nothing more is written.
const FAILED: u8 = 2;

static STATE: AtomicU8 = AtomicU8::new(OPEN);

/// Writes `args` to stdout, unless a write has failed before.
pub fn write(args: std::fmt::Arguments<'_>) {
    if STATE.load(Ordering::Relaxed) != OPEN {
        return;
    }
    let written = std::io::stdout().lock().write_fmt(args);
    closed(&written);
}

/// Whether stdout is closed or failed, after `written` (a write to stdout): a closed pipe
/// or another error is noted (the latter said on stderr), and nothing more is written.
pub fn closed(written: &std::io::Result<()>) -> bool {
    match written {
        Ok(()) => STATE.load(Ordering::Relaxed) != OPEN,
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => {
            STATE.store(CLOSED, Ordering::Relaxed);
            true
        }
        Err(e) => {
            if STATE.swap(FAILED, Ordering::Relaxed) == OPEN {
                let _ = writeln!(std::io::stderr(), "error: stdout: {e}");
            }
            true
        }
    }
}

/// How a command that succeeded ends: as usual, killed by SIGPIPE when its stdout was a
/// closed pipe, exit status 1 when writing failed otherwise.
pub fn success() -> std::process::ExitCode {
    match STATE.load(Ordering::Relaxed) {
        OPEN => std::process::ExitCode::SUCCESS,
        CLOSED => {
            // What the default action of SIGPIPE does (std ignores it so that writes
            // return an error instead): restore it and raise it.
            let _ = signal_hook::low_level::emulate_default_handler(signal_hook::consts::SIGPIPE);
            // Not reached; the shell's code for SIGPIPE, should the raise fail.
            std::process::ExitCode::from(141)
        }
        _ => std::process::ExitCode::FAILURE,
    }
}
