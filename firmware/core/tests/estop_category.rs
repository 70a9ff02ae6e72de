//! Issue 32: the wired e-stop input's stop category (ESTOP_CATEGORY 0x2b, kept in the
//! settings, shown in MOTION's byte 7). Category 0 (the default) is today's instant stop;
//! category 1 ramps a run to a standstill along its path within the accelerations, then
//! stops it latched with the drivers disabled. The edge handler records the opening at
//! once and blocks new runs; the ramp is bounded (`estop_ramp_bound_us`), and past the
//! bound, on a step side without a warp, or at a second opening the stop is instant.
//! Sans-io on virtual time: the controller over a fake plant, the edge handler over the
//! shared engine, and both together over the engine (the oracle's warp) with its edges.
//! (One file past 600 lines for the three layers of one rule: the last test reuses the
//! first's trajectory and the second's step timer.)

mod common;

use std::cell::{Cell, RefCell};

use arm_core::bus::Cs;
use arm_core::controller::{ESTOP_RAMP_LOOKAHEAD_US, ESTOP_RAMP_SLACK_US, estop_ramp_bound_us};
use arm_core::hw::{SerialError, StepKick};
use arm_core::plant::Plant;
use arm_core::{EStopLine, StepShared};
use arm_step::{JointMask, Segment, StepPins, StepTiming};
use common::*;
use embassy_sync::signal::Signal;
use protocol::{
    Command, ControlledStop, EStopCategory, MAX_JOINTS, MoreFlags, MotionFlags, Point, Pwm, State,
    StatusCode, StatusFlags, StopCause, Tag, UartInit,
};

const ONE: u64 = arm_step::RATE_ONE;

/// Joint 0 from rest up to 4,000 steps/s at 10,000 steps/s^2 (one step more every 10 ms
/// point), then `cruise` points at 40 steps per 10 ms, then down to rest alike.
fn ramp_and_cruise(cruise: usize) -> Vec<Point> {
    let mut at = [0i32; MAX_JOINTS];
    let steps = (1..=40)
        .chain(std::iter::repeat_n(40, cruise))
        .chain((1..40).rev());
    steps
        .map(|s| {
            let before = at;
            at[0] += s;
            Point::from_motion(10_000, &before, &at)
        })
        .collect()
}

fn set_category(s: &mut Session<64>, category: EStopCategory) {
    s.expect(Command::EstopCategory(category), StatusCode::Ok);
}

/// A run of joint 0 at 4,000 steps/s with ACCEL_SET 20,000 on joint 0, category 1.
fn running_category_1() -> Session<64> {
    let mut s = Session::<64>::new(64);
    s.expect(
        Command::AccelSet {
            joint: 0,
            max_accel_steps_s2: 20_000,
        },
        StatusCode::Ok,
    );
    set_category(&mut s, EStopCategory::Controlled);
    // 60 of the 99 points sent (the buffer holds 64): the run is far from its end.
    let pts = ramp_and_cruise(20);
    s.expect(Command::New { count: 99 }, StatusCode::Ok);
    for chunk in pts[..60].chunks(protocol::MAX_POINTS_PER_FRAME) {
        assert_eq!(s.pending(chunk).status, StatusCode::Ok);
    }
    s.expect(Command::Runing, StatusCode::Ok);
    s.plant.run(&mut s.controller, 45);
    assert_eq!(s.controller.state(), State::Running);
    s
}

