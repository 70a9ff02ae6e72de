//! `armctl move`, `jog` and `home`: the arm to a position, a joint by an increment (or by
//! keys), and every joint to zero, each with its progress and a check of where it ended.
//!
//! Moves are planned on the host (`armctl::motion`): one trapezoidal profile for all
//! joints, within each joint's step rate and acceleration (the joint config's, capped by the
//! rate the controller advertises in STATUS) and position range (the config's), and
//! within the limits the controller keeps (LIMITS_GET), config or not. Positions
//! are taken and shown in `--units` (steps, deg or rad; default: the config's `units`).
//! SIGINT, SIGTERM or SIGHUP during a move or a home: STOPPED (crate::interrupt).

use std::path::PathBuf;
use std::time::Duration;

use armctl::motion::{
    JointLimit, MoveSpeed, TargetArg, Units, check_targets, joint_index, joint_label, plan_move,
    targets_in_steps,
};
use armctl::trajectory::ArmConfig;
use armctl::{Client, RunOptions};
use clap::Args;
use protocol::{MAX_JOINTS, MoreFlags, State, StatusCode};

use crate::CliResult;

/// What `move` and `jog` share: the config, units and speed.
#[derive(Args, Debug, Clone)]
pub struct MotionArgs {
    /// Joint config (JSON: names, units, steps_per_radian, zero_offset_steps, min/max_steps,
    /// max_step_rate_hz, max_accel_steps_s2); without one, positions are in steps and only
    /// the controller's step rate limits the move.
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Units of the positions given and shown: steps, deg or rad (default: the config's
    /// `units`, else steps). Degrees and radians need a config.
    #[arg(long)]
    pub units: Option<Units>,
    /// Percent of each joint's step rate the move may reach.
    #[arg(long, default_value_t = 50, value_parser = clap::value_parser!(u8).range(1..=100))]
    pub speed: u8,
    /// Segment duration of the planned profile, milliseconds.
    #[arg(long, default_value_t = 10.0)]
    pub segment_ms: f64,
}

/// `move` options.
#[derive(Args, Debug)]
pub struct MoveArgs {
    /// Targets: `VALUE ...` for joints 0, 1, ... in order, or `JOINT=VALUE` (JOINT an index
    /// or a config name); joints not given hold.
    #[arg(required = true, num_args = 1..=8, allow_negative_numbers = true)]
    pub targets: Vec<TargetArg>,
    /// The values are increments from where the arm is.
    #[arg(long)]
    pub relative: bool,
    #[command(flatten)]
    pub motion: MotionArgs,
}

/// `jog` options.
#[derive(Args, Debug)]
pub struct JogArgs {
    /// The joint (index or config name); without it, jog by keys (needs a terminal).
    pub joint: Option<String>,
    /// The increment in `--units` (negative: the other way).
    #[arg(allow_negative_numbers = true)]
    pub by: Option<f64>,
    /// The starting increment of each key press (default: 1 deg, 0.02 rad or 100 steps).
    #[arg(long, value_name = "AMOUNT")]
    pub increment: Option<f64>,
    #[command(flatten)]
    pub motion: MotionArgs,
}

/// Whether the arm may start a motion (`run`, `move`, `jog`, `home`): STOPPED, and no
/// latched e-stop input (the upload would be taken, its RUNING refused, and the upload
/// left behind); the error says what to do.
pub fn ready_to_move(status: &protocol::StatusReport) -> Result<(), String> {
    if status.state != State::Stopped {
        return Err(format!(
            "the controller is {}: `armctl stop` first, or wait for the run to end",
            status.state.name()
        ));
    }
    if status.more_flags.has(MoreFlags::ESTOP_LATCHED) {
        return Err(format!(
            "the controller's wired e-stop input is {} (ESTOP_LATCHED): {}",
            if status.more_flags.has(MoreFlags::ESTOP_OPEN) {
                "open"
            } else {
                "latched"
            },
            StatusCode::EstopLatched.advice()
        ));
    }
    Ok(())
}

/// The limits the controller keeps (LIMITS_GET), or `None` from a controller that
/// predates them (UNKNOWN_TAG).
pub fn kept_limits(client: &Client) -> Result<Option<protocol::LimitsReport>, String> {
    match client.limits() {
        Ok(report) => Ok(Some(report)),
        Err(e) if e.status() == Some(StatusCode::UnknownTag) => Ok(None),
        Err(e) => Err(e.to_string()),
    }
}

/// After a failed upload: a controller left in NEW (refused at the first frame) or in
/// PENDING (points taken before the one it refused) is sent STOPPED, which drops the
/// upload, so that the next motion is taken (issue 31: NEW was left as it was); the
/// message says so. Otherwise `message` as it is.
pub fn drop_partial_upload(client: &Client, message: String) -> String {
    // Another host's now (it took the controller over): its upload is not ours to stop.
    if message.contains("NOT_OWNER") || message.contains("AUTH_") {
        return message;
    }
    match client.status() {
        Ok(status) if matches!(status.state, State::New | State::Pending) => {
            let left = status.state.name();
            let dropped = if status.state == State::New {
                "nothing had been taken"
            } else {
                "with the points taken before"
            };
            match client.stop() {
                Ok(_) => format!(
                    "{message}\nSTOPPED sent: the upload was dropped (state {left}: {dropped}), \
                     the controller is STOPPED"
                ),
                Err(e) => format!(
                    "{message}\nthe controller is left in {left} (STOPPED failed: {e}): \
                     `armctl stop`"
                ),
            }
        }
        _ => message,
    }
}

/// The arm as a move sees it: joints, config, units, limits.
pub struct Arm<'a> {
    pub client: &'a Client,
    /// Joints the controller drives.
    pub joints: usize,
    /// The config given, or one without limits (steps, the controller's rate).
    pub config: ArmConfig,
    pub units: Units,
    limits: Vec<JointLimit>,
    speed: MoveSpeed,
    segment_us: u32,
}

