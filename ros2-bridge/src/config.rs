//! The bridge's configuration file (JSON): the controller's address, ROS names, rates and
//! the joint config in armctl's format (`joints`: steps per radian, offsets, limits, step
//! rates), plus the gripper servo's duty range.

use std::path::Path;

use armctl::trajectory::ArmConfig;
use serde::Deserialize;

/// Everything the bridge is told. Every field but `joints` has a default.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BridgeConfig {
    /// The controller, `host:port`.
    #[serde(default = "default_controller")]
    pub controller: String,
    /// The controller's authentication key (docs/PROTOCOL.md section 13): a file of 64 hex
    /// digits, as `armctl --key-file` takes (a relative path is from the working
    /// directory). `None`: frames go plain, for a controller without a key.
    #[serde(default)]
    pub key_file: Option<std::path::PathBuf>,
    /// DDS domain (`ROS_DOMAIN_ID`).
    #[serde(default)]
    pub domain_id: u16,
    /// ROS node name.
    #[serde(default = "default_node_name")]
    pub node_name: String,
    /// ROS node namespace.
    #[serde(default = "default_namespace")]
    pub namespace: String,
    /// The FollowJointTrajectory action (MoveIt: `<controller name>/<action_ns>`).
    #[serde(default = "default_action_name")]
    pub action_name: String,
    /// The GripperCommand action.
    #[serde(default = "default_gripper_action_name")]
    pub gripper_action_name: String,
    /// The `std_srvs/Trigger` service that sends STOPPED.
    #[serde(default = "default_estop_service")]
    pub estop_service: String,
    /// The `std_srvs/Trigger` service that sends HOLD (issue 32): the run under way
    /// decelerates along its path to a standstill and waits.
    #[serde(default = "default_hold_service")]
    pub hold_service: String,
    /// The `std_srvs/Trigger` service that sends RESUME (issue 32).
    #[serde(default = "default_resume_service")]
    pub resume_service: String,
    /// The speed scaling input (issue 32; UR's speed slider): `std_msgs/Float64`, a
    /// fraction, 1.0 = the trajectory's own speed, 0.01..=2.0 (above 1.0 where the
    /// controller allows), sent to the controller as OVERRIDE (percent, rounded).
    #[serde(default = "default_speed_scaling_topic")]
    pub speed_scaling_topic: String,
    /// The speed scaling state (as UR's `speed_scaling_state_broadcaster`):
    /// `std_msgs/Float64`, **percent**, the controller's rate now (MOTION report): the
    /// factor, below it while ramping, 0 while held.
    #[serde(default = "default_speed_scaling_state_topic")]
    pub speed_scaling_state_topic: String,
    /// How often the speed scaling state is read from the controller and published,
    /// 1..=100 Hz.
    #[serde(default = "default_speed_scaling_rate_hz")]
    pub speed_scaling_rate_hz: f64,
    /// The `std_srvs/Trigger` service that homes the arm (issue 33): on its home switches
    /// when it has them (HOME, answered when the cycle ended), by RETURN otherwise.
    #[serde(default = "default_home_service")]
    pub home_service: String,
    /// The JointState topic.
    #[serde(default = "default_joint_states_topic")]
    pub joint_states_topic: String,
    /// JointState rate, 1..=1000 Hz: the controller is asked for LOCATION reports at this
    /// rate and every report becomes one JointState.
    #[serde(default = "default_joint_state_rate_hz")]
    pub joint_state_rate_hz: f64,
    /// FollowJointTrajectory feedback rate while a goal runs, 1..=1000 Hz.
    #[serde(default = "default_feedback_rate_hz")]
    pub feedback_rate_hz: f64,
    /// Duration of one controller point when resampling a trajectory, microseconds.
    #[serde(default = "default_segment_us")]
    pub segment_us: u32,
    /// Largest difference between a goal's first point (at time 0) and where the arm is,
    /// radians (MoveIt's default allowed start deviation is 0.01).
    #[serde(default = "default_start_tolerance_rad")]
    pub start_tolerance_rad: f64,
    /// Largest difference between the last point and where the arm ends, steps, when the
    /// goal gives no goal tolerance for a joint.
    #[serde(default)]
    pub goal_tolerance_steps: u32,
    /// The arm's joints, joint 0 first (armctl's joint config entries; `name` is the ROS
    /// joint name). Empty or absent: the arm the controller keeps (issue 31: names, units,
    /// scale, limits and accelerations from `armctl config push`), read when the bridge
    /// connects ([`crate::Bridge::connect`]).
    #[serde(default)]
    pub joints: Vec<armctl::trajectory::JointConfig>,
    /// armctl's display units (`steps`, `deg`, `rad`; issue 31: one file for armctl and
    /// the bridge, which refused armctl's with "unknown field `units`"). Understood and
    /// unused: ROS always speaks radians.
    #[serde(default)]
    pub units: armctl::motion::Units,
    /// The gripper servo; `None`: no GripperCommand action.
    #[serde(default)]
    pub gripper: Option<GripperConfig>,
    /// The ROS 2 distribution whose message layouts and type hashes the bridge speaks;
    /// absent: `ROS_DISTRO` from the environment, else Jazzy ([`BridgeConfig::parse`] fills
    /// it in).
    #[serde(default)]
    pub ros_distro: Option<RosDistro>,
}