#[test]
fn the_category_is_kept_shown_in_motion_and_set_only_while_stopped() {
    let mut s = Session::<64>::new(64);
    let m = s.controller.motion_report(&s.plant);
    assert_eq!(m.estop_category, Some(EStopCategory::Instant), "default 0");
    set_category(&mut s, EStopCategory::Controlled);
    assert_eq!(
        s.controller.settings().estop_category,
        EStopCategory::Controlled,
        "kept in the settings (saved before the ACK)"
    );
    let m = s.controller.motion_report(&s.plant);
    assert_eq!(m.estop_category, Some(EStopCategory::Controlled));
    // A byte other than 0 and 1: refused, nothing changes.
    s.seq = s.seq.wrapping_add(1);
    let r = s.send_raw(HOST, &raw(s.seq, Tag::EstopCategory as u8, &[2]));
    assert_eq!(
        r.reply.map(|r| r.ack.status),
        Some(StatusCode::InvalidConfig)
    );
    s.seq = s.seq.wrapping_add(1);
    let r = s.send_raw(HOST, &raw(s.seq, Tag::EstopCategory as u8, &[]));
    assert_eq!(r.reply.map(|r| r.ack.status), Some(StatusCode::BadLength));
    // While a run plays: BAD_STATE (the flash rule).
    s.start_endless_run();
    s.expect(
        Command::EstopCategory(EStopCategory::Instant),
        StatusCode::BadState,
    );
    assert_eq!(s.controller.estop_category(), EStopCategory::Controlled);
    // Another host may not set it.
    s.expect(Command::Stopped, StatusCode::Ok);
    let r = s.send_raw(
        OTHER,
        &frame(90, Command::EstopCategory(EStopCategory::Instant)),
    );
    assert_eq!(r.reply.map(|r| r.ack.status), Some(StatusCode::NotOwner));
    set_category(&mut s, EStopCategory::Instant);
    assert_eq!(s.controller.estop_category(), EStopCategory::Instant);
}

#[test]
fn category_1_ramps_the_run_then_stops_latched_with_the_drivers_disabled() {
    let mut s = running_category_1();
    let stops = s.plant.stops;
    let now = s.now_us;
    assert_eq!(s.controller.estop_controlled(now, &mut s.plant), None);
    // The hold's ramp: to 0 with joint 0's slope (20,000 steps/s^2 at 4,000 steps/s).
    assert_eq!(s.plant.rate_changes.last(), Some(&(0, 20_000, 4_000)));
    assert_eq!(s.plant.stops, stops, "nothing halted: a ramp");
    assert_eq!(s.controller.state(), State::Running);
    assert!(s.controller.estop_latched(), "latched at once");
    let bound = estop_ramp_bound_us(ONE, 20_000, 4_000);
    assert_eq!(
        bound,
        200_000 + ESTOP_RAMP_LOOKAHEAD_US + ESTOP_RAMP_SLACK_US,
        "v/a + lookahead + slack"
    );
    assert_eq!(
        ESTOP_RAMP_LOOKAHEAD_US, 100_000,
        "the simulator's, the longest"
    );
    assert_eq!(s.controller.estop_ramp_deadline(), Some(now + bound));
    let m = s.controller.motion_report(&s.plant);
    assert!(
        m.flags.has(MotionFlags::HELD | MotionFlags::ESTOP_RAMP),
        "{m:?}"
    );
    assert_eq!(m.last_stop, Some(ControlledStop::EStop));
    // No host lifts it: RESUME refused, OVERRIDE changes no rate, HOLD is a no-op.
    let changes = s.plant.rate_changes.len();
    s.expect(Command::Resume, StatusCode::EstopLatched);
    s.expect(Command::Override { percent: 50 }, StatusCode::Ok);
    s.expect(Command::Hold, StatusCode::Ok);
    assert_eq!(s.plant.rate_changes.len(), changes);
    // At the standstill (the fake plant ramps at once): stopped, drivers off, latched.
    let location = s
        .controller
        .estop_ramp_poll(now + 1_000, &mut s.plant)
        .expect("a LOCATION of the state change");
    assert_eq!(location.state, State::Stopped as u8);
    assert_eq!(s.plant.stops, stops + 1, "then stopped as category 0");
    assert_eq!(s.plant.enabled.last(), Some(&0), "drivers disabled");
    let status = s.controller.status(&s.plant);
    assert!(!status.flags.has(StatusFlags::DRIVERS_ENABLED));
    assert!(status.more_flags.has(MoreFlags::ESTOP_LATCHED));
    assert_eq!(s.controller.estop_ramp_deadline(), None);
    assert_eq!(
        s.controller.stop_report().cause,
        Some(StopCause::EstopInput)
    );
    let m = s.controller.motion_report(&s.plant);
    assert!(!m.flags.has(MotionFlags::ESTOP_RAMP), "{m:?}");
    s.expect(Command::Runing, StatusCode::EstopLatched);
    // ESTOP_RESET once closed; the drivers stay off until a host enables them.
    s.controller.estop_input(false, &mut s.plant);
    s.expect(Command::EstopReset, StatusCode::Ok);
    assert!(!s.controller.estop_latched());
    assert_eq!(s.controller.enabled(), 0);
}

