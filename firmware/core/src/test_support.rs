//! Fakes and helpers for the controller's tests, behind the `test-support` feature: used by
//! arm-core's own tests and by other crates' tests (sequential-storage's `mock_flash` is the
//! model). [`FakePlant`] is a step engine and peripherals that record every call, with
//! faults a test switches on: a full engine queue ([`FakePlant::room`]), a serial port
//! that refuses its settings ([`FakePlant::serial_refuses`]) or has no room
//! ([`FakePlant::serial_room`], [`FakePlant::serial_refuses_if`]); and contract checks
//! ([`FakePlant::checks`]) that panic when the controller asks the hardware for what it
//! must never ask (the fuzz target runs with them). [`Session`] is a host talking to one
//! controller over it.

use std::collections::VecDeque;
use std::vec::Vec;

use arm_step::Segment;
use protocol::{Ack, Command, Location, MAX_JOINTS, Point, PointList, Pwm, StatusCode, UartInit};

use crate::hw::{Endpoint, SerialError};
use crate::{Controller, ControllerConfig, Plant, Response};

/// The host most tests talk from.
pub const HOST: Endpoint = Endpoint {
    ip: [127, 0, 0, 1],
    port: 40_000,
};
/// A second host.
pub const OTHER: Endpoint = Endpoint {
    ip: [127, 0, 0, 2],
    port: 40_001,
};

/// The gripper burst of issue 30 (a stop stops the gripper): 8000 pulses at 1 kHz (8 s)
/// on the 200 MHz gripper timer. One value for the controller's tests and the
/// simulator's (`sim-host/tests/gripper_trials`).
pub const GRIPPER_BURST: Pwm = Pwm {
    psc: 199,
    arr: 999,
    ccr1: 500,
    pulse_count: 8000,
};

/// A 50 Hz hobby-servo signal, 1.5 ms pulse, on the 200 MHz gripper timer: the PWM a stop
/// holds by default (issue 30). Shared as [`GRIPPER_BURST`] is.
pub const GRIPPER_SERVO: Pwm = Pwm {
    psc: 199,
    arr: 19_999,
    ccr1: 1_500,
    pulse_count: 0,
};

/// A step engine and peripherals that record what they are told. Segments pushed wait in
/// `queue` until the test runs them with [`run`].
#[derive(Debug)]
pub struct FakePlant {
    /// Position of each joint, steps.
    pub positions: [i32; MAX_JOINTS],
    /// Segments in the engine, not yet run.
    pub queue: VecDeque<Segment>,
    /// Fault: segments the engine queue holds at most; a push beyond is refused.
    pub room: usize,
    /// Every segment run, in order.
    pub executed: Vec<Segment>,
    /// Whether the engine is running (started and not yet dry or stopped).
    pub running: bool,
    /// Calls to `stop`.
    pub stops: u32,
    /// Calls to `start`.
    pub starts: u32,
    /// Every user pin set, in order: (pin, high).
    pub pins: Vec<(u8, bool)>,
    /// Every driver-enable mask set, in order.
    pub enabled: Vec<u16>,
    /// The gripper's PWM while it runs.
    pub gripper: Option<Pwm>,
    /// Calls to `gripper_start` and `gripper_stop`.
    pub gripper_calls: u32,
    /// The serial port's settings while it is open.
    pub serial: Option<UartInit>,
    /// Fault: the serial port refuses any settings (`SerialError::Unsupported`).
    pub serial_refuses: bool,
    /// Every serial chunk sent, in order.
    pub serial_sent: Vec<Vec<u8>>,
    /// Fault: serial chunks the port queues at most; further sends find no room.
    pub serial_room: usize,
    /// Serial chunks queued and not yet transmitted: closing the port empties it, and so
    /// may the test (the port transmitting).
    pub serial_queued: usize,
    /// Fault: the serial port refuses the settings for which this returns true.
    pub serial_refuses_if: Option<fn(&UartInit) -> bool>,
    /// Calls to `serial_open` that succeeded.
    pub serial_opens: u32,
    /// Calls to `serial_close`.
    pub serial_closes: u32,
    /// Segments `push_segment` took.
    pub pushed: u64,
    /// Every rate change taken while running (issue 32), in order: (rate, accel, speed).
    pub rate_changes: Vec<(u64, u32, u32)>,
    /// The rate the next start begins at (`set_start_rate`).
    pub start_rate: u64,
    /// Fault: a step side without a warp (the boards' before issue 32's board work):
    /// `change_rate` is refused and `rate_now` is `None`.
    pub warpless: bool,
    /// Fault: a rate change never settles (`rate_now` says ramping): a ramp that never
    /// reaches its standstill.
    pub ramp_never_ends: bool,
    /// The step side's warp budget, steps/s of all joints (0: no limit, the default).
    pub warp_budget_hz: u32,
    /// Contract checks: panic on a segment shorter than 1 us or faster than
    /// [`FakePlant::max_step_rate_hz`] on any joint, a user pin other than 0 and 1, enable
    /// bits beyond the gripper's, a serial chunk of 0 or more than 255 bytes.
    pub checks: bool,
    /// With [`FakePlant::checks`]: the highest step rate a segment may ask of a joint.
    pub max_step_rate_hz: u64,
    /// Every `set_positions` taken, in order.
    pub set_positions_calls: Vec<[i32; MAX_JOINTS]>,
}

