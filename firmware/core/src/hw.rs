//! The small hardware traits the controller's tasks are generic over. The board binary
//! implements them with embassy-stm32 drivers, sim-host with simulated hardware; the
//! behaviour behind them is written once, in this crate.

use core::future::Future;

use protocol::{NetSettings, Pwm, UartInit};

pub use arm_step::{JointMask, StepPins};

/// What the tasks need of a hardware error to log it: `Debug`, and `defmt::Format` when
/// logging with defmt (so the board never formats with `core::fmt`).
#[cfg(feature = "defmt")]
pub trait LogError: core::fmt::Debug + defmt::Format {}
#[cfg(feature = "defmt")]
impl<T: core::fmt::Debug + defmt::Format> LogError for T {}
/// What the tasks need of a hardware error to log it: `Debug`, and `defmt::Format` when
/// logging with defmt (so the board never formats with `core::fmt`).
#[cfg(not(feature = "defmt"))]
pub trait LogError: core::fmt::Debug {}
#[cfg(not(feature = "defmt"))]
impl<T: core::fmt::Debug> LogError for T {}

/// An IPv4 UDP endpoint.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Endpoint {
    /// IPv4 address.
    pub ip: [u8; 4],
    /// UDP port.
    pub port: u16,
}

/// Monotonic time in microseconds since boot, and waiting for it.
pub trait Clock {
    /// Microseconds since boot.
    fn now_us(&self) -> u64;
    /// Completes once `now_us() >= at_us`.
    fn sleep_until(&self, at_us: u64) -> impl Future<Output = ()>;
}

/// The controller's UDP socket (bound to port 8510). Methods take `&self` so that one task
/// can wait for a datagram and send one at the same time.
pub trait Datagrams {
    /// Transport error (logged, never fatal).
    type Error: LogError;
    /// Waits for the next datagram; returns its length (truncated to `buf`) and sender.
    fn recv(&self, buf: &mut [u8]) -> impl Future<Output = Result<(usize, Endpoint), Self::Error>>;
    /// Sends one datagram.
    fn send(&self, to: Endpoint, frame: &[u8]) -> impl Future<Output = Result<(), Self::Error>>;
}

/// Asks the step timer for an interrupt as soon as possible (new segments, start, stop).
/// The interrupt then does the backend's timer work (the producer's DIR changes and run
/// end on the board; [`arm_step::StepEngine::poll`] for the engine).
pub trait StepKick {
    /// Requests an immediate step timer interrupt. Callable from any context.
    fn kick(&self);
    /// Current step timer tick (the time base of the backend's ticks).
    fn now_tick(&self) -> u64;
}

/// PIN0/PIN1 and the drivers' ENABLE lines.
pub trait Outputs {
    /// Drives user pin `pin` (0 or 1).
    fn set_user_pin(&mut self, pin: u8, high: bool);
    /// Sets the ENABLE lines: bit j = joint j enabled (holding), bit 8 = gripper.
    fn set_enabled(&mut self, enabled: u16);
}

/// The gripper timer output (servo PWM or counted stepper pulses).
pub trait Gripper {
    /// Input clock of the gripper timer (STATUS `pwm_timer_clock_hz`).
    fn timer_clock_hz(&self) -> u32;
    /// Starts PWM with these registers (already validated). Stepper mode
    /// (`pulse_count != 0`): sets the direction from the sign and stops by itself after
    /// `|pulse_count|` pulses.
    fn start(&mut self, pwm: &Pwm);
    /// Output off at once.
    fn stop(&mut self);
    /// Whether the output is running (false once a counted burst has finished).
    fn is_active(&self) -> bool;
}

/// Why the serial port refused something.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SerialError {
    /// The settings cannot be applied by this hardware.
    Unsupported,
    /// The port is closed.
    Closed,
    /// A framing, parity or overrun error on the line.
    Line,
}

/// The pass-through serial port. Methods take `&self` so that reading and writing can wait
/// at the same time (implementations keep the two halves apart).
pub trait SerialPort {
    /// Opens (or reopens) the port with these settings.
    fn open(&self, init: &UartInit) -> Result<(), SerialError>;
    /// Closes the port; pending reads return `Closed`.
    fn close(&self);
    /// Waits for at least one byte, then returns what arrived until `buf` is full or the
    /// line went idle for one byte time. Must be cancel-safe: the serial task races it
    /// against the USART_RECV batch deadline, and a read dropped before it completes must
    /// lose no byte (a ring-buffered UART read is).
    fn read(&self, buf: &mut [u8]) -> impl Future<Output = Result<usize, SerialError>>;
    /// Writes every byte.
    fn write(&self, bytes: &[u8]) -> impl Future<Output = Result<(), SerialError>>;
}

