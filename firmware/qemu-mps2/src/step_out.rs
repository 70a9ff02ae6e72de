//! The step output of the emulated board: arm-step's producer, as on the NUCLEO, played by
//! a software model of the NUCLEO's joint timers and DMA streams.
//!
//! [`QemuSteps`] is this board's [`StepBackend`]: the same
//! [`StepStreams`](arm_step::StepStreams) (producer and per-joint double buffers of
//! [`arm_step::PulsePeriod`]s, ARR/RCR/CCR1 values) as the NUCLEO's `BoardSteps`, with its
//! buffer half ([`HALF`]), its prelude and its joint timers' ranges ([`MAX_PERIOD_TICKS`],
//! the NUCLEO's in time). The producer fills the buffers and refills each half when the
//! "stream" leaves it, exactly as the NUCLEO's refill interrupts do.
//!
//! What differs from the NUCLEO: mps2-an500 has no timer whose period and compare values a
//! DMA can reload, so arm-step's [`StreamPlayer`] plays the buffers in software. The CMSDK
//! dual timer's first counter (one-shot, on the time driver's 64-bit SYSCLK count: step
//! ticks are 40 ns) interrupts where the NUCLEO's streams would raise their half-transfer /
//! transfer-complete interrupts (a joint's timer entering a new half), at DIR changes, at
//! the run's end, when kicked, and at least every [`PLAY_INTERVAL_CYCLES`] while a run
//! plays (so that positions and lines lag the present by at most that). At each interrupt
//! the player walks the periods that started since the last one and applies their edges
//! to the fake STEP/DIR lines in tick order, then the refill writes the half just left.
//! No interrupt per edge: the edges' ticks are the producer's, only the moment the lines
//! show them is late by up to one play interval.
//!
//! The STEP/DIR lines are a memory fake, [`StepLines`]: each rising edge moves that joint's
//! pulse counter in its DIR direction (and counts in its edge counter), so the pulses
//! "output" can be compared with the positions the controller reports and the steps the
//! trajectory asked for (tests/tests/qemu.rs reads them from the log). An emergency stop
//! ([`StepBackend::stop`]) plays the edges up to the stop's SYSCLK tick, drops the rest
//! (the positions keep only the pulses played, as the NUCLEO's unwind from its streams'
//! positions) and lowers every STEP line before it returns. The player gives a pulse high
//! at the stop its own fall tick, but these lines are written when played, not at their
//! ticks, so here it falls at once: the counters count rises, and the board has no driver
//! to miss a short pulse (the NUCLEO keeps its width: docs/BOARD.md).

use core::sync::atomic::{AtomicI32, AtomicU8, AtomicU32, Ordering};

use arm_core::hw::StepKick;
use arm_core::profile::BoardProfile;
use arm_core::{StepBackend, StepProgress, StepShared};
use arm_step::{MAX_JOINTS, Segment, StepTiming, StreamPlayer, StreamsSlot, TimedStepPins};
use cortex_m::peripheral::NVIC;

use crate::mps2::{self, DUALTIMER, Irq, SYSCLK_HZ, write};
use crate::time_driver::now_cycles;

// Segments the producer holds on the interrupt's side (declared once, in arm-core).

/// SYSCLK cycles per microsecond.
const CYCLES_PER_US: u32 = SYSCLK_HZ / 1_000_000;

/// This board's profile (arm-core's `profile`: every per-board figure, with its reason).
pub const PROFILE: BoardProfile = arm_core::profile::QEMU_MPS2_AN500;

// The profile's step timer clock is SYSCLK, which the player and the time driver count.
const _: () = assert!(PROFILE.step_timer_hz == SYSCLK_HZ);

/// The step timing: the NUCLEO's default drivers (opto-isolated: 2.5 us STEP high, 2.5 us
/// low, 5 us DIR setup) on SYSCLK ticks. (The NUCLEO adds 5 us for its DIR interrupt's
/// latency; here the player makes each DIR change at its tick, in order with the edges.)
pub const STEP_TIMING: StepTiming = PROFILE.step_timing();

/// Periods per buffer half: the NUCLEO's (the profile's).
pub const HALF: usize = PROFILE.step_buffer_half;

/// Segments the step producer holds: the profile's lookahead in time.
pub const STEP_QUEUE: usize = PROFILE.step_queue();

/// The longest period of each joint's "timer": the NUCLEO's, in time (the profile's), so
/// that gaps are split into the same periods and refills come as often as there.
pub const MAX_PERIOD_TICKS: [u32; MAX_JOINTS] = PROFILE.stream_period_ticks();

