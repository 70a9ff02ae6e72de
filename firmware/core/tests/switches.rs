//! Issue 33 on virtual time: the switch logic (`arm_core::switches`) and the homing cycle
//! (`arm_core::homing`) against a physical model of the joints. Each joint has a true
//! position (where it really is) and a count (what the controller believes; 0 at boot);
//! a step moves both. Switches are computed from the true position, as the simulator
//! will; their edges go to the `SwitchBank` stamped with the virtual clock and the count.

use arm_core::homing::{HomingAction, HomingCycle, HomingError, HomingJoint};
use arm_core::switches::{
    InputConfig, LimitRefusal, Limits, Side, Switch, SwitchBank, SwitchConfig, SwitchEvent,
};
use protocol::MAX_JOINTS;

const DEBOUNCE_US: u32 = 2_000;

/// A normally closed contact to GND with a pull-up: active (open) reads high.
const NC: InputConfig = InputConfig {
    fitted: true,
    active_high: true,
    debounce_us: DEBOUNCE_US,
};

/// A normally open contact to GND with a pull-up: active (closed) reads low.
const NO: InputConfig = InputConfig {
    fitted: true,
    active_high: false,
    debounce_us: DEBOUNCE_US,
};

#[derive(Clone, Copy, Debug, Default)]
struct Joint {
    /// Where the joint really is, steps.
    truth: i64,
    /// The controller's count.
    count: i32,
    /// Home switch: active at or beyond this position towards the side.
    home: Option<(Side, i64)>,
    /// Limit switches: active at or below `min`, at or above `max`.
    limits: Option<(i64, i64)>,
}

impl Joint {
    fn active(&self, switch: Switch) -> bool {
        match (switch, self.home, self.limits) {
            (Switch::Home, Some((Side::Max, at)), _) => self.truth >= at,
            (Switch::Home, Some((Side::Min, at)), _) => self.truth <= at,
            (Switch::Min, _, Some((min, _))) => self.truth <= min,
            (Switch::Max, _, Some((_, max))) => self.truth >= max,
            _ => false,
        }
    }
}

struct Rig {
    config: SwitchConfig,
    bank: SwitchBank,
    limits: Limits,
    joints: [Joint; MAX_JOINTS],
    now_us: u64,
    /// Every step: (instant, joint).
    steps: Vec<(u64, usize)>,
    /// Inject a bounce (inactive then active again) after each activation.
    bounce: bool,
    /// Steps a joint runs on after being told to stop (the latency of a real stop).
    overrun: u32,
}

const SWITCHES: [Switch; 3] = Switch::ALL;

impl Rig {
    fn new(joints: [Joint; MAX_JOINTS], input: InputConfig) -> Rig {
        let mut config = SwitchConfig::NONE;
        for (j, joint) in joints.iter().enumerate() {
            if joint.home.is_some() {
                config.inputs[j].home = input;
            }
            if joint.limits.is_some() {
                config.inputs[j].min = input;
                config.inputs[j].max = input;
            }
        }
        let mut rig = Rig {
            config,
            bank: SwitchBank::new(config),
            limits: Limits::new(),
            joints,
            now_us: 0,
            steps: Vec::new(),
            bounce: false,
            overrun: 0,
        };
        // The boot reading of every input.
        let mut boot = Vec::new();
        for j in 0..MAX_JOINTS {
            for s in SWITCHES {
                boot.extend(rig.feed(j, s));
            }
        }
        for e in boot {
            rig.limits.on_event(e);
        }
        rig
    }

    fn level(&self, j: usize, s: Switch, active: bool) -> bool {
        active == self.config.inputs[j].at(s).active_high
    }

    /// Feeds switch `s` of joint `j`'s current level as an edge.
    fn feed(&mut self, j: usize, s: Switch) -> Vec<SwitchEvent> {
        let active = self.joints[j].active(s);
        let level = self.level(j, s, active);
        let count = self.joints[j].count;
        let mut events: Vec<_> = self
            .bank
            .edge(j as u8, s, level, count, self.now_us)
            .into_iter()
            .collect();
        if active && self.bounce && !events.is_empty() {
            // Contact bounce within the same step: no new activation, no release.
            let off = self.level(j, s, false);
            events.extend(self.bank.edge(j as u8, s, off, count, self.now_us + 1));
            events.extend(self.bank.edge(j as u8, s, level, count, self.now_us + 2));
        }
        events
    }

    /// One step of joint `j` at the current instant; the switch events it causes, then
    /// the releases whose debounce has passed.
    fn step(&mut self, j: usize, dir: i32) -> Vec<SwitchEvent> {
        let before: Vec<bool> = SWITCHES.iter().map(|&s| self.joints[j].active(s)).collect();
        self.joints[j].truth += i64::from(dir);
        self.joints[j].count += dir;
        self.steps.push((self.now_us, j));
        let mut events = Vec::new();
        for (k, &s) in SWITCHES.iter().enumerate() {
            if self.joints[j].active(s) != before[k] {
                events.extend(self.feed(j, s));
            }
        }
        events.extend(self.poll());
        events
    }

