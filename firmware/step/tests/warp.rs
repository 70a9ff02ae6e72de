//! HOLD, RESUME and the speed override through the step engine (the oracle), sans-io on
//! virtual time (the fake clock jumps from deadline to deadline): issue 32's figures. The
//! producer takes the same warp and gives the same edges (tests/producer.rs).
//!
//! Joint 0 runs at 4,000 steps/s with a limit of 20,000 steps/s^2, joint 1 at 1,000 steps/s
//! (reversing once) with the same limit; a hold at 2 s must slow joint 0 to a standstill
//! within v/a = 0.2 s, after about v^2/2a = 400 steps, never at more than 1.1x the limit as
//! implied by any two consecutive step intervals; after the resume every joint ends exactly
//! at its last point.

mod common;

use arm_step::{MAX_JOINTS, RATE_ONE, Segment, StepEngine, WARP_PHASES, Warp, WarpError, ramp_for};
use common::{BOARD_TIMING, Recorder};

const QUEUE: usize = 16;
const HZ: u64 = BOARD_TIMING.tick_hz as u64;
const ACCEL: u32 = 20_000;
/// Where the run's first segment starts: room for the DIR setup.
const ORIGIN: u64 = 10_000;

/// Eight 0.5 s segments: joint 0 at 4,000 steps/s throughout, joint 1 at 1,000 steps/s,
/// reversing at 2.5 s (the path's own velocity step there is outside the windows checked).
fn segments() -> Vec<Segment> {
    (0..8)
        .map(|i| {
            let mut steps = [0; MAX_JOINTS];
            steps[0] = 2_000;
            steps[1] = if i < 5 { 500 } else { -500 };
            Segment {
                duration_us: 500_000,
                steps,
            }
        })
        .collect()
}

/// Runs the segments under `warp` to the end; the recorder and the final positions.
fn run(warp: Warp) -> (Recorder, [i32; MAX_JOINTS], u32) {
    let mut engine = StepEngine::<QUEUE>::new(BOARD_TIMING);
    assert!(engine.set_warp(warp));
    for segment in segments() {
        assert!(engine.push(segment).is_ok());
    }
    engine.start(ORIGIN);
    let mut pins = Recorder::default();
    let mut now = 0;
    // Bounded: a pulse, a fall, a DIR change per deadline at most.
    for _ in 0..200_000 {
        pins.now = now;
        match engine.poll(now, &mut pins).next_deadline {
            Some(deadline) => now = deadline,
            None => {
                pins.check_timing(&BOARD_TIMING);
                return (pins, engine.positions(), engine.late_pulses());
            }
        }
    }
    panic!("the run never ended");
}

/// Highest acceleration (steps/s^2) two consecutive intervals of `rises` imply, over the
/// pulses rising in `from..to`: the mean speed over an interval is the speed at its middle,
/// so `(1/i2 - 1/i1) / ((i1 + i2) / 2)`, exact for a constant acceleration.
fn max_implied_accel(rises: &[u64], from: u64, to: u64) -> f64 {
    let ticks: Vec<u64> = rises
        .iter()
        .copied()
        .filter(|t| (from..to).contains(t))
        .collect();
    ticks
        .windows(3)
        .map(|w| {
            let i1 = (w[1] - w[0]) as f64 / HZ as f64;
            let i2 = (w[2] - w[1]) as f64 / HZ as f64;
            (1.0 / i2 - 1.0 / i1).abs() / ((i1 + i2) / 2.0)
        })
        .fold(0.0, f64::max)
}

fn final_points() -> [i32; MAX_JOINTS] {
    segments().iter().fold([0; MAX_JOINTS], |mut sum, s| {
        for (total, steps) in sum.iter_mut().zip(s.steps) {
            *total += steps;
        }
        sum
    })
}

fn rise_ticks(pins: &Recorder, joint: usize) -> Vec<u64> {
    pins.rises(joint).into_iter().map(|(t, _)| t).collect()
}

