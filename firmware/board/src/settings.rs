//! Persistent settings in the last two 128 KiB sectors of flash bank 2, as a
//! `sequential-storage` map (wear-levelled, power-fail safe, CRC-checked items).
//!
//! Bank 2 is written while the code runs from bank 1 (read-while-write), so an erase
//! (about 2 s for a sector) stalls neither the step interrupt nor the network; the async
//! flash driver yields while the flash is busy.

use arm_core::hw::PersistentSettings;
use embassy_stm32::flash::{Async, Flash};
use sequential_storage::cache::{Cache, Uncached};
use sequential_storage::map::{MapConfig, MapStorage};

/// First byte (offset from the start of flash) of the settings area: bank 2 sector 6.
pub const SETTINGS_START: u32 = 0x1C_0000;
/// End of the settings area: the end of flash (2 MiB). Two sectors, the least a
/// sequential-storage map works with.
pub const SETTINGS_END: u32 = 0x20_0000;

/// Map key of the settings record.
const SETTINGS_KEY: u8 = 1;
/// Layout version in the record's first byte: a record written by another layout is
/// ignored (defaults apply) rather than misread.
const RECORD_VERSION: u8 = 1;
/// Bytes of the record: version, joints, ip[4], prefix_len, reserved.
const RECORD_LEN: usize = 8;
/// Map key of the network record NET_SET added (gateway, DHCP), beside the first record
/// so that a record written before it still loads.
const NET_KEY: u8 = 2;
/// Bytes of the network record: gateway[4], flags (bit 0: DHCP), reserved.
const NET_RECORD_LEN: usize = 6;

/// Scratch for one item: key + record + item header, rounded up to the H7's 32-byte flash
/// word (32-byte aligned, as the flash driver writes whole words from it).
#[repr(C, align(32))]
struct ItemBuffer([u8; 64]);

/// The stored record for `settings`.
pub const fn encode(settings: &PersistentSettings) -> [u8; RECORD_LEN] {
    let [a, b, c, d] = settings.ip;
    [
        RECORD_VERSION,
        settings.joints,
        a,
        b,
        c,
        d,
        settings.prefix_len,
        0,
    ]
}

/// The settings in a stored record, if it is one this firmware wrote and its values are
/// in range.
pub fn decode(record: &[u8; RECORD_LEN]) -> Option<PersistentSettings> {
    let [version, joints, a, b, c, d, prefix_len, _] = *record;
    let valid =
        version == RECORD_VERSION && protocol::limits::JOINTS.contains(&joints) && prefix_len <= 32;
    valid.then_some(PersistentSettings {
        joints,
        ip: [a, b, c, d],
        prefix_len,
        ..PersistentSettings::DEFAULT
    })
}

/// The stored network record (NET_SET) for `settings`.
pub const fn encode_net(settings: &PersistentSettings) -> [u8; NET_RECORD_LEN] {
    let [a, b, c, d] = settings.gateway;
    [a, b, c, d, settings.dhcp as u8, 0]
}

/// `settings` with the gateway and DHCP choice of a stored network record.
pub fn decode_net(
    settings: PersistentSettings,
    record: &[u8; NET_RECORD_LEN],
) -> PersistentSettings {
    let [a, b, c, d, flags, _] = *record;
    PersistentSettings {
        gateway: [a, b, c, d],
        dhcp: flags & 1 != 0,
        ..settings
    }
}

/// Why settings could not be read or written.
pub type StoreError = sequential_storage::Error<embassy_stm32::flash::Error>;

/// [`arm_core::hw::SettingsStore`] on the internal flash.
pub struct FlashSettings {
    map: MapStorage<u8, Flash<'static, Async>, Cache<Uncached, Uncached, Uncached, u8>>,
    buffer: ItemBuffer,
}

impl FlashSettings {
    /// Uses the settings area of `flash`.
    pub fn new(flash: Flash<'static, Async>) -> Self {
        FlashSettings {
            map: MapStorage::new(
                flash,
                const { MapConfig::new(SETTINGS_START..SETTINGS_END) },
                Cache::new_uncached(),
            ),
            buffer: ItemBuffer([0; 64]),
        }
    }

    /// Reads the settings before the tasks start (the address is needed for the network).
    pub async fn read(&mut self) -> Result<Option<PersistentSettings>, StoreError> {
        let record = self
            .map
            .fetch_item::<[u8; RECORD_LEN]>(&mut self.buffer.0, &SETTINGS_KEY)
            .await?;
        let Some(settings) = record.as_ref().and_then(decode) else {
            return Ok(None);
        };
        let net = self
            .map
            .fetch_item::<[u8; NET_RECORD_LEN]>(&mut self.buffer.0, &NET_KEY)
            .await?;
        Ok(Some(match net {
            Some(net) => decode_net(settings, &net),
            None => settings,
        }))
    }
}

impl arm_core::hw::SettingsStore for FlashSettings {
    type Error = StoreError;

    async fn load(&mut self) -> Result<Option<PersistentSettings>, Self::Error> {
        self.read().await
    }

    async fn save(&mut self, settings: &PersistentSettings) -> Result<(), Self::Error> {
        self.map
            .store_item(&mut self.buffer.0, &SETTINGS_KEY, &encode(settings))
            .await?;
        self.map
            .store_item(&mut self.buffer.0, &NET_KEY, &encode_net(settings))
            .await
    }
}
