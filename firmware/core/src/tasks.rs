//! The controller's async tasks, generic over the hardware traits, and the step timer
//! interrupt's body. Binaries allocate a [`Bus`], a [`StepShared`] and a
//! [`Controller`] in statics and wrap these functions in `#[embassy_executor::task]`s.
//!
//! Every channel and signal uses [`CriticalSectionRawMutex`]: the step engine and the
//! step task's wake-up are touched from the timer interrupt, and one kind of mutex for all
//! keeps the rules simple.

use core::cell::{Cell, RefCell};

use arm_step::{Segment, StepEngine, StepPins, StepTiming};
use embassy_futures::join::join;
use embassy_futures::select::{Either, Either3, select, select3};
use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::channel::Channel;
use embassy_sync::signal::Signal;
use heapless::Vec;
use protocol::{MAX_DATAGRAM, MAX_JOINTS, MAX_SERIAL_CHUNK, Pwm, Tag, UartInit, UartMode, crc8};

use crate::config::HOST_WINDOW;
use crate::controller::{Controller, Deferred, Plant, ReportSettings, Response};
use crate::hw::{
    Clock, Datagrams, Encoders, Endpoint, Gripper, Outputs, SerialError, SerialPort, SettingsStore,
    StepKick,
};
use crate::log_limit::{LogLimit, LogVerdict};
use crate::outgoing::{MAX_REPORT_FRAME, Outgoing, ReportEncoder};
use crate::serial::{SerialBatcher, byte_time_us};

/// The mutex kind of every channel, signal and shared cell.
pub type Cs = CriticalSectionRawMutex;

/// Queued STOPPED frames: one is enough to stop the arm; a few more keep the ACKs of a
/// host that repeats STOPPED quickly (or several hosts stopping at once).
pub const ESTOP_QUEUE: usize = 4;

/// Queued datagrams for the trajectory task: a host's whole window
/// ([`HOST_WINDOW`] = 32 datagrams, each up to 1472 bytes, sent back to back) plus 8 for
/// the commands of other tools on the same machine (a STATUS poller, a watcher) arriving
/// in the same instant. The network task can route a burst faster than the trajectory
/// task handles it (on the board the Ethernet ring and the UDP socket hold the same burst
/// before it), so the inbox must hold it whole. When full, datagrams are dropped (the host
/// resends: no ACK came), never waited for, so that a STOPPED behind them is never held
/// up. Each slot is a [`Datagram`] (1472 bytes + 12): 40 slots are 58 KiB of RAM.
pub const INBOX_QUEUE: usize = HOST_WINDOW + 8;

/// Queued frames to send: the ACKs of a full inbox and of the e-stop queue (44), plus a
/// LOCATION, a STATUS and a USART_RECV, and a few LOCATIONs of state changes. When full,
/// a frame is dropped (counted, logged at most once a second): the controller never
/// waits to report. A slot holds the largest frame's content (USART_RECV, 255 bytes).
pub const OUTBOX_QUEUE: usize = INBOX_QUEUE + ESTOP_QUEUE + 8;

/// Segments between the trajectory task and the step task, on top of the engine's own
/// queue: enough to refill the engine's queue in one go after a burst of short segments.
pub const SEGMENT_QUEUE: usize = 8;

/// USART_SEND payloads waiting for the serial port: at 115200 baud four are 90 ms of
/// line time; a full queue refuses USART_SEND with BUFFER_FULL.
pub const SERIAL_TX_QUEUE: usize = 4;

/// Time between the start of a run being decided and its first segment's start: leaves
/// the step interrupt time to set the DIR lines (and a simulator's scheduler some slack).
pub const START_LEAD_US: u32 = 1_000;

/// A datagram as received.
#[derive(Clone, Debug)]
pub struct Datagram {
    /// Sender.
    pub from: Endpoint,
    /// The whole frame (seq, tag, data, crc).
    pub bytes: Vec<u8, MAX_DATAGRAM>,
    /// STOPPED frames put on `bus.estop` before this one arrived (wrapping), stamped by
    /// [`Bus::route`]: tells the trajectory task which STOPPEDs it handled overtook it.
    pub stops_before: u32,
}

impl Datagram {
    /// A datagram from `from`, not yet stamped (see [`Bus::route`]).
    pub fn new(from: Endpoint, bytes: Vec<u8, MAX_DATAGRAM>) -> Self {
        Datagram {
            from,
            bytes,
            stops_before: 0,
        }
    }
}

/// A segment on its way to the engine, tagged with the engine's stop count at the time it
/// was cut: a segment cut before an emergency stop is dropped, not run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SegmentMsg {
    /// [`StepShared::generation`] when the segment was cut.
    pub generation: u32,
    /// The segment.
    pub segment: Segment,
}

