//! Ethernet bring-up decisions: is the PHY's 50 MHz RMII reference clock there (without it
//! the MAC's DMA reset never completes), what did autonegotiation choose, and the link-loss
//! policy.
//!
//! Link-loss policy: a link that drops changes nothing in the controller. A run keeps
//! executing what is buffered; if the host cannot stream the rest in time, the underrun
//! rule stops the arm at the end of the last buffered point (STATUS bit 5), exactly as
//! with a host that stopped sending. The static address stays configured, the socket stays
//! bound, and the owner keeps ownership until its timeout: when the cable is back, the
//! same host carries on. Stopping the arm on link loss was rejected: a flaky cable would
//! turn into jerky stops mid-trajectory, and the host can always stop the arm itself
//! (STOPPED) once it is reachable; an operator who needs a stop without network uses the
//! drivers' own e-stop input.

/// Reads of the REF_CLK pin made to decide whether the clock runs.
pub const REF_CLK_SAMPLES: u32 = 4_096;
/// Each level must be seen at least this often: a 50 MHz square wave sampled at irregular
/// intervals gives about half and half; a dead or absent PHY gives one level only (the
/// pin has a pull-down).
pub const REF_CLK_MIN_EACH_LEVEL: u32 = REF_CLK_SAMPLES / 16;

/// Whether samples with `highs` high and `lows` low readings show a running clock.
pub const fn ref_clock_running(highs: u32, lows: u32) -> bool {
    highs >= REF_CLK_MIN_EACH_LEVEL && lows >= REF_CLK_MIN_EACH_LEVEL
}

/// Link speed and duplex, as autonegotiation settled them.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LinkMode {
    /// 100 Mbit/s (else 10).
    pub fast: bool,
    /// Full duplex (else half).
    pub full_duplex: bool,
}

/// LAN8742A register 31 (PHY special control/status): autodone bit.
pub const PSCSR_AUTODONE: u16 = 1 << 12;

/// The mode in the LAN8742A's register 31, once autonegotiation is done (bits 4:2: 001
/// 10BASE-T half, 101 10BASE-T full, 010 100BASE-TX half, 110 100BASE-TX full).
pub const fn link_mode(pscsr: u16) -> Option<LinkMode> {
    if pscsr & PSCSR_AUTODONE == 0 {
        return None;
    }
    match (pscsr >> 2) & 0b111 {
        0b001 => Some(LinkMode {
            fast: false,
            full_duplex: false,
        }),
        0b101 => Some(LinkMode {
            fast: false,
            full_duplex: true,
        }),
        0b010 => Some(LinkMode {
            fast: true,
            full_duplex: false,
        }),
        0b110 => Some(LinkMode {
            fast: true,
            full_duplex: true,
        }),
        _ => None,
    }
}

/// Seconds between attempts to bring the network up while the PHY is missing or dead.
pub const RETRY_SECONDS: u32 = 5;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_running_clock_shows_both_levels() {
        assert!(ref_clock_running(2000, 2096));
        assert!(!ref_clock_running(0, REF_CLK_SAMPLES), "no PHY: pulled low");
        assert!(!ref_clock_running(REF_CLK_SAMPLES, 0), "stuck high");
        assert!(
            !ref_clock_running(10, REF_CLK_SAMPLES - 10),
            "a glitch is not a clock"
        );
    }

    #[test]
    fn register_31_decodes_to_speed_and_duplex() {
        let done = PSCSR_AUTODONE;
        assert_eq!(
            link_mode(done | 0b110 << 2),
            Some(LinkMode {
                fast: true,
                full_duplex: true
            })
        );
        assert_eq!(
            link_mode(done | 0b010 << 2),
            Some(LinkMode {
                fast: true,
                full_duplex: false
            })
        );
        assert_eq!(
            link_mode(done | 0b101 << 2),
            Some(LinkMode {
                fast: false,
                full_duplex: true
            })
        );
        assert_eq!(
            link_mode(done | 0b001 << 2),
            Some(LinkMode {
                fast: false,
                full_duplex: false
            })
        );
        assert_eq!(link_mode(0b110 << 2), None, "not negotiated yet");
        assert_eq!(link_mode(done | 0b111 << 2), None, "reserved code");
    }
}
