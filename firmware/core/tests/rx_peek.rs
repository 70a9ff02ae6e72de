//! Issue 30 part 4: the boards' receive interrupt looks at each frame the moment the MAC
//! has filled its buffer ([`stop_in_frame`], [`RingPeek`]) and halts for a STOPPED, so a
//! STOPPED behind a flood is obeyed before the runner (and the ring behind it) gets to it.
//! Sans-io: frames as bytes, the ring as the ownership bits the interrupt reads.

mod common;

use std::cell::Cell;

use arm_core::Bus;
use arm_core::hw::Endpoint;
use arm_core::ingress::{
    Ingress, MAX_RING, RingPeek, RxRingCounters, StepHalt, stop_in_frame, stop_signature,
    udp_payload,
};
use common::*;
use protocol::auth::{AuthKey, Direction, seal};
use protocol::{Command, PORT, Tag, crc8};

const STRANGER: Endpoint = Endpoint {
    ip: [192, 168, 1, 77],
    port: 40_000,
};

fn udp_frame(from: Endpoint, port: u16, payload: &[u8]) -> Vec<u8> {
    udp_frame_to([0x02, 0, 0, 0, 0, 1], from, port, payload)
}

#[derive(Default)]
struct CountingHalt(Cell<u32>);

impl StepHalt for CountingHalt {
    fn halt(&self) {
        self.0.set(self.0.get() + 1);
    }
}

/// The interrupt's look and the runner's look agree: whatever the interrupt halts for,
/// `Bus::receive_first` halts for too (and routes to `estop`), and the reverse.
fn same_verdict_as_the_first_look(frame: &[u8]) -> bool {
    let bus = Bus::new();
    let halt = CountingHalt::default();
    let runner_halts = match udp_payload(frame, PORT) {
        Some((from, payload)) => {
            bus.receive_first(from, payload, frame[0] & 1 == 1, 0, &halt) == Ingress::Stopped
        }
        None => false,
    };
    assert_eq!(runner_halts, halt.0.get() == 1);
    stop_in_frame(frame, PORT) == runner_halts
}

#[test]
fn a_stopped_from_anyone_whatever_its_data_or_address_is_seen() {
    let stop = frame(9, Command::Stopped);
    for f in [
        udp_frame(HOST, PORT, &stop),
        udp_frame(STRANGER, PORT, &stop),
        udp_frame_to([0xff; 6], STRANGER, PORT, &stop),
    ] {
        assert!(stop_in_frame(&f, PORT));
        assert!(same_verdict_as_the_first_look(&f));
    }
    // With data (a panel's fixed frame): still a STOPPED (docs/PROTOCOL.md section 4).
    let mut body = vec![3u8, Tag::Stopped as u8];
    body.extend_from_slice(&[0xa5; 1400]);
    body.push(crc8(&body));
    let f = udp_frame(STRANGER, PORT, &body);
    assert!(stop_in_frame(&f, PORT));
    assert!(same_verdict_as_the_first_look(&f));
}

#[test]
fn anything_but_a_crc_valid_plain_stopped_to_the_port_is_not() {
    let stop = frame(9, Command::Stopped);
    let mut bad_crc = stop.clone();
    *bad_crc.last_mut().unwrap() ^= 1;
    let cases = [
        udp_frame(HOST, PORT, &bad_crc),
        udp_frame(HOST, PORT + 1, &stop),
        udp_frame(HOST, PORT, &frame(9, Command::Status)),
        udp_frame(HOST, PORT, &frame(9, Command::Runing)),
        udp_frame(HOST, PORT, &stop[..2]),
        udp_frame(HOST, PORT, &[]),
    ];
    for (i, f) in cases.iter().enumerate() {
        assert!(!stop_in_frame(f, PORT), "case {i}");
        assert!(same_verdict_as_the_first_look(f), "case {i}");
    }
    // A STOPPED sealed in an envelope is the controller's to verify (section 13): no
    // early look, in the interrupt as in the runner.
    let mut sealed = [0u8; 64];
    let n = seal(
        &AuthKey([7; 32]),
        Direction::ToController,
        1,
        5,
        1,
        &stop,
        &mut sealed,
    )
    .expect("a STOPPED fits an envelope");
    let f = udp_frame(HOST, PORT, &sealed[..n]);
    assert!(!stop_in_frame(&f, PORT));
    assert!(same_verdict_as_the_first_look(&f));
}

/// Frames from the wire are anything: every truncation, every byte changed to a few
/// values, and random bytes are looked at within bounds, never panic, and agree with the
/// runner's look.
#[test]
fn bad_frames_never_panic_and_agree_with_the_runners_look() {
    let stop = frame(9, Command::Stopped);
    let f = udp_frame(STRANGER, PORT, &stop);
    for n in 0..f.len() {
        assert!(!stop_in_frame(&f[..n], PORT), "{n} bytes");
    }
    for at in 0..f.len() {
        for v in [0u8, 1, 5, 0x45, 0x7f, 0x80, 0xff] {
            let mut changed = f.clone();
            changed[at] = v;
            assert!(same_verdict_as_the_first_look(&changed), "byte {at} = {v}");
        }
    }
    // xorshift: reproducible noise, some of it with a valid Ethernet/IPv4/UDP head.
    let mut x = 0x2545_f491_4f6c_dd1du64;
    let mut next = || {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        x
    };
    for i in 0..20_000 {
        let len = (next() % 1600) as usize;
        let mut noise: Vec<u8> = (0..len).map(|_| next() as u8).collect();
        if i % 2 == 0 && noise.len() >= 44 {
            noise[..42].copy_from_slice(&f[..42]);
        }
        assert!(same_verdict_as_the_first_look(&noise), "noise {i}");
    }
}

