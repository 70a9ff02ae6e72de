//! [`Late`]: a `static` built at run time, so that a value whose `const` constructor has
//! non-zero bytes costs no flash.
//!
//! A static with a `const` initialiser is stored whole in flash (`.data`) and copied to RAM
//! at boot as soon as one of its bytes is not zero: `Bus::new()` is 23 KiB of that. A
//! `Late<T>` is zero bytes of flash (`.bss`) and is written once at the start of `main`,
//! before anything can reach it. Use it for every big static whose initial value is not
//! all zeros; one whose initial value is all zeros (`step_dma::STEP`) is a plain `static`.

use core::cell::UnsafeCell;
use core::mem::MaybeUninit;
use core::ops::Deref;

/// A `static` written once by [`Late::init`] before its first use.
pub struct Late<T>(UnsafeCell<MaybeUninit<T>>);

// SAFETY: written once by `init` before any task, interrupt or other reference exists
// (the caller's promise); after that only shared references are handed out, which is
// sound for a `Sync` value.
unsafe impl<T: Sync> Sync for Late<T> {}

impl<T> Late<T> {
    /// Not yet initialised (`.bss`).
    pub const fn new() -> Self {
        Late(UnsafeCell::new(MaybeUninit::uninit()))
    }

    /// Builds the value.
    ///
    /// # Safety
    /// Call once, before anything dereferences this static: first thing in `main`, before
    /// interrupts that use it are enabled and before tasks are spawned.
    pub unsafe fn init(&self, value: T) {
        // SAFETY: the caller guarantees nothing else has a reference yet.
        unsafe { (*self.0.get()).write(value) };
    }
}

impl<T> Deref for Late<T> {
    type Target = T;

    fn deref(&self) -> &T {
        // SAFETY: `init` ran first thing in `main` (see its contract), before anything that
        // can reach this static.
        unsafe { (*self.0.get()).assume_init_ref() }
    }
}
