//! The board's step hardware, simulated: each joint's timer playing the periods that
//! arm-step's producer writes into its DMA buffer, and the DMA refilling each half as the
//! timer leaves it, in simulated time.
//!
//! [`SimSteps`] is the simulator's [`StepBackend`]: the same [`StepStreams`] (producer and
//! buffers) as the board, with the same buffer halves, prelude and timer ranges. A step
//! thread plays the buffers: every STEP edge and DIR change is stamped with the exact tick
//! the producer computed (so positions, the VCD trace and e-stop behave as on the board),
//! but the thread does not wake per edge: it wakes when a joint's timer enters a new half
//! (the refill), at the end of the run, when kicked, and every [`PLAY_INTERVAL`] to bring
//! the motors and the trace up to the present. It never spins, so it leaves the cores to
//! the executor. An emergency stop plays the edges up to the stop's tick, cuts a pulse in
//! progress and drops the rest: no STEP edge after the stop, as on the board.
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::time::{Duration, Instant};

use arm_core::hw::StepKick;
use arm_core::{StepBackend, StepProgress};
use arm_step::{
    JointBuffer, MAX_JOINTS, NUCLEO_STEP_TIMER_MAX_PERIOD_TICKS, PRELUDE, PulsePeriod, Segment,
    StepPins, StepStreams, StepTiming,
};

use crate::clock::SimClock;
use crate::probe::Probe;
use crate::steppers::SimSteppers;

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

/// Where one joint's simulated timer is.
#[derive(Clone, Copy, Debug, Default)]
struct Play {
    /// Index of the next period to start: 0 and 1 the prelude, then the buffer circularly
    /// (period `n >= 2` is buffer entry `(n - 2) % (2 * HALF)`).
    next: u64,
    /// Run tick at which period `next` starts.
    at: u64,
    /// Run tick at which the pulse in progress falls, if STEP is high.
    fall: Option<u64>,
}

/// The simulated step hardware ([`StepBackend`] of the simulator).
pub struct SimSteps<const Q: usize> {
    streams: Box<StepStreams<Q, HALF>>,
    buffers: Box<[JointBuffer<HALF>; MAX_JOINTS]>,
    prelude: [[PulsePeriod; PRELUDE]; MAX_JOINTS],
    pins: SimSteppers,
    clock: SimClock,
    /// Step clock tick of the run's start (the timers' tick 0), while a run plays.
    origin: Option<u64>,
    play: [Play; MAX_JOINTS],
    /// Segments finished while priming a run, reported with the next progress.
    primed_finished: u32,
    /// Told when an emergency stop has stopped the run (the e-stop latency's end).
    probe: Option<Arc<Probe>>,
}

impl<const Q: usize> std::fmt::Debug for SimSteps<Q> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SimSteps")
            .field("origin", &self.origin)
            .finish()
    }
}

