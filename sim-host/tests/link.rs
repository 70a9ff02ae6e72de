//! Issue 14 over UDP, against the sim-host process: every CRC-valid STOPPED stops a run
//! (issue 18 reversed bug 1's rule, under which one with data or repeated bytes did not), a second tool on the owner's machine disturbs neither the upload
//! nor another tool's reports (bug 2), and a burst of a whole window is taken whole
//! (bug 3). Every loop is bounded in count and time; traffic goes to 127.0.0.1 only.

mod common;

use std::collections::HashMap;
use std::time::{Duration, Instant};

use common::{Client, OwnedReport, Sim, points_through, temp_path};
use protocol::{
    Ack, Command, MAX_JOINTS, MAX_POINTS_PER_FRAME, Point, PointList, State, StatusCode,
    StatusFlags, Tag, crc8,
};

/// A frame with any tag and data, with a correct CRC.
fn raw(seq: u8, tag: u8, data: &[u8]) -> Vec<u8> {
    let mut bytes = vec![seq, tag];
    bytes.extend_from_slice(data);
    bytes.push(crc8(&bytes));
    bytes
}

fn encoded(seq: u8, command: &Command<'_>) -> Vec<u8> {
    let mut buf = vec![0u8; protocol::MAX_DATAGRAM];
    let n = command.encode(seq, &mut buf).expect("encodes");
    buf.truncate(n);
    buf
}

/// `command` encoded with `seq`, with its seq: one entry of a [`burst`].
fn seq_frame(seq: u8, command: &Command<'_>) -> (u8, Vec<u8>) {
    (seq, encoded(seq, command))
}

/// Sends `frames` (seq, bytes) back to back, then collects their ACKs (by seq) for up to
/// `wait`; other reports are kept in `client.reports`.
fn burst(client: &mut Client, frames: &[(u8, Vec<u8>)], wait: Duration) -> HashMap<u8, Ack> {
    for (_, bytes) in frames {
        client.socket.send(bytes).expect("send");
    }
    let mut acks = HashMap::new();
    let deadline = Instant::now() + wait;
    while acks.len() < frames.len() {
        let Some(left) = deadline.checked_duration_since(Instant::now()) else {
            break;
        };
        match client.receive(left) {
            Some((seq, OwnedReport::Ack(ack))) => {
                acks.insert(seq, ack);
            }
            Some(other) => client.reports.push(other),
            None => break,
        }
    }
    acks
}

/// `n` points moving joint 0 by +5 steps each, `us` long.
fn points(n: usize, us: i32) -> Vec<Point> {
    let targets: Vec<[i32; MAX_JOINTS]> = (1..=n as i32)
        .map(|i| [i * 5, 0, 0, 0, 0, 0, 0, 0])
        .collect();
    points_through([0; MAX_JOINTS], &targets, us)
}

/// Takes the next `n` seqs of the client.
fn seqs(client: &mut Client, n: usize) -> Vec<u8> {
    (0..n)
        .map(|_| {
            let s = client.seq;
            client.seq = client.seq.wrapping_add(1);
            s
        })
        .collect()
}

/// Points of [`run_then_stop`]'s runs: 1.2 s of them, so that a STOPPED sent once the run
/// moved lands in it however slow the machine (12 points left 220 ms).
const STOP_RUN_POINTS: i32 = 60;

/// Steps joint 0 moves in a whole run of [`run_then_stop`].
const STOP_RUN_STEPS: i32 = 5 * STOP_RUN_POINTS;

