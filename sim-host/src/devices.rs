//! The small simulated devices: user pins and ENABLE lines, the gripper timer, the absolute
//! encoders, and the settings file.

use std::io;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU8, AtomicU16, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use arm_core::config::ServoOnStop;
use arm_core::hw::{
    Clock, EncoderFault, Encoders, Gripper, Outputs, PersistentSettings, SettingsStore,
};
use arm_step::MAX_JOINTS;
use board_logic::encoder::{self, EncoderBus, EncoderConfig};
use protocol::Pwm;

use crate::clock::SimClock;
use crate::steppers::MotorState;
use crate::vcd::{Signal, Tracer, Value};

/// The simulated gripper timer's input clock: the profile's (the NUCLEO's TIM15 at 200 MHz),
/// so that a host computes the same PSC/ARR for both.
pub const PWM_TIMER_CLOCK_HZ: u32 = crate::app::PROFILE.pwm_timer_clock_hz;

/// Levels of PIN0/PIN1 and the ENABLE lines, for whoever looks (tests, the demo).
#[derive(Debug, Default)]
pub struct OutputLevels {
    /// Bit p = user pin p high.
    pub user_pins: AtomicU8,
    /// Bit j = joint j enabled, bit 8 = gripper.
    pub enabled: AtomicU16,
}

/// [`Outputs`]: the two user pins and the drivers' ENABLE lines.
#[derive(Clone, Debug)]
pub struct SimOutputs {
    levels: Arc<OutputLevels>,
    tracer: Tracer,
}

impl SimOutputs {
    /// Outputs recording into `levels` and the trace.
    pub fn new(levels: Arc<OutputLevels>, tracer: Tracer) -> SimOutputs {
        SimOutputs { levels, tracer }
    }
}

impl Outputs for SimOutputs {
    fn set_user_pin(&mut self, pin: u8, high: bool) {
        let bit = 1u8 << (pin & 1);
        let before = if high {
            self.levels.user_pins.fetch_or(bit, Ordering::Relaxed)
        } else {
            self.levels.user_pins.fetch_and(!bit, Ordering::Relaxed)
        };
        if (before & bit != 0) != high {
            log::info!("PIN{} {}", pin & 1, if high { "high" } else { "low" });
        }
        let signal = if pin & 1 == 0 {
            Signal::Pin0
        } else {
            Signal::Pin1
        };
        self.tracer.record(signal, Value::Bit(high));
    }

    fn set_enabled(&mut self, enabled: u16) {
        let before = self.levels.enabled.swap(enabled, Ordering::Relaxed);
        if before != enabled {
            log::info!("ENABLE lines {enabled:#011b} (bit 8 gripper, bits 0-7 joints)");
        }
        for j in 0..MAX_JOINTS {
            self.tracer
                .record(Signal::Enable(j as u8), Value::Bit(enabled & (1 << j) != 0));
        }
        self.tracer
            .record(Signal::GripperEnable, Value::Bit(enabled & (1 << 8) != 0));
    }
}

/// What the gripper timer is doing.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct GripperStatus {
    /// Registers of the last start, if running.
    pub pwm: Option<Pwm>,
    /// End of a counted burst, simulated ns.
    pub burst_end_ns: Option<u64>,
    /// Bursts and servo starts so far.
    pub starts: u64,
    /// Stepper-mode pulses emitted by finished or stopped bursts so far (signed).
    pub pulses_done: i64,
}

/// [`Gripper`]: a timer output simulated from its registers. Servo mode runs until
/// stopped; stepper mode ends by itself after `|pulse_count|` periods of simulated time.
#[derive(Clone, Debug)]
pub struct SimGripper {
    status: Arc<Mutex<GripperStatus>>,
    generation: Arc<AtomicU64>,
    clock: SimClock,
    tracer: Tracer,
}

impl SimGripper {
    /// A stopped gripper.
    pub fn new(clock: SimClock, tracer: Tracer) -> SimGripper {
        SimGripper {
            status: Arc::new(Mutex::new(GripperStatus::default())),
            generation: Arc::new(AtomicU64::new(0)),
            clock,
            tracer,
        }
    }

