//! Marks for `scripts/qemu-cost`: empty functions that are never inlined, called where a
//! measured path starts or ends. QEMU's exec trace (`-d exec,nochain -singlestep`) names
//! the function of every executed instruction, so the script counts the instructions
//! between a start mark and an end mark. Each costs a call, a store and a return: the store
//! is volatile, so that the optimiser keeps the function and its calls, and the stored
//! values differ, so that no two marks are merged into one function.

use core::sync::atomic::AtomicU32;

/// The last mark passed.
static LAST_MARK: AtomicU32 = AtomicU32::new(0);

fn mark(n: u32) {
    // SAFETY: an aligned u32 inside the atomic; a volatile store cannot be elided.
    unsafe { LAST_MARK.as_ptr().write_volatile(n) }
}

/// The LAN9118 interrupt handler was entered (a frame arrived).
#[unsafe(no_mangle)]
#[inline(never)]
pub extern "C" fn qemu_mark_nic_irq() {
    mark(1);
}

/// A frame was written to the LAN9118's TX FIFO.
#[unsafe(no_mangle)]
#[inline(never)]
pub extern "C" fn qemu_mark_frame_sent() {
    mark(2);
}

/// A stop (`StepBackend::stop`, in the task that handles STOPPED, or the fault path) has
/// lowered every STEP line: the step output is stopped.
#[unsafe(no_mangle)]
#[inline(never)]
pub extern "C" fn qemu_mark_steps_stopped() {
    mark(3);
}

/// See [`qemu_mark_steps_stopped`].
pub fn step_output_stopped() {
    qemu_mark_steps_stopped();
}