/// Starts a run of [`STOP_RUN_POINTS`] points of 20 ms moving joint 0 by +5 steps each,
/// from where it is, as `client` (NEW, PENDING, RUNING, each ACKed); once it moved a
/// point's worth, sends `stop` from `panel` (raw bytes, no ACK awaited), and returns the
/// STATUS once the run has ended, and the steps joint 0 moved of [`STOP_RUN_STEPS`].
fn run_then_stop(
    client: &mut Client,
    panel: &Client,
    stop: &[u8],
) -> (protocol::StatusReport, i32) {
    // STATUS first: the client is the owner and a LOCATION listener.
    client.status();
    let start = client.location().position;
    let targets: Vec<[i32; MAX_JOINTS]> = (1..=STOP_RUN_POINTS)
        .map(|i| {
            let mut t = start;
            t[0] += 5 * i;
            t
        })
        .collect();
    let pts = points_through(start, &targets, 20_000);
    client.ok(&Command::New {
        count: pts.len() as u16,
    });
    for chunk in pts.chunks(protocol::MAX_POINTS_PER_FRAME) {
        client.ok(&Command::Pending(PointList::Points(chunk)));
    }
    client.ok(&Command::Runing);
    // Under way (a point's worth moved), observed rather than slept for (issue 19).
    client.wait_moved(start[0], 5, Duration::from_secs(5));
    panel.socket.send(stop).expect("send");
    let status = client.wait_stopped(Duration::from_secs(5));
    client.status();
    let moved = client.location().position[0] - start[0];
    (status, moved)
}

// Issue 18 reversed this test's rule (issue 14's bug 1: a STOPPED with data was
// BAD_LENGTH and the same bytes again a duplicate, both "did nothing" and the test asserted
// the run completed). Now every CRC-valid STOPPED stops; a bad CRC still does nothing.
#[test]
fn every_crc_valid_stopped_stops_the_run_and_a_bad_crc_does_not() {
    let sim = Sim::start(&["--settings", temp_path("link-stop.txt").to_str().unwrap()]);
    let mut client = sim.client();
    let panel = sim.client();
    let stopped_early = |(status, moved): (protocol::StatusReport, i32)| {
        status.flags.has(StatusFlags::STOPPED_BY_HOST) && moved < STOP_RUN_STEPS
    };
    // An e-stop panel's one fixed frame, sent at every stop, runs less than 2 s apart.
    let fixed = raw(0x5a, Tag::Stopped as u8, &[]);
    for round in 0..10 {
        let outcome = run_then_stop(&mut client, &panel, &fixed);
        assert!(
            stopped_early(outcome),
            "round {round}: identical bytes must stop: {outcome:?}"
        );
    }
    for len in [1usize, 4] {
        let stop = raw(0x60 + len as u8, Tag::Stopped as u8, &vec![0xee; len]);
        let outcome = run_then_stop(&mut client, &panel, &stop);
        assert!(
            stopped_early(outcome),
            "{len} data bytes must stop: {outcome:?}"
        );
    }
    let mut bad = raw(0x70, Tag::Stopped as u8, &[]);
    *bad.last_mut().unwrap() ^= 0x01;
    let (status, moved) = run_then_stop(&mut client, &panel, &bad);
    assert!(
        !status.flags.has(StatusFlags::STOPPED_BY_HOST) && moved == STOP_RUN_STEPS,
        "a bad CRC stops nothing: {status:?}, moved {moved}"
    );
}

