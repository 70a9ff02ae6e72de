//! CLI parsing and `frame encode`/`frame decode` against the golden frames.

use clap::Parser;

use crate::cli::{self, Cli, Cmd, OnOff};
use crate::frame::{self, Direction, EncodeCmd, FrameCmd};
use crate::pwm::PwmCmd;
use crate::run;

fn parse(args: &[&str]) -> Cli {
    Cli::try_parse_from(std::iter::once("armctl").chain(args.iter().copied()))
        .unwrap_or_else(|e| panic!("{args:?}: {e}"))
}

fn refused(args: &[&str]) -> String {
    match Cli::try_parse_from(std::iter::once("armctl").chain(args.iter().copied())) {
        Ok(cli) => panic!("{args:?} parsed as {cli:?}"),
        Err(e) => e.to_string(),
    }
}

#[test]
fn global_controller_option_and_default() {
    assert_eq!(parse(&["status"]).controller, "127.0.0.1:8510");
    let cli = parse(&["--controller", "127.0.0.2:9000", "stop"]);
    assert_eq!(cli.controller, "127.0.0.2:9000");
    assert!(matches!(cli.command, Cmd::Stop));
    // Global: also after the subcommand.
    assert_eq!(
        parse(&["status", "--controller", "127.0.0.3:1"]).controller,
        "127.0.0.3:1"
    );
}

#[test]
fn run_options() {
    let cli = parse(&[
        "run",
        "t.json",
        "--config",
        "arm.json",
        "--segment-ms",
        "5",
        "--window",
        "1",
        "--record",
        "rec.csv",
    ]);
    let Cmd::Run(args) = cli.command else {
        panic!("not run")
    };
    assert_eq!(args.file.to_str(), Some("t.json"));
    assert_eq!(
        args.config.as_deref().and_then(|p| p.to_str()),
        Some("arm.json")
    );
    assert_eq!(args.segment_ms, 5.0);
    assert_eq!(args.window, Some(1));
    assert_eq!(
        args.record.as_deref().and_then(|p| p.to_str()),
        Some("rec.csv")
    );
    assert!(refused(&["run", "t.csv", "--window", "33"]).contains("33"));
    assert!(refused(&["run", "t.csv", "--window", "0"]).contains('0'));
    let Cmd::Run(args) = parse(&["run", "t.csv", "--window", "32"]).command else {
        panic!("not run")
    };
    assert_eq!(args.window, Some(32));
    // Default: the controller's advertised window.
    let Cmd::Run(args) = parse(&["run", "t.csv"]).command else {
        panic!("not run")
    };
    assert_eq!(args.window, None);
    assert_eq!(args.max_step_rate, run::DEFAULT_MAX_STEP_RATE_HZ);
}

#[test]
fn controller_address_gets_the_default_port() {
    use armctl::controller_address as addr;
    assert_eq!(addr("192.168.1.30"), "192.168.1.30:8510");
    assert_eq!(addr("192.168.1.30:9000"), "192.168.1.30:9000");
    assert_eq!(addr("localhost"), "localhost:8510");
    assert_eq!(addr("localhost:7"), "localhost:7");
    assert_eq!(addr("arm-1.lab"), "arm-1.lab:8510");
    assert_eq!(addr("::1"), "[::1]:8510");
    assert_eq!(addr("[::1]"), "[::1]:8510");
    assert_eq!(addr("[::1]:9"), "[::1]:9");
    assert_eq!(addr(" 127.0.0.1 "), "127.0.0.1:8510");
}

#[test]
fn resends_past_the_duplicate_window_are_warned_about() {
    assert_eq!(cli::resend_warning(100, 10), None);
    assert_eq!(cli::resend_warning(200, 10), None);
    let warning = cli::resend_warning(500, 10).expect("5 s of resends");
    assert!(warning.contains("5.0 s"), "{warning}");
    assert!(warning.contains("2 s duplicate window"), "{warning}");
}

