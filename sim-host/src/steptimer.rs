//! The board's step hardware, simulated: each joint's timer playing the periods that
//! arm-step's producer writes into its DMA buffer, and the DMA refilling each half as the
//! timer leaves it, in simulated time.
//!
//! [`SimSteps`] is the simulator's [`StepBackend`]: the same [`StepStreams`] (producer and
//! buffers) as the board, with the same buffer halves, prelude and timer ranges. A step
//! thread plays the buffers through arm-step's [`StreamPlayer`] (which the QEMU board uses
//! too): every STEP edge and DIR change is stamped with the exact tick
//! the producer computed (so positions, the VCD trace and e-stop behave as on the board),
//! but the thread does not wake per edge: it wakes when a joint's timer enters a new half
//! (the refill), at the end of the run, when kicked, and every [`PLAY_INTERVAL`] to bring
//! the motors and the trace up to the present. It never spins, so it leaves the cores to
//! the executor. An emergency stop plays the edges up to the stop's tick, lets a pulse in
//! progress fall at its own width and drops the rest: no STEP pulse rises after the stop,
//! and none is cut short, as on the board (docs/PROTOCOL.md, STOPPED).
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::time::{Duration, Instant};

use arm_core::hw::StepKick;
use arm_core::{StepBackend, StepProgress};
use arm_step::{
    HaltingStepPins, MAX_JOINTS, Segment, StepPins, StepStreams, StepTiming, StreamPlayer,
    TimedStepPins,
};

use crate::clock::SimClock;
use crate::probe::Probe;
use crate::steppers::SimSteppers;
use crate::switches::{SwitchEdge, SwitchModel};
use arm_core::switch_line::SwitchLine;

/// How the step thread runs.
#[derive(Clone, Copy, Debug)]
pub struct StepThreadConfig {
    /// SCHED_FIFO instead of nice -10.
    pub realtime: bool,
}

/// `kick_at` when no kick is pending.
const NO_KICK: u64 = u64::MAX;

struct TimerShared {
    /// Tick of the earliest kick not yet served, or [`NO_KICK`].
    kick_at: AtomicU64,
    lock: Mutex<()>,
    wake: Condvar,
    clock: SimClock,
}

/// [`StepKick`] for the simulator: wakes the step thread.
#[derive(Clone)]
pub struct SimStepKick {
    shared: Arc<TimerShared>,
}

impl std::fmt::Debug for SimStepKick {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SimStepKick").finish()
    }
}

impl SimStepKick {
    /// A kick for a step thread on `clock`.
    pub fn new(clock: SimClock) -> SimStepKick {
        SimStepKick {
            shared: Arc::new(TimerShared {
                kick_at: AtomicU64::new(NO_KICK),
                lock: Mutex::new(()),
                wake: Condvar::new(),
                clock,
            }),
        }
    }
}

impl SimStepKick {
    /// Whether a kick came since the last call (and forgets it): the virtual board plays
    /// the step hardware when kicked, as the step thread does.
    pub fn take_kick(&self) -> bool {
        self.shared.kick_at.swap(NO_KICK, Ordering::AcqRel) != NO_KICK
    }
}

impl StepKick for SimStepKick {
    fn kick(&self) {
        let now = self.shared.clock.now_tick();
        self.shared.kick_at.fetch_min(now, Ordering::AcqRel);
        let _guard = self.shared.lock.lock();
        self.shared.wake.notify_one();
    }

    fn now_tick(&self) -> u64 {
        self.shared.clock.now_tick()
    }
}

/// Longest the step thread sleeps while a run plays: the motors and the trace lag the
/// present by at most this much.
pub const PLAY_INTERVAL: Duration = Duration::from_millis(5);

/// Periods per DMA buffer half: the board's.
pub const HALF: usize = arm_step::NUCLEO_STEP_BUFFER_HALF;

/// The simulated step hardware ([`StepBackend`] of the simulator): the producer, and
/// arm-step's [`StreamPlayer`] (the joints' timers and DMA streams in software) playing
/// its buffers onto the simulated drivers.
pub struct SimSteps<const Q: usize> {
    streams: Box<StepStreams<Q, HALF>>,
    player: Box<StreamPlayer<HALF>>,
    pins: SimSteppers,
    clock: SimClock,
    /// Step clock tick of the run's start (the timers' tick 0), while a run plays.
    origin: Option<u64>,
    /// Segments finished while priming a run, reported with the next progress.
    primed_finished: u32,
    /// Told when an emergency stop has stopped the run (the e-stop latency's end).
    probe: Option<Arc<Probe>>,
    /// The joints' switches (issue 33), if any: looked at each STEP edge; with the
    /// switch line whose mask says which limit does not halt.
    switches: Option<(SwitchModel, &'static SwitchLine)>,
}

impl<const Q: usize> std::fmt::Debug for SimSteps<Q> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SimSteps")
            .field("origin", &self.origin)
            .finish()
    }
}

