//! Why the chip last reset, from the RCC reset status register (RM0433, RCC_RSR): logged at
//! boot so that a watchdog reset or a brown-out in the field is seen, not guessed.
//!
//! Several flags are set together: a power-on reset also sets BORRSTF, PINRSTF and the domain
//! flags, and every internal reset (watchdog, software) also drives the NRST pin, so PINRSTF
//! comes with it. [`reset_cause`] reads them in that order: the most specific cause first,
//! the pin alone last.

/// RCC_RSR flags (RM0433, RCC reset status register).
pub mod rsr {
    /// Low-power reset (entering Standby or Stop with the option bytes saying so).
    pub const LPWRRSTF: u32 = 1 << 30;
    /// Window watchdog 1.
    pub const WWDG1RSTF: u32 = 1 << 28;
    /// Independent watchdog 1.
    pub const IWDG1RSTF: u32 = 1 << 26;
    /// System reset requested by the CPU (SCB AIRCR.SYSRESETREQ: the fault path's reset).
    pub const SFTRSTF: u32 = 1 << 24;
    /// Power-on (and power-down) reset.
    pub const PORRSTF: u32 = 1 << 23;
    /// The NRST pin (also set by every internal reset, which drives the pin).
    pub const PINRSTF: u32 = 1 << 22;
    /// Brown-out reset.
    pub const BORRSTF: u32 = 1 << 21;
    /// Writing it clears every flag.
    pub const RMVF: u32 = 1 << 16;
}

/// Why the chip reset.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ResetCause {
    /// Power applied (or restored after a power-down).
    PowerOn,
    /// The supply dropped under the brown-out threshold.
    Brownout,
    /// The IWDG was not fed: a hung task or executor (docs/BOARD.md, "Watchdog"), or a
    /// lockup.
    IndependentWatchdog,
    /// The window watchdog (not used by this firmware).
    WindowWatchdog,
    /// The firmware reset itself: the fault path's last step, or a debugger's reset.
    Software,
    /// A low-power mode entry configured to reset.
    LowPower,
    /// The reset button (NRST) or the debug probe pulling NRST.
    Pin,
    /// None of the flags above: the raw RCC_RSR value.
    Unknown(u32),
}

/// The cause RCC_RSR `rsr` records.
pub fn reset_cause(rsr: u32) -> ResetCause {
    use rsr::*;
    let set = |flag| rsr & flag != 0;
    if set(PORRSTF) {
        ResetCause::PowerOn
    } else if set(BORRSTF) {
        ResetCause::Brownout
    } else if set(IWDG1RSTF) {
        ResetCause::IndependentWatchdog
    } else if set(WWDG1RSTF) {
        ResetCause::WindowWatchdog
    } else if set(SFTRSTF) {
        ResetCause::Software
    } else if set(LPWRRSTF) {
        ResetCause::LowPower
    } else if set(PINRSTF) {
        ResetCause::Pin
    } else {
        ResetCause::Unknown(rsr)
    }
}

#[cfg(test)]
mod tests {
    use super::rsr::*;
    use super::*;

    /// D1 and D2 domain flags (bits 19, 20), set by every system reset.
    const DOMAINS: u32 = (1 << 19) | (1 << 20);

    #[test]
    fn each_reset_is_named_by_its_most_specific_flag() {
        // RM0433's table of flags per reset source: power-on sets POR, BOR, PIN and the domains.
        assert_eq!(
            reset_cause(PORRSTF | BORRSTF | PINRSTF | DOMAINS),
            ResetCause::PowerOn
        );
        assert_eq!(reset_cause(BORRSTF | PINRSTF), ResetCause::Brownout);
        // Internal resets drive NRST: the pin flag comes with them.
        assert_eq!(
            reset_cause(IWDG1RSTF | PINRSTF),
            ResetCause::IndependentWatchdog
        );
        assert_eq!(reset_cause(SFTRSTF | PINRSTF), ResetCause::Software);
        assert_eq!(reset_cause(WWDG1RSTF | PINRSTF), ResetCause::WindowWatchdog);
        assert_eq!(reset_cause(LPWRRSTF | PINRSTF), ResetCause::LowPower);
        assert_eq!(reset_cause(PINRSTF), ResetCause::Pin);
        assert_eq!(reset_cause(DOMAINS), ResetCause::Unknown(DOMAINS));
    }
}