#[test]
fn small_commands() {
    assert!(matches!(
        parse(&["joints", "6"]).command,
        Cmd::Joints { n: 6 }
    ));
    refused(&["joints", "9"]);
    refused(&["joints", "0"]);
    let Cmd::SetLocation { positions } = parse(&["set-location", "1", "-2", "300"]).command else {
        panic!()
    };
    assert_eq!(positions, vec![1, -2, 300]);
    refused(&["set-location"]);
    refused(&["set-location", "1", "2", "3", "4", "5", "6", "7", "8", "9"]);
    // Issue 23: `enable` and `disable` are explicit (SET_ENABLE); the toggle is
    // `toggle-enable`.
    assert!(matches!(
        parse(&["toggle-enable", "--mask", "0x1ff"]).command,
        Cmd::ToggleEnable { mask: Some(0x1FF) }
    ));
    assert!(matches!(
        parse(&["toggle-enable"]).command,
        Cmd::ToggleEnable { mask: None }
    ));
    assert!(refused(&["toggle-enable", "--mask", "0x200"]).contains("bits above 8"));
    let drivers = |args: &[&str]| match parse(args).command {
        Cmd::Enable { joints } | Cmd::Disable { joints } => crate::enable::mask_of(&joints),
        other => panic!("{other:?}"),
    };
    assert_eq!(drivers(&["enable"]), 0x1FF);
    assert_eq!(drivers(&["disable"]), 0x1FF);
    assert_eq!(drivers(&["disable", "0", "1"]), 0x003);
    assert_eq!(drivers(&["enable", "2,5", "gripper"]), 0x124);
    assert_eq!(drivers(&["enable", "all"]), 0x1FF);
    assert!(matches!(
        parse(&["disable", "3"]).command,
        Cmd::Disable { .. }
    ));
    assert!(refused(&["enable", "8"]).contains("joint numbers 0-7"));
    assert!(refused(&["disable", "--mask", "3"]).contains("--mask"));
    assert_eq!(
        crate::enable::describe(0x103),
        "joints 0, 1 and the gripper"
    );
    assert_eq!(crate::enable::describe(0x004), "joint 2");
    assert_eq!(crate::enable::describe(0x1FF), "every driver");
    assert!(matches!(
        parse(&["pin", "1", "on"]).command,
        Cmd::Pin {
            pin: 1,
            level: OnOff::On
        }
    ));
    refused(&["pin", "2", "on"]);
    refused(&["pin", "0", "maybe"]);
    assert!(matches!(
        parse(&["upload-period", "20000"]).command,
        Cmd::UploadPeriod { us: 20000 }
    ));
    assert!(matches!(
        parse(&["return", "--wait"]).command,
        Cmd::Return { wait: true }
    ));
    assert!(matches!(
        parse(&["serial", "--baud", "9600"]).command,
        Cmd::Serial { baud: 9600, .. }
    ));
    assert!(matches!(parse(&["estop-reset"]).command, Cmd::EstopReset));
}

#[test]
fn unlock_command_and_frame() {
    assert!(matches!(parse(&["unlock"]).command, Cmd::Unlock));
    assert_eq!(
        encode(&["frame", "encode", "--seq", "33", "unlock"]),
        format!("2125{:02x}", protocol::crc8(&[0x21, 0x25]))
    );
}

