//! What `armctl config push FILE` stores on the controller (issues 23 and 31), read and
//! sent once for every host tool (the CLI and Python's `Arm.push_config`): each joint's
//! limits (LIMITS_SET), acceleration (ACCEL_SET) and description (JOINT_DESC_SET: name,
//! units, scale), from a joint config file or from what `config get --json` printed.

use protocol::{JointDesc, JointLimits, JointUnit, MAX_JOINTS, StatusCode, Tag};

use crate::trajectory::ArmConfig;
use crate::{Client, Error};

/// One joint as pushed: the name it is shown with, its limits, and its acceleration.
#[derive(Clone, Debug, PartialEq)]
pub struct PushedJoint {
    /// The name shown in messages ("-" when none).
    pub name: String,
    /// Range and rate (LIMITS_SET).
    pub limits: JointLimits,
    /// Steps/s² (ACCEL_SET); `None`: none sent (a `config get --json` of a controller
    /// older than issue 31); `Some(0)`: none kept.
    pub accel: Option<u32>,
}

/// Everything a push sends, joint 0 first.
#[derive(Clone, Debug, PartialEq)]
pub struct PushedArm {
    /// Limits and accelerations, 1 to [`MAX_JOINTS`] joints.
    pub joints: Vec<PushedJoint>,
    /// The descriptions (JOINT_DESC_SET); `None`: none sent (a `config get --json` of an
    /// older controller).
    pub descs: Option<Vec<JointDesc>>,
}

/// What `config get --json` prints, as a push reads it back: the joints' limits and
/// accelerations and descriptions (the last refusal, also printed, is left alone).
#[derive(serde::Deserialize)]
struct Kept {
    joints: Vec<JointLimits>,
    /// Each joint's acceleration (issue 31); absent or null from an older controller.
    #[serde(default)]
    max_accel: Option<Vec<u32>>,
    /// Each joint's description (issue 31); absent or null from an older controller.
    #[serde(default)]
    joint_desc: Option<Vec<KeptDesc>>,
}

/// One joint of `config get --json`'s `joint_desc`.
#[derive(serde::Deserialize)]
struct KeptDesc {
    name: String,
    unit: String,
    zero_offset_steps: i32,
    scale: f64,
}

impl PushedArm {
    /// Reads `path` ([`PushedArm::parse`]).
    pub fn load(path: &std::path::Path) -> Result<PushedArm, String> {
        let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
        PushedArm::parse(&text, &path.display().to_string())
    }

    /// A joint config (`min_steps`, `max_steps`, `max_step_rate_hz`, `max_accel_steps_s2`,
    /// names, its units, `zero_offset_steps`, `steps_per_radian`), or what `config get
    /// --json` printed (`min`, `max`, `max_rate_hz`, `max_accel`, `joint_desc`; issue 31:
    /// it was refused, "missing field `max_step_rate_hz`"). `file` names it in errors.
    pub fn parse(text: &str, file: &str) -> Result<PushedArm, String> {
        let value: serde_json::Value =
            serde_json::from_str(text).map_err(|e| format!("{file}: cannot parse: {e}"))?;
        let from_get = value
            .pointer("/joints/0")
            .is_some_and(|joint| joint.get("max_rate_hz").is_some());
        if !from_get {
            let config = ArmConfig::parse(text, file).map_err(|e| e.to_string())?;
            return PushedArm::of_config(&config).map_err(|e| format!("{file}: {e}"));
        }
        let kept: Kept =
            serde_json::from_value(value).map_err(|e| format!("{file}: cannot parse: {e}"))?;
        if kept.joints.is_empty() || kept.joints.len() > MAX_JOINTS {
            return Err(format!(
                "{file}: {} joints: 1 to {MAX_JOINTS}",
                kept.joints.len()
            ));
        }
        if let Some(j) = kept.joints.iter().position(|l| !l.is_valid()) {
            return Err(format!(
                "{file}: joint {j}: min {} is above max {}",
                kept.joints[j].min, kept.joints[j].max
            ));
        }
        let accel = kept.max_accel;
        let joints = kept
            .joints
            .into_iter()
            .enumerate()
            .map(|(j, limits)| PushedJoint {
                name: "-".into(),
                limits,
                accel: accel.as_ref().map(|a| a.get(j).copied().unwrap_or(0)),
            })
            .collect();
        let descs = kept
            .joint_desc
            .map(|descs| {
                descs
                    .iter()
                    .enumerate()
                    .map(|(j, d)| kept_desc(file, j, d))
                    .collect::<Result<Vec<_>, _>>()
            })
            .transpose()?;
        Ok(PushedArm { joints, descs })
    }

