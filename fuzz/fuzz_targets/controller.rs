//! Drives arm-core's sans-io `Controller` with a sequence of events read from the fuzz
//! input (datagrams from three endpoints, resends, time, step progress, RETURN's encoder
//! reading, an overtaking STOPPED) against a fake plant, and checks after every event what
//! PROTOCOL.md guarantees. Nothing may panic.
//!
//! The checks, and why each holds by the protocol (docs/PROTOCOL.md):
//! * a datagram under 3 bytes gets no reply and changes nothing; any other gets exactly
//!   one ACK, to its sender, with its seq and tag; BAD_CRC exactly when the CRC is wrong;
//! * every ACK: `buffered + free == capacity`, `buffered <= capacity`, and its state,
//!   `next_seq` and `buffered` are the controller's after the command; the ACK re-encodes
//!   and decodes (state code one of the four);
//! * OK only for a CRC-valid frame that decodes, or that matches an earlier accepted one
//!   (a duplicate); a CRC-valid STOPPED, whatever its data, is always OK, executed (never
//!   a duplicate) and not remembered (issue 18);
//! * a refused frame (status not OK) changes nothing: no plant call other than feeding
//!   already-buffered points, no change of state or counters;
//! * a frame that surely is a duplicate (same sender, seq, tag and CRC as a frame executed
//!   less than 2 s ago, with fewer than `DUPLICATE_MEMORY` accepted frames since) is ACKed
//!   OK and changes nothing at all, engine pushes included;
//! * the points taken are exactly the uploader's PENDING points, in order, none skipped
//!   (only accepted commands, and commands other than PENDING refused for good, fill a gap):
//!   a PENDING is taken only from the endpoint (address and port) whose NEW started the
//!   upload, and only if every seq between the last frame taken (or the NEW) and its own
//!   was used by a frame from that endpoint ACKed OK or refused for good (another tool on the owner's address,
//!   endpoint 1, numbers its seqs on its own and must never fill the uploader's gaps);
//! * a NOT_OWNER ACK carries zeros for state, next_seq, buffered and free; a STATUS
//!   report goes to the endpoint that asked for it;
//! * an executed command was allowed in the state it arrived in (docs/PROTOCOL.md, "The
//!   trajectory state machine") and did what the table says (NEW, PENDING, RUNING,
//!   STOPPED, RETURN, JOINTS_COUNT, LOCATION_SETTING, STATUS);
//! * positions change only by segments the engine runs, or by an executed
//!   LOCATION_SETTING; LOCATION reports carry the plant's positions and the current state,
//!   and one comes with every state change while reports are on;
//! * at all times: `buffered + free == capacity`, `received <= expected`,
//!   `executed <= received`; no pulse outside RUNNING; no segment left in the engine in
//!   STOPPED or NEW; every segment has a duration >= 1 us and obeys `max_step_rate_hz`;
//! * when the engine runs dry in RUNNING the state becomes STOPPED; the underrun flag is
//!   set exactly when fewer points ran than announced; a completed upload ends exactly on
//!   its last point, a completed RETURN exactly on zero (joints in use).
#![no_main]

use std::collections::VecDeque;

use arm_core::hw::Endpoint;
use arm_core::test_support::FakePlant;
use arm_core::{Controller, ControllerConfig, Deferred, Response};
use libfuzzer_sys::arbitrary::{Result, Unstructured};
use libfuzzer_sys::fuzz_target;
use protocol::{
    Ack, Command, Frame, Location, MAX_DATAGRAM, MAX_JOINTS, Point, PointList, Pwm, Report, State,
    StatusCode, StatusFlags, StatusReport, StopCause, Tag, UartInit, crc8,
};

/// Compile-time trajectory buffer size (the run-time capacity is 1..=64, from the input).
const CAP: usize = 64;
/// How long an accepted frame is a duplicate.
const DUPLICATE_WINDOW_US: u64 = protocol::limits::DUPLICATE_WINDOW_US;
/// How many accepted frames are remembered.
const DUPLICATE_MEMORY: u64 = protocol::limits::DUPLICATE_MEMORY as u64;
/// Events per input: keeps one execution short.
const MAX_EVENTS: usize = 400;
/// Datagrams kept for the resend event.
const RESEND_MEMORY: usize = 8;
/// Serial sends the fake port queues before it reports no room (drained as time passes).
const SERIAL_ROOM: usize = 4;

/// The owner's address on two ports (two tools on one machine: reports and the ordering
/// rule must tell them apart), and a stranger.
const ENDPOINTS: [Endpoint; 3] = [
    Endpoint {
        ip: [127, 0, 0, 1],
        port: 40_000,
    },
    Endpoint {
        ip: [127, 0, 0, 1],
        port: 40_001,
    },
    Endpoint {
        ip: [127, 0, 0, 2],
        port: 40_000,
    },
];

