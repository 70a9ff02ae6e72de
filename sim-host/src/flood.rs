//! A STOPPED from a third host while a stranger floods the controller (issue 18): the
//! measurement behind `sim-host bench`'s "e-stop under a flood" lines and the flood test
//! (`sim-host/tests/flood.rs`).
//!
//! Three hosts, each its own address ([`Hosts`]; on loopback 127.0.0.1-3): the owner (an
//! armctl [`Client`]) runs a 6-joint trajectory and polls STATUS; a stranger sends
//! `flood_hz` datagrams a second, valid STATUS frames and garbage (bad CRCs, unknown tags)
//! mixed; a panel sends one STOPPED per run, never resent. For each STOPPED the figure is
//! the time from its send to its effect ([`Effect`]): inside the simulator, the step engine
//! going idle ([`Probe::last_engine_stop`]); from outside (`sim-host flood` against the
//! QEMU board), the STOPPED's ACK reaching the panel, after which the owner's STATUS must
//! say STOPPED. One without its effect 1 s later is lost. Every loop that sends is bounded
//! in count and time; the addresses are loopback or a test's own network namespace.

use std::net::{SocketAddr, UdpSocket};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use armctl::{Client, RunOptions};
use protocol::{MAX_JOINTS, Point, Tag, crc8};

use crate::probe::Probe;

/// The three hosts' addresses.
#[derive(Clone, Copy, Debug)]
pub struct Hosts {
    /// The owner's.
    pub owner: std::net::Ipv4Addr,
    /// The stranger's, which floods.
    pub stranger: std::net::Ipv4Addr,
    /// The panel's, which stops.
    pub panel: std::net::Ipv4Addr,
}

impl Hosts {
    /// 127.0.0.1, .2 and .3.
    pub const LOOPBACK: Hosts = Hosts {
        owner: std::net::Ipv4Addr::new(127, 0, 0, 1),
        stranger: std::net::Ipv4Addr::new(127, 0, 0, 2),
        panel: std::net::Ipv4Addr::new(127, 0, 0, 3),
    };
}

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
/// How long a STOPPED may take before it counts as lost.
const LOST_AFTER: Duration = Duration::from_secs(1);
/// The flood never runs longer than this, whatever happens to the measurement.
const FLOOD_LIMIT: Duration = Duration::from_secs(120);

