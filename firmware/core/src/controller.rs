//! The controller's behaviour, sans-io: one datagram in, an ACK, reports and effects out.
//!
//! # Check order
//! Every datagram goes through these checks, in this order; the first that fails decides
//! the ACK's status and nothing further is done:
//! 1. **length**: fewer than 3 bytes: no reply at all.
//! 2. **CRC**: `BAD_CRC`, ACKed to the sender with the frame's seq and tag. A frame with a
//!    bad CRC never changes the owner.
//! 3. **owner**: the first sender of a CRC-valid frame owns the controller; another
//!    address takes over when the owner has been silent for 5 s and the state is not
//!    RUNNING (an upload it had not started is dropped then: STATUS `more_flags` bit 0);
//!    other senders get `NOT_OWNER` with zeros for state, next_seq, buffered and free,
//!    except for tag STOPPED (anyone may stop the arm).
//! 4. **duplicate**: a frame (sender, seq, tag, CRC) accepted within the last 2 s (and
//!    among the last [`crate::config::DUPLICATE_MEMORY`] accepted) is ACKed `OK` again and
//!    not executed ([`Response::executed`] is false).
//! 5. **decode**: `UNKNOWN_TAG`, `BAD_LENGTH`, `INVALID_CONFIG`, `INVALID_POINT` (duration
//!    under 1 us), `UNSUPPORTED` (a report tag from a host).
//! 6. **state**: `BAD_STATE` when the command is not allowed in the current state
//!    (PROTOCOL.md, "Commands (host to controller)"; USART_SEND needs an open port that may
//!    transmit; PENDING must come from the endpoint that sent the NEW).
//! 7. **execute**: PENDING checks, in order: `OUT_OF_ORDER` (seq != `next_seq`),
//!    `TOO_MANY_POINTS`, `INVALID_POINT` (step rate), `BUFFER_FULL`; every point of the
//!    frame is checked before any is taken. USART_SEND: `BUFFER_FULL` when the serial
//!    transmit queue has no room. USART_START: `INVALID_CONFIG` when the port cannot apply
//!    the settings.
//!
//! A frame "accepted" is one ACKed `OK`: it is remembered for duplicate detection and it
//! counts for the PENDING ordering rule when it comes from the uploader (the endpoint,
//! address and port, that sent the NEW: another tool on the owner's machine numbers its
//! seqs on its own).
//!
//! # Who gets which report
//! The ACK and a STATUS report go to the command's sender. LOCATION goes to each of the
//! owner's endpoints (up to [`LOCATION_LISTENERS`]) whose commands were executed and that
//! have not been silent for 5 s; the endpoint that started the upload or run (NEW,
//! RETURN) or turned reports on (UPLOAD_START, UPLOAD_PERIOD) keeps them while anything
//! runs, however long it is silent. So no tool takes another's reports: a watcher keeps
//! its LOCATIONs while a poller polls, and an uploader that waits for its first LOCATION
//! gets it though another tool spoke last. USART_RECV goes to the endpoint that sent
//! USART_START. At first everything goes to the endpoint that became the owner; one tool
//! with one socket gets everything, as the manual has it.
//!
//! # Runs, reports and flags
//! * A run starts with RUNING (or RETURN) and ends in STOPPED three ways: every point
//!   ran (completion), the engine ran dry first (underrun: STATUS flag bit 5), or a
//!   STOPPED command (bit 7; also set by a STOPPED that drops an upload in NEW or
//!   PENDING, while a STOPPED in state STOPPED leaves both bits alone). Both bits are
//!   cleared when a run starts, so they tell how the last run ended.
//! * A LOCATION is produced at every state change while reports are on (UPLOAD_STOP
//!   turns all LOCATION reports off, the periodic ones and these).
//! * RETURN is accepted at once (ACK state RUNNING); the encoders are read by the caller
//!   ([`Deferred::ReadEncoders`]) and [`Controller::begin_return`] plans and starts the
//!   move. During it, PENDING is refused with `BAD_STATE` (the points are the
//!   controller's own); STOPPED and LOCATION work as in any run.
//!
//! # Overtaken frames
//! The tasks handle a STOPPED before datagrams queued ahead of it (the e-stop path in
//! [`crate::tasks`]). Such an overtaken frame is still handled with [`Controller::handle`]
//! (its ACK and duplicate memory as in arrival order: a resent RUNING is a duplicate, not
//! a new run), and [`Controller::stop_after_overtaken`] then applies the STOPPED that
//! followed it, so that the result is that of arrival order.
//!
//! # Effects
//! What must happen synchronously (the step engine, pins, gripper, serial port) goes
//! through the [`Plant`] trait; what needs waiting (flash, encoders) comes back as a
//! [`Deferred`] in the [`Response`].

use protocol::{
    Ack, Command, Frame, Location, MAX_JOINTS, MAX_POINTS_PER_FRAME, MoreFlags, Pwm, State,
    StatusCode, StatusFlags, StatusReport, Tag, UartInit, UartMode, limits,
};
use protocol::{DecodeError, DecodeErrorKind};
use protocol::{DiscoverReply, NetSettings, OwnerState};

use core::mem::MaybeUninit;

use arm_step::Segment;

