//! DIAG (0x32, controller to host; issue 34 part C): the board's own timing, asked for by
//! bit 6 of STATUS's request byte (docs/PROTOCOL.md, STATUS and DIAG). The emulators
//! cannot give these figures (Renode and QEMU take no time for a masked span or a DMA
//! burst): a user with a real NUCLEO reads them with `armctl diag`. A report of its own,
//! as RX_COUNTERS: STATUS is full at 36 bytes.
//!
//! Counts are in the controller's own clocks, which the report carries: CPU cycles
//! (`cpu_hz`) for masked spans, step-clock ticks (`step_hz`) for DIR and the step DMA. A
//! clock of 0 says "not measured on this controller" (the simulator; the QEMU board has no
//! cycle counter): its counts are 0 and mean nothing.

use crate::codec::{Writer, i32_le, u32_le};

/// The board's timing counters, each since boot (counts wrap).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct Diag {
    /// The cycle counter's clock, Hz (the CPU's: 400 MHz on the NUCLEO); 0: masked spans
    /// are not measured here.
    pub cpu_hz: u32,
    /// The longest span with every interrupt masked (a critical section: PRIMASK), CPU
    /// cycles. It delays the DIR changes (P1) and the wired e-stop input (P0).
    pub masked_max_cycles: u32,
    /// The code address that opened that span (where the critical section was entered:
    /// `addr2line -e` the ELF finds the function); 0: none yet.
    pub masked_opener: u32,
    /// Masked spans measured (wrapping).
    pub masked_spans: u32,
    /// The step clock, Hz (TIM13 and the joint timers: 200 MHz on the NUCLEO); 0: DIR
    /// and DMA timing are not measured here.
    pub step_hz: u32,
    /// The latest DIR change against its compare: the most step-clock ticks a DIR write
    /// came after the tick it was due (TIM13's counter minus its compare value at the
    /// write). [`Diag::NO_DIR_WRITE`]: no DIR change since boot.
    pub dir_late_max_ticks: i32,
    /// DIR changes written (wrapping).
    pub dir_writes: u32,
    /// The least slack of the step DMA: the fewest step-clock ticks from a refill
    /// interrupt's look at its timer to that timer's next update event, when the burst
    /// for the period after it must have landed. [`Diag::NO_REFILL`]: none yet.
    pub dma_slack_min_ticks: u32,
    /// Refills measured (wrapping).
    pub dma_refills: u32,
}

impl Diag {
    /// `dir_late_max_ticks` before the first DIR change.
    pub const NO_DIR_WRITE: i32 = i32::MIN;
    /// `dma_slack_min_ticks` before the first refill.
    pub const NO_REFILL: u32 = u32::MAX;

    /// A controller that measures none of it (the simulator).
    pub const NOT_MEASURED: Diag = Diag {
        cpu_hz: 0,
        masked_max_cycles: 0,
        masked_opener: 0,
        masked_spans: 0,
        step_hz: 0,
        dir_late_max_ticks: Diag::NO_DIR_WRITE,
        dir_writes: 0,
        dma_slack_min_ticks: Diag::NO_REFILL,
        dma_refills: 0,
    };

    /// The longest masked span in nanoseconds; `None` when not measured.
    pub fn masked_max_ns(&self) -> Option<u64> {
        ns(u64::from(self.masked_max_cycles), self.cpu_hz)
    }

    /// The latest DIR change in nanoseconds after its tick (negative: early); `None` when
    /// not measured or no DIR change yet.
    pub fn dir_late_max_ns(&self) -> Option<i64> {
        if self.step_hz == 0 || self.dir_late_max_ticks == Diag::NO_DIR_WRITE {
            return None;
        }
        let late = i64::from(self.dir_late_max_ticks);
        let magnitude = ns(late.unsigned_abs(), self.step_hz)?;
        let magnitude = i64::try_from(magnitude).unwrap_or(i64::MAX);
        Some(if late < 0 { -magnitude } else { magnitude })
    }

    /// The least DMA slack in nanoseconds; `None` when not measured or no refill yet.
    pub fn dma_slack_min_ns(&self) -> Option<u64> {
        if self.dma_slack_min_ticks == Diag::NO_REFILL {
            return None;
        }
        ns(u64::from(self.dma_slack_min_ticks), self.step_hz)
    }

    pub(crate) fn read(b: &[u8]) -> Diag {
        Diag {
            cpu_hz: u32_le(b, 0),
            masked_max_cycles: u32_le(b, 4),
            masked_opener: u32_le(b, 8),
            masked_spans: u32_le(b, 12),
            step_hz: u32_le(b, 16),
            dir_late_max_ticks: i32_le(b, 20),
            dir_writes: u32_le(b, 24),
            dma_slack_min_ticks: u32_le(b, 28),
            dma_refills: u32_le(b, 32),
        }
    }

    pub(crate) fn write(&self, w: &mut Writer<'_>, at: usize) {
        w.u32(at, self.cpu_hz);
        w.u32(at + 4, self.masked_max_cycles);
        w.u32(at + 8, self.masked_opener);
        w.u32(at + 12, self.masked_spans);
        w.u32(at + 16, self.step_hz);
        w.u32(
            at + 20,
            u32::from_le_bytes(self.dir_late_max_ticks.to_le_bytes()),
        );
        w.u32(at + 24, self.dir_writes);
        w.u32(at + 28, self.dma_slack_min_ticks);
        w.u32(at + 32, self.dma_refills);
    }
}

/// `count` ticks of a `hz` clock in nanoseconds (rounded down); `None` for `hz` 0.
fn ns(count: u64, hz: u32) -> Option<u64> {
    if hz == 0 {
        return None;
    }
    // count < 2^32 and 1e9 < 2^30: no overflow in u64... nor for |i32| ticks.
    Some(count.saturating_mul(1_000_000_000) / u64::from(hz))
}