    /// What the timer is doing now.
    pub fn status(&self) -> GripperStatus {
        self.status.lock().map(|s| *s).unwrap_or_default()
    }

    fn trace_off_at(&self, t_ns: u64, generation: Option<u64>) {
        let guard = generation.map(|g| (self.generation.clone(), g));
        self.tracer.record_guarded(
            t_ns,
            Signal::GripperActive,
            Value::Bit(false),
            guard.clone(),
        );
        self.tracer.record_guarded(
            t_ns,
            Signal::GripperFrequency,
            Value::Real(0.0),
            guard.clone(),
        );
        self.tracer
            .record_guarded(t_ns, Signal::GripperDuty, Value::Real(0.0), guard);
    }

    /// A stop's own cut, from the thread that saw it (the wired input's, or the socket
    /// reader's for a STOPPED), as the board's EXTI0 and receive path cut TIM15: a counted
    /// burst that runs, or a servo PWM under [`ServoOnStop::Cut`], stopped now. The
    /// controller's stop for the same stop follows and makes the same decision.
    pub fn cut_at_stop(&self, servo_on_stop: ServoOnStop) {
        let running = self.status().pwm;
        let cut = running.is_some_and(|pwm| servo_on_stop.cuts(pwm.pulse_count));
        if cut && self.is_active() {
            self.clone().stop();
        }
    }

    /// Ends a burst whose time is over (bookkeeping only; the trace has the end already).
    fn settle(status: &mut GripperStatus, now_ns: u64) {
        if let (Some(end), Some(pwm)) = (status.burst_end_ns, status.pwm)
            && now_ns >= end
        {
            status.pulses_done += i64::from(pwm.pulse_count);
            status.pwm = None;
            status.burst_end_ns = None;
        }
    }
}

impl Gripper for SimGripper {
    fn timer_clock_hz(&self) -> u32 {
        PWM_TIMER_CLOCK_HZ
    }

    fn start(&mut self, pwm: &Pwm) {
        let now = self.clock.now_ns();
        let generation = self.generation.fetch_add(1, Ordering::Relaxed) + 1;
        let Ok(mut status) = self.status.lock() else {
            return;
        };
        Self::settle(&mut status, now);
        let period_ns = pwm.period_ticks() as f64 * 1e9 / f64::from(PWM_TIMER_CLOCK_HZ);
        let frequency = pwm.frequency_hz(PWM_TIMER_CLOCK_HZ);
        status.pwm = Some(*pwm);
        status.starts += 1;
        status.burst_end_ns = (pwm.pulse_count != 0)
            .then(|| now + (period_ns * f64::from(pwm.pulse_count.unsigned_abs())) as u64);
        self.tracer
            .record_at(now, Signal::GripperActive, Value::Bit(true));
        self.tracer
            .record_at(now, Signal::GripperFrequency, Value::Real(frequency));
        self.tracer
            .record_at(now, Signal::GripperDuty, Value::Real(pwm.duty()));
        self.tracer.record_at(
            now,
            Signal::GripperPulses,
            Value::Int(pwm.pulse_count.unsigned_abs()),
        );
        if pwm.pulse_count != 0 {
            self.tracer
                .record_at(now, Signal::GripperDir, Value::Bit(pwm.pulse_count > 0));
        }
        match status.burst_end_ns {
            Some(end) => {
                log::info!(
                    "gripper: stepper burst of {} pulses at {frequency:.1} Hz, ends in {:.1} ms",
                    pwm.pulse_count,
                    (end - now) as f64 / 1e6
                );
                self.trace_off_at(end, Some(generation));
            }
            None => log::info!(
                "gripper: servo PWM {frequency:.1} Hz, duty {:.1}%",
                pwm.duty() * 100.0
            ),
        }
    }

    fn stop(&mut self) {
        let now = self.clock.now_ns();
        self.generation.fetch_add(1, Ordering::Relaxed);
        let Ok(mut status) = self.status.lock() else {
            return;
        };
        Self::settle(&mut status, now);
        if let Some(pwm) = status.pwm.take() {
            if let Some(end) = status.burst_end_ns.take() {
                // Stopped mid-burst: count the whole periods that ran.
                let period_ns = pwm.period_ticks() as f64 * 1e9 / f64::from(PWM_TIMER_CLOCK_HZ);
                let total_ns = period_ns * f64::from(pwm.pulse_count.unsigned_abs());
                let left_ns = (end - now) as f64;
                let done = ((total_ns - left_ns) / period_ns).floor() as i64;
                status.pulses_done += done * i64::from(pwm.pulse_count.signum());
            }
            log::info!("gripper: stopped");
        }
        self.trace_off_at(now, None);
    }