/// Issue 33: `status` names a latched limit's joint (with its config name) and side, and
/// the homing cycle's result; nothing when there is nothing to say.
#[test]
fn the_switches_line_names_the_latched_limit_and_the_homing() {
    use protocol::{HomingFailure, HomingPhase, SwitchesReport};
    assert_eq!(
        crate::status::switches_line(&SwitchesReport::default(), None),
        None
    );
    let latched = SwitchesReport {
        latched: Some(0x82),
        max_active: 0b100,
        ..SwitchesReport::default()
    };
    let names = [None, None, Some("elbow".to_string())];
    let line = crate::status::switches_line(&latched, Some(&names)).unwrap();
    assert!(
        line.contains("LATCHED on the max limit of joint 2 (elbow)"),
        "{line}"
    );
    assert!(
        line.contains("max limit of joint 2 (elbow) pressed"),
        "{line}"
    );
    let failed = SwitchesReport {
        phase: HomingPhase::Failed,
        joint: 1,
        error: Some(HomingFailure::SeekTravel),
        ..SwitchesReport::default()
    };
    let line = crate::status::switches_line(&failed, None).unwrap();
    assert!(
        line.contains("homing failed on joint 1: the seek travelled its maximum"),
        "{line}"
    );
}

#[test]
fn estop_category_sets_shows_and_encodes() {
    assert!(matches!(
        parse(&["estop-category", "1"]).command,
        Cmd::EstopCategory { category: Some(1) }
    ));
    assert!(matches!(
        parse(&["estop-category"]).command,
        Cmd::EstopCategory { category: None }
    ));
    assert!(Cli::try_parse_from(["armctl", "estop-category", "2"]).is_err());
    // PROTOCOL.md's worked example.
    assert_eq!(
        encode(&["frame", "encode", "--seq", "58", "estop-category", "1"]),
        "3a2b0158"
    );
    use crate::single::estop_category_line;
    use protocol::EStopCategory;
    assert!(estop_category_line(Some(Some(EStopCategory::Controlled))).contains("category 1"));
    assert!(estop_category_line(Some(Some(EStopCategory::Instant))).contains("category 0"));
    assert!(estop_category_line(None).contains("predates"));
}

#[test]
fn hold_resume_override_and_run_speed() {
    assert!(matches!(parse(&["hold"]).command, Cmd::Hold));
    assert!(matches!(parse(&["resume"]).command, Cmd::Resume));
    assert!(matches!(
        parse(&["override", "25"]).command,
        Cmd::Override { percent: 25 }
    ));
    for bad in ["0", "201"] {
        assert!(
            Cli::try_parse_from(["armctl", "override", bad]).is_err(),
            "{bad}"
        );
    }
    match parse(&["run", "t.csv", "--speed", "50"]).command {
        Cmd::Run(args) => assert_eq!(args.speed, Some(50)),
        other => panic!("{other:?}"),
    }
    assert_eq!(
        encode(&["frame", "encode", "--seq", "16", "hold"]),
        format!("1027{:02x}", protocol::crc8(&[0x10, 0x27]))
    );
    assert_eq!(
        encode(&["frame", "encode", "--seq", "18", "override", "50"]),
        format!("122932{:02x}", protocol::crc8(&[0x12, 0x29, 0x32]))
    );
    // watch's suffix: nothing at 100 % unheld (as older controllers show).
    let mut m = protocol::MotionReport::IDLE;
    assert_eq!(crate::watch::motion_suffix(Some(&m)), "");
    m.factor_percent = 50;
    m.flags = protocol::MotionFlags(protocol::MotionFlags::HELD | protocol::MotionFlags::AT_REST);
    assert_eq!(crate::watch::motion_suffix(Some(&m)), " speed 50 % HELD");
    // Issue 32's controlled underrun, slowing.
    m.flags = protocol::MotionFlags(
        protocol::MotionFlags::UNDERRUN_RAMP | protocol::MotionFlags::RAMPING,
    );
    assert_eq!(
        crate::watch::motion_suffix(Some(&m)),
        " speed 50 % UNDERRUN (slowing: the host is late)"
    );
    m.flags = protocol::MotionFlags(
        protocol::MotionFlags::HELD
            | protocol::MotionFlags::AT_REST
            | protocol::MotionFlags::DOOR_OPEN,
    );
    assert_eq!(
        crate::watch::motion_suffix(Some(&m)),
        " speed 50 % HELD DOOR OPEN"
    );
    m.flags =
        protocol::MotionFlags(protocol::MotionFlags::ESTOP_RAMP | protocol::MotionFlags::RAMPING);
    assert_eq!(
        crate::watch::motion_suffix(Some(&m)),
        " speed 50 % E-STOP (category 1: decelerating)"
    );
}