/// Calls the controller made on the plant, counted.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct Effects {
    pushed: u64,
    stops: u32,
    starts: u32,
    pins: u32,
    enables: u32,
    gripper_calls: u32,
    serial_opens: u32,
    serial_closes: u32,
    serial_sends: u32,
    position_sets: u32,
}

impl Effects {
    /// What `plant` (arm-core's test-support fake, with its contract checks on) counted.
    fn of(plant: &FakePlant) -> Effects {
        let count = |n: usize| u32::try_from(n).unwrap_or(u32::MAX);
        Effects {
            pushed: plant.pushed,
            stops: plant.stops,
            starts: plant.starts,
            pins: count(plant.pins.len()),
            enables: count(plant.enabled.len()),
            gripper_calls: plant.gripper_calls,
            serial_opens: plant.serial_opens,
            serial_closes: plant.serial_closes,
            serial_sends: count(plant.serial_sent.len()),
            position_sets: count(plant.set_positions_calls.len()),
        }
    }
}

/// Everything a command could change that the harness can see.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Snapshot {
    effects: Effects,
    positions: [i32; MAX_JOINTS],
    running: bool,
    queued: usize,
    status: StatusReport,
    next_seq: u8,
}

impl Snapshot {
    /// Without the engine feeding (which may catch up after any command).
    fn without_feeding(mut self) -> Snapshot {
        self.effects.pushed = 0;
        self.queued = 0;
        self
    }
}

/// What identifies a frame for duplicate detection (sender, seq, tag, CRC).
type FrameKey = (Endpoint, u8, u8, u8);

/// A frame ACKed OK.
struct Accepted {
    key: FrameKey,
    at_us: u64,
    /// Whether the controller executed it: surely (no earlier match at all), surely not
    /// (surely a duplicate), or unknown.
    executed: Option<bool>,
    /// Its place among all OK replies.
    index: u64,
}

/// The upload under way, as the host side sees it.
struct UploadTrack {
    /// The endpoint whose executed NEW started it.
    uploader: Endpoint,
    /// Seq of the NEW or of the last PENDING taken.
    last_taken_seq: u8,
    /// Seqs of the uploader's frames ACKed OK since then.
    accepted: [bool; 256],
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum RunKind {
    Upload,
    Return,
}

struct Harness {
    controller: Controller<CAP>,
    plant: FakePlant,
    capacity: usize,
    now_us: u64,
    /// The host's seq counter for structured commands.
    host_seq: u8,
    /// The last ACK's next_seq.
    acked_next_seq: u8,
    /// End position of the last point the host had taken (where new points start).
    host_end: [i32; MAX_JOINTS],
    sent: VecDeque<(usize, Vec<u8>)>,
    /// OK replies of the last 2 s, oldest first.
    accepted: VecDeque<Accepted>,
    ok_replies: u64,
    /// Positions of the last point taken since the last NEW.
    last_taken: Option<[i32; MAX_JOINTS]>,
    run_kind: Option<RunKind>,
    upload: Option<UploadTrack>,
}

impl Harness {
    fn new(capacity: usize, room: usize) -> Self {
        let config = ControllerConfig {
            capacity,
            ..ControllerConfig::BOARD
        };
        Harness {
            controller: Controller::new(config),
            plant: FakePlant {
                room,
                serial_room: SERIAL_ROOM,
                // Some settings this "hardware" cannot apply, to reach USART_START's refusal.
                serial_refuses_if: Some(|init| init.baud_rate.is_multiple_of(7)),
                checks: true,
                max_step_rate_hz: u64::from(config.max_step_rate_hz),
                ..FakePlant::default()
            },
            capacity,
            now_us: 1_000,
            host_seq: 0,
            acked_next_seq: 1,
            host_end: [0; MAX_JOINTS],
            sent: VecDeque::new(),
            accepted: VecDeque::new(),
            ok_replies: 0,
            last_taken: None,
            run_kind: None,
            upload: None,
        }
    }

    fn status(&self) -> StatusReport {
        self.controller.status(&self.plant)
    }

    fn snapshot(&self) -> Snapshot {
        Snapshot {
            effects: Effects::of(&self.plant),
            positions: self.plant.positions,
            running: self.plant.running,
            queued: self.plant.queue.len(),
            status: self.status(),
            next_seq: self.controller.next_seq(),
        }
    }

    /// Invariants that hold between any two events.
    fn check_always(&self) {
        let s = self.status();
        assert_eq!(usize::from(s.capacity), self.capacity);
        assert!(usize::from(s.buffered) <= self.capacity, "{s:?}");
        assert_eq!(
            usize::from(s.buffered) + self.controller.free(),
            self.capacity
        );
        assert!(s.received <= s.expected, "received > expected: {s:?}");
        assert!(s.executed <= s.received, "executed > received: {s:?}");
        assert!(State::from_u8(s.state as u8).is_some());
        if s.state != State::Running {
            assert!(!self.plant.running, "engine running in {:?}", s.state);
        }
        if matches!(s.state, State::Stopped | State::New) {
            assert!(
                self.plant.queue.is_empty(),
                "{} segments left in the engine in {:?}",
                self.plant.queue.len(),
                s.state
            );
        }
        assert!(self.plant.queue.len() <= self.plant.room);
    }

