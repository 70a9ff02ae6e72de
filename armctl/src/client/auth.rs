//! The host side of authentication (docs/PROTOCOL.md section 13, issue 21): the key, the
//! session HELLO opened, and sealing and opening envelopes.

use protocol::auth::{
    AuthKey, Direction, Envelope, HelloReply, KEY_LEN, MAX_INNER, NONCE_LEN, ReplayWindow, seal,
};
use protocol::{MAX_DATAGRAM, Tag};

/// A key from a key file's text: 64 hex digits (surrounding white space ignored).
pub fn parse_key(text: &str) -> Result<AuthKey, String> {
    let hex = text.trim();
    let mut key = [0u8; KEY_LEN];
    if hex.len() != 2 * KEY_LEN || !hex.is_ascii() {
        return Err(format!(
            "a key is {} hex digits (32 bytes); this has {} characters",
            2 * KEY_LEN,
            hex.len()
        ));
    }
    for (i, b) in key.iter_mut().enumerate() {
        *b = u8::from_str_radix(&hex[2 * i..2 * i + 2], 16).map_err(|_| {
            format!(
                "not a hex digit pair at {}: {:?}",
                2 * i,
                &hex[2 * i..2 * i + 2]
            )
        })?;
    }
    Ok(AuthKey(key))
}

/// Reads a key file (`--key-file`): 64 hex digits.
pub fn read_key_file(path: &std::path::Path) -> Result<AuthKey, String> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    parse_key(&text).map_err(|e| format!("{}: {e}", path.display()))
}

/// A new random key as 64 hex digits (for `armctl key new`).
pub fn new_key_hex() -> std::io::Result<String> {
    let mut key = [0u8; KEY_LEN];
    getrandom(&mut key)?;
    Ok(key.iter().map(|b| format!("{b:02x}")).collect())
}

/// Random bytes from the system.
pub(crate) fn getrandom(buf: &mut [u8]) -> std::io::Result<()> {
    use std::io::Read;
    std::fs::File::open("/dev/urandom")?.read_exact(buf)
}

/// A host's authentication state.
#[derive(Debug)]
pub(crate) struct HostAuth {
    pub(crate) key: AuthKey,
    /// The HELLO waiting for its reply.
    pub(crate) pending_nonce: Option<[u8; NONCE_LEN]>,
    /// The session: epoch and id.
    pub(crate) session: Option<(u64, u32)>,
    /// The last counter sent.
    counter: u64,
    /// The controller's counters seen.
    rx: ReplayWindow,
}

/// What the receiver makes of a datagram, with a key.
pub(crate) enum Opened {
    /// A verified envelope's inner frame, or a plain frame the host may take unsealed.
    Frame(Vec<u8>),
    /// The HELLO_REPLY of the pending HELLO, verified: the session is open.
    Hello,
    /// A HELLO_REPLY whose MAC does not verify under this key: the controller holds
    /// another key.
    WrongKey,
    /// Forged, replayed or plain where a seal is required: dropped.
    Dropped,
}

impl HostAuth {
    pub(crate) fn new(key: AuthKey) -> Self {
        HostAuth {
            key,
            pending_nonce: None,
            session: None,
            counter: 0,
            rx: ReplayWindow::new(),
        }
    }

    /// Forgets the session (the controller was reset, or took it back).
    /// The session frames are sealed in now: the controller's epoch and session id.
    pub(crate) fn session(&self) -> Option<(u64, u32)> {
        self.session
    }

    pub(crate) fn reset(&mut self) {
        self.session = None;
        self.rx = ReplayWindow::new();
    }

    /// `frame` in an envelope with the next counter, or `None` without a session.
    pub(crate) fn seal(&mut self, frame: &[u8]) -> Option<Vec<u8>> {
        let (epoch, session) = self.session?;
        if frame.len() > MAX_INNER {
            return None;
        }
        self.counter += 1;
        let mut buf = vec![0u8; MAX_DATAGRAM];
        let n = seal(
            &self.key,
            Direction::ToController,
            epoch,
            session,
            self.counter,
            frame,
            &mut buf,
        )
        .ok()?;
        buf.truncate(n);
        Some(buf)
    }

    /// Opens what the controller sent.
    pub(crate) fn open(&mut self, datagram: &[u8]) -> Opened {
        if datagram.get(1) != Some(&(Tag::Auth as u8)) {
            // Plain: an ACK refusing something (it changes nothing the host relies on), the
            // ACK of a STOPPED sent before any session, or of SET_KEY (the controller ends
            // every session with it); never a report or another OK.
            return match protocol::Report::decode(datagram) {
                Ok(protocol::Frame {
                    body: protocol::Report::Ack(ack),
                    ..
                }) if ack.status != protocol::StatusCode::Ok
                    || ack.acked_tag == Tag::Stopped as u8
                    || ack.acked_tag == Tag::SetKey as u8 =>
                {
                    Opened::Frame(datagram.to_vec())
                }
                _ => Opened::Dropped,
            };
        }
        let Ok(envelope) = Envelope::open(datagram) else {
            return Opened::Dropped;
        };
        if let Ok(hello) = HelloReply::decode(envelope.inner) {
            let reply = hello.body;
            if self.pending_nonce != Some(reply.nonce) {
                return Opened::Dropped;
            }
            if !envelope.verify(&self.key, Direction::ToHost, reply.epoch)
                || envelope.session != reply.session
            {
                return Opened::WrongKey;
            }
            self.pending_nonce = None;
            self.session = Some((reply.epoch, reply.session));
            self.rx = ReplayWindow::new();
            self.rx.accept(envelope.counter);
            return Opened::Hello;
        }
        let Some((epoch, session)) = self.session else {
            return Opened::Dropped;
        };
        if envelope.session != session
            || !self.rx.is_fresh(envelope.counter)
            || !envelope.verify(&self.key, Direction::ToHost, epoch)
        {
            return Opened::Dropped;
        }
        self.rx.accept(envelope.counter);
        Opened::Frame(envelope.inner.to_vec())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn key_files_take_64_hex_digits() {
        let key = parse_key(&format!("{}\n", "0f".repeat(32))).unwrap();
        assert_eq!(key.0, [0x0f; 32]);
        assert!(parse_key("0f0f").is_err());
        assert!(parse_key(&"zz".repeat(32)).is_err());
        assert_eq!(new_key_hex().unwrap().len(), 64);
    }
}
