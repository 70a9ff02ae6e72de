//! DISCOVER and NET_SET (docs/PROTOCOL.md, "Finding controllers and setting their
//! address") in the sans-io controller: DISCOVER is answered to any host with a
//! DISCOVER_REPLY and changes nothing; NET_SET is the owner's, refused while RUNNING,
//! stored through the settings (a deferred save) and reported as pending until the next
//! boot.

mod common;

use arm_core::config::OWNER_TIMEOUT_US;
use arm_core::hw::Endpoint;
use arm_core::hw::PersistentSettings;
use arm_core::{Deferred, Outgoing, ReportEncoder, ReportSettings};
use common::*;
use protocol::{
    Command, DiscoverReply, NetSettings, OwnerState, State, StatusCode, Tag, VERSION, crc8,
};

use StatusCode::*;

fn discover(seq: u8) -> Vec<u8> {
    frame(seq, Command::Discover)
}

#[test]
fn discover_is_answered_to_anyone_and_changes_nothing() {
    let mut s = Session::<64>::new(64);
    s.controller.set_mac([2, 0x53, 0x49, 0x4d, 0, 7]);

    // Before anyone spoke: free, and still free afterwards (no owner taken).
    let r = s.send_raw(OTHER, &discover(9));
    assert_eq!(r.reply, None, "a DISCOVER_REPLY instead of an ACK");
    let d = r.discovery.expect("answered");
    assert_eq!((d.to, d.seq), (OTHER, 9));
    assert_eq!(d.reply.mac, [2, 0x53, 0x49, 0x4d, 0, 7]);
    assert_eq!(d.reply.version, VERSION);
    assert_eq!(d.reply.joints, 6);
    assert_eq!(d.reply.state, State::Stopped);
    assert_eq!(d.reply.owner, OwnerState::Free);
    assert_eq!(d.reply.net, NetSettings::fixed([192, 168, 1, 30], 24, None));
    assert!(!d.reply.pending_reset);
    assert_eq!(s.controller.owner(), None);

    // HOST becomes the owner; OTHER's DISCOVER is answered all the same, and says so.
    s.expect(Command::Status, Ok);
    let d = s.send_raw(OTHER, &discover(10)).discovery.unwrap();
    assert_eq!(d.reply.owner, OwnerState::Other);
    assert_eq!(d.reply.owner_ip, HOST.ip);
    let d = s.send_raw(HOST, &discover(11)).discovery.unwrap();
    assert_eq!(d.reply.owner, OwnerState::Asker);
    assert_eq!(s.controller.owner().unwrap().ip, HOST.ip);

    // A DISCOVER from another port of the owner's host (`armctl discover` uses a socket of
    // its own) does not make that port a LOCATION listener (issue 14's per-endpoint
    // routing): it changes nothing.
    let side_port = Endpoint {
        port: HOST.port + 1,
        ..HOST
    };
    let before = s.controller.report_settings();
    let d = s.send_raw(side_port, &discover(12)).discovery.unwrap();
    assert_eq!(d.reply.owner, OwnerState::Asker);
    assert_eq!(s.controller.report_settings(), before);
    assert!(
        !s.controller
            .report_settings()
            .location_goes_to(side_port, s.now_us)
    );

    // A resent DISCOVER (same bytes) is answered again: it is not a command to dedupe.
    assert!(s.send_raw(OTHER, &discover(10)).discovery.is_some());

    // The owner's upload is not disturbed: a DISCOVER's seq between NEW and PENDING
    // would otherwise be a hole in the ordering.
    s.expect(Command::New { count: 2 }, Ok);
    s.send_raw(HOST, &discover(s.seq.wrapping_add(1)));
    let pts = points([0; 8], 2, 1);
    s.seq = s.seq.wrapping_add(1); // the DISCOVER's seq, not a command
    assert_eq!(
        s.pending(&pts).status,
        OutOfOrder,
        "a DISCOVER does not fill a gap"
    );
    s.seq = s.seq.wrapping_sub(2);
    assert_eq!(s.pending(&pts).status, Ok);
}

#[test]
fn lapsed_owner_is_reported_free() {
    let mut s = Session::<64>::new(64);
    s.expect(Command::Status, Ok);
    s.now_us += OWNER_TIMEOUT_US;
    let d = s.send_raw(OTHER, &discover(1)).discovery.unwrap();
    assert_eq!(d.reply.owner, OwnerState::Free);
}

#[test]
fn discover_with_data_or_bad_crc_is_not_answered_as_discovery() {
    let mut s = Session::<64>::new(64);
    let mut bad = discover(3);
    *bad.last_mut().unwrap() ^= 1;
    let r = s.send_raw(OTHER, &bad);
    assert!(r.discovery.is_none());
    assert_eq!(r.reply.unwrap().ack.status, BadCrc);
    let mut long = vec![4, Tag::Discover as u8, 0];
    long.push(crc8(&long));
    let r = s.send_raw(HOST, &long);
    assert!(r.discovery.is_none());
    assert_eq!(r.reply.unwrap().ack.status, BadLength);
}

