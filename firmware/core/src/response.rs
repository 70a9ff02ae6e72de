//! What [`crate::Controller::handle`] returns: the ACK ([`Reply`]), reports, and the
//! work left to the caller ([`Deferred`]), all in one [`Response`].

use protocol::{
    Ack, DiscoverReply, JointDescSet, LimitsReport, Location, StatusReport, StopReport,
};

use crate::hw::{Endpoint, PersistentSettings};
#[cfg(doc)]
use crate::reports::ReportSettings;

/// Work that needs waiting, left to the caller (the trajectory task).
// The settings (440 bytes since issue 31's joint descriptions) ride by value: no heap to
// box them in, and a Deferred is returned once per datagram and handled at once by the
// trajectory task, never queued, so the size is one stack copy, not a channel's slots.
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Deferred {
    /// Store these settings ([`crate::hw::SettingsStore::save`]).
    SaveSettings(PersistentSettings),
    /// RETURN was accepted: read the encoders ([`crate::hw::Encoders::read`]) and pass
    /// the result to [`crate::Controller::begin_return`].
    ReadEncoders,
}

/// The ACK for one command.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Reply {
    /// Where it goes: the command's sender.
    pub to: Endpoint,
    /// The command's seq.
    pub seq: u8,
    /// Content.
    pub ack: Ack,
}

/// What handling one datagram produced.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Response {
    /// The ACK; `None` only for a datagram under 3 bytes.
    pub reply: Option<Reply>,
    /// A STATUS report and where it goes: the endpoint that asked for it.
    pub status: Option<(Endpoint, StatusReport)>,
    /// A LOCATION report: the state changed (only while reports are on). It goes to
    /// [`ReportSettings::location_to`].
    pub location: Option<Location>,
    /// A LOCATION report for the asker alone: STATUS's request byte asked for one (bit 0,
    /// issue 23), whether reports are on or not.
    pub asked_location: Option<(Endpoint, Location)>,
    /// A STOP_CAUSE report for the asker alone: STATUS's request byte asked for one (bit
    /// 2, issue 31).
    pub asked_stop: Option<(Endpoint, StopReport)>,
    /// An RX_COUNTERS report for the asker alone: STATUS's request byte asked for one
    /// (bit 3, issue 30), sent after the STOP_CAUSE. The counters are the bus's: the
    /// caller fills them in.
    pub asked_counters: Option<Endpoint>,
    /// A DIAG report for the asker alone: STATUS's request byte asked for one (bit 6,
    /// issue 34), sent last. The counters are the board's ([`crate::bus::Bus::diag`]):
    /// the caller fills them in.
    pub asked_diag: Option<Endpoint>,
    /// A MOTION report for the asker alone: STATUS's request byte asked for one (bit 4,
    /// issue 32), sent last.
    pub asked_motion: Option<(Endpoint, protocol::MotionReport)>,
    /// A LIMITS report for the endpoint that sent LIMITS_GET (issue 23).
    pub limits: Option<(Endpoint, LimitsReport)>,
    /// A JOINT_DESC report for the endpoint that sent JOINT_DESC_GET (issue 31).
    pub joint_desc: Option<(Endpoint, JointDescSet)>,
    /// `Some(seq)`: [`Response::status`], [`Response::asked_location`],
    /// [`Response::asked_stop`], [`Response::asked_counters`] and [`Response::asked_diag`]
    /// are a read-only answer
    /// to a host that does not own the controller (docs/PROTOCOL.md section 1, issue 23)
    /// and carry its request's seq, not the controller's report counter.
    pub answer_seq: Option<u8>,
    /// Work left to the caller.
    pub deferred: Option<Deferred>,
    /// The command was executed: ACKed `OK` and not a duplicate. Only an executed STOPPED
    /// stops anything (the e-stop path in [`crate::tasks`] relies on it).
    pub executed: bool,
    /// The answer to a DISCOVER, for its sender (instead of an ACK).
    pub discovery: Option<Discovery>,
    /// The answer to a HELLO, for its sender (instead of an ACK), sealed in the new
    /// session.
    pub hello: Option<HelloGrant>,
}

/// A HELLO_REPLY for the host that asked (docs/PROTOCOL.md section 13).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct HelloGrant {
    /// The HELLO's sender.
    pub to: Endpoint,
    /// The HELLO's seq.
    pub seq: u8,
    /// Content.
    pub reply: protocol::auth::HelloReply,
}

/// A DISCOVER_REPLY for the host that asked (docs/PROTOCOL.md, "Finding controllers and
/// setting their address").
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Discovery {
    /// The DISCOVER's sender.
    pub to: Endpoint,
    /// The DISCOVER's seq.
    pub seq: u8,
    /// Content.
    pub reply: DiscoverReply,
}
