//! The module's exceptions, and the armctl errors as them (fields as attributes).

use armctl::motion::Units;
use armctl::trajectory::{ArmConfig, ErrorKind};
use armctl::{Error, trajectory};
use pyo3::create_exception;
use pyo3::exceptions::PyException;
use pyo3::prelude::*;

create_exception!(
    armctl,
    ArmctlError,
    PyException,
    "Base class of every error of the armctl module."
);
create_exception!(
    armctl,
    RefusedError,
    ArmctlError,
    "The controller refused a command: `.status` is the status name (e.g. 'BAD_STATE'), `.command` the command, `.state` the controller's state."
);
create_exception!(
    armctl,
    NoReplyError,
    ArmctlError,
    "The controller did not answer: no ACK or report after every retry."
);
create_exception!(
    armctl,
    RunEndedError,
    ArmctlError,
    "A run ended before every point ran: `.reason` is 'stopped', 'estop_input', 'fault', 'underrun', 'starved', 'limit_switch' or 'unknown'; `.limit_switch` (joint, 'max' or 'min') for a limit switch's cut; `.stopped_by` the STOPPED's sender ('127.0.0.2:40001') if the controller said; `.executed` and `.total` count points."
);
create_exception!(
    armctl,
    StalledError,
    ArmctlError,
    "An upload or a run made no progress for too long."
);
create_exception!(
    armctl,
    TrajectoryError,
    ArmctlError,
    "A trajectory the controller cannot take: bad shape, a joint limit, a step rate, a file that does not parse."
);

/// The Python exception for an armctl error, with its fields as attributes.
pub(crate) fn to_py_err(py: Python<'_>, error: Error) -> PyErr {
    let message = error.to_string();
    to_py_err_said(py, error, message)
}

/// As [`to_py_err`], its message `message` (the error with what it happened to, e.g. the
/// joint of a push).
pub(crate) fn to_py_err_said(py: Python<'_>, error: Error, message: String) -> PyErr {
    match error {
        Error::Refused {
            command,
            status,
            state,
        } => {
            let err = RefusedError::new_err(message);
            let value = err.value(py);
            let _ = value.setattr("status", status.name());
            let _ = value.setattr("command", command.name());
            let _ = value.setattr("state", state.name());
            err
        }
        // A closed port on loopback is refused at once (nothing listens there): to Python
        // that is the same "nothing answers" as a timeout.
        Error::NoReply { .. }
        | Error::ConnectionRefused { .. }
        | Error::NoReport { .. }
        | Error::NoLocation { .. } => NoReplyError::new_err(message),
        Error::RunEnded {
            reason,
            executed,
            received,
            total,
            stopped_by,
            controlled,
            limit_switch,
        } => {
            let err = RunEndedError::new_err(message);
            let value = err.value(py);
            let _ = value.setattr("reason", reason.name());
            let _ = value.setattr("executed", executed);
            let _ = value.setattr("received", received);
            let _ = value.setattr("total", total);
            // Who sent the STOPPED ("127.0.0.2:40001"), if the controller said (issue 31).
            let _ = value.setattr("stopped_by", stopped_by.map(|a| a.to_string()));
            // A controlled underrun (issue 32): slowed along what was held, then stopped.
            let _ = value.setattr("controlled", controlled);
            // A limit switch's cut (issue 33): (joint, "max" or "min"), if the controller said.
            let _ = value.setattr(
                "limit_switch",
                limit_switch.map(|(joint, max)| (joint, if max { "max" } else { "min" })),
            );
            err
        }
        Error::Stalled { .. } => StalledError::new_err(message),
        Error::InvalidTrajectory(_) => TrajectoryError::new_err(message),
        // A run thread whose wait a KeyboardInterrupt ended (the arm was stopped then); an
        // authentication failure (no key on the controller, another key).
        Error::Io(_)
        | Error::Encode(_)
        | Error::Interrupted
        | Error::Auth(_)
        | Error::HomingFailed(_)
        | Error::HomingTimedOut { .. } => ArmctlError::new_err(message),
    }
}

pub(crate) fn trajectory_err(e: trajectory::TrajectoryError) -> PyErr {
    TrajectoryError::new_err(e.to_string())
}

/// A trajectory refused with a joint config (issue 31): the joint named as the config
/// names it, and a position out of range given in `units` too (the error speaks steps).
pub(crate) fn trajectory_err_in(
    e: trajectory::TrajectoryError,
    config: &ArmConfig,
    units: Units,
) -> PyErr {
    let joint = e.joint.and_then(|j| config.joints.get(j));
    let in_units = match (&e.kind, joint) {
        (ErrorKind::BelowMin { value, limit } | ErrorKind::AboveMax { value, limit }, Some(j))
            if units != Units::Steps =>
        {
            format!(
                " ({} against a limit of {})",
                units.show(*value, j),
                units.show(i64::from(*limit), j)
            )
        }
        (ErrorKind::StartMismatch { current, start }, Some(j)) if units != Units::Steps => {
            format!(
                " (starts at {}, the arm is at {})",
                units.show(*start, j),
                units.show(i64::from(*current), j)
            )
        }
        _ => String::new(),
    };
    TrajectoryError::new_err(format!("{}{in_units}", e.with_joint_names(config)))
}