/// The simulated drivers as the player's lines: each change stamped with its step clock
/// tick (the run's tick plus its origin).
/// With switches, each rise moves the joint's physical model; a limit switch closing asks
/// the player to halt at that (run) tick.
struct Stamped<'a> {
    pins: &'a mut SimSteppers,
    origin: u64,
    /// The step clock tick the thread plays at (DIR lateness, [`crate::sim_diag`]).
    now: u64,
    switches: Option<(&'a mut SwitchModel, &'static SwitchLine)>,
    halt: Option<u64>,
}

impl<'a> Stamped<'a> {
    fn new(
        pins: &'a mut SimSteppers,
        origin: u64,
        now: u64,
        switches: Option<(&'a mut SwitchModel, &'static SwitchLine)>,
    ) -> Self {
        Stamped {
            pins,
            origin,
            now,
            switches,
            halt: None,
        }
    }
}

impl TimedStepPins for Stamped<'_> {
    fn step_high(&mut self, joint: usize, tick: u64) {
        self.pins.set_tick(self.origin + tick);
        self.pins.step_high(1 << joint);
        if let Some((model, line)) = self.switches.as_mut() {
            let motor = self.pins.motors().position[joint].load(Ordering::Relaxed);
            if let Some(side) = model.moved(joint, motor, self.origin + tick)
                && self.halt.is_none()
                && !line.is_masked(joint as u8, side)
            {
                self.halt = Some(tick);
            }
        }
    }

    fn step_low(&mut self, joint: usize, tick: u64) {
        self.pins.set_tick(self.origin + tick);
        self.pins.step_low(1 << joint);
    }

    fn set_direction(&mut self, joint: usize, positive: bool, tick: u64) {
        self.pins.set_tick(self.origin + tick);
        self.pins.set_direction(joint, positive);
        crate::sim_diag::dir_played(self.origin + tick, self.now);
    }
}

impl HaltingStepPins for Stamped<'_> {
    fn halt_tick(&self) -> Option<u64> {
        self.halt
    }
}

impl<const Q: usize> SimSteps<Q> {
    /// Idle hardware driving `pins`.
    pub fn new(timing: StepTiming, pins: SimSteppers, clock: SimClock) -> SimSteps<Q> {
        SimSteps {
            // The board's stream periods (its timers' ranges, capped: a speed change waits
            // for at most two buffer halves of them, `profile::STREAM_PERIOD_CAP_NS`).
            streams: Box::new(StepStreams::new(
                timing,
                arm_core::profile::NUCLEO_H743ZI2.stream_period_ticks(),
            )),
            player: Box::new(StreamPlayer::IDLE),
            pins,
            clock,
            origin: None,
            primed_finished: 0,
            probe: None,
            switches: None,
        }
    }

    /// Gives the joints `model`'s switches (issue 33), whose edges go to `line`.
    pub fn with_switches(mut self, model: SwitchModel, line: &'static SwitchLine) -> SimSteps<Q> {
        self.switches = Some((model, line));
        self
    }

    /// The switch edges the played STEP edges made since the last call (for the switch
    /// path, outside the step backend's lock).
    pub fn take_switch_edges(&mut self) -> Vec<SwitchEdge> {
        self.switches
            .as_mut()
            .map_or_else(Vec::new, |(model, _)| model.take_edges())
    }

    /// Tells `probe` when an emergency stop has stopped a run.
    pub fn with_probe(mut self, probe: Arc<Probe>) -> SimSteps<Q> {
        self.probe = Some(probe);
        self
    }

    /// Whether a run is playing.
    pub fn is_running(&self) -> bool {
        self.origin.is_some()
    }