use crate::buffer::{StoredPoint, TrajectoryBuffer};
use crate::config::{ControllerConfig, HOST_WINDOW, OWNER_TIMEOUT_US};
use crate::hw::{EncoderFault, Endpoint, PersistentSettings, SerialError};
use crate::link::{FrameKey, RecentFrames, UploadOrder};
use crate::plan::{ReturnPlan, plan_return};

/// Every ENABLE line: joints 0-7 and the gripper (bit 8).
pub const ALL_DRIVERS: u16 = limits::ENABLE_MASK_BITS;

/// What the controller drives and queries synchronously while it handles a command.
///
/// The firmware's implementation talks to the step engine shared with the step timer
/// interrupt, the output pins, the gripper timer and the serial task's queue; tests use a
/// fake that records every call.
pub trait Plant {
    /// Joint positions in steps, counted per pulse emitted.
    fn positions(&self) -> [i32; MAX_JOINTS];
    /// Overwrites the position counters (only called while no segment runs); `false` if
    /// refused.
    fn set_positions(&mut self, positions: [i32; MAX_JOINTS]) -> bool;
    /// Emergency stop: no further step pulse, every segment handed over is dropped.
    fn stop(&mut self);
    /// Hands over the next segment of the trajectory; `false` when there is no room now
    /// (offered again later).
    fn push_segment(&mut self, segment: Segment) -> bool;
    /// Starts executing the segments handed over (and those that follow) as soon as the
    /// first one is in the engine.
    fn start(&mut self);
    /// Drives user pin 0 or 1.
    fn set_user_pin(&mut self, pin: u8, high: bool);
    /// Sets the ENABLE lines: bit j = joint j holding, bit 8 = gripper.
    fn set_enabled(&mut self, enabled: u16);
    /// Starts the gripper PWM (values already validated).
    fn gripper_start(&mut self, pwm: &Pwm);
    /// Gripper output off at once.
    fn gripper_stop(&mut self);
    /// Whether the gripper output runs (a counted burst ends by itself).
    fn gripper_active(&self) -> bool;
    /// Opens (or reopens) the pass-through serial port.
    fn serial_open(&mut self, init: &UartInit) -> Result<(), SerialError>;
    /// Closes it; whatever was not yet written is dropped.
    fn serial_close(&mut self);
    /// Queues bytes for the serial port; `false` when the queue has no room.
    fn serial_send(&mut self, bytes: &[u8]) -> bool;
}

/// Work that needs waiting, left to the caller (the trajectory task).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Deferred {
    /// Store these settings ([`crate::hw::SettingsStore::save`]).
    SaveSettings(PersistentSettings),
    /// RETURN was accepted: read the encoders ([`crate::hw::Encoders::read`]) and pass
    /// the result to [`Controller::begin_return`].
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
    /// Work left to the caller.
    pub deferred: Option<Deferred>,
    /// The command was executed: ACKed `OK` and not a duplicate. Only an executed STOPPED
    /// stops anything (the e-stop path in [`crate::tasks`] relies on it).
    pub executed: bool,
    /// The answer to a DISCOVER, for its sender (instead of an ACK).
    pub discovery: Option<Discovery>,
}

/// A DISCOVER_REPLY for the host that asked (PROTOCOL.md, "Finding controllers and setting
/// their address").
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

/// The host that owns the controller.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Owner {
    /// Its IPv4 address.
    pub ip: [u8; 4],
    /// When it last sent a CRC-valid frame, microseconds.
    pub last_heard_us: u64,
}

/// Owner endpoints that get the LOCATION reports at once: a few tools on the owner's
/// machine (an uploader, a watcher, a poller, one more), each a socket of its own.
pub const LOCATION_LISTENERS: usize = 4;

/// An owner endpoint that gets LOCATION reports (see "Who gets which report").
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
struct Listener {
    /// The endpoint.
    to: Endpoint,
    /// When it last sent a CRC-valid frame, microseconds: silent [`OWNER_TIMEOUT_US`], it
    /// stops getting reports (unless it started the upload or run under way).
    heard_us: u64,
}

/// Settings the location upload needs, copied out after every change.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ReportSettings {
    /// Where LOCATION reports go: each of these owner endpoints (none before any host
    /// spoke).
    pub location_to: [Option<Endpoint>; LOCATION_LISTENERS],
    /// Where USART_RECV reports go (`None` before any host spoke).
    pub serial_to: Option<Endpoint>,
    /// LOCATION reports on.
    pub reports_on: bool,
    /// LOCATION period, microseconds.
    pub upload_period_us: u32,
    /// The trajectory state.
    pub state: State,
}

impl ReportSettings {
    /// Whether a LOCATION report has anywhere to go.
    pub fn has_location_listener(&self) -> bool {
        self.location_to.iter().any(Option::is_some)
    }

    /// Whether `endpoint` gets LOCATION reports.
    pub fn location_goes_to(&self, endpoint: Endpoint) -> bool {
        self.location_to.contains(&Some(endpoint))
    }

    /// Before the trajectory task first publishes the controller's: no report anywhere,
    /// period 0 (the upload task waits for the first publication). All zero bytes, so that
    /// a [`crate::Bus`] in a `static` is zero-initialised (`.bss`, not a flash copy).
    pub const UNPUBLISHED: ReportSettings = ReportSettings {
        location_to: [None; LOCATION_LISTENERS],
        serial_to: None,
        reports_on: false,
        upload_period_us: 0,
        state: State::New,
    };

