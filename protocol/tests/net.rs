//! DISCOVER, NET_SET and DISCOVER_REPLY (PROTOCOL.md, "Finding controllers and setting
//! their address"): layouts, round trips, what NET_SET refuses, and that old frames are
//! untouched.

use protocol::{
    Command, DecodeErrorKind, DiscoverReply, Field, NetSettings, OwnerState, Report, State,
    StatusCode, Tag, crc8,
};

// The worked examples' hex layout.
#[path = "../examples/doc_frames.rs"]
#[allow(dead_code, reason = "only hex_block is used here")]
mod doc_frames;

fn encode(seq: u8, command: Command<'_>) -> Vec<u8> {
    let mut buf = [0u8; 64];
    let n = command.encode(seq, &mut buf).unwrap();
    buf[..n].to_vec()
}

#[test]
fn discover_and_net_set_layouts() {
    assert_eq!(
        encode(5, Command::Discover),
        vec![5, 0x20, crc8(&[5, 0x20])]
    );
    let net = NetSettings::fixed([192, 168, 7, 9], 24, Some([192, 168, 7, 1]));
    let bytes = encode(6, Command::NetSet(net));
    assert_eq!(
        &bytes[..12],
        &[6, 0x21, 0, 192, 168, 7, 9, 24, 192, 168, 7, 1]
    );
    assert_eq!(bytes.len(), 13);
    assert_eq!(Command::decode(&bytes).unwrap().body, Command::NetSet(net));
    let dhcp = encode(7, Command::NetSet(NetSettings::DHCP));
    assert_eq!(&dhcp[2..12], &[1, 0, 0, 0, 0, 0, 0, 0, 0, 0]);
    assert_eq!(
        Command::decode(&dhcp).unwrap().body,
        Command::NetSet(NetSettings::DHCP)
    );
    assert_eq!(Tag::from_u8(0x20), Some(Tag::Discover));
    assert_eq!(Tag::Discover.name(), "DISCOVER");
    assert_eq!(Tag::NetSet.name(), "NET_SET");
    assert_eq!(Tag::DiscoverReply.name(), "DISCOVER_REPLY");
}

#[test]
fn net_set_refuses_unusable_settings() {
    let refused = |net: NetSettings| {
        let mut data = vec![9, 0x21, u8::from(net.dhcp)];
        data.extend_from_slice(&net.ip);
        data.push(net.prefix_len);
        data.extend_from_slice(&net.gateway);
        data.push(crc8(&data));
        let e = Command::decode(&data).unwrap_err();
        assert_eq!(
            e.kind,
            DecodeErrorKind::OutOfRange(Field::NetSettings),
            "{net:?}"
        );
        assert_eq!(e.status(), Some(StatusCode::InvalidConfig));
    };
    for net in [
        NetSettings::fixed([0, 0, 0, 0], 24, None),
        NetSettings::fixed([255, 255, 255, 255], 24, None),
        NetSettings::fixed([127, 0, 0, 5], 8, None),
        NetSettings::fixed([239, 1, 1, 1], 24, None),
        NetSettings::fixed([10, 0, 0, 0], 24, None),
        NetSettings::fixed([10, 0, 0, 255], 24, None),
        NetSettings::fixed([10, 0, 0, 2], 0, None),
        NetSettings::fixed([10, 0, 0, 2], 33, None),
        NetSettings::fixed([10, 0, 0, 2], 24, Some([10, 0, 1, 1])),
        NetSettings::fixed([10, 0, 0, 2], 24, Some([10, 0, 0, 2])),
        // Issue 21 F15: reserved (240/4), "this network" (0/8), and a gateway that is the
        // subnet's network or broadcast address were accepted.
        NetSettings::fixed([240, 0, 0, 1], 8, None),
        NetSettings::fixed([254, 1, 1, 1], 24, None),
        NetSettings::fixed([0, 1, 2, 3], 8, None),
        NetSettings::fixed([10, 0, 0, 2], 24, Some([10, 0, 0, 0])),
        NetSettings::fixed([10, 0, 0, 2], 24, Some([10, 0, 0, 255])),
        NetSettings {
            ip: [10, 0, 0, 2],
            ..NetSettings::DHCP
        },
    ] {
        refused(net);
    }
    assert!(NetSettings::fixed([10, 0, 0, 2], 32, None).is_valid());
    assert!(NetSettings::fixed([10, 0, 0, 2], 8, Some([10, 200, 0, 1])).is_valid());
    // Mode 2 is no mode.
    let mut data = vec![9, 0x21, 2, 0, 0, 0, 0, 0, 0, 0, 0, 0];
    data.push(crc8(&data));
    assert!(Command::decode(&data).is_err());
    // Wrong length.
    let mut data = vec![9, 0x21, 0, 10, 0, 0, 2, 24];
    data.push(crc8(&data));
    assert!(matches!(
        Command::decode(&data).unwrap_err().kind,
        DecodeErrorKind::BadLength { .. }
    ));
}

