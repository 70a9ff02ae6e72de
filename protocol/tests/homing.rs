//! Issue 33, homing on switches (PROTOCOL.md, "Homing on switches"): HOME (0x2c, no data),
//! HOMING_SET (0x2d) and HOMING_GET (0x2e) with the HOMING report (0x2f), the SWITCHES
//! report (0x30) asked for by STATUS's request byte bit 5, and HOMING_FAILED (20).

use protocol::{
    Command, DecodeErrorKind, Field, HomingFailure, HomingPhase, HomingSet, HomingSettings, Report,
    StatusAsk, StatusCode, SwitchesReport, Tag, crc8,
};

fn settings() -> HomingSettings {
    HomingSettings {
        enabled: true,
        towards_max: false,
        switch_is_limit: false,
        order: 1,
        seek_rate_hz: 2_000,
        approach_rate_hz: 200,
        backoff_steps: 100,
        max_travel_steps: 20_000,
        offset: -50,
    }
}

#[test]
fn home_is_tag_0x2c_without_data() {
    assert_eq!(Tag::from_u8(0x2c), Some(Tag::Home));
    assert_eq!(Tag::Home.name(), "HOME");
    let mut buf = [0u8; 8];
    let n = Command::Home.encode(0x05, &mut buf).unwrap();
    assert_eq!(&buf[..n], &[0x05, 0x2c, crc8(&[0x05, 0x2c])]);
    assert_eq!(Command::decode(&buf[..n]).unwrap().body, Command::Home);
    let with_data = [0x06, 0x2c, 0x01, crc8(&[0x06, 0x2c, 0x01])];
    assert!(matches!(
        Command::decode(&with_data).unwrap_err().kind,
        DecodeErrorKind::BadLength { .. }
    ));
}

#[test]
fn homing_set_and_the_homing_report_round_trip() {
    let set = HomingSet {
        joint: 2,
        settings: settings(),
    };
    let mut buf = [0u8; 64];
    let n = Command::HomingSet(set).encode(9, &mut buf).unwrap();
    assert_eq!(n, 3 + 24);
    assert_eq!(
        &buf[2..6],
        &[2, 0x01, 1, 0],
        "joint, flags, order, reserved"
    );
    assert_eq!(
        Command::decode(&buf[..n]).unwrap().body,
        Command::HomingSet(set)
    );
    let n = Report::Homing(set).encode(9, &mut buf).unwrap();
    assert_eq!(buf[1], 0x2f);
    assert_eq!(Report::decode(&buf[..n]).unwrap().body, Report::Homing(set));
    let n = Command::HomingGet { joint: 7 }.encode(1, &mut buf).unwrap();
    assert_eq!(&buf[..n], &[1, 0x2e, 7, crc8(&[1, 0x2e, 7])]);
    assert_eq!(
        Command::decode(&buf[..n]).unwrap().body,
        Command::HomingGet { joint: 7 }
    );
}

#[test]
fn homing_set_refuses_a_bad_joint_flags_or_settings_that_cannot_run() {
    let mut buf = [0u8; 64];
    let good = HomingSet {
        joint: 0,
        settings: settings(),
    };
    let n = Command::HomingSet(good).encode(1, &mut buf).unwrap();
    for (at, value) in [(2, 8u8), (3, 0x08), (8, 0)] {
        let mut bad = buf[..n].to_vec();
        bad[at] = value;
        if at == 8 {
            // seek rate 0 (bytes 6..10 of the frame: data 4..8)
            bad[6..10].copy_from_slice(&[0; 4]);
        }
        let last = bad.len() - 1;
        bad[last] = crc8(&bad[..last]);
        let e = Command::decode(&bad).unwrap_err();
        assert_eq!(
            e.kind,
            DecodeErrorKind::OutOfRange(Field::Homing),
            "byte {at}"
        );
        assert_eq!(e.status(), Some(StatusCode::InvalidConfig));
    }
    // Not enabled: zeros are fine (the default).
    let off = HomingSet {
        joint: 3,
        settings: HomingSettings::NONE,
    };
    let n = Command::HomingSet(off).encode(1, &mut buf).unwrap();
    assert_eq!(
        Command::decode(&buf[..n]).unwrap().body,
        Command::HomingSet(off)
    );
}

#[test]
fn status_bit_5_asks_for_the_switches_report() {
    let ask = StatusAsk {
        switches: true,
        ..StatusAsk::default()
    };
    assert_eq!(ask.byte(), 0x20);
    assert_eq!(StatusAsk::from_byte(0x20), Some(ask));
    let report = SwitchesReport {
        phase: HomingPhase::Failed,
        joint: 3,
        error: Some(HomingFailure::SeekTravel),
        homed: 0b0111,
        home_active: 0,
        min_active: 0,
        max_active: 0b1000,
        latched: Some(0x83),
    };
    let mut buf = [0u8; 16];
    let n = Report::Switches(report).encode(4, &mut buf).unwrap();
    assert_eq!(&buf[2..n - 1], &[3, 3, 1, 0b0111, 0, 0, 0b1000, 0x83]);
    assert_eq!(
        Report::decode(&buf[..n]).unwrap().body,
        Report::Switches(report)
    );
    let idle = SwitchesReport::default();
    let n = Report::Switches(idle).encode(4, &mut buf).unwrap();
    assert_eq!(buf[9], 0xFF, "not latched");
    assert_eq!(
        Report::decode(&buf[..n]).unwrap().body,
        Report::Switches(idle)
    );
}

#[test]
fn homing_failed_is_status_20() {
    assert_eq!(StatusCode::from_u8(20), Some(StatusCode::HomingFailed));
    assert_eq!(StatusCode::HomingFailed.name(), "HOMING_FAILED");
    assert!(!StatusCode::HomingFailed.refuses_for_good());
}