    /// Boot values: reports on at the default period, nobody to send them to yet.
    pub const BOOT: ReportSettings = ReportSettings {
        location_to: [None; LOCATION_LISTENERS],
        serial_to: None,
        reports_on: true,
        upload_period_us: limits::DEFAULT_UPLOAD_PERIOD_US,
        state: State::Stopped,
    };
}

/// The controller: state machine, trajectory buffer, owner and reliability rules.
///
/// `CAP` is the trajectory buffer's compile-time size (see
/// [`crate::config::BOARD_TRAJECTORY_CAPACITY`]); `config.capacity` may use less of it.
/// Construct it in a static (`new` is `const`): with 8192 points it is 300 KB.
pub struct Controller<const CAP: usize> {
    config: ControllerConfig,
    settings: PersistentSettings,
    state: State,
    buffer: TrajectoryBuffer<CAP>,
    /// Points the current trajectory has (NEW's count, or RETURN's).
    expected: u32,
    /// Points of it received.
    received: u32,
    /// Points of it finished.
    executed: u32,
    /// End position of the last point received (the next point's previous position).
    received_end: [i32; MAX_JOINTS],
    /// End position of the last point handed to the engine.
    fed_end: [i32; MAX_JOINTS],
    /// RETURN accepted, waiting for the encoder reading.
    return_pending: bool,
    /// RETURN running: its remaining points.
    return_plan: Option<ReturnPlan>,
    /// Why the last RETURN was refused after its ACK (an encoder did not answer); cleared
    /// by the next RETURN.
    return_fault: Option<EncoderFault>,
    order: UploadOrder,
    /// The endpoint whose NEW started the upload: only its frames count for the ordering
    /// rule, so another tool on the owner's machine cannot fill the upload's gaps.
    uploader: Option<Endpoint>,
    recent: RecentFrames,
    owner: Option<Owner>,
    /// The owner's endpoints that get LOCATION reports.
    listeners: [Option<Listener>; LOCATION_LISTENERS],
    /// The endpoint that started the upload or run (NEW, RETURN) or turned reports on
    /// (UPLOAD_START, UPLOAD_PERIOD): it keeps its LOCATION reports while anything runs,
    /// however long it is silent.
    location_claimer: Option<Endpoint>,
    /// Where USART_RECV reports go: the endpoint that sent USART_START.
    serial_to: Option<Endpoint>,
    /// STATUS `more_flags`.
    more_flags: MoreFlags,
    reports_on: bool,
    upload_period_us: u32,
    enabled: u16,
    pins: [bool; 2],
    serial: Option<UartMode>,
    underrun: bool,
    stopped_by_host: bool,
    /// Ethernet MAC, for DISCOVER_REPLY.
    mac: [u8; 6],
    /// The network settings loaded at boot (the ones in use); NET_SET stores others.
    booted_net: NetSettings,
    /// Steps per second of all joints together that points may ask for (0: no limit).
    step_budget_hz: u32,
}

/// The boot value of every [`Controller`] field but the trajectory buffer, written once for
/// [`Controller::new`] (a struct literal: the compiler checks that no field is missing) and
/// [`Controller::init_in_place`] (the same list, each field written where it lies).
/// `$emit!($($head)* ; field: value, ...)` is called with the list.
macro_rules! with_boot_fields {
    ($config:expr, $emit:ident!($($head:tt)*)) => {
        $emit!($($head)* ;
        config: $config,
        settings: PersistentSettings::DEFAULT,
        state: State::Stopped,
        expected: 0,
        received: 0,
        executed: 0,
        received_end: [0; MAX_JOINTS],
        fed_end: [0; MAX_JOINTS],
        return_pending: false,
        return_plan: None,
        return_fault: None,
        order: UploadOrder::new(),
        uploader: None,
        recent: RecentFrames::new(),
        owner: None,
        listeners: [None; LOCATION_LISTENERS],
        location_claimer: None,
        serial_to: None,
        more_flags: MoreFlags(0),
        reports_on: true,
        upload_period_us: limits::DEFAULT_UPLOAD_PERIOD_US,
        enabled: ALL_DRIVERS,
        pins: [false; 2],
        serial: None,
        underrun: false,
        stopped_by_host: false,
        mac: [0; 6],
        booted_net: NetSettings::fixed([192, 168, 1, 30], 24, None),
        step_budget_hz: crate::config::BOARD_STEP_BUDGET_HZ,
        )
    };
}

/// `Controller { buffer, boot fields }`: see `with_boot_fields`.
macro_rules! controller_literal {
    ($buffer:expr ; $($field:ident : $value:expr),* $(,)?) => {
        Controller { buffer: $buffer, $($field: $value),* }
    };
}

/// Writes each boot field through the pointer `$slot`: see `with_boot_fields`.
macro_rules! write_fields {
    ($slot:expr ; $($field:ident : $value:expr),* $(,)?) => {
        $( (&raw mut (*$slot).$field).write($value); )*
    };
}

impl<const CAP: usize> Controller<CAP> {
    /// A controller in its boot state: STOPPED, drivers enabled, reports on.
    pub const fn new(config: ControllerConfig) -> Self {
        with_boot_fields!(
            config,
            controller_literal!(TrajectoryBuffer::new(config.capacity))
        )
    }

