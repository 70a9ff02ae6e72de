//! What the H743's flash needs around each operation that embassy-stm32 0.6 does not do
//! (issue 20): [`UpkeptFlash`] wraps the HAL's flash for the settings store.
//!
//! - **Sticky error flags.** The HAL clears the bank's error flags by writing the status
//!   register back, a no-op on the H7, whose flags clear only through FLASH_CCR. It then
//!   reports any flag still set as the result of every later operation, so one error (the
//!   H743 sets RDPERR/RDSERR spontaneously) fails every settings save until a reset.
//!   The flags are cleared before each operation.
//! - **Cached flash.** Flash is cacheable: after an erase or a write, the D-cache may
//!   still hold the old bytes, which the next read would return. The changed range is
//!   invalidated after each.

use embedded_storage_async::nor_flash::{ErrorType, NorFlash, ReadNorFlash};

/// The chip's side of [`UpkeptFlash`].
pub trait FlashUpkeep {
    /// Clears the bank's error flags (on the H7: FLASH_CCR).
    fn clear_errors(&self);
    /// Bytes `from..to` (offsets in the flash) were erased or written: drop any cached
    /// copy of them.
    fn changed(&self, from: u32, to: u32);
}

/// `flash` with `upkeep` around every operation (see the module docs).
pub struct UpkeptFlash<F, U> {
    flash: F,
    upkeep: U,
}

impl<F, U> UpkeptFlash<F, U> {
    /// Wraps `flash`.
    pub fn new(flash: F, upkeep: U) -> Self {
        UpkeptFlash { flash, upkeep }
    }

    /// The flash back.
    pub fn into_inner(self) -> F {
        self.flash
    }
}

impl<F: ErrorType, U> ErrorType for UpkeptFlash<F, U> {
    type Error = F::Error;
}

impl<F: ReadNorFlash, U: FlashUpkeep> ReadNorFlash for UpkeptFlash<F, U> {
    const READ_SIZE: usize = F::READ_SIZE;

    async fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        self.upkeep.clear_errors();
        self.flash.read(offset, bytes).await
    }

    fn capacity(&self) -> usize {
        self.flash.capacity()
    }
}

impl<F: NorFlash, U: FlashUpkeep> NorFlash for UpkeptFlash<F, U> {
    const WRITE_SIZE: usize = F::WRITE_SIZE;
    const ERASE_SIZE: usize = F::ERASE_SIZE;

    async fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        self.upkeep.clear_errors();
        let result = self.flash.erase(from, to).await;
        // Also after a failed erase: part of the range may have changed.
        self.upkeep.changed(from, to);
        result
    }

    async fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        self.upkeep.clear_errors();
        let result = self.flash.write(offset, bytes).await;
        let end = u32::try_from(bytes.len()).map_or(u32::MAX, |n| offset.saturating_add(n));
        self.upkeep.changed(offset, end);
        result
    }
}

#[cfg(test)]
mod tests {
    use core::cell::{Cell, RefCell};

    use embassy_futures::block_on;
    use embedded_storage_async::nor_flash::{NorFlashError, NorFlashErrorKind};
    use sequential_storage::mock_flash::MockFlashBase;
    use std::vec::Vec;

    use super::*;
    use crate::settings::SettingsArea;
    use arm_core::hw::PersistentSettings;

    type Mock = MockFlashBase<4, 32, 64>;
    const RANGE: core::ops::Range<u32> = 0..(4 * 64 * 32);

    /// The H7's flags: an error flag, once set, stays set until cleared, and the HAL
    /// reports it as the result of every operation meanwhile (the operation itself is
    /// done). `changed` records the ranges reported.
    #[derive(Default)]
    struct Flags {
        error: Cell<bool>,
        changed: RefCell<Vec<(u32, u32)>>,
    }

    impl FlashUpkeep for &Flags {
        fn clear_errors(&self) {
            self.error.set(false);
        }
        fn changed(&self, from: u32, to: u32) {
            self.changed.borrow_mut().push((from, to));
        }
    }

    #[derive(Debug, Clone, Copy, PartialEq, Eq)]
    struct FlagSet;

    impl NorFlashError for FlagSet {
        fn kind(&self) -> NorFlashErrorKind {
            NorFlashErrorKind::Other
        }
    }

    /// A flash whose HAL reports the sticky flag (see [`Flags`]).
    struct StickyFlash<'a> {
        mock: Mock,
        flags: &'a Flags,
    }

    impl StickyFlash<'_> {
        fn result(&self, done: bool) -> Result<(), FlagSet> {
            if self.flags.error.get() || !done {
                Err(FlagSet)
            } else {
                Ok(())
            }
        }
    }

    impl ErrorType for StickyFlash<'_> {
        type Error = FlagSet;
    }

    impl ReadNorFlash for StickyFlash<'_> {
        const READ_SIZE: usize = Mock::READ_SIZE;
        async fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), FlagSet> {
            let done = self.mock.read(offset, bytes).await.is_ok();
            self.result(done)
        }
        fn capacity(&self) -> usize {
            self.mock.capacity()
        }
    }

    impl NorFlash for StickyFlash<'_> {
        const WRITE_SIZE: usize = Mock::WRITE_SIZE;
        const ERASE_SIZE: usize = Mock::ERASE_SIZE;
        async fn erase(&mut self, from: u32, to: u32) -> Result<(), FlagSet> {
            let done = self.mock.erase(from, to).await.is_ok();
            self.result(done)
        }
        async fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), FlagSet> {
            let done = self.mock.write(offset, bytes).await.is_ok();
            self.result(done)
        }
    }

    fn settings(joints: u8) -> PersistentSettings {
        PersistentSettings {
            joints,
            ..PersistentSettings::default()
        }
    }

    #[test]
    fn without_upkeep_one_error_flag_fails_every_later_save() {
        // What the board did before (issue 20): the flag set once is never cleared.
        let flags = Flags::default();
        let flash = StickyFlash {
            mock: Mock::default(),
            flags: &flags,
        };
        let mut area = SettingsArea::new(flash, RANGE);
        block_on(area.save(&settings(3))).unwrap();
        flags.error.set(true);
        for _ in 0..3 {
            assert!(block_on(area.save(&settings(4))).is_err());
        }
    }

    #[test]
    fn a_spontaneous_error_flag_costs_no_save_and_changed_ranges_are_reported() {
        let flags = Flags::default();
        let flash = StickyFlash {
            mock: Mock::default(),
            flags: &flags,
        };
        let mut area = SettingsArea::new(UpkeptFlash::new(flash, &flags), RANGE);
        block_on(area.save(&settings(3))).unwrap();
        // RDSERR set between two saves, by nothing the firmware did.
        flags.error.set(true);
        assert_eq!(
            block_on(area.save(&settings(4))),
            Ok(false),
            "not even an erase"
        );
        assert_eq!(block_on(area.load()).settings().joints, 4);
        // Every write reported its bytes; an erase reports its sectors.
        assert!(!flags.changed.borrow().is_empty());
        flags.changed.borrow_mut().clear();
        block_on(area.erase()).unwrap();
        let changed = flags.changed.borrow();
        assert!(
            changed
                .iter()
                .any(|&(from, to)| from == RANGE.start && to == RANGE.end)
                || changed.iter().map(|&(from, to)| to - from).sum::<u32>() >= RANGE.end,
            "{changed:?}"
        );
    }
}
