//! `StepStreams::init_in_place` builds the same streams as `StepStreams::new`: the same
//! state (every field, through `Debug`), and the same outputs (buffers, preludes, refill
//! results, DIR changes, positions, unplayed pulses) after the same pushes, primes,
//! refills, stops and restarts. The slot is filled with junk first, so a field the in-place
//! constructor forgot to write shows up as a difference.

use core::mem::MaybeUninit;

use arm_step::{
    JointBuffer, MAX_JOINTS, NUCLEO_STEP_TIMER_MAX_PERIOD_TICKS, PRELUDE, PulsePeriod, Refill,
    Segment, StepStreams, StepTiming, StreamsSlot,
};
use proptest::prelude::*;

mod common;

use common::BOARD_TIMING as BOARD;

/// The board's buffer halves (64 periods) and a queue of 32 segments.
const HALF: usize = 64;
const QUEUE: usize = 32;

type Streams = StepStreams<QUEUE, HALF>;
type Prelude = [[PulsePeriod; PRELUDE]; MAX_JOINTS];

/// `StepStreams::new`, on the heap (as sim-host keeps them).
fn by_value(timing: StepTiming, max_period_ticks: [u32; MAX_JOINTS]) -> Box<Streams> {
    Box::new(StepStreams::new(timing, max_period_ticks))
}

/// A heap slot filled with `junk`, with streams built in it by `init_in_place`.
fn in_place(
    timing: StepTiming,
    max_period_ticks: [u32; MAX_JOINTS],
    junk: u8,
) -> Box<MaybeUninit<Streams>> {
    let mut slot = Box::<Streams>::new_uninit();
    // SAFETY: writes bytes into the slot's own storage (a MaybeUninit may hold any bytes).
    unsafe {
        slot.as_mut_ptr()
            .cast::<u8>()
            .write_bytes(junk, size_of::<Streams>())
    };
    let streams = StepStreams::init_in_place(&mut slot, timing, max_period_ticks);
    // The returned reference is the slot's value.
    assert!(core::ptr::eq(streams, slot.as_ptr()));
    slot
}

/// The value `init_in_place` wrote (it returned after writing every field).
fn built(slot: &mut MaybeUninit<Streams>) -> &mut Streams {
    // SAFETY: `in_place` ran `init_in_place` on this slot, which initialises it.
    unsafe { slot.assume_init_mut() }
}

/// Every field, as `Debug` prints it.
fn state(streams: &Streams) -> String {
    format!("{streams:?}")
}

/// One side of the comparison: its streams, preludes and buffers, and what it returned.
struct Side<'a> {
    streams: &'a mut Streams,
    prelude: Prelude,
    buffers: Vec<JointBuffer<HALF>>,
    log: Vec<String>,
}

impl<'a> Side<'a> {
    fn new(streams: &'a mut Streams) -> Self {
        Side {
            streams,
            prelude: [[PulsePeriod::ZERO; PRELUDE]; MAX_JOINTS],
            buffers: (0..MAX_JOINTS).map(|_| JointBuffer::ZERO).collect(),
            log: Vec::new(),
        }
    }

    fn push(&mut self, segments: &[Segment]) {
        for segment in segments {
            let pushed = self.streams.producer().push(*segment);
            self.log.push(format!("push {pushed:?}"));
        }
    }

    fn prime(&mut self, at_tick: u64) {
        let mut it = self.buffers.iter_mut();
        let mut all: [&mut JointBuffer<HALF>; MAX_JOINTS] =
            core::array::from_fn(|_| it.next().expect("eight buffers"));
        let primed: Refill = self.streams.prime(at_tick, &mut self.prelude, &mut all);
        self.log
            .push(format!("prime {primed:?} prelude {:?}", self.prelude));
    }

    /// `rounds` refills of every joint, halves alternating, then the DIR changes up to the
    /// producer's furthest point (popped) and the unplayed pulses from a few positions.
    fn refill(&mut self, rounds: usize) {
        for round in 0..rounds {
            let half = round % 2;
            for joint in 0..MAX_JOINTS {
                let periods = &mut self.buffers[joint].periods[half];
                let refill = self.streams.refill(joint, half, periods);
                self.log
                    .push(format!("refill {joint} {half} {refill:?} {periods:?}"));
            }
        }
        for joint in 0..MAX_JOINTS {
            while let Some(change) = self.streams.next_dir_change(joint) {
                self.log.push(format!("dir {joint} {change:?}"));
                self.streams.pop_dir_change(joint);
            }
            for (first, other) in [(None, false), (Some(0), false), (Some(HALF + 3), true)] {
                let unplayed =
                    self.streams
                        .unplayed_steps(joint, &self.buffers[joint], first, other);
                self.log.push(format!("unplayed {joint} {unplayed}"));
            }
            let evicted = self
                .streams
                .unplayed_evicted(joint, &self.buffers[joint], 1);
            self.log.push(format!("evicted {joint} {evicted}"));
        }
        let producer = self.streams.producer_ref();
        self.log.push(format!(
            "positions {:?} queued {} end {:?}",
            producer.positions(),
            producer.queued(),
            producer.run_end_tick()
        ));
    }

    /// A stop (at a different period per joint): the unplayed pulses taken back.
    fn stop(&mut self) {
        for joint in 0..MAX_JOINTS {
            let buffer = &self.buffers[joint];
            self.streams
                .unwind(joint, buffer, Some(joint * 5), joint % 2 == 0);
        }
        self.streams.producer().stop();
        self.streams.clear_dir_changes();
        self.log.push(format!(
            "stopped {:?}",
            self.streams.producer_ref().positions()
        ));
    }
}