#[test]
fn a_hold_stops_within_the_acceleration_and_the_resume_ends_on_the_points() {
    // The slope the faster joint allows (the smaller one).
    let ramp = ramp_for(ACCEL, 4_000, BOARD_TIMING.tick_hz).min(ramp_for(
        ACCEL,
        1_000,
        BOARD_TIMING.tick_hz,
    ));
    let hold = ORIGIN + 2 * HZ;
    let resume = hold + HZ;
    let mut warp = Warp::IDENTITY;
    assert_eq!(warp.hold(hold, ramp), Ok(()));
    assert_eq!(warp.resume(resume, RATE_ONE, ramp), Ok(()));
    let (pins, positions, late) = run(warp);

    let joint0 = rise_ticks(&pins, 0);
    let held: Vec<u64> = joint0
        .iter()
        .copied()
        .filter(|&t| (hold + 1..resume).contains(&t))
        .collect();
    let last = *held.last().expect("steps after the hold");
    let to_standstill = (last - hold) as f64 / HZ as f64;
    let standstill = (hold..resume)
        .find(|&t| warp.rate(t) == 0)
        .map(|t| (t - hold) as f64 / HZ as f64);
    let after_resume = joint0.iter().find(|&&t| t >= resume).copied();
    let ratio = max_implied_accel(&joint0, ORIGIN + HZ, u64::MAX) / f64::from(ACCEL);
    let joint1 = rise_ticks(&pins, 1);
    // Joint 1 reverses at 2.5 s of the path: check it where the path is smooth.
    let ratio1 = max_implied_accel(&joint1, ORIGIN + HZ, hold + HZ / 2) / f64::from(ACCEL);
    let held1 = joint1
        .iter()
        .filter(|&&t| (hold + 1..resume).contains(&t))
        .count();
    println!(
        "hold at 2 s: last step {to_standstill:.4} s after it (warp at rest after {:.4} s), \
         {} steps after the hold (v^2/2a = 400; joint 1: {held1}, path ratio 100), \
         first step after the resume {:.4} s after it; max implied acceleration / limit: \
         joint 0 {ratio:.4}, joint 1 {ratio1:.4}; {late} late pulses",
        standstill.unwrap_or(f64::NAN),
        held.len(),
        after_resume.map_or(f64::NAN, |t| (t - resume) as f64 / HZ as f64),
    );
    assert!(
        to_standstill <= 0.2,
        "stopped {to_standstill} s after the hold"
    );
    assert!(
        standstill.is_some_and(|s| s <= 0.2 + 1e-6),
        "{standstill:?}"
    );
    assert!((398..=402).contains(&held.len()), "{} steps", held.len());
    assert!(
        (99..=101).contains(&held1),
        "joint 1 kept the path: {held1}"
    );
    assert!(ratio <= 1.1, "joint 0 implied {ratio} x the limit");
    assert!(ratio1 <= 1.1, "joint 1 implied {ratio1} x the limit");
    assert_eq!(late, 0);
    assert_eq!(positions, final_points(), "every joint on its last point");
    assert_eq!(pins.signed_pulses(), final_points());
}

#[test]
fn an_override_slows_and_speeds_within_the_acceleration() {
    let ramp = ramp_for(ACCEL, 4_000, BOARD_TIMING.tick_hz);
    let mut warp = Warp::IDENTITY;
    // 30 % from 1 s, back to 100 % from 2.5 s.
    assert_eq!(
        warp.change_rate(ORIGIN + HZ, RATE_ONE * 3 / 10, ramp),
        Ok(())
    );
    assert_eq!(
        warp.change_rate(ORIGIN + 5 * HZ / 2, RATE_ONE, ramp),
        Ok(())
    );
    let (pins, positions, late) = run(warp);
    let joint0 = rise_ticks(&pins, 0);
    let ratio = max_implied_accel(&joint0, ORIGIN + HZ / 2, u64::MAX) / f64::from(ACCEL);
    // At 30 %: 1,200 steps/s, from 1.14 s (0.14 s of ramp) to 2.5 s.
    let slow = joint0
        .iter()
        .filter(|&&t| (ORIGIN + 3 * HZ / 2..ORIGIN + 5 * HZ / 2).contains(&t))
        .count();
    let end = *joint0.last().expect("pulses") as f64 / HZ as f64;
    println!(
        "override 30 % at 1 s, 100 % at 2.5 s: {slow} steps in 1.5-2.5 s (1,200 at 30 %), \
         run ends at {end:.4} s (4 s unwarped), max implied acceleration / limit {ratio:.4}"
    );
    assert!((1_199..=1_201).contains(&slow), "{slow}");
    assert!(ratio <= 1.1, "implied {ratio} x the limit");
    assert_eq!(late, 0);
    assert_eq!(positions, final_points());
}

