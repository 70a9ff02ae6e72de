//! The controller against PROTOCOL.md: every command in every state, the golden frames,
//! owner rule, duplicates, ordering, flow control, runs and their ends.

mod common;

use arm_core::config::OWNER_TIMEOUT_US;
use arm_core::hw::Endpoint;
use arm_core::{Controller, ControllerConfig, Deferred, StoredPoint};
use common::*;
use protocol::{
    Command, Location, MAX_JOINTS, Point, PointList, Pwm, State, StatusCode, StatusFlags, Tag,
    UartInit,
};

use StatusCode::*;

/// A session brought into `state` with a trajectory of 4 announced points, 2 sent.
fn in_state(state: State) -> Session<64> {
    let mut s = Session::<64>::new(64);
    match state {
        State::Stopped => {}
        State::New => {
            s.expect(Command::New { count: 4 }, Ok);
        }
        State::Pending | State::Running => {
            s.expect(Command::New { count: 4 }, Ok);
            assert_eq!(s.pending(&points([0; 8], 2, 1)).status, Ok);
            if state == State::Running {
                s.expect(Command::Runing, Ok);
            }
        }
    }
    assert_eq!(s.controller.state(), state);
    s
}

fn all_commands<'a>(pts: &'a [Point], location: Location) -> Vec<Command<'a>> {
    vec![
        Command::New { count: 3 },
        Command::Pending(PointList::Points(pts)),
        Command::Runing,
        Command::Stopped,
        Command::UploadStart,
        Command::UploadStop,
        Command::PwmStart(Pwm {
            psc: 239,
            arr: 19_999,
            ccr1: 1_500,
            pulse_count: 0,
        }),
        Command::PwmStop,
        Command::UsartStart(UartInit {
            baud_rate: 115_200,
            ..UartInit::default()
        }),
        Command::UsartStop,
        Command::UsartSend(b"hello"),
        Command::Pin0On,
        Command::Pin0Off,
        Command::Pin1On,
        Command::Pin1Off,
        Command::ToggleEnablePins { mask: None },
        Command::ToggleEnablePins { mask: Some(0x101) },
        Command::Return,
        Command::JointsCount(4),
        Command::LocationSetting(location),
        Command::Status,
        Command::UploadPeriod { period_us: 20_000 },
    ]
}

/// The "allowed when" column of docs/PROTOCOL.md, "Commands (host to controller)"
/// (USART_SEND with the port closed).
fn allowed(cmd: &Command<'_>, state: State) -> StatusCode {
    use State::*;
    let ok_if = |yes: bool| if yes { Ok } else { BadState };
    match cmd {
        Command::New { .. } => ok_if(state != Running),
        Command::Pending(_) => ok_if(state != Stopped),
        Command::Runing => ok_if(matches!(state, Pending | Running)),
        Command::UsartSend(_) => BadState,
        Command::ToggleEnablePins { .. }
        | Command::Return
        | Command::JointsCount(_)
        | Command::LocationSetting(_) => ok_if(state == Stopped),
        _ => Ok,
    }
}

/// The state a command leaves behind when it succeeds.
fn state_after(cmd: &Command<'_>, state: State) -> State {
    match cmd {
        Command::New { .. } => State::New,
        Command::Pending(_) if state == State::New => State::Pending,
        Command::Runing => State::Running,
        Command::Stopped => State::Stopped,
        Command::Return => State::Running,
        _ => state,
    }
}

#[test]
fn every_command_in_every_state() {
    let location = Location {
        position: [5; 8],
        state: 0,
    };
    let mut checked = 0;
    for state in [State::Stopped, State::New, State::Pending, State::Running] {
        let from = if state == State::Stopped {
            [0; 8]
        } else {
            [2; 8]
        };
        let from = if state == State::New { [0; 8] } else { from };
        let pts = points(from, 1, 1);
        for cmd in all_commands(&pts, location) {
            let mut s = in_state(state);
            let buffered = s.controller.buffered();
            let ack = s.send(cmd);
            let want = allowed(&cmd, state);
            assert_eq!(ack.status, want, "{} in {}", cmd.tag().name(), state.name());
            assert_eq!(ack.acked_tag, cmd.tag() as u8);
            let expect_state = if want == Ok {
                state_after(&cmd, state)
            } else {
                state
            };
            assert_eq!(
                ack.state,
                expect_state,
                "{} in {}",
                cmd.tag().name(),
                state.name()
            );
            assert_eq!(s.controller.state(), expect_state);
            if want != Ok {
                assert_eq!(s.controller.buffered(), buffered, "refused: nothing done");
            }
            checked += 1;
        }
    }
    assert_eq!(checked, 4 * 22);
}

