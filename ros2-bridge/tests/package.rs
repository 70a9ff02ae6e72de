//! The ROS package in ros/armctl_ros2 (launch file, example URDF, MoveIt controllers)
//! matches the example config: the same joint names the bridge publishes, URDF limits
//! within what the bridge accepts, no controller joint the bridge never publishes.

use armctl_ros2::BridgeConfig;

const EXAMPLE: &str = include_str!("../examples/bridge.json");
const PACKAGE_CONFIG: &str = include_str!("../ros/armctl_ros2/config/bridge.json");
const URDF: &str = include_str!("../ros/armctl_ros2/urdf/arm.urdf.xacro");
const CONTROLLERS: &str = include_str!("../ros/armctl_ros2/config/moveit_controllers.yaml");

/// The value of `attr="..."` in `tag`.
fn attr(tag: &str, attr: &str) -> f64 {
    let start = tag.find(&format!("{attr}=\"")).expect(attr) + attr.len() + 2;
    let end = start + tag[start..].find('"').unwrap();
    tag[start..end].parse().unwrap()
}

#[test]
fn the_package_config_is_the_example() {
    assert_eq!(
        PACKAGE_CONFIG, EXAMPLE,
        "ros/armctl_ros2/config/bridge.json must be examples/bridge.json"
    );
}

#[test]
fn the_urdf_has_the_configs_joints_within_its_limits() {
    let (config, _) = BridgeConfig::parse(EXAMPLE, "bridge.json").unwrap();
    let revolute = URDF.matches("type=\"revolute\"").count();
    assert_eq!(
        revolute,
        config.joints.len(),
        "one revolute joint per config joint"
    );
    for joint in &config.joints {
        let name = joint.name.as_deref().unwrap();
        let at = URDF
            .find(&format!("<joint name=\"{name}\" type=\"revolute\">"))
            .unwrap_or_else(|| panic!("joint {name} not in the URDF"));
        let limit = &URDF[at..][URDF[at..].find("<limit").unwrap()..];
        let limit = &limit[..limit.find("/>").unwrap()];
        let spr = joint.steps_per_radian;
        let off = f64::from(joint.zero_offset_steps);
        let (lower, upper) = (attr(limit, "lower"), attr(limit, "upper"));
        let min = (f64::from(joint.min_steps) - off) / spr;
        let max = (f64::from(joint.max_steps) - off) / spr;
        assert!(
            lower >= min && upper <= max,
            "{name}: URDF {lower}..{upper}, config {min}..{max}"
        );
        assert!(
            lower - min < 1e-3 && max - upper < 1e-3,
            "{name}: URDF limits far inside"
        );
        let velocity = attr(limit, "velocity");
        let rate = f64::from(joint.max_step_rate_hz) / spr;
        assert!(
            velocity <= rate && rate - velocity < 1e-3,
            "{name}: velocity {velocity}, config {rate}"
        );
    }
}

#[test]
fn the_moveit_controllers_name_the_published_joints_only() {
    let (config, _) = BridgeConfig::parse(EXAMPLE, "bridge.json").unwrap();
    let lines: Vec<&str> = CONTROLLERS
        .lines()
        .filter(|l| l.trim_start().starts_with("joints:"))
        .collect();
    assert_eq!(lines.len(), 1, "one controller with joints: {lines:?}");
    let list = lines[0]
        .split_once('[')
        .unwrap()
        .1
        .trim_end()
        .trim_end_matches(']');
    let joints: Vec<&str> = list.split(',').map(str::trim).collect();
    assert_eq!(joints, config.joint_names());
    assert!(CONTROLLERS.contains("action_ns: follow_joint_trajectory"));
    assert!(config.action_name.ends_with("/follow_joint_trajectory"));
}
