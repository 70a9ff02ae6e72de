//! Stopping what a call started (issue 18), in the library: a [`Cancel`] token ends an
//! upload, a run's wait and `wait_stopped_cancellable` within `CANCEL_POLL` without sending
//! anything, and `stop_until_acked` resends STOPPED until it is ACKed, bounded, or until the
//! caller gives up. Against the fake controller (arm-core's state machine) and a socket that
//! swallows everything.

mod fake;

use std::net::UdpSocket;
use std::sync::Arc;
use std::time::{Duration, Instant};

use armctl::{Cancel, Client, Error, Options, RunOptions, StopOutcome, StopRetry};
use fake::{Fake, Faults, ramp};
use protocol::{State, StatusFlags, Tag};

/// How late a cancelled call may return: a bound a machine ten times slower or busier than
/// ours still meets (here 12-24 ms after the cancel: the 20 ms `CANCEL_POLL` and the
/// wake-up), far below what a call that ignored the token takes (the run's end, 700 ms
/// after the cancel or more). The figure is printed. (It was 100 ms: 4x the figure.)
const CANCEL_LATENCY: Duration = Duration::from_millis(400);

fn options() -> Options {
    Options {
        ack_timeout: Duration::from_millis(30),
        attempts: 20,
        report_timeout: Duration::from_millis(100),
        ..Options::default()
    }
}

/// Cancels `cancel` after `delay` on a thread of its own; the instant it did.
fn cancel_after(cancel: &Cancel, delay: Duration) -> std::thread::JoinHandle<Instant> {
    let cancel = cancel.clone();
    std::thread::spawn(move || {
        std::thread::sleep(delay);
        let at = Instant::now();
        cancel.cancel();
        at
    })
}

#[test]
fn a_cancelled_run_returns_at_once_sends_nothing_and_stop_until_acked_stops_it() {
    // A 64-point buffer: the upload still streams when the token is set; 4096: every point
    // is in, the client waits for the end of the run.
    for capacity in [64, 4096] {
        let fake = Fake::start(capacity, Faults::default());
        let arm = Client::connect_with(fake.addr, options()).unwrap();
        let points = ramp(500, 1, 2000); // 1 s
        let cancel = Cancel::new();
        let options = RunOptions {
            cancel: Some(cancel.clone()),
            ..RunOptions::default()
        };
        let canceller = cancel_after(&cancel, Duration::from_millis(300));
        let result = arm.run_trajectory(&points, &options, |_| {});
        let returned = Instant::now();
        let cancelled = canceller.join().unwrap();
        let late = returned - cancelled;
        eprintln!("capacity {capacity}: returned {late:?} after the cancel");
        assert!(matches!(result, Err(Error::Interrupted)), "{result:?}");
        assert!(late <= CANCEL_LATENCY, "returned {late:?} after the cancel");
        // The token sends nothing: the arm still runs.
        let status = arm.status().unwrap();
        assert_eq!(status.state, State::Running, "{status:?}");
        assert!(usize::from(status.executed) < points.len());

        let outcome = arm.stop_until_acked(&StopRetry::default(), || false);
        assert!(outcome.is_acked(), "{outcome}");
        assert_eq!(outcome.tries(), 1, "{outcome}");
        assert!(
            outcome
                .to_string()
                .starts_with("STOPPED sent, the arm is stopped (ACKed after 1 try"),
            "{outcome}"
        );
        let status = arm.status().unwrap();
        assert_eq!(status.state, State::Stopped);
        assert!(status.flags.has(StatusFlags::STOPPED_BY_HOST));
        assert!(usize::from(status.executed) < points.len());
    }
}

#[test]
fn a_token_cancelled_before_the_call_sends_no_new() {
    let fake = Fake::start(64, Faults::default());
    let arm = Client::connect_with(fake.addr, options()).unwrap();
    let cancel = Cancel::new();
    cancel.cancel();
    let options = RunOptions {
        cancel: Some(cancel),
        ..RunOptions::default()
    };
    let result = arm.run_trajectory(&ramp(10, 1, 2000), &options, |_| {});
    assert!(matches!(result, Err(Error::Interrupted)), "{result:?}");
    let status = arm.status().unwrap();
    assert_eq!((status.state, status.expected), (State::Stopped, 0));
}

