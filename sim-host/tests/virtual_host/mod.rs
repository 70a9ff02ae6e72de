//! The host side of the virtual-time tests (`virtual_time.rs`, `hold.rs`): a board on
//! virtual time with a VCD trace, numbered commands whose ACKs are found among what the
//! board sent, and the waits they need (all on simulated time).
#![allow(dead_code)]

use std::path::PathBuf;

use arm_core::hw::Endpoint;
use protocol::{
    Command, Frame, Location, MAX_JOINTS, MotionReport, Point, PointList, Report, State, StatusAsk,
    StatusCode, StatusReport, StopReport,
};
use sim_host::options::SimOptions;
use sim_host::virtual_board::VirtualBoard;

pub const HOST: Endpoint = Endpoint {
    ip: [127, 0, 0, 1],
    port: 50_000,
};

/// Simulated time a test allows for what it waits for (virtual: costs nothing if unused).
pub const SECOND_NS: u64 = 1_000_000_000;

pub fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("sim-host-virtual-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

/// A board with a 1 MHz step timer (pulse times in whole microseconds), traced to
/// `NAME.vcd`, its settings in `NAME.txt`.
pub fn board(name: &str, tick_hz: u32) -> (VirtualBoard, PathBuf) {
    let mut options = SimOptions::defaults();
    options.tick_hz = tick_hz;
    options.settings = Some(scratch(&format!("{name}.txt")));
    let _ = std::fs::remove_file(options.settings.as_ref().unwrap());
    let trace = scratch(&format!("{name}.vcd"));
    (VirtualBoard::new(&options, Some(&trace)).unwrap(), trace)
}

/// The host side: numbered commands, their ACKs found among what the board sent.
pub struct Host {
    pub seq: u8,
    pub reports: Vec<(u8, Vec<u8>)>,
}

impl Host {
    pub fn new() -> Host {
        Host {
            seq: 0,
            reports: Vec::new(),
        }
    }

    /// Sends `command` and runs the board until its ACK (100 ms of simulated time at most).
    pub fn command(&mut self, board: &mut VirtualBoard, command: &Command<'_>) -> protocol::Ack {
        let seq = self.seq;
        self.seq = self.seq.wrapping_add(1);
        let mut buf = [0u8; protocol::MAX_DATAGRAM];
        let n = command.encode(seq, &mut buf).unwrap();
        board.send(HOST, &buf[..n]);
        let mut ack = None;
        let tag = command.tag() as u8;
        let reports = &mut self.reports;
        let found = board.run_until(SECOND_NS / 10, |b| {
            for (_, bytes) in b.sent() {
                if let Ok(Frame {
                    seq: s,
                    body: Report::Ack(a),
                }) = Report::decode(&bytes)
                    && s == seq
                    && a.acked_tag == tag
                {
                    ack = Some(a);
                } else {
                    reports.push((0, bytes));
                }
            }
            ack.is_some()
        });
        assert!(found, "no ACK for {:?}", command.tag());
        ack.unwrap()
    }

    pub fn ok(&mut self, board: &mut VirtualBoard, command: &Command<'_>) -> protocol::Ack {
        let ack = self.command(board, command);
        assert_eq!(ack.status, StatusCode::Ok, "{:?}: {ack:?}", command.tag());
        ack
    }

    /// STATUS, and the report that follows its ACK.
    pub fn status(&mut self, board: &mut VirtualBoard) -> StatusReport {
        self.reports.clear();
        self.ok(board, &Command::Status);
        let mut status = self.find_status();
        if status.is_none() {
            board.run_until(SECOND_NS / 10, |b| {
                for (_, bytes) in b.sent() {
                    self.reports.push((0, bytes));
                }
                self.find_status().is_some()
            });
            status = self.find_status();
        }
        status.expect("a STATUS report")
    }

    pub fn find_status(&self) -> Option<StatusReport> {
        self.reports
            .iter()
            .rev()
            .find_map(|(_, bytes)| match Report::decode(bytes) {
                Ok(Frame {
                    body: Report::Status(s),
                    ..
                }) => Some(s),
                _ => None,
            })
    }

    /// Uploads and runs `points` (the buffer holds them all).
    pub fn upload_and_run(&mut self, board: &mut VirtualBoard, points: &[Point]) {
        self.ok(
            board,
            &Command::New {
                count: points.len() as u16,
            },
        );
        for chunk in points.chunks(protocol::MAX_POINTS_PER_FRAME) {
            self.ok(board, &Command::Pending(PointList::Points(chunk)));
        }
        self.ok(board, &Command::Runing);
    }
}

/// STOP_CAUSE and MOTION (STATUS's request byte bits 2 and 4).
pub fn stop_and_motion(host: &mut Host, board: &mut VirtualBoard) -> (StopReport, MotionReport) {
    host.reports.clear();
    let ask = StatusAsk {
        stop_cause: true,
        motion: true,
        ..StatusAsk::default()
    };
    host.ok(board, &Command::StatusWith(ask));
    let (mut stop, mut motion) = (None, None);
    board.run_until(SECOND_NS / 10, |b| {
        for (_, bytes) in b.sent() {
            host.reports.push((0, bytes));
        }
        for (_, bytes) in &host.reports {
            match Report::decode(bytes) {
                Ok(Frame {
                    body: Report::StopCause(s),
                    ..
                }) => stop = Some(s),
                Ok(Frame {
                    body: Report::Motion(m),
                    ..
                }) => motion = Some(m),
                _ => {}
            }
        }
        stop.is_some() && motion.is_some()
    });
    (stop.expect("STOP_CAUSE"), motion.expect("MOTION"))
}

/// Runs the board until a LOCATION report says STOPPED (at most `limit_ns`).
pub fn run_until_stopped(board: &mut VirtualBoard, limit_ns: u64) -> Location {
    let mut last = None;
    let stopped = board.run_until(limit_ns, |b| {
        for (_, bytes) in b.sent() {
            if let Ok(Frame {
                body: Report::Location(l),
                ..
            }) = Report::decode(&bytes)
                && l.state == State::Stopped as u8
            {
                last = Some(l);
            }
        }
        last.is_some()
    });
    assert!(
        stopped,
        "the run did not end within {} ms",
        limit_ns / 1_000_000
    );
    last.unwrap()
}

pub fn points_through(
    start: [i32; MAX_JOINTS],
    targets: &[[i32; MAX_JOINTS]],
    us: i32,
) -> Vec<Point> {
    let mut previous = start;
    targets
        .iter()
        .map(|t| {
            let p = Point::from_motion(us, &previous, t);
            previous = *t;
            p
        })
        .collect()
}
