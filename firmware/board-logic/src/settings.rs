//! The persisted settings: the record's layout, and a store on any NOR flash
//! (sequential-storage's map) that recovers from corruption instead of failing forever.
//!
//! Recovery rules:
//! * A read that finds the area corrupted (sequential-storage cannot repair it) erases the
//!   whole area and continues on defaults ([`LoadOutcome::Erased`]).
//! * A save that fails for any reason erases the area and stores again once; a second failure is reported (the controller keeps running on what it
//!   has, and the next save tries again).
//! * A write cut by power loss can leave a flash word with an ECC double error; on the H7,
//!   reading it is a bus fault, so the boot-time read faults (and, through the fault path,
//!   resets) on every boot. The board sets a marker in RAM that survives the reset
//!   ([`BootMarker`]) before the read and clears it after: a boot that finds it set knows
//!   the previous read faulted and erases the area before reading ([`must_erase_first`]).

use arm_core::hw::PersistentSettings;
use embedded_storage_async::nor_flash::NorFlash;
use sequential_storage::cache::{Cache, Uncached};
use sequential_storage::map::{MapConfig, MapStorage, SerializationError};

/// Map key of the settings record.
pub const SETTINGS_KEY: u8 = 1;
/// Layout version in the record's first byte: a record written by another layout is
/// ignored (defaults apply) rather than misread.
pub const RECORD_VERSION: u8 = 1;
/// Bytes of the record: version, joints, `ip[4]`, prefix_len, reserved.
pub const RECORD_LEN: usize = 8;
/// Map key of the network record NET_SET added (gateway, DHCP), beside the first record
/// so that a record written before it still loads (with no gateway, static address).
pub const NET_KEY: u8 = 2;
/// Bytes of the network record: `gateway[4]`, flags (bit 0: DHCP), reserved.
pub const NET_RECORD_LEN: usize = 6;

/// Map key of the authentication record (issue 21): the key and the boot epoch, beside
/// the others so that a flash written before it loads with no key.
pub const AUTH_KEY: u8 = 3;
/// Bytes of the authentication record: flags (bit 0: a key is set), the epoch's bits 32-55
/// (3 bytes LE; reserved and 0 before issue 30, whose epochs start at a random 56-bit
/// place: a record written before then loads as the same epoch), the epoch's bits 0-31
/// (u32 LE), the key (zeros without one).
pub const AUTH_RECORD_LEN: usize = 4 + 4 + protocol::auth::KEY_LEN;

/// Map keys of the limits records (LIMITS_SET, issue 23): joints 0-3, then 4-7. Two
/// records of four joints, not one of eight, so that every item (key, record and item
/// header, read in whole 32-byte flash words) fits [`ItemBuffer`]'s 64 bytes: a map read
/// meets every item on the way, and one that does not fit is taken for corruption. Beside
/// the others, so that a flash written before them loads with no limits.
pub const LIMITS_KEYS: [u8; 2] = [4, 5];
/// Joints per limits record.
pub const LIMITS_PER_RECORD: usize = protocol::MAX_JOINTS / LIMITS_KEYS.len();
/// Bytes of one limits record: per joint min (i32 LE), max (i32 LE), max_rate_hz (u32 LE).
pub const LIMITS_RECORD_LEN: usize = 12 * LIMITS_PER_RECORD;
// 1 key byte + the record, in whole 32-byte words, within the item buffer.
const _: () = assert!((1 + LIMITS_RECORD_LEN).div_ceil(32) * 32 <= 64);
const _: () = assert!(LIMITS_PER_RECORD * LIMITS_KEYS.len() == protocol::MAX_JOINTS);

/// Map key of the acceleration record (ACCEL_SET, issue 31): each joint's
/// `max_accel_steps_s2`, beside the others so that a flash written before it loads with
/// none (0).
pub const ACCEL_KEY: u8 = 6;
/// Bytes of the acceleration record: joints 0-7, u32 LE each.
pub const ACCEL_RECORD_LEN: usize = 4 * protocol::MAX_JOINTS;
// 1 key byte + the record, in whole 32-byte words, within the item buffer.
const _: () = assert!((1 + ACCEL_RECORD_LEN).div_ceil(32) * 32 <= 64);

/// Map keys of the description records (JOINT_DESC_SET, issue 31): joints 0-1, 2-3, 4-5,
/// 6-7. Two joints a record so that each item fits [`ItemBuffer`]'s 64 bytes (as the
/// limits records); beside the others, so that a flash written before them loads with no
/// description.
pub const DESC_KEYS: [u8; 4] = [7, 8, 9, 10];
/// Joints per description record.
pub const DESC_PER_RECORD: usize = protocol::MAX_JOINTS / DESC_KEYS.len();
/// Bytes of one joint's description in flash: name (16), unit (1), zero offset (i32 LE),
/// scale (f64 bits, u64 LE); the wire's reserved bytes are not stored.
const DESC_LEN: usize = protocol::JOINT_NAME_LEN + 1 + 4 + 8;
/// Bytes of one description record.
pub const DESC_RECORD_LEN: usize = DESC_LEN * DESC_PER_RECORD;
// 1 key byte + the record, in whole 32-byte words, within the item buffer.
const _: () = assert!((1 + DESC_RECORD_LEN).div_ceil(32) * 32 <= 64);
const _: () = assert!(DESC_PER_RECORD * DESC_KEYS.len() == protocol::MAX_JOINTS);