/// `armctl status`'s MOTION line (issue 32): the override and the rate now, a hold, the
/// door, the last controlled stop and the last OVERRIDE refused, each named.
#[test]
fn status_names_the_override_the_hold_the_door_and_a_refusal() {
    use crate::status::motion_line;
    use protocol::{ControlledStop, MotionFlags, MotionReport, OverrideLimit};
    assert_eq!(
        motion_line(&MotionReport::IDLE),
        "motion           speed 100 % (now 100.0 %)"
    );
    let held = MotionReport {
        factor_percent: 50,
        flags: MotionFlags(MotionFlags::HELD | MotionFlags::AT_REST | MotionFlags::DOOR_OPEN),
        rate_permille: 0,
        last_stop: Some(ControlledStop::Door),
        ..MotionReport::IDLE
    };
    assert_eq!(
        motion_line(&held),
        "motion           speed 50 % (now 0.0 %); HELD at rest: `armctl resume` goes on; \
         DOOR OPEN: runs hold, RUNING and RESUME refused; last controlled stop DOOR"
    );
    let holding = MotionReport {
        flags: MotionFlags(MotionFlags::HELD | MotionFlags::RAMPING),
        rate_permille: 375,
        refused_joint: 2,
        refused_limit: Some(OverrideLimit::Rate),
        ..MotionReport::IDLE
    };
    assert_eq!(
        motion_line(&holding),
        "motion           speed 100 % (now 37.5 %); HOLDING (decelerating); \
         last OVERRIDE refused: joint 2 would pass its RATE limit"
    );
    let over_budget = MotionReport {
        refused_limit: Some(OverrideLimit::StepBudget),
        last_stop: None,
        ..MotionReport::IDLE
    };
    assert_eq!(
        motion_line(&over_budget),
        "motion           speed 100 % (now 100.0 %); \
         last controlled stop unknown (a newer controller); \
         last OVERRIDE refused: the run's steps per second would pass the board's budget \
         for warped steps (STEP_BUDGET)"
    );
}

#[test]
fn estop_reset_frame_and_the_status_line() {
    assert_eq!(
        encode(&["frame", "encode", "--seq", "25", "estop-reset"]),
        "19178f"
    );
    let mut s = protocol::StatusReport::default();
    assert_eq!(
        crate::status::estop_line(&s),
        "e-stop input     closed, not latched"
    );
    s.more_flags =
        protocol::MoreFlags(protocol::MoreFlags::ESTOP_OPEN | protocol::MoreFlags::ESTOP_LATCHED);
    assert!(crate::status::estop_line(&s).contains("OPEN, LATCHED"));
    s.more_flags = protocol::MoreFlags(protocol::MoreFlags::ESTOP_LATCHED);
    assert!(crate::status::estop_line(&s).contains("closed, LATCHED"));
    assert!(crate::status::estop_line(&s).contains("armctl estop-reset"));
}

#[test]
fn pwm_commands() {
    let Cmd::Pwm(PwmCmd::Servo { freq, duty }) =
        parse(&["pwm", "servo", "--freq", "50", "--duty", "0.075"]).command
    else {
        panic!()
    };
    assert_eq!((freq, duty), (50.0, 0.075));
    let Cmd::Pwm(PwmCmd::Stepper { pulses, .. }) =
        parse(&["pwm", "stepper", "--pulses", "-400"]).command
    else {
        panic!()
    };
    assert_eq!(pulses, -400);
    let Cmd::Pwm(PwmCmd::Raw(raw)) = parse(&[
        "pwm", "raw", "--psc", "239", "--arr", "19999", "--ccr1", "1500",
    ])
    .command
    else {
        panic!()
    };
    assert_eq!(
        (raw.psc, raw.arr, raw.ccr1, raw.pulses),
        (239, 19999, 1500, 0)
    );
    assert!(matches!(
        parse(&["pwm", "stop"]).command,
        Cmd::Pwm(PwmCmd::Stop)
    ));
}

