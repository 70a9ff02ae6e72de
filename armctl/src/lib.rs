//! Host side of the arm controller: a client library over UDP and the `armctl` tool.
//!
//! ```no_run
//! use armctl::{Client, RunOptions};
//! use protocol::Point;
//!
//! let arm = Client::connect("127.0.0.1:8510")?;
//! let status = arm.status()?;
//! println!("{} joints, state {}", status.joints, status.state.name());
//! let start = arm.last_location().map(|l| l.position).unwrap_or_default();
//! let mut target = start;
//! target[0] += 100;
//! // 100 steps on joint 0 in 50 ms.
//! let points = [Point::from_motion(50_000, &start, &target)];
//! let report = arm.run_trajectory(&points, &RunOptions::default(), |p| {
//!     println!("{}/{} acked, {} executed", p.acked, p.total, p.executed)
//! })?;
//! println!("{:?}", report.final_location);
//! # Ok::<(), armctl::Error>(())
//! ```
//!
//! - [`Client`]: commands with retries and ACK checks; every refusal is an
//!   [`Error::Refused`] whose message names the status and what to do about it.
//! - [`Client::run_trajectory`]: the reliable upload (go-back-N window, flow control).
//! - [`Cancel`] and [`Client::stop_until_acked`]: stopping what a call started (Ctrl-C):
//!   the upload and the waits return [`Error::Interrupted`] soon after the token is set, and
//!   STOPPED is resent until it is ACKed.
//! - [`trajectory`]: JointTrajectory JSON and CSV files to checked [`protocol::Point`]s.
//! - [`motion`]: point-to-point moves planned on the host (`armctl move`, `jog`), and
//!   [`motion::Units`] (steps, degrees, radians).
//! - [`record`] and [`plot`]: recorded location reports as CSV, and SVG plots of them;
//!   [`vcd`]: joint positions from a simulator trace (`sim-host --trace`), for the same plots.

mod client;
pub mod described;
pub mod discover;
mod error;
mod interrupt;
pub mod motion;
pub mod pcap;
pub mod plot;
pub mod push;
pub mod pwm;
pub mod record;
mod rtt;
mod run;
mod stop;
pub mod trajectory;
pub mod vcd;

pub use client::auth;
pub use client::{Client, Diagnosis, GIVE_UP_AFTER, Glance, Options};

/// The old name of [`Client`], kept so that integrators' code still builds. Renamed because
/// it clashed with `arm_core::Controller` (the controller's state machine) in code that
/// uses both.
#[deprecated(since = "0.1.0", note = "renamed to `armctl::Client`")]
pub type Controller = Client;
pub use error::{Error, Result, RunEnd};
pub use interrupt::{CANCEL_POLL, Cancel, StopOutcome, StopRetry};
pub use rtt::{DEFAULT_MIN_RTO, DUPLICATE_WINDOW, RESEND_HORIZON, RttEstimator};
pub use run::{DEFAULT_WINDOW, MAX_POINTS, MAX_WINDOW, Progress, RunOptions, RunReport, window_of};
pub use stop::{stop_cause_text, stopped_by};

/// Whether `ARMCTL_TRACE` is set: a program that installs a logger then shows every record
/// of the `armctl` target (an upload's ACKs at `trace`, timeouts and go-back-N resends at
/// `debug`), whatever `RUST_LOG` says. The library itself only logs; the `armctl` binary,
/// sim-host, ros2-bridge and the Python module install the loggers.
pub fn trace_requested() -> bool {
    std::env::var_os("ARMCTL_TRACE").is_some()
}

/// The logger the project's host programs install (the `armctl` tool, sim-host,
/// ros2-bridge): `RUST_LOG` when set, else `default_filter`; with `ARMCTL_TRACE` set, every
/// record of the armctl crate too ([`trace_requested`]).
pub fn logger(default_filter: &str) -> env_logger::Builder {
    let env = env_logger::Env::default().default_filter_or(default_filter);
    let mut logger = env_logger::Builder::from_env(env);
    if trace_requested() {
        logger.filter_module("armctl", log::LevelFilter::Trace);
    }
    logger
}

/// The controller's UDP port, when an address names none.
pub const DEFAULT_PORT: u16 = 8510;

/// The controller address with the default port when `text` names none: `HOST`,
/// `A.B.C.D`, `::1` or `[::1]` get `:8510`; `HOST:PORT` and `[V6]:PORT` are kept.
pub fn controller_address(text: &str) -> String {
    let text = text.trim();
    if text.parse::<std::net::SocketAddr>().is_ok() {
        return text.to_string();
    }
    if let Ok(ip) = text.parse::<std::net::IpAddr>() {
        return std::net::SocketAddr::new(ip, DEFAULT_PORT).to_string();
    }
    if let Some(inner) = text.strip_prefix('[').and_then(|t| t.strip_suffix(']'))
        && let Ok(ip) = inner.parse::<std::net::Ipv6Addr>()
    {
        return std::net::SocketAddr::new(ip.into(), DEFAULT_PORT).to_string();
    }
    match text.rsplit_once(':') {
        Some((host, port)) if !host.contains(':') && port.parse::<u16>().is_ok() => {
            text.to_string()
        }
        _ => format!("{text}:{}", DEFAULT_PORT),
    }
}

pub use protocol;
