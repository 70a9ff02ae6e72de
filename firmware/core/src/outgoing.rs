//! Frames the controller sends, and their encoding with the controller's own report seq.

use heapless::Vec;
use protocol::{LimitsReport, Location, MAX_SERIAL_CHUNK, Report, StatusReport, StopReport, size};

use crate::hw::Endpoint;
use crate::reports::{LOCATION_LISTENERS, ReportSettings};
use crate::response::{Discovery, HelloGrant, Reply};

/// Where one encoded frame goes.
pub type Destinations = Vec<Endpoint, LOCATION_LISTENERS>;

/// Largest frame the controller sends: USART_RECV (257 data bytes) + seq, tag and CRC.
pub const MAX_REPORT_FRAME: usize = size::USART_RECV + protocol::FRAME_OVERHEAD;

// The LIMITS report (issue 23), with the accelerations too (issue 31), fits the buffer
// sized for USART_RECV.
const _: () = assert!(size::LIMITS_WITH_ACCEL + protocol::FRAME_OVERHEAD <= MAX_REPORT_FRAME);
const _: () = assert!(size::JOINT_DESC_SET + protocol::FRAME_OVERHEAD <= MAX_REPORT_FRAME);

/// Largest sealed frame: the largest report in an envelope.
pub const MAX_SEALED_FRAME: usize = MAX_REPORT_FRAME + protocol::auth::ENVELOPE_OVERHEAD;

/// Seals frames for the endpoints holding a session (with a key set), counting the
/// controller's envelopes: one counter for every session, from 1 at boot (the epoch in
/// the MAC tells boots apart), so each session sees its counters rise.
#[derive(Clone, Debug, Default)]
pub struct Sealer {
    counter: u64,
}

/// How a frame goes to one endpoint.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Sealing {
    /// As it is: no key (as before issue 21), a DISCOVER_REPLY, or an ACK to a host
    /// without a session (a refusal: it says nothing about the arm).
    Plain,
    /// In an envelope of this many bytes, written to the sealing buffer.
    Sealed(usize),
    /// Not at all: a report, with a key set, to an endpoint without a session.
    Withheld,
}

impl Sealer {
    /// Starts counting at 1.
    pub const fn new() -> Self {
        Sealer { counter: 0 }
    }

    /// How `frame` (the encoding of `out`) goes to `to`; a sealed one is written to `buf`
    /// ([`MAX_SEALED_FRAME`] bytes).
    pub fn seal(
        &mut self,
        out: &Outgoing,
        frame: &[u8],
        to: Endpoint,
        routes: &crate::auth::SealRoutes,
        buf: &mut [u8],
    ) -> Sealing {
        let Some(key) = routes.key else {
            return Sealing::Plain;
        };
        if matches!(out, Outgoing::Discovery(_)) {
            return Sealing::Plain;
        }
        // A HELLO_REPLY goes in the session it grants: unproven (issue 30), so no route
        // has it yet, and an endpoint's earlier session may still have one.
        let session = match out {
            Outgoing::Hello(h) => Some(h.reply.session),
            _ => routes.session_of(to),
        };
        match session {
            Some(session) => {
                self.counter += 1;
                match protocol::auth::seal_with(
                    &key,
                    protocol::auth::Direction::ToHost,
                    routes.epoch,
                    session,
                    self.counter,
                    frame,
                    buf,
                ) {
                    Ok(n) => Sealing::Sealed(n),
                    Err(_) => Sealing::Withheld,
                }
            }
            None if matches!(out, Outgoing::Ack(_)) => Sealing::Plain,
            None => Sealing::Withheld,
        }
    }
}

/// One frame to send.
// Sized by USART_RECV's 255 bytes on purpose: channel slots hold the largest variant
// anyway, and there is no heap to box it in.
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Outgoing {
    /// An ACK, to the command's sender, with the command's seq.
    Ack(Reply),
    /// A LOCATION report, to [`ReportSettings::location_to`].
    Location(Location),
    /// A STATUS report, to the endpoint that asked for it.
    Status(Endpoint, StatusReport),
    /// Bytes read from the serial port, to [`ReportSettings::serial_to`].
    UsartRecv(Vec<u8, MAX_SERIAL_CHUNK>),
    /// A DISCOVER_REPLY, to the DISCOVER's sender, with its seq.
    Discovery(Discovery),
    /// A HELLO_REPLY, to the HELLO's sender, with its seq (sealed in its new session).
    Hello(HelloGrant),
    /// A STATUS or LOCATION report for one endpoint (the asker of a STATUS), with the
    /// asker's seq or the report counter.
    Answer(Answer),
}

/// A report for the endpoint that asked for it ([`Outgoing::Answer`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Answer {
    /// The asker.
    pub to: Endpoint,
    /// `Some`: the asker's own seq (a read-only answer to a host that does not own the
    /// controller: the report counter is none of its business); `None`: the report
    /// counter, as every report to the owner.
    pub seq: Option<u8>,
    /// What it gets.
    pub report: AnswerReport,
}

/// What an [`Answer`] carries.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum AnswerReport {
    /// A STATUS report.
    Status(StatusReport),
    /// A LOCATION report.
    Location(Location),
    /// A LIMITS report (the answer to LIMITS_GET).
    Limits(LimitsReport),
    /// A STOP_CAUSE report (STATUS's request byte, bit 2).
    StopCause(StopReport),
    /// An RX_COUNTERS report (STATUS's request byte bit 3, issue 30).
    RxCounters(protocol::RxCounters),
    /// A DIAG report (STATUS's request byte bit 6, issue 34).
    Diag(protocol::Diag),
    /// A JOINT_DESC report (the answer to JOINT_DESC_GET, issue 31).
    JointDesc(protocol::JointDescSet),
    /// A MOTION report (STATUS's request byte bit 4, issue 32).
    Motion(protocol::MotionReport),
}