#[test]
fn past_its_bound_the_ramp_is_halted_at_once() {
    let mut s = running_category_1();
    s.plant.ramp_never_ends = true;
    let now = s.now_us;
    s.controller.estop_controlled(now, &mut s.plant);
    let deadline = s.controller.estop_ramp_deadline().expect("a ramp");
    let stops = s.plant.stops;
    assert_eq!(
        s.controller.estop_ramp_poll(deadline - 1, &mut s.plant),
        None
    );
    assert_eq!(s.plant.stops, stops, "still ramping before the bound");
    assert!(
        s.controller
            .estop_ramp_poll(deadline, &mut s.plant)
            .is_some()
    );
    assert_eq!(s.plant.stops, stops + 1, "halted at the bound");
    assert_eq!(s.controller.state(), State::Stopped);
    assert_eq!(s.plant.enabled.last(), Some(&0));
}

#[test]
fn a_step_side_without_a_warp_stops_at_once() {
    let mut s = running_category_1();
    s.plant.warpless = true;
    let stops = s.plant.stops;
    let changes = s.plant.rate_changes.len();
    let now = s.now_us;
    assert!(s.controller.estop_controlled(now, &mut s.plant).is_some());
    assert_eq!(s.plant.rate_changes.len(), changes, "no ramp");
    assert_eq!(s.plant.stops, stops + 1, "stopped at once");
    assert_eq!(s.controller.state(), State::Stopped);
    assert_eq!(s.controller.estop_ramp_deadline(), None);
    assert_eq!(s.plant.enabled.last(), Some(&0), "category 1: drivers off");
    assert!(s.controller.estop_latched());
}

#[test]
fn a_second_opening_or_a_stopped_during_the_ramp_stops_at_once() {
    // A second opening (its handler halted: the sample is not a controlled one).
    let mut s = running_category_1();
    s.plant.ramp_never_ends = true;
    let now = s.now_us;
    s.controller.estop_controlled(now, &mut s.plant);
    let stops = s.plant.stops;
    assert!(s.controller.estop_input(true, &mut s.plant).is_some());
    assert_eq!(s.plant.stops, stops + 1);
    assert_eq!(s.controller.state(), State::Stopped);
    assert_eq!(s.controller.estop_ramp_deadline(), None);
    assert_eq!(s.plant.enabled.last(), Some(&0));
    // A second controlled opening (the line's ramp flag already cleared): at once too.
    let mut s = running_category_1();
    s.plant.ramp_never_ends = true;
    let now = s.now_us;
    s.controller.estop_controlled(now, &mut s.plant);
    let stops = s.plant.stops;
    s.controller.estop_controlled(now + 5, &mut s.plant);
    assert_eq!(s.plant.stops, stops + 1);
    assert_eq!(s.controller.state(), State::Stopped);
    // STOPPED from a host: category 0, at once; the drivers go off at the next look.
    let mut s = running_category_1();
    s.plant.ramp_never_ends = true;
    let now = s.now_us;
    s.controller.estop_controlled(now, &mut s.plant);
    let stops = s.plant.stops;
    s.expect(Command::Stopped, StatusCode::Ok);
    assert_eq!(s.plant.stops, stops + 1, "the STOPPED stopped at once");
    assert_eq!(s.controller.state(), State::Stopped);
    s.controller.estop_ramp_poll(now + 1, &mut s.plant);
    assert_eq!(s.plant.enabled.last(), Some(&0));
    assert!(s.controller.estop_latched());
}

#[test]
fn category_0_and_a_stopped_from_the_network_are_unchanged() {
    let mut s = Session::<64>::new(64);
    s.start_endless_run();
    let enabled = s.plant.enabled.clone();
    let stops = s.plant.stops;
    s.controller.estop_input(true, &mut s.plant);
    assert_eq!(s.plant.stops, stops + 1);
    assert_eq!(
        s.plant.enabled, enabled,
        "category 0 leaves the drivers alone"
    );
    assert!(s.plant.rate_changes.is_empty());
    // Category 1 set: a STOPPED is still an instant stop, the drivers untouched.
    let mut s = running_category_1();
    let enabled = s.plant.enabled.clone();
    let changes = s.plant.rate_changes.len();
    s.expect(Command::Stopped, StatusCode::Ok);
    assert_eq!(s.controller.state(), State::Stopped);
    assert_eq!(s.plant.rate_changes.len(), changes);
    assert_eq!(s.plant.enabled, enabled);
}