    fn poll(&mut self) -> Vec<SwitchEvent> {
        std::iter::from_fn(|| self.bank.poll(self.now_us)).collect()
    }
}

/// Runs a homing cycle to its end on the rig. Limit trips stop everything (the e-stop
/// path) and abort the cycle.
fn home(rig: &mut Rig, settings: [HomingJoint; MAX_JOINTS], joints: u8) -> HomingAction {
    let mut home_active = 0u8;
    for j in 0..MAX_JOINTS {
        if rig.bank.is_active(j as u8, Switch::Home) {
            home_active |= 1 << j;
        }
    }
    let (mut cycle, mut action) = HomingCycle::start(settings, joints, home_active);
    loop {
        match action {
            HomingAction::Move {
                joint,
                steps,
                rate_hz,
            } => {
                rig.limits.set_mask(cycle.masked_limit());
                let period = 1_000_000 / u64::from(rate_hz);
                let j = usize::from(joint);
                let mut aborted = false;
                'travel: for _ in 0..steps.unsigned_abs() {
                    rig.now_us += period;
                    for e in rig.step(j, steps.signum()) {
                        if rig.limits.on_event(e) {
                            aborted = true;
                        }
                        match e {
                            SwitchEvent::HomeActive {
                                joint: hj,
                                position,
                                ..
                            } => {
                                if let Some(stop) = cycle.home_active(hj, position) {
                                    assert_eq!(stop, HomingAction::Stop { joint });
                                    for _ in 0..rig.overrun {
                                        rig.now_us += period;
                                        for e in rig.step(j, steps.signum()) {
                                            rig.limits.on_event(e);
                                        }
                                    }
                                    break 'travel;
                                }
                            }
                            SwitchEvent::HomeReleased { joint: hj } => cycle.home_released(hj),
                            _ => {}
                        }
                        if aborted {
                            break 'travel;
                        }
                    }
                }
                if aborted {
                    return HomingAction::Failed(cycle.abort().unwrap());
                }
                // The stopped joint idles on: releases still come in.
                rig.now_us += period;
                for e in rig.poll() {
                    rig.limits.on_event(e);
                    if let SwitchEvent::HomeReleased { joint: hj } = e {
                        cycle.home_released(hj);
                    }
                }
                action = cycle.move_ended(rig.joints[j].count);
            }
            HomingAction::SetPosition { joint, count } => {
                rig.joints[usize::from(joint)].count = count;
                action = cycle.position_set();
            }
            HomingAction::Stop { .. } => unreachable!("Stop comes from home_active"),
            HomingAction::Done | HomingAction::Failed(_) => {
                rig.limits.set_mask(None);
                return action;
            }
        }
    }
}

fn settings(towards: Side, offset: i32, order: u8) -> HomingJoint {
    HomingJoint {
        enabled: true,
        order,
        towards,
        seek_rate_hz: 2_000,
        approach_rate_hz: 200,
        backoff_steps: 50,
        max_travel_steps: 20_000,
        offset,
        switch_is_limit: false,
    }
}

/// A small deterministic generator (the test must repeat).
struct Lcg(u64);
impl Lcg {
    fn next(&mut self) -> u64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        self.0 >> 33
    }
    fn range(&mut self, lo: i64, hi: i64) -> i64 {
        lo + (self.next() % (hi - lo) as u64) as i64
    }
}

