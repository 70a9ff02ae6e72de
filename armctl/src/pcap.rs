//! Writing the datagrams a tool sends and receives as a pcap file (`--pcap FILE`), so that
//! a session can be opened in Wireshark (with `tools/wireshark/arm_controller.lua`) without
//! capture rights.
//!
//! Each datagram is stored as a raw IPv4 packet (link type 228): a 20-byte IPv4 header and
//! an 8-byte UDP header (checksum 0, "none", as IPv4 allows) around the payload, with the
//! addresses and ports it really had. Every packet is written through to the file at once,
//! so a process that is killed leaves a readable capture.

use std::fs::File;
use std::io;
use std::net::{Ipv4Addr, SocketAddr, SocketAddrV4};
use std::path::Path;
use std::sync::Mutex;
use std::time::{SystemTime, UNIX_EPOCH};

use pcap_file::DataLink;
use pcap_file::pcap::{PcapHeader, PcapPacket, PcapWriter};

/// IPv4 header without options.
const IPV4_HEADER: usize = 20;
/// UDP header.
const UDP_HEADER: usize = 8;
/// Largest UDP payload an IPv4 packet can carry.
const MAX_PAYLOAD: usize = u16::MAX as usize - IPV4_HEADER - UDP_HEADER;

/// A pcap file that datagrams are appended to; shareable between threads.
pub struct PcapLog {
    writer: Mutex<PcapWriter<File>>,
    /// IPv4 identification field, one more per packet.
    ident: Mutex<u16>,
}

impl std::fmt::Debug for PcapLog {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PcapLog").finish_non_exhaustive()
    }
}

impl PcapLog {
    /// Creates (or truncates) `path` and writes the pcap header.
    pub fn create(path: &Path) -> io::Result<PcapLog> {
        let file = File::create(path)?;
        let header = PcapHeader {
            datalink: DataLink::IPV4,
            ..PcapHeader::default()
        };
        let writer = PcapWriter::with_header(file, header).map_err(io::Error::other)?;
        Ok(PcapLog {
            writer: Mutex::new(writer),
            ident: Mutex::new(0),
        })
    }

    /// Appends one datagram from `from` to `to`, stamped now. IPv6 addresses (the protocol
    /// is IPv4 only) are written as 0.0.0.0.
    pub fn record(&self, from: SocketAddr, to: SocketAddr, payload: &[u8]) -> io::Result<()> {
        let timestamp = SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .unwrap_or_default();
        let ident = {
            let mut ident = self.ident.lock().unwrap_or_else(|e| e.into_inner());
            *ident = ident.wrapping_add(1);
            *ident
        };
        let packet = ipv4_udp(v4(from), v4(to), ident, payload);
        let mut writer = self.writer.lock().unwrap_or_else(|e| e.into_inner());
        writer
            .write_packet(&PcapPacket::new(timestamp, packet.len() as u32, &packet))
            .map(|_| ())
            .map_err(io::Error::other)
    }
}

fn v4(addr: SocketAddr) -> SocketAddrV4 {
    match addr {
        SocketAddr::V4(a) => a,
        SocketAddr::V6(a) => SocketAddrV4::new(
            a.ip().to_ipv4_mapped().unwrap_or(Ipv4Addr::UNSPECIFIED),
            a.port(),
        ),
    }
}

/// An IPv4 packet holding a UDP datagram (payloads beyond 65507 bytes are cut).
pub fn ipv4_udp(from: SocketAddrV4, to: SocketAddrV4, ident: u16, payload: &[u8]) -> Vec<u8> {
    let payload = &payload[..payload.len().min(MAX_PAYLOAD)];
    let udp_len = (UDP_HEADER + payload.len()) as u16;
    let total = IPV4_HEADER as u16 + udp_len;
    let mut p = Vec::with_capacity(usize::from(total));
    p.extend_from_slice(&[0x45, 0]); // version 4, 5 words; DSCP 0
    p.extend_from_slice(&total.to_be_bytes());
    p.extend_from_slice(&ident.to_be_bytes());
    p.extend_from_slice(&[0x40, 0]); // don't fragment
    p.extend_from_slice(&[64, 17]); // TTL, protocol UDP
    p.extend_from_slice(&[0, 0]); // checksum, below
    p.extend_from_slice(&from.ip().octets());
    p.extend_from_slice(&to.ip().octets());
    let checksum = ipv4_checksum(&p);
    p[10..12].copy_from_slice(&checksum.to_be_bytes());
    p.extend_from_slice(&from.port().to_be_bytes());
    p.extend_from_slice(&to.port().to_be_bytes());
    p.extend_from_slice(&udp_len.to_be_bytes());
    p.extend_from_slice(&[0, 0]); // no UDP checksum
    p.extend_from_slice(payload);
    p
}

/// The one's-complement sum of the header's 16-bit words, complemented.
fn ipv4_checksum(header: &[u8]) -> u16 {
    let mut sum: u32 = header
        .chunks(2)
        .map(|w| u32::from(u16::from_be_bytes([w[0], *w.get(1).unwrap_or(&0)])))
        .sum();
    while sum > 0xFFFF {
        sum = (sum & 0xFFFF) + (sum >> 16);
    }
    !(sum as u16)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn header_checksum_verifies() {
        let p = ipv4_udp(
            "127.0.0.1:40000".parse().unwrap(),
            "127.0.0.1:8510".parse().unwrap(),
            7,
            &[1, 0x15, 0x2e],
        );
        assert_eq!(p.len(), 20 + 8 + 3);
        // A correct header sums to 0xFFFF, i.e. its checksum over itself is 0.
        assert_eq!(ipv4_checksum(&p[..20]), 0);
        assert_eq!(&p[20..24], &[0x9c, 0x40, 0x21, 0x3e]);
        assert_eq!(u16::from_be_bytes([p[24], p[25]]), 11);
    }

    #[test]
    fn capture_reads_back() {
        let dir = std::env::temp_dir().join(format!("armctl-pcap-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("t.pcap");
        let log = PcapLog::create(&path).unwrap();
        let host: SocketAddr = "127.0.0.1:40000".parse().unwrap();
        let arm: SocketAddr = "127.0.0.1:8510".parse().unwrap();
        log.record(host, arm, &[1, 0x15, 0x2e]).unwrap();
        log.record(arm, host, &[0; 11]).unwrap();
        drop(log);
        let bytes = std::fs::read(&path).unwrap();
        let mut reader = pcap_file::pcap::PcapReader::new(&bytes[..]).unwrap();
        assert_eq!(reader.header().datalink, DataLink::IPV4);
        let first = reader.next_packet().unwrap().unwrap();
        assert_eq!(&first.data[28..], &[1, 0x15, 0x2e]);
        let second = reader.next_packet().unwrap().unwrap();
        assert_eq!(second.data.len(), 28 + 11);
        assert!(reader.next_packet().is_none());
        let _ = std::fs::remove_dir_all(&dir);
    }
}