    /// Builds a controller in its boot state in place, in `slot` (a static's storage), and
    /// returns it: the same value as [`Controller::new`], but never built on the stack first.
    /// A board's controller is 300 KB, more than its stack; `StaticCell::init(new())` relies
    /// on the compiler to elide that copy, which it does not at every optimisation level.
    pub fn init_in_place(slot: &mut MaybeUninit<Self>, config: ControllerConfig) -> &mut Self {
        let p = slot.as_mut_ptr();
        // SAFETY: `p` points to `slot`'s storage, valid for writes and aligned; every field
        // is written below (the buffer by its own in-place constructor, the others from the
        // list that `new`'s struct literal proves complete), so the value is initialised.
        unsafe {
            TrajectoryBuffer::init_in_place(&raw mut (*p).buffer, config.capacity);
            with_boot_fields!(config, write_fields!(p));
            slot.assume_init_mut()
        }
    }

    /// Sets the MAC address DISCOVER_REPLY reports (at boot).
    pub fn set_mac(&mut self, mac: [u8; 6]) {
        self.mac = mac;
    }

    /// The DISCOVER_REPLY for a host at `asker`: changes nothing.
    fn discovery(&self, asker: [u8; 4], now_us: u64) -> DiscoverReply {
        // An owner silent for 5 s with the arm not running has lost the arm already.
        let owner = self.owner.filter(|o| {
            self.state == State::Running
                || now_us.saturating_sub(o.last_heard_us) < OWNER_TIMEOUT_US
        });
        let net = self.settings.net();
        DiscoverReply {
            mac: self.mac,
            net,
            version: protocol::VERSION,
            joints: self.settings.joints,
            state: self.state,
            owner: match owner {
                None => OwnerState::Free,
                Some(o) if o.ip == asker => OwnerState::Asker,
                Some(_) => OwnerState::Other,
            },
            owner_ip: owner.map_or([0; 4], |o| o.ip),
            pending_reset: net != self.booted_net,
        }
    }

    /// Applies stored settings (at boot); an out-of-range joint count keeps the default.
    pub fn apply_settings(&mut self, settings: PersistentSettings) {
        self.settings = settings;
        self.booted_net = settings.net();
        if !limits::JOINTS.contains(&settings.joints) {
            self.settings.joints = limits::DEFAULT_JOINTS;
        }
    }

    /// Replaces the configuration (at boot, before any command: the trajectory buffer is
    /// emptied). Lets a board build the controller as a `const` in a static (no 300 KB
    /// value on the stack) and apply the configuration it computes at run time.
    pub fn reconfigure(&mut self, config: ControllerConfig) {
        self.config = config;
        self.buffer.set_capacity(config.capacity);
    }

    /// Sets the gripper timer's input clock reported in STATUS (the trajectory task takes
    /// it from the [`crate::hw::Gripper`] at start).
    pub fn set_pwm_timer_clock_hz(&mut self, hz: u32) {
        self.config.pwm_timer_clock_hz = hz;
    }

    /// Sets the steps per second of all joints together that points may ask for (STATUS
    /// `step_budget_hz`; 0: no limit beyond the per-joint one). Boot default:
    /// [`crate::config::BOARD_STEP_BUDGET_HZ`].
    pub fn set_step_budget_hz(&mut self, hz: u32) {
        self.step_budget_hz = hz;
    }

    /// The settings as they should be stored.
    pub fn settings(&self) -> PersistentSettings {
        self.settings
    }

    /// The configuration.
    pub fn config(&self) -> &ControllerConfig {
        &self.config
    }

    /// The trajectory state.
    pub fn state(&self) -> State {
        self.state
    }

    /// Joints in use.
    pub fn joints(&self) -> u8 {
        self.settings.joints
    }

    /// The owner, if any host has spoken.
    pub fn owner(&self) -> Option<Owner> {
        self.owner
    }

    /// The endpoint whose NEW started the current upload (its frames alone count for the
    /// ordering rule).
    pub fn uploader(&self) -> Option<Endpoint> {
        self.uploader
    }

    /// The ENABLE lines as they should be driven (bit 8 = gripper).
    pub fn enabled(&self) -> u16 {
        self.enabled
    }

    /// LOCATION period, microseconds.
    pub fn upload_period_us(&self) -> u32 {
        self.upload_period_us
    }

    /// What the location upload needs to know.
    pub fn report_settings(&self) -> ReportSettings {
        ReportSettings {
            location_to: self.listeners.map(|l| l.map(|l| l.to)),
            serial_to: self.serial_to,
            reports_on: self.reports_on,
            upload_period_us: self.upload_period_us,
            state: self.state,
        }
    }

    /// Points held (received, not finished).
    pub fn buffered(&self) -> usize {
        self.buffer.buffered()
    }

    /// Free trajectory slots.
    pub fn free(&self) -> usize {
        self.buffer.free()
    }

    /// Points in use by design (`config.capacity` clamped to `CAP`).
    pub fn capacity(&self) -> usize {
        self.buffer.capacity()
    }

    /// The seq the next PENDING must carry.
    pub fn next_seq(&self) -> u8 {
        self.order.next_seq()
    }

    /// A LOCATION report of the current positions and state.
    pub fn location(&self, plant: &impl Plant) -> Location {
        Location {
            position: plant.positions(),
            state: self.state as u8,
        }
    }

