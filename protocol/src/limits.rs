//! The protocol's numbers, each declared once and used by the firmware, the simulator,
//! the host tools and the fuzz target.
//!
//! Two kinds: value ranges that decode enforces (docs/PROTOCOL.md: the table of
//! "Commands (host to controller)", its TOGGLE_ENABLE_PINS section, and "UartInit
//! (28 bytes)" for the baud rate), and the timing and memory of ownership and duplicate
//! detection ("Transport and ownership", "Ordering, retransmission and duplicates").

/// Smallest and largest UPLOAD_PERIOD, microseconds.
pub const UPLOAD_PERIOD_US: core::ops::RangeInclusive<u32> = 1_000..=1_000_000;
/// Joint counts JOINTS_COUNT accepts.
pub const JOINTS: core::ops::RangeInclusive<u8> = 1..=8;
/// Serial baud rates USART_START accepts.
pub const BAUD_RATE: core::ops::RangeInclusive<u32> = 300..=4_000_000;
/// Bits of TOGGLE_ENABLE_PINS's mask that name a driver: joints 0-7, gripper 8.
pub const ENABLE_MASK_BITS: u16 = 0x01FF;
/// Default upload period, microseconds.
pub const DEFAULT_UPLOAD_PERIOD_US: u32 = 10_000;
/// Default joint count.
pub const DEFAULT_JOINTS: u8 = 6;

/// Most points one NEW announces: its count is a u16 ("NEW (0x00)"). Longer trajectories
/// are refused, not split: splitting would stop the arm between uploads.
pub const MAX_POINTS_PER_NEW: usize = u16::MAX as usize;

/// How long the owner may be silent before another host may take over, microseconds
/// ("Transport and ownership").
pub const OWNER_TIMEOUT_US: u64 = 5_000_000;

/// How long an accepted frame is remembered for duplicate detection, microseconds
/// ("Ordering, retransmission and duplicates").
pub const DUPLICATE_WINDOW_US: u64 = 2_000_000;

/// Largest host window: datagrams a host may send back to back without waiting for an
/// ACK, all taken without a drop; the most a controller advertises in STATUS `window`
/// ("Ordering, retransmission and duplicates"). 32 PENDING frames of 12 points are 384
/// points, 3.8 s of 10 ms points: enough to cover a LAN round trip many times over.
pub const HOST_WINDOW: usize = 32;

/// The window a host may assume when STATUS `window` is 0 (a controller from before the
/// field existed took bursts of 8 datagrams).
pub const DEFAULT_WINDOW: u16 = 8;

/// Accepted frames remembered for duplicate detection ("Ordering, retransmission and
/// duplicates"): twice the window, so that a resend of the oldest frame of a full window
/// is still recognised after the whole window and as many interleaved commands were
/// executed behind it.
pub const DUPLICATE_MEMORY: usize = 2 * HOST_WINDOW;

// A host resending the first frame of a full window must still find it remembered.
const _: () = assert!(
    DUPLICATE_MEMORY > HOST_WINDOW,
    "duplicate memory must exceed the largest window"
);

// A host that assumes the default window of an old controller stays within the largest.
const _: () = assert!(
    DEFAULT_WINDOW as usize <= HOST_WINDOW,
    "the default window must not exceed the largest"
);