impl Default for FakePlant {
    fn default() -> Self {
        FakePlant {
            positions: [0; MAX_JOINTS],
            queue: VecDeque::new(),
            room: 16,
            executed: Vec::new(),
            running: false,
            stops: 0,
            starts: 0,
            pins: Vec::new(),
            enabled: Vec::new(),
            gripper: None,
            gripper_calls: 0,
            serial: None,
            serial_refuses: false,
            serial_sent: Vec::new(),
            serial_room: 4,
            serial_queued: 0,
            serial_refuses_if: None,
            serial_opens: 0,
            serial_closes: 0,
            pushed: 0,
            warp_budget_hz: 0,
            rate_changes: Vec::new(),
            start_rate: arm_step::RATE_ONE,
            warpless: false,
            ramp_never_ends: false,
            checks: false,
            max_step_rate_hz: u64::MAX,
            set_positions_calls: Vec::new(),
        }
    }
}

impl Plant for FakePlant {
    fn positions(&self) -> [i32; MAX_JOINTS] {
        self.positions
    }
    fn set_positions(&mut self, positions: [i32; MAX_JOINTS]) -> bool {
        if self.running {
            return false;
        }
        self.set_positions_calls.push(positions);
        self.positions = positions;
        true
    }
    fn stop(&mut self) {
        self.stops += 1;
        self.queue.clear();
        self.running = false;
    }
    fn push_segment(&mut self, segment: Segment) -> bool {
        if self.checks {
            assert!(segment.duration_us >= 1, "segment of 0 us: {segment:?}");
            for s in segment.steps {
                assert!(
                    u64::from(s.unsigned_abs()) * 1_000_000
                        <= self.max_step_rate_hz * u64::from(segment.duration_us),
                    "segment faster than max_step_rate_hz: {segment:?}"
                );
            }
        }
        if self.queue.len() >= self.room {
            return false;
        }
        self.queue.push_back(segment);
        self.pushed += 1;
        true
    }
    fn start(&mut self) {
        self.starts += 1;
        self.running = true;
    }
    fn change_rate(&mut self, rate: u64, accel: u32, speed: u32) -> bool {
        if self.warpless {
            return false;
        }
        if self.running {
            self.rate_changes.push((rate, accel, speed));
        }
        self.running
    }
    fn set_start_rate(&mut self, rate: u64) {
        self.start_rate = rate;
    }
    fn warp_budget_hz(&self) -> u32 {
        self.warp_budget_hz
    }
    fn rate_now(&self) -> Option<(u64, bool)> {
        // Every change done at once.
        let last = self.rate_changes.last().map(|&(rate, _, _)| rate);
        (self.running && !self.warpless)
            .then_some((last.unwrap_or(self.start_rate), self.ramp_never_ends))
    }
    fn set_user_pin(&mut self, pin: u8, high: bool) {
        assert!(!self.checks || pin < 2, "user pin {pin}");
        self.pins.push((pin, high));
    }
    fn set_enabled(&mut self, enabled: u16) {
        assert!(
            !self.checks || enabled & !protocol::limits::ENABLE_MASK_BITS == 0,
            "ENABLE bits beyond the gripper's"
        );
        self.enabled.push(enabled);
    }
    fn gripper_start(&mut self, pwm: &Pwm) {
        self.gripper = Some(*pwm);
        self.gripper_calls += 1;
    }
    fn gripper_stop(&mut self) {
        self.gripper = None;
        self.gripper_calls += 1;
    }
    fn gripper_active(&self) -> bool {
        self.gripper.is_some()
    }
    fn serial_open(&mut self, init: &UartInit) -> Result<(), SerialError> {
        if self.serial_refuses || self.serial_refuses_if.is_some_and(|refuses| refuses(init)) {
            return Err(SerialError::Unsupported);
        }
        self.serial = Some(*init);
        self.serial_opens += 1;
        Ok(())
    }
    fn serial_close(&mut self) {
        self.serial = None;
        self.serial_closes += 1;
        self.serial_queued = 0;
    }
    fn serial_send(&mut self, bytes: &[u8]) -> bool {
        assert!(
            !self.checks || (1..=255).contains(&bytes.len()),
            "serial chunk of {}",
            bytes.len()
        );
        if self.serial_queued >= self.serial_room {
            return false;
        }
        self.serial_queued += 1;
        self.serial_sent.push(bytes.to_vec());
        true
    }
}