    /// The STATUS report.
    pub fn status(&self, plant: &impl Plant) -> StatusReport {
        let mut flags = StatusFlags::default();
        flags.set(StatusFlags::REPORTS_ON, self.reports_on);
        flags.set(StatusFlags::DRIVERS_ENABLED, self.enabled != 0);
        flags.set(StatusFlags::SERIAL_OPEN, self.serial.is_some());
        flags.set(StatusFlags::PIN0_HIGH, self.pins[0]);
        flags.set(StatusFlags::PIN1_HIGH, self.pins[1]);
        flags.set(StatusFlags::UNDERRUN, self.underrun);
        flags.set(StatusFlags::PWM_ACTIVE, plant.gripper_active());
        flags.set(StatusFlags::STOPPED_BY_HOST, self.stopped_by_host);
        StatusReport {
            version: protocol::VERSION,
            joints: self.settings.joints,
            state: self.state,
            flags,
            window: saturate(HOST_WINDOW),
            buffered: saturate(self.buffer.buffered()),
            expected: saturate(self.expected as usize),
            received: saturate(self.received as usize),
            executed: saturate(self.executed as usize),
            capacity: saturate(self.buffer.capacity()),
            more_flags: self.more_flags,
            upload_period_us: self.upload_period_us,
            pwm_timer_clock_hz: self.config.pwm_timer_clock_hz,
            max_step_rate_hz: self.config.max_step_rate_hz,
            step_budget_hz: self.step_budget_hz,
        }
    }

    fn ack(&self, to: Endpoint, seq: u8, tag: u8, status: StatusCode) -> Reply {
        Reply {
            to,
            seq,
            ack: Ack {
                acked_tag: tag,
                status,
                state: self.state,
                next_seq: self.order.next_seq(),
                buffered: saturate(self.buffer.buffered()),
                free: saturate(self.buffer.free()),
            },
        }
    }

    /// Handles one datagram from `from` received at `now_us` (see the module docs for the
    /// order of checks).
    pub fn handle(
        &mut self,
        from: Endpoint,
        datagram: &[u8],
        now_us: u64,
        plant: &mut impl Plant,
    ) -> Response {
        let before = self.state;
        let mut response = self.check_and_execute(from, datagram, now_us, plant);
        // A state change (the command's, or a hand-over that dropped an upload before the
        // command was refused) is reported at once.
        if self.state != before && self.reports_on {
            response.location = Some(self.location(plant));
        }
        response
    }

    /// [`Controller::handle`] but for the LOCATION of a state change.
    fn check_and_execute(
        &mut self,
        from: Endpoint,
        datagram: &[u8],
        now_us: u64,
        plant: &mut impl Plant,
    ) -> Response {
        let mut response = Response::default();
        // 1. length
        let [seq, tag, .., crc] = *datagram else {
            return response;
        };
        let reply = |c: &Self, status| Some(c.ack(from, seq, tag, status));
        // Decoding has no side effects, so it runs once here (checking the CRC once);
        // its verdict is applied in the documented order below.
        let decoded = Command::decode(datagram);
        // 2. CRC
        if let Err(DecodeError {
            kind: DecodeErrorKind::BadCrc { .. },
            ..
        }) = decoded
        {
            response.reply = reply(self, StatusCode::BadCrc);
            return response;
        }
        // DISCOVER (PROTOCOL.md, "Finding controllers and setting their address"): answered
        // to any host, before the owner rule, with a DISCOVER_REPLY instead of an ACK; it
        // changes nothing (no owner, no duplicate memory, no ordering mark, no LOCATION
        // listener).
        if tag == Tag::Discover as u8 && datagram.len() == protocol::FRAME_OVERHEAD {
            response.discovery = Some(Discovery {
                to: from,
                seq,
                reply: self.discovery(from.ip, now_us),
            });
            return response;
        }
        // 3. owner
        let from_owner = match self.owner {
            None => {
                self.take_over(from, now_us, plant);
                true
            }
            Some(ref mut owner) if owner.ip == from.ip => {
                owner.last_heard_us = now_us;
                for listener in self.listeners.iter_mut().flatten() {
                    if listener.to == from {
                        listener.heard_us = now_us;
                    }
                }
                true
            }
            Some(owner)
                if self.state != State::Running
                    && now_us.saturating_sub(owner.last_heard_us) >= OWNER_TIMEOUT_US =>
            {
                self.take_over(from, now_us, plant);
                true
            }
            Some(_) if tag == Tag::Stopped as u8 => false,
            Some(_) => {
                // Tells a stranger nothing about the arm: zeros (PROTOCOL.md, "Status codes").
                response.reply = Some(Reply {
                    to: from,
                    seq,
                    ack: Ack {
                        acked_tag: tag,
                        status: StatusCode::NotOwner,
                        state: State::New,
                        next_seq: 0,
                        buffered: 0,
                        free: 0,
                    },
                });
                return response;
            }
        };
        // 4. duplicate
        let key = FrameKey {
            from,
            seq,
            tag,
            crc,
        };
        if self.recent.contains(&key, now_us) {
            response.reply = reply(self, StatusCode::Ok);
            return response;
        }
        // 5. decode
        let frame = match decoded {
            Ok(frame) => frame,
            Err(e) => {
                response.reply = reply(self, e.status().unwrap_or(StatusCode::BadLength));
                return response;
            }
        };
        // 6. state and 7. execute
        let status = match self.execute(frame, from, plant, &mut response) {
            Ok(()) => {
                self.executed(key, from_owner, now_us);
                response.executed = true;
                StatusCode::Ok
            }
            Err(status) => status,
        };
        self.pump(plant);
        response.reply = reply(self, status);
        response
    }

