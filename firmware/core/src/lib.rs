//! The arm controller's behaviour, written once for the board and the simulator.
//!
//! # Where each piece lives
//! Following a datagram from the socket to the step engine:
//!
//! 1. [`tasks::network_task`] (`tasks/network.rs`) receives it from a [`hw::Datagrams`]
//!    socket and [`Bus::route`]s it (`bus.rs`): a CRC-valid STOPPED onto `bus.estop`,
//!    anything else onto `bus.inbox`. [`bus`] holds every queue and signal between the
//!    tasks, their capacities, and the one diagram of who sends what to whom.
//! 2. [`tasks::trajectory_task`] (`tasks/trajectory.rs`) takes it (STOPPED first) and
//!    hands it to the [`Controller`] (`controller.rs`, sans-io: the state machine, with
//!    the check order, owner, duplicate and ordering rules in its docs; the duplicate
//!    memory and upload order are in `link.rs`, the trajectory points in `buffer.rs`,
//!    RETURN's move in `plan.rs`). The controller answers with a [`Response`]
//!    (`response.rs`: the ACK, reports, [`Deferred`] work such as a flash write or an
//!    encoder read) and acts on the hardware at once through the [`Plant`] trait
//!    (`plant.rs`). `tasks/overtaken.rs` keeps the result that of arrival order when a
//!    STOPPED overtook queued datagrams.
//! 3. The controller hands buffered points to its [`Plant`] as segments
//!    ([`Controller::pump`]), which the trajectory task pushes straight into the step
//!    backend in [`StepShared`] (`step_shared.rs`: the backend shared with the step
//!    interrupts; the boards' and the simulator's is arm-step's DMA stream producer),
//!    as many as its queue holds (the board profile's `lookahead_us` of motion). The backend
//!    makes the pulses, and its interrupts wake the trajectory task (`bus.step_progress`)
//!    as segments finish.
//! 4. Replies go out the other way: ACK, STATUS and state-change LOCATION onto
//!    `bus.outbox`, encoded and addressed by [`ReportEncoder`] (`outgoing.rs`, with
//!    [`ReportSettings`] from `reports.rs`), sent by the network task. Periodic LOCATION
//!    comes from [`tasks::upload_task`] (`tasks/upload.rs`), USART_RECV from
//!    [`tasks::serial_task`] (`tasks/serial.rs`, batching in `serial.rs`).
//!
//! Limit and home switches (issue 33): `switches.rs` (debounce, the hard-limit latch),
//! `switch_line.rs` (edge handler and trajectory task, as `estop_input.rs`), `homing.rs`
//! (the homing cycle, sans-io; not yet run by a task).
//!
//! Also: `config.rs` (capacities and board defaults), `hw.rs` (the hardware traits the
//! tasks are generic over), `uart.rs` (the USART_START settings the controller accepts:
//! the board's, for the simulator too), `log_limit.rs` (at most one log line a second),
//! and `test_support.rs` (fakes for tests, feature `test-support`).
//!
//! Binaries implement the [`hw`] traits, allocate a [`Bus`], a [`StepShared`] and a
//! [`Controller`] in statics, and wrap the task functions in
//! `#[embassy_executor::task]`s.
//!
//! # The e-stop path
//! Whatever reads datagrams first (the Ethernet driver's receive path on the boards,
//! through [`ingress::GuardedDriver`]; the simulator's socket reader) hands each to
//! [`Bus::receive_first`] (`ingress.rs`, issue 18) before any queue: a CRC-valid STOPPED
//! halts the step outputs right there ([`ingress::StepHalt`]) and goes onto `bus.estop`,
//! a separate queue; any other datagram passes only within its class's fair share of the
//! receive path (`source_share.rs`: the owner's reserved, strangers pooled), so no flood,
//! from however many addresses, fills the queues a STOPPED or the owner's commands wait in.
//! `network_task` then routes what the socket gives it the same way (a valid STOPPED to
//! `bus.estop`); it never waits on a full queue (a full inbox drops the datagram, which
//! the host resends), so a STOPPED is never stuck behind uploads. `trajectory_task` waits on `estop` first (biased select) and never waits on
//! output (a full outbox drops the frame), so a STOPPED is handled after at most the one
//! command being handled: the controller then stops the engine under the step lock
//! (no pulse after that), and kicks the step interrupt, which lowers the STEP lines.
//! Segments queued in the engine are dropped with it. The one wait in
//! the trajectory task is deferred work: a settings write (JOINTS_COUNT, LIMITS_SET,
//! SET_KEY, NET_SET: only in STOPPED since issue 30, and the command's ACK waits for it)
//! or the encoder read of a RETURN (before it moves); nothing moves meanwhile.
//!
//! A STOPPED overtakes the datagrams queued before it, but the result is that of arrival
//! order: `Bus::route` stamps each datagram with the STOPPEDs put on `estop` before it
//! arrived, and `trajectory_task` records which of those it took the controller executed
//! ([`tasks::OvertakingStops`]; since issue 18 every CRC-valid STOPPED is executed, so
//! every one counts). A datagram that arrived before an executed STOPPED taken
//! already was overtaken: it and the queued datagrams up to that STOPPED are handled as
//! usual, each executed STOPPED applied again ([`Controller::stop_after_overtaken`]) right
//! after the datagram it followed, all before any wait (a run one of them started never
//! emits a pulse: the engine starts [`step_shared::START_LEAD_US`] later);
//! a RETURN's encoder read is dropped, a settings write is done.
//!
//! # The wired e-stop input
//! A normally-closed input (`estop_input.rs`, issue 18): the handler that sees it open (an
//! interrupt above every other on the board) stops the step backend itself
//! ([`EStopLine::edge`]: [`StepShared::halt`], no run may start while it is open), then
//! wakes `trajectory_task` (through `bus.step_progress`), which, whatever woke it and
//! before it handles anything else, applies it to the controller ([`Controller::estop_input`]:
//! STOPPED, and a latch that refuses RUNING and RETURN with `ESTOP_LATCHED` until the
//! input is closed and a host sends ESTOP_RESET). Under stop category 1 (ESTOP_CATEGORY,
//! issue 32) the handler leaves a run on a step side with a warp to a controlled stop
//! (it only blocks new runs); the task ramps it down within the accelerations, bounded,
//! then stops it and disables the drivers ([`Controller::estop_controlled`],
//! [`Controller::estop_ramp_poll`]). The safety door (`door_input.rs`) is recorded alike
//! and holds the run.
#![no_std]
// Firmware code never panics on data from the network: no indexing, no unwrap, no
// silently truncating cast (issue 12). Unit tests index and unwrap freely.
#![warn(missing_docs, clippy::cast_possible_truncation)]
#![cfg_attr(not(test), warn(clippy::indexing_slicing, clippy::unwrap_used))]