    /// A LOCATION report: the plant's positions and the current state.
    fn check_location(&self, location: &Location) {
        assert_eq!(
            location.position, self.plant.positions,
            "LOCATION positions"
        );
        assert_eq!(
            State::from_u8(location.state),
            Some(self.status().state),
            "LOCATION state"
        );
    }

    /// (possibly a duplicate, surely a duplicate) for a frame with `key` arriving now.
    fn duplicate(&self, key: &FrameKey) -> (bool, bool) {
        let mut possibly = false;
        let mut surely = false;
        for a in self.accepted.iter().filter(|a| a.key == *key) {
            let age = self.now_us - a.at_us;
            possibly |= age <= DUPLICATE_WINDOW_US;
            surely |= a.executed == Some(true)
                && age < DUPLICATE_WINDOW_US
                && self.ok_replies - a.index <= DUPLICATE_MEMORY;
        }
        (possibly, surely)
    }

    fn datagram(&mut self, from_index: usize, bytes: &[u8]) {
        if self.sent.len() >= RESEND_MEMORY {
            self.sent.pop_front();
        }
        self.sent.push_back((from_index, bytes.to_vec()));
        let from = ENDPOINTS[from_index];
        let before = self.snapshot();
        if bytes.len() < 3 {
            let r = self
                .controller
                .handle(from, bytes, self.now_us, &mut self.plant);
            assert_eq!(r, Response::default(), "reply to {} bytes", bytes.len());
            assert_eq!(
                self.snapshot(),
                before,
                "{} bytes changed something",
                bytes.len()
            );
            return;
        }
        let (&crc, body) = bytes.split_last().expect("3 bytes or more");
        if bytes.len() == 3 && bytes[1] == Tag::Discover as u8 && crc8(body) == crc {
            // DISCOVER (docs/PROTOCOL.md, "Finding controllers and setting their address"):
            // a DISCOVER_REPLY to the sender instead of an ACK, and nothing changes: no
            // owner taken or refreshed, no LOCATION listener or serial route registered
            // (issue 14's per-endpoint routing).
            let owner_before = self.controller.owner();
            let routes_before = self.controller.report_settings();
            let r = self
                .controller
                .handle(from, bytes, self.now_us, &mut self.plant);
            // Answered within the replies' rate limit (issue 21 F6), else not at all.
            if let Some(d) = r.discovery {
                assert_eq!((d.to, d.seq), (from, bytes[0]));
            }
            assert_eq!(r.reply, None, "an ACK besides the DISCOVER_REPLY");
            assert_eq!((r.status, r.executed), (None, false), "DISCOVER executed");
            assert_eq!(self.snapshot(), before, "DISCOVER changed something");
            assert_eq!(
                self.controller.owner(),
                owner_before,
                "DISCOVER touched the owner"
            );
            assert_eq!(
                self.controller.report_settings(),
                routes_before,
                "DISCOVER changed where reports go"
            );
            return;
        }
        let key = (from, bytes[0], bytes[1], crc);
        // A CRC-valid STOPPED is never a duplicate and is not remembered (issue 18).
        let is_stop = bytes[1] == Tag::Stopped as u8 && crc8(body) == crc;
        let (possibly_dup, surely_dup) = if is_stop {
            (false, false)
        } else {
            self.duplicate(&key)
        };
        let owner_before = self.controller.owner().map(|o| o.ip);
        let mut r = self
            .controller
            .handle(from, bytes, self.now_us, &mut self.plant);
        // A command that writes flash: no ACK until its save ended (issue 30), which the
        // trajectory task does next; here it succeeds at once.
        if let Some(Deferred::SaveSettings(_)) = r.deferred {
            assert_eq!(r.reply, None, "an ACK before the save");
            // (The state it was taken in: a hand-over may have dropped an upload first.)
            assert_eq!(self.controller.state(), State::Stopped, "a save while not STOPPED");
            r.reply = self.controller.settings_saved(true, self.now_us);
            r.executed = r.reply.is_some_and(|a| a.ack.status == StatusCode::Ok);
        }
        let after = self.snapshot();
        // A new owner (the old one silent 5 s, not running) takes over with any CRC-valid
        // frame, even one it then refuses; an upload the old owner had not started is
        // dropped then (STATUS more_flags bit 0): an effect of the hand-over, not of the
        // frame.
        let handed_over = owner_before.is_some_and(|ip| ip != from.ip)
            && self.controller.owner().map(|o| o.ip) == Some(from.ip);
        let dropped_at_hand_over =
            handed_over && matches!(before.status.state, State::New | State::Pending);
        if dropped_at_hand_over {
            assert!(
                after
                    .status
                    .more_flags
                    .has(protocol::MoreFlags::UPLOAD_DROPPED)
                    || after.status.state == State::New,
                "an unstarted upload survived the hand-over: {:?}",
                after.status
            );
            self.upload = None;
        }

        // A read-only STATUS (issue 23) from a host that does not own the controller:
        // answered (or, beyond its budget, not at all) and nothing taken or changed; it
        // is not remembered, so it is no duplicate later.
        let plain_status = matches!(
            Command::decode(bytes).map(|f| f.body),
            Ok(Command::Status | Command::StatusWith(_))
        );
        if plain_status
            && owner_before != Some(from.ip)
            && (r.answer_seq.is_some() || r.reply.is_none())
        {
            assert_eq!(
                self.controller.owner().map(|o| o.ip),
                owner_before,
                "a read-only STATUS took the controller"
            );
            assert_eq!(
                after.without_feeding(),
                before.without_feeding(),
                "a read-only STATUS changed something"
            );
            if let Some(reply) = r.reply {
                assert_eq!((reply.to, reply.ack.status), (from, StatusCode::Ok));
                let a = reply.ack;
                assert_eq!(
                    (a.next_seq, a.buffered, a.free),
                    (0, 0, 0),
                    "a read-only STATUS told the next seq or the buffer"
                );
                assert_eq!(r.answer_seq, Some(bytes[0]));
                assert_eq!(r.status.map(|(to, _)| to), Some(from));
            }
            return;
        }
        // Exactly one ACK, to the sender, for this frame.
        let reply = r.reply.expect("no ACK for a datagram of 3 bytes or more");
        assert_eq!(reply.to, from);
        assert_eq!((reply.seq, reply.ack.acked_tag), (bytes[0], bytes[1]));
        let crc_ok = crc8(body) == crc;
        let status = reply.ack.status;
        assert_eq!(
            status == StatusCode::BadCrc,
            !crc_ok,
            "{status:?}, CRC ok {crc_ok}"
        );
        // A stranger learns nothing: NOT_OWNER, and BAD_CRC to anyone but the owner
        // (issue 21 F9).
        let stranger_bad_crc = status == StatusCode::BadCrc
            && self.controller.owner().is_some_and(|o| o.ip != from.ip);
        if status == StatusCode::NotOwner || stranger_bad_crc {
            let a = reply.ack;
            assert_eq!(
                (a.state as u8, a.next_seq, a.buffered, a.free),
                (0, 0, 0, 0),
                "a {status:?} ACK told a stranger about the arm"
            );
        } else {
            self.check_ack(reply.seq, &reply.ack, &after);
            self.acked_next_seq = reply.ack.next_seq;
        }
        if let Some((to, _)) = r.status {
            assert_eq!(to, from, "a STATUS report not to its requester");
        }

        let decoded = Command::decode(bytes);
        if crc_ok && bytes[1] == Tag::Stopped as u8 {
            assert_ne!(status, StatusCode::NotOwner, "STOPPED refused as NOT_OWNER");
            assert_eq!(status, StatusCode::Ok, "a CRC-valid STOPPED refused");
        }
        if status == StatusCode::Ok {
            assert!(
                decoded.is_ok() || possibly_dup,
                "OK for a frame that does not decode ({:?}) and is no duplicate",
                decoded.err()
            );
        }
        if surely_dup && crc_ok {
            assert_eq!(status, StatusCode::Ok, "a duplicate not ACKed OK");
            if !dropped_at_hand_over {
                assert_eq!(after, before, "a duplicate changed something");
            }
        }
        if (status != StatusCode::Ok || (surely_dup && crc_ok)) && !dropped_at_hand_over {
            // Issue 21 F12: a command other than PENDING refused for good from the
            // uploader fills its seq in the upload's order, so next_seq may move past it;
            // nothing else may change.
            let mut after_cmp = after.without_feeding();
            let fills_its_seq = status.refuses_for_good()
                && bytes[1] != Tag::Pending as u8
                && self.upload.as_ref().is_some_and(|u| u.uploader == from);
            if fills_its_seq {
                after_cmp.next_seq = before.next_seq;
            }
            assert_eq!(
                after_cmp,
                before.without_feeding(),
                "a frame ACKed {status:?} changed something"
            );
            assert_eq!(
                (r.status, r.location, r.deferred),
                (None, None, None),
                "reports or work from a frame ACKed {status:?} (duplicate: {surely_dup})"
            );
        }
        let executed = status == StatusCode::Ok && !possibly_dup;
        if after.positions != before.positions {
            assert!(
                status == StatusCode::Ok
                    && matches!(
                        decoded,
                        Ok(Frame {
                            body: Command::LocationSetting(_),
                            ..
                        })
                    ),
                "positions changed without the engine: {:?} -> {:?}",
                before.positions,
                after.positions
            );
        }
        if let Some(location) = &r.location {
            self.check_location(location);
        }
        let reports_on = |s: &StatusReport| s.flags.has(StatusFlags::REPORTS_ON);
        if after.status.state != before.status.state
            && reports_on(&before.status)
            && reports_on(&after.status)
        {
            assert!(r.location.is_some(), "no LOCATION for a state change");
        }

        // A RELEASE from a host that does not own the controller is OK and not
        // remembered (it must never take the controller): no duplicate later.
        let release_by_other = bytes[1] == Tag::Release as u8 && owner_before != Some(from.ip);
        if status == StatusCode::Ok && !is_stop && !release_by_other {
            self.accepted.push_back(Accepted {
                key,
                at_us: self.now_us,
                executed: if surely_dup {
                    Some(false)
                } else if possibly_dup {
                    None
                } else {
                    Some(true)
                },
                index: self.ok_replies,
            });
            self.ok_replies += 1;
        }
        if after.status.state == State::New {
            self.last_taken = None;
            self.run_kind = Some(RunKind::Upload);
        }
        self.check_upload_order(from, bytes[0], bytes[1], status, &decoded, &before, &after);
        if release_by_other && status == StatusCode::Ok {
            // ACKed OK (a host whose owner fell silent may always say so) but done nothing:
            // the silent owner stays recorded until a host takes over.
            assert_eq!(
                self.controller.owner().map(|o| o.ip),
                owner_before,
                "a RELEASE from a host that does not own the controller changed the owner"
            );
        }
        if executed
            && !release_by_other
            && let Ok(frame) = decoded
        {
            // After a hand-over that dropped an upload, the command met state STOPPED.
            let mut met = before;
            if dropped_at_hand_over {
                met.status.state = State::Stopped;
                met.status.buffered = 0;
            }
            self.check_executed(&frame.body, &met, &after, &r);
        }
    }

