//! StepEngine driven by a fake tick clock and recording pins.

mod common;

use arm_step::{MAX_JOINTS, Poll, Segment, StepEngine, StepTiming};
use common::*;

fn timing(tick_hz: u32, pulse_width_ticks: u32, dir_setup_ticks: u32) -> StepTiming {
    StepTiming {
        tick_hz,
        pulse_width_ticks,
        dir_setup_ticks,
        // Room for the DIR setup between any two pulses: trajectories at the max rate
        // reverse on time too.
        step_low_ticks: dir_setup_ticks,
    }
}

/// The tick rates the board and the simulator may use, including one that is not a
/// multiple of 1 MHz. Pulse width 2 us, direction setup 5 us (rounded up to ticks).
fn timings() -> Vec<StepTiming> {
    [1_000_000u32, 10_000_000, 3_000_000, 2_999_999]
        .iter()
        .map(|&hz| {
            let ticks = |us: u64| (u64::from(hz) * us).div_ceil(1_000_000) as u32;
            timing(hz, ticks(2), ticks(5))
        })
        .collect()
}

/// Most steps a joint may make in `duration_us` at the engine's max rate.
fn max_steps(timing: &StepTiming, duration_us: u32) -> i32 {
    (u64::from(timing.max_step_rate_hz()) * u64::from(duration_us) / 1_000_000) as i32
}

/// A trajectory with every case in it: several joints, zero steps, sign changes, a 1 us
/// segment, joints at exactly the max rate.
fn mixed_trajectory(timing: &StepTiming) -> Vec<Segment> {
    let max = |us| max_steps(timing, us);
    vec![
        Segment {
            duration_us: 1_000,
            steps: [10, -3, 0, 0, 1, 0, 0, max(1_000)],
        },
        Segment {
            duration_us: 333,
            steps: [-7, -1, 1, 0, 0, 0, 0, -max(333)],
        },
        Segment {
            duration_us: 1,
            steps: [0; MAX_JOINTS],
        },
        Segment {
            duration_us: 7_777,
            steps: [max(7_777), 0, -100, -max(7_777), 3, 0, 0, 1],
        },
        Segment {
            duration_us: 50,
            steps: [-2, 2, -2, 2, -2, 2, -2, 2],
        },
        Segment {
            duration_us: 20_000,
            steps: [1, 0, 0, 0, 0, 0, 0, 0],
        },
    ]
}

/// Checks that the `k`-th pulse of each segment's last lands exactly on the segment's end.
fn assert_segments_end_on_their_ticks(segments: &[Segment], model: &Model, pins: &Recorder) {
    for joint in 0..MAX_JOINTS {
        let rises = pins.rises(joint);
        let mut emitted = 0usize;
        for (k, segment) in segments.iter().enumerate() {
            let n = segment.steps[joint].unsigned_abs() as usize;
            if n == 0 {
                continue;
            }
            emitted += n;
            assert_eq!(
                rises[emitted - 1].0,
                model.segment_ends[k],
                "joint {joint}: last pulse of segment {k} not on its end"
            );
        }
    }
}

/// The k-th finished segment is reported at a poll at or after its end.
fn assert_finished_after_end(model: &Model, outcome: &Outcome) {
    let mut k = 0usize;
    for (tick, poll) in &outcome.polls {
        for _ in 0..poll.segments_finished {
            assert!(*tick >= model.segment_ends[k], "segment {k} freed early");
            k += 1;
        }
    }
    assert_eq!(
        k,
        model.segment_ends.len(),
        "every segment reported finished"
    );
}

#[test]
fn mixed_trajectory_is_exact_at_every_tick_rate() {
    for timing in timings() {
        let segments = mixed_trajectory(&timing);
        let start = 1_000_000;
        let (engine, pins, outcome) =
            run_all::<8>(timing, &segments, start, timing.tick_hz as u64 / 1000);
        let model = Model::new(&segments, start, timing.tick_hz);
        assert!(model.total_pulses() > 1000, "the trajectory is not trivial");
        model.assert_exact(&pins);
        pins.check_timing(&timing);
        assert_segments_end_on_their_ticks(&segments, &model, &pins);
        assert_finished_after_end(&model, &outcome);
        assert_eq!(engine.late_pulses(), 0, "{timing:?}");
        assert_eq!(engine.positions(), net_steps(&segments));
        assert_eq!(pins.signed_pulses(), net_steps(&segments));
        // The last segment moves joint 0 once, at its end; the run ends when it falls.
        let end = *model.segment_ends.last().unwrap_or(&0);
        assert_eq!(
            outcome.dry_at,
            Some(end + u64::from(timing.pulse_width_ticks))
        );
        assert_eq!(pins.step_high, [false; MAX_JOINTS]);
        assert_eq!(engine.free_slots(), 8);
    }
}

