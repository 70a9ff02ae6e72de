//! The ROS 2 message types the bridge speaks, as plain serde structs in the field order of
//! their `.msg`/`.action`/`.srv` definitions (Jazzy): CDR serialises fields in declaration
//! order, so that order is the wire format. Constants of the definitions are associated
//! constants here.

use ros2_client::Message;
use serde::{Deserialize, Serialize};

/// `builtin_interfaces/Time`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Time {
    /// Seconds since the Unix epoch.
    pub sec: i32,
    /// Nanoseconds, 0..1e9.
    pub nanosec: u32,
}

impl Time {
    /// A wall-clock instant.
    pub fn from_system(t: std::time::SystemTime) -> Time {
        let since = t.duration_since(std::time::UNIX_EPOCH).unwrap_or_default();
        Time {
            sec: i32::try_from(since.as_secs()).unwrap_or(i32::MAX),
            nanosec: since.subsec_nanos(),
        }
    }

    /// Seconds since the Unix epoch.
    pub fn as_secs_f64(&self) -> f64 {
        f64::from(self.sec) + f64::from(self.nanosec) * 1e-9
    }
}

/// `builtin_interfaces/Duration`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Duration {
    /// Whole seconds.
    pub sec: i32,
    /// Nanoseconds, 0..1e9.
    pub nanosec: u32,
}

impl Duration {
    /// From a std duration (saturating at i32::MAX seconds).
    pub fn from_std(d: std::time::Duration) -> Duration {
        Duration {
            sec: i32::try_from(d.as_secs()).unwrap_or(i32::MAX),
            nanosec: d.subsec_nanos(),
        }
    }

    /// Microseconds (negative durations count as written: sec + nanosec).
    pub fn as_micros(&self) -> i64 {
        i64::from(self.sec) * 1_000_000 + i64::from(self.nanosec / 1000)
    }
}

/// `std_msgs/Header`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Header {
    /// When the data was taken.
    pub stamp: Time,
    /// Coordinate frame (unused for joint data: empty).
    pub frame_id: String,
}

/// `sensor_msgs/JointState`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct JointState {
    /// Stamp: when the controller's LOCATION report arrived.
    pub header: Header,
    /// Joint names.
    pub name: Vec<String>,
    /// Radians.
    pub position: Vec<f64>,
    /// Radians per second (empty: not measured).
    pub velocity: Vec<f64>,
    /// Empty: not measured.
    pub effort: Vec<f64>,
}
impl Message for JointState {}

/// `trajectory_msgs/JointTrajectoryPoint`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct JointTrajectoryPoint {
    /// Radians.
    pub positions: Vec<f64>,
    /// Radians per second, or empty.
    pub velocities: Vec<f64>,
    /// Radians per second squared, or empty (not used by the bridge).
    pub accelerations: Vec<f64>,
    /// Not used by the bridge.
    pub effort: Vec<f64>,
    /// When to be there.
    pub time_from_start: Duration,
}

/// `trajectory_msgs/JointTrajectory`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct JointTrajectory {
    /// `stamp` 0: start now (the bridge always starts on receipt).
    pub header: Header,
    /// Joint names, in the order of each point's values.
    pub joint_names: Vec<String>,
    /// The waypoints.
    pub points: Vec<JointTrajectoryPoint>,
}

/// `geometry_msgs/Vector3`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Vector3 {
    /// x.
    pub x: f64,
    /// y.
    pub y: f64,
    /// z.
    pub z: f64,
}

/// `geometry_msgs/Quaternion`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Quaternion {
    /// x.
    pub x: f64,
    /// y.
    pub y: f64,
    /// z.
    pub z: f64,
    /// w.
    pub w: f64,
}

/// `geometry_msgs/Transform`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Transform {
    /// Translation.
    pub translation: Vector3,
    /// Rotation.
    pub rotation: Quaternion,
}

/// `geometry_msgs/Twist`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Twist {
    /// Linear.
    pub linear: Vector3,
    /// Angular.
    pub angular: Vector3,
}

/// `trajectory_msgs/MultiDOFJointTrajectoryPoint` (carried, never used: the arm has only
/// single-DOF joints).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct MultiDofJointTrajectoryPoint {
    /// Transforms.
    pub transforms: Vec<Transform>,
    /// Velocities.
    pub velocities: Vec<Twist>,
    /// Accelerations.
    pub accelerations: Vec<Twist>,
    /// When.
    pub time_from_start: Duration,
}

/// `trajectory_msgs/MultiDOFJointTrajectory`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct MultiDofJointTrajectory {
    /// Header.
    pub header: Header,
    /// Joint names.
    pub joint_names: Vec<String>,
    /// Points.
    pub points: Vec<MultiDofJointTrajectoryPoint>,
}

/// `control_msgs/JointTolerance`: 0 = the bridge's default, -1 = none.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct JointTolerance {
    /// Joint name.
    pub name: String,
    /// Radians.
    pub position: f64,
    /// Radians per second.
    pub velocity: f64,
    /// Radians per second squared.
    pub acceleration: f64,
}

