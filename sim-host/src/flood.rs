//! A STOPPED from a third host while strangers flood the controller (issues 18 and 30): the
//! measurement behind `sim-host bench`'s "e-stop under a flood" lines and the flood tests
//! (`sim-host/tests/flood.rs`).
//!
//! The hosts, each its own address ([`Hosts`]; on loopback the owner 127.0.0.1, the panel
//! 127.0.0.3, the strangers 127.0.0.10 and on): the owner (an armctl [`Client`]) runs a
//! 6-joint trajectory, and a second socket of its address polls STATUS at 10 Hz
//! throughout, each poll sent once (answered within 1 s, or lost); the strangers
//! ([`Flood`]) send datagrams, from one address valid STATUS frames and garbage (bad CRCs,
//! unknown tags) mixed at a given rate (issue 18), or from many addresses valid STATUS as
//! fast as their sockets send (issue 30); a panel sends one STOPPED per run, never resent. For each STOPPED the figure is
//! the time from its send to its effect ([`Effect`]): inside the simulator, the step engine
//! going idle ([`Probe::last_engine_stop`]); from outside (`sim-host flood` against the
//! QEMU board), the STOPPED's ACK reaching the panel, after which the owner's STATUS must
//! say STOPPED. One without its effect 5 s later is lost. Every loop that sends is bounded
//! in count and time; the addresses are loopback or a test's own network namespace.

use std::net::{SocketAddr, UdpSocket};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use armctl::{Client, RunOptions};
use protocol::{MAX_JOINTS, Point, Tag, crc8};

use crate::probe::Probe;

mod traffic;
use traffic::{kernel_drops, poll_status, send_flood};

/// The hosts' addresses.
#[derive(Clone, Copy, Debug)]
pub struct Hosts {
    /// The owner's.
    pub owner: std::net::Ipv4Addr,
    /// The first stranger's, which flood (the others follow it: .10, .11, ...).
    pub stranger: std::net::Ipv4Addr,
    /// The panel's, which stops.
    pub panel: std::net::Ipv4Addr,
}

impl Hosts {
    /// The owner 127.0.0.1, the panel 127.0.0.3, the strangers 127.0.0.10 and on.
    pub const LOOPBACK: Hosts = Hosts {
        owner: std::net::Ipv4Addr::new(127, 0, 0, 1),
        stranger: std::net::Ipv4Addr::new(127, 0, 0, 10),
        panel: std::net::Ipv4Addr::new(127, 0, 0, 3),
    };

    /// The `i`th stranger's address.
    fn stranger(&self, i: u8) -> std::net::Ipv4Addr {
        std::net::Ipv4Addr::from(u32::from(self.stranger).wrapping_add(u32::from(i)))
    }
}

/// The strangers' flood.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Flood {
    /// Source addresses (0: no flood), consecutive from [`Hosts::stranger`].
    pub sources: u8,
    /// Datagrams a second from all of them; `None`: as fast as their sockets send, from
    /// [`UNTHROTTLED_SENDERS`] threads (the highest rate loopback carries here).
    pub rate_hz: Option<u32>,
    /// Valid STATUS only (issue 30's strangers); else every fourth, the rest garbage.
    pub valid_only: bool,
    /// The flood and the owner's polls last at least this long (past the STOPPEDs' runs),
    /// so that the polls are many.
    pub hold: Duration,
}

impl Flood {
    /// No flood.
    pub const NONE: Flood = Flood {
        sources: 0,
        rate_hz: Some(0),
        valid_only: false,
        hold: Duration::ZERO,
    };

    /// Issue 18's: one stranger, `rate_hz` datagrams a second, valid and garbage mixed.
    pub const fn one(rate_hz: u32) -> Flood {
        Flood {
            sources: 1,
            rate_hz: Some(rate_hz),
            valid_only: false,
            hold: Duration::ZERO,
        }
    }