#[cfg(any(test, feature = "test-support"))]
#[macro_use]
extern crate std;

// This must go first so that the other modules see its macros.
mod fmt;

pub mod auth;
pub mod buffer;
pub mod bus;
pub mod config;
pub mod controller;
pub mod diag;
pub mod door_input;
pub mod estop_input;
pub mod homing;
pub mod hw;
pub mod ingress;
pub mod link;
pub mod log_limit;
pub mod outgoing;
pub mod plan;
pub mod plant;
pub mod profile;
pub mod reports;
pub mod response;
pub mod serial;
pub mod slot_queue;
pub mod source_share;
pub mod step_shared;
pub mod switch_line;
pub mod switches;
pub mod tasks;
#[cfg(feature = "test-support")]
pub mod test_support;
pub mod uart;

pub use buffer::{StoredPoint, TrajectoryBuffer};
pub use bus::{Bus, Datagram};
pub use config::ControllerConfig;
pub use controller::{Controller, DISCOVER_BURST, DISCOVER_REPLIES_PER_S, Owner};
pub use door_input::{DoorLine, DoorSample};
pub use estop_input::{EStopLine, EStopSample};
pub use log_limit::{LogLimit, LogVerdict};
pub use outgoing::{Answer, AnswerReport, Outgoing, ReportEncoder};
pub use plan::{ReturnPlan, plan_return};
pub use plant::Plant;
pub use reports::{LOCATION_LISTENERS, ReportSettings};
pub use response::{Deferred, Discovery, Reply, Response};
#[cfg(feature = "test-support")]
pub use step_shared::on_step_timer;
pub use step_shared::{StepBackend, StepProgress, StepShared};
pub use tasks::{
    TaskWatch, TrajectoryHw, Unwatched, controller_task, network_task, serial_task,
    trajectory_task, upload_task,
};
