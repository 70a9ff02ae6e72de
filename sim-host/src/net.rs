//! The controller's UDP socket on a PC: a std socket (`--bind`), or embassy-net on a TAP
//! device (`--tap`, see [`crate::tap`]); either behind [`Faulty`], the fault injector.

use std::collections::VecDeque;
use std::net::{SocketAddr, SocketAddrV4, UdpSocket};
use std::sync::{Arc, Mutex};
use std::time::Instant;

use arm_core::hw::{Datagrams, Endpoint};
use arm_core::ingress::Ingress;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::channel::Channel;
use protocol::MAX_DATAGRAM;

use crate::faults::{Direction, FaultConfig, FaultInjector, FaultStats};
use crate::probe::Probe;

/// Datagrams received and not yet taken by the network task: a host's whole window
/// ([`arm_core::config::HOST_WINDOW`] = 32) plus 8 for other tools' commands, as the
/// board's Ethernet ring. The receiving thread never waits for room (issue 18): beyond
/// this a datagram is shed (counted, logged once a second), so the thread keeps reading
/// the socket and a STOPPED behind a flood is seen as soon as it arrives.
const RX_QUEUE: usize = arm_core::bus::INBOX_QUEUE;

/// Receive buffer asked of the kernel: 4 MiB, the time the receiving thread (the board's
/// receive interrupt, which silicon never deschedules) may lose to other work on a loaded
/// PC before the kernel drops a datagram silently. The kernel charges about 768 B for a
/// small datagram and 2.3 KiB for a full one on loopback, and doubles the size asked:
/// 8 MiB holds ~10,000 small datagrams, 200 ms of a 50,000/s flood (issue 19: with 320 KiB,
/// ~17 ms, two busy loops per core made the kernel drop 1-4 of 20 STOPPEDs in such a
/// flood). Linux caps it at `net.core.rmem_max` (often 208 KiB; `.ci/run`'s machines
/// 4 MiB); root may go past it (SO_RCVBUFFORCE, tried first).
const SOCKET_RX_BYTES: usize = 4 << 20;

/// A received datagram.
#[derive(Clone, Debug)]
pub struct Received {
    /// Its bytes (at most [`MAX_DATAGRAM`]; longer ones are cut, so their CRC fails).
    pub bytes: Vec<u8>,
    /// Sender.
    pub from: Endpoint,
}

/// What the receiving thread does with each datagram before it queues it: the
/// controller's first look ([`arm_core::Bus::receive_first`]: a STOPPED halts the steps
/// there and goes to the e-stop queue; anything else sent to a broadcast or multicast
/// address (the `bool`) but DISCOVER is ignored; others are admitted or shed by their
/// sender's share).
pub type FirstLook = Box<dyn Fn(Endpoint, &[u8], bool) -> Ingress + Send>;

/// [`Datagrams`] over a std UDP socket. A thread does the blocking receive, gives each
/// datagram its first look ([`FirstLook`]) and hands those admitted to the executor
/// through a channel; sends go straight to the socket (a UDP send to a local address does
/// not block).
pub struct UdpDatagrams {
    socket: UdpSocket,
    received: Channel<CriticalSectionRawMutex, Received, RX_QUEUE>,
    /// Admitted datagrams shed because `received` was full.
    queue_full: std::sync::atomic::AtomicU32,
}

impl std::fmt::Debug for UdpDatagrams {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("UdpDatagrams")
            .field("local", &self.socket.local_addr().ok())
            .finish()
    }
}

