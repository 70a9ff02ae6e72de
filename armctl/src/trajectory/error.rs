//! Why a trajectory file was refused.

use std::fmt;

use super::{ArmConfig, JointConfig};
use crate::motion::Units;
use crate::run::MAX_POINTS;

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
    /// How the message shows the joint: its config name, and the user's units (boxed: a
    /// small error). Set by [`Self::with_joint_names`] and [`Self::in_units`].
    pub shown: Option<Box<JointShown>>,
    /// What is wrong.
    pub kind: ErrorKind,
}

/// How a [`TrajectoryError`] shows its joint.
#[derive(Clone, Debug, PartialEq)]
pub struct JointShown {
    /// The joint's name in the joint config, when it has one.
    pub name: Option<String>,
    /// The units the user gave positions in, other than steps, with the joint's
    /// calibration: positions and rates are shown in them too (issue 31).
    pub units: Option<(Units, JointConfig)>,
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
    /// More waypoints than one upload takes points (each span between two waypoints is
    /// at least one point).
    TooManyWaypoints {
        /// Spans between waypoints (the arm's position at t = 0 counts as one when the
        /// file starts later).
        count: usize,
    },
    /// A plan that does not pass a waypoint at its time ([`check_waypoints`]).
    ///
    /// [`check_waypoints`]: super::check_waypoints
    WaypointMissed {
        /// The planned position and the waypoint's, steps, for the joint named; `None`: no
        /// segment ends at the waypoint's time.
        planned: Option<(i64, i64)>,
    },
    /// A segment duration of 0.
    BadSegment,
}

impl TrajectoryError {
    pub(super) fn new(file: &str, kind: ErrorKind) -> TrajectoryError {
        TrajectoryError {
            file: file.to_string(),
            point: None,
            time_s: None,
            joint: None,
            shown: None,
            kind,
        }
    }

    pub(super) fn at(
        mut self,
        point: usize,
        time_us: i64,
        joint: Option<usize>,
    ) -> TrajectoryError {
        self.point = Some(point);
        self.time_s = Some(time_us as f64 / 1e6);
        self.joint = joint;
        self
    }

    /// Names the joint after `config` (its `name`), for the message.
    pub fn with_joint_names(self, config: &ArmConfig) -> TrajectoryError {
        self.in_units(config, Units::Steps)
    }

    /// Names the joint after `config` and shows values in `units` as well as in steps
    /// (issue 31: refusals speak the user's units).
    pub fn in_units(mut self, config: &ArmConfig, units: Units) -> TrajectoryError {
        if let Some(joint) = self.joint.and_then(|j| config.joints.get(j)) {
            self.shown = Some(Box::new(JointShown {
                name: joint.name.clone(),
                units: (units != Units::Steps).then(|| (units, joint.clone())),
            }));
        }
        self
    }

    /// The user's units and the joint's calibration, when they are not steps.
    fn units(&self) -> Option<&(Units, JointConfig)> {
        self.shown.as_deref().and_then(|s| s.units.as_ref())
    }

    /// ` (30.02 deg)`: `steps`, a position, in the user's units; empty in steps.
    fn position_in_units(&self, steps: i64) -> String {
        match self.units() {
            Some((units, joint)) => format!(" ({})", units.show(steps, joint)),
            None => String::new(),
        }
    }

    /// ` (114.59 deg/s)`: `steps_per_s` in the user's units; empty in steps.
    fn rate_in_units(&self, steps_per_s: f64) -> String {
        match self.units() {
            Some((units, joint)) => format!(
                " ({:.2} {}/s)",
                units.distance_from_steps(steps_per_s, joint).abs(),
                units.name()
            ),
            None => String::new(),
        }
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
            if let Some(name) = self.shown.as_deref().and_then(|s| s.name.as_ref()) {
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
            ErrorKind::BelowMin { value, limit } => write!(
                f,
                "position {value} steps{} is below the minimum {limit} steps{}",
                self.position_in_units(*value),
                self.position_in_units(i64::from(*limit))
            ),
            ErrorKind::AboveMax { value, limit } => write!(
                f,
                "position {value} steps{} is above the maximum {limit} steps{}",
                self.position_in_units(*value),
                self.position_in_units(i64::from(*limit))
            ),
            ErrorKind::StepRate {
                steps,
                duration_us,
                limit_hz,
            } => {
                let rate = *steps as f64 * 1e6 / f64::from(*duration_us);
                write!(
                    f,
                    "{steps} steps in {duration_us} us = {rate:.0} steps/s{} exceeds the limit \
                     of {limit_hz} steps/s{}: slow the trajectory down, it needs {} longer \
                     here",
                    self.rate_in_units(rate),
                    self.rate_in_units(f64::from(*limit_hz)),
                    slow_down(rate, f64::from(*limit_hz))
                )
            }
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
            ErrorKind::TooManyWaypoints { count } => write!(
                f,
                "{count} spans between waypoints, one upload takes at most {MAX_POINTS} \
                 points and every waypoint ends one: split the file into several runs"
            ),
            ErrorKind::WaypointMissed { planned: None } => f.write_str(
                "no segment ends at this waypoint's time: the plan would pass it unchecked",
            ),
            ErrorKind::WaypointMissed {
                planned: Some((planned, wanted)),
            } => write!(
                f,
                "the plan is at {planned} steps at this waypoint's time, the file says {wanted}"
            ),
            ErrorKind::BadSegment => f.write_str("the segment duration must be at least 1 us"),
        }
    }
}

impl std::error::Error for TrajectoryError {}

/// `2.3x`: how many times longer a motion at `rate` must take to keep within `limit`,
/// rounded up to a tenth (so that it fits).
pub fn slow_down(rate: f64, limit: f64) -> String {
    if limit <= 0.0 {
        return "a limit above 0 (it has none), and so infinitely".into();
    }
    format!("{:.1}x", (rate / limit * 10.0).ceil() / 10.0)
}