/// The ROS 2 distributions the bridge can speak. What differs between them on the wire:
/// control_msgs 5.x (Humble, Iron, Jazzy) or 6.x (Kilted, Rolling: FollowJointTrajectory
/// feedback has `index` and `multi_dof_index`), and type hashes in USER_DATA (Iron and
/// later).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum RosDistro {
    /// Humble Hawksbill: control_msgs 4.x/5.x feedback, no type hashes.
    Humble,
    /// Iron Irwini: control_msgs 5.x, type hashes.
    Iron,
    /// Jazzy Jalisco: control_msgs 5.x, type hashes.
    Jazzy,
    /// Kilted Kaiju: control_msgs 6.x, type hashes.
    Kilted,
    /// Rolling Ridley: control_msgs 6.x, type hashes.
    Rolling,
}

impl RosDistro {
    /// The names, as in `ROS_DISTRO` and the config.
    pub const NAMES: &'static str = "humble, iron, jazzy, kilted, rolling";

    /// From a `ROS_DISTRO`-style name.
    pub fn from_name(name: &str) -> Option<RosDistro> {
        Some(match name.trim().to_ascii_lowercase().as_str() {
            "humble" => RosDistro::Humble,
            "iron" => RosDistro::Iron,
            "jazzy" => RosDistro::Jazzy,
            "kilted" => RosDistro::Kilted,
            "rolling" => RosDistro::Rolling,
            _ => return None,
        })
    }

    /// control_msgs 6.x layouts (FollowJointTrajectory feedback with `index` and
    /// `multi_dof_index`).
    pub fn control_msgs_6(self) -> bool {
        matches!(self, RosDistro::Kilted | RosDistro::Rolling)
    }

    /// Publishes RIHS01 type hashes in USER_DATA (REP 2011: Iron and later).
    pub fn type_hashes(self) -> bool {
        !matches!(self, RosDistro::Humble)
    }
}

/// A hobby servo on the gripper PWM: a position (gap, metres) maps linearly to a duty.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GripperConfig {
    /// Servo frame rate, Hz (50 for most hobby servos).
    #[serde(default = "default_servo_hz")]
    pub pwm_hz: f64,
    /// Gap when closed, metres.
    pub closed_position: f64,
    /// Gap when open, metres.
    pub open_position: f64,
    /// Duty (0..1) that closes it (1 ms of 20 ms = 0.05).
    pub closed_duty: f64,
    /// Duty (0..1) that opens it (2 ms of 20 ms = 0.10).
    pub open_duty: f64,
    /// How long the servo takes to get anywhere, milliseconds: the result waits this long.
    #[serde(default = "default_settle_ms")]
    pub settle_ms: u64,
}