impl<const Q: usize> SimSteps<Q> {
    /// Idle hardware driving `pins`.
    pub fn new(timing: StepTiming, pins: SimSteppers, clock: SimClock) -> SimSteps<Q> {
        SimSteps {
            streams: Box::new(StepStreams::new(timing, NUCLEO_STEP_TIMER_MAX_PERIOD_TICKS)),
            buffers: Box::new([JointBuffer::ZERO; MAX_JOINTS]),
            prelude: [[PulsePeriod::ZERO; PRELUDE]; MAX_JOINTS],
            pins,
            clock,
            origin: None,
            play: [Play::default(); MAX_JOINTS],
            primed_finished: 0,
            probe: None,
        }
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

    /// Period `n` of joint `j`'s stream.
    fn period(&self, j: usize, n: u64) -> PulsePeriod {
        if n < PRELUDE as u64 {
            return self.prelude[j][n as usize];
        }
        let e = ((n - PRELUDE as u64) % (2 * HALF) as u64) as usize;
        self.buffers[j].periods[e / HALF][e % HALF]
    }

    /// Plays every joint up to step clock tick `now`: edges, DIR changes, refills of the
    /// halves the timers left; ends the run at its end.
    pub fn advance(&mut self, now: u64) -> StepProgress {
        let Some(origin) = self.origin else {
            return StepProgress::default();
        };
        let t = now.saturating_sub(origin);
        let mut progress = StepProgress {
            segments_finished: std::mem::take(&mut self.primed_finished),
            ran_dry: false,
        };
        let end = self.streams.producer_ref().run_end_tick();
        let until = end.map_or(t, |end| t.min(end));
        for j in 0..MAX_JOINTS {
            progress.segments_finished += self.play_joint(j, origin, until);
        }
        if let Some(end) = self.streams.producer_ref().run_end_tick()
            && t >= end
        {
            self.streams.producer().end_run();
            self.origin = None;
            progress.ran_dry = true;
        }
        progress
    }

    /// Plays joint `j` up to run tick `t`; returns segments finished by its refills.
    fn play_joint(&mut self, j: usize, origin: u64, t: u64) -> u32 {
        let mut finished = 0;
        let bit = 1u8 << j;
        loop {
            let play = self.play[j];
            let dir = self.streams.next_dir_change(j);
            // The earliest of: the pulse's fall, a DIR change, the next period's start.
            let fall = play.fall.unwrap_or(u64::MAX);
            let dir_at = dir.map_or(u64::MAX, |d| d.tick);
            let next = fall.min(dir_at).min(play.at);
            if next > t {
                break;
            }
            if fall == next {
                self.pins.set_tick(origin + fall);
                self.pins.step_low(bit);
                self.play[j].fall = None;
            } else if let Some(change) = dir.filter(|_| dir_at == next) {
                self.pins.set_tick(origin + change.tick);
                self.pins.set_direction(j, change.positive);
                self.streams.pop_dir_change(j);
            } else {
                let period = self.period(j, play.next);
                if period.high != 0 {
                    self.pins.set_tick(origin + play.at);
                    self.pins.step_high(bit);
                    self.play[j].fall = Some(play.at + u64::from(period.high));
                }
                self.play[j].at = play.at + period.ticks();
                self.play[j].next = play.next + 1;
                // Entering a new half: the one before is free (the DMA has read it all).
                let n = play.next;
                if n >= (PRELUDE + HALF) as u64 && (n - PRELUDE as u64).is_multiple_of(HALF as u64)
                {
                    let entered = ((n - PRELUDE as u64) / HALF as u64 % 2) as usize;
                    let freed = 1 - entered;
                    let refill = self
                        .streams
                        .refill(j, freed, &mut self.buffers[j].periods[freed]);
                    finished += refill.segments_finished;
                }
            }
        }
        finished
    }

    /// Step clock tick at which the thread must run next: the first refill, or the end.
    pub fn next_due(&self) -> Option<u64> {
        let origin = self.origin?;
        let mut due = self
            .streams
            .producer_ref()
            .run_end_tick()
            .unwrap_or(u64::MAX);
        for (j, play) in self.play.iter().enumerate() {
            // Start of the first period of the next half.
            let past = play.next.saturating_sub(PRELUDE as u64) % HALF as u64;
            let to_boundary = if play.next < PRELUDE as u64 {
                PRELUDE as u64 - play.next + HALF as u64
            } else {
                HALF as u64 - past
            };
            let mut at = play.at;
            for k in 0..to_boundary {
                at += self.period(j, play.next + k).ticks();
            }
            due = due.min(at);
        }
        Some(origin + due)
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
        let [b0, b1, b2, b3, b4, b5, b6, b7] = &mut *self.buffers;
        let primed = self.streams.prime(
            at_tick.saturating_sub(now),
            &mut self.prelude,
            &mut [b0, b1, b2, b3, b4, b5, b6, b7],
        );
        if primed.dir_overflow {
            self.streams.producer().stop();
            return;
        }
        self.play = [Play::default(); MAX_JOINTS];
        self.primed_finished = primed.segments_finished;
        self.origin = Some(now);
    }

    fn stop(&mut self) {
        let Some(origin) = self.origin else {
            self.streams.producer().stop();
            return;
        };
        // Everything up to the stop happened; nothing after it does.
        let now = self.clock.now_tick();
        self.advance(now);
        for j in 0..MAX_JOINTS {
            if self.play[j].fall.take().is_some() {
                self.pins.set_tick(now.max(origin));
                self.pins.step_low(1 << j);
            }
            // Periods from `next` on never started.
            let (first_unplayed, stale) = unplayed_from(self.play[j].next);
            self.streams
                .unwind(j, &self.buffers[j], first_unplayed, stale);
        }
        self.streams.producer().stop();
        self.streams.clear_dir_changes();
        self.origin = None;
        if let Some(probe) = &self.probe {
            probe.engine_running.store(false, Ordering::Release);
            probe.engine_stopped(Instant::now(), self.clock.tick_to_ns(now));
        }
    }

    /// The pulses played so far (the producer's count less what is still in the
    /// buffers), as on the board.
    fn positions(&self) -> [i32; MAX_JOINTS] {
        let mut positions = self.streams.producer_ref().positions();
        if self.origin.is_some() {
            for (j, position) in positions.iter_mut().enumerate() {
                let (first_unplayed, stale) = unplayed_from(self.play[j].next);
                *position -=
                    self.streams
                        .unplayed_steps(j, &self.buffers[j], first_unplayed, stale);
            }
        }
        positions
    }

    fn set_positions(&mut self, positions: [i32; MAX_JOINTS]) -> bool {
        self.origin.is_none() && self.streams.producer().set_positions(positions)
    }
}

/// For a stream whose next period to start is `next`: the buffer index of that period
/// (`None` while in the prelude) and whether the half before it is stale (played, and
/// its refill, due when `next` starts, not done: `next` is the first of a half).
fn unplayed_from(next: u64) -> (Option<usize>, bool) {
    let first =
        (next >= PRELUDE as u64).then(|| ((next - PRELUDE as u64) % (2 * HALF) as u64) as usize);
    let stale =
        next >= (PRELUDE + HALF) as u64 && (next - PRELUDE as u64).is_multiple_of(HALF as u64);
    (first, stale)
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
        let tid = libc::syscall(libc::SYS_gettid) as libc::id_t;
        if libc::setpriority(libc::PRIO_PROCESS, tid, -10) == 0 {
            log::debug!("step thread: nice -10");
        }
    }
}