/// Holds and resumes taken DURING the run (`change_warp` when the clock reaches them, at
/// the engine's horizon or later) give the edges of the same changes planned before it;
/// twenty of them, more than [`WARP_PHASES`] holds without forgetting what is over; a change
/// before the horizon is refused and changes nothing.
#[test]
fn changes_taken_mid_run_match_the_same_changes_planned_and_forget_what_is_over() {
    let ramp = ramp_for(ACCEL, 4_000, BOARD_TIMING.tick_hz);
    // Every 0.4 s from 0.1 s: a hold, then a resume 0.05 s later (mid-ramp) or 0.3 s later
    // (held: the pulses due meanwhile are "never" until the resume maps them again).
    let asked: Vec<(u64, u64)> = (0..20u64)
        .map(|i| {
            let hold = ORIGIN + HZ / 10 + (i / 2) * 2 * HZ / 5;
            let after = if i % 4 == 1 { HZ / 20 } else { 3 * HZ / 10 };
            (hold + if i % 2 == 0 { 0 } else { after }, i % 2)
        })
        .collect();
    let mut engine = StepEngine::<QUEUE>::new(BOARD_TIMING);
    for segment in segments() {
        assert!(engine.push(segment).is_ok());
    }
    engine.start(ORIGIN);
    let mut pins = Recorder::default();
    let mut now = 0;
    let mut taken = Vec::new();
    let mut pending = &asked[..];
    let mut most_phases = 0;
    for _ in 0..400_000 {
        while let Some((&(at, resume), rest)) = pending.split_first() {
            if at > now {
                break;
            }
            let horizon = engine.warp_horizon();
            if horizon > 0 {
                assert_eq!(
                    engine.change_warp(horizon - 1, 0, ramp),
                    Err(WarpError::Committed)
                );
            }
            let at = at.max(horizon);
            let target = if resume == 1 { RATE_ONE } else { 0 };
            assert_eq!(engine.change_warp(at, target, ramp), Ok(()));
            most_phases = most_phases.max(engine.warp().phases());
            taken.push((at, target));
            pending = rest;
        }
        pins.now = now;
        match engine.poll(now, &mut pins).next_deadline {
            Some(deadline) => {
                now = pending
                    .first()
                    .map_or(deadline, |&(at, _)| deadline.min(at))
            }
            None => break,
        }
    }
    assert!(!engine.is_running(), "the run ended");
    assert_eq!(taken.len(), asked.len());
    assert!(
        most_phases < WARP_PHASES,
        "{most_phases} phases held at most"
    );
    pins.check_timing(&BOARD_TIMING);

    // The reference: as many of the same changes as one warp holds, planned before the
    // run; the edges agree up to the first change it lacks.
    let fit = planned_changes(&taken, ramp);
    let mut planned = Warp::IDENTITY;
    for &(at, target) in &taken[..fit] {
        assert_eq!(planned.change_rate(at, target, ramp), Ok(()));
    }
    let checked = taken.get(fit).map_or(u64::MAX, |&(at, _)| at);
    let (reference, _, _) = run(planned);
    let upto = |p: &Recorder, joint| -> Vec<u64> {
        rise_ticks(p, joint)
            .into_iter()
            .filter(|&t| t <= checked)
            .collect()
    };
    for joint in 0..2 {
        assert_eq!(upto(&pins, joint), upto(&reference, joint), "joint {joint}");
    }
    println!(
        "{} changes taken mid-run, at most {most_phases} warp phases held ({WARP_PHASES} \
         fit); edges equal to those of the first {fit} planned before the run, up to {:.3} s",
        taken.len(),
        checked.min(now) as f64 / HZ as f64
    );
    assert_eq!(
        engine.positions(),
        final_points(),
        "every joint on its last point"
    );
}

/// How many of `taken` (from the first) fit one warp planned before the run.
fn planned_changes(taken: &[(u64, u64)], ramp: u64) -> usize {
    let mut warp = Warp::IDENTITY;
    taken
        .iter()
        .take_while(|&&(at, target)| warp.change_rate(at, target, ramp).is_ok())
        .count()
}
