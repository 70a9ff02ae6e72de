//! The reliability rules of docs/PROTOCOL.md, "Ordering, retransmission and duplicates":
//! the ordering of PENDING frames (go-back-N) and the memory of recently accepted frames
//! (duplicates).

use crate::config::{DUPLICATE_MEMORY, DUPLICATE_WINDOW_US};
use crate::hw::Endpoint;

/// Accepted seqs in a row after the base that make the base move up to them: half the
/// 256 seqs, so the marks always have room ahead for frames that arrive out of order.
pub const SLIDE_AFTER: usize = 128;

/// Seqs just behind the base (base - 64 up to base - 1) whose accepted frames are taken
/// for late arrivals from before it, and not marked: marked, they would stand for the same
/// seqs a lap (256) later and let a PENDING lost there be skipped. Leaves 191 seqs ahead
/// for marks, far more than any host keeps in flight.
pub const LATE_SEQS: usize = 64;

/// Which seqs after the last taken PENDING (or NEW) were used by accepted commands.
///
/// Bit `i` of `marks` stands for seq `base + 1 + i` (mod 256). A PENDING is taken only if
/// its seq is the first unmarked one (`next_seq`): then every seq between the last taken
/// upload frame and its own was used by an accepted command.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct UploadOrder {
    base: u8,
    marks: [u64; 4],
}

impl UploadOrder {
    /// No upload yet: the base is seq 0.
    pub const fn new() -> Self {
        UploadOrder {
            base: 0,
            marks: [0; 4],
        }
    }

    /// The seq of the last taken NEW or PENDING (or of the last of [`SLIDE_AFTER`]
    /// accepted commands in a row after it).
    pub fn base(&self) -> u8 {
        self.base
    }

    /// NEW with `seq` was accepted: a new upload starts after it.
    pub fn restart(&mut self, seq: u8) {
        self.base = seq;
        self.marks = [0; 4];
    }

    /// A command (any tag) with `seq` was accepted.
    ///
    /// Once [`SLIDE_AFTER`] seqs after the base are accepted in a row, the base moves to
    /// the last of them, as if a PENDING had been taken there (`next_seq` is unchanged):
    /// the marks only cover 255 seqs, and a host may interleave any number of commands
    /// (say, STATUS polls while it waits for room) between two PENDING frames.
    pub fn mark(&mut self, seq: u8) {
        let d = usize::from(seq.wrapping_sub(self.base));
        // A seq just behind the base is a late frame from before it, not one a lap ahead.
        if (1..=255 - LATE_SEQS).contains(&d) {
            let i = d - 1;
            if let Some(w) = self.marks.get_mut(i / 64) {
                *w |= 1 << (i % 64);
            }
        }
        let run = self.first_unmarked();
        if usize::from(run) >= SLIDE_AFTER {
            self.take(self.base.wrapping_add(run));
        }
    }

    /// Index of the first unmarked bit (0..=255).
    fn first_unmarked(&self) -> u8 {
        let mut at = 0;
        for w in self.marks {
            let ones = w.trailing_ones();
            at += ones;
            if ones < 64 {
                break;
            }
        }
        u8::try_from(at).unwrap_or(u8::MAX)
    }

    /// The seq the next PENDING must carry.
    pub fn next_seq(&self) -> u8 {
        self.base
            .wrapping_add(1)
            .wrapping_add(self.first_unmarked())
    }

    /// Whether a PENDING with `seq` may be taken now.
    pub fn in_order(&self, seq: u8) -> bool {
        seq == self.next_seq()
    }

    /// A PENDING with `seq` was taken: it becomes the new base; marks of later seqs stay.
    pub fn take(&mut self, seq: u8) {
        let d = usize::from(seq.wrapping_sub(self.base));
        let (words, bits) = (d / 64, d % 64);
        let old = self.marks;
        for (i, mark) in self.marks.iter_mut().enumerate() {
            let src = i + words;
            let lo = old.get(src).map_or(0, |w| w >> bits);
            let hi = if bits > 0 {
                old.get(src + 1).map_or(0, |w| w << (64 - bits))
            } else {
                0
            };
            *mark = lo | hi;
        }
        self.base = seq;
    }
}

/// What identifies a frame for duplicate detection.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FrameKey {
    /// Sender. PROTOCOL.md names the source port; the address is compared as well, since
    /// a frame from another host can be neither a retransmission nor a network duplicate.
    pub from: Endpoint,
    /// The frame's seq.
    pub seq: u8,
    /// The frame's tag.
    pub tag: u8,
    /// The frame's CRC byte.
    pub crc: u8,
}

/// Endpoints (address and port) whose last [`DUPLICATE_MEMORY`] accepted frames are kept
/// at once: the owner's machine runs the uploading tool and, beside it, a STATUS poller or
/// a watcher (frames from other addresses are refused NOT_OWNER and never remembered). A
/// fourth endpoint takes the memory of the one heard least recently.
pub const DUPLICATE_ENDPOINTS: usize = 3;

/// One remembered frame of an endpoint: its seq, tag and CRC, and when it was accepted.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct Remembered {
    seq: u8,
    tag: u8,
    crc: u8,
    at_us: u64,
}