/// `control_msgs/JointComponentTolerance`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct JointComponentTolerance {
    /// Joint name.
    pub joint_name: String,
    /// X_AXIS = 1 .. ROTATION = 5.
    pub component: u16,
    /// Position.
    pub position: f64,
    /// Velocity.
    pub velocity: f64,
    /// Acceleration.
    pub acceleration: f64,
}

/// `control_msgs/action/FollowJointTrajectory` goal.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct FollowJointTrajectoryGoal {
    /// The trajectory.
    pub trajectory: JointTrajectory,
    /// Must be empty: the arm has no multi-DOF joints.
    pub multi_dof_trajectory: MultiDofJointTrajectory,
    /// Largest |desired - actual| while moving, per joint.
    pub path_tolerance: Vec<JointTolerance>,
    /// Not used (no multi-DOF joints).
    pub component_path_tolerance: Vec<JointComponentTolerance>,
    /// Largest |goal - final| per joint.
    pub goal_tolerance: Vec<JointTolerance>,
    /// Not used (no multi-DOF joints).
    pub component_goal_tolerance: Vec<JointComponentTolerance>,
    /// Extra time allowed after the trajectory's end.
    pub goal_time_tolerance: Duration,
}
impl Message for FollowJointTrajectoryGoal {}

/// `control_msgs/action/FollowJointTrajectory` result.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct FollowJointTrajectoryResult {
    /// One of the constants below.
    pub error_code: i32,
    /// What happened, in words.
    pub error_string: String,
}
impl Message for FollowJointTrajectoryResult {}

impl FollowJointTrajectoryResult {
    /// The goal was reached.
    pub const SUCCESSFUL: i32 = 0;
    /// The goal cannot be run (start state, limits, step rates, malformed).
    pub const INVALID_GOAL: i32 = -1;
    /// A joint name is unknown or repeated.
    pub const INVALID_JOINTS: i32 = -2;
    /// The header stamp is too old.
    pub const OLD_HEADER_TIMESTAMP: i32 = -3;
    /// The run left the path (stopped, underrun, lost link).
    pub const PATH_TOLERANCE_VIOLATED: i32 = -4;
    /// The arm did not end at the goal.
    pub const GOAL_TOLERANCE_VIOLATED: i32 = -5;
}

/// `control_msgs/action/FollowJointTrajectory` feedback, in the layout of either
/// control_msgs 5.x (Humble, Jazzy: `index` and `multi_dof_index` `None`) or 6.3+ (Kilted,
/// Rolling: both `Some`, serialised after `error` and after `multi_dof_error`). Both have
/// the same DDS type name, so the layout must be the reader's: a 6.x reader drops every
/// 5.x sample and the other way round.
///
/// Deserialises the 5.x layout only (the indices stay `None`).
#[derive(Clone, Debug, Default, PartialEq, Deserialize)]
pub struct FollowJointTrajectoryFeedback {
    /// Stamp: when this feedback was made.
    pub header: Header,
    /// Joint names of the goal.
    pub joint_names: Vec<String>,
    /// Where the trajectory wants the joints now.
    pub desired: JointTrajectoryPoint,
    /// Where the last LOCATION report put them.
    pub actual: JointTrajectoryPoint,
    /// desired - actual.
    pub error: JointTrajectoryPoint,
    /// control_msgs 6.x: the goal point being executed.
    #[serde(skip)]
    pub index: Option<i32>,
    /// Empty.
    pub multi_dof_joint_names: Vec<String>,
    /// Empty.
    pub multi_dof_desired: MultiDofJointTrajectoryPoint,
    /// Empty.
    pub multi_dof_actual: MultiDofJointTrajectoryPoint,
    /// Empty.
    pub multi_dof_error: MultiDofJointTrajectoryPoint,
    /// control_msgs 6.x: the multi-DOF point being executed (0: there are none).
    #[serde(skip)]
    pub multi_dof_index: Option<i32>,
}

impl Serialize for FollowJointTrajectoryFeedback {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeStruct;
        let fields =
            9 + usize::from(self.index.is_some()) + usize::from(self.multi_dof_index.is_some());
        let mut s = serializer.serialize_struct("FollowJointTrajectory_Feedback", fields)?;
        s.serialize_field("header", &self.header)?;
        s.serialize_field("joint_names", &self.joint_names)?;
        s.serialize_field("desired", &self.desired)?;
        s.serialize_field("actual", &self.actual)?;
        s.serialize_field("error", &self.error)?;
        if let Some(index) = self.index {
            s.serialize_field("index", &index)?;
        }
        s.serialize_field("multi_dof_joint_names", &self.multi_dof_joint_names)?;
        s.serialize_field("multi_dof_desired", &self.multi_dof_desired)?;
        s.serialize_field("multi_dof_actual", &self.multi_dof_actual)?;
        s.serialize_field("multi_dof_error", &self.multi_dof_error)?;
        if let Some(index) = self.multi_dof_index {
            s.serialize_field("multi_dof_index", &index)?;
        }
        s.end()
    }
}
impl Message for FollowJointTrajectoryFeedback {}

