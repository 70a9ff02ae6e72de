//! Issue 20: every timer period the step producer writes for a board can be reloaded by the
//! board's step DMA in time. A period's 3-word burst (ARR, RCR, CCR1) must land before the
//! next update event; eight streams on DMA2 can request at once. The review found 40-tick
//! (0.2 us) periods routine with `tmc-drivers` (100 ns high + 100 ns low), where a pulse is
//! then lost or repeated on silicon. Random trajectories at each profile's limits, through
//! the producer as the boards fill it (halves, pushes during the run, reversals, idle
//! joints, tiny and long segments): no period shorter than the profile's floor.

use arm_core::profile::{ALL, BoardProfile};
use arm_step::{MAX_JOINTS, PulsePeriod, PulseProducer, Segment};

/// xorshift64*.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }
    fn range(&mut self, lo: u64, hi: u64) -> u64 {
        lo + self.next() % (hi - lo + 1)
    }
}

/// (shortest period written, pulses written) over `cases` random runs on `profile`.
fn shortest_period(profile: &BoardProfile, cases: usize, seed: u64) -> (u64, u64) {
    let timing = profile.step_timing();
    let rate = u64::from(profile.max_step_rate_hz());
    let half = profile.step_buffer_half;
    let mut rng = Rng(seed);
    let (mut shortest, mut pulses) = (u64::MAX, 0u64);
    for _ in 0..cases {
        let mut producer = PulseProducer::<64>::new(timing, profile.step_timer_max_period_ticks);
        let n = rng.range(1, 60) as usize;
        let mut pending: Vec<Segment> = (0..n)
            .map(|_| {
                // Tiny segments (1-60 us) and ordinary ones, at up to the per-joint limit.
                let d = if rng.next().is_multiple_of(2) {
                    rng.range(1, 60)
                } else {
                    rng.range(100, 20_000)
                };
                let mut steps = [0i32; MAX_JOINTS];
                for s in &mut steps {
                    let most = (d * rate / 1_000_000).max(1);
                    let v = rng.range(0, most) as i32;
                    *s = match rng.next() % 4 {
                        0 => 0,
                        1 => -v,
                        _ => v,
                    };
                }
                Segment {
                    duration_us: d as u32,
                    steps,
                }
            })
            .collect();
        let first = rng.range(1, n as u64) as usize;
        for s in pending.drain(..first) {
            assert!(producer.push(s).is_ok());
        }
        producer.start(1_000, 0);
        let mut periods = vec![PulsePeriod::ZERO; half];
        let mut signs = vec![0i8; half];
        let mut idle = [false; MAX_JOINTS];
        let mut rounds = 0;
        while !(idle.iter().all(|&i| i) && pending.is_empty()) {
            rounds += 1;
            assert!(rounds < 1_000_000, "the producer never drained");
            // Segments keep coming while the run goes on, as the trajectory task pushes.
            if !pending.is_empty() && rng.next().is_multiple_of(3) {
                assert!(producer.push(pending.remove(0)).is_ok());
            }
            for (joint, idle) in idle.iter_mut().enumerate() {
                let filled = producer.fill(joint, &mut periods, &mut signs, &mut |_, _| {});
                for p in &periods {
                    shortest = shortest.min(p.ticks());
                    pulses += u64::from(p.high != 0);
                }
                *idle = filled.idle;
            }
        }
    }
    (shortest, pulses)
}

#[test]
fn no_profile_writes_a_period_its_step_dma_cannot_reload() {
    for (i, profile) in ALL.iter().enumerate() {
        let floor = profile.min_dma_period_ticks();
        let (shortest, pulses) = shortest_period(profile, 60, 0x5eed_0000 + i as u64);
        println!(
            "{}: shortest period {shortest} ticks over {pulses} pulses (floor {floor})",
            profile.name
        );
        assert!(pulses > 100_000, "{}: the runs made pulses", profile.name);
        assert!(
            shortest >= floor,
            "{}: a {shortest}-tick period, below the DMA's {floor}",
            profile.name
        );
    }
}
