//! Command-line syntax of `armctl`, and the commands that need no controller (`frame`,
//! `plot`).

use std::path::PathBuf;

use armctl::plot::{self, Commanded};
use armctl::trajectory;
use armctl::{record, vcd};
use clap::{Args, Parser, Subcommand, ValueEnum};
use protocol::{
    Command, Location, MAX_DATAGRAM, MAX_JOINTS, Point, PointList, Pwm, Report, State, UartInit,
};

/// Drive an arm controller over UDP.
#[derive(Parser, Debug)]
#[command(name = "armctl", version, about)]
pub struct Cli {
    /// The controller's address: HOST or HOST:PORT (port 8510 when not given).
    #[arg(
        long,
        global = true,
        default_value = "127.0.0.1:8510",
        value_name = "HOST[:PORT]"
    )]
    pub controller: String,
    /// Milliseconds to wait for an ACK before sending again, until round trips are
    /// measured (the wait then follows them, down to 3 ms); also the longest wait.
    #[arg(long, global = true, default_value_t = 100, value_name = "MS")]
    pub ack_timeout_ms: u64,
    /// Times a frame is sent at most (no copy leaves later than 1.8 s after the first:
    /// the controller recognises copies for 2 s).
    #[arg(long, global = true, default_value_t = 10)]
    pub attempts: u32,
    /// Local address to send from (e.g. 127.0.0.2:0 to act as another host).
    #[arg(long, global = true, env = "ARMCTL_BIND", value_name = "ADDR:PORT")]
    pub bind: Option<std::net::SocketAddr>,
    /// Write every datagram sent and received to this pcap file (open it in Wireshark
    /// with tools/wireshark/arm_controller.lua).
    #[arg(long, global = true, value_name = "FILE")]
    pub pcap: Option<PathBuf>,
    /// What to do.
    #[command(subcommand)]
    pub command: Cmd,
}

/// The commands.
#[derive(Subcommand, Debug)]
pub enum Cmd {
    /// Print the controller's STATUS.
    Status {
        /// As JSON.
        #[arg(long)]
        json: bool,
    },
    /// Print live positions and state (Ctrl-C ends).
    Watch {
        /// Also write every LOCATION report to this CSV file (for `plot`).
        #[arg(long, value_name = "FILE")]
        record: Option<PathBuf>,
        /// Stop after this many seconds.
        #[arg(long, value_name = "S")]
        duration: Option<f64>,
    },
    /// Upload and execute a trajectory file (JointTrajectory .json or CSV in steps).
    Run(RunArgs),
    /// STOPPED: stop every joint at once and drop the trajectory.
    Stop,
    /// RETURN: move every joint to zero.
    Return {
        /// Wait until the move ends.
        #[arg(long)]
        wait: bool,
    },
    /// JOINTS_COUNT: set the number of joints (1..8).
    Joints {
        /// Joint count.
        #[arg(value_parser = clap::value_parser!(u8).range(1..=8))]
        n: u8,
    },
    /// LOCATION_SETTING: declare the current joint positions, in steps.
    SetLocation {
        /// Position of joint 0, 1, ... in steps.
        #[arg(required = true, num_args = 1..=8, allow_negative_numbers = true)]
        positions: Vec<i32>,
    },
    /// TOGGLE_ENABLE_PINS: toggle driver ENABLE lines (all, or the masked ones).
    Enable {
        /// Bits 0-7 joints, bit 8 gripper (decimal or 0x hex).
        #[arg(long, value_parser = parse_mask)]
        mask: Option<u16>,
    },
    /// Set GPIO pin 0 or 1.
    Pin {
        /// Pin number.
        #[arg(value_parser = clap::value_parser!(u8).range(0..=1))]
        pin: u8,
        /// Level.
        level: OnOff,
    },
    /// Gripper PWM.
    #[command(subcommand)]
    Pwm(PwmCmd),
    /// Bridge stdin/stdout to the controller's serial port.
    Serial {
        /// Baud rate.
        #[arg(long, default_value_t = 115_200)]
        baud: u32,
        /// Directions.
        #[arg(long, value_enum, default_value_t = SerialMode::Both)]
        mode: SerialMode,
        /// Leave the port open at the end of input.
        #[arg(long)]
        keep_open: bool,
    },
    /// UPLOAD_PERIOD: location report period in microseconds (1000..1000000).
    UploadPeriod {
        /// Microseconds.
        us: u32,
    },
    /// UPLOAD_START/UPLOAD_STOP: location reports on or off.
    Reports {
        /// On or off.
        state: OnOff,
    },
    /// Find controllers: DISCOVER to a broadcast address (or --to one controller). Every
    /// controller answers with its MAC, address, version, joints and owner; nothing changes.
    Discover {
        /// Where DISCOVER goes: a broadcast address or one controller.
        #[arg(long, default_value = "255.255.255.255:8510", value_name = "ADDR:PORT")]
        to: std::net::SocketAddrV4,
        /// Milliseconds to collect answers after each DISCOVER.
        #[arg(long, default_value_t = 300, value_name = "MS")]
        wait_ms: u64,
        /// DISCOVERs to send.
        #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u32).range(1..=10))]
        rounds: u32,
        /// As JSON.
        #[arg(long)]
        json: bool,
    },
    /// The controller's network settings (stored in flash, applied after a reset).
    #[command(subcommand)]
    Net(NetCmd),
    /// Encode or decode frames (no controller needed).
    #[command(subcommand)]
    Frame(FrameCmd),
    /// Draw a recorded run (CSV of LOCATION reports, or a sim-host VCD trace) as SVG.
    Plot(PlotArgs),
}

