//! Everything that can go wrong talking to a controller, each with a message that says what
//! to do about it.

use std::fmt;
use std::time::Duration;

use protocol::{EncodeError, State, StatusCode, Tag};

/// The result type of this crate.
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// Why an operation on the controller failed.
#[derive(Debug)]
pub enum Error {
    /// The socket failed (bind, send, receive).
    Io(std::io::Error),
    /// The controller answered with a status other than OK: the command did nothing.
    Refused {
        /// The command refused.
        command: Tag,
        /// Why.
        status: StatusCode,
        /// The controller's state when it refused.
        state: State,
    },
    /// No ACK came back after every retry.
    NoReply {
        /// The command that got no answer.
        command: Tag,
        /// Times it was sent.
        attempts: u32,
        /// Time spent waiting in all.
        waited: Duration,
        /// Where the frames went.
        to: std::net::SocketAddr,
    },
    /// Nothing listens on the controller's port (the system answered "port unreachable"
    /// on loopback): the controller or simulator is not running there.
    ConnectionRefused {
        /// The address tried.
        addr: std::net::SocketAddr,
    },
    /// The ACK came, but the report it asks for (STATUS) did not.
    NoReport {
        /// The command whose report is missing.
        command: Tag,
        /// Times it was asked for.
        attempts: u32,
    },
    /// No LOCATION report came in time.
    NoLocation {
        /// How long it waited.
        waited: Duration,
    },
    /// A command could not be encoded (an empty or oversized point list or serial chunk).
    Encode(EncodeError),
    /// A run ended before all its points were executed.
    RunEnded {
        /// Why it ended.
        reason: RunEnd,
        /// Points executed (from STATUS), if known.
        executed: Option<u16>,
        /// Points the controller received (from STATUS), if known: more than `executed`
        /// means points were still waiting in its buffer when it stopped.
        received: Option<u16>,
        /// Points in the trajectory.
        total: usize,
        /// For [`RunEnd::Stopped`]: who sent the STOPPED, if the controller said (issue 31:
        /// the STOP_CAUSE report; `None` from an older controller).
        stopped_by: Option<std::net::SocketAddrV4>,
        /// For [`RunEnd::Underrun`]: the controller slowed the run along what it held,
        /// within the accelerations, and stopped at the last point it had (issue 32:
        /// STOP_CAUSE detail 1); `false`: a dead stop at speed, or an older controller.
        controlled: bool,
        /// For [`RunEnd::LimitSwitch`]: the joint and whether its max-side switch tripped
        /// (`false`: the min side), if the controller said (the STOP_CAUSE report).
        limit_switch: Option<(u8, bool)>,
    },
    /// An upload made no progress for too long (every ACK lost, or the buffer never drained).
    Stalled {
        /// Points acknowledged so far.
        acked: usize,
        /// Points in the trajectory.
        total: usize,
        /// How long it went without progress.
        waited: Duration,
    },
    /// A trajectory the controller cannot take (too many points, none at all).
    InvalidTrajectory(String),
    /// Authentication failed (docs/PROTOCOL.md section 13): no key set on the
    /// controller, another key, or no key given.
    Auth(String),
    /// A homing cycle on the switches failed (issue 33): the SWITCHES report names the
    /// joint and why.
    HomingFailed(protocol::SwitchesReport),
    /// A homing cycle did not end within the time given.
    HomingTimedOut {
        /// How long it waited.
        waited: Duration,
    },
    /// The call's [`Cancel`](crate::Cancel) token was set (Ctrl-C in the tool): it returned
    /// without finishing, and sent no STOPPED. What it started may still run: stop it with
    /// [`Client::stop_until_acked`](crate::Client::stop_until_acked).
    Interrupted,
}

/// Why a run ended early.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RunEnd {
    /// Someone sent STOPPED (this host or any other; `stopped_by` says who when the
    /// controller tells), or, from a controller older than issue 31, the wired e-stop
    /// input opened.
    Stopped,
    /// The wired e-stop input opened (issue 31: a controller that tells it apart).
    EstopInput,
    /// The controller found a fault (RETURN's encoder read).
    Fault,
    /// The buffer ran dry before every point had arrived: every point received had run
    /// (STATUS `received` = `executed` < total), so the upload came too slowly.
    Underrun,
    /// The controller reported an underrun although points it had received were not run
    /// (`received` > `executed`), or every point had arrived: it fell behind feeding its
    /// own step engine (a controller fault, not the upload's).
    Starved,
    /// A limit switch tripped (issue 33): the joint stopped at once and is latched until
    /// UNLOCK.
    LimitSwitch,
    /// The controller left the upload for a reason it did not say.
    Unknown,
}

