//! Arbitrary datagrams never panic the controller, and are answered by the rules.

mod common;

use common::*;
use proptest::prelude::*;
use protocol::{Command, StatusCode, Tag, crc8};

fn datagram() -> impl Strategy<Value = Vec<u8>> {
    (
        any::<u8>(),
        // Every tag (DISCOVER and NET_SET are 0x20..0x22), and any byte.
        prop_oneof![0u8..0x18, 0x20u8..0x23, any::<u8>()],
        // Often no payload at all (DISCOVER's form), else anything up to a datagram.
        prop_oneof![
            Just(Vec::new()),
            prop::collection::vec(any::<u8>(), 0..1500)
        ],
        any::<bool>(),
    )
        .prop_map(|(seq, tag, data, fix_crc)| {
            let mut bytes = vec![seq, tag];
            bytes.extend_from_slice(&data);
            if fix_crc {
                let crc = crc8(&bytes);
                bytes.push(crc);
            }
            bytes
        })
}

/// A CRC-valid DISCOVER (tag and CRC only): the one frame of 3 bytes or more that gets no ACK.
fn is_discover(bytes: &[u8]) -> bool {
    matches!(bytes, [_, tag, crc] if *tag == Tag::Discover as u8 && crc8(&bytes[..2]) == *crc)
}

/// The property's inputs once drew a CRC-valid DISCOVER (seq 0) and expected an ACK for it;
/// DISCOVER is answered with a DISCOVER_REPLY instead.
#[test]
fn a_discover_among_arbitrary_datagrams_gets_its_reply_not_an_ack() {
    let mut s = Session::<32>::new(32);
    let mut bytes = vec![0, Tag::Discover as u8];
    bytes.push(crc8(&bytes));
    assert!(is_discover(&bytes));
    let r = s.send_raw(HOST, &bytes);
    assert!(r.reply.is_none());
    assert_eq!(r.discovery.map(|d| (d.to, d.seq)), Some((HOST, 0)));
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(500))]
    #[test]
    fn any_datagram_is_answered_by_the_rules(
        prelude in 0usize..4,
        datagrams in prop::collection::vec((datagram(), any::<bool>()), 1..20),
    ) {
        let mut s = Session::<32>::new(32);
        // Some state to disturb: an upload under way, maybe running.
        if prelude > 0 {
            s.expect(Command::New { count: 20 }, StatusCode::Ok);
            s.pending(&points([0; 8], 3, 2));
        }
        if prelude > 1 {
            s.expect(Command::Runing, StatusCode::Ok);
        }
        for (bytes, stranger) in datagrams {
            let from = if stranger { OTHER } else { HOST };
            let r = s.send_raw(from, &bytes);
            if bytes.len() < 3 {
                prop_assert!(r.reply.is_none());
                continue;
            }
            if is_discover(&bytes) {
                // Answered with a DISCOVER_REPLY instead of an ACK (docs/PROTOCOL.md,
                // "Finding controllers and setting their address").
                prop_assert!(r.reply.is_none());
                prop_assert_eq!(r.discovery.map(|d| (d.to, d.seq)), Some((from, bytes[0])));
                continue;
            }
            let Some(reply) = r.reply else {
                // Beyond the read-only answers' budget (issue 23): a STATUS from a host
                // that does not own the controller gets nothing.
                prop_assert!(from != HOST && bytes[1] == Tag::Status as u8, "no ACK");
                continue;
            };
            prop_assert_eq!(reply.to, from);
            prop_assert_eq!((reply.seq, reply.ack.acked_tag), (bytes[0], bytes[1]));
            let crc_ok = crc8(&bytes[..bytes.len() - 1]) == bytes[bytes.len() - 1];
            prop_assert_eq!(reply.ack.status == StatusCode::BadCrc, !crc_ok);
            // A stranger learns nothing about the arm: NOT_OWNER, and (issue 21 F9) a
            // BAD_CRC to anyone but the owner.
            let stranger_bad_crc = reply.ack.status == StatusCode::BadCrc
                && s.controller.owner().is_some_and(|o| o.ip != from.ip);
            if r.answer_seq.is_some() {
                // A read-only STATUS (issue 23): the state, never the next seq or the
                // buffer counts; the reports carry the request's seq.
                prop_assert_eq!(r.answer_seq, Some(bytes[0]));
                prop_assert_eq!(reply.ack.state, s.controller.state());
                prop_assert_eq!(
                    (reply.ack.next_seq, reply.ack.buffered, reply.ack.free),
                    (0, 0, 0)
                );
            } else if reply.ack.status == StatusCode::NotOwner || stranger_bad_crc {
                prop_assert_eq!(
                    (reply.ack.state as u8, reply.ack.next_seq, reply.ack.buffered, reply.ack.free),
                    (0, 0, 0, 0)
                );
            } else {
                prop_assert!(usize::from(reply.ack.buffered) <= s.controller.capacity());
                prop_assert_eq!(
                    usize::from(reply.ack.buffered) + usize::from(reply.ack.free),
                    s.controller.capacity()
                );
            }
            // Run a little, as the engine would.
            s.plant.run(&mut s.controller, 1);
        }
    }
}