/// The stored description record `part` (joints `2 * part`, `2 * part + 1`) for `settings`.
pub fn encode_desc(settings: &PersistentSettings, part: usize) -> [u8; DESC_RECORD_LEN] {
    let mut record = [0u8; DESC_RECORD_LEN];
    let joints = settings.desc.iter().skip(part * DESC_PER_RECORD);
    for (chunk, d) in record.chunks_exact_mut(DESC_LEN).zip(joints) {
        let (name, rest) = chunk.split_at_mut(protocol::JOINT_NAME_LEN);
        name.copy_from_slice(&d.name_bytes);
        let (unit, rest) = rest.split_at_mut(1);
        unit.copy_from_slice(&[d.unit as u8]);
        let (zero, scale) = rest.split_at_mut(4);
        zero.copy_from_slice(&d.zero_offset_steps.to_le_bytes());
        scale.copy_from_slice(&d.scale_bits.to_le_bytes());
    }
    record
}

/// `settings` with the description record `part`'s joints. A joint whose stored bytes are
/// not a valid description (an unknown unit) loads with none.
pub fn decode_desc(
    settings: PersistentSettings,
    part: usize,
    record: &[u8; DESC_RECORD_LEN],
) -> PersistentSettings {
    let mut desc = settings.desc;
    let slots = desc.iter_mut().skip(part * DESC_PER_RECORD);
    for (d, chunk) in slots.zip(record.chunks_exact(DESC_LEN)) {
        let (name, rest) = chunk.split_at(protocol::JOINT_NAME_LEN);
        let (unit, rest) = rest.split_at(1);
        let (zero, scale) = rest.split_at(4);
        let mut name_bytes = [0u8; protocol::JOINT_NAME_LEN];
        name_bytes.copy_from_slice(name);
        let mut z = [0u8; 4];
        z.copy_from_slice(zero);
        let mut s = [0u8; 8];
        s.copy_from_slice(scale);
        let loaded = unit
            .first()
            .and_then(|u| protocol::JointUnit::from_u8(*u))
            .map(|unit| protocol::JointDesc {
                name_bytes,
                unit,
                zero_offset_steps: i32::from_le_bytes(z),
                scale_bits: u64::from_le_bytes(s),
            });
        *d = match loaded {
            Some(l) if l.is_valid() => l,
            _ => protocol::JointDesc::NONE,
        };
    }
    PersistentSettings { desc, ..settings }
}

/// Map key of the stop record (ESTOP_CATEGORY, issue 32): the wired e-stop input's
/// category; beside the others, so that a flash written before it loads with category 0.
/// Key 12 is kept for the next stop setting.
pub const STOP_KEY: u8 = 11;
/// Bytes of the stop record: the e-stop category, three reserved (0).
pub const STOP_RECORD_LEN: usize = 4;

/// The stored stop record for `settings`.
pub fn encode_stop(settings: &PersistentSettings) -> [u8; STOP_RECORD_LEN] {
    [settings.estop_category as u8, 0, 0, 0]
}

/// `settings` with the stop record's values; an unknown category loads as 0 (the
/// instant stop: never a slower stop than asked for).
pub fn decode_stop(
    settings: PersistentSettings,
    record: &[u8; STOP_RECORD_LEN],
) -> PersistentSettings {
    let estop_category = protocol::EStopCategory::from_u8(record[0]).unwrap_or_default();
    PersistentSettings {
        estop_category,
        ..settings
    }
}

/// Map keys of the homing records (HOMING_SET, issue 33): joints 0-1, 2-3, 4-5, 6-7, two
/// joints a record as the descriptions; beside the others, so that a flash written before
/// them loads with no homing.
pub const HOMING_KEYS: [u8; 4] = [13, 14, 15, 16];
/// Joints per homing record.
pub const HOMING_PER_RECORD: usize = protocol::MAX_JOINTS / HOMING_KEYS.len();
/// Bytes of one joint's homing in flash: flags, order, then seek and approach rates,
/// back-off, max travel (u32 LE) and offset (i32 LE); the wire's reserved byte is not
/// stored.
const HOMING_LEN: usize = 2 + 5 * 4;
/// Bytes of one homing record.
pub const HOMING_RECORD_LEN: usize = HOMING_LEN * HOMING_PER_RECORD;
// 1 key byte + the record, in whole 32-byte words, within the item buffer.
const _: () = assert!((1 + HOMING_RECORD_LEN).div_ceil(32) * 32 <= 64);
const _: () = assert!(HOMING_PER_RECORD * HOMING_KEYS.len() == protocol::MAX_JOINTS);

/// The stored homing record `part` (joints `2 * part`, `2 * part + 1`) for `settings`.
pub fn encode_homing(settings: &PersistentSettings, part: usize) -> [u8; HOMING_RECORD_LEN] {
    let mut record = [0u8; HOMING_RECORD_LEN];
    let joints = settings.homing.iter().skip(part * HOMING_PER_RECORD);
    for (chunk, h) in record.chunks_exact_mut(HOMING_LEN).zip(joints) {
        let words = [
            h.seek_rate_hz.to_le_bytes(),
            h.approach_rate_hz.to_le_bytes(),
            h.backoff_steps.to_le_bytes(),
            h.max_travel_steps.to_le_bytes(),
            h.offset.to_le_bytes(),
        ];
        let head = [h.flags(), h.order];
        for (out, b) in chunk
            .iter_mut()
            .zip(head.iter().chain(words.iter().flatten()))
        {
            *out = *b;
        }
    }
    record
}

