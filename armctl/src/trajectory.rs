//! Trajectory files to controller [`Point`]s.
//!
//! Two inputs:
//! - JSON in the shape of ROS `trajectory_msgs/JointTrajectory`: `joint_names`, and
//!   `points` with `positions` in radians and `time_from_start {sec, nanosec}`. It needs an
//!   [`ArmConfig`] (steps per radian, zero offset, limits, max step rate per joint).
//! - CSV: `time_s, joint 0, joint 1, ...` with positions in steps (an optional header line).
//!
//! [`to_points`] resamples the waypoints at a fixed segment duration (the last segment may
//! be shorter), rounds to whole steps, fills the timer hints with [`Point::from_motion`],
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

use std::fmt;
use std::path::Path;

use protocol::{MAX_JOINTS, Point};
use serde::Deserialize;

use crate::run::MAX_POINTS;

/// One joint's calibration and limits.
#[derive(Clone, Debug, Deserialize, PartialEq)]
pub struct JointConfig {
    /// The name the trajectory files use (`joint_names`); optional for CSV.
    #[serde(default)]
    pub name: Option<String>,
    /// Steps per radian of joint motion (gearing and microstepping included; negative to
    /// reverse the direction).
    #[serde(default = "default_steps_per_radian")]
    pub steps_per_radian: f64,
    /// Step position of 0 rad.
    #[serde(default)]
    pub zero_offset_steps: i32,
    /// Lowest position allowed, steps.
    #[serde(default = "min_i32")]
    pub min_steps: i32,
    /// Highest position allowed, steps.
    #[serde(default = "max_i32")]
    pub max_steps: i32,
    /// Highest step rate of this joint, steps per second.
    pub max_step_rate_hz: u32,
}

fn default_steps_per_radian() -> f64 {
    1.0
}
fn min_i32() -> i32 {
    i32::MIN
}
fn max_i32() -> i32 {
    i32::MAX
}

/// The joint config file: `{"joints": [ {...}, ... ]}` in joint order.
#[derive(Clone, Debug, Deserialize, PartialEq)]
pub struct ArmConfig {
    /// Joint 0 first.
    pub joints: Vec<JointConfig>,
}

impl ArmConfig {
    /// Reads a joint config file.
    pub fn load(path: &Path) -> Result<ArmConfig, TrajectoryError> {
        let file = path.display().to_string();
        let text = std::fs::read_to_string(path)
            .map_err(|e| TrajectoryError::new(&file, ErrorKind::Read(e.to_string())))?;
        Self::parse(&text, &file)
    }

    /// Parses a joint config; `file` names it in errors.
    pub fn parse(text: &str, file: &str) -> Result<ArmConfig, TrajectoryError> {
        let config: ArmConfig = serde_json::from_str(text)
            .map_err(|e| TrajectoryError::new(file, ErrorKind::Parse(e.to_string())))?;
        if config.joints.is_empty() || config.joints.len() > MAX_JOINTS {
            return Err(TrajectoryError::new(
                file,
                ErrorKind::Parse(format!(
                    "{} joints configured: 1 to {MAX_JOINTS}",
                    config.joints.len()
                )),
            ));
        }
        for (j, joint) in config.joints.iter().enumerate() {
            if joint.min_steps > joint.max_steps
                || !joint.steps_per_radian.is_finite()
                || joint.steps_per_radian == 0.0
            {
                let name = joint
                    .name
                    .as_ref()
                    .map_or(String::new(), |n| format!(" ({n})"));
                return Err(TrajectoryError::new(
                    file,
                    ErrorKind::Parse(format!(
                        "joint {j}{name}: min_steps must not exceed max_steps and \
                         steps_per_radian must be a non-zero number"
                    )),
                ));
            }
        }
        Ok(config)
    }

