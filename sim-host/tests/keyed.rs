//! A keyed arm stays its key holder's (issue 30, docs/PROTOCOL.md section 13), against
//! the real simulator: a HELLO flood from 20 other addresses during keyed runs; a key set
//! again after the settings were erased; SET_KEY while running; a save that fails.
//!
//! Every loop that sends is bounded in count and time; every address is loopback
//! (127.0.0.1 the key holder, 127.0.0.10-29 the flood).

mod common;

use std::net::{Ipv4Addr, SocketAddr, UdpSocket};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use armctl::{Client as Armctl, Error, Options, RunOptions};
use common::*;
use protocol::auth::{AuthKey, Envelope, HelloReply, KEY_LEN};
use protocol::{Command, MAX_DATAGRAM, State, StatusCode};

const KEY: AuthKey = AuthKey([0x42; KEY_LEN]);

/// Flooding addresses.
const FLOODERS: u8 = 20;
/// HELLOs a second from all of them together.
const FLOOD_HZ: u64 = 500;
/// The flood never runs longer than this, nor sends more than `FLOOD_HZ` times it.
const FLOOD_LIMIT: Duration = Duration::from_secs(90);

/// A settings file holding `KEY`.
fn keyed_settings(name: &str) -> std::path::PathBuf {
    let path = temp_path(&format!("{name}.txt"));
    let hex: String = KEY.0.iter().map(|b| format!("{b:02x}")).collect();
    std::fs::write(&path, format!("joints=6\nkey={hex}\nauth_epoch=3\n")).unwrap();
    path
}

fn key_holder(addr: SocketAddr) -> Armctl {
    Armctl::connect_with(
        addr,
        Options {
            key: Some(KEY),
            ..Options::default()
        },
    )
    .expect("the key holder connects")
}

/// HELLOs from 127.0.0.10-29 at `FLOOD_HZ` in all, each with a new nonce, until stopped.
struct Flood {
    stop: Arc<AtomicBool>,
    sent: Arc<AtomicU64>,
    answered: Arc<AtomicU64>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Flood {
    fn start(to: SocketAddr) -> Flood {
        let sockets: Vec<UdpSocket> = (0..FLOODERS)
            .map(|i| {
                let s = UdpSocket::bind((Ipv4Addr::new(127, 0, 0, 10 + i), 0)).unwrap();
                s.set_nonblocking(true).unwrap();
                s
            })
            .collect();
        let stop = Arc::new(AtomicBool::new(false));
        let sent = Arc::new(AtomicU64::new(0));
        let answered = Arc::new(AtomicU64::new(0));
        let thread = {
            let (stop, sent, answered) = (stop.clone(), sent.clone(), answered.clone());
            std::thread::spawn(move || {
                let started = Instant::now();
                let period = Duration::from_micros(1_000_000 / FLOOD_HZ);
                let most = FLOOD_HZ * FLOOD_LIMIT.as_secs();
                let mut buf = [0u8; MAX_DATAGRAM];
                let mut n: u64 = 0;
                while !stop.load(Ordering::Relaxed) && n < most && started.elapsed() < FLOOD_LIMIT {
                    let socket = &sockets[(n % u64::from(FLOODERS)) as usize];
                    let mut nonce = [0u8; 16];
                    nonce[..8].copy_from_slice(&n.to_le_bytes());
                    let len = Command::Hello { nonce }.encode(n as u8, &mut buf).unwrap();
                    if socket.send_to(&buf[..len], to).is_ok() {
                        sent.fetch_add(1, Ordering::Relaxed);
                    }
                    while socket.recv(&mut buf).is_ok() {
                        answered.fetch_add(1, Ordering::Relaxed);
                    }
                    n += 1;
                    // Paced from the start: a late wake-up sends the ones it owes.
                    let due = started + period * (n as u32);
                    if let Some(wait) = due.checked_duration_since(Instant::now()) {
                        std::thread::sleep(wait);
                    }
                }
            })
        };
        Flood {
            stop,
            sent,
            answered,
            thread: Some(thread),
        }
    }

    /// Stops it; (HELLOs sent, replies they got).
    fn stop(mut self) -> (u64, u64) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            t.join().unwrap();
        }
        (
            self.sent.load(Ordering::Relaxed),
            self.answered.load(Ordering::Relaxed),
        )
    }
}

/// Issue 30's "done when": before it, the flood's HELLOs took the key holder's session
/// (AUTH_FAILED, a HELLO more, whose reply the flood's had spent the budget of) and a
/// run could stall.
#[test]
fn a_hello_flood_from_20_addresses_never_breaks_a_keyed_run() {
    let settings = keyed_settings("keyed-flood");
    // A buffer of 24 points: the 80-point runs stream through it during the flood.
    let sim = Sim::start(&[
        "--settings",
        settings.to_str().unwrap(),
        "--buffer-capacity",
        "24",
    ]);
    let flood = Flood::start(sim.addr);
    // The flood is under way before the key holder says HELLO.
    let began = Instant::now();
    while flood.sent.load(Ordering::Relaxed) < 200 {
        assert!(
            began.elapsed() < Duration::from_secs(30),
            "the flood never started"
        );
        std::thread::sleep(Duration::from_millis(10));
    }
    // Out and back: each run starts where the last ended.
    let targets: Vec<[i32; 8]> = (1..=40)
        .chain((0..40).rev())
        .map(|i| [i * 20, -i * 10, i * 5, 0, 0, 0, 0, 0])
        .collect();
    let points = points_through([0; 8], &targets, 20_000);
    let mut completed = 0;
    for run in 1..=3 {
        let arm = key_holder(sim.addr);
        let report = arm
            .run_trajectory(&points, &RunOptions::default(), |_| {})
            .expect("the key holder's run during the flood");
        let status = report.final_status.expect("STATUS after the run");
        println!(
            "run {run}/3: {} of {} points executed in {:.2} s, {} datagrams ({} resent), AUTH_FAILED seen: {}, flood so far {} HELLOs",
            status.executed,
            points.len(),
            report.total_time.as_secs_f64(),
            report.datagrams_sent,
            report.retransmissions,
            arm.auth_failures(),
            flood.sent.load(Ordering::Relaxed)
        );
        assert_eq!(
            usize::from(status.executed),
            points.len(),
            "run {run}: {status:?}"
        );
        assert_eq!(status.state, State::Stopped);
        assert_eq!(
            arm.auth_failures(),
            0,
            "run {run}: the key holder's session was taken"
        );
        completed += 1;
    }
    let seconds = began.elapsed().as_secs_f64();
    let (sent, answered) = flood.stop();
    println!(
        "flood: {sent} HELLOs from {FLOODERS} addresses in {seconds:.1} s ({:.0}/s), {answered} answered ({:.1}/s); runs completed {completed}/3",
        sent as f64 / seconds,
        answered as f64 / seconds
    );
    assert_eq!(completed, 3);
}