/// The channels and signals that connect the tasks. Put one in a `static` (`new` is
/// `const`) or a `StaticCell`.
///
/// ```text
///            Datagrams                                               StepPins
///   UDP <-> network_task --estop (STOPPED, first)--> trajectory_task     ^
///              ^   |     --inbox (everything else)-->   | Controller     | on_step_timer
///              |   |                                    | Outputs,       |   (ISR)
///           outbox <----- ACK, STATUS, LOCATION --------+ Gripper,...  StepShared
///              ^   ^                                    |  \--stop/start-->  ^  |
///              |   |                          segments  v                    |  | step_wake
///              |   |                                  step_task --push-------'  |
///              |   |                                    | <---------------------'
///              |   |                      step_progress '--> trajectory_task
///              |   '-- LOCATION (period) -- upload_task <-- reports, upload_changed
///              '------ USART_RECV --------- serial_task <-- serial_tx, serial_opened
/// ```
pub struct Bus {
    /// CRC-valid STOPPED frames, routed here by `network_task`; drained by
    /// `trajectory_task` before anything else (the e-stop path).
    pub estop: Channel<Cs, Datagram, ESTOP_QUEUE>,
    /// Every other datagram, from `network_task`; drained by `trajectory_task`.
    pub inbox: Channel<Cs, Datagram, INBOX_QUEUE>,
    /// Frames to send, from `trajectory_task`, `upload_task` and `serial_task`; drained by
    /// `network_task`.
    pub outbox: Channel<Cs, Outgoing, OUTBOX_QUEUE>,
    /// Segments cut from the trajectory buffer by `trajectory_task`; drained by
    /// `step_task` into the engine.
    pub segments: Channel<Cs, SegmentMsg, SEGMENT_QUEUE>,
    /// Raised by the step interrupt ([`on_step_timer`]) when segments finished or the
    /// engine ran dry; waited on by `step_task`.
    pub step_wake: Signal<Cs, ()>,
    /// Raised by `step_task` after it moved segments or was woken by the interrupt;
    /// waited on by `trajectory_task`, which then collects the progress from
    /// [`StepShared`] and feeds more segments.
    pub step_progress: Signal<Cs, ()>,
    /// USART_SEND payloads, from `trajectory_task`; drained by `serial_task`.
    pub serial_tx: Channel<Cs, Vec<u8, MAX_SERIAL_CHUNK>, SERIAL_TX_QUEUE>,
    /// The serial port was opened with these settings, by `trajectory_task`; taken by
    /// `serial_task`'s reader.
    pub serial_opened: Signal<Cs, UartInit>,
    /// Report destination, state and upload settings, written by `trajectory_task`; read
    /// by `upload_task` and `network_task`.
    pub reports: Mutex<Cs, Cell<ReportSettings>>,
    /// Raised by `trajectory_task` when reports were switched or the period changed;
    /// waited on by `upload_task`.
    pub upload_changed: Signal<Cs, ()>,
    /// STOPPED frames put on `estop` so far (wrapping); every datagram is stamped with it
    /// ([`Datagram::stops_before`]). Counted by [`Bus::route`] only.
    stops_routed: Mutex<Cs, Cell<u32>>,
    /// Datagrams dropped by [`Bus::route`] (full inbox), and the limit on their log lines.
    inbox_drops: Mutex<Cs, Cell<(u32, LogLimit)>>,
    /// Frames dropped by [`Bus::send`] (full outbox) not yet logged: `network_task` logs
    /// them, at most once a second.
    outbox_drops: Mutex<Cs, Cell<u32>>,
}

impl Default for Bus {
    fn default() -> Self {
        Self::new()
    }
}

impl Bus {
    /// Empty channels, boot report settings.
    pub const fn new() -> Self {
        Bus {
            estop: Channel::new(),
            inbox: Channel::new(),
            outbox: Channel::new(),
            segments: Channel::new(),
            step_wake: Signal::new(),
            step_progress: Signal::new(),
            serial_tx: Channel::new(),
            serial_opened: Signal::new(),
            reports: Mutex::new(Cell::new(ReportSettings::UNPUBLISHED)),
            upload_changed: Signal::new(),
            stops_routed: Mutex::new(Cell::new(0)),
            inbox_drops: Mutex::new(Cell::new((0, LogLimit::new()))),
            outbox_drops: Mutex::new(Cell::new(0)),
        }
    }

    /// Datagrams dropped so far because the inbox was full (wrapping).
    pub fn inbox_drops(&self) -> u32 {
        self.inbox_drops.lock(|c| c.get().0)
    }

    /// Takes the count of frames dropped because the outbox was full since the last call.
    pub fn take_outbox_drops(&self) -> u32 {
        self.outbox_drops.lock(|c| c.replace(0))
    }

    /// The report settings as last published.
    pub fn report_settings(&self) -> ReportSettings {
        self.reports.lock(|c| c.get())
    }

    /// Queues a frame to send; a full outbox drops it (counted; `network_task` logs the
    /// count) rather than wait.
    pub fn send(&self, out: Outgoing) {
        if self.outbox.try_send(out).is_err() {
            self.outbox_drops.lock(|c| c.set(c.get().saturating_add(1)));
        }
    }

