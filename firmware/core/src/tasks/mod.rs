//! The controller's async tasks, generic over the hardware traits ([`crate::hw`]), one file
//! each. Binaries allocate a [`Bus`], a [`StepShared`] and a [`Controller`] in statics and
//! wrap these functions in `#[embassy_executor::task]`s (they cannot be generic).
//!
//! * [`network_task`] (`network.rs`): socket in, [`Bus::route`] onto `estop`/`inbox`;
//!   `outbox` out.
//! * [`trajectory_task`] (`trajectory.rs`): owns the [`Controller`]; `overtaken.rs` keeps
//!   the e-stop path's arrival order ([`OvertakingStops`]).
//! * [`step_task`] (`step.rs`): `segments` into the engine ([`StepShared`]).
//! * [`upload_task`] (`upload.rs`): periodic LOCATION.
//! * [`serial_task`] (`serial.rs`): the USART pass-through.
//!
//! The queues, signals and the diagram of who sends what to whom are in [`crate::bus`];
//! the step engine shared with the interrupts is in [`crate::step_shared`]. Both are
//! re-exported here, so `arm_core::tasks::Bus` and the like keep working.

#[cfg(doc)]
use crate::controller::Controller;

mod network;
mod overtaken;
mod serial;
mod step;
mod trajectory;
mod upload;

pub use crate::bus::{
    Bus, Cs, Datagram, ESTOP_QUEUE, INBOX_QUEUE, OUTBOX_QUEUE, SEGMENT_QUEUE, SERIAL_TX_QUEUE,
    SegmentMsg, is_stop,
};
pub use crate::step_shared::{
    PushOutcome, START_LEAD_US, STEP_QUEUE, StepBackend, StepProgress, StepShared, StepState,
    on_step_timer, us_to_ticks,
};
pub use network::network_task;
pub use overtaken::{OvertakingStops, STOP_MEMORY};
pub use serial::serial_task;
pub use step::step_task;
pub use trajectory::{TrajectoryHw, trajectory_task};
pub use upload::upload_task;