/// Issue 33's "done when": from 10 random physical positions, homing ends with every
/// joint's count equal to its true position minus the switch's plus the offset, to the
/// step (three joints, both directions, a bouncing contact, both polarities).
#[test]
fn homing_from_random_positions_ends_at_the_true_position() {
    let mut rng = Lcg(33);
    for trial in 0..10 {
        let input = if trial % 2 == 0 { NC } else { NO };
        let mut joints = [Joint::default(); MAX_JOINTS];
        let homes = [(Side::Max, 4_000i64), (Side::Min, -3_000), (Side::Max, 0)];
        for (j, &home) in homes.iter().enumerate() {
            // Anywhere from well before the switch to just past it (on it at boot).
            let (side, at) = home;
            let start = match side {
                Side::Max => rng.range(at - 15_000, at + 20),
                Side::Min => rng.range(at - 20, at + 15_000),
            };
            joints[j] = Joint {
                truth: start,
                count: 0,
                home: Some(home),
                limits: None,
            };
        }
        let mut rig = Rig::new(joints, input);
        rig.bounce = trial % 3 == 0;
        rig.overrun = trial % 4;
        let mut s = [HomingJoint::NONE; MAX_JOINTS];
        s[0] = settings(Side::Max, 1_000, 2);
        s[1] = settings(Side::Min, -250, 0);
        s[2] = settings(Side::Max, 0, 1);
        let starts: Vec<i64> = rig.joints[..3].iter().map(|j| j.truth).collect();
        let end = home(&mut rig, s, 3);
        assert_eq!(end, HomingAction::Done, "trial {trial} from {starts:?}");
        for j in 0..3 {
            let expect = rig.joints[j].truth - homes[j].1 + i64::from(s[j].offset);
            assert_eq!(
                i64::from(rig.joints[j].count),
                expect,
                "trial {trial}, joint {j} from {}: truth {}",
                starts[j],
                rig.joints[j].truth
            );
        }
        // Order: joint 1 (order 0) moved first, then 2, then 0.
        let mut firsts: Vec<usize> = Vec::new();
        for &(_, j) in &rig.steps {
            if firsts.last() != Some(&j) {
                firsts.push(j);
            }
        }
        firsts.dedup();
        let mut seen = Vec::new();
        for j in firsts {
            if !seen.contains(&j) {
                seen.push(j);
            }
        }
        assert_eq!(seen, vec![1, 2, 0], "trial {trial}");
        println!(
            "trial {trial}: from {starts:?}, counts {:?}",
            &rig.joints[..3].iter().map(|j| j.count).collect::<Vec<_>>()
        );
    }
}

/// A seek that travels its maximum without the switch fails naming the joint; nothing
/// moved past the maximum.
#[test]
fn a_seek_past_its_maximum_travel_fails_naming_the_joint() {
    let mut joints = [Joint::default(); MAX_JOINTS];
    joints[1] = Joint {
        truth: 0,
        count: 0,
        home: Some((Side::Max, 30_000)),
        limits: None,
    };
    let mut rig = Rig::new(joints, NC);
    let mut s = [HomingJoint::NONE; MAX_JOINTS];
    s[1] = settings(Side::Max, 0, 0);
    let end = home(&mut rig, s, 2);
    assert_eq!(
        end,
        HomingAction::Failed(HomingError::SeekTravel { joint: 1 })
    );
    assert_eq!(
        rig.joints[1].truth, 20_000,
        "moved exactly the maximum travel"
    );
}

/// Hard limits stay active while homing: another joint's limit aborts the cycle naming
/// the joint being homed, and latches.
#[test]
fn a_limit_trip_while_homing_aborts_and_latches() {
    let mut joints = [Joint::default(); MAX_JOINTS];
    joints[0] = Joint {
        truth: 0,
        count: 0,
        home: Some((Side::Max, 5_000)),
        limits: Some((-10_000, 1_000)),
    };
    let mut rig = Rig::new(joints, NC);
    let mut s = [HomingJoint::NONE; MAX_JOINTS];
    s[0] = settings(Side::Max, 0, 0);
    let end = home(&mut rig, s, 1);
    assert_eq!(end, HomingAction::Failed(HomingError::Aborted { joint: 0 }));
    assert_eq!(rig.limits.latched(), Some((0, Side::Max)));
    assert_eq!(
        rig.joints[0].truth, 1_000,
        "stopped on the step that tripped"
    );
}

/// The switch being homed on, when it is also the joint's limit, does not stop the arm.
#[test]
fn the_switch_being_homed_on_is_masked_when_it_is_the_limit() {
    let mut joints = [Joint::default(); MAX_JOINTS];
    joints[0] = Joint {
        truth: -700,
        count: 0,
        home: Some((Side::Min, -2_000)),
        limits: Some((-2_000, 9_000)),
    };
    let mut rig = Rig::new(joints, NC);
    let mut s = [HomingJoint::NONE; MAX_JOINTS];
    s[0] = HomingJoint {
        switch_is_limit: true,
        ..settings(Side::Min, 0, 0)
    };
    assert_eq!(home(&mut rig, s, 1), HomingAction::Done);
    assert_eq!(rig.limits.latched(), None);
    assert_eq!(i64::from(rig.joints[0].count), rig.joints[0].truth + 2_000);
}