#[test]
fn usart_send_needs_an_open_port_that_transmits() {
    let mut s = Session::<16>::new(16);
    s.expect(Command::UsartSend(b"x"), BadState);
    let rx_only = UartInit {
        baud_rate: 9600,
        mode: 1,
        ..UartInit::default()
    };
    s.expect(Command::UsartStart(rx_only), Ok);
    s.expect(Command::UsartSend(b"x"), BadState);
    s.expect(Command::UsartStart(UartInit { mode: 2, ..rx_only }), Ok);
    for _ in 0..4 {
        s.expect(Command::UsartSend(b"abc"), Ok);
    }
    s.expect(Command::UsartSend(b"abc"), BufferFull);
    assert_eq!(s.plant.serial_sent.len(), 4);
    s.expect(Command::UsartStop, Ok);
    s.expect(Command::UsartSend(b"x"), BadState);
    s.plant.serial_refuses = true;
    s.expect(Command::UsartStart(rx_only), InvalidConfig);
    let status = s.controller.status(&s.plant);
    assert!(!status.flags.has(StatusFlags::SERIAL_OPEN));
}

/// Settings the board's USART cannot make are refused by the controller itself, so the
/// simulator (whose port accepts anything) refuses what the board refuses; the port is
/// never touched and the port stays as it was.
#[test]
fn usart_start_refuses_what_the_board_cannot_make() {
    use arm_core::uart::hal;
    let mut s = Session::<16>::new(16);
    let good = UartInit {
        baud_rate: 115_200,
        ..UartInit::default()
    };
    for bad in [
        UartInit {
            word_length: 0x0800,
            ..good
        },
        UartInit {
            stop_bits: 0x1000,
            ..good
        },
        UartInit {
            parity: 0x0200,
            ..good
        },
        UartInit {
            hw_flow_ctl: 0x0300,
            ..good
        },
        UartInit {
            over_sampling: 0x4000,
            ..good
        },
    ] {
        s.expect(Command::UsartStart(bad), InvalidConfig);
        assert_eq!(s.plant.serial, None, "{bad:?}");
        assert_eq!(s.plant.serial_opens, 0, "{bad:?}");
    }
    let seven_e2 = UartInit {
        parity: hal::PARITY_EVEN,
        stop_bits: hal::STOP_2,
        over_sampling: hal::OVERSAMPLING_8,
        ..good
    };
    s.expect(Command::UsartStart(seven_e2), Ok);
    assert_eq!(s.plant.serial, Some(seven_e2));
    s.expect(
        Command::UsartStart(UartInit {
            parity: 0x0200,
            ..good
        }),
        InvalidConfig,
    );
    assert_eq!(
        s.plant.serial,
        Some(seven_e2),
        "a refused USART_START keeps the port"
    );
    let status = s.controller.status(&s.plant);
    assert!(status.flags.has(StatusFlags::SERIAL_OPEN));
}

#[test]
fn golden_frames_get_the_right_status() {
    // As protocol's golden test: ARM_VECTORS overrides the copy beside the repository.
    let path = std::env::var_os("ARM_VECTORS").map_or_else(
        || {
            std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
                .join("../../../shared/vectors/frames.json")
        },
        std::path::PathBuf::from,
    );
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| {
        panic!(
            "golden frames not readable at {}: {e} (shared/ beside the repository, \
             or set ARM_VECTORS=/path/to/frames.json)",
            path.display()
        )
    });
    let json: serde_json::Value = serde_json::from_str(&text).expect("json");
    let mut checked = 0;
    for f in json["frames"].as_array().expect("frames") {
        if f["direction"] != "to_controller" {
            continue;
        }
        let hex = f["hex"].as_str().expect("hex");
        let bytes: Vec<u8> = (0..hex.len() / 2)
            .map(|i| u8::from_str_radix(&hex[2 * i..2 * i + 2], 16).expect("hex digit"))
            .collect();
        let mut s = Session::<64>::new(64);
        let response = s.send_raw(HOST, &bytes);
        let name = f["name"].as_str().unwrap_or("?");
        if bytes.len() < 3 {
            assert!(response.reply.is_none(), "{name}: no reply");
            checked += 1;
            continue;
        }
        let reply = response.reply.expect("an ACK");
        assert_eq!(
            (reply.seq, reply.ack.acked_tag),
            (bytes[0], bytes[1]),
            "{name}"
        );
        assert_eq!(reply.to, HOST);
        let want = match f["expect_status"].as_str() {
            Some(code) => {
                StatusCode::from_name(code).unwrap_or_else(|| panic!("unexpected code {code}"))
            }
            // Valid frames, at boot (STOPPED, serial closed).
            None => match Tag::from_u8(bytes[1]) {
                Some(Tag::Pending | Tag::Runing | Tag::UsartSend) => BadState,
                _ => Ok,
            },
        };
        assert_eq!(reply.ack.status, want, "{name}");
        checked += 1;
    }
    assert!(checked >= 30, "{checked} frames");
}

