//! Trajectory files to [`Waypoints`]: ROS JointTrajectory JSON (radians, with a joint
//! config) and CSV (steps).

use protocol::MAX_JOINTS;
use serde::Deserialize;

use super::{ArmConfig, ErrorKind, TrajectoryError, Waypoints};

/// ROS `trajectory_msgs/JointTrajectory` (as JSON: other fields ignored), in radians.
#[derive(Clone, Debug, Default, Deserialize, PartialEq)]
pub struct JointTrajectory {
    /// Names of the joints, in the order of each point's values.
    pub joint_names: Vec<String>,
    /// The waypoints.
    pub points: Vec<JointTrajectoryPoint>,
}

/// One waypoint of a [`JointTrajectory`].
#[derive(Clone, Debug, Default, Deserialize, PartialEq)]
pub struct JointTrajectoryPoint {
    /// Radians, one per joint name.
    pub positions: Vec<f64>,
    /// Radians per second, one per joint name, or empty: not given.
    #[serde(default)]
    pub velocities: Vec<f64>,
    /// When to be there, from the start of the trajectory.
    pub time_from_start: RosDuration,
}

/// ROS `builtin_interfaces/Duration`.
#[derive(Clone, Copy, Debug, Default, Deserialize, PartialEq)]
pub struct RosDuration {
    /// Whole seconds.
    pub sec: i64,
    /// Nanoseconds, 0..1e9.
    #[serde(default)]
    pub nanosec: u32,
}

/// Parses a JointTrajectory JSON into steps with `config`.
pub fn parse_joint_trajectory(
    text: &str,
    file: &str,
    config: &ArmConfig,
) -> Result<Waypoints, TrajectoryError> {
    let trajectory: JointTrajectory = serde_json::from_str(text)
        .map_err(|e| TrajectoryError::new(file, ErrorKind::Parse(e.to_string())))?;
    joint_trajectory_to_waypoints(&trajectory, file, config)
}

/// Converts a [`JointTrajectory`] in radians into waypoints in steps with `config`; `file`
/// names its source in errors. Joint names are matched against the config's names (by
/// position when the config names none).
pub fn joint_trajectory_to_waypoints(
    trajectory: &JointTrajectory,
    file: &str,
    config: &ArmConfig,
) -> Result<Waypoints, TrajectoryError> {
    let named = config.joints.iter().any(|j| j.name.is_some());
    // Index into the config of each column of the file.
    let mut columns = Vec::with_capacity(trajectory.joint_names.len());
    for (i, name) in trajectory.joint_names.iter().enumerate() {
        let joint = if named {
            config
                .joints
                .iter()
                .position(|j| j.name.as_deref() == Some(name.as_str()))
        } else {
            (i < config.joints.len()).then_some(i)
        };
        match joint {
            Some(j) => columns.push(j),
            None => {
                return Err(TrajectoryError::new(
                    file,
                    ErrorKind::UnknownJoint(name.clone()),
                ));
            }
        }
    }
    let mut waypoints = Waypoints {
        file: file.to_string(),
        times_us: Vec::new(),
        positions: Vec::new(),
        velocities: Vec::new(),
    };
    for (i, point) in trajectory.points.iter().enumerate() {
        let time_us =
            point.time_from_start.sec * 1_000_000 + i64::from(point.time_from_start.nanosec / 1000);
        let finite = point
            .positions
            .iter()
            .chain(&point.velocities)
            .all(|v| v.is_finite());
        if !finite {
            return Err(TrajectoryError::new(
                file,
                ErrorKind::Parse("a position or velocity is not a finite number".into()),
            )
            .at(i, time_us, None));
        }
        let velocities_given = !point.velocities.is_empty();
        if velocities_given && point.velocities.len() != columns.len() {
            return Err(TrajectoryError::new(
                file,
                ErrorKind::WrongJointCount {
                    found: point.velocities.len(),
                    expected: columns.len(),
                },
            )
            .at(i, time_us, None));
        }
        if point.positions.len() != columns.len() {
            return Err(TrajectoryError::new(
                file,
                ErrorKind::WrongJointCount {
                    found: point.positions.len(),
                    expected: columns.len(),
                },
            )
            .at(i, time_us, None));
        }
        let mut row = vec![None; config.joints.len()];
        for (&j, &radians) in columns.iter().zip(&point.positions) {
            let joint = &config.joints[j];
            row[j] = Some(f64::from(joint.zero_offset_steps) + radians * joint.steps_per_radian);
        }
        let mut speeds = vec![None; config.joints.len()];
        for (&j, &radians_per_s) in columns.iter().zip(&point.velocities) {
            speeds[j] = Some(radians_per_s * config.joints[j].steps_per_radian);
        }
        waypoints.times_us.push(time_us);
        waypoints.positions.push(row);
        waypoints.velocities.push(speeds);
    }
    check_times(&waypoints)?;
    Ok(waypoints)
}

