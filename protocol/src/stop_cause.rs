//! What ended the last run (issue 31): STATUS `more_flags` bits 5-7 carry the cause, and
//! the STOP_CAUSE report (asked for with STATUS's request byte, bit 2) adds who sent the
//! STOPPED. Before it, a wired e-stop and a STOPPED from another host both read "STOPPED
//! was sent" (STATUS `flags` bit 7, which stays for old hosts).

use crate::codec::{Writer, u8_at, u16_le};

crate::codes::wire_code! {
    /// Why the last run ended (docs/PROTOCOL.md, STATUS "What ended the last run"). Byte
    /// 0 is not a cause: an older controller's `more_flags` bits 5-7 are 0, so
    /// [`crate::StatusReport::stop_cause`] gives `None` for it.
    pub enum StopCause {
        /// Nothing cut the last run short: it ran to its end, or no run has ended since
        /// boot.
        Complete = 1 => "COMPLETE",
        /// A STOPPED command (the STOP_CAUSE report names its sender).
        Stopped = 2 => "STOPPED",
        /// The wired e-stop input opened.
        EstopInput = 3 => "ESTOP_INPUT",
        /// The buffer ran dry before NEW's count of points had arrived. `detail` 1: a
        /// controlled underrun (the run slowed along what it held, within the
        /// accelerations, issue 32); 0: a dead one (stopped at the speed of its last
        /// point, as every controller before issue 32 did).
        Underrun = 4 => "UNDERRUN",
        /// The controller found a fault: RETURN's absolute encoder of joint `detail` did
        /// not answer properly (nothing moved).
        Fault = 5 => "FAULT",
        /// A limit switch tripped (issue 33): `detail` is the joint in bits 0-6, bit 7 set
        /// for its max side (the simulator; the NUCLEO built with `switch-inputs`).
        LimitSwitch = 6 => "LIMIT_SWITCH",
        /// A hold that had to stop the run (issue 32): `detail` 3 (DOOR) when the safety
        /// door opened on a step side without a time warp, which cannot hold.
        Hold = 7 => "HOLD",
    }
}

impl StopCause {
    /// What it means, for a person.
    pub const fn describe(self) -> &'static str {
        match self {
            StopCause::Complete => "the run ran to its end",
            StopCause::Stopped => "a STOPPED command",
            StopCause::EstopInput => "the wired e-stop input opened",
            StopCause::Underrun => "underrun: the buffer ran dry before the last point arrived",
            StopCause::Fault => "a fault (RETURN: an absolute encoder did not answer)",
            StopCause::LimitSwitch => "a limit switch",
            StopCause::Hold => "a hold that had to stop the run (the safety door opened)",
        }
    }
}

/// The STOP_CAUSE report (12 bytes), the answer to STATUS's request byte bit 2.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct StopReport {
    /// What ended the last run; `None`: a cause byte this crate does not know (a newer
    /// controller's).
    pub cause: Option<StopCause>,
    /// For [`StopCause::Fault`]: the joint whose encoder failed; for
    /// [`StopCause::LimitSwitch`]: the joint (bits 0-6) and the side (bit 7: max); for
    /// [`StopCause::Underrun`]: 1 controlled, 0 dead; 0 otherwise.
    pub detail: u8,
    /// For [`StopCause::Stopped`]: the sender's IPv4 address; zeros otherwise.
    pub from_ip: [u8; 4],
    /// For [`StopCause::Stopped`]: the sender's UDP port; 0 otherwise.
    pub from_port: u16,
}

impl Default for StopReport {
    fn default() -> Self {
        Self::COMPLETE
    }
}

impl StopReport {
    /// Nothing cut the last run short (the boot value).
    pub const COMPLETE: StopReport = StopReport::of(StopCause::Complete);

    /// `cause` with no detail and no sender.
    pub const fn of(cause: StopCause) -> StopReport {
        StopReport {
            cause: Some(cause),
            detail: 0,
            from_ip: [0; 4],
            from_port: 0,
        }
    }

    pub(crate) fn read(b: &[u8]) -> StopReport {
        StopReport {
            cause: StopCause::from_u8(u8_at(b, 0)),
            detail: u8_at(b, 1),
            from_ip: [u8_at(b, 4), u8_at(b, 5), u8_at(b, 6), u8_at(b, 7)],
            from_port: u16_le(b, 8),
        }
    }

    pub(crate) fn write(&self, w: &mut Writer<'_>, at: usize) {
        w.u8(at, self.cause.map_or(0, |c| c as u8));
        w.u8(at + 1, self.detail);
        w.put(at + 4, &self.from_ip);
        w.u16(at + 8, self.from_port);
    }
}