#[test]
fn frame_subcommands_parse() {
    let Cmd::Frame(FrameCmd::Decode { hex, direction }) =
        parse(&["frame", "decode", "0003", "c5", "--as", "command"]).command
    else {
        panic!()
    };
    assert_eq!(hex, vec!["0003".to_string(), "c5".to_string()]);
    assert_eq!(direction, Some(Direction::Command));
    let Cmd::Frame(FrameCmd::Encode { seq, command }) =
        parse(&["frame", "encode", "--seq", "7", "joints-count", "4"]).command
    else {
        panic!()
    };
    assert_eq!(seq, 7);
    assert!(matches!(command, EncodeCmd::JointsCount { n: 4 }));
}

#[test]
fn hex_parsing() {
    assert_eq!(
        frame::parse_hex("0x01 02:03-0a").unwrap(),
        vec![1, 2, 3, 10]
    );
    assert!(frame::parse_hex("123").unwrap_err().contains("odd"));
    assert!(
        frame::parse_hex("zz")
            .unwrap_err()
            .contains("not a hex byte")
    );
}

fn encode(args: &[&str]) -> String {
    let Cmd::Frame(FrameCmd::Encode { seq, command }) = parse(args).command else {
        panic!("not frame encode")
    };
    frame::encode_frame(seq, &command).unwrap()
}

/// The golden frames from the project's shared vectors (`shared/` beside the repository).
fn golden() -> Vec<serde_json::Value> {
    // As protocol's golden test: ARM_VECTORS overrides the copy beside the repository.
    let path = std::env::var_os("ARM_VECTORS").map_or_else(
        || {
            std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
                .join("../../shared/vectors/frames.json")
        },
        std::path::PathBuf::from,
    );
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| {
        panic!(
            "{}: {e} (shared/ must sit beside the repository)",
            path.display()
        )
    });
    let value: serde_json::Value = serde_json::from_str(&text).unwrap();
    value["frames"].as_array().unwrap().clone()
}

fn golden_hex(name: &str) -> String {
    golden()
        .into_iter()
        .find(|f| f["name"] == name)
        .unwrap_or_else(|| panic!("no golden frame {name:?}"))["hex"]
        .as_str()
        .unwrap()
        .to_string()
}

/// Issue 23's frames encode as docs/PROTOCOL.md shows them.
#[test]
fn encode_issue_23_frames_as_the_protocol_document_shows() {
    assert_eq!(
        encode(&[
            "frame",
            "encode",
            "--seq",
            "27",
            "set-enable",
            "3",
            "--disable"
        ]),
        "1b18030000e7"
    );
    assert_eq!(
        encode(&["frame", "encode", "--seq", "30", "release"]),
        "1e19ce"
    );
    assert_eq!(
        encode(&[
            "frame",
            "encode",
            "--seq",
            "31",
            "limits-set",
            "1",
            "-16000",
            "16000",
            "4000"
        ]),
        "1f1a0100000080c1ffff803e0000a00f0000fd"
    );
    assert_eq!(
        encode(&["frame", "encode", "--seq", "32", "limits-get"]),
        "201bef"
    );
}