/// Encodes [`Outgoing`] frames. Reports (everything but ACKs) carry the controller's own
/// seq: one counter for LOCATION, STATUS and USART_RECV, counted here, where they are
/// sent, so the seqs on the wire are consecutive in sending order.
#[derive(Clone, Debug, Default)]
pub struct ReportEncoder {
    next_seq: u8,
}

impl ReportEncoder {
    /// Starts counting at seq 0.
    pub const fn new() -> Self {
        ReportEncoder { next_seq: 0 }
    }

    /// The seq the next report will carry.
    pub fn next_seq(&self) -> u8 {
        self.next_seq
    }

    /// Encodes `out`, sent at `now_us`, into `buf`: returns the destinations (ACK and
    /// STATUS: their own; LOCATION and USART_RECV: as `routes` say; every one gets the same
    /// bytes) and the
    /// frame's length, or `None` when a report has nowhere to go (no owner yet; no seq is
    /// used then) or `buf` is too small.
    pub fn encode(
        &mut self,
        out: &Outgoing,
        routes: &ReportSettings,
        now_us: u64,
        buf: &mut [u8],
    ) -> Option<(Destinations, usize)> {
        let one = |to: Endpoint| {
            let mut d = Destinations::new();
            // Capacity LOCATION_LISTENERS >= 1.
            let _ = d.push(to);
            d
        };
        if let Outgoing::Discovery(d) = out {
            // Like an ACK: the asker's seq, not the report counter.
            return Some((one(d.to), d.reply.encode(d.seq, buf).ok()?));
        }
        if let Outgoing::Hello(h) = out {
            return Some((one(h.to), h.reply.encode(h.seq, buf).ok()?));
        }
        let (to, seq, report) = match out {
            Outgoing::Ack(reply) => (one(reply.to), reply.seq, Report::Ack(reply.ack)),
            Outgoing::Status(to, s) => (one(*to), self.next_seq, Report::Status(*s)),
            Outgoing::Answer(a) => (
                one(a.to),
                a.seq.unwrap_or(self.next_seq),
                match a.report {
                    AnswerReport::Status(s) => Report::Status(s),
                    AnswerReport::Location(l) => Report::Location(l),
                    AnswerReport::Limits(l) => Report::Limits(l),
                    AnswerReport::StopCause(s) => Report::StopCause(s),
                    AnswerReport::RxCounters(c) => Report::RxCounters(c),
                    AnswerReport::Diag(d) => Report::Diag(d),
                    AnswerReport::Motion(m) => Report::Motion(m),
                    AnswerReport::JointDesc(d) => Report::JointDesc(d),
                },
            ),
            Outgoing::Location(l) => {
                let to: Destinations = routes.location_destinations(now_us).collect();
                if to.is_empty() {
                    return None;
                }
                (to, self.next_seq, Report::Location(*l))
            }
            Outgoing::UsartRecv(bytes) => (
                one(routes.serial_to?),
                self.next_seq,
                Report::UsartRecv(bytes),
            ),
            Outgoing::Discovery(_) | Outgoing::Hello(_) => return None,
        };
        let n = report.encode(seq, buf).ok()?;
        let own_seq = matches!(out, Outgoing::Answer(a) if a.seq.is_some());
        if !matches!(out, Outgoing::Ack(_)) && !own_seq {
            self.next_seq = self.next_seq.wrapping_add(1);
        }
        Some((to, n))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use protocol::{Ack, Frame, State, StatusCode};

    #[test]
    fn reports_share_one_counter_and_acks_keep_their_seq() {
        let owner = Endpoint {
            ip: [127, 0, 0, 1],
            port: 7000,
        };
        let other = Endpoint {
            ip: [127, 0, 0, 2],
            port: 9,
        };
        let mut enc = ReportEncoder::new();
        let mut buf = [0u8; MAX_REPORT_FRAME];
        assert_eq!(
            enc.encode(
                &Outgoing::Location(Location::default()),
                &ReportSettings::BOOT,
                0,
                &mut buf
            ),
            None
        );
        let tool = Endpoint {
            port: 7001,
            ..owner
        };
        let routes = ReportSettings {
            location_to: [Some(owner), None, None, None],
            location_until_us: [1_000, 0, 0, 0],
            serial_to: Some(owner),
            ..ReportSettings::BOOT
        };
        let ack = Outgoing::Ack(Reply {
            to: other,
            seq: 77,
            ack: Ack {
                acked_tag: 3,
                status: StatusCode::Ok,
                state: State::Stopped,
                next_seq: 1,
                buffered: 0,
                free: 8,
            },
        });
        let outs = [
            Outgoing::Location(Location::default()),
            ack,
            Outgoing::Status(tool, StatusReport::default()),
            Outgoing::UsartRecv(Vec::from_slice(b"hi").unwrap_or_default()),
        ];
        let mut seen = std::vec::Vec::new();
        for out in &outs {
            let (to, n) = enc.encode(out, &routes, 0, &mut buf).expect("encodes");
            let to = to[0];
            let frame: Frame<Report<'_>> = Report::decode(&buf[..n]).expect("decodes");
            seen.push((to, frame.seq, frame.body.tag() as u8));
        }
        assert_eq!(
            seen,
            [
                (owner, 0, 0x13),
                (other, 77, 0x14),
                (tool, 1, 0x15),
                (owner, 2, 0x0b)
            ]
        );
    }
}
