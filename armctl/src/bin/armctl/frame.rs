//! `armctl frame decode|encode`: frames to and from hex, no controller needed.

use clap::{Subcommand, ValueEnum};
use protocol::{Command, Location, MAX_DATAGRAM, MAX_JOINTS, Point, PointList, Report, UartInit};

use crate::CliResult;
use crate::cli::{SerialMode, parse_mask};
use crate::pwm::RawPwm;

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
    /// ESTOP_RESET.
    EstopReset,
    /// ESTOP_CATEGORY N (issue 32; 0 or 1 is what the controller takes).
    EstopCategory {
        /// The category.
        category: u8,
    },
    /// UNLOCK (issue 33).
    Unlock,
    /// HOLD (issue 32).
    Hold,
    /// RESUME (issue 32).
    Resume,
    /// OVERRIDE PERCENT (issue 32; 1..200 is what the controller takes).
    Override {
        /// Percent.
        percent: u8,
    },
    /// SET_ENABLE MASK (issue 23): `--disable` for limp, else holding.
    SetEnable {
        /// Mask, bits 0-7 joints, 8 gripper (decimal or 0x hex).
        #[arg(value_parser = parse_mask)]
        mask: u16,
        /// Disable (limp) instead of enable.
        #[arg(long)]
        disable: bool,
    },
    /// RELEASE (issue 23).
    Release,
    /// LIMITS_SET JOINT MIN MAX MAX_RATE_HZ (issue 23).
    LimitsSet {
        /// Joint, 0-7.
        joint: u8,
        /// Lowest position, steps.
        #[arg(allow_negative_numbers = true)]
        min: i32,
        /// Highest position, steps.
        #[arg(allow_negative_numbers = true)]
        max: i32,
        /// Steps per second (0: the controller's own only).
        max_rate_hz: u32,
    },
    /// LIMITS_GET (issue 23).
    LimitsGet,
}

/// Runs `frame decode` or `frame encode`: prints the JSON or the hex.
pub fn execute(command: &FrameCmd) -> CliResult {
    match command {
        FrameCmd::Decode { hex, direction } => {
            let bytes = parse_hex(&hex.join(" "))?;
            println!("{}", decode_frame(&bytes, *direction)?);
        }
        FrameCmd::Encode { seq, command } => println!("{}", encode_frame(*seq, command)?),
    }
    Ok(())
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
        EncodeCmd::EstopReset => Command::EstopReset,
        EncodeCmd::EstopCategory { category } => Command::EstopCategory(
            protocol::EStopCategory::from_u8(*category)
                .ok_or_else(|| format!("ESTOP_CATEGORY {category}: the protocol has 0 and 1"))?,
        ),
        EncodeCmd::Unlock => Command::Unlock,
        EncodeCmd::Hold => Command::Hold,
        EncodeCmd::Resume => Command::Resume,
        EncodeCmd::Override { percent } => Command::Override { percent: *percent },
        EncodeCmd::SetEnable { mask, disable } => Command::SetEnable {
            mask: *mask,
            enable: !*disable,
        },
        EncodeCmd::Release => Command::Release,
        EncodeCmd::LimitsSet {
            joint,
            min,
            max,
            max_rate_hz,
        } => Command::LimitsSet(protocol::LimitsSet {
            joint: *joint,
            limits: protocol::JointLimits {
                min: *min,
                max: *max,
                max_rate_hz: *max_rate_hz,
            },
        }),
        EncodeCmd::LimitsGet => Command::LimitsGet,
    };
    let mut buf = [0u8; MAX_DATAGRAM];
    let len = command.encode(seq, &mut buf).map_err(|e| e.to_string())?;
    Ok(to_hex(&buf[..len]))
}