    /// Issue 30's: `sources` strangers, valid STATUS as fast as their sockets send, for
    /// 20 s at least (200 polls of the owner's).
    pub const fn many(sources: u8) -> Flood {
        Flood {
            sources,
            rate_hz: None,
            valid_only: true,
            hold: Duration::from_secs(20),
        }
    }

    fn is_none(&self) -> bool {
        self.sources == 0 || self.rate_hz == Some(0)
    }
}

/// Threads that send an unthrottled flood: the machines have 2 cores, which the
/// controller's threads share.
pub const UNTHROTTLED_SENDERS: usize = 2;

/// An unthrottled flood never sends more than this many datagrams (a bound besides
/// [`FLOOD_LIMIT`]).
const FLOOD_MAX_DATAGRAMS: u64 = 100_000_000;

/// The owner's STATUS polls: every 100 ms (10 Hz).
const POLL_PERIOD: Duration = Duration::from_millis(100);

/// What tells that a STOPPED took effect.
#[derive(Clone, Copy, Debug)]
pub enum Effect<'a> {
    /// The simulated step engine went idle (in-process).
    EngineIdle(&'a Probe),
    /// Its ACK reached the panel, and then the owner's STATUS says STOPPED (any
    /// controller, from outside: an upper bound of the time to the halt, which comes
    /// before the ACK is queued).
    Acked,
}
/// How long a STOPPED may take before it counts as lost: 5 s, so that a machine ten times
/// slower or busier does not turn a late one into a lost one (1 s was: a QEMU board on a
/// loaded CI machine). The figures show how long they took.
const LOST_AFTER: Duration = Duration::from_secs(5);
/// The flood never runs longer than this, whatever happens to the measurement.
const FLOOD_LIMIT: Duration = Duration::from_secs(120);

/// What one measurement saw.
#[derive(Clone, Debug, Default)]
pub struct FloodFigures {
    /// Datagrams a second the stranger sent (0: no flood).
    pub flood_rate_hz: f64,
    /// For each STOPPED that took effect: its send to the engine idle.
    pub effect: Vec<Duration>,
    /// STOPPEDs that had not stopped the engine [`LOST_AFTER`] after their send.
    pub lost: usize,
    /// With [`Effect::Acked`]: STOPPEDs whose ACK never came but which stopped the run
    /// (counted in `lost` too).
    pub acks_lost: usize,
    /// The owner's STATUS round trips during the runs (armctl's, resends included).
    pub status_round_trips: Vec<Duration>,
    /// The owner's 10 Hz polls answered: each one's send to its ACK (never resent).
    pub polls: Vec<Duration>,
    /// The owner's polls not answered within 1 s.
    pub polls_lost: usize,
    /// The flood's source addresses.
    pub sources: u8,
    /// Datagrams the kernel dropped at the controller's socket meanwhile (its buffer
    /// full: the socket reader fell behind), from /proc/net/udp; `None` where unreadable.
    pub kernel_drops: Option<u64>,
    /// Datagrams the controller's receive path shed (over their sender's share); `None`
    /// when measured from outside, where the count cannot be read.
    pub shed: Option<u32>,
}

impl FloodFigures {
    /// `q` quantile of the effect times, milliseconds (NaN if none).
    pub fn effect_ms(&self, q: f64) -> f64 {
        quantile_ms(&self.effect, q)
    }

    /// `q` quantile of the owner's STATUS round trips, milliseconds (NaN if none).
    pub fn status_ms(&self, q: f64) -> f64 {
        quantile_ms(&self.status_round_trips, q)
    }

    /// `q` quantile of the owner's answered 10 Hz polls, milliseconds (NaN if none).
    pub fn poll_ms(&self, q: f64) -> f64 {
        quantile_ms(&self.polls, q)
    }
}

fn quantile_ms(values: &[Duration], q: f64) -> f64 {
    let mut sorted = values.to_vec();
    sorted.sort();
    if sorted.is_empty() {
        return f64::NAN;
    }
    let i = ((sorted.len() - 1) as f64 * q).round() as usize;
    sorted[i.min(sorted.len() - 1)].as_secs_f64() * 1e3
}

