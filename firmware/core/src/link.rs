//! The reliability rules of PROTOCOL.md, "Ordering, retransmission and duplicates": the
//! ordering of PENDING frames (go-back-N) and the memory of recently accepted frames
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
        if run >= SLIDE_AFTER {
            self.take(self.base.wrapping_add(run as u8));
        }
    }

    /// Index of the first unmarked bit (0..=255).
    fn first_unmarked(&self) -> usize {
        let mut at = 0;
        for w in self.marks {
            let ones = w.trailing_ones() as usize;
            at += ones;
            if ones < 64 {
                break;
            }
        }
        at.min(255)
    }

    /// The seq the next PENDING must carry.
    pub fn next_seq(&self) -> u8 {
        self.base
            .wrapping_add(1)
            .wrapping_add(self.first_unmarked() as u8)
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
        for i in 0..4 {
            let src = i + words;
            let lo = old.get(src).map_or(0, |w| w >> bits);
            let hi = if bits > 0 {
                old.get(src + 1).map_or(0, |w| w << (64 - bits))
            } else {
                0
            };
            self.marks[i] = lo | hi;
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

/// The last [`DUPLICATE_MEMORY`] accepted frames, each remembered for
/// [`DUPLICATE_WINDOW_US`].
#[derive(Clone, Debug)]
pub struct RecentFrames {
    entries: [Option<(FrameKey, u64)>; DUPLICATE_MEMORY],
    next: usize,
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
            entries: [None; DUPLICATE_MEMORY],
            next: 0,
        }
    }

    /// Whether `key` was accepted within the window before `now_us`.
    pub fn contains(&self, key: &FrameKey, now_us: u64) -> bool {
        self.entries
            .iter()
            .flatten()
            .any(|(k, at)| k == key && now_us.saturating_sub(*at) < DUPLICATE_WINDOW_US)
    }

    /// Remembers an accepted frame, forgetting the oldest.
    pub fn remember(&mut self, key: FrameKey, now_us: u64) {
        if let Some(slot) = self.entries.get_mut(self.next) {
            *slot = Some((key, now_us));
        }
        self.next = (self.next + 1) % DUPLICATE_MEMORY;
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
        for s in 0..DUPLICATE_MEMORY as u8 {
            r.remember(FrameKey { seq: s + 10, ..key }, 2_000);
        }
        assert!(!r.contains(&key, 2_000), "forgotten after 32 newer frames");
    }
}
