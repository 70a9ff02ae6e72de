//! Handling one 12-point PENDING frame (decode, checks, taking the points, feeding the
//! engine) and encoding an ACK.
//!
//! `cargo bench -p arm-core --bench pending`. Measured on the development VM (x86-64, 2
//! shared cores, load ~4): handle 12-point PENDING 4.08 us (4.05-4.12), encode ACK
//! 11 ns. The per-frame budget at the board's link rate is far larger: a 12-point frame
//! carries 12 points, i.e. 120 ms of motion at 10 ms points.

use arm_core::hw::{Endpoint, SerialError};
use arm_core::{Controller, ControllerConfig, Plant};
use arm_step::Segment;
use criterion::{Criterion, black_box, criterion_group, criterion_main};
use protocol::{Command, MAX_JOINTS, Point, PointList, Pwm, Report, UartInit};

const HOST: Endpoint = Endpoint {
    ip: [127, 0, 0, 1],
    port: 40_000,
};

/// An engine that takes every segment and forgets it.
struct Sink {
    positions: [i32; MAX_JOINTS],
}

impl Plant for Sink {
    fn positions(&self) -> [i32; MAX_JOINTS] {
        self.positions
    }
    fn set_positions(&mut self, positions: [i32; MAX_JOINTS]) -> bool {
        self.positions = positions;
        true
    }
    fn stop(&mut self) {}
    fn push_segment(&mut self, segment: Segment) -> bool {
        black_box(segment);
        true
    }
    fn start(&mut self) {}
    fn set_user_pin(&mut self, _pin: u8, _high: bool) {}
    fn set_enabled(&mut self, _enabled: u16) {}
    fn gripper_start(&mut self, _pwm: &Pwm) {}
    fn gripper_stop(&mut self) {}
    fn gripper_active(&self) -> bool {
        false
    }
    fn serial_open(&mut self, _init: &UartInit) -> Result<(), SerialError> {
        Ok(())
    }
    fn serial_close(&mut self) {}
    fn serial_send(&mut self, _bytes: &[u8]) -> bool {
        true
    }
}

fn encode(seq: u8, cmd: Command<'_>) -> Vec<u8> {
    let mut buf = vec![0u8; protocol::MAX_DATAGRAM];
    let n = cmd.encode(seq, &mut buf).expect("encodes");
    buf.truncate(n);
    buf
}

fn pending_frame(c: &mut Criterion) {
    let mut prev = [0i32; MAX_JOINTS];
    let points: Vec<Point> = (0..12)
        .map(|k| {
            let next = prev.map(|p| p + 7 + k);
            let p = Point::from_motion(10_000, &prev, &next);
            prev = next;
            p
        })
        .collect();
    // Frames with consecutive seqs after a NEW at seq 0, cycling through 200 of them;
    // a new upload starts each cycle so the buffer never fills.
    let frames: Vec<Vec<u8>> = (1..=200u8)
        .map(|seq| encode(seq, Command::Pending(PointList::Points(&points))))
        .collect();
    let new = encode(0, Command::New { count: 65_535 });
    let mut controller = Box::new(Controller::<8192>::new(ControllerConfig::BOARD));
    let mut plant = Sink {
        positions: [0; MAX_JOINTS],
    };
    let mut now = 0u64;
    let mut i = 0usize;
    c.bench_function("handle 12-point PENDING", |b| {
        b.iter(|| {
            if i.is_multiple_of(frames.len()) {
                now += 3_000_000; // past the duplicate window
                controller.handle(HOST, &new, now, &mut plant);
            }
            let frame = &frames[i % frames.len()];
            i += 1;
            now += 1;
            // Not running: the fed points stay; finish them so the buffer has room.
            let r = controller.handle(HOST, black_box(frame), now, &mut plant);
            controller.on_step_progress(12, false, &mut plant);
            assert!(
                matches!(r.reply, Some(ref reply) if reply.ack.status == protocol::StatusCode::Ok)
            );
            r
        })
    });
    let ack = protocol::Ack {
        acked_tag: 1,
        status: protocol::StatusCode::Ok,
        state: protocol::State::Running,
        next_seq: 9,
        buffered: 100,
        free: 8092,
    };
    let mut buf = [0u8; 16];
    c.bench_function("encode ACK", |b| {
        b.iter(|| Report::Ack(black_box(ack)).encode(black_box(3), &mut buf))
    });
}

criterion_group!(benches, pending_frame);
criterion_main!(benches);
