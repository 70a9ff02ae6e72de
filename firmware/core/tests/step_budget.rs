//! The board's step rate budget: a point whose steps per second over all joints exceed
//! `step_budget_hz` is refused with INVALID_POINT (docs/PROTOCOL.md, "Step rate budget"),
//! and STATUS reports the budget at offset 32.

mod common;

use arm_core::{Controller, ControllerConfig};
use common::*;
use protocol::{Command, MAX_JOINTS, Point, StatusCode::*};

/// 1 MHz per joint, 2 M steps/s in all.
fn budget_session() -> Session<16> {
    let mut s = Session::<16>::new(16);
    s.controller = Controller::new(ControllerConfig {
        capacity: 16,
        max_step_rate_hz: 1_000_000,
        ..ControllerConfig::BOARD
    });
    s.controller.set_step_budget_hz(2_000_000);
    s
}

/// One 1 ms point from `from` moving the first `joints` joints by `steps` each.
fn point(from: [i32; MAX_JOINTS], joints: usize, steps: i32) -> Point {
    let mut to = from;
    for p in to.iter_mut().take(joints) {
        *p += steps;
    }
    Point::from_motion(1_000, &from, &to)
}

#[test]
fn points_over_the_budget_are_invalid_and_take_nothing() {
    let mut s = budget_session();
    s.expect(Command::New { count: 4 }, Ok);
    // Two joints at 1 MHz: exactly the budget.
    let first = point([0; MAX_JOINTS], 2, 1_000);
    assert_eq!(s.pending(&[first]).status, Ok);
    // Three joints at 1 MHz each (every joint within its own limit): 3 M steps/s.
    let before = s.controller.next_seq();
    let ack = s.pending(&[point(first.position, 3, 1_000)]);
    assert_eq!((ack.status, ack.next_seq), (InvalidPoint, before));
    assert_eq!(s.controller.buffered(), 1);
}

#[test]
fn status_reports_the_budget() {
    let mut s = budget_session();
    let status = s.controller.status(&s.plant);
    assert_eq!(status.step_budget_hz, 2_000_000);
    let boot = Controller::<4>::new(ControllerConfig::BOARD);
    assert_eq!(
        boot.status(&s.plant).step_budget_hz,
        arm_core::profile::NUCLEO_H743ZI2.step_budget_hz
    );
    s.expect(Command::Status, Ok);
}