#[test]
fn short_datagrams_get_no_reply_and_bad_crc_is_acked_with_seq_and_tag() {
    let mut s = Session::<16>::new(16);
    assert!(s.send_raw(HOST, &[]).reply.is_none());
    assert!(s.send_raw(HOST, &[1, 2]).reply.is_none());
    let mut bytes = frame(42, Command::Pin0On);
    *bytes.last_mut().unwrap() ^= 0xFF;
    let reply = s.send_raw(OTHER, &bytes).reply.expect("ACK");
    assert_eq!(
        (reply.to, reply.seq, reply.ack.acked_tag),
        (OTHER, 42, 0x0c)
    );
    assert_eq!(reply.ack.status, BadCrc);
    assert!(s.plant.pins.is_empty());
    assert_eq!(
        s.controller.owner(),
        None,
        "a bad CRC does not make an owner"
    );
}

#[test]
fn owner_rule() {
    let mut s = Session::<16>::new(16);
    s.expect(Command::Pin0On, Ok);
    assert_eq!(s.controller.owner().map(|o| o.ip), Some(HOST.ip));
    // Another host is refused...
    let r = s.send_raw(OTHER, &frame(1, Command::Pin1On)).reply.unwrap();
    assert_eq!((r.to, r.ack.status), (OTHER, NotOwner));
    assert!(!s.plant.pins.contains(&(1, true)));
    // ... but may stop the arm.
    s.start_run(2, &points([0; 8], 2, 1));
    let stops = s.plant.stops;
    let r = s.send_raw(OTHER, &frame(9, Command::Stopped));
    assert_eq!(r.reply.map(|r| (r.to, r.ack.status)), Some((OTHER, Ok)));
    assert_eq!(s.controller.state(), State::Stopped);
    assert_eq!(s.plant.stops, stops + 1);
    assert_eq!(s.controller.owner().map(|o| o.ip), Some(HOST.ip));
    // LOCATION goes to each owner endpoint whose command was executed.
    s.from = Endpoint {
        port: 41_000,
        ..HOST
    };
    s.expect(Command::UploadStart, Ok);
    assert!(
        s.controller
            .report_settings()
            .location_goes_to(s.from, s.now_us)
    );
    // A refused frame does not add its sender.
    s.from = Endpoint {
        port: 41_001,
        ..HOST
    };
    s.expect(Command::Runing, BadState);
    assert!(
        !s.controller
            .report_settings()
            .location_goes_to(s.from, s.now_us)
    );
    // After 5 s of silence, not running, another host takes over.
    s.now_us += OWNER_TIMEOUT_US - 100;
    let r = s
        .send_raw(OTHER, &frame(2, Command::UploadStart))
        .reply
        .unwrap();
    assert_eq!(r.ack.status, NotOwner);
    // Its STATUS is answered read-only (issue 23) and takes nothing.
    let r = s.send_raw(OTHER, &frame(2, Command::Status));
    assert_eq!(r.answer_seq, Some(2));
    assert_eq!(s.controller.owner().map(|o| o.ip), Some(HOST.ip));
    s.now_us += 100;
    let r = s.send_raw(OTHER, &frame(3, Command::Status)).reply.unwrap();
    assert_eq!(r.ack.status, Ok);
    assert_eq!(
        s.controller.report_settings().location_to,
        [Some(OTHER), None, None, None]
    );
    let r = s
        .send_raw(HOST, &frame(50, Command::UploadStart))
        .reply
        .unwrap();
    assert_eq!(r.ack.status, NotOwner);
}

#[test]
fn no_takeover_while_running() {
    let mut s = Session::<16>::new(16);
    s.start_run(2, &points([0; 8], 2, 1));
    s.now_us += 10 * OWNER_TIMEOUT_US;
    let r = s
        .send_raw(OTHER, &frame(3, Command::UploadStart))
        .reply
        .unwrap();
    assert_eq!(r.ack.status, NotOwner);
    // Read-only STATUS (issue 23): answered, takes nothing.
    let r = s.send_raw(OTHER, &frame(3, Command::Status));
    assert_eq!((r.reply.unwrap().ack.status, r.answer_seq), (Ok, Some(3)));
    s.plant.run_to_end(&mut s.controller);
    assert_eq!(s.controller.state(), State::Stopped);
    let r = s.send_raw(OTHER, &frame(4, Command::Status)).reply.unwrap();
    assert_eq!(r.ack.status, Ok, "not running any more");
}

#[test]
fn duplicates_are_acked_and_not_executed_twice() {
    let mut s = Session::<16>::new(16);
    let pin = frame(7, Command::Pin0On);
    for _ in 0..3 {
        let r = s.send_raw(HOST, &pin).reply.unwrap();
        assert_eq!((r.seq, r.ack.status), (7, Ok));
    }
    assert_eq!(s.plant.pins, vec![(0, true)]);
    s.send_raw(HOST, &frame(8, Command::New { count: 10 }));
    let p = pending(9, &points([0; 8], 3, 1));
    for _ in 0..2 {
        assert_eq!(s.send_raw(HOST, &p).reply.unwrap().ack.status, Ok);
    }
    assert_eq!(s.controller.buffered(), 3);
    // The same bytes from another port are another frame.
    let r = s
        .send_raw(Endpoint { port: 1, ..HOST }, &pin)
        .reply
        .unwrap();
    assert_eq!(r.ack.status, Ok);
    assert_eq!(s.plant.pins.len(), 2);
    // After 2 s a frame is no longer a duplicate.
    s.now_us += 2_000_000;
    s.send_raw(HOST, &pin);
    assert_eq!(s.plant.pins.len(), 3);
}