    /// The points taken are exactly the uploader's PENDING points, in order, none skipped.
    #[allow(clippy::too_many_arguments)]
    fn check_upload_order(
        &mut self,
        from: Endpoint,
        seq: u8,
        raw_tag: u8,
        status: StatusCode,
        decoded: &std::result::Result<Frame<Command<'_>>, protocol::DecodeError>,
        before: &Snapshot,
        after: &Snapshot,
    ) {
        let is = |tag: Tag| matches!(decoded, Ok(f) if f.body.tag() == tag);
        // An executed NEW always stops the engine; its duplicate changes nothing.
        let new_upload = is(Tag::New)
            && status == StatusCode::Ok
            && after.status.state == State::New
            && after.effects.stops > before.effects.stops;
        if new_upload {
            self.upload = Some(UploadTrack {
                uploader: from,
                last_taken_seq: seq,
                accepted: [false; 256],
            });
            return;
        }
        let taken = is(Tag::Pending) && after.status.received > before.status.received;
        if taken {
            let upload = self
                .upload
                .as_mut()
                .expect("a PENDING taken with no upload started");
            assert_eq!(
                from, upload.uploader,
                "a PENDING taken from an endpoint that did not send the NEW"
            );
            let gap = seq.wrapping_sub(upload.last_taken_seq);
            assert_ne!(gap, 0, "a PENDING taken with the seq of the last one");
            for d in 1..gap {
                let between = upload.last_taken_seq.wrapping_add(d);
                assert!(
                    upload.accepted[usize::from(between)],
                    "PENDING {seq} taken after {}: seq {between} was never accepted from \
                     the uploader (points skipped)",
                    upload.last_taken_seq
                );
            }
            // The controller keeps the marks of later seqs (a command refused for good
            // ahead of a late PENDING still fills its seq): forget only those passed.
            for d in 1..=gap {
                upload.accepted[usize::from(upload.last_taken_seq.wrapping_add(d))] = false;
            }
            upload.last_taken_seq = seq;
        } else if let Some(upload) = self.upload.as_mut()
            && upload.uploader == from
        {
            // Accepted, or (issue 21 F12) a command other than PENDING refused for good:
            // these bytes can never be accepted, and its seq does not hold up the upload.
            let refused_for_good = raw_tag != Tag::Pending as u8 && status.refuses_for_good();
            if status == StatusCode::Ok || refused_for_good {
                upload.accepted[usize::from(seq)] = true;
            }
        }
    }

