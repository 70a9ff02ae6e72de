//! The arm controller's behaviour, written once for the board and the simulator.
//!
//! * [`Controller`] (sans-io): one datagram in, the ACK, reports and effects out. The
//!   check order, owner, duplicate and ordering rules are documented in [`controller`].
//!   Effects that must happen at once go through the [`Plant`] trait; flash writes and
//!   encoder reads come back as [`Deferred`] work.
//! * [`plan_return`] (sans-io): RETURN's trapezoidal move to zero as ordinary points.
//! * [`serial::SerialBatcher`] (sans-io): USART_RECV batching.
//! * [`tasks`]: the async tasks, generic over the [`hw`] traits, and the step timer
//!   interrupt's body [`on_step_timer`]. Binaries implement the traits, allocate a
//!   [`Bus`], a [`StepShared`] and a [`Controller`] in statics, and wrap the task
//!   functions in `#[embassy_executor::task]`s.
//!
//! # Tasks and channels
//! ```text
//!   UDP socket                                         step timer interrupt
//!       |                                                  on_step_timer()
//!  network_task --estop (CRC-valid STOPPED)-->+               |  ^
//!   rx | tx     --inbox (all other frames)--->| trajectory    |  | StepShared: engine,
//!      |  ^                                   | _task         |  | stop count, progress
//!      |  |<--- outbox: ACK, STATUS, --------| (Controller)--+--' (stop/start directly)
//!      |  |     LOCATION on state change      |   | segments    |
//!      |  |                                   |   v             | step_wake
//!      |  |                                   |  step_task <----+
//!      |  |                                   |<--' step_progress (finished/ran dry)
//!      |  |<--- LOCATION every period --- upload_task  (reads bus.reports + positions)
//!      |  '<--- USART_RECV ------------- serial_task <-- serial_tx, serial_opened
//! ```
//!
//! # The e-stop path
//! `network_task` checks each datagram's tag and CRC as it arrives and puts a valid
//! STOPPED on `bus.estop`, a separate queue; it never waits on a full queue (a full inbox
//! drops the datagram, which the host resends), so a STOPPED is never stuck behind
//! uploads. `trajectory_task` waits on `estop` first (biased select) and never waits on
//! output (a full outbox drops the frame), so a STOPPED is handled after at most the one
//! command being handled: the controller then stops the engine in a critical section
//! (no pulse after that), and kicks the step interrupt, which lowers the STEP lines.
//! Segments already cut for the engine are dropped by their stop count. The one wait in
//! the trajectory task is deferred work: a settings write (JOINTS_COUNT, only in STOPPED)
//! or the encoder read of a RETURN (before it moves); nothing moves meanwhile.
//!
//! A STOPPED overtakes the datagrams queued before it, but the result is that of arrival
//! order: `Bus::route` stamps each datagram with the STOPPEDs put on `estop` before it
//! arrived, and `trajectory_task` records which of those it took the controller executed
//! ([`tasks::OvertakingStops`]; a refused STOPPED, say `BAD_LENGTH`, or a duplicate did
//! nothing, so it stops nothing). A datagram that arrived before an executed STOPPED taken
//! already was overtaken: it and the queued datagrams up to that STOPPED are handled as
//! usual, each executed STOPPED applied again ([`Controller::stop_after_overtaken`]) right
//! after the datagram it followed, all before any wait (a run one of them started never
//! emits a pulse: the engine starts [`tasks::START_LEAD_US`] later, fed by the step task);
//! a RETURN's encoder read is dropped, a settings write is done.
#![no_std]
#![warn(missing_docs)]

#[cfg(any(test, feature = "test-support"))]
#[macro_use]
extern crate std;

// This must go first so that the other modules see its macros.
mod fmt;

pub mod buffer;
pub mod config;
pub mod controller;
pub mod hw;
pub mod link;
pub mod log_limit;
pub mod outgoing;
pub mod plan;
pub mod serial;
pub mod tasks;
#[cfg(feature = "test-support")]
pub mod test_support;

pub use buffer::{StoredPoint, TrajectoryBuffer};
pub use config::ControllerConfig;
pub use controller::{
    Controller, Deferred, Discovery, LOCATION_LISTENERS, Owner, Plant, Reply, ReportSettings,
    Response,
};
pub use log_limit::{LogLimit, LogVerdict};
pub use outgoing::{Outgoing, ReportEncoder};
pub use plan::{ReturnPlan, plan_return};
pub use tasks::{
    Bus, Datagram, StepBackend, StepProgress, StepShared, TrajectoryHw, network_task,
    on_step_timer, serial_task, step_task, trajectory_task, upload_task,
};
