//! What ended the last run, for a person (issue 31): STATUS `more_flags` bits 5-7 and the
//! STOP_CAUSE report, with the older flags (bits 5 and 7) for a controller that predates
//! them. `armctl status`, `watch` and `run` print it; the Python binding's `status()`
//! names the cause.

use std::net::{Ipv4Addr, SocketAddrV4};

use protocol::{StatusFlags, StatusReport, StopCause, StopReport};

/// The STOPPED's sender the report names, if the last run ended by a STOPPED and the
/// controller said who sent it.
pub fn stopped_by(stop: Option<&StopReport>) -> Option<SocketAddrV4> {
    let stop = stop?;
    (stop.cause == Some(StopCause::Stopped) && stop.from_ip != [0; 4])
        .then(|| SocketAddrV4::new(Ipv4Addr::from(stop.from_ip), stop.from_port))
}

/// One line: what ended the last run.
pub fn stop_cause_text(status: &StatusReport, stop: Option<&StopReport>) -> String {
    let Some(cause) = status.stop_cause() else {
        // An older controller: flags bits 5 and 7 only.
        return if status.flags.has(StatusFlags::UNDERRUN) {
            "underrun (the buffer ran dry)".into()
        } else if status.flags.has(StatusFlags::STOPPED_BY_HOST) {
            "a STOPPED or the wired e-stop input (this controller does not say which)".into()
        } else {
            "not cut short".into()
        };
    };
    match cause {
        StopCause::Complete => {
            "nothing cut it short (it ran to its end, or none ran since boot)".into()
        }
        StopCause::Stopped => match stopped_by(stop) {
            Some(from) => format!("a STOPPED from {from}"),
            None => "a STOPPED (the controller did not say from where)".into(),
        },
        StopCause::Fault => match stop.filter(|s| s.cause == Some(StopCause::Fault)) {
            Some(s) => format!(
                "a fault: RETURN's absolute encoder of joint {} did not answer",
                s.detail
            ),
            None => cause.describe().into(),
        },
        StopCause::LimitSwitch => match stop.filter(|s| s.cause == Some(StopCause::LimitSwitch)) {
            Some(s) => format!(
                "the {} limit switch of joint {} tripped (latched: `armctl unlock`, then \
                     move away from it)",
                if s.detail & 0x80 != 0 { "max" } else { "min" },
                s.detail & 0x7f
            ),
            None => cause.describe().into(),
        },
        StopCause::Underrun => match stop.filter(|s| s.cause == Some(StopCause::Underrun)) {
            Some(s) if s.detail == 1 => "a controlled underrun: the host was late and the \
                 controller slowed along what it held, within the accelerations, to the last \
                 point it had"
                .into(),
            Some(_) => "a dead underrun: the buffer ran dry at speed before the last point \
                 arrived (too little path held to slow down, or no ACCEL_SET limit)"
                .into(),
            None => cause.describe().into(),
        },
        StopCause::Hold => match stop.filter(|s| s.cause == Some(StopCause::Hold)) {
            Some(s) if s.detail == protocol::ControlledStop::Door as u8 => "the safety door \
                 opened and this controller's step side cannot hold a run, so it stopped it \
                 (close the door, then run again)"
                .into(),
            _ => cause.describe().into(),
        },
        _ => cause.describe().into(),
    }
}
