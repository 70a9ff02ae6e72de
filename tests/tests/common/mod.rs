//! Helpers shared by the end-to-end tests.
#![allow(dead_code)]

use std::net::{SocketAddr, UdpSocket};
use std::time::{Duration, Instant};

use protocol::{
    Ack, Command, MAX_DATAGRAM, MAX_JOINTS, Point, PointList, Pwm, Report, StatusCode, Tag,
    UartInit,
};

/// `count` points of `duration_us` from `start`, each joint j moving `step * (j + 1)` per
/// point, alternating direction by joint.
pub fn sweep(
    start: [i32; MAX_JOINTS],
    joints: usize,
    count: usize,
    step: i32,
    duration_us: i32,
) -> Vec<Point> {
    let mut previous = start;
    (0..count)
        .map(|k| {
            let mut target = previous;
            for (j, position) in target.iter_mut().enumerate().take(joints) {
                // Out and back so that positions stay bounded.
                let direction = if (k * 2 / count.max(1)) == 0 { 1 } else { -1 };
                let sign = if j % 2 == 0 { 1 } else { -1 };
                *position += direction * sign * step * (j as i32 + 1);
            }
            let point = Point::from_motion(duration_us, &previous, &target);
            previous = target;
            point
        })
        .collect()
}

/// A bare UDP socket that sends hand-made datagrams and reads the ACK for a seq.
pub struct Raw {
    pub socket: UdpSocket,
}

impl Raw {
    pub fn new(bind: &str, controller: SocketAddr) -> Raw {
        let socket = UdpSocket::bind(bind).unwrap();
        socket.connect(controller).unwrap();
        socket
            .set_read_timeout(Some(Duration::from_millis(100)))
            .unwrap();
        Raw { socket }
    }

    /// Sends `datagram` (up to 5 times) until an ACK with `seq` comes back.
    pub fn exchange(&self, datagram: &[u8], seq: u8) -> Option<Ack> {
        let mut buf = [0u8; MAX_DATAGRAM];
        for _ in 0..5 {
            self.socket.send(datagram).unwrap();
            let deadline = std::time::Instant::now() + Duration::from_millis(200);
            while std::time::Instant::now() < deadline {
                let Ok(n) = self.socket.recv(&mut buf) else {
                    continue;
                };
                if let Ok(frame) = Report::decode(&buf[..n])
                    && let Report::Ack(ack) = frame.body
                    && frame.seq == seq
                {
                    return Some(ack);
                }
            }
        }
        None
    }

    /// Encodes and exchanges a command.
    pub fn command(&self, seq: u8, command: &protocol::Command<'_>) -> Option<Ack> {
        let mut buf = [0u8; MAX_DATAGRAM];
        let n = command.encode(seq, &mut buf).unwrap();
        self.exchange(&buf[..n], seq)
    }
}

/// Issue 30 part 4: `stops` single STOPPEDs from `raw`, each sent until ACKed, then a
/// look-only STATUS asking for RX_COUNTERS (request byte bit 3): the counters it gets.
/// `None` if a STOPPED or the report never comes. Bounded: 10 exchanges per STOPPED, 30
/// tries of 1 s for the report.
pub fn rx_counters_after_stops(raw: &Raw, stops: u8) -> Option<protocol::RxCounters> {
    for seq in 0..stops {
        (0..10).find_map(|_| raw.command(seq, &protocol::Command::Stopped))?;
    }
    let ask = protocol::Command::StatusWith(protocol::StatusAsk {
        location: false,
        look_only: true,
        stop_cause: false,
        counters: true,
        diag: false,
        motion: false,
        switches: false,
    });
    let mut request = [0u8; 8];
    let n = ask.encode(0x40, &mut request).unwrap();
    let mut buf = [0u8; MAX_DATAGRAM];
    for _ in 0..30 {
        raw.socket.send(&request[..n]).unwrap();
        let deadline = std::time::Instant::now() + Duration::from_secs(1);
        while std::time::Instant::now() < deadline {
            let Ok(got) = raw.socket.recv(&mut buf) else {
                continue;
            };
            if let Ok(frame) = Report::decode(&buf[..got])
                && let Report::RxCounters(counters) = frame.body
            {
                return Some(counters);
            }
        }
    }
    None
}

/// A datagram from parts with a correct CRC.
pub fn datagram(seq: u8, tag: u8, data: &[u8]) -> Vec<u8> {
    let mut bytes = vec![seq, tag];
    bytes.extend_from_slice(data);
    bytes.push(protocol::crc8(&bytes));
    bytes
}