impl RunEnd {
    /// The reason as one lower-case word (`stopped`, `estop_input`, `fault`, `underrun`,
    /// `starved`, `limit_switch`, `unknown`): what
    /// the Python package's `RunEndedError.reason` says.
    pub fn name(self) -> &'static str {
        match self {
            RunEnd::Stopped => "stopped",
            RunEnd::EstopInput => "estop_input",
            RunEnd::Fault => "fault",
            RunEnd::Underrun => "underrun",
            RunEnd::Starved => "starved",
            RunEnd::LimitSwitch => "limit_switch",
            RunEnd::Unknown => "unknown",
        }
    }
}

impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Error::Io(e) => write!(f, "network error: {e}"),
            // NOT_OWNER's state is 0 whatever the arm does (a stranger learns nothing):
            // no state is shown for it (issue 21 F10: "controller state NEW" misled).
            // So do the refusals of a keyed controller to a host without the key.
            Error::Refused {
                command,
                status:
                    status @ (StatusCode::NotOwner | StatusCode::AuthRequired | StatusCode::AuthFailed),
                ..
            } => write!(
                f,
                "{} refused with {}: {}",
                command.name(),
                status.name(),
                status.advice()
            ),
            Error::Refused {
                command,
                status,
                state,
            } => write!(
                f,
                "{} refused with {} (controller state {}): {}",
                command.name(),
                status.name(),
                state.name(),
                invalid_config_advice(*command, *status).unwrap_or(status.advice())
            ),
            Error::NoReply {
                command,
                attempts,
                waited,
                to,
            } => write!(
                f,
                "no ACK for {} after {attempts} attempts in {:.1} s: is the controller on and \
                 reachable at {}, and is port {} right (controllers listen on {} unless \
                 configured otherwise)?",
                command.name(),
                waited.as_secs_f64(),
                to.ip(),
                to.port(),
                crate::DEFAULT_PORT
            ),
            Error::ConnectionRefused { addr } => write!(
                f,
                "nothing listens on {addr} (connection refused): start the controller \
                 (`cargo sim`), or check the port (controllers listen on {} unless \
                 configured otherwise)",
                crate::DEFAULT_PORT
            ),
            Error::NoReport { command, attempts } => write!(
                f,
                "{} was ACKed but its report never came ({attempts} attempts): another host may \
                 own the controller (reports go to the owner), or reports are being lost",
                command.name()
            ),
            Error::NoLocation { waited } => write!(
                f,
                "no LOCATION report in {:.1} s: reports may be off (`armctl reports on`), \
                 another host owns the controller (reports go to the owner), or another \
                 tool on this machine claimed them since",
                waited.as_secs_f64()
            ),
            Error::Encode(e) => write!(f, "cannot encode the frame: {e}"),
            Error::RunEnded {
                reason,
                executed,
                received,
                total,
                stopped_by,
                controlled,
                limit_switch,
            } => {
                let by;
                let why = match (reason, stopped_by) {
                    (RunEnd::Stopped, Some(from)) => {
                        by = format!("STOPPED was sent by {from}");
                        by.as_str()
                    }
                    (RunEnd::Stopped, None) => {
                        "STOPPED was sent (by this host or another), or the wired e-stop \
                         input opened (the controller does not say which)"
                    }
                    (RunEnd::EstopInput, _) => {
                        "the wired e-stop input opened (close it, then `armctl estop-reset`)"
                    }
                    (RunEnd::Fault, _) => "the controller found a fault",
                    (RunEnd::LimitSwitch, _) => {
                        by = match limit_switch {
                            Some((joint, max)) => format!(
                                "the {} limit switch of joint {joint} tripped (the joint is \
                                 latched: `armctl unlock`, then move it off the switch)",
                                if *max { "max" } else { "min" }
                            ),
                            None => "a limit switch tripped (the joint is latched: `armctl \
                                     unlock`, then move it off the switch)"
                                .to_string(),
                        };
                        by.as_str()
                    }
                    (RunEnd::Underrun, _) if *controlled => {
                        "the trajectory buffer was running dry before every point had \
                         arrived (controlled underrun: the controller slowed along what it \
                         held, within the accelerations, and stopped on the last point it \
                         had): the upload was too slow; use a larger window, longer \
                         segments, or let RUNING wait for a full buffer (no --start-after)"
                    }
                    (RunEnd::Underrun, _) => {
                        "the trajectory buffer ran dry before every point had arrived \
                         (underrun; every point received had run): the upload was too slow; \
                         use a larger window, longer segments, or let RUNING wait for a \
                         full buffer (no --start-after)"
                    }
                    (RunEnd::Starved, _) => {
                        "the controller reported an underrun although it had points left \
                         to run: it fell behind feeding its step engine (a controller \
                         fault, not the upload's; on the simulator, a loaded machine or a \
                         high --time-scale)"
                    }
                    (RunEnd::Unknown, _) => "the controller left the upload",
                };
                match (executed, received) {
                    (Some(n), Some(r)) => write!(
                        f,
                        "run ended after {n} of {total} points ({r} received, {} not run): {why}",
                        r.saturating_sub(*n)
                    ),
                    (Some(n), None) => write!(f, "run ended after {n} of {total} points: {why}"),
                    _ => write!(f, "run ended before its {total} points: {why}"),
                }
            }
            Error::Stalled {
                acked,
                total,
                waited,
            } => write!(
                f,
                "upload stalled at {acked} of {total} points: no progress for {:.1} s \
                 (ACKs lost, or the buffer never drained)",
                waited.as_secs_f64()
            ),
            Error::InvalidTrajectory(why) => write!(f, "invalid trajectory: {why}"),
            Error::Auth(why) => write!(f, "authentication: {why}"),
            Error::HomingFailed(report) => write!(
                f,
                "homing failed on joint {}: {}",
                report.joint,
                report
                    .error
                    .map_or("the controller did not say why", |e| e.text())
            ),
            Error::HomingTimedOut { waited } => write!(
                f,
                "homing did not end in {:.1} s (`armctl stop` stops it)",
                waited.as_secs_f64()
            ),
            Error::Interrupted => write!(
                f,
                "interrupted before the end (cancelled); what was started may still run \
                 until STOPPED is sent"
            ),
        }
    }
}