    fn is_active(&self) -> bool {
        let now = self.clock.now_ns();
        self.status
            .lock()
            .map(|mut status| {
                Self::settle(&mut status, now);
                status.pwm.is_some()
            })
            .unwrap_or(false)
    }
}

/// How a simulated encoder misbehaves (`--encoder-fault J:KIND`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum EncoderFaultMode {
    /// Answers every request correctly.
    #[default]
    None,
    /// Never answers (unplugged, unpowered, wrong address).
    Silent,
    /// Answers with a wrong CRC (noise, missing termination).
    Crc,
    /// Answers with Modbus exception 2 (illegal data address: wrong register configured).
    Exception,
}

/// [`Encoders`]: absolute multi-turn encoders on every joint, on a simulated RS-485 bus
/// speaking Modbus RTU, read with the board's own code (board-logic's `encoder` module:
/// the same requests, CRC checks, timeouts and retries). Each encoder reads the simulated
/// motor's physical position plus a per-joint offset (`--encoder-offset J:STEPS`: where
/// the joint really was at boot while the step count says 0, as after steps lost with
/// power off), in steps; `--encoder-fault J:KIND` makes one misbehave.
#[derive(Clone, Debug)]
pub struct SimEncoders {
    motors: Arc<MotorState>,
    offsets: [i64; MAX_JOINTS],
    present: bool,
    clock: Option<SimClock>,
    faults: [EncoderFaultMode; MAX_JOINTS],
}

impl SimEncoders {
    /// Encoders on `motors`; `present = false` simulates a board without them.
    pub fn new(motors: Arc<MotorState>, offsets: [i64; MAX_JOINTS], present: bool) -> Self {
        SimEncoders {
            motors,
            offsets,
            present,
            clock: None,
            faults: [EncoderFaultMode::None; MAX_JOINTS],
        }
    }

    /// Timeouts and line time on `clock` (without one, a silent encoder costs no time),
    /// and the given misbehaviours.
    pub fn with_bus(mut self, clock: SimClock, faults: [EncoderFaultMode; MAX_JOINTS]) -> Self {
        self.clock = Some(clock);
        self.faults = faults;
        self
    }

    /// What the encoders read now.
    pub fn positions(&self) -> [i64; MAX_JOINTS] {
        let motors = self.motors.positions();
        core::array::from_fn(|j| motors[j] + self.offsets[j])
    }

    async fn wait_us(&self, us: u32) {
        if let Some(clock) = self.clock {
            clock.sleep_until(clock.now_us() + u64::from(us)).await;
        }
    }
}

/// The simulated RS-485 bus with the encoders on it.
struct SimEncoderBus<'a> {
    encoders: &'a SimEncoders,
    /// The reply to the last request (empty: none).
    reply: Vec<u8>,
}