impl UdpDatagrams {
    /// Binds `addr`; [`UdpDatagrams::start`] starts the receiving thread (until then the
    /// kernel holds what arrives).
    pub fn bind(addr: SocketAddrV4) -> std::io::Result<&'static UdpDatagrams> {
        let socket = UdpSocket::bind(addr)?;
        set_receive_buffer(&socket, SOCKET_RX_BYTES);
        // Each datagram's destination address comes with it (recv_with_destination).
        nix::sys::socket::setsockopt(&socket, nix::sys::socket::sockopt::Ipv4PacketInfo, &true)
            .map_err(std::io::Error::from)?;
        Ok(Box::leak(Box::new(UdpDatagrams {
            socket,
            received: Channel::new(),
            queue_full: std::sync::atomic::AtomicU32::new(0),
        })))
    }

    /// Starts the receiving thread, which gives every datagram `first_look` as it reads it.
    /// A datagram it admits but cannot queue is shed, its slot of the sender's share given
    /// back to `bus`.
    pub fn start(
        &'static self,
        probe: Arc<Probe>,
        bus: &'static arm_core::Bus,
        first_look: FirstLook,
    ) -> std::io::Result<()> {
        std::thread::Builder::new()
            .name("udp-rx".into())
            .spawn(move || {
                // The board's receive interrupt: a STOPPED under a flood must be read
                // before the socket's buffer overflows (issue 19: with two busy loops per
                // core and the thread at normal priority, 2 of 20 were dropped by the
                // kernel under a 50,000/s flood).
                crate::steptimer::raise_nice("udp-rx", crate::steptimer::INTERRUPT_NICE);
                self.receive_loop(&probe, bus, &first_look)
            })?;
        Ok(())
    }

    /// Admitted datagrams shed so far because the network task's queue was full.
    pub fn queue_full(&self) -> u32 {
        self.queue_full.load(std::sync::atomic::Ordering::Relaxed)
    }

    /// The bound address (the port, when bound to port 0).
    pub fn local_addr(&self) -> std::io::Result<SocketAddr> {
        self.socket.local_addr()
    }

    fn receive_loop(&self, probe: &Probe, bus: &arm_core::Bus, first_look: &FirstLook) {
        // Bigger than any valid frame, so an oversized datagram is seen (and cut), not lost.
        let mut buf = vec![0u8; 2048];
        let mut failures = arm_core::LogLimit::new();
        let mut full = arm_core::LogLimit::new();
        loop {
            let (len, from, to_group) = match recv_with_destination(&self.socket, &mut buf) {
                Ok(r) => r,
                Err(e) => {
                    if let arm_core::LogVerdict::Log { suppressed } =
                        failures.event(crate::simnet::log_time_us())
                    {
                        log::warn!(
                            "udp: receive failed: {e} ({suppressed} more since the last such line)"
                        );
                    }
                    std::thread::sleep(std::time::Duration::from_millis(10));
                    continue;
                }
            };
            let SocketAddr::V4(from) = from else { continue };
            let bytes = &buf[..len.min(MAX_DATAGRAM)];
            probe.datagram_received(bytes, Instant::now());
            let from = endpoint_of(from);
            if first_look(from, bytes, to_group) != Ingress::Admit {
                continue;
            }
            let received = Received {
                bytes: bytes.to_vec(),
                from,
            };
            if self.received.try_send(received).is_err() {
                bus.release(from.ip);
                self.queue_full
                    .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                if let arm_core::LogVerdict::Log { suppressed } =
                    full.event(crate::simnet::log_time_us())
                {
                    log::warn!(
                        "udp: receive queue full, a datagram was shed ({suppressed} more since the last such line)"
                    );
                }
            }
        }
    }
}

/// Asks the kernel for a receive buffer of `bytes` (it may grant less: logged).
fn set_receive_buffer(socket: &UdpSocket, bytes: usize) {
    use nix::sys::socket::{getsockopt, setsockopt, sockopt::RcvBuf, sockopt::RcvBufForce};
    let set =
        setsockopt(socket, RcvBufForce, &bytes).or_else(|_| setsockopt(socket, RcvBuf, &bytes));
    match set.and_then(|()| getsockopt(socket, RcvBuf)) {
        Ok(granted) => log::debug!("udp: receive buffer {granted} bytes (asked {bytes})"),
        Err(e) => log::warn!("udp: cannot size the receive buffer: {e}"),
    }
}

/// Receives one datagram (blocking): its length, its sender, and whether it was sent to a
/// broadcast or multicast address. The socket has IP_PKTINFO on: the header's destination
/// (`ipi_addr`) is then compared with the local address it reached (`ipi_spec_dst`): they
/// differ for a broadcast (255.255.255.255 or a subnet's), and a multicast destination is
/// 224/4 (issue 21 F7; the boards see the destination MAC's group bit instead).
pub fn recv_with_destination(
    socket: &UdpSocket,
    buf: &mut [u8],
) -> std::io::Result<(usize, SocketAddr, bool)> {
    use std::os::fd::AsRawFd;

    use nix::sys::socket::{ControlMessageOwned, MsgFlags, SockaddrIn, recvmsg};
    let mut iov = [std::io::IoSliceMut::new(buf)];
    let mut space = nix::cmsg_space!(libc::in_pktinfo);
    let msg = recvmsg::<SockaddrIn>(
        socket.as_raw_fd(),
        &mut iov,
        Some(&mut space),
        MsgFlags::empty(),
    )
    .map_err(std::io::Error::from)?;
    let mut to_group = false;
    for cmsg in msg.cmsgs().map_err(std::io::Error::from)? {
        if let ControlMessageOwned::Ipv4PacketInfo(info) = cmsg {
            let to = u32::from_be(info.ipi_addr.s_addr);
            let local = u32::from_be(info.ipi_spec_dst.s_addr);
            to_group = to >> 28 == 0xE || to != local;
        }
    }
    let from = msg
        .address
        .map(|a| SocketAddr::V4(SocketAddrV4::new(a.ip(), a.port())))
        .ok_or_else(|| std::io::Error::other("a datagram without a sender address"))?;
    Ok((msg.bytes, from, to_group))
}

/// The [`Endpoint`] of a std address.
pub fn endpoint_of(addr: SocketAddrV4) -> Endpoint {
    Endpoint {
        ip: addr.ip().octets(),
        port: addr.port(),
    }
}

