//! Cost of `StepEngine::poll` per step pulse: the fake tick clock jumps straight to each
//! deadline, pins do nothing (but are not optimised away). Throughput is in steps, so
//! criterion's "thrpt" is steps per second: ns per step = 1e9 / thrpt.

use std::hint::black_box;

use arm_step::{
    JointBuffer, JointMask, MAX_JOINTS, NUCLEO_STEP_TIMER_MAX_PERIOD_TICKS, PRELUDE, PulsePeriod,
    Segment, StepEngine, StepPins, StepStreams, StepTiming,
};
use criterion::{BatchSize, Criterion, Throughput, criterion_group, criterion_main};

/// Segments per run: all held at once so that the run measures `poll` alone.
const SEGMENTS: usize = 100;

/// Pins that only keep the last masks (through `black_box`).
struct SinkPins(u32);

impl StepPins for SinkPins {
    fn set_direction(&mut self, joint: usize, positive: bool) {
        self.0 ^= black_box(joint as u32) ^ u32::from(positive);
    }
    fn step_high(&mut self, joints: JointMask) {
        self.0 ^= u32::from(black_box(joints));
    }
    fn step_low(&mut self, joints: JointMask) {
        self.0 ^= u32::from(black_box(joints)) << 8;
    }
}

/// Board timing: 10 MHz timer, 2 us pulses, 5 us direction setup (max 142 kHz).
const TIMING: StepTiming = StepTiming {
    tick_hz: 10_000_000,
    pulse_width_ticks: 20,
    dir_setup_ticks: 50,
    step_low_ticks: 20,
};

/// 1 ms segments, direction reversing each segment, `steps[j]` pulses per joint.
fn trajectory(steps: [i32; MAX_JOINTS]) -> Vec<Segment> {
    (0..SEGMENTS)
        .map(|k| {
            let sign = if k % 2 == 0 { 1 } else { -1 };
            Segment {
                duration_us: 1_000,
                steps: steps.map(|n| n * sign),
            }
        })
        .collect()
}

fn loaded(segments: &[Segment]) -> StepEngine<SEGMENTS> {
    let mut engine = StepEngine::new(TIMING);
    for segment in segments {
        assert!(engine.push(*segment).is_ok());
    }
    engine
}

/// Runs the whole queue; returns the positions so nothing is dead code.
fn run(mut engine: StepEngine<SEGMENTS>) -> [i32; MAX_JOINTS] {
    let mut pins = SinkPins(0);
    engine.start(1_000);
    let mut now = 0;
    loop {
        let poll = engine.poll(now, &mut pins);
        match poll.next_deadline {
            Some(deadline) => now = deadline,
            None => break,
        }
    }
    black_box(pins.0);
    engine.positions()
}

/// Periods per DMA buffer half, as on the board.
const HALF: usize = 64;

/// The producer with every segment queued, and the buffers it fills.
struct Producing {
    streams: Box<StepStreams<SEGMENTS, HALF>>,
    buffers: Box<[JointBuffer<HALF>; MAX_JOINTS]>,
}

fn producing(segments: &[Segment]) -> Producing {
    let mut streams = Box::new(StepStreams::new(TIMING, NUCLEO_STEP_TIMER_MAX_PERIOD_TICKS));
    for segment in segments {
        assert!(streams.producer().push(*segment).is_ok());
    }
    Producing {
        streams,
        buffers: Box::new([JointBuffer::ZERO; MAX_JOINTS]),
    }
}

/// The board's step path without the hardware: prime, then refill every joint's halves
/// in turn until every pulse is written (the DMA interrupts' work, in a fixed order).
fn produce(mut p: Producing) -> [i32; MAX_JOINTS] {
    let mut prelude = [[PulsePeriod::ZERO; PRELUDE]; MAX_JOINTS];
    {
        let [b0, b1, b2, b3, b4, b5, b6, b7] = &mut *p.buffers;
        p.streams
            .prime(1_000, &mut prelude, &mut [b0, b1, b2, b3, b4, b5, b6, b7]);
    }
    let mut half = 0;
    while p.streams.producer_ref().run_end_tick().is_none() {
        for (joint, buffer) in p.buffers.iter_mut().enumerate() {
            black_box(p.streams.refill(joint, half, &mut buffer.periods[half]));
        }
        half ^= 1;
    }
    // Close every joint's last pulse period.
    for (joint, buffer) in p.buffers.iter_mut().enumerate() {
        p.streams.refill(joint, half, &mut buffer.periods[half]);
    }
    p.streams.producer().end_run();
    p.streams.producer_ref().positions()
}

/// One benchmark per case: `setup` (not measured) then `play`, which must emit every step
/// (checked once before measuring), in steps per second.
fn group<S>(
    c: &mut Criterion,
    name: &str,
    cases: &[(&str, [i32; MAX_JOINTS])],
    setup: fn(&[Segment]) -> S,
    play: fn(S) -> [i32; MAX_JOINTS],
) {
    let mut group = c.benchmark_group(name);
    for &(name, steps) in cases {
        let segments = trajectory(steps);
        let total: u64 = segments
            .iter()
            .flat_map(|s| s.steps)
            .map(|n| u64::from(n.unsigned_abs()))
            .sum();
        // Sanity: the run emits every step.
        assert_eq!(play(setup(&segments)), [0; MAX_JOINTS]);
        group.throughput(Throughput::Elements(total));
        group.bench_function(name, |b| {
            b.iter_batched(|| setup(&segments), play, BatchSize::SmallInput)
        });
    }
    group.finish();
}

fn bench(c: &mut Criterion) {
    let cases: [(&str, [i32; MAX_JOINTS]); 3] = [
        ("1 joint", [100, 0, 0, 0, 0, 0, 0, 0]),
        ("8 joints in step", [100; MAX_JOINTS]),
        (
            "8 joints, distinct rates",
            [100, 97, 89, 83, 79, 73, 71, 67],
        ),
    ];
    group(c, "poll per step", &cases, loaded, run);
    group(c, "producer per step", &cases, producing, produce);
}

criterion_group!(benches, bench);
criterion_main!(benches);