#[test]
fn out_of_order_pending_names_the_missing_seq() {
    let mut s = Session::<64>::new(64);
    s.send_raw(HOST, &frame(100, Command::New { count: 9 }));
    let pts = points([0; 8], 9, 1);
    let r = s.send_raw(HOST, &pending(102, &pts[0..3])).reply.unwrap();
    assert_eq!((r.ack.status, r.ack.next_seq), (OutOfOrder, 101));
    assert_eq!(s.controller.buffered(), 0);
    // A command accepted with 101 fills the gap.
    s.send_raw(HOST, &frame(101, Command::Status));
    let r = s.send_raw(HOST, &pending(102, &pts[0..3])).reply.unwrap();
    assert_eq!((r.ack.status, r.ack.next_seq), (Ok, 103));
    // A command refused for a reason a resend can change (RETURN while an upload is
    // pending: BAD_STATE) does not fill it: the PENDING after it names it, and the host
    // resends it (a RUNING that overtook its PENDING is accepted that way).
    let r = s
        .send_raw(HOST, &frame(103, Command::Return))
        .reply
        .unwrap();
    assert_eq!(r.ack.status, BadState);
    let r = s.send_raw(HOST, &pending(104, &pts[3..6])).reply.unwrap();
    assert_eq!((r.ack.status, r.ack.next_seq), (OutOfOrder, 103));
    let r = s.send_raw(HOST, &pending(103, &pts[3..6])).reply.unwrap();
    assert_eq!((r.ack.status, r.ack.next_seq), (Ok, 104));
    assert_eq!(s.controller.buffered(), 6);
    // One these bytes can never make acceptable fills it (issue 21 F12: it did not, and a
    // host resending from next_seq as section 7 says looped).
    let bad_pwm = Command::PwmStart(protocol::Pwm {
        psc: 0,
        arr: 10,
        ccr1: 20,
        pulse_count: 0,
    });
    let r = s.send_raw(HOST, &frame(104, bad_pwm)).reply.unwrap();
    assert_eq!(r.ack.status, InvalidConfig);
    let r = s.send_raw(HOST, &pending(105, &pts[6..9])).reply.unwrap();
    assert_eq!((r.ack.status, r.ack.next_seq), (Ok, 106));
    assert_eq!(s.controller.buffered(), 9);
}

/// Issue 21 F12: a command refused in the middle of an upload, from a host that follows
/// section 7 (resend from the ACK's next_seq, unchanged): the upload goes on, no loop.
#[test]
fn a_refused_command_inside_an_upload_does_not_stall_it() {
    let mut s = Session::<64>::new(64);
    s.send_raw(HOST, &frame(10, Command::New { count: 6 }));
    let pts = points([0; 8], 6, 1);
    assert_eq!(
        s.send_raw(HOST, &pending(11, &pts[0..3]))
            .reply
            .unwrap()
            .ack
            .status,
        Ok
    );
    // A gripper setting the board cannot make (CCR1 > ARR): INVALID_CONFIG.
    let bad_pwm = frame(
        12,
        Command::PwmStart(protocol::Pwm {
            psc: 0,
            arr: 10,
            ccr1: 20,
            pulse_count: 0,
        }),
    );
    let r = s.send_raw(HOST, &bad_pwm).reply.unwrap();
    assert_eq!(r.ack.status, InvalidConfig);
    // The host goes on with its upload; at most a few rounds of section 7, never a loop.
    let mut next = 13u8;
    for round in 0..4 {
        let r = s.send_raw(HOST, &pending(next, &pts[3..6])).reply.unwrap();
        if r.ack.status == Ok {
            assert_eq!(s.controller.buffered(), 6);
            return;
        }
        assert_eq!(r.ack.status, OutOfOrder, "round {round}");
        // Section 7: resend from next_seq, unchanged.
        if r.ack.next_seq == 12 {
            s.send_raw(HOST, &bad_pwm);
        }
        next = 13;
    }
    panic!("the upload never went on past the refused PWM_START");
}

