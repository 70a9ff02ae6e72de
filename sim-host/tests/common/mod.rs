//! Starting the sim-host binary and talking to it with the `protocol` crate.
#![allow(dead_code)]

use std::net::{SocketAddr, UdpSocket};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use protocol::{
    Ack, Command, Location, MAX_JOINTS, Point, Report, State, StatusCode, StatusReport,
};
use system_tests::SimHost;

/// Simulators running at once in this test binary: the machine may have 2 cores, and a
/// simulator whose executor is starved runs its buffer dry like a starved board would.
const CONCURRENT_SIMS: usize = 2;

/// A running sim-host process (system-tests' harness, the one for every test), killed
/// (SIGTERM, so it flushes its trace) when dropped.
pub struct Sim {
    host: SimHost,
    pub addr: SocketAddr,
    /// What it printed on stdout before the address line (e.g. the pty path).
    pub banner: Vec<String>,
}

impl Sim {
    /// Starts sim-host on a free 127.0.0.1 port with these extra arguments.
    pub fn start(args: &[&str]) -> Sim {
        system_tests::limit_simulators(CONCURRENT_SIMS);
        let host = SimHost::start_binary(Path::new(env!("CARGO_BIN_EXE_sim-host")), args);
        Sim {
            addr: host.addr,
            banner: host.banner.clone(),
            host,
        }
    }

    /// Starts sim-host as [`Sim::start`] does, writing its VCD trace to `NAME.vcd` and its
    /// settings to `NAME.txt` in this process's temporary directory; returns the trace's
    /// path with it.
    pub fn start_traced(name: &str, args: &[&str]) -> (Sim, PathBuf) {
        let trace = temp_path(&format!("{name}.vcd"));
        let settings = temp_path(&format!("{name}.txt"));
        let mut all = args.to_vec();
        all.extend([
            "--trace",
            trace.to_str().unwrap(),
            "--settings",
            settings.to_str().unwrap(),
        ]);
        (Sim::start(&all), trace)
    }

    /// Stops it with SIGTERM and waits for it to exit (trace flushed).
    pub fn stop(&mut self) {
        self.host.stop();
    }

    /// What it logged so far.
    pub fn log(&self) -> String {
        self.host.log()
    }

    /// A client socket talking to it.
    pub fn client(&self) -> Client {
        Client::new(self.addr)
    }
}

/// A minimal host: one UDP socket, frames from `protocol`.
pub struct Client {
    pub socket: UdpSocket,
    pub seq: u8,
    /// Reports that arrived while waiting for something else.
    pub reports: Vec<(u8, OwnedReport)>,
}

/// A report with its data copied out.
#[derive(Clone, Debug, PartialEq)]
pub enum OwnedReport {
    Ack(Ack),
    Location(Location),
    UsartRecv(Vec<u8>),
    Status(StatusReport),
    Limits(protocol::LimitsReport),
    StopCause(protocol::StopReport),
    RxCounters(protocol::RxCounters),
    Diag(protocol::Diag),
    JointDesc(protocol::JointDescSet),
    /// MOTION (issue 32).
    Motion(protocol::MotionReport),
    Homing(protocol::HomingSet),
    Switches(protocol::SwitchesReport),
}

impl Client {
    pub fn new(addr: SocketAddr) -> Client {
        let socket = UdpSocket::bind("127.0.0.1:0").expect("bind");
        socket.connect(addr).expect("connect");
        Client {
            socket,
            seq: 0,
            reports: Vec::new(),
        }
    }

    /// Sends `command` with `seq`, as is.
    pub fn send_with_seq(&self, command: &Command<'_>, seq: u8) {
        let mut buf = [0u8; protocol::MAX_DATAGRAM];
        let n = command.encode(seq, &mut buf).expect("encodes");
        self.socket.send(&buf[..n]).expect("send");
    }

    /// Receives one report within `timeout`.
    pub fn receive(&self, timeout: Duration) -> Option<(u8, OwnedReport)> {
        let deadline = Instant::now() + timeout;
        let mut buf = [0u8; 2048];
        let left = deadline.checked_duration_since(Instant::now())?;
        self.socket
            .set_read_timeout(Some(left.max(Duration::from_micros(100))))
            .ok()?;
        let n = self.socket.recv(&mut buf).ok()?;
        let frame = Report::decode(&buf[..n]).expect("the controller sends valid frames");
        let report = match frame.body {
            Report::Ack(a) => OwnedReport::Ack(a),
            Report::Location(l) => OwnedReport::Location(l),
            Report::UsartRecv(b) => OwnedReport::UsartRecv(b.to_vec()),
            Report::Status(s) => OwnedReport::Status(s),
            Report::Limits(l) => OwnedReport::Limits(l),
            Report::StopCause(s) => OwnedReport::StopCause(s),
            Report::RxCounters(c) => OwnedReport::RxCounters(c),
            Report::Diag(d) => OwnedReport::Diag(d),
            Report::JointDesc(d) => OwnedReport::JointDesc(d),
            Report::Motion(m) => OwnedReport::Motion(m),
            Report::Homing(h) => OwnedReport::Homing(h),
            Report::Switches(s) => OwnedReport::Switches(s),
        };
        Some((frame.seq, report))
    }