/// `settings` with the homing record `part`'s joints; a joint whose stored bytes cannot
/// run (unknown flags, a zero rate) loads with none.
pub fn decode_homing(
    settings: PersistentSettings,
    part: usize,
    record: &[u8; HOMING_RECORD_LEN],
) -> PersistentSettings {
    let mut homing = settings.homing;
    let slots = homing.iter_mut().skip(part * HOMING_PER_RECORD);
    for (h, chunk) in slots.zip(record.chunks_exact(HOMING_LEN)) {
        let byte = |i: usize| chunk.get(i).copied().unwrap_or(0);
        let word = |i: usize| {
            let mut w = [0u8; 4];
            for (o, b) in w.iter_mut().zip(chunk.iter().skip(2 + 4 * i)) {
                *o = *b;
            }
            w
        };
        let flags = byte(0);
        let read = protocol::HomingSettings {
            enabled: flags & 1 != 0,
            towards_max: flags & 2 != 0,
            switch_is_limit: flags & 4 != 0,
            order: byte(1),
            seek_rate_hz: u32::from_le_bytes(word(0)),
            approach_rate_hz: u32::from_le_bytes(word(1)),
            backoff_steps: u32::from_le_bytes(word(2)),
            max_travel_steps: u32::from_le_bytes(word(3)),
            offset: i32::from_le_bytes(word(4)),
        };
        *h = if flags & !7 == 0 && read.is_valid() {
            read
        } else {
            protocol::HomingSettings::NONE
        };
    }
    PersistentSettings { homing, ..settings }
}

/// The stored acceleration record for `settings`.
pub fn encode_accel(settings: &PersistentSettings) -> [u8; ACCEL_RECORD_LEN] {
    let mut record = [0u8; ACCEL_RECORD_LEN];
    for (chunk, a) in record.chunks_exact_mut(4).zip(&settings.max_accel) {
        chunk.copy_from_slice(&a.to_le_bytes());
    }
    record
}

/// `settings` with the acceleration record's values.
pub fn decode_accel(
    settings: PersistentSettings,
    record: &[u8; ACCEL_RECORD_LEN],
) -> PersistentSettings {
    let mut max_accel = settings.max_accel;
    for (a, chunk) in max_accel.iter_mut().zip(record.chunks_exact(4)) {
        let mut w = [0u8; 4];
        w.copy_from_slice(chunk);
        *a = u32::from_le_bytes(w);
    }
    PersistentSettings {
        max_accel,
        ..settings
    }
}

/// The stored limits record `half` (0: joints 0-3, 1: joints 4-7) for `settings`.
pub fn encode_limits(settings: &PersistentSettings, half: usize) -> [u8; LIMITS_RECORD_LEN] {
    let mut record = [0u8; LIMITS_RECORD_LEN];
    let joints = settings.limits.iter().skip(half * LIMITS_PER_RECORD);
    for (chunk, l) in record.chunks_exact_mut(12).zip(joints) {
        let words = [
            l.min.to_le_bytes(),
            l.max.to_le_bytes(),
            l.max_rate_hz.to_le_bytes(),
        ];
        for (out, b) in chunk.iter_mut().zip(words.iter().flatten()) {
            *out = *b;
        }
    }
    record
}

/// `settings` with the joints of limits record `half`; a range with min above max (not
/// written by this firmware) is no limit.
pub fn decode_limits(
    settings: PersistentSettings,
    half: usize,
    record: &[u8; LIMITS_RECORD_LEN],
) -> PersistentSettings {
    let mut limits = settings.limits;
    let joints = limits.iter_mut().skip(half * LIMITS_PER_RECORD);
    for (l, chunk) in joints.zip(record.chunks_exact(12)) {
        let word = |i: usize| {
            let mut w = [0u8; 4];
            for (o, b) in w.iter_mut().zip(chunk.iter().skip(4 * i)) {
                *o = *b;
            }
            w
        };
        let read = protocol::JointLimits {
            min: i32::from_le_bytes(word(0)),
            max: i32::from_le_bytes(word(1)),
            max_rate_hz: u32::from_le_bytes(word(2)),
        };
        *l = if read.is_valid() {
            read
        } else {
            protocol::JointLimits::NONE
        };
    }
    PersistentSettings { limits, ..settings }
}

/// The stored authentication record for `settings`.
pub fn encode_auth(settings: &PersistentSettings) -> [u8; AUTH_RECORD_LEN] {
    let [e0, e1, e2, e3, e4, e5, e6, _] = settings.auth_epoch.to_le_bytes();
    let head = [u8::from(settings.key.is_some()), e4, e5, e6, e0, e1, e2, e3];
    let key = settings.key.map_or([0; protocol::auth::KEY_LEN], |k| k.0);
    let mut record = [0u8; AUTH_RECORD_LEN];
    for (r, b) in record.iter_mut().zip(head.iter().chain(&key)) {
        *r = *b;
    }
    record
}

/// `settings` with the key and epoch of a stored authentication record.
pub fn decode_auth(
    settings: PersistentSettings,
    record: &[u8; AUTH_RECORD_LEN],
) -> PersistentSettings {
    let (head, key) = record.split_first_chunk::<8>().unwrap_or((&[0; 8], &[]));
    let [flags, e4, e5, e6, e0, e1, e2, e3] = *head;
    let key: Option<[u8; protocol::auth::KEY_LEN]> = key.try_into().ok();
    PersistentSettings {
        key: key.filter(|_| flags & 1 != 0).map(protocol::auth::AuthKey),
        auth_epoch: u64::from_le_bytes([e0, e1, e2, e3, e4, e5, e6, 0]),
        ..settings
    }
}

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

/// The RAM marker that tells a boot the previous boot's settings read faulted.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BootMarker;

impl BootMarker {
    /// Written before the boot-time read, cleared after. Any other value (RAM after
    /// power-on is random, but 32 bits matching by chance is 1 in 4 billion) means no read
    /// was under way.
    pub const READING: u32 = 0x5E77_1265;
    /// Written after the read.
    pub const IDLE: u32 = 0;
}

/// Whether the area must be erased before the boot-time read: the marker left by the
/// previous boot says its read never finished (it faulted, e.g. on an ECC double error).
pub const fn must_erase_first(marker: u32) -> bool {
    marker == BootMarker::READING
}