/// Runs the same script on streams from `new` and from `init_in_place` and compares all
/// they returned and their whole state after each step.
fn same_behaviour(timing: StepTiming, max_period_ticks: [u32; MAX_JOINTS], runs: &[Vec<Segment>]) {
    let mut reference = by_value(timing, max_period_ticks);
    let mut slot = in_place(timing, max_period_ticks, 0xA5);
    assert_eq!(state(&reference), state(built(&mut slot)));
    let mut a = Side::new(&mut reference);
    let mut b = Side::new(built(&mut slot));
    let mut at_tick = 1_000;
    for segments in runs {
        for side in [&mut a, &mut b] {
            side.push(segments);
            side.prime(at_tick);
            side.refill(6);
        }
        assert_eq!(a.log, b.log);
        assert_eq!(state(a.streams), state(b.streams));
        for side in [&mut a, &mut b] {
            side.stop();
        }
        assert_eq!(a.log, b.log);
        assert_eq!(state(a.streams), state(b.streams));
        at_tick += 7_919;
    }
    for joint in 0..MAX_JOINTS {
        assert_eq!(a.buffers[joint].periods, b.buffers[joint].periods);
    }
}

fn segment(duration_us: u32, steps: [i32; MAX_JOINTS]) -> Segment {
    Segment { duration_us, steps }
}

#[test]
fn in_place_state_is_new_state_whatever_the_slot_held() {
    let reference = state(&by_value(BOARD, NUCLEO_STEP_TIMER_MAX_PERIOD_TICKS));
    for junk in [0x00, 0xFF, 0x5A] {
        let mut slot = in_place(BOARD, NUCLEO_STEP_TIMER_MAX_PERIOD_TICKS, junk);
        assert_eq!(
            state(built(&mut slot)),
            reference,
            "slot filled with {junk:#x}"
        );
    }
    // A timing whose derived fields (gcd, scales, the raised timer ranges) differ.
    let odd = StepTiming {
        tick_hz: 84_000_007,
        pulse_width_ticks: 1,
        dir_setup_ticks: 3,
        step_low_ticks: 0,
    };
    let mut slot = in_place(odd, [1; MAX_JOINTS], 0xC3);
    assert_eq!(
        state(built(&mut slot)),
        state(&by_value(odd, [1; MAX_JOINTS]))
    );
}

#[test]
fn in_place_streams_refill_like_new_ones() {
    let reversal = [
        segment(2_000, [40, -40, 3, 0, 100, -1, 7, 250]),
        segment(1_500, [-40, 40, -3, 0, -100, 1, 7, -250]),
        segment(50_000, [0, 0, 0, 0, 0, 0, 0, 0]),
        segment(800, [400, 1, -2, 3, -4, 5, -6, 7]),
    ];
    let long = [
        segment(3_000_000, [5, -5, 1_000, -1_000, 0, 2, 0, 60_000]),
        segment(90, [1, 1, 1, 1, 1, 1, 1, 1]),
    ];
    same_behaviour(
        BOARD,
        NUCLEO_STEP_TIMER_MAX_PERIOD_TICKS,
        &[reversal.to_vec(), long.to_vec(), reversal.to_vec()],
    );
}

/// A `StreamsSlot` (a static's place for the streams, as the NUCLEO and the QEMU board keep
/// them) holds nothing and takes no segment until `init`; after `init` it holds the same
/// streams as `new` (once: a second `init` changes nothing). That an empty one is all zero
/// bytes, so `.bss`, is what `scripts/fw-size.sh` checks (`.data` stays small).
#[test]
fn a_streams_slot_is_empty_until_init_then_holds_new_streams() {
    let mut slot = Box::new(StreamsSlot::<QUEUE, HALF>::EMPTY);
    assert!(slot.get().is_none());
    assert_eq!(slot.queued(), 0);
    let first = segment(1_000, [10, 0, 0, 0, 0, 0, 0, 0]);
    assert_eq!(slot.push(first), Err(first), "no streams yet: given back");

    slot.init(BOARD, NUCLEO_STEP_TIMER_MAX_PERIOD_TICKS);
    let fresh = by_value(BOARD, NUCLEO_STEP_TIMER_MAX_PERIOD_TICKS);
    assert_eq!(state(slot.get().expect("built")), state(&fresh));
    assert_eq!(slot.push(first), Ok(()));
    assert_eq!(slot.queued(), 1);
    slot.init(BOARD, NUCLEO_STEP_TIMER_MAX_PERIOD_TICKS);
    assert_eq!(slot.queued(), 1, "a second init keeps the streams");
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]

    /// Random trajectories (reversals, idle joints, full queues) and timer ranges.
    #[test]
    fn in_place_streams_behave_like_new_ones(
        runs in prop::collection::vec(
            prop::collection::vec(
                (1u32..20_000, prop::array::uniform8(-300i32..300)),
                1..(QUEUE + 4),
            ),
            1..4,
        ),
        max_period in prop::array::uniform8(prop_oneof![Just(1u32 << 16), Just(u32::MAX), 1u32..5_000]),
    ) {
        let runs: Vec<Vec<Segment>> = runs
            .into_iter()
            .map(|run| run.into_iter().map(|(d, s)| segment(d, s)).collect())
            .collect();
        same_behaviour(BOARD, max_period, &runs);
    }
}