#[test]
fn net_set_is_stored_by_the_owner_and_applied_after_reset() {
    let mut s = Session::<64>::new(64);
    s.expect(Command::Status, Ok);
    let net = NetSettings::fixed([10, 0, 7, 9], 24, Some([10, 0, 7, 1]));

    // Another host: NOT_OWNER, nothing stored.
    s.from = OTHER;
    s.expect(Command::NetSet(net), NotOwner);
    s.from = HOST;

    s.seq = s.seq.wrapping_add(1);
    let r = s.send_raw(HOST, &frame(s.seq, Command::NetSet(net)));
    assert_eq!(r.reply.unwrap().ack.status, Ok);
    let Some(Deferred::SaveSettings(saved)) = r.deferred else {
        panic!("a settings save: {:?}", r.deferred);
    };
    assert_eq!(saved.net(), net);
    assert_eq!(saved.joints, 6, "the joint count is kept");

    // Stored, not yet in use: DISCOVER says so.
    let d = s.send_raw(OTHER, &discover(50)).discovery.unwrap();
    assert_eq!(d.reply.net, net);
    assert!(d.reply.pending_reset);

    // After a reset (the stored settings applied at boot): in use, nothing pending.
    let mut booted = controller::<64>(64);
    booted.apply_settings(saved);
    let r = booted.handle(OTHER, &discover(1), 1, &mut FakePlant::default());
    let d = r.discovery.unwrap();
    assert_eq!(d.reply.net, net);
    assert!(!d.reply.pending_reset);

    // DHCP keeps the static address in the settings (a fallback for the board).
    s.expect(Command::NetSet(NetSettings::DHCP), Ok);
    let d = s.send_raw(OTHER, &discover(51)).discovery.unwrap();
    assert_eq!(d.reply.net, NetSettings::DHCP);
    assert_eq!(s.controller.settings().ip, [10, 0, 7, 9]);
}

#[test]
fn net_set_is_refused_while_running_and_when_invalid() {
    let mut s = Session::<64>::new(64);
    s.start_run(4, &points([0; 8], 4, 1));
    let ack = s.expect(
        Command::NetSet(NetSettings::fixed([10, 0, 0, 2], 8, None)),
        BadState,
    );
    assert_eq!(ack.state, State::Running);
    assert_eq!(s.controller.settings(), PersistentSettings::default());

    s.plant.run_to_end(&mut s.controller);
    assert_eq!(s.controller.state(), State::Stopped);
    // Invalid settings never decode: INVALID_CONFIG (a broadcast address, a gateway
    // outside the subnet, DHCP with an address, an unknown mode).
    for data in [
        [0u8, 10, 0, 0, 255, 24, 0, 0, 0, 0],
        [0, 10, 0, 0, 2, 24, 10, 0, 1, 1],
        [1, 10, 0, 0, 2, 24, 0, 0, 0, 0],
        [2, 0, 0, 0, 0, 0, 0, 0, 0, 0],
        [0, 224, 0, 0, 1, 24, 0, 0, 0, 0],
        [0, 10, 0, 0, 2, 0, 0, 0, 0, 0],
    ] {
        s.seq = s.seq.wrapping_add(1);
        let mut bytes = vec![s.seq, Tag::NetSet as u8];
        bytes.extend_from_slice(&data);
        bytes.push(crc8(&bytes));
        let r = s.send_raw(HOST, &bytes);
        assert_eq!(r.reply.unwrap().ack.status, InvalidConfig, "{data:?}");
        assert_eq!(r.deferred, None);
    }
}

#[test]
fn discovery_goes_to_the_asker_with_its_seq_and_leaves_the_report_counter() {
    let mut s = Session::<64>::new(64);
    let d = s.send_raw(OTHER, &discover(77)).discovery.unwrap();
    let mut encoder = ReportEncoder::new();
    let mut buf = [0u8; 300];
    let (to, n) = encoder
        .encode(
            &Outgoing::Discovery(d),
            &ReportSettings::BOOT,
            s.now_us,
            &mut buf,
        )
        .expect("sent even with no owner");
    assert_eq!(to.as_slice(), &[OTHER]);
    let frame = DiscoverReply::decode(&buf[..n]).expect("a DISCOVER_REPLY");
    assert_eq!(frame.seq, 77);
    assert_eq!(frame.body, d.reply);
    assert_eq!(
        encoder.next_seq(),
        0,
        "not a report: the report seq is untouched"
    );
}

/// Issue 21 F6: DISCOVER replies (30 bytes for a 3-byte request, to whatever address the
/// request names) had no rate limit: a forged stream of DISCOVERs made the controller a
/// 10x amplifier at any rate. Now at most DISCOVER_REPLIES_PER_S a second (a burst of
/// DISCOVER_BURST first): a cell's hosts looking for controllers never come near it.
#[test]
fn discover_replies_are_rate_limited() {
    use arm_core::controller::{DISCOVER_BURST, DISCOVER_REPLIES_PER_S};
    let mut s = Session::<16>::new(16);
    let answered = |s: &mut Session<16>, n: u32| {
        (0..n)
            .filter(|i| s.send_raw(OTHER, &discover(*i as u8)).discovery.is_some())
            .count() as u32
    };
    assert_eq!(
        answered(&mut s, 1_000),
        DISCOVER_BURST,
        "a burst, then nothing"
    );
    // A second later: a second's worth.
    s.now_us += 1_000_000;
    assert_eq!(
        answered(&mut s, 1_000),
        DISCOVER_REPLIES_PER_S.min(DISCOVER_BURST)
    );
    // A host asking once a second is always answered.
    for _ in 0..10 {
        s.now_us += 1_000_000;
        assert_eq!(answered(&mut s, 1), 1);
    }
}