    /// Routes a received datagram: a CRC-valid STOPPED to `estop` (to `inbox` if that
    /// is full), everything else to `inbox`. Never waits: a full inbox drops the datagram
    /// (the host resends it since no ACK came; the drops are counted and logged at most
    /// once a second, `now_us` being the arrival time). Stamps it with the STOPPEDs put on
    /// `estop` before it ([`Datagram::stops_before`]).
    pub fn route(&self, mut datagram: Datagram, now_us: u64) {
        // One critical section: stamps and queue order agree even if two tasks route.
        let queued = self.stops_routed.lock(|routed| {
            datagram.stops_before = routed.get();
            let datagram = if is_stop(&datagram.bytes) {
                match self.estop.try_send(datagram) {
                    Ok(()) => {
                        routed.set(routed.get().wrapping_add(1));
                        return true;
                    }
                    Err(embassy_sync::channel::TrySendError::Full(d)) => d,
                }
            } else {
                datagram
            };
            self.inbox.try_send(datagram).is_ok()
        });
        if !queued {
            let verdict = self.inbox_drops.lock(|c| {
                let (drops, mut limit) = c.get();
                let verdict = limit.event(now_us);
                c.set((drops.wrapping_add(1), limit));
                verdict
            });
            if let LogVerdict::Log { suppressed } = verdict {
                warn!(
                    "inbox full: a datagram was dropped ({} more since the last such line)",
                    suppressed
                );
            }
        }
    }
}

/// Whether a datagram is a CRC-valid STOPPED frame.
pub fn is_stop(bytes: &[u8]) -> bool {
    match bytes {
        [_, tag, .., crc] => *tag == Tag::Stopped as u8 && crc8(&bytes[..bytes.len() - 1]) == *crc,
        _ => false,
    }
}

/// Microseconds to step timer ticks (rounded down).
pub fn us_to_ticks(us: u64, tick_hz: u32) -> u64 {
    (u128::from(us) * u128::from(tick_hz) / 1_000_000) as u64
}

/// Pins that do nothing: thread-level code stops the engine with these, and the next
/// interrupt lowers the real STEP lines.
struct NoPins;

impl StepPins for NoPins {
    fn set_direction(&mut self, _joint: usize, _positive: bool) {}
    fn step_high(&mut self, _joints: arm_step::JointMask) {}
    fn step_low(&mut self, _joints: arm_step::JointMask) {}
}

/// What the tasks need from whatever makes the step pulses: [`StepEngine`] (edges made by
/// an interrupt; the simulator) or the DMA streams' producer (the board). Called inside
/// [`StepShared`]'s critical section: implementations must not block.
pub trait StepBackend {
    /// Timer resolution and driver timing.
    fn timing(&self) -> StepTiming;
    /// Queues a segment; gives it back if the queue is full.
    fn push(&mut self, segment: Segment) -> Result<(), Segment>;
    /// Segments held.
    fn queued(&self) -> usize;
    /// Starts running the queue at `at_tick` (step timer ticks, [`StepKick::now_tick`]).
    fn start(&mut self, at_tick: u64);
    /// Emergency stop: no pulse after this returns (or, for an engine whose lines the
    /// next interrupt lowers, after that interrupt); the queue is dropped; positions
    /// keep the pulses made.
    fn stop(&mut self);
    /// Joint positions, steps.
    fn positions(&self) -> [i32; MAX_JOINTS];
    /// Overwrites the positions; refused (false) while running.
    fn set_positions(&mut self, positions: [i32; MAX_JOINTS]) -> bool;
}

impl<const Q: usize> StepBackend for StepEngine<Q> {
    fn timing(&self) -> StepTiming {
        StepEngine::timing(self)
    }
    fn push(&mut self, segment: Segment) -> Result<(), Segment> {
        StepEngine::push(self, segment)
    }
    fn queued(&self) -> usize {
        StepEngine::queued(self)
    }
    fn start(&mut self, at_tick: u64) {
        StepEngine::start(self, at_tick)
    }
    fn stop(&mut self) {
        // The lines are lowered by the next interrupt (`lower_step_lines`).
        StepEngine::stop(self, &mut NoPins)
    }
    fn positions(&self) -> [i32; MAX_JOINTS] {
        StepEngine::positions(self)
    }
    fn set_positions(&mut self, positions: [i32; MAX_JOINTS]) -> bool {
        StepEngine::set_positions(self, positions)
    }
}

/// What a step interrupt reports to the tasks.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct StepProgress {
    /// Segments finished (their slots are free).
    pub segments_finished: u32,
    /// The run is over: every pulse was made and the last segment ended.
    pub ran_dry: bool,
}

/// The step backend and what the interrupts report to the tasks, behind one critical
/// section mutex.
pub struct StepState<B> {
    /// The engine (or other backend).
    pub engine: B,
    /// Emergency stops so far: segments cut before the last stop are stale.
    generation: u32,
    /// Segments finished since the trajectory task last collected.
    finished: u32,
    /// The engine ran dry since the trajectory task last collected.
    ran_dry: bool,
    /// A start was asked for while the engine's queue was empty: start with the first
    /// segment pushed.
    start_pending: bool,
    /// The engine was stopped outside the interrupt: the interrupt must lower every STEP
    /// line.
    lower_step_lines: bool,
}