/// Scratch for one item: key + record + item header, rounded up to the H7's 32-byte flash
/// word (32-byte aligned, as the flash driver writes whole words from it).
#[repr(C, align(32))]
struct ItemBuffer([u8; 64]);

/// What a load found.
// The settings by value (440 bytes with issue 31's joint descriptions): no heap, and a
// load happens once at boot, returned straight to its caller.
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum LoadOutcome {
    /// A valid record.
    Stored(PersistentSettings),
    /// Nothing stored, or a record of another layout: defaults.
    Empty,
    /// The area was corrupted (or the previous boot faulted reading it) and was erased:
    /// defaults.
    Erased,
    /// Unreadable, and erasing failed too: defaults (the next save tries again).
    Unreadable,
}

impl LoadOutcome {
    /// The settings to run with.
    pub fn settings(self) -> PersistentSettings {
        match self {
            LoadOutcome::Stored(s) => s,
            _ => PersistentSettings::default(),
        }
    }
}

/// Why a save failed.
pub type StoreError<E> = sequential_storage::Error<E>;

/// The settings store on `F`'s `range` (at least two erase sectors).
pub struct SettingsArea<F: NorFlash> {
    map: MapStorage<u8, F, Cache<Uncached, Uncached, Uncached, u8>>,
    buffer: ItemBuffer,
}

impl<F: NorFlash> SettingsArea<F> {
    /// Uses `range` of `flash`. Panics (at compile time when `range` is a constant
    /// evaluated in a `const` block by the caller) if the range is not whole sectors.
    pub fn new(flash: F, range: core::ops::Range<u32>) -> Self {
        SettingsArea {
            map: MapStorage::new(flash, MapConfig::new(range), Cache::new_uncached()),
            buffer: ItemBuffer([0; 64]),
        }
    }

    /// Erases the whole area.
    pub async fn erase(&mut self) -> Result<(), StoreError<F::Error>> {
        self.map.erase_all().await
    }

    /// Reads the settings, recovering from corruption by erasing (see the module docs).
    pub async fn load(&mut self) -> LoadOutcome {
        match self.fetch_record::<RECORD_LEN>(&SETTINGS_KEY).await {
            Ok(Some(record)) => match decode(&record) {
                Some(s) => match self.load_net(s).await {
                    Ok(s) => LoadOutcome::Stored(s),
                    Err(_) => self.erase_after_corruption().await,
                },
                None => LoadOutcome::Empty,
            },
            Ok(None) => LoadOutcome::Empty,
            Err(_) => self.erase_after_corruption().await,
        }
    }

    /// `settings` with the network record applied, if there is one (a record from before
    /// NET_SET has none: no gateway, static address).
    async fn load_net(
        &mut self,
        settings: PersistentSettings,
    ) -> Result<PersistentSettings, StoreError<F::Error>> {
        let settings = match self.fetch_record::<NET_RECORD_LEN>(&NET_KEY).await? {
            Some(net) => decode_net(settings, &net),
            None => settings,
        };
        let mut settings = match self.fetch_record::<AUTH_RECORD_LEN>(&AUTH_KEY).await? {
            Some(auth) => decode_auth(settings, &auth),
            None => settings,
        };
        for (half, key) in LIMITS_KEYS.iter().enumerate() {
            if let Some(record) = self.fetch_record::<LIMITS_RECORD_LEN>(key).await? {
                settings = decode_limits(settings, half, &record);
            }
        }
        if let Some(record) = self.fetch_record::<ACCEL_RECORD_LEN>(&ACCEL_KEY).await? {
            settings = decode_accel(settings, &record);
        }
        for (part, key) in DESC_KEYS.iter().enumerate() {
            if let Some(record) = self.fetch_record::<DESC_RECORD_LEN>(key).await? {
                settings = decode_desc(settings, part, &record);
            }
        }
        for (part, key) in HOMING_KEYS.iter().enumerate() {
            if let Some(record) = self.fetch_record::<HOMING_RECORD_LEN>(key).await? {
                settings = decode_homing(settings, part, &record);
            }
        }
        if let Some(record) = self.fetch_record::<STOP_RECORD_LEN>(&STOP_KEY).await? {
            settings = decode_stop(settings, &record);
        }
        Ok(settings)
    }

    /// The record stored under `key`, if any, read as `[u8; N]`'s own `Value` impl reads
    /// it (a shorter value is a serialization error). Both records go through one
    /// `fetch_item::<&[u8]>`: each value type instantiates the map's fetch-and-repair code
    /// again (about 0.5 KB of the board's flash).
    async fn fetch_record<const N: usize>(
        &mut self,
        key: &u8,
    ) -> Result<Option<[u8; N]>, StoreError<F::Error>> {
        let value = self.fetch_value(key).await?;
        value
            .map(|bytes| {
                bytes.first_chunk::<N>().copied().ok_or(
                    sequential_storage::Error::SerializationError(
                        SerializationError::BufferTooSmall,
                    ),
                )
            })
            .transpose()
    }

    /// The value bytes stored under `key`, if any (not generic: one instantiation).
    async fn fetch_value(&mut self, key: &u8) -> Result<Option<&[u8]>, StoreError<F::Error>> {
        self.map.fetch_item::<&[u8]>(&mut self.buffer.0, key).await
    }

    async fn erase_after_corruption(&mut self) -> LoadOutcome {
        match self.erase().await {
            Ok(()) => LoadOutcome::Erased,
            Err(_) => LoadOutcome::Unreadable,
        }
    }

    /// Stores `settings`; on any failure, erases the area and stores once more (a word
    /// left half-programmed by a power cut makes every later write there fail; only an
    /// erase clears it). Returns whether the area was erased on the way.
    pub async fn save(
        &mut self,
        settings: &PersistentSettings,
    ) -> Result<bool, StoreError<F::Error>> {
        if self.store_once(settings).await.is_ok() {
            return Ok(false);
        }
        self.erase().await?;
        self.store_once(settings).await?;
        Ok(true)
    }

