//! Point-to-point moves planned on the host (`armctl move`, `jog`; Python `move_to`, `jog`).
//!
//! All joints of a move start and end together on one trapezoidal speed profile: the joint
//! that needs longest under its step rate and acceleration sets the duration, the others
//! follow the same profile scaled to their distance, so the arm moves along a straight line
//! in joint space. The profile is cut into segments of at most the asked duration, each
//! rounded to whole steps, the last exactly at the target; every segment is checked against
//! the joint's hard step rate (the lower of the config's and the controller's), and the
//! profile is stretched a little when rounding to steps would break it.
//!
//! Targets and limits come from the joint config when there is one ([`ArmConfig`]: its
//! position range, rate, acceleration and units) and from the controller's advertised step
//! rate when there is not; [`Units`] converts degrees and radians with the config's
//! `steps_per_radian` and `zero_offset_steps`.

use std::fmt;

use protocol::{MAX_JOINTS, Point};
use serde::Deserialize;

use crate::trajectory::{ArmConfig, JointConfig};
use crate::{Client, Error, Progress, RunOptions, RunReport};

/// The units positions are given and shown in.
#[derive(Clone, Copy, Debug, Default, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum Units {
    /// Motor steps (no config needed).
    #[default]
    Steps,
    /// Degrees of joint motion (the config's `steps_per_radian` and `zero_offset_steps`).
    Deg,
    /// Radians of joint motion.
    Rad,
}

impl Units {
    /// The unit's short name, as `--units` takes it.
    pub fn name(self) -> &'static str {
        match self {
            Units::Steps => "steps",
            Units::Deg => "deg",
            Units::Rad => "rad",
        }
    }

    /// `value` in these units as a step position of `joint` (fractional: the caller rounds).
    pub fn to_steps(self, value: f64, joint: &JointConfig) -> f64 {
        match self {
            Units::Steps => value,
            Units::Deg => {
                f64::from(joint.zero_offset_steps) + value.to_radians() * joint.steps_per_radian
            }
            Units::Rad => f64::from(joint.zero_offset_steps) + value * joint.steps_per_radian,
        }
    }

    /// A step position of `joint` in these units.
    pub fn from_steps(self, steps: i64, joint: &JointConfig) -> f64 {
        let radians = (steps - i64::from(joint.zero_offset_steps)) as f64 / joint.steps_per_radian;
        match self {
            Units::Steps => steps as f64,
            Units::Deg => radians.to_degrees(),
            Units::Rad => radians,
        }
    }

    /// A distance of `steps` of `joint` in these units (no zero offset).
    pub fn distance_from_steps(self, steps: f64, joint: &JointConfig) -> f64 {
        match self {
            Units::Steps => steps,
            Units::Deg => (steps / joint.steps_per_radian).to_degrees(),
            Units::Rad => steps / joint.steps_per_radian,
        }
    }

    /// `value` (a position of `joint` in steps) formatted in these units, with the unit.
    pub fn show(self, steps: i64, joint: &JointConfig) -> String {
        // Rounded first, and `+ 0.0` turns -0.0 into 0.0: home never reads "-0.00 deg".
        let rounded = |scale: f64| (self.from_steps(steps, joint) * scale).round() / scale + 0.0;
        match self {
            Units::Steps => format!("{steps} steps"),
            Units::Deg => format!("{:.2} deg", rounded(100.0)),
            Units::Rad => format!("{:.4} rad", rounded(10_000.0)),
        }
    }
}

impl std::str::FromStr for Units {
    type Err = String;
    fn from_str(s: &str) -> Result<Units, String> {
        match s.to_ascii_lowercase().as_str() {
            "steps" | "step" => Ok(Units::Steps),
            "deg" | "degrees" => Ok(Units::Deg),
            "rad" | "radians" => Ok(Units::Rad),
            other => Err(format!("units {other:?}: steps, deg or rad")),
        }
    }
}

/// A joint's acceleration when its config gives none: from rest to its full step rate in
/// this many seconds. A quarter second is gentle for a geared stepper joint and still
/// reaches speed on moves of a few degrees.
pub const DEFAULT_ACCEL_TIME_S: f64 = 0.25;

/// How fast a move may go, as fractions of each joint's limits.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MoveSpeed {
    /// Fraction (0 to 1] of each joint's step rate the move may reach.
    pub rate: f64,
    /// Fraction (0 to 1] of each joint's acceleration the move may use.
    pub accel: f64,
}

impl Default for MoveSpeed {
    /// Half speed, full acceleration: a first move that can be watched and stopped.
    fn default() -> MoveSpeed {
        MoveSpeed {
            rate: 0.5,
            accel: 1.0,
        }
    }
}