    fn check_ack(&self, seq: u8, ack: &Ack, after: &Snapshot) {
        assert!(usize::from(ack.buffered) <= self.capacity, "{ack:?}");
        assert_eq!(
            usize::from(ack.buffered) + usize::from(ack.free),
            self.capacity
        );
        assert_eq!(ack.state, after.status.state, "ACK state");
        assert_eq!(ack.buffered, after.status.buffered, "ACK buffered");
        assert_eq!(ack.next_seq, after.next_seq, "ACK next_seq");
        let mut buf = [0u8; 16];
        let n = Report::Ack(*ack)
            .encode(seq, &mut buf)
            .expect("an ACK encodes");
        let again = Report::decode(&buf[..n]).expect("an ACK decodes");
        assert_eq!(again.body, Report::Ack(*ack));
    }

    /// What an executed command must have done (docs/PROTOCOL.md, "Commands (host to
    /// controller)" and "The trajectory state machine").
    fn check_executed(
        &mut self,
        cmd: &Command<'_>,
        before: &Snapshot,
        after: &Snapshot,
        r: &Response,
    ) {
        let (was, is) = (before.status.state, after.status.state);
        match cmd {
            Command::New { count } => {
                assert_ne!(was, State::Running, "NEW accepted in RUNNING");
                assert_eq!(is, State::New);
                let s = after.status;
                assert_eq!(
                    (s.expected, s.received, s.executed, s.buffered),
                    (*count, 0, 0, 0)
                );
                self.host_end = after.positions;
            }
            Command::Pending(points) => {
                assert!(
                    matches!(was, State::New | State::Pending | State::Running),
                    "PENDING accepted in {was:?}"
                );
                assert_eq!(
                    is,
                    if was == State::New {
                        State::Pending
                    } else {
                        was
                    }
                );
                let n = points.len() as u16;
                assert_eq!(
                    after.status.received,
                    before.status.received + n,
                    "points taken"
                );
                assert_eq!(
                    after.status.buffered,
                    before.status.buffered + n,
                    "points buffered"
                );
                // Issue 31: a point that moves a joint whose driver is disabled is never
                // taken.
                let enabled = before.status.drivers_enabled().unwrap_or(0x1FF);
                let joints = usize::from(before.status.joints).min(MAX_JOINTS);
                let mut previous = self.host_end;
                for point in points.iter() {
                    for j in 0..joints {
                        assert!(
                            point.position[j] == previous[j] || enabled & (1 << j) != 0,
                            "a point moving limp joint {j} was taken"
                        );
                    }
                    previous = point.position;
                }
                if let Some(last) = points.iter().last() {
                    self.last_taken = Some(last.position);
                    self.host_end = last.position;
                }
            }
            Command::Runing => {
                assert!(
                    matches!(was, State::Pending | State::Running),
                    "RUNING in {was:?}"
                );
                assert_eq!(is, State::Running);
            }
            Command::Stopped => {
                assert_eq!(is, State::Stopped);
                assert!(!self.plant.running && self.plant.queue.is_empty());
                // Issue 31: a STOPPED that ended something is its cause.
                if was != State::Stopped {
                    assert_eq!(after.status.stop_cause(), Some(StopCause::Stopped));
                }
            }
            Command::Return => {
                assert_eq!(was, State::Stopped, "RETURN accepted in {was:?}");
                assert_eq!(is, State::Running);
                assert_eq!(r.deferred, Some(Deferred::ReadEncoders));
                self.run_kind = Some(RunKind::Return);
            }
            Command::JointsCount(n) => {
                assert_eq!(was, State::Stopped, "JOINTS_COUNT accepted in {was:?}");
                assert_eq!(after.status.joints, *n);
                assert!(
                    matches!(r.deferred, Some(Deferred::SaveSettings(s)) if s.joints == *n),
                    "{:?}",
                    r.deferred
                );
            }
            Command::LocationSetting(location) => {
                assert_eq!(was, State::Stopped, "LOCATION_SETTING accepted in {was:?}");
                assert_eq!(self.plant.positions, location.position);
            }
            Command::ToggleEnablePins { .. } => {
                assert_eq!(
                    was,
                    State::Stopped,
                    "TOGGLE_ENABLE_PINS accepted in {was:?}"
                );
            }
            Command::SetEnable { mask, enable } => {
                assert_eq!(was, State::Stopped, "SET_ENABLE accepted in {was:?}");
                let drivers = after.status.drivers_enabled().expect("per-driver enables");
                let want = if *enable {
                    drivers & mask
                } else {
                    !drivers & mask
                };
                assert_eq!(want, *mask, "SET_ENABLE left a masked driver unchanged");
            }
            Command::LimitsSet(set) => {
                assert_eq!(was, State::Stopped, "LIMITS_SET accepted in {was:?}");
                assert!(
                    matches!(r.deferred, Some(Deferred::SaveSettings(s))
                        if s.limits[usize::from(set.joint)] == set.limits),
                    "{:?}",
                    r.deferred
                );
            }
            // Flash writes only while STOPPED (issue 30).
            Command::SetKey(_) | Command::NetSet(_) => {
                assert_eq!(was, State::Stopped, "{cmd:?} accepted in {was:?}");
            }
            // The arm's description (issue 31): a flash write, and read back as kept.
            Command::JointDescSet(set) => {
                assert_eq!(was, State::Stopped, "JOINT_DESC_SET accepted in {was:?}");
                assert!(
                    matches!(r.deferred, Some(Deferred::SaveSettings(s))
                        if s.desc[usize::from(set.joint)] == set.desc),
                    "{:?}",
                    r.deferred
                );
            }
            Command::JointDescGet { joint } => {
                let (_, report) = r.joint_desc.expect("no JOINT_DESC report for JOINT_DESC_GET");
                assert_eq!(report.joint, *joint);
                assert_eq!(
                    report.desc,
                    self.controller.settings().desc[usize::from(*joint)]
                );
            }
            Command::LimitsGet => {
                let (_, report) = r.limits.expect("no LIMITS report for LIMITS_GET");
                assert_eq!(report.joints, self.controller.settings().limits);
            }
            Command::Release => {
                assert_eq!(was, State::Stopped, "RELEASE accepted in {was:?}");
                assert_eq!(self.controller.owner(), None, "RELEASE left an owner");
            }
            Command::Status | Command::StatusWith(_) => {
                let (_, report) = r.status.expect("no STATUS report for STATUS");
                assert_eq!(report.state, is);
            }
            Command::UploadStart => assert!(after.status.flags.has(StatusFlags::REPORTS_ON)),
            Command::UploadStop => assert!(!after.status.flags.has(StatusFlags::REPORTS_ON)),
            _ => {}
        }
    }