/// What every controller (sim-host, the firmware on QEMU) answers to frames only a raw
/// socket makes: BAD_CRC naming the tag, UNKNOWN_TAG, BAD_LENGTH (seqs 40 to 42).
pub fn raw_frames_are_refused(raw: &Raw) {
    let mut bad_crc = datagram(40, Tag::Status as u8, &[]);
    *bad_crc.last_mut().unwrap() ^= 0xFF;
    let ack = raw.exchange(&bad_crc, 40).expect("an ACK for a bad CRC");
    assert_eq!(
        (ack.status, ack.acked_tag),
        (StatusCode::BadCrc, Tag::Status as u8)
    );
    // 0x4f: no tag (0x27-0x33 are issues 32-34's since, 0x50-0x53 the key's).
    let ack = raw.exchange(&datagram(41, 0x4f, &[]), 41).unwrap();
    assert_eq!(ack.status, StatusCode::UnknownTag);
    let ack = raw
        .exchange(&datagram(42, Tag::New as u8, &[0, 1, 2]), 42)
        .unwrap();
    assert_eq!(ack.status, StatusCode::BadLength);
}

/// OUT_OF_ORDER: NEW at 50, PENDING at 52 (51 never sent) is refused naming 51, which is
/// then taken; the arm is at `here`.
pub fn out_of_order_names_the_missing_frame(raw: &Raw, here: [i32; MAX_JOINTS]) {
    let ack = raw.command(50, &Command::New { count: 2 }).unwrap();
    assert_eq!(ack.status, StatusCode::Ok);
    let two = sweep(here, 1, 2, 1, 10_000);
    let ack = raw
        .command(52, &Command::Pending(PointList::Points(&two[..1])))
        .unwrap();
    assert_eq!(ack.status, StatusCode::OutOfOrder);
    assert_eq!(ack.next_seq, 51, "next_seq names the missing frame");
    let ack = raw
        .command(51, &Command::Pending(PointList::Points(&two[..1])))
        .unwrap();
    assert_eq!(ack.status, StatusCode::Ok);
}

/// Opens the serial pass-through at 115200 baud, sends 600 bytes and collects what comes
/// back within `timeout` (the line is a loopback); returns (sent, received).
pub fn serial_round_trip(arm: &armctl::Client, timeout: Duration) -> (Vec<u8>, Vec<u8>) {
    let rx = arm.serial_rx();
    arm.serial_open(protocol::UartInit {
        baud_rate: 115_200,
        ..protocol::UartInit::default()
    })
    .unwrap();
    let message: Vec<u8> = (0..600u32).map(|i| b'a' + (i % 26) as u8).collect();
    arm.serial_send(&message).unwrap();
    let mut echoed = Vec::new();
    let deadline = Instant::now() + timeout;
    while echoed.len() < message.len() && Instant::now() < deadline {
        if let Ok(bytes) = rx.recv_timeout(Duration::from_millis(100)) {
            echoed.extend(bytes);
        }
    }
    (message, echoed)
}

/// The refusals every controller gives in STOPPED (sim-host and the firmware under QEMU
/// alike): each command's result goes to `check` with the status it must carry and what
/// it is.
pub fn refusals_in_stopped(
    arm: &armctl::Client,
    mut check: impl FnMut(armctl::Result<Ack>, StatusCode, &str),
) {
    check(
        arm.send(&Command::Runing),
        StatusCode::BadState,
        "RUNING when stopped",
    );
    let one = [Point::from_motion(
        10_000,
        &[0; 8],
        &[1, 0, 0, 0, 0, 0, 0, 0],
    )];
    check(
        arm.send(&Command::Pending(PointList::Points(&one))),
        StatusCode::BadState,
        "PENDING without NEW",
    );
    check(
        arm.send(&Command::New { count: 0 }),
        StatusCode::InvalidConfig,
        "NEW 0",
    );
    check(
        arm.set_joints(9),
        StatusCode::InvalidConfig,
        "JOINTS_COUNT 9",
    );
    check(
        arm.upload_period(999),
        StatusCode::InvalidConfig,
        "UPLOAD_PERIOD 999",
    );
    check(
        arm.pwm_start(Pwm {
            psc: 0,
            arr: 100,
            ccr1: 101,
            pulse_count: 0,
        }),
        StatusCode::InvalidConfig,
        "PWM CCR1 > ARR",
    );
    check(
        arm.serial_open(UartInit {
            baud_rate: 299,
            ..UartInit::default()
        }),
        StatusCode::InvalidConfig,
        "baud 299",
    );
    check(
        arm.send(&Command::UsartSend(b"x")),
        StatusCode::BadState,
        "USART_SEND with the port closed",
    );
    check(
        arm.toggle_enable(Some(0x200)),
        StatusCode::InvalidConfig,
        "enable mask bit 9",
    );
}