/// What a joint may do in a move.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct JointLimit {
    /// Position range, steps.
    pub min_steps: i32,
    /// Position range, steps.
    pub max_steps: i32,
    /// Hard step rate, steps per second (never exceeded by any segment).
    pub max_rate_hz: u32,
    /// Acceleration, steps per second squared.
    pub max_accel: f64,
}

impl JointLimit {
    /// The limits of `joint` in the config, its rate capped by the controller's.
    pub fn from_config(joint: &JointConfig, controller_max_rate_hz: Option<u32>) -> JointLimit {
        let max_rate_hz = controller_max_rate_hz
            .map_or(joint.max_step_rate_hz, |c| c.min(joint.max_step_rate_hz));
        JointLimit {
            min_steps: joint.min_steps,
            max_steps: joint.max_steps,
            max_rate_hz,
            max_accel: joint
                .max_accel_steps_s2
                .unwrap_or(f64::from(max_rate_hz) / DEFAULT_ACCEL_TIME_S),
        }
    }

    /// The limits of every configured joint of `config`.
    pub fn all(config: &ArmConfig, controller_max_rate_hz: Option<u32>) -> Vec<JointLimit> {
        config
            .joints
            .iter()
            .map(|j| JointLimit::from_config(j, controller_max_rate_hz))
            .collect()
    }
}

/// Why a move was not planned.
#[derive(Clone, Debug, PartialEq)]
pub enum MoveError {
    /// A target outside the joint's position range.
    OutOfRange {
        /// The joint.
        joint: usize,
        /// The target, steps.
        target: i64,
        /// The joint's range, steps.
        min: i32,
        /// The joint's range, steps.
        max: i32,
    },
    /// A joint that must move has a step rate or acceleration of 0.
    CannotMove {
        /// The joint.
        joint: usize,
    },
    /// A speed fraction outside (0, 1].
    BadSpeed(f64),
    /// A segment duration of 0.
    BadSegment,
    /// The move takes more points than one upload.
    TooLong {
        /// Its duration, seconds.
        duration_s: f64,
    },
}

impl fmt::Display for MoveError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            MoveError::OutOfRange {
                joint,
                target,
                min,
                max,
            } => write!(
                f,
                "joint {joint}: target {target} steps is outside its range {min} to {max} steps"
            ),
            MoveError::CannotMove { joint } => write!(
                f,
                "joint {joint} must move but its step rate or acceleration limit is 0"
            ),
            MoveError::BadSpeed(s) => write!(f, "speed {s}: a fraction above 0 and at most 1"),
            MoveError::BadSegment => f.write_str("the segment duration must be at least 1 us"),
            MoveError::TooLong { duration_s } => write!(
                f,
                "the move takes {duration_s:.1} s, more than one upload holds at this segment \
                 duration: use longer segments or a higher speed"
            ),
        }
    }
}

impl std::error::Error for MoveError {}

/// Accel fractions of the profile tried when planning (the share of the move spent
/// speeding up, and again slowing down): the fastest that meets every joint's limits wins.
const ACCEL_FRACTIONS: [f64; 12] = [
    0.02, 0.05, 0.08, 0.12, 0.16, 0.2, 0.25, 0.3, 0.35, 0.4, 0.45, 0.5,
];

/// Stretches of the profile tried when rounding to whole steps breaks a step rate: 2 %
/// each, at most 50 (2.7 times).
const STRETCH: f64 = 1.02;
const MAX_STRETCHES: u32 = 50;

/// The trapezoid from 0 to 1 over `u` in 0..=1 with `alpha` of the time speeding up and
/// `alpha` slowing down.
fn trapezoid(u: f64, alpha: f64) -> f64 {
    let k = 1.0 / (2.0 * alpha * (1.0 - alpha));
    if u <= alpha {
        u * u * k
    } else if u >= 1.0 - alpha {
        1.0 - (1.0 - u) * (1.0 - u) * k
    } else {
        (u - alpha / 2.0) / (1.0 - alpha)
    }
}