#[test]
fn single_joint_pulses_at_floor_of_i_d_over_n() {
    // 1 MHz: D = 1000 ticks, N = 7: pulse i at floor(i * 1000 / 7).
    let timing = timing(1_000_000, 2, 5);
    let segments = [one_joint(1_000, 3, 7)];
    let (_, pins, _) = run_all::<4>(timing, &segments, 500, 100);
    let ticks: Vec<u64> = pins.rises(3).iter().map(|(t, _)| *t).collect();
    assert_eq!(ticks, vec![642, 785, 928, 1071, 1214, 1357, 1500]);
}

#[test]
fn no_drift_over_ten_thousand_segments() {
    for tick_hz in [1_000_000u32, 10_000_000, 3_000_000, 2_999_999] {
        let timing = timing(tick_hz, 1, 1);
        let segments: Vec<Segment> = (0..10_000u32)
            .map(|k| {
                let duration_us = 97 + (k * 7_919) % 1_000;
                let mut steps = [0; MAX_JOINTS];
                steps[0] = if k % 2 == 0 { 3 } else { -2 };
                steps[5] = (k % 7) as i32 - 3;
                Segment { duration_us, steps }
            })
            .collect();
        let total_us: u64 = segments.iter().map(|s| u64::from(s.duration_us)).sum();
        let start = 12_345;
        let mut engine = StepEngine::<8>::new(timing);
        let mut pins = Recorder::default();
        let mut feed = segments.iter().copied();
        for _ in 0..4 {
            assert!(engine.push(feed.next().unwrap()).is_ok());
        }
        engine.start(start);
        let outcome = drive(
            &mut engine,
            &mut pins,
            start - 10,
            &mut feed,
            || 0,
            u64::MAX,
            1_000_000,
        );
        let end = start + (u128::from(total_us) * u128::from(tick_hz) / 1_000_000) as u64;
        let last = pins.rises(0).last().map(|(t, _)| *t);
        assert_eq!(
            last,
            Some(end),
            "{tick_hz} Hz: last pulse not on the end tick"
        );
        assert_eq!(outcome.dry_at, Some(end + 1));
        assert_eq!(outcome.segments_finished(), 10_000);
        let model = Model::new(&segments, start, tick_hz);
        model.assert_exact(&pins);
        pins.check_timing(&timing);
        assert_eq!(engine.late_pulses(), 0);
        assert_eq!(engine.positions(), net_steps(&segments));
    }
}

#[test]
fn direction_changes_only_while_low_and_before_setup() {
    // Alternating directions at the max rate: every DIR change sits between a fall and the
    // next rise, `dir_setup` before it, and nothing is late.
    for timing in timings() {
        let n = max_steps(&timing, 100);
        assert!(n > 1);
        let segments: Vec<Segment> = (0..50)
            .map(|k| {
                let sign = if k % 2 == 0 { 1 } else { -1 };
                Segment {
                    duration_us: 100,
                    steps: [sign * n, -sign * n, sign, 0, sign * n, 0, 0, -sign],
                }
            })
            .collect();
        let start = 10_000;
        let (engine, pins, _) =
            run_all::<64>(timing, &segments, start, u64::from(timing.dir_setup_ticks));
        let model = Model::new(&segments, start, timing.tick_hz);
        model.assert_exact(&pins);
        pins.check_timing(&timing);
        assert_eq!(engine.late_pulses(), 0);
        let dir_changes = pins
            .events
            .iter()
            .filter(|e| matches!(e.edge, Edge::Dir(_)) && e.joint == 0)
            .count();
        assert_eq!(dir_changes, 50);
    }
}