#[test]
fn a_second_tool_on_the_owners_machine_disturbs_neither_upload_nor_reports() {
    let sim = Sim::start(&["--settings", temp_path("link-tools.txt").to_str().unwrap()]);
    let mut uploader = sim.client();
    let mut poller = sim.client();
    assert_ne!(
        uploader.socket.local_addr().unwrap(),
        poller.socket.local_addr().unwrap()
    );
    // 24 points of 20 ms: a half-second run.
    let pts = points(24, 20_000);
    uploader.seq = 10;
    uploader.ok(&Command::New { count: 24 });
    let ack = uploader.ok(&Command::Pending(PointList::Points(&pts[..12])));
    assert_eq!(ack.next_seq, 12);
    // The other tool's STATUS uses seq 12 of its own numbering.
    poller.seq = 12;
    let status = poller.status();
    assert_eq!(status.state, State::Pending, "STATUS answers its requester");
    let ack = uploader.command(&Command::Pending(PointList::Points(&pts[12..])));
    assert_eq!((ack.status, ack.next_seq), (StatusCode::Ok, 13), "{ack:?}");
    uploader.ok(&Command::Runing);
    // The poller polls through the run; the uploader keeps getting its LOCATION
    // reports (every 10 ms), with no hole, and sees the run end.
    let started = Instant::now();
    let mut polls = 0;
    let mut final_state = None;
    let mut arrivals: Vec<Instant> = Vec::new();
    let mut stopped_seen = false;
    while started.elapsed() < Duration::from_secs(5) {
        let status = poller.status();
        polls += 1;
        let until = Instant::now() + Duration::from_millis(20);
        while let Some(left) = until.checked_duration_since(Instant::now()) {
            let Some(report) = uploader.receive(left) else {
                break;
            };
            if let (_, OwnedReport::Location(l)) = report {
                arrivals.push(Instant::now());
                stopped_seen |= l.state == State::Stopped as u8;
            }
        }
        if status.state == State::Stopped && stopped_seen {
            final_state = Some(status);
            break;
        }
    }
    let status = final_state.expect("the run ended, and the uploader saw it");
    assert_eq!((status.executed, status.expected), (24, 24), "{status:?}");
    assert!(polls > 3, "{polls}");
    assert!(
        arrivals.len() >= 20,
        "the uploader got {} LOCATIONs",
        arrivals.len()
    );
    let longest_hole = arrivals
        .windows(2)
        .map(|w| w[1] - w[0])
        .max()
        .unwrap_or_default();
    let mut holes: Vec<Duration> = arrivals.windows(2).map(|w| w[1] - w[0]).collect();
    holes.sort();
    println!(
        "uploader's LOCATION intervals over {} reports: p50 {:?} p90 {:?} max {:?}",
        arrivals.len(),
        holes[holes.len() / 2],
        holes[holes.len() * 9 / 10],
        longest_hole
    );
    // None went to the poller: its STATUS did not take the reports over.
    let diverted = poller
        .reports
        .iter()
        .filter(|(_, r)| matches!(r, OwnedReport::Location(_)))
        .count();
    assert_eq!(diverted, 0, "LOCATION reports sent to the poller");
    // 10 ms reports, stamped when this thread reads them: a loaded machine stalls it
    // (300 ms was the bound; it must hold ten times slower), never for the run's length.
    assert!(
        longest_hole < Duration::from_secs(2),
        "a {longest_hole:?} hole in the uploader's LOCATION reports"
    );
}

/// NEW then 31 PENDING frames of 12 points (1395 bytes each), back to back: how many of
/// `tries` bursts were taken whole (every frame ACKed OK).
fn whole_bursts(client: &mut Client, tries: usize) -> usize {
    let window = protocol::limits::HOST_WINDOW;
    let pts = points(MAX_POINTS_PER_FRAME * (window - 1), 10_000);
    let mut whole = 0;
    for _ in 0..tries {
        let s = seqs(client, window);
        let mut frames = vec![seq_frame(
            s[0],
            &Command::New {
                count: pts.len() as u16,
            },
        )];
        for (chunk, &seq) in pts.chunks(MAX_POINTS_PER_FRAME).zip(&s[1..]) {
            frames.push(seq_frame(seq, &Command::Pending(PointList::Points(chunk))));
        }
        assert!(frames[1..].iter().all(|(_, b)| b.len() == 1395));
        let acks = burst(client, &frames, Duration::from_secs(3));
        let ok = s
            .iter()
            .filter(|seq| acks.get(seq).is_some_and(|a| a.status == StatusCode::Ok))
            .count();
        whole += usize::from(ok == window);
    }
    whole
}

