//! What the bridge decides, without any I/O: whether a FollowJointTrajectory goal can run
//! and the controller points it becomes, where the trajectory wants the joints at a time,
//! whether a run ended at the goal, and JointState/feedback messages from LOCATION reports.

use armctl::motion::Units;
use armctl::protocol::{MAX_JOINTS, Point};
use armctl::trajectory::{self, ArmConfig, ErrorKind, RosDuration};

use crate::config::{BridgeConfig, RosDistro};
use crate::msgs::{
    FollowJointTrajectoryFeedback, FollowJointTrajectoryGoal, FollowJointTrajectoryResult as R,
    Header, JointState, JointTrajectoryPoint, Time,
};

/// Why a goal is refused: a control_msgs result code and the reason in words.
#[derive(Clone, Debug, PartialEq)]
pub struct Refusal {
    /// `FollowJointTrajectoryResult::INVALID_GOAL` or `INVALID_JOINTS`.
    pub code: i32,
    /// What is wrong.
    pub message: String,
}

impl Refusal {
    fn goal(message: String) -> Refusal {
        Refusal {
            code: R::INVALID_GOAL,
            message,
        }
    }
    fn joints(message: String) -> Refusal {
        Refusal {
            code: R::INVALID_JOINTS,
            message,
        }
    }
}

/// A goal ready to stream.
#[derive(Clone, Debug, PartialEq)]
pub struct Plan {
    /// Controller points, from `start`.
    pub points: Vec<Point>,
    /// Where the arm was when the goal was planned, steps.
    pub start: [i32; MAX_JOINTS],
    /// The goal's joint names and the config joint of each.
    pub joint_names: Vec<String>,
    /// Config joint index of each goal joint.
    pub columns: Vec<usize>,
    /// Largest |end - last point| accepted per config joint, steps (`u32::MAX`: any).
    pub goal_tolerance_steps: [u32; MAX_JOINTS],
    /// Largest |desired - actual| while moving per config joint, radians (`None`: none).
    pub path_tolerance_rad: [Option<f64>; MAX_JOINTS],
    /// `time_from_start` of each of the goal's points, microseconds (for the feedback's
    /// `index`).
    pub waypoint_times_us: Vec<i64>,
}

impl Plan {
    /// The last point: where the arm must end.
    pub fn end(&self) -> [i32; MAX_JOINTS] {
        self.points.last().map_or(self.start, |p| p.position)
    }

    /// The goal point the arm is heading to `elapsed_us` into the run: the first whose
    /// `time_from_start` is not yet past (the last one once the run is over); control_msgs
    /// 6.x feedback's `index`.
    pub fn waypoint_index(&self, elapsed_us: i64) -> i32 {
        let i = self
            .waypoint_times_us
            .iter()
            .position(|&t| t >= elapsed_us)
            .unwrap_or(self.waypoint_times_us.len().saturating_sub(1));
        i32::try_from(i).unwrap_or(i32::MAX)
    }

    /// Total duration, microseconds.
    pub fn duration_us(&self) -> i64 {
        self.points.iter().map(|p| i64::from(p.duration)).sum()
    }

    /// Where the points put each joint `elapsed_us` into the run (straight between points,
    /// which are a few milliseconds apart), steps.
    pub fn desired_steps(&self, elapsed_us: i64) -> [f64; MAX_JOINTS] {
        let mut from = self.start;
        let mut t0 = 0i64;
        for p in &self.points {
            let t1 = t0 + i64::from(p.duration);
            if elapsed_us < t1 {
                let f = (elapsed_us - t0).max(0) as f64 / f64::from(p.duration.max(1));
                let mut out = [0.0; MAX_JOINTS];
                for j in 0..MAX_JOINTS {
                    out[j] = f64::from(from[j]) + f64::from(p.position[j] - from[j]) * f;
                }
                return out;
            }
            from = p.position;
            t0 = t1;
        }
        from.map(f64::from)
    }
}

