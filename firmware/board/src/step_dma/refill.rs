//! The step streams' half-transfer and transfer-complete interrupts (DMA1 streams 0-3 for
//! joints 0-3, DMA2 streams 0-3 for joints 4-7: `registers::joint_stream`): each refills
//! the half its stream just left, or stops everything on an underrun or a transfer error.

use arm_core::{StepBackend, StepProgress};
use arm_step::MAX_JOINTS;
use embassy_stm32::interrupt;

use super::registers::{BUFFER_WORDS, WORDS_PER_PERIOD, clear_stream_flags, joint_stream};
use super::{HALF, STEP};

/// The streams' interrupts, joint order.
pub(super) const STREAM_IRQS: [interrupt::Interrupt; MAX_JOINTS] = [
    interrupt::DMA1_STREAM0,
    interrupt::DMA1_STREAM1,
    interrupt::DMA1_STREAM2,
    interrupt::DMA1_STREAM3,
    interrupt::DMA2_STREAM0,
    interrupt::DMA2_STREAM1,
    interrupt::DMA2_STREAM2,
    interrupt::DMA2_STREAM3,
];

/// The body of joint `joint`'s stream interrupt: refill the half the stream left, or stop
/// everything on an underrun or a transfer error.
fn refill(joint: usize) {
    let (dma, number) = joint_stream(joint);
    let n = number % 4;
    let flags = dma.isr(number / 4).read();
    clear_stream_flags(joint);
    let (half_played, full_played) = (flags.htif(n), flags.tcif(n));
    let remaining = dma.st(number).ndtr().read().ndt() as usize;
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
fn DMA1_STREAM0() {
    refill(0);
}
#[interrupt]
fn DMA1_STREAM1() {
    refill(1);
}
#[interrupt]
fn DMA1_STREAM2() {
    refill(2);
}
#[interrupt]
fn DMA1_STREAM3() {
    refill(3);
}
#[interrupt]
fn DMA2_STREAM0() {
    refill(4);
}
#[interrupt]
fn DMA2_STREAM1() {
    refill(5);
}
#[interrupt]
fn DMA2_STREAM2() {
    refill(6);
}
#[interrupt]
fn DMA2_STREAM3() {
    refill(7);
}
