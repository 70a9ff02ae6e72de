//! `armctl homing get|set`: each joint's homing on its home switch (HOMING_GET,
//! HOMING_SET; docs/PROTOCOL.md, HOME; issue 33), kept by the controller with its limits.
//! `armctl home` runs the cycle.

use armctl::Client;
use clap::{Subcommand, ValueEnum};
use protocol::HomingSettings;

use crate::CliResult;

/// The side of travel a home switch is on.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum Towards {
    /// The min side: the seek moves negative.
    Min,
    /// The max side: the seek moves positive.
    Max,
}

/// `armctl homing ...`.
#[derive(Subcommand, Debug)]
pub enum HomingCmd {
    /// HOMING_GET: one joint's homing settings.
    Get {
        /// The joint, 0-7.
        #[arg(value_parser = clap::value_parser!(u8).range(0..=7))]
        joint: u8,
    },
    /// HOMING_SET: one joint homes on its home switch (only while STOPPED; kept across
    /// power cycles). `--off` makes it not home.
    Set {
        /// The joint, 0-7.
        #[arg(value_parser = clap::value_parser!(u8).range(0..=7))]
        joint: u8,
        /// Do not home this joint.
        #[arg(long)]
        off: bool,
        /// The side the switch is on.
        #[arg(long, value_enum, default_value_t = Towards::Min)]
        towards: Towards,
        /// Seek rate, steps/s.
        #[arg(long, default_value_t = 2_000)]
        seek: u32,
        /// Back-off and slow approach rate, steps/s.
        #[arg(long, default_value_t = 200)]
        approach: u32,
        /// Back-off, steps (more than the seek runs on past the switch).
        #[arg(long, default_value_t = 400)]
        backoff: u32,
        /// Longest seek, steps: past it the cycle fails naming the joint.
        #[arg(long)]
        travel: Option<u32>,
        /// The joint's count at the switch, steps.
        #[arg(long, default_value_t = 0, allow_negative_numbers = true)]
        offset: i32,
        /// Joints home in increasing order.
        #[arg(long, default_value_t = 0)]
        order: u8,
        /// The home switch is also that side's limit switch.
        #[arg(long)]
        switch_is_limit: bool,
    },
}

/// Runs `homing get|set`.
pub fn execute(arm: &Client, command: &HomingCmd) -> CliResult {
    match *command {
        HomingCmd::Get { joint } => {
            let s = arm.homing(joint).map_err(|e| e.to_string())?;
            println!("{}", describe(joint, &s));
            Ok(())
        }
        HomingCmd::Set {
            joint,
            off,
            towards,
            seek,
            approach,
            backoff,
            travel,
            offset,
            order,
            switch_is_limit,
        } => {
            let settings = if off {
                HomingSettings::NONE
            } else {
                HomingSettings {
                    enabled: true,
                    towards_max: towards == Towards::Max,
                    switch_is_limit,
                    order,
                    seek_rate_hz: seek,
                    approach_rate_hz: approach,
                    backoff_steps: backoff,
                    max_travel_steps: travel
                        .ok_or("--travel is needed (the longest seek, steps)")?,
                    offset,
                }
            };
            crate::single::done(arm.set_homing(joint, settings))
        }
    }
}

/// One line: what the joint's homing does.
pub fn describe(joint: u8, s: &HomingSettings) -> String {
    if !s.enabled {
        return format!("joint {joint}: not homed on a switch (`armctl home` uses RETURN)");
    }
    format!(
        "joint {joint}: order {}, towards {}, seek {} steps/s within {} steps, back-off {} steps and approach at {} steps/s, offset {}{}",
        s.order,
        if s.towards_max { "max" } else { "min" },
        s.seek_rate_hz,
        s.max_travel_steps,
        s.backoff_steps,
        s.approach_rate_hz,
        s.offset,
        if s.switch_is_limit {
            " (the switch is also the limit)"
        } else {
            ""
        }
    )
}
