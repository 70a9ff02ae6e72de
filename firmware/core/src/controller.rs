//! The controller's behaviour, sans-io: one datagram in, an ACK, reports and effects out.
//!
//! # Check order
//! Every datagram goes through these checks, in this order; the first that fails decides
//! the ACK's status and nothing further is done:
//! 1. **length**: fewer than 3 bytes: no reply at all.
//!    - then (1a) **authentication**, only with a key set (docs/PROTOCOL.md section 13,
//!      `authenticate`): a plain frame with a wrong CRC is `BAD_CRC` with the NOT_OWNER
//!      zeros; plain STOPPED and DISCOVER go on; HELLO opens a session (a HELLO_REPLY, no
//!      ACK); an envelope whose MAC, session and counter verify is replaced by its inner
//!      frame, which every check below then takes; anything else is `AUTH_REQUIRED`
//!      (plain) or `AUTH_FAILED` (an envelope), with the NOT_OWNER zeros, before it can
//!      take the owner.
//! 2. **CRC**: `BAD_CRC`, ACKed to the sender with the frame's seq and tag. A frame with a
//!    bad CRC never changes the owner.
//! 3. **STOPPED**: a CRC-valid STOPPED stops the arm and is ACKed `OK`, from any
//!    sender, in any state, whatever its data (ignored); it is never a duplicate, takes
//!    no owner and is not remembered (issue 18: a spurious stop is safe, an ignored one
//!    is not). The checks below never see it.
//!    - then (3a) **STATUS and RELEASE from a host that does not own the controller**
//!      (issue 23, `not_owner_status_or_release`): STATUS while another host holds the
//!      controller (or asking only to look) is answered read-only, with the request's seq,
//!      the NOT_OWNER zeros in the ACK and nothing taken, at most
//!      [`DISCOVER_REPLIES_PER_S`] a second; RELEASE is `OK` with nothing done when
//!      nobody holds it (it never takes the controller) and goes on to `NOT_OWNER`
//!      otherwise.
//! 4. **owner**: the first sender of a CRC-valid frame owns the controller; another
//!    address takes over when the owner has been silent for 5 s and the state is not
//!    RUNNING (an upload it had not started is dropped then: STATUS `more_flags` bit 0);
//!    other senders get `NOT_OWNER` with zeros for state, next_seq, buffered and free.
//! 5. **duplicate**: a frame (sender, seq, tag, CRC) accepted within the last 2 s (and
//!    among the last [`crate::config::DUPLICATE_MEMORY`] accepted) is ACKed `OK` again and
//!    not executed ([`Response::executed`] is false).
//! 6. **decode**: `UNKNOWN_TAG`, `BAD_LENGTH`, `INVALID_CONFIG`, `INVALID_POINT` (duration
//!    under 1 us), `UNSUPPORTED` (a report tag from a host).
//! 7. **state**: `ESTOP_LATCHED` for RUNING and RETURN while the wired e-stop input's
//!    latch is set, and for ESTOP_RESET while the input is open (see "The wired e-stop
//!    input" below); `BAD_STATE` when the command is not allowed in the current state
//!    (docs/PROTOCOL.md, "Commands (host to controller)"; USART_SEND needs an open port
//!    that may transmit; PENDING must come from the endpoint that sent the NEW).
//! 8. **execute**: PENDING checks, in order: `OUT_OF_ORDER` (seq != `next_seq`),
//!    `TOO_MANY_POINTS`, `INVALID_POINT` (range, a limp joint moved, step rate, step
//!    budget, then acceleration: issues 23 and 31), `BUFFER_FULL`; every point of the
//!    frame is checked before any is taken. USART_SEND: `BUFFER_FULL` when the serial
//!    transmit queue has no room. USART_START: `INVALID_CONFIG` for settings the board's
//!    USART cannot make ([`crate::uart::uart_frame`]), or when the port cannot apply them.
//!
//! A frame "accepted" is one ACKed `OK`: it is remembered for duplicate detection and it
//! counts for the PENDING ordering rule when it comes from the uploader (the endpoint,
//! address and port, that sent the NEW: another tool on the owner's machine numbers its
//! seqs on its own).
//!
//! # Who gets which report
//! The ACK and a STATUS report go to the command's sender, and so do the LOCATION a
//! STATUS's request byte asks for and the LIMITS report of LIMITS_GET (issue 23). LOCATION goes to each of the
//! owner's endpoints (up to [`LOCATION_LISTENERS`]) whose commands were executed and that
//! have not been silent for 5 s; the endpoint that started the upload or run (NEW,
//! RETURN) or turned reports on (UPLOAD_START, UPLOAD_PERIOD) keeps them while anything
//! runs, however long it is silent (and, when the run ends by itself, 5 s from the end:
//! the end-of-run report reaches it), and otherwise the endpoint heard most recently keeps
//! them (so a host with one socket gets every report, as the manual has it). The 5 s are
//! checked each time a LOCATION is sent ([`ReportSettings::location_until_us`]), so a tool
//! that went away stops getting them even while nobody speaks. So no tool takes another's reports: a watcher keeps
//! its LOCATIONs while a poller polls, and an uploader that waits for its first LOCATION
//! gets it though another tool spoke last. USART_RECV goes to the endpoint that sent
//! USART_START. At first everything goes to the endpoint that became the owner; one tool
//! with one socket gets everything, as the manual has it.
//!
//! # Runs, reports and flags
//! * A run starts with RUNING (or RETURN) and ends in STOPPED in one of these ways, the
//!   **stop cause** (issue 31; STATUS `more_flags` bits 5-7, the STOP_CAUSE report): every
//!   point ran (COMPLETE), the engine ran dry first (UNDERRUN: also STATUS flag bit 5), a
//!   STOPPED command (STOPPED, with its sender: also bit 7), the wired e-stop input
//!   (ESTOP_INPUT: also bit 7, as before issue 31), or RETURN's encoder read failed
//!   (FAULT, with the joint). A STOPPED or the input dropping an upload in NEW or PENDING
//!   sets it too, while one in state STOPPED leaves it alone. A run's start sets it back
//!   to COMPLETE, so it tells how the last run ended.
//! * Every stop (STOPPED, the wired e-stop input) also cuts a counted gripper burst, and a
//!   servo PWM as [`ControllerConfig::servo_on_stop`] says (held by default; issue 30).
//!   STATUS flag bit 6 reads the gripper output, so it tells which.
//! * A LOCATION is produced at every state change while reports are on (UPLOAD_STOP
//!   turns all LOCATION reports off, the periodic ones and these).
//! * RETURN is accepted at once (ACK state RUNNING); the encoders are read by the caller
//!   ([`Deferred::ReadEncoders`]) and [`Controller::begin_return`] plans and starts the
//!   move. During it, PENDING is refused with `BAD_STATE` (the points are the
//!   controller's own); STOPPED and LOCATION work as in any run.
//!
//! # The wired e-stop input
//! [`Controller::estop_input`] is told when the board's normally-closed e-stop input
//! opens or closes (the step outputs were stopped already, by the input's own handler:
//! [`crate::estop_input`]). Opening does what a STOPPED does (state STOPPED, buffer and
//! upload dropped, STATUS flag bit 7 as for a STOPPED, a LOCATION of the state change)
//! and sets the latch (STATUS `more_flags` bit 2; bit 1 shows the input open now). While
//! the latch is set RUNING and RETURN are refused with `ESTOP_LATCHED`, whether the
//! input is still open or closed again; uploads (NEW, PENDING) and every other command
//! work. ESTOP_RESET clears the latch once the input is closed (while it is open:
//! `ESTOP_LATCHED`; with no latch: `OK`, nothing changes). Old hosts see state STOPPED
//! and a RUNING refused.
//!
//! Under ESTOP_CATEGORY 1 (issue 32, `controller/motion.rs`) an opening the handler left
//! to a controlled stop goes to [`Controller::estop_controlled`] instead: latched at once,
//! the run ramps to a standstill with HOLD's slope within a bound, then
//! [`Controller::estop_ramp_poll`] stops it as above and disables the drivers.
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
//! [`Deferred`] in the [`Response`]. A command that writes flash (JOINTS_COUNT,
//! LIMITS_SET, SET_KEY, NET_SET; only while STOPPED, one at a time) changes nothing and
//! gets no ACK in its response: the caller saves [`Deferred::SaveSettings`], then
//! [`Controller::settings_saved`] applies it and gives the ACK, `OK` or `SAVE_FAILED`
//! (issue 30: the ACK went out `OK` before the save, whose failure was only logged).
//!
//! # Layout
//! This file is the state machine proper: the checks above in their order
//! (`check_and_execute`) and what each command does (`execute`, one `match` so that every
//! command's rule reads in one place), about 600 lines with these docs. The boot state is
//! in `controller/boot.rs`, the owner rule and LOCATION listeners in `controller/owner.rs`,
//! admitting points, feeding the engine, run ends and RETURN in `controller/runs.rs`.