#[test]
fn encode_matches_golden_frames() {
    let seq_of = |name: &str| -> String {
        golden().into_iter().find(|f| f["name"] == name).unwrap()["seq"].to_string()
    };
    let cases: Vec<(&str, Vec<String>)> = vec![
        ("NEW", vec!["new".into(), "61513".into()]),
        ("RUNING", vec!["runing".into()]),
        ("STOPPED", vec!["stopped".into()]),
        ("UPLOAD_START", vec!["upload-start".into()]),
        ("UPLOAD_STOP", vec!["upload-stop".into()]),
        ("PWM_STOP", vec!["pwm-stop".into()]),
        ("USART_STOP", vec!["usart-stop".into()]),
        ("PIN0_ON", vec!["pin0-on".into()]),
        ("PIN0_OFF", vec!["pin0-off".into()]),
        ("PIN1_ON", vec!["pin1-on".into()]),
        ("PIN1_OFF", vec!["pin1-off".into()]),
        ("TOGGLE_ENABLE_PINS", vec!["toggle-enable".into()]),
        (
            "TOGGLE_ENABLE_PINS with mask",
            vec!["toggle-enable".into(), "--mask".into(), "61".into()],
        ),
        ("RETURN", vec!["return".into()]),
        ("STATUS", vec!["status".into()]),
        (
            "PWM_START",
            [
                "pwm-start",
                "--psc",
                "45001",
                "--arr",
                "65009",
                "--ccr1",
                "64779",
                "--pulses",
                "-18570",
            ]
            .map(String::from)
            .to_vec(),
        ),
        (
            "USART_START",
            ["usart-start", "--baud", "19200", "--mode", "tx"]
                .map(String::from)
                .to_vec(),
        ),
        ("USART_SEND", vec!["usart-send".into(), "c9bf".into()]),
        ("JOINTS_COUNT", vec!["joints-count".into(), "5".into()]),
        (
            "UPLOAD_PERIOD",
            vec!["upload-period".into(), "940520".into()],
        ),
    ];
    for (name, args) in cases {
        let seq = seq_of(name);
        let mut argv = vec!["frame", "encode", "--seq", seq.as_str()];
        argv.extend(args.iter().map(String::as_str));
        assert_eq!(encode(&argv), golden_hex(name), "{name}");
    }
}

#[test]
fn encode_location_setting_matches_golden() {
    let frame = golden()
        .into_iter()
        .find(|f| f["name"] == "LOCATION_SETTING")
        .unwrap();
    let positions: Vec<String> = frame["fields"]["position"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| p.to_string())
        .collect();
    let seq = frame["seq"].to_string();
    let mut argv = vec!["frame", "encode", "--seq", seq.as_str(), "location-setting"];
    argv.extend(positions.iter().map(String::as_str));
    assert_eq!(encode(&argv), frame["hex"].as_str().unwrap());
}

#[test]
fn encode_pending_fills_hints_from_motion() {
    let hex = encode(&[
        "frame",
        "encode",
        "pending",
        "--from",
        "0,0",
        "--point",
        "10000:100,-50",
        "--point",
        "5000000:101,-50",
    ]);
    let bytes = frame::parse_hex(&hex).unwrap();
    let frame = protocol::Command::decode(&bytes).unwrap();
    let protocol::Command::Pending(points) = frame.body else {
        panic!("not PENDING")
    };
    let points: Vec<_> = points.iter().collect();
    assert_eq!(points.len(), 2);
    assert_eq!(points[0].duration, 10_000);
    assert_eq!(&points[0].position[..2], &[100, -50]);
    assert_eq!(&points[0].number_of_period[..2], &[100, 50]);
    assert_eq!(&points[0].period[..2], &[100, 200]);
    // 5 s for one step: the period needs more than 16 bits and is split.
    assert_eq!(points[1].number_of_period[0], 1);
    assert_eq!(points[1].period[0], 5_000_000);
    assert_eq!(points[1].number_of_full_period[0], (5_000_000 >> 16) as i16);
    assert_eq!(points[1].rest_period[0], (5_000_000 & 0xFFFF) as u16 as i16);
    assert_eq!(points[1].number_of_period[1], 0);
}