    /// Bookkeeping for an executed frame. (A duplicate's seq was marked when the frame
    /// was executed: marking it again once the upload has moved past it would mark that
    /// seq a lap (256) ahead, and a PENDING lost there would be skipped.)
    fn executed(&mut self, key: FrameKey, from_owner: bool, now_us: u64) {
        self.recent.remember(key, now_us);
        if self.uploader == Some(key.from) {
            self.order.mark(key.seq);
        }
        if !from_owner {
            return;
        }
        let claims_location = [Tag::New, Tag::Return, Tag::UploadStart, Tag::UploadPeriod]
            .iter()
            .any(|t| *t as u8 == key.tag);
        if claims_location {
            self.location_claimer = Some(key.from);
        }
        if key.tag == Tag::UsartStart as u8 {
            self.serial_to = Some(key.from);
        }
        self.listen(key.from, now_us);
    }

    /// `from`, an owner endpoint whose command was executed, gets LOCATION reports from
    /// now on: it takes a free slot, or that of a listener silent for 5 s, or else that of
    /// the one heard least recently (never the claimer's while something runs).
    fn listen(&mut self, from: Endpoint, now_us: u64) {
        let keep_claimer = self.state != State::Stopped;
        let claimer = self.location_claimer;
        let protected = |l: &Listener| keep_claimer && Some(l.to) == claimer;
        for slot in self.listeners.iter_mut() {
            if slot.is_some_and(|l| {
                !protected(&l) && now_us.saturating_sub(l.heard_us) >= OWNER_TIMEOUT_US
            }) {
                *slot = None;
            }
        }
        let fresh = Listener {
            to: from,
            heard_us: now_us,
        };
        if let Some(slot) = self.listeners.iter_mut().flatten().find(|l| l.to == from) {
            *slot = fresh;
            return;
        }
        if let Some(slot) = self.listeners.iter_mut().find(|l| l.is_none()) {
            *slot = Some(fresh);
            return;
        }
        let oldest = self
            .listeners
            .iter_mut()
            .filter(|l| l.is_some_and(|l| !protected(&l)))
            .min_by_key(|l| l.map_or(0, |l| l.heard_us));
        if let Some(slot) = oldest {
            *slot = Some(fresh);
        }
    }

    /// `from` becomes the owner (the first host, or a new one after the owner's 5 s of
    /// silence, not while running): every report goes to it, and an upload the old owner
    /// had not started is dropped, so that the new owner's RUNING cannot run half of it.
    fn take_over(&mut self, from: Endpoint, now_us: u64, plant: &mut impl Plant) {
        self.owner = Some(Owner {
            ip: from.ip,
            last_heard_us: now_us,
        });
        self.listeners = [None; LOCATION_LISTENERS];
        self.listeners[0] = Some(Listener {
            to: from,
            heard_us: now_us,
        });
        self.location_claimer = Some(from);
        self.serial_to = Some(from);
        self.uploader = None;
        if matches!(self.state, State::New | State::Pending) {
            plant.stop();
            self.buffer.clear();
            self.return_plan = None;
            self.return_pending = false;
            self.state = State::Stopped;
            self.more_flags.set(MoreFlags::UPLOAD_DROPPED, true);
            warn!("owner hand-over: the old owner's unstarted upload was dropped");
        }
    }