/// Radians of config joint `j` at `steps`.
pub fn radians(arm: &ArmConfig, j: usize, steps: f64) -> f64 {
    let joint = &arm.joints[j];
    (steps - f64::from(joint.zero_offset_steps)) / joint.steps_per_radian
}

/// The units a refusal shows values in besides steps, with the joint's name (issue 31:
/// ROS goal errors said "joint 1" and steps only): the arm's (`units` of the file or the
/// controller's description), else radians, the goal's own.
fn refusal_units(arm: &ArmConfig) -> Units {
    match arm.units {
        Units::Steps => Units::Rad,
        units => units,
    }
}

/// Checks `goal` against the config and the arm's position `current` (steps) and turns it
/// into controller points: joint names known and not repeated (INVALID_JOINTS), a first
/// point at time 0 within `start_tolerance_rad` of where the arm is, positions within the
/// limits and segments within the step rates of the joints and of the controller
/// (`controller_max_rate_hz`) (INVALID_GOAL).
pub fn plan(
    goal: &FollowJointTrajectoryGoal,
    config: &BridgeConfig,
    arm: &ArmConfig,
    current: &[i32; MAX_JOINTS],
    controller_max_rate_hz: Option<u32>,
) -> Result<Plan, Refusal> {
    let names = config.joint_names();
    let trajectory = &goal.trajectory;
    if trajectory.joint_names.is_empty() {
        return Err(Refusal::joints(format!(
            "the goal names no joints; this controller has {names:?}"
        )));
    }
    let unknown: Vec<&String> = trajectory
        .joint_names
        .iter()
        .filter(|n| !names.contains(n))
        .collect();
    if !unknown.is_empty() {
        return Err(Refusal::joints(format!(
            "unknown joint names {unknown:?}: this controller has {names:?}"
        )));
    }
    for (i, name) in trajectory.joint_names.iter().enumerate() {
        if trajectory.joint_names[..i].contains(name) {
            return Err(Refusal::joints(format!("joint {name:?} is named twice")));
        }
    }
    if !goal.multi_dof_trajectory.joint_names.is_empty() {
        return Err(Refusal::joints(format!(
            "multi-DOF joints {:?}: this controller has single-DOF joints only",
            goal.multi_dof_trajectory.joint_names
        )));
    }
    if trajectory.points.is_empty() {
        return Err(Refusal::goal("the trajectory has no points".into()));
    }
    let columns: Vec<usize> = trajectory
        .joint_names
        .iter()
        .filter_map(|n| names.iter().position(|c| c == n))
        .collect();
    let converted = trajectory::JointTrajectory {
        joint_names: trajectory.joint_names.clone(),
        points: trajectory
            .points
            .iter()
            .map(|p| trajectory::JointTrajectoryPoint {
                positions: p.positions.clone(),
                velocities: p.velocities.clone(),
                time_from_start: RosDuration {
                    sec: i64::from(p.time_from_start.sec),
                    nanosec: p.time_from_start.nanosec,
                },
            })
            .collect(),
    };
    let source = "goal";
    let units = refusal_units(arm);
    let mut waypoints = trajectory::joint_trajectory_to_waypoints(&converted, source, arm)
        .map_err(|e| match e.kind {
            ErrorKind::UnknownJoint(_) => Refusal::joints(e.in_units(arm, units).to_string()),
            _ => Refusal::goal(e.in_units(arm, units).to_string()),
        })?;
    // MoveIt's first point is the start state at time 0: within the tolerance of where
    // the arm is, it is taken as exactly there (whole steps).
    if waypoints.times_us[0] == 0 {
        for &j in &columns {
            let Some(start) = waypoints.positions[0][j] else {
                continue;
            };
            let at = radians(arm, j, f64::from(current[j]));
            let wanted = radians(arm, j, start);
            if (wanted - at).abs() > config.start_tolerance_rad {
                return Err(Refusal::goal(format!(
                    "the trajectory starts joint {:?} at {wanted:.4} rad but it is at {at:.4} rad \
                     ({:.4} rad apart, more than the start tolerance of {} rad): plan from the \
                     current state",
                    names[j],
                    (wanted - at).abs(),
                    config.start_tolerance_rad
                )));
            }
            waypoints.positions[0][j] = Some(f64::from(current[j]));
        }
    }
    let waypoint_times_us: Vec<i64> = trajectory
        .points
        .iter()
        .map(|p| p.time_from_start.as_micros())
        .collect();
    let goal_tolerance_steps = goal_tolerances(goal, config, arm, &names);
    let path_tolerance_rad = path_tolerances(goal, &names);
    // A lone point at time 0 (MoveIt sends one when the arm is already at the goal): the
    // start check above passed, so there is nothing to move.
    if waypoints.times_us == [0] {
        return Ok(Plan {
            points: Vec::new(),
            start: *current,
            joint_names: trajectory.joint_names.clone(),
            columns,
            goal_tolerance_steps,
            path_tolerance_rad,
            waypoint_times_us,
        });
    }
    let points = trajectory::to_points(
        &waypoints,
        current,
        config.segment_us,
        arm,
        controller_max_rate_hz,
    )
    .map_err(|e| Refusal::goal(e.in_units(arm, units).to_string()))?;

    Ok(Plan {
        points,
        start: *current,
        joint_names: trajectory.joint_names.clone(),
        columns,
        goal_tolerance_steps,
        path_tolerance_rad,
        waypoint_times_us,
    })
}