#[test]
fn too_short_dir_setup_delays_pulses_never_drops_them() {
    // 10 pulses 10 ticks apart, then 10 back: the turn-around needs 100 ticks of setup.
    // A driver that needs one tick low between pulses.
    let timing = StepTiming {
        step_low_ticks: 1,
        ..timing(1_000_000, 2, 100)
    };
    let segments = [one_joint(100, 0, 10), one_joint(100, 0, -10)];
    let start = 1_000;
    let (engine, pins, outcome) = run_all::<4>(timing, &segments, start, 200);
    let model = Model::new(&segments, start, 1_000_000);
    model.assert_complete_in_order(&pins);
    pins.check_timing(&timing);
    let rises = pins.rises(0);
    // Last forward pulse at 1100, falls at 1102, DIR at 1102: first pulse back at 1202.
    assert_eq!(rises[9], (1_100, true));
    assert_eq!(rises[10], (1_202, false));
    // They then follow one another at width + one tick low, all late.
    for pair in rises[10..].windows(2) {
        assert_eq!(pair[1].0 - pair[0].0, 3);
    }
    assert_eq!(engine.late_pulses(), 10);
    assert_eq!(engine.positions()[0], 0);
    assert_eq!(outcome.dry_at, Some(1_202 + 27 + 2));
}

#[test]
fn faster_than_the_pins_allow_is_delayed_not_dropped() {
    // N = D: one pulse per tick requested, twice more than width + low allow.
    let timing = timing(1_000_000, 1, 1);
    let segments = [one_joint(1_000, 2, 1_000), one_joint(10, 2, 1)];
    let (engine, pins, outcome) = run_all::<4>(timing, &segments, 100, 10);
    let model = Model::new(&segments, 100, 1_000_000);
    model.assert_complete_in_order(&pins);
    pins.check_timing(&timing);
    assert_eq!(engine.positions()[2], 1_001);
    assert!(engine.late_pulses() >= 999);
    let last = pins.rises(2).last().map(|(t, _)| *t);
    assert_eq!(last, Some(101 + 2 * 1_000));
    assert_eq!(outcome.segments_finished(), 2);
}

#[test]
fn late_polls_still_emit_every_pulse_in_order() {
    for timing in timings() {
        let segments = mixed_trajectory(&timing);
        let start = 100_000;
        let mut engine = StepEngine::<8>::new(timing);
        let mut pins = Recorder::default();
        let mut feed = segments.iter().copied();
        engine.start(start);
        // Interrupt latency up to three minimum pulse periods, pseudo-random.
        let span = 3 * timing.min_pulse_period_ticks();
        let mut seed = 0x2545_f491_4f6c_dd1d_u64;
        let latency = move || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            seed % span
        };
        let outcome = drive(
            &mut engine,
            &mut pins,
            start - 1_000,
            &mut feed,
            latency,
            u64::MAX,
            10_000_000,
        );
        assert!(outcome.dry_at.is_some());
        let model = Model::new(&segments, start, timing.tick_hz);
        model.assert_complete_in_order(&pins);
        pins.check_timing(&timing);
        assert_eq!(engine.positions(), net_steps(&segments));
        assert!(engine.late_pulses() > 0, "some pulses were pushed back");
        assert_eq!(pins.step_high, [false; MAX_JOINTS]);
    }
}

