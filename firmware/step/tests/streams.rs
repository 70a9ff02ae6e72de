//! StepStreams as the board's DMA plays them: after a stop at any period, the positions
//! less the unplayed pulses are exactly the pulses of the periods that started.

use arm_step::{JointBuffer, MAX_JOINTS, PRELUDE, PulsePeriod, Segment, StepStreams, StepTiming};
use proptest::prelude::*;

const HALF: usize = 8;
const QUEUE: usize = 16;

const TIMING: StepTiming = StepTiming {
    tick_hz: 10_000_000,
    pulse_width_ticks: 20,
    dir_setup_ticks: 50,
    step_low_ticks: 20,
};

/// Streams with `segments` queued, and zeroed preludes and buffers for them.
fn queued(segments: &[Segment]) -> (Streams, Prelude, Vec<JointBuffer<HALF>>) {
    let mut streams = Box::new(StepStreams::<QUEUE, HALF>::new(
        TIMING,
        [1 << 16; MAX_JOINTS],
    ));
    for segment in segments {
        assert!(streams.producer().push(*segment).is_ok());
    }
    let prelude = [[PulsePeriod::ZERO; PRELUDE]; MAX_JOINTS];
    let buffers = (0..MAX_JOINTS).map(|_| JointBuffer::ZERO).collect();
    (streams, prelude, buffers)
}

type Streams = Box<StepStreams<QUEUE, HALF>>;
type Prelude = [[PulsePeriod; PRELUDE]; MAX_JOINTS];

/// Plays the streams period by period (refilling a half when the player enters the other
/// one, as the DMA interrupts do) and stops after `stop_after` periods of every joint.
fn stop_after(segments: &[Segment], stop_after: u64) -> ([i32; MAX_JOINTS], [i32; MAX_JOINTS]) {
    let (mut streams, mut prelude, mut buffers) = queued(segments);
    let mut played = [0i32; MAX_JOINTS];
    {
        let mut it = buffers.iter_mut();
        let mut all: [&mut JointBuffer<HALF>; MAX_JOINTS] =
            core::array::from_fn(|_| it.next().expect("eight buffers"));
        streams.prime(100, &mut prelude, &mut all);
    }
    let mut first_unplayed = [None; MAX_JOINTS];
    for j in 0..MAX_JOINTS {
        for n in 0..stop_after {
            let period = if n < PRELUDE as u64 {
                prelude[j][n as usize]
            } else {
                let e = ((n - PRELUDE as u64) % (2 * HALF) as u64) as usize;
                buffers[j].periods[e / HALF][e % HALF]
            };
            // Entering a new half frees the one before.
            if n >= (PRELUDE + HALF) as u64 && (n - PRELUDE as u64).is_multiple_of(HALF as u64) {
                let entered = ((n - PRELUDE as u64) / HALF as u64 % 2) as usize;
                let freed = 1 - entered;
                let buffer = &mut buffers[j];
                streams.refill(j, freed, &mut buffer.periods[freed]);
            }
            if period.high != 0 {
                played[j] += 1;
            }
        }
        first_unplayed[j] = (stop_after >= PRELUDE as u64)
            .then(|| ((stop_after - PRELUDE as u64) % (2 * HALF) as u64) as usize);
    }
    // Stopped right where a half begins: the half before was played and its refill (due
    // when this period starts) has not happened.
    let stale = stop_after >= (PRELUDE + HALF) as u64
        && (stop_after - PRELUDE as u64).is_multiple_of(HALF as u64);
    let mut positions = streams.producer_ref().positions();
    for j in 0..MAX_JOINTS {
        positions[j] -= streams.unplayed_steps(j, &buffers[j], first_unplayed[j], stale);
    }
    (positions, played)
}