    /// The engine finishes some of its segments (the step interrupts' report), or nothing.
    fn progress(&mut self, batch: u8) {
        let before = self.status();
        if !self.plant.running || self.plant.queue.is_empty() {
            let location = self.controller.on_step_progress(0, false, &mut self.plant);
            assert_eq!(
                self.status().state,
                before.state,
                "state changed with no progress"
            );
            if let Some(l) = location {
                self.check_location(&l);
            }
            return;
        }
        let k = 1 + usize::from(batch) % self.plant.queue.len();
        for _ in 0..k {
            let segment = self.plant.queue.pop_front().expect("k <= queue length");
            for (p, s) in self.plant.positions.iter_mut().zip(segment.steps) {
                *p = p
                    .checked_add(s)
                    .expect("a joint driven beyond the i32 range");
            }
        }
        let dry = self.plant.queue.is_empty();
        if dry {
            self.plant.running = false;
        }
        let location = self
            .controller
            .on_step_progress(k as u32, dry, &mut self.plant);
        let after = self.status();
        if let Some(l) = &location {
            self.check_location(l);
        }
        if !dry {
            return;
        }
        assert_eq!(before.state, State::Running);
        assert_eq!(
            after.state,
            State::Stopped,
            "the engine ran dry but the run goes on"
        );
        if before.flags.has(StatusFlags::REPORTS_ON) {
            assert!(location.is_some(), "no LOCATION when the run ended");
        }
        let underrun = after.flags.has(StatusFlags::UNDERRUN);
        assert_eq!(
            underrun,
            after.executed < after.expected,
            "underrun flag vs points run: {after:?}"
        );
        assert!(!after.flags.has(StatusFlags::STOPPED_BY_HOST));
        // Issue 31: the stop cause says the same.
        let cause = if underrun {
            StopCause::Underrun
        } else {
            StopCause::Complete
        };
        assert_eq!(after.stop_cause(), Some(cause), "stop cause: {after:?}");
        if underrun {
            return;
        }
        let joints = usize::from(after.joints).min(MAX_JOINTS);
        match self.run_kind {
            Some(RunKind::Upload) => {
                if let Some(last) = self.last_taken {
                    assert_eq!(
                        self.plant.positions[..joints],
                        last[..joints],
                        "a completed upload did not end on its last point"
                    );
                }
            }
            Some(RunKind::Return) => assert_eq!(
                self.plant.positions[..joints],
                [0; MAX_JOINTS][..joints],
                "a completed RETURN did not end on zero"
            ),
            None => {}
        }
    }

