//! Optional authentication (issue 21, docs/PROTOCOL.md section 13), sans-io: with a key a
//! forged frame moves nothing, a replayed envelope is refused, STOPPED still works from
//! anyone; without a key nothing changes; the key's set/clear flow; reports only to
//! sessions.

mod common;

use arm_core::auth::SealRoutes;
use arm_core::hw::{Endpoint, PersistentSettings};
use arm_core::outgoing::{MAX_SEALED_FRAME, Outgoing, Sealer, Sealing};
use arm_core::{Deferred, Reply};
use common::*;
use protocol::auth::{AuthKey, KEY_LEN};
use protocol::{Ack, Command, Location, PointList, State, StatusCode};

const KEY: AuthKey = AuthKey([0x5a; KEY_LEN]);
const WRONG_KEY: AuthKey = AuthKey([0xa5; KEY_LEN]);

/// A controller whose key was set (plain SET_KEY from HOST, the first time) and a session
/// of HOST's with that key.
fn keyed() -> Session<64> {
    let mut s = Session::<64>::new(64);
    let ack = s.expect(Command::SetKey(Some(KEY)), StatusCode::Ok);
    assert_eq!(ack.status, StatusCode::Ok);
    assert!(s.controller.keyed());
    s.hello(KEY);
    s
}

fn status_of(s: &mut Session<64>, from: Endpoint, bytes: &[u8]) -> StatusCode {
    s.send_raw(from, bytes).reply.expect("an ACK").ack.status
}

#[test]
fn forged_frames_without_the_key_move_nothing() {
    let mut s = keyed();
    let pts = points([0; 8], 3, 5);
    // From a stranger and from the key holder's own address and port (a forged source):
    // plain frames, and envelopes under a wrong key.
    for from in [OTHER, HOST] {
        let mut forger = HostAuthForger::new(s.auth.expect("session"));
        for (i, cmd) in [
            Command::New { count: 3 },
            Command::Pending(PointList::Points(&pts)),
            Command::Runing,
            Command::Pin0On,
            Command::UploadStart,
            Command::JointsCount(3),
            Command::SetKey(None),
            Command::Return,
        ]
        .into_iter()
        .enumerate()
        {
            let plain = frame(100 + i as u8, cmd);
            assert_eq!(
                status_of(&mut s, from, &plain),
                StatusCode::AuthRequired,
                "{cmd:?}"
            );
            let forged = forger.seal_with(WRONG_KEY, &plain);
            assert_eq!(
                status_of(&mut s, from, &forged),
                StatusCode::AuthFailed,
                "{cmd:?}"
            );
        }
    }
    assert!(s.plant.executed.is_empty() && s.plant.queue.is_empty());
    assert_eq!(s.plant.starts, 0);
    assert!(s.plant.pins.is_empty());
    assert_eq!(s.controller.state(), State::Stopped);
    assert!(s.controller.keyed(), "the key stays");
    // The refusals told nothing: blank ACKs.
    let r = s.send_raw(OTHER, &frame(9, Command::Status)).reply.unwrap();
    assert_eq!((r.ack.next_seq, r.ack.buffered, r.ack.free), (0, 0, 0));
    // The key holder still moves the arm.
    s.start_run(3, &pts);
    assert_eq!(s.controller.state(), State::Running);
    s.plant.run_to_end(&mut s.controller);
    assert_eq!(s.plant.positions[0], 15);
}

/// Seals with any key (an attacker's guess) in the real session's numbering.
struct HostAuthForger(HostAuth);

impl HostAuthForger {
    fn new(auth: HostAuth) -> Self {
        HostAuthForger(HostAuth {
            counter: 1_000,
            ..auth
        })
    }
    fn seal_with(&mut self, key: AuthKey, inner: &[u8]) -> Vec<u8> {
        self.0.key = key;
        self.0.seal(inner)
    }
}

