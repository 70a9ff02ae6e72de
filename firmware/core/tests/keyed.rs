//! A keyed arm stays its key holder's (issue 30, docs/PROTOCOL.md section 13), sans-io:
//! HELLOs without the key never evict a session that proved it and never spend a key
//! holder's address's HELLO budget; commands that write flash are taken only while
//! STOPPED, and their ACK comes after the save, with its result.

mod common;

use arm_core::Deferred;
use arm_core::hw::Endpoint;
use common::*;
use protocol::auth::{AuthKey, KEY_LEN};
use protocol::{Command, JointLimits, LimitsSet, NetSettings, State, StatusCode};

const KEY: AuthKey = AuthKey([0x5a; KEY_LEN]);

/// A controller whose key was set (plain SET_KEY from HOST) and a session of HOST's
/// that proved it (an envelope verified).
fn keyed() -> Session<64> {
    let mut s = Session::<64>::new(64);
    s.expect(Command::SetKey(Some(KEY)), StatusCode::Ok);
    s.hello(KEY);
    s.expect(Command::Pin0On, StatusCode::Ok);
    s
}

/// One HELLO from each of 20 flooding addresses (127.0.0.10-29), each with a new nonce;
/// returns how many were answered.
fn flood_round(s: &mut Session<64>, round: u32) -> usize {
    (0..20u8)
        .filter(|i| {
            let from = Endpoint {
                ip: [127, 0, 0, 10 + i],
                port: 40_000,
            };
            let nonce = [(round % 256) as u8; 16];
            let hello = frame(round as u8, Command::Hello { nonce });
            s.send_raw(from, &hello).hello.is_some()
        })
        .count()
}

/// Before issue 30 the 9th HELLO took the key holder's session (the slot used least
/// recently): its next command was `AUTH_FAILED`.
#[test]
fn a_hello_flood_never_evicts_a_session_that_proved_the_key() {
    let mut s = keyed();
    // 25 rounds of 20 addresses: 500 HELLOs, in 1 s of virtual time (send_raw's 10 us per
    // frame, plus 1 ms per round).
    for round in 0..25 {
        s.now_us += 1_000;
        flood_round(&mut s, round);
        s.expect(Command::Pin0On, StatusCode::Ok);
    }
    s.expect(Command::Pin0Off, StatusCode::Ok);
}

/// Before issue 30 a flood spent the one budget of 10 replies/s: the key holder's new
/// HELLO was answered only if it came just after the refill.
#[test]
fn a_key_holders_hello_is_answered_during_a_flood_from_other_addresses() {
    let mut s = keyed();
    let mut answered = 0;
    // 5 s at 500 HELLOs/s (a round of 20 every 40 ms); the holder says HELLO every second.
    for round in 0..125u32 {
        s.now_us += 40_000;
        flood_round(&mut s, round);
        if round % 25 == 24 {
            s.hello(KEY);
            s.expect(Command::Pin0On, StatusCode::Ok);
            answered += 1;
        }
    }
    assert_eq!(answered, 5);
}

#[test]
fn commands_that_write_flash_are_refused_unless_stopped() {
    let limits = LimitsSet {
        joint: 0,
        limits: JointLimits {
            min: -100,
            max: 100,
            max_rate_hz: 0,
        },
    };
    let net = NetSettings::fixed([10, 0, 0, 9], 24, None);
    let flash_writers = [
        Command::SetKey(Some(KEY)),
        Command::SetKey(None),
        Command::JointsCount(4),
        Command::LimitsSet(limits),
        Command::NetSet(net),
    ];
    // RUNNING (before issue 30 SET_KEY and NET_SET were taken, and the save held the
    // trajectory task far past its lookahead).
    let mut s = Session::<64>::new(64);
    s.start_endless_run();
    for cmd in flash_writers {
        let r = s.send_raw(HOST, &frame(200, cmd));
        assert_eq!(r.reply.unwrap().ack.status, StatusCode::BadState, "{cmd:?}");
        assert_eq!(r.deferred, None, "{cmd:?}");
    }
    assert_eq!(s.controller.state(), State::Running);
    // PENDING (an upload not started): the same.
    let mut s = Session::<64>::new(64);
    s.expect(Command::New { count: 5 }, StatusCode::Ok);
    s.pending(&points([0; 8], 2, 1));
    for cmd in flash_writers {
        s.expect(cmd, StatusCode::BadState);
    }
    assert!(!s.controller.keyed());
    // Keyed, in a session, while running: SET_KEY is BAD_STATE and the key stays.
    let mut s = keyed();
    s.start_endless_run();
    s.expect(Command::SetKey(None), StatusCode::BadState);
    assert!(s.controller.keyed());
}