/// `net` subcommands.
#[derive(Subcommand, Debug)]
pub enum NetCmd {
    /// Show the stored settings of --controller (asks with DISCOVER: any host may).
    Show,
    /// NET_SET: store a static address or DHCP (owner only, not while RUNNING); the
    /// controller uses it from its next reset.
    #[command(group(clap::ArgGroup::new("mode").required(true).args(["ip", "dhcp"])))]
    Set {
        /// Static address with its prefix length, e.g. 192.168.1.30/24.
        #[arg(long, value_name = "A.B.C.D/P")]
        ip: Option<String>,
        /// Default gateway (with --ip).
        #[arg(long, value_name = "A.B.C.D", requires = "ip")]
        gateway: Option<std::net::Ipv4Addr>,
        /// Take the address from DHCP.
        #[arg(long, conflicts_with_all = ["ip", "gateway"])]
        dhcp: bool,
    },
}

/// `plot` options.
#[derive(Args, Debug)]
pub struct PlotArgs {
    /// Recording CSV written by `watch --record` or `run --record`, or a VCD trace written
    /// by `sim-host --trace` (recognised by its `.vcd` name or `$` header).
    pub recording: PathBuf,
    /// The commanded trajectory file to draw dashed.
    #[arg(long, value_name = "FILE")]
    pub trajectory: Option<PathBuf>,
    /// Joint config, for a JointTrajectory .json.
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Seconds into the recording at which the trajectory starts (default: the first
    /// report in state RUNNING; for a trace, the first STEP pulse less the time the
    /// trajectory takes to its first step).
    #[arg(long)]
    pub offset: Option<f64>,
    /// Output file.
    #[arg(short, long, default_value = "run.svg")]
    pub output: PathBuf,
    /// Title.
    #[arg(long)]
    pub title: Option<String>,
}

/// `run` options.
#[derive(Args, Debug)]
pub struct RunArgs {
    /// Trajectory file: `.json` (JointTrajectory, radians; needs --config) or CSV
    /// (`time_s, steps...`).
    pub file: PathBuf,
    /// Joint config (JSON: steps_per_radian, zero_offset_steps, min/max_steps,
    /// max_step_rate_hz per joint).
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Segment duration in milliseconds.
    #[arg(long, default_value_t = 10.0)]
    pub segment_ms: f64,
    /// Frames in flight (1 = stop-and-wait, at most 32; default: the window the
    /// controller advertises in STATUS, 8 for one that advertises none).
    #[arg(long, value_parser = clap::value_parser!(u16).range(1..=32))]
    pub window: Option<u16>,
    /// Send RUNING once this many points are acknowledged (default: when the buffer is full
    /// or everything is uploaded).
    #[arg(long)]
    pub start_after: Option<usize>,
    /// Write every LOCATION report during the run to this CSV file.
    #[arg(long, value_name = "FILE")]
    pub record: Option<PathBuf>,
    /// Only convert and check the file; print the points count and send nothing. Without
    /// a controller the step rate is checked against the config, and at most against
    /// `--max-step-rate`.
    #[arg(long)]
    pub dry_run: bool,
    /// For `--dry-run`: the controller's step rate limit per joint (steps/s) to check
    /// against; the board's by default.
    #[arg(long, value_name = "HZ", default_value_t = DEFAULT_MAX_STEP_RATE_HZ)]
    pub max_step_rate: u32,
    /// Do not show a progress bar.
    #[arg(long)]
    pub quiet: bool,
}

/// On or off.
#[derive(ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum OnOff {
    /// High / on.
    On,
    /// Low / off.
    Off,
}

