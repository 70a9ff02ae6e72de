//! Command-line syntax of `armctl`: the global options and the list of subcommands. The
//! options of the larger subcommands live with them (`run::RunArgs`, `plot::PlotArgs`,
//! `pwm::PwmCmd`, `net::NetCmd`, `frame::FrameCmd`).

use std::path::PathBuf;

use clap::{Parser, Subcommand, ValueEnum};

use crate::config::ConfigCmd;
use crate::frame::FrameCmd;
use crate::motion::{JogArgs, MoveArgs};
use crate::net::NetCmd;
use crate::plot::PlotArgs;
use crate::pwm::PwmCmd;
use crate::run::RunArgs;
use crate::serve::ServeArgs;

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
    /// The controller's authentication key: a file of 64 hex digits (docs/PROTOCOL.md
    /// section 13). With it every frame but STOPPED goes authenticated.
    #[arg(long, global = true, env = "ARMCTL_KEY_FILE", value_name = "FILE")]
    pub key_file: Option<PathBuf>,
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
    /// Print the controller's STATUS, each joint's position and driver: from any host
    /// (read-only when another owns the controller), never taking the controller.
    Status {
        /// As JSON.
        #[arg(long)]
        json: bool,
        /// A joint config (the `run --config` file): joint names and positions in degrees.
        /// Without it: the names and units the controller keeps (`config push`), if any.
        #[arg(long, value_name = "FILE")]
        config: Option<PathBuf>,
    },
    /// Print the controller's own counters (issue 34): the longest span with interrupts
    /// masked and where it was opened, DIR lateness, the least step DMA slack, RX ring
    /// overflows and shed datagrams. From any host, never taking the controller; the
    /// simulator gives figures of its own (host ns, its step thread's lateness; no DMA).
    Diag {
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
        /// Joint config: positions shown with the joints' names, in its units. Without it:
        /// the names and units the controller keeps (`config push`), if any.
        #[arg(long, value_name = "FILE")]
        config: Option<PathBuf>,
        /// Units of the positions shown with --config: steps, deg or rad (default: the
        /// config's).
        #[arg(long, requires = "config")]
        units: Option<armctl::motion::Units>,
    },
    /// Upload and execute a trajectory file (JointTrajectory .json or CSV in steps).
    Run(RunArgs),
    /// Convert and check a trajectory file without a controller (`run --dry-run`): points,
    /// duration, every waypoint reached, limits and step rates.
    Check(RunArgs),
    /// STOPPED: stop every joint at once and drop the trajectory.
    Stop,
    /// RELEASE: give the controller up (only while STOPPED), so that another host may take
    /// it at once instead of after 5 s of silence.
    Release,
    /// ESTOP_RESET: clear the wired e-stop input's latch (once the input is closed again);
    /// until then RUNING and RETURN are refused with ESTOP_LATCHED.
    EstopReset,
    /// ESTOP_CATEGORY: how the wired e-stop input stops the arm, 0 (at once, the
    /// default) or 1 (a controlled stop along the path, then the drivers disabled); kept
    /// in the controller's settings, set only while STOPPED. Without a value: shows it.
    EstopCategory {
        /// 0 or 1.
        #[arg(value_parser = clap::value_parser!(u8).range(0..=1))]
        category: Option<u8>,
    },
    /// UNLOCK: clear the latch a limit switch set; then only motion away from a switch
    /// still active is accepted, until it opens.
    Unlock,
    /// HOLD: decelerate the run along its path to a standstill and wait (RUNNING, held);
    /// from any host. `resume` goes on; `stop` still stops at once.
    Hold,
    /// RESUME: after a hold, accelerate back and go on (the owner).
    Resume,
    /// OVERRIDE: run at PERCENT of the trajectory's speed (1..200), ramped in within the
    /// joints' accelerations; also the speed of the runs to come until changed.
    Override {
        /// Percent of the planned speed: 100 is the file's own.
        #[arg(value_parser = clap::value_parser!(u8).range(1..=200))]
        percent: u8,
    },
    /// Each joint's homing on its home switch (HOMING_GET, HOMING_SET; `home` runs it).
    #[command(subcommand)]
    Homing(crate::homing::HomingCmd),
    /// RETURN: move every joint to zero.
    Return {
        /// Wait until the move ends.
        #[arg(long)]
        wait: bool,
    },
    /// Move joints to positions (steps, or deg/rad with a config) on a speed profile
    /// planned within each joint's limits; joints not given hold.
    Move(MoveArgs),
    /// Jog: `jog JOINT BY` moves one joint by an increment; `jog` alone jogs by keys (digits
    /// choose a joint, arrows move it, Space stops, q quits).
    Jog(JogArgs),
    /// Home the arm: on the home switches when it has them (HOME: each joint set with
    /// `homing set` seeks its switch, backs off, approaches slowly and takes its offset),
    /// otherwise RETURN with progress: every joint to zero, a live position line, and a
    /// check that all are there.
    Home {
        /// Joint config (names, units).
        #[arg(long, value_name = "FILE")]
        config: Option<PathBuf>,
        /// Units of the positions shown: steps, deg or rad (default: the config's).
        #[arg(long)]
        units: Option<armctl::motion::Units>,
    },
    /// JOINTS_COUNT: set the number of joints (1..8).
    Joints {
        /// Joint count.
        #[arg(value_parser = clap::value_parser!(u8).range(1..=8))]
        n: u8,
    },
    /// LOCATION_SETTING: declare the current joint positions, in steps.
    SetLocation {
        /// Position of joint 0, 1, ... in steps; joints not given keep their positions.
        #[arg(required = true, num_args = 1..=8, allow_negative_numbers = true)]
        positions: Vec<i32>,
    },
    /// SET_ENABLE: enable (holding torque) the drivers of JOINTS, every driver when none
    /// is given; the others are left as they are. Sending it twice changes nothing more.
    Enable {
        /// Joints (0-7) and `gripper`, e.g. `0 1 gripper` or `0,1`; `all` or none: every
        /// driver.
        #[arg(value_parser = crate::enable::parse_driver, value_delimiter = ',')]
        joints: Vec<u16>,
    },
    /// SET_ENABLE: disable (make limp: the joint can be moved by hand) the drivers of
    /// JOINTS, every driver when none is given; the others are left as they are.
    Disable {
        /// Joints (0-7) and `gripper`, e.g. `2 3` or `2,3`; `all` or none: every driver.
        #[arg(value_parser = crate::enable::parse_driver, value_delimiter = ',')]
        joints: Vec<u16>,
    },
    /// TOGGLE_ENABLE_PINS: toggle driver ENABLE lines (all, or the masked ones), for
    /// controllers older than SET_ENABLE.
    ToggleEnable {
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
        /// Where DISCOVER goes: a broadcast address or one controller (default:
        /// 255.255.255.255:8510, or the broadcast address of --interface).
        #[arg(long, value_name = "ADDR:PORT")]
        to: Option<std::net::SocketAddrV4>,
        /// The interface on the controllers' network (e.g. eth0): DISCOVER is sent from its
        /// IPv4 address to its network's broadcast address.
        #[arg(long, value_name = "NAME")]
        interface: Option<String>,
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
    /// A pendant in the browser: serve a page (127.0.0.1:8520 by default) with live
    /// positions, a plot of the run, the e-stop, jog, home, enable and trajectory runs.
    Serve(ServeArgs),
    /// Draw a recorded run (CSV of LOCATION reports, or a sim-host VCD trace) as SVG.
    Plot(PlotArgs),
    /// The authentication key (docs/PROTOCOL.md section 13).
    #[command(subcommand)]
    Key(KeyCmd),
    /// The limits kept on the controller: each joint's position range and step rate
    /// (LIMITS_GET, LIMITS_SET), enforced on every point, RETURN and set-location.
    #[command(subcommand)]
    Config(ConfigCmd),
}

/// `armctl key ...`.
#[derive(Subcommand, Debug)]
pub enum KeyCmd {
    /// A new random key (64 hex digits) for a key file: `armctl key new -o arm.key` (or
    /// `> arm.key`); the file is made readable by its owner alone (0600).
    New {
        /// Write it to this file (created 0600; an existing file is not overwritten).
        #[arg(short, long, value_name = "FILE")]
        output: Option<PathBuf>,
    },
    /// SET_KEY: store the key of FILE in the controller. The first time plain (as the
    /// owner); to change a key set already, give the current one with --key-file.
    Set {
        /// The new key's file.
        file: PathBuf,
    },
    /// SET_KEY with no key: the controller takes every frame plain again (needs the
    /// current key, --key-file; lost: hold the user button at reset, or --clear-key).
    Clear,
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
