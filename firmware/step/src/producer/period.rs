//! What the producer writes: timer periods for the DMA, and what one fill wrote.

/// One timer period of a joint's STEP output, laid out for the timer's DMA burst
/// (ARR, RCR, CCR1: `DCR.DBA` = ARR, three transfers per update).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PulsePeriod {
    /// Period length in ticks, minus one (ARR).
    pub reload: u32,
    /// Always 0 (RCR: one period per update event; a reserved word on timers that have no
    /// repetition counter).
    pub repetition: u32,
    /// STEP high time from the period's start, ticks (CCR1 in PWM mode 1); 0: no pulse.
    pub high: u32,
}

/// The sign of each pulse in `periods` as [`crate::PulseProducer::fill`] marked them in `signs`
/// (0 for periods without a pulse), starting from `sign` for pulses before the first mark.
pub fn sign_of(periods: &[PulsePeriod], signs: &[i8], mut sign: i8) -> impl Iterator<Item = i8> {
    periods.iter().zip(signs).map(move |(period, &mark)| {
        if mark != 0 {
            sign = mark;
        }
        if period.high != 0 { sign } else { 0 }
    })
}

impl PulsePeriod {
    /// A zeroed period (one tick, no pulse): what a buffer holds before its first fill.
    pub const ZERO: PulsePeriod = PulsePeriod {
        reload: 0,
        repetition: 0,
        high: 0,
    };

    /// Length in ticks.
    pub const fn ticks(&self) -> u64 {
        self.reload as u64 + 1
    }
}

/// What one [`crate::PulseProducer::fill`] wrote.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Filled {
    /// Pulses written (periods with `high > 0`).
    pub pulses: u32,
    /// Position change of the last period written (its pulse's sign, 0 for none): what
    /// a stop must take back if that period never started after its buffer half was
    /// refilled over (`StepStreams` keeps it).
    pub last_sign: i8,
    /// Segments every joint has now been through (their slots are free).
    pub segments_finished: u32,
    /// Tick at which the written periods end (where the next fill continues).
    pub end_tick: u64,
    /// Whether the joint has nothing left to do in the queued segments: the written periods
    /// after its last pulse are idle fillers.
    pub idle: bool,
    /// Every period written is the same idle period, of this many ticks: a buffer half
    /// that holds these needs no rewrite while the joint would write the same
    /// ([`crate::PulseProducer::idle_period`], [`crate::PulseProducer::skip_idle`]).
    pub uniform_idle: Option<u32>,
}
