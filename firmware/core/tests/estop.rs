//! Issue 18, "a CRC-valid STOPPED always stops" (docs/PROTOCOL.md sections 4, 7 and 11):
//! from any sender, in any state, whatever its data length, never swallowed as a
//! duplicate, ACKed `OK`, and it never makes its sender the owner. Each test failed under
//! the old rule (a STOPPED repeated within 2 s was a duplicate, one with data was
//! BAD_LENGTH, and the first STOPPED of an unowned controller took it over).

mod common;

use arm_core::config::OWNER_TIMEOUT_US;
use common::*;
use protocol::{Command, State, StatusCode, StatusFlags, Tag};

#[test]
fn the_same_stopped_bytes_stop_every_run_however_soon_they_repeat() {
    // An e-stop panel sends one fixed frame: same seq, same bytes, every time.
    let panel = OTHER;
    let stop = raw(0x42, Tag::Stopped as u8, &[]);
    let mut s = Session::<64>::new(64);
    for round in 0..10 {
        s.start_endless_run();
        let stops = s.plant.stops;
        let r = s.send_raw(panel, &stop);
        let ack = r.reply.expect("an ACK").ack;
        assert_eq!(ack.status, StatusCode::Ok, "round {round}");
        assert_eq!(ack.state, State::Stopped, "round {round}");
        assert!(r.executed, "round {round}: executed, not a duplicate");
        assert!(
            s.plant.stops > stops,
            "round {round}: the engine was stopped"
        );
        assert!(!s.plant.running, "round {round}");
        assert_eq!(s.controller.state(), State::Stopped);
        // The next run starts well within the old 2 s duplicate window.
        s.now_us += 100_000;
    }
}

#[test]
fn the_owners_own_repeated_stopped_stops_too() {
    let mut s = Session::<64>::new(64);
    let stop = raw(0x99, Tag::Stopped as u8, &[]);
    for round in 0..3 {
        s.start_endless_run();
        let r = s.send_raw(HOST, &stop);
        assert_eq!(r.reply.expect("an ACK").ack.status, StatusCode::Ok);
        assert_eq!(s.controller.state(), State::Stopped, "round {round}");
        assert!(!s.plant.running, "round {round}");
    }
}

#[test]
fn a_stopped_with_data_stops_and_its_data_is_ignored() {
    for len in [1usize, 4, 200] {
        let mut s = Session::<64>::new(64);
        s.start_endless_run();
        let data = vec![0xA5u8; len];
        let r = s.send_raw(OTHER, &raw(7, Tag::Stopped as u8, &data));
        let ack = r.reply.expect("an ACK").ack;
        assert_eq!(
            (ack.status, ack.state),
            (StatusCode::Ok, State::Stopped),
            "{len} bytes"
        );
        assert!(!s.plant.running, "{len} data bytes");
        let status = s.controller.status(&s.plant);
        assert!(status.flags.has(StatusFlags::STOPPED_BY_HOST));
    }
}

#[test]
fn a_stopped_with_a_bad_crc_stops_nothing() {
    let mut s = Session::<64>::new(64);
    s.start_endless_run();
    let mut bad = raw(7, Tag::Stopped as u8, &[]);
    *bad.last_mut().unwrap() ^= 0x01;
    let r = s.send_raw(OTHER, &bad);
    assert_eq!(r.reply.expect("an ACK").ack.status, StatusCode::BadCrc);
    assert_eq!(s.controller.state(), State::Running);
    assert!(s.plant.running);
}

#[test]
fn a_stopped_never_makes_its_sender_the_owner() {
    // Unowned controller: a STOPPED stops, and the controller stays unowned.
    let mut s = Session::<64>::new(64);
    let r = s.send_raw(OTHER, &frame(1, Command::Stopped));
    assert_eq!(r.reply.expect("an ACK").ack.status, StatusCode::Ok);
    assert_eq!(s.controller.owner(), None, "STOPPED took no owner");
    // The first other command does.
    s.expect(Command::Status, StatusCode::Ok);
    assert_eq!(s.controller.owner().map(|o| o.ip), Some(HOST.ip));
    // Owner silent 5 s, arm STOPPED: a stranger's STOPPED still takes nothing over.
    s.now_us += OWNER_TIMEOUT_US;
    let r = s.send_raw(OTHER, &frame(2, Command::Stopped));
    assert_eq!(r.reply.expect("an ACK").ack.status, StatusCode::Ok);
    assert_eq!(s.controller.owner().map(|o| o.ip), Some(HOST.ip));
    assert!(
        !s.controller
            .report_settings()
            .location_goes_to(OTHER, s.now_us),
        "a stopper is no LOCATION listener"
    );
}

#[test]
fn a_stopped_does_not_fill_the_duplicate_memory() {
    // A host resending a RUNING (its ACK lost) while a panel repeats STOPPED: the RUNING's
    // copy is still recognised as a duplicate, not executed again.
    let mut s = Session::<64>::new(64);
    let from = s.plant.positions;
    s.expect(Command::New { count: 50 }, StatusCode::Ok);
    s.pending(&points(from, 12, 1));
    s.seq += 1;
    let runing = frame(s.seq, Command::Runing);
    assert_eq!(status(&s.send_raw(HOST, &runing)), StatusCode::Ok);
    for i in 0..200u8 {
        s.send_raw(OTHER, &raw(i, Tag::Stopped as u8, &[i]));
    }
    let starts = s.plant.starts;
    assert_eq!(status(&s.send_raw(HOST, &runing)), StatusCode::Ok);
    assert_eq!(s.plant.starts, starts, "the RUNING copy is not run again");
    assert_eq!(s.controller.state(), State::Stopped);
}

fn status(r: &arm_core::Response) -> StatusCode {
    r.reply.expect("an ACK").ack.status
}