impl GripperConfig {
    /// The duty for a gap, or why the gap is refused.
    pub fn duty(&self, position: f64) -> Result<f64, String> {
        let (low, high) = if self.closed_position <= self.open_position {
            (self.closed_position, self.open_position)
        } else {
            (self.open_position, self.closed_position)
        };
        if !position.is_finite() || position < low - 1e-9 || position > high + 1e-9 {
            return Err(format!(
                "gripper position {position} m is outside {low}..={high} m (closed {} m, open {} m)",
                self.closed_position, self.open_position
            ));
        }
        let f = (position - self.closed_position) / (self.open_position - self.closed_position);
        Ok(self.closed_duty + f.clamp(0.0, 1.0) * (self.open_duty - self.closed_duty))
    }
}

/// The serde default functions, `name: Type = value;` each.
macro_rules! defaults {
    ($($name:ident: $ty:ty = $value:expr;)*) => {
        $(fn $name() -> $ty {
            $value
        })*
    };
}

defaults! {
    default_controller: String = String::from("127.0.0.1:8510");
    default_node_name: String = String::from("armctl_bridge");
    default_namespace: String = String::from("/");
    default_action_name: String = String::from("/arm_controller/follow_joint_trajectory");
    default_gripper_action_name: String = String::from("/gripper_controller/gripper_cmd");
    default_estop_service: String = String::from("/arm_controller/estop");
    default_hold_service: String = String::from("/arm_controller/hold");
    default_resume_service: String = String::from("/arm_controller/resume");
    default_home_service: String = String::from("/arm_controller/home");
    default_speed_scaling_topic: String = String::from("/arm_controller/speed_scaling_factor");
    default_speed_scaling_state_topic: String =
        String::from("/speed_scaling_state_broadcaster/speed_scaling");
    default_speed_scaling_rate_hz: f64 = 10.0;
    default_joint_states_topic: String = String::from("/joint_states");
    default_joint_state_rate_hz: f64 = 50.0;
    default_feedback_rate_hz: f64 = 30.0;
    default_segment_us: u32 = 10_000;
    default_start_tolerance_rad: f64 = 0.01;
    default_servo_hz: f64 = 50.0;
    default_settle_ms: u64 = 300;
}