/// A 6-joint run of 300 points of 10 ms (3 s; 2..7 kHz per joint, alternating
/// directions) from zero: what the e-stop measurements stop.
pub fn long_run() -> Vec<Point> {
    let mut previous = [0; MAX_JOINTS];
    (1..=300)
        .map(|i| {
            let mut target = [0; MAX_JOINTS];
            for (j, t) in target.iter_mut().take(6).enumerate() {
                let rate = 20 + 10 * j as i32;
                *t = if j % 2 == 0 { i * rate } else { -i * rate };
            }
            let p = Point::from_motion(10_000, &previous, &target);
            previous = target;
            p
        })
        .collect()
}

/// `stops` runs, each stopped by one STOPPED from the panel 20..80 ms in, with the
/// strangers' `flood`, on loopback, measured inside the simulator. `shed` reads the
/// controller's count of shed datagrams.
pub fn estop_under_flood(
    addr: SocketAddr,
    probe: &Probe,
    stops: usize,
    flood: Flood,
    shed: impl Fn() -> u32,
) -> std::io::Result<FloodFigures> {
    measure(
        addr,
        Hosts::LOOPBACK,
        Effect::EngineIdle(probe),
        stops,
        flood,
        Some(shed),
    )
}

/// [`estop_under_flood`] with any hosts and effect; `shed` reads the controller's count
/// of shed datagrams where it can be read (in-process).
pub fn measure(
    addr: SocketAddr,
    hosts: Hosts,
    effect: Effect<'_>,
    stops: usize,
    flood: Flood,
    shed: Option<impl Fn() -> u32>,
) -> std::io::Result<FloodFigures> {
    let to_io = |e: armctl::Error| std::io::Error::other(e.to_string());
    let owner = Client::connect_with(
        addr,
        armctl::Options {
            bind: Some(SocketAddr::from((hosts.owner, 0))),
            ..armctl::Options::default()
        },
    )
    .map_err(to_io)?;
    owner.set_joints(6).map_err(to_io)?;
    let panel = UdpSocket::bind((hosts.panel, 0))?;
    panel.set_read_timeout(Some(Duration::from_millis(5)))?;
    let stop_flood = Arc::new(AtomicBool::new(false));
    let flood_sent = Arc::new(AtomicU64::new(0));
    let mut flooders = Vec::new();
    if !flood.is_none() {
        let strangers: Vec<std::net::Ipv4Addr> =
            (0..flood.sources).map(|i| hosts.stranger(i)).collect();
        if strangers.contains(&hosts.owner) || strangers.contains(&hosts.panel) {
            return Err(std::io::Error::other(
                "the strangers' addresses include the owner's or the panel's",
            ));
        }
        let threads = if flood.rate_hz.is_none() {
            UNTHROTTLED_SENDERS.min(strangers.len())
        } else {
            1
        };
        let mut sockets: Vec<Vec<UdpSocket>> = (0..threads).map(|_| Vec::new()).collect();
        for (i, ip) in strangers.iter().enumerate() {
            let socket = UdpSocket::bind((*ip, 0))?;
            socket.set_nonblocking(true)?;
            sockets[i % threads].push(socket);
        }
        for group in sockets {
            let stop = stop_flood.clone();
            let sent = flood_sent.clone();
            flooders.push(std::thread::spawn(move || {
                send_flood(&group, addr, flood.rate_hz, flood.valid_only, &stop, &sent)
            }));
        }
    }
    let stop_polls = Arc::new(AtomicBool::new(false));
    let poller = {
        let stop = stop_polls.clone();
        std::thread::spawn(move || poll_status(hosts.owner, addr, &stop))
    };
    let shed_before = shed.as_ref().map(|read| read());
    let kernel_drops_before = kernel_drops(addr);
    let flood_started = Instant::now();
    let mut figures = FloodFigures::default();
    let run = long_run();
    let mut pseudo_random = 0x2545_F491_4F6C_DD1Du64;
    let result = (|| -> std::io::Result<()> {
        for round in 0..stops {
            owner.set_location(&[0; 6]).map_err(to_io)?;
            let options = RunOptions {
                wait: false,
                ..RunOptions::default()
            };
            owner
                .run_trajectory(&run, &options, |_| {})
                .map_err(to_io)?;
            pseudo_random ^= pseudo_random << 13;
            pseudo_random ^= pseudo_random >> 7;
            pseudo_random ^= pseudo_random << 17;
            let polled = Instant::now();
            owner.status().map_err(to_io)?;
            figures.status_round_trips.push(polled.elapsed());
            let wait = Duration::from_millis(20 + pseudo_random % 60);
            std::thread::sleep(wait.saturating_sub(polled.elapsed()));
            // The panel's fixed frame: a new run less than 2 s after the last stop.
            let body = [0x42, Tag::Stopped as u8];
            let stop = [body[0], body[1], crc8(&body)];
            let mut reply = [0u8; 64];
            while panel.recv_from(&mut reply).is_ok() {}
            let sent = Instant::now();
            panel.send_to(&stop, addr)?;
            let stopped = loop {
                let seen = match effect {
                    Effect::EngineIdle(probe) => {
                        std::thread::sleep(Duration::from_micros(200));
                        probe.last_engine_stop().filter(|at| *at >= sent)
                    }
                    // ACK (tag 0x14) of seq 0x42 acking STOPPED.
                    Effect::Acked => match panel.recv_from(&mut reply) {
                        Ok((n, _))
                            if n >= 4
                                && reply[0] == 0x42
                                && reply[1] == Tag::Ack as u8
                                && reply[2] == Tag::Stopped as u8 =>
                        {
                            Some(Instant::now())
                        }
                        _ => None,
                    },
                };
                match seen {
                    Some(at) => break Some(at),
                    None if sent.elapsed() > LOST_AFTER => break None,
                    None => {}
                }
            };
            match stopped {
                Some(at) => figures.effect.push(at - sent),
                None => {
                    figures.lost += 1;
                    let state = owner.status().map_err(to_io)?.state;
                    if state == protocol::State::Stopped {
                        figures.acks_lost += 1;
                    }
                    log::warn!(
                        "flood: the STOPPED of round {round} had no effect in {LOST_AFTER:?} (state then {state:?})"
                    );
                    owner.stop().map_err(to_io)?;
                }
            }
            let polled = Instant::now();
            let status = owner.status().map_err(to_io)?;
            figures.status_round_trips.push(polled.elapsed());
            if status.state != protocol::State::Stopped {
                if stopped.is_some() {
                    // ACKed but not stopped: as good as lost.
                    figures.effect.pop();
                    figures.lost += 1;
                }
                owner.stop().map_err(to_io)?;
            }
        }
        Ok(())
    })();
    // The measurement's length, not a wait for the controller: the polls go on meanwhile.
    while result.is_ok() && flood_started.elapsed() < flood.hold {
        std::thread::sleep(Duration::from_millis(50));
    }
    stop_flood.store(true, Ordering::Relaxed);
    for flooder in flooders {
        flooder
            .join()
            .map_err(|_| std::io::Error::other("a flooder panicked"))?;
    }
    stop_polls.store(true, Ordering::Relaxed);
    let polls = poller
        .join()
        .map_err(|_| std::io::Error::other("the poller panicked"))??;
    result?;
    figures.polls = polls.iter().flatten().copied().collect();
    figures.polls_lost = polls.iter().filter(|p| p.is_none()).count();
    figures.sources = if flood.is_none() { 0 } else { flood.sources };
    figures.kernel_drops = kernel_drops(addr)
        .zip(kernel_drops_before)
        .map(|(after, before)| after.saturating_sub(before));
    let seconds = flood_started.elapsed().as_secs_f64();
    figures.flood_rate_hz = flood_sent.load(Ordering::Relaxed) as f64 / seconds;
    figures.shed = shed
        .as_ref()
        .zip(shed_before)
        .map(|(read, before)| read().wrapping_sub(before));
    Ok(figures)
}