    fn execute(
        &mut self,
        frame: Frame<Command<'_>>,
        from: Endpoint,
        plant: &mut impl Plant,
        response: &mut Response,
    ) -> Result<(), StatusCode> {
        let stopped_only = |c: &Self| {
            if c.state == State::Stopped {
                Ok(())
            } else {
                Err(StatusCode::BadState)
            }
        };
        match frame.body {
            Command::New { count } => {
                if self.state == State::Running {
                    return Err(StatusCode::BadState);
                }
                // An upload not yet running is dropped, with whatever was pre-fed.
                plant.stop();
                self.buffer.clear();
                self.return_plan = None;
                self.return_pending = false;
                self.expected = u32::from(count);
                self.received = 0;
                self.executed = 0;
                self.received_end = plant.positions();
                self.fed_end = self.received_end;
                self.order.restart(frame.seq);
                self.uploader = Some(from);
                self.more_flags.set(MoreFlags::UPLOAD_DROPPED, false);
                self.state = State::New;
            }
            Command::Pending(points) => {
                let uploading = matches!(self.state, State::New | State::Pending)
                    || (self.state == State::Running && self.return_plan.is_none());
                if !uploading || self.return_pending {
                    return Err(StatusCode::BadState);
                }
                // The upload under way is another endpoint's: its points are the ones
                // that sender numbered, never a second tool's.
                if self.uploader != Some(from) {
                    return Err(StatusCode::BadState);
                }
                if !self.order.in_order(frame.seq) {
                    return Err(StatusCode::OutOfOrder);
                }
                let n = points.len();
                if self.received as usize + n > self.expected as usize {
                    return Err(StatusCode::TooManyPoints);
                }
                // Every point is checked before any is taken.
                let mut admitted = [StoredPoint::default(); MAX_POINTS_PER_FRAME];
                let mut previous = self.received_end;
                for (slot, point) in admitted.iter_mut().zip(points.iter()) {
                    *slot = self
                        .admit(&previous, &point)
                        .ok_or(StatusCode::InvalidPoint)?;
                    previous = slot.position;
                }
                if n > self.buffer.free() {
                    return Err(StatusCode::BufferFull);
                }
                for stored in admitted.iter().take(n) {
                    if self.buffer.push(*stored) {
                        self.received_end = stored.position;
                        self.received += 1;
                    }
                }
                self.order.take(frame.seq);
                if self.state == State::New {
                    self.state = State::Pending;
                }
            }
            Command::Runing => match self.state {
                State::Pending => {
                    self.underrun = false;
                    self.stopped_by_host = false;
                    self.state = State::Running;
                    self.pump(plant);
                    plant.start();
                }
                State::Running => {}
                _ => return Err(StatusCode::BadState),
            },
            Command::Stopped => self.stop_by_host(plant),
            Command::UploadStart => self.reports_on = true,
            Command::UploadStop => self.reports_on = false,
            Command::PwmStart(pwm) => plant.gripper_start(&pwm),
            Command::PwmStop => plant.gripper_stop(),
            Command::UsartStart(init) => {
                plant
                    .serial_open(&init)
                    .map_err(|_| StatusCode::InvalidConfig)?;
                self.serial = Some(init.mode());
            }
            Command::UsartStop => {
                plant.serial_close();
                self.serial = None;
            }
            Command::UsartSend(bytes) => {
                match self.serial {
                    None | Some(UartMode::ReceiveOnly) => return Err(StatusCode::BadState),
                    Some(_) => {}
                }
                if !plant.serial_send(bytes) {
                    return Err(StatusCode::BufferFull);
                }
            }
            Command::Pin0On | Command::Pin0Off | Command::Pin1On | Command::Pin1Off => {
                let pin = u8::from(matches!(frame.body, Command::Pin1On | Command::Pin1Off));
                let high = matches!(frame.body, Command::Pin0On | Command::Pin1On);
                plant.set_user_pin(pin, high);
                if let Some(p) = self.pins.get_mut(usize::from(pin)) {
                    *p = high;
                }
            }
            Command::ToggleEnablePins { mask } => {
                stopped_only(self)?;
                self.enabled ^= mask.unwrap_or(ALL_DRIVERS) & ALL_DRIVERS;
                plant.set_enabled(self.enabled);
            }
            Command::Return => {
                stopped_only(self)?;
                self.buffer.clear();
                self.return_plan = None;
                self.return_pending = true;
                self.return_fault = None;
                self.underrun = false;
                self.stopped_by_host = false;
                self.state = State::Running;
                response.deferred = Some(Deferred::ReadEncoders);
            }
            Command::JointsCount(joints) => {
                stopped_only(self)?;
                self.settings.joints = joints;
                response.deferred = Some(Deferred::SaveSettings(self.settings));
            }
            Command::LocationSetting(location) => {
                stopped_only(self)?;
                if !plant.set_positions(location.position) {
                    return Err(StatusCode::BadState);
                }
            }
            Command::Status => response.status = Some((from, self.status(plant))),
            Command::UploadPeriod { period_us } => self.upload_period_us = period_us,
            // Answered in `handle` before the owner rule; never reaches here.
            Command::Discover => {}
            // Stored now, applied after the next reset (PROTOCOL.md, "Finding controllers
            // and setting their address").
            Command::NetSet(net) => {
                if self.state == State::Running {
                    return Err(StatusCode::BadState);
                }
                self.settings.set_net(net);
                response.deferred = Some(Deferred::SaveSettings(self.settings));
            }
        }
        Ok(())
    }

    /// STOPPED's execution: no further pulse, the trajectory dropped, state STOPPED.
    fn stop_by_host(&mut self, plant: &mut impl Plant) {
        plant.stop();
        self.buffer.clear();
        self.return_plan = None;
        self.return_pending = false;
        // Bits 5 and 7 tell how the last trajectory ended: a STOPPED with none under way
        // (already STOPPED) leaves them alone.
        if self.state != State::Stopped {
            self.underrun = false;
            self.stopped_by_host = true;
        }
        self.state = State::Stopped;
    }

    /// Applies a STOPPED that arrived after the frame just handled but was handled before
    /// it (see "Overtaken frames" in the module docs): what STOPPED's execution does,
    /// without an ACK, and nothing when the state is STOPPED already. Call it right after
    /// [`Controller::handle`], with no wait in between, so that a run that frame started
    /// never emits a pulse. Returns a LOCATION report when the state changed (reports on).
    pub fn stop_after_overtaken(&mut self, plant: &mut impl Plant) -> Option<Location> {
        if self.state == State::Stopped {
            return None;
        }
        self.stop_by_host(plant);
        self.reports_on.then(|| self.location(plant))
    }