/// The reply of a 6-joint controller at 192.168.7.`host`/24 (gateway .1), MAC
/// 02:53:49:4d:`mac_tail`, owned by another host, its stored settings pending a reset.
fn owned_reply(mac_tail: [u8; 2], host: u8, state: State, owner_ip: [u8; 4]) -> DiscoverReply {
    let [m4, m5] = mac_tail;
    DiscoverReply {
        mac: [0x02, 0x53, 0x49, 0x4d, m4, m5],
        net: NetSettings::fixed([192, 168, 7, host], 24, Some([192, 168, 7, 1])),
        version: [1, 0, 0],
        joints: 6,
        state,
        owner: OwnerState::Other,
        owner_ip,
        pending_reset: true,
    }
}

#[test]
fn discover_reply_round_trips() {
    let reply = owned_reply([0x12, 0x34], 2, State::Running, [192, 168, 7, 1]);
    let mut buf = [0u8; 64];
    let n = reply.encode(42, &mut buf).unwrap();
    assert_eq!(n, 30);
    assert_eq!(&buf[..2], &[42, 0x22]);
    assert_eq!(&buf[2..8], &reply.mac);
    assert_eq!(&buf[8..12], &[192, 168, 7, 2]);
    assert_eq!(buf[12], 24);
    assert_eq!(buf[28], 1);
    let frame = DiscoverReply::decode(&buf[..n]).unwrap();
    assert_eq!((frame.seq, frame.body), (42, reply));
    // A host's decoders: the reply is not a command, and Report leaves it alone.
    assert_eq!(
        Command::decode(&buf[..n]).unwrap_err().status(),
        Some(StatusCode::Unsupported)
    );
    assert!(Report::decode(&buf[..n]).is_err());
    // Damaged or short: errors, never a panic.
    for len in 0..n {
        assert!(DiscoverReply::decode(&buf[..len]).is_err());
    }
    buf[5] ^= 0x10;
    assert!(matches!(
        DiscoverReply::decode(&buf[..n]).unwrap_err().kind,
        DecodeErrorKind::BadCrc { .. }
    ));
}

/// The examples of PROTOCOL.md, "Finding controllers and setting their address", are what
/// the crate encodes.
#[test]
fn protocol_md_examples_are_the_crates_bytes() {
    let hex = doc_frames::hex_block;
    let doc = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../docs/PROTOCOL.md"))
        .expect("docs/PROTOCOL.md");
    let discover = encode(5, Command::Discover);
    let reply = owned_reply([0xd6, 0x9c], 9, State::Stopped, [192, 168, 7, 200]);
    let mut buf = [0u8; 64];
    let n = reply.encode(5, &mut buf).unwrap();
    let net_set = encode(
        6,
        Command::NetSet(NetSettings::fixed(
            [192, 168, 7, 9],
            24,
            Some([192, 168, 7, 1]),
        )),
    );
    let block = format!("{}\n{}\n", hex(&discover), hex(&buf[..n]));
    assert!(doc.contains(&block), "PROTOCOL.md should show:\n{block}");
    let block = format!("{}\n", hex(&net_set));
    assert!(doc.contains(&block), "PROTOCOL.md should show:\n{block}");
}