/// The std address of an [`Endpoint`].
pub fn socket_addr_of(endpoint: Endpoint) -> SocketAddrV4 {
    SocketAddrV4::new(endpoint.ip.into(), endpoint.port)
}

impl Datagrams for UdpDatagrams {
    type Error = std::io::ErrorKind;

    async fn recv(&self, buf: &mut [u8]) -> Result<(usize, Endpoint), Self::Error> {
        let received = self.received.receive().await;
        let n = received.bytes.len().min(buf.len());
        buf[..n].copy_from_slice(&received.bytes[..n]);
        Ok((n, received.from))
    }

    async fn send(&self, to: Endpoint, frame: &[u8]) -> Result<(), Self::Error> {
        self.socket
            .send_to(frame, socket_addr_of(to))
            .map(|_| ())
            .map_err(|e| e.kind())
    }
}

/// A datagram on its way through the fault injector.
type Travelling = (Vec<u8>, Endpoint);

/// [`Datagrams`] wrapper that loses, duplicates and reorders datagrams in both directions
/// (`--loss`, `--dup`, `--reorder`, `--seed`). With no fault configured it only forwards.
pub struct Faulty<D> {
    inner: D,
    faults: Mutex<FaultInjector<Travelling>>,
    /// Received datagrams already through the faults, waiting for `recv`.
    ready: Mutex<VecDeque<Travelling>>,
    enabled: bool,
}

impl<D> std::fmt::Debug for Faulty<D> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Faulty")
            .field("enabled", &self.enabled)
            .finish()
    }
}

impl<D> Faulty<D> {
    /// `inner` with `config`'s faults.
    pub fn new(inner: D, config: FaultConfig) -> Self {
        Faulty {
            inner,
            faults: Mutex::new(FaultInjector::new(config)),
            ready: Mutex::new(VecDeque::new()),
            enabled: config.is_active(),
        }
    }

    /// What the faults did so far.
    pub fn stats(&self) -> FaultStats {
        self.faults.lock().map(|f| f.stats()).unwrap_or_default()
    }
}

fn stream_tag(bytes: &[u8]) -> u8 {
    bytes.get(1).copied().unwrap_or(0xFF)
}

impl<D: Datagrams> Datagrams for Faulty<D> {
    type Error = D::Error;

    async fn recv(&self, buf: &mut [u8]) -> Result<(usize, Endpoint), Self::Error> {
        if !self.enabled {
            return self.inner.recv(buf).await;
        }
        loop {
            if let Some((bytes, from)) = self.ready.lock().ok().and_then(|mut r| r.pop_front()) {
                let n = bytes.len().min(buf.len());
                buf[..n].copy_from_slice(&bytes[..n]);
                return Ok((n, from));
            }
            let (n, from) = self.inner.recv(buf).await?;
            let bytes = buf[..n].to_vec();
            let tag = stream_tag(&bytes);
            if let (Ok(mut faults), Ok(mut ready)) = (self.faults.lock(), self.ready.lock()) {
                let fate = faults.apply(Direction::Received, tag, (bytes, from), |d| {
                    ready.push_back(d)
                });
                log::trace!("faults: received tag {tag:#04x}: {fate:?}");
            }
        }
    }

    async fn send(&self, to: Endpoint, frame: &[u8]) -> Result<(), Self::Error> {
        if !self.enabled {
            return self.inner.send(to, frame).await;
        }
        let mut outgoing = Vec::new();
        if let Ok(mut faults) = self.faults.lock() {
            let tag = stream_tag(frame);
            let fate = faults.apply(Direction::Sent, tag, (frame.to_vec(), to), |d| {
                outgoing.push(d)
            });
            log::trace!("faults: sent tag {tag:#04x}: {fate:?}");
        }
        for (bytes, to) in outgoing {
            self.inner.send(to, &bytes).await?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod destination_tests {
    use std::net::{SocketAddrV4, UdpSocket};

    use super::recv_with_destination;

    /// A unicast datagram is not a group's; its sender and bytes come through. (Broadcast
    /// runs only inside a network namespace: sim-host/tests/discover.sh sends one there.)
    #[test]
    fn a_unicast_datagram_is_not_sent_to_a_group() {
        let rx = UdpSocket::bind(SocketAddrV4::new([127, 0, 0, 1].into(), 0)).unwrap();
        nix::sys::socket::setsockopt(&rx, nix::sys::socket::sockopt::Ipv4PacketInfo, &true)
            .unwrap();
        let tx = UdpSocket::bind(SocketAddrV4::new([127, 0, 0, 1].into(), 0)).unwrap();
        tx.send_to(b"abc", rx.local_addr().unwrap()).unwrap();
        let mut buf = [0u8; 16];
        let (n, from, to_group) = recv_with_destination(&rx, &mut buf).unwrap();
        assert_eq!(
            (&buf[..n], from, to_group),
            (&b"abc"[..], tx.local_addr().unwrap(), false)
        );
    }
}
