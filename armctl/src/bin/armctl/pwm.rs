//! `armctl pwm servo|stepper|raw|stop`: the gripper PWM.

use armctl::Client;
use clap::{Args, Subcommand};
use protocol::Pwm;

use crate::CliResult;
use crate::single::done;

/// `pwm` subcommands.
#[derive(Subcommand, Debug)]
pub enum PwmCmd {
    /// Servo mode: runs until `pwm stop`.
    Servo {
        /// Frequency, Hz.
        #[arg(long, default_value_t = 50.0)]
        freq: f64,
        /// Duty cycle, 0..1.
        #[arg(long)]
        duty: f64,
    },
    /// Stepper mode: N pulses (negative: the other way), then stops by itself.
    Stepper {
        /// Pulses, signed.
        #[arg(long, allow_negative_numbers = true)]
        pulses: i32,
        /// Pulse frequency, Hz.
        #[arg(long, default_value_t = 1000.0)]
        freq: f64,
    },
    /// Raw timer registers.
    Raw(RawPwm),
    /// PWM_STOP.
    Stop,
}

/// Raw `Pwm` registers.
#[derive(Args, Debug, Clone, Copy)]
pub struct RawPwm {
    /// Prescaler (16 bits).
    #[arg(long)]
    pub psc: u32,
    /// Auto-reload (16 bits).
    #[arg(long)]
    pub arr: u32,
    /// Compare (<= ARR).
    #[arg(long)]
    pub ccr1: u32,
    /// 0: servo mode; else stepper pulses.
    #[arg(long, default_value_t = 0, allow_negative_numbers = true)]
    pub pulses: i32,
}

impl From<RawPwm> for Pwm {
    fn from(raw: RawPwm) -> Pwm {
        Pwm {
            psc: raw.psc,
            arr: raw.arr,
            ccr1: raw.ccr1,
            pulse_count: raw.pulses,
        }
    }
}

/// Runs a `pwm` subcommand; servo and stepper compute the registers from the
/// controller's PWM timer clock (STATUS).
pub fn execute(arm: &Client, command: &PwmCmd) -> CliResult {
    match command {
        PwmCmd::Stop => done(arm.pwm_stop()),
        PwmCmd::Raw(raw) => done(arm.pwm_start((*raw).into())),
        PwmCmd::Servo { freq, duty } => {
            let clock = arm.status().map_err(|e| e.to_string())?.pwm_timer_clock_hz;
            let pwm = armctl::pwm::settings(clock, *freq, *duty, 0)?;
            println!(
                "PSC {} ARR {} CCR1 {}: {:.3} Hz, duty {:.4}",
                pwm.psc,
                pwm.arr,
                pwm.ccr1,
                pwm.frequency_hz(clock),
                pwm.duty()
            );
            done(arm.pwm_start(pwm))
        }
        PwmCmd::Stepper { pulses, freq } => {
            if *pulses == 0 {
                return Err("--pulses 0 would be servo mode: give a non-zero count".into());
            }
            let clock = arm.status().map_err(|e| e.to_string())?.pwm_timer_clock_hz;
            let pwm = armctl::pwm::settings(clock, *freq, 0.5, *pulses)?;
            done(arm.pwm_start(pwm))
        }
    }
}
