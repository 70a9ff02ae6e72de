//! The step backend shared between the step interrupts and the tasks ([`StepShared`]):
//! the engine (or the board's DMA producer, any [`StepBackend`]) behind one lock (a
//! critical section by default; the NUCLEO's is BASEPRI-based), with the bookkeeping that
//! must change with it (stop count, finished segments, ran dry), and the step timer
//! interrupt's body [`on_step_timer`].

use core::cell::RefCell;

#[cfg(any(test, feature = "test-support"))]
use arm_step::StepPins;
use arm_step::{Segment, StepEngine, StepTiming};
use embassy_sync::blocking_mutex::Mutex;
// The mutex kind of the bus ([`crate::bus::Cs`]), named here directly: this module sits
// below the bus (the ingress path halts the steps through it), so it imports nothing
// from it.
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex as Cs;
use embassy_sync::blocking_mutex::raw::RawMutex;
use embassy_sync::signal::Signal;
use protocol::MAX_JOINTS;

#[cfg(doc)]
use crate::hw::StepKick;

/// The shortest point for which a board's lookahead (its profile's `lookahead_us`, the
/// motion the step side holds ahead of the pulses) holds in full: the protocol's own
/// examples and the fastest streams seen (armctl's 200 us resampling) use points of 200 us
/// or more. Shorter points get the queue's count of them (a shorter span): the count
/// bounds the RAM.
pub const LOOKAHEAD_SHORTEST_POINT_US: u32 = 200;

/// Segments the step backend holds on the interrupts' side (the board's DMA producer's
/// queue, or the test oracle's) for a lookahead of `lookahead_us`: that much motion of
/// points of [`LOOKAHEAD_SHORTEST_POINT_US`], rounded up to a power of two. The trajectory
/// task pushes every buffered point that fits, so with points this long or longer the
/// step side always holds at least the lookahead (or the rest of the run). Each slot is
/// 64 bytes. Each board's is `crate::profile::BoardProfile::step_queue`.
pub const fn step_queue_for(lookahead_us: u32) -> usize {
    ((lookahead_us / LOOKAHEAD_SHORTEST_POINT_US) as usize).next_power_of_two()
}

/// Time between the start of a run being decided and its first segment's start: leaves
/// the step interrupt time to set the DIR lines (and a simulator's scheduler some slack).
pub const START_LEAD_US: u32 = 1_000;

/// Microseconds to step timer ticks (rounded down).
pub fn us_to_ticks(us: u64, tick_hz: u32) -> u64 {
    u64::try_from(u128::from(us) * u128::from(tick_hz) / 1_000_000).unwrap_or(u64::MAX)
}

/// Pins that do nothing: thread-level code stops the engine with these, and the next
/// interrupt lowers the real STEP lines.
#[cfg(any(test, feature = "test-support"))]
struct NoPins;

#[cfg(any(test, feature = "test-support"))]
impl StepPins for NoPins {
    fn set_direction(&mut self, _joint: usize, _positive: bool) {}
    fn step_high(&mut self, _joints: arm_step::JointMask) {}
    fn step_low(&mut self, _joints: arm_step::JointMask) {}
}

/// What the tasks need from whatever makes the step pulses: arm-step's DMA stream producer
/// (the board's timers play its buffers; the QEMU board and the simulator play them in
/// software with arm-step's `StreamPlayer`) or [`StepEngine`] (edges made by an interrupt
/// per deadline: arm-core's own task tests, through [`on_step_timer`]). Called inside
/// [`StepShared`]'s lock: implementations must not block.
pub trait StepBackend {
    /// Timer resolution and driver timing.
    fn timing(&self) -> StepTiming;
    /// Queues a segment; gives it back if the queue is full.
    fn push(&mut self, segment: Segment) -> Result<(), Segment>;
    /// Segments held.
    fn queued(&self) -> usize;
    /// Starts running the queue at `at_tick` (step timer ticks, [`StepKick::now_tick`]).
    /// A backend whose start is long may only begin it here and leave the rest to
    /// [`StepBackend::continue_start`] (see [`StepBackend::starting`]).
    fn start(&mut self, at_tick: u64);
    /// Whether a start begun by [`StepBackend::start`] has pieces left:
    /// [`StepShared`] then calls [`StepBackend::continue_start`], each call in a lock of its
    /// own, until it has none (or a stop in between ended it), so that no lock is held for
    /// a whole start (the NUCLEO primes every joint's buffers: up to 228 us, issue 20).
    /// Default: a start is done at once.
    fn starting(&self) -> bool {
        false
    }
    /// The next piece of a start ([`StepBackend::starting`]).
    fn continue_start(&mut self) {}
    /// Emergency stop: no pulse after this returns (or, for an engine whose lines the
    /// next interrupt lowers, after that interrupt); the queue is dropped; positions
    /// keep the pulses made.
    fn stop(&mut self);
    /// Joint positions, steps.
    fn positions(&self) -> [i32; MAX_JOINTS];
    /// Overwrites the positions; refused (false) while running.
    fn set_positions(&mut self, positions: [i32; MAX_JOINTS]) -> bool;
    /// Changes the rate of the run under way (issue 32: HOLD, RESUME, OVERRIDE; arm-step's
    /// warp): from `now_tick` ([`StepKick::now_tick`]), or the first tick after every
    /// edge already committed if later, ramps to `rate` (`arm_step::RATE_ONE` = 100 %)
    /// with the slope that adds at most `accel` steps/s^2 to a joint moving at `speed`
    /// steps/s ([`arm_step::ramp_for`]). False: not taken (no run, or a backend without a
    /// warp: the default, the NUCLEO's and QEMU's for now).
    fn change_rate(&mut self, _now_tick: u64, _rate: u64, _accel: u32, _speed: u32) -> bool {
        false
    }
    /// The rate the run [`StepBackend::start`] starts next begins at, from its start
    /// tick `at_tick` (`RATE_ONE`: no warp). Called just before the start. False: not
    /// taken (the default: only 100 % is run).
    fn set_start_rate(&mut self, _at_tick: u64, rate: u64) -> bool {
        rate == arm_step::RATE_ONE
    }
    /// The rate at `now_tick` (`RATE_ONE` = 100 %) and whether it is changing; `None`:
    /// no run, or a backend without a warp.
    fn rate_now(&self, _now_tick: u64) -> Option<(u64, bool)> {
        None
    }
    /// Steps per second of all joints together this backend can place under a warp
    /// (`BoardProfile::warp_budget_hz`); 0: no limit (the default, the test oracle's).
    fn warp_budget_hz(&self) -> u32 {
        0
    }
}

