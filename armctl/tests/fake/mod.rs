//! A small controller that follows PROTOCOL.md closely enough to exercise the client's
//! reliability logic with deterministic loss, duplication and reordering that the test
//! chooses. It is not the simulator: `tests/` (system-tests) runs the real sim-host.

#![allow(dead_code)]

use std::collections::VecDeque;
use std::net::{SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use protocol::{
    Ack, Command, Frame, Location, MAX_DATAGRAM, Point, Report, State, StatusCode, StatusFlags,
    StatusReport, Tag,
};

/// Faults applied to datagrams in both directions.
#[derive(Clone, Copy, Debug, Default)]
pub struct Faults {
    /// Probability that a datagram is dropped.
    pub loss: f64,
    /// Probability that a datagram is delivered twice.
    pub dup: f64,
    /// Probability that a datagram is held back and delivered after the next one.
    pub reorder: f64,
    /// RNG seed.
    pub seed: u64,
    /// Datagrams the controller can queue at once (0: unbounded); a burst beyond it is
    /// dropped, like a firmware inbox that is full.
    pub inbox: usize,
    /// After executing this many points of a run, the fake "falls behind": it ends the run
    /// with an underrun although points are still buffered (a controller that cannot feed
    /// its step engine in time).
    pub fall_behind_after: Option<u16>,
    /// The window STATUS advertises (0: none, as an older controller).
    pub window: u16,
    /// Drops the received datagram with this index (0 = the first), once.
    pub drop_received: Option<usize>,
}

/// What the fake counted.
#[derive(Clone, Debug, Default)]
pub struct Counters {
    /// PENDING frames whose points were taken.
    pub pending_taken: usize,
    /// Frames recognised as duplicates.
    pub duplicates: usize,
    /// OUT_OF_ORDER refusals.
    pub out_of_order: usize,
    /// BUFFER_FULL refusals.
    pub buffer_full: usize,
    /// Every point taken, in order.
    pub taken: Vec<Point>,
}

struct Rng(u64);
impl Rng {
    fn chance(&mut self, p: f64) -> bool {
        // xorshift64*
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        let x = self.0.wrapping_mul(0x2545_F491_4F6C_DD1D);
        ((x >> 11) as f64 / (1u64 << 53) as f64) < p
    }
}

struct Sim {
    state: State,
    joints: u8,
    capacity: usize,
    buffer: VecDeque<Point>,
    expected: u16,
    received: u16,
    executed: u16,
    position: [i32; 8],
    segment_start: Instant,
    flags: StatusFlags,
    /// The seq a PENDING must carry to be taken: the first seq after the last taken
    /// NEW/PENDING not used by an accepted command.
    expect_seq: u8,
    /// Seqs accepted since the last taken NEW/PENDING.
    accepted: std::collections::HashSet<u8>,
    recent: VecDeque<(u16, u8, u8, u8, Instant)>,
    owner: Option<SocketAddr>,
    report_seq: u8,
    counters: Counters,
    upload_period: Duration,
    last_report: Instant,
    fall_behind_after: Option<u16>,
    window: u16,
}

/// A running fake controller on 127.0.0.1.
pub struct Fake {
    pub addr: SocketAddr,
    sim: Arc<Mutex<Sim>>,
    shutdown: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl Fake {
    /// Starts a fake with `capacity` buffer slots and the given faults.
    pub fn start(capacity: usize, faults: Faults) -> Fake {
        let socket = UdpSocket::bind("127.0.0.1:0").unwrap();
        socket
            .set_read_timeout(Some(Duration::from_millis(1)))
            .unwrap();
        let addr = socket.local_addr().unwrap();
        let sim = Arc::new(Mutex::new(Sim {
            state: State::Stopped,
            joints: 6,
            capacity,
            buffer: VecDeque::new(),
            expected: 0,
            received: 0,
            executed: 0,
            position: [0; 8],
            segment_start: Instant::now(),
            flags: StatusFlags(StatusFlags::REPORTS_ON),
            expect_seq: 0,
            accepted: Default::default(),
            recent: VecDeque::new(),
            owner: None,
            report_seq: 0,
            counters: Counters::default(),
            upload_period: Duration::from_millis(10),
            last_report: Instant::now(),
            fall_behind_after: faults.fall_behind_after,
            window: faults.window,
        }));
        let shutdown = Arc::new(AtomicBool::new(false));
        let thread = {
            let sim = sim.clone();
            let shutdown = shutdown.clone();
            std::thread::spawn(move || serve(socket, sim, shutdown, faults))
        };
        Fake {
            addr,
            sim,
            shutdown,
            thread: Some(thread),
        }
    }

    pub fn counters(&self) -> Counters {
        self.sim.lock().unwrap().counters.clone()
    }

    pub fn position(&self) -> [i32; 8] {
        self.sim.lock().unwrap().position
    }
}

impl Drop for Fake {
    fn drop(&mut self) {
        self.shutdown.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// Outgoing datagrams pass through here.
struct Link {
    socket: UdpSocket,
    rng: Rng,
    faults: Faults,
    held: Option<(Vec<u8>, SocketAddr)>,
}

impl Link {
    fn send(&mut self, bytes: &[u8], to: SocketAddr) {
        if self.rng.chance(self.faults.loss) {
            return;
        }
        if self.held.is_none() && self.rng.chance(self.faults.reorder) {
            self.held = Some((bytes.to_vec(), to));
            return;
        }
        let _ = self.socket.send_to(bytes, to);
        if self.rng.chance(self.faults.dup) {
            let _ = self.socket.send_to(bytes, to);
        }
        if let Some((held, to)) = self.held.take() {
            let _ = self.socket.send_to(&held, to);
        }
    }
}

fn serve(socket: UdpSocket, sim: Arc<Mutex<Sim>>, shutdown: Arc<AtomicBool>, faults: Faults) {
    let mut link = Link {
        socket: socket.try_clone().unwrap(),
        rng: Rng(faults.seed.max(1)),
        faults,
        held: None,
    };
    let mut in_rng = Rng(faults.seed.wrapping_mul(31).max(7));
    let mut held_in: Option<(Vec<u8>, SocketAddr)> = None;
    let mut received = 0usize;
    let mut buf = [0u8; MAX_DATAGRAM];
    while !shutdown.load(Ordering::Relaxed) {
        let mut incoming = Vec::new();
        // The first datagram (waiting 1 ms at most), then whatever is queued behind it:
        // one burst.
        let mut burst = Vec::new();
        if let Ok((n, from)) = socket.recv_from(&mut buf) {
            burst.push((buf[..n].to_vec(), from));
            socket.set_nonblocking(true).unwrap();
            while let Ok((n, from)) = socket.recv_from(&mut buf) {
                burst.push((buf[..n].to_vec(), from));
                if burst.len() >= 64 {
                    break;
                }
            }
            socket.set_nonblocking(false).unwrap();
        }
        if faults.inbox > 0 {
            burst.truncate(faults.inbox);
        }
        for (datagram, from) in burst {
            received += 1;
            if faults.drop_received == Some(received - 1) {
                continue;
            }
            if !in_rng.chance(faults.loss) {
                if held_in.is_none() && in_rng.chance(faults.reorder) {
                    held_in = Some((datagram, from));
                } else {
                    incoming.push((datagram.clone(), from));
                    if in_rng.chance(faults.dup) {
                        incoming.push((datagram, from));
                    }
                    if let Some(h) = held_in.take() {
                        incoming.push(h);
                    }
                }
            }
        }
        let mut sim = sim.lock().unwrap();
        for (datagram, from) in incoming {
            sim.handle(&datagram, from, &mut link);
        }
        sim.tick(&mut link);
    }
}

impl Sim {
    fn report(&mut self, report: &Report<'_>, link: &mut Link) {
        let Some(owner) = self.owner else { return };
        let mut out = [0u8; MAX_DATAGRAM];
        self.report_seq = self.report_seq.wrapping_add(1);
        let n = report.encode(self.report_seq, &mut out).unwrap();
        link.send(&out[..n], owner);
    }

    fn location(&mut self, link: &mut Link) {
        let location = Location {
            position: self.position,
            state: self.state as u8,
        };
        self.report(&Report::Location(location), link);
    }

    fn set_state(&mut self, state: State, link: &mut Link) {
        if self.state != state {
            self.state = state;
            self.location(link);
        }
    }

    fn handle(&mut self, datagram: &[u8], from: SocketAddr, link: &mut Link) {
        let reply = |status: StatusCode, sim: &Sim, seq: u8, tag: u8, link: &mut Link| {
            let mut out = [0u8; MAX_DATAGRAM];
            let ack = Ack {
                acked_tag: tag,
                status,
                state: sim.state,
                next_seq: sim.expect_seq,
                buffered: sim.buffer.len() as u16,
                free: (sim.capacity - sim.buffer.len()) as u16,
            };
            let n = Report::Ack(ack).encode(seq, &mut out).unwrap();
            link.send(&out[..n], from);
        };
        let frame: Frame<Command<'_>> = match Command::decode(datagram) {
            Ok(f) => f,
            Err(e) => {
                if let Some(status) = e.status() {
                    reply(status, self, e.seq, e.tag, link);
                }
                return;
            }
        };
        let seq = frame.seq;
        let tag = frame.body.tag() as u8;
        let crc = datagram[datagram.len() - 1];
        let now = Instant::now();
        self.owner = Some(from);
        self.recent
            .retain(|r| now.duration_since(r.4) < Duration::from_secs(2));
        if self
            .recent
            .iter()
            .any(|r| (r.0, r.1, r.2, r.3) == (from.port(), seq, tag, crc))
        {
            self.counters.duplicates += 1;
            reply(StatusCode::Ok, self, seq, tag, link);
            return;
        }
        let status = self.execute(seq, &frame.body, link);
        match status {
            StatusCode::Ok => {
                self.recent.push_back((from.port(), seq, tag, crc, now));
                if self.recent.len() > 32 {
                    self.recent.pop_front();
                }
                if !matches!(frame.body, Command::New { .. }) {
                    self.accepted.insert(seq);
                }
                while self.accepted.remove(&self.expect_seq) {
                    self.expect_seq = self.expect_seq.wrapping_add(1);
                }
            }
            StatusCode::OutOfOrder => self.counters.out_of_order += 1,
            StatusCode::BufferFull => self.counters.buffer_full += 1,
            _ => {}
        }
        reply(status, self, seq, tag, link);
        if matches!(frame.body, Command::Status) && status == StatusCode::Ok {
            let status = StatusReport {
                version: protocol::VERSION,
                joints: self.joints,
                state: self.state,
                flags: self.flags,
                buffered: self.buffer.len() as u16,
                expected: self.expected,
                received: self.received,
                executed: self.executed,
                capacity: self.capacity as u16,
                more_flags: protocol::MoreFlags::default(),
                upload_period_us: self.upload_period.as_micros() as u32,
                pwm_timer_clock_hz: 240_000_000,
                max_step_rate_hz: 50_000,
                window: self.window,
                step_budget_hz: 0,
            };
            self.report(&Report::Status(status), link);
        }
    }

    fn execute(&mut self, seq: u8, command: &Command<'_>, link: &mut Link) -> StatusCode {
        match *command {
            Command::New { count } => {
                if self.state == State::Running {
                    return StatusCode::BadState;
                }
                self.buffer.clear();
                self.expected = count;
                self.received = 0;
                self.executed = 0;
                self.expect_seq = seq.wrapping_add(1);
                self.accepted.clear();
                self.set_state(State::New, link);
                StatusCode::Ok
            }
            Command::Pending(points) => {
                if !matches!(self.state, State::New | State::Pending | State::Running) {
                    return StatusCode::BadState;
                }
                if seq != self.expect_seq {
                    return StatusCode::OutOfOrder;
                }
                if usize::from(self.received) + points.len() > usize::from(self.expected) {
                    return StatusCode::TooManyPoints;
                }
                if self.buffer.len() + points.len() > self.capacity {
                    return StatusCode::BufferFull;
                }
                for p in points.iter() {
                    self.buffer.push_back(p);
                    self.counters.taken.push(p);
                }
                self.received += points.len() as u16;
                self.counters.pending_taken += 1;
                if self.state != State::Running {
                    self.set_state(State::Pending, link);
                }
                StatusCode::Ok
            }
            Command::Runing => match self.state {
                State::Pending => {
                    self.segment_start = Instant::now();
                    self.flags.set(StatusFlags::UNDERRUN, false);
                    self.flags.set(StatusFlags::STOPPED_BY_HOST, false);
                    self.set_state(State::Running, link);
                    StatusCode::Ok
                }
                State::Running => StatusCode::Ok,
                _ => StatusCode::BadState,
            },
            Command::Stopped => {
                if self.state == State::Running {
                    self.flags.set(StatusFlags::STOPPED_BY_HOST, true);
                }
                self.buffer.clear();
                self.set_state(State::Stopped, link);
                StatusCode::Ok
            }
            Command::JointsCount(n) => {
                if self.state != State::Stopped {
                    return StatusCode::BadState;
                }
                self.joints = n;
                StatusCode::Ok
            }
            Command::LocationSetting(location) => {
                if self.state != State::Stopped {
                    return StatusCode::BadState;
                }
                self.position = location.position;
                StatusCode::Ok
            }
            Command::UploadPeriod { period_us } => {
                self.upload_period = Duration::from_micros(u64::from(period_us));
                StatusCode::Ok
            }
            _ => StatusCode::Ok,
        }
    }

    fn tick(&mut self, link: &mut Link) {
        let now = Instant::now();
        if self.state == State::Running
            && self
                .fall_behind_after
                .is_some_and(|n| self.executed >= n && !self.buffer.is_empty())
        {
            self.flags.set(StatusFlags::UNDERRUN, true);
            self.buffer.clear();
            self.set_state(State::Stopped, link);
        }
        if self.state == State::Running {
            while let Some(p) = self.buffer.front() {
                let end = self.segment_start + Duration::from_micros(p.duration as u64);
                if now < end {
                    break;
                }
                self.position = p.position;
                self.segment_start = end;
                self.executed += 1;
                self.buffer.pop_front();
            }
            if self.buffer.is_empty() {
                if self.executed < self.expected {
                    self.flags.set(StatusFlags::UNDERRUN, true);
                }
                self.set_state(State::Stopped, link);
            }
        }
        if now.duration_since(self.last_report) >= self.upload_period {
            self.last_report = now;
            self.location(link);
        }
    }
}

/// `n` points moving joint 0 by `step` steps each over `duration_us`.
pub fn ramp(n: usize, step: i32, duration_us: i32) -> Vec<Point> {
    let mut previous = [0i32; 8];
    (0..n)
        .map(|_| {
            let mut target = previous;
            target[0] += step;
            target[1] -= step / 2;
            let p = Point::from_motion(duration_us, &previous, &target);
            previous = target;
            p
        })
        .collect()
}

#[allow(unused)]
pub fn tag_name(t: u8) -> &'static str {
    Tag::from_u8(t).map_or("?", Tag::name)
}