/// Plans a move of the first `limits.len()` joints from `from` to `to` (the other joints
/// hold), at `speed`, in segments of at most `segment_us`. Empty when nothing moves.
pub fn plan_move(
    from: &[i32; MAX_JOINTS],
    to: &[i32; MAX_JOINTS],
    limits: &[JointLimit],
    speed: MoveSpeed,
    segment_us: u32,
) -> Result<Vec<Point>, MoveError> {
    for s in [speed.rate, speed.accel] {
        if !(s > 0.0 && s <= 1.0) {
            return Err(MoveError::BadSpeed(s));
        }
    }
    if segment_us == 0 {
        return Err(MoveError::BadSegment);
    }
    let joints = limits.len().min(MAX_JOINTS);
    let mut target = *from;
    for (j, limit) in limits.iter().enumerate().take(joints) {
        if to[j] < limit.min_steps || to[j] > limit.max_steps {
            return Err(MoveError::OutOfRange {
                joint: j,
                target: i64::from(to[j]),
                min: limit.min_steps,
                max: limit.max_steps,
            });
        }
        target[j] = to[j];
    }
    let distance: Vec<f64> = (0..joints)
        .map(|j| (f64::from(target[j]) - f64::from(from[j])).abs())
        .collect();
    if distance.iter().all(|&d| d == 0.0) {
        return Ok(Vec::new());
    }
    for (j, limit) in limits.iter().enumerate().take(joints) {
        if distance[j] > 0.0
            && (limit.max_rate_hz == 0 || limit.max_accel.is_nan() || limit.max_accel <= 0.0)
        {
            return Err(MoveError::CannotMove { joint: j });
        }
    }
    // The shortest duration over the profile shapes tried.
    let (mut duration_s, alpha) = ACCEL_FRACTIONS
        .iter()
        .map(|&alpha| {
            let t = (0..joints)
                .filter(|&j| distance[j] > 0.0)
                .map(|j| {
                    let v = f64::from(limits[j].max_rate_hz) * speed.rate;
                    let a = limits[j].max_accel * speed.accel;
                    (distance[j] / (v * (1.0 - alpha)))
                        .max((distance[j] / (a * alpha * (1.0 - alpha))).sqrt())
                })
                .fold(0.0f64, f64::max);
            (t, alpha)
        })
        .fold(
            (f64::INFINITY, 0.5),
            |best, c| if c.0 < best.0 { c } else { best },
        );
    for _ in 0..=MAX_STRETCHES {
        let total_us = (duration_s * 1e6).ceil().max(1.0);
        if total_us / f64::from(segment_us) > crate::run::MAX_POINTS as f64 {
            return Err(MoveError::TooLong { duration_s });
        }
        let total_us = total_us as i64;
        let segment = i64::from(segment_us);
        let n = (total_us + segment - 1) / segment;
        let mut points = Vec::with_capacity(n as usize);
        let mut previous = *from;
        let mut previous_t = 0i64;
        let mut within_rates = true;
        for k in 1..=n {
            let t = total_us * k / n;
            let s = trapezoid(t as f64 / total_us as f64, alpha);
            let mut position = previous;
            for j in 0..joints {
                position[j] = if k == n {
                    target[j]
                } else {
                    (f64::from(from[j]) + (f64::from(target[j]) - f64::from(from[j])) * s).round()
                        as i32
                };
                let steps = (i64::from(position[j]) - i64::from(previous[j])).unsigned_abs();
                // steps / duration > rate, in integers.
                if u128::from(steps) * 1_000_000
                    > u128::from(limits[j].max_rate_hz) * (t - previous_t) as u128
                {
                    within_rates = false;
                }
            }
            points.push(Point::from_motion(
                (t - previous_t) as i32,
                &previous,
                &position,
            ));
            previous = position;
            previous_t = t;
        }
        if within_rates {
            return Ok(points);
        }
        duration_s *= STRETCH;
    }
    // Rounding to whole steps keeps breaking a rate: only with segments far shorter than
    // a step at the joint's rate, which a longer segment cures.
    Err(MoveError::TooLong { duration_s })
}

impl Client {
    /// Moves the first `limits.len()` joints from where the arm is to `target` (steps; the
    /// other joints hold) on a profile planned by [`plan_move`], uploaded and run as a
    /// trajectory (`options` as for [`Client::run_trajectory`]). `None` when the arm is
    /// already there. The arm must be STOPPED.
    pub fn move_to(
        &self,
        target: &[i32; MAX_JOINTS],
        limits: &[JointLimit],
        speed: MoveSpeed,
        segment_us: u32,
        options: &RunOptions,
        progress: impl FnMut(&Progress),
    ) -> crate::Result<Option<RunReport>> {
        let from = self
            .current_location(std::time::Duration::from_secs(2))?
            .position;
        let points = plan_move(&from, target, limits, speed, segment_us)
            .map_err(|e| Error::InvalidTrajectory(e.to_string()))?;
        if points.is_empty() {
            return Ok(None);
        }
        self.run_trajectory(&points, options, progress).map(Some)
    }
}

/// A target position for one joint, as `armctl move` takes it: `VALUE` (the next joint in
/// order) or `JOINT=VALUE`, JOINT an index or a config name.
#[derive(Clone, Debug, PartialEq)]
pub struct TargetArg {
    /// The joint, when named.
    pub joint: Option<String>,
    /// The value in the move's units.
    pub value: f64,
}

