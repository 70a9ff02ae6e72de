//! The arm description the controller keeps (issue 31: JOINT_DESC), from Python: one
//! joint's description as a dict, a changed one from `set_joint_description`'s keywords,
//! and `push_config`'s report (armctl::push, the same reading and sending as `armctl
//! config push`).

use std::ffi::CString;

use armctl::push::{PushError, Pushed};
use protocol::{JointDesc, JointUnit};
use pyo3::exceptions::{PyUserWarning, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::errors::to_py_err_said;

/// `{"name", "unit", "zero_offset", "scale", "described"}` of one joint.
pub(crate) fn desc_dict<'py>(py: Python<'py>, d: &JointDesc) -> PyResult<Bound<'py, PyDict>> {
    let dict = PyDict::new(py);
    set_items!(dict, {
        "name" => d.name(),
        "unit" => d.unit.name(),
        "zero_offset" => d.zero_offset_steps,
        "scale" => d.scale(),
        "described" => d.is_described(),
    });
    Ok(dict)
}

/// `old` with the arguments given changed; a clear ValueError for a unit that is none of
/// steps, deg, rad, mm, a name over 16 bytes, or a scale that is not a finite number.
pub(crate) fn changed(
    joint: u8,
    old: &JointDesc,
    name: Option<&str>,
    unit: Option<&str>,
    zero_offset: Option<i32>,
    scale: Option<f64>,
) -> PyResult<JointDesc> {
    let unit = match unit {
        None => old.unit,
        Some(u) => JointUnit::from_name(u).ok_or_else(|| {
            PyValueError::new_err(format!("joint {joint}: unit {u:?}: steps, deg, rad or mm"))
        })?,
    };
    let name = name.unwrap_or(old.name());
    let scale = scale.unwrap_or(old.scale());
    JointDesc::new(
        name,
        unit,
        zero_offset.unwrap_or(old.zero_offset_steps),
        scale,
    )
    .filter(JointDesc::is_valid)
    .ok_or_else(|| {
        PyValueError::new_err(format!(
            "joint {joint}: name {name:?} over {} bytes (or with a NUL), or scale {scale} not \
             a finite number",
            protocol::JOINT_NAME_LEN
        ))
    })
}

/// A push's report to Python: the lines kept (returned), each warning as a UserWarning,
/// and a refusal as the armctl error it is, its message naming the joint.
pub(crate) fn push_result(
    py: Python<'_>,
    said: Vec<Pushed>,
    result: Result<(), PushError>,
) -> PyResult<Vec<String>> {
    let mut kept = Vec::new();
    for s in said {
        match s {
            Pushed::Kept(line) => kept.push(line),
            Pushed::Warning(line) => {
                let message = CString::new(line.replace('\0', " "))
                    .map_err(|e| PyValueError::new_err(e.to_string()))?;
                PyErr::warn(py, &py.get_type::<PyUserWarning>(), &message, 1)?;
            }
        }
    }
    match result {
        Ok(()) => Ok(kept),
        Err(e) => {
            let message = e.to_string();
            Err(to_py_err_said(py, e.error, message))
        }
    }
}