#[test]
fn a_replayed_envelope_is_refused_and_a_resend_runs_once() {
    let mut s = keyed();
    let mut auth = s.auth.unwrap();
    let toggle = frame(50, Command::ToggleEnablePins { mask: Some(1) });
    let sealed = auth.seal(&toggle);
    assert_eq!(status_of(&mut s, HOST, &sealed), StatusCode::Ok);
    assert_eq!(s.plant.enabled.len(), 1);
    // The same bytes again (a recording played back, from anywhere): refused.
    assert_eq!(status_of(&mut s, HOST, &sealed), StatusCode::AuthFailed);
    assert_eq!(status_of(&mut s, OTHER, &sealed), StatusCode::AuthFailed);
    // The host's resend (its ACK was lost) is the same inner frame in a new envelope: a
    // duplicate, ACKed OK and not executed again.
    let resend = auth.seal(&toggle);
    assert_eq!(status_of(&mut s, HOST, &resend), StatusCode::Ok);
    assert_eq!(s.plant.enabled.len(), 1, "toggled once");
}

#[test]
fn stopped_from_a_stranger_still_stops_a_keyed_controller() {
    let mut s = keyed();
    s.start_endless_run();
    let stops = s.plant.stops;
    assert_eq!(
        status_of(&mut s, OTHER, &frame(1, Command::Stopped)),
        StatusCode::Ok
    );
    assert_eq!(s.controller.state(), State::Stopped);
    assert!(s.plant.stops > stops);
    assert!(!s.plant.running);
}

#[test]
fn without_a_key_nothing_changes_and_envelopes_are_refused() {
    let mut s = Session::<64>::new(64);
    assert!(!s.controller.keyed());
    s.expect(Command::Pin0On, StatusCode::Ok);
    let hello = frame(7, Command::Hello { nonce: [1; 16] });
    let r = s.send_raw(HOST, &hello);
    assert!(r.hello.is_none());
    assert_eq!(r.reply.unwrap().ack.status, StatusCode::BadState);
    let mut auth = HostAuth {
        key: KEY,
        epoch: 0,
        session: 1,
        counter: 0,
    };
    let env = auth.seal(&frame(8, Command::Pin1On));
    assert_eq!(status_of(&mut s, HOST, &env), StatusCode::Unsupported);
    assert_eq!(status_of(&mut s, OTHER, &env), StatusCode::NotOwner);
    assert_eq!(s.plant.pins, [(0, true)]);
    assert_eq!(s.controller.owner().unwrap().ip, HOST.ip, "no owner taken");
    assert_eq!(s.controller.report_settings().seal, SealRoutes::NONE);
}

#[test]
fn the_key_is_set_once_plain_then_changed_or_cleared_only_with_it() {
    let mut s = Session::<64>::new(64);
    let r = s.send_raw(HOST, &frame(1, Command::SetKey(Some(KEY))));
    assert_eq!(r.reply.unwrap().ack.status, StatusCode::Ok);
    let Some(Deferred::SaveSettings(saved)) = r.deferred else {
        panic!("the key is stored: {r:?}");
    };
    assert_eq!(saved.key, Some(KEY));
    // A random first epoch (issue 30; it was 1, and a key set again after the settings
    // were lost repeated its epochs): this controller's entropy is 0.
    assert_eq!(saved.auth_epoch, arm_core::auth::epoch_base(0, 0));
    // Plain, it cannot be replaced any more, not even by the owner.
    let r = s.send_raw(HOST, &frame(2, Command::SetKey(Some(WRONG_KEY))));
    assert_eq!(r.reply.unwrap().ack.status, StatusCode::AuthRequired);
    assert!(r.deferred.is_none());
    // Authenticated, it is cleared: then every plain frame works again.
    s.seq = 2;
    s.hello(KEY);
    s.expect(Command::SetKey(None), StatusCode::Ok);
    assert!(!s.controller.keyed());
    s.auth = None;
    s.expect(Command::Pin1On, StatusCode::Ok);
}

#[test]
fn a_frame_from_before_a_reset_never_verifies_after_it() {
    let s = keyed();
    let mut auth = s.auth.unwrap();
    let recorded = auth.seal(&frame(60, Command::Pin0On));
    // The controller resets with its stored settings: a new epoch, stored first.
    let stored: PersistentSettings = s.controller.settings();
    let mut rebooted = Session::<64>::new(64);
    rebooted.controller.apply_settings(stored);
    let next = rebooted
        .controller
        .begin_auth_epoch()
        .expect("a key is stored");
    assert_eq!(next.auth_epoch, stored.auth_epoch + 1);
    // Before the epoch is stored, HELLO is refused.
    let r = rebooted.send_raw(HOST, &frame(1, Command::Hello { nonce: [3; 16] }));
    assert_eq!(r.reply.unwrap().ack.status, StatusCode::BadState);
    rebooted.controller.auth_epoch_stored();
    // The attacker replays the HELLO too: same session id, but another epoch.
    let again = rebooted.hello(KEY);
    assert_eq!(again.session, auth.session);
    assert_ne!(again.epoch, auth.epoch);
    assert_eq!(
        status_of(&mut rebooted, HOST, &recorded),
        StatusCode::AuthFailed
    );
    assert!(rebooted.plant.pins.is_empty());
}

