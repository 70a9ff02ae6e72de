//! `armctl-ros2 CONFIG.json [--controller HOST:PORT]`: the ROS 2 bridge (see docs/ROS2.md).

use std::path::PathBuf;
use std::process::ExitCode;

use armctl_ros2::{Bridge, BridgeConfig};

const USAGE: &str = "usage: armctl-ros2 CONFIG.json [--controller HOST:PORT]\n\
    Serves FollowJointTrajectory, GripperCommand, an e-stop Trigger and /joint_states\n\
    for the arm controller named in the config (docs/ROS2.md). RUST_LOG=debug logs more.";

fn main() -> ExitCode {
    // With ARMCTL_TRACE, the armctl client's upload traces (ACKs, timeouts, resends) too.
    armctl::logger("info,rustdds=warn,ros2_client=warn")
        .format_timestamp_millis()
        .init();
    let mut args = std::env::args().skip(1);
    let mut config_path: Option<PathBuf> = None;
    let mut controller: Option<String> = None;
    while let Some(arg) = args.next() {
        match arg.as_str() {
            "--controller" => controller = args.next(),
            "-h" | "--help" => {
                println!("{USAGE}");
                return ExitCode::SUCCESS;
            }
            _ if config_path.is_none() && !arg.starts_with('-') => config_path = Some(arg.into()),
            _ => {
                eprintln!("armctl-ros2: unexpected argument {arg:?}\n{USAGE}");
                return ExitCode::from(2);
            }
        }
    }
    let Some(config_path) = config_path else {
        eprintln!("{USAGE}");
        return ExitCode::from(2);
    };
    let (mut config, arm) = match BridgeConfig::load(&config_path) {
        Ok(c) => c,
        Err(e) => {
            eprintln!("armctl-ros2: {e}");
            return ExitCode::from(2);
        }
    };
    if let Some(controller) = controller {
        config.controller = controller;
    }
    let bridge = match Bridge::connect(config, arm) {
        Ok(b) => b,
        Err(e) => {
            eprintln!("armctl-ros2: {e}");
            return ExitCode::FAILURE;
        }
    };
    log::info!("bridge up: {bridge:?}");
    // Runs until killed: the stop channel's sender lives as long as main.
    let (_stop_tx, stop_rx) = async_channel::bounded(1);
    match bridge.run(stop_rx) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("armctl-ros2: {e}");
            ExitCode::FAILURE
        }
    }
}