/// What became of a segment offered to the engine.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum PushOutcome {
    /// Queued in the engine.
    Queued,
    /// Cut before the last emergency stop: dropped.
    Stale,
    /// The engine's queue is full: offer it again later.
    Full,
}

/// The step engine (or other [`StepBackend`]) shared between the step interrupts and the
/// tasks: `Mutex<CriticalSectionRawMutex, RefCell<..>>` around it plus the bookkeeping
/// that must change atomically with it (stop count, finished segments, ran dry). `Q`:
/// the engine's queue when the backend is the default [`StepEngine`].
pub struct StepShared<const Q: usize, B = StepEngine<Q>> {
    inner: Mutex<Cs, RefCell<StepState<B>>>,
}

impl<const Q: usize> StepShared<Q> {
    /// An idle engine with this timing.
    pub const fn new(timing: StepTiming) -> Self {
        Self::with_backend(StepEngine::new(timing))
    }
}

impl<const Q: usize, B: StepBackend> StepShared<Q, B> {
    /// Shares `backend` (idle).
    pub const fn with_backend(backend: B) -> Self {
        StepShared {
            inner: Mutex::new(RefCell::new(StepState {
                engine: backend,
                generation: 0,
                finished: 0,
                ran_dry: false,
                start_pending: false,
                lower_step_lines: false,
            })),
        }
    }

    /// Runs `f` on the backend inside the critical section (inspection, simulators).
    pub fn with_engine<R>(&self, f: impl FnOnce(&mut B) -> R) -> R {
        self.inner.lock(|s| f(&mut s.borrow_mut().engine))
    }

    /// The body of a step interrupt other than the engine's timer (the board's DMA
    /// refills and run end): runs `f` on the backend in the critical section, records the
    /// progress it reports and wakes `wake` (the bus's `step_wake`) if there is any.
    /// Nothing is recorded for a run cut by a stop in the meantime (the caller's `f`
    /// sees the stopped backend).
    pub fn on_interrupt<R>(
        &self,
        wake: &Signal<Cs, ()>,
        f: impl FnOnce(&mut B) -> (R, StepProgress),
    ) -> R {
        self.inner.lock(|s| {
            let mut s = s.borrow_mut();
            let (r, progress) = f(&mut s.engine);
            if progress.segments_finished > 0 || progress.ran_dry {
                s.finished = s.finished.saturating_add(progress.segments_finished);
                s.ran_dry |= progress.ran_dry;
                wake.signal(());
            }
            r
        })
    }

    /// The engine's timing.
    pub fn timing(&self) -> StepTiming {
        self.with_engine(|e| e.timing())
    }

    /// Joint positions in steps, counted per pulse emitted.
    pub fn positions(&self) -> [i32; MAX_JOINTS] {
        self.with_engine(|e| e.positions())
    }

    /// Overwrites the positions; refused while running.
    pub fn set_positions(&self, positions: [i32; MAX_JOINTS]) -> bool {
        self.with_engine(|e| e.set_positions(positions))
    }

    /// Emergency stops so far.
    pub fn generation(&self) -> u32 {
        self.inner.lock(|s| s.borrow().generation)
    }

    /// Emergency stop: the engine drops every segment and emits no further pulse; the
    /// next interrupt lowers the STEP lines (kick it). Segments cut before now become
    /// stale; uncollected progress is dropped.
    pub fn stop(&self) {
        self.inner.lock(|s| {
            let mut s = s.borrow_mut();
            s.engine.stop();
            s.generation = s.generation.wrapping_add(1);
            s.finished = 0;
            s.ran_dry = false;
            s.start_pending = false;
            s.lower_step_lines = true;
        })
    }

    /// Offers a segment; starts the engine at `start_tick` if a start is pending.
    pub fn push(&self, msg: SegmentMsg, start_tick: u64) -> PushOutcome {
        self.inner.lock(|s| {
            let mut s = s.borrow_mut();
            if msg.generation != s.generation {
                return PushOutcome::Stale;
            }
            if s.engine.push(msg.segment).is_err() {
                return PushOutcome::Full;
            }
            if s.start_pending {
                s.start_pending = false;
                s.engine.start(start_tick);
            }
            PushOutcome::Queued
        })
    }

    /// Starts the engine at `start_tick` if it holds a segment, else as soon as one is
    /// pushed.
    pub fn start(&self, start_tick: u64) {
        self.inner.lock(|s| {
            let mut s = s.borrow_mut();
            if s.engine.queued() > 0 {
                s.engine.start(start_tick);
            } else {
                s.start_pending = true;
            }
        })
    }

    /// Collects the progress since the last call: segments finished, ran dry.
    pub fn take_progress(&self) -> (u32, bool) {
        self.inner.lock(|s| {
            let mut s = s.borrow_mut();
            let progress = (s.finished, s.ran_dry);
            s.finished = 0;
            s.ran_dry = false;
            progress
        })
    }
}

