//! The DMA2 streams' half-transfer and transfer-complete interrupts: each refills the
//! half its stream just left, or stops everything on an underrun or a transfer error.

use arm_core::{StepBackend, StepProgress};
use arm_step::MAX_JOINTS;
use embassy_stm32::{interrupt, pac};

use super::registers::{BUFFER_WORDS, WORDS_PER_PERIOD, clear_stream_flags};
use super::{HALF, STEP};

/// The streams' interrupts, joint order.
pub(super) const STREAM_IRQS: [interrupt::Interrupt; MAX_JOINTS] = [
    interrupt::DMA2_STREAM0,
    interrupt::DMA2_STREAM1,
    interrupt::DMA2_STREAM2,
    interrupt::DMA2_STREAM3,
    interrupt::DMA2_STREAM4,
    interrupt::DMA2_STREAM5,
    interrupt::DMA2_STREAM6,
    interrupt::DMA2_STREAM7,
];

/// The body of joint `joint`'s stream interrupt: refill the half the stream left, or stop
/// everything on an underrun or a transfer error.
fn refill(joint: usize) {
    let n = joint % 4;
    let flags = pac::DMA2.isr(joint / 4).read();
    clear_stream_flags(joint);
    let (half_played, full_played) = (flags.htif(n), flags.tcif(n));
    let remaining = pac::DMA2.st(joint).ndtr().read().ndt() as usize;
    let next = BUFFER_WORDS.saturating_sub(remaining) / WORDS_PER_PERIOD;
    // HT: half 0 played, the stream is in half 1. TC: half 1 played, back in half 0.
    let half = usize::from(full_played);
    let in_half = next / HALF;
    let underrun = flags.teif(n) || (half_played && full_played) || in_half == half;
    if half_played || full_played {
        super::registers::sample_slack(joint, next);
    }
    STEP.on_interrupt(&crate::BUS.step_progress, |steps| {
        if !half_played && !full_played {
            return ((), StepProgress::default());
        }
        if underrun {
            // The stream reached periods that were never refilled: stop as for STOPPED;
            // the controller sees the run end early (STATUS underrun flag).
            defmt::warn!("step stream {} underrun", joint);
            steps.stop();
            return (
                (),
                StepProgress {
                    segments_finished: 0,
                    ran_dry: true,
                },
            );
        }
        ((), steps.refill(joint, half))
    });
}

#[interrupt]
fn DMA2_STREAM0() {
    refill(0);
}
#[interrupt]
fn DMA2_STREAM1() {
    refill(1);
}
#[interrupt]
fn DMA2_STREAM2() {
    refill(2);
}
#[interrupt]
fn DMA2_STREAM3() {
    refill(3);
}
#[interrupt]
fn DMA2_STREAM4() {
    refill(4);
}
#[interrupt]
fn DMA2_STREAM5() {
    refill(5);
}
#[interrupt]
fn DMA2_STREAM6() {
    refill(6);
}
#[interrupt]
fn DMA2_STREAM7() {
    refill(7);
}
