//! The joint config file: calibration and limits of each joint.

use std::path::Path;

use protocol::MAX_JOINTS;
use serde::Deserialize;

use super::{ErrorKind, TrajectoryError};
use crate::motion::Units;

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
    /// Highest acceleration of this joint for moves planned on the host (`armctl move`,
    /// `jog`), steps per second squared; without it, full rate in
    /// [`DEFAULT_ACCEL_TIME_S`](crate::motion::DEFAULT_ACCEL_TIME_S).
    #[serde(default)]
    pub max_accel_steps_s2: Option<f64>,
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

/// The joint config file: `{"units": "deg", "joints": [ {...}, ... ]}` in joint order.
#[derive(Clone, Debug, Deserialize, PartialEq)]
pub struct ArmConfig {
    /// The units the tools take and show positions in by default (`--units` overrides):
    /// `steps` (the default), `deg` or `rad`.
    #[serde(default)]
    pub units: Units,
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
                || joint
                    .max_accel_steps_s2
                    .is_some_and(|a| !(a.is_finite() && a > 0.0))
            {
                let name = joint
                    .name
                    .as_ref()
                    .map_or(String::new(), |n| format!(" ({n})"));
                return Err(TrajectoryError::new(
                    file,
                    ErrorKind::Parse(format!(
                        "joint {j}{name}: min_steps must not exceed max_steps, \
                         steps_per_radian must be a non-zero number and max_accel_steps_s2 \
                         (when given) a number above 0"
                    )),
                ));
            }
        }
        Ok(config)
    }

    /// Each configured joint's short name: its `name`, else `jN` (recording headers, plot
    /// legends, `watch` lines).
    pub fn short_names(&self) -> Vec<String> {
        self.joints
            .iter()
            .enumerate()
            .map(|(j, c)| c.name.clone().unwrap_or_else(|| format!("j{j}")))
            .collect()
    }

    /// This config within the limits a controller keeps (LIMITS_GET, joint 0 first): each
    /// joint's range the overlap of both (empty when they do not overlap: min above max,
    /// every target refused), its step rate the lower of both (a kept rate of 0 is none).
    /// Plans made with it are not refused for a kept limit (issue 31).
    pub fn within(&self, kept: &[protocol::JointLimits]) -> ArmConfig {
        let mut config = self.clone();
        for (joint, kept) in config.joints.iter_mut().zip(kept) {
            joint.min_steps = joint.min_steps.max(kept.min);
            joint.max_steps = joint.max_steps.min(kept.max);
            if kept.max_rate_hz != 0 {
                joint.max_step_rate_hz = joint.max_step_rate_hz.min(kept.max_rate_hz);
            }
        }
        config
    }

    /// A config with no position limits and one step rate for `joints` joints.
    pub fn unlimited(joints: usize, max_step_rate_hz: u32) -> ArmConfig {
        ArmConfig {
            units: Units::Steps,
            joints: (0..joints.min(MAX_JOINTS))
                .map(|_| JointConfig {
                    name: None,
                    steps_per_radian: 1.0,
                    zero_offset_steps: 0,
                    min_steps: i32::MIN,
                    max_steps: i32::MAX,
                    max_step_rate_hz,
                    max_accel_steps_s2: None,
                })
                .collect(),
        }
    }
}
