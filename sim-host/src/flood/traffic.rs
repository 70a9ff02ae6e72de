//! The traffic of a flood measurement ([`super`]): the strangers' senders, the owner's
//! 10 Hz poller, and the kernel's count of drops at the controller's socket.

use std::net::{SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use protocol::{Tag, crc8};

use super::{FLOOD_LIMIT, FLOOD_MAX_DATAGRAMS, LOST_AFTER, POLL_PERIOD};

/// One stranger datagram, the `n`th: a valid STATUS, or (unless `valid_only`) for three
/// in four, garbage.
fn stranger_frame(n: u64, valid_only: bool, junk: &mut u64) -> Vec<u8> {
    let seq = n as u8;
    if valid_only || n.is_multiple_of(4) {
        let body = [seq, Tag::Status as u8];
        return vec![body[0], body[1], crc8(&body)];
    }
    *junk ^= *junk << 13;
    *junk ^= *junk >> 7;
    *junk ^= *junk << 17;
    let len = 3 + (*junk % 60) as usize;
    let mut f: Vec<u8> = (0..len).map(|i| (*junk >> (i % 8 * 8)) as u8).collect();
    // Never a STOPPED (the strangers flood, the panel stops) and never a valid CRC.
    if f[1] == Tag::Stopped as u8 {
        f[1] = 0x7f;
    }
    let last = f.len() - 1;
    f[last] = crc8(&f[..last]) ^ 0x5a;
    f
}

/// Strangers sending from `sockets` in turn to `to` until `stop`: `rate_hz` datagrams a
/// second in 1 ms batches, or (`None`) as fast as the sockets send; counts them in `sent`.
/// Their own answers are read and dropped.
pub(super) fn send_flood(
    sockets: &[UdpSocket],
    to: SocketAddr,
    rate_hz: Option<u32>,
    valid_only: bool,
    stop: &AtomicBool,
    sent: &AtomicU64,
) {
    let started = Instant::now();
    let mut next = started;
    let mut n: u64 = 0;
    let mut junk = 0x9E37_79B9_7F4A_7C15u64;
    let mut buf = [0u8; 2048];
    // Unthrottled, frames are made once: the senders' time goes to sending.
    let statuses: Vec<Vec<u8>> = (0..=255u64)
        .map(|n| stranger_frame(n, true, &mut junk))
        .collect();
    while !stop.load(Ordering::Relaxed)
        && started.elapsed() < FLOOD_LIMIT
        && n < FLOOD_MAX_DATAGRAMS
    {
        next += Duration::from_millis(1);
        let due = match rate_hz {
            Some(rate) => {
                u64::from(rate) * next.duration_since(started).as_micros() as u64 / 1_000_000
            }
            None => n + 256,
        };
        let batch_start = n;
        while n < due {
            let socket = &sockets[n as usize % sockets.len()];
            let _ = match rate_hz {
                None if valid_only => socket.send_to(&statuses[n as usize % 256], to),
                _ => socket.send_to(&stranger_frame(n, valid_only, &mut junk), to),
            };
            n += 1;
        }
        sent.fetch_add(n - batch_start, Ordering::Relaxed);
        for socket in sockets {
            while socket.recv_from(&mut buf).is_ok() {}
        }
        if rate_hz.is_some()
            && let Some(wait) = next.checked_duration_since(Instant::now())
        {
            std::thread::sleep(wait);
        }
    }
}

/// The owner's second tool: from `owner`'s address, a STATUS every [`POLL_PERIOD`] to `to`
/// until `stop`, each sent once; returns each poll's round trip to its ACK (`None`: none
/// within [`LOST_AFTER`]).
pub(super) fn poll_status(
    owner: std::net::Ipv4Addr,
    to: SocketAddr,
    stop: &AtomicBool,
) -> std::io::Result<Vec<Option<Duration>>> {
    let socket = UdpSocket::bind((owner, 0))?;
    socket.set_read_timeout(Some(Duration::from_millis(5)))?;
    let started = Instant::now();
    // Each poll's send time and its round trip.
    let mut polls: Vec<(Instant, Option<Duration>)> = Vec::new();
    let mut next = started;
    let mut stopped_at: Option<Instant> = None;
    let mut reply = [0u8; 2048];
    loop {
        let now = Instant::now();
        if stopped_at.is_none() && (stop.load(Ordering::Relaxed) || started.elapsed() > FLOOD_LIMIT)
        {
            stopped_at = Some(now);
        }
        match stopped_at {
            // The last polls get their 1 s too.
            Some(at) if now - at > LOST_AFTER => break,
            Some(_) => {}
            None if now >= next => {
                let seq = polls.len() as u8;
                let body = [seq, Tag::Status as u8];
                socket.send_to(&[body[0], body[1], crc8(&body)], to)?;
                polls.push((Instant::now(), None));
                next += POLL_PERIOD;
            }
            None => {}
        }
        // ACK (tag 0x14) of a STATUS: the newest unanswered poll with its seq.
        if let Ok((n, _)) = socket.recv_from(&mut reply)
            && n >= 4
            && reply[1] == Tag::Ack as u8
            && reply[2] == Tag::Status as u8
        {
            let at = Instant::now();
            if let Some(poll) = polls
                .iter_mut()
                .enumerate()
                .rev()
                .find(|(i, p)| *i as u8 == reply[0] && p.1.is_none())
                .map(|(_, p)| p)
            {
                let round_trip = at - poll.0;
                poll.1 = (round_trip <= LOST_AFTER).then_some(round_trip);
            }
        }
    }
    Ok(polls.into_iter().map(|(_, rtt)| rtt).collect())
}

/// The kernel's count of datagrams dropped at the UDP socket bound to `addr` on this
/// machine (the last field of its /proc/net/udp line), if there is one.
pub(super) fn kernel_drops(addr: SocketAddr) -> Option<u64> {
    let SocketAddr::V4(addr) = addr else {
        return None;
    };
    // The local address as /proc shows it: the IP's bytes as a little-endian hex word.
    let local = format!(
        "{:08X}:{:04X}",
        u32::from_le_bytes(addr.ip().octets()),
        addr.port()
    );
    let table = std::fs::read_to_string("/proc/net/udp").ok()?;
    table
        .lines()
        .find(|line| line.split_whitespace().nth(1) == Some(local.as_str()))
        .and_then(|line| line.split_whitespace().last()?.parse().ok())
}