#[test]
fn each_stopped_is_counted_once_per_buffer_it_lands_in() {
    let a = udp_frame(HOST, PORT, &frame(1, Command::Stopped));
    let b = udp_frame(STRANGER, PORT, &frame(1, Command::Stopped));
    let sig = |f: &[u8]| stop_signature(f, PORT).expect("a STOPPED");
    assert_ne!(sig(&a), sig(&b), "another sender's STOPPED is another");
    assert_ne!(
        sig(&a),
        sig(&udp_frame(HOST, PORT, &frame(2, Command::Stopped))),
        "another seq is another"
    );
    assert_eq!(
        stop_signature(&udp_frame(HOST, PORT, &frame(1, Command::Status)), PORT),
        None
    );
    let mut ring = RingPeek::<40>::new();
    // The interrupt looks at buffer 3 three times while the runner is busy: one count.
    assert!(ring.stop_at(3, sig(&a)));
    assert!(!ring.stop_at(3, sig(&a)));
    assert!(!ring.stop_at(3, sig(&a)));
    // The runner gave buffer 3 back and the MAC filled it with another STOPPED before
    // the interrupt saw it empty (a full ring, Renode's synchronous refill): counted.
    assert!(ring.stop_at(3, sig(&b)));
    // Given back, then the same bytes again (a panel's fixed frame): counted again.
    ring.given_back(3);
    assert!(ring.stop_at(3, sig(&b)));
    // Buffers are independent; beyond the ring: never counted, never a panic.
    assert!(ring.stop_at(4, sig(&b)));
    for i in [40, MAX_RING, usize::MAX] {
        assert!(!ring.stop_at(i, sig(&a)));
        ring.given_back(i);
    }
}

#[test]
fn the_ring_counters_add_up_and_wrap() {
    let bus = Bus::new();
    assert_eq!(bus.rx_ring(), RxRingCounters::default());
    bus.count_rx_ring(3, 1, 0);
    bus.count_rx_ring(2, 0, 1);
    assert_eq!(
        bus.rx_ring(),
        RxRingCounters {
            dropped: 5,
            full: 1,
            stops: 1
        }
    );
    bus.count_rx_ring(u32::MAX, 0, 0);
    assert_eq!(bus.rx_ring().dropped, 4);
}

/// STATUS's request byte bit 3 (issue 30; bit 2 is issue 31's STOP_CAUSE): the asker gets
/// an RX_COUNTERS report too, from the owner's STATUS and from a stranger's read-only one
/// alike, with the bus's counts; with bit 2 as well, both reports.
#[test]
fn status_bit_3_asks_for_the_receive_counters() {
    use protocol::StatusAsk;
    let mut s = Session::<64>::new(64);
    let ask = StatusAsk {
        location: false,
        look_only: false,
        stop_cause: false,
        counters: true,
        diag: false,
        motion: false,
    };
    let r = s.send_raw(HOST, &frame(1, Command::StatusWith(ask)));
    assert_eq!(r.reply.unwrap().ack.status, protocol::StatusCode::Ok);
    assert!(r.status.is_some());
    assert_eq!(r.asked_counters, Some(HOST));
    assert_eq!(r.answer_seq, None, "the owner's: the report counter");
    // A stranger while the owner is present: read-only, with its own seq.
    let r = s.send_raw(OTHER, &frame(9, Command::StatusWith(ask)));
    assert_eq!(r.asked_counters, Some(OTHER));
    assert_eq!(r.answer_seq, Some(9));
    // Without the bit: none, as before.
    let r = s.send_raw(HOST, &frame(2, Command::Status));
    assert_eq!(r.asked_counters, None);
    // Bit 2 alone is the STOP_CAUSE's; bits 2 and 3 (0x0c) ask for both.
    let stop_only = StatusAsk {
        stop_cause: true,
        motion: false,
        counters: false,
        ..ask
    };
    let r = s.send_raw(HOST, &frame(3, Command::StatusWith(stop_only)));
    assert!(r.asked_stop.is_some());
    assert_eq!(r.asked_counters, None);
    let both = StatusAsk {
        stop_cause: true,
        ..ask
    };
    assert_eq!(both.byte(), 0x0c);
    let r = s.send_raw(HOST, &frame(4, Command::StatusWith(both)));
    assert!(r.asked_stop.is_some());
    assert_eq!(r.asked_counters, Some(HOST));
    // What the report carries: the board's ring counts and the first look's.
    let bus = Bus::new();
    bus.count_rx_ring(7, 2, 1);
    let halt = CountingHalt::default();
    for _ in 0..3 {
        bus.receive_first(STRANGER, &frame(1, Command::Status), true, 0, &halt);
    }
    let c = bus.rx_counters();
    assert_eq!(
        (
            c.ring_dropped,
            c.ring_full,
            c.interrupt_stops,
            c.group_ignored
        ),
        (7, 2, 1, 3)
    );
    assert_eq!((c.shed, c.inbox_dropped), (0, 0));
}