/// Goal tolerance per config joint in steps: the goal's (radians; -1: any), else the
/// config's.
fn goal_tolerances(
    goal: &FollowJointTrajectoryGoal,
    config: &BridgeConfig,
    arm: &ArmConfig,
    names: &[String],
) -> [u32; MAX_JOINTS] {
    let mut steps = [config.goal_tolerance_steps; MAX_JOINTS];
    for tolerance in &goal.goal_tolerance {
        if let Some(j) = names.iter().position(|n| *n == tolerance.name) {
            if tolerance.position < 0.0 {
                steps[j] = u32::MAX;
            } else if tolerance.position > 0.0 {
                let value = tolerance.position * arm.joints[j].steps_per_radian.abs();
                steps[j] = value.floor().min(f64::from(u32::MAX - 1)) as u32;
            }
        }
    }
    steps
}

/// Path tolerance per config joint in radians, where the goal gives one.
fn path_tolerances(
    goal: &FollowJointTrajectoryGoal,
    names: &[String],
) -> [Option<f64>; MAX_JOINTS] {
    let mut radians = [None; MAX_JOINTS];
    for tolerance in &goal.path_tolerance {
        if let Some(j) = names.iter().position(|n| *n == tolerance.name)
            && tolerance.position > 0.0
        {
            radians[j] = Some(tolerance.position);
        }
    }
    radians
}

/// Whether the arm ended where `plan` goes: `Ok` with a summary, or the
/// GOAL_TOLERANCE_VIOLATED message naming each joint off, by how much.
pub fn check_end(
    plan: &Plan,
    arm: &ArmConfig,
    config: &BridgeConfig,
    end: &[i32; MAX_JOINTS],
) -> Result<String, String> {
    let names = config.joint_names();
    let goal = plan.end();
    let mut off = Vec::new();
    for j in 0..arm.joints.len() {
        let error = (i64::from(end[j]) - i64::from(goal[j])).unsigned_abs();
        if error > u64::from(plan.goal_tolerance_steps[j]) {
            off.push(format!(
                "joint {:?} ended at {} steps ({:.5} rad), the goal is {} steps ({:.5} rad): \
                 {error} steps off, tolerance {} steps",
                names[j],
                end[j],
                radians(arm, j, f64::from(end[j])),
                goal[j],
                radians(arm, j, f64::from(goal[j])),
                plan.goal_tolerance_steps[j]
            ));
        }
    }
    if off.is_empty() {
        Ok(format!(
            "reached the goal: {} points executed, every joint at its goal step",
            plan.points.len()
        ))
    } else {
        Err(off.join("; "))
    }
}