impl EncoderBus for SimEncoderBus<'_> {
    async fn send(&mut self, frame: &[u8]) -> Result<(), ()> {
        let timing = EncoderConfig::DEFAULT.timing;
        self.encoders.wait_us(timing.frame_us(frame.len())).await;
        self.reply.clear();
        // An encoder ignores a request with a bad CRC or for another address.
        let Some((address, _register)) = encoder::parse_position_request(frame) else {
            return Ok(());
        };
        let Some(joint) = usize::from(address)
            .checked_sub(1)
            .filter(|j| *j < MAX_JOINTS)
        else {
            return Ok(());
        };
        let counts =
            self.encoders.positions()[joint].clamp(i64::from(i32::MIN), i64::from(i32::MAX)) as i32;
        match self.encoders.faults[joint] {
            EncoderFaultMode::None => {
                self.reply
                    .extend_from_slice(&encoder::position_reply(address, counts));
            }
            EncoderFaultMode::Silent => {}
            EncoderFaultMode::Crc => {
                let mut reply = encoder::position_reply(address, counts);
                reply[encoder::POSITION_REPLY_LEN - 1] ^= 0x5A;
                self.reply.extend_from_slice(&reply);
            }
            EncoderFaultMode::Exception => {
                self.reply
                    .extend_from_slice(&encoder::exception_reply(address, 2));
            }
        }
        Ok(())
    }

    async fn receive(
        &mut self,
        buf: &mut [u8],
        first_byte_timeout_us: u32,
        silent_us: u32,
    ) -> usize {
        if self.reply.is_empty() {
            self.encoders.wait_us(first_byte_timeout_us).await;
            return 0;
        }
        let timing = EncoderConfig::DEFAULT.timing;
        self.encoders
            .wait_us(timing.frame_us(self.reply.len()) + silent_us)
            .await;
        let n = self.reply.len().min(buf.len());
        buf[..n].copy_from_slice(&self.reply[..n]);
        self.reply.clear();
        n
    }

    async fn pause(&mut self, us: u32) {
        self.encoders.wait_us(us).await;
    }
}

impl Encoders for SimEncoders {
    async fn read(&mut self) -> Option<[i32; protocol::MAX_JOINTS]> {
        self.read_joints(MAX_JOINTS as u8).await.ok().flatten()
    }

    async fn read_joints(
        &mut self,
        joints: u8,
    ) -> Result<Option<[i32; protocol::MAX_JOINTS]>, EncoderFault> {
        if !self.present {
            return Ok(None);
        }
        let mut bus = SimEncoderBus {
            encoders: self,
            reply: Vec::new(),
        };
        let read = encoder::read_positions(&mut bus, &EncoderConfig::DEFAULT, joints).await;
        if let Err(fault) = read {
            log::warn!("encoders: joint {} failed: {:?}", fault.joint, fault.kind);
        }
        read.map(Some)
    }
}

/// [`SettingsStore`] in a small text file (`key=value` lines), replaced atomically.
#[derive(Clone, Debug)]
pub struct FileSettings {
    path: PathBuf,
    boot_joints: Option<u8>,
    clear_key: bool,
}

impl FileSettings {
    /// Settings kept in `path` (created on the first save).
    pub fn new(path: PathBuf) -> FileSettings {
        FileSettings {
            path,
            boot_joints: None,
            clear_key: false,
        }
    }

    /// Makes `load` remove a stored key (and store that at once): `--clear-key`, the
    /// simulator's user button held at reset (docs/PROTOCOL.md section 13).
    pub fn set_clear_key(&mut self, clear: bool) {
        self.clear_key = clear;
    }

    /// Makes `load` report this joint count (`--joints`), whatever the file says; saving
    /// still stores what the controller asks.
    pub fn set_boot_joints(&mut self, joints: Option<u8>) {
        self.boot_joints = joints;
    }

    /// The file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Reads the file; `Ok(None)` if it does not exist.
    pub fn read(&self) -> io::Result<Option<PersistentSettings>> {
        let text = match std::fs::read_to_string(&self.path) {
            Ok(text) => text,
            Err(e) if e.kind() == io::ErrorKind::NotFound => return Ok(None),
            Err(e) => return Err(e),
        };
        parse_settings(&text)
            .map(Some)
            .map_err(|e| io::Error::new(io::ErrorKind::InvalidData, e))
    }

    /// Writes the file (to a temporary file first, then renamed over it).
    pub fn write(&self, settings: &PersistentSettings) -> io::Result<()> {
        if let Some(dir) = self.path.parent()
            && !dir.as_os_str().is_empty()
        {
            std::fs::create_dir_all(dir)?;
        }
        let tmp = self.path.with_extension("tmp");
        std::fs::write(&tmp, format_settings(settings))?;
        // It may hold the key: readable by its owner only.
        {
            use std::os::unix::fs::PermissionsExt;
            std::fs::set_permissions(&tmp, std::fs::Permissions::from_mode(0o600))?;
        }
        std::fs::rename(&tmp, &self.path)
    }
}