    /// A config with no position limits and one step rate for `joints` joints.
    pub fn unlimited(joints: usize, max_step_rate_hz: u32) -> ArmConfig {
        ArmConfig {
            joints: (0..joints.min(MAX_JOINTS))
                .map(|_| JointConfig {
                    name: None,
                    steps_per_radian: 1.0,
                    zero_offset_steps: 0,
                    min_steps: i32::MIN,
                    max_steps: i32::MAX,
                    max_step_rate_hz,
                })
                .collect(),
        }
    }
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

/// Why a trajectory file was refused: where, and what.
#[derive(Clone, Debug, PartialEq)]
pub struct TrajectoryError {
    /// The file.
    pub file: String,
    /// Index of the file's waypoint (limits, start, times) or of the resampled segment
    /// (step rate: the kind says which).
    pub point: Option<usize>,
    /// Time from start of that point, seconds.
    pub time_s: Option<f64>,
    /// The joint.
    pub joint: Option<usize>,
    /// The joint's name in the joint config, when it has one (boxed: a small error).
    pub joint_name: Option<Box<str>>,
    /// What is wrong.
    pub kind: ErrorKind,
}

/// What is wrong with a trajectory.
#[derive(Clone, Debug, PartialEq)]
pub enum ErrorKind {
    /// The file cannot be read.
    Read(String),
    /// The file is not valid JSON/CSV of the expected shape.
    Parse(String),
    /// A joint name not in the joint config.
    UnknownJoint(String),
    /// A waypoint has the wrong number of positions.
    WrongJointCount {
        /// Positions found.
        found: usize,
        /// Positions expected.
        expected: usize,
    },
    /// Times do not increase strictly.
    TimeNotIncreasing,
    /// Fewer than two waypoints, or no time between them.
    TooShort,
    /// A position below the joint's minimum (steps).
    BelowMin {
        /// Position, steps.
        value: i64,
        /// Limit, steps.
        limit: i32,
    },
    /// A position above the joint's maximum (steps).
    AboveMax {
        /// Position, steps.
        value: i64,
        /// Limit, steps.
        limit: i32,
    },
    /// A segment asks for more steps per second than the joint (or controller) allows.
    StepRate {
        /// Steps in the segment.
        steps: u64,
        /// Segment duration, microseconds.
        duration_us: u32,
        /// Limit, steps per second.
        limit_hz: u32,
    },
    /// The first waypoint at time 0 is not where the arm is.
    StartMismatch {
        /// Where the arm is, steps.
        current: i32,
        /// Where the trajectory starts, steps.
        start: i64,
    },
    /// More points than one upload takes.
    TooManyPoints {
        /// Points after resampling.
        count: usize,
        /// Shortest segment duration that fits, microseconds.
        min_segment_us: u64,
    },
    /// A segment duration of 0.
    BadSegment,
}

impl TrajectoryError {
    fn new(file: &str, kind: ErrorKind) -> TrajectoryError {
        TrajectoryError {
            file: file.to_string(),
            point: None,
            time_s: None,
            joint: None,
            joint_name: None,
            kind,
        }
    }

    fn at(mut self, point: usize, time_us: i64, joint: Option<usize>) -> TrajectoryError {
        self.point = Some(point);
        self.time_s = Some(time_us as f64 / 1e6);
        self.joint = joint;
        self
    }

    /// Names the joint after `config` (its `name`), for the message.
    pub fn with_joint_names(mut self, config: &ArmConfig) -> TrajectoryError {
        if let Some(j) = self.joint {
            self.joint_name = config
                .joints
                .get(j)
                .and_then(|c| c.name.as_deref())
                .map(Box::from);
        }
        self
    }

    /// Whether `point` counts resampled segments (`--segment-ms`) rather than the file's
    /// waypoints.
    pub fn point_is_segment(&self) -> bool {
        matches!(self.kind, ErrorKind::StepRate { .. })
    }
}

impl fmt::Display for TrajectoryError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.file)?;
        if let Some(p) = self.point {
            if self.point_is_segment() {
                write!(f, ": resampled segment {p}")?;
            } else {
                write!(f, ": waypoint {p} of the file")?;
            }
        }
        if let Some(t) = self.time_s {
            write!(f, " (t = {t:.6} s)")?;
        }
        if let Some(j) = self.joint {
            write!(f, ", joint {j}")?;
            if let Some(name) = &self.joint_name {
                write!(f, " ({name})")?;
            }
        }
        f.write_str(": ")?;
        match &self.kind {
            ErrorKind::Read(e) => write!(f, "cannot read: {e}"),
            ErrorKind::Parse(e) => write!(f, "cannot parse: {e}"),
            ErrorKind::UnknownJoint(name) => write!(
                f,
                "joint name {name:?} is not in the joint config (add a joint with that `name`)"
            ),
            ErrorKind::WrongJointCount { found, expected } => {
                write!(f, "{found} positions, expected {expected}")
            }
            ErrorKind::TimeNotIncreasing => {
                f.write_str("time does not increase from the previous point")
            }
            ErrorKind::TooShort => {
                f.write_str("a trajectory needs two waypoints at different times")
            }
            ErrorKind::BelowMin { value, limit } => {
                write!(
                    f,
                    "position {value} steps is below the minimum {limit} steps"
                )
            }
            ErrorKind::AboveMax { value, limit } => {
                write!(
                    f,
                    "position {value} steps is above the maximum {limit} steps"
                )
            }
            ErrorKind::StepRate {
                steps,
                duration_us,
                limit_hz,
            } => write!(
                f,
                "{steps} steps in {duration_us} us = {:.0} steps/s exceeds the limit of {limit_hz} steps/s: slow the trajectory down",
                *steps as f64 * 1e6 / f64::from(*duration_us)
            ),
            ErrorKind::StartMismatch { current, start } => write!(
                f,
                "the trajectory starts at {start} steps at t = 0 but the arm is at {current} \
                 steps: move there first, or start the trajectory later than t = 0 to move \
                 from the current position"
            ),
            ErrorKind::TooManyPoints {
                count,
                min_segment_us,
            } => write!(
                f,
                "{count} points after resampling, one upload takes at most {MAX_POINTS}: \
                 use segments of {min_segment_us} us or longer"
            ),
            ErrorKind::BadSegment => f.write_str("the segment duration must be at least 1 us"),
        }
    }
}

