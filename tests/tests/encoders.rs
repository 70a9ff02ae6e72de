//! RETURN by absolute encoder, end to end: sim-host's simulated Modbus RTU encoders on a
//! simulated RS-485 bus, read with the board's own protocol code (board-logic `encoder`).

mod common;

use std::time::Duration;

use armctl::Client;
use common::{loopback, position};
use protocol::{State, StatusFlags};
use system_tests::SimHost;

#[test]
fn return_homes_by_the_encoders_not_the_step_count() {
    // The step count says 0 everywhere; the encoders know where the joints really are.
    let sim = SimHost::start(&[
        "--joints",
        "3",
        "--encoder-offset",
        "0:400",
        "--encoder-offset",
        "2:-250",
    ]);
    let arm = Client::connect_with(sim.addr, loopback()).unwrap();
    arm.go_home().unwrap();
    let status = arm.wait_stopped(Duration::from_secs(30)).unwrap();
    assert_eq!(status.state, State::Stopped);
    // The controller took the encoders' positions (400, 0, -250) as its step count, then
    // drove them to 0: had it trusted the step count (all 0), nothing would have moved.
    assert_eq!(position(&arm)[..3], [0, 0, 0]);
    assert!(status.executed > 0, "RETURN moved: {status:?}");
}

#[test]
fn return_with_a_silent_encoder_ends_stopped_without_moving() {
    let sim = SimHost::start(&["--joints", "3", "--encoder-fault", "1:silent"]);
    let arm = Client::connect_with(sim.addr, loopback()).unwrap();
    arm.set_location(&[400, -300, 200]).unwrap();
    // Accepted (RUNNING) at once: the encoders are read after the ACK.
    arm.go_home().unwrap();
    let status = arm.wait_stopped(Duration::from_secs(30)).unwrap();
    assert_eq!(status.state, State::Stopped);
    assert_eq!(status.executed, 0, "nothing ran: {status:?}");
    assert!(!status.flags.has(StatusFlags::UNDERRUN));
    assert!(!status.flags.has(StatusFlags::STOPPED_BY_HOST));
    assert_eq!(
        position(&arm)[..3],
        [400, -300, 200],
        "the arm did not move"
    );
}

#[test]
fn return_with_a_corrupting_encoder_ends_stopped_without_moving() {
    let sim = SimHost::start(&["--joints", "2", "--encoder-fault", "0:crc"]);
    let arm = Client::connect_with(sim.addr, loopback()).unwrap();
    arm.set_location(&[123, 456]).unwrap();
    arm.go_home().unwrap();
    let status = arm.wait_stopped(Duration::from_secs(30)).unwrap();
    assert_eq!(status.state, State::Stopped);
    assert_eq!(position(&arm)[..2], [123, 456]);
}
