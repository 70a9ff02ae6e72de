//! Property tests over random trajectories and timings.

mod common;

use arm_step::{MAX_JOINTS, Segment, StepEngine, StepTiming};
use common::*;
use proptest::prelude::*;

/// Random step timing: the usual tick rates (including one that is not a multiple of
/// 1 MHz) and any rate in between, pulse width and setup from the minimum up.
fn timing_strategy() -> impl Strategy<Value = StepTiming> {
    let tick_hz = prop_oneof![
        Just(1_000_000u32),
        Just(10_000_000),
        Just(3_000_000),
        Just(2_999_999),
        1_000_000u32..=20_000_000,
    ];
    (tick_hz, 1u32..=30, 0u32..=60).prop_map(|(tick_hz, pulse_width_ticks, dir_setup_ticks)| {
        StepTiming {
            tick_hz,
            pulse_width_ticks,
            dir_setup_ticks,
            // Room for the DIR setup between any two pulses: at the max rate even
            // reversals are on time.
            step_low_ticks: dir_setup_ticks,
        }
    })
}

/// Steps of one joint in a segment the engine can run on time: zero, exactly the max rate
/// (when that is a reasonable count), or anything in between, either sign.
fn joint_steps(max: i32) -> impl Strategy<Value = i32> {
    let cap = max.min(400);
    let at_max = if max <= 500 { max } else { cap };
    prop_oneof![
        2 => Just(0),
        2 => prop_oneof![Just(at_max), Just(-at_max)],
        3 => -cap..=cap,
    ]
}

/// Segments whose rates never exceed `timing.max_step_rate_hz()`, none shorter than a
/// pulse: a segment's ring slot is held until its last pulse falls, so a few segments all
/// shorter than one pulse can end, with the ring full, before a new one can be pushed, an
/// underrun by capacity (`found_by_the_soak.rs`; issue 19's soak found it with 4 slots:
/// 18, 2 and 8 us behind a 29 us pulse). The board's 256 slots of at least 1 us each
/// always outlast its 2.5 us pulse.
fn rate_limited(timing: StepTiming, count: usize) -> impl Strategy<Value = Vec<Segment>> {
    let pulse_us = u32::try_from(
        (u64::from(timing.pulse_width_ticks) * 1_000_000).div_ceil(u64::from(timing.tick_hz)),
    )
    .unwrap_or(u32::MAX)
    .max(1);
    let duration = prop_oneof![pulse_us..=200.max(pulse_us), pulse_us..=3_000];
    prop::collection::vec(duration, 1..=count).prop_flat_map(move |durations| {
        durations
            .into_iter()
            .map(|duration_us| {
                let max = (u64::from(timing.max_step_rate_hz()) * u64::from(duration_us)
                    / 1_000_000) as i32;
                prop::array::uniform8(joint_steps(max))
                    .prop_map(move |steps| Segment { duration_us, steps })
            })
            .collect::<Vec<_>>()
    })
}

/// Segments with any step counts, faster than the pins allow included.
fn unlimited(count: usize) -> impl Strategy<Value = Vec<Segment>> {
    let segment = (
        1u32..=2_000,
        prop::array::uniform8(prop_oneof![Just(0i32), -300i32..=300]),
    )
        .prop_map(|(duration_us, steps)| Segment { duration_us, steps });
    prop::collection::vec(segment, 1..=count)
}

fn case_with<S: Strategy<Value = Vec<Segment>>>(
    make: impl Fn(StepTiming) -> S,
) -> impl Strategy<Value = (StepTiming, Vec<Segment>, u64)> {
    timing_strategy().prop_flat_map(move |timing| (Just(timing), make(timing), 0u64..=1u64 << 40))
}