#[test]
fn buffer_full_and_streaming() {
    let mut s = Session::<8>::new(4);
    assert_eq!(s.controller.capacity(), 4);
    s.expect(Command::New { count: 10 }, Ok);
    let pts = points([0; 8], 10, 1);
    let a = s.pending(&pts[0..3]);
    assert_eq!((a.status, a.buffered, a.free), (Ok, 3, 1));
    let seq_before = s.seq;
    let a = s.pending(&pts[3..6]);
    assert_eq!((a.status, a.buffered, a.free), (BufferFull, 3, 1));
    assert_eq!(a.next_seq, seq_before.wrapping_add(1), "resend from here");
    s.seq = seq_before;
    s.expect(Command::Runing, Ok);
    // Two points finish: their slots are free again.
    s.plant.run(&mut s.controller, 2);
    assert_eq!(s.controller.free(), 3);
    let a = s.pending(&pts[3..6]);
    assert_eq!((a.status, a.state), (Ok, State::Running));
    s.plant.run(&mut s.controller, 3);
    assert_eq!(s.pending(&pts[6..9]).status, Ok);
    s.plant.run(&mut s.controller, 3);
    assert_eq!(s.pending(&pts[9..10]).status, Ok);
    let loc = s
        .plant
        .run_to_end(&mut s.controller)
        .expect("LOCATION at the end");
    assert_eq!(loc.state, State::Stopped as u8);
    assert_eq!(s.plant.positions, [10, 10, 10, 10, 10, 10, 0, 0]);
    let status = s.controller.status(&s.plant);
    assert_eq!(
        (status.executed, status.received, status.expected),
        (10, 10, 10)
    );
    assert!(!status.flags.has(StatusFlags::UNDERRUN));
}

#[test]
fn too_many_points() {
    let mut s = Session::<16>::new(16);
    s.expect(Command::New { count: 2 }, Ok);
    let pts = points([0; 8], 3, 1);
    assert_eq!(s.pending(&pts).status, TooManyPoints);
    assert_eq!(s.controller.buffered(), 0);
    s.seq = s.seq.wrapping_sub(1);
    assert_eq!(s.pending(&pts[..2]).status, Ok);
    assert_eq!(s.pending(&pts[2..]).status, TooManyPoints);
}

#[test]
fn invalid_point_takes_nothing() {
    let mut s = Session::<16>::new(16);
    s.expect(Command::New { count: 10 }, Ok);
    let max = s.controller.config().max_step_rate_hz as i32;
    let mut pts = points([0; 8], 3, 1);
    // Point 2: joint 0 at one step over the limit (max/1000 steps in 1 ms is allowed).
    let mut fast = pts[1].position;
    fast[0] += max / 1000 + 1;
    pts[2] = Point::from_motion(1_000, &pts[1].position, &fast);
    let before = s.controller.next_seq();
    let a = s.pending(&pts);
    assert_eq!(
        (a.status, a.buffered, a.next_seq),
        (InvalidPoint, 0, before)
    );
    // Exactly at the limit is fine, and joints beyond JOINTS_COUNT are not checked.
    fast[0] -= 1;
    fast[7] += 1_000_000;
    pts[2] = Point::from_motion(1_000, &pts[1].position, &fast);
    s.seq = s.seq.wrapping_sub(1);
    assert_eq!(s.pending(&pts).status, Ok);
    s.expect(Command::Runing, Ok);
    s.plant.run(&mut s.controller, 3);
    assert_eq!(s.plant.positions[0], 2 + max / 1000);
    assert_eq!(s.plant.positions[7], 0, "joint 7 is not in use (6 joints)");
    // Duration 0 is refused by decode.
    let mut zero = points(s.plant.positions, 1, 1);
    zero[0].duration = 0;
    assert_eq!(s.pending(&zero).status, InvalidPoint);
}

#[test]
fn first_point_starts_from_the_position_at_new() {
    let mut s = Session::<16>::new(16);
    s.set_location([100, -100, 0, 0, 0, 0, 0, 0]);
    s.expect(Command::New { count: 1 }, Ok);
    let target = [103, -90, 1, 0, 0, 0, 0, 0];
    s.pending(&[Point::from_motion(500, &[0; 8], &target)]);
    s.expect(Command::Runing, Ok);
    s.plant.run_to_end(&mut s.controller);
    assert_eq!(s.plant.executed[0].steps, [3, 10, 1, 0, 0, 0, 0, 0]);
    assert_eq!(s.plant.executed[0].duration_us, 500);
}

#[test]
fn underrun_stops_at_the_end_of_the_last_point() {
    let mut s = Session::<16>::new(16);
    s.start_run(5, &points([0; 8], 2, 3));
    let loc = s.plant.run_to_end(&mut s.controller).expect("LOCATION");
    assert_eq!((loc.state, loc.position[0]), (State::Stopped as u8, 6));
    let status = s.controller.status(&s.plant);
    assert!(status.flags.has(StatusFlags::UNDERRUN));
    assert!(!status.flags.has(StatusFlags::STOPPED_BY_HOST));
    assert_eq!((status.executed, status.expected), (2, 5));
    // Late points are refused now.
    assert_eq!(s.pending(&points([6; 8], 1, 1)).status, BadState);
}

