//! The arm controller on a PC.
//!
//! The firmware's own tasks from `arm-core` run on Embassy's std executor, with simulated
//! hardware behind the `arm_core::hw` traits: steppers that count and trace their pulses,
//! a step timer "interrupt" thread, a gripper timer, a serial port (pseudo-terminal or
//! loopback), absolute encoders and a settings file. The network is a UDP socket on the
//! host, or embassy-net on a TAP device. Nothing here decides how the controller behaves:
//! that is `arm-core`'s, the same code the board runs.

pub mod clock;
pub mod devices;
pub mod door;
pub mod estop;
pub mod faults;
pub mod flood;
pub mod net;
pub mod options;
pub mod probe;
pub mod rx_counters;
pub mod serial;
pub mod sim_diag;
pub mod simnet;
pub mod steppers;
pub mod steptimer;
pub mod switches;
pub mod tap;
pub mod vcd;
pub mod virtual_board;

pub mod app;
pub mod bench;
pub mod demo;