/// The first joint (of the goal's) off its path by more than its path tolerance, as a
/// PATH_TOLERANCE_VIOLATED message.
pub fn path_violation(
    plan: &Plan,
    arm: &ArmConfig,
    desired: &[f64; MAX_JOINTS],
    actual: &[i32; MAX_JOINTS],
) -> Option<String> {
    plan.columns.iter().find_map(|&j| {
        let tolerance = plan.path_tolerance_rad[j]?;
        let error = radians(arm, j, desired[j]) - radians(arm, j, f64::from(actual[j]));
        (error.abs() > tolerance).then(|| {
            format!(
                "joint {:?} was {:.4} rad off its path (path tolerance {tolerance} rad)",
                plan.joint_names[plan.columns.iter().position(|&c| c == j).unwrap_or(0)],
                error.abs()
            )
        })
    })
}

/// A JointState of every configured joint from a LOCATION, stamped `stamp`.
pub fn joint_state(
    names: &[String],
    arm: &ArmConfig,
    position: &[i32; MAX_JOINTS],
    stamp: Time,
) -> JointState {
    JointState {
        header: Header {
            stamp,
            frame_id: String::new(),
        },
        name: names.to_vec(),
        position: (0..arm.joints.len())
            .map(|j| radians(arm, j, f64::from(position[j])))
            .collect(),
        velocity: Vec::new(),
        effort: Vec::new(),
    }
}

