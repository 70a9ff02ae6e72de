//! The controller's async tasks, generic over the hardware traits ([`crate::hw`]), one file
//! each. Binaries allocate a [`Bus`], a [`StepShared`] and a [`Controller`] in statics and
//! wrap these functions in `#[embassy_executor::task]`s (they cannot be generic).
//!
//! * [`network_task`] (`network.rs`): socket in, [`Bus::route`] onto `estop`/`inbox`;
//!   `outbox` out.
//! * [`trajectory_task`] (`trajectory.rs`): owns the [`Controller`] and pushes its segments
//!   into the step backend ([`StepShared`]), woken by the step interrupts; `overtaken.rs`
//!   keeps the e-stop path's arrival order ([`OvertakingStops`]).
//! * [`upload_task`] (`upload.rs`): periodic LOCATION.
//! * [`serial_task`] (`serial.rs`): the USART pass-through.
//!
//! The queues, signals and the diagram of who sends what to whom are in [`crate::bus`];
//! the step engine shared with the interrupts is in [`crate::step_shared`].

#[cfg(doc)]
use crate::{bus::Bus, controller::Controller, step_shared::StepShared};

mod network;
mod overtaken;
mod serial;
mod trajectory;
mod upload;

pub use network::network_task;
pub use overtaken::{OvertakingStops, STOP_MEMORY};
pub use serial::serial_task;
pub use trajectory::{TrajectoryHw, trajectory_task};
pub use upload::upload_task;