impl<const Q: usize> StepShared<Q> {
    /// The body of the step timer interrupt, see [`on_step_timer`].
    pub fn on_timer(
        &self,
        now_tick: u64,
        pins: &mut impl StepPins,
        wake: &Signal<Cs, ()>,
    ) -> Option<u64> {
        self.inner.lock(|s| {
            let mut s = s.borrow_mut();
            if s.lower_step_lines {
                s.lower_step_lines = false;
                pins.step_low(0xFF);
            }
            let poll = s.engine.poll(now_tick, pins);
            if poll.segments_finished > 0 || poll.ran_dry {
                s.finished = s.finished.saturating_add(poll.segments_finished);
                s.ran_dry |= poll.ran_dry;
                wake.signal(());
            }
            poll.next_deadline
        })
    }
}

/// What the step timer interrupt calls (board and simulator alike): emits the edges due
/// at `now_tick`, records finished segments and running dry for the tasks (waking
/// `wake`, the bus's `step_wake`), and returns the tick to be called again at (`None`:
/// only when kicked).
pub fn on_step_timer<const Q: usize>(
    shared: &StepShared<Q>,
    now_tick: u64,
    pins: &mut impl StepPins,
    wake: &Signal<Cs, ()>,
) -> Option<u64> {
    shared.on_timer(now_tick, pins, wake)
}

/// Moves segments from `bus.segments` into the engine as its queue frees up, starts a
/// pending run with the first one, kicks the step timer, and tells the trajectory task
/// when segments finished (relayed from the interrupt) or the segment channel has room.
pub async fn step_task<const Q: usize, B: StepBackend, K: StepKick>(
    bus: &Bus,
    step: &StepShared<Q, B>,
    kick: &K,
) -> ! {
    let lead = us_to_ticks(u64::from(START_LEAD_US), step.timing().tick_hz);
    let mut held: Option<SegmentMsg> = None;
    loop {
        let mut moved = false;
        loop {
            if held.is_none() {
                held = bus.segments.try_receive().ok();
            }
            let Some(msg) = held else { break };
            match step.push(msg, kick.now_tick() + lead) {
                PushOutcome::Queued => {
                    moved = true;
                    held = None;
                }
                PushOutcome::Stale => held = None,
                PushOutcome::Full => break,
            }
        }
        if moved {
            kick.kick();
        }
        bus.step_progress.signal(());
        if held.is_some() {
            bus.step_wake.wait().await;
        } else {
            select(bus.step_wake.wait(), bus.segments.ready_to_receive()).await;
        }
    }
}

/// Receives datagrams and routes them ([`Bus::route`]), and sends what `bus.outbox`
/// holds, both at once. ACKs and STATUS reports go to their requester, LOCATION and
/// USART_RECV as last published in `bus.reports`. Failures a datagram can cause are
/// logged at most once a second each ([`LogLimit`]), with the count.
pub async fn network_task<D: Datagrams, C: Clock>(socket: &D, bus: &Bus, clock: &C) -> ! {
    let rx = async {
        let mut buf = [0u8; MAX_DATAGRAM];
        let mut failures = LogLimit::new();
        loop {
            match socket.recv(&mut buf).await {
                Ok((n, from)) => {
                    let bytes =
                        Vec::from_slice(buf.get(..n).unwrap_or_default()).unwrap_or_default();
                    bus.route(Datagram::new(from, bytes), clock.now_us());
                }
                Err(e) => {
                    if let LogVerdict::Log { suppressed } = failures.event(clock.now_us()) {
                        warn!(
                            "receive failed: {:?} ({} more since the last such line)",
                            debug_value!(e),
                            suppressed
                        );
                    }
                }
            }
        }
    };
    let tx = async {
        let mut encoder = ReportEncoder::new();
        let mut buf = [0u8; MAX_REPORT_FRAME];
        let mut failures = LogLimit::new();
        let mut outbox_full = LogLimit::new();
        loop {
            let out = bus.outbox.receive().await;
            let drops = bus.take_outbox_drops();
            if let LogVerdict::Log { suppressed } = outbox_full.events(drops, clock.now_us()) {
                warn!(
                    "outbox full: {} frames dropped since the last such line",
                    suppressed.saturating_add(drops)
                );
            }
            let routes = bus.report_settings();
            let Some((destinations, n)) = encoder.encode(&out, &routes, &mut buf) else {
                continue;
            };
            for to in destinations {
                if let Err(e) = socket.send(to, buf.get(..n).unwrap_or_default()).await
                    && let LogVerdict::Log { suppressed } = failures.event(clock.now_us())
                {
                    warn!(
                        "send failed: {:?} ({} more since the last such line)",
                        debug_value!(e),
                        suppressed
                    );
                }
            }
        }
    };
    match join(rx, tx).await {}
}