/// The file's text for `settings`.
pub fn format_settings(settings: &PersistentSettings) -> String {
    let [a, b, c, d] = settings.ip;
    let [e, f, g, h] = settings.gateway;
    let mut text = format!(
        "# arm controller simulator settings (sim-host)\njoints={}\nip={a}.{b}.{c}.{d}\nprefix_len={}\ngateway={e}.{f}.{g}.{h}\ndhcp={}\nauth_epoch={}\n",
        settings.joints, settings.prefix_len, settings.dhcp, settings.auth_epoch
    );
    if let Some(key) = settings.key {
        let hex: String = key.0.iter().map(|b| format!("{b:02x}")).collect();
        text.push_str(&format!("key={hex}\n"));
    }
    // LIMITS_SET (issue 23): `limit.J=min,max,max_rate_hz`, only for joints with limits.
    for (j, l) in settings.limits.iter().enumerate() {
        if *l != protocol::JointLimits::NONE {
            text.push_str(&format!(
                "limit.{j}={},{},{}\n",
                l.min, l.max, l.max_rate_hz
            ));
        }
    }
    // ACCEL_SET (issue 31): `accel.J=steps/s²`, only for joints with one.
    for (j, a) in settings.max_accel.iter().enumerate() {
        if *a != 0 {
            text.push_str(&format!("accel.{j}={a}\n"));
        }
    }
    // JOINT_DESC_SET (issue 31): `desc.J=unit,zero_offset_steps,scale,name in hex` (the
    // name may hold any UTF-8, a line break or '=' included), only for described joints.
    // The scale prints as the shortest decimal that reads back to the same f64.
    for (j, d) in settings.desc.iter().enumerate() {
        if *d != protocol::JointDesc::NONE {
            let name: String = d.name().bytes().map(|b| format!("{b:02x}")).collect();
            text.push_str(&format!(
                "desc.{j}={},{},{:?},{name}\n",
                d.unit,
                d.zero_offset_steps,
                d.scale()
            ));
        }
    }
    // HOMING_SET (issue 33): `homing.J=flags,order,seek_hz,approach_hz,backoff,travel,
    // offset` (flags as on the wire), only for joints set.
    for (j, h) in settings.homing.iter().enumerate() {
        if *h != protocol::HomingSettings::NONE {
            text.push_str(&format!(
                "homing.{j}={},{},{},{},{},{},{}\n",
                h.flags(),
                h.order,
                h.seek_rate_hz,
                h.approach_rate_hz,
                h.backoff_steps,
                h.max_travel_steps,
                h.offset
            ));
        }
    }
    // ESTOP_CATEGORY (issue 32): only when not the default 0.
    if settings.estop_category != protocol::EStopCategory::Instant {
        text.push_str(&format!(
            "estop_category={}\n",
            settings.estop_category as u8
        ));
    }
    text
}

