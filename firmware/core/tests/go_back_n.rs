//! A host streaming a trajectory with go-back-N over a channel that loses, duplicates and
//! reorders datagrams (both ways): every point runs exactly once, in order.

mod common;

use common::*;
use proptest::prelude::*;
use protocol::{Command, MAX_JOINTS, Point, State, StatusCode, StatusFlags, Tag};

/// xorshift64*: the channel's and the engine's dice, seeded by proptest.
struct Dice(u64);

impl Dice {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
    fn below(&mut self, n: u64) -> u64 {
        self.next() % n.max(1)
    }
    fn chance(&mut self, percent: u64) -> bool {
        self.below(100) < percent
    }
}

/// A lossy, duplicating, reordering link: datagrams wait a random number of ticks.
struct Link {
    in_flight: Vec<(u64, Vec<u8>)>,
    loss: u64,
    dup: u64,
    max_delay: u64,
}

impl Link {
    fn send(&mut self, dice: &mut Dice, now: u64, bytes: Vec<u8>) {
        if dice.chance(self.loss) {
            return;
        }
        if dice.chance(self.dup) {
            let at = now + dice.below(self.max_delay + 1);
            self.in_flight.push((at, bytes.clone()));
        }
        let at = now + dice.below(self.max_delay + 1);
        self.in_flight.push((at, bytes));
    }
    /// Datagrams due at `now`, in random order.
    fn due(&mut self, dice: &mut Dice, now: u64) -> Vec<Vec<u8>> {
        let mut due = Vec::new();
        let mut i = 0;
        while i < self.in_flight.len() {
            if self.in_flight[i].0 <= now {
                due.push(self.in_flight.swap_remove(i).1);
            } else {
                i += 1;
            }
        }
        for i in (1..due.len()).rev() {
            due.swap(i, dice.below(i as u64 + 1) as usize);
        }
        due
    }
}

fn trajectory(dice: &mut Dice, n: usize) -> Vec<Point> {
    let mut prev = [0i32; MAX_JOINTS];
    (0..n)
        .map(|_| {
            let next = prev.map(|p| p + dice.below(101) as i32 - 50);
            let duration = 1_000 + dice.below(4_000) as i32;
            let p = Point::from_motion(duration, &prev, &next);
            prev = next;
            p
        })
        .collect()
}