/// Sends a LOCATION report (positions from the engine, state from `bus.reports`) every
/// upload period while reports are on and an owner exists. The period restarts when the
/// trajectory task changes it. (LOCATION reports on state changes are sent by the
/// trajectory task itself, with the state of that instant.)
pub async fn upload_task<const Q: usize, B: StepBackend, C: Clock>(
    bus: &Bus,
    step: &StepShared<Q, B>,
    clock: &C,
) -> ! {
    let mut next = clock.now_us();
    loop {
        if bus.report_settings().upload_period_us == 0 {
            // Not published yet (ReportSettings::UNPUBLISHED).
            bus.upload_changed.wait().await;
            next = clock.now_us();
            continue;
        }
        let period = u64::from(bus.report_settings().upload_period_us.max(1));
        next += period;
        let now = clock.now_us();
        if next <= now {
            // Fell behind (a long pause): skip the missed reports.
            next = now + period;
        }
        match select(clock.sleep_until(next), bus.upload_changed.wait()).await {
            Either::First(()) => {
                let settings = bus.report_settings();
                if settings.reports_on && settings.has_location_listener() {
                    bus.send(Outgoing::Location(protocol::Location {
                        position: step.positions(),
                        state: settings.state as u8,
                    }));
                }
            }
            Either::Second(()) => next = clock.now_us(),
        }
    }
}

/// The serial pass-through: writes USART_SEND payloads, and reads the port into
/// USART_RECV reports (sent when 255 bytes wait, after one byte time of idle line, or 1 ms
/// after data arrived). `port.read` must be cancel-safe (a read dropped before it
/// completes loses no byte), since it is raced against the batch deadline.
pub async fn serial_task<P: SerialPort, C: Clock>(port: &P, bus: &Bus, clock: &C) -> ! {
    let writer = async {
        loop {
            let bytes = bus.serial_tx.receive().await;
            if let Err(e) = port.write(&bytes).await {
                warn!("serial write failed: {:?}", e);
            }
        }
    };
    let reader = async {
        let mut open: Option<UartInit> = None;
        let mut batch = SerialBatcher::new(0);
        let mut buf = [0u8; MAX_SERIAL_CHUNK];
        loop {
            if let Some(init) = bus.serial_opened.try_take() {
                open = Some(init);
            }
            let init = match open {
                Some(init) if init.mode() != UartMode::TransmitOnly => init,
                _ => {
                    // Closed, or nothing to read: wait for the next USART_START.
                    batch.clear();
                    open = Some(bus.serial_opened.wait().await);
                    continue;
                }
            };
            batch.set_byte_time_us(byte_time_us(&init));
            let room = batch.room().min(buf.len());
            let read = port.read(&mut buf[..room]);
            let outcome = match batch.deadline_us() {
                Some(deadline) => match select(read, clock.sleep_until(deadline)).await {
                    Either::First(r) => Some(r),
                    Either::Second(()) => None,
                },
                None => Some(read.await),
            };
            match outcome {
                Some(Ok(n)) => {
                    batch.push(buf.get(..n).unwrap_or_default(), clock.now_us());
                }
                Some(Err(SerialError::Closed)) => {
                    batch.clear();
                    open = None;
                }
                Some(Err(e)) => warn!("serial read failed: {:?}", e),
                None => {}
            }
            if batch.is_due(clock.now_us()) {
                bus.send(Outgoing::UsartRecv(batch.take()));
            }
        }
    };
    match join(writer, reader).await {}
}

/// The hardware the trajectory task drives besides the step engine.
pub struct TrajectoryHw<'a, K, O, G, P, S, E> {
    /// The step timer.
    pub kick: &'a K,
    /// PIN0/PIN1 and the ENABLE lines.
    pub outputs: O,
    /// The gripper timer.
    pub gripper: G,
    /// The serial port (shared with `serial_task`; opened and closed here).
    pub serial: &'a P,
    /// Persistent settings.
    pub settings: S,
    /// Absolute encoders.
    pub encoders: E,
}

/// [`Plant`] over the shared engine and the hardware.
struct TaskPlant<'a, const Q: usize, B, K, O, G, P> {
    bus: &'a Bus,
    step: &'a StepShared<Q, B>,
    kick: &'a K,
    lead_ticks: u64,
    outputs: &'a mut O,
    gripper: &'a mut G,
    serial: &'a P,
}