    /// One attempt at storing `settings`, no recovery: what a power cut interrupts.
    pub async fn store_once(
        &mut self,
        settings: &PersistentSettings,
    ) -> Result<(), StoreError<F::Error>> {
        // As `&[u8]`: the same bytes as the arrays' `Value` impls write, with one
        // instantiation of the serialiser instead of one per record length.
        self.map
            .store_item::<&[u8]>(
                &mut self.buffer.0,
                &SETTINGS_KEY,
                &encode(settings).as_slice(),
            )
            .await?;
        self.map
            .store_item::<&[u8]>(
                &mut self.buffer.0,
                &NET_KEY,
                &encode_net(settings).as_slice(),
            )
            .await?;
        self.map
            .store_item::<&[u8]>(
                &mut self.buffer.0,
                &AUTH_KEY,
                &encode_auth(settings).as_slice(),
            )
            .await?;
        for (half, key) in LIMITS_KEYS.iter().enumerate() {
            self.map
                .store_item::<&[u8]>(
                    &mut self.buffer.0,
                    key,
                    &encode_limits(settings, half).as_slice(),
                )
                .await?;
        }
        self.map
            .store_item::<&[u8]>(
                &mut self.buffer.0,
                &ACCEL_KEY,
                &encode_accel(settings).as_slice(),
            )
            .await?;
        for (part, key) in DESC_KEYS.iter().enumerate() {
            self.map
                .store_item::<&[u8]>(
                    &mut self.buffer.0,
                    key,
                    &encode_desc(settings, part).as_slice(),
                )
                .await?;
        }
        for (part, key) in HOMING_KEYS.iter().enumerate() {
            self.map
                .store_item::<&[u8]>(
                    &mut self.buffer.0,
                    key,
                    &encode_homing(settings, part).as_slice(),
                )
                .await?;
        }
        self.map
            .store_item::<&[u8]>(
                &mut self.buffer.0,
                &STOP_KEY,
                &encode_stop(settings).as_slice(),
            )
            .await?;
        Ok(())
    }

