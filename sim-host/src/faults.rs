//! Network fault injection: loss, duplication and reordering of datagrams, deterministic
//! for a seed.
//!
//! Every datagram belongs to a *stream*: its direction and its tag byte (ACKs, LOCATION
//! reports, PENDING frames, ...). Each stream draws from its own generator, seeded from
//! `--seed`, the direction and the tag. So the fate of the n-th ACK depends only on the
//! seed and n, not on how many periodic LOCATION reports happened to be sent in between:
//! a run is reproducible even though reports are timed by the clock.
//!
//! Per datagram, three numbers are drawn (always three, so the streams stay aligned):
//! lost with probability `loss`; else sent twice with probability `dup`; else, when no
//! datagram of the stream is held back already, held back with probability `reorder` and
//! delivered right after the stream's next datagram.

use std::collections::HashMap;

/// Fault probabilities and the seed.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct FaultConfig {
    /// Probability that a datagram is dropped.
    pub loss: f64,
    /// Probability that a datagram is delivered twice.
    pub dup: f64,
    /// Probability that a datagram is held back and delivered after the next one.
    pub reorder: f64,
    /// Seed of the generators.
    pub seed: u64,
}

impl FaultConfig {
    /// Whether any fault is enabled.
    pub fn is_active(&self) -> bool {
        self.loss > 0.0 || self.dup > 0.0 || self.reorder > 0.0
    }
}

/// Which way a datagram travels.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Direction {
    /// Host to controller.
    Received,
    /// Controller to host.
    Sent,
}

/// What the injector did to one datagram.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Fate {
    /// Passed unchanged.
    Passed,
    /// Dropped.
    Lost,
    /// Delivered twice.
    Duplicated,
    /// Held back until the stream's next datagram.
    HeldBack,
}

/// Counts of what was done, for the log.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FaultStats {
    /// Datagrams seen.
    pub seen: u64,
    /// Dropped.
    pub lost: u64,
    /// Sent twice.
    pub duplicated: u64,
    /// Held back and reordered.
    pub reordered: u64,
}

/// SplitMix64: tiny, fast, and good enough to pick faults.
#[derive(Clone, Debug)]
struct SplitMix64(u64);

impl SplitMix64 {
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    fn next_f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
}

struct Stream<T> {
    rng: SplitMix64,
    held: Option<T>,
}

/// Applies [`FaultConfig`] to datagrams of type `T` (the bytes, plus whatever travels
/// with them, such as the destination).
pub struct FaultInjector<T> {
    config: FaultConfig,
    streams: HashMap<(Direction, u8), Stream<T>>,
    stats: FaultStats,
}

impl<T: Clone> FaultInjector<T> {
    /// An injector with this configuration.
    pub fn new(config: FaultConfig) -> Self {
        FaultInjector {
            config,
            streams: HashMap::new(),
            stats: FaultStats::default(),
        }
    }

    /// What was done so far.
    pub fn stats(&self) -> FaultStats {
        self.stats
    }

    /// Passes `datagram` (of stream `direction`, `tag`) through the faults; `deliver` is
    /// called for each datagram to deliver now, in order.
    pub fn apply(
        &mut self,
        direction: Direction,
        tag: u8,
        datagram: T,
        mut deliver: impl FnMut(T),
    ) -> Fate {
        self.stats.seen += 1;
        if !self.config.is_active() {
            deliver(datagram);
            return Fate::Passed;
        }
        let seed = self.config.seed;
        let stream = self
            .streams
            .entry((direction, tag))
            .or_insert_with(|| Stream {
                rng: SplitMix64(stream_seed(seed, direction, tag)),
                held: None,
            });
        let lost = stream.rng.next_f64() < self.config.loss;
        let duplicated = stream.rng.next_f64() < self.config.dup;
        let reordered = stream.rng.next_f64() < self.config.reorder;
        if lost {
            self.stats.lost += 1;
            return Fate::Lost;
        }
        if reordered && stream.held.is_none() {
            self.stats.reordered += 1;
            if duplicated {
                // The copy goes now, the original later: still a reordering.
                self.stats.duplicated += 1;
                deliver(datagram.clone());
            }
            stream.held = Some(datagram);
            return Fate::HeldBack;
        }
        let held = stream.held.take();
        if duplicated {
            self.stats.duplicated += 1;
            deliver(datagram.clone());
        }
        deliver(datagram);
        if let Some(held) = held {
            deliver(held);
        }
        if duplicated {
            Fate::Duplicated
        } else {
            Fate::Passed
        }
    }
}

fn stream_seed(seed: u64, direction: Direction, tag: u8) -> u64 {
    let dir = match direction {
        Direction::Received => 0x5245_4356u64,
        Direction::Sent => 0x5345_4e54u64,
    };
    let mut mix = SplitMix64(seed ^ (dir << 16) ^ u64::from(tag));
    mix.next_u64()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(config: FaultConfig, tags: &[u8]) -> Vec<u32> {
        let mut injector = FaultInjector::new(config);
        let mut delivered = Vec::new();
        for (i, &tag) in tags.iter().enumerate() {
            injector.apply(Direction::Received, tag, i as u32, |d| delivered.push(d));
        }
        delivered
    }

    #[test]
    fn no_faults_passes_everything_in_order() {
        let tags = [1u8; 100];
        assert_eq!(
            run(FaultConfig::default(), &tags),
            (0..100).collect::<Vec<_>>()
        );
    }

    #[test]
    fn same_seed_same_fates_different_seed_different() {
        let config = FaultConfig {
            loss: 0.2,
            dup: 0.2,
            reorder: 0.2,
            seed: 42,
        };
        let tags: Vec<u8> = (0..500).map(|i| (i % 3) as u8).collect();
        let a = run(config, &tags);
        assert_eq!(a, run(config, &tags));
        assert_ne!(a, run(FaultConfig { seed: 43, ..config }, &tags));
    }

    #[test]
    fn probabilities_are_roughly_honoured() {
        let config = FaultConfig {
            loss: 0.1,
            dup: 0.0,
            reorder: 0.0,
            seed: 7,
        };
        let delivered = run(config, &vec![0u8; 10_000]);
        let lost = 10_000 - delivered.len();
        assert!((700..1300).contains(&lost), "lost {lost}");
    }

    #[test]
    fn a_stream_is_unaffected_by_other_streams() {
        let config = FaultConfig {
            loss: 0.3,
            dup: 0.3,
            reorder: 0.3,
            seed: 9,
        };
        let only_a = run(config, &[5u8; 200]);
        // The same 200 datagrams of tag 5, interleaved with datagrams of tag 6.
        let mut injector = FaultInjector::new(config);
        let mut delivered = Vec::new();
        for i in 0..200u32 {
            injector.apply(Direction::Received, 5, i, |d| delivered.push(d));
            injector.apply(Direction::Received, 6, 1000 + i, |_| {});
        }
        assert_eq!(only_a, delivered);
    }

    #[test]
    fn reordered_datagram_follows_the_next() {
        let config = FaultConfig {
            loss: 0.0,
            dup: 0.0,
            reorder: 1.0,
            seed: 1,
        };
        // Always reorder: 0 held, 1 delivered then 0, 2 held, 3 then 2 ...
        assert_eq!(run(config, &[0u8; 4]), vec![1, 0, 3, 2]);
    }
}
