//! Issue 34 part C: the board's timing counters, sans-io (arm-core's `diag`), fed stamps
//! as the NUCLEO's critical section, step clock and refills feed them; and a STATUS with
//! request byte bit 6 is answered with a DIAG report from the bus's source, "not
//! measured" without one.

use arm_core::diag::{self, DirLateness, DmaSlack, MaskedSpans};
use protocol::Diag;

#[test]
fn the_longest_masked_span_keeps_its_opener_across_a_counter_wrap() {
    let mut spans = MaskedSpans::NEW;
    spans.open(100, 0x0800_1000);
    spans.close(140);
    spans.open(1_000, 0x0800_2000);
    spans.close(1_400);
    spans.open(5_000, 0x0800_3000);
    spans.close(5_100);
    assert_eq!(spans.max_cycles, 400);
    assert_eq!(spans.max_opener, 0x0800_2000);
    assert_eq!(spans.spans, 3);
    // Across CYCCNT's wrap: 0xffff_ff00 to 0x200 is 0x300 cycles.
    spans.open(0xffff_ff00, 0x0800_4000);
    spans.close(0x200);
    assert_eq!((spans.max_cycles, spans.max_opener), (0x300, 0x0800_4000));
    // A span of 0 cycles still names its opener when it is the first.
    let mut first = MaskedSpans::NEW;
    first.open(7, 0x0800_5000);
    first.close(7);
    assert_eq!(
        (first.max_cycles, first.max_opener, first.spans),
        (0, 0x0800_5000, 1)
    );
}

#[test]
fn dir_lateness_is_the_counter_against_the_compare_across_the_16_bit_wrap() {
    let mut dir = DirLateness::NEW;
    assert_eq!(dir.max_late_ticks, Diag::NO_DIR_WRITE);
    // Due at tick 0x1_0010 (compare 0x0010), written at counter 0x0035: 37 ticks late.
    dir.written(0x0035, 0x1_0010);
    assert_eq!(dir.max_late_ticks, 37);
    // Due just before the wrap, written just after it: 0xfffe -> 0x0003 is 5 ticks.
    dir.written(0x0003, 0x2_fffe);
    assert_eq!(dir.max_late_ticks, 37);
    dir.written(0x0100, 0x3_0000);
    assert_eq!(dir.max_late_ticks, 256);
    assert_eq!(dir.writes, 3);
    // An early write (never expected) reads negative and does not lower the latest.
    let mut early = DirLateness::NEW;
    early.written(0x0008, 0x0010);
    assert_eq!(early.max_late_ticks, -8);
}

#[test]
fn dma_slack_is_the_playing_periods_ticks_left() {
    // A circular buffer of 2 x 64 periods: after the half-transfer the next burst reads
    // period 64, the timer plays period 62 (63 is preloaded).
    assert_eq!(DmaSlack::playing(64, 128), 62);
    // After the transfer-complete: back at 0, playing 126.
    assert_eq!(DmaSlack::playing(0, 128), 126);
    assert_eq!(DmaSlack::playing(1, 128), 127);
    let mut dma = DmaSlack::NEW;
    assert_eq!(dma.min_ticks, Diag::NO_REFILL);
    // 100 kHz at 200 MHz: ARR 1999; counter 150 when the refill looked: 1850 left.
    dma.sampled(1_999, 150);
    assert_eq!(dma.min_ticks, 1_850);
    dma.sampled(1_999, 1_990);
    assert_eq!(dma.min_ticks, 10);
    // A counter past its reload counts as no slack at all.
    dma.sampled(99, 500);
    assert_eq!((dma.min_ticks, dma.refills), (0, 3));
}

#[test]
fn the_report_carries_the_counters_and_the_clocks() {
    let mut spans = MaskedSpans::NEW;
    spans.open(0, 0x0801_2345);
    spans.close(812);
    let mut dir = DirLateness::NEW;
    dir.written(37, 0);
    let mut dma = DmaSlack::NEW;
    dma.sampled(4_320, 0);
    let d = diag::report(spans, dir, dma, 400_000_000, 200_000_000);
    assert_eq!(
        d,
        Diag {
            cpu_hz: 400_000_000,
            masked_max_cycles: 812,
            masked_opener: 0x0801_2345,
            masked_spans: 1,
            step_hz: 200_000_000,
            dir_late_max_ticks: 37,
            dir_writes: 1,
            dma_slack_min_ticks: 4_321,
            dma_refills: 1,
        }
    );
    assert_eq!(d.masked_max_ns(), Some(2_030));
}

#[test]
fn the_bus_answers_not_measured_until_a_board_gives_its_source() {
    let bus = arm_core::Bus::new();
    assert_eq!(bus.diag(), Diag::NOT_MEASURED);
    fn board() -> Diag {
        Diag {
            cpu_hz: 400_000_000,
            ..Diag::NOT_MEASURED
        }
    }
    bus.set_diag_source(board);
    assert_eq!(bus.diag().cpu_hz, 400_000_000);
}

mod common;
use common::*;

/// STATUS's request byte bit 6: the owner's STATUS and a stranger's read-only one alike
/// ask for a DIAG report (with its own seq for the stranger); without the bit, none.
#[test]
fn status_bit_6_asks_for_the_diag_report() {
    use protocol::{Command, StatusAsk};
    let mut s = Session::<64>::new(64);
    let ask = StatusAsk {
        diag: true,
        ..StatusAsk::default()
    };
    let r = s.send_raw(HOST, &frame(1, Command::StatusWith(ask)));
    assert_eq!(r.reply.unwrap().ack.status, protocol::StatusCode::Ok);
    assert_eq!(r.asked_diag, Some(HOST));
    assert_eq!(r.asked_counters, None);
    assert_eq!(r.answer_seq, None, "the owner's: the report counter");
    let r = s.send_raw(OTHER, &frame(9, Command::StatusWith(ask)));
    assert_eq!(r.asked_diag, Some(OTHER));
    assert_eq!(r.answer_seq, Some(9));
    let r = s.send_raw(HOST, &frame(2, Command::Status));
    assert_eq!(r.asked_diag, None);
}