#[test]
fn encode_refuses_empty_serial_and_bad_points() {
    let Cmd::Frame(FrameCmd::Encode { seq, command }) =
        parse(&["frame", "encode", "usart-send", ""]).command
    else {
        panic!()
    };
    assert!(frame::encode_frame(seq, &command).is_err());
    let Cmd::Frame(FrameCmd::Encode { seq, command }) =
        parse(&["frame", "encode", "pending", "--point", "100"]).command
    else {
        panic!()
    };
    assert!(
        frame::encode_frame(seq, &command)
            .unwrap_err()
            .contains("DURATION_US")
    );
}

#[test]
fn decode_every_golden_frame() {
    for frame in golden() {
        let name = frame["name"].as_str().unwrap();
        let bytes = frame::parse_hex(frame["hex"].as_str().unwrap()).unwrap();
        let expect_error = !frame["expect_status"].is_null() || name == "two bytes: no reply";
        if expect_error {
            // As a command (a USART_RECV from a host is a fine report, a bad command).
            let message = frame::decode_frame(&bytes, Some(Direction::Command)).expect_err(name);
            assert!(!message.is_empty(), "{name}");
            continue;
        }
        let result = frame::decode_frame(&bytes, None);
        let json: serde_json::Value =
            serde_json::from_str(&result.unwrap_or_else(|e| panic!("{name}: {e}"))).unwrap();
        assert_eq!(json["seq"], frame["seq"], "{name}");
        let direction = if frame["direction"] == "to_host" {
            "report"
        } else {
            "command"
        };
        // A LOCATION report decodes as LOCATION_SETTING too (same tag and length):
        // auto-detection prefers the command; --as report gives the report.
        if name == "LOCATION report" {
            let json: serde_json::Value = serde_json::from_str(
                &frame::decode_frame(&bytes, Some(Direction::Report)).unwrap(),
            )
            .unwrap();
            assert_eq!(json["direction"], "report");
            assert_eq!(json["tag"], "LOCATION");
            assert_eq!(
                json["report"]["Location"]["position"],
                frame["fields"]["position"]
            );
            continue;
        }
        assert_eq!(json["direction"], direction, "{name}");
    }
}

#[test]
fn decode_shows_fields() {
    let json: serde_json::Value = serde_json::from_str(
        &frame::decode_frame(&frame::parse_hex(&golden_hex("NEW")).unwrap(), None).unwrap(),
    )
    .unwrap();
    assert_eq!(json["tag"], "NEW");
    assert_eq!(json["command"]["New"]["count"], 61513);
    let json: serde_json::Value = serde_json::from_str(
        &frame::decode_frame(&frame::parse_hex(&golden_hex("ACK")).unwrap(), None).unwrap(),
    )
    .unwrap();
    assert_eq!(json["direction"], "report");
    assert_eq!(json["report"]["Ack"]["status"], "NotOwner");
    assert_eq!(json["report"]["Ack"]["free"], 1868);
}

#[test]
fn decode_errors_are_the_decode_error_message() {
    let bad_crc =
        frame::decode_frame(&frame::parse_hex(&golden_hex("bad CRC")).unwrap(), None).unwrap_err();
    assert!(bad_crc.contains("CRC mismatch"), "{bad_crc}");
    let short = frame::decode_frame(&[1, 2], None).unwrap_err();
    assert!(short.contains("too short"), "{short}");
    let joints = frame::decode_frame(
        &frame::parse_hex(&golden_hex("JOINTS_COUNT 9")).unwrap(),
        None,
    )
    .unwrap_err();
    assert!(joints.contains("joint count must be 1..8"), "{joints}");
    // Forced direction: a command frame is not a report.
    let wrong = frame::decode_frame(
        &frame::parse_hex(&golden_hex("NEW")).unwrap(),
        Some(Direction::Report),
    )
    .unwrap_err();
    assert!(wrong.contains("other way"), "{wrong}");
}