/// A latency source: xorshift from a seed, below `span` ticks.
fn latency(seed: u64, span: u64) -> impl FnMut() -> u64 {
    let mut state = seed | 1;
    move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state % span.max(1)
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]

    /// Within the max rate, streamed through a small queue: every pulse at the floor of
    /// its exact time, each segment's last pulse on its end tick, nothing late, positions
    /// exact, the run ends when the last pulse falls after the last end.
    #[test]
    fn rate_limited_trajectories_are_exact(
        (timing, segments, start) in case_with(|timing| rate_limited(timing, 24))
    ) {
        let lead = u64::from(timing.dir_setup_ticks) + 1;
        let start = start + lead;
        let mut engine = StepEngine::<4>::new(timing);
        let mut pins = Recorder::default();
        let mut feed = segments.iter().copied();
        engine.start(start);
        let outcome = drive(&mut engine, &mut pins, start - lead, &mut feed, || 0, u64::MAX, 10_000_000);
        let model = Model::new(&segments, start, timing.tick_hz);
        model.assert_exact(&pins);
        pins.check_timing(&timing);
        prop_assert_eq!(engine.late_pulses(), 0);
        prop_assert_eq!(engine.positions(), net_steps(&segments));
        prop_assert_eq!(outcome.segments_finished(), segments.len() as u64);

        // Each segment's last pulse sits on the segment's end tick.
        for joint in 0..MAX_JOINTS {
            let rises = pins.rises(joint);
            let mut emitted = 0;
            for (k, segment) in segments.iter().enumerate() {
                let n = segment.steps[joint].unsigned_abs() as usize;
                if n > 0 {
                    emitted += n;
                    prop_assert_eq!(rises[emitted - 1].0, model.segment_ends[k]);
                }
            }
        }
        // The run ends at the last end, or when the last pulse falls if that is later.
        let end = *model.segment_ends.last().unwrap_or(&start);
        let last_fall = pins
            .events
            .iter()
            .filter(|e| e.edge == Edge::Fall)
            .map(|e| e.tick)
            .max()
            .unwrap_or(0);
        let last_rise = (0..MAX_JOINTS).filter_map(|j| pins.rises(j).last().map(|r| r.0)).max();
        if let Some(rise) = last_rise {
            prop_assert_eq!(last_fall, rise + u64::from(timing.pulse_width_ticks));
        }
        prop_assert_eq!(outcome.dry_at, Some(end.max(last_fall)));
        prop_assert_eq!(pins.step_high, [false; MAX_JOINTS]);
    }

    /// Any step counts (over the max rate too) and any interrupt latency: every pulse is
    /// emitted once, in order, never before its ideal tick, with full pulse width, STEP low
    /// between pulses and DIR setup honoured; positions follow the emitted pulses.
    #[test]
    fn any_trajectory_with_latency_emits_every_pulse(
        (timing, segments, start) in case_with(|_| unlimited(12)),
        seed in any::<u64>(),
        spread in 0u64..=4,
    ) {
        let start = start + 1_000;
        let mut engine = StepEngine::<16>::new(timing);
        let mut pins = Recorder::default();
        let mut feed = segments.iter().copied();
        engine.start(start);
        let span = spread * timing.min_pulse_period_ticks();
        let outcome = drive(&mut engine, &mut pins, start - 1_000, &mut feed, latency(seed, span), u64::MAX, 10_000_000);
        prop_assert!(outcome.dry_at.is_some());
        let model = Model::new(&segments, start, timing.tick_hz);
        model.assert_complete_in_order(&pins);
        pins.check_timing(&timing);
        prop_assert_eq!(engine.positions(), net_steps(&segments));
        prop_assert_eq!(pins.signed_pulses(), net_steps(&segments));
        prop_assert_eq!(outcome.segments_finished(), segments.len() as u64);
        prop_assert_eq!(pins.step_high, [false; MAX_JOINTS]);
        if span == 0 && engine.late_pulses() == 0 {
            model.assert_exact(&pins);
        }
    }

    /// Stop at any moment: every STEP line low, idle, queue empty, and the positions are
    /// exactly the pulses emitted.
    #[test]
    fn stop_anywhere_keeps_the_emitted_pulses(
        (timing, segments, start) in case_with(|timing| rate_limited(timing, 8)),
        stop_permille in 0u64..=1_000,
        base in prop::array::uniform8(-1_000i32..=1_000),
    ) {
        let start = start + 100;
        let mut engine = StepEngine::<8>::new(timing);
        let mut pins = Recorder::default();
        prop_assert!(engine.set_positions(base));
        let mut feed = segments.iter().copied();
        engine.start(start);
        let model = Model::new(&segments, start, timing.tick_hz);
        let end = *model.segment_ends.last().unwrap_or(&start);
        let until = start + (end - start) * stop_permille / 1_000;
        drive(&mut engine, &mut pins, start - 100, &mut feed, || 0, until, 10_000_000);
        pins.stopping = true;
        engine.stop(&mut pins);
        prop_assert!(!engine.is_running());
        prop_assert_eq!(engine.free_slots(), 8);
        prop_assert_eq!(pins.step_high, [false; MAX_JOINTS]);
        let moved = pins.signed_pulses();
        let mut expected = base;
        for (position, moved) in expected.iter_mut().zip(moved) {
            *position += moved;
        }
        prop_assert_eq!(engine.positions(), expected);
        pins.check_timing(&timing);
    }
}