#[test]
fn stop_mid_segment_keeps_exactly_the_emitted_pulses() {
    for timing in timings() {
        let segments = [
            Segment {
                duration_us: 100_000,
                steps: [1_000, -500, 0, 7, 0, 0, 0, 3],
            },
            one_joint(100_000, 1, 400),
        ];
        let start = 5_000;
        let mut engine = StepEngine::<4>::new(timing);
        let mut pins = Recorder::default();
        for segment in segments {
            assert!(engine.push(segment).is_ok());
        }
        assert!(engine.set_positions([10, 20, 30, 40, 50, 60, 70, 80]));
        engine.start(start);
        let until = start + u64::from(timing.tick_hz) * 37_777 / 1_000_000;
        let outcome = drive(
            &mut engine,
            &mut pins,
            start - 100,
            &mut core::iter::empty(),
            || 0,
            until,
            1_000_000,
        );
        assert_eq!(outcome.dry_at, None);
        assert!(engine.is_running());
        // Stop in the middle of a pulse.
        let mut next = outcome.polls.last().and_then(|(_, p)| p.next_deadline);
        while !pins.step_high.contains(&true) {
            let now = next.expect("still running");
            pins.now = now;
            next = engine.poll(now, &mut pins).next_deadline;
        }

        pins.stopping = true;
        engine.stop(&mut pins);
        pins.stopping = false;
        assert!(!engine.is_running());
        assert_eq!(pins.step_high, [false; MAX_JOINTS], "every STEP line low");
        assert_eq!(engine.free_slots(), 4, "queue dropped");
        let moved = pins.signed_pulses();
        assert!(
            moved[0] > 300 && moved[0] < 1_000,
            "stopped mid-segment: {moved:?}"
        );
        let expected: Vec<i32> = [10, 20, 30, 40, 50, 60, 70, 80]
            .iter()
            .zip(moved)
            .map(|(base, moved)| base + moved)
            .collect();
        assert_eq!(engine.positions().to_vec(), expected);
        let calls = pins.calls;
        assert_eq!(engine.poll(until + 1_000, &mut pins), Poll::default());
        assert_eq!(pins.calls, calls, "an idle engine touches no line");

        // A new run starts from where the arm stopped.
        let later = until + 1_000_000;
        assert!(engine.push(one_joint(1_000, 0, -5)).is_ok());
        engine.start(later);
        let outcome = drive(
            &mut engine,
            &mut pins,
            later - 100,
            &mut core::iter::empty(),
            || 0,
            u64::MAX,
            1_000,
        );
        assert!(outcome.dry_at.is_some());
        assert_eq!(engine.positions()[0], expected[0] - 5);
        pins.check_timing(&timing);
    }
}

#[test]
fn runs_dry_at_the_end_and_starts_again() {
    let timing = timing(1_000_000, 2, 5);
    let mut engine = StepEngine::<4>::new(timing);
    let mut pins = Recorder::default();
    assert!(engine.push(one_joint(1_000, 1, 10)).is_ok());
    engine.start(100);
    let outcome = drive(
        &mut engine,
        &mut pins,
        90,
        &mut core::iter::empty(),
        || 0,
        u64::MAX,
        1_000,
    );
    assert_eq!(outcome.dry_at, Some(1_102));
    let dry: Vec<_> = outcome.polls.iter().filter(|(_, p)| p.ran_dry).collect();
    assert_eq!(dry.len(), 1);
    assert!(!engine.is_running());
    assert_eq!(engine.poll(5_000, &mut pins), Poll::default());

    // Second run: its own timeline from its own start tick.
    assert!(engine.push(one_joint(1_000, 1, -10)).is_ok());
    engine.start(10_000);
    let outcome = drive(
        &mut engine,
        &mut pins,
        9_990,
        &mut core::iter::empty(),
        || 0,
        u64::MAX,
        1_000,
    );
    assert_eq!(outcome.dry_at, Some(11_002));
    assert_eq!(pins.rises(1)[10], (10_100, false));
    assert_eq!(engine.positions()[1], 0);
    pins.check_timing(&timing);
}

#[test]
fn streaming_through_a_two_slot_queue_chains_exactly() {
    // Each segment is pushed as soon as a slot frees, while the one before it runs: the
    // run never runs dry early and every segment chains on the same timeline.
    let timing = timing(3_000_000, 6, 15);
    let segments = [
        one_joint(1_000, 0, 10),
        one_joint(1_000, 0, 10),
        one_joint(777, 0, -3),
    ];
    let mut engine = StepEngine::<2>::new(timing);
    let mut pins = Recorder::default();
    let mut feed = segments.iter().copied();
    engine.start(3_000);
    let outcome = drive(
        &mut engine,
        &mut pins,
        2_900,
        &mut feed,
        || 0,
        u64::MAX,
        1_000,
    );
    let dry = outcome.polls.iter().filter(|(_, p)| p.ran_dry).count();
    assert_eq!(dry, 1);
    assert_eq!(outcome.segments_finished(), 3);
    Model::new(&segments, 3_000, 3_000_000).assert_exact(&pins);
    assert_eq!(engine.late_pulses(), 0);
}