    fn begin_return(&mut self, encoders: Option<[i32; MAX_JOINTS]>) {
        let location = self.controller.begin_return(encoders, &mut self.plant);
        if let Some(l) = &location {
            self.check_location(l);
            assert_eq!(self.status().state, State::Stopped);
        }
    }

    fn stop_after_overtaken(&mut self) {
        let location = self.controller.stop_after_overtaken(&mut self.plant);
        assert_eq!(self.status().state, State::Stopped);
        if let Some(l) = &location {
            self.check_location(l);
        }
    }

    /// A well-formed command, so that runs get far past decoding.
    fn command(&mut self, u: &mut Unstructured<'_>) -> Result<()> {
        let from = usize::from(u.arbitrary::<u8>()?) % ENDPOINTS.len();
        let seq = match u.arbitrary::<u8>()? % 4 {
            0 => u.arbitrary::<u8>()?,
            1 => self.acked_next_seq,
            _ => {
                self.host_seq = self.host_seq.wrapping_add(1);
                self.host_seq
            }
        };
        let small = |u: &mut Unstructured<'_>| -> Result<[i32; MAX_JOINTS]> {
            let mut p = [0i32; MAX_JOINTS];
            for x in &mut p {
                *x = i32::from(u.arbitrary::<i8>()?);
            }
            Ok(p)
        };
        let mut points = Vec::new();
        let serial_bytes: Vec<u8>;
        let cmd = match u.arbitrary::<u8>()? % 22 {
            0 => Command::New {
                count: if u.arbitrary()? {
                    u.int_in_range(1..=30)?
                } else {
                    u.arbitrary()?
                },
            },
            1..=4 => {
                // Often exactly the points still missing, so that uploads complete.
                let s = self.status();
                let missing = usize::from(s.expected.saturating_sub(s.received));
                let n = if u.arbitrary()? && (1..=12).contains(&missing) {
                    missing
                } else {
                    u.int_in_range(1..=12)?
                };
                let mut previous = self.host_end;
                for _ in 0..n {
                    let duration = i32::from(u.arbitrary::<u16>()?);
                    let deltas = small(u)?;
                    let mut next = previous;
                    for (p, d) in next.iter_mut().zip(deltas) {
                        *p = p.saturating_add(d);
                    }
                    points.push(Point::from_motion(duration, &previous, &next));
                    previous = next;
                }
                Command::Pending(PointList::Points(&points))
            }
            5 | 6 => Command::Runing,
            7 => Command::Stopped,
            8 => Command::UploadStart,
            9 => Command::UploadStop,
            10 => Command::PwmStart(Pwm {
                psc: u.arbitrary::<u16>()?.into(),
                arr: u.arbitrary::<u16>()?.into(),
                ccr1: u.arbitrary::<u16>()?.into(),
                pulse_count: u.arbitrary::<i16>()?.into(),
            }),
            11 => Command::PwmStop,
            12 => Command::UsartStart(UartInit {
                baud_rate: u.int_in_range(0..=5_000_000)?,
                mode: u.int_in_range(0..=3)?,
                ..UartInit::default()
            }),
            13 => Command::UsartStop,
            14 => {
                let n = u.int_in_range(1..=16)?;
                serial_bytes = u.bytes(n)?.to_vec();
                Command::UsartSend(&serial_bytes)
            }
            15 => match u.arbitrary::<u8>()? % 4 {
                0 => Command::Pin0On,
                1 => Command::Pin0Off,
                2 => Command::Pin1On,
                _ => Command::Pin1Off,
            },
            16 => Command::ToggleEnablePins {
                mask: u.arbitrary()?,
            },
            17 => Command::Return,
            18 => Command::JointsCount(u.int_in_range(0..=9)?),
            19 => Command::LocationSetting(Location {
                position: if u.arbitrary()? {
                    small(u)?
                } else {
                    u.arbitrary()?
                },
                state: 0,
            }),
            20 => Command::Status,
            _ => Command::UploadPeriod {
                period_us: if u.arbitrary()? {
                    u.int_in_range(1_000..=1_000_000)?
                } else {
                    u.arbitrary()?
                },
            },
        };
        let mut buf = [0u8; MAX_DATAGRAM];
        if let Ok(n) = cmd.encode(seq, &mut buf) {
            self.datagram(from, &buf[..n]);
        }
        Ok(())
    }

