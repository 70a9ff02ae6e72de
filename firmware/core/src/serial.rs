//! USART_RECV batching (docs/PROTOCOL.md, "USART_RECV (0x0b)"): bytes from the port are sent
//! when 255 are waiting, when the line has been idle for one byte time after data, or 1 ms
//! after the first of them arrived, whichever comes first.

use heapless::Vec;
use protocol::{MAX_SERIAL_CHUNK, UartInit};

/// The longest a received byte waits before it is sent, microseconds.
pub const SERIAL_BATCH_DELAY_US: u64 = 1_000;

/// Microseconds one byte occupies on the line with these settings (rounded up).
pub fn byte_time_us(init: &UartInit) -> u32 {
    let bits = u64::from(init.bits_per_byte()) * 1_000_000;
    u32::try_from(bits.div_ceil(u64::from(init.baud_rate.max(1)))).unwrap_or(u32::MAX)
}

/// Collects received bytes into USART_RECV payloads. Sans-io: the caller passes the time.
#[derive(Clone, Debug, Default)]
pub struct SerialBatcher {
    bytes: Vec<u8, MAX_SERIAL_CHUNK>,
    first_at_us: u64,
    last_at_us: u64,
    byte_time_us: u32,
}

impl SerialBatcher {
    /// An empty batch for a line where one byte takes `byte_time_us`.
    pub const fn new(byte_time_us: u32) -> Self {
        SerialBatcher {
            bytes: Vec::new(),
            first_at_us: 0,
            last_at_us: 0,
            byte_time_us,
        }
    }

    /// Changes the idle time (the port was reopened with other settings).
    pub fn set_byte_time_us(&mut self, byte_time_us: u32) {
        self.byte_time_us = byte_time_us;
    }

    /// Bytes the batch can still take.
    pub fn room(&self) -> usize {
        MAX_SERIAL_CHUNK - self.bytes.len()
    }

    /// Whether nothing is waiting.
    pub fn is_empty(&self) -> bool {
        self.bytes.is_empty()
    }

    /// Adds bytes that arrived at `now_us`; returns how many were taken (the rest belong
    /// to the next batch).
    pub fn push(&mut self, bytes: &[u8], now_us: u64) -> usize {
        let n = bytes.len().min(self.room());
        if n == 0 {
            return 0;
        }
        if self.bytes.is_empty() {
            self.first_at_us = now_us;
        }
        self.last_at_us = now_us;
        let _ = self
            .bytes
            .extend_from_slice(bytes.get(..n).unwrap_or_default());
        n
    }

    /// When the batch must be sent if nothing else arrives: 1 ms after its first byte or
    /// one byte time of idle line after its last one. `None` when empty.
    pub fn deadline_us(&self) -> Option<u64> {
        if self.bytes.is_empty() {
            return None;
        }
        let batch = self.first_at_us + SERIAL_BATCH_DELAY_US;
        let idle = self.last_at_us + u64::from(self.byte_time_us);
        Some(batch.min(idle))
    }

    /// Whether the batch must be sent at `now_us`.
    pub fn is_due(&self, now_us: u64) -> bool {
        self.bytes.is_full() || self.deadline_us().is_some_and(|d| now_us >= d)
    }

    /// Takes the batch (empties it).
    pub fn take(&mut self) -> Vec<u8, MAX_SERIAL_CHUNK> {
        core::mem::take(&mut self.bytes)
    }

    /// Drops what is waiting (the port was closed).
    pub fn clear(&mut self) {
        self.bytes.clear();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn byte_time_follows_the_settings() {
        let init = UartInit {
            baud_rate: 115_200,
            ..UartInit::default()
        };
        assert_eq!(byte_time_us(&init), 87); // 10 bits / 115200 = 86.8 us
        let slow = UartInit {
            baud_rate: 300,
            stop_bits: 0x2000,
            ..UartInit::default()
        };
        assert_eq!(byte_time_us(&slow), 36_667);
    }

    #[test]
    fn sends_after_one_idle_byte_time() {
        let mut b = SerialBatcher::new(87);
        assert!(!b.is_due(0) && b.deadline_us().is_none());
        assert_eq!(b.push(b"ab", 100), 2);
        assert!(!b.is_due(186));
        assert!(b.is_due(187));
        assert_eq!(b.take().as_slice(), b"ab");
        assert!(b.is_empty());
    }

    #[test]
    fn sends_1ms_after_data_on_a_busy_line() {
        let mut b = SerialBatcher::new(87);
        // A byte every 80 us: never idle for a byte time.
        let mut t = 5_000;
        while !b.is_due(t) {
            b.push(b"x", t);
            t += 80;
        }
        assert_eq!(b.deadline_us(), Some(6_000));
        assert!((6_000..6_080).contains(&t), "due at {t}");
        assert_eq!(b.take().len(), 13);
    }

    #[test]
    fn sends_when_255_bytes_wait() {
        let mut b = SerialBatcher::new(1_000_000);
        let block = [7u8; 300];
        assert_eq!(b.push(&block, 0), 255);
        assert!(b.is_due(0), "full");
        assert_eq!(b.push(&block, 0), 0);
        assert_eq!(b.take().len(), 255);
        assert_eq!(b.push(&block[255..], 1), 45);
        assert!(!b.is_due(1));
    }
}