/// The ACK of a command that writes flash is not in the response: the controller waits
/// for the save ([`arm_core::Controller::settings_saved`]).
#[test]
fn the_ack_of_a_flash_write_comes_after_the_save() {
    let mut s = Session::<64>::new(64);
    s.now_us += 10;
    let r = s.controller.handle(
        HOST,
        &frame(1, Command::JointsCount(4)),
        s.now_us,
        &mut s.plant,
    );
    assert_eq!(r.reply, None, "no ACK before the save");
    let Some(Deferred::SaveSettings(to_save)) = r.deferred else {
        panic!("a save: {r:?}");
    };
    assert_eq!(to_save.joints, 4);
    assert_ne!(s.controller.joints(), 4, "applied once saved");
    assert!(s.controller.saving());
    // Another flash write meanwhile (a datagram handled before the save ended: the
    // overtaken path) waits its turn.
    let r = s.send_raw(HOST, &frame(2, Command::JointsCount(5)));
    assert_eq!(r.reply.unwrap().ack.status, StatusCode::BadState);
    let ack = s
        .controller
        .settings_saved(true, s.now_us)
        .expect("the ACK");
    assert_eq!((ack.seq, ack.ack.status), (1, StatusCode::Ok));
    assert_eq!(s.controller.joints(), 4);
    // Its resend is a duplicate: OK, nothing saved again.
    let r = s.send_raw(HOST, &frame(1, Command::JointsCount(4)));
    assert_eq!(r.reply.unwrap().ack.status, StatusCode::Ok);
    assert_eq!(r.deferred, None);
    assert_eq!(s.controller.settings_saved(true, s.now_us), None);
}

#[test]
fn a_failed_save_is_save_failed_and_changes_nothing() {
    let mut s = Session::<64>::new(64);
    s.saves_fail = true;
    let before = s.controller.settings();
    s.expect(Command::JointsCount(4), StatusCode::SaveFailed);
    s.expect(Command::SetKey(Some(KEY)), StatusCode::SaveFailed);
    assert!(!s.controller.keyed(), "no key: it was not stored");
    assert_eq!(s.controller.settings(), before);
    // Not remembered as done: the same frame again is saved again, and succeeds.
    s.saves_fail = false;
    let again = frame(s.seq.wrapping_sub(1), Command::JointsCount(4));
    let r = s.send_raw(HOST, &again);
    assert_eq!(r.reply.unwrap().ack.status, StatusCode::Ok);
    assert_eq!(s.controller.joints(), 4);
    // Keyed: a failed key change keeps the old key and its sessions.
    let mut s = keyed();
    s.saves_fail = true;
    s.expect(Command::SetKey(None), StatusCode::SaveFailed);
    assert!(s.controller.keyed());
    s.expect(Command::Pin0Off, StatusCode::Ok);
}

/// Before issue 30 a key set on a controller whose settings were lost started at epoch 1
/// again: every envelope recorded in its first life verified again.
#[test]
fn a_key_set_again_after_the_settings_were_lost_never_repeats_an_epoch() {
    let mut epochs = Vec::new();
    for (life, entropy) in [0x0123_4567_89ab_cdefu64, 0xfedc_ba98_7654_3210]
        .into_iter()
        .enumerate()
    {
        // Settings erased: a fresh controller, its RNG's bits.
        let mut s = Session::<64>::new(64);
        s.controller.set_entropy(entropy);
        s.expect(Command::SetKey(Some(KEY)), StatusCode::Ok);
        let auth = s.hello(KEY);
        // Ten boots of this life.
        let mut epoch = auth.epoch;
        for _ in 0..10 {
            epochs.push((life, epoch));
            epoch = arm_core::auth::next_epoch(epoch);
        }
        // Set again in the same life: another base.
        s.expect(Command::SetKey(Some(KEY)), StatusCode::Ok);
        s.auth = None;
        let again = s.hello(KEY);
        assert_ne!(again.epoch, auth.epoch);
        epochs.push((life, again.epoch));
    }
    for (i, (_, e)) in epochs.iter().enumerate() {
        assert!(
            epochs[..i].iter().all(|(_, f)| f != e),
            "epoch {e} repeated: {epochs:?}"
        );
        assert_ne!(*e, 1);
    }
}
