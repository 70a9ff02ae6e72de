//! One joint's walk through the segment queue and its pulse clock.

/// One joint's stream: its walk through the queue, its pulse clock, and the open period
/// (started at `cursor`, not written yet because its end is not known).
#[derive(Clone, Copy, Debug)]
pub(super) struct JointStream {
    /// Ordinal (wrapping) of the segment this joint works on or waits for.
    pub(super) ordinal: u32,
    /// Ring index of that segment.
    pub(super) slot: usize,
    /// Walked past every queued segment: writes idle fillers until more are pushed.
    pub(super) waiting: bool,
    /// The last `cruise` stopped at the end of the buffer with pulses left, so the next
    /// fill can go straight on cruising (its conditions still hold).
    pub(super) cruising: bool,
    /// Pulses still to compute in the current segment.
    pub(super) remaining: u32,
    /// u32 clock usable (modulus and the segment's relative ticks fit).
    pub(super) fast: bool,
    /// Tick the u32 clock counts from (floor of the segment's start).
    pub(super) base: u64,
    /// u32 clock: next pulse's ideal tick relative to `base`, whole ticks per pulse,
    /// fraction, remainder, modulus.
    pub(super) ideal: u32,
    pub(super) whole: u32,
    pub(super) fraction: u32,
    pub(super) remainder: u32,
    pub(super) modulus: u32,
    /// u64 clock (absolute ideal tick), used when the u32 one does not fit.
    pub(super) wide_ideal: u64,
    pub(super) wide_whole: u64,
    pub(super) wide_fraction: u64,
    pub(super) wide_remainder: u64,
    pub(super) wide_modulus: u64,
    /// The producer's warp is not the identity (a copy where the per-pulse path has its
    /// joint at hand: reading the warp's own flag cost 10 instructions per step at 1 kHz
    /// with 8 joints, scripts/step-cost).
    pub(super) warped: bool,
    /// Ideal tick (trajectory time) of a pulse the warp holds back for good (it maps to
    /// "never"), taken from the clock but not placed: placed when a warp change lets it
    /// come; `u64::MAX`: none.
    pub(super) parked: u64,
    /// -1 or +1.
    pub(super) sign: i8,
    /// Steps, counted per pulse written.
    pub(super) position: i32,
    /// DIR level last handed out (`None`: never since boot).
    pub(super) direction: Option<bool>,
    /// No rising edge before this tick.
    pub(super) earliest: u64,
    /// Start of the open period.
    pub(super) cursor: u64,
    /// `high` of the open period (pulse width, or 0 for a filler).
    pub(super) open_high: u32,
    /// Position change of the open period (its pulse's sign, 0 for a filler).
    pub(super) open_delta: i8,
    /// Rising edge that ends the open period, once computed (`u64::MAX`: not yet).
    pub(super) next_rise: u64,
    /// When the joint moves on to its next segment: the fall of its last pulse, or the
    /// run's start.
    pub(super) seek_at: u64,
}

impl JointStream {
    pub(super) const IDLE: JointStream = JointStream {
        ordinal: 0,
        slot: 0,
        waiting: true,
        cruising: false,
        remaining: 0,
        fast: false,
        base: 0,
        ideal: 0,
        whole: 0,
        fraction: 0,
        remainder: 0,
        modulus: 1,
        wide_ideal: 0,
        wide_whole: 0,
        wide_fraction: 0,
        wide_remainder: 0,
        wide_modulus: 1,
        warped: false,
        parked: u64::MAX,
        sign: 1,
        position: 0,
        direction: None,
        earliest: 0,
        cursor: 0,
        open_high: 0,
        open_delta: 0,
        next_rise: u64::MAX,
        seek_at: 0,
    };

    /// Ideal tick of the next pulse (absolute), without advancing the clock.
    pub(super) fn next_ideal(&self) -> u64 {
        if self.fast {
            self.base + u64::from(self.ideal)
        } else {
            self.wide_ideal
        }
    }

    /// Ideal tick of the next pulse (absolute), advancing the clock past it.
    ///
    /// The u32 and u64 clocks step alike, written out twice on purpose: a generic helper
    /// (or one clock struct for both) cost the step path 0.4 instructions per step when
    /// measured (scripts/step-cost, 1 joint: 30.2 instead of 29.8; the limit is 30).
    #[inline]
    pub(super) fn take_ideal(&mut self) -> u64 {
        self.remaining -= 1;
        if self.fast {
            let ideal = self.base + u64::from(self.ideal);
            self.ideal += self.whole;
            self.remainder += self.fraction;
            if self.remainder >= self.modulus {
                self.remainder -= self.modulus;
                self.ideal += 1;
            }
            ideal
        } else {
            let ideal = self.wide_ideal;
            self.wide_ideal += self.wide_whole;
            self.wide_remainder += self.wide_fraction;
            if self.wide_remainder >= self.wide_modulus {
                self.wide_remainder -= self.wide_modulus;
                self.wide_ideal += 1;
            }
            ideal
        }
    }
}