impl std::str::FromStr for TargetArg {
    type Err = String;
    fn from_str(s: &str) -> Result<TargetArg, String> {
        let (joint, value) = match s.split_once('=') {
            Some((j, v)) => (Some(j.trim().to_string()), v),
            None => (None, s),
        };
        let value: f64 = value
            .trim()
            .parse()
            .map_err(|_| format!("{s:?}: a number, or JOINT=NUMBER"))?;
        if !value.is_finite() {
            return Err(format!("{s:?}: a finite number"));
        }
        Ok(TargetArg { joint, value })
    }
}

/// The joint `name` stands for: an index below `joints` or a config name.
pub fn joint_index(name: &str, joints: usize, config: Option<&ArmConfig>) -> Result<usize, String> {
    if let Ok(j) = name.parse::<usize>() {
        return if j < joints {
            Ok(j)
        } else {
            Err(format!("joint {j}: the arm has joints 0 to {}", joints - 1))
        };
    }
    config
        .and_then(|c| {
            c.joints
                .iter()
                .take(joints)
                .position(|jc| jc.name.as_deref() == Some(name))
        })
        .ok_or_else(|| {
            let names: Vec<&str> = config
                .map(|c| c.joints.iter().filter_map(|j| j.name.as_deref()).collect())
                .unwrap_or_default();
            if names.is_empty() {
                format!("joint {name:?}: give an index 0 to {}", joints - 1)
            } else {
                format!(
                    "joint {name:?} is not in the config (its joints: {}), or give an index 0 to {}",
                    names.join(", "),
                    joints - 1
                )
            }
        })
}

/// Absolute step targets from `args` (values in `units`; `relative`: increments from
/// `current`). Joints not named hold. `config` gives units and names; without one only
/// steps.
pub fn targets_in_steps(
    args: &[TargetArg],
    units: Units,
    relative: bool,
    current: &[i32; MAX_JOINTS],
    joints: usize,
    config: &ArmConfig,
) -> Result<[i32; MAX_JOINTS], String> {
    let mut target = *current;
    let mut next = 0usize;
    let mut named = [false; MAX_JOINTS];
    for arg in args {
        let j = match &arg.joint {
            Some(name) => joint_index(name, joints, Some(config))?,
            None => {
                let j = next;
                if j >= joints {
                    return Err(format!(
                        "{} values for {joints} joints",
                        args.iter().filter(|a| a.joint.is_none()).count()
                    ));
                }
                j
            }
        };
        next = j + 1;
        if std::mem::replace(&mut named[j], true) {
            return Err(format!("joint {j} is given twice"));
        }
        let joint = config
            .joints
            .get(j)
            .ok_or_else(|| format!("joint {j} is not in the joint config"))?;
        let steps = if relative {
            f64::from(current[j]) + units.to_steps(arg.value, joint) - units.to_steps(0.0, joint)
        } else {
            units.to_steps(arg.value, joint)
        };
        if !(f64::from(i32::MIN)..=f64::from(i32::MAX)).contains(&steps.round()) {
            return Err(format!(
                "joint {j}: {} {} is {steps:.0} steps, beyond what a position holds",
                arg.value,
                units.name()
            ));
        }
        target[j] = steps.round() as i32;
    }
    Ok(target)
}

/// The name a message gives joint `j`: its name in `config`, else `joint j`.
pub fn joint_label(config: &ArmConfig, j: usize) -> String {
    match config.joints.get(j).and_then(|c| c.name.as_deref()) {
        Some(name) => name.to_string(),
        None => format!("joint {j}"),
    }
}

/// Checks `target` (steps) against each joint's range in `limits`; the message names the
/// joint as the config does and gives the target and the range in `units` (and in steps
/// beside them), as the user gave them (`armctl move`, `jog`; Python `move_to`, `jog`).
pub fn check_targets(
    target: &[i32; MAX_JOINTS],
    limits: &[JointLimit],
    config: &ArmConfig,
    units: Units,
) -> Result<(), String> {
    for (j, limit) in limits.iter().enumerate() {
        if target[j] >= limit.min_steps && target[j] <= limit.max_steps {
            continue;
        }
        let Some(joint) = config.joints.get(j) else {
            return Err(format!(
                "joint {j}: target {} steps is outside its range {} to {} steps",
                target[j], limit.min_steps, limit.max_steps
            ));
        };
        let (in_steps, range_in_steps) = match units {
            Units::Steps => (String::new(), String::new()),
            _ => (
                format!(" ({} steps)", target[j]),
                format!(" ({} to {} steps)", limit.min_steps, limit.max_steps),
            ),
        };
        return Err(format!(
            "{}: target {}{in_steps} is outside its range {} to {}{range_in_steps}",
            joint_label(config, j),
            units.show(i64::from(target[j]), joint),
            units.show(i64::from(limit.min_steps), joint),
            units.show(i64::from(limit.max_steps), joint),
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests;
