//! Issue 31's arm description on the wire: JOINT_DESC_SET (0x1f), JOINT_DESC_GET (0x23)
//! and the JOINT_DESC report (0x26), byte for byte as docs/PROTOCOL.md's worked example.

use protocol::{Command, JointDesc, JointDescSet, JointUnit, Report, StatusCode, Tag};

fn frame(seq: u8, tag: u8, data: &[u8]) -> Vec<u8> {
    let mut v = vec![seq, tag];
    v.extend_from_slice(data);
    v.push(protocol::crc8(&v));
    v
}

/// PROTOCOL.md's example: joint 1 "shoulder", degrees, zero at 0, 2546.4790894703255
/// steps per radian (16000 steps per turn).
fn shoulder() -> JointDescSet {
    JointDescSet {
        joint: 1,
        desc: JointDesc::new(
            "shoulder",
            JointUnit::Degrees,
            0,
            16000.0 / std::f64::consts::TAU,
        )
        .unwrap(),
    }
}

#[test]
fn joint_desc_set_is_the_documented_bytes_and_round_trips() {
    let set = shoulder();
    let mut buf = [0u8; 64];
    let n = Command::JointDescSet(set).encode(0x25, &mut buf).unwrap();
    assert_eq!(n, 3 + protocol::size::JOINT_DESC_SET);
    let mut expected = vec![0x25, 0x1f, 1, 0, 0, 0];
    expected.extend_from_slice(b"shoulder\0\0\0\0\0\0\0\0");
    expected.extend_from_slice(&[1, 0, 0, 0, 0, 0, 0, 0]);
    expected.extend_from_slice(&(16000.0 / std::f64::consts::TAU).to_le_bytes());
    assert_eq!(&buf[..n - 1], expected.as_slice());
    assert_eq!(
        &buf[n - 1 - 8..n - 1],
        &[0xd0, 0x0d, 0x37, 0x4b, 0xf5, 0xe4, 0xa3, 0x40],
        "the f64 as PROTOCOL.md prints it"
    );
    let decoded = Command::decode(&buf[..n]).unwrap().body;
    assert_eq!(decoded, Command::JointDescSet(set));
    let Command::JointDescSet(back) = decoded else {
        unreachable!()
    };
    assert_eq!(back.desc.name(), "shoulder");
    assert_eq!(back.desc.scale(), 16000.0 / std::f64::consts::TAU);
}

#[test]
fn joint_desc_get_and_the_report_carry_the_set_s_data() {
    let mut buf = [0u8; 64];
    let n = Command::JointDescGet { joint: 1 }
        .encode(0x26, &mut buf)
        .unwrap();
    assert_eq!(&buf[..n - 1], &[0x26, 0x23, 0x01]);
    assert_eq!(
        Command::decode(&buf[..n]).unwrap().body,
        Command::JointDescGet { joint: 1 }
    );
    let n = Report::JointDesc(shoulder())
        .encode(0x30, &mut buf)
        .unwrap();
    assert_eq!(buf[1], Tag::JointDesc as u8);
    assert_eq!(n, 3 + 36);
    assert_eq!(
        Report::decode(&buf[..n]).unwrap().body,
        Report::JointDesc(shoulder())
    );
    // A report is not a command.
    assert!(Command::decode(&buf[..n]).is_err());
}

#[test]
fn bad_descriptions_are_invalid_config_and_never_panic() {
    let good = {
        let mut buf = [0u8; 64];
        let n = Command::JointDescSet(shoulder())
            .encode(1, &mut buf)
            .unwrap();
        buf[2..n - 1].to_vec()
    };
    let refused = |data: &[u8]| Command::decode(&frame(1, 0x1f, data)).unwrap_err().status();
    let mut joint8 = good.clone();
    joint8[0] = 8;
    assert_eq!(refused(&joint8), Some(StatusCode::InvalidConfig));
    let mut unit4 = good.clone();
    unit4[4 + 16] = 4;
    assert_eq!(refused(&unit4), Some(StatusCode::InvalidConfig));
    let mut not_utf8 = good.clone();
    not_utf8[4] = 0xff;
    assert_eq!(refused(&not_utf8), Some(StatusCode::InvalidConfig));
    let mut after_nul = good.clone();
    after_nul[4 + 12] = b'x';
    assert_eq!(refused(&after_nul), Some(StatusCode::InvalidConfig));
    let mut nan = good.clone();
    nan[28..36].copy_from_slice(&f64::NAN.to_le_bytes());
    assert_eq!(refused(&nan), Some(StatusCode::InvalidConfig));
    assert_eq!(refused(&good[..35]), Some(StatusCode::BadLength));
    assert_eq!(
        Command::decode(&frame(1, 0x23, &[8])).unwrap_err().status(),
        Some(StatusCode::InvalidConfig)
    );
    assert_eq!(
        Command::decode(&frame(1, 0x23, &[])).unwrap_err().status(),
        Some(StatusCode::BadLength)
    );
    // 16 bytes is the most; a NUL inside is not a name.
    assert!(JointDesc::new("sixteen_bytes_ok", JointUnit::Radians, 0, 1.0).is_some());
    assert!(JointDesc::new("seventeen_bytes_x", JointUnit::Radians, 0, 1.0).is_none());
    assert!(JointDesc::new("a\0b", JointUnit::Radians, 0, 1.0).is_none());
    // Every length and byte pattern decodes without a panic.
    for len in 0..40 {
        for fill in [0u8, 0x01, 0x7f, 0xff] {
            let _ = Command::decode(&frame(1, 0x1f, &vec![fill; len]));
            let _ = Report::decode(&frame(1, 0x26, &vec![fill; len]));
        }
    }
    // The none description (boot default) is valid, names nothing.
    assert!(JointDesc::NONE.is_valid());
    assert!(!JointDesc::NONE.is_described());
    assert_eq!(JointDesc::NONE.name(), "");
}