/// As `stop_after`, with the board's DMA: at the start of period `n` the stream loads
/// period `n + 1` into the timer's preload register, and when that is the last of a
/// half, the half is refilled at once (its interrupt). A stop after `stop` periods
/// started leaves period `stop` in the preload register: unplayed, though its half may
/// have been refilled over it.
fn board_stop_after(segments: &[Segment], stop: u64) -> ([i32; MAX_JOINTS], [i32; MAX_JOINTS]) {
    let (mut streams, mut prelude, mut buffers) = queued(segments);
    {
        let mut it = buffers.iter_mut();
        let mut all: [&mut JointBuffer<HALF>; MAX_JOINTS] =
            core::array::from_fn(|_| it.next().expect("eight buffers"));
        streams.prime(100, &mut prelude, &mut all);
    }
    let entry = |n: u64| ((n - PRELUDE as u64) % (2 * HALF) as u64) as usize;
    let mut played = [0i32; MAX_JOINTS];
    for j in 0..MAX_JOINTS {
        // The timer's active and preload registers.
        let mut active = prelude[j][0];
        let mut preload = prelude[j][1];
        for n in 0..stop {
            // Period n starts with what was loaded; period n + 1 goes to the preload
            // register (the DMA reads it from the buffer now).
            if n > 0 {
                active = preload;
                let e = entry(n + 1);
                preload = buffers[j].periods[e / HALF][e % HALF];
            }
            if active.high != 0 {
                played[j] += 1;
            }
            let loaded = n + 1;
            if n > 0 && loaded >= PRELUDE as u64 && entry(loaded) % HALF == HALF - 1 {
                let half = entry(loaded) / HALF;
                let buffer = &mut buffers[j];
                streams.refill(j, half, &mut buffer.periods[half]);
            }
        }
    }
    let mut positions = streams.producer_ref().positions();
    for j in 0..MAX_JOINTS {
        positions[j] -= if stop < PRELUDE as u64 {
            streams.unplayed_steps(j, &buffers[j], None, false)
                + if stop == 0 {
                    i32::from(prelude[j][0].high != 0)
                } else {
                    0
                }
        } else {
            let e = entry(stop);
            if e % HALF == HALF - 1 && stop >= 1 {
                streams.unplayed_evicted(j, &buffers[j], e / HALF)
            } else {
                streams.unplayed_steps(j, &buffers[j], Some(e), false)
            }
        };
    }
    (positions, played)
}

/// One segment per duration, each with the same `steps`.
fn segments(steps: [i32; MAX_JOINTS], durations: &[u32]) -> Vec<Segment> {
    durations
        .iter()
        .map(|&duration_us| Segment { duration_us, steps })
        .collect()
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

    /// One direction per joint (so the played count is the position): the position
    /// less the unplayed pulses equals the pulses of the periods that started, wherever
    /// the stop falls (across refills and half boundaries).
    #[test]
    fn positions_less_unplayed_are_the_played_pulses(
        steps in prop::array::uniform8(0i32..=40),
        durations in prop::collection::vec(50u32..=2_000, 1..=QUEUE),
        stop in 0u64..200,
    ) {
        let (positions, played) = stop_after(&segments(steps, &durations), stop);
        prop_assert_eq!(positions, played);
    }

    /// The same with the board's DMA timing: the period in the preload register is
    /// unplayed even when its half was refilled over it.
    #[test]
    fn board_positions_less_unplayed_are_the_played_pulses(
        steps in prop::array::uniform8(0i32..=40),
        durations in prop::collection::vec(50u32..=2_000, 1..=QUEUE),
        stop in 1u64..200,
    ) {
        let (positions, played) = board_stop_after(&segments(steps, &durations), stop);
        prop_assert_eq!(positions, played);
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 128, ..ProptestConfig::default() })]

    /// Issue 34: the board switches each STEP output from forced-inactive to PWM with the
    /// prelude's first period in the active registers (`load_joint`): a pulse there would
    /// rise at the switch, before the timers start together. The first period never has
    /// one, whatever the segments and wherever they start (tick 0 included), both
    /// directions; the board also checks it at each run's start (a run refused, logged).
    #[test]
    fn the_first_prelude_period_has_no_pulse(
        steps in prop::array::uniform8(-40i32..=40),
        durations in prop::collection::vec(50u32..=2_000, 1..=QUEUE),
        at_tick in prop_oneof![Just(0u64), 0u64..5_000],
    ) {
        let (mut streams, mut prelude, mut buffers) = queued(&segments(steps, &durations));
        let mut it = buffers.iter_mut();
        let mut all: [&mut JointBuffer<HALF>; MAX_JOINTS] =
            core::array::from_fn(|_| it.next().expect("eight buffers"));
        streams.prime(at_tick, &mut prelude, &mut all);
        for (j, p) in prelude.iter().enumerate() {
            prop_assert_eq!(p[0].high, 0, "joint {} prelude {:?}", j, p);
        }
    }
}
