//! Feeds arbitrary datagrams to both decoders. Every frame that decodes must re-encode and
//! decode again to the same value; nothing may panic.
#![no_main]

use libfuzzer_sys::fuzz_target;
use protocol::{Command, MAX_DATAGRAM, Report, crc8};

/// If `bytes` decode as a `$kind` frame, it must re-encode (into `$buf`) and decode again
/// to the same value; `$what` names it in the panic messages.
macro_rules! round_trip {
    ($kind:ident, $what:literal, $bytes:expr, $buf:expr) => {
        if let Ok(frame) = $kind::decode($bytes) {
            let n = frame.body.encode(frame.seq, $buf).expect(concat!(
                "a decoded ",
                $what,
                " must re-encode"
            ));
            let again =
                $kind::decode(&$buf[..n]).expect(concat!("a re-encoded ", $what, " must decode"));
            assert_eq!(again, frame, concat!($what, " changed in a round trip"));
        }
    };
}

/// Decodes `bytes` both ways and checks the round trip of whatever decodes.
fn check(bytes: &[u8]) {
    let mut buf = [0u8; MAX_DATAGRAM];
    round_trip!(Command, "command", bytes, &mut buf);
    round_trip!(Report, "report", bytes, &mut buf);
}

fuzz_target!(|bytes: &[u8]| {
    check(bytes);
    // Random bytes rarely carry a matching CRC; fix it so the field checks get exercised.
    if let Some((_, body)) = bytes.split_last() {
        let mut fixed = body.to_vec();
        fixed.push(crc8(body));
        check(&fixed);
    }
});