/// Parses CSV rows `time_s, steps joint 0, steps joint 1, ...` (a first line that is not
/// numbers is a header; `#` starts a comment line). A header's joint columns are named
/// `j0`, `j1`, ... or `0`, `1`, ..., in any order (joints left out hold); any other name
/// is refused, naming it (a config's names need [`parse_csv_with`]).
pub fn parse_csv(text: &str, file: &str) -> Result<Waypoints, TrajectoryError> {
    parse_csv_with(text, file, None)
}

/// As [`parse_csv`], a header's columns also named after `config`'s joints (issue 31:
/// `time_s,elbow,base` moved joints 0 and 1, in the file's order). Without a header the
/// columns are joints 0, 1, ... in order.
pub fn parse_csv_with(
    text: &str,
    file: &str,
    config: Option<&ArmConfig>,
) -> Result<Waypoints, TrajectoryError> {
    let (mut waypoints, header) = parse_csv_table(text, file)?;
    if let Some(header) = header {
        let columns = header
            .iter()
            .enumerate()
            .map(|(c, name)| column_joint(name, c + 2, file, config))
            .collect::<Result<Vec<usize>, _>>()?;
        for (c, &j) in columns.iter().enumerate() {
            if let Some(first) = columns[..c].iter().position(|&k| k == j) {
                return Err(TrajectoryError::new(
                    file,
                    ErrorKind::Parse(format!(
                        "columns {} ({:?}) and {} ({:?}) are both joint {j}",
                        first + 2,
                        header[first],
                        c + 2,
                        header[c]
                    )),
                ));
            }
        }
        let width = columns.iter().max().map_or(0, |&j| j + 1);
        for row in &mut waypoints.positions {
            let mut mapped = vec![None; width];
            for (&j, value) in columns.iter().zip(row.iter()) {
                mapped[j] = *value;
            }
            *row = mapped;
        }
    }
    Ok(waypoints)
}

/// The joint a CSV header's column `name` (column number `column`, from 1) stands for: a
/// name of `config`'s joints, `jN` or `N`.
fn column_joint(
    name: &str,
    column: usize,
    file: &str,
    config: Option<&ArmConfig>,
) -> Result<usize, TrajectoryError> {
    if let Some(j) = config.and_then(|c| {
        c.joints
            .iter()
            .position(|jc| jc.name.as_deref() == Some(name))
    }) {
        return Ok(j);
    }
    let index = name
        .strip_prefix(['j', 'J'])
        .unwrap_or(name)
        .parse::<usize>()
        .ok();
    let joints = config.map_or(MAX_JOINTS, |c| c.joints.len());
    match index {
        Some(j) if j < joints => Ok(j),
        _ => {
            let names: Vec<&str> = config
                .map(|c| c.joints.iter().filter_map(|j| j.name.as_deref()).collect())
                .unwrap_or_default();
            let known = if names.is_empty() {
                format!("name the columns j0 to j{}", joints - 1)
            } else {
                format!(
                    "the config's joints are {}; j0 to j{} also name joints by index",
                    names.join(", "),
                    joints - 1
                )
            };
            Err(TrajectoryError::new(
                file,
                ErrorKind::Parse(format!(
                    "column {column} of the header, {name:?}, is not a joint ({known})"
                )),
            ))
        }
    }
}