/// Serial directions.
#[derive(ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum SerialMode {
    /// Transmit and receive.
    Both,
    /// Receive only.
    Rx,
    /// Transmit only.
    Tx,
}

impl SerialMode {
    /// The UartInit `Mode` value.
    pub fn code(self) -> u32 {
        match self {
            SerialMode::Both => 0,
            SerialMode::Rx => 1,
            SerialMode::Tx => 2,
        }
    }
}

/// `pwm` subcommands.
#[derive(Subcommand, Debug)]
pub enum PwmCmd {
    /// Servo mode: runs until `pwm stop`.
    Servo {
        /// Frequency, Hz.
        #[arg(long, default_value_t = 50.0)]
        freq: f64,
        /// Duty cycle, 0..1.
        #[arg(long)]
        duty: f64,
    },
    /// Stepper mode: N pulses (negative: the other way), then stops by itself.
    Stepper {
        /// Pulses, signed.
        #[arg(long, allow_negative_numbers = true)]
        pulses: i32,
        /// Pulse frequency, Hz.
        #[arg(long, default_value_t = 1000.0)]
        freq: f64,
    },
    /// Raw timer registers.
    Raw(RawPwm),
    /// PWM_STOP.
    Stop,
}

/// Raw `Pwm` registers.
#[derive(Args, Debug, Clone, Copy)]
pub struct RawPwm {
    /// Prescaler (16 bits).
    #[arg(long)]
    pub psc: u32,
    /// Auto-reload (16 bits).
    #[arg(long)]
    pub arr: u32,
    /// Compare (<= ARR).
    #[arg(long)]
    pub ccr1: u32,
    /// 0: servo mode; else stepper pulses.
    #[arg(long, default_value_t = 0, allow_negative_numbers = true)]
    pub pulses: i32,
}

impl From<RawPwm> for Pwm {
    fn from(raw: RawPwm) -> Pwm {
        Pwm {
            psc: raw.psc,
            arr: raw.arr,
            ccr1: raw.ccr1,
            pulse_count: raw.pulses,
        }
    }
}

/// `frame` subcommands.
#[derive(Subcommand, Debug)]
pub enum FrameCmd {
    /// Decode a frame given in hex and print it as JSON.
    Decode {
        /// Hex bytes (spaces, colons and a 0x prefix are allowed).
        hex: Vec<String>,
        /// Which direction to decode it as (default: a command if it is one, else a report).
        #[arg(long = "as", value_enum)]
        direction: Option<Direction>,
    },
    /// Encode a command and print it in hex.
    Encode {
        /// Sequence number.
        #[arg(long, default_value_t = 0)]
        seq: u8,
        /// The command.
        #[command(subcommand)]
        command: EncodeCmd,
    },
}

/// Frame direction.
#[derive(ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum Direction {
    /// Host to controller.
    Command,
    /// Controller to host.
    Report,
}

