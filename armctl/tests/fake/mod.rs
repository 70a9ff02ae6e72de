//! The real controller state machine (`arm_core::Controller`, with arm-core's test-support
//! `FakePlant` run in real time) behind a UDP socket on 127.0.0.1, with a fault injector
//! between it and the client: deterministic loss, duplication and reordering the test
//! chooses, a small inbox, one chosen datagram dropped, an advertised window, and a
//! controller that falls behind mid-run. The duplicate, ordering and BUFFER_FULL rules are
//! the firmware's own. `tests/` (system-tests) runs the whole sim-host.

#![allow(dead_code)]

use std::net::{SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use arm_core::hw::Endpoint;
use arm_core::test_support::FakePlant;
use arm_core::{Controller, ControllerConfig, Deferred};
use protocol::{Command, Location, MAX_DATAGRAM, Point, PointList, Report, StatusCode, Tag};

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
    /// After executing this many points of a run, the fake "falls behind": its step engine
    /// runs dry although points are still buffered (a controller that cannot feed its step
    /// engine in time), which the controller ends as an underrun.
    pub fall_behind_after: Option<u16>,
    /// The window STATUS advertises (0: none, as an older controller), written over the
    /// controller's own.
    pub window: u16,
    /// Drops the received datagram with this index (0 = the first), once.
    pub drop_received: Option<usize>,
}

/// What the fake counted.
#[derive(Clone, Debug, Default)]
pub struct Counters {
    /// PENDING frames whose points were taken.
    pub pending_taken: usize,
    /// PENDING frames ACKed OK whose points were not taken again (duplicates).
    pub duplicates: usize,
    /// OUT_OF_ORDER refusals.
    pub out_of_order: usize,
    /// BUFFER_FULL refusals.
    pub buffer_full: usize,
    /// Every point taken, in order.
    pub taken: Vec<Point>,
    /// Points received when the first run started (RUNING taken).
    pub received_at_start: Option<u16>,
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

/// The largest trajectory buffer a test asks for.
const CAP: usize = 4096;

/// Highest step rate of one joint of the fake engine: fast enough for any test's jump.
const FAST_ENGINE_HZ: u32 = 10_000_000;

/// Segments the fake step engine queues (the controller keeps it fed).
const ENGINE_ROOM: usize = 16;

struct Sim {
    controller: Box<Controller<CAP>>,
    plant: FakePlant,
    /// The controller's clock starts here.
    started: Instant,
    /// When the engine's front segment began, while it runs.
    segment_start: Option<Instant>,
    report_seq: u8,
    counters: Counters,
    last_report: Instant,
    fall_behind_after: Option<u16>,
    window: u16,
}

/// A running fake controller on 127.0.0.1.
pub struct Fake {
    pub addr: SocketAddr,
    sim: Arc<Mutex<Sim>>,
    shutdown: Arc<AtomicBool>,
    /// A pause the controller takes when the next datagram arrives ([`Fake::pause_next`]).
    pause: Arc<Mutex<Option<Duration>>>,
    thread: Option<JoinHandle<()>>,
    /// This test binary's fakes run one at a time ([`ONE_AT_A_TIME`]); dropped last.
    _turn: std::sync::MutexGuard<'static, ()>,
}

/// Held by each running fake. A fake runs its controller in real time, and the tests feed
/// small buffers (a few hundred milliseconds of motion) in real time: a dozen of them side
/// by side, on a loaded 2-core machine, starved each other's uploads into underruns
/// (issue 19's soak: 2 of 3 runs of `cargo test` with two busy loops per core). One at a
/// time, each has the margin its buffer gives.
static ONE_AT_A_TIME: Mutex<()> = Mutex::new(());

impl Fake {
    /// Starts a fake with `capacity` buffer slots and the given faults.
    pub fn start(capacity: usize, faults: Faults) -> Fake {
        assert!(capacity <= CAP, "the fake buffers at most {CAP} points");
        // A test that failed while holding it poisons it; the next still runs.
        let turn = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
        let socket = UdpSocket::bind("127.0.0.1:0").unwrap();
        socket
            .set_read_timeout(Some(Duration::from_millis(1)))
            .unwrap();
        let addr = socket.local_addr().unwrap();
        let sim = Arc::new(Mutex::new(Sim {
            controller: Box::new(Controller::new(ControllerConfig {
                capacity,
                // Tests run the same ramp twice from where the first run ended: the jump
                // back to its start is a fast first segment, which this engine can take.
                max_step_rate_hz: FAST_ENGINE_HZ,
                ..ControllerConfig::BOARD
            })),
            plant: FakePlant {
                room: ENGINE_ROOM,
                ..FakePlant::default()
            },
            started: Instant::now(),
            segment_start: None,
            report_seq: 0,
            counters: Counters::default(),
            last_report: Instant::now(),
            fall_behind_after: faults.fall_behind_after,
            window: faults.window,
        }));
        let shutdown = Arc::new(AtomicBool::new(false));
        let pause = Arc::new(Mutex::new(None));
        let thread = {
            let sim = sim.clone();
            let shutdown = shutdown.clone();
            let pause = pause.clone();
            std::thread::spawn(move || serve(socket, sim, shutdown, pause, faults))
        };
        Fake {
            addr,
            sim,
            shutdown,
            pause,
            thread: Some(thread),
            _turn: turn,
        }
    }

    /// The controller stops reading for `pause` when the next datagram arrives (a board
    /// busy erasing a flash sector, a stalled process): what arrives meanwhile waits in
    /// its socket, as in a network stack's buffers, and is then taken in order.
    pub fn pause_next(&self, pause: Duration) {
        *self.pause.lock().unwrap() = Some(pause);
    }