// --- The edge handler's half over the shared engine. ---

const TIMING: StepTiming = StepTiming {
    tick_hz: 1_000_000,
    pulse_width_ticks: 2,
    dir_setup_ticks: 1,
    step_low_ticks: 1,
};

/// A step timer at a virtual tick, kicks counted.
#[derive(Default)]
struct Kick {
    tick: Cell<u64>,
    kicks: Cell<u32>,
}

impl StepKick for Kick {
    fn kick(&self) {
        self.kicks.set(self.kicks.get() + 1);
    }
    fn now_tick(&self) -> u64 {
        self.tick.get()
    }
}

type Wake = Signal<Cs, ()>;

fn running_engine() -> StepShared<8> {
    let step = StepShared::<8>::new(TIMING);
    step.with_engine(|e| {
        e.push(Segment {
            duration_us: 1_000_000,
            steps: [1_000, 0, 0, 0, 0, 0, 0, 0],
        })
        .unwrap();
        e.start(10);
    });
    step
}

#[test]
fn category_1_leaves_a_warped_run_to_the_ramp_and_blocks_new_runs() {
    let step = running_engine();
    let kick = Kick::default();
    let (line, wake) = (EStopLine::new(), Wake::new());
    line.set_category(EStopCategory::Controlled);
    line.edge(true, &step, &kick, &wake);
    assert!(step.with_engine(|e| e.is_running()), "not halted");
    assert!(wake.signaled());
    let sample = line.take();
    assert!(
        sample.open && sample.opened && sample.controlled,
        "{sample:?}"
    );
    // The run ends (the task's stop at the standstill): no new run starts.
    step.stop();
    step.with_engine(|e| {
        e.push(Segment {
            duration_us: 1_000,
            steps: [10, 0, 0, 0, 0, 0, 0, 0],
        })
        .unwrap()
    });
    step.start(100);
    assert!(!step.with_engine(|e| e.is_running()), "blocked");
    line.edge(false, &step, &kick, &wake);
    step.start(100);
    assert!(step.with_engine(|e| e.is_running()), "released on closing");
}

#[test]
fn a_second_opening_during_the_ramp_halts_at_once() {
    let step = running_engine();
    let kick = Kick::default();
    let (line, wake) = (EStopLine::new(), Wake::new());
    line.set_category(EStopCategory::Controlled);
    line.edge(true, &step, &kick, &wake);
    assert!(line.take().controlled);
    // The ramp is on (the task has not called `ramp_over`): closed and opened again, the
    // handler halts at once.
    line.edge(false, &step, &kick, &wake);
    line.edge(true, &step, &kick, &wake);
    assert!(!step.with_engine(|e| e.is_running()), "halted at once");
    let sample = line.take();
    assert!(sample.opened && !sample.controlled, "{sample:?}");
    // The halt ended the ramp: the next opening of a new run is left to one again.
    line.edge(false, &step, &kick, &wake);
    let again = running_engine();
    line.edge(true, &again, &kick, &wake);
    assert!(again.with_engine(|e| e.is_running()), "a ramp again");
    assert!(line.take().controlled);
}

#[test]
fn without_a_run_or_in_category_0_the_handler_halts() {
    let kick = Kick::default();
    let (line, wake) = (EStopLine::new(), Wake::new());
    // Category 0 (the default): a running engine is halted.
    let step = running_engine();
    line.edge(true, &step, &kick, &wake);
    assert!(!step.with_engine(|e| e.is_running()));
    assert!(!line.take().controlled);
    line.edge(false, &step, &kick, &wake);
    // Category 1 with no run: nothing to ramp, halted.
    line.set_category(EStopCategory::Controlled);
    let idle = StepShared::<8>::new(TIMING);
    line.edge(true, &idle, &kick, &wake);
    let sample = line.take();
    assert!(sample.opened && !sample.controlled);
    idle.with_engine(|e| {
        e.push(Segment {
            duration_us: 1_000,
            steps: [10, 0, 0, 0, 0, 0, 0, 0],
        })
        .unwrap()
    });
    idle.start(100);
    assert!(!idle.with_engine(|e| e.is_running()), "halted: no start");
}

// --- Both together over the engine, on virtual time. ---

/// The trajectory task's plant over the shared engine at the kick's virtual tick.
struct EnginePlant<'a> {
    step: &'a StepShared<64>,
    kick: &'a Kick,
    enabled: Vec<u16>,
}