/// Commands `frame encode` knows.
#[derive(Subcommand, Debug)]
pub enum EncodeCmd {
    /// NEW COUNT.
    New {
        /// Points.
        count: u16,
    },
    /// PENDING: points from `--from`, each `--point DURATION_US:P0,P1,...`.
    Pending {
        /// Position before the first point, steps (default all 0).
        #[arg(long, value_delimiter = ',', allow_negative_numbers = true)]
        from: Vec<i32>,
        /// `DURATION_US:P0,P1,...`, 1 to 12 times.
        #[arg(long = "point", required = true, allow_negative_numbers = true)]
        points: Vec<String>,
    },
    /// RUNING.
    Runing,
    /// STOPPED.
    Stopped,
    /// UPLOAD_START.
    UploadStart,
    /// UPLOAD_STOP.
    UploadStop,
    /// PWM_START with raw registers.
    PwmStart(RawPwm),
    /// PWM_STOP.
    PwmStop,
    /// USART_START.
    UsartStart {
        /// Baud rate.
        #[arg(long, default_value_t = 115_200)]
        baud: u32,
        /// Directions.
        #[arg(long, value_enum, default_value_t = SerialMode::Both)]
        mode: SerialMode,
    },
    /// USART_STOP.
    UsartStop,
    /// USART_SEND with bytes in hex.
    UsartSend {
        /// Hex bytes.
        hex: String,
    },
    /// PIN0_ON.
    Pin0On,
    /// PIN0_OFF.
    Pin0Off,
    /// PIN1_ON.
    Pin1On,
    /// PIN1_OFF.
    Pin1Off,
    /// TOGGLE_ENABLE_PINS.
    ToggleEnable {
        /// Mask (decimal or 0x hex).
        #[arg(long, value_parser = parse_mask)]
        mask: Option<u16>,
    },
    /// RETURN.
    Return,
    /// JOINTS_COUNT N.
    JointsCount {
        /// Joints.
        n: u8,
    },
    /// LOCATION_SETTING P0 P1 ...
    LocationSetting {
        /// Steps.
        #[arg(required = true, num_args = 1..=8, allow_negative_numbers = true)]
        positions: Vec<i32>,
    },
    /// STATUS.
    Status,
    /// UPLOAD_PERIOD US.
    UploadPeriod {
        /// Microseconds.
        us: u32,
    },
}

/// The step rate limit `run --dry-run` checks against without a controller: the board's
/// `max_step_rate_hz` (PROTOCOL.md, "Figures of this firmware"; sim-host reports the same).
pub const DEFAULT_MAX_STEP_RATE_HZ: u32 = 100_000;

/// The controller address with the default port when `text` names none: `HOST`,
/// `A.B.C.D`, `::1` or `[::1]` get `:8510`; `HOST:PORT` and `[V6]:PORT` are kept.
pub fn controller_address(text: &str) -> String {
    let text = text.trim();
    if text.parse::<std::net::SocketAddr>().is_ok() {
        return text.to_string();
    }
    if let Ok(ip) = text.parse::<std::net::IpAddr>() {
        return std::net::SocketAddr::new(ip, armctl::DEFAULT_PORT).to_string();
    }
    if let Some(inner) = text.strip_prefix('[').and_then(|t| t.strip_suffix(']'))
        && let Ok(ip) = inner.parse::<std::net::Ipv6Addr>()
    {
        return std::net::SocketAddr::new(ip.into(), armctl::DEFAULT_PORT).to_string();
    }
    match text.rsplit_once(':') {
        Some((host, port)) if !host.contains(':') && port.parse::<u16>().is_ok() => {
            text.to_string()
        }
        _ => format!("{text}:{}", armctl::DEFAULT_PORT),
    }
}

/// A warning when `--ack-timeout-ms` x `--attempts` reaches past the controller's
/// duplicate window: the client then stops resending 1.8 s after the first copy.
pub fn resend_warning(ack_timeout_ms: u64, attempts: u32) -> Option<String> {
    let span = u128::from(ack_timeout_ms) * u128::from(attempts);
    (span > armctl::DUPLICATE_WINDOW.as_millis()).then(|| {
        format!(
            "--ack-timeout-ms {ack_timeout_ms} x --attempts {attempts} = {:.1} s exceeds the \
             controller's {} s duplicate window: a copy sent later could be executed twice, \
             so resends stop {:.1} s after the first copy",
            span as f64 / 1000.0,
            armctl::DUPLICATE_WINDOW.as_secs(),
            armctl::RESEND_HORIZON.as_secs_f64()
        )
    })
}

/// Parses a mask in decimal or `0x` hex.
pub fn parse_mask(text: &str) -> Result<u16, String> {
    let value = match text.strip_prefix("0x").or_else(|| text.strip_prefix("0X")) {
        Some(hex) => u16::from_str_radix(hex, 16),
        None => text.parse::<u16>(),
    }
    .map_err(|e| format!("{text:?} is not a 16-bit number: {e}"))?;
    if value & !protocol::limits::ENABLE_MASK_BITS != 0 {
        return Err(format!(
            "mask {value:#x} uses bits above 8 (bits 0-7 joints, bit 8 gripper)"
        ));
    }
    Ok(value)
}

