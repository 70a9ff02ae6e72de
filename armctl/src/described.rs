//! The arm as the controller describes it (issue 31): each joint's name, units and scale
//! (JOINT_DESC_GET) with the limits and accelerations it keeps (LIMITS_GET), as the
//! [`ArmConfig`] a joint config file would give. Every host that talks to the controller
//! (armctl's subcommands, Python, the ROS bridge) reads the same arm from it, so none needs
//! its own file once `armctl config push` has stored one.

use protocol::{JointDesc, JointUnit, MAX_JOINTS, StatusCode};

use crate::motion::Units;
use crate::trajectory::{ArmConfig, JointConfig};
use crate::{Client, Error, Result};

/// The units a host shows a joint described in `unit` in (a linear joint's millimetres
/// are shown in steps: armctl's units are angles).
pub fn units_of(unit: JointUnit) -> Units {
    match unit {
        JointUnit::Degrees => Units::Deg,
        JointUnit::Radians => Units::Rad,
        JointUnit::Steps | JointUnit::Millimetres => Units::Steps,
    }
}

/// The description a joint config's joint gives (`units` the file's): name (at most
/// [`protocol::JOINT_NAME_LEN`] bytes, else an error naming the joint), units, zero offset
/// and steps per radian.
pub fn desc_of(joint: usize, config: &JointConfig, units: Units) -> Result<JointDesc> {
    let unit = match units {
        Units::Steps => JointUnit::Steps,
        Units::Deg => JointUnit::Degrees,
        Units::Rad => JointUnit::Radians,
    };
    let name = config.name.as_deref().unwrap_or("");
    JointDesc::new(
        name,
        unit,
        config.zero_offset_steps,
        config.steps_per_radian,
    )
    .ok_or_else(|| {
        Error::InvalidTrajectory(format!(
            "joint {joint}: name {name:?} is longer than {} bytes (or holds a NUL): the \
                 controller keeps at most that",
            protocol::JOINT_NAME_LEN
        ))
    })
}

impl Client {
    /// The arm the controller describes for its first `joints` joints (issue 31), as a
    /// joint config: names, units, scale (JOINT_DESC_GET), limits and accelerations
    /// (LIMITS_GET). `Ok(None)` when no joint is described, or the controller is older
    /// than issue 31 (`UNKNOWN_TAG`): callers fall back to steps. A joint's rate of its
    /// own of 0 is `max_rate_hz` (the controller's).
    pub fn described_arm(&self, joints: usize, max_rate_hz: u32) -> Result<Option<ArmConfig>> {
        let Some((units, descs)) = self.joint_descs(joints)? else {
            return Ok(None);
        };
        let limits = self.limits_with_accel()?;
        let joints = descs
            .iter()
            .zip(limits.joints)
            .enumerate()
            .map(|(j, (d, kept))| {
                let accel = limits
                    .max_accel
                    .and_then(|a| a.get(j).copied())
                    .filter(|a| *a != 0);
                JointConfig {
                    name: (!d.name().is_empty()).then(|| d.name().to_string()),
                    steps_per_radian: scale_of(d),
                    zero_offset_steps: d.zero_offset_steps,
                    min_steps: kept.min,
                    max_steps: kept.max,
                    max_step_rate_hz: if kept.max_rate_hz == 0 {
                        max_rate_hz
                    } else {
                        kept.max_rate_hz.min(max_rate_hz)
                    },
                    max_accel_steps_s2: accel.map(f64::from),
                }
            })
            .collect();
        Ok(Some(ArmConfig { units, joints }))
    }

    /// The names, units and scale the controller keeps for its first `joints` joints, for
    /// showing positions only (`armctl status`, `watch`): JOINT_DESC_GET alone, which any
    /// host may ask without taking the controller (LIMITS_GET is the owner's), so the
    /// limits are left open (any position, the rate 0). `Ok(None)` as for
    /// [`Client::described_arm`].
    pub fn described_names(&self, joints: usize) -> Result<Option<ArmConfig>> {
        let Some((units, descs)) = self.joint_descs(joints)? else {
            return Ok(None);
        };
        let joints = descs
            .iter()
            .map(|d| JointConfig {
                name: (!d.name().is_empty()).then(|| d.name().to_string()),
                steps_per_radian: scale_of(d),
                zero_offset_steps: d.zero_offset_steps,
                min_steps: i32::MIN,
                max_steps: i32::MAX,
                max_step_rate_hz: 0,
                max_accel_steps_s2: None,
            })
            .collect();
        Ok(Some(ArmConfig { units, joints }))
    }

    /// JOINT_DESC_GET for joints 0 to `joints - 1`, with the units of the first described
    /// one; `None` when none is described or the controller is older than issue 31.
    fn joint_descs(&self, joints: usize) -> Result<Option<(Units, Vec<JointDesc>)>> {
        let joints = joints.clamp(1, MAX_JOINTS);
        let mut descs = Vec::with_capacity(joints);
        for j in 0..joints {
            let j = u8::try_from(j).unwrap_or(u8::MAX);
            match self.joint_desc(j) {
                Ok(d) => descs.push(d),
                Err(e) if e.status() == Some(StatusCode::UnknownTag) => return Ok(None),
                Err(e) => return Err(e),
            }
        }
        let Some(first) = descs.iter().find(|d| d.is_described()) else {
            return Ok(None);
        };
        Ok(Some((units_of(first.unit), descs)))
    }
}

/// A joint's steps per radian as described; 1 (steps shown as they are) when it is not.
fn scale_of(d: &JointDesc) -> f64 {
    if d.is_described() && d.scale() != 0.0 {
        d.scale()
    } else {
        1.0
    }
}