    /// What a joint config pushes: each joint's limits, acceleration (0: none) and
    /// description.
    pub fn of_config(config: &ArmConfig) -> Result<PushedArm, String> {
        let joints = config
            .joints
            .iter()
            .map(|joint| PushedJoint {
                name: joint.name.clone().unwrap_or_else(|| "-".into()),
                limits: JointLimits {
                    min: joint.min_steps,
                    max: joint.max_steps,
                    max_rate_hz: joint.max_step_rate_hz,
                },
                accel: Some(
                    joint
                        .max_accel_steps_s2
                        .map_or(0, |a| a.round().clamp(1.0, f64::from(u32::MAX)) as u32),
                ),
            })
            .collect();
        let descs = config
            .joints
            .iter()
            .enumerate()
            .map(|(j, joint)| {
                crate::described::desc_of(j, joint, config.units).map_err(|e| e.to_string())
            })
            .collect::<Result<Vec<_>, _>>()?;
        Ok(PushedArm {
            joints,
            descs: Some(descs),
        })
    }
}

fn kept_desc(file: &str, j: usize, d: &KeptDesc) -> Result<JointDesc, String> {
    let unit = JointUnit::from_name(&d.unit).ok_or_else(|| {
        format!(
            "{file}: joint {j}: unit {:?}: steps, deg, rad or mm",
            d.unit
        )
    })?;
    JointDesc::new(&d.name, unit, d.zero_offset_steps, d.scale)
        .filter(JointDesc::is_valid)
        .ok_or_else(|| {
            format!(
                "{file}: joint {j}: name {:?} over {} bytes or scale not a number",
                d.name,
                protocol::JOINT_NAME_LEN
            )
        })
}

/// What a push did, line by line, as `armctl config push` prints it.
#[derive(Clone, Debug, PartialEq)]
pub enum Pushed {
    /// Something kept ("joint 1 shoulder: -4000..4000 steps, at most 2000 steps/s").
    Kept(String),
    /// Something the controller could not keep (an older one): a warning.
    Warning(String),
}

/// A push that failed: which joint, which command, and the controller's answer. What was
/// sent before it stays kept.
#[derive(Debug)]
pub struct PushError {
    /// The joint.
    pub joint: u8,
    /// LIMITS_SET, ACCEL_SET or JOINT_DESC_SET.
    pub command: Tag,
    /// Why.
    pub error: Error,
}

impl std::fmt::Display for PushError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self.error {
            // It names the command already ("LIMITS_SET refused with NOT_OWNER ...").
            Error::Refused { .. } => write!(f, "joint {}: {}", self.joint, self.error),
            _ => write!(
                f,
                "joint {}: {}: {}",
                self.joint,
                self.command.name(),
                self.error
            ),
        }
    }
}

impl std::error::Error for PushError {}

/// A joint's limits in words.
pub fn describe_limits(l: &JointLimits) -> String {
    let range = match (l.min, l.max) {
        (i32::MIN, i32::MAX) => "any position".to_string(),
        (i32::MIN, max) => format!("up to {max} steps"),
        (min, i32::MAX) => format!("from {min} steps"),
        (min, max) => format!("{min}..{max} steps"),
    };
    let rate = match l.max_rate_hz {
        0 => "the controller's max step rate".to_string(),
        hz => format!("at most {hz} steps/s"),
    };
    format!("{range}, {rate}")
}

/// What a description's scale counts steps per.
pub fn scale_unit(unit: JointUnit) -> &'static str {
    match unit {
        JointUnit::Degrees | JointUnit::Radians => "radian",
        JointUnit::Millimetres => "mm",
        JointUnit::Steps => "step",
    }
}