/// Parses hex bytes, ignoring spaces, colons, dashes and `0x` prefixes.
pub fn parse_hex(text: &str) -> Result<Vec<u8>, String> {
    let cleaned: String = text
        .split_whitespace()
        .map(|w| w.trim_start_matches("0x").trim_start_matches("0X"))
        .collect::<Vec<_>>()
        .concat()
        .chars()
        .filter(|c| !matches!(c, ':' | '-' | '_'))
        .collect();
    if !cleaned.len().is_multiple_of(2) {
        return Err(format!(
            "odd number of hex digits ({}): every byte needs two",
            cleaned.len()
        ));
    }
    (0..cleaned.len())
        .step_by(2)
        .map(|i| {
            u8::from_str_radix(&cleaned[i..i + 2], 16)
                .map_err(|_| format!("{:?} is not a hex byte", &cleaned[i..i + 2]))
        })
        .collect()
}

/// Hex of bytes, lower case, no separators.
pub fn to_hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// `frame decode`: the frame as pretty JSON, or the decode error's message.
pub fn decode_frame(bytes: &[u8], direction: Option<Direction>) -> Result<String, String> {
    let as_command = || {
        Command::decode(bytes).map(|frame| {
            serde_json::json!({ "direction": "command", "seq": frame.seq, "tag": frame.body.tag().name(), "command": frame.body })
        })
    };
    let as_report = || {
        // DISCOVER_REPLY is not a `Report` (it answers only the asker): decoded on its own.
        if let Ok(frame) = protocol::DiscoverReply::decode(bytes) {
            return Ok(
                serde_json::json!({ "direction": "report", "seq": frame.seq, "tag": "DISCOVER_REPLY", "report": frame.body }),
            );
        }
        Report::decode(bytes).map(|frame| {
            let tag = match frame.body.tag() {
                protocol::Tag::Location => "LOCATION",
                other => other.name(),
            };
            serde_json::json!({ "direction": "report", "seq": frame.seq, "tag": tag, "report": frame.body })
        })
    };
    let value = match direction {
        Some(Direction::Command) => as_command().map_err(|e| e.to_string())?,
        Some(Direction::Report) => as_report().map_err(|e| e.to_string())?,
        None => match as_command() {
            Ok(v) => v,
            Err(command_error) => match as_report() {
                Ok(v) => v,
                Err(report_error) => {
                    // The message that explains most: the report's only when the tag is
                    // one that travels from the controller.
                    let error = if command_error.kind == protocol::DecodeErrorKind::WrongDirection {
                        report_error
                    } else {
                        command_error
                    };
                    return Err(error.to_string());
                }
            },
        },
    };
    serde_json::to_string_pretty(&value).map_err(|e| e.to_string())
}

/// Parses `DURATION_US:P0,P1,...`.
fn parse_point_spec(spec: &str) -> Result<(i32, [i32; MAX_JOINTS]), String> {
    let (duration, positions) = spec
        .split_once(':')
        .ok_or_else(|| format!("point {spec:?} is not DURATION_US:P0,P1,..."))?;
    let duration = duration
        .trim()
        .parse::<i32>()
        .map_err(|e| format!("point {spec:?}: duration: {e}"))?;
    let mut target = [0; MAX_JOINTS];
    let values: Vec<&str> = positions.split(',').collect();
    if values.len() > MAX_JOINTS {
        return Err(format!("point {spec:?}: {MAX_JOINTS} positions at most"));
    }
    for (slot, value) in target.iter_mut().zip(values) {
        *slot = value
            .trim()
            .parse()
            .map_err(|e| format!("point {spec:?}: position {value:?}: {e}"))?;
    }
    Ok((duration, target))
}

