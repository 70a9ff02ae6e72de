//! Finding controllers and setting their address (PROTOCOL.md, the section of that name):
//! DISCOVER (0x20)
//! and its answer DISCOVER_REPLY (0x22), and NET_SET (0x21).
//!
//! DISCOVER travels as a [`crate::Command`] like any other command; DISCOVER_REPLY is
//! decoded and encoded here rather than as a [`crate::Report`] variant: it answers only
//! the host that asked (as an ACK does), and hosts that never ask never see one.

use crate::codec::{Writer, u8_at};
use crate::codes::{State, Tag};
use crate::error::{DecodeError, DecodeErrorKind, EncodeError, ExpectedLen, Field};
use crate::frame::{Frame, crc8, seal};
use crate::size;

/// How the controller gets its IPv4 address (NET_SET's data, 10 bytes).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct NetSettings {
    /// From a DHCP server (then `ip`, `prefix_len` and `gateway` are all zero).
    pub dhcp: bool,
    /// Static address.
    pub ip: [u8; 4],
    /// Prefix length of its subnet, 1..=32.
    pub prefix_len: u8,
    /// Default gateway; 0.0.0.0 for none.
    pub gateway: [u8; 4],
}

impl NetSettings {
    /// A static address with an optional gateway.
    pub const fn fixed(ip: [u8; 4], prefix_len: u8, gateway: Option<[u8; 4]>) -> NetSettings {
        NetSettings {
            dhcp: false,
            ip,
            prefix_len,
            gateway: match gateway {
                Some(g) => g,
                None => [0; 4],
            },
        }
    }

    /// An address from DHCP.
    pub const DHCP: NetSettings = NetSettings {
        dhcp: true,
        ip: [0; 4],
        prefix_len: 0,
        gateway: [0; 4],
    };

    /// Whether a controller can use these settings: DHCP with every other field zero, or
    /// a unicast address (not in 0/8 "this network", loopback, multicast, 240/4 reserved
    /// or broadcast, nor the subnet's own network or broadcast address, for prefixes up to
    /// /30) with a prefix of 1..32 and a gateway that is 0.0.0.0 or another host address
    /// inside the subnet (not its network or broadcast address).
    pub fn is_valid(&self) -> bool {
        if self.dhcp {
            return self.ip == [0; 4] && self.prefix_len == 0 && self.gateway == [0; 4];
        }
        if !(1..=32).contains(&self.prefix_len) {
            return false;
        }
        let ip = u32::from_be_bytes(self.ip);
        let [first, ..] = self.ip;
        // 0/8, 127/8, 224/4 (multicast) and 240/4 (reserved, and the broadcast address).
        if first == 0 || first == 127 || first >= 224 {
            return false;
        }
        let mask = u32::MAX << (32 - u32::from(self.prefix_len));
        // The subnet's network and broadcast addresses are no host's (up to /30: /31 and
        // /32 subnets have none).
        let is_host = |a: u32| self.prefix_len > 30 || (a & !mask != 0 && a & !mask != !mask);
        if !is_host(ip) {
            return false;
        }
        let gateway = u32::from_be_bytes(self.gateway);
        gateway == 0 || (gateway != ip && gateway & mask == ip & mask && is_host(gateway))
    }

    pub(crate) fn read(b: &[u8]) -> Option<NetSettings> {
        let dhcp = match u8_at(b, 0) {
            0 => false,
            1 => true,
            _ => return None,
        };
        Some(NetSettings {
            dhcp,
            ip: [u8_at(b, 1), u8_at(b, 2), u8_at(b, 3), u8_at(b, 4)],
            prefix_len: u8_at(b, 5),
            gateway: [u8_at(b, 6), u8_at(b, 7), u8_at(b, 8), u8_at(b, 9)],
        })
    }

    pub(crate) fn write(&self, w: &mut Writer<'_>, at: usize) {
        w.u8(at, u8::from(self.dhcp));
        w.put(at + 1, &self.ip);
        w.u8(at + 5, self.prefix_len);
        w.put(at + 6, &self.gateway);
    }
}

/// Who owns the controller, as DISCOVER_REPLY tells the host that asked.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub enum OwnerState {
    /// No host has spoken to it (or ownership lapsed: the owner was silent 5 s).
    #[default]
    Free,
    /// Another host owns it.
    Other,
    /// The host that asked owns it.
    Asker,
}

impl OwnerState {
    /// Lower-case name for tools.
    pub const fn name(self) -> &'static str {
        match self {
            OwnerState::Free => "free",
            OwnerState::Other => "owned",
            OwnerState::Asker => "owned by you",
        }
    }
}

