//! The arm's description kept on the controller (issue 31): each joint's name, the units
//! hosts show it in and its scale, so that every host (armctl, Python, the ROS bridge, a
//! web page) reads the same arm. Set with JOINT_DESC_SET (STOPPED only, kept across power
//! cycles with the limits), read with JOINT_DESC_GET, answered with a JOINT_DESC report
//! whose data is JOINT_DESC_SET's (docs/PROTOCOL.md, "JOINT_DESC_SET, JOINT_DESC_GET").
//!
//! The controller stores and returns the description; it never computes with it (its
//! limits and moves are in steps), so the scale is carried as the bits of an IEEE-754
//! f64, exactly as the host gave it (a host's `steps_per_radian` round-trips unchanged).
//! One joint per frame keeps the report at 36 bytes, well inside the controller's report
//! buffer (a whole arm would be 256).

use crate::codec::{Writer, i32_le, u8_at, u64_le};
use crate::codes::wire_code;

/// Most bytes of a joint's name: UTF-8, padded with zero bytes (a name holds no NUL).
pub const NAME_LEN: usize = 16;

wire_code! {
    /// The units hosts show a joint's positions in (JOINT_DESC's `unit` byte).
    #[derive(Default)]
    pub enum JointUnit {
        /// Motor steps (scale 1, or none).
        #[default]
        Steps = 0 => "steps",
        /// Degrees; the scale is steps per radian.
        Degrees = 1 => "deg",
        /// Radians; the scale is steps per radian.
        Radians = 2 => "rad",
        /// Millimetres (a linear joint); the scale is steps per millimetre.
        Millimetres = 3 => "mm",
    }
}

/// One joint's description (32 bytes on the wire: name, unit, 3 reserved, zero offset,
/// scale).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct JointDesc {
    /// The joint's name, UTF-8 padded with zeros ([`JointDesc::name`]); all zero: none.
    pub name_bytes: [u8; NAME_LEN],
    /// The units hosts show it in.
    pub unit: JointUnit,
    /// Step position of the unit's 0.
    pub zero_offset_steps: i32,
    /// Steps per radian (deg, rad), per millimetre (mm) or 1 (steps), as the bits of an
    /// f64 ([`JointDesc::scale`]); 0: none (not described).
    pub scale_bits: u64,
}

impl JointDesc {
    /// Not described: no name, steps, no scale (the boot default and what a flash written
    /// before issue 31 loads with).
    pub const NONE: JointDesc = JointDesc {
        name_bytes: [0; NAME_LEN],
        unit: JointUnit::Steps,
        zero_offset_steps: 0,
        scale_bits: 0,
    };

    /// A description named `name` (None when it is over [`NAME_LEN`] bytes or holds a
    /// NUL) with `scale` steps per unit (per radian for angles).
    pub fn new(name: &str, unit: JointUnit, zero_offset_steps: i32, scale: f64) -> Option<Self> {
        let bytes = name.as_bytes();
        if bytes.len() > NAME_LEN || bytes.contains(&0) {
            return None;
        }
        let mut name_bytes = [0u8; NAME_LEN];
        name_bytes
            .iter_mut()
            .zip(bytes)
            .for_each(|(slot, b)| *slot = *b);
        Some(JointDesc {
            name_bytes,
            unit,
            zero_offset_steps,
            scale_bits: scale.to_bits(),
        })
    }

    /// The name ("" when none, or when the bytes are not a valid name).
    pub fn name(&self) -> &str {
        let end = self
            .name_bytes
            .iter()
            .position(|b| *b == 0)
            .unwrap_or(NAME_LEN);
        self.name_bytes
            .get(..end)
            .and_then(|b| core::str::from_utf8(b).ok())
            .unwrap_or("")
    }

    /// The scale: steps per radian (deg, rad), per mm (mm) or per step; 0.0: none.
    pub fn scale(&self) -> f64 {
        f64::from_bits(self.scale_bits)
    }

    /// Whether the joint is described at all (a scale given).
    pub fn is_described(&self) -> bool {
        self.scale_bits != 0
    }

    /// Whether a controller may keep it: a UTF-8 name without NUL, zeros after it, and a
    /// finite scale other than -0.0 (0 clears the description).
    pub fn is_valid(&self) -> bool {
        let end = self
            .name_bytes
            .iter()
            .position(|b| *b == 0)
            .unwrap_or(NAME_LEN);
        let (name, rest) = self.name_bytes.split_at(end);
        core::str::from_utf8(name).is_ok()
            && rest.iter().all(|b| *b == 0)
            && self.scale().is_finite()
            && self.scale_bits != (-0.0f64).to_bits()
    }

    pub(crate) fn read(b: &[u8], at: usize) -> Option<JointDesc> {
        let mut name_bytes = [0u8; NAME_LEN];
        for (i, slot) in name_bytes.iter_mut().enumerate() {
            *slot = u8_at(b, at + i);
        }
        Some(JointDesc {
            name_bytes,
            unit: JointUnit::from_u8(u8_at(b, at + NAME_LEN))?,
            zero_offset_steps: i32_le(b, at + 20),
            scale_bits: u64_le(b, at + 24),
        })
    }

    pub(crate) fn write(&self, w: &mut Writer<'_>, at: usize) {
        w.put(at, &self.name_bytes);
        w.put(at + NAME_LEN, &[self.unit as u8, 0, 0, 0]);
        w.u32(at + 20, self.zero_offset_steps as u32);
        w.put(at + 24, &self.scale_bits.to_le_bytes());
    }
}

/// JOINT_DESC_SET's data, and the JOINT_DESC report's: a joint and its description.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct JointDescSet {
    /// The joint, 0-7.
    pub joint: u8,
    /// Its description.
    pub desc: JointDesc,
}

impl JointDescSet {
    /// Decodes the 36 bytes; None for a joint over 7, an unknown unit or an invalid
    /// description.
    pub(crate) fn read(b: &[u8]) -> Option<JointDescSet> {
        let joint = u8_at(b, 0);
        let desc = JointDesc::read(b, 4)?;
        (usize::from(joint) < crate::MAX_JOINTS && desc.is_valid())
            .then_some(JointDescSet { joint, desc })
    }

    pub(crate) fn write(&self, w: &mut Writer<'_>, at: usize) {
        w.put(at, &[self.joint, 0, 0, 0]);
        self.desc.write(w, at + 4);
    }
}