/// The engine's clock here: the NUCLEO's 200 MHz, so that a step interval's rounding
/// (5 ns) does not look like an acceleration.
const FINE: StepTiming = StepTiming {
    tick_hz: 200_000_000,
    pulse_width_ticks: 400,
    dir_setup_ticks: 200,
    step_low_ticks: 200,
};
/// Ticks per microsecond of [`FINE`].
const PER_US: u64 = 200;
/// A run's start lead, ticks.
const LEAD: u64 = 1_000 * PER_US;

impl Plant for EnginePlant<'_> {
    fn positions(&self) -> [i32; MAX_JOINTS] {
        self.step.positions()
    }
    fn set_positions(&mut self, positions: [i32; MAX_JOINTS]) -> bool {
        self.step.set_positions(positions)
    }
    fn stop(&mut self) {
        self.step.stop();
    }
    fn push_segment(&mut self, segment: Segment) -> bool {
        self.step.push(segment, self.kick.now_tick() + LEAD)
    }
    fn start(&mut self) {
        self.step.start(self.kick.now_tick() + LEAD);
    }
    fn set_user_pin(&mut self, _pin: u8, _high: bool) {}
    fn set_enabled(&mut self, enabled: u16) {
        self.enabled.push(enabled);
    }
    fn gripper_start(&mut self, _pwm: &Pwm) {}
    fn gripper_stop(&mut self) {}
    fn gripper_active(&self) -> bool {
        false
    }
    fn serial_open(&mut self, _init: &UartInit) -> Result<(), SerialError> {
        Ok(())
    }
    fn serial_close(&mut self) {}
    fn serial_send(&mut self, _bytes: &[u8]) -> bool {
        true
    }
    fn change_rate(&mut self, rate: u64, accel: u32, speed: u32) -> bool {
        self.step
            .change_rate(self.kick.now_tick(), rate, accel, speed)
    }
    fn set_start_rate(&mut self, rate: u64) {
        self.step.set_start_rate(rate);
    }
    fn rate_now(&self) -> Option<(u64, bool)> {
        self.step.rate_now(self.kick.now_tick())
    }
}

/// Joint 0's rising edges, at the tick they were made.
struct Edges<'a> {
    tick: &'a Kick,
    rises: RefCell<Vec<u64>>,
}

impl StepPins for &Edges<'_> {
    fn set_direction(&mut self, _joint: usize, _positive: bool) {}
    fn step_high(&mut self, joints: JointMask) {
        if joints & 1 != 0 {
            self.rises.borrow_mut().push(self.tick.now_tick());
        }
    }
    fn step_low(&mut self, _joints: JointMask) {}
}