use protocol::NetSettings;
use protocol::{
    Ack, Command, Frame, LimitsReport, Location, MAX_JOINTS, MAX_POINTS_PER_FRAME, MoreFlags,
    Refusal, State, StatusCode, StatusFlags, StatusReport, StopCause, StopReport, Tag, UartMode,
    limits,
};
use protocol::{DecodeError, DecodeErrorKind};

use crate::auth::Sessions;
use crate::buffer::{StoredPoint, TrajectoryBuffer};
use crate::config::{ControllerConfig, HOST_WINDOW, OWNER_TIMEOUT_US};
use crate::hw::{EncoderFault, Endpoint, PersistentSettings};
use crate::link::{FrameKey, RecentFrames, UploadOrder};
use crate::plan::ReturnPlan;
use crate::plant::Plant;
use crate::reports::{LOCATION_LISTENERS, Listener, ReportSettings};
use crate::response::{Deferred, Discovery, HelloGrant, Reply, Response};
use crate::uart::uart_frame;

mod boot;
mod homing_run;
mod motion;
pub use motion::{
    ESTOP_RAMP_LOOKAHEAD_US, ESTOP_RAMP_POLL_US, ESTOP_RAMP_SLACK_US, UNLIMITED_RAMP,
    estop_ramp_bound_us,
};
mod owner;
mod runs;

/// Every ENABLE line: joints 0-7 and the gripper (bit 8).
pub const ALL_DRIVERS: u16 = limits::ENABLE_MASK_BITS;

/// DISCOVER replies sent per second at most (issue 21 F6: a 30-byte reply to a 3-byte
/// request, to whatever address the request names, had no limit). Hosts looking for
/// controllers ask once or twice; 10 a second leave room for a cell's worth of them.
pub const DISCOVER_REPLIES_PER_S: u32 = 10;

/// DISCOVER replies that may go out at once, before the rate applies: a few tools starting
/// together.
pub const DISCOVER_BURST: u32 = 10;

/// A reply budget: a token bucket of `burst` replies refilled at `per_s` a second (the
/// DISCOVER replies': [`DISCOVER_BURST`] at [`DISCOVER_REPLIES_PER_S`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub(crate) struct ReplyBudget {
    /// Millionths of a reply available.
    credit: u64,
    at_us: u64,
    per_s: u32,
    /// Millionths of a reply at most.
    full: u64,
}

impl ReplyBudget {
    /// DISCOVER's budget (and the read-only STATUS answers').
    pub(crate) const fn new() -> Self {
        Self::with(DISCOVER_REPLIES_PER_S, DISCOVER_BURST)
    }

    /// `burst` replies at once, `per_s` a second after that; full.
    pub(crate) const fn with(per_s: u32, burst: u32) -> Self {
        ReplyBudget {
            credit: burst as u64 * 1_000_000,
            at_us: 0,
            per_s,
            full: burst as u64 * 1_000_000,
        }
    }

    /// Takes one reply's worth at `now_us`, if there is one.
    pub(crate) fn take(&mut self, now_us: u64) -> bool {
        let elapsed = now_us.saturating_sub(self.at_us);
        self.at_us = self.at_us.max(now_us);
        self.credit = self
            .credit
            .saturating_add(elapsed.saturating_mul(u64::from(self.per_s)))
            .min(self.full);
        if self.credit >= 1_000_000 {
            self.credit -= 1_000_000;
            true
        } else {
            false
        }
    }
}

/// A command whose settings are being saved ([`Deferred::SaveSettings`]): nothing of it
/// applies, and no ACK goes out, until the save's result is known.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct PendingSave {
    /// The command (its sender, seq, tag and CRC: the ACK, the duplicate memory).
    frame: FrameKey,
    from_owner: bool,
    /// The settings it stores, applied once stored.
    settings: PersistentSettings,
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