    /// The flash back (tests inspect it).
    pub fn into_flash(self) -> F {
        self.map.destroy().0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use embassy_futures::block_on;
    use sequential_storage::mock_flash::{MockFlashBase, WriteCountCheck};

    /// Like the H7's flash: 32-byte words written once (ECC); small sectors for speed.
    type Flash = MockFlashBase<4, 32, 64>;
    const RANGE: core::ops::Range<u32> = 0..(4 * 64 * 32);

    fn custom() -> PersistentSettings {
        PersistentSettings {
            joints: 3,
            ip: [10, 0, 0, 7],
            prefix_len: 16,
            gateway: [10, 0, 0, 1],
            dhcp: false,
            key: None,
            auth_epoch: 0,
            limits: [protocol::JointLimits::NONE; protocol::MAX_JOINTS],
            max_accel: [0; protocol::MAX_JOINTS],
            desc: [protocol::JointDesc::NONE; protocol::MAX_JOINTS],
            homing: [protocol::HomingSettings::NONE; protocol::MAX_JOINTS],
            estop_category: protocol::EStopCategory::Instant,
        }
    }

    /// A settings area holding only `records` (key, bytes): a flash written by an older
    /// firmware, before the records that came later.
    fn older_flash(records: &[(u8, &[u8])]) -> SettingsArea<Flash> {
        let mut old = SettingsArea::new(Flash::default(), RANGE);
        for (key, bytes) in records {
            block_on(old.map.store_item(&mut old.buffer.0, key, bytes)).unwrap();
        }
        old
    }

    /// Issue 32: the e-stop category is kept (key 11); a flash written before it (the
    /// settings and network records alone) loads with category 0, and an unknown byte loads as 0.
    #[test]
    fn the_estop_category_is_stored_and_an_older_flash_loads_category_0() {
        let mut controlled = custom();
        controlled.estop_category = protocol::EStopCategory::Controlled;
        let mut area = SettingsArea::new(Flash::default(), RANGE);
        block_on(area.save(&controlled)).unwrap();
        assert_eq!(block_on(area.load()), LoadOutcome::Stored(controlled));
        let mut old = older_flash(&[
            (SETTINGS_KEY, &encode(&custom())),
            (NET_KEY, &encode_net(&custom())),
        ]);
        assert_eq!(block_on(old.load()), LoadOutcome::Stored(custom()));
        assert_eq!(
            decode_stop(custom(), &[7, 0, 0, 0]).estop_category,
            protocol::EStopCategory::Instant
        );
    }

    /// Issue 31: each joint's description (name, units, scale) is kept; a flash written
    /// before it (every other record, no description records) loads with none.
    #[test]
    fn descriptions_are_stored_and_an_older_flash_loads_without_them() {
        let mut described = custom();
        described.desc[0] =
            protocol::JointDesc::new("base", protocol::JointUnit::Degrees, -7, 2546.5).unwrap();
        described.desc[7] = protocol::JointDesc::new(
            "sixteen_bytes_ok",
            protocol::JointUnit::Millimetres,
            0,
            80.0,
        )
        .unwrap();
        described.max_accel[3] = 9;
        let mut area = SettingsArea::new(Flash::default(), RANGE);
        block_on(area.save(&described)).unwrap();
        assert_eq!(block_on(area.load()), LoadOutcome::Stored(described));
        // Saved again and again (each save writes every record): the map keeps up.
        for round in 0..20 {
            described.desc[1] = protocol::JointDesc::new(
                "elbow",
                protocol::JointUnit::Radians,
                round,
                1000.0 + f64::from(round),
            )
            .unwrap();
            block_on(area.save(&described)).unwrap();
        }
        assert_eq!(block_on(area.load()), LoadOutcome::Stored(described));
        let mut old = older_flash(&[
            (SETTINGS_KEY, &encode(&custom())),
            (NET_KEY, &encode_net(&custom())),
            (AUTH_KEY, &encode_auth(&custom())),
            (ACCEL_KEY, &encode_accel(&custom())),
        ]);
        assert_eq!(block_on(old.load()), LoadOutcome::Stored(custom()));
    }

    /// Issue 33: each joint's homing settings are kept (keys 13-16), saved again and
    /// again; a flash written before them loads with none; stored bytes that cannot run
    /// load as none.
    #[test]
    fn homing_is_stored_and_an_older_flash_loads_without_it() {
        let mut homed = custom();
        homed.homing[0] = protocol::HomingSettings {
            enabled: true,
            towards_max: false,
            switch_is_limit: true,
            order: 2,
            seek_rate_hz: 3_000,
            approach_rate_hz: 150,
            backoff_steps: 321,
            max_travel_steps: 50_000,
            offset: -77,
        };
        homed.homing[7] = protocol::HomingSettings {
            towards_max: true,
            offset: i32::MIN,
            ..homed.homing[0]
        };
        let mut area = SettingsArea::new(Flash::default(), RANGE);
        block_on(area.save(&homed)).unwrap();
        assert_eq!(block_on(area.load()), LoadOutcome::Stored(homed));
        for round in 0..20 {
            homed.homing[3] = protocol::HomingSettings {
                order: round,
                ..homed.homing[0]
            };
            block_on(area.save(&homed)).unwrap();
        }
        assert_eq!(block_on(area.load()), LoadOutcome::Stored(homed));
        // Before issue 33: no homing records.
        let mut old = older_flash(&[(SETTINGS_KEY, &encode(&custom()))]);
        let LoadOutcome::Stored(loaded) = block_on(old.load()) else {
            panic!("the old record loads");
        };
        assert_eq!(
            loaded.homing,
            [protocol::HomingSettings::NONE; protocol::MAX_JOINTS]
        );
        // A record whose joint cannot run (seek rate 0) loads with none for it.
        let mut record = encode_homing(&homed, 0);
        record[2..6].copy_from_slice(&[0; 4]);
        let decoded = decode_homing(custom(), 0, &record);
        assert_eq!(decoded.homing[0], protocol::HomingSettings::NONE);
    }

    /// Issue 31: each joint's max acceleration is kept; a flash written before it (with
    /// the limits records, without the acceleration record) loads with none.
    #[test]
    fn accelerations_are_stored_and_an_older_flash_loads_without_them() {
        let mut fast = custom();
        fast.max_accel[0] = 100_000;
        fast.max_accel[7] = 1;
        let mut area = SettingsArea::new(Flash::default(), RANGE);
        block_on(area.save(&fast)).unwrap();
        assert_eq!(block_on(area.load()), LoadOutcome::Stored(fast));
        let mut old = older_flash(&[
            (SETTINGS_KEY, &encode(&custom())),
            (NET_KEY, &encode_net(&custom())),
            (AUTH_KEY, &encode_auth(&custom())),
        ]);
        for (half, key) in LIMITS_KEYS.iter().enumerate() {
            let limits: &[u8] = &encode_limits(&custom(), half);
            block_on(old.map.store_item(&mut old.buffer.0, key, &limits)).unwrap();
        }
        assert_eq!(block_on(old.load()), LoadOutcome::Stored(custom()));
    }

    #[test]
    fn limits_are_stored_in_two_records_and_an_older_flash_loads_without_them() {
        let mut limited = custom();
        limited.limits[1] = protocol::JointLimits {
            min: -16_000,
            max: 16_000,
            max_rate_hz: 5_000,
        };
        limited.limits[7] = protocol::JointLimits {
            min: i32::MIN,
            max: 0,
            max_rate_hz: 0,
        };
        let mut area = SettingsArea::new(Flash::default(), RANGE);
        block_on(area.save(&limited)).unwrap();
        assert_eq!(block_on(area.load()), LoadOutcome::Stored(limited));
        // Saved again and again (the map rewrites each item): still loads.
        for _ in 0..20 {
            block_on(area.save(&limited)).unwrap();
        }
        assert_eq!(block_on(area.load()), LoadOutcome::Stored(limited));
        // A flash written before LIMITS_SET: no limits records, no limits.
        let mut old = older_flash(&[
            (SETTINGS_KEY, &encode(&custom())),
            (NET_KEY, &encode_net(&custom())),
            (AUTH_KEY, &encode_auth(&custom())),
        ]);
        assert_eq!(block_on(old.load()), LoadOutcome::Stored(custom()));
        // A record with min above max is no limit.
        let mut bad = encode_limits(&limited, 0);
        bad[12..16].copy_from_slice(&5i32.to_le_bytes());
        bad[16..20].copy_from_slice(&(-5i32).to_le_bytes());
        let decoded = decode_limits(custom(), 0, &bad);
        assert_eq!(decoded.limits[1], protocol::JointLimits::NONE);
    }

    #[test]
    fn the_key_and_its_epoch_are_stored_and_an_older_flash_loads_without_a_key() {
        let keyed = PersistentSettings {
            key: Some(protocol::auth::AuthKey([9; protocol::auth::KEY_LEN])),
            auth_epoch: 5,
            ..custom()
        };
        let mut area = SettingsArea::new(Flash::default(), RANGE);
        block_on(area.save(&keyed)).unwrap();
        assert_eq!(block_on(area.load()), LoadOutcome::Stored(keyed));
        let cleared = PersistentSettings { key: None, ..keyed };
        block_on(area.save(&cleared)).unwrap();
        assert_eq!(block_on(area.load()), LoadOutcome::Stored(cleared));
        // A flash written before issue 21 has no authentication record: no key.
        let mut old = older_flash(&[
            (SETTINGS_KEY, &encode(&custom())),
            (NET_KEY, &encode_net(&custom())),
        ]);
        assert_eq!(block_on(old.load()), LoadOutcome::Stored(custom()));
    }

    /// Issue 30: a key's epochs start at a random 56-bit place; the record keeps bits
    /// 32-55 in the bytes that were reserved (0), so an older record reads as before.
    #[test]
    fn a_56_bit_epoch_is_stored_and_an_older_auth_record_reads_as_before() {
        let keyed = PersistentSettings {
            key: Some(protocol::auth::AuthKey([9; protocol::auth::KEY_LEN])),
            auth_epoch: 0x00AB_CDEF_1234_5678,
            ..custom()
        };
        let mut area = SettingsArea::new(Flash::default(), RANGE);
        block_on(area.save(&keyed)).unwrap();
        assert_eq!(block_on(area.load()), LoadOutcome::Stored(keyed));
        // The layout before issue 30: flags, 3 reserved zeros, epoch u32 LE, key.
        let mut old = [0u8; AUTH_RECORD_LEN];
        old[0] = 1;
        old[4..8].copy_from_slice(&7u32.to_le_bytes());
        old[8..].copy_from_slice(&[9; protocol::auth::KEY_LEN]);
        let read = decode_auth(custom(), &old);
        assert_eq!(read.auth_epoch, 7);
        assert_eq!(read.key, keyed.key);
        assert_eq!(encode_auth(&read), old, "written back the same way");
    }

    #[test]
    fn record_round_trips_and_refuses_foreign_layouts() {
        let s = custom();
        // The first record has no gateway; the network record adds it back.
        let base = decode(&encode(&s)).unwrap();
        assert_eq!(base.gateway, [0; 4]);
        assert_eq!(decode_net(base, &encode_net(&s)), s);
        let mut other_version = encode(&s);
        other_version[0] = 2;
        assert_eq!(decode(&other_version), None);
        let mut bad_joints = encode(&s);
        bad_joints[1] = 9;
        assert_eq!(decode(&bad_joints), None);
        bad_joints[1] = 0;
        assert_eq!(decode(&bad_joints), None);
        let mut bad_prefix = encode(&s);
        bad_prefix[6] = 33;
        assert_eq!(decode(&bad_prefix), None);
        assert_eq!(encode(&s), [1, 3, 10, 0, 0, 7, 16, 0]);
    }

    #[test]
    fn a_record_from_before_net_set_still_loads_without_gateway_or_dhcp() {
        let mut area = SettingsArea::new(Flash::default(), RANGE);
        // What the firmware before NET_SET stored: the first record only.
        let old = custom();
        block_on(
            area.map
                .store_item(&mut area.buffer.0, &SETTINGS_KEY, &encode(&old)),
        )
        .unwrap();
        assert_eq!(
            block_on(area.load()),
            LoadOutcome::Stored(PersistentSettings {
                gateway: [0; 4],
                dhcp: false,
                ..old
            })
        );
    }

    #[test]
    fn a_record_shorter_than_its_layout_is_corruption_and_is_erased() {
        // As `[u8; N]`'s own `Value` reads them: a short value is a serialization error.
        let mut area = SettingsArea::new(Flash::default(), RANGE);
        let short: &[u8] = &encode(&custom())[..RECORD_LEN - 1];
        block_on(
            area.map
                .store_item(&mut area.buffer.0, &SETTINGS_KEY, &short),
        )
        .unwrap();
        assert_eq!(block_on(area.load()), LoadOutcome::Erased);

        let mut area = SettingsArea::new(Flash::default(), RANGE);
        block_on(area.save(&custom())).unwrap();
        let short_net: &[u8] = &encode_net(&custom())[..NET_RECORD_LEN - 1];
        block_on(
            area.map
                .store_item(&mut area.buffer.0, &NET_KEY, &short_net),
        )
        .unwrap();
        assert_eq!(block_on(area.load()), LoadOutcome::Erased);
        // A longer value still reads its first bytes, as before.
        let long = [encode(&custom()).as_slice(), &[0xAA; 4]].concat();
        block_on(
            area.map
                .store_item(&mut area.buffer.0, &SETTINGS_KEY, &long.as_slice()),
        )
        .unwrap();
        block_on(area.map.remove_item(&mut area.buffer.0, &NET_KEY)).unwrap();
        assert_eq!(
            block_on(area.load()),
            LoadOutcome::Stored(PersistentSettings {
                gateway: [0; 4],
                dhcp: false,
                ..custom()
            })
        );
    }

    #[test]
    fn saves_store_the_records_as_the_fixed_size_arrays_did() {
        // Flash written by this firmware must read back with the earlier `[u8; N]` values.
        let mut area = SettingsArea::new(Flash::default(), RANGE);
        block_on(area.save(&custom())).unwrap();
        let record = block_on(
            area.map
                .fetch_item::<[u8; RECORD_LEN]>(&mut area.buffer.0, &SETTINGS_KEY),
        );
        assert_eq!(record.unwrap(), Some(encode(&custom())));
        let net = block_on(
            area.map
                .fetch_item::<[u8; NET_RECORD_LEN]>(&mut area.buffer.0, &NET_KEY),
        );
        assert_eq!(net.unwrap(), Some(encode_net(&custom())));
    }

    #[test]
    fn gateway_and_dhcp_are_saved_and_read_back() {
        let dhcp = PersistentSettings {
            dhcp: true,
            ..custom()
        };
        assert_eq!(encode_net(&dhcp), [10, 0, 0, 1, 1, 0]);
        assert!(decode_net(PersistentSettings::DEFAULT, &encode_net(&dhcp)).dhcp);
        let mut area = SettingsArea::new(Flash::default(), RANGE);
        block_on(area.save(&dhcp)).unwrap();
        assert_eq!(block_on(area.load()), LoadOutcome::Stored(dhcp));
        block_on(area.save(&custom())).unwrap();
        assert_eq!(block_on(area.load()), LoadOutcome::Stored(custom()));
    }

    #[test]
    fn empty_flash_gives_defaults_and_a_save_is_read_back() {
        let mut area = SettingsArea::new(Flash::default(), RANGE);
        assert_eq!(block_on(area.load()), LoadOutcome::Empty);
        assert_eq!(block_on(area.save(&custom())), Ok(false));
        assert_eq!(block_on(area.load()), LoadOutcome::Stored(custom()));
        // A second area on the same flash (a reboot) reads the same.
        let flash = area.into_flash();
        let mut rebooted = SettingsArea::new(flash, RANGE);
        assert_eq!(block_on(rebooted.load()), LoadOutcome::Stored(custom()));
    }

    #[test]
    fn many_saves_wrap_around_the_sectors() {
        let mut area = SettingsArea::new(Flash::default(), RANGE);
        for i in 0..500u32 {
            let s = PersistentSettings {
                joints: 1 + (i % 8) as u8,
                ..custom()
            };
            block_on(area.save(&s)).unwrap();
            assert_eq!(block_on(area.load()), LoadOutcome::Stored(s));
        }
    }

    /// Garbage over the page headers: sequential-storage sees an impossible page state.
    fn scribble(flash: &mut Flash) {
        for (i, b) in flash.as_bytes_mut().iter_mut().enumerate() {
            *b = (i * 37 % 251) as u8;
        }
    }

    #[test]
    fn a_corrupted_area_is_erased_to_defaults_and_saves_work_again() {
        let mut flash = Flash::default();
        scribble(&mut flash);
        let mut area = SettingsArea::new(flash, RANGE);
        assert_eq!(block_on(area.load()), LoadOutcome::Erased);
        assert_eq!(block_on(area.load()), LoadOutcome::Empty);
        assert_eq!(block_on(area.save(&custom())), Ok(false));
        assert_eq!(block_on(area.load()), LoadOutcome::Stored(custom()));
    }

    #[test]
    fn a_save_into_a_corrupted_area_erases_it_and_stores() {
        let mut flash = Flash::default();
        scribble(&mut flash);
        let mut area = SettingsArea::new(flash, RANGE);
        assert_eq!(block_on(area.save(&custom())), Ok(true));
        assert_eq!(block_on(area.load()), LoadOutcome::Stored(custom()));
    }

    /// Power cut after every possible number of bytes of a save: the next boot always
    /// reads either the old or the new settings (or defaults after an erase), and the
    /// next save always succeeds.
    #[test]
    fn a_save_cut_by_power_loss_at_any_byte_never_bricks_the_settings() {
        let old = custom();
        let new = PersistentSettings {
            joints: 8,
            ..custom()
        };
        let mut cuts = 0;
        // A save writes about 64 bytes, more when it moves to the next sector; saves before
        // it walk its position through two sector switches.
        for (before, shutoff) in (0..70u32)
            .step_by(3)
            .flat_map(|b| (0..=100u32).map(move |s| (b, s)))
        {
            let mut area = SettingsArea::new(Flash::default(), RANGE);
            for _ in 0..before {
                block_on(area.save(&old)).unwrap();
            }
            block_on(area.save(&old)).unwrap();
            let mut flash = area.into_flash();
            flash.bytes_until_shutoff = Some(shutoff);
            let mut area = SettingsArea::new(flash, RANGE);
            let result = block_on(area.store_once(&new));
            let mut flash = area.into_flash();
            if flash.bytes_until_shutoff.is_none() {
                cuts += 1;
                assert!(result.is_err());
            }
            flash.bytes_until_shutoff = None;
            let mut rebooted = SettingsArea::new(flash, RANGE);
            let loaded = block_on(rebooted.load());
            assert!(
                matches!(loaded, LoadOutcome::Stored(s) if s == old || s == new)
                    || loaded == LoadOutcome::Erased,
                "cut after {before} saves and {shutoff} bytes: {loaded:?}"
            );
            block_on(rebooted.save(&new)).unwrap();
            assert_eq!(block_on(rebooted.load()), LoadOutcome::Stored(new));
        }
        assert!(
            cuts > 1500,
            "the fault injection must actually cut saves ({cuts})"
        );
    }

    #[test]
    fn the_boot_marker_asks_for_an_erase_only_after_a_faulted_read() {
        assert!(must_erase_first(BootMarker::READING));
        assert!(!must_erase_first(BootMarker::IDLE));
        assert!(!must_erase_first(0xFFFF_FFFF));
    }

    #[test]
    fn an_area_erased_after_a_faulted_boot_read_gives_defaults() {
        let mut area = SettingsArea::new(Flash::default(), RANGE);
        block_on(area.save(&custom())).unwrap();
        // The previous boot faulted mid-read (ECC double error): this one erases first.
        if must_erase_first(BootMarker::READING) {
            block_on(area.erase()).unwrap();
        }
        assert_eq!(block_on(area.load()), LoadOutcome::Empty);
        assert_eq!(LoadOutcome::Empty.settings(), PersistentSettings::default());
    }

    #[test]
    fn writes_respect_the_h7_write_once_rule() {
        let flash = MockFlashBase::<4, 32, 64>::new(WriteCountCheck::OnceOnly, None, true);
        let mut area = SettingsArea::new(flash, RANGE);
        for _ in 0..50 {
            block_on(area.save(&custom())).unwrap();
        }
    }
}