/// `control_msgs/GripperCommand`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct GripperCommand {
    /// Gap, metres.
    pub position: f64,
    /// Newtons (a hobby servo has no effort control: ignored).
    pub max_effort: f64,
}

/// `control_msgs/action/GripperCommand` goal.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct GripperCommandGoal {
    /// The command.
    pub command: GripperCommand,
}
impl Message for GripperCommandGoal {}

/// `control_msgs/action/GripperCommand` result and feedback.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct GripperCommandResult {
    /// Gap, metres (the commanded one: the servo reports nothing back).
    pub position: f64,
    /// Newtons (0: not measured).
    pub effort: f64,
    /// Never measured: false.
    pub stalled: bool,
    /// The PWM for the position was applied and the settle time passed.
    pub reached_goal: bool,
}
impl Message for GripperCommandResult {}

/// `std_srvs/Trigger` request (an empty message carries one placeholder byte in ROS 2).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TriggerRequest {
    /// Always 0.
    pub structure_needs_at_least_one_member: u8,
}
impl Message for TriggerRequest {}

/// `std_srvs/Trigger` response.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TriggerResponse {
    /// Whether it worked.
    pub success: bool,
    /// What happened.
    pub message: String,
}
impl Message for TriggerResponse {}

#[cfg(test)]
mod tests {
    use super::*;
    use byteorder::LittleEndian;

    /// control_msgs 6.3+'s feedback, field for field (as a Kilted reader decodes it).
    #[derive(Debug, Deserialize)]
    struct Feedback6 {
        header: Header,
        joint_names: Vec<String>,
        desired: JointTrajectoryPoint,
        actual: JointTrajectoryPoint,
        error: JointTrajectoryPoint,
        index: i32,
        multi_dof_joint_names: Vec<String>,
        multi_dof_desired: MultiDofJointTrajectoryPoint,
        multi_dof_actual: MultiDofJointTrajectoryPoint,
        multi_dof_error: MultiDofJointTrajectoryPoint,
        multi_dof_index: i32,
    }

    fn sample() -> FollowJointTrajectoryFeedback {
        let point = |x: f64| JointTrajectoryPoint {
            positions: vec![x, -x],
            time_from_start: Duration { sec: 1, nanosec: 5 },
            ..JointTrajectoryPoint::default()
        };
        FollowJointTrajectoryFeedback {
            header: Header {
                stamp: Time { sec: 7, nanosec: 9 },
                frame_id: String::new(),
            },
            joint_names: vec!["base".into(), "elbow".into()],
            desired: point(0.5),
            actual: point(0.25),
            error: point(0.25),
            ..FollowJointTrajectoryFeedback::default()
        }
    }

    #[test]
    fn feedback_has_the_layout_of_its_control_msgs_version() {
        let jazzy = sample();
        let bytes5 = cdr_encoding::to_vec::<_, LittleEndian>(&jazzy).unwrap();
        let (back, used) =
            cdr_encoding::from_bytes::<FollowJointTrajectoryFeedback, LittleEndian>(&bytes5)
                .unwrap();
        assert_eq!((back, used), (jazzy.clone(), bytes5.len()));

        let kilted = FollowJointTrajectoryFeedback {
            index: Some(3),
            multi_dof_index: Some(0),
            ..jazzy
        };
        let bytes6 = cdr_encoding::to_vec::<_, LittleEndian>(&kilted).unwrap();
        let (six, used) = cdr_encoding::from_bytes::<Feedback6, LittleEndian>(&bytes6).unwrap();
        assert_eq!(used, bytes6.len());
        assert_eq!((six.index, six.multi_dof_index), (3, 0));
        assert_eq!(six.header, kilted.header);
        assert_eq!(six.joint_names, kilted.joint_names);
        assert_eq!(
            (six.desired, six.actual, six.error),
            (kilted.desired, kilted.actual, kilted.error)
        );
        assert!(six.multi_dof_joint_names.is_empty());
        assert_eq!(
            six.multi_dof_desired,
            MultiDofJointTrajectoryPoint::default()
        );
        assert_eq!(
            six.multi_dof_actual,
            MultiDofJointTrajectoryPoint::default()
        );
        assert_eq!(six.multi_dof_error, MultiDofJointTrajectoryPoint::default());
        // The 5.x layout is what a 6.x reader cannot take: 8 bytes short.
        assert_eq!(bytes6.len(), bytes5.len() + 8);
        assert!(cdr_encoding::from_bytes::<Feedback6, LittleEndian>(&bytes5).is_err());
    }
}

/// `std_msgs/Float64`: the speed scaling input (a fraction) and state (percent; issue 32).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Float64 {
    /// The value.
    pub data: f64,
}
impl Message for Float64 {}