/// Parses the settings file; unknown keys are ignored, missing ones take their defaults.
pub fn parse_settings(text: &str) -> Result<PersistentSettings, String> {
    let mut settings = PersistentSettings::default();
    for line in text.lines() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let (key, value) = line
            .split_once('=')
            .ok_or_else(|| format!("not key=value: {line}"))?;
        let value = value.trim();
        match key.trim() {
            "joints" => {
                let joints: u8 = value.parse().map_err(|_| format!("bad joints: {value}"))?;
                if !protocol::limits::JOINTS.contains(&joints) {
                    return Err(format!("joints out of range: {joints}"));
                }
                settings.joints = joints;
            }
            "ip" => {
                let ip: std::net::Ipv4Addr =
                    value.parse().map_err(|_| format!("bad ip: {value}"))?;
                settings.ip = ip.octets();
            }
            "prefix_len" => {
                let prefix: u8 = value
                    .parse()
                    .map_err(|_| format!("bad prefix_len: {value}"))?;
                if prefix > 32 {
                    return Err(format!("prefix_len out of range: {prefix}"));
                }
                settings.prefix_len = prefix;
            }
            "gateway" => {
                let gateway: std::net::Ipv4Addr =
                    value.parse().map_err(|_| format!("bad gateway: {value}"))?;
                settings.gateway = gateway.octets();
            }
            "dhcp" => {
                settings.dhcp = value.parse().map_err(|_| format!("bad dhcp: {value}"))?;
            }
            "auth_epoch" => {
                settings.auth_epoch = value
                    .parse()
                    .map_err(|_| format!("bad auth_epoch: {value}"))?;
            }
            "key" => {
                let bad = || "bad key: not 64 hex digits".to_string();
                let mut key = [0u8; protocol::auth::KEY_LEN];
                if value.len() != 2 * key.len() || !value.is_ascii() {
                    return Err(bad());
                }
                for (i, b) in key.iter_mut().enumerate() {
                    *b = u8::from_str_radix(&value[2 * i..2 * i + 2], 16).map_err(|_| bad())?;
                }
                settings.key = Some(protocol::auth::AuthKey(key));
            }
            other if other.starts_with("limit.") => {
                let bad = || format!("bad {other}: give limit.J=min,max,max_rate_hz, J 0-7");
                let joint: usize = other["limit.".len()..].parse().map_err(|_| bad())?;
                let fields: Vec<&str> = value.split(',').map(str::trim).collect();
                let [min, max, rate] = fields[..] else {
                    return Err(bad());
                };
                let limits = protocol::JointLimits {
                    min: min.parse().map_err(|_| bad())?,
                    max: max.parse().map_err(|_| bad())?,
                    max_rate_hz: rate.parse().map_err(|_| bad())?,
                };
                if !limits.is_valid() {
                    return Err(format!(
                        "{other}: min {} is above max {}",
                        limits.min, limits.max
                    ));
                }
                *settings.limits.get_mut(joint).ok_or_else(bad)? = limits;
            }
            other if other.starts_with("homing.") => {
                let bad = || {
                    format!(
                        "bad {other}: give homing.J=flags,order,seek_hz,approach_hz,backoff,travel,offset, J 0-7"
                    )
                };
                let joint: usize = other["homing.".len()..].parse().map_err(|_| bad())?;
                let v: Vec<i64> = value
                    .split(',')
                    .map(|f| f.trim().parse::<i64>())
                    .collect::<Result<_, _>>()
                    .map_err(|_| bad())?;
                let [flags, order, seek, approach, backoff, travel, offset] = v[..] else {
                    return Err(bad());
                };
                let u32_of = |x: i64| u32::try_from(x).map_err(|_| bad());
                let flags = u8::try_from(flags).map_err(|_| bad())?;
                let homing = protocol::HomingSettings {
                    enabled: flags & 1 != 0,
                    towards_max: flags & 2 != 0,
                    switch_is_limit: flags & 4 != 0,
                    order: u8::try_from(order).map_err(|_| bad())?,
                    seek_rate_hz: u32_of(seek)?,
                    approach_rate_hz: u32_of(approach)?,
                    backoff_steps: u32_of(backoff)?,
                    max_travel_steps: u32_of(travel)?,
                    offset: i32::try_from(offset).map_err(|_| bad())?,
                };
                if flags > 7 || !homing.is_valid() {
                    return Err(bad());
                }
                *settings.homing.get_mut(joint).ok_or_else(bad)? = homing;
            }
            "estop_category" => {
                settings.estop_category = value
                    .parse::<u8>()
                    .ok()
                    .and_then(protocol::EStopCategory::from_u8)
                    .ok_or_else(|| format!("bad estop_category {value:?}: give 0 or 1"))?;
            }
            other if other.starts_with("accel.") => {
                let bad = || format!("bad {other}: give accel.J=steps/s², J 0-7");
                let joint: usize = other["accel.".len()..].parse().map_err(|_| bad())?;
                let accel: u32 = value.parse().map_err(|_| bad())?;
                *settings.max_accel.get_mut(joint).ok_or_else(bad)? = accel;
            }
            other if other.starts_with("desc.") => {
                let bad = || {
                    format!("bad {other}: give desc.J=unit,zero_offset_steps,scale,name_hex, J 0-7")
                };
                let joint: usize = other["desc.".len()..].parse().map_err(|_| bad())?;
                let fields: Vec<&str> = value.splitn(4, ',').collect();
                let [unit, zero, scale, name] = fields.as_slice() else {
                    return Err(bad());
                };
                let unit = protocol::JointUnit::from_name(unit).ok_or_else(bad)?;
                let zero: i32 = zero.parse().map_err(|_| bad())?;
                let scale: f64 = scale.parse().map_err(|_| bad())?;
                let bytes = (0..name.len())
                    .step_by(2)
                    .map(|i| {
                        name.get(i..i + 2)
                            .and_then(|h| u8::from_str_radix(h, 16).ok())
                    })
                    .collect::<Option<Vec<u8>>>()
                    .ok_or_else(bad)?;
                let name = String::from_utf8(bytes).map_err(|_| bad())?;
                let desc = protocol::JointDesc::new(&name, unit, zero, scale)
                    .filter(protocol::JointDesc::is_valid)
                    .ok_or_else(bad)?;
                *settings.desc.get_mut(joint).ok_or_else(bad)? = desc;
            }
            _ => {}
        }
    }
    Ok(settings)
}