impl Client {
    /// Stores `arm` on the controller (only while STOPPED): each joint's limits, its
    /// acceleration and its description, in that order, `said` told each thing kept and
    /// each warning (an older controller keeps no acceleration or description). Stops at
    /// the first refusal.
    pub fn push_arm(&self, arm: &PushedArm, mut said: impl FnMut(Pushed)) -> Result<(), PushError> {
        let failed = |joint, command, error| PushError {
            joint,
            command,
            error,
        };
        for (j, joint) in arm.joints.iter().enumerate().take(MAX_JOINTS) {
            let name = &joint.name;
            let j = u8::try_from(j).unwrap_or(u8::MAX);
            self.set_limits(j, joint.limits)
                .map_err(|e| failed(j, Tag::LimitsSet, e))?;
            said(Pushed::Kept(format!(
                "joint {j} {name}: {}",
                describe_limits(&joint.limits)
            )));
            let Some(accel) = joint.accel else { continue };
            match self.set_accel(j, accel) {
                Ok(_) if accel > 0 => {
                    said(Pushed::Kept(format!(
                        "joint {j} {name}: at most {accel} steps/s²"
                    )));
                }
                Ok(_) => {}
                Err(e) if e.status() == Some(StatusCode::UnknownTag) => {
                    if accel > 0 {
                        said(Pushed::Warning(format!(
                            "joint {j}: the controller keeps no acceleration (older than issue \
                             31): max_accel_steps_s2 not enforced there"
                        )));
                    }
                }
                Err(e) => return Err(failed(j, Tag::AccelSet, e)),
            }
        }
        for (j, desc) in arm.descs.iter().flatten().enumerate().take(MAX_JOINTS) {
            let j = u8::try_from(j).unwrap_or(u8::MAX);
            match self.set_joint_desc(j, *desc) {
                Ok(_) => {}
                Err(e) if e.status() == Some(StatusCode::UnknownTag) => {
                    said(Pushed::Warning(
                        "the controller keeps no names or units (older than issue 31): other \
                         hosts need this file (--config)"
                            .into(),
                    ));
                    break;
                }
                Err(e) => return Err(failed(j, Tag::JointDescSet, e)),
            }
            if desc.is_described() {
                said(Pushed::Kept(format!(
                    "joint {j} {}: {} ({} steps per {}, zero at {} steps)",
                    desc.name(),
                    desc.unit,
                    desc.scale(),
                    scale_unit(desc.unit),
                    desc.zero_offset_steps
                )));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A joint config and `config get --json`'s output push the same limits; the
    /// latter's descriptions when it has them, none from an older controller's.
    #[test]
    fn a_config_and_config_get_s_json_push_alike() {
        let config = r#"{"units": "deg", "joints": [
            {"name": "base", "steps_per_radian": 2546.5, "min_steps": -4000, "max_steps": 4000,
             "max_step_rate_hz": 2000, "max_accel_steps_s2": 400000}
        ]}"#;
        let from_config = PushedArm::parse(config, "arm.json").unwrap();
        let limits = JointLimits {
            min: -4000,
            max: 4000,
            max_rate_hz: 2000,
        };
        assert_eq!(
            from_config.joints,
            [PushedJoint {
                name: "base".into(),
                limits,
                accel: Some(400_000),
            }]
        );
        let desc = from_config.descs.as_ref().unwrap()[0];
        assert_eq!(
            (desc.name(), desc.unit, desc.scale()),
            ("base", JointUnit::Degrees, 2546.5)
        );
        let got = r#"{"joints": [{"min": -4000, "max": 4000, "max_rate_hz": 2000}],
            "max_accel": [400000],
            "joint_desc": [{"name": "base", "unit": "deg", "zero_offset_steps": 0, "scale": 2546.5}]}"#;
        let from_get = PushedArm::parse(got, "kept.json").unwrap();
        assert_eq!(from_get.joints[0].limits, limits);
        assert_eq!(from_get.joints[0].accel, Some(400_000));
        assert_eq!(from_get.descs, from_config.descs);
        let older = r#"{"joints": [{"min": -4000, "max": 4000, "max_rate_hz": 2000}],
            "max_accel": null, "joint_desc": null}"#;
        let older = PushedArm::parse(older, "old.json").unwrap();
        assert_eq!((older.joints[0].accel, older.descs), (None, None));
        let bad_unit = got.replace("\"deg\"", "\"furlong\"");
        let e = PushedArm::parse(&bad_unit, "kept.json").unwrap_err();
        assert!(e.contains("kept.json: joint 0: unit \"furlong\""), "{e}");
    }
}