impl std::error::Error for Error {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            Error::Io(e) => Some(e),
            Error::Encode(e) => Some(e),
            _ => None,
        }
    }
}

impl From<std::io::Error> for Error {
    fn from(e: std::io::Error) -> Self {
        Error::Io(e)
    }
}

impl From<EncodeError> for Error {
    fn from(e: EncodeError) -> Self {
        Error::Encode(e)
    }
}

impl Error {
    /// The refusal status, when the controller refused the command.
    pub fn status(&self) -> Option<StatusCode> {
        match self {
            Error::Refused { status, .. } => Some(*status),
            _ => None,
        }
    }
}

/// For INVALID_CONFIG, which field of the refused command is out of which range
/// (docs/PROTOCOL.md; issue 23: the message named neither).
fn invalid_config_advice(command: Tag, status: StatusCode) -> Option<&'static str> {
    if status != StatusCode::InvalidConfig {
        return None;
    }
    Some(match command {
        Tag::PwmStart => {
            "PSC and ARR must fit 16 bits (0..65535) and CCR1 must not exceed ARR; the output \
             frequency is pwm_timer_clock_hz / ((PSC + 1)(ARR + 1))"
        }
        Tag::UsartStart => {
            "BaudRate must be 300..4000000, WordLength 0 or 0x1000, StopBits 0 or 0x2000, \
             Parity 0, 0x400 or 0x600, HwFlowCtl 0, OverSampling 0 or 0x8000"
        }
        Tag::UploadPeriod => "the period must be 1000..1000000 microseconds",
        Tag::JointsCount => "the joint count must be 1..8",
        Tag::New => "the point count must be 1..65535",
        Tag::ToggleEnablePins | Tag::SetEnable => {
            "the mask may only use bits 0-8 (joints 0-7, gripper 8) and the action must be \
             enable or disable"
        }
        Tag::NetSet => {
            "a unicast address (not 0.x, 127.x, 224-255.x, nor the subnet's network or \
             broadcast address) with a prefix of 1..32 and a gateway inside the subnet, or DHCP"
        }
        _ => return None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Issue 23: INVALID_CONFIG named neither the field nor its range.
    #[test]
    fn invalid_config_names_the_field_and_its_range() {
        let message = |command| {
            Error::Refused {
                command,
                status: StatusCode::InvalidConfig,
                state: State::Stopped,
            }
            .to_string()
        };
        assert!(message(Tag::PwmStart).contains("CCR1 must not exceed ARR"));
        assert!(message(Tag::UsartStart).contains("BaudRate must be 300..4000000"));
        assert!(message(Tag::UploadPeriod).contains("1000..1000000 microseconds"));
        assert!(message(Tag::JointsCount).contains("1..8"));
    }

    /// Issue 21 F10: a NOT_OWNER ACK's state is 0 (a stranger learns nothing), which armctl
    /// printed as "controller state NEW" whatever the arm was doing.
    #[test]
    fn not_owner_shows_no_state_and_other_refusals_do() {
        let not_owner = Error::Refused {
            command: Tag::Runing,
            status: StatusCode::NotOwner,
            state: State::New,
        }
        .to_string();
        assert!(
            not_owner.starts_with("RUNING refused with NOT_OWNER: "),
            "{not_owner}"
        );
        assert!(!not_owner.contains("NEW"), "{not_owner}");
        let bad_state = Error::Refused {
            command: Tag::Runing,
            status: StatusCode::BadState,
            state: State::Running,
        }
        .to_string();
        assert!(
            bad_state.starts_with("RUNING refused with BAD_STATE (controller state RUNNING)"),
            "{bad_state}"
        );
    }
}