/// PIN0 high and PIN1 low, then a 50 Hz servo PWM started and stopped, each checked in
/// STATUS; returns the STATUS after the pins were set.
pub fn pins_and_servo_pwm(arm: &armctl::Client) -> protocol::StatusReport {
    use protocol::StatusFlags;
    arm.pin(0, true).unwrap();
    arm.pin(1, false).unwrap();
    let status = arm.status().unwrap();
    assert!(status.flags.has(StatusFlags::PIN0_HIGH));
    assert!(!status.flags.has(StatusFlags::PIN1_HIGH));
    let pwm = armctl::pwm::settings(status.pwm_timer_clock_hz, 50.0, 0.075, 0).unwrap();
    arm.pwm_start(pwm).unwrap();
    assert!(arm.status().unwrap().flags.has(StatusFlags::PWM_ACTIVE));
    arm.pwm_stop().unwrap();
    assert!(!arm.status().unwrap().flags.has(StatusFlags::PWM_ACTIVE));
    status
}

/// Runs `points` on a thread of its own and sends STOPPED once the controller has reported
/// `after_executed` points executed (its ACK must say STOPPED); returns how the run ended.
/// Observed progress, not a guessed delay: a loaded machine may take any time to get there.
pub fn stop_mid_run(
    arm: &std::sync::Arc<armctl::Client>,
    points: Vec<Point>,
    after_executed: usize,
) -> armctl::Result<armctl::RunReport> {
    let runner = run_reporting_progress(arm, points);
    runner.wait_executed(after_executed);
    let ack = arm.stop().unwrap();
    assert_eq!(ack.state, protocol::State::Stopped);
    runner.join()
}

/// A run on a thread of its own whose progress the test can wait for.
pub struct ObservedRun {
    executed: std::sync::mpsc::Receiver<usize>,
    thread: std::thread::JoinHandle<armctl::Result<armctl::RunReport>>,
}

/// Starts `arm.run_trajectory(points)` on a thread of its own.
pub fn run_reporting_progress(
    arm: &std::sync::Arc<armctl::Client>,
    points: Vec<Point>,
) -> ObservedRun {
    run_reporting_progress_with(arm, points, armctl::RunOptions::default())
}

/// [`run_reporting_progress`] with `options` (an emulator's longer waits).
pub fn run_reporting_progress_with(
    arm: &std::sync::Arc<armctl::Client>,
    points: Vec<Point>,
    options: armctl::RunOptions,
) -> ObservedRun {
    let (tx, executed) = std::sync::mpsc::channel();
    let arm = arm.clone();
    let thread = std::thread::spawn(move || {
        arm.run_trajectory(&points, &options, |p| {
            let _ = tx.send(p.executed);
        })
    });
    ObservedRun { executed, thread }
}

impl ObservedRun {
    /// Waits until the controller has reported at least `count` points executed (30 s at
    /// most; panics if the run ended first).
    pub fn wait_executed(&self, count: usize) {
        let deadline = Instant::now() + Duration::from_secs(30);
        loop {
            let left = deadline
                .checked_duration_since(Instant::now())
                .unwrap_or_else(|| panic!("fewer than {count} points executed after 30 s"));
            match self.executed.recv_timeout(left) {
                Ok(n) if n >= count => return,
                Ok(_) => {}
                Err(e) => panic!("the run ended before {count} points executed ({e})"),
            }
        }
    }

    /// How the run ended.
    pub fn join(self) -> armctl::Result<armctl::RunReport> {
        self.thread.join().unwrap()
    }
}

/// Asserts that the next `reports` LOCATION reports (claimed for `arm`) all show the
/// joints where the first of them does: the arm stays put for that many report periods
/// of the controller's own clock (10 ms each by default), however slow this machine is.
pub fn assert_stays_put(arm: &armctl::Client, reports: usize) -> [i32; MAX_JOINTS] {
    let locations = arm.locations();
    arm.claim_locations().expect("claim LOCATION reports");
    let next = || {
        locations
            .recv_timeout(Duration::from_secs(5))
            .expect("a LOCATION report")
    };
    let first = next();
    for k in 1..reports {
        let later = next();
        assert_eq!(
            later.position, first.position,
            "a joint moved after the stop (report {k} of {reports})"
        );
        assert_eq!(later.state, first.state, "state changed (report {k})");
    }
    first.position
}

/// Client options for a simulator on loopback: a short first ACK wait, many tries.
pub fn loopback() -> armctl::Options {
    armctl::Options {
        ack_timeout: Duration::from_millis(50),
        attempts: 20,
        ..armctl::Options::default()
    }
}

/// Where the arm is, from a LOCATION report (2 s at most).
pub fn position(arm: &armctl::Client) -> [i32; MAX_JOINTS] {
    arm.current_location(Duration::from_secs(2))
        .expect("a LOCATION report")
        .position
}