impl std::error::Error for TrajectoryError {}

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

/// Reads a trajectory file and, when given, the joint config file it is read with; the
/// config is returned too, for the conversion to points.
pub fn load_files(
    path: &Path,
    config: Option<&Path>,
) -> Result<(Waypoints, Option<ArmConfig>), TrajectoryError> {
    let config = config.map(ArmConfig::load).transpose()?;
    let waypoints = load(path, config.as_ref())?;
    Ok((waypoints, config))
}

/// Reads a trajectory file: `.json` (JointTrajectory, needs `config`) or anything else as
/// CSV in steps.
pub fn load(path: &Path, config: Option<&ArmConfig>) -> Result<Waypoints, TrajectoryError> {
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
        parse_csv(&text, &file)
    }
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
/// numbers is a header; `#` starts a comment line).
pub fn parse_csv(text: &str, file: &str) -> Result<Waypoints, TrajectoryError> {
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
    Ok(waypoints)
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

/// Resamples `waypoints` into points of `segment_us` (the last one may be shorter), from
/// the arm's current position `current`, and checks every position against the joint
/// limits of `config` and every segment against the lower of the joint's and the
/// controller's (`controller_max_rate_hz`) step rate.
pub fn to_points(
    waypoints: &Waypoints,
    current: &[i32; MAX_JOINTS],
    segment_us: u32,
    config: &ArmConfig,
    controller_max_rate_hz: Option<u32>,
) -> Result<Vec<Point>, TrajectoryError> {
    let file = waypoints.file.as_str();
    if segment_us == 0 {
        return Err(TrajectoryError::new(file, ErrorKind::BadSegment));
    }
    let joints = waypoints
        .positions
        .first()
        .map_or(0, Vec::len)
        .min(MAX_JOINTS);
    if joints != config.joints.len() {
        return Err(TrajectoryError::new(
            file,
            ErrorKind::WrongJointCount {
                found: joints,
                expected: config.joints.len(),
            },
        ));
    }
    // Waypoints in whole-number steps (held joints at the current position), with the
    // current position prepended at t = 0 when the file starts later.
    let mut times = Vec::with_capacity(waypoints.times_us.len() + 1);
    let mut rows: Vec<[f64; MAX_JOINTS]> = Vec::with_capacity(times.capacity());
    // Steps per second where given (Hermite segments), `None` where not (straight lines).
    let mut speeds: Vec<[Option<f64>; MAX_JOINTS]> = Vec::with_capacity(times.capacity());
    if waypoints.times_us[0] > 0 {
        times.push(0);
        rows.push(current.map(f64::from));
        speeds.push([None; MAX_JOINTS]);
    }
    for (i, (&t, row)) in waypoints
        .times_us
        .iter()
        .zip(&waypoints.positions)
        .enumerate()
    {
        let mut steps = current.map(f64::from);
        let mut speed = [None; MAX_JOINTS];
        for (j, value) in row.iter().enumerate().take(joints) {
            if let Some(v) = value {
                steps[j] = *v;
                speed[j] = waypoints
                    .velocities
                    .get(i)
                    .and_then(|r| r.get(j))
                    .copied()
                    .flatten();
            }
            let position = steps[j].round() as i64;
            let limits = &config.joints[j];
            if position < i64::from(limits.min_steps) {
                return Err(TrajectoryError::new(
                    file,
                    ErrorKind::BelowMin {
                        value: position,
                        limit: limits.min_steps,
                    },
                )
                .at(i, t, Some(j)));
            }
            if position > i64::from(limits.max_steps) {
                return Err(TrajectoryError::new(
                    file,
                    ErrorKind::AboveMax {
                        value: position,
                        limit: limits.max_steps,
                    },
                )
                .at(i, t, Some(j)));
            }
            if t == 0 && position != i64::from(current[j]) {
                return Err(TrajectoryError::new(
                    file,
                    ErrorKind::StartMismatch {
                        current: current[j],
                        start: position,
                    },
                )
                .at(i, t, Some(j)));
            }
        }
        times.push(t);
        rows.push(steps);
        speeds.push(speed);
    }
    let total_us = *times.last().unwrap_or(&0);
    if times.len() < 2 || total_us <= 0 {
        return Err(TrajectoryError::new(file, ErrorKind::TooShort));
    }
    let segment = i64::from(segment_us);
    let count = (total_us + segment - 1) / segment;
    if count > MAX_POINTS as i64 {
        let min_segment_us = (total_us as u64).div_ceil(MAX_POINTS as u64);
        return Err(TrajectoryError::new(
            file,
            ErrorKind::TooManyPoints {
                count: count as usize,
                min_segment_us,
            },
        ));
    }
    let mut points = Vec::with_capacity(count as usize);
    let mut previous = *current;
    let mut previous_t = 0i64;
    let mut w = 0usize;
    for k in 1..=count {
        let t = (k * segment).min(total_us);
        while w + 2 < times.len() && times[w + 1] < t {
            w += 1;
        }
        let (t0, t1) = (times[w], times[w + 1]);
        let f = (t - t0) as f64 / (t1 - t0) as f64;
        let segment_s = (t1 - t0) as f64 / 1e6;
        let mut target = previous;
        for j in 0..joints {
            let (p0, p1) = (rows[w][j], rows[w + 1][j]);
            let p = match (speeds[w][j], speeds[w + 1][j]) {
                (Some(v0), Some(v1)) => hermite(p0, v0 * segment_s, p1, v1 * segment_s, f),
                _ => p0 + (p1 - p0) * f,
            };
            target[j] = p.round().clamp(f64::from(i32::MIN), f64::from(i32::MAX)) as i32;
        }
        let duration = (t - previous_t) as u32;
        let index = points.len();
        for (j, limits) in config.joints.iter().enumerate() {
            // Waypoints are checked above; a Hermite curve can overshoot between them.
            if target[j] < limits.min_steps {
                return Err(TrajectoryError::new(
                    file,
                    ErrorKind::BelowMin {
                        value: i64::from(target[j]),
                        limit: limits.min_steps,
                    },
                )
                .at(index, t, Some(j)));
            }
            if target[j] > limits.max_steps {
                return Err(TrajectoryError::new(
                    file,
                    ErrorKind::AboveMax {
                        value: i64::from(target[j]),
                        limit: limits.max_steps,
                    },
                )
                .at(index, t, Some(j)));
            }
            let limit_hz = controller_max_rate_hz
                .map_or(limits.max_step_rate_hz, |c| c.min(limits.max_step_rate_hz));
            let steps = (i64::from(target[j]) - i64::from(previous[j])).unsigned_abs();
            // steps / duration > limit, in integers.
            if u128::from(steps) * 1_000_000 > u128::from(limit_hz) * u128::from(duration) {
                return Err(TrajectoryError::new(
                    file,
                    ErrorKind::StepRate {
                        steps,
                        duration_us: duration,
                        limit_hz,
                    },
                )
                .at(index, t, Some(j)));
            }
        }
        points.push(Point::from_motion(duration as i32, &previous, &target));
        previous = target;
        previous_t = t;
    }
    Ok(points)
}

/// The cubic Hermite curve from `p0` to `p1` at `f` in 0..=1, with the end tangents `m0`
/// and `m1` already scaled to the segment (velocity times its duration).
fn hermite(p0: f64, m0: f64, p1: f64, m1: f64, f: f64) -> f64 {
    let f2 = f * f;
    let f3 = f2 * f;
    (2.0 * f3 - 3.0 * f2 + 1.0) * p0
        + (f3 - 2.0 * f2 + f) * m0
        + (-2.0 * f3 + 3.0 * f2) * p1
        + (f3 - f2) * m1
}

#[cfg(test)]
mod tests {
    use super::*;

    const CONFIG: &str = r#"{"joints": [
        {"name": "shoulder", "steps_per_radian": 1000.0, "zero_offset_steps": 100,
         "min_steps": -2000, "max_steps": 4000, "max_step_rate_hz": 2000},
        {"name": "elbow", "steps_per_radian": -500.0, "max_step_rate_hz": 1000}
    ]}"#;

    fn config() -> ArmConfig {
        ArmConfig::parse(CONFIG, "arm.json").unwrap()
    }

    fn trajectory(points: &str) -> String {
        format!(r#"{{"joint_names": ["shoulder", "elbow"], "points": [{points}]}}"#)
    }

    fn point(sec: i64, nanosec: u32, a: f64, b: f64) -> String {
        format!(
            r#"{{"positions": [{a}, {b}], "velocities": [], "time_from_start": {{"sec": {sec}, "nanosec": {nanosec}}}}}"#
        )
    }

    #[test]
    fn joint_trajectory_radians_to_steps() {
        let text = trajectory(&[point(0, 0, 0.0, 0.0), point(1, 500_000_000, 1.5, 0.5)].join(","));
        let w = parse_joint_trajectory(&text, "t.json", &config()).unwrap();
        assert_eq!(w.times_us, vec![0, 1_500_000]);
        assert_eq!(w.positions[0], vec![Some(100.0), Some(0.0)]);
        assert_eq!(w.positions[1], vec![Some(1600.0), Some(-250.0)]);
    }

    #[test]
    fn joint_names_follow_the_config_not_the_file_order() {
        let text = r#"{"joint_names": ["elbow"], "points": [
            {"positions": [1.0], "time_from_start": {"sec": 1, "nanosec": 0}}]}"#;
        let w = parse_joint_trajectory(text, "t.json", &config()).unwrap();
        assert_eq!(w.positions[0], vec![None, Some(-500.0)]);
        let unknown = r#"{"joint_names": ["wrist"], "points": []}"#;
        let err = parse_joint_trajectory(unknown, "t.json", &config()).unwrap_err();
        assert_eq!(err.kind, ErrorKind::UnknownJoint("wrist".into()));
        assert!(err.to_string().contains("\"wrist\""));
    }

    #[test]
    fn resampling_interpolates_linearly_and_keeps_the_end_exact() {
        // Joint 0 from 100 to 1600 steps in 1.5 s, at 100 ms segments: 15 points of 100.
        let text = trajectory(&[point(0, 0, 0.0, 0.0), point(1, 500_000_000, 1.5, 0.5)].join(","));
        let w = parse_joint_trajectory(&text, "t.json", &config()).unwrap();
        let start = [100, 0, 7, 0, 0, 0, 0, 0];
        let points = to_points(&w, &start, 100_000, &config(), None).unwrap();
        assert_eq!(points.len(), 15);
        for (k, p) in points.iter().enumerate() {
            assert_eq!(p.duration, 100_000);
            assert_eq!(p.position[0], 100 + 100 * (k as i32 + 1));
            // Joints beyond the config hold their position.
            assert_eq!(p.position[2], 7);
        }
        assert_eq!(points[14].position[1], -250);
        // Hints as PROTOCOL.md section 5 wants them.
        assert_eq!(points[0].number_of_period[0], 100);
        assert_eq!(points[0].period[0], 1000);
    }

    #[test]
    fn last_segment_is_shorter_when_the_duration_does_not_divide() {
        let w = parse_csv("time_s,j0\n0,0\n0.25,100\n", "t.csv").unwrap();
        let config = ArmConfig::unlimited(1, 10_000);
        let points = to_points(&w, &[0; 8], 100_000, &config, None).unwrap();
        let durations: Vec<i32> = points.iter().map(|p| p.duration).collect();
        assert_eq!(durations, vec![100_000, 100_000, 50_000]);
        let positions: Vec<i32> = points.iter().map(|p| p.position[0]).collect();
        assert_eq!(positions, vec![40, 80, 100]);
    }

    #[test]
    fn a_late_first_waypoint_starts_from_the_current_position() {
        let w = parse_csv("0.1,50\n0.2,50\n", "t.csv").unwrap();
        let config = ArmConfig::unlimited(1, 10_000);
        let points = to_points(&w, &[10, 0, 0, 0, 0, 0, 0, 0], 50_000, &config, None).unwrap();
        let positions: Vec<i32> = points.iter().map(|p| p.position[0]).collect();
        assert_eq!(positions, vec![30, 50, 50, 50]);
    }

    #[test]
    fn a_first_waypoint_at_zero_must_be_where_the_arm_is() {
        let w = parse_csv("0,5\n1,50\n", "t.csv").unwrap();
        let err =
            to_points(&w, &[0; 8], 10_000, &ArmConfig::unlimited(1, 10_000), None).unwrap_err();
        assert_eq!(
            err.kind,
            ErrorKind::StartMismatch {
                current: 0,
                start: 5
            }
        );
        assert_eq!((err.point, err.joint), (Some(0), Some(0)));
    }

    #[test]
    fn step_rate_over_the_joint_limit_is_refused_with_where_and_what() {
        // Shoulder: 2000 steps/s at most. 300 steps in 100 ms = 3000 steps/s.
        let text = trajectory(&[point(0, 0, 0.0, 0.0), point(0, 100_000_000, 0.3, 0.0)].join(","));
        let w = parse_joint_trajectory(&text, "fast.json", &config()).unwrap();
        let err = to_points(&w, &[100, 0, 0, 0, 0, 0, 0, 0], 50_000, &config(), None).unwrap_err();
        assert_eq!(err.point, Some(0));
        assert_eq!(err.joint, Some(0));
        assert_eq!(
            err.kind,
            ErrorKind::StepRate {
                steps: 150,
                duration_us: 50_000,
                limit_hz: 2000
            }
        );
        let message = err.clone().with_joint_names(&config()).to_string();
        assert!(
            message
                .starts_with("fast.json: resampled segment 0 (t = 0.050000 s), joint 0 (shoulder)"),
            "{message}"
        );
        assert!(
            message.contains("3000 steps/s exceeds the limit of 2000"),
            "{message}"
        );
    }

    #[test]
    fn the_controller_rate_caps_the_joint_rate() {
        let w = parse_csv("0,0\n1,1500\n", "t.csv").unwrap();
        let config = ArmConfig::unlimited(1, 10_000);
        assert!(to_points(&w, &[0; 8], 10_000, &config, Some(2000)).is_ok());
        let err = to_points(&w, &[0; 8], 10_000, &config, Some(1000)).unwrap_err();
        assert!(matches!(
            err.kind,
            ErrorKind::StepRate { limit_hz: 1000, .. }
        ));
    }

    #[test]
    fn exactly_the_limit_is_allowed() {
        let w = parse_csv("0,0\n1,1000\n", "t.csv").unwrap();
        assert!(to_points(&w, &[0; 8], 10_000, &ArmConfig::unlimited(1, 1000), None).is_ok());
        assert!(to_points(&w, &[0; 8], 10_000, &ArmConfig::unlimited(1, 999), None).is_err());
    }

    #[test]
    fn position_limits_are_checked_per_waypoint() {
        // Shoulder max 4000 steps = 100 + 3.9 rad * 1000.
        let text = trajectory(
            &[
                point(0, 0, 0.0, 0.0),
                point(10, 0, 3.9, 0.0),
                point(20, 0, 3.95, 0.0),
            ]
            .join(","),
        );
        let w = parse_joint_trajectory(&text, "far.json", &config()).unwrap();
        let err = to_points(&w, &[100, 0, 0, 0, 0, 0, 0, 0], 10_000, &config(), None).unwrap_err();
        assert_eq!(
            err.kind,
            ErrorKind::AboveMax {
                value: 4050,
                limit: 4000
            }
        );
        assert_eq!(
            (err.point, err.joint, err.time_s),
            (Some(2), Some(0), Some(20.0))
        );
        let low = parse_csv("0,0\n1,-2001\n", "low.csv").unwrap();
        let config = ArmConfig::parse(
            r#"{"joints": [{"min_steps": -2000, "max_step_rate_hz": 100000}]}"#,
            "c.json",
        )
        .unwrap();
        let err = to_points(&low, &[0; 8], 10_000, &config, None).unwrap_err();
        assert_eq!(
            err.kind,
            ErrorKind::BelowMin {
                value: -2001,
                limit: -2000
            }
        );
        assert!(
            err.to_string()
                .contains("low.csv: waypoint 1 of the file (t = 1.000000 s), joint 0")
        );
    }

    #[test]
    fn more_than_65535_points_is_refused_with_the_segment_that_fits() {
        // 700 s at 10 ms = 70000 points.
        let w = parse_csv("0,0\n700,0\n", "long.csv").unwrap();
        let config = ArmConfig::unlimited(1, 1000);
        let err = to_points(&w, &[0; 8], 10_000, &config, None).unwrap_err();
        let ErrorKind::TooManyPoints {
            count,
            min_segment_us,
        } = err.kind
        else {
            panic!("{err}")
        };
        assert_eq!(count, 70_000);
        assert_eq!(min_segment_us, 10_682);
        let points = to_points(&w, &[0; 8], min_segment_us as u32, &config, None).unwrap();
        assert!(points.len() <= MAX_POINTS);
    }

    #[test]
    fn csv_header_comments_and_blank_lines_are_skipped() {
        let text = "# made by hand\ntime_s, j0 ,j1\n\n0, 0, 0\n   \n  # halfway\n0.5,10,-10\n";
        let w = parse_csv(text, "t.csv").unwrap();
        assert_eq!(w.times_us, vec![0, 500_000]);
        assert_eq!(w.positions[1], vec![Some(10.0), Some(-10.0)]);
        let err = parse_csv("time_s,j0\n0,0\n1,x\n", "t.csv").unwrap_err();
        assert!(err.to_string().contains("line 3"), "{err}");
    }

    #[test]
    fn csv_errors() {
        assert!(matches!(
            parse_csv("0,0\n0,1\n", "t.csv").unwrap_err().kind,
            ErrorKind::TimeNotIncreasing
        ));
        let err = parse_csv("0,0,0\n1,1\n", "t.csv").unwrap_err();
        assert_eq!(
            err.kind,
            ErrorKind::WrongJointCount {
                found: 1,
                expected: 2
            }
        );
        assert!(matches!(
            parse_csv("0,0\n1,x\n", "t.csv").unwrap_err().kind,
            ErrorKind::Parse(_)
        ));
        assert!(matches!(
            parse_csv("time_s,j0\n", "t.csv").unwrap_err().kind,
            ErrorKind::TooShort
        ));
        let one = parse_csv("0,0\n", "t.csv").unwrap();
        assert!(matches!(
            to_points(&one, &[0; 8], 1000, &ArmConfig::unlimited(1, 1000), None)
                .unwrap_err()
                .kind,
            ErrorKind::TooShort
        ));
    }

    #[test]
    fn config_errors() {
        assert!(ArmConfig::parse(r#"{"joints": []}"#, "c").is_err());
        assert!(ArmConfig::parse(r#"{"joints": [{"steps_per_radian": 1}]}"#, "c").is_err());
        assert!(
            ArmConfig::parse(
                r#"{"joints": [{"min_steps": 5, "max_steps": 4, "max_step_rate_hz": 1}]}"#,
                "c"
            )
            .is_err()
        );
    }

    /// Waypoints of one joint sampled from `curve` (position, velocity in steps, steps/s)
    /// every `every_us` up to `end_us`.
    fn sampled(curve: impl Fn(f64) -> (f64, f64), every_us: i64, end_us: i64) -> Waypoints {
        let times_us: Vec<i64> = (0..=end_us / every_us).map(|k| k * every_us).collect();
        let (positions, velocities) = times_us
            .iter()
            .map(|&t| {
                let (p, v) = curve(t as f64 / 1e6);
                (vec![Some(p)], vec![Some(v)])
            })
            .unzip();
        Waypoints {
            file: "curve".into(),
            times_us,
            positions,
            velocities,
        }
    }

    #[test]
    fn hermite_reproduces_a_cubic_exactly() {
        // p(t) = 100 + 400 t + 900 t^2 - 450 t^3 steps: a cubic is its own Hermite curve,
        // so every resampled point is the curve rounded to a step, whatever the waypoints.
        let cubic = |t: f64| {
            (
                100.0 + 400.0 * t + 900.0 * t * t - 450.0 * t * t * t,
                400.0 + 1800.0 * t - 1350.0 * t * t,
            )
        };
        let w = sampled(cubic, 500_000, 2_000_000);
        let points = to_points(
            &w,
            &[100, 0, 0, 0, 0, 0, 0, 0],
            10_000,
            &ArmConfig::unlimited(1, 100_000),
            None,
        )
        .unwrap();
        assert_eq!(points.len(), 200);
        for (k, p) in points.iter().enumerate() {
            let t = (k + 1) as f64 * 0.01;
            let exact = cubic(t).0;
            assert!(
                (f64::from(p.position[0]) - exact).abs() <= 0.5 + 1e-6,
                "t = {t}: {} vs {exact}",
                p.position[0]
            );
        }
        assert_eq!(points[199].position[0], cubic(2.0).0.round() as i32);
    }

    #[test]
    fn hermite_follows_a_sine_within_its_error_bound() {
        // 2000 sin(2 pi t) steps, waypoints every 100 ms. The cubic Hermite error is at
        // most max|p''''| h^4 / 384 = 2000 (2 pi)^4 0.1^4 / 384 = 0.81 steps, plus the
        // rounding to a step; straight lines through the same waypoints miss by up to
        // 2000 (1 - cos(pi/10)) = 98 steps.
        let w = 2.0 * std::f64::consts::PI;
        let sine = |t: f64| (2000.0 * (w * t).sin(), 2000.0 * w * (w * t).cos());
        let bound = 2000.0 * w.powi(4) * 0.1f64.powi(4) / 384.0 + 0.5;
        let waypoints = sampled(sine, 100_000, 1_000_000);
        let config = ArmConfig::unlimited(1, 100_000);
        let points = to_points(&waypoints, &[0; 8], 5_000, &config, None).unwrap();
        let worst = points
            .iter()
            .enumerate()
            .map(|(k, p)| (f64::from(p.position[0]) - sine((k + 1) as f64 * 0.005).0).abs())
            .fold(0.0, f64::max);
        assert!(worst <= bound, "worst {worst} > bound {bound}");
        assert_eq!(points.last().unwrap().position[0], 0);
        // The same waypoints without velocities: straight lines, far off between them.
        let mut linear = waypoints.clone();
        linear.velocities.clear();
        let points = to_points(&linear, &[0; 8], 5_000, &config, None).unwrap();
        let worst_linear = points
            .iter()
            .enumerate()
            .map(|(k, p)| (f64::from(p.position[0]) - sine((k + 1) as f64 * 0.005).0).abs())
            .fold(0.0, f64::max);
        assert!(worst_linear > 90.0, "{worst_linear}");
    }

    #[test]
    fn velocities_in_radians_per_second_become_steps_per_second() {
        // MoveIt-style: at rest at both ends, 1 rad in 1 s; the shoulder has 1000
        // steps/rad, the elbow -500. The Hermite curve with zero end velocities is the
        // smoothstep 3f^2 - 2f^3: a quarter of the way is 15.625 % of the move.
        let text = r#"{"joint_names": ["shoulder", "elbow"], "points": [
            {"positions": [0.0, 0.0], "velocities": [0.0, 0.0], "time_from_start": {"sec": 0}},
            {"positions": [1.0, 1.0], "velocities": [0.0, 0.0], "time_from_start": {"sec": 1}}]}"#;
        let w = parse_joint_trajectory(text, "t.json", &config()).unwrap();
        assert_eq!(w.velocities[1], vec![Some(0.0), Some(-0.0)]);
        let points = to_points(&w, &[100, 0, 0, 0, 0, 0, 0, 0], 250_000, &config(), None).unwrap();
        let shoulder: Vec<i32> = points.iter().map(|p| p.position[0]).collect();
        let elbow: Vec<i32> = points.iter().map(|p| p.position[1]).collect();
        assert_eq!(shoulder, vec![256, 600, 944, 1100]);
        assert_eq!(elbow, vec![-78, -250, -422, -500]);
        let text = r#"{"joint_names": ["shoulder", "elbow"], "points": [
            {"positions": [0.0, 0.0], "velocities": [0.0], "time_from_start": {"sec": 0}}]}"#;
        let err = parse_joint_trajectory(text, "t.json", &config()).unwrap_err();
        assert_eq!(
            err.kind,
            ErrorKind::WrongJointCount {
                found: 1,
                expected: 2
            }
        );
    }

    #[test]
    fn a_segment_without_velocities_at_both_ends_is_a_straight_line() {
        // Velocity given at t = 0 and 2 s, not at 1 s: both segments are straight lines.
        let w = Waypoints {
            file: "mixed".into(),
            times_us: vec![0, 1_000_000, 2_000_000],
            positions: vec![vec![Some(0.0)], vec![Some(100.0)], vec![Some(300.0)]],
            velocities: vec![vec![Some(500.0)], vec![None], vec![Some(0.0)]],
        };
        let points = to_points(&w, &[0; 8], 250_000, &ArmConfig::unlimited(1, 1000), None).unwrap();
        let positions: Vec<i32> = points.iter().map(|p| p.position[0]).collect();
        assert_eq!(positions, vec![25, 50, 75, 100, 150, 200, 250, 300]);
    }

    #[test]
    fn a_hermite_overshoot_past_a_limit_is_refused() {
        // From 0 to 100 steps with a large start velocity: the curve passes 100 between
        // the waypoints, which a limit at 100 refuses although both waypoints are inside.
        let w = Waypoints {
            file: "over".into(),
            times_us: vec![0, 1_000_000],
            positions: vec![vec![Some(0.0)], vec![Some(100.0)]],
            velocities: vec![vec![Some(600.0)], vec![Some(0.0)]],
        };
        let config = ArmConfig::parse(
            r#"{"joints": [{"max_steps": 100, "max_step_rate_hz": 100000}]}"#,
            "c.json",
        )
        .unwrap();
        let err = to_points(&w, &[0; 8], 50_000, &config, None).unwrap_err();
        assert!(
            matches!(err.kind, ErrorKind::AboveMax { limit: 100, .. }),
            "{err}"
        );
    }

    #[test]
    fn the_shipped_examples_convert() {
        let config = ArmConfig::parse(include_str!("../examples/arm.json"), "arm.json").unwrap();
        let reach = parse_joint_trajectory(
            include_str!("../examples/reach.json"),
            "reach.json",
            &config,
        )
        .unwrap();
        let points = to_points(&reach, &[0; 8], 10_000, &config, Some(100_000)).unwrap();
        assert_eq!(points.len(), 350);
        assert_eq!(points[349].position, [0; 8]);
        // 0.5 rad of base at 5093 steps/rad, reached at 1.5 s (point 149).
        assert_eq!(points[149].position[0], 2547);
        let wave = parse_csv(include_str!("../examples/wave.csv"), "wave.csv").unwrap();
        let points = to_points(
            &wave,
            &[0; 8],
            10_000,
            &ArmConfig::unlimited(3, 100_000),
            None,
        )
        .unwrap();
        assert_eq!(points.len(), 200);
        assert_eq!(&points[49].position[..3], &[800, -400, 200]);
    }
}