/// DISCOVER_REPLY (0x22) data, 27 bytes: who the controller is and how it is set up.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct DiscoverReply {
    /// Ethernet MAC address.
    pub mac: [u8; 6],
    /// The stored network settings (used from the next reset on).
    pub net: NetSettings,
    /// Protocol version, as in STATUS.
    pub version: [u8; 3],
    /// Joints in use.
    pub joints: u8,
    /// Trajectory state.
    pub state: State,
    /// Ownership, from the asking host's point of view.
    pub owner: OwnerState,
    /// The owner's IPv4 address (0.0.0.0 when free).
    pub owner_ip: [u8; 4],
    /// The stored settings differ from the ones in use: applied after the next reset.
    pub pending_reset: bool,
}

impl DiscoverReply {
    /// The frame's tag.
    pub const TAG: Tag = Tag::DiscoverReply;

    /// Writes the frame with `seq` (the DISCOVER's) into `buf`; returns its length.
    pub fn encode(&self, seq: u8, buf: &mut [u8]) -> Result<usize, EncodeError> {
        seal(seq, Tag::DiscoverReply, size::DISCOVER_REPLY, buf, |w| {
            w.put(0, &self.mac);
            w.put(6, &self.net.ip);
            w.u8(10, self.net.prefix_len);
            w.put(11, &self.net.gateway);
            w.u8(15, u8::from(self.net.dhcp));
            w.put(16, &self.version);
            w.u8(19, self.joints);
            w.u8(20, self.state as u8);
            w.u8(21, self.owner as u8);
            w.put(22, &self.owner_ip);
            w.u8(26, u8::from(self.pending_reset));
        })
    }

    /// Decodes a DISCOVER_REPLY datagram. Never panics.
    pub fn decode(bytes: &[u8]) -> Result<Frame<DiscoverReply>, DecodeError> {
        let err = |kind| DecodeError {
            seq: u8_at(bytes, 0),
            tag: u8_at(bytes, 1),
            kind,
        };
        let Some((&crc, body)) = bytes.split_last() else {
            return Err(err(DecodeErrorKind::TooShort { len: bytes.len() }));
        };
        let [seq, tag, data @ ..] = body else {
            return Err(err(DecodeErrorKind::TooShort { len: bytes.len() }));
        };
        let computed = crc8(body);
        if computed != crc {
            return Err(err(DecodeErrorKind::BadCrc {
                computed,
                received: crc,
            }));
        }
        if *tag != Tag::DiscoverReply as u8 {
            return Err(err(match Tag::from_u8(*tag) {
                Some(_) => DecodeErrorKind::WrongDirection,
                None => DecodeErrorKind::UnknownTag,
            }));
        }
        if data.len() != size::DISCOVER_REPLY {
            return Err(err(DecodeErrorKind::BadLength {
                expected: ExpectedLen::Exactly(size::DISCOVER_REPLY),
                found: data.len(),
            }));
        }
        let b = data;
        let quad = |at: usize| {
            [
                u8_at(b, at),
                u8_at(b, at + 1),
                u8_at(b, at + 2),
                u8_at(b, at + 3),
            ]
        };
        let state = State::from_u8(u8_at(b, 20))
            .ok_or_else(|| err(DecodeErrorKind::OutOfRange(Field::State)))?;
        let owner = match u8_at(b, 21) {
            0 => OwnerState::Free,
            1 => OwnerState::Other,
            2 => OwnerState::Asker,
            _ => return Err(err(DecodeErrorKind::OutOfRange(Field::Owner))),
        };
        let dhcp = match u8_at(b, 15) {
            0 => false,
            1 => true,
            _ => return Err(err(DecodeErrorKind::OutOfRange(Field::NetSettings))),
        };
        Ok(Frame {
            seq: *seq,
            body: DiscoverReply {
                mac: [
                    u8_at(b, 0),
                    u8_at(b, 1),
                    u8_at(b, 2),
                    u8_at(b, 3),
                    u8_at(b, 4),
                    u8_at(b, 5),
                ],
                net: NetSettings {
                    dhcp,
                    ip: quad(6),
                    prefix_len: u8_at(b, 10),
                    gateway: quad(11),
                },
                version: [u8_at(b, 16), u8_at(b, 17), u8_at(b, 18)],
                joints: u8_at(b, 19),
                state,
                owner,
                owner_ip: quad(22),
                pending_reset: u8_at(b, 26) & 1 != 0,
            },
        })
    }
}
