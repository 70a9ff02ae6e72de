//! STATUS, LOCATION, progress and run reports as Python dicts.

use armctl::{Progress, RunReport};
use numpy::PyArray1;
use protocol::{Location, MAX_JOINTS, State, StatusFlags, StatusReport};
use pyo3::prelude::*;
use pyo3::types::PyDict;

/// STATUS as a dict.
pub(crate) fn status_dict<'py>(py: Python<'py>, s: &StatusReport) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    set_items!(d, {
        "version" => (s.version[0], s.version[1], s.version[2]),
        "joints" => s.joints,
        "state" => s.state.name(),
    });
    let flags = PyDict::new(py);
    for (name, bit) in [
        ("reports_on", StatusFlags::REPORTS_ON),
        ("drivers_enabled", StatusFlags::DRIVERS_ENABLED),
        ("serial_open", StatusFlags::SERIAL_OPEN),
        ("pin0_high", StatusFlags::PIN0_HIGH),
        ("pin1_high", StatusFlags::PIN1_HIGH),
        ("underrun", StatusFlags::UNDERRUN),
        ("pwm_active", StatusFlags::PWM_ACTIVE),
        ("stopped_by_host", StatusFlags::STOPPED_BY_HOST),
    ] {
        flags.set_item(name, s.flags.has(bit))?;
    }
    set_items!(d, {
        "flags" => flags,
        "buffered" => s.buffered,
        "expected" => s.expected,
        "received" => s.received,
        "executed" => s.executed,
        "capacity" => s.capacity,
        "upload_period_us" => s.upload_period_us,
        "pwm_timer_clock_hz" => s.pwm_timer_clock_hz,
        "max_step_rate_hz" => s.max_step_rate_hz,
        // Issue 23: the package's STATUS lacked these three.
        "window" => s.window,
        "step_budget_hz" => s.step_budget_hz,
    });
    let more = PyDict::new(py);
    for (name, bit) in [
        ("upload_dropped", protocol::MoreFlags::UPLOAD_DROPPED),
        ("estop_open", protocol::MoreFlags::ESTOP_OPEN),
        ("estop_latched", protocol::MoreFlags::ESTOP_LATCHED),
    ] {
        more.set_item(name, s.more_flags.has(bit))?;
    }
    d.set_item("more_flags", more)?;
    // What ended the last run (issue 31, more_flags bits 5-7): "COMPLETE", "STOPPED",
    // "ESTOP_INPUT", "UNDERRUN", "FAULT", ...; None from an older controller (then only
    // flags "underrun" and "stopped_by_host" tell). `Arm.status()` fills `stopped_by`.
    match s.stop_cause() {
        Some(cause) => d.set_item("stop_cause", cause.name())?,
        None => d.set_item("stop_cause", py.None())?,
    }
    d.set_item("stopped_by", py.None())?;
    // Each driver's ENABLE (issue 23, STATUS more_flags bits 3, 4, 8-15); None from a
    // controller that does not report them.
    match s.drivers_enabled() {
        Some(mask) => {
            let enabled = PyDict::new(py);
            let joints: Vec<bool> = (0..usize::from(s.joints).min(MAX_JOINTS))
                .map(|j| mask & (1 << j) != 0)
                .collect();
            enabled.set_item("joints", joints)?;
            enabled.set_item("gripper", mask & 0x100 != 0)?;
            d.set_item("enabled", enabled)?;
        }
        None => d.set_item("enabled", py.None())?,
    }
    Ok(d)
}

pub(crate) fn state_name(code: u8) -> &'static str {
    State::name_of(code)
}

/// A LOCATION report as a dict: `positions` (int32 array, steps) and `state`.
pub(crate) fn location_dict<'py>(
    py: Python<'py>,
    location: &Location,
    joints: usize,
) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item(
        "positions",
        PyArray1::from_slice(py, &location.position[..joints.clamp(1, MAX_JOINTS)]),
    )?;
    d.set_item("state", state_name(location.state))?;
    Ok(d)
}

pub(crate) fn progress_dict<'py>(
    py: Python<'py>,
    p: &Progress,
    done: bool,
) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    set_items!(d, {
        "total" => p.total,
        "sent" => p.sent,
        "acked" => p.acked,
        "executed" => p.executed,
        "state" => p.state.name(),
        "done" => done,
    });
    Ok(d)
}

pub(crate) fn report_dict<'py>(
    py: Python<'py>,
    r: &RunReport,
    joints: usize,
) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    set_items!(d, {
        "points" => r.points,
        "frames" => r.frames,
        "window" => r.window,
        "datagrams_sent" => r.datagrams_sent,
        "retransmissions" => r.retransmissions,
        "upload_time" => r.upload_time.as_secs_f64(),
        "total_time" => r.total_time.as_secs_f64(),
    });
    match &r.final_status {
        Some(s) => d.set_item("final_status", status_dict(py, s)?)?,
        None => d.set_item("final_status", py.None())?,
    }
    match &r.final_location {
        Some(l) => d.set_item(
            "final_positions",
            PyArray1::from_slice(py, &l.position[..joints.clamp(1, MAX_JOINTS)]),
        )?,
        None => d.set_item("final_positions", py.None())?,
    }
    Ok(d)
}