    /// Plays every joint up to step clock tick `now`: edges, DIR changes, refills of the
    /// halves the timers left; ends the run at its end.
    pub fn advance(&mut self, now: u64) -> StepProgress {
        let Some(origin) = self.origin else {
            return StepProgress::default();
        };
        let mut pins = Stamped::new(
            &mut self.pins,
            origin,
            now,
            self.switches.as_mut().map(|(m, l)| (m, *l)),
        );
        let (advance, halt) =
            self.player
                .advance_halting(&mut self.streams, now.saturating_sub(origin), &mut pins);
        if let Some(halt) = halt {
            // A limit switch closed at `halt`: nothing after it is played, on any joint
            // (the switch path halts the shared backend next, outside this lock).
            self.player.stop(&mut self.streams, halt, &mut pins);
            self.origin = None;
        } else if advance.ended {
            self.origin = None;
        }
        StepProgress {
            segments_finished: advance.segments_finished
                + std::mem::take(&mut self.primed_finished),
            ran_dry: advance.ended,
        }
    }

    /// Step clock tick at which the thread must run next: the first refill, or the end.
    pub fn next_due(&self) -> Option<u64> {
        let origin = self.origin?;
        Some(origin + self.player.next_due(&self.streams)?)
    }
}

impl<const Q: usize> StepBackend for SimSteps<Q> {
    fn timing(&self) -> StepTiming {
        self.streams.producer_ref().timing()
    }

    fn push(&mut self, segment: Segment) -> Result<(), Segment> {
        self.streams.producer().push(segment)
    }

    fn queued(&self) -> usize {
        self.streams.producer_ref().queued()
    }

    fn start(&mut self, at_tick: u64) {
        if self.origin.is_some() {
            return;
        }
        let now = self.clock.now_tick();
        let primed = self
            .player
            .prime(&mut self.streams, at_tick.saturating_sub(now));
        if primed.dir_overflow {
            self.streams.producer().stop();
            return;
        }
        self.primed_finished = primed.segments_finished;
        self.origin = Some(now);
    }

    fn stop(&mut self) {
        let Some(origin) = self.origin.take() else {
            self.streams.producer().stop();
            return;
        };
        // Everything up to the stop happened; nothing rises after it, and a pulse high at
        // it falls at its own width (the outputs are quiet from `quiet`).
        let now = self.clock.now_tick();
        let quiet = self.player.stop(
            &mut self.streams,
            now.saturating_sub(origin),
            &mut Stamped::new(
                &mut self.pins,
                origin,
                now,
                self.switches.as_mut().map(|(m, l)| (m, *l)),
            ),
        );
        self.primed_finished = 0;
        if let Some(probe) = &self.probe {
            probe.engine_running.store(false, Ordering::Release);
            probe.engine_stopped(Instant::now(), self.clock.tick_to_ns(origin + quiet));
        }
    }

    /// The pulses played so far (the producer's count less what is still in the
    /// buffers), as on the board.
    fn positions(&self) -> [i32; MAX_JOINTS] {
        self.player.positions(&self.streams)
    }

    fn set_positions(&mut self, positions: [i32; MAX_JOINTS]) -> bool {
        let set = self.origin.is_none() && self.streams.producer().set_positions(positions);
        if set && let Some((model, _)) = &mut self.switches {
            model.counts_set(positions, self.pins.motors().positions());
        }
        set
    }

    /// The board's producer takes the warp on the run's clock (from the run's start, as
    /// `start` restarts it at 0): the change goes in at the first tick after what it has
    /// written (a buffer half or two ahead of the timers).
    fn change_rate(&mut self, now_tick: u64, rate: u64, accel: u32, speed: u32) -> bool {
        let Some(origin) = self.origin else {
            return false;
        };
        let producer = self.streams.producer();
        let ramp = arm_step::ramp_for(accel, speed, producer.timing().tick_hz);
        let at = now_tick.saturating_sub(origin).max(producer.warp_horizon());
        producer.change_warp(at, rate, ramp).is_ok()
    }

    fn set_start_rate(&mut self, _at_tick: u64, rate: u64) -> bool {
        // The run's clock starts at 0 (`start`): the rate from there.
        arm_step::Warp::steady(0, rate)
            .is_ok_and(|warp| self.origin.is_none() && self.streams.producer().set_warp(warp))
    }

    /// The NUCLEO's, which the simulator models: a speed change is refused alike.
    fn warp_budget_hz(&self) -> u32 {
        arm_core::profile::SIMULATOR.warp_budget_hz
    }

    fn rate_now(&self, now_tick: u64) -> Option<(u64, bool)> {
        let origin = self.origin?;
        let warp = self.streams.producer_ref().warp();
        let tick = now_tick.saturating_sub(origin);
        Some((warp.rate(tick), warp.ramping(tick)))
    }
}

