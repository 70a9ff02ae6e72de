//! The firmware itself (no_std, Cortex-M7, embassy-net over the LAN9118 driver) on QEMU's
//! `mps2-an500`, driven over emulated Ethernet by armctl: the end-to-end checks that
//! `e2e.rs` runs against sim-host, where they apply to the board (its buffer is the
//! NUCLEO's 8192 points; the lossy link is a relay on the host side).
//!
//! Needs `qemu-system-arm`; without it every test prints why it is skipped and passes
//! (`.ci/run` installs QEMU, so CI runs them). A panic, HardFault, stack overflow or
//! unexpected interrupt in the firmware ends QEMU and fails the test with the firmware's
//! log; a hang fails it through armctl's timeouts, also with the log.
//!
//! Owner lock and an e-stop from a second host need two host addresses; QEMU's user-mode
//! network shows every host as 10.0.2.2, so those run over TAP in a network namespace, in
//! `tests/qemu/tap.sh` (root; `.ci/run` runs it).

mod common;

use std::net::{SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use armctl::{Client, Error, Options, RunEnd, RunOptions};
use common::{
    Raw, assert_stays_put, out_of_order_names_the_missing_frame, pins_and_servo_pwm,
    raw_frames_are_refused, refusals_in_stopped, rx_counters_after_stops, serial_round_trip,
    stop_mid_run, sweep,
};
use protocol::{Command, MAX_JOINTS, Point, PointList, State, StatusCode, StatusFlags, Tag};
use system_tests::qemu::{FAULT_MARKERS, QemuBoard, echo, run_to_exit, unavailable};

/// Skips the test, saying what it needs, when QEMU is not installed. The message goes to
/// the real stderr (not the test harness's capture), so a passing skip is still seen.
macro_rules! require_qemu {
    () => {
        if let Some(reason) = unavailable() {
            use std::io::Write;
            let _ = writeln!(std::io::stderr().lock(), "{}: {reason}", module_path!());
            return;
        }
    };
}

/// Emulated time runs close to wall time, but a loaded host stalls QEMU now and then:
/// generous ACK timeouts, many attempts.
fn emulated() -> Options {
    Options {
        ack_timeout: Duration::from_millis(150),
        attempts: 20,
        ..Options::default()
    }
}

fn position(board: &QemuBoard, arm: &Client) -> [i32; MAX_JOINTS] {
    arm.current_location(Duration::from_secs(3))
        .unwrap_or_else(|e| panic!("a LOCATION report: {e}\n{}", board.log()))
        .position
}

/// What the board's fake STEP lines saw since boot, per joint, as the last whole "step
/// output at rest" line of its log says: the net pulses (rising edges signed by DIR) and
/// the rising edges (no such line yet: none). A line still being written (no newline yet)
/// is not read.
fn lines_seen(log: &str) -> ([i32; MAX_JOINTS], [u32; MAX_JOINTS]) {
    fn counts<T: std::str::FromStr>(list: &str) -> [T; MAX_JOINTS] {
        let counts: Vec<T> = list
            .split(',')
            .map(|n| n.trim().parse().ok().expect("a count"))
            .collect();
        counts.try_into().ok().expect("one count per joint")
    }
    let Some(line) = log
        .split_inclusive('\n')
        .filter(|line| line.ends_with('\n'))
        .rfind(|line| line.contains("step output at rest: pulses ["))
    else {
        return ([0; MAX_JOINTS], [0; MAX_JOINTS]);
    };
    let list = |after: &str| {
        let (_, rest) = line.split_once(after).expect("the log line's format");
        rest.split_once(']').expect("the log line's format").0
    };
    (counts(list("pulses [")), counts(list("rising edges [")))
}

/// CI once read the log while the board was writing that line: the test panicked on the
/// half line ("the log line's format") instead of reading the one before and retrying.
#[test]
fn a_line_being_written_is_not_read() {
    let whole = "INFO step output at rest: pulses [3, -2, 0, 0, 0, 0, 0, 0], rising edges \
                 [3, 4, 0, 0, 0, 0, 0, 0], late pulses 0\n";
    let cut = "INFO step output at rest: pulses [5, -2, 0, 0, 0, 0, 0, 0], rising ed";
    let expected = ([3, -2, 0, 0, 0, 0, 0, 0], [3, 4, 0, 0, 0, 0, 0, 0]);
    assert_eq!(lines_seen(&format!("{whole}{cut}")), expected);
    assert_eq!(lines_seen(whole), expected);
    assert_eq!(lines_seen(cut), ([0; MAX_JOINTS], [0; MAX_JOINTS]));
}

/// Waits (30 s at most) until the STEP lines, at rest, have seen `moved` net pulses since
/// boot (the edges played from the producer's buffers, signed by DIR) and rising edges
/// that `rising_ok` accepts: what left the "pins" must be what the controller says it
/// moved, and the steps the trajectory asked for.
fn assert_lines_saw(
    board: &QemuBoard,
    moved: [i32; MAX_JOINTS],
    rising_ok: impl Fn(&[u32; MAX_JOINTS]) -> bool,
) {
    // The line comes from the board's step-output monitor, at rest, on the emulator's own
    // progress: a loaded host stalls QEMU, so the bound is generous (it returns as soon as
    // the line says so; only a wrong count waits it out).
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        // The firmware's log alone: in `board.log()` the QEMU heading that follows it
        // gives a line still being written its newline, so the half line was read (a run
        // of .ci/run panicked with "the log line's format" on a line whole in the log
        // printed just after).
        let (pulses, rising) = lines_seen(&board.firmware_log());
        if pulses == moved && rising_ok(&rising) {
            return;
        }
        assert!(
            Instant::now() < deadline,
            "the STEP lines saw {pulses:?} pulses ({rising:?} rising edges), the positions \
             moved {moved:?}\n{}",
            board.log()
        );
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// `to - from`, joint by joint.
fn moved(from: [i32; MAX_JOINTS], to: [i32; MAX_JOINTS]) -> [i32; MAX_JOINTS] {
    std::array::from_fn(|j| to[j] - from[j])
}

/// The steps (one pulse each) `points` ask of every joint from `start`: out and back
/// counts both ways.
fn steps_asked(start: [i32; MAX_JOINTS], points: &[Point]) -> [u32; MAX_JOINTS] {
    let mut steps = [0; MAX_JOINTS];
    let mut at = start;
    for point in points {
        for (j, steps) in steps.iter_mut().enumerate() {
            *steps += point.position[j].abs_diff(at[j]);
        }
        at = point.position;
    }
    steps
}

fn refused(
    board: &QemuBoard,
    result: armctl::Result<protocol::Ack>,
    status: StatusCode,
    what: &str,
) {
    match result {
        Err(e) if e.status() == Some(status) => {}
        Err(e) => panic!(
            "{what}: expected {}, got: {e}\n{}",
            status.name(),
            board.log()
        ),
        Ok(ack) => panic!("{what}: expected {}, got {ack:?}", status.name()),
    }
}

#[test]
fn status_over_emulated_ethernet() {
    require_qemu!();
    let mut board = QemuBoard::start();
    let arm = board.connect_with(emulated());
    let status = arm.status().unwrap();
    assert_eq!(status.state, State::Stopped);
    // The QEMU board's profile (arm_core::profile, checked against the docs in
    // sim-host/tests/profile.rs).
    let profile = arm_core::profile::QEMU_MPS2_AN500;
    assert_eq!(
        usize::from(status.capacity),
        profile.trajectory_capacity,
        "{status:?}"
    );
    assert_eq!(status.pwm_timer_clock_hz, profile.pwm_timer_clock_hz);
    assert_eq!(status.max_step_rate_hz, profile.max_step_rate_hz());
    assert_eq!(status.step_budget_hz, profile.step_budget_hz);
    assert_eq!(
        usize::from(status.window),
        protocol::limits::HOST_WINDOW,
        "{status:?}"
    );
    assert_eq!(status.joints, 6);
    assert!(
        board.log().contains("LAN9118 id 0x01180001"),
        "{}",
        board.log()
    );
    board.assert_healthy();
}

/// DISCOVER_REPLY carries the LAN9118's MAC (the board hands it to the controller at boot,
/// through arm-wiring's `spawn_controller`) and the stored address, which is the one in use.
#[test]
fn discover_reports_the_boards_mac_and_address() {
    require_qemu!();
    let mut board = QemuBoard::start();
    let SocketAddr::V4(target) = board.addr else {
        panic!("the board's forwarded port is IPv4: {}", board.addr);
    };
    let found = armctl::discover::discover(&armctl::discover::DiscoverOptions {
        target,
        bind: Some(std::net::SocketAddrV4::new(
            std::net::Ipv4Addr::LOCALHOST,
            0,
        )),
        wait: Duration::from_millis(500),
        rounds: 4,
    })
    .unwrap();
    let reply = found
        .first()
        .and_then(|f| f.reply)
        .unwrap_or_else(|| panic!("no DISCOVER_REPLY: {found:?}\n{}", board.log()));
    assert_ne!(reply.mac, [0; 6], "the controller was never given the MAC");
    let mac = armctl::discover::mac_string(&reply.mac);
    assert!(
        board.log().contains(&format!("MAC {mac}")),
        "DISCOVER_REPLY says {mac}:\n{}",
        board.log()
    );
    assert_eq!(reply.net.ip, [10, 0, 2, 15], "{reply:?}");
    assert!(!reply.net.dhcp && !reply.pending_reset, "{reply:?}");
    assert_eq!((reply.joints, reply.state), (6, State::Stopped));
    board.assert_healthy();
}

#[test]
fn run_reaches_the_last_point_and_executes_every_point() {
    require_qemu!();
    let mut board = QemuBoard::start();
    let arm = board.connect_with(emulated());
    arm.set_location(&[100, -200, 300, 0, 0, 0]).unwrap();
    let start = position(&board, &arm);
    assert_eq!(&start[..3], &[100, -200, 300]);
    let points = sweep(start, 6, 120, 4, 10_000);
    let report = arm
        .run_trajectory(&points, &RunOptions::default(), |_| {})
        .unwrap_or_else(|e| panic!("{e}\n{}", board.log()));
    let status = report.final_status.unwrap();
    let expected = points.last().unwrap().position;
    assert_eq!(status.state, State::Stopped);
    assert_eq!(usize::from(status.executed), points.len());
    assert!(!status.flags.has(StatusFlags::UNDERRUN));
    let end = position(&board, &arm);
    assert_eq!(end[..6], expected[..6]);
    let asked = steps_asked(start, &points);
    assert_lines_saw(&board, moved(start, end), |rising| *rising == asked);
    assert!(
        report.total_time >= Duration::from_millis(1150),
        "{report:?}"
    );
    board.assert_healthy();
}

#[test]
fn every_command_of_the_manual() {
    require_qemu!();
    let mut board = QemuBoard::start();
    let arm = board.connect_with(emulated());

    // Refusals in STOPPED.
    refusals_in_stopped(&arm, |result, status, what| {
        refused(&board, result, status, what)
    });

    // JOINTS_COUNT (settings in RAM), LOCATION_SETTING, UPLOAD_PERIOD, UPLOAD_START/STOP.
    arm.set_joints(3).unwrap();
    assert_eq!(arm.status().unwrap().joints, 3);
    arm.set_location(&[400, -300, 200]).unwrap();
    assert_eq!(position(&board, &arm)[..3], [400, -300, 200]);
    arm.upload_period(20_000).unwrap();
    assert_eq!(arm.status().unwrap().upload_period_us, 20_000);
    arm.reports(false).unwrap();
    assert!(!arm.status().unwrap().flags.has(StatusFlags::REPORTS_ON));
    arm.reports(true).unwrap();

    // RETURN: a planned move to zero, run by the step engine.
    arm.go_home().unwrap();
    let status = arm
        .wait_stopped(Duration::from_secs(30))
        .unwrap_or_else(|e| panic!("RETURN: {e}\n{}", board.log()));
    assert_eq!(status.state, State::Stopped);
    assert_eq!(position(&board, &arm)[..3], [0, 0, 0]);
    assert_lines_saw(&board, [-400, 300, -200, 0, 0, 0, 0, 0], |rising| {
        *rising == [400, 300, 200, 0, 0, 0, 0, 0]
    });

    // TOGGLE_ENABLE_PINS, PIN0/PIN1, gripper PWM.
    let enabled = arm
        .status()
        .unwrap()
        .flags
        .has(StatusFlags::DRIVERS_ENABLED);
    arm.toggle_enable(None).unwrap();
    assert_ne!(
        arm.status()
            .unwrap()
            .flags
            .has(StatusFlags::DRIVERS_ENABLED),
        enabled
    );
    arm.toggle_enable(None).unwrap();
    let status = pins_and_servo_pwm(&arm);
    // A counted burst (gripper stepper mode): 50 pulses at 1 kHz end by themselves.
    let burst = armctl::pwm::settings(status.pwm_timer_clock_hz, 1000.0, 0.5, 50).unwrap();
    arm.pwm_start(burst).unwrap();
    assert!(arm.status().unwrap().flags.has(StatusFlags::PWM_ACTIVE));
    // It ends by itself: STATUS shows so within a bounded wait (polled, not guessed).
    let deadline = Instant::now() + Duration::from_secs(5);
    while arm.status().unwrap().flags.has(StatusFlags::PWM_ACTIVE) {
        assert!(Instant::now() < deadline, "burst did not end");
    }
    // Issue 30: a STOPPED from another host cuts a burst (8000 pulses at 1 kHz: 8 s) before
    // it is ACKed; STATUS bit 6 is clear at once.
    let long = armctl::pwm::settings(status.pwm_timer_clock_hz, 1000.0, 0.5, 8000).unwrap();
    arm.pwm_start(long).unwrap();
    assert!(arm.status().unwrap().flags.has(StatusFlags::PWM_ACTIVE));
    let panel = Raw::new("127.0.0.1:0", board.addr);
    let ack = panel.command(0x42, &Command::Stopped);
    assert_eq!(ack.map(|a| a.status), Some(StatusCode::Ok));
    assert!(
        !arm.status().unwrap().flags.has(StatusFlags::PWM_ACTIVE),
        "the burst is cut by the STOPPED"
    );

    // UART_INIT, USART_SEND, USART_RECV through the CMSDK UART and QEMU's chardev, with
    // the test as a loopback device on the line.
    let device = echo(board.serial_device(), Duration::from_secs(10));
    let (message, echoed) = serial_round_trip(&arm, Duration::from_secs(5));
    assert_eq!(echoed, message, "{}", board.log());
    arm.serial_close().unwrap();
    drop(device);

    // Frames only a raw socket can make.
    let here = position(&board, &arm);
    let raw = Raw::new("127.0.0.1:0", board.addr);
    raw_frames_are_refused(&raw);
    out_of_order_names_the_missing_frame(&raw, here);
    arm.stop().unwrap();
    board.assert_healthy();
}

#[test]
fn upload_streams_past_the_buffer_and_ends_exactly() {
    require_qemu!();
    let mut board = QemuBoard::start();
    let arm = board.connect_with(emulated());
    arm.set_joints(2).unwrap();
    arm.set_location(&[0, 0]).unwrap();
    let capacity = usize::from(arm.status().unwrap().capacity);

    // BUFFER_FULL: fill the buffer before RUNING, then one frame more.
    let filler = sweep([0; 8], 2, capacity + 12, 1, 10_000);
    arm.send(&Command::New {
        count: u16::try_from(filler.len()).unwrap(),
    })
    .unwrap();
    for chunk in filler[..capacity].chunks(12) {
        arm.send(&Command::Pending(PointList::Points(chunk)))
            .unwrap_or_else(|e| panic!("filling the buffer: {e}\n{}", board.log()));
    }
    assert_eq!(usize::from(arm.status().unwrap().buffered), capacity);
    refused(
        &board,
        arm.send(&Command::Pending(PointList::Points(&filler[capacity..]))),
        StatusCode::BufferFull,
        "12 points into a full buffer",
    );
    arm.stop().unwrap();

    // A run of 1.3 buffers of 1 ms points, streamed while it executes.
    let points = sweep([0; 8], 2, capacity * 13 / 10, 1, 1_000);
    let report = arm
        .run_trajectory(&points, &RunOptions::default(), |_| {})
        .unwrap_or_else(|e| panic!("{e}\n{}", board.log()));
    let status = report.final_status.unwrap();
    assert_eq!(usize::from(status.executed), points.len());
    assert!(!status.flags.has(StatusFlags::UNDERRUN), "{status:?}");
    let end = position(&board, &arm);
    assert_eq!(end[..2], points.last().unwrap().position[..2]);
    let asked = steps_asked([0; MAX_JOINTS], &points);
    assert_lines_saw(&board, end, |rising| *rising == asked);
    board.assert_healthy();
}

/// HOLD and RESUME on the QEMU board (issue 32: its backend takes arm-step's warp as the
/// NUCLEO's does): HOLD 20 points into the QEMU sweep, the MOTION report at rest, the
/// joints stay put while held, RESUME, the run ends with every point executed and every
/// joint exactly on its last point, the board's own lines having made exactly the pulses
/// asked. (Exact edge times are the Renode tests', against the warped oracle.)
#[test]
fn hold_and_resume_end_every_joint_on_its_last_point() {
    require_qemu!();
    let mut board = QemuBoard::start();
    let arm = Arc::new(board.connect_with(emulated()));
    arm.set_location(&[0; 6]).unwrap();
    let start = position(&board, &arm);
    let points = sweep(start, 6, 120, 4, 10_000);
    let options = RunOptions {
        completion_timeout: Some(Duration::from_secs(120)),
        ..RunOptions::default()
    };
    let run = common::run_reporting_progress_with(&arm, points.clone(), options);
    run.wait_executed(20);
    let ack = arm
        .hold()
        .unwrap_or_else(|e| panic!("HOLD: {e}\n{}", board.log()));
    assert_eq!(ack.state, State::Running);
    let deadline = Instant::now() + Duration::from_secs(30);
    let held = loop {
        let (status, motion) = arm.motion().unwrap();
        let motion = motion.expect("a MOTION report");
        if motion.flags.has(protocol::MotionFlags::AT_REST) {
            break status;
        }
        assert!(Instant::now() < deadline, "not at rest: {motion:?}");
        std::thread::sleep(Duration::from_millis(20));
    };
    assert_eq!(held.state, State::Running);
    let at_rest = assert_stays_put(&arm, 10);
    assert!(
        usize::from(held.executed) < points.len(),
        "held before the end: {held:?}"
    );
    let ack = arm
        .resume()
        .unwrap_or_else(|e| panic!("RESUME: {e}\n{}", board.log()));
    assert_eq!(ack.state, State::Running);
    let report = run
        .join()
        .unwrap_or_else(|e| panic!("{e}\n{}", board.log()));
    let status = report.final_status.unwrap();
    assert_eq!(status.state, State::Stopped);
    assert_eq!(usize::from(status.executed), points.len());
    assert!(!status.flags.has(StatusFlags::UNDERRUN), "{status:?}");
    let end = position(&board, &arm);
    let expected = points.last().unwrap().position;
    assert_eq!(end[..6], expected[..6]);
    let asked = steps_asked(start, &points);
    assert_lines_saw(&board, moved(start, end), |rising| *rising == asked);
    let _ = writeln_note(&format!(
        "qemu: held at rest at {at_rest:?} ({} of {} points executed), resumed, ended on \
         {:?}",
        held.executed,
        points.len(),
        &end[..6]
    ));
    board.assert_healthy();
}

/// Prints a figure to the real stderr (seen without --nocapture).
fn writeln_note(text: &str) -> std::io::Result<()> {
    use std::io::Write;
    writeln!(std::io::stderr().lock(), "{text}")
}

#[test]
fn emergency_stop_mid_run_freezes_the_joints() {
    require_qemu!();
    let mut board = QemuBoard::start();
    let arm = Arc::new(board.connect_with(emulated()));
    let start = position(&board, &arm);
    let points = sweep(start, 6, 300, 3, 10_000);
    let asked = steps_asked(start, &points);
    let total = points.len();
    match stop_mid_run(&arm, points, 20) {
        Err(Error::RunEnded {
            reason: RunEnd::Stopped,
            executed: Some(n),
            ..
        }) => assert!(usize::from(n) < total - 50, "executed {n}"),
        other => panic!("expected RunEnded(Stopped), got {other:?}\n{}", board.log()),
    }
    let status = arm.status().unwrap();
    assert_eq!(status.state, State::Stopped);
    assert!(status.flags.has(StatusFlags::STOPPED_BY_HOST));
    // 30 report periods of the board's own clock without a change.
    let first = assert_stays_put(&arm, 30);
    assert_ne!(first, start, "nothing moved before the stop");
    // Every joint had moved and none had finished; the pulses cut by the stop are
    // neither counted nor played.
    assert_lines_saw(&board, moved(start, first), |rising| {
        (0..6).all(|j| rising[j] >= first[j].abs_diff(start[j]) && rising[j] < asked[j])
    });
    board.assert_healthy();
}

/// Malformed datagrams of every kind, from a second socket, `count` of them.
fn flood(to: SocketAddr, count: usize, stop: &AtomicBool) -> usize {
    let socket = UdpSocket::bind("127.0.0.1:0").unwrap();
    let mut sent = 0;
    let mut state = 0x2545_f491_u32;
    let started = Instant::now();
    while sent < count
        && !stop.load(Ordering::Relaxed)
        && started.elapsed() < Duration::from_secs(20)
    {
        state ^= state << 13;
        state ^= state >> 17;
        state ^= state << 5;
        let len = (state % 1500) as usize;
        let mut bytes: Vec<u8> = (0..len).map(|i| (state >> (i % 24)) as u8).collect();
        match sent % 5 {
            // A valid-looking PENDING with a wrong CRC.
            0 if len > 3 => bytes[1] = Tag::Pending as u8,
            // A STOPPED with a wrong CRC (must not stop anything).
            1 if len > 3 => {
                bytes.truncate(3);
                bytes[1] = Tag::Stopped as u8;
                bytes[2] = !protocol::crc8(&bytes[..2]);
            }
            // Too short for a frame.
            2 => bytes.truncate(1),
            // A correct CRC over a PENDING of garbage length.
            3 if len > 3 => {
                bytes[1] = Tag::Pending as u8;
                let crc = protocol::crc8(&bytes[..len - 1]);
                bytes[len - 1] = crc;
            }
            _ => {}
        }
        let _ = socket.send_to(&bytes, to);
        sent += 1;
        if sent % 50 == 0 {
            std::thread::sleep(Duration::from_millis(2));
        }
    }
    sent
}

#[test]
fn malformed_flood_during_a_run_changes_no_step() {
    require_qemu!();
    let mut board = QemuBoard::start();
    let arm = board.connect_with(emulated());
    arm.set_location(&[0; 6]).unwrap();
    let points = sweep([0; 8], 6, 200, 3, 10_000);
    let stop = Arc::new(AtomicBool::new(false));
    let flooder = {
        let stop = stop.clone();
        let to = board.addr;
        std::thread::spawn(move || flood(to, 5_000, &stop))
    };
    let report = arm.run_trajectory(&points, &RunOptions::default(), |_| {});
    stop.store(true, Ordering::Relaxed);
    let sent = flooder.join().unwrap();
    let report = report.unwrap_or_else(|e| panic!("{e}\n{}", board.log()));
    let status = report.final_status.unwrap();
    assert!(sent > 500, "only {sent} malformed datagrams sent");
    assert_eq!(usize::from(status.executed), points.len());
    assert!(
        !status.flags.has(StatusFlags::STOPPED_BY_HOST),
        "{status:?}"
    );
    let end = position(&board, &arm);
    assert_eq!(end[..6], points.last().unwrap().position[..6]);
    let asked = steps_asked([0; MAX_JOINTS], &points);
    assert_lines_saw(&board, end, |rising| *rising == asked);
    board.assert_healthy();
}

/// A UDP relay between one client and the board that drops, duplicates and reorders
/// datagrams in both directions (seeded, so runs repeat).
///
/// Each direction has its own thread blocked in `recv`, so every datagram is passed on as
/// soon as it arrives. (A single thread polling the two sockets in turn with 5 ms read
/// timeouts passed on at most one datagram per direction per turn, about 80 a second on a
/// loaded host: fewer than the board sends, 100 LOCATION reports a second to its one
/// endpoint besides an ACK per frame. The backlog in the relay grew without end, ACKs
/// came later and later, armctl resent more, and after a run a command's ACK queued
/// behind seconds of old datagrams: `NoReply` with no datagram lost.)
struct LossyRelay {
    addr: SocketAddr,
    stop: Arc<AtomicBool>,
    threads: Vec<std::thread::JoinHandle<()>>,
}

/// How a [`LossyRelay`] spoils one direction, in percent of datagrams.
#[derive(Clone, Copy)]
struct Spoil {
    loss: u32,
    dup: u32,
    reorder: u32,
}

/// A read timeout, so that a relay thread with nothing to do sees `stop` soon.
const RELAY_POLL: Duration = Duration::from_millis(20);

/// Bounded: a test run never takes ten minutes.
const RELAY_LIFETIME: Duration = Duration::from_secs(600);

impl LossyRelay {
    fn start(board: SocketAddr, loss: u32, dup: u32, reorder: u32, seed: u32) -> LossyRelay {
        let spoil = Spoil { loss, dup, reorder };
        let front = UdpSocket::bind("127.0.0.1:0").unwrap();
        let back = UdpSocket::bind("127.0.0.1:0").unwrap();
        back.connect(board).unwrap();
        front.set_read_timeout(Some(RELAY_POLL)).unwrap();
        back.set_read_timeout(Some(RELAY_POLL)).unwrap();
        let addr = front.local_addr().unwrap();
        let stop = Arc::new(AtomicBool::new(false));
        // The client's address, learnt from its datagrams: the board's go back to it.
        let client: Arc<Mutex<Option<SocketAddr>>> = Arc::default();
        let up = {
            let (front, back) = (front.try_clone().unwrap(), back.try_clone().unwrap());
            let (stop, client) = (stop.clone(), client.clone());
            std::thread::spawn(move || {
                relay_one_way(
                    |buf| {
                        let (n, from) = front.recv_from(buf).ok()?;
                        *client.lock().unwrap() = Some(from);
                        Some(n)
                    },
                    |frame| {
                        let _ = back.send(frame);
                    },
                    spoil,
                    seed,
                    &stop,
                )
            })
        };
        let down = {
            let stop = stop.clone();
            std::thread::spawn(move || {
                relay_one_way(
                    |buf| back.recv(buf).ok(),
                    |frame| {
                        if let Some(client) = *client.lock().unwrap() {
                            let _ = front.send_to(frame, client);
                        }
                    },
                    spoil,
                    // Its own sequence: the directions run concurrently.
                    seed.rotate_left(16) ^ 0x5a5a_5a5a,
                    &stop,
                )
            })
        };
        LossyRelay {
            addr,
            stop,
            threads: vec![up, down],
        }
    }
}

/// One direction of a [`LossyRelay`]: each datagram `recv` yields is dropped, or held back
/// to go after the next one (reordered), or passed to `send`, sometimes twice.
fn relay_one_way(
    mut recv: impl FnMut(&mut [u8]) -> Option<usize>,
    send: impl Fn(&[u8]),
    spoil: Spoil,
    seed: u32,
    stop: &AtomicBool,
) {
    let mut state = seed | 1;
    let mut roll = move || {
        state ^= state << 13;
        state ^= state >> 17;
        state ^= state << 5;
        state % 100
    };
    let mut held: Option<Vec<u8>> = None;
    let mut buf = [0u8; 2048];
    let started = Instant::now();
    while !stop.load(Ordering::Relaxed) && started.elapsed() < RELAY_LIFETIME {
        let Some(n) = recv(&mut buf) else {
            continue;
        };
        let frame = &buf[..n];
        if roll() < spoil.loss {
            continue;
        }
        if roll() < spoil.reorder && held.is_none() {
            held = Some(frame.to_vec());
            continue;
        }
        send(frame);
        if roll() < spoil.dup {
            send(frame);
        }
        if let Some(late) = held.take() {
            send(&late);
        }
    }
}

impl Drop for LossyRelay {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        for thread in self.threads.drain(..) {
            let _ = thread.join();
        }
    }
}

/// Regression: the relay keeps up with a board that sends more than it is sent (reports
/// on a timer besides an ACK per frame, as the controller's 100 LOCATION reports a
/// second), so its delay does not grow with time. The polling relay passed on one
/// datagram per 5 ms turn at best: its backlog grew by hundreds a second here, and the
/// replies fell seconds behind. Needs no QEMU: the board is a socket that echoes each
/// datagram and sends a report every 2 ms.
#[test]
fn the_relay_passes_on_everything_the_board_sends_as_it_comes() {
    const REPORT_EVERY: Duration = Duration::from_millis(2);
    const TALK_FOR: Duration = Duration::from_secs(3);
    let board = UdpSocket::bind("127.0.0.1:0").unwrap();
    board
        .set_read_timeout(Some(Duration::from_millis(1)))
        .unwrap();
    let board_addr = board.local_addr().unwrap();
    let stop = Arc::new(AtomicBool::new(false));
    let fake_board = {
        let stop = stop.clone();
        std::thread::spawn(move || {
            let mut buf = [0u8; 64];
            let mut client = None;
            let mut next_report = Instant::now();
            while !stop.load(Ordering::Relaxed) {
                if let Ok((n, from)) = board.recv_from(&mut buf) {
                    let _ = board.send_to(&buf[..n], from);
                    client = Some(from);
                }
                while let Some(client) = client
                    && next_report <= Instant::now()
                {
                    let _ = board.send_to(b"report", client);
                    next_report += REPORT_EVERY;
                }
            }
        })
    };
    let relay = LossyRelay::start(board_addr, 0, 0, 0, 7);
    let client = UdpSocket::bind("127.0.0.1:0").unwrap();
    client.connect(relay.addr).unwrap();
    client
        .set_read_timeout(Some(Duration::from_millis(50)))
        .unwrap();
    let started = Instant::now();
    let (mut round, mut slowest, mut unanswered) = (0u32, Duration::ZERO, 0u32);
    // Round trips of the rounds started in the second half: a relay that falls behind has
    // its backlog (and their delay) grow with time.
    let (mut trips, mut late_trips) = (Vec::new(), Vec::new());
    while started.elapsed() < TALK_FOR {
        let sent = Instant::now();
        let second_half = started.elapsed() >= TALK_FOR / 2;
        client.send(&round.to_be_bytes()).unwrap();
        let mut buf = [0u8; 64];
        // Generous: a relay that keeps up answers within milliseconds.
        let answered = loop {
            if sent.elapsed() >= Duration::from_secs(3) {
                break false;
            }
            if let Ok(n) = client.recv(&mut buf)
                && buf[..n] == round.to_be_bytes()
            {
                break true;
            }
        };
        let trip = sent.elapsed();
        unanswered += u32::from(!answered);
        slowest = slowest.max(trip);
        trips.push(trip);
        if second_half {
            late_trips.push(trip);
        }
        round += 1;
    }
    trips.sort();
    late_trips.sort();
    let median_late = late_trips.get(late_trips.len() / 2).copied();
    println!(
        "relay round trips ({round}): p50 {:?} p90 {:?} max {slowest:?}; second half p50 {median_late:?}",
        trips[trips.len() / 2],
        trips[trips.len() * 9 / 10]
    );
    drop(relay);
    stop.store(true, Ordering::Relaxed);
    fake_board.join().unwrap();
    // Not the slowest round trip (it was asserted < 1 s): on a busy machine one took 222 ms
    // here while QEMU tests ran beside it, against p50 35 us. A relay that falls behind
    // delays most rounds, and the more the later: the median of the second half's rounds
    // (35 us here) must stay under 100 ms, and every round be answered within 3 s.
    assert_eq!(
        unanswered, 0,
        "{unanswered} of {round} rounds unanswered in 3 s"
    );
    assert!(
        median_late.is_some_and(|m| m < Duration::from_millis(100)),
        "the second half's round trips through the relay: median {median_late:?} ({round} round trips): it falls behind"
    );
}

#[test]
fn lossy_link_executes_the_same_steps_as_a_lossless_one() {
    require_qemu!();
    // The same trajectory through a clean link and through 20% loss, 5% duplication and
    // 5% reordering each way.
    let run = |lossy: bool| {
        let mut board = QemuBoard::start();
        let relay = lossy.then(|| LossyRelay::start(board.addr, 20, 5, 5, 7));
        let addr = relay.as_ref().map_or(board.addr, |r| r.addr);
        let arm = Client::connect_with(
            addr,
            Options {
                ack_timeout: Duration::from_millis(60),
                attempts: 60,
                ..Options::default()
            },
        )
        .unwrap_or_else(|e| panic!("connect: {e}\n{}", board.log()));
        arm.set_location(&[0; 6]).unwrap();
        let points = sweep([0; 8], 6, 250, 3, 8_000);
        let report = arm
            .run_trajectory(&points, &RunOptions::default(), |_| {})
            .unwrap_or_else(|e| panic!("lossy {lossy}: {e}\n{}", board.log()));
        let position = arm
            .current_location(Duration::from_secs(3))
            .expect("LOCATION after the run")
            .position;
        let asked = steps_asked([0; MAX_JOINTS], &points);
        assert_lines_saw(&board, position, |rising| *rising == asked);
        board.assert_healthy();
        (report, position, points)
    };
    let (clean, clean_position, points) = run(false);
    let (lossy, lossy_position, _) = run(true);
    assert_eq!(clean_position[..6], points.last().unwrap().position[..6]);
    assert_eq!(lossy_position, clean_position);
    let (clean_status, lossy_status) = (clean.final_status.unwrap(), lossy.final_status.unwrap());
    assert_eq!(usize::from(lossy_status.executed), points.len());
    assert_eq!(lossy_status.executed, clean_status.executed);
    assert!(lossy.retransmissions > 0, "no loss seen: {lossy:?}");
}

#[test]
fn the_boards_mem_and_division_routines_match_their_models() {
    require_qemu!();
    // The memcpy/memmove/memset/memcmp and u64 division both boards link (compiler-builtins')
    // against byte-by-byte and bit-by-bit models, on the emulated Cortex-M7 (arm-wiring's
    // runtime_check).
    let (exited, log) = run_to_exit("check-runtime", Duration::from_secs(60));
    assert_eq!(exited, Some(true), "the check failed or did not end\n{log}");
    assert!(log.contains(" 0 failures"), "{log}");
}

#[test]
fn a_fault_ends_qemu_with_a_failure_and_its_log() {
    require_qemu!();
    // The firmware commits the fault QEMU's command line asks for, 300 ms after boot.
    for (kind, expected) in [
        ("panic", "PANIC: panicked at"),
        ("hardfault", "HARDFAULT: pc="),
        (
            "stack-overflow",
            "HARDFAULT: stack overflow (guard region hit)",
        ),
    ] {
        let (exited, log) = run_to_exit(&format!("inject-fault={kind}"), Duration::from_secs(20));
        assert_eq!(
            exited,
            Some(false),
            "{kind}: QEMU should exit with a failure\n{log}"
        );
        assert!(log.contains(expected), "{kind}: no '{expected}' in\n{log}");
        assert!(
            log.contains("FATAL: steps stopped"),
            "{kind}: no safe stop in\n{log}"
        );
        assert!(FAULT_MARKERS.iter().any(|m| log.contains(m)));
    }
    // And without one it keeps running: it comes up (its "listening on" line) and is still
    // running, with no fault in its log, once its own clock is well past the time an
    // injected fault would have come (300 ms after its tasks start, ~0.34 s of its clock).
    // Observed, not timed: this once waited a fixed 2 s of wall time for the line, which a
    // loaded host's stalled QEMU could miss. Its clock is read off its log's timestamps; a
    // STOPPED at rest makes it log a line (the step-output monitor's "STOPPED frame to the
    // last STEP edge", within 100 ms of its clock).
    let mut board = QemuBoard::start();
    let deadline = Instant::now() + Duration::from_secs(30);
    while !board
        .firmware_log()
        .contains("listening on 10.0.2.15/24:8510")
    {
        board.assert_healthy();
        assert!(
            Instant::now() < deadline,
            "no 'listening on 10.0.2.15/24:8510' in 30 s\n{}",
            board.log()
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    let arm = board.connect_with(emulated());
    const PAST_ANY_INJECTION_S: f64 = 1.0;
    while board_clock_s(&board.firmware_log()).is_none_or(|s| s < PAST_ANY_INJECTION_S) {
        board.assert_healthy();
        assert!(
            Instant::now() < deadline,
            "the board's clock did not pass {PAST_ANY_INJECTION_S} s in 30 s\n{}",
            board.log()
        );
        let _ = arm.stop();
        std::thread::sleep(Duration::from_millis(50));
    }
    println!(
        "qemu: no fault injected: still running at {:?} s of the board's clock",
        board_clock_s(&board.firmware_log())
    );
    board.assert_healthy();
}

/// The board's clock (seconds since boot) as its log's last whole line stamps it
/// (`[   0.034389] INFO  ...`); `None` before any.
fn board_clock_s(log: &str) -> Option<f64> {
    log.split_inclusive('\n')
        .filter(|line| line.ends_with('\n'))
        .filter_map(|line| {
            line.strip_prefix('[')?
                .split_once(']')?
                .0
                .trim()
                .parse()
                .ok()
        })
        .next_back()
}

#[test]
fn the_board_clock_is_read_off_the_last_whole_log_line() {
    let log = "[   0.027130] INFO  link_up = true\r\n[   1.034389] INFO  listening on x\r\n[   2.5";
    assert_eq!(board_clock_s(log), Some(1.034389));
    assert_eq!(board_clock_s("[   0.5"), None);
    assert_eq!(board_clock_s(""), None);
}

#[test]
fn link_down_and_up_reach_the_stack_through_the_phy_interrupt() {
    require_qemu!();
    let mut board = QemuBoard::start();
    let arm = board.connect_with(emulated());
    arm.status().unwrap();
    board.monitor("set_link lan9118.0 off");
    let quick = Options {
        ack_timeout: Duration::from_millis(100),
        attempts: 3,
        ..Options::default()
    };
    let wait_for = |line: &str| {
        let deadline = Instant::now() + Duration::from_secs(5);
        while !board.log().contains(line) && Instant::now() < deadline {
            std::thread::sleep(Duration::from_millis(20));
        }
        assert!(
            board.log().contains(line),
            "no '{line}' in\n{}",
            board.log()
        );
    };
    wait_for("WARN  ethernet link down");
    assert!(
        Client::connect_with(board.addr, quick.clone()).is_err(),
        "answered with the link down"
    );
    board.monitor("set_link lan9118.0 on");
    wait_for("INFO  ethernet link up");
    let status = arm
        .status()
        .unwrap_or_else(|e| panic!("no STATUS after the link came back: {e}\n{}", board.log()));
    assert_eq!(status.state, State::Stopped);
    board.assert_healthy();
}

/// Authentication on the board (issue 21, docs/PROTOCOL.md section 13): the first key set
/// plain, then frames without it refused and nothing moved (QEMU's user network shows every
/// host as 10.0.2.2: these forged frames even come from the owner's address), an envelope
/// under another key or replayed refused, the key holder's run executed, a plain STOPPED
/// still stops it, and the key cleared with the key.
#[test]
fn a_keyed_board_moves_for_the_key_holder_only() {
    use protocol::auth::{AuthKey, Direction, Envelope, HelloReply, KEY_LEN, seal};
    require_qemu!();
    const KEY: AuthKey = AuthKey([0x3c; KEY_LEN]);
    let mut board = QemuBoard::start();
    let plain = board.connect_with(emulated());
    let start = position(&board, &plain);
    plain.set_key(Some(KEY)).expect("the first key, plain");
    // Opened without the STATUS that connecting sends: it would be refused.
    let stranger = Client::open(board.addr, emulated()).unwrap();
    let points = sweep(start, 6, 40, 2, 10_000);
    match stranger.run_trajectory(&points, &RunOptions::default(), |_| {}) {
        Err(Error::Refused {
            status: StatusCode::AuthRequired,
            ..
        }) => {}
        other => panic!("a run without the key: {other:?}\n{}", board.log()),
    }
    for result in [
        stranger.pin(0, true),
        stranger.toggle_enable(None),
        stranger.go_home(),
    ] {
        assert!(
            matches!(
                &result,
                Err(Error::Refused {
                    status: StatusCode::AuthRequired,
                    ..
                })
            ),
            "{result:?}"
        );
    }
    // By hand: a session, an envelope under another key, and a replay.
    let raw = UdpSocket::bind("127.0.0.1:0").unwrap();
    raw.connect(board.addr).unwrap();
    raw.set_read_timeout(Some(Duration::from_millis(500)))
        .unwrap();
    let mut buf = [0u8; protocol::MAX_DATAGRAM];
    // The answer to `bytes`: the first datagram that is not a report. Once this socket
    // has a session it also gets the board's sealed LOCATION reports, which may come
    // first on a loaded machine (issue 19 soak: "not an ACK: Location").
    let is_report = |reply: &[u8]| {
        let inner = Envelope::open(reply).map_or(reply.to_vec(), |e| e.inner.to_vec());
        matches!(
            protocol::Report::decode(&inner).map(|f| f.body),
            Ok(protocol::Report::Location(_) | protocol::Report::Status(_))
        )
    };
    let answer = |bytes: &[u8], buf: &mut [u8]| -> Vec<u8> {
        for _ in 0..10 {
            raw.send(bytes).unwrap();
            // Bounded: a few reports at most before the answer, or resend.
            for _ in 0..20 {
                match raw.recv(buf) {
                    Ok(n) if is_report(&buf[..n]) => continue,
                    Ok(n) => return buf[..n].to_vec(),
                    Err(_) => break,
                }
            }
        }
        panic!("no answer\n{}", board.log());
    };
    let mut hello_frame = [0u8; 32];
    let n = Command::Hello { nonce: [7; 16] }
        .encode(200, &mut hello_frame)
        .unwrap();
    let reply = answer(&hello_frame[..n], &mut buf);
    let env = Envelope::open(&reply).expect("a HELLO_REPLY envelope");
    let hello = HelloReply::decode(env.inner).expect("HELLO_REPLY").body;
    assert!(env.verify(&KEY, Direction::ToHost, hello.epoch));
    let ack_status = |reply: &[u8]| {
        let inner = Envelope::open(reply).map_or(reply.to_vec(), |e| e.inner.to_vec());
        match protocol::Report::decode(&inner).map(|f| f.body) {
            Ok(protocol::Report::Ack(ack)) => ack.status,
            other => panic!("not an ACK: {other:?}"),
        }
    };
    let mut pin = [0u8; 8];
    let n = Command::Pin1On.encode(201, &mut pin).unwrap();
    let mut forged = [0u8; protocol::MAX_DATAGRAM];
    let m = seal(
        &AuthKey([0xc3; KEY_LEN]),
        Direction::ToController,
        hello.epoch,
        hello.session,
        1,
        &pin[..n],
        &mut forged,
    )
    .unwrap();
    assert_eq!(
        ack_status(&answer(&forged[..m], &mut buf)),
        StatusCode::AuthFailed
    );
    let mut sealed = [0u8; protocol::MAX_DATAGRAM];
    let m = seal(
        &KEY,
        Direction::ToController,
        hello.epoch,
        hello.session,
        1,
        &pin[..n],
        &mut sealed,
    )
    .unwrap();
    assert_eq!(ack_status(&answer(&sealed[..m], &mut buf)), StatusCode::Ok);
    assert_eq!(
        ack_status(&answer(&sealed[..m], &mut buf)),
        StatusCode::AuthFailed,
        "a replay"
    );

    let arm = Arc::new(board.connect_with(Options {
        key: Some(KEY),
        ..emulated()
    }));
    assert_eq!(
        position(&board, &arm),
        start,
        "nothing moved without the key"
    );
    let status = arm.status().unwrap();
    assert!(status.flags.has(StatusFlags::PIN1_HIGH) && !status.flags.has(StatusFlags::PIN0_HIGH));
    let report = arm
        .run_trajectory(&points, &RunOptions::default(), |_| {})
        .unwrap_or_else(|e| panic!("the key holder's run: {e}\n{}", board.log()));
    assert_eq!(
        usize::from(report.final_status.unwrap().executed),
        points.len()
    );
    let end = position(&board, &arm);
    assert_eq!(end[..6], points.last().unwrap().position[..6]);
    // A plain STOPPED, from a host without the key, stops the key holder's run.
    let long = sweep(end, 6, 300, 3, 10_000);
    let runner = {
        let arm = arm.clone();
        std::thread::spawn(move || arm.run_trajectory(&long, &RunOptions::default(), |_| {}))
    };
    let deadline = Instant::now() + Duration::from_secs(10);
    while arm.last_location().is_none_or(|l| l.position == end) {
        assert!(
            Instant::now() < deadline,
            "the run never started\n{}",
            board.log()
        );
        std::thread::sleep(Duration::from_millis(10));
    }
    assert_eq!(stranger.stop().unwrap().status, StatusCode::Ok);
    assert!(
        matches!(
            runner.join().unwrap(),
            Err(Error::RunEnded {
                reason: RunEnd::Stopped,
                ..
            })
        ),
        "the run ended by the stranger's STOPPED"
    );
    let first = position(&board, &arm);
    std::thread::sleep(Duration::from_millis(300));
    assert_eq!(position(&board, &arm), first, "a joint moved after STOPPED");
    // Cleared with the key: plain hosts work again.
    arm.set_key(None).expect("cleared with the key");
    stranger.pin(0, true).expect("plain again");
    board.assert_healthy();
}

/// Issue 30 part 4: the LAN9118's interrupt looks at each frame as it moves it into the
/// receive ring and halts the steps for a STOPPED there; RX_COUNTERS (STATUS's request
/// byte bit 2) tells how many it halted for and what the ring dropped. Every STOPPED the
/// board ACKs was seen by the interrupt first (the ACK comes from the runner's path,
/// after it), so the count is at least the STOPPEDs ACKed.
#[test]
fn the_receive_interrupt_halts_for_stopped_and_rx_counters_tell_it() {
    require_qemu!();
    let mut board = QemuBoard::start();
    let raw = Raw::new("127.0.0.1:0", board.addr);
    let stops = 5;
    let c = rx_counters_after_stops(&raw, stops)
        .unwrap_or_else(|| panic!("STOPPEDs ACKed and RX_COUNTERS answered\n{}", board.log()));
    println!("qemu: RX_COUNTERS after {stops} STOPPEDs: {c:?}");
    assert!(
        c.interrupt_stops >= u32::from(stops),
        "the interrupt halted for every STOPPED ACKed: {c:?}"
    );
    board.assert_healthy();
}

/// Issue 34: the QEMU board measures none of the board's timing (QEMU's Cortex-M7 has no
/// DWT cycle counter and the board plays its STEP lines in software): its DIAG report says
/// "not measured" (clocks of 0), honestly, beside its receive path's own counters.
#[test]
fn the_qemu_board_says_its_timing_is_not_measured() {
    require_qemu!();
    let mut board = QemuBoard::start();
    let arm = Client::open(board.addr, emulated())
        .unwrap_or_else(|e| panic!("open: {e}\n{}", board.log()));
    let d = arm
        .diag()
        .unwrap_or_else(|e| panic!("DIAG: {e}\n{}", board.log()))
        .unwrap_or_else(|| panic!("the board refused DIAG\n{}", board.log()));
    println!("qemu: DIAG {:?}, RX_COUNTERS {:?}", d.diag, d.rx);
    assert_eq!(d.diag, protocol::Diag::NOT_MEASURED);
    board.assert_healthy();
}

/// Issue 30 part 4's figure on the QEMU board: a STATUS flood (bounded, ~5,000/s) while the
/// owner runs, and one single STOPPED (never resent) per run from another socket, 20 runs.
/// Every one that reaches the board halts the arm (STATUS STOPPED; RX_COUNTERS tells how
/// many its receive interrupt saw), and the board logs, per STOPPED, the time from
/// its receive interrupt taking the frame from the chip to the last STEP rise after it
/// (its own clock: QEMU runs without icount, so that is host time; the frame's landing in
/// QEMU's model is not visible to the guest: the interrupt is the first look). Printed
/// p50/p90/max; asserted only under 1 s (host time: see the assertion).
#[test]
fn every_single_stopped_halts_the_arm_under_a_flood_and_its_last_step_edge_is_logged() {
    require_qemu!();
    let mut board = QemuBoard::start();
    let arm = Arc::new(board.connect_with(Options {
        give_up_after: Duration::from_secs(10),
        ..emulated()
    }));
    arm.set_location(&[0; 6]).unwrap();
    let panel = Raw::new("127.0.0.1:0", board.addr);
    let before = rx_counters_after_stops(&panel, 0).expect("RX_COUNTERS");
    let done = AtomicBool::new(false);
    let flooder = UdpSocket::bind("127.0.0.1:0").unwrap();
    let mut status = [0u8; 8];
    let status_len = Command::Status.encode(1, &mut status).unwrap();
    let options = RunOptions {
        start_after: Some(48),
        stall_timeout: Duration::from_secs(30),
        completion_timeout: Some(Duration::from_secs(120)),
        ..RunOptions::default()
    };
    // The monitor logs at rest, every 100 ms, for the last STOPPED its interrupt saw.
    let lines = |log: &str| -> Vec<f64> {
        log.lines()
            .filter_map(|l| l.split("STOPPED frame to the last STEP edge: ").nth(1))
            .filter_map(|rest| rest.split_whitespace().next()?.parse().ok())
            .collect()
    };
    let (flooded, halted, acked, missed) = std::thread::scope(|scope| {
        let flood = scope.spawn(|| {
            let started = Instant::now();
            let mut sent = 0u64;
            while !done.load(Ordering::Relaxed)
                && sent < 2_000_000
                && started.elapsed() < Duration::from_secs(300)
            {
                for _ in 0..10 {
                    let _ = flooder.send_to(&status[..status_len], board.addr);
                }
                sent += 10;
                std::thread::sleep(Duration::from_millis(2));
            }
            (sent, started.elapsed())
        });
        struct EndsTheFlood<'a>(&'a AtomicBool);
        impl Drop for EndsTheFlood<'_> {
            fn drop(&mut self) {
                self.0.store(true, Ordering::Relaxed);
            }
        }
        let ends = EndsTheFlood(&done);
        let (mut halted, mut acked) = (0, 0);
        let mut missed = Vec::new();
        for k in 0..20u8 {
            let here = position(&board, &arm);
            let points = sweep(here, 6, 600, 2, 10_000);
            let (progress, executed) = std::sync::mpsc::channel();
            let run = {
                let (arm, options) = (arm.clone(), options.clone());
                std::thread::spawn(move || {
                    arm.run_trajectory(&points, &options, |p| {
                        let _ = progress.send(p.executed);
                    })
                })
            };
            if !executed.iter().any(|n| n >= 5) {
                println!("qemu: try {k}: the run ended first: {:?}", run.join());
                continue;
            }
            let mut stop = [0u8; 8];
            let len = Command::Stopped.encode(100 + k, &mut stop).unwrap();
            panel.socket.send(&stop[..len]).unwrap();
            let mut buf = [0u8; protocol::MAX_DATAGRAM];
            let sent_at = Instant::now();
            let mut got_ack = false;
            while !got_ack && sent_at.elapsed() < Duration::from_secs(2) {
                if let Ok(n) = panel.socket.recv(&mut buf)
                    && let Ok(frame) = protocol::Report::decode(&buf[..n])
                    && let protocol::Report::Ack(ack) = frame.body
                {
                    got_ack = frame.seq == 100 + k && ack.acked_tag == Tag::Stopped as u8;
                }
            }
            acked += usize::from(got_ack);
            if arm.status().is_ok_and(|s| s.state == State::Stopped) {
                halted += 1;
            } else {
                missed.push(k);
                let _ = arm.stop();
            }
            let _ = run.join();
            // This STOPPED's line before the next run (bounded).
            let deadline = Instant::now() + Duration::from_secs(3);
            while lines(&board.log()).len() <= usize::from(k) && Instant::now() < deadline {
                std::thread::sleep(Duration::from_millis(20));
            }
        }
        drop(ends);
        (flood.join().unwrap(), halted, acked, missed)
    });
    let after = rx_counters_after_stops(&panel, 0).expect("RX_COUNTERS after");
    let us = lines(&board.log());
    let mut sorted = us.clone();
    sorted.sort_by(f64::total_cmp);
    let q = |p: f64| {
        sorted
            .get(((sorted.len() as f64 - 1.0) * p).round() as usize)
            .copied()
            .unwrap_or(f64::NAN)
    };
    println!(
        "qemu: e-stop under a flood: {} STATUS in {:.1} s; 20 single STOPPEDs: halted the arm \
         {halted}, ACKed {acked}; the interrupt's look -> last STEP edge ({} logged) p50 {:.0} \
         us, p90 {:.0}, max {:.0}; missed {missed:?}; the interrupt halted for {}, ring \
         dropped {}, ring full {}, shed {}",
        flooded.0,
        flooded.1.as_secs_f64(),
        us.len(),
        q(0.5),
        q(0.9),
        q(1.0),
        after.interrupt_stops - before.interrupt_stops,
        after.ring_dropped - before.ring_dropped,
        after.ring_full - before.ring_full,
        after.shed - before.shed,
    );
    // The interrupt saw the panel's STOPPEDs that reached the board and the owner's
    // clean-up STOPPED after each miss. A STOPPED lost before the board (QEMU's user
    // network or the host's socket buffer under the flood: 1 in 20 in 1 of 9 runs, the
    // chip's drop counter 0) is not the board's; every one that reached it halted the arm.
    let reached =
        ((after.interrupt_stops - before.interrupt_stops) as usize).saturating_sub(missed.len());
    println!(
        "qemu: STOPPEDs that reached the board {reached}, lost before it {}",
        20 - reached.min(20)
    );
    assert_eq!(
        halted,
        reached,
        "every single STOPPED that reached the board halted the arm\n{}",
        board.log()
    );
    assert!(
        halted >= 18,
        "at most 2 of 20 lost before the board\n{}",
        board.log()
    );
    // The figure is printed above (p50, p90 and max have been 0 us: the halt in the
    // interrupt stops the software player before its next edge). The bound only tells a
    // halt from none: the STOPPED lands early in a 6 s run, which a missed halt would play
    // on for seconds. It is measured by the board's own clock, and QEMU runs without
    // icount, so that clock is host time: a stall of the emulator's thread on a loaded
    // host between the interrupt's look and the player's halt counts in full. 100 ms was
    // asserted here; 1 s holds on a host ten times slower or busier.
    assert!(
        q(1.0) < 1_000_000.0,
        "the last STEP edge within 1 s of the STOPPED's frame (max {:.0} us)\n{}",
        q(1.0),
        board.log()
    );
    board.assert_healthy();
}