#[test]
fn stopped_drops_the_buffer_and_sets_its_flag() {
    let mut s = Session::<16>::new(16);
    s.start_run(5, &points([0; 8], 5, 1));
    s.plant.run(&mut s.controller, 1);
    let stops = s.plant.stops;
    let r = s.send_raw(HOST, &frame(s.seq.wrapping_add(1), Command::Stopped));
    assert_eq!(s.plant.stops, stops + 1);
    assert_eq!(r.location.map(|l| l.state), Some(State::Stopped as u8));
    assert_eq!(s.controller.buffered(), 0);
    let status = s.controller.status(&s.plant);
    assert!(status.flags.has(StatusFlags::STOPPED_BY_HOST));
    assert_eq!(
        s.plant.positions,
        [1, 1, 1, 1, 1, 1, 0, 0],
        "6 joints in use"
    );
}

#[test]
fn location_on_state_changes_only_while_reports_are_on() {
    let mut s = Session::<16>::new(16);
    s.seq = 1;
    let r = s.send_raw(HOST, &frame(2, Command::New { count: 1 }));
    assert_eq!(r.location.map(|l| l.state), Some(State::New as u8));
    let r = s.send_raw(HOST, &frame(3, Command::Status));
    assert!(r.location.is_none(), "no change");
    assert_eq!(r.status.map(|(_, st)| st.version), Some(protocol::VERSION));
    s.send_raw(HOST, &frame(4, Command::UploadStop));
    let r = s.send_raw(HOST, &pending(5, &points([0; 8], 1, 1)));
    assert_eq!(r.reply.map(|r| r.ack.status), Some(Ok));
    assert!(r.location.is_none(), "reports off");
    assert!(!s.controller.report_settings().reports_on);
}

#[test]
fn status_report_fields() {
    let mut s = Session::<32>::new(20);
    s.expect(Command::Pin1On, Ok);
    s.expect(Command::UploadPeriod { period_us: 5_000 }, Ok);
    s.expect(
        Command::PwmStart(Pwm {
            psc: 1,
            arr: 2,
            ccr1: 1,
            pulse_count: 5,
        }),
        Ok,
    );
    s.expect(Command::ToggleEnablePins { mask: None }, Ok);
    s.expect(Command::JointsCount(3), Ok);
    s.expect(Command::New { count: 7 }, Ok);
    // Points that hold still: every driver is limp, and since issue 31 a point that moves
    // a limp joint is refused (this test moved them by 1 step before).
    assert_eq!(s.pending(&points([0; 8], 2, 0)).status, Ok);
    let st = s.controller.status(&s.plant);
    assert_eq!(st.version, protocol::VERSION);
    assert_eq!((st.joints, st.state), (3, State::Pending));
    assert_eq!(
        (st.buffered, st.expected, st.received, st.executed),
        (2, 7, 2, 0)
    );
    assert_eq!(st.capacity, 20);
    assert_eq!(st.upload_period_us, 5_000);
    assert_eq!(st.max_step_rate_hz, s.controller.config().max_step_rate_hz);
    assert_eq!(
        st.pwm_timer_clock_hz,
        s.controller.config().pwm_timer_clock_hz
    );
    let f = st.flags;
    assert!(f.has(StatusFlags::REPORTS_ON | StatusFlags::PIN1_HIGH | StatusFlags::PWM_ACTIVE));
    assert!(!f.has(StatusFlags::DRIVERS_ENABLED), "all toggled off");
    assert!(!f.has(StatusFlags::PIN0_HIGH) && !f.has(StatusFlags::SERIAL_OPEN));
}

#[test]
fn enable_pins_toggle_all_or_by_mask() {
    let mut s = Session::<16>::new(16);
    assert_eq!(s.controller.enabled(), 0x1FF, "drivers boot enabled");
    s.expect(Command::ToggleEnablePins { mask: Some(0x0003) }, Ok);
    s.expect(Command::ToggleEnablePins { mask: None }, Ok);
    s.expect(Command::ToggleEnablePins { mask: Some(0x0100) }, Ok);
    assert_eq!(s.plant.enabled, vec![0x1FC, 0x003, 0x103]);
}

#[test]
fn joints_count_is_saved_and_limits_the_checked_joints() {
    let mut s = Session::<16>::new(16);
    let r = s.send_raw(HOST, &frame(1, Command::JointsCount(2)));
    let saved = match r.deferred {
        Some(Deferred::SaveSettings(settings)) => settings,
        other => panic!("expected a save, got {other:?}"),
    };
    assert_eq!(saved.joints, 2);
    assert_eq!(s.controller.joints(), 2);
    s.seq = 1;
    s.expect(Command::New { count: 1 }, Ok);
    // Joint 2 may now move as fast as it likes: it is ignored (kept where it is).
    let p = Point::from_motion(1_000, &[0; 8], &[1, 1, 1_000_000, 0, 0, 0, 0, 0]);
    s.pending(&[p]);
    s.expect(Command::Runing, Ok);
    s.plant.run_to_end(&mut s.controller);
    assert_eq!(s.plant.positions, [1, 1, 0, 0, 0, 0, 0, 0]);
}

