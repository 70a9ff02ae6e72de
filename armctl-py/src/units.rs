//! Units for Python (issue 31): what `run`'s arrays are in, and how `positions` and
//! `home` show positions, following the joint config's `units` as the `armctl` tool does
//! (`run`, `watch`, `home`), with a `units=` override.

use std::path::PathBuf;

use armctl::motion::Units;
use armctl::trajectory::ArmConfig;
use numpy::PyArray1;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use crate::errors::{TrajectoryError, trajectory_err};

/// What `run`'s arrays are in (issue 31: a config's `"units": "deg"` was read as radians):
/// `units=`, else the config's `units` when its file states them, else radians with a
/// config (Python's rule from before configs had units, a JointTrajectory's) and steps
/// without. Degrees and radians without a config are a ValueError.
pub(crate) fn array_units(
    py: Python<'_>,
    units: Option<Units>,
    path: Option<&std::path::Path>,
    config: Option<&ArmConfig>,
) -> PyResult<Units> {
    let (Some(path), Some(config)) = (path, config) else {
        return match units {
            Some(u) if u != Units::Steps => Err(PyValueError::new_err(format!(
                "units {:?} need a joint config (config=PATH)",
                u.name()
            ))),
            _ => Ok(Units::Steps),
        };
    };
    if let Some(units) = units {
        return Ok(units);
    }
    // ArmConfig reads a missing `units` as steps; whether the file says so is asked of
    // Python's json (the file was just parsed, so it is valid JSON).
    let text = std::fs::read_to_string(path)
        .map_err(|e| TrajectoryError::new_err(format!("{}: cannot read: {e}", path.display())))?;
    let stated = py
        .import("json")?
        .call_method1("loads", (text,))?
        .contains("units")?;
    Ok(if stated { config.units } else { Units::Rad })
}

/// How `positions` and `home` show positions, as `armctl watch` and `home` take
/// `--config` and `--units`: `None` for steps; else the config and its units (or
/// `units=`). Degrees and radians without a config are a ValueError.
pub(crate) fn shown_in(
    config: Option<PathBuf>,
    units: Option<String>,
) -> PyResult<Option<(ArmConfig, Units)>> {
    let config = config
        .map(|p| ArmConfig::load(&p))
        .transpose()
        .map_err(trajectory_err)?;
    let units = parse_units(units)?
        .or(config.as_ref().map(|c| c.units))
        .unwrap_or_default();
    match (config, units) {
        (_, Units::Steps) => Ok(None),
        (Some(config), units) => Ok(Some((config, units))),
        (None, units) => Err(PyValueError::new_err(format!(
            "units {:?} need a joint config (config=PATH)",
            units.name()
        ))),
    }
}

/// Positions as numpy: int32 steps, or float64 in the units of `shown` (a joint the
/// config leaves out stays in steps).
pub(crate) fn positions_array<'py>(
    py: Python<'py>,
    position: &[i32],
    shown: Option<&(ArmConfig, Units)>,
) -> Bound<'py, PyAny> {
    match shown {
        None => PyArray1::from_slice(py, position).into_any(),
        Some((config, units)) => {
            let values: Vec<f64> = position
                .iter()
                .enumerate()
                .map(|(j, &s)| {
                    config
                        .joints
                        .get(j)
                        .map_or(f64::from(s), |jc| units.from_steps(i64::from(s), jc))
                })
                .collect();
            PyArray1::from_vec(py, values).into_any()
        }
    }
}

/// `units="deg"` and the like as [`Units`]; a ValueError names the accepted ones.
pub(crate) fn parse_units(units: Option<String>) -> PyResult<Option<Units>> {
    units
        .map(|u| u.parse())
        .transpose()
        .map_err(PyValueError::new_err)
}