    pub fn counters(&self) -> Counters {
        self.sim.lock().unwrap().counters.clone()
    }

    pub fn position(&self) -> [i32; 8] {
        self.sim.lock().unwrap().plant.positions
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

fn serve(
    socket: UdpSocket,
    sim: Arc<Mutex<Sim>>,
    shutdown: Arc<AtomicBool>,
    pause: Arc<Mutex<Option<Duration>>>,
    faults: Faults,
) {
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
            let paused = pause.lock().unwrap().take();
            if let Some(pause) = paused {
                std::thread::sleep(pause);
            }
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
    fn send_report(&mut self, report: &Report<'_>, to: SocketAddr, link: &mut Link) {
        let mut out = [0u8; MAX_DATAGRAM];
        self.report_seq = self.report_seq.wrapping_add(1);
        let n = report.encode(self.report_seq, &mut out).unwrap();
        link.send(&out[..n], to);
    }

    /// A LOCATION to every endpoint the controller reports to.
    fn send_location(&mut self, location: Location, link: &mut Link) {
        let settings = self.controller.report_settings();
        let now_us = u64::try_from(self.started.elapsed().as_micros()).unwrap_or(u64::MAX);
        for to in settings.location_destinations(now_us) {
            self.send_report(&Report::Location(location), address(to), link);
        }
    }

    fn handle(&mut self, datagram: &[u8], from: SocketAddr, link: &mut Link) {
        let now_us = u64::try_from(self.started.elapsed().as_micros()).unwrap_or(u64::MAX);
        let before = self.controller.status(&self.plant);
        let received_before = before.received;
        let mut response =
            self.controller
                .handle(endpoint(from), datagram, now_us, &mut self.plant);
        // A settings write: stored at once (in memory), then its ACK.
        if let Some(Deferred::SaveSettings(_)) = response.deferred {
            response.reply = self.controller.settings_saved(true, now_us);
        }
        let after = self.controller.status(&self.plant);
        let received_after = after.received;
        if before.state != protocol::State::Running
            && after.state == protocol::State::Running
            && self.counters.received_at_start.is_none()
        {
            self.counters.received_at_start = Some(after.received);
        }
        if let Some(reply) = response.reply {
            match reply.ack.status {
                StatusCode::OutOfOrder => self.counters.out_of_order += 1,
                StatusCode::BufferFull => self.counters.buffer_full += 1,
                StatusCode::Ok => {
                    if let Ok(frame) = Command::decode(datagram)
                        && let Command::Pending(points) = frame.body
                    {
                        if received_after > received_before {
                            self.counters.taken.extend(points_of(&points));
                            self.counters.pending_taken += 1;
                        } else {
                            self.counters.duplicates += 1;
                        }
                    }
                }
                _ => {}
            }
            let mut out = [0u8; MAX_DATAGRAM];
            let n = Report::Ack(reply.ack).encode(reply.seq, &mut out).unwrap();
            link.send(&out[..n], address(reply.to));
        }
        if let Some((to, mut status)) = response.status {
            status.window = self.window;
            self.send_report(&Report::Status(status), address(to), link);
        }
        if let Some(location) = response.location {
            self.send_location(location, link);
        }
        if response.deferred == Some(Deferred::ReadEncoders)
            && let Some(location) = self.controller.begin_return(None, &mut self.plant)
        {
            self.send_location(location, link);
        }
    }

    /// Runs the engine's segments in real time, falls behind when told, and sends the
    /// periodic LOCATION reports.
    fn tick(&mut self, link: &mut Link) {
        let now = Instant::now();
        if !self.plant.running {
            self.segment_start = None;
        }
        if self.plant.running
            && self.fall_behind_after.is_some_and(|n| {
                self.controller.status(&self.plant).executed >= n
                    && self.controller.buffered() > self.plant.queue.len()
            })
        {
            self.plant.queue.clear();
            self.plant.running = false;
            if let Some(location) = self.controller.on_step_progress(0, true, &mut self.plant) {
                self.send_location(location, link);
            }
        }
        while self.plant.running {
            let begun = *self.segment_start.get_or_insert(now);
            let Some(segment) = self.plant.queue.front() else {
                break;
            };
            let end = begun + Duration::from_micros(u64::from(segment.duration_us));
            if now < end {
                break;
            }
            let segment = self.plant.queue.pop_front().expect("a front segment");
            for (position, steps) in self.plant.positions.iter_mut().zip(segment.steps) {
                *position += steps;
            }
            self.segment_start = Some(end);
            let dry = self.plant.queue.is_empty();
            if dry {
                self.plant.running = false;
                self.segment_start = None;
            }
            if let Some(location) = self.controller.on_step_progress(1, dry, &mut self.plant) {
                self.send_location(location, link);
            }
        }
        let settings = self.controller.report_settings();
        let period = Duration::from_micros(u64::from(settings.upload_period_us));
        if settings.reports_on && now.duration_since(self.last_report) >= period {
            self.last_report = now;
            let location = self.controller.location(&self.plant);
            self.send_location(location, link);
        }
    }
}

fn endpoint(address: SocketAddr) -> Endpoint {
    let ip = match address.ip() {
        std::net::IpAddr::V4(ip) => ip.octets(),
        std::net::IpAddr::V6(_) => [0; 4],
    };
    Endpoint {
        ip,
        port: address.port(),
    }
}

fn address(endpoint: Endpoint) -> SocketAddr {
    SocketAddr::from((endpoint.ip, endpoint.port))
}

fn points_of(points: &PointList<'_>) -> Vec<Point> {
    points.iter().collect()
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
    Tag::name_of(t)
}