impl FakePlant {
    /// Runs up to `n` queued segments (if running), one at a time, reporting each to the
    /// controller (which refills the queue in between, as the trajectory task does while
    /// a segment runs); the engine runs dry when it finishes its last queued segment.
    /// Returns the LOCATION the controller sent, if any.
    pub fn run<const CAP: usize>(
        &mut self,
        controller: &mut Controller<CAP>,
        n: usize,
    ) -> Option<Location> {
        if !self.running {
            return controller.on_step_progress(0, false, self);
        }
        for _ in 0..n {
            let Some(s) = self.queue.pop_front() else {
                break;
            };
            for (p, steps) in self.positions.iter_mut().zip(s.steps) {
                *p += steps;
            }
            self.executed.push(s);
            let dry = self.queue.is_empty();
            if dry {
                self.running = false;
            }
            let location = controller.on_step_progress(1, dry, self);
            if dry {
                return location;
            }
        }
        None
    }

    /// Runs until the engine ran dry; returns the LOCATION the controller sent then.
    pub fn run_to_end<const CAP: usize>(
        &mut self,
        controller: &mut Controller<CAP>,
    ) -> Option<Location> {
        for _ in 0..1_000_000 {
            if !self.running {
                return None;
            }
            if let Some(l) = self.run(controller, 1) {
                return Some(l);
            }
        }
        None
    }
}

/// Encodes a command.
pub fn frame(seq: u8, cmd: Command<'_>) -> Vec<u8> {
    let mut buf = std::vec![0u8; protocol::MAX_DATAGRAM];
    let n = cmd.encode(seq, &mut buf).expect("encodable command");
    buf.truncate(n);
    buf
}

/// A frame with any tag and data and a correct CRC (for lengths and tags no command has).
pub fn raw(seq: u8, tag: u8, data: &[u8]) -> Vec<u8> {
    let mut bytes = std::vec![seq, tag];
    bytes.extend_from_slice(data);
    bytes.push(protocol::crc8(&bytes));
    bytes
}

/// A controller with the board's configuration but `capacity` points.
pub fn controller<const CAP: usize>(capacity: usize) -> Controller<CAP> {
    Controller::new(ControllerConfig {
        capacity,
        ..ControllerConfig::BOARD
    })
}

/// Points moving every joint by `step` per point from `from`, 1 ms each.
pub fn points(from: [i32; MAX_JOINTS], n: usize, step: i32) -> Vec<Point> {
    let mut prev = from;
    (0..n)
        .map(|_| {
            let next = prev.map(|p| p + step);
            let p = Point::from_motion(1_000, &prev, &next);
            prev = next;
            p
        })
        .collect()
}

/// Encodes PENDING with these points.
pub fn pending(seq: u8, pts: &[Point]) -> Vec<u8> {
    frame(seq, Command::Pending(PointList::Points(pts)))
}

/// A host talking to one controller with a fake plant, numbering its frames.
pub struct Session<const CAP: usize> {
    /// The controller under test.
    pub controller: Controller<CAP>,
    /// Its plant.
    pub plant: FakePlant,
    /// The time of the last frame, microseconds (each frame advances it by 10).
    pub now_us: u64,
    /// The seq of the last frame sent.
    pub seq: u8,
    /// Where [`Session::send`] sends from.
    pub from: Endpoint,
    /// A session opened with HELLO: [`Session::send`] seals its frames.
    pub auth: Option<HostAuth>,
    /// Settings saves fail ([`Session::send_raw`] completes each save the controller asks
    /// for: with this, as a failed one).
    pub saves_fail: bool,
}

/// A host's side of an authenticated session (docs/PROTOCOL.md section 13).
#[derive(Clone, Copy, Debug)]
pub struct HostAuth {
    /// The key.
    pub key: protocol::auth::AuthKey,
    /// The controller's boot epoch (HELLO_REPLY).
    pub epoch: u64,
    /// The session (HELLO_REPLY).
    pub session: u32,
    /// The last counter used.
    pub counter: u64,
}