    /// Sends `command` with the next seq and waits for its ACK (resending up to 5 times);
    /// other reports are kept in `reports`.
    pub fn command(&mut self, command: &Command<'_>) -> Ack {
        let seq = self.seq;
        self.seq = self.seq.wrapping_add(1);
        for _ in 0..5 {
            self.send_with_seq(command, seq);
            let deadline = Instant::now() + Duration::from_millis(500);
            while let Some(left) = deadline.checked_duration_since(Instant::now()) {
                match self.receive(left) {
                    Some((s, OwnedReport::Ack(ack)))
                        if s == seq && ack.acked_tag == command.tag() as u8 =>
                    {
                        return ack;
                    }
                    Some(other) => self.reports.push(other),
                    None => break,
                }
            }
        }
        panic!("no ACK for {:?} (seq {seq})", command.tag());
    }

    /// Like [`Client::command`], and checks the ACK says OK.
    pub fn ok(&mut self, command: &Command<'_>) -> Ack {
        let ack = self.command(command);
        assert_eq!(
            ack.status,
            StatusCode::Ok,
            "{:?} refused: {ack:?}",
            command.tag()
        );
        ack
    }

    /// Asks for STATUS and returns the report.
    pub fn status(&mut self) -> StatusReport {
        self.ok(&Command::Status);
        let deadline = Instant::now() + Duration::from_secs(2);
        loop {
            if let Some(i) = self
                .reports
                .iter()
                .rposition(|(_, r)| matches!(r, OwnedReport::Status(_)))
            {
                let (_, OwnedReport::Status(s)) = self.reports.remove(i) else {
                    unreachable!()
                };
                self.reports.clear();
                return s;
            }
            let left = deadline
                .checked_duration_since(Instant::now())
                .expect("a STATUS report");
            if let Some(r) = self.receive(left) {
                self.reports.push(r);
            }
        }
    }

    /// Waits until the controller reports STOPPED (polling STATUS).
    pub fn wait_stopped(&mut self, timeout: Duration) -> StatusReport {
        let deadline = Instant::now() + timeout;
        loop {
            let status = self.status();
            if status.state == State::Stopped {
                return status;
            }
            assert!(
                Instant::now() < deadline,
                "still {:?} after {timeout:?}",
                status.state
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// Waits until joint 0 has moved `steps` from `from` (LOCATION reports), at most
    /// `timeout`: a run under way, observed, instead of a guessed sleep (issue 19).
    pub fn wait_moved(&mut self, from: i32, steps: i32, timeout: Duration) -> Location {
        let deadline = Instant::now() + timeout;
        loop {
            let location = self.location();
            if (location.position[0] - from).abs() >= steps {
                return location;
            }
            assert!(
                Instant::now() < deadline,
                "joint 0 at {} after {timeout:?}, expected {steps} steps from {from}",
                location.position[0]
            );
        }
    }

    /// Asserts that the next `reports` LOCATION reports all show the joints where the first
    /// does: the arm stays put for that many of the controller's report periods, however
    /// slow this machine is. Returns the position.
    pub fn assert_stays_put(&mut self, reports: usize) -> [i32; MAX_JOINTS] {
        let first = self.location();
        for k in 1..reports {
            let later = self.next_location();
            assert_eq!(
                later.position, first.position,
                "a joint moved after the stop (report {k} of {reports})"
            );
        }
        first.position
    }

    /// The next LOCATION report to arrive (2 s at most).
    pub fn next_location(&mut self) -> Location {
        let deadline = Instant::now() + Duration::from_secs(2);
        loop {
            let left = deadline
                .checked_duration_since(Instant::now())
                .expect("a LOCATION report");
            match self.receive(left) {
                Some((_, OwnedReport::Location(l))) => return l,
                Some(other) => self.reports.push(other),
                None => {}
            }
        }
    }

    /// Uploads `points` (NEW, then PENDING frames of up to 12, each ACKed OK), runs them
    /// and waits until STOPPED. The buffer must hold them all.
    pub fn run_points(&mut self, points: &[Point], timeout: Duration) -> StatusReport {
        self.ok(&Command::New {
            count: points.len() as u16,
        });
        for chunk in points.chunks(protocol::MAX_POINTS_PER_FRAME) {
            self.ok(&Command::Pending(protocol::PointList::Points(chunk)));
        }
        self.ok(&Command::Runing);
        self.wait_stopped(timeout)
    }

    /// The latest LOCATION among the kept reports, or a fresh one.
    pub fn location(&mut self) -> Location {
        self.reports.clear();
        let deadline = Instant::now() + Duration::from_secs(2);
        loop {
            let left = deadline
                .checked_duration_since(Instant::now())
                .expect("a LOCATION report");
            if let Some((_, OwnedReport::Location(l))) = self.receive(left) {
                return l;
            }
        }
    }

    /// A SWITCHES report (STATUS request byte bit 5), fresh.
    pub fn switches(&mut self) -> protocol::SwitchesReport {
        self.ok(&Command::StatusWith(protocol::StatusAsk {
            switches: true,
            ..protocol::StatusAsk::default()
        }));
        let deadline = Instant::now() + Duration::from_secs(2);
        while let Some(left) = deadline.checked_duration_since(Instant::now()) {
            if let Some((_, OwnedReport::Switches(s))) = self.receive(left) {
                return s;
            }
        }
        panic!("no SWITCHES report");
    }
}

/// A unique temporary path for this test.
pub fn temp_path(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("sim-host-tests-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    dir.join(name)
}

/// Points moving from `start` through `targets`, each segment `duration_us` long.
pub fn points_through(
    start: [i32; MAX_JOINTS],
    targets: &[[i32; MAX_JOINTS]],
    duration_us: i32,
) -> Vec<Point> {
    let mut previous = start;
    targets
        .iter()
        .map(|target| {
            let p = Point::from_motion(duration_us, &previous, target);
            previous = *target;
            p
        })
        .collect()
}