impl BridgeConfig {
    /// Reads and checks a config file.
    pub fn load(path: &Path) -> Result<(BridgeConfig, ArmConfig), String> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| format!("{}: cannot read: {e}", path.display()))?;
        Self::parse(&text, &path.display().to_string())
    }

    /// Parses and checks a config; `file` names it in messages. Returns the joint config
    /// as armctl takes it too.
    pub fn parse(text: &str, file: &str) -> Result<(BridgeConfig, ArmConfig), String> {
        Self::parse_with_env(text, file, std::env::var("ROS_DISTRO").ok().as_deref())
    }

    /// [`BridgeConfig::parse`] with `ros_distro_env` in place of the environment's
    /// `ROS_DISTRO`.
    pub fn parse_with_env(
        text: &str,
        file: &str,
        ros_distro_env: Option<&str>,
    ) -> Result<(BridgeConfig, ArmConfig), String> {
        let mut config: BridgeConfig =
            serde_json::from_str(text).map_err(|e| format!("{file}: cannot parse: {e}"))?;
        if config.ros_distro.is_none() {
            config.ros_distro = match ros_distro_env.filter(|d| !d.is_empty()) {
                None => Some(RosDistro::Jazzy),
                Some(name) => Some(RosDistro::from_name(name).ok_or_else(|| {
                    format!(
                        "ROS_DISTRO={name:?} is not a distribution the bridge knows ({}); \
                         set ros_distro in {file}",
                        RosDistro::NAMES
                    )
                })?),
            };
        }
        // No joints: the controller's, filled in by Bridge::connect (issue 31).
        let arm = if config.joints.is_empty() {
            ArmConfig {
                units: config.units,
                joints: Vec::new(),
            }
        } else {
            ArmConfig::parse(text, file).map_err(|e| e.to_string())?
        };
        let rates = [
            ("joint_state_rate_hz", config.joint_state_rate_hz),
            ("feedback_rate_hz", config.feedback_rate_hz),
        ];
        for (name, rate) in rates {
            if !(1.0..=1000.0).contains(&rate) {
                return Err(format!("{file}: {name} {rate} must be 1 to 1000 Hz"));
            }
        }
        // Each reading is a STATUS round trip to the controller.
        if !(1.0..=100.0).contains(&config.speed_scaling_rate_hz) {
            return Err(format!(
                "{file}: speed_scaling_rate_hz {} must be 1 to 100 Hz",
                config.speed_scaling_rate_hz
            ));
        }
        if config.segment_us == 0 {
            return Err(format!("{file}: segment_us must be at least 1"));
        }
        if !(config.start_tolerance_rad.is_finite() && config.start_tolerance_rad >= 0.0) {
            return Err(format!("{file}: start_tolerance_rad must be 0 or more"));
        }
        for (j, joint) in config.joints.iter().enumerate() {
            if joint.name.is_none() {
                return Err(format!(
                    "{file}: joint {j} has no `name` (the ROS joint name is needed)"
                ));
            }
            let repeated = config.joints[..j].iter().any(|o| o.name == joint.name);
            if repeated {
                return Err(format!("{file}: joint name {:?} repeated", joint.name));
            }
        }
        if let Some(g) = &config.gripper {
            let duties_ok = [g.closed_duty, g.open_duty]
                .iter()
                .all(|d| (0.0..=1.0).contains(d));
            if !(duties_ok && g.pwm_hz.is_finite() && g.pwm_hz > 0.0) {
                return Err(format!(
                    "{file}: gripper duties must be 0 to 1 and pwm_hz above 0"
                ));
            }
            if !(g.closed_position.is_finite() && g.open_position.is_finite())
                || g.closed_position == g.open_position
            {
                return Err(format!(
                    "{file}: gripper closed_position and open_position must differ"
                ));
            }
        }
        Ok((config, arm))
    }

    /// The ROS 2 distribution to speak (Jazzy if neither the config nor `ROS_DISTRO` says).
    pub fn distro(&self) -> RosDistro {
        self.ros_distro.unwrap_or(RosDistro::Jazzy)
    }

    /// Names the joints the file leaves unnamed with `described` (joint 0 first: the
    /// names the controller keeps, JOINT_DESC, issue 31; "" for none). A name the file
    /// gives wins. Returns how many were named.
    pub fn name_unnamed(&mut self, described: &[String]) -> usize {
        let mut named = 0;
        for (joint, name) in self.joints.iter_mut().zip(described) {
            if joint.name.as_deref().unwrap_or("").is_empty() && !name.is_empty() {
                joint.name = Some(name.clone());
                named += 1;
            }
        }
        named
    }

    /// Takes the arm the controller keeps (`described`, from
    /// [`armctl::Client::described_arm`]) as the joints of a config that lists none. Every
    /// joint needs a name, the ROS joint name: an error names the first without one.
    pub fn take_described(&mut self, described: &ArmConfig) -> Result<(), String> {
        for (j, joint) in described.joints.iter().enumerate() {
            let name = joint.name.as_deref().unwrap_or("");
            if name.is_empty() {
                return Err(format!(
                    "the config lists no joints and the controller keeps no name for joint \
                     {j} (ROS needs one): push an arm description with names (`armctl \
                     config push ARM.json`) or list `joints` in the config"
                ));
            }
            if described.joints[..j]
                .iter()
                .any(|o| o.name.as_deref() == Some(name))
            {
                return Err(format!(
                    "the controller keeps the joint name {name:?} twice: push an arm \
                     description with distinct names (`armctl config push ARM.json`)"
                ));
            }
        }
        self.joints = described.joints.clone();
        self.units = described.units;
        Ok(())
    }

    /// The ROS joint names, joint 0 first.
    pub fn joint_names(&self) -> Vec<String> {
        self.joints
            .iter()
            .map(|j| j.name.clone().unwrap_or_default())
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const EXAMPLE: &str = include_str!("../examples/bridge.json");

    /// Issue 31: a joint the bridge's file leaves unnamed takes the controller's name;
    /// a name in the file wins, and "" (not described) names nothing.
    #[test]
    fn unnamed_joints_take_the_controller_s_names() {
        let (mut config, _) = BridgeConfig::parse(EXAMPLE, "bridge.json").unwrap();
        config.joints[1].name = None;
        config.joints[2].name = None;
        let described: Vec<String> = ["x", "shoulder", ""]
            .iter()
            .map(|s| s.to_string())
            .collect();
        assert_eq!(config.name_unnamed(&described), 1);
        let names = config.joint_names();
        assert_eq!(names[0], "base", "the file's name wins");
        assert_eq!(names[1], "shoulder");
        assert_eq!(names[2], "", "not described: still unnamed");
    }

    /// Issue 31: a bridge file without `joints` takes the arm the controller keeps (it
    /// was refused "missing field `joints`"); that arm's joints need ROS names.
    #[test]
    fn a_file_without_joints_takes_the_controller_s_arm() {
        let (mut config, arm) =
            BridgeConfig::parse(r#"{"controller": "127.0.0.1:9"}"#, "bridge.json")
                .unwrap_or_else(|e| panic!("{e}"));
        assert!(config.joints.is_empty() && arm.joints.is_empty());
        let kept = ArmConfig::parse(
            r#"{"units": "deg", "joints": [
                {"name": "base", "steps_per_radian": 2546.5, "max_step_rate_hz": 2000},
                {"name": "shoulder", "steps_per_radian": 2546.5, "max_step_rate_hz": 2000}
            ]}"#,
            "kept",
        )
        .unwrap();
        config.take_described(&kept).unwrap();
        assert_eq!(config.joint_names(), ["base", "shoulder"]);
        assert_eq!(config.units, armctl::motion::Units::Deg);
        let mut unnamed = kept.clone();
        unnamed.joints[1].name = None;
        let mut fresh = config.clone();
        fresh.joints.clear();
        assert!(
            fresh
                .take_described(&unnamed)
                .unwrap_err()
                .contains("no name for joint 1"),
        );
        let mut twice = kept;
        twice.joints[1].name = Some("base".into());
        assert!(fresh.take_described(&twice).unwrap_err().contains("twice"));
    }

    #[test]
    fn the_example_parses() {
        let (config, arm) = BridgeConfig::parse(EXAMPLE, "bridge.json").unwrap();
        assert_eq!(arm.joints.len(), 6);
        assert_eq!(config.joint_names()[0], "base");
        assert_eq!(
            config.action_name,
            "/arm_controller/follow_joint_trajectory"
        );
        let gripper = config.gripper.unwrap();
        assert!(
            (gripper.duty(gripper.closed_position).unwrap() - gripper.closed_duty).abs() < 1e-12
        );
        assert!((gripper.duty(gripper.open_position).unwrap() - gripper.open_duty).abs() < 1e-12);
        assert!(gripper.duty(gripper.open_position + 0.01).is_err());
    }

    #[test]
    fn the_distro_comes_from_the_config_then_ros_distro_then_jazzy() {
        let plain = r#"{"joints": [{"name": "a", "max_step_rate_hz": 1}]}"#;
        let kilted =
            r#"{"ros_distro": "kilted", "joints": [{"name": "a", "max_step_rate_hz": 1}]}"#;
        let distro = |text, env| BridgeConfig::parse_with_env(text, "c", env).map(|c| c.0.distro());
        assert_eq!(distro(plain, None), Ok(RosDistro::Jazzy));
        assert_eq!(distro(plain, Some("")), Ok(RosDistro::Jazzy));
        assert_eq!(distro(plain, Some("rolling")), Ok(RosDistro::Rolling));
        assert_eq!(distro(plain, Some("humble")), Ok(RosDistro::Humble));
        assert_eq!(distro(kilted, Some("humble")), Ok(RosDistro::Kilted));
        assert!(
            distro(plain, Some("ardent"))
                .unwrap_err()
                .contains("ROS_DISTRO")
        );
        assert!(RosDistro::Kilted.control_msgs_6() && RosDistro::Rolling.control_msgs_6());
        assert!(!RosDistro::Jazzy.control_msgs_6() && !RosDistro::Humble.control_msgs_6());
        assert!(RosDistro::Jazzy.type_hashes() && !RosDistro::Humble.type_hashes());
    }

    /// Issue 31: the bridge refused armctl's joint config file ("unknown field `units`");
    /// one file now serves both.
    #[test]
    fn armctl_s_config_file_is_taken() {
        let armctl_file = r#"{"units": "deg", "joints": [
            {"name": "base", "steps_per_radian": 5093.0, "min_steps": -16000, "max_steps": 16000,
             "max_step_rate_hz": 20000, "max_accel_steps_s2": 40000}
        ]}"#;
        let (config, arm) = BridgeConfig::parse(armctl_file, "arm.json").unwrap();
        assert_eq!(config.units, armctl::motion::Units::Deg);
        assert_eq!(
            arm,
            ArmConfig::parse(armctl_file, "arm.json").unwrap_or_else(|e| panic!("{e}"))
        );
        let (_, arm) = BridgeConfig::load(std::path::Path::new(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../armctl/examples/arm.json"
        )))
        .unwrap();
        assert_eq!(arm.joints.len(), 6);
        // Other unknown fields are still refused (a typo must not pass silently).
        let typo = r#"{"unit": "deg", "joints": [{"name": "a", "max_step_rate_hz": 1}]}"#;
        assert!(BridgeConfig::parse(typo, "c").unwrap_err().contains("unit"));
    }

    #[test]
    fn a_key_file_is_taken_and_is_optional() {
        let keyed = r#"{"key_file": "arm.key", "joints": [{"name": "a", "max_step_rate_hz": 1}]}"#;
        let (config, _) = BridgeConfig::parse(keyed, "c").unwrap();
        assert_eq!(config.key_file, Some(std::path::PathBuf::from("arm.key")));
        let (example, _) = BridgeConfig::parse(EXAMPLE, "bridge.json").unwrap();
        assert_eq!(example.key_file, None);
    }

    #[test]
    fn bad_configs_are_refused_with_what_is_wrong() {
        let nameless = r#"{"joints": [{"max_step_rate_hz": 1000}]}"#;
        assert!(
            BridgeConfig::parse(nameless, "c")
                .unwrap_err()
                .contains("no `name`")
        );
        let rate =
            r#"{"joint_state_rate_hz": 0, "joints": [{"name": "a", "max_step_rate_hz": 1}]}"#;
        assert!(
            BridgeConfig::parse(rate, "c")
                .unwrap_err()
                .contains("joint_state_rate_hz")
        );
        let typo = r#"{"joint_state_hz": 50, "joints": [{"name": "a", "max_step_rate_hz": 1}]}"#;
        assert!(
            BridgeConfig::parse(typo, "c")
                .unwrap_err()
                .contains("joint_state_hz")
        );
        let distro = r#"{"ros_distro": "foxy", "joints": [{"name": "a", "max_step_rate_hz": 1}]}"#;
        assert!(
            BridgeConfig::parse(distro, "c")
                .unwrap_err()
                .contains("unknown variant `foxy`")
        );
        let twice = r#"{"joints": [{"name": "a", "max_step_rate_hz": 1}, {"name": "a", "max_step_rate_hz": 1}]}"#;
        assert!(
            BridgeConfig::parse(twice, "c")
                .unwrap_err()
                .contains("repeated")
        );
    }
}
