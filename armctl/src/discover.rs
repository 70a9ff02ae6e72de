//! Finding controllers: DISCOVER to a broadcast address (every controller on the segment
//! answers) or to one address, and the DISCOVER_REPLYs that come back (PROTOCOL.md,
//! "Finding controllers and setting their address").
//!
//! Discovery changes nothing on a controller (no owner is taken), so it may be run from any
//! host at any time. Broadcasts leave the host: in tests, run it only inside a network
//! namespace of the test's own.

use std::net::{SocketAddr, SocketAddrV4, UdpSocket};
use std::time::{Duration, Instant};

use protocol::{Ack, Command, DiscoverReply, MAX_DATAGRAM, Report, StatusCode, Tag};

/// One controller that answered.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Found {
    /// Where the answer came from: the controller's address in use and its port.
    pub from: SocketAddrV4,
    /// What it said; `None` for a controller older than DISCOVER (it answered with an ACK
    /// `UNKNOWN_TAG` or `NOT_OWNER`: it is there, but cannot tell more).
    pub reply: Option<DiscoverReply>,
}

/// How to look.
#[derive(Clone, Debug)]
pub struct DiscoverOptions {
    /// Where DISCOVER goes: a broadcast address (`255.255.255.255:8510`, or the subnet's)
    /// or one controller.
    pub target: SocketAddrV4,
    /// Local address to send from (default any address, a port chosen by the system).
    pub bind: Option<SocketAddrV4>,
    /// How long to collect answers after each DISCOVER.
    pub wait: Duration,
    /// DISCOVERs sent (each with a new seq), in case one or an answer is lost.
    pub rounds: u32,
}

impl Default for DiscoverOptions {
    fn default() -> Self {
        DiscoverOptions {
            target: SocketAddrV4::new([255, 255, 255, 255].into(), protocol::PORT),
            bind: None,
            wait: Duration::from_millis(300),
            rounds: 2,
        }
    }
}

/// Sends DISCOVER `options.rounds` times and returns every controller that answered, once
/// each, in order of first answer. Bounded: at most `rounds` datagrams, `rounds * wait`.
pub fn discover(options: &DiscoverOptions) -> std::io::Result<Vec<Found>> {
    let bind = options
        .bind
        .unwrap_or_else(|| SocketAddrV4::new([0, 0, 0, 0].into(), 0));
    let socket = UdpSocket::bind(bind)?;
    socket.set_broadcast(true)?;
    let first_seq = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.subsec_nanos() as u8);
    let mut found: Vec<Found> = Vec::new();
    let mut buf = [0u8; MAX_DATAGRAM];
    for round in 0..options.rounds.max(1) {
        let seq = first_seq.wrapping_add(round as u8);
        let mut frame = [0u8; 3];
        let n = Command::Discover
            .encode(seq, &mut frame)
            .map_err(std::io::Error::other)?;
        socket.send_to(&frame[..n], options.target)?;
        let deadline = Instant::now() + options.wait;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                break;
            }
            socket.set_read_timeout(Some(left))?;
            let (len, from) = match socket.recv_from(&mut buf) {
                Ok(r) => r,
                Err(e)
                    if matches!(
                        e.kind(),
                        std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                    ) =>
                {
                    break;
                }
                // An ICMP error from an earlier datagram: keep listening.
                Err(_) => continue,
            };
            let SocketAddr::V4(from) = from else { continue };
            let Some(reply) = answer(&buf[..len]) else {
                continue;
            };
            match found.iter_mut().find(|f| f.from == from) {
                Some(known) => {
                    if known.reply.is_none() {
                        known.reply = reply;
                    }
                }
                None => found.push(Found { from, reply }),
            }
        }
    }
    Ok(found)
}

/// One interface's IPv4 address, as `discover --interface` uses it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct InterfaceV4 {
    /// The interface's address: DISCOVER is sent from it.
    pub address: std::net::Ipv4Addr,
    /// Its network's broadcast address (address | !netmask): DISCOVER goes there.
    pub broadcast: std::net::Ipv4Addr,
}