#[test]
fn set_positions_refused_while_running() {
    let timing = timing(1_000_000, 2, 5);
    let mut engine = StepEngine::<4>::new(timing);
    let mut pins = Recorder::default();
    assert!(engine.set_positions([1, 2, 3, 4, 5, 6, 7, 8]));
    assert_eq!(engine.positions(), [1, 2, 3, 4, 5, 6, 7, 8]);
    assert!(engine.push(one_joint(1_000, 0, 3)).is_ok());
    engine.start(10);
    assert!(!engine.set_positions([0; MAX_JOINTS]));
    assert_eq!(engine.positions(), [1, 2, 3, 4, 5, 6, 7, 8]);
    drive(
        &mut engine,
        &mut pins,
        0,
        &mut core::iter::empty(),
        || 0,
        u64::MAX,
        100,
    );
    assert_eq!(engine.positions(), [4, 2, 3, 4, 5, 6, 7, 8]);
    assert!(engine.set_positions([-1; MAX_JOINTS]));
    assert_eq!(engine.positions(), [-1; MAX_JOINTS]);
}

#[test]
fn start_with_nothing_queued_runs_dry_at_once() {
    let mut engine = StepEngine::<4>::new(timing(1_000_000, 2, 5));
    let mut pins = Recorder::default();
    engine.start(100);
    assert!(engine.is_running());
    let poll = engine.poll(50, &mut pins);
    assert_eq!(
        poll,
        Poll {
            next_deadline: None,
            segments_finished: 0,
            ran_dry: true
        }
    );
    assert!(!engine.is_running());
    assert_eq!(pins.calls, 0);
}

#[test]
fn push_refuses_when_full_and_hands_the_segment_back() {
    let mut engine = StepEngine::<3>::new(timing(1_000_000, 2, 5));
    assert_eq!(engine.free_slots(), 3);
    for k in 0..3 {
        assert!(engine.push(one_joint(100 + k, 0, 1)).is_ok());
    }
    assert_eq!(engine.free_slots(), 0);
    let extra = one_joint(999, 4, -2);
    assert_eq!(engine.push(extra), Err(extra));
    assert_eq!(engine.queued(), 3);
}

#[test]
fn start_while_running_is_a_no_op() {
    let timing = timing(1_000_000, 2, 5);
    let segments = [one_joint(500, 6, 5)];
    let mut engine = StepEngine::<2>::new(timing);
    let mut pins = Recorder::default();
    assert!(engine.push(segments[0]).is_ok());
    engine.start(1_000);
    engine.start(7_000);
    drive(
        &mut engine,
        &mut pins,
        990,
        &mut core::iter::empty(),
        || 0,
        u64::MAX,
        100,
    );
    Model::new(&segments, 1_000, 1_000_000).assert_exact(&pins);
}

#[test]
fn a_joint_idle_now_sets_its_direction_early() {
    let timing = timing(1_000_000, 2, 5);
    let segments = [one_joint(10_000, 0, 10), one_joint(1_000, 1, -5)];
    let (_, pins, _) = run_all::<4>(timing, &segments, 1_000, 10);
    let dir: Vec<&Event> = pins
        .events
        .iter()
        .filter(|e| e.joint == 1)
        .take(1)
        .collect();
    assert_eq!(
        dir,
        vec![&Event {
            tick: 990,
            joint: 1,
            edge: Edge::Dir(false)
        }],
        "joint 1 sets DIR at the first poll, 10 ms before it moves"
    );
    assert_eq!(pins.rises(1)[0], (11_200, false));
}

#[test]
fn zero_step_segments_poll_only_at_their_ends() {
    let timing = timing(2_999_999, 6, 15);
    let segments: Vec<Segment> = [10u32, 333, 1, 1_000_000]
        .iter()
        .map(|&duration_us| Segment {
            duration_us,
            steps: [0; MAX_JOINTS],
        })
        .collect();
    let (_, pins, outcome) = run_all::<4>(timing, &segments, 77, 7);
    let model = Model::new(&segments, 77, 2_999_999);
    assert_eq!(pins.calls, 0);
    let ticks: Vec<u64> = outcome.polls.iter().skip(1).map(|(t, _)| *t).collect();
    let mut ends = model.segment_ends.clone();
    // A 1 us segment at 2_999_999 Hz can be shorter than a tick... or not: dedup.
    ends.dedup();
    assert_eq!(ticks, ends);
    assert_finished_after_end(&model, &outcome);
    assert_eq!(outcome.dry_at, model.segment_ends.last().copied());
}