/// Issue 33's hard-limit rules: a trajectory running into a max limit switch stops every
/// joint with no STEP edge later than one step period after the switch closes; the
/// controller is latched; motion is refused naming the limit; after an unlock, jogging
/// away works and jogging further in is refused until the switch has opened.
#[test]
fn a_max_limit_stops_every_joint_latches_and_after_unlock_allows_only_away() {
    let mut joints = [Joint::default(); MAX_JOINTS];
    joints[0] = Joint {
        truth: 0,
        count: 0,
        home: None,
        limits: Some((-5_000, 3_000)),
    };
    joints[1] = Joint {
        truth: 0,
        count: 0,
        home: None,
        limits: Some((-5_000, 5_000)),
    };
    joints[2] = Joint::default();
    let mut rig = Rig::new(joints, NC);
    // A "trajectory": joint 0 +5,000 at 1 kHz, joint 1 -4,000 at 800 Hz, joint 2 +3,000
    // at 600 Hz; steps interleaved by their instants.
    let moves = [(0usize, 1i32, 1_000u64), (1, -1, 1_250), (2, 1, 1_667)];
    assert_eq!(rig.limits.check_move(&[5_000, -4_000, 3_000]), Ok(()));
    let mut next: Vec<u64> = moves.iter().map(|m| m.2).collect();
    let mut tripped_at = None;
    'run: for _ in 0..20_000 {
        let (k, &t) = next.iter().enumerate().min_by_key(|(_, t)| **t).unwrap();
        rig.now_us = t;
        next[k] += moves[k].2;
        for e in rig.step(moves[k].0, moves[k].1) {
            if let SwitchEvent::LimitTripped { at_us, .. } = e {
                tripped_at.get_or_insert(at_us);
            }
            if rig.limits.on_event(e) {
                break 'run; // the e-stop path: every joint stops here
            }
        }
    }
    let closed = tripped_at.expect("the max limit tripped");
    let last_edge = rig.steps.iter().map(|s| s.0).max().unwrap();
    let shortest_period = 1_000;
    println!(
        "limit closed at {closed} us; last STEP edge {last_edge} us ({} us after)",
        last_edge.saturating_sub(closed)
    );
    assert!(last_edge <= closed + shortest_period);
    assert_eq!(rig.joints[0].truth, 3_000);
    assert_eq!(rig.limits.latched(), Some((0, Side::Max)));

    // Latched: nothing moves, whichever way, naming the limit.
    let refused = LimitRefusal::Latched {
        joint: 0,
        side: Side::Max,
    };
    assert_eq!(rig.limits.check_move(&[0, 10, 0]), Err(refused));
    assert_eq!(rig.limits.check_move(&[-10, 0, 0]), Err(refused));

    rig.limits.unlock();
    let further = LimitRefusal::TowardsTripped {
        joint: 0,
        side: Side::Max,
    };
    assert_eq!(rig.limits.check_move(&[1, 0, 0]), Err(further));
    assert_eq!(rig.limits.check_move(&[-1, 10, -10]), Ok(()));

    // Jog away at 100 Hz until the switch has opened (debounced).
    let mut away = 0;
    while rig.limits.is_active(0, Side::Max) {
        assert_eq!(rig.limits.check_move(&[-1]), Ok(()));
        assert_eq!(rig.limits.check_move(&[1]), Err(further), "still active");
        rig.now_us += 10_000;
        for e in rig.step(0, -1) {
            rig.limits.on_event(e);
        }
        away += 1;
        assert!(away < 100, "the switch never opened");
    }
    println!("released after {away} steps away");
    assert_eq!(rig.limits.check_move(&[1, 0, 0]), Ok(()));
    assert_eq!(rig.limits.latched(), None);
}

/// A switch that bounces on release counts as released only after a whole quiet
/// debounce time; activation is never delayed.
#[test]
fn release_is_debounced_on_the_edges_instants() {
    let mut config = SwitchConfig::NONE;
    config.inputs[3].max = NC;
    let mut bank = SwitchBank::new(config);
    assert_eq!(
        bank.edge(3, Switch::Max, true, 77, 1_000),
        Some(SwitchEvent::LimitTripped {
            joint: 3,
            side: Side::Max,
            at_us: 1_000
        })
    );
    assert_eq!(bank.edge(3, Switch::Max, false, 70, 5_000), None);
    assert_eq!(bank.poll(5_000 + u64::from(DEBOUNCE_US) - 1), None);
    // A bounce restarts the quiet time.
    assert_eq!(bank.edge(3, Switch::Max, true, 70, 6_000), None);
    assert_eq!(bank.edge(3, Switch::Max, false, 70, 6_500), None);
    assert_eq!(bank.poll(8_000), None);
    assert!(bank.is_active(3, Switch::Max));
    assert_eq!(
        bank.poll(6_500 + u64::from(DEBOUNCE_US)),
        Some(SwitchEvent::LimitReleased {
            joint: 3,
            side: Side::Max
        })
    );
    assert!(!bank.is_active(3, Switch::Max));
    // Unfitted inputs and joints out of range are ignored, never a panic.
    assert_eq!(bank.edge(2, Switch::Max, true, 0, 0), None);
    assert_eq!(bank.edge(200, Switch::Home, true, 0, 0), None);
}
