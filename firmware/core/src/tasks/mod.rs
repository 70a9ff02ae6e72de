//! The controller's async tasks, generic over the hardware traits ([`crate::hw`]), one file
//! each. Binaries allocate a [`Bus`], a [`StepShared`] and a [`Controller`] in statics and
//! spawn two `#[embassy_executor::task]`s (which cannot be generic): [`controller_task`]
//! (`controller.rs`: the trajectory, upload and serial tasks below, wired once for every
//! board and the simulator) and [`network_task`] behind their first look at datagrams.
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

mod controller;
mod network;
mod overtaken;
mod serial;
mod trajectory;
mod upload;

pub use controller::{TaskWatch, Unwatched, controller_task};
pub use network::network_task;
pub use overtaken::{OvertakingStops, STOP_MEMORY};
pub use serial::serial_task;
pub use trajectory::{TrajectoryHw, trajectory_task};
pub use upload::upload_task;
