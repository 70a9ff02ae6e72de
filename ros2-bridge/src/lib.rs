//! ROS 2 bridge for the arm controller, for MoveIt: a `control_msgs/FollowJointTrajectory`
//! action server that streams whole trajectories with armctl's reliable client,
//! `sensor_msgs/JointState` from the controller's LOCATION reports, a
//! `control_msgs/GripperCommand` action on the gripper PWM and a `std_srvs/Trigger` e-stop.
//! It is built on the pure-Rust `ros2-client` (RustDDS): no ROS installation is needed.
//!
//! - [`config`]: the JSON config file (controller, names, rates, joints, gripper).
//! - [`goal`]: the decisions, without I/O (goal checks, result codes, messages).
//! - [`bridge`]: the running node.
//! - [`msgs`]: the ROS message types, field for field.
//! - [`typehash`]: their RIHS01 type hashes (REP 2011), announced with every endpoint.
//!
//! docs/ROS2.md tells how to run it with MoveIt.

pub mod bridge;
pub mod config;
pub mod goal;
pub mod msgs;
pub mod typehash;

pub use bridge::{Bridge, Sample};
pub use config::{BridgeConfig, GripperConfig, RosDistro};