/// Longest time between two plays while a run plays, SYSCLK cycles (5 ms, as sim-host's
/// step thread): the lines and the positions the tasks read lag the present by at most
/// this. Without it they could lag by a half: a joint stepping slowly fills a half with
/// long periods (64 pulses at 100 Hz: 0.64 s), which the NUCLEO's DMA plays live.
pub const PLAY_INTERVAL_CYCLES: u64 = 5_000 * CYCLES_PER_US as u64;

/// This board's [`StepBackend`]: arm-step's producer and buffers, played by [`StreamPlayer`].
pub struct QemuSteps {
    streams: StreamsSlot<STEP_QUEUE, HALF>,
    player: StreamPlayer<HALF>,
    /// SYSCLK cycle of the run's tick 0 (the "timers'" start), while a run plays.
    origin: u64,
    /// Segments finished while priming the run, reported with the next progress.
    primed_finished: u32,
}

/// The backend shared by the tasks and the step interrupt. All zero bytes (the streams'
/// slot is empty, the player idle): `.bss`.
pub static STEP: StepShared<STEP_QUEUE, QemuSteps> = StepShared::with_backend(QemuSteps::new());

impl QemuSteps {
    /// Idle, without streams (set by [`init`]).
    const fn new() -> Self {
        QemuSteps {
            streams: StreamsSlot::EMPTY,
            player: StreamPlayer::IDLE,
            origin: 0,
            primed_finished: 0,
        }
    }

    /// Whether a run is playing.
    pub fn is_running(&self) -> bool {
        self.player.is_playing()
    }

    /// Pulses the producer placed later than their ideal tick.
    pub fn late_pulses(&self) -> u32 {
        self.streams
            .get()
            .map_or(0, |s| s.producer_ref().late_pulses())
    }

    /// The step interrupt's work at SYSCLK cycle `now`: plays every joint up to `now`
    /// (edges, DIR changes, refills), ends the run at its end. Returns the cycle to play
    /// at next (`None`: only when kicked) and the progress for the tasks.
    fn play(&mut self, now: u64) -> (Option<u64>, StepProgress) {
        let Some(streams) = self.streams.get_mut() else {
            return (None, StepProgress::default());
        };
        if !self.player.is_playing() {
            return (None, StepProgress::default());
        }
        let t = now.saturating_sub(self.origin);
        let advance = self.player.advance(streams, t, &mut LineWriter);
        let progress = StepProgress {
            segments_finished: advance.segments_finished
                + core::mem::take(&mut self.primed_finished),
            ran_dry: advance.ended,
        };
        if !self.player.is_playing() {
            // Every pulse of the run fell before its end.
            return (None, progress);
        }
        let mut due = t.saturating_add(PLAY_INTERVAL_CYCLES);
        if let Some(refill_or_end) = self.player.next_due(streams) {
            due = due.min(refill_or_end);
        }
        if let Some(dir) = self.player.next_dir_change(streams) {
            due = due.min(dir);
        }
        (Some(self.origin.saturating_add(due)), progress)
    }
}

impl StepBackend for QemuSteps {
    fn timing(&self) -> StepTiming {
        STEP_TIMING
    }

    fn push(&mut self, segment: Segment) -> Result<(), Segment> {
        self.streams.push(segment)
    }

    fn queued(&self) -> usize {
        self.streams.queued()
    }

    /// Primes every joint's prelude and buffer (the producer's work for the run's first
    /// 2 * HALF periods) with the "timers" starting now; the kick that follows plays the
    /// first DIR levels and arms the step timer.
    fn start(&mut self, at_tick: u64) {
        if self.player.is_playing() {
            return;
        }
        let Some(streams) = self.streams.get_mut() else {
            return;
        };
        let now = now_cycles();
        let primed = self.player.prime(streams, at_tick.saturating_sub(now));
        if primed.dir_overflow {
            streams.producer().stop();
            return;
        }
        self.origin = now;
        self.primed_finished = primed.segments_finished;
    }

    /// Plays every edge up to now, drops the rest and lowers every STEP line (a pulse in
    /// progress falls at once: see the module's header): no STEP edge after this returns.
    fn stop(&mut self) {
        if let Some(streams) = self.streams.get_mut() {
            let t = now_cycles().saturating_sub(self.origin);
            self.player.stop(streams, t, &mut LineWriter);
        }
        self.primed_finished = 0;
        disarm();
        lower_every_step_line();
    }