/// What one measurement saw.
#[derive(Clone, Debug, Default)]
pub struct FloodFigures {
    /// Datagrams a second the stranger sent (0: no flood).
    pub flood_rate_hz: f64,
    /// For each STOPPED that took effect: its send to the engine idle.
    pub effect: Vec<Duration>,
    /// STOPPEDs that had not stopped the engine 1 s after their send.
    pub lost: usize,
    /// With [`Effect::Acked`]: STOPPEDs whose ACK never came but which stopped the run
    /// (counted in `lost` too).
    pub acks_lost: usize,
    /// The owner's STATUS round trips during the runs (armctl's, resends included).
    pub status_round_trips: Vec<Duration>,
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

/// The stranger: `rate_hz` datagrams a second to `to` until `stop`, in 1 ms batches, every
/// fourth one valid (STATUS), the rest garbage; counts them in `sent`.
fn flood(
    from: std::net::Ipv4Addr,
    to: SocketAddr,
    rate_hz: u32,
    stop: &AtomicBool,
    sent: &AtomicU64,
) -> std::io::Result<()> {
    let socket = UdpSocket::bind((from, 0))?;
    socket.set_nonblocking(true)?;
    let started = Instant::now();
    let mut next = started;
    let mut n: u64 = 0;
    let mut junk = 0x9E37_79B9_7F4A_7C15u64;
    let mut buf = [0u8; 2048];
    while !stop.load(Ordering::Relaxed) && started.elapsed() < FLOOD_LIMIT {
        next += Duration::from_millis(1);
        let due = u64::from(rate_hz) * next.duration_since(started).as_micros() as u64 / 1_000_000;
        while n < due {
            let seq = n as u8;
            let frame: Vec<u8> = if n.is_multiple_of(4) {
                let body = [seq, Tag::Status as u8];
                vec![body[0], body[1], crc8(&body)]
            } else {
                junk ^= junk << 13;
                junk ^= junk >> 7;
                junk ^= junk << 17;
                let len = 3 + (junk % 60) as usize;
                let mut f: Vec<u8> = (0..len).map(|i| (junk >> (i % 8 * 8)) as u8).collect();
                // Never a STOPPED (the stranger floods, the panel stops) and never a
                // valid CRC: garbage.
                if f[1] == Tag::Stopped as u8 {
                    f[1] = 0x7f;
                }
                let last = f.len() - 1;
                f[last] = crc8(&f[..last]) ^ 0x5a;
                f
            };
            let _ = socket.send_to(&frame, to);
            n += 1;
            sent.fetch_add(1, Ordering::Relaxed);
        }
        // Its own answers (NOT_OWNER, BAD_CRC ACKs) are read and dropped.
        while socket.recv_from(&mut buf).is_ok() {}
        if let Some(wait) = next.checked_duration_since(Instant::now()) {
            std::thread::sleep(wait);
        }
    }
    Ok(())
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
/// stranger flooding at `flood_hz` (0: no flood), on loopback, measured inside the
/// simulator. `shed` reads the controller's count of shed datagrams.
pub fn estop_under_flood(
    addr: SocketAddr,
    probe: &Probe,
    stops: usize,
    flood_hz: u32,
    shed: impl Fn() -> u32,
) -> std::io::Result<FloodFigures> {
    measure(
        addr,
        Hosts::LOOPBACK,
        Effect::EngineIdle(probe),
        stops,
        flood_hz,
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
    flood_hz: u32,
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
    let flooder = (flood_hz > 0).then(|| {
        let stop = stop_flood.clone();
        let sent = flood_sent.clone();
        std::thread::spawn(move || flood(hosts.stranger, addr, flood_hz, &stop, &sent))
    });
    let shed_before = shed.as_ref().map(|read| read());
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
                        "flood: the STOPPED of round {round} had no effect in 1 s (state then {state:?})"
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
    stop_flood.store(true, Ordering::Relaxed);
    if let Some(flooder) = flooder {
        flooder
            .join()
            .map_err(|_| std::io::Error::other("the flooder panicked"))??;
    }
    result?;
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
    /// The owner's address (bound by its socket).
    #[arg(long, default_value = "127.0.0.1")]
    pub owner: std::net::Ipv4Addr,
    /// The stranger's address.
    #[arg(long, default_value = "127.0.0.2")]
    pub stranger: std::net::Ipv4Addr,
    /// The panel's address.
    #[arg(long, default_value = "127.0.0.3")]
    pub panel: std::net::Ipv4Addr,
    /// Flood rates to measure at, datagrams per second (0: no flood).
    #[arg(long, value_delimiter = ',', default_value = "0,10000")]
    pub rates: Vec<u32>,
    /// STOPPEDs per rate.
    #[arg(long, default_value_t = 20)]
    pub stops: usize,
}

/// `sim-host flood`: the figures of [`measure`] with [`Effect::Acked`], one line per rate.
pub fn run(options: &FloodOptions) -> std::io::Result<()> {
    let hosts = Hosts {
        owner: options.owner,
        stranger: options.stranger,
        panel: options.panel,
    };
    println!(
        "e-stop under a flood at {} ({} single STOPPEDs from {} per rate, never resent; send -> its ACK, then STATUS STOPPED):",
        options.controller, options.stops, options.panel
    );
    for &rate in &options.rates {
        let f = measure(
            options.controller,
            hosts,
            Effect::Acked,
            options.stops,
            rate,
            None::<fn() -> u32>,
        )?;
        println!("  {}", f.line(rate));
        let counters = crate::rx_counters::read(options.controller, options.panel);
        println!("    {}", crate::rx_counters::line(counters));
    }
    Ok(())
}

impl FloodFigures {
    /// One line of figures for a flood of `flood_hz` (0: idle).
    pub fn line(&self, flood_hz: u32) -> String {
        let label = if flood_hz == 0 {
            "idle".to_string()
        } else {
            format!("flood {:.0}/s", self.flood_rate_hz)
        };
        format!(
            "{label:<14} p50 {:>6.2} ms  p90 {:>6.2} ms  max {:>6.2} ms  lost {} of {}{}   owner STATUS p50 {:.2} ms max {:.2} ms   shed {}",
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
            self.status_ms(0.5),
            self.status_ms(1.0),
            self.shed
                .map_or("n/a (not readable from outside)".to_string(), |n| n
                    .to_string())
        )
    }
}
