//! Trajectory files to controller [`Point`](protocol::Point)s.
//!
//! Two inputs:
//! - JSON in the shape of ROS `trajectory_msgs/JointTrajectory`: `joint_names`, and
//!   `points` with `positions` in radians and `time_from_start {sec, nanosec}`. It needs an
//!   [`ArmConfig`] (steps per radian, zero offset, limits, max step rate per joint).
//! - CSV: `time_s, joint 0, joint 1, ...` with positions in steps, or in the config's
//!   `units` (degrees, radians); an optional header line whose columns name the joints
//!   (the config's names, `jN` or `N`, in any order; another name is refused). Joints
//!   the file leaves out hold their position.
//!
//! [`to_points`] resamples the waypoints into segments no longer than the duration asked
//! for, each span between two waypoints cut into equal segments so that every waypoint is a
//! segment's end (none is skipped, whatever the duration: [`check_waypoints`] proves it of
//! the result), rounds to whole steps, fills the timer hints with
//! [`Point::from_motion`](protocol::Point::from_motion),
//! and refuses, naming the file, the point and time, the joint, the value and the limit,
//! whatever breaks a joint's position limits or step rate.
//!
//! Between two waypoints that both give a joint's velocity (MoveIt's trajectories do), that
//! joint follows the cubic Hermite curve through both positions with both velocities, as
//! ROS trajectory controllers do; without velocities it follows a straight line. Either way
//! every waypoint is passed exactly (to the rounding to whole steps) and the last point is
//! the last waypoint.
//!
//! As in ROS, a first waypoint later than time 0 means "from wherever the arm is": the
//! current position is taken as the waypoint at time 0. A first waypoint at time 0 must be
//! where the arm is. More than 65535 points is refused (one NEW announces at most 65535):
//! the message gives the shortest segment duration that fits.

//!
//! The module is laid out as the conversion runs: `config` (the joint config file),
//! `parse` (JointTrajectory JSON and CSV to [`Waypoints`]), `resample` (waypoints to
//! points, linear or Hermite, with the limit checks), and the error type.

use std::path::Path;

use crate::motion::Units;

mod config;
mod error;
mod parse;
mod resample;
#[cfg(test)]
mod tests;

pub use config::{ArmConfig, JointConfig};
pub use error::{ErrorKind, JointShown, TrajectoryError, slow_down};
pub use parse::{
    JointTrajectory, JointTrajectoryPoint, RosDuration, joint_trajectory_to_waypoints, parse_csv,
    parse_csv_with, parse_joint_trajectory,
};
pub use resample::{check_waypoints, to_points};

/// A segment duration given in milliseconds (`--segment-ms`, Python's `segment_ms`) as
/// microseconds, 1 us at least; the error names the option.
pub fn segment_us(segment_ms: f64, option: &str) -> Result<u32, String> {
    if !(segment_ms.is_finite() && segment_ms > 0.0) {
        return Err(format!("{option} must be above 0, not {segment_ms}"));
    }
    Ok((segment_ms * 1000.0).round().clamp(1.0, 1e9) as u32)
}

/// Waypoints in steps, as read from a file.
#[derive(Clone, Debug, PartialEq)]
pub struct Waypoints {
    /// The file they came from (for messages).
    pub file: String,
    /// Time from start of each waypoint, microseconds, strictly increasing.
    pub times_us: Vec<i64>,
    /// Position of each joint at each waypoint, in (fractional) steps; `None`: the joint is
    /// not in the file and holds its current position.
    pub positions: Vec<Vec<Option<f64>>>,
    /// Velocity of each joint at each waypoint, steps per second, in the shape of
    /// `positions`; `None` (or an empty list for the waypoint): not given. A segment whose
    /// two ends give a joint's velocity is a cubic Hermite curve for that joint.
    pub velocities: Vec<Vec<Option<f64>>>,
}

/// Reads a trajectory file and, when given, the joint config file it is read with; the
/// config is returned too, for the conversion to points. A CSV is in the config's `units`.
pub fn load_files(
    path: &Path,
    config: Option<&Path>,
) -> Result<(Waypoints, Option<ArmConfig>), TrajectoryError> {
    load_files_in(path, config, None)
}

/// As [`load_files`], a CSV in `units` when given (else the config's `units`, else steps).
pub fn load_files_in(
    path: &Path,
    config: Option<&Path>,
    units: Option<Units>,
) -> Result<(Waypoints, Option<ArmConfig>), TrajectoryError> {
    let config = config.map(ArmConfig::load).transpose()?;
    let waypoints = load_in(path, config.as_ref(), units)?;
    Ok((waypoints, config))
}

/// Reads a trajectory file: `.json` (JointTrajectory, needs `config`) or anything else as
/// CSV in the config's `units` (steps without a config).
pub fn load(path: &Path, config: Option<&ArmConfig>) -> Result<Waypoints, TrajectoryError> {
    load_in(path, config, None)
}

/// As [`load`], a CSV in `units` when given. With a config, a CSV may name fewer joints
/// than it configures: the others hold their position.
pub fn load_in(
    path: &Path,
    config: Option<&ArmConfig>,
    units: Option<Units>,
) -> Result<Waypoints, TrajectoryError> {
    let file = path.display().to_string();
    let text = std::fs::read_to_string(path)
        .map_err(|e| TrajectoryError::new(&file, ErrorKind::Read(e.to_string())))?;
    let is_json = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("json"));
    if is_json {
        let config = config.ok_or_else(|| {
            TrajectoryError::new(
                &file,
                ErrorKind::Parse(
                    "a JointTrajectory in radians needs a joint config (--config FILE)".into(),
                ),
            )
        })?;
        parse_joint_trajectory(&text, &file, config)
    } else {
        let mut waypoints = parse_csv_with(&text, &file, config)?;
        let units = units.or(config.map(|c| c.units)).unwrap_or_default();
        match config {
            Some(config) => csv_with_config(&mut waypoints, config, units)?,
            None if units != Units::Steps => {
                return Err(TrajectoryError::new(
                    &file,
                    ErrorKind::Parse(format!(
                        "a CSV in {} needs a joint config (--config FILE)",
                        units.name()
                    )),
                ));
            }
            None => {}
        }
        Ok(waypoints)
    }
}

/// A CSV read with a joint config: positions from `units` to steps, and rows padded to
/// the config's joints (joints left out hold). More columns than joints configured is
/// refused.
fn csv_with_config(
    waypoints: &mut Waypoints,
    config: &ArmConfig,
    units: Units,
) -> Result<(), TrajectoryError> {
    let columns = waypoints.positions.first().map_or(0, Vec::len);
    if columns > config.joints.len() {
        return Err(TrajectoryError::new(
            &waypoints.file,
            ErrorKind::WrongJointCount {
                found: columns,
                expected: config.joints.len(),
            },
        ));
    }
    for row in &mut waypoints.positions {
        for (value, joint) in row.iter_mut().zip(&config.joints) {
            *value = value.map(|v| units.to_steps(v, joint));
        }
        row.resize(config.joints.len(), None);
    }
    Ok(())
}