    fn step(&mut self, u: &mut Unstructured<'_>) -> Result<()> {
        match u.arbitrary::<u8>()? % 12 {
            // Raw bytes, as received or with the CRC fixed.
            op @ 0..=1 => {
                let from = usize::from(u.arbitrary::<u8>()?) % ENDPOINTS.len();
                let n = usize::from(u.arbitrary::<u16>()?) % (MAX_DATAGRAM + 1);
                let mut bytes = u.bytes(n.min(u.len()))?.to_vec();
                if op == 1
                    && let Some((last, body)) = bytes.split_last_mut()
                {
                    *last = crc8(body);
                }
                self.datagram(from, &bytes);
            }
            2..=4 => self.command(u)?,
            5 => {
                if !self.sent.is_empty() {
                    let i = usize::from(u.arbitrary::<u8>()?) % self.sent.len();
                    let (from, bytes) = self.sent[i].clone();
                    self.datagram(from, &bytes);
                }
            }
            6 => {
                self.now_us += if u.arbitrary()? {
                    u64::from(u.arbitrary::<u16>()?)
                } else {
                    u.int_in_range(0..=10_000_000)?
                };
                self.plant.serial_queued = 0;
                while self
                    .accepted
                    .front()
                    .is_some_and(|a| self.now_us - a.at_us > DUPLICATE_WINDOW_US)
                {
                    self.accepted.pop_front();
                }
            }
            7..=9 => self.progress(u.arbitrary()?),
            10 => {
                let encoders = match u.arbitrary::<u8>()? % 3 {
                    0 => None,
                    1 => Some(u.arbitrary::<[i16; MAX_JOINTS]>()?.map(i32::from)),
                    _ => Some(u.arbitrary()?),
                };
                self.begin_return(encoders);
            }
            _ => self.stop_after_overtaken(),
        }
        self.check_always();
        Ok(())
    }
}

fuzz_target!(|data: &[u8]| {
    let mut u = Unstructured::new(data);
    let (Ok(capacity), Ok(room)) = (u.int_in_range(1..=CAP), u.int_in_range(1..=16usize)) else {
        return;
    };
    let mut harness = Harness::new(capacity, room);
    harness.check_always();
    for _ in 0..MAX_EVENTS {
        if u.is_empty() || harness.step(&mut u).is_err() {
            break;
        }
    }
});