/// Issue 31: a NOT_OWNER refusal names the command the user ran, not the frame refused.
#[test]
fn not_owner_names_the_command_run() {
    use crate::owner::name_the_command;
    assert_eq!(
        name_the_command(
            "UPLOAD_PERIOD refused with NOT_OWNER: another host owns the controller",
            "move"
        ),
        "move refused with NOT_OWNER: another host owns the controller"
    );
    assert_eq!(
        name_the_command(
            "joint 0: LIMITS_SET refused with NOT_OWNER: x",
            "config push"
        ),
        "joint 0: config push refused with NOT_OWNER: x"
    );
    let other = "PENDING refused with INVALID_POINT (controller state NEW): y";
    assert_eq!(name_the_command(other, "run"), other);
}

/// Issue 31: the controller's refusal (LIMITS_GET's last refusal) is found among the
/// points sent: its time, the joint's config name, the user's units, the slow-down.
#[test]
fn a_controllers_refusal_is_told_in_the_users_terms() {
    use crate::config::{Sent, refused_point};
    use armctl::motion::Units;
    use armctl::trajectory::ArmConfig;
    use protocol::{Point, Refusal, RefusalReason, Tag};
    let config = ArmConfig::parse(
        r#"{"joints": [{"name": "base", "steps_per_radian": 1000, "max_step_rate_hz": 9000}]}"#,
        "arm.json",
    )
    .unwrap();
    let at = |p: i32| [p, 0, 0, 0, 0, 0, 0, 0];
    let points = [
        Point::from_motion(10_000, &at(0), &at(50)),
        Point::from_motion(10_000, &at(50), &at(150)),
    ];
    let sent = Sent {
        from: at(0),
        points: &points,
        config: &config,
        units: Units::Deg,
    };
    let refusal = Refusal {
        seq: 0x21,
        tag: Tag::Pending as u8,
        point: 1,
        joint: 0,
        reason: RefusalReason::AboveMax,
        value: 150,
        limit: 100,
    };
    let line = refused_point(&refusal, &sent).unwrap();
    assert!(
        line.starts_with("point 1 of the upload, ending at t = 0.020000 s (PENDING seq 0x21"),
        "{line}"
    );
    assert!(
        line.contains(
            "joint 0 (base): position 150 steps (8.59 deg) is above its max 100 steps (5.73 deg)"
        ),
        "{line}"
    );
    // 100 steps in 10 ms against 4000 steps/s.
    let rate = Refusal {
        reason: RefusalReason::JointRate,
        value: 10_000,
        limit: 4000,
        ..refusal
    };
    let line = refused_point(&rate, &sent).unwrap();
    assert!(line.starts_with("point 0 of the upload"), "{line}");
    assert!(line.contains("it needs 2.5x longer"), "{line}");
    // Not a PENDING: not found among the points.
    let other = Refusal {
        tag: Tag::Return as u8,
        ..refusal
    };
    assert_eq!(refused_point(&other, &sent), None);
}

#[test]
fn the_speed_line_says_which_limit_lowered_the_speed() {
    let lowered = |factor_percent, refused_joint, refused_limit| {
        Some(protocol::MotionReport {
            factor_percent,
            refused_joint,
            refused_limit: Some(refused_limit),
            ..protocol::MotionReport::IDLE
        })
    };
    assert_eq!(
        run::speed_line(150, lowered(125, 0, protocol::OverrideLimit::Rate)),
        "speed 150 % lowered to 125 % by the controller: joint 0 would pass its RATE limit \
         (every joint within its limits; `armctl override` changes it)"
    );
    assert_eq!(
        run::speed_line(50, lowered(41, 0xFF, protocol::OverrideLimit::StepBudget)),
        "speed 50 % lowered to 41 % by the controller: the steps of all joints together \
         would pass its warp budget (STEP_BUDGET; every step still made)"
    );
    assert_eq!(
        run::speed_line(50, Some(protocol::MotionReport::IDLE)),
        "speed 100 %"
    );
}
