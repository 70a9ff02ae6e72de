//! What authentication (docs/PROTOCOL.md section 13) costs the controller per 12-point
//! PENDING, at the board's code generation: between `auth_cost_on` and `auth_cost_off`,
//! what arm-core does for an envelope on top of a plain frame (open it: both CRCs; verify
//! its keyed BLAKE2s-128 MAC over the epoch and 1,410 bytes) and for its ACK (seal the
//! 11-byte ACK: MAC and CRC). run.sh counts the instructions between the markers.
#![no_std]
#![no_main]

use core::hint::black_box;

use cortex_m_rt::entry;
use cortex_m_semihosting::{debug, hprintln};
use protocol::auth::{AuthKey, Direction, Envelope, MacKey, seal, seal_with};
use protocol::{Command, MAX_DATAGRAM, MAX_POINTS_PER_FRAME, Point, PointList};

/// A failed check ends QEMU with a failure status (the module is linked for its handler).
mod panic_halt {
    #[panic_handler]
    fn panic(_: &core::panic::PanicInfo) -> ! {
        cortex_m_semihosting::debug::exit(cortex_m_semihosting::debug::EXIT_FAILURE);
        loop {}
    }
}

// Markers run.sh looks for in the exec trace. Each body differs (a distinct constant), so
// that LLVM merges them neither with each other nor with another empty function (the trace
// names instructions by function).
#[unsafe(no_mangle)]
#[inline(never)]
pub extern "C" fn auth_cost_on() {
    black_box(0xA0u32);
}

#[unsafe(no_mangle)]
#[inline(never)]
pub extern "C" fn auth_cost_off() {
    black_box(0xA1u32);
}

const KEY: AuthKey = AuthKey([0x5a; 32]);
const EPOCH: u64 = 7;

#[entry]
fn main() -> ! {
    let mut points = [Point::default(); MAX_POINTS_PER_FRAME];
    for (k, p) in points.iter_mut().enumerate() {
        let to = [k as i32 + 1; 8];
        *p = Point::from_motion(10_000, &[k as i32; 8], &to);
    }
    let mut inner = [0u8; MAX_DATAGRAM];
    let n = Command::Pending(PointList::Points(&points))
        .encode(3, &mut inner)
        .unwrap_or(0);
    let mut envelope = [0u8; MAX_DATAGRAM];
    let mut ack_out = [0u8; 64];
    let ack = [3u8, 0x14, 1, 0, 1, 4, 12, 0, 0, 0x20, 0];
    // Made ready once, when the key is set (arm-core's `Sessions::start_epoch`).
    let key = MacKey::new(&KEY);
    for round in 0..3u64 {
        let m = seal(&KEY, Direction::ToController, EPOCH, 1, round + 1, &inner[..n], &mut envelope)
            .unwrap_or(0);
        auth_cost_on();
        // What the controller does for an envelope on top of a plain frame (arm-core's
        // `Controller::authenticate`): the outer CRC (a plain frame's CRC is checked on
        // its inner frame, as before), the split, the MAC; then the ACK sealed.
        let bytes = black_box(&envelope[..m]);
        let crc_ok = bytes
            .split_last()
            .is_some_and(|(crc, body)| protocol::crc8(body) == *crc);
        let ok = crc_ok
            && match Envelope::split(bytes) {
                Ok(env) => env.verify_with(&key, Direction::ToController, EPOCH) && env.inner.len() == n,
                Err(_) => false,
            };
        let sealed = seal_with(&key, Direction::ToHost, EPOCH, 1, round + 1, black_box(&ack), &mut ack_out);
        auth_cost_off();
        hprintln!("round {} envelope {} verified {} ack {}", round, m, ok, sealed.unwrap_or(0));
        if !ok {
            debug::exit(debug::EXIT_FAILURE);
        }
    }
    debug::exit(debug::EXIT_SUCCESS);
    loop {}
}