/// `frame encode`: the frame in hex.
pub fn encode_frame(seq: u8, command: &EncodeCmd) -> Result<String, String> {
    let mut location = Location::default();
    let serial: Vec<u8>;
    let mut points = Vec::new();
    let command = match command {
        EncodeCmd::New { count } => Command::New { count: *count },
        EncodeCmd::Pending {
            from,
            points: specs,
        } => {
            if from.len() > MAX_JOINTS {
                return Err(format!("--from: {MAX_JOINTS} positions at most"));
            }
            let mut previous = [0; MAX_JOINTS];
            previous[..from.len()].copy_from_slice(from);
            for spec in specs {
                let (duration, target) = parse_point_spec(spec)?;
                points.push(Point::from_motion(duration, &previous, &target));
                previous = target;
            }
            Command::Pending(PointList::Points(&points))
        }
        EncodeCmd::Runing => Command::Runing,
        EncodeCmd::Stopped => Command::Stopped,
        EncodeCmd::UploadStart => Command::UploadStart,
        EncodeCmd::UploadStop => Command::UploadStop,
        EncodeCmd::PwmStart(raw) => Command::PwmStart((*raw).into()),
        EncodeCmd::PwmStop => Command::PwmStop,
        EncodeCmd::UsartStart { baud, mode } => Command::UsartStart(UartInit {
            baud_rate: *baud,
            mode: mode.code(),
            ..UartInit::default()
        }),
        EncodeCmd::UsartStop => Command::UsartStop,
        EncodeCmd::UsartSend { hex } => {
            serial = parse_hex(hex)?;
            Command::UsartSend(&serial)
        }
        EncodeCmd::Pin0On => Command::Pin0On,
        EncodeCmd::Pin0Off => Command::Pin0Off,
        EncodeCmd::Pin1On => Command::Pin1On,
        EncodeCmd::Pin1Off => Command::Pin1Off,
        EncodeCmd::ToggleEnable { mask } => Command::ToggleEnablePins { mask: *mask },
        EncodeCmd::Return => Command::Return,
        EncodeCmd::JointsCount { n } => Command::JointsCount(*n),
        EncodeCmd::LocationSetting { positions } => {
            location.position[..positions.len()].copy_from_slice(positions);
            Command::LocationSetting(location)
        }
        EncodeCmd::Status => Command::Status,
        EncodeCmd::UploadPeriod { us } => Command::UploadPeriod { period_us: *us },
    };
    let mut buf = [0u8; MAX_DATAGRAM];
    let len = command.encode(seq, &mut buf).map_err(|e| e.to_string())?;
    Ok(to_hex(&buf[..len]))
}

/// Whether `path` is a VCD trace: a `.vcd` name, or a first word that is a `$` keyword.
fn is_vcd(path: &std::path::Path) -> bool {
    if path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("vcd"))
    {
        return true;
    }
    let mut start = [0u8; 256];
    std::fs::File::open(path)
        .and_then(|mut f| std::io::Read::read(&mut f, &mut start))
        .is_ok_and(|n| vcd::looks_like_vcd(&start[..n]))
}

/// `plot`: draws a recording or a trace to `args.output`; returns what to print.
pub fn plot(args: &PlotArgs) -> Result<String, String> {
    let commanded = match &args.trajectory {
        Some(path) => {
            let (waypoints, _) =
                trajectory::load_files(path, args.config.as_deref()).map_err(|e| e.to_string())?;
            Some(Commanded::from_waypoints(&waypoints))
        }
        None => None,
    };
    let title = args
        .title
        .clone()
        .unwrap_or_else(|| args.recording.display().to_string());
    let (svg, summary) = if is_vcd(&args.recording) {
        let trace = vcd::read(&args.recording).map_err(|e| e.to_string())?;
        let commanded = commanded.map(|mut c| {
            // The trace has no "run started" mark: its first STEP pulse is the
            // trajectory's first step.
            c.offset_s =
                args.offset
                    .unwrap_or_else(|| match (trace.first_step_s(), c.first_step_s()) {
                        (Some(traced), Some(commanded)) => traced - commanded,
                        (traced, _) => traced.unwrap_or(0.0),
                    });
            c
        });
        let moved: Vec<String> = trace
            .joints
            .iter()
            .enumerate()
            .filter(|(_, j)| j.steps > 0)
            .map(|(i, j)| format!("joint {i}: {} steps, ends at {}", j.steps, j.position))
            .collect();
        let summary = format!(
            "trace of {:.6} s; {}",
            trace.end_tick as f64 * trace.seconds_per_tick,
            if moved.is_empty() {
                "no STEP pulses".to_string()
            } else {
                moved.join("; ")
            }
        );
        (plot::trace_svg(&trace, commanded.as_ref(), &title), summary)
    } else {
        let samples = record::read(&args.recording).map_err(|e| e.to_string())?;
        let commanded = commanded.map(|mut c| {
            // A run's points start when the controller starts RUNNING.
            c.offset_s = args.offset.unwrap_or_else(|| {
                samples
                    .iter()
                    .find(|s| s.state == State::Running as u8)
                    .map_or(0.0, |s| s.time_s)
            });
            c
        });
        let summary = format!("{} samples", samples.len());
        (plot::svg(&samples, commanded.as_ref(), &title), summary)
    };
    std::fs::write(&args.output, svg).map_err(|e| format!("{}: {e}", args.output.display()))?;
    Ok(format!("wrote {} ({summary})", args.output.display()))
}