/// The controller: state machine, trajectory buffer, owner and reliability rules.
///
/// `CAP` is the trajectory buffer's compile-time size (see
/// [`crate::profile::BoardProfile::trajectory_capacity`]); `config.capacity` may use less of it.
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
    /// The last point received as a segment: each joint's steps and its duration (0 at
    /// NEW: the trajectory starts from rest). The acceleration check's previous rate
    /// (ACCEL_SET, issue 31).
    received_last: crate::controller::runs::LastSegment,
    /// End position of the last point handed to the engine.
    fed_end: [i32; MAX_JOINTS],
    /// RETURN accepted, waiting for the encoder reading.
    return_pending: bool,
    /// `PluseCount` of the last PWM_START (0: a servo PWM): what a stop does to the gripper
    /// output ([`crate::config::ServoOnStop::cuts`]).
    gripper_pulse_count: i32,
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
    /// What DISCOVER replies may still be sent ([`DISCOVER_REPLIES_PER_S`]).
    discover_budget: ReplyBudget,
    /// What read-only STATUS answers to hosts that do not own the controller may still
    /// be sent (the same bound as DISCOVER's: issue 23's read-only STATUS is a 39-byte
    /// report, and a 39-byte LOCATION when asked, to a 4-byte request).
    glance_budget: ReplyBudget,
    /// Authenticated sessions (with a key set).
    sessions: Sessions,
    /// Random bits from the board (its RNG, at boot): the epochs of keys set
    /// ([`crate::auth::epoch_base`]).
    entropy: u64,
    /// Keys set since boot (each draws another epoch base from `entropy`).
    keys_set: u32,
    /// A command that writes flash, accepted and waiting for its save: its ACK goes out
    /// with the save's result ([`Controller::settings_saved`]).
    saving: Option<PendingSave>,
    /// The latest time the controller was told (by [`Controller::handle`] or
    /// [`Controller::note_time`]): what it knows of "now" when a run ends, which it notices
    /// without a clock.
    last_handled_us: u64,
    /// Where USART_RECV reports go: the endpoint that sent USART_START.
    serial_to: Option<Endpoint>,
    /// STATUS `more_flags`.
    more_flags: MoreFlags,
    /// The limit switches' latch and "away only" rule (issue 33; never set on a board
    /// without limit switches: nothing changes for it).
    hard_limits: crate::switches::Limits,
    /// The homing cycle on the home switches (issue 33, `homing_run.rs`).
    homing: homing_run::HomingRun,
    reports_on: bool,
    upload_period_us: u32,
    enabled: u16,
    pins: [bool; 2],
    serial: Option<UartMode>,
    /// What ended the last run (STATUS `flags` bits 5 and 7, `more_flags` bits 5-7, the
    /// STOP_CAUSE report; issue 31).
    stop: StopReport,
    /// The sender of the last STOPPED executed: the cause of a stop applied after
    /// overtaken frames ([`Controller::stop_after_overtaken`]).
    last_stopper: Option<Endpoint>,
    /// Ethernet MAC, for DISCOVER_REPLY.
    mac: [u8; 6],
    /// The network settings loaded at boot (the ones in use); NET_SET stores others.
    booted_net: NetSettings,
    /// Steps per second of all joints together that points may ask for (0: no limit).
    step_budget_hz: u32,
    /// Override and hold (issue 32; the MOTION report).
    motion: motion::Motion,
    /// The last INVALID_POINT for a limit (the LIMITS report's detail, issue 23).
    last_refusal: Refusal,
}

impl<const CAP: usize> Controller<CAP> {
    /// Sets the MAC address DISCOVER_REPLY reports (at boot).
    pub fn set_mac(&mut self, mac: [u8; 6]) {
        self.mac = mac;
    }