/// The epoch a raw HELLO from a new socket gets.
fn epoch_of(addr: SocketAddr) -> u64 {
    let raw = Client::new(addr);
    raw.socket
        .set_read_timeout(Some(Duration::from_millis(500)))
        .unwrap();
    let mut buf = [0u8; MAX_DATAGRAM];
    let n = Command::Hello { nonce: [5; 16] }
        .encode(1, &mut buf)
        .unwrap();
    // Bounded: a few tries (the first HELLO of a boot may come before the epoch is stored).
    for _ in 0..20 {
        raw.socket.send(&buf[..n]).unwrap();
        let mut answer = [0u8; MAX_DATAGRAM];
        if let Ok(m) = raw.socket.recv(&mut answer)
            && let Ok(env) = Envelope::open(&answer[..m])
            && let Ok(reply) = HelloReply::decode(env.inner)
        {
            return reply.body.epoch;
        }
    }
    panic!("no HELLO_REPLY");
}

/// Before issue 30 a key set again on a controller whose settings were lost started at
/// epoch 1 again, the epochs of its first life: every envelope recorded then verified
/// again.
#[test]
fn a_key_set_again_after_the_settings_were_erased_never_repeats_an_epoch() {
    let settings = temp_path("keyed-erased.txt");
    let mut epochs = Vec::new();
    for life in 0..2 {
        let _ = std::fs::remove_file(&settings);
        let mut sim = Sim::start(&["--settings", settings.to_str().unwrap()]);
        Armctl::connect(sim.addr)
            .unwrap()
            .set_key(Some(KEY))
            .expect("the first key, plain");
        epochs.push((life, "set", epoch_of(sim.addr)));
        sim.stop();
        // A boot with the key: the next epoch.
        let mut sim = Sim::start(&["--settings", settings.to_str().unwrap()]);
        epochs.push((life, "boot", epoch_of(sim.addr)));
        sim.stop();
    }
    println!("epochs: {epochs:?}");
    for (i, (_, _, e)) in epochs.iter().enumerate() {
        assert!(
            epochs[..i].iter().all(|(_, _, f)| f != e),
            "an epoch repeated: {epochs:?}"
        );
    }
    assert_eq!(epochs[1].2, epochs[0].2 + 1, "a boot is the next epoch");
}

#[test]
fn set_key_while_running_is_bad_state_and_the_key_stays() {
    let settings = keyed_settings("keyed-running");
    let sim = Sim::start(&["--settings", settings.to_str().unwrap()]);
    let arm = Arc::new(key_holder(sim.addr));
    let pts = points_through([0; 8], &[[2_000, 0, 0, 0, 0, 0, 0, 0]], 2_000_000);
    let runner = {
        let arm = arm.clone();
        std::thread::spawn(move || arm.run_trajectory(&pts, &RunOptions::default(), |_| {}))
    };
    let deadline = Instant::now() + Duration::from_secs(10);
    while arm.last_location().is_none_or(|l| l.position[0] < 20) {
        assert!(Instant::now() < deadline, "the run never started");
        std::thread::sleep(Duration::from_millis(10));
    }
    match arm.set_key(None) {
        Err(Error::Refused { status, .. }) => assert_eq!(status, StatusCode::BadState),
        other => panic!("SET_KEY while running: {other:?}"),
    }
    let report = runner.join().unwrap().expect("the run goes on");
    assert_eq!(report.final_status.unwrap().executed, 1);
    // Stopped, the key holder may clear it.
    arm.set_key(None).expect("SET_KEY while stopped");
    sim.client().ok(&Command::Pin0On);
}

/// Before issue 30 the ACK went out `OK` before the save, and a failed save was only
/// logged: the host believed a setting stored that the next boot did not have.
#[test]
fn a_save_that_fails_is_save_failed() {
    // A settings path under a regular file: no directory can be made there, even as root.
    let blocker = temp_path("keyed-not-a-dir");
    std::fs::write(&blocker, "a file").unwrap();
    let settings = blocker.join("settings.txt");
    let sim = Sim::start(&["--settings", settings.to_str().unwrap()]);
    let mut host = sim.client();
    assert_eq!(
        host.command(&Command::JointsCount(4)).status,
        StatusCode::SaveFailed
    );
    assert_eq!(host.status().joints, 6, "nothing changed");
    assert_eq!(
        host.command(&Command::SetKey(Some(KEY))).status,
        StatusCode::SaveFailed
    );
    host.ok(&Command::Pin0On);
}