impl SettingsStore for FileSettings {
    type Error = io::ErrorKind;

    async fn load(&mut self) -> Result<Option<PersistentSettings>, Self::Error> {
        let loaded = self.read().map_err(|e| {
            log::warn!("settings: cannot read {}: {e}", self.path.display());
            e.kind()
        })?;
        let loaded = match (loaded, self.boot_joints) {
            (Some(stored), Some(joints)) => Some(PersistentSettings { joints, ..stored }),
            (None, Some(joints)) => Some(PersistentSettings {
                joints,
                ..PersistentSettings::default()
            }),
            (loaded, None) => loaded,
        };
        let loaded = match loaded {
            Some(stored) if self.clear_key && stored.key.is_some() => {
                let cleared = PersistentSettings {
                    key: None,
                    ..stored
                };
                self.write(&cleared).map_err(|e| e.kind())?;
                log::warn!(
                    "settings: authentication key cleared (--clear-key) in {}",
                    self.path.display()
                );
                Some(cleared)
            }
            loaded => loaded,
        };
        match &loaded {
            Some(s) => log::info!("settings: loaded {s:?} from {}", self.path.display()),
            None => log::info!(
                "settings: {} does not exist yet: defaults",
                self.path.display()
            ),
        }
        Ok(loaded)
    }