impl<const Q: usize, B: StepBackend, K: StepKick, O: Outputs, G: Gripper, P: SerialPort> Plant
    for TaskPlant<'_, Q, B, K, O, G, P>
{
    fn positions(&self) -> [i32; MAX_JOINTS] {
        self.step.positions()
    }
    fn set_positions(&mut self, positions: [i32; MAX_JOINTS]) -> bool {
        self.step.set_positions(positions)
    }
    fn stop(&mut self) {
        self.step.stop();
        self.kick.kick();
        self.bus.segments.clear();
        // step_task may be waiting on step_wake with a segment the full engine refused;
        // after a stop no segment finishes to wake it: wake it here, or it never takes
        // the next run's segments.
        self.bus.step_wake.signal(());
    }
    fn push_segment(&mut self, segment: Segment) -> bool {
        let msg = SegmentMsg {
            generation: self.step.generation(),
            segment,
        };
        self.bus.segments.try_send(msg).is_ok()
    }
    fn start(&mut self) {
        self.step.start(self.kick.now_tick() + self.lead_ticks);
        self.kick.kick();
    }
    fn set_user_pin(&mut self, pin: u8, high: bool) {
        self.outputs.set_user_pin(pin, high);
    }
    fn set_enabled(&mut self, enabled: u16) {
        self.outputs.set_enabled(enabled);
    }
    fn gripper_start(&mut self, pwm: &Pwm) {
        self.gripper.start(pwm);
    }
    fn gripper_stop(&mut self) {
        self.gripper.stop();
    }
    fn gripper_active(&self) -> bool {
        self.gripper.is_active()
    }
    fn serial_open(&mut self, init: &UartInit) -> Result<(), SerialError> {
        self.serial.open(init)?;
        self.bus.serial_opened.signal(*init);
        Ok(())
    }
    fn serial_close(&mut self) {
        self.bus.serial_tx.clear();
        self.serial.close();
    }
    fn serial_send(&mut self, bytes: &[u8]) -> bool {
        match Vec::from_slice(bytes) {
            Ok(v) => self.bus.serial_tx.try_send(v).is_ok(),
            Err(_) => false,
        }
    }
}

/// Owns the [`Controller`]: handles datagrams (STOPPED from `bus.estop` first), sends
/// ACKs and reports, executes the effects on the hardware, feeds segments to the step
/// task and ends runs when the engine runs dry. At start: loads the stored settings,
/// takes the gripper timer clock for STATUS, and drives the ENABLE lines to their boot
/// state (all holding).
pub async fn trajectory_task<const CAP: usize, const Q: usize, B, C, K, O, G, P, S, E>(
    controller: &mut Controller<CAP>,
    bus: &Bus,
    step: &StepShared<Q, B>,
    clock: &C,
    hw: TrajectoryHw<'_, K, O, G, P, S, E>,
) -> !
where
    B: StepBackend,
    C: Clock,
    K: StepKick,
    O: Outputs,
    G: Gripper,
    P: SerialPort,
    S: SettingsStore,
    E: Encoders,
{
    let TrajectoryHw {
        kick,
        mut outputs,
        mut gripper,
        serial,
        mut settings,
        mut encoders,
    } = hw;
    match settings.load().await {
        Ok(Some(stored)) => controller.apply_settings(stored),
        Ok(None) => {}
        Err(e) => warn!("settings not loaded, using defaults: {:?}", debug_value!(e)),
    }
    controller.set_pwm_timer_clock_hz(gripper.timer_clock_hz());
    outputs.set_enabled(controller.enabled());
    publish(bus, controller);
    let lead_ticks = us_to_ticks(u64::from(START_LEAD_US), step.timing().tick_hz);
    // STOPPEDs taken from `bus.estop`, and which of them the controller executed: an
    // inbox datagram stamped with fewer arrived before them; only an executed one stops.
    let mut stops = OvertakingStops::new();
    loop {
        // Biased: a waiting STOPPED is always taken first.
        let event = select3(
            bus.estop.receive(),
            bus.inbox.receive(),
            bus.step_progress.wait(),
        )
        .await;
        let mut plant = TaskPlant {
            bus,
            step,
            kick,
            lead_ticks,
            outputs: &mut outputs,
            gripper: &mut gripper,
            serial,
        };
        let response = match event {
            Either3::First(d) => {
                let response = controller.handle(d.from, &d.bytes, clock.now_us(), &mut plant);
                // Refused (BAD_LENGTH) or a duplicate: it did nothing, and it must not
                // stop the frames it overtook either.
                stops.took(response.executed);
                response
            }
            Either3::Second(d) if stops.executed_between(d.stops_before, None) => Response {
                deferred: handle_overtaken(controller, bus, d, clock, &mut plant, &stops),
                ..Response::default()
            },
            Either3::Second(d) => controller.handle(d.from, &d.bytes, clock.now_us(), &mut plant),
            Either3::Third(()) => Response::default(),
        };
        // Published before the reports are queued: the network task addresses them when
        // it sends them, possibly while this task waits below.
        publish(bus, controller);
        deliver(bus, &response);
        match response.deferred {
            Some(Deferred::SaveSettings(s)) => {
                if let Err(e) = settings.save(&s).await {
                    warn!("settings not saved: {:?}", debug_value!(e));
                }
            }
            Some(Deferred::ReadEncoders) => {
                let location = match encoders.read_joints(controller.joints()).await {
                    Ok(read) => controller.begin_return(read, &mut plant),
                    Err(fault) => {
                        warn!(
                            "RETURN refused: encoder of joint {} failed: {:?}",
                            fault.joint, fault.kind
                        );
                        controller.fail_return(fault, &mut plant)
                    }
                };
                if let Some(location) = location {
                    bus.send(Outgoing::Location(location));
                }
            }
            None => {}
        }
        let (finished, ran_dry) = step.take_progress();
        if let Some(location) = controller.on_step_progress(finished, ran_dry, &mut plant) {
            bus.send(Outgoing::Location(location));
        }
        publish(bus, controller);
    }
}