/// What one play of the step hardware found.
#[derive(Clone, Copy, Debug, Default)]
pub struct Played {
    /// A run is still playing.
    pub running: bool,
    /// Step clock tick at which to play next (a refill or the run's end).
    pub due: Option<u64>,
    /// The run reached its end during this play.
    pub ended: bool,
}

/// What the step thread asks of the shared hardware at each wake-up.
pub trait StepPlayer: Send + 'static {
    /// Plays up to step clock tick `now` (recording progress for the tasks).
    fn play(&mut self, now: u64) -> Played;
}

impl<F: FnMut(u64) -> Played + Send + 'static> StepPlayer for F {
    fn play(&mut self, now: u64) -> Played {
        self(now)
    }
}

/// Starts the step thread: plays the simulated step hardware through `player` when a
/// refill or the run's end is due, when kicked, and every [`PLAY_INTERVAL`] while a run
/// plays; sleeps otherwise.
pub fn spawn_step_thread(
    kick: &SimStepKick,
    probe: Arc<Probe>,
    config: StepThreadConfig,
    mut player: impl StepPlayer,
) -> std::io::Result<()> {
    let shared = kick.shared.clone();
    std::thread::Builder::new()
        .name("step-dma".into())
        .spawn(move || {
            raise_priority(config.realtime);
            let clock = shared.clock;
            loop {
                shared.kick_at.store(NO_KICK, Ordering::Release);
                let now = clock.now_tick();
                let Played {
                    running,
                    due,
                    ended,
                } = player.play(now);
                probe.engine_running.store(running, Ordering::Release);
                if ended {
                    // (An emergency stop tells the probe itself, inside the stop.)
                    probe.engine_stopped(Instant::now(), clock.tick_to_ns(now));
                }
                // Sleep until the next refill or end, a kick, or the play interval.
                let mut wait = if running {
                    PLAY_INTERVAL
                } else {
                    Duration::from_millis(100)
                };
                if let Some(due) = due {
                    let at = clock.real_instant_of_tick(due);
                    wait = wait.min(at.saturating_duration_since(Instant::now()));
                }
                if let Ok(guard) = shared.lock.lock()
                    && shared.kick_at.load(Ordering::Acquire) == NO_KICK
                    && !wait.is_zero()
                {
                    let _ = shared.wake.wait_timeout(guard, wait);
                }
            }
        })?;
    Ok(())
}

/// Makes the step thread preempt the executor: a finer timer slack always, then
/// SCHED_FIFO when asked (and permitted), else the highest nice level permitted.
fn raise_priority(realtime: bool) {
    // SAFETY: prctl and setpriority on the calling thread, with plain integer arguments;
    // sched_setscheduler with a valid sched_param.
    unsafe {
        libc::prctl(libc::PR_SET_TIMERSLACK, 1 as libc::c_ulong);
        if realtime {
            let param = libc::sched_param { sched_priority: 50 };
            if libc::sched_setscheduler(0, libc::SCHED_FIFO, &param) == 0 {
                log::info!("step thread: SCHED_FIFO priority 50");
                return;
            }
            log::warn!(
                "step thread: SCHED_FIFO refused ({}); normal priority",
                std::io::Error::last_os_error()
            );
        }
    }
    raise_nice("step thread", INTERRUPT_NICE);
}

/// Nice level of the threads that play the board's interrupts (the step timers, the
/// receive path's first look at each datagram): other work on a loaded PC delays them
/// little, as interrupts preempt tasks on the board.
pub const INTERRUPT_NICE: i32 = -10;

/// Nice level of the executor's thread (the board's CPU running the tasks): above other
/// work on the PC, which the board does not share its CPU with, below the interrupts.
pub const EXECUTOR_NICE: i32 = -5;

/// Sets the calling thread's nice level to `nice`, when permitted (root, or
/// CAP_SYS_NICE); otherwise it keeps its priority and says so at debug level.
pub fn raise_nice(what: &str, nice: i32) {
    // SAFETY: setpriority on the calling thread's id, plain integer arguments.
    let raised = unsafe {
        let tid = libc::syscall(libc::SYS_gettid) as libc::id_t;
        libc::setpriority(libc::PRIO_PROCESS, tid, nice) == 0
    };
    if raised {
        log::debug!("{what}: nice {nice}");
    } else {
        log::debug!(
            "{what}: nice {nice} refused ({}); normal priority",
            std::io::Error::last_os_error()
        );
    }
}