    async fn save(&mut self, settings: &PersistentSettings) -> Result<(), Self::Error> {
        self.write(settings).map_err(|e| {
            log::warn!("settings: cannot write {}: {e}", self.path.display());
            e.kind()
        })?;
        log::info!("settings: saved {settings:?} to {}", self.path.display());
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn settings_text_round_trips() {
        let settings = PersistentSettings {
            joints: 4,
            ip: [10, 1, 2, 3],
            prefix_len: 16,
            gateway: [10, 1, 0, 1],
            dhcp: true,
            key: Some(protocol::auth::AuthKey([0xc3; 32])),
            auth_epoch: 7,
            limits: [protocol::JointLimits::NONE; protocol::MAX_JOINTS],
            max_accel: [0, 50_000, 0, 0, 0, 0, 0, 1],
            desc: [protocol::JointDesc::NONE; protocol::MAX_JOINTS],
            homing: [protocol::HomingSettings::NONE; protocol::MAX_JOINTS],
            estop_category: protocol::EStopCategory::Instant,
        };
        assert_eq!(parse_settings(&format_settings(&settings)), Ok(settings));
        // JOINT_DESC_SET's descriptions (issue 31) round-trip exactly, any name included;
        // a file without them loads with none.
        let mut described = settings;
        described.desc[1] = protocol::JointDesc::new(
            "shoulder",
            protocol::JointUnit::Degrees,
            -3,
            16000.0 / std::f64::consts::TAU,
        )
        .unwrap();
        described.desc[6] =
            protocol::JointDesc::new("a=b,\nc", protocol::JointUnit::Millimetres, 0, 0.1).unwrap();
        let text = format_settings(&described);
        assert!(
            text.contains("desc.1=deg,-3,2546.47908947032") && text.contains(",73686f756c646572\n"),
            "{text}"
        );
        assert_eq!(parse_settings(&text), Ok(described));
        // HOMING_SET's settings (issue 33) round-trip too.
        let mut homed = described;
        homed.homing[2] = protocol::HomingSettings {
            enabled: true,
            towards_max: true,
            switch_is_limit: false,
            order: 3,
            seek_rate_hz: 2_000,
            approach_rate_hz: 100,
            backoff_steps: 40,
            max_travel_steps: 30_000,
            offset: -12,
        };
        let text = format_settings(&homed);
        assert!(
            text.contains("homing.2=3,3,2000,100,40,30000,-12\n"),
            "{text}"
        );
        assert_eq!(parse_settings(&text), Ok(homed));
        // ESTOP_CATEGORY's (issue 32) round-trips; a file without it loads category 0.
        let mut controlled = homed;
        controlled.estop_category = protocol::EStopCategory::Controlled;
        let text = format_settings(&controlled);
        assert!(text.contains("estop_category=1\n"), "{text}");
        assert_eq!(parse_settings(&text), Ok(controlled));
        assert!(parse_settings("estop_category=2\n").is_err());
        assert!(parse_settings("homing.2=1,0,0,100,40,30000,0\n").is_err());
        assert!(parse_settings("desc.8=deg,0,1.0,61\n").is_err());
        assert!(parse_settings("desc.0=furlong,0,1.0,61\n").is_err());
        assert!(parse_settings("desc.0=deg,0,1.0,6\n").is_err());
        // A file written before ACCEL_SET (issue 31) loads with none.
        let old = format_settings(&settings)
            .replace("accel.1=50000\n", "")
            .replace("accel.7=1\n", "");
        assert_eq!(
            parse_settings(&old).map(|s| s.max_accel),
            Ok([0; protocol::MAX_JOINTS])
        );
        // LIMITS_SET's limits (issue 23) round-trip too.
        let mut limited = settings;
        limited.limits[3] = protocol::JointLimits {
            min: -16_000,
            max: 16_000,
            max_rate_hz: 4_000,
        };
        let text = format_settings(&limited);
        assert!(text.contains("limit.3=-16000,16000,4000\n"), "{text}");
        assert_eq!(parse_settings(&text), Ok(limited));
        assert!(parse_settings("limit.8=0,1,0\n").is_err());
        assert!(parse_settings("limit.0=5,-5,0\n").is_err());
        assert!(parse_settings("limit.0=5,6\n").is_err());
        // A file from before NET_SET: a static address, no gateway.
        assert_eq!(
            parse_settings("joints=4\nip=10.1.2.3\nprefix_len=16\n"),
            Ok(PersistentSettings {
                gateway: [0; 4],
                dhcp: false,
                key: None,
                auth_epoch: 0,
                max_accel: [0; protocol::MAX_JOINTS],
                desc: [protocol::JointDesc::NONE; protocol::MAX_JOINTS],
                homing: [protocol::HomingSettings::NONE; protocol::MAX_JOINTS],
                ..settings
            })
        );
        assert!(parse_settings("joints=9\n").is_err());
        assert!(parse_settings("ip=1.2.3\n").is_err());
        assert_eq!(
            parse_settings("# only a comment\nfuture_key=1\n"),
            Ok(PersistentSettings::default())
        );
    }

    #[test]
    fn gripper_burst_ends_by_itself() {
        let clock = SimClock::new(1000.0, 1_000_000);
        let mut gripper = SimGripper::new(clock, Tracer::disabled());
        // 200 MHz / (200 * 1000) = 1 kHz: 10 pulses = 10 ms simulated = 10 us real.
        let pwm = Pwm {
            psc: 199,
            arr: 999,
            ccr1: 500,
            pulse_count: -10,
        };
        gripper.start(&pwm);
        assert!(gripper.status().burst_end_ns.is_some());
        let deadline = std::time::Instant::now() + std::time::Duration::from_secs(2);
        while gripper.is_active() && std::time::Instant::now() < deadline {
            std::thread::sleep(std::time::Duration::from_micros(100));
        }
        assert!(!gripper.is_active());
        assert_eq!(gripper.status().pulses_done, -10);
        // Servo mode runs until stopped.
        gripper.start(&Pwm {
            pulse_count: 0,
            ..pwm
        });
        std::thread::sleep(std::time::Duration::from_millis(1));
        assert!(gripper.is_active());
        gripper.stop();
        assert!(!gripper.is_active());
    }
}
