//! Where a joint's step DMA stream stands, from its NDTR and its half-transfer and
//! transfer-complete flags (`firmware/board/src/step_dma/registers.rs` reads them), and the
//! stop's rule for the transfer-complete flag that clearing EN sets.
//!
//! The stream plays a circular buffer of `2 * HALF` periods, [`WORDS_PER_PERIOD`] words each
//! (one timer DMA burst per update event). HTIF set: half 0 was played and its refill
//! interrupt has not run yet; TCIF set: the same for half 1. The stop unwinds the periods
//! written but not played from this ([`stream_position`]), so the flags it reads must be the
//! transfers' own.
//!
//! RM0433 (Rev 7) section 15.3 "DMA functional description", "DMA transfer suspension" (the
//! same text in RM0399 16.3.16 and RM0090 10.3.14; zephyr's STM32 DMA driver waits for EN = 0
//! and clears TCIF after a disable for this reason, zephyrproject-rtos/zephyr#55312): a stream
//! disabled by software (EN cleared) first completes the transfer under way, then "the
//! transfer complete interrupt flag (TCIF in the DMA_LISR or DMA_HISR register) is set in
//! order to indicate the end of transfer", EN reads 0, and NDTR holds the items left. That TCIF says nothing about half 1: read as "half 1 played and not refilled",
//! it made the stop count half 1's pulses as played while they were not (Renode's RM0433
//! DMA model: joint 0 reported +124 with +60 pulses made). [`tcif_from_disable`] tells it
//! from a real one, so the stop can clear it right after the disable.

/// Words the stream moves per period: one DMA burst of ARR, RCR, CCR1.
pub const WORDS_PER_PERIOD: usize = 3;

/// Where a stream stood (running, or when it was stopped).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct StreamPosition {
    /// Index (0..2*HALF) of the next period the stream would have transferred.
    pub next: usize,
    /// The half other than the one of the first unplayed period (`next - 1`, in the
    /// preload register) was played and not refilled yet (its interrupt was pending).
    pub other_half_played: bool,
    /// The first unplayed period (`next - 1`) is the last of its half and that half was
    /// refilled since: the period lives on only in the preload register.
    pub preload_evicted: bool,
}

/// Where a stream of `2 * HALF` periods stands: `remaining` = NDTR (words left before the
/// buffer's end), `htif`/`tcif` its flags as the transfers set them (not a TCIF set by
/// clearing EN: [`tcif_from_disable`]).
pub fn stream_position<const HALF: usize>(
    remaining: usize,
    htif: bool,
    tcif: bool,
) -> StreamPosition {
    let buffer_words = 2 * HALF * WORDS_PER_PERIOD;
    // A burst cut short (the stop clears the timer's DMA request between its transfers)
    // counts as transferred: its update event came, so the period in the preload register
    // then started and made its pulse (issue 34: floored, the stop counted one step short
    // with 100 ns pulses). Rounded up.
    let moved = buffer_words.saturating_sub(remaining);
    let done = moved.div_ceil(WORDS_PER_PERIOD);
    let cut = !moved.is_multiple_of(WORDS_PER_PERIOD);
    let next = done % (2 * HALF);
    // The first unplayed period is the one in the preload register (next - 1); the other
    // half than its own is stale if its refill is still pending (HT: half 0 played, TC:
    // half 1 played).
    let preload = (next + 2 * HALF - 1) % (2 * HALF);
    let unplayed_half = preload / HALF;
    let (own_flag, other_flag) = if unplayed_half == 0 {
        (htif, tcif)
    } else {
        (tcif, htif)
    };
    StreamPosition {
        next,
        other_half_played: other_flag,
        // The half's end was read (its flag was raised); not pending any more: refilled.
        // Not after a cut burst: that burst never finished reading the half's end, so its
        // flag was never raised, and the half was not refilled.
        preload_evicted: preload % HALF == HALF - 1 && !own_flag && !cut,
    }
}

/// What the stop reads of a stream before it clears EN (its timer already stopped, so no
/// new request comes): NDTR first, then TCIF.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BeforeDisable {
    /// NDTR.
    pub ndtr: u16,
    /// TCIF.
    pub tcif: bool,
}