/// One endpoint's last [`DUPLICATE_MEMORY`] accepted frames, a ring.
#[derive(Clone, Copy, Debug)]
struct EndpointFrames {
    from: Option<Endpoint>,
    /// When its last frame was remembered.
    last_us: u64,
    frames: [Option<Remembered>; DUPLICATE_MEMORY],
    next: usize,
}

impl EndpointFrames {
    const EMPTY: EndpointFrames = EndpointFrames {
        from: None,
        last_us: 0,
        frames: [None; DUPLICATE_MEMORY],
        next: 0,
    };
}

/// Accepted frames, each remembered for [`DUPLICATE_WINDOW_US`]: of each of
/// [`DUPLICATE_ENDPOINTS`] endpoints its last [`DUPLICATE_MEMORY`] (issue 21 F13: one
/// memory of 64 shared by all let a poller's 70 STATUS frames evict the owner's TOGGLE,
/// whose resend then ran twice). 3 x 64 frames of 16 bytes.
#[derive(Clone, Debug)]
pub struct RecentFrames {
    endpoints: [EndpointFrames; DUPLICATE_ENDPOINTS],
}

impl Default for RecentFrames {
    fn default() -> Self {
        Self::new()
    }
}

impl RecentFrames {
    /// Remembers nothing.
    pub const fn new() -> Self {
        RecentFrames {
            endpoints: [EndpointFrames::EMPTY; DUPLICATE_ENDPOINTS],
        }
    }

    /// Whether `key` was accepted within the window before `now_us`.
    pub fn contains(&self, key: &FrameKey, now_us: u64) -> bool {
        self.endpoints
            .iter()
            .filter(|e| e.from == Some(key.from))
            .flat_map(|e| e.frames.iter().flatten())
            .any(|r| {
                (r.seq, r.tag, r.crc) == (key.seq, key.tag, key.crc)
                    && now_us.saturating_sub(r.at_us) < DUPLICATE_WINDOW_US
            })
    }

    /// Remembers an accepted frame in its endpoint's ring (forgetting that endpoint's
    /// oldest); a new endpoint takes the ring of the one heard least recently.
    pub fn remember(&mut self, key: FrameKey, now_us: u64) {
        let index = match self.endpoints.iter().position(|e| e.from == Some(key.from)) {
            Some(i) => i,
            None => {
                let lru = self
                    .endpoints
                    .iter()
                    .enumerate()
                    .min_by_key(|(_, e)| (e.from.is_some(), e.last_us))
                    .map_or(0, |(i, _)| i);
                if let Some(e) = self.endpoints.get_mut(lru) {
                    *e = EndpointFrames {
                        from: Some(key.from),
                        ..EndpointFrames::EMPTY
                    };
                }
                lru
            }
        };
        let Some(e) = self.endpoints.get_mut(index) else {
            return;
        };
        e.last_us = now_us;
        if let Some(slot) = e.frames.get_mut(e.next) {
            *slot = Some(Remembered {
                seq: key.seq,
                tag: key.tag,
                crc: key.crc,
                at_us: now_us,
            });
        }
        e.next = (e.next + 1) % DUPLICATE_MEMORY;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn next_seq_skips_accepted_commands() {
        let mut o = UploadOrder::default();
        o.restart(250);
        assert_eq!(o.next_seq(), 251);
        o.mark(252); // a RUNING after a lost PENDING 251
        assert_eq!(o.next_seq(), 251);
        assert!(!o.in_order(253));
        o.mark(251);
        assert_eq!(o.next_seq(), 253);
        assert!(o.in_order(253));
        o.mark(255);
        o.mark(1); // wraps
        o.take(253);
        assert_eq!(o.base(), 253);
        assert_eq!(o.next_seq(), 254, "254 unmarked");
        o.mark(254);
        assert_eq!(o.next_seq(), 0, "255 kept its mark across the take");
        o.mark(0);
        assert_eq!(o.next_seq(), 2);
    }

    #[test]
    fn take_shifts_across_words() {
        let mut o = UploadOrder::default();
        o.restart(0);
        for s in 1..=200u8 {
            o.mark(s);
        }
        assert_eq!(o.next_seq(), 201);
        o.take(130);
        assert_eq!(o.next_seq(), 201);
        o.take(201);
        assert_eq!(o.next_seq(), 202);
        o.restart(7);
        assert_eq!(o.next_seq(), 8);
    }

    #[test]
    fn duplicates_expire() {
        let mut r = RecentFrames::new();
        let key = FrameKey {
            from: Endpoint {
                ip: [127, 0, 0, 1],
                port: 5000,
            },
            seq: 1,
            tag: 1,
            crc: 9,
        };
        r.remember(key, 1_000);
        assert!(r.contains(&key, 1_000 + DUPLICATE_WINDOW_US - 1));
        assert!(!r.contains(&key, 1_000 + DUPLICATE_WINDOW_US));
        assert!(!r.contains(&FrameKey { crc: 8, ..key }, 1_000));
        for s in (0u8..).take(DUPLICATE_MEMORY) {
            r.remember(FrameKey { seq: s + 10, ..key }, 2_000);
        }
        assert!(!r.contains(&key, 2_000), "forgotten after 32 newer frames");
    }
}