impl<'a> Arm<'a> {
    /// Reads STATUS (the arm must be STOPPED, with no e-stop latch) and the config.
    pub fn new(client: &'a Client, args: &MotionArgs) -> Result<Arm<'a>, String> {
        let status = client.status().map_err(|e| e.to_string())?;
        ready_to_move(&status)?;
        let joints = usize::from(status.joints).clamp(1, MAX_JOINTS);
        let config = match &args.config {
            Some(path) => {
                let config = ArmConfig::load(path).map_err(|e| e.to_string())?;
                if config.joints.len() < joints {
                    return Err(format!(
                        "{}: {} joints configured, the controller drives {joints}",
                        path.display(),
                        config.joints.len()
                    ));
                }
                config
            }
            // The arm the controller describes (issue 31), else steps without limits.
            None => {
                crate::run::described_without_config(client, true, joints, status.max_step_rate_hz)?
                    .unwrap_or_else(|| ArmConfig::unlimited(joints, status.max_step_rate_hz))
            }
        };
        // A described arm converts units as a config does.
        let described = args.config.is_none()
            && (config.units != Units::Steps
                || config.joints.iter().any(|j| j.steps_per_radian != 1.0));
        // Within what the controller keeps too: it refuses the rest (issue 31).
        let config = match kept_limits(client)? {
            Some(kept) => config.within(&kept.joints),
            None => config,
        };
        let units = args.units.unwrap_or(config.units);
        if units != Units::Steps && args.config.is_none() && !described {
            return Err(format!(
                "--units {} needs a joint config (--config FILE: steps_per_radian, \
                 zero_offset_steps per joint), or one kept on the controller (armctl config \
                 push FILE)",
                units.name()
            ));
        }
        let segment_us = armctl::trajectory::segment_us(args.segment_ms, "--segment-ms")?;
        let mut limits = JointLimit::all(&config, Some(status.max_step_rate_hz));
        limits.truncate(joints);
        Ok(Arm {
            client,
            joints,
            config,
            units,
            limits,
            speed: MoveSpeed {
                rate: f64::from(args.speed) / 100.0,
                accel: 1.0,
            },
            segment_us,
        })
    }

    /// The name a message gives joint `j`: its config name, else `joint j`.
    pub fn joint_name(&self, j: usize) -> String {
        joint_label(&self.config, j)
    }

    /// `base 90.00 deg, elbow -3.20 deg`: positions in the arm's units.
    pub fn positions_line(&self, position: &[i32; MAX_JOINTS]) -> String {
        (0..self.joints)
            .map(|j| {
                format!(
                    "{} {}",
                    self.joint_name(j),
                    self.units
                        .show(i64::from(position[j]), &self.config.joints[j])
                )
            })
            .collect::<Vec<_>>()
            .join(", ")
    }

    /// Where the arm is.
    pub fn position(&self) -> Result<[i32; MAX_JOINTS], String> {
        self.client
            .current_location(Duration::from_secs(2))
            .map(|l| l.position)
            .map_err(|e| e.to_string())
    }

    /// Targets from `args` in the arm's units, checked against the config's range (the
    /// message names the joint, the value in units and the range).
    pub fn targets(
        &self,
        args: &[TargetArg],
        relative: bool,
        current: &[i32; MAX_JOINTS],
    ) -> Result<[i32; MAX_JOINTS], String> {
        let target = targets_in_steps(
            args,
            self.units,
            relative,
            current,
            self.joints,
            &self.config,
        )?;
        check_targets(&target, &self.limits, &self.config, self.units)?;
        Ok(target)
    }

    /// Moves to `target` with a progress bar (unless `quiet`), then checks the arm is
    /// there. `cancel` ends the move (the caller sends STOPPED).
    pub fn move_to(
        &self,
        target: &[i32; MAX_JOINTS],
        cancel: Option<armctl::Cancel>,
        quiet: bool,
    ) -> Result<[i32; MAX_JOINTS], String> {
        let bar = if quiet {
            indicatif::ProgressBar::hidden()
        } else {
            indicatif::ProgressBar::new(0)
        };
        bar.set_style(
            indicatif::ProgressStyle::with_template("{spinner} {bar:40} {pos}/{len} points  {msg}")
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        );
        let options = RunOptions {
            window: 0,
            cancel,
            ..RunOptions::default()
        };
        // As Client::move_to, keeping the points: a refusal says which one it was.
        let from = self.position()?;
        let points = plan_move(&from, target, &self.limits, self.speed, self.segment_us)
            .map_err(|e| format!("invalid trajectory: {e}"))?;
        let report = if points.is_empty() {
            Ok(None)
        } else {
            self.client
                .run_trajectory(&points, &options, |p| {
                    bar.set_length(p.total as u64);
                    bar.set_position(p.executed as u64);
                    bar.set_message(p.state.name());
                })
                .map(Some)
        };
        bar.finish_and_clear();
        let report = report.map_err(|e| {
            let sent = crate::config::Sent {
                from,
                points: &points,
                config: &self.config,
                units: self.units,
            };
            let message =
                crate::config::explain_invalid_point(e.to_string(), self.client, Some(&sent));
            drop_partial_upload(self.client, message)
        })?;
        let at = match report.and_then(|r| r.final_location) {
            Some(location) => location.position,
            None => self.position()?,
        };
        let wrong: Vec<String> = (0..self.joints)
            .filter(|&j| at[j] != target[j])
            .map(|j| {
                let joint = &self.config.joints[j];
                format!(
                    "{} at {}, expected {}",
                    self.joint_name(j),
                    self.units.show(i64::from(at[j]), joint),
                    self.units.show(i64::from(target[j]), joint)
                )
            })
            .collect();
        if wrong.is_empty() {
            Ok(at)
        } else {
            Err(format!("the move ended elsewhere: {}", wrong.join("; ")))
        }
    }
}

/// Runs `move`.
pub fn execute_move(client: &Client, args: &MoveArgs) -> CliResult {
    let arm = Arm::new(client, &args.motion)?;
    let current = arm.position()?;
    let target = arm.targets(&args.targets, args.relative, &current)?;
    if target == current {
        println!("already there: {}", arm.positions_line(&current));
        return Ok(());
    }
    let cancel = crate::interrupt::watch()?;
    let result = arm.move_to(&target, Some(cancel), false);
    if crate::interrupt::stop_if_signalled(client) {
        return Err("interrupted".into());
    }
    println!("at {}", arm.positions_line(&result?));
    Ok(())
}

/// Runs `jog`: one increment of one joint, or by keys.
pub fn execute_jog(client: &Client, args: &JogArgs) -> CliResult {
    let arm = Arm::new(client, &args.motion)?;
    match (&args.joint, args.by) {
        (Some(joint), Some(by)) => {
            let j = joint_index(joint, arm.joints, Some(&arm.config))?;
            let current = arm.position()?;
            let target = arm.targets(
                &[TargetArg {
                    joint: Some(j.to_string()),
                    value: by,
                }],
                true,
                &current,
            )?;
            let cancel = crate::interrupt::watch()?;
            let result = arm.move_to(&target, Some(cancel), true);
            if crate::interrupt::stop_if_signalled(client) {
                return Err("interrupted".into());
            }
            println!("at {}", arm.positions_line(&result?));
            Ok(())
        }
        (Some(_), None) => {
            Err("jog JOINT BY: give the increment too (or neither, for keys)".into())
        }
        (None, _) => crate::jog_keys::execute(&arm, args.increment),
    }
}

/// Runs `home`: on the home switches when the arm has them (HOME, issue 33: a live
/// position line until the cycle ends, then its result naming the joint that failed), else
/// RETURN, a live position line until the arm is STOPPED, and the check that every joint
/// is at zero.
pub fn execute_home(client: &Client, config: Option<&PathBuf>, units: Option<Units>) -> CliResult {
    let arm = Arm::new(
        client,
        &MotionArgs {
            config: config.cloned(),
            units,
            speed: 100,
            segment_ms: 10.0,
        },
    )?;
    let cancel = crate::interrupt::watch()?;
    let locations = client.locations();
    let on_switches = match client.start_homing() {
        Ok(_) => true,
        // No joint set to home, no switches, or a controller older than issue 33.
        Err(armctl::Error::Refused {
            status: protocol::StatusCode::HomingFailed | protocol::StatusCode::UnknownTag,
            ..
        }) => false,
        Err(e) => return Err(e.to_string()),
    };
    if !on_switches {
        client.go_home().map_err(|e| e.to_string())?;
    }
    let quiet = !console::Term::stdout().is_term();
    let mut last = None;
    let status = loop {
        if let Ok(location) = locations.recv_timeout(Duration::from_millis(100)) {
            if !quiet {
                print!("\rhoming: {}   ", arm.positions_line(&location.position));
                use std::io::Write;
                let _ = std::io::stdout().flush();
            }
            last = Some(location.position);
        }
        if cancel.is_cancelled() {
            crate::interrupt::stop_if_signalled(client);
            return Err("interrupted".into());
        }
        let status = client.status().map_err(|e| e.to_string())?;
        if status.state == State::Stopped {
            break status;
        }
    };
    if !quiet {
        println!();
    }
    // The controller sends a LOCATION report at the state change; ask for a fresh one.
    let at = arm.position().or_else(|e| last.ok_or(e))?;
    if on_switches {
        let report = client
            .switches()
            .map_err(|e| e.to_string())?
            .ok_or("no SWITCHES report")?;
        return match report.phase {
            protocol::HomingPhase::Homed => {
                println!("homed on the switches: {}", arm.positions_line(&at));
                Ok(())
            }
            _ => Err(format!(
                "homing failed on {}: {}",
                arm.joint_name(usize::from(report.joint)),
                report.error.map_or(
                    "stopped (STOPPED, a limit switch or the e-stop input)",
                    |e| { e.text() }
                )
            )),
        };
    }
    let away: Vec<String> = (0..arm.joints)
        .filter(|&j| at[j] != 0)
        .map(|j| format!("{} at {} steps", arm.joint_name(j), at[j]))
        .collect();
    if away.is_empty() {
        println!("home: {}", arm.positions_line(&at));
        Ok(())
    } else {
        Err(format!(
            "RETURN ended (state {}) with joints away from zero: {}",
            status.state.name(),
            away.join("; ")
        ))
    }
}