    /// The stored form of `point` after `previous`, if it obeys PROTOCOL.md's "Point (116
    /// bytes)" and "Step rate budget": for every joint in use, at most `max_step_rate_hz`
    /// steps per second and a step count that fits a segment, and all joints together at
    /// most `step_budget_hz` steps per second. Joints not in use keep their previous
    /// position.
    fn admit(&self, previous: &[i32; MAX_JOINTS], point: &protocol::Point) -> Option<StoredPoint> {
        let duration = u32::try_from(point.duration).ok().filter(|d| *d >= 1)?;
        let joints = usize::from(self.settings.joints).min(MAX_JOINTS);
        let mut position = *previous;
        let mut total_steps = 0u64;
        for (j, p) in position.iter_mut().enumerate().take(joints) {
            let steps = point.steps(previous, j).unsigned_abs();
            total_steps += steps;
            // steps < 2^33 and duration < 2^31: both products fit u64.
            let too_fast =
                steps * 1_000_000 > u64::from(self.config.max_step_rate_hz) * u64::from(duration);
            if too_fast || steps > i32::MAX as u64 {
                return None;
            }
            *p = point.position[j];
        }
        // total_steps < 2^36: the product fits u64.
        let budget = u64::from(self.step_budget_hz);
        if budget > 0 && total_steps * 1_000_000 > budget * u64::from(duration) {
            return None;
        }
        Some(StoredPoint {
            duration_us: duration,
            position,
        })
    }

    /// Hands as many buffered points to the engine as it takes (and, during RETURN, tops
    /// the buffer up from the plan first).
    pub fn pump(&mut self, plant: &mut impl Plant) {
        if let Some(plan) = self.return_plan.as_mut() {
            while self.buffer.free() > 0 {
                let Some(point) = plan.next() else { break };
                if self.buffer.push(point) {
                    self.received += 1;
                }
            }
        }
        if !matches!(self.state, State::Pending | State::Running) {
            return;
        }
        while let Some(point) = self.buffer.next_unfed() {
            let mut steps = [0i32; MAX_JOINTS];
            for (j, s) in steps.iter_mut().enumerate() {
                let delta = i64::from(point.position[j]) - i64::from(self.fed_end[j]);
                *s = delta.clamp(i64::from(i32::MIN), i64::from(i32::MAX)) as i32;
            }
            let segment = Segment {
                duration_us: point.duration_us,
                steps,
            };
            if !plant.push_segment(segment) {
                break;
            }
            self.buffer.mark_fed();
            self.fed_end = point.position;
        }
    }

    /// The engine finished `finished` more segments and, if `ran_dry`, ran out of them
    /// and stopped. Ends the run (completion or underrun) when it ran dry, feeds more
    /// points otherwise. Returns a LOCATION report when the state changed.
    pub fn on_step_progress(
        &mut self,
        finished: u32,
        ran_dry: bool,
        plant: &mut impl Plant,
    ) -> Option<Location> {
        let done = self.buffer.finish(finished as usize);
        self.executed = self.executed.saturating_add(done as u32);
        if ran_dry && self.state == State::Running && !self.return_pending {
            let complete = self.executed >= self.expected;
            // Clears anything pushed after the engine went idle.
            plant.stop();
            self.buffer.clear();
            self.return_plan = None;
            self.underrun = !complete;
            self.stopped_by_host = false;
            self.state = State::Stopped;
            return self.reports_on.then(|| self.location(plant));
        }
        self.pump(plant);
        None
    }

    /// Ends an accepted RETURN whose encoder read failed: nothing moves, the state goes
    /// back to STOPPED (neither underrun nor STOPPED-by-host: the run never started) and
    /// the fault is kept for [`Controller::return_fault`]. Returns a LOCATION report when
    /// the state changed (reports on).
    pub fn fail_return(&mut self, fault: EncoderFault, plant: &mut impl Plant) -> Option<Location> {
        if !self.return_pending || self.state != State::Running {
            return None;
        }
        self.return_pending = false;
        self.return_plan = None;
        self.buffer.clear();
        // A RETURN of no points: STATUS shows expected = executed = 0, not the last run's.
        self.expected = 0;
        self.received = 0;
        self.executed = 0;
        self.underrun = false;
        self.stopped_by_host = false;
        self.return_fault = Some(fault);
        self.state = State::Stopped;
        self.reports_on.then(|| self.location(plant))
    }

    /// Why the last RETURN was refused after its ACK (`None`: it was not, or no RETURN
    /// since boot).
    pub fn return_fault(&self) -> Option<EncoderFault> {
        self.return_fault
    }

    /// Continues an accepted RETURN with the encoder reading (`None`: no encoders, trust
    /// the step count): corrects the positions of the joints in use if they differ, plans
    /// the move to zero and starts it. Returns a LOCATION report when the state changed
    /// (nothing to move: back to STOPPED).
    pub fn begin_return(
        &mut self,
        encoders: Option<[i32; MAX_JOINTS]>,
        plant: &mut impl Plant,
    ) -> Option<Location> {
        if !self.return_pending || self.state != State::Running {
            return None;
        }
        self.return_pending = false;
        let joints = usize::from(self.settings.joints).min(MAX_JOINTS);
        let mut start = plant.positions();
        if let Some(read) = encoders {
            let mut corrected = start;
            corrected[..joints].copy_from_slice(&read[..joints]);
            if corrected != start && plant.set_positions(corrected) {
                start = corrected;
            }
        }
        let plan = plan_return(start, self.settings.joints, &self.config);
        self.buffer.clear();
        self.expected = plan.total_points();
        self.received = 0;
        self.executed = 0;
        self.received_end = start;
        self.fed_end = start;
        if plan.total_points() == 0 {
            self.state = State::Stopped;
            return self.reports_on.then(|| self.location(plant));
        }
        self.return_plan = Some(plan);
        self.pump(plant);
        plant.start();
        None
    }
}

fn saturate(n: usize) -> u16 {
    u16::try_from(n).unwrap_or(u16::MAX)
}