/// Handles `first`, an inbox datagram overtaken by an executed STOPPED, then the queued
/// datagrams that arrived before the last executed STOPPED, in arrival order (same ACKs,
/// same duplicate memory), applying each executed STOPPED after the datagram it followed
/// ([`Controller::stop_after_overtaken`]). All without a wait: a run one of them starts
/// is stopped before the step task can hand the engine a segment. Returns the deferred
/// work still to do: a settings write (an encoder read would start a cancelled RETURN).
fn handle_overtaken<const CAP: usize, C: Clock>(
    controller: &mut Controller<CAP>,
    bus: &Bus,
    first: Datagram,
    clock: &C,
    plant: &mut impl Plant,
    stops: &OvertakingStops,
) -> Option<Deferred> {
    let mut save = None;
    let mut next = Some(first);
    while let Some(datagram) = next.take() {
        let response = controller.handle(datagram.from, &datagram.bytes, clock.now_us(), plant);
        publish(bus, controller);
        deliver(bus, &response);
        if let Some(Deferred::SaveSettings(settings)) = response.deferred {
            save = Some(settings);
        }
        let next_stamp = bus.inbox.try_peek().ok().map(|queued| queued.stops_before);
        // An executed STOPPED arrived between this datagram and the next: apply it now.
        if stops.executed_between(datagram.stops_before, next_stamp) {
            let location = controller.stop_after_overtaken(plant);
            publish(bus, controller);
            if let Some(location) = location {
                bus.send(Outgoing::Location(location));
            }
        }
        // The next one was overtaken too: handle it before anything else.
        if next_stamp.is_some_and(|stamp| stops.executed_between(stamp, None)) {
            next = bus.inbox.try_receive().ok();
        }
    }
    save.map(Deferred::SaveSettings)
}

/// STOPPED window of [`OvertakingStops`]: how many of the latest STOPPEDs taken it tells
/// apart. Older ones count as executed (a stop is the safe side); only a flood of more
/// than this many STOPPEDs while a datagram waits in the inbox gets there.
pub const STOP_MEMORY: u32 = 128;

/// The STOPPEDs the trajectory task took from `bus.estop` (each numbered by
/// [`Bus::route`] as it arrived: the stamps of [`Datagram::stops_before`]) and which of
/// them the controller executed. A datagram stamped `s` arrived before STOPPED number
/// `s`; it was overtaken by those numbered `s` and up that were taken before it. Only an
/// executed STOPPED (ACK `OK`, not a duplicate) stops what it overtook: a refused or
/// repeated one did nothing in arrival order either.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct OvertakingStops {
    /// STOPPEDs taken (wrapping): the next one taken is number `taken`.
    taken: u32,
    /// Bit `i`: STOPPED number `taken - 1 - i` was executed.
    executed: u128,
}

impl OvertakingStops {
    /// None taken yet.
    pub const fn new() -> Self {
        OvertakingStops {
            taken: 0,
            executed: 0,
        }
    }

    /// The next STOPPED from `bus.estop` was handled; `executed` if it did stop.
    pub fn took(&mut self, executed: bool) {
        self.taken = self.taken.wrapping_add(1);
        self.executed = (self.executed << 1) | u128::from(executed);
    }

    /// Whether an executed STOPPED numbered `from` up to (not including) `to` (`None`:
    /// every one taken) was taken.
    pub fn executed_between(&self, from: u32, to: Option<u32>) -> bool {
        // Stops taken with a number >= from (wrapping counters, small differences).
        let since_from = self.taken.wrapping_sub(from) as i32;
        let since_to = to.map_or(0, |to| (self.taken.wrapping_sub(to) as i32).max(0));
        if since_from <= since_to {
            return false;
        }
        if since_from as u32 > STOP_MEMORY {
            return true;
        }
        // Bits since_to..since_from stand for numbers from..to.
        let below = |n: i32| 1u128.checked_shl(n as u32).map_or(u128::MAX, |bit| bit - 1);
        self.executed & below(since_from) & !below(since_to) != 0
    }
}

/// Queues what a handled datagram produced.
fn deliver(bus: &Bus, response: &Response) {
    if let Some(reply) = response.reply {
        bus.send(Outgoing::Ack(reply));
    }
    if let Some((to, status)) = response.status {
        bus.send(Outgoing::Status(to, status));
    }
    if let Some(location) = response.location {
        bus.send(Outgoing::Location(location));
    }
    if let Some(discovery) = response.discovery {
        bus.send(Outgoing::Discovery(discovery));
    }
}

/// Copies the report settings out for the other tasks; wakes the upload task when its
/// settings changed.
fn publish<const CAP: usize>(bus: &Bus, controller: &Controller<CAP>) {
    let new = controller.report_settings();
    let old = bus.reports.lock(|c| c.replace(new));
    if old.reports_on != new.reports_on || old.upload_period_us != new.upload_period_us {
        bus.upload_changed.signal(());
    }
}