/// The first IPv4 address of interface `name`; the error lists the interfaces that have
/// one (issue 23: a user on a machine with several networks had no way to choose).
#[cfg(unix)]
pub fn interface_v4(name: &str) -> Result<InterfaceV4, String> {
    let addrs = nix::ifaddrs::getifaddrs().map_err(|e| format!("cannot list interfaces: {e}"))?;
    let mut known: Vec<String> = Vec::new();
    for ifa in addrs {
        let (Some(address), Some(netmask)) = (
            ifa.address
                .as_ref()
                .and_then(|a| a.as_sockaddr_in())
                .map(|a| a.ip()),
            ifa.netmask
                .as_ref()
                .and_then(|a| a.as_sockaddr_in())
                .map(|a| a.ip()),
        ) else {
            continue;
        };
        if ifa.interface_name == name {
            let broadcast = std::net::Ipv4Addr::from(address.to_bits() | !netmask.to_bits());
            return Ok(InterfaceV4 { address, broadcast });
        }
        known.push(format!("{} ({address})", ifa.interface_name));
    }
    Err(format!(
        "interface {name:?} has no IPv4 address; interfaces with one: {}",
        if known.is_empty() {
            "none".to_string()
        } else {
            known.join(", ")
        }
    ))
}

/// `--interface` needs getifaddrs: Unix only.
#[cfg(not(unix))]
pub fn interface_v4(name: &str) -> Result<InterfaceV4, String> {
    Err(format!(
        "--interface {name}: not on this system; use --bind ADDR:0 and --to BROADCAST:8510"
    ))
}

/// A DISCOVER that could not be sent, said with what to do about it (issue 23: on a
/// machine without a route for the broadcast, the system's "Network is unreachable" was
/// all a user got).
pub fn explain_send_error(e: &std::io::Error, target: SocketAddrV4) -> String {
    let advice = match e.kind() {
        std::io::ErrorKind::NetworkUnreachable | std::io::ErrorKind::HostUnreachable => {
            if target.ip().is_broadcast() {
                " (no route for 255.255.255.255: no interface is up with an IPv4 address and \
                 a route; bring up the interface on the controllers' network, or name it: \
                 --interface eth0 sends from its address to its broadcast address)"
            } else {
                " (no route to that address: check the interface and its address, or \
                 --interface NAME for the one on the controllers' network)"
            }
        }
        std::io::ErrorKind::PermissionDenied if target.ip().is_broadcast() => {
            " (the system refused a broadcast: a firewall rule, or a socket option \
             this system does not allow)"
        }
        _ => "",
    };
    format!("DISCOVER to {target}: {e}{advice}")
}

/// What a datagram says about its sender: `Some(Some(reply))` a DISCOVER_REPLY,
/// `Some(None)` an older controller's ACK to DISCOVER (`UNKNOWN_TAG`, or `NOT_OWNER` when
/// another host owns it: a controller that knows DISCOVER never ACKs an intact one),
/// `None` anything else.
fn answer(datagram: &[u8]) -> Option<Option<DiscoverReply>> {
    if let Ok(frame) = DiscoverReply::decode(datagram) {
        return Some(Some(frame.body));
    }
    match Report::decode(datagram).ok()?.body {
        Report::Ack(Ack {
            acked_tag, status, ..
        }) if acked_tag == Tag::Discover as u8 && status != StatusCode::BadCrc => Some(None),
        _ => None,
    }
}

/// A MAC address as `02:53:49:4d:00:01`.
pub fn mac_string(mac: &[u8; 6]) -> String {
    mac.iter()
        .map(|b| format!("{b:02x}"))
        .collect::<Vec<_>>()
        .join(":")
}

/// Network settings as `192.168.1.30/24 via 192.168.1.1` or `DHCP`.
pub fn net_string(net: &protocol::NetSettings) -> String {
    if net.dhcp {
        return "DHCP".into();
    }
    let [a, b, c, d] = net.ip;
    let mut s = format!("{a}.{b}.{c}.{d}/{}", net.prefix_len);
    if net.gateway != [0; 4] {
        let [a, b, c, d] = net.gateway;
        s.push_str(&format!(" via {a}.{b}.{c}.{d}"));
    }
    s
}

/// Parses `A.B.C.D/P` (the prefix is required).
pub fn parse_cidr(s: &str) -> Result<([u8; 4], u8), String> {
    let (ip, prefix) = s
        .split_once('/')
        .ok_or_else(|| format!("{s}: give the address with its prefix, e.g. 192.168.1.30/24"))?;
    let ip: std::net::Ipv4Addr = ip
        .parse()
        .map_err(|_| format!("{ip}: not an IPv4 address"))?;
    let prefix: u8 = prefix
        .parse()
        .ok()
        .filter(|p| (1..=32).contains(p))
        .ok_or_else(|| format!("{prefix}: the prefix length must be 1..32"))?;
    Ok((ip.octets(), prefix))
}

