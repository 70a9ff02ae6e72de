//! The board's own timing counters (issue 34 part C), sans-io: small structs a board
//! updates with stamps from its own clocks and reads into the DIAG report
//! ([`protocol::Diag`], docs/PROTOCOL.md "DIAG"). The NUCLEO keeps one of each in a
//! static, each written from one context only (`firmware/board/src/diag.rs`):
//!
//! - [`MaskedSpans`]: its critical-section implementation stamps DWT CYCCNT when the
//!   outermost section opens (with the caller's return address) and closes: the longest
//!   span with every interrupt masked, which delays the DIR changes (P1) and the wired
//!   e-stop input (P0), and where it was opened.
//! - [`DirLateness`]: the step clock's interrupt, at each DIR write, its counter against
//!   the tick the change was due.
//! - [`DmaSlack`]: each refill interrupt, the ticks left before its timer's next update
//!   event: a burst that lands after that event replays the previous period.
//!
//! Counts wrap; a clock in the report of 0 says "not measured" (the simulator, and the
//! QEMU board, which has no cycle counter and no step timers).

use protocol::Diag;

/// The longest span with every interrupt masked, from open and close stamps of a
/// free-running 32-bit cycle counter (wrapping: a span is shorter than a wrap, 10.7 s at
/// 400 MHz, which the watchdog never allows).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MaskedSpans {
    /// The open span's first stamp and opener.
    opened_at: u32,
    opener: u32,
    /// The longest span closed so far, cycles.
    pub max_cycles: u32,
    /// The address that opened it (0: none yet).
    pub max_opener: u32,
    /// Spans closed (wrapping).
    pub spans: u32,
}

impl MaskedSpans {
    /// No span yet.
    pub const NEW: MaskedSpans = MaskedSpans {
        opened_at: 0,
        opener: 0,
        max_cycles: 0,
        max_opener: 0,
        spans: 0,
    };

    /// The outermost masked section opened at cycle `now`, entered from `opener`.
    pub fn open(&mut self, now: u32, opener: u32) {
        self.opened_at = now;
        self.opener = opener;
    }

    /// The section opened last closed at cycle `now`.
    pub fn close(&mut self, now: u32) {
        let span = now.wrapping_sub(self.opened_at);
        if span > self.max_cycles || self.spans == 0 {
            self.max_cycles = span;
            self.max_opener = self.opener;
        }
        self.spans = self.spans.wrapping_add(1);
    }
}

/// The latest DIR change against its compare, from a 16-bit step clock counter.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DirLateness {
    /// Most ticks a DIR write came after its due tick; [`Diag::NO_DIR_WRITE`]: none.
    pub max_late_ticks: i32,
    /// DIR writes counted (wrapping).
    pub writes: u32,
}

impl DirLateness {
    /// No DIR write yet.
    pub const NEW: DirLateness = DirLateness {
        max_late_ticks: Diag::NO_DIR_WRITE,
        writes: 0,
    };

    /// A DIR line was written with the step clock's 16-bit counter at `counter`, for a
    /// change due at step clock tick `due` (its low 16 bits are the compare value). Right
    /// while the write comes within half a wrap of its tick (164 us on the NUCLEO's
    /// 200 MHz TIM13): later reads as early, which the figure would show anyway.
    pub fn written(&mut self, counter: u16, due: u64) {
        #[allow(
            clippy::cast_possible_truncation,
            clippy::cast_possible_wrap,
            reason = "the compare is the due tick's low 16 bits; the wrapping difference of two 16-bit counts, read signed, is the lateness within half a wrap"
        )]
        let late = i32::from(counter.wrapping_sub(due as u16) as i16);
        self.max_late_ticks = self.max_late_ticks.max(late);
        self.writes = self.writes.wrapping_add(1);
    }
}

/// The least slack of the step DMA before an update event.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DmaSlack {
    /// Fewest ticks seen; [`Diag::NO_REFILL`]: none.
    pub min_ticks: u32,
    /// Refills measured (wrapping).
    pub refills: u32,
}

impl DmaSlack {
    /// No refill yet.
    pub const NEW: DmaSlack = DmaSlack {
        min_ticks: Diag::NO_REFILL,
        refills: 0,
    };

    /// The buffer index of the period a timer is playing, from `next`, the index the
    /// stream's next burst reads (NDTR), in a circular buffer of `periods`: at each update
    /// event the burst loads the period after the one starting (ARR is preloaded), so the
    /// one playing was read two bursts ago. `periods` is at least 2.
    pub fn playing(next: usize, periods: usize) -> usize {
        (next + periods.saturating_mul(2) - 2) % periods.max(1)
    }

    /// A refill looked at its timer: `reload` is the playing period's ARR (from the buffer
    /// at [`DmaSlack::playing`]), `counter` the timer's counter. The ticks to the next
    /// update event are `reload + 1 - counter` (arm-step never repeats a period: RCR is
    /// always 0). The look comes after the burst landed, so the burst's own slack was at
    /// least this. A counter past its reload (a period read wrongly, racing an update
    /// event) counts as 0.
    pub fn sampled(&mut self, reload: u32, counter: u32) {
        let slack = reload.saturating_add(1).saturating_sub(counter);
        self.min_ticks = self.min_ticks.min(slack);
        self.refills = self.refills.wrapping_add(1);
    }
}

/// The DIAG report of a board's counters and clocks (`cpu_hz` for the spans, `step_hz`
/// for DIR and the DMA; 0: not measured).
pub fn report(
    spans: MaskedSpans,
    dir: DirLateness,
    dma: DmaSlack,
    cpu_hz: u32,
    step_hz: u32,
) -> Diag {
    Diag {
        cpu_hz,
        masked_max_cycles: spans.max_cycles,
        masked_opener: spans.max_opener,
        masked_spans: spans.spans,
        step_hz,
        dir_late_max_ticks: dir.max_late_ticks,
        dir_writes: dir.writes,
        dma_slack_min_ticks: dma.min_ticks,
        dma_refills: dma.refills,
    }
}