/// Feedback for the goal's joints: desired (steps, from [`Plan::desired_steps`]), actual
/// (the last LOCATION) and their difference, in radians; `elapsed_us` into the run.
pub fn feedback(
    plan: &Plan,
    arm: &ArmConfig,
    desired: &[f64; MAX_JOINTS],
    actual: &[i32; MAX_JOINTS],
    elapsed_us: i64,
    stamp: Time,
    distro: RosDistro,
) -> FollowJointTrajectoryFeedback {
    let time_from_start =
        crate::msgs::Duration::from_std(std::time::Duration::from_micros(elapsed_us.max(0) as u64));
    let point = |values: Vec<f64>| JointTrajectoryPoint {
        positions: values,
        time_from_start,
        ..JointTrajectoryPoint::default()
    };
    let desired_rad: Vec<f64> = plan
        .columns
        .iter()
        .map(|&j| radians(arm, j, desired[j]))
        .collect();
    let actual_rad: Vec<f64> = plan
        .columns
        .iter()
        .map(|&j| radians(arm, j, f64::from(actual[j])))
        .collect();
    let error: Vec<f64> = desired_rad
        .iter()
        .zip(&actual_rad)
        .map(|(d, a)| d - a)
        .collect();
    FollowJointTrajectoryFeedback {
        header: Header {
            stamp,
            frame_id: String::new(),
        },
        joint_names: plan.joint_names.clone(),
        desired: point(desired_rad),
        actual: point(actual_rad),
        error: point(error),
        // control_msgs 6.x only: the goal point being executed; no multi-DOF points (0).
        index: distro
            .control_msgs_6()
            .then(|| plan.waypoint_index(elapsed_us)),
        multi_dof_index: distro.control_msgs_6().then_some(0),
        ..FollowJointTrajectoryFeedback::default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::msgs::{Duration, JointTolerance, JointTrajectory};

    fn setup() -> (BridgeConfig, ArmConfig) {
        BridgeConfig::parse(include_str!("../examples/bridge.json"), "bridge.json").unwrap()
    }

    fn point(t_ms: i64, positions: &[f64], velocities: &[f64]) -> JointTrajectoryPoint {
        JointTrajectoryPoint {
            positions: positions.to_vec(),
            velocities: velocities.to_vec(),
            time_from_start: Duration::from_std(std::time::Duration::from_millis(t_ms as u64)),
            ..JointTrajectoryPoint::default()
        }
    }

    /// `plan`'s refusal of `g` from the arm at zero, without a controller step limit.
    fn refuse(g: &FollowJointTrajectoryGoal) -> Refusal {
        let (config, arm) = setup();
        plan(g, &config, &arm, &[0; 8], None).unwrap_err()
    }

    /// Asserts that `message` says `text`.
    fn assert_says(message: &str, text: &str) {
        assert!(message.contains(text), "{message}");
    }

    fn goal(names: &[&str], points: Vec<JointTrajectoryPoint>) -> FollowJointTrajectoryGoal {
        FollowJointTrajectoryGoal {
            trajectory: JointTrajectory {
                joint_names: names.iter().map(|n| n.to_string()).collect(),
                points,
                ..JointTrajectory::default()
            },
            ..FollowJointTrajectoryGoal::default()
        }
    }

    #[test]
    fn a_moveit_goal_becomes_points_ending_at_its_last_point() {
        let (config, arm) = setup();
        // Start 0.005 rad (25 steps) from where the arm is: within 0.01 rad.
        let current = [25, 0, 0, 0, 0, 0, 0, 0];
        let g = goal(
            &["base", "elbow"],
            vec![
                point(0, &[0.0, 0.0], &[0.0, 0.0]),
                point(500, &[0.1, -0.2], &[0.3, -0.5]),
                point(1000, &[0.2, -0.3], &[0.0, 0.0]),
            ],
        );
        let plan = plan(&g, &config, &arm, &current, Some(100_000)).unwrap();
        assert_eq!(plan.points.len(), 100);
        assert_eq!(plan.columns, vec![0, 2]);
        // 0.2 rad * 5093 steps/rad = 1018.6 -> 1019; -0.3 * 5093 = -1527.9 -> -1528.
        assert_eq!(plan.end()[..3], [1019, 0, -1528]);
        assert_eq!(plan.desired_steps(0)[0], 25.0);
        assert_eq!(plan.desired_steps(2_000_000)[2], -1528.0);
        assert_eq!(plan.duration_us(), 1_000_000);
    }

    #[test]
    fn wrong_joint_names_are_invalid_joints() {
        let g = goal(&["base", "knee"], vec![point(1000, &[0.0, 0.0], &[])]);
        let refusal = refuse(&g);
        assert_eq!(refusal.code, R::INVALID_JOINTS);
        assert_says(&refusal.message, "\"knee\"");
        let twice = goal(&["base", "base"], vec![point(1000, &[0.0, 0.0], &[])]);
        assert_eq!(refuse(&twice).code, R::INVALID_JOINTS);
    }

    #[test]
    fn a_start_away_from_the_arm_is_an_invalid_goal() {
        let g = goal(
            &["base"],
            vec![point(0, &[0.02], &[]), point(1000, &[0.1], &[])],
        );
        let refusal = refuse(&g);
        assert_eq!(refusal.code, R::INVALID_GOAL);
        assert_says(&refusal.message, "start tolerance");
    }

    #[test]
    fn too_fast_or_out_of_limits_is_an_invalid_goal_naming_the_joint() {
        // base: 20000 steps/s at most; 1 rad in 0.1 s is 50930 steps/s.
        let g = goal(
            &["base"],
            vec![point(0, &[0.0], &[]), point(100, &[1.0], &[])],
        );
        let refusal = refuse(&g);
        assert_eq!(refusal.code, R::INVALID_GOAL);
        assert_says(&refusal.message, "joint 0");
        let far = goal(
            &["shoulder"],
            vec![point(0, &[0.0], &[]), point(10_000, &[2.0], &[])],
        );
        let refusal = refuse(&far);
        assert_says(&refusal.message, "above the maximum");
        // Issue 31: the joint's name and the goal's radians as well as steps (it said
        // "joint 1: position 10186 steps is above the maximum 8000 steps").
        assert_says(&refusal.message, "joint 1 (shoulder)");
        assert_says(&refusal.message, "10186 steps (2.0000 rad)");
        assert_says(&refusal.message, "8000 steps (1.5708 rad)");
        // An arm in degrees (the file's `units`, or the controller's description): degrees.
        let mut arm = setup().1;
        arm.units = Units::Deg;
        let refusal = plan(&far, &setup().0, &arm, &[0; 8], None).unwrap_err();
        assert_says(&refusal.message, "10186 steps (114.59 deg)");
    }

    #[test]
    fn goal_tolerance_from_the_goal_or_the_config() {
        let (config, arm) = setup();
        let mut g = goal(
            &["base"],
            vec![point(0, &[0.0], &[]), point(1000, &[0.1], &[])],
        );
        let exact = plan(&g, &config, &arm, &[0; 8], None).unwrap();
        let mut end = exact.end();
        assert!(check_end(&exact, &arm, &config, &end).is_ok());
        end[0] += 1;
        let message = check_end(&exact, &arm, &config, &end).unwrap_err();
        assert!(message.contains("1 steps off"), "{message}");
        g.goal_tolerance = vec![JointTolerance {
            name: "base".into(),
            position: 0.001,
            ..JointTolerance::default()
        }];
        let loose = plan(&g, &config, &arm, &[0; 8], None).unwrap();
        assert_eq!(loose.goal_tolerance_steps[0], 5);
        assert!(check_end(&loose, &arm, &config, &end).is_ok());
    }

    #[test]
    fn a_lone_point_at_the_arm_is_nothing_to_do() {
        let (config, arm) = setup();
        let g = goal(&["base"], vec![point(0, &[0.001], &[0.0])]);
        let plan = plan(&g, &config, &arm, &[5, 0, 0, 0, 0, 0, 0, 0], None).unwrap();
        assert!(plan.points.is_empty());
        assert_eq!(plan.end(), [5, 0, 0, 0, 0, 0, 0, 0]);
        let far = goal(&["base"], vec![point(0, &[0.1], &[])]);
        assert_eq!(refuse(&far).code, R::INVALID_GOAL);
    }

    #[test]
    fn malformed_goals_are_invalid_not_a_panic() {
        let (config, arm) = setup();
        let cases = [
            goal(&["base"], vec![point(0, &[f64::NAN], &[])]),
            goal(&["base"], vec![point(1000, &[f64::INFINITY], &[])]),
            goal(&["base"], vec![point(1000, &[0.1], &[f64::NAN])]),
            goal(&["base"], vec![point(1000, &[1e300], &[1e300])]),
            goal(&["base"], vec![point(1000, &[0.1, 0.2], &[])]),
            goal(&["base"], vec![point(1000, &[0.1], &[0.1, 0.2])]),
            goal(
                &["base"],
                vec![point(1000, &[0.1], &[]), point(500, &[0.2], &[])],
            ),
            goal(&["base"], vec![]),
        ];
        for g in &cases {
            let refusal = refuse(g);
            assert_eq!(refusal.code, R::INVALID_GOAL, "{g:?}");
        }
        let mut negative = goal(&["base"], vec![point(1000, &[0.1], &[])]);
        negative.trajectory.points[0].time_from_start.sec = -5;
        assert!(plan(&negative, &config, &arm, &[0; 8], None).is_err());
        let mut endless = goal(&["base"], vec![point(1000, &[0.1], &[])]);
        endless.trajectory.points[0].time_from_start.sec = i32::MAX;
        let refusal = refuse(&endless);
        assert_says(&refusal.message, "at most 65535");
    }

    #[test]
    fn joint_states_are_radians_in_config_order() {
        let (config, arm) = setup();
        let state = joint_state(
            &config.joint_names(),
            &arm,
            &[5093, -5093, 0, 2546, 0, 0, 0, 0],
            Time { sec: 5, nanosec: 7 },
        );
        assert_eq!(state.name.len(), 6);
        assert_eq!(state.position[..4], [1.0, -1.0, 0.0, 1.0]);
        assert_eq!(state.header.stamp, Time { sec: 5, nanosec: 7 });
    }
}
