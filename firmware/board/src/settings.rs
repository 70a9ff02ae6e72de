//! Persistent settings in the last two 128 KiB sectors of flash bank 2, as a
//! `sequential-storage` map (wear-levelled, power-fail safe, CRC-checked items), with
//! board-logic's recovery: a corrupted area is erased to defaults, a save that fails
//! erases and stores again.
//!
//! Bank 2 is written while the code runs from bank 1 (read-while-write), so an erase
//! (about 2 s for a sector) stalls neither the step interrupt nor the network; the async
//! flash driver yields while the flash is busy. `memory.x` ends FLASH at
//! [`SETTINGS_START`], so the program can never grow into these sectors (the link fails).
//!
//! ECC double errors: a flash word whose programming was cut by a power loss can read
//! with an uncorrectable ECC error, which the H7 reports as a bus fault. The read is
//! bracketed by a marker in `.uninit` RAM (kept across the fault path's reset): a boot
//! that finds the marker still set erases the area before reading (one extra reset, then
//! defaults), instead of faulting on every boot.

use core::mem::MaybeUninit;

use arm_core::hw::PersistentSettings;
use board_logic::flash_upkeep::{FlashUpkeep, UpkeptFlash};
use board_logic::settings::{BootMarker, LoadOutcome, SettingsArea, must_erase_first};
use defmt::{info, warn};
use embassy_stm32::flash::{Async, Flash};
use embassy_stm32::pac;

/// First byte (offset from the start of flash) of the settings area: bank 2 sector 6.
pub const SETTINGS_START: u32 = 0x1C_0000;
/// End of the settings area: the end of flash (2 MiB). Two sectors, the least a
/// sequential-storage map works with.
pub const SETTINGS_END: u32 = 0x20_0000;
// Bank2Upkeep clears bank 2's flags: the area must lie in bank 2 (the second MiB).
const _: () = assert!(SETTINGS_START >= 0x10_0000 && SETTINGS_END <= 0x20_0000);

/// Why settings could not be written.
pub type StoreError = board_logic::settings::StoreError<embassy_stm32::flash::Error>;

/// Set while a read of the settings area is under way; survives a reset (not zeroed).
#[unsafe(link_section = ".uninit.SETTINGS_READ_MARK")]
static mut SETTINGS_READ_MARK: MaybeUninit<u32> = MaybeUninit::uninit();

fn read_mark() -> u32 {
    // SAFETY: a plain 32-bit location; any bit pattern is a valid u32, and only thread
    // mode touches it (before and during the settings reads, never from interrupts).
    unsafe {
        core::ptr::addr_of!(SETTINGS_READ_MARK)
            .cast::<u32>()
            .read_volatile()
    }
}

fn write_mark(value: u32) {
    // SAFETY: as in `read_mark`.
    unsafe {
        core::ptr::addr_of_mut!(SETTINGS_READ_MARK)
            .cast::<u32>()
            .write_volatile(value)
    }
}

/// Start of the flash in the address space: offsets are from here.
const FLASH_BASE: u32 = 0x0800_0000;

/// Bank 2's upkeep around the HAL's operations (board-logic's `flash_upkeep`, issue 20).
pub struct Bank2Upkeep;

impl FlashUpkeep for Bank2Upkeep {
    fn clear_errors(&self) {
        // FLASH_CCR2: the H7 clears its status flags here only (RM0433, FLASH_CCR);
        // embassy-stm32 writes FLASH_SR, which does nothing.
        pac::FLASH
            .bank(1)
            .ccr()
            .write_value(pac::flash::regs::Ccr(CCR_CLEAR_ALL));
    }

    fn changed(&self, from: u32, to: u32) {
        // SAFETY: invalidating the D-cache lines of flash bytes that just changed, which
        // nothing has written through the cache (flash is written by its controller only):
        // no dirty data is lost. The SCB is only borrowed for this call.
        unsafe {
            let mut core = cortex_m::Peripherals::steal();
            core.SCB.invalidate_dcache_by_address(
                (FLASH_BASE + from) as usize,
                to.saturating_sub(from) as usize,
            );
        }
    }
}

/// FLASH_CCR's clear bits: EOP, WRPERR, PGSERR, STRBERR, INCERR, OPERR, RDPERR, RDSERR,
/// SNECCERR, DBECCERR, CRCEND, CRCRDERR (bits 16-28 but 20, RM0433).
const CCR_CLEAR_ALL: u32 = 0x1FEF_0000;

/// [`arm_core::hw::SettingsStore`] on the internal flash.
pub struct FlashSettings {
    area: SettingsArea<UpkeptFlash<Flash<'static, Async>, Bank2Upkeep>>,
    /// The user button (B1, PC13) was held at reset: the stored key is cleared at load
    /// (docs/PROTOCOL.md section 13: the way back when the key is lost).
    clear_key: bool,
}

impl FlashSettings {
    /// Uses the settings area of `flash`.
    pub fn new(flash: Flash<'static, Async>) -> Self {
        FlashSettings {
            area: SettingsArea::new(
                UpkeptFlash::new(flash, Bank2Upkeep),
                SETTINGS_START..SETTINGS_END,
            ),
            clear_key: false,
        }
    }

    /// Clears a stored key at the next load (the user button held at reset).
    pub fn set_clear_key(&mut self, clear: bool) {
        self.clear_key = clear;
    }

    /// Reads the settings (marker set around the read, area erased first if the previous
    /// boot's read faulted); logs what it found.
    pub async fn read(&mut self) -> LoadOutcome {
        if must_erase_first(read_mark()) {
            warn!("settings: the previous read faulted (ECC error?): erasing the area");
            if let Err(e) = self.area.erase().await {
                warn!("settings: erase failed: {}", e);
            }
        }
        write_mark(BootMarker::READING);
        let outcome = self.area.load().await;
        write_mark(BootMarker::IDLE);
        // Stored(..), Empty (defaults), Erased (corrupted, erased: defaults), Unreadable.
        info!("settings: {}", outcome);
        outcome
    }
}

impl arm_core::hw::SettingsStore for FlashSettings {
    type Error = StoreError;

    async fn load(&mut self) -> Result<Option<PersistentSettings>, Self::Error> {
        Ok(match self.read().await {
            LoadOutcome::Stored(s) if self.clear_key && s.key.is_some() => {
                let cleared = PersistentSettings { key: None, ..s };
                self.save(&cleared).await?;
                warn!("settings: user button held at reset: authentication key cleared");
                Some(cleared)
            }
            LoadOutcome::Stored(s) => Some(s),
            _ => None,
        })
    }

    async fn save(&mut self, settings: &PersistentSettings) -> Result<(), Self::Error> {
        if self.area.save(settings).await? {
            warn!("settings: the area was corrupted: erased and stored again");
        }
        Ok(())
    }
}