/// The test oracle's backend (arm-core's task tests; feature `test-support`): the boards
/// and the simulator step through arm-step's producer instead.
#[cfg(any(test, feature = "test-support"))]
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
    fn change_rate(&mut self, now_tick: u64, rate: u64, accel: u32, speed: u32) -> bool {
        if !self.is_running() {
            return false;
        }
        let ramp = arm_step::ramp_for(accel, speed, StepEngine::timing(self).tick_hz);
        let at = now_tick.max(self.warp_horizon());
        self.change_warp(at, rate, ramp).is_ok()
    }
    fn set_start_rate(&mut self, at_tick: u64, rate: u64) -> bool {
        // The engine's clock runs on across runs: the rate from this run's start.
        arm_step::Warp::steady(at_tick, rate).is_ok_and(|warp| self.set_warp(warp))
    }
    fn rate_now(&self, now_tick: u64) -> Option<(u64, bool)> {
        let warp = self.warp();
        self.is_running()
            .then(|| (warp.rate(now_tick), warp.ramping(now_tick)))
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
    /// The wired e-stop input is open ([`StepShared::halt`]): no run starts.
    halted: bool,
    /// The rate the next run starts at ([`StepShared::set_start_rate`]).
    start_rate: u64,
}

impl<B: StepBackend> StepState<B> {
    /// [`StepShared::stop`]'s work, inside the lock.
    fn stop(&mut self) {
        self.engine.stop();
        self.finished = 0;
        self.ran_dry = false;
        self.start_pending = false;
        self.lower_step_lines = true;
    }
}

/// The step engine (or other [`StepBackend`]) shared between the step interrupts and the
/// tasks: `Mutex<M, RefCell<..>>` around it plus the bookkeeping that must change
/// atomically with it (stop count, finished segments, ran dry). `Q`: the engine's queue
/// when the backend is the default [`StepEngine`]. `M`: the lock, by default a critical
/// section (every interrupt masked); the NUCLEO's masks only the interrupts at or below
/// its step refills (BASEPRI), so that its DIR changes and e-stop input, which never
/// take this lock, are never held off by it (issue 20).
pub struct StepShared<const Q: usize, B = StepEngine<Q>, M = Cs> {
    inner: Mutex<M, RefCell<StepState<B>>>,
}

#[cfg(any(test, feature = "test-support"))]
impl<const Q: usize> StepShared<Q> {
    /// An idle engine with this timing.
    pub const fn new(timing: StepTiming) -> Self {
        Self::with_backend(StepEngine::new(timing))
    }
}

impl<const Q: usize, B: StepBackend, M: RawMutex> StepShared<Q, B, M> {
    /// Shares `backend` (idle).
    pub const fn with_backend(backend: B) -> Self {
        StepShared {
            inner: Mutex::new(RefCell::new(StepState {
                engine: backend,
                finished: 0,
                ran_dry: false,
                start_pending: false,
                lower_step_lines: false,
                halted: false,
                start_rate: arm_step::RATE_ONE,
            })),
        }
    }

    /// Runs `f` on the backend inside the lock (inspection, simulators).
    pub fn with_engine<R>(&self, f: impl FnOnce(&mut B) -> R) -> R {
        self.inner.lock(|s| f(&mut s.borrow_mut().engine))
    }

