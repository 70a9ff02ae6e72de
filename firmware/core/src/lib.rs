//! The arm controller's behaviour, written once for the board and the simulator.
#![no_std]

#[cfg(test)]
#[macro_use]
extern crate std;

// This must go first so that the other modules see its macros.
mod fmt;

pub mod buffer;
pub mod config;
pub mod controller;
pub mod hw;
pub mod link;
pub mod plan;
pub mod serial;

pub use buffer::{StoredPoint, TrajectoryBuffer};
pub use config::ControllerConfig;
pub use controller::{Controller, Deferred, Owner, Plant, Reply, ReportSettings, Response};
pub use plan::{ReturnPlan, plan_return};