/// Options of `sim-host flood`.
#[derive(Clone, Debug, clap::Args)]
pub struct FloodOptions {
    /// The controller.
    #[arg(long)]
    pub controller: SocketAddr,
    /// The owner's address (bound by its sockets).
    #[arg(long, default_value = "127.0.0.1")]
    pub owner: std::net::Ipv4Addr,
    /// The first stranger's address (the others follow it).
    #[arg(long, default_value = "127.0.0.10")]
    pub stranger: std::net::Ipv4Addr,
    /// The panel's address.
    #[arg(long, default_value = "127.0.0.3")]
    pub panel: std::net::Ipv4Addr,
    /// Flood rates to measure at, datagrams per second from one stranger, valid and
    /// garbage mixed (0: no flood); `max`: `--sources` strangers sending valid STATUS as
    /// fast as their sockets send.
    #[arg(long, value_delimiter = ',', default_value = "0,10000,max", value_parser = parse_rate)]
    pub rates: Vec<Option<u32>>,
    /// Strangers flooding at the `max` rate.
    #[arg(long, default_value_t = 20)]
    pub sources: u8,
    /// STOPPEDs per rate.
    #[arg(long, default_value_t = 20)]
    pub stops: usize,
}

fn parse_rate(s: &str) -> Result<Option<u32>, String> {
    if s == "max" {
        return Ok(None);
    }
    s.parse().map(Some).map_err(|e| format!("{s}: {e}"))
}