    /// The body of a step interrupt other than the engine's timer (the board's DMA
    /// refills and run end): runs `f` on the backend in the lock, records the
    /// progress it reports and wakes `wake` (the bus's `step_progress`, which the
    /// trajectory task waits on) if there is any.
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

    /// Emergency stop: the engine drops every segment and emits no further pulse; the
    /// next interrupt lowers the STEP lines (kick it); uncollected progress is dropped.
    /// Segments pushed afterwards wait for a [`StepShared::start`]: the only pusher is
    /// the trajectory task, whose controller handles the stop (and drops them) before it
    /// starts anything.
    pub fn stop(&self) {
        self.inner.lock(|s| s.borrow_mut().stop())
    }

    /// The wired e-stop input opened ([`crate::estop_input`]): [`StepShared::stop`], and
    /// no run starts ([`StepShared::start`] does nothing) until [`StepShared::release`],
    /// whatever the tasks do meanwhile. For the input's edge handler (an interrupt on the
    /// board; on the NUCLEO, whose lock its e-stop interrupt may not take, the step
    /// service interrupt that interrupt pends): one lock, no wait.
    pub fn halt(&self) {
        self.inner.lock(|s| {
            let mut s = s.borrow_mut();
            s.stop();
            s.halted = true;
        })
    }

    /// The wired e-stop input opened under category 1 ([`crate::estop_input`]): the run
    /// under way goes on (the trajectory task ramps it down) but no run starts until
    /// [`StepShared::release`], as after [`StepShared::halt`].
    pub fn block_starts(&self) {
        self.inner.lock(|s| s.borrow_mut().halted = true)
    }

    /// The wired e-stop input closed: runs may start again (the controller still refuses
    /// them until its latch is cleared).
    pub fn release(&self) {
        self.inner.lock(|s| s.borrow_mut().halted = false)
    }

    /// Queues a segment (false: the queue is full, offer it again when segments
    /// finished); starts the engine at `start_tick` if a start is pending.
    pub fn push(&self, segment: Segment, start_tick: u64) -> bool {
        let pushed = self.inner.lock(|s| {
            let mut s = s.borrow_mut();
            if s.engine.push(segment).is_err() {
                return false;
            }
            if s.start_pending {
                s.start_pending = false;
                let rate = s.start_rate;
                s.engine.set_start_rate(start_tick, rate);
                s.engine.start(start_tick);
            }
            true
        });
        self.finish_start();
        pushed
    }

    /// Changes the rate of the run under way ([`StepBackend::change_rate`]).
    pub fn change_rate(&self, now_tick: u64, rate: u64, accel: u32, speed: u32) -> bool {
        self.with_engine(|e| e.change_rate(now_tick, rate, accel, speed))
    }

    /// The warp budget ([`StepBackend::warp_budget_hz`]).
    pub fn warp_budget_hz(&self) -> u32 {
        self.with_engine(|e| e.warp_budget_hz())
    }

    /// The rate now and whether it is changing ([`StepBackend::rate_now`]).
    pub fn rate_now(&self, now_tick: u64) -> Option<(u64, bool)> {
        self.with_engine(|e| e.rate_now(now_tick))
    }

    /// The rate the next run starts at (`RATE_ONE`: 100 %, the default), taken when it
    /// starts ([`StepBackend::set_start_rate`]).
    pub fn set_start_rate(&self, rate: u64) {
        self.inner.lock(|s| s.borrow_mut().start_rate = rate);
    }

    /// Starts the engine at `start_tick` if it holds a segment, else as soon as one is
    /// pushed; nothing while halted ([`StepShared::halt`]).
    pub fn start(&self, start_tick: u64) {
        self.inner.lock(|s| {
            let mut s = s.borrow_mut();
            if s.halted {
                return;
            }
            if s.engine.queued() > 0 {
                let rate = s.start_rate;
                s.engine.set_start_rate(start_tick, rate);
                s.engine.start(start_tick);
            } else {
                s.start_pending = true;
            }
        });
        self.finish_start();
    }

    /// The rest of a start the backend does in pieces ([`StepBackend::starting`]), one lock
    /// each: between two, the interrupts that take the lock run (a halt among them, which
    /// stops the backend and so ends the start).
    fn finish_start(&self) {
        while self.inner.lock(|s| {
            let mut s = s.borrow_mut();
            if !s.engine.starting() {
                return false;
            }
            s.engine.continue_start();
            true
        }) {}
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

#[cfg(any(test, feature = "test-support"))]
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

/// The step timer interrupt's body for the default [`StepEngine`] backend (arm-core's
/// task tests; the boards and the simulator use the producer): emits the edges due
/// at `now_tick`, records finished segments and running dry for the tasks (waking
/// `wake`, the bus's `step_progress`), and returns the tick to be called again at (`None`:
/// only when kicked).
#[cfg(any(test, feature = "test-support"))]
pub fn on_step_timer<const Q: usize>(
    shared: &StepShared<Q>,
    now_tick: u64,
    pins: &mut impl StepPins,
    wake: &Signal<Cs, ()>,
) -> Option<u64> {
    shared.on_timer(now_tick, pins, wake)
}
