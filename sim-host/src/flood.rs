//! A STOPPED from a third host while a stranger floods the controller (issue 18): the
//! measurement behind `sim-host bench`'s "e-stop under a flood" lines and the flood test
//! (`sim-host/tests/flood.rs`).
//!
//! Three hosts on loopback, each its own address: the owner (127.0.0.1, an armctl
//! [`Client`]) runs a 6-joint trajectory and polls STATUS; a stranger (127.0.0.2) sends
//! `flood_hz` datagrams a second, valid STATUS frames and garbage (bad CRCs, unknown tags)
//! mixed; a panel (127.0.0.3) sends one STOPPED per run, never resent. For each STOPPED
//! the figure is the time from its send to the simulated step engine going idle
//! ([`Probe::last_engine_stop`]); one that has not stopped the engine 1 s later is lost.
//! Every loop that sends is bounded in count and time, and everything stays on loopback.

use std::net::{SocketAddr, UdpSocket};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use armctl::{Client, RunOptions};
use protocol::{MAX_JOINTS, Point, Tag, crc8};

use crate::probe::Probe;

/// The stranger's address.
pub const STRANGER_IP: [u8; 4] = [127, 0, 0, 2];
/// The panel's address.
pub const PANEL_IP: [u8; 4] = [127, 0, 0, 3];
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
    /// The owner's STATUS round trips during the runs (armctl's, resends included).
    pub status_round_trips: Vec<Duration>,
    /// Datagrams the controller's receive path shed (over their sender's share).
    pub shed: u32,
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
fn flood(to: SocketAddr, rate_hz: u32, stop: &AtomicBool, sent: &AtomicU64) -> std::io::Result<()> {
    let socket = UdpSocket::bind((std::net::Ipv4Addr::from(STRANGER_IP), 0))?;
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

/// A 6-joint run of 300 points of 10 ms (3 s; 2..7 kHz per joint) from zero.
fn long_run() -> Vec<Point> {
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
/// stranger flooding at `flood_hz` (0: no flood). `shed` reads the controller's count of
/// shed datagrams.
pub fn estop_under_flood(
    addr: SocketAddr,
    probe: &Probe,
    stops: usize,
    flood_hz: u32,
    shed: impl Fn() -> u32,
) -> std::io::Result<FloodFigures> {
    let to_io = |e: armctl::Error| std::io::Error::other(e.to_string());
    let owner = Client::connect(addr).map_err(to_io)?;
    owner.set_joints(6).map_err(to_io)?;
    let panel = UdpSocket::bind((std::net::Ipv4Addr::from(PANEL_IP), 0))?;
    let stop_flood = Arc::new(AtomicBool::new(false));
    let flood_sent = Arc::new(AtomicU64::new(0));
    let flooder = (flood_hz > 0).then(|| {
        let stop = stop_flood.clone();
        let sent = flood_sent.clone();
        std::thread::spawn(move || flood(addr, flood_hz, &stop, &sent))
    });
    let shed_before = shed();
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
            let sent = Instant::now();
            panel.send_to(&stop, addr)?;
            let stopped = loop {
                match probe.last_engine_stop() {
                    Some(at) if at >= sent => break Some(at),
                    _ if sent.elapsed() > LOST_AFTER => break None,
                    _ => std::thread::sleep(Duration::from_micros(200)),
                }
            };
            match stopped {
                Some(at) => figures.effect.push(at - sent),
                None => {
                    figures.lost += 1;
                    log::warn!("flood: the STOPPED of round {round} was lost");
                    owner.stop().map_err(to_io)?;
                }
            }
            let polled = Instant::now();
            let status = owner.status().map_err(to_io)?;
            figures.status_round_trips.push(polled.elapsed());
            if status.state != protocol::State::Stopped {
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
    figures.shed = shed().wrapping_sub(shed_before);
    Ok(figures)
}