/// Settings that survive a power cycle.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PersistentSettings {
    /// Joints in use (JOINTS_COUNT), 1..8.
    pub joints: u8,
    /// The controller's IPv4 address.
    pub ip: [u8; 4],
    /// Prefix length of its subnet.
    pub prefix_len: u8,
    /// Default gateway, 0.0.0.0 for none (NET_SET).
    pub gateway: [u8; 4],
    /// Take the address from DHCP instead of `ip`/`prefix_len` (NET_SET).
    pub dhcp: bool,
    /// The authentication key (SET_KEY; docs/PROTOCOL.md section 13), `None`: no key,
    /// every frame is taken as before issue 21.
    pub key: Option<protocol::auth::AuthKey>,
    /// The boot epoch of the last boot with a key (one more at each such boot, stored
    /// before any HELLO is answered): part of every MAC, so no frame of an earlier boot
    /// verifies. A key's first epoch is random ([`crate::auth::epoch_base`], issue 30);
    /// within [`crate::auth::AUTH_EPOCH_BITS`].
    pub auth_epoch: u64,
    /// Each joint's position range and step rate (LIMITS_SET, issue 23); no limit by
    /// default.
    pub limits: [protocol::JointLimits; protocol::MAX_JOINTS],
    /// Each joint's most acceleration, steps/s² (ACCEL_SET, issue 31); 0: none (the
    /// default, and what settings stored before it load with).
    pub max_accel: [u32; protocol::MAX_JOINTS],
    /// Each joint's description: name, units, scale (JOINT_DESC_SET, issue 31), kept for
    /// the hosts and never used by the controller; none by default and in settings stored
    /// before it.
    pub desc: [protocol::JointDesc; protocol::MAX_JOINTS],
    /// Each joint's homing on its home switch (HOMING_SET, issue 33), kept with its
    /// limits; none by default and in settings stored before it.
    pub homing: [protocol::HomingSettings; protocol::MAX_JOINTS],
    /// How the wired e-stop input stops the arm (ESTOP_CATEGORY, issue 32): category 0
    /// (instant, the default and what settings stored before it load with) or 1.
    pub estop_category: protocol::EStopCategory,
}

impl PersistentSettings {
    /// The defaults, as a constant.
    pub const DEFAULT: PersistentSettings = PersistentSettings {
        joints: protocol::limits::DEFAULT_JOINTS,
        ip: [192, 168, 1, 30],
        prefix_len: 24,
        gateway: [0; 4],
        dhcp: false,
        key: None,
        auth_epoch: 0,
        limits: [protocol::JointLimits::NONE; protocol::MAX_JOINTS],
        max_accel: [0; protocol::MAX_JOINTS],
        desc: [protocol::JointDesc::NONE; protocol::MAX_JOINTS],
        homing: [protocol::HomingSettings::NONE; protocol::MAX_JOINTS],
        estop_category: protocol::EStopCategory::Instant,
    };

    /// The network part, as NET_SET and DISCOVER_REPLY carry it.
    pub fn net(&self) -> NetSettings {
        if self.dhcp {
            NetSettings::DHCP
        } else {
            NetSettings::fixed(self.ip, self.prefix_len, Some(self.gateway))
        }
    }

    /// Replaces the network part (the static address is kept when DHCP is chosen, so that
    /// the board can fall back to it).
    pub fn set_net(&mut self, net: NetSettings) {
        self.dhcp = net.dhcp;
        if !net.dhcp {
            self.ip = net.ip;
            self.prefix_len = net.prefix_len;
            self.gateway = net.gateway;
        }
    }
}

impl Default for PersistentSettings {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// Persistent storage of [`PersistentSettings`].
pub trait SettingsStore {
    /// Storage error (logged; the controller keeps running on defaults).
    type Error: LogError;
    /// The stored settings, or `None` if nothing valid is stored.
    fn load(&mut self) -> impl Future<Output = Result<Option<PersistentSettings>, Self::Error>>;
    /// Stores the settings.
    fn save(
        &mut self,
        settings: &PersistentSettings,
    ) -> impl Future<Output = Result<(), Self::Error>>;
}

/// Why the absolute encoders could not be read.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct EncoderFault {
    /// The first joint whose encoder did not answer properly (0-based).
    pub joint: u8,
    /// What went wrong.
    pub kind: EncoderFaultKind,
}

/// What went wrong with one encoder (after the retries its driver makes).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum EncoderFaultKind {
    /// No answer within the response timeout (not connected, no power, wrong address or
    /// baud rate).
    NoAnswer,
    /// Answers arrived with a wrong checksum (CRC) or parity: wiring, termination, noise.
    BadCrc,
    /// An answer that is not a position reply (cut off, wrong length, another address).
    BadReply,
    /// The encoder refused the request (a Modbus exception code).
    Exception(u8),
}

/// Absolute joint encoders, for RETURN.
pub trait Encoders {
    /// Current joint positions in steps, or `None` if this board has no encoders (RETURN
    /// then trusts the step count).
    fn read(&mut self) -> impl Future<Output = Option<[i32; protocol::MAX_JOINTS]>>;

    /// The positions of joints `0..joints` (the others are not used), `Ok(None)` without
    /// encoders, or the encoder that failed: RETURN is then refused without moving
    /// ([`crate::Controller::fail_return`]). The default has no failure mode: it is
    /// [`Encoders::read`].
    fn read_joints(
        &mut self,
        joints: u8,
    ) -> impl Future<Output = Result<Option<[i32; protocol::MAX_JOINTS]>, EncoderFault>> {
        let _ = joints;
        async { Ok(self.read().await) }
    }
}