#[test]
fn max_step_rate_leaves_room_for_width_and_low_time() {
    // The DIR setup does not limit the rate: it is waited for after a change only.
    let timing = StepTiming {
        step_low_ticks: 30,
        ..timing(10_000_000, 20, 50)
    };
    assert_eq!(timing.min_pulse_period_ticks(), 50);
    assert_eq!(timing.max_step_rate_hz(), 200_000);
    // TMC-class timing at 200 MHz: 100 ns high, 100 ns low.
    let tmc = StepTiming {
        tick_hz: 200_000_000,
        pulse_width_ticks: 20,
        dir_setup_ticks: 4,
        step_low_ticks: 20,
    };
    assert_eq!(tmc.max_step_rate_hz(), 5_000_000);
    let zero = StepTiming {
        tick_hz: 1_000_000,
        pulse_width_ticks: 0,
        dir_setup_ticks: 0,
        step_low_ticks: 0,
    };
    assert_eq!(zero.min_pulse_period_ticks(), 2);
    assert_eq!(zero.max_step_rate_hz(), 500_000);
    assert_eq!(StepEngine::<1>::new(timing).timing(), timing);
}

#[test]
fn poll_while_idle_does_nothing() {
    let mut engine = StepEngine::<2>::new(timing(1_000_000, 2, 5));
    let mut pins = Recorder::default();
    assert!(engine.push(one_joint(100, 0, 1)).is_ok());
    assert_eq!(engine.poll(1_000, &mut pins), Poll::default());
    assert_eq!(pins.calls, 0);
    assert_eq!(engine.queued(), 1, "segments wait for start");
}

#[test]
fn zero_length_segment_pulses_come_late_but_all_come() {
    let timing = timing(1_000_000, 2, 5);
    let segments = [
        one_joint(0, 0, 5),
        one_joint(100, 0, 1),
        Segment {
            duration_us: 0,
            steps: [0; MAX_JOINTS],
        },
    ];
    let (engine, pins, outcome) = run_all::<4>(timing, &segments, 1_000, 10);
    Model::new(&segments, 1_000, 1_000_000).assert_complete_in_order(&pins);
    pins.check_timing(&timing);
    assert_eq!(engine.positions()[0], 6);
    assert_eq!(engine.late_pulses(), 4, "the first of the five is on time");
    assert_eq!(outcome.segments_finished(), 3);
}

#[test]
fn extreme_values_do_not_panic() {
    // Largest durations, step counts and timings: a few polls, then stop.
    for timing in [
        timing(u32::MAX, u32::MAX, u32::MAX),
        timing(0, 0, 0),
        timing(1, 1, 0),
        timing(10_000_000, 20, 50),
    ] {
        let mut engine = StepEngine::<4>::new(timing);
        let mut pins = Recorder::default();
        for steps in [i32::MIN, i32::MAX, 1, -1] {
            let segment = Segment {
                duration_us: u32::MAX,
                steps: [steps; MAX_JOINTS],
            };
            assert!(engine.push(segment).is_ok());
        }
        assert!(engine.set_positions([i32::MAX; MAX_JOINTS]));
        engine.start(u64::from(u32::MAX));
        let mut now = 0;
        for _ in 0..1_000 {
            pins.now = now;
            match engine.poll(now, &mut pins).next_deadline {
                Some(deadline) => now = deadline,
                None => break,
            }
        }
        pins.stopping = true;
        engine.stop(&mut pins);
        assert_eq!(pins.step_high, [false; MAX_JOINTS]);
        pins.check_timing(&timing);
        // Positions wrap rather than panic; they still follow the emitted pulses.
        let moved = pins.signed_pulses();
        for (position, moved) in engine.positions().iter().zip(moved) {
            assert_eq!(*position, i32::MAX.wrapping_add(moved));
        }
    }
}