fn run_case(seed: u64, n_points: usize, capacity: usize, loss: u64, dup: u64, delay: u64) {
    let mut dice = Dice(seed | 1);
    let points = trajectory(&mut dice, n_points);
    let mut s = Session::<64>::new(capacity);
    // The engine holds the running segment and at least one more (a queue of one would
    // run dry between segments: a real underrun).
    s.plant.room = 2 + dice.below(7) as usize;

    // NEW goes first, reliably; then the frames, each with the next seq: PENDINGs of
    // 1..12 points, with a RUNING after the first one.
    let new_seq = dice.below(256) as u8;
    let ack = s
        .send_raw(
            HOST,
            &frame(
                new_seq,
                Command::New {
                    count: n_points as u16,
                },
            ),
        )
        .reply
        .unwrap()
        .ack;
    assert_eq!(ack.status, StatusCode::Ok);
    let mut frames: Vec<Vec<u8>> = Vec::new();
    let mut at = 0;
    while at < points.len() {
        // A frame never needs more than half the buffer: a host cannot expect a full
        // buffer's worth of room while points are running.
        let most = (capacity / 2).min(12) as u64;
        let take = (1 + dice.below(most) as usize).min(points.len() - at);
        let seq = new_seq.wrapping_add(1 + frames.len() as u8);
        frames.push(pending(seq, &points[at..at + take]));
        at += take;
        if frames.len() == 1 {
            let seq = new_seq.wrapping_add(2);
            frames.push(frame(seq, Command::Runing));
        }
    }
    assert!(frames.len() < 200, "seqs must not wrap onto each other");
    let index_of = |seq: u8| usize::from(seq.wrapping_sub(new_seq).wrapping_sub(1));

    let mut to_controller = Link {
        in_flight: Vec::new(),
        loss,
        dup,
        max_delay: delay,
    };
    let mut to_host = Link {
        in_flight: Vec::new(),
        loss,
        dup,
        max_delay: delay,
    };
    let window = 4;
    let mut acked = vec![false; frames.len()];
    let mut next = 0;
    let mut last_progress = 0;
    let mut hold_until = 0;
    let mut tick = 0u64;
    while s.controller.state() != State::Stopped || acked.iter().any(|a| !a) {
        tick += 1;
        assert!(tick < 100_000, "no progress: {acked:?}");
        let base = acked.iter().position(|a| !a).unwrap_or(frames.len());
        // Host: a silent link means loss; go back to the first frame not acknowledged.
        if tick - last_progress > 3 * (delay + 2) {
            next = base;
            last_progress = tick;
        }
        next = next.max(base);
        while tick >= hold_until && next < frames.len() && next < base + window {
            to_controller.send(&mut dice, tick, frames[next].clone());
            next += 1;
        }
        // Controller.
        for bytes in to_controller.due(&mut dice, tick) {
            s.now_us += 100;
            let before = s.controller.state();
            let r = s.controller.handle(HOST, &bytes, s.now_us, &mut s.plant);
            if std::env::var("DBG").is_ok() {
                eprintln!(
                    "tick {tick} seq {} tag {} -> {:?} {:?}->{:?} queue {}",
                    bytes[0],
                    bytes[1],
                    r.reply
                        .map(|r| (r.ack.status, r.ack.next_seq, r.ack.buffered)),
                    before,
                    s.controller.state(),
                    s.plant.queue.len()
                );
            }
            if let Some(reply) = r.reply {
                let mut ack = vec![0u8; 16];
                let n = protocol::Report::Ack(reply.ack)
                    .encode(reply.seq, &mut ack)
                    .unwrap();
                ack.truncate(n);
                to_host.send(&mut dice, tick, ack);
            }
        }
        // Engine: runs a few segments, but never into an underrun (the host keeps ahead).
        let st = s.controller.status(&s.plant);
        let k = dice.below(3) as usize;
        if st.received == st.expected || s.controller.buffered() > k {
            s.plant.run(&mut s.controller, k);
        }
        // Host: ACKs.
        for bytes in to_host.due(&mut dice, tick) {
            let frame = protocol::Report::decode(&bytes).unwrap();
            let protocol::Report::Ack(ack) = frame.body else {
                panic!("not an ACK")
            };
            let i = index_of(frame.seq);
            if i >= frames.len() {
                continue;
            }
            match ack.status {
                StatusCode::Ok => {
                    if ack.acked_tag == Tag::Pending as u8 {
                        // Taken in order: everything before it was accepted too.
                        acked[..=i].iter_mut().for_each(|a| *a = true);
                    } else {
                        acked[i] = true;
                    }
                    last_progress = tick;
                }
                StatusCode::OutOfOrder => next = next.min(index_of(ack.next_seq)),
                StatusCode::BufferFull => {
                    next = next.min(i);
                    hold_until = tick + 2;
                }
                StatusCode::BadState => next = next.min(i),
                other => panic!("unexpected {other:?}"),
            }
        }
    }
    if std::env::var("DBG").is_ok() {
        eprintln!(
            "end tick {tick} status {:?} acked {:?}",
            s.controller.status(&s.plant),
            acked
        );
    }
    // Every point ran exactly once, in order.
    let mut prev = [0i32; MAX_JOINTS];
    let expected: Vec<(u32, [i32; MAX_JOINTS])> = points
        .iter()
        .map(|p| {
            let mut steps = [0; MAX_JOINTS];
            for j in 0..6 {
                steps[j] = p.position[j] - prev[j];
            }
            prev = p.position;
            (p.duration as u32, steps)
        })
        .collect();
    let executed: Vec<(u32, [i32; MAX_JOINTS])> = s
        .plant
        .executed
        .iter()
        .map(|g| (g.duration_us, g.steps))
        .collect();
    assert_eq!(executed, expected);
    let st = s.controller.status(&s.plant);
    assert_eq!(usize::from(st.executed), n_points);
    assert!(!st.flags.has(StatusFlags::UNDERRUN));
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(200))]
    #[test]
    fn every_point_runs_once_in_order(
        seed in any::<u64>(),
        n_points in 1usize..120,
        capacity in 12usize..64,
        loss in 0u64..30,
        dup in 0u64..30,
        delay in 0u64..4,
    ) {
        run_case(seed, n_points, capacity, loss, dup, delay);
    }
}

#[test]
fn a_clean_link_needs_no_retransmission() {
    run_case(7, 100, 16, 0, 0, 0);
}

#[test]
fn a_bad_link_still_delivers() {
    run_case(12345, 119, 12, 29, 29, 3);
}