#[test]
fn reports_go_sealed_to_sessions_only() {
    let mut s = keyed();
    // Routed once the session proved the key (issue 30: a HELLO alone proves nothing).
    assert_eq!(s.controller.report_settings().seal.session_of(HOST), None);
    s.expect(Command::Pin0On, StatusCode::Ok);
    let routes = s.controller.report_settings();
    assert_eq!(routes.seal.session_of(HOST), Some(s.auth.unwrap().session));
    assert_eq!(routes.seal.session_of(OTHER), None);
    let mut sealer = Sealer::new();
    let mut buf = [0u8; MAX_SEALED_FRAME];
    let location = Outgoing::Location(Location::default());
    let frame_bytes = raw(1, 0x13, &[]);
    assert!(matches!(
        sealer.seal(&location, &frame_bytes, HOST, &routes.seal, &mut buf),
        Sealing::Sealed(_)
    ));
    assert_eq!(
        sealer.seal(&location, &frame_bytes, OTHER, &routes.seal, &mut buf),
        Sealing::Withheld
    );
    let refusal = Outgoing::Ack(Reply {
        to: OTHER,
        seq: 1,
        ack: Ack {
            acked_tag: 0,
            status: StatusCode::AuthRequired,
            state: State::New,
            next_seq: 0,
            buffered: 0,
            free: 0,
        },
    });
    assert_eq!(
        sealer.seal(&refusal, &frame_bytes, OTHER, &routes.seal, &mut buf),
        Sealing::Plain
    );
    // The host opens what the controller sealed.
    let Sealing::Sealed(n) = sealer.seal(&location, &frame_bytes, HOST, &routes.seal, &mut buf)
    else {
        panic!("sealed");
    };
    let env = protocol::auth::Envelope::open(&buf[..n]).unwrap();
    assert!(env.verify(&KEY, protocol::auth::Direction::ToHost, routes.seal.epoch));
    assert!(!env.verify(
        &KEY,
        protocol::auth::Direction::ToController,
        routes.seal.epoch
    ));
    assert_eq!(env.inner, &frame_bytes[..]);
}

#[test]
fn a_key_set_at_run_time_gates_plain_status_too() {
    let mut s = Session::<64>::new(64);
    s.expect(Command::Status, StatusCode::Ok);
    s.expect(Command::SetKey(Some(KEY)), StatusCode::Ok);
    let other_port = Endpoint { port: 5555, ..HOST };
    assert_eq!(
        status_of(&mut s, other_port, &frame(77, Command::Status)),
        StatusCode::AuthRequired
    );
}

/// Issue 30: the receive path's reserved share goes to the owner's address and to the
/// addresses of sessions that sent a valid envelope; a HELLO alone needs no key and
/// earns nothing.
#[test]
fn sessions_that_proved_the_key_are_trusted_by_the_receive_path() {
    let mut s = keyed();
    let trusted = |s: &Session<64>| s.controller.trusted_sources();
    assert!(trusted(&s).contains(HOST.ip), "the owner");
    s.from = OTHER;
    s.hello(KEY);
    assert!(!trusted(&s).contains(OTHER.ip), "a HELLO alone");
    s.send(Command::Status);
    assert!(trusted(&s).contains(OTHER.ip), "a valid envelope");
    // Without a key: the owner alone, and nobody after RELEASE.
    let mut plain = Session::<64>::new(64);
    assert!(plain.controller.trusted_sources().is_empty());
    plain.expect(Command::Status, StatusCode::Ok);
    let _ = plain.send_raw(OTHER, &frame(7, Command::Status));
    assert!(plain.controller.trusted_sources().contains(HOST.ip));
    assert!(!plain.controller.trusted_sources().contains(OTHER.ip));
    plain.expect(Command::Release, StatusCode::Ok);
    assert!(plain.controller.trusted_sources().is_empty());
}