#[test]
fn over_the_engine_the_ramp_keeps_the_acceleration_and_ends_latched_with_drivers_off() {
    const CAP: usize = 512;
    let step = StepShared::<64>::new(FINE);
    let kick = Kick::default();
    let (line, wake) = (EStopLine::new(), Wake::new());
    let edges = Edges {
        tick: &kick,
        rises: RefCell::new(Vec::new()),
    };
    let mut controller = controller::<CAP>(CAP);
    let mut plant = EnginePlant {
        step: &step,
        kick: &kick,
        enabled: Vec::new(),
    };
    let mut seq = 0u8;
    let mut send =
        |controller: &mut arm_core::Controller<CAP>, plant: &mut EnginePlant, cmd: Command<'_>| {
            seq = seq.wrapping_add(1);
            let now = kick.now_tick() / PER_US;
            let r = controller.handle(HOST, &frame(seq, cmd), now, plant);
            let status = match r.reply {
                Some(reply) => reply.ack.status,
                None => controller
                    .settings_saved(true, now)
                    .map(|r| r.ack.status)
                    .expect("the save's ACK"),
            };
            assert_eq!(status, StatusCode::Ok, "{cmd:?}");
        };
    send(
        &mut controller,
        &mut plant,
        Command::AccelSet {
            joint: 0,
            max_accel_steps_s2: 20_000,
        },
    );
    send(
        &mut controller,
        &mut plant,
        Command::EstopCategory(EStopCategory::Controlled),
    );
    let pts = ramp_and_cruise(300);
    send(
        &mut controller,
        &mut plant,
        Command::New {
            count: pts.len() as u16,
        },
    );
    for chunk in pts.chunks(protocol::MAX_POINTS_PER_FRAME) {
        send(
            &mut controller,
            &mut plant,
            Command::Pending(protocol::PointList::Points(chunk)),
        );
    }
    send(&mut controller, &mut plant, Command::Runing);
    // The mini trajectory task: the engine's interrupt at its deadlines (and every
    // ramp look), progress to the controller, the line applied when it opens.
    const OPEN_AT: u64 = 2_000_000 * PER_US;
    let mut opened = false;
    let mut stopped_at = None;
    let mut next = Some(0u64);
    for _ in 0..2_000_000 {
        let mut at = next.unwrap_or(kick.now_tick() + 1_000 * PER_US);
        if let Some(d) = controller.estop_ramp_deadline() {
            at = at
                .min(kick.now_tick() + arm_core::controller::ESTOP_RAMP_POLL_US * PER_US)
                .min(d * PER_US);
        }
        if !opened && at >= OPEN_AT {
            at = OPEN_AT;
        }
        let at = at.max(kick.now_tick());
        kick.tick.set(at);
        if !opened && at == OPEN_AT {
            opened = true;
            line.set_category(controller.estop_category());
            line.edge(true, &step, &kick, &wake);
            let sample = line.take();
            assert!(sample.controlled, "a warped run: left to the ramp");
            assert_eq!(controller.estop_controlled(at / PER_US, &mut plant), None);
        }
        next = step.on_timer(at, &mut &edges, &wake);
        let (finished, dry) = step.take_progress();
        controller.on_step_progress(finished, dry, &mut plant);
        if controller
            .estop_ramp_poll(at / PER_US, &mut plant)
            .is_some()
        {
            stopped_at = Some(at);
        }
        if stopped_at.is_some_and(|s| at > s + 1_000_000 * PER_US) {
            break;
        }
    }
    let stopped_at = stopped_at.expect("the ramp ended");
    let rises = edges.rises.borrow();
    let after: Vec<u64> = rises.iter().copied().filter(|&t| t >= OPEN_AT).collect();
    let last = *after.last().expect("steps after the opening");
    // Standstill within v/a (0.2 s) + the lookahead + 20 ms; the drivers off after it.
    assert!(
        last - OPEN_AT <= (200_000 + ESTOP_RAMP_LOOKAHEAD_US + 20_000) * PER_US,
        "last edge {} ticks after the opening",
        last - OPEN_AT
    );
    assert!(stopped_at >= last, "stopped after the last edge");
    assert!(
        stopped_at - last <= (2 * arm_core::controller::ESTOP_RAMP_POLL_US + 1_000) * PER_US,
        "stopped {} ticks after the standstill",
        stopped_at - last
    );
    // About v^2/2a = 400 steps in the ramp.
    let steps = after.len();
    assert!(
        (380..=440).contains(&steps),
        "{steps} steps after the opening"
    );
    // No two consecutive intervals imply more than 1.1 x the acceleration.
    let window: Vec<u64> = rises
        .iter()
        .copied()
        .filter(|&t| t + 100_000 * PER_US >= OPEN_AT)
        .collect();
    let mut worst = 0.0f64;
    for w in window.windows(3) {
        let tick_s = 1.0 / f64::from(FINE.tick_hz);
        let (i1, i2) = ((w[1] - w[0]) as f64 * tick_s, (w[2] - w[1]) as f64 * tick_s);
        let a = (1.0 / i2 - 1.0 / i1).abs() / ((i1 + i2) / 2.0);
        worst = worst.max(a);
    }
    println!(
        "category 1 over the engine: {steps} steps after the opening, last edge {:.1} ms, \
         stopped {:.1} ms after it, max implied acceleration {:.0} steps/s^2 ({:.3} x)",
        (last - OPEN_AT) as f64 / (1e3 * PER_US as f64),
        (stopped_at - last) as f64 / (1e3 * PER_US as f64),
        worst,
        worst / 20_000.0
    );
    assert!(worst <= 1.1 * 20_000.0, "implied acceleration {worst}");
    assert!(
        rises.iter().all(|&t| t <= last),
        "no edge after the standstill"
    );
    assert_eq!(controller.state(), State::Stopped);
    assert!(controller.estop_latched());
    assert_eq!(plant.enabled.last(), Some(&0), "drivers disabled");
    assert_eq!(controller.enabled(), 0);
}