    /// Applies stored settings (at boot); an out-of-range joint count keeps the default,
    /// a joint range with min above max is no limit.
    pub fn apply_settings(&mut self, settings: PersistentSettings) {
        self.settings = settings;
        self.booted_net = settings.net();
        if !limits::JOINTS.contains(&settings.joints) {
            self.settings.joints = limits::DEFAULT_JOINTS;
        }
        // A stored range that cannot be met (never written by LIMITS_SET, which refuses
        // it) is no limit rather than one no point could meet.
        for l in self.settings.limits.iter_mut() {
            if !l.is_valid() {
                *l = protocol::JointLimits::NONE;
            }
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
    /// [`crate::profile::BOOT_STEP_BUDGET_HZ`] (every board profile's).
    pub fn set_step_budget_hz(&mut self, hz: u32) {
        self.step_budget_hz = hz;
    }

    /// Gives the controller random bits (at boot, from the board's RNG; the simulator's
    /// OS): a key set later starts its epochs at a random place
    /// ([`crate::auth::epoch_base`]), never again at 1.
    pub fn set_entropy(&mut self, entropy: u64) {
        self.entropy = entropy;
    }

    /// With a key stored: this boot's epoch (one more than the stored one), in the
    /// settings to store before HELLO is answered ([`Controller::auth_epoch_stored`]).
    /// `None` without a key.
    pub fn begin_auth_epoch(&mut self) -> Option<PersistentSettings> {
        self.settings.key?;
        self.settings.auth_epoch = crate::auth::next_epoch(self.settings.auth_epoch);
        Some(self.settings)
    }

    /// The epoch [`Controller::begin_auth_epoch`] chose is stored: HELLO is answered.
    pub fn auth_epoch_stored(&mut self) {
        if let Some(key) = self.settings.key {
            self.sessions.start_epoch(self.settings.auth_epoch, &key);
        }
    }

    /// The save of the settings [`Deferred::SaveSettings`] asked for ended (`saved`: it
    /// succeeded) at `now_us`: the command applies (`OK`) or did nothing (`SAVE_FAILED`),
    /// and this is its ACK. `None` when no save was asked for.
    pub fn settings_saved(&mut self, saved: bool, now_us: u64) -> Option<Reply> {
        let pending = self.saving.take()?;
        let FrameKey { from, seq, tag, .. } = pending.frame;
        self.last_handled_us = self.last_handled_us.max(now_us);
        if !saved {
            self.refused(pending.frame, StatusCode::SaveFailed);
            return Some(self.ack(from, seq, tag, StatusCode::SaveFailed));
        }
        self.settings = pending.settings;
        // A new key starts a new epoch (every session ends: the ACK goes plain); no key,
        // no sessions.
        if tag == Tag::SetKey as u8 {
            match self.settings.key {
                Some(key) => self.sessions.start_epoch(self.settings.auth_epoch, &key),
                None => self.sessions.close(),
            }
        }
        self.executed(pending.frame, pending.from_owner, now_us);
        Some(self.ack(from, seq, tag, StatusCode::Ok))
    }

    /// Whether a save is under way ([`Controller::settings_saved`] not called yet).
    pub fn saving(&self) -> bool {
        self.saving.is_some()
    }

    /// Whether a key is set.
    pub fn keyed(&self) -> bool {
        self.settings.key.is_some()
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

    /// The addresses whose datagrams take the reserved share of the receive path (issue
    /// 30, [`crate::source_share`]): the owner's and, with a key, those of the sessions
    /// that sent a valid envelope.
    pub fn trusted_sources(&self) -> crate::source_share::TrustedSources {
        let mut trusted = crate::source_share::TrustedSources::NONE;
        if let Some(owner) = self.owner {
            trusted.add(owner.ip);
        }
        if self.settings.key.is_some() {
            self.sessions.proven_ips().for_each(|ip| trusted.add(ip));
        }
        trusted
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
            location_until_us: self
                .listeners
                .map(|l| l.map_or(0, |l| l.until_us(self.keep_of(l.to)))),
            serial_to: self.serial_to,
            reports_on: self.reports_on,
            upload_period_us: self.upload_period_us,
            state: self.state,
            seal: self.sessions.routes(self.settings.key.is_some()),
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
        let cause = self.stop.cause.unwrap_or(StopCause::Complete);
        flags.set(StatusFlags::UNDERRUN, cause == StopCause::Underrun);
        flags.set(StatusFlags::PWM_ACTIVE, plant.gripper_active());
        // Bit 7 means "a stop" to old hosts: the wired input's too, as before issue 31.
        flags.set(
            StatusFlags::STOPPED_BY_HOST,
            matches!(cause, StopCause::Stopped | StopCause::EstopInput),
        );
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
            more_flags: MoreFlags(
                self.more_flags.0
                    | MoreFlags::of_enabled(self.enabled)
                    | MoreFlags::of_stop_cause(cause),
            ),
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

    /// The time now, for what the controller decides outside [`Controller::handle`]: when
    /// a run ends by itself, its claimer's reports run 5 s (or a minute) from then. The
    /// trajectory task calls it before [`Controller::on_step_progress`].
    pub fn note_time(&mut self, now_us: u64) {
        self.last_handled_us = self.last_handled_us.max(now_us);
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
        self.last_handled_us = self.last_handled_us.max(now_us);
        let mut response = self.check_and_execute(plant, now_us, from, datagram);
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
        plant: &mut impl Plant,
        now_us: u64,
        from: Endpoint,
        datagram: &[u8],
    ) -> Response {
        let mut response = Response::default();
        // 1. length
        if datagram.len() < protocol::FRAME_OVERHEAD {
            return response;
        }
        // Authentication (docs/PROTOCOL.md section 13): with a key, an envelope that
        // verifies is replaced by its inner frame; STOPPED and DISCOVER pass plain; HELLO
        // is answered here; anything else is refused before it can take the owner.
        let datagram = match self.authenticate(from, datagram, now_us, &mut response) {
            Some(inner) => inner,
            None => return response,
        };
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
            // The owner (or anyone while there is none) gets the usual fields; a stranger
            // learns nothing about the arm: the NOT_OWNER zeros (issue 21 F9).
            response.reply = if self.owner.is_none_or(|o| o.ip == from.ip) {
                reply(self, StatusCode::BadCrc)
            } else {
                Some(blank_ack(from, seq, tag, StatusCode::BadCrc))
            };
            return response;
        }
        // DISCOVER (docs/PROTOCOL.md, "Finding controllers and setting their address"):
        // answered to any host, before the owner rule, with a DISCOVER_REPLY instead of an
        // ACK; it changes nothing (no owner, no duplicate memory, no ordering mark, no
        // LOCATION listener).
        if tag == Tag::Discover as u8 && datagram.len() == protocol::FRAME_OVERHEAD {
            // Beyond the budget: no reply at all (the host asks again).
            if !self.discover_budget.take(now_us) {
                return response;
            }
            response.discovery = Some(Discovery {
                to: from,
                seq,
                reply: self.discovery(from.ip, now_us),
            });
            return response;
        }
        // STOPPED (docs/PROTOCOL.md sections 4, 7 and 11, issue 18): a CRC-valid STOPPED
        // always stops, from any sender, in any state, whatever its data, and is ACKed
        // `OK`. It is never a duplicate (an e-stop panel repeats the same bytes; a
        // spurious stop is safe, an ignored one is not), never takes the controller over
        // and is not remembered (a stream of STOPPEDs cannot evict the frames whose
        // copies must still be recognised).
        if tag == Tag::Stopped as u8 {
            if self.owner.is_some_and(|o| o.ip == from.ip) {
                self.heard_from_owner(from, now_us);
                self.listen(from, now_us);
            }
            self.last_stopper = Some(from);
            self.stop_by_host(plant, Some(from));
            response.executed = true;
            response.reply = reply(self, StatusCode::Ok);
            return response;
        }
        // HOLD (issue 32, docs/PROTOCOL.md "HOLD, RESUME, OVERRIDE"): from any host, as
        // STOPPED (whoever sees a danger may stop the arm; a hold is the gentle stop and
        // starts nothing), before the owner rule, taking nothing. The owner's goes the
        // usual way (duplicates, ordering).
        if tag == Tag::Hold as u8 && self.owner.is_some_and(|o| o.ip != from.ip) {
            let status = match decoded {
                Ok(Frame {
                    body: Command::Hold,
                    ..
                }) => self.hold(plant).err().unwrap_or(StatusCode::Ok),
                Ok(_) => StatusCode::BadLength,
                Err(e) => e.status().unwrap_or(StatusCode::BadLength),
            };
            response.executed = status == StatusCode::Ok;
            response.reply = reply(self, status);
            return response;
        }
        // Read-only STATUS and RELEASE from a host that does not own the controller
        // (docs/PROTOCOL.md section 1, issue 23): answered before the owner rule, taking
        // nothing.
        if self.owner.is_none_or(|o| o.ip != from.ip)
            && let Some(done) = self.not_owner_status_or_release(from, datagram, now_us, plant)
        {
            return done;
        }
        // 3. owner
        let from_owner = match self.owner {
            None => {
                self.take_over(from, now_us, plant);
                true
            }
            Some(owner) if owner.ip == from.ip => {
                self.heard_from_owner(from, now_us);
                true
            }
            Some(owner)
                if self.state != State::Running
                    && now_us.saturating_sub(owner.last_heard_us) >= OWNER_TIMEOUT_US =>
            {
                self.take_over(from, now_us, plant);
                true
            }
            Some(_) => {
                response.reply = Some(blank_ack(from, seq, tag, StatusCode::NotOwner));
                return response;
            }
        };
        // 5. duplicate
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
        // 6. decode
        let frame = match decoded {
            Ok(frame) => frame,
            Err(e) => {
                let status = e.status().unwrap_or(StatusCode::BadLength);
                self.refused(key, status);
                response.reply = reply(self, status);
                return response;
            }
        };
        // 7. state and 8. execute
        let status = match self.execute(frame, from, plant, &mut response) {
            Ok(()) => {
                // Flash is written first: the ACK waits for the save (settings_saved).
                if let Some(Deferred::SaveSettings(settings)) = response.deferred {
                    self.saving = Some(PendingSave {
                        frame: key,
                        from_owner,
                        settings,
                    });
                    return response;
                }
                self.executed(key, from_owner, now_us);
                response.executed = true;
                StatusCode::Ok
            }
            Err(status) => {
                self.refused(key, status);
                status
            }
        };
        self.pump(plant);
        response.reply = reply(self, status);
        response
    }

    /// The authentication gate: the frame the checks below take (`datagram` itself, or
    /// an envelope's inner frame), or `None` with `response` filled in (a refusal, or a
    /// HELLO's answer).
    fn authenticate<'d>(
        &mut self,
        from: Endpoint,
        datagram: &'d [u8],
        now_us: u64,
        response: &mut Response,
    ) -> Option<&'d [u8]> {
        use protocol::auth::{Direction, Envelope};
        let [seq, tag, ..] = *datagram else {
            return None;
        };
        let refuse = |response: &mut Response, status| {
            response.reply = Some(blank_ack(from, seq, tag, status));
            None
        };
        let crc_ok = protocol::crc8(datagram.split_last().map_or(&[][..], |(_, b)| b))
            == datagram.last().copied().unwrap_or(0);
        // No key: every frame as before issue 21 (an envelope is UNSUPPORTED, a HELLO
        // BAD_STATE, after the owner rule like any frame).
        if self.settings.key.is_none() {
            return Some(datagram);
        }
        if !crc_ok {
            // A stranger learns nothing (a key holder's frames are envelopes).
            return refuse(response, StatusCode::BadCrc);
        }
        if tag == Tag::Stopped as u8 || tag == Tag::Discover as u8 {
            return Some(datagram);
        }
        if tag == Tag::Hello as u8 {
            let Ok(protocol::Frame {
                body: Command::Hello { nonce },
                ..
            }) = Command::decode(datagram)
            else {
                return refuse(response, StatusCode::BadLength);
            };
            if !self.sessions.ready() {
                return refuse(response, StatusCode::BadState);
            }
            // Past the budget of HELLO's source address: no reply at all (it asks again).
            let session = self.sessions.hello(from, nonce, now_us)?;
            response.hello = Some(HelloGrant {
                to: from,
                seq,
                reply: protocol::auth::HelloReply {
                    nonce,
                    epoch: self.sessions.epoch(),
                    session,
                },
            });
            return None;
        }
        if tag != Tag::Auth as u8 {
            return refuse(response, StatusCode::AuthRequired);
        }
        // The outer CRC was checked above; the inner frame's is checked when it is
        // decoded (a damaged one is BAD_CRC there, as any frame).
        let Ok(envelope) = Envelope::split(datagram) else {
            return refuse(response, StatusCode::BadLength);
        };
        let epoch = self.sessions.epoch();
        // No epoch started yet (it is being stored): no session either.
        let Some(key) = self.sessions.mac_key().copied() else {
            return refuse(response, StatusCode::AuthFailed);
        };
        let verified = self.sessions.accept(
            envelope.session,
            envelope.counter,
            || envelope.verify_with(&key, Direction::ToController, epoch),
            from,
            now_us,
        );
        match verified {
            Ok(()) => Some(envelope.inner),
            Err(_) => refuse(response, StatusCode::AuthFailed),
        }
    }

    /// The owner (whose address `from` has) spoke at `now_us`: its silence and that of
    /// the endpoint's LOCATION listener start again.
    fn heard_from_owner(&mut self, from: Endpoint, now_us: u64) {
        if let Some(owner) = self.owner.as_mut() {
            owner.last_heard_us = now_us;
        }
        for listener in self.listeners.iter_mut().flatten() {
            if listener.to == from {
                listener.heard_us = now_us;
            }
        }
    }

    /// Bookkeeping for a CRC-valid frame of the owner refused after the duplicate check.
    /// A command other than PENDING from the uploader refused for good
    /// ([`StatusCode::refuses_for_good`]: these bytes can never be accepted) fills its seq in the upload's order, as an accepted one does (issue 21 F12: its seq
    /// stayed a gap, and a host resending from `next_seq` as section 7 says got the same
    /// refusal and the same OUT_OF_ORDER for ever). A refusal that a resend can turn into
    /// an acceptance (`BAD_STATE`, e.g. a RUNING that overtook its PENDING;
    /// `ESTOP_LATCHED`; `BUFFER_FULL`) keeps the gap, so that the PENDING after it names
    /// it and the host resends it; a refused PENDING keeps it too (its points were not
    /// taken). Neither is remembered as a duplicate: a resend is checked again.
    fn refused(&mut self, key: FrameKey, status: StatusCode) {
        if status.refuses_for_good()
            && self.uploader == Some(key.from)
            && key.tag != Tag::Pending as u8
        {
            self.order.mark(key.seq);
        }
    }

    /// Bookkeeping for an executed frame. (A duplicate's seq was marked when the frame
    /// was executed: marking it again once the upload has moved past it would mark that
    /// seq a lap (256) ahead, and a PENDING lost there would be skipped.)
    fn executed(&mut self, key: FrameKey, from_owner: bool, now_us: u64) {
        self.recent.remember(key, now_us);
        if self.uploader == Some(key.from) {
            self.order.mark(key.seq);
        }
        // RELEASE ended the ownership: its sender gets nothing more.
        if !from_owner || key.tag == Tag::Release as u8 {
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
        // A command that writes flash (JOINTS_COUNT, LIMITS_SET, SET_KEY, NET_SET): only
        // while STOPPED (issue 30: the save, a sector erase of up to 2 s on the board,
        // holds the trajectory task), and one at a time.
        let flash_only = |c: &Self| {
            if c.saving.is_none() {
                stopped_only(c)
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
                self.received_last = runs::LastSegment::REST;
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
                let mut last = self.received_last;
                // An override above 100 % that a point would take past a limit is
                // lowered to what every point allows (issue 32: points that arrive
                // after the OVERRIDE, or before RUNING at `--speed`).
                let mut cap = None;
                for (i, (slot, point)) in admitted.iter_mut().zip(points.iter()).enumerate() {
                    // The trajectory's last point must bring every joint to rest.
                    let ends = self.received as usize + i + 1 >= self.expected as usize;
                    let before = last;
                    let checked = self.admit(&previous, &point).and_then(|stored| {
                        self.within_accel(&mut last, &previous, &stored, ends)
                            .map(|()| stored)
                    });
                    if let Ok(stored) = &checked
                        && let Some(lower) = self.factor_cap(
                            cap.map_or(self.motion.factor, |c: (u8, u8, _)| c.0),
                            &before,
                            &previous,
                            stored,
                            ends,
                        )
                    {
                        cap = Some(lower);
                    }
                    *slot = match checked {
                        Ok(stored) => stored,
                        Err(refusal) => {
                            self.last_refusal = Refusal {
                                seq: frame.seq,
                                tag: Tag::Pending as u8,
                                point: u8::try_from(i).unwrap_or(u8::MAX),
                                ..refusal
                            };
                            return Err(StatusCode::InvalidPoint);
                        }
                    };
                    // After an unlock, never further into a limit switch still active.
                    let mut steps = [0i64; MAX_JOINTS];
                    for ((s, &to), &from) in steps.iter_mut().zip(&slot.position).zip(&previous) {
                        *s = i64::from(to) - i64::from(from);
                    }
                    if self.hard_limits.check_direction(&steps).is_err() {
                        return Err(StatusCode::LimitLatched);
                    }
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
                self.received_last = last;
                self.order.take(frame.seq);
                if let Some(cap) = cap {
                    self.lower_override(cap, plant);
                }
                self.fit_warp_budget(plant);
                if self.state == State::New {
                    self.state = State::Pending;
                }
            }
            Command::Runing if self.estop_latched() => return Err(StatusCode::EstopLatched),
            Command::Runing if self.hard_limits.latched().is_some() => {
                return Err(StatusCode::LimitLatched);
            }
            Command::Runing if self.motion.door_open => return Err(StatusCode::DoorOpen),
            Command::Runing => match self.state {
                // A run at a factor other than 100 % is warped from its start: within the
                // step side's warp budget over the points held (issue 32), else refused
                // (old hosts never set a factor).
                State::Pending
                    if self.motion.factor != 100
                        && !self.warp_fits(plant, motion::rate_of(self.motion.factor)) =>
                {
                    return Err(self.over_warp_budget());
                }
                State::Pending => {
                    self.stop = StopReport::COMPLETE;
                    self.state = State::Running;
                    self.motion.held = false;
                    self.motion.underrun = false;
                    self.motion.warped = self.motion.factor != 100;
                    plant.set_start_rate(motion::rate_of(self.motion.factor));
                    self.pump(plant);
                    plant.start();
                }
                State::Running => {}
                _ => return Err(StatusCode::BadState),
            },
            // Handled in `check_and_execute` before the owner rule; never reaches here.
            Command::Stopped => self.stop_by_host(plant, Some(from)),
            Command::UploadStart => self.reports_on = true,
            Command::UploadStop => self.reports_on = false,
            Command::PwmStart(pwm) => {
                self.gripper_pulse_count = pwm.pulse_count;
                plant.gripper_start(&pwm);
            }
            Command::PwmStop => plant.gripper_stop(),
            Command::UsartStart(init) => {
                // Settings the board's USART cannot make are refused here, before the
                // port is touched: the simulator refuses what the board refuses.
                uart_frame(&init).map_err(|_| StatusCode::InvalidConfig)?;
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
            // Explicit, so that sending it twice (a resend after the duplicate window, a
            // second tool) never undoes it; only while STOPPED, as TOGGLE: a joint made
            // limp mid-run loses its steps.
            Command::SetEnable { mask, enable } => {
                stopped_only(self)?;
                let mask = mask & ALL_DRIVERS;
                if enable {
                    self.enabled |= mask;
                } else {
                    self.enabled &= !mask;
                }
                plant.set_enabled(self.enabled);
            }
            Command::Return => {
                if self.estop_latched() {
                    return Err(StatusCode::EstopLatched);
                }
                if self.hard_limits.latched().is_some() {
                    return Err(StatusCode::LimitLatched);
                }
                stopped_only(self)?;
                // Towards zero, which may be further into a limit switch still active.
                let mut steps = [0i64; MAX_JOINTS];
                for (s, &p) in steps.iter_mut().zip(&plant.positions()) {
                    *s = -i64::from(p);
                }
                if self.hard_limits.check_move(&steps).is_err() {
                    return Err(StatusCode::LimitLatched);
                }
                // Every joint in use must be allowed at 0 (LIMITS_SET): refused before
                // anything moves.
                // A limp joint away from 0 would not move (issue 31): refused the same way.
                let refused = self
                    .outside_limits(&[0; MAX_JOINTS])
                    .or_else(|| self.limp_and_away(&plant.positions(), &[0; MAX_JOINTS]));
                if let Some(refusal) = refused {
                    self.last_refusal = Refusal {
                        seq: frame.seq,
                        tag: Tag::Return as u8,
                        ..refusal
                    };
                    return Err(StatusCode::InvalidPoint);
                }
                self.buffer.clear();
                self.return_plan = None;
                self.return_pending = true;
                self.return_fault = None;
                self.stop = StopReport::COMPLETE;
                self.state = State::Running;
                response.deferred = Some(Deferred::ReadEncoders);
            }
            Command::JointsCount(joints) => {
                flash_only(self)?;
                let settings = PersistentSettings {
                    joints,
                    ..self.settings
                };
                response.deferred = Some(Deferred::SaveSettings(settings));
            }
            Command::LocationSetting(location) => {
                stopped_only(self)?;
                // A position outside a joint's range (LIMITS_SET) is refused: the limits
                // or the calibration are wrong (widen the limits first if the arm is
                // really there).
                if let Some(refusal) = self.outside_limits(&location.position) {
                    self.last_refusal = Refusal {
                        seq: frame.seq,
                        tag: Tag::Location as u8,
                        ..refusal
                    };
                    return Err(StatusCode::InvalidPoint);
                }
                if !plant.set_positions(location.position) {
                    return Err(StatusCode::BadState);
                }
            }
            // Kept across power cycles as JOINTS_COUNT; only while STOPPED, so that no
            // point already taken was admitted under other limits.
            Command::LimitsSet(set) => {
                flash_only(self)?;
                let settings =
                    with_joint_setting(self.settings, set.joint, |s| &mut s.limits, set.limits)?;
                response.deferred = Some(Deferred::SaveSettings(settings));
            }
            Command::LimitsGet | Command::LimitsGetWithAccel => {
                let with_accel = matches!(frame.body, Command::LimitsGetWithAccel);
                response.limits = Some((
                    from,
                    LimitsReport {
                        joints: self.settings.limits,
                        last_refusal: self.last_refusal,
                        max_accel: with_accel.then_some(self.settings.max_accel),
                    },
                ));
            }
            // Kept with the limits, under the same rule: only while STOPPED, so that no
            // point already taken was admitted under another acceleration (issue 31), and a
            // command that writes flash: taken, and ACKed, once the save succeeded (issue 30).
            Command::AccelSet {
                joint,
                max_accel_steps_s2,
            } => {
                flash_only(self)?;
                let settings = with_joint_setting(
                    self.settings,
                    joint,
                    |s| &mut s.max_accel,
                    max_accel_steps_s2,
                )?;
                response.deferred = Some(Deferred::SaveSettings(settings));
            }
            // The arm's description (issue 31): kept for the hosts, never used here; kept
            // with the limits under their rule (STOPPED only, ACKed after the save) so a
            // host never reads a description half-way through a config push's run.
            Command::JointDescSet(set) => {
                flash_only(self)?;
                let settings =
                    with_joint_setting(self.settings, set.joint, |s| &mut s.desc, set.desc)?;
                response.deferred = Some(Deferred::SaveSettings(settings));
            }
            Command::JointDescGet { joint } => {
                let Some(desc) = self.settings.desc.get(usize::from(joint)) else {
                    return Err(StatusCode::InvalidConfig);
                };
                response.joint_desc = Some((from, protocol::JointDescSet { joint, desc: *desc }));
            }
            Command::Status => response.status = Some((from, self.status(plant))),
            Command::StatusWith(ask) => self.answer_status(plant, from, ask, response),
            Command::Hold => self.hold(plant)?,
            Command::Resume => self.resume(plant)?,
            Command::Override { percent } => self.set_override(percent, plant)?,
            // Kept with the limits, under their rule (STOPPED only, ACKed after the save):
            // a run never changes its stop category under way.
            Command::EstopCategory(estop_category) => {
                flash_only(self)?;
                let settings = PersistentSettings {
                    estop_category,
                    ..self.settings
                };
                response.deferred = Some(Deferred::SaveSettings(settings));
            }
            // The owner gives the controller up: no owner, no report destinations (the
            // next host to speak takes it, as at boot). Only while STOPPED: an upload or
            // run of the owner's would otherwise pass to whoever speaks next.
            Command::Release => {
                stopped_only(self)?;
                self.release();
            }
            Command::UploadPeriod { period_us } => self.upload_period_us = period_us,
            // Answered in `handle` before the owner rule; never reaches here.
            Command::Discover => {}
            Command::Unlock => self.hard_limits.unlock(),
            // Issue 33: the homing cycle (controller/homing_run.rs); RETURN is unchanged.
            Command::Home => {
                if self.estop_latched() {
                    return Err(StatusCode::EstopLatched);
                }
                if self.hard_limits.latched().is_some() {
                    return Err(StatusCode::LimitLatched);
                }
                stopped_only(self)?;
                self.start_homing(plant)?;
            }
            // Kept with the limits, as LIMITS_SET.
            Command::HomingSet(set) => {
                flash_only(self)?;
                let settings =
                    with_joint_setting(self.settings, set.joint, |s| &mut s.homing, set.settings)?;
                response.deferred = Some(Deferred::SaveSettings(settings));
            }
            Command::HomingGet { joint } => {
                let Some(settings) = self.settings.homing.get(usize::from(joint)) else {
                    return Err(StatusCode::InvalidConfig);
                };
                response.homing = Some((
                    from,
                    protocol::HomingSet {
                        joint,
                        settings: *settings,
                    },
                ));
            }
            Command::EstopReset => {
                if self.more_flags.has(MoreFlags::ESTOP_OPEN) {
                    return Err(StatusCode::EstopLatched);
                }
                self.more_flags.set(MoreFlags::ESTOP_LATCHED, false);
            }
            // With a key it is answered by `authenticate`; without one (or inside an
            // envelope) there is no session to open.
            Command::Hello { .. } => return Err(StatusCode::BadState),
            // With a key this arrived in an envelope (`authenticate` refuses it plain).
            // A new key starts a new epoch, at a random place (issue 30: a key set again
            // never repeats its epochs); every session ends once it is stored.
            Command::SetKey(key) => {
                flash_only(self)?;
                let mut settings = PersistentSettings {
                    key,
                    ..self.settings
                };
                if key.is_some() {
                    settings.auth_epoch = crate::auth::epoch_base(self.entropy, self.keys_set);
                    self.keys_set = self.keys_set.wrapping_add(1);
                }
                response.deferred = Some(Deferred::SaveSettings(settings));
            }
            // Stored now, applied after the next reset (docs/PROTOCOL.md, "Finding controllers").
            Command::NetSet(net) => {
                flash_only(self)?;
                let mut settings = self.settings;
                settings.set_net(net);
                response.deferred = Some(Deferred::SaveSettings(settings));
            }
        }
        Ok(())
    }

    /// RELEASE's execution: the controller has no owner and sends reports to no one.
    fn release(&mut self) {
        self.owner = None;
        self.listeners = [None; LOCATION_LISTENERS];
        self.location_claimer = None;
        self.serial_to = None;
        self.uploader = None;
    }

    /// STATUS for `from`, and each report its request byte asks for besides: the same
    /// for the owner's STATUS and another host's look-only one.
    fn answer_status(
        &self,
        plant: &impl Plant,
        from: Endpoint,
        ask: protocol::StatusAsk,
        response: &mut Response,
    ) {
        response.status = Some((from, self.status(plant)));
        if ask.location {
            response.asked_location = Some((from, self.location(plant)));
        }
        if ask.stop_cause {
            response.asked_stop = Some((from, self.stop));
        }
        if ask.counters {
            response.asked_counters = Some(from);
        }
        if ask.motion {
            response.asked_motion = Some((from, self.motion_report(plant)));
        }
        if ask.switches {
            response.asked_switches = Some((from, self.switches_report()));
        }
        if ask.diag {
            response.asked_diag = Some(from);
        }
    }

    /// STATUS and RELEASE from `from`, a host that does not own the controller (none may,
    /// or another does): the response, or `None` to go on with the owner rule.
    ///
    /// * STATUS is answered read-only (issue 23) when another host owns the controller
    ///   (and has not lost it: silent 5 s with the arm not running), or whatever the owner
    ///   when the request byte asks only to look: an ACK `OK` with the arm's state and the
    ///   NOT_OWNER zeros (no next seq, no buffer counts), the STATUS report (and the
    ///   LOCATION asked for), all with the request's own seq. It takes nothing: no owner,
    ///   no owner's timer, no duplicate memory, no ordering mark, no report destination;
    ///   at most [`DISCOVER_REPLIES_PER_S`] a second after a burst of [`DISCOVER_BURST`]
    ///   (beyond that: no answer at all).
    /// * RELEASE never takes the controller: with no owner (or one that lost it) it is
    ///   `OK` and does nothing (the RELEASE that freed it, resent because its ACK was
    ///   lost, must not take it back); with another owner it is `NOT_OWNER`.
    fn not_owner_status_or_release(
        &mut self,
        from: Endpoint,
        datagram: &[u8],
        now_us: u64,
        plant: &mut impl Plant,
    ) -> Option<Response> {
        let [seq, tag, ..] = *datagram else {
            return None;
        };
        let held_by_other = self.owner.is_some_and(|o| {
            self.state == State::Running
                || now_us.saturating_sub(o.last_heard_us) < OWNER_TIMEOUT_US
        });
        let mut response = Response::default();
        if tag == Tag::Release as u8 {
            if held_by_other {
                return None;
            }
            // A malformed one is refused as any frame is (BAD_LENGTH), taking nothing
            // either.
            let status = match Command::decode(datagram) {
                Ok(_) => StatusCode::Ok,
                Err(e) => e.status().unwrap_or(StatusCode::BadLength),
            };
            response.reply = Some(self.ack(from, seq, tag, status));
            return Some(response);
        }
        // JOINT_DESC_GET (issue 31) is read-only from any host, as a look-only STATUS: the
        // arm's description is for every host (Python's positions(), a watcher) and
        // reading it must not take a free controller.
        if tag == Tag::JointDescGet as u8 {
            let Ok(Command::JointDescGet { joint }) = Command::decode(datagram).map(|f| f.body)
            else {
                return None;
            };
            if !self.glance_budget.take(now_us) {
                return Some(response);
            }
            let desc = self.settings.desc.get(usize::from(joint)).copied()?;
            let mut ack = blank_ack(from, seq, tag, StatusCode::Ok);
            ack.ack.state = self.state;
            response.reply = Some(ack);
            response.joint_desc = Some((from, protocol::JointDescSet { joint, desc }));
            response.answer_seq = Some(seq);
            return Some(response);
        }
        if tag != Tag::Status as u8 {
            return None;
        }
        let ask = match Command::decode(datagram).map(|f| f.body) {
            Ok(Command::Status) => protocol::StatusAsk::default(),
            Ok(Command::StatusWith(ask)) => ask,
            _ => return None,
        };
        if !held_by_other && !ask.look_only {
            return None;
        }
        if !self.glance_budget.take(now_us) {
            return Some(response);
        }
        let mut ack = blank_ack(from, seq, tag, StatusCode::Ok);
        ack.ack.state = self.state;
        response.reply = Some(ack);
        self.answer_status(plant, from, ask, &mut response);
        response.answer_seq = Some(seq);
        Some(response)
    }

    /// STOPPED's execution: no further pulse, the trajectory dropped, state STOPPED.
    /// `by`: the STOPPED's sender; `None`: the wired e-stop input.
    fn stop_by_host(&mut self, plant: &mut impl Plant, by: Option<Endpoint>) {
        plant.stop();
        self.abort_homing(plant);
        self.stop_gripper(plant);
        self.buffer.clear();
        self.return_plan = None;
        self.return_pending = false;
        // The cause tells how the last trajectory ended: a stop with none under way
        // (already STOPPED) leaves it alone.
        if self.state != State::Stopped {
            self.stop = match by {
                Some(from) => StopReport {
                    from_ip: from.ip,
                    from_port: from.port,
                    ..StopReport::of(StopCause::Stopped)
                },
                None => StopReport::of(StopCause::EstopInput),
            };
        }
        self.state = State::Stopped;
    }

    /// A stop's effect on the gripper (issue 30): a counted burst is cut; a servo PWM as
    /// [`ControllerConfig::servo_on_stop`] says (held by default). STATUS flag bit 6
    /// reads the output, so it tells which. Called whether or not the output still runs:
    /// a board whose interrupt already cut the timer ([`crate::ingress::StepHalt`], the
    /// wired input's handler) has its burst bookkeeping reset here, and stopping an idle
    /// output is harmless.
    fn stop_gripper(&mut self, plant: &mut impl Plant) {
        if self.config.servo_on_stop.cuts(self.gripper_pulse_count) {
            plant.gripper_stop();
        }
    }

    /// What ended the last run, and who sent the STOPPED if one did (the STOP_CAUSE
    /// report, issue 31).
    pub fn stop_report(&self) -> StopReport {
        self.stop
    }

    /// Whether the wired e-stop input's latch is set (RUNING and RETURN refused).
    pub fn estop_latched(&self) -> bool {
        self.more_flags.has(MoreFlags::ESTOP_LATCHED)
    }

    /// The wired e-stop input is now `open` (or closed). Opening does what a STOPPED does
    /// (no further pulse, the trajectory dropped, state STOPPED) and sets the latch;
    /// closing only records the level (the latch stays until ESTOP_RESET). Returns a
    /// LOCATION report when the state changed (reports on). The caller applies every
    /// opening, also one that closed again before it looked ([`crate::EStopSample`]).
    pub fn estop_input(&mut self, open: bool, plant: &mut impl Plant) -> Option<Location> {
        self.more_flags.set(MoreFlags::ESTOP_OPEN, open);
        if !open {
            return None;
        }
        // Category 1 ends with the drivers disabled, also when its stop had to be
        // instant (a board without a warp: its handler halted, as category 0's).
        if self.settings.estop_category == protocol::EStopCategory::Controlled {
            return self.estop_stop_now(plant);
        }
        self.more_flags.set(MoreFlags::ESTOP_LATCHED, true);
        let before = self.state;
        self.stop_by_host(plant, None);
        (before != self.state && self.reports_on).then(|| self.location(plant))
    }

    /// Every driver (and the gripper's) disabled: ENABLE off.
    fn disable_drivers(&mut self, plant: &mut impl Plant) {
        self.enabled = 0;
        plant.set_enabled(0);
    }

    /// A limit switch's event (issue 33, [`crate::switches`]): a trip does what a STOPPED
    /// does (the caller's edge handler has halted the step outputs already, as the wired
    /// e-stop's does) and latches (RUNING and RETURN refused `LIMIT_LATCHED` until
    /// UNLOCK); a release lifts the "away only" rule. Returns a LOCATION report when the
    /// state changed (reports on).
    pub fn limit_switch(
        &mut self,
        event: crate::switches::SwitchEvent,
        plant: &mut impl Plant,
    ) -> Option<Location> {
        // A home switch's: the homing cycle's (controller/homing_run.rs).
        if matches!(
            event,
            crate::switches::SwitchEvent::HomeActive { .. }
                | crate::switches::SwitchEvent::HomeReleased { .. }
        ) {
            return self.home_switch(event, plant);
        }
        if !self.hard_limits.on_event(event) {
            return None;
        }
        let before = self.state;
        self.stop_by_host(plant, None);
        // The stop cause names the switch (issue 31's STOP_CAUSE, detail: the joint, bit 7
        // for the max side), as stop_by_host's does the input's when a run was cut.
        if before != State::Stopped
            && let crate::switches::SwitchEvent::LimitTripped { joint, side, .. } = event
        {
            let max = matches!(side, crate::switches::Side::Max);
            self.stop = StopReport {
                detail: (joint & 0x7f) | if max { 0x80 } else { 0 },
                ..StopReport::of(StopCause::LimitSwitch)
            };
        }
        (before != self.state && self.reports_on).then(|| self.location(plant))
    }

    /// The limit switches' latch and which are active (STATUS's limit detail).
    pub fn hard_limits(&self) -> &crate::switches::Limits {
        &self.hard_limits
    }

    /// Applies a STOPPED that arrived after the frame just handled but was handled before
    /// it (see "Overtaken frames" in the module docs): what STOPPED's execution does,
    /// without an ACK; when the state is STOPPED already, only its effect on the gripper
    /// (a burst that frame started is cut). Call it right after
    /// [`Controller::handle`], with no wait in between, so that a run that frame started
    /// never emits a pulse. Returns a LOCATION report when the state changed (reports on).
    pub fn stop_after_overtaken(&mut self, plant: &mut impl Plant) -> Option<Location> {
        if self.state == State::Stopped {
            // The frame may have started the gripper (PWM_START): the stop that followed
            // it cuts that as any stop does.
            self.stop_gripper(plant);
            return None;
        }
        self.stop_by_host(plant, self.last_stopper);
        self.reports_on.then(|| self.location(plant))
    }
}

/// An ACK that tells a stranger nothing about the arm: state, next seq and buffer counts
/// all zero (docs/PROTOCOL.md, "Status codes": NOT_OWNER, and BAD_CRC to a stranger).
fn blank_ack(to: Endpoint, seq: u8, tag: u8, status: StatusCode) -> Reply {
    Reply {
        to,
        seq,
        ack: Ack {
            acked_tag: tag,
            status,
            state: State::New,
            next_seq: 0,
            buffered: 0,
            free: 0,
        },
    }
}

fn saturate(n: usize) -> u16 {
    u16::try_from(n).unwrap_or(u16::MAX)
}

/// `settings` with joint `joint`'s entry of one per-joint table (`table`: the limits,
/// accelerations, descriptions or homing settings) set to `value`, for the commands that
/// keep one joint's setting and save it before their ACK; `INVALID_CONFIG` for a joint
/// past the table.
fn with_joint_setting<T>(
    mut settings: PersistentSettings,
    joint: u8,
    table: impl FnOnce(&mut PersistentSettings) -> &mut [T],
    value: T,
) -> Result<PersistentSettings, StatusCode> {
    let slot = table(&mut settings)
        .get_mut(usize::from(joint))
        .ok_or(StatusCode::InvalidConfig)?;
    *slot = value;
    Ok(settings)
}