impl crate::Client {
    /// NET_SET: stores new network settings on the controller (owner only, not while
    /// RUNNING); the controller applies them at its next reset. Invalid settings are
    /// refused here, before anything is sent.
    pub fn net_set(&self, net: protocol::NetSettings) -> crate::Result<Ack> {
        if !net.is_valid() {
            return Err(crate::Error::Io(std::io::Error::new(
                std::io::ErrorKind::InvalidInput,
                format!(
                    "{}: not usable (a unicast address with a prefix of 1..32, a gateway \
                     inside its subnet, or DHCP)",
                    net_string(&net)
                ),
            )));
        }
        self.send(&Command::NetSet(net))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use protocol::{NetSettings, OwnerState, State};

    #[test]
    fn answers_are_recognised() {
        let reply = DiscoverReply {
            mac: [2, 0x53, 0x49, 0x4d, 0, 1],
            net: NetSettings::fixed([10, 0, 0, 2], 24, Some([10, 0, 0, 1])),
            version: [1, 0, 0],
            joints: 6,
            state: State::Stopped,
            owner: OwnerState::Free,
            owner_ip: [0; 4],
            pending_reset: false,
        };
        let mut buf = [0u8; 64];
        let n = reply.encode(7, &mut buf).unwrap();
        assert_eq!(answer(&buf[..n]), Some(Some(reply)));
        let ack = Report::Ack(Ack {
            acked_tag: Tag::Discover as u8,
            status: StatusCode::UnknownTag,
            state: State::Stopped,
            next_seq: 0,
            buffered: 0,
            free: 8192,
        });
        let n = ack.encode(7, &mut buf).unwrap();
        assert_eq!(answer(&buf[..n]), Some(None));
        for (status, old) in [(StatusCode::NotOwner, true), (StatusCode::BadCrc, false)] {
            let ack = Report::Ack(Ack {
                acked_tag: Tag::Discover as u8,
                status,
                state: State::Stopped,
                next_seq: 0,
                buffered: 0,
                free: 8192,
            });
            let n = ack.encode(7, &mut buf).unwrap();
            assert_eq!(answer(&buf[..n]), old.then_some(None), "{status:?}");
        }
        assert_eq!(answer(&[1, 2, 3]), None);
        assert_eq!(mac_string(&reply.mac), "02:53:49:4d:00:01");
        assert_eq!(net_string(&reply.net), "10.0.0.2/24 via 10.0.0.1");
        assert_eq!(net_string(&NetSettings::DHCP), "DHCP");
        assert_eq!(parse_cidr("10.0.0.2/24"), Ok(([10, 0, 0, 2], 24)));
        assert!(parse_cidr("10.0.0.2").is_err());
        assert!(parse_cidr("10.0.0.2/33").is_err());
    }
}

#[cfg(test)]
mod send_error_tests {
    use super::*;

    #[test]
    #[cfg(unix)]
    fn the_loopback_interface_has_its_address_and_broadcast() {
        let lo = interface_v4("lo").unwrap();
        assert_eq!(lo.address, std::net::Ipv4Addr::LOCALHOST);
        assert_eq!(lo.broadcast, std::net::Ipv4Addr::new(127, 255, 255, 255));
        let err = interface_v4("no-such-if0").unwrap_err();
        assert!(
            err.contains("interfaces with one: ") && err.contains("lo (127.0.0.1)"),
            "{err}"
        );
    }

    #[test]
    fn an_unreachable_network_gets_advice() {
        let e = std::io::Error::from(std::io::ErrorKind::NetworkUnreachable);
        let broadcast = SocketAddrV4::new([255, 255, 255, 255].into(), 8510);
        let text = explain_send_error(&e, broadcast);
        assert!(
            text.starts_with("DISCOVER to 255.255.255.255:8510: "),
            "{text}"
        );
        assert!(text.contains("--interface eth0"), "{text}");
        let one = SocketAddrV4::new([10, 0, 0, 7].into(), 8510);
        assert!(explain_send_error(&e, one).contains("no route to that address"));
        let other = std::io::Error::other("boom");
        assert_eq!(
            explain_send_error(&other, one),
            "DISCOVER to 10.0.0.7:8510: boom"
        );
    }
}