#[test]
fn return_reads_encoders_then_moves_every_joint_to_zero() {
    let mut s = Session::<64>::new(64);
    s.set_location([500, -300, 0, 0, 0, 0, 7, 7]);
    let r = s.send_raw(HOST, &frame(9, Command::Return));
    assert_eq!(
        r.reply.map(|r| (r.ack.status, r.ack.state)),
        Some((Ok, State::Running))
    );
    assert_eq!(r.deferred, Some(Deferred::ReadEncoders));
    // The encoders disagree with the step count on joint 1: they win.
    let encoders = [500, -320, 0, 0, 0, 0, 0, 0];
    assert!(
        s.controller
            .begin_return(Some(encoders), &mut s.plant)
            .is_none()
    );
    assert_eq!(
        s.plant.set_positions_calls.last(),
        Some(&[500, -320, 0, 0, 0, 0, 7, 7])
    );
    assert!(s.plant.running);
    // STOPPED works during it... but here it runs to the end.
    let loc = s
        .plant
        .run_to_end(&mut s.controller)
        .expect("LOCATION at the end");
    assert_eq!(loc.state, State::Stopped as u8);
    assert_eq!(
        s.plant.positions,
        [0, 0, 0, 0, 0, 0, 7, 7],
        "joints 6, 7 not in use"
    );
    let status = s.controller.status(&s.plant);
    assert!(status.executed > 0 && status.executed == status.expected);
    // Every point is a normal segment within the board's step rate.
    for seg in &s.plant.executed {
        for j in 0..MAX_JOINTS {
            let rate =
                u64::from(seg.steps[j].unsigned_abs()) * 1_000_000 / u64::from(seg.duration_us);
            assert!(rate <= u64::from(s.controller.config().return_speed[j]));
        }
    }
    // A RETURN with nothing to move ends at once.
    let r = s.send_raw(HOST, &frame(10, Command::Return));
    assert_eq!(r.deferred, Some(Deferred::ReadEncoders));
    let loc = s.controller.begin_return(None, &mut s.plant);
    assert_eq!(loc.map(|l| l.state), Some(State::Stopped as u8));
}

#[test]
fn stopped_during_return_and_pending_refused() {
    let mut s = Session::<64>::new(64);
    s.set_location([5_000; 8]);
    s.expect(Command::Return, Ok);
    s.controller.begin_return(None, &mut s.plant);
    s.plant.run(&mut s.controller, 3);
    assert_eq!(
        s.pending(&points(s.plant.positions, 1, -1)).status,
        BadState
    );
    let at = s.plant.positions;
    s.expect(Command::Stopped, Ok);
    assert_eq!(s.controller.state(), State::Stopped);
    assert!(s.plant.queue.is_empty());
    assert_eq!(s.plant.positions, at);
}

#[test]
fn a_long_return_streams_through_a_small_buffer() {
    let mut s = Session::<8>::new(8);
    s.set_location([40_000, 0, 0, 0, 0, 0, 0, 0]);
    s.expect(Command::Return, Ok);
    s.controller.begin_return(None, &mut s.plant);
    assert!(s.controller.buffered() <= 8);
    s.plant.run_to_end(&mut s.controller);
    assert_eq!(s.plant.positions[0], 0);
    assert!(s.plant.executed.len() > 8);
    assert!(
        !s.controller
            .status(&s.plant)
            .flags
            .has(StatusFlags::UNDERRUN)
    );
}

#[test]
fn segments_are_fed_only_as_the_engine_takes_them() {
    let mut s = Session::<64>::new(64);
    s.plant.room = 2;
    s.expect(Command::New { count: 6 }, Ok);
    s.pending(&points([0; 8], 6, 2));
    assert_eq!(s.plant.queue.len(), 2, "pre-fed before RUNING");
    s.expect(Command::Runing, Ok);
    let mut total = 0;
    while s.plant.running {
        s.plant.run(&mut s.controller, 1);
        total += 1;
        assert!(total <= 6);
    }
    let steps: Vec<i32> = s.plant.executed.iter().map(|g| g.steps[0]).collect();
    assert_eq!(steps, vec![2; 6]);
    assert_eq!(s.controller.state(), State::Stopped);
}

#[test]
fn new_drops_an_upload_that_is_not_running() {
    let mut s = Session::<16>::new(16);
    s.expect(Command::New { count: 3 }, Ok);
    s.pending(&points([0; 8], 2, 1));
    assert_eq!(s.plant.queue.len(), 2);
    s.expect(Command::New { count: 1 }, Ok);
    assert!(s.plant.queue.is_empty() && s.controller.buffered() == 0);
    let st = s.controller.status(&s.plant);
    assert_eq!((st.expected, st.received), (1, 0));
    let _ = StoredPoint::default();
}