/// `sim-host flood`: the figures of [`measure`] with [`Effect::Acked`], one line per rate.
pub fn run(options: &FloodOptions) -> std::io::Result<()> {
    let hosts = Hosts {
        owner: options.owner,
        stranger: options.stranger,
        panel: options.panel,
    };
    println!(
        "e-stop under a flood at {} ({} single STOPPEDs from {} per rate, never resent; send -> its ACK, then STATUS STOPPED; the owner's 10 Hz polls, never resent):",
        options.controller, options.stops, options.panel
    );
    for &rate in &options.rates {
        let flood = match rate {
            Some(0) => Flood::NONE,
            Some(rate) => Flood::one(rate),
            None => Flood::many(options.sources),
        };
        let f = measure(
            options.controller,
            hosts,
            Effect::Acked,
            options.stops,
            flood,
            None::<fn() -> u32>,
        )?;
        println!("  {}", f.line());
        let counters = crate::rx_counters::read(options.controller, options.panel);
        println!("    {}", crate::rx_counters::line(counters));
    }
    Ok(())
}

impl FloodFigures {
    /// One line of figures: the STOPPEDs', the owner's STATUS round trips in the runs and
    /// its 10 Hz polls.
    pub fn line(&self) -> String {
        let label = match self.sources {
            0 => "idle".to_string(),
            1 => format!("flood {:.0}/s", self.flood_rate_hz),
            n => format!("{n} srcs {:.0}/s", self.flood_rate_hz),
        };
        format!(
            "{label:<22} STOPPED p50 {:>6.2} ms  p90 {:>6.2} ms  max {:>6.2} ms  lost {} of {}{}   owner's 10 Hz polls p50 {:.2} ms  p90 {:.2} ms  max {:.2} ms  lost {} of {}   owner STATUS in runs max {:.2} ms   shed {}{}",
            self.effect_ms(0.5),
            self.effect_ms(0.9),
            self.effect_ms(1.0),
            self.lost,
            self.effect.len() + self.lost,
            if self.acks_lost > 0 {
                format!(" ({} stopped the arm, their ACK lost)", self.acks_lost)
            } else {
                String::new()
            },
            self.poll_ms(0.5),
            self.poll_ms(0.9),
            self.poll_ms(1.0),
            self.polls_lost,
            self.polls.len() + self.polls_lost,
            self.status_ms(1.0),
            self.shed
                .map_or("n/a (not readable from outside)".to_string(), |n| n
                    .to_string()),
            self.kernel_drops
                .map_or(String::new(), |n| format!("   kernel dropped {n}"))
        )
    }
}