impl HostAuth {
    /// `inner` in an envelope with the next counter.
    pub fn seal(&mut self, inner: &[u8]) -> Vec<u8> {
        self.counter += 1;
        let mut buf = std::vec![0u8; protocol::MAX_DATAGRAM];
        let n = protocol::auth::seal(
            &self.key,
            protocol::auth::Direction::ToController,
            self.epoch,
            self.session,
            self.counter,
            inner,
            &mut buf,
        )
        .expect("sealable");
        buf.truncate(n);
        buf
    }
}

impl<const CAP: usize> Session<CAP> {
    /// A controller with `capacity` points and a default [`FakePlant`], at 1 ms.
    pub fn new(capacity: usize) -> Self {
        Session {
            controller: controller(capacity),
            plant: FakePlant::default(),
            now_us: 1_000,
            seq: 0,
            from: HOST,
            auth: None,
            saves_fail: false,
        }
    }

    /// Opens a session with `key` by HELLO from [`Session::from`]: later frames are
    /// sealed. Panics if the controller does not grant one.
    pub fn hello(&mut self, key: protocol::auth::AuthKey) -> HostAuth {
        self.seq = self.seq.wrapping_add(1);
        let nonce = [self.seq; protocol::auth::NONCE_LEN];
        let bytes = frame(self.seq, Command::Hello { nonce });
        let grant = self
            .send_raw(self.from, &bytes)
            .hello
            .expect("a HELLO_REPLY");
        assert_eq!(grant.reply.nonce, nonce);
        let auth = HostAuth {
            key,
            epoch: grant.reply.epoch,
            session: grant.reply.session,
            counter: 0,
        };
        self.auth = Some(auth);
        auth
    }

    /// Sends raw bytes from `from`. A settings save the controller asks for is done at
    /// once (failing with [`Session::saves_fail`]) and the response gets its ACK, as the
    /// trajectory task sends it; the deferred save stays in the response.
    pub fn send_raw(&mut self, from: Endpoint, bytes: &[u8]) -> Response {
        self.now_us += 10;
        let mut response = self
            .controller
            .handle(from, bytes, self.now_us, &mut self.plant);
        if let Some(crate::response::Deferred::SaveSettings(_)) = response.deferred {
            assert!(response.reply.is_none(), "an ACK before the save");
            response.reply = self
                .controller
                .settings_saved(!self.saves_fail, self.now_us);
        }
        response
    }

    /// Sends a command with the next seq; returns the ACK.
    pub fn send(&mut self, cmd: Command<'_>) -> Ack {
        self.seq = self.seq.wrapping_add(1);
        let mut bytes = frame(self.seq, cmd);
        if let Some(auth) = self.auth.as_mut() {
            bytes = auth.seal(&bytes);
        }
        self.send_raw(self.from, &bytes).reply.expect("an ACK").ack
    }

    /// Sends a command and asserts its status.
    pub fn expect(&mut self, cmd: Command<'_>, status: StatusCode) -> Ack {
        let ack = self.send(cmd);
        assert_eq!(ack.status, status, "{cmd:?}");
        ack
    }

    /// Sets the joint positions (LOCATION_SETTING) and asserts it was taken (`OK`).
    pub fn set_location(&mut self, position: [i32; MAX_JOINTS]) -> Ack {
        let location = Location { position, state: 0 };
        self.expect(Command::LocationSetting(location), StatusCode::Ok)
    }

    /// NEW of `count` points (asserted `OK`), PENDING with `pts`, RUNING (asserted `OK`).
    pub fn start_run(&mut self, count: u16, pts: &[Point]) {
        self.expect(Command::New { count }, StatusCode::Ok);
        self.pending(pts);
        self.expect(Command::Runing, StatusCode::Ok);
    }

    /// A run that goes on until stopped: NEW of 50 points, 12 of them sent, RUNING, and one
    /// segment run; asserts the arm is RUNNING.
    pub fn start_endless_run(&mut self) {
        let from = self.plant.positions;
        self.start_run(50, &points(from, 12, 1));
        self.plant.run(&mut self.controller, 1);
        assert_eq!(self.controller.state(), protocol::State::Running);
        assert!(self.plant.running);
    }

    /// Sends PENDING with these points.
    pub fn pending(&mut self, pts: &[Point]) -> Ack {
        self.send(Command::Pending(PointList::Points(pts)))
    }
}