    /// The pulses played so far (the producer's count less what is still in the
    /// buffers), as on the NUCLEO; up to the last play.
    fn positions(&self) -> [i32; MAX_JOINTS] {
        self.streams
            .get()
            .map_or([0; MAX_JOINTS], |s| self.player.positions(s))
    }

    fn set_positions(&mut self, positions: [i32; MAX_JOINTS]) -> bool {
        !self.player.is_playing()
            && self
                .streams
                .get_mut()
                .is_some_and(|s| s.producer().set_positions(positions))
    }

    /// HOLD, RESUME and OVERRIDE (issue 32), as the NUCLEO's and the simulator's backends:
    /// the producer's warp on the run's clock (tick 0 = `origin`, SYSCLK cycles), a change
    /// at the first tick after what it has written, never before now.
    fn change_rate(&mut self, now_tick: u64, rate: u64, accel: u32, speed: u32) -> bool {
        if !self.player.is_playing() {
            return false;
        }
        let Some(streams) = self.streams.get_mut() else {
            return false;
        };
        let producer = streams.producer();
        let ramp = arm_step::ramp_for(accel, speed, STEP_TIMING.tick_hz);
        let at = now_tick
            .saturating_sub(self.origin)
            .max(producer.warp_horizon());
        producer.change_warp(at, rate, ramp).is_ok()
    }

    fn set_start_rate(&mut self, _at_tick: u64, rate: u64) -> bool {
        // The run's clock starts at 0 (`start`): the rate from there.
        if self.player.is_playing() {
            return false;
        }
        let Some(streams) = self.streams.get_mut() else {
            return false;
        };
        arm_step::Warp::steady(0, rate).is_ok_and(|warp| streams.producer().set_warp(warp))
    }

    fn warp_budget_hz(&self) -> u32 {
        arm_core::profile::QEMU_MPS2_AN500.warp_budget_hz
    }

    fn rate_now(&self, now_tick: u64) -> Option<(u64, bool)> {
        if !self.player.is_playing() {
            return None;
        }
        let warp = self.streams.get()?.producer_ref().warp();
        let tick = now_tick.saturating_sub(self.origin);
        Some((warp.rate(tick), warp.ramping(tick)))
    }
}

/// Dual timer registers (first counter).
mod reg {
    /// Value loaded into the counter when written.
    pub const LOAD: usize = 0x00;
    /// Control: one-shot (0), 32-bit (1), interrupt enable (5), enable (7).
    pub const CONTROL: usize = 0x08;
    /// Interrupt clear (any write).
    pub const INTCLR: usize = 0x0C;
}
const CONTROL_ONE_SHOT_32: u32 = 1 | (1 << 1) | (1 << 5) | (1 << 7);

/// Deadlines farther than this are armed at this distance and looked at again (the
/// counter is 32 bits: 171 s).
const MAX_ARMED_CYCLES: u64 = u32::MAX as u64;
/// Plays in one interrupt before it pends itself again (deadlines already past).
const MAX_PLAYS_PER_INTERRUPT: u32 = 8;

/// The STEP and DIR lines as memory: what a logic analyser on the NUCLEO would see, plus a
/// signed count of the rising STEP edges per joint.
pub struct StepLines {
    /// Bit j = STEP line of joint j high.
    pub step: AtomicU8,
    /// Bit j = DIR line of joint j high (positive).
    pub dir: AtomicU8,
    /// Rising STEP edges per joint, +1 with DIR high, -1 with DIR low.
    pub pulses: [AtomicI32; MAX_JOINTS],
    /// Rising STEP edges per joint.
    pub rising: [AtomicU32; MAX_JOINTS],
}

/// The lines the player drives.
pub static LINES: StepLines = StepLines {
    step: AtomicU8::new(0),
    dir: AtomicU8::new(0),
    pulses: [const { AtomicI32::new(0) }; MAX_JOINTS],
    rising: [const { AtomicU32::new(0) }; MAX_JOINTS],
};

/// When the receive interrupt last halted for a STOPPED and when a STEP line last rose,
/// in SYSCLK cycles (issue 30's figure: a STOPPED's frame to the last STEP edge after it;
/// `main.rs`'s monitor logs it). Written by interrupts; read in thread mode.
pub static STOP_TIMES: critical_section::Mutex<core::cell::Cell<StopTimes>> =
    critical_section::Mutex::new(core::cell::Cell::new(StopTimes {
        stop_seen: 0,
        last_rise: 0,
        stops: 0,
    }));

