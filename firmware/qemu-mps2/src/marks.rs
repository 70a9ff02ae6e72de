//! Marks for `scripts/qemu-cost`: empty functions that are never inlined, called where a
//! measured path starts or ends. QEMU's exec trace (`-d exec,nochain -singlestep`) names
//! the function of every executed instruction, so the script counts the instructions
//! between a start mark and an end mark. Each costs a call, a store and a return; the
//! stored values differ so that no two marks are merged into one function.

use core::sync::atomic::{AtomicU32, Ordering};

/// The last mark passed.
static LAST_MARK: AtomicU32 = AtomicU32::new(0);

/// The LAN9118 interrupt handler was entered (a frame arrived).
#[unsafe(no_mangle)]
#[inline(never)]
pub extern "C" fn qemu_mark_nic_irq() {
    LAST_MARK.store(1, Ordering::Relaxed);
}

/// A frame was written to the LAN9118's TX FIFO.
#[unsafe(no_mangle)]
#[inline(never)]
pub extern "C" fn qemu_mark_frame_sent() {
    LAST_MARK.store(2, Ordering::Relaxed);
}

/// The step interrupt lowered every STEP line after a stop: the step output is stopped.
#[unsafe(no_mangle)]
#[inline(never)]
pub extern "C" fn qemu_mark_steps_stopped() {
    LAST_MARK.store(3, Ordering::Relaxed);
}

/// See [`qemu_mark_steps_stopped`].
pub fn step_output_stopped() {
    qemu_mark_steps_stopped();
}