/// Whether the TCIF a stream shows once its EN reads 0 was set by the disable alone (and is
/// to be cleared) rather than by the transfers: `before` was read before EN was cleared,
/// `ndtr_after` once EN reads 0.
///
/// A real TCIF is set by the transfer that reaches the buffer's end, which reloads NDTR
/// (circular mode: NDTR never reads 0). So if TCIF was clear before the disable and NDTR
/// has not gone up since, no transfer reached the end: the TCIF is the disable's. If NDTR
/// went up, a transfer still under way (a request taken before the timer stopped) wrapped
/// the buffer: the TCIF is real. NDTR is read before TCIF so that a wrap between the two
/// reads shows as TCIF set before, never as an NDTR that did not go up. A stream cannot go
/// round its whole buffer between the reads (the timer is stopped: at most one burst is
/// under way).
pub fn tcif_from_disable(before: BeforeDisable, ndtr_after: u16) -> bool {
    !before.tcif && ndtr_after <= before.ndtr
}

#[cfg(test)]
mod tests {
    use super::*;

    const HALF: usize = 4;
    const WORDS: usize = 2 * HALF * WORDS_PER_PERIOD;

    #[test]
    fn ndtr_gives_the_next_period() {
        assert_eq!(stream_position::<HALF>(WORDS, false, false).next, 0);
        assert_eq!(
            stream_position::<HALF>(WORDS - WORDS_PER_PERIOD, false, false).next,
            1
        );
        // A burst cut short counts as transferred: its update event started the preload's
        // period (issue 34; this asserted 1, "not transferred", before).
        assert_eq!(
            stream_position::<HALF>(WORDS - WORDS_PER_PERIOD - 1, false, false).next,
            2
        );
        // Cut in the buffer's last period: back at 0.
        assert_eq!(stream_position::<HALF>(2, false, false).next, 0);
        assert_eq!(
            stream_position::<HALF>(WORDS_PER_PERIOD, false, false).next,
            2 * HALF - 1
        );
    }

    #[test]
    fn a_tcif_reads_as_half_1_played_while_the_preload_is_in_half_0() {
        // The preload period is buffer index 1 (next = 2): a TCIF says half 1 holds played
        // periods, so they are not counted as unplayed. Hence the disable's TCIF must go.
        let at = stream_position::<HALF>(WORDS - 2 * WORDS_PER_PERIOD, false, true);
        assert_eq!(
            at,
            StreamPosition {
                next: 2,
                other_half_played: true,
                preload_evicted: false
            }
        );
        let at = stream_position::<HALF>(WORDS - 2 * WORDS_PER_PERIOD, false, false);
        assert!(!at.other_half_played);
    }

    #[test]
    fn the_preload_is_evicted_once_its_half_is_refilled() {
        // next = HALF: the preload is half 0's last period, read by the DMA (HT raised).
        let remaining = WORDS - HALF * WORDS_PER_PERIOD;
        assert!(!stream_position::<HALF>(remaining, true, false).preload_evicted);
        assert!(stream_position::<HALF>(remaining, false, false).preload_evicted);
        // next = 0 (wrapped): half 1's last period, its flag TC.
        assert!(!stream_position::<HALF>(WORDS, false, true).preload_evicted);
        assert!(stream_position::<HALF>(WORDS, false, false).preload_evicted);
    }

    #[test]
    fn the_disables_tcif_is_told_from_a_transfers() {
        let clear = |ndtr| BeforeDisable { ndtr, tcif: false };
        // Nothing moved: the TCIF is the disable's.
        assert!(tcif_from_disable(clear(9), 9));
        // A burst under way moved on, within the buffer: still the disable's.
        assert!(tcif_from_disable(clear(9), 6));
        assert!(tcif_from_disable(clear(9), 8));
        // A burst under way reached the end: NDTR reloaded, a real TCIF.
        assert!(!tcif_from_disable(clear(3), WORDS as u16));
        assert!(!tcif_from_disable(clear(1), WORDS as u16 - 2));
        // Pending before the disable: real whatever NDTR does.
        assert!(!tcif_from_disable(
            BeforeDisable {
                ndtr: 9,
                tcif: true
            },
            9
        ));
    }
}
