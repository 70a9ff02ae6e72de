//! The NUCLEO-H743ZI2 board's logic that needs no hardware, kept out of the board binary
//! (which builds for `thumbv7em-none-eabihf` only) so that it is tested on the host:
//!
//! * [`fault`]: the one fault path of panics and HardFaults, as an ordered sequence of
//!   calls on a [`fault::SafeStateHw`] trait (the board implements it with register
//!   writes, the tests with a recording fake).
//! * [`watchdog`]: the liveness rule that decides whether the IWDG is fed.
//! * [`clock`]: the bounded wait for HSE, with the HSI fallback decision.
//! * [`flash_upkeep`]: the H7 flash's error flags and cache around each operation.
//! * [`settings`]: the settings record, and its flash store that recovers from corruption
//!   (on sequential-storage, tested with its mock flash and fault injection).
//! * [`encoder`]: absolute multi-turn encoders over Modbus RTU (RS-485): frame codec, CRC,
//!   timeouts, and the read of every joint, generic over the bus.
//! * [`gripper`]: the burst arithmetic of counted gripper pulses.
//! * [`net`]: REF_CLK detection, autonegotiated link mode, the link-loss policy.
//! * [`reset_cause`]: why the chip last reset, from RCC_RSR, logged at boot.
//! * [`step_clock`]: the step clock's 64-bit tick from TIM13's counter and its wraps, and
//!   the rule for arming its compare for an alarm.
//! * [`step_stream`]: where a step DMA stream stands (NDTR and flags), and which TCIF a
//!   stream's disable set.
#![no_std]
#![warn(missing_docs)]
// Tests index and unwrap freely: a failing test is meant to panic.
#![cfg_attr(not(test), warn(clippy::indexing_slicing, clippy::unwrap_used))]
#![cfg_attr(not(test), warn(clippy::cast_possible_truncation))]

#[cfg(test)]
#[macro_use]
extern crate std;

pub mod clock;
pub mod encoder;
pub mod fault;
pub mod flash_upkeep;
pub mod gripper;
pub mod net;
pub mod reset_cause;
pub mod settings;
pub mod step_clock;
pub mod step_stream;
pub mod watchdog;