/// The CSV's rows in the file's column order, and its header's joint column names (the
/// time column left out), when it has a header.
fn parse_csv_table(
    text: &str,
    file: &str,
) -> Result<(Waypoints, Option<Vec<String>>), TrajectoryError> {
    let mut header = None;
    let mut waypoints = Waypoints {
        file: file.to_string(),
        times_us: Vec::new(),
        positions: Vec::new(),
        velocities: Vec::new(),
    };
    let mut joints = None;
    let mut rows = csv::ReaderBuilder::new()
        .has_headers(false)
        .flexible(true)
        .trim(csv::Trim::All)
        .comment(Some(b'#'))
        .from_reader(text.as_bytes());
    for row in rows.records() {
        let row = row.map_err(|e| {
            let line = e
                .position()
                .map_or(String::new(), |p| format!("line {}: ", p.line()));
            TrajectoryError::new(file, ErrorKind::Parse(format!("{line}{e}")))
        })?;
        let line_no = row.position().map_or(0, |p| p.line() as usize - 1);
        let fields: Vec<&str> = row.iter().collect();
        if fields.iter().all(|f| f.is_empty()) || fields[0].starts_with('#') {
            // A blank line, or a comment after spaces.
            continue;
        }
        let numbers: Result<Vec<f64>, _> = fields.iter().map(|f| f.parse::<f64>()).collect();
        let numbers = match numbers {
            Ok(n) => n,
            Err(_) if waypoints.times_us.is_empty() && joints.is_none() => {
                // The header.
                joints = Some(fields.len().saturating_sub(1));
                header = Some(fields.iter().skip(1).map(|f| f.to_string()).collect());
                continue;
            }
            Err(e) => {
                return Err(TrajectoryError::new(
                    file,
                    ErrorKind::Parse(format!("line {}: {e}", line_no + 1)),
                ));
            }
        };
        let expected = *joints.get_or_insert(numbers.len().saturating_sub(1));
        if expected == 0 || expected > MAX_JOINTS {
            return Err(TrajectoryError::new(
                file,
                ErrorKind::Parse(format!(
                    "line {}: time and 1 to {MAX_JOINTS} joint positions expected",
                    line_no + 1
                )),
            ));
        }
        let time_us = (numbers[0] * 1e6).round() as i64;
        let point = waypoints.times_us.len();
        if numbers.len() - 1 != expected {
            return Err(TrajectoryError::new(
                file,
                ErrorKind::WrongJointCount {
                    found: numbers.len() - 1,
                    expected,
                },
            )
            .at(point, time_us, None));
        }
        if numbers.iter().any(|n| !n.is_finite()) {
            return Err(TrajectoryError::new(
                file,
                ErrorKind::Parse(format!("line {}: not a finite number", line_no + 1)),
            ));
        }
        waypoints.times_us.push(time_us);
        waypoints
            .positions
            .push(numbers[1..].iter().map(|&p| Some(p)).collect());
    }
    check_times(&waypoints)?;
    Ok((waypoints, header))
}

fn check_times(waypoints: &Waypoints) -> Result<(), TrajectoryError> {
    let file = &waypoints.file;
    if waypoints.times_us.is_empty() {
        return Err(TrajectoryError::new(file, ErrorKind::TooShort));
    }
    if waypoints.times_us[0] < 0 {
        return Err(TrajectoryError::new(file, ErrorKind::TimeNotIncreasing).at(
            0,
            waypoints.times_us[0],
            None,
        ));
    }
    for (i, pair) in waypoints.times_us.windows(2).enumerate() {
        if pair[1] <= pair[0] {
            return Err(TrajectoryError::new(file, ErrorKind::TimeNotIncreasing).at(
                i + 1,
                pair[1],
                None,
            ));
        }
    }
    Ok(())
}