#[test]
fn wait_stopped_cancellable_returns_soon_after_the_cancel() {
    let fake = Fake::start(4096, Faults::default());
    let arm = Arc::new(Client::connect_with(fake.addr, options()).unwrap());
    let points = ramp(500, 1, 2000);
    let upload_only = RunOptions {
        wait: false,
        ..RunOptions::default()
    };
    arm.run_trajectory(&points, &upload_only, |_| {}).unwrap();
    let cancel = Cancel::new();
    let canceller = cancel_after(&cancel, Duration::from_millis(200));
    let result = arm.wait_stopped_cancellable(Duration::from_secs(30), &cancel);
    let late = Instant::now() - canceller.join().unwrap();
    eprintln!("wait_stopped_cancellable: returned {late:?} after the cancel");
    assert!(matches!(result, Err(Error::Interrupted)), "{result:?}");
    assert!(late <= CANCEL_LATENCY, "returned {late:?} after the cancel");
    assert_eq!(arm.status().unwrap().state, State::Running);
    assert!(
        arm.stop_until_acked(&StopRetry::default(), || false)
            .is_acked()
    );
}

/// A "controller" that takes every datagram and answers none.
fn black_hole() -> UdpSocket {
    let socket = UdpSocket::bind("127.0.0.1:0").unwrap();
    socket
        .set_read_timeout(Some(Duration::from_millis(50)))
        .unwrap();
    socket
}

fn swallowed(socket: &UdpSocket) -> Vec<Vec<u8>> {
    let mut buf = [0u8; 2048];
    let mut got = Vec::new();
    while let Ok(n) = socket.recv(&mut buf) {
        got.push(buf[..n].to_vec());
    }
    got
}

#[test]
fn stopped_unanswered_is_resent_every_interval_then_reported_not_acked() {
    let hole = black_hole();
    let arm = Client::open(hole.local_addr().unwrap(), Options::default()).unwrap();
    let retry = StopRetry {
        interval: Duration::from_millis(40),
        tries: 5,
    };
    let started = Instant::now();
    let outcome = arm.stop_until_acked(&retry, || false);
    let took = started.elapsed();
    eprintln!("5 unanswered copies 40 ms apart: gave up after {took:?}");
    match outcome {
        StopOutcome::NotAcked { tries: 5, waited } => {
            assert!(waited >= Duration::from_millis(190), "{waited:?}")
        }
        other => panic!("{other:?}"),
    }
    // Bounded: 200 ms of resends by design; 2 s holds on a machine ten times slower or
    // busier (it was 600 ms), and catches a resend that waits out the client's own
    // retries (`Options::default()`: 1 s per copy).
    assert!(took < Duration::from_secs(2), "{took:?}");
    assert!(
        outcome.to_string().contains("not ACKed after 5 tries"),
        "{outcome}"
    );
    // Five copies of one frame: a STOPPED, the same seq each time.
    let copies = swallowed(&hole);
    assert_eq!(copies.len(), 5);
    assert!(copies.iter().all(|c| c == &copies[0]));
    assert_eq!(copies[0][1], Tag::Stopped as u8);
}

#[test]
fn giving_up_ends_the_wait_after_the_first_copy() {
    let hole = black_hole();
    let arm = Client::open(hole.local_addr().unwrap(), Options::default()).unwrap();
    // Copies 1 s apart: the give-up 60 ms in comes long before the second copy, however
    // slow this machine (with the default 100 ms a busy machine could send the second
    // copy first).
    let retry = StopRetry {
        interval: Duration::from_secs(1),
        tries: 10,
    };
    let started = Instant::now();
    // A second Ctrl-C 60 ms into the resending.
    let outcome = arm.stop_until_acked(&retry, || started.elapsed() >= Duration::from_millis(60));
    let took = started.elapsed();
    eprintln!("given up 60 ms in: returned after {took:?}");
    assert!(
        matches!(outcome, StopOutcome::Abandoned { tries: 1, .. }),
        "{outcome:?}"
    );
    // The give-up is looked at every CANCEL_POLL (20 ms): about 60-80 ms here. 500 ms holds
    // ten times slower or busier (it was 60 ms + 3 polls = 120 ms), and is half the interval
    // a wait that looked only between copies would take.
    assert!(took < Duration::from_millis(500), "{took:?}");
    assert_eq!(swallowed(&hole).len(), 1);
    // Even a caller who gives up at once sends one copy.
    let outcome = arm.stop_until_acked(&StopRetry::default(), || true);
    assert!(
        matches!(outcome, StopOutcome::Abandoned { tries: 1, .. }),
        "{outcome:?}"
    );
    assert_eq!(swallowed(&hole).len(), 1);
}