#[test]
fn a_burst_of_a_whole_window_is_taken_whole() {
    let sim = Sim::start(&["--settings", temp_path("link-burst.txt").to_str().unwrap()]);
    let mut client = sim.client();
    let status = client.status();
    assert_eq!(status.window, 32, "STATUS advertises the window");
    let tries = burst_tries();
    let whole = whole_bursts(&mut client, tries);
    println!(
        "burst of 32 (NEW + 31 PENDING of 1395 bytes) taken whole in {whole} of {tries} tries"
    );
    assert_eq!(whole, tries);
    // And a STOPPED behind a burst is still obeyed.
    let s = seqs(&mut client, 1)[0];
    let acks = burst(
        &mut client,
        &[(s, encoded(s, &Command::Stopped))],
        Duration::from_secs(2),
    );
    assert_eq!(acks.get(&s).map(|a| a.status), Some(StatusCode::Ok));
    assert_eq!(client.status().state, State::Stopped);
}

/// Bursts per measurement: `LINK_BURST_TRIES` (at most 500), else 20.
fn burst_tries() -> usize {
    std::env::var("LINK_BURST_TRIES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(20usize)
        .clamp(1, 500)
}

/// The figure against a controller already running at `LINK_BURST_ADDR` (a loopback
/// address only; e.g. an older sim-host, for comparison). Prints, asserts nothing.
#[test]
#[ignore = "needs LINK_BURST_ADDR=127.0.0.1:PORT of a running controller"]
fn burst_figure_against_a_running_controller() {
    let Some(addr) = std::env::var("LINK_BURST_ADDR")
        .ok()
        .and_then(|a| a.parse::<std::net::SocketAddr>().ok())
    else {
        println!("set LINK_BURST_ADDR=127.0.0.1:PORT");
        return;
    };
    assert!(addr.ip().is_loopback(), "loopback addresses only");
    let mut client = Client::new(addr);
    let tries = burst_tries();
    let whole = whole_bursts(&mut client, tries);
    println!("{addr}: burst of 32 taken whole in {whole} of {tries} tries");
}

/// A host resending a refused frame in a loop: the simulator logs the first refusal of
/// each second with a count, not a line per datagram.
#[test]
fn a_host_resending_in_a_loop_gets_no_log_line_per_datagram() {
    use std::io::{BufRead, BufReader};
    use std::process::{Command as Process, Stdio};
    let settings = temp_path("link-log.txt");
    let mut child = Process::new(env!("CARGO_BIN_EXE_sim-host"))
        .args(["--bind", "127.0.0.1:0", "--log-level", "info", "--settings"])
        .arg(&settings)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("sim-host starts");
    let stdout = child.stdout.take().expect("stdout");
    let mut lines = BufReader::new(stdout).lines();
    let addr: std::net::SocketAddr = loop {
        let line = lines.next().expect("an address line").expect("readable");
        if let Some(a) = line.strip_prefix("sim-host: listening on udp ") {
            break a.parse().expect("an address");
        }
    };
    std::thread::spawn(move || for _ in lines {});
    let stderr = child.stderr.take().expect("stderr");
    let log = std::thread::spawn(move || {
        BufReader::new(stderr)
            .lines()
            .map_while(Result::ok)
            .filter(|l| l.contains("refused"))
            .count()
    });
    let mut client = Client::new(addr);
    client.ok(&Command::Status);
    // RUNING in STOPPED: BAD_STATE, 2000 times in well under a second.
    const SENT: usize = 2_000;
    let runing = encoded(7, &Command::Runing);
    let started = Instant::now();
    let mut acked = 0;
    for _ in 0..SENT {
        client.socket.send(&runing).expect("send");
        if let Some((_, OwnedReport::Ack(a))) = client.receive(Duration::from_millis(200)) {
            acked += usize::from(a.status == StatusCode::BadState);
        }
    }
    let seconds = started.elapsed().as_secs() as usize + 1;
    // SAFETY: signalling our own child process by its pid.
    unsafe {
        libc::kill(child.id() as libc::pid_t, libc::SIGTERM);
    }
    let _ = child.wait();
    let logged = log.join().expect("log reader");
    assert!(acked > SENT / 2, "{acked} refusals ACKed");
    assert!(
        (1..=seconds + 1).contains(&logged),
        "{logged} refusal lines for {SENT} refusals in {seconds} s"
    );
}
