//! The controller's tests use arm-core's test-support layer (the `test-support` feature).
#![allow(unused_imports)]

pub use arm_core::test_support::*;

#[allow(dead_code)] // used by the frame-level tests (ingress.rs, rx_peek.rs) only
/// An Ethernet II / IPv4 / UDP frame from `from` to `port` carrying `payload`, sent to
/// `dst_mac`.
pub fn udp_frame_to(
    dst_mac: [u8; 6],
    from: arm_core::hw::Endpoint,
    port: u16,
    payload: &[u8],
) -> Vec<u8> {
    let mut f = dst_mac.to_vec();
    f.extend_from_slice(&[0x02, 0, 0, 0, 0, 2, 0x08, 0x00]);
    let total = 20 + 8 + payload.len();
    f.extend_from_slice(&[0x45, 0, (total >> 8) as u8, total as u8, 0, 0, 0x40, 0]);
    f.extend_from_slice(&[64, 17, 0, 0]);
    f.extend_from_slice(&from.ip);
    f.extend_from_slice(&[192, 168, 1, 30]);
    let udp_len = 8 + payload.len();
    f.extend_from_slice(&from.port.to_be_bytes());
    f.extend_from_slice(&port.to_be_bytes());
    f.extend_from_slice(&[(udp_len >> 8) as u8, udp_len as u8, 0, 0]);
    f.extend_from_slice(payload);
    f
}
