//! Arbitrary datagrams never panic the controller, and are answered by the rules.

mod common;

use common::*;
use proptest::prelude::*;
use protocol::{Command, StatusCode, crc8};

fn datagram() -> impl Strategy<Value = Vec<u8>> {
    (
        any::<u8>(),
        prop_oneof![0u8..0x18, any::<u8>()],
        prop::collection::vec(any::<u8>(), 0..1500),
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
            let reply = r.reply.expect("an ACK for 3 bytes or more");
            prop_assert_eq!(reply.to, from);
            prop_assert_eq!((reply.seq, reply.ack.acked_tag), (bytes[0], bytes[1]));
            let crc_ok = crc8(&bytes[..bytes.len() - 1]) == bytes[bytes.len() - 1];
            prop_assert_eq!(reply.ack.status == StatusCode::BadCrc, !crc_ok);
            if reply.ack.status == StatusCode::NotOwner {
                // A stranger learns nothing about the arm.
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