/// See [`STOP_TIMES`].
#[derive(Clone, Copy)]
pub struct StopTimes {
    /// The receive interrupt took the last STOPPED's frame from the chip (cycles).
    pub stop_seen: u64,
    /// The last rising STEP edge (cycles).
    pub last_rise: u64,
    /// STOPPEDs seen so far.
    pub stops: u32,
}

/// The receive interrupt found a STOPPED in a frame (now).
pub fn note_stop_seen() {
    let now = now_cycles();
    critical_section::with(|cs| {
        let cell = STOP_TIMES.borrow(cs);
        let mut t = cell.get();
        t.stop_seen = now;
        t.stops = t.stops.wrapping_add(1);
        cell.set(t);
    });
}

/// [`TimedStepPins`] onto [`LINES`] (the edges' ticks only order them).
struct LineWriter;

impl TimedStepPins for LineWriter {
    fn set_direction(&mut self, joint: usize, positive: bool, _tick: u64) {
        let bit = 1u8 << (joint & 7);
        if positive {
            LINES.dir.fetch_or(bit, Ordering::Relaxed);
        } else {
            LINES.dir.fetch_and(!bit, Ordering::Relaxed);
        }
    }

    fn step_high(&mut self, joint: usize, _tick: u64) {
        let bit = 1u8 << (joint & 7);
        if LINES.step.fetch_or(bit, Ordering::Relaxed) & bit != 0 {
            return;
        }
        let step = if LINES.dir.load(Ordering::Relaxed) & bit != 0 {
            1
        } else {
            -1
        };
        if let (Some(pulses), Some(rising)) = (LINES.pulses.get(joint), LINES.rising.get(joint)) {
            pulses.fetch_add(step, Ordering::Relaxed);
            rising.fetch_add(1, Ordering::Relaxed);
        }
        let now = now_cycles();
        critical_section::with(|cs| {
            let cell = STOP_TIMES.borrow(cs);
            let mut t = cell.get();
            t.last_rise = now;
            cell.set(t);
        });
    }

    fn step_low(&mut self, joint: usize, _tick: u64) {
        LINES
            .step
            .fetch_and(!(1u8 << (joint & 7)), Ordering::Relaxed);
    }
}

/// Every STEP line low: the step output is stopped (a stop, or the fault path).
fn lower_every_step_line() {
    LINES.step.store(0, Ordering::Relaxed);
    crate::marks::step_output_stopped();
}

/// Handle on the step timer ([`StepKick`]).
#[derive(Clone, Copy)]
pub struct StepTimer {
    _private: (),
}

impl StepKick for StepTimer {
    fn kick(&self) {
        NVIC::pend(Irq::DualTimer);
    }

    fn now_tick(&self) -> u64 {
        now_cycles()
    }
}

/// Builds the idle streams, stops the counter and enables its interrupt at the highest
/// priority.
pub fn init() -> StepTimer {
    STEP.with_engine(|steps| steps.streams.init(STEP_TIMING, MAX_PERIOD_TICKS));
    disarm();
    mps2::enable(Irq::DualTimer, mps2::priority::STEP);
    StepTimer { _private: () }
}

/// Stops the counter and clears its interrupt.
fn disarm() {
    write(DUALTIMER, reg::CONTROL, 0);
    write(DUALTIMER, reg::INTCLR, 1);
}

/// Arms the counter for `deadline` (SYSCLK cycle); true if it has already passed (play
/// again now).
fn arm(deadline: Option<u64>) -> bool {
    disarm();
    let Some(deadline) = deadline else {
        return false;
    };
    let now = now_cycles();
    if deadline <= now {
        return true;
    }
    let cycles = (deadline - now).min(MAX_ARMED_CYCLES) as u32;
    write(DUALTIMER, reg::LOAD, cycles);
    write(DUALTIMER, reg::CONTROL, CONTROL_ONE_SHOT_32);
    false
}

/// The step timer interrupt: a half boundary, a DIR change, the run's end, the play
/// interval, or a kick.
pub fn on_interrupt() {
    for _ in 0..MAX_PLAYS_PER_INTERRUPT {
        let now = now_cycles();
        let next = STEP.on_interrupt(&crate::BUS.step_progress, |steps| steps.play(now));
        if !arm(next) {
            return;
        }
    }
    NVIC::pend(Irq::DualTimer);
}