#[test]
fn stop_after_overtaken_applies_stopped_without_an_ack() {
    // A RUNING overtaken by a STOPPED: handled as usual, then stopped again.
    let mut s = in_state(State::Pending);
    let runing = frame(s.seq.wrapping_add(1), Command::Runing);
    let r = s.send_raw(HOST, &runing);
    assert_eq!(r.reply.map(|r| r.ack.state), Some(State::Running));
    assert!(s.plant.running);
    let (stops, starts) = (s.plant.stops, s.plant.starts);
    let loc = s.controller.stop_after_overtaken(&mut s.plant);
    assert_eq!(loc.map(|l| l.state), Some(State::Stopped as u8));
    assert_eq!(s.plant.stops, stops + 1);
    assert!(!s.plant.running && s.plant.queue.is_empty());
    assert!(s.plant.executed.is_empty(), "nothing ran");
    assert_eq!(s.controller.state(), State::Stopped);
    assert_eq!(s.controller.buffered(), 0);
    let status = s.controller.status(&s.plant);
    assert!(status.flags.has(StatusFlags::STOPPED_BY_HOST));
    assert!(!status.flags.has(StatusFlags::UNDERRUN));
    // The RUNING resent: a duplicate, ACKed and not run again.
    let r = s.send_raw(HOST, &runing);
    assert_eq!(
        r.reply.map(|r| (r.ack.status, r.ack.state)),
        Some((Ok, State::Stopped))
    );
    assert_eq!(s.plant.starts, starts);

    // An upload (NEW) cut: bit 7 too; reports off: no LOCATION.
    let mut s = in_state(State::New);
    s.expect(Command::UploadStop, Ok);
    assert_eq!(s.controller.stop_after_overtaken(&mut s.plant), None);
    assert_eq!(s.controller.state(), State::Stopped);
    assert!(
        s.controller
            .status(&s.plant)
            .flags
            .has(StatusFlags::STOPPED_BY_HOST)
    );

    // A RETURN waiting for its encoder reading: cancelled, it never starts.
    let mut s = Session::<64>::new(64);
    s.set_location([300; 8]);
    s.expect(Command::Return, Ok);
    let loc = s.controller.stop_after_overtaken(&mut s.plant);
    assert_eq!(loc.map(|l| l.state), Some(State::Stopped as u8));
    assert_eq!(s.controller.begin_return(None, &mut s.plant), None);
    assert_eq!((s.plant.starts, s.plant.running), (0, false));
    assert_eq!(s.plant.positions, [300; 8]);

    // Already STOPPED (the last run ended by underrun): nothing done, flags kept.
    let mut s = in_state(State::Running);
    s.plant.run_to_end(&mut s.controller);
    assert_eq!(s.controller.state(), State::Stopped);
    let stops = s.plant.stops;
    assert_eq!(s.controller.stop_after_overtaken(&mut s.plant), None);
    assert_eq!(s.plant.stops, stops);
    let flags = s.controller.status(&s.plant).flags;
    assert!(flags.has(StatusFlags::UNDERRUN) && !flags.has(StatusFlags::STOPPED_BY_HOST));
}

/// `init_in_place` (how the boards build their 300 KB controller) gives the same controller
/// as `new`, whatever the storage held before: same getters, same STATUS, and the same
/// answers to an upload, a run and its end.
#[test]
fn a_controller_built_in_place_behaves_as_new() {
    use std::mem::MaybeUninit;
    const CAP: usize = 64;
    let config = ControllerConfig {
        capacity: 48,
        ..ControllerConfig::BOARD
    };
    // Storage full of garbage: a field that init_in_place forgot would show up as a
    // difference below.
    let mut slot = Box::new(MaybeUninit::<Controller<CAP>>::uninit());
    // SAFETY: filling the bytes of a MaybeUninit is always sound.
    unsafe {
        slot.as_mut_ptr()
            .cast::<u8>()
            .write_bytes(0xA5, size_of::<Controller<CAP>>())
    };
    let in_place = Controller::<CAP>::init_in_place(&mut slot, config);
    let mut by_value = Controller::<CAP>::new(config);

    let plant = FakePlant::default();
    assert_eq!(in_place.status(&plant), by_value.status(&plant));
    assert_eq!(in_place.location(&plant), by_value.location(&plant));
    assert_eq!(in_place.report_settings(), by_value.report_settings());
    assert_eq!(in_place.settings(), by_value.settings());
    assert_eq!(
        (in_place.capacity(), in_place.free(), in_place.next_seq()),
        (by_value.capacity(), by_value.free(), by_value.next_seq())
    );

    let pts = points([0; MAX_JOINTS], 6, 3);
    let frames = [
        frame(1, Command::Status),
        frame(2, Command::New { count: 6 }),
        pending(3, &pts),
        frame(4, Command::Runing),
        frame(5, Command::Status),
    ];
    let (mut plant_a, mut plant_b) = (FakePlant::default(), FakePlant::default());
    for (i, bytes) in frames.iter().enumerate() {
        let now = 1_000 + 100 * i as u64;
        let a = in_place.handle(HOST, bytes, now, &mut plant_a);
        let b = by_value.handle(HOST, bytes, now, &mut plant_b);
        assert_eq!(format!("{a:?}"), format!("{b:?}"), "frame {i}");
    }
    assert_eq!(in_place.status(&plant_a), by_value.status(&plant_b));
}
