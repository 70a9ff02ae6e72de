//! Command-line options of the simulated controller.

use std::net::SocketAddrV4;
use std::path::PathBuf;

use arm_core::config::ServoOnStop;
use clap::{Args, Parser, Subcommand};

use crate::devices::EncoderFaultMode;
use crate::faults::FaultConfig;
use crate::serial::SerialKind;

/// The arm controller on a PC: the firmware's own tasks with simulated hardware.
#[derive(Debug, Parser)]
#[command(name = "sim-host", version, about, long_about = None)]
pub struct Cli {
    /// The simulated controller.
    #[command(flatten)]
    pub sim: SimOptions,
    /// What to do (default: run the controller until Ctrl-C).
    #[command(subcommand)]
    pub command: Option<Command>,
}

/// Subcommands.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Run a 6-joint pick-and-place against an in-process simulated controller, over UDP,
    /// and write a plot of commanded versus executed joint positions.
    Demo(crate::demo::DemoOptions),
    /// Measure upload throughput, e-stop latency and CPU use of the simulated controller.
    Bench(crate::bench::BenchOptions),
    /// Measure, from outside, STOPPEDs from a third host while a stranger floods a running
    /// controller (this simulator's, or the QEMU board over TAP: tests/qemu/tap.sh).
    Flood(crate::flood::FloodOptions),
}

/// Everything that configures the simulated controller.
#[derive(Clone, Debug, Args)]
pub struct SimOptions {
    /// UDP address the controller listens on.
    #[arg(long, default_value = "127.0.0.1:8510")]
    pub bind: SocketAddrV4,

    /// Joint count at boot, overriding the persisted JOINTS_COUNT (1..8; not saved).
    #[arg(long, value_parser = clap::value_parser!(u8).range(1..=8))]
    pub joints: Option<u8>,

    /// Trajectory buffer size in points (at most the firmware's compile-time storage).
    #[arg(long)]
    pub buffer_capacity: Option<usize>,

    /// Step timer frequency, ticks per simulated second (default: the NUCLEO's joint
    /// timers' 200 MHz, the simulator's profile).
    #[arg(long, default_value_t = crate::app::PROFILE.step_timer_hz, value_parser = clap::value_parser!(u32).range(1_000..=1_000_000_000))]
    pub tick_hz: u32,

    /// Simulated seconds per real second (10 = ten times faster than real time).
    #[arg(long, default_value_t = 1.0, value_parser = parse_time_scale)]
    pub time_scale: f64,

    /// Log level: error, warn, info, debug, trace (or an env_logger filter such as
    /// `info,sim_host=debug`). RUST_LOG overrides it.
    #[arg(long, default_value = "info")]
    pub log_level: String,

    /// Write STEP/DIR/ENABLE of every joint, the gripper and PIN0/PIN1 to this VCD file.
    #[arg(long, value_name = "FILE.vcd")]
    pub trace: Option<PathBuf>,

    /// Write every datagram the controller receives and sends to this pcap file (open it
    /// in Wireshark with tools/wireshark/arm_controller.lua).
    #[arg(long, value_name = "FILE.pcap")]
    pub pcap: Option<PathBuf>,

    /// The serial pass-through port.
    #[arg(long, value_enum, default_value_t = SerialKind::Loopback)]
    pub serial: SerialKind,

    /// Where joint J's absolute encoder really is at boot, in steps, while the step count
    /// starts at 0 (repeatable): RETURN then moves it home by the encoder.
    #[arg(long = "encoder-offset", value_name = "J:STEPS", value_parser = parse_encoder_offset)]
    pub encoder_offsets: Vec<(usize, i64)>,

    /// Where joint J physically is at boot, in steps, while its step count starts at 0
    /// (repeatable; issue 33's switch model: the home and limit switches below are at
    /// physical positions).
    #[arg(long = "position", value_name = "J:STEPS", value_parser = parse_encoder_offset)]
    pub positions: Vec<(usize, i64)>,

    /// Give joint J a home switch, pressed when the joint is at or beyond physical STEPS
    /// towards `min` (the default) or `max` (repeatable). Wired normally closed: the
    /// controller sees it as an input reading high when pressed.
    #[arg(long = "home-switch", value_name = "J:STEPS[:min|max]", value_parser = parse_home_switch)]
    pub home_switches: Vec<(usize, i64, arm_core::switches::Side)>,

    /// Give joint J limit switches: min pressed at or below physical MIN, max at or above
    /// MAX (repeatable). A limit closing stops every joint at that step edge and latches
    /// the controller until UNLOCK.
    #[arg(long = "limit-switch", value_name = "J:MIN:MAX", value_parser = parse_limit_switch)]
    pub limit_switches: Vec<(usize, i64, i64)>,

    /// Make joint J's simulated Modbus encoder misbehave (repeatable): `silent` never
    /// answers, `crc` answers with a bad CRC, `exception` refuses the request. RETURN then
    /// ends in STOPPED without moving.
    #[arg(long = "encoder-fault", value_name = "J:KIND", value_parser = parse_encoder_fault)]
    pub encoder_faults: Vec<(usize, EncoderFaultMode)>,

    /// Simulate a board without absolute encoders (RETURN trusts the step count).
    #[arg(long)]
    pub no_encoders: bool,

    /// Settings file (JOINTS_COUNT, address). Default: sim-host/settings-PORT.txt in the
    /// user's state directory.
    #[arg(long, value_name = "FILE")]
    pub settings: Option<PathBuf>,

    /// Remove the authentication key from the settings file at start (the simulator's
    /// stand-in for the board's user button held at reset: docs/PROTOCOL.md section 13).
    #[arg(long)]
    pub clear_key: bool,

    /// Probability that a datagram is lost (each direction).
    #[arg(long, default_value_t = 0.0, value_parser = parse_probability)]
    pub loss: f64,

    /// Probability that a datagram is duplicated (each direction).
    #[arg(long, default_value_t = 0.0, value_parser = parse_probability)]
    pub dup: f64,

    /// Probability that a datagram is held back and delivered after the next one.
    #[arg(long, default_value_t = 0.0, value_parser = parse_probability)]
    pub reorder: f64,

    /// Seed of the fault injection (same seed, same faults).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,

    /// Run the network task on embassy-net over this TAP device instead of a host socket.
    #[arg(long, value_name = "IFACE")]
    pub tap: Option<String>,

    /// With --tap: static address and prefix (`192.168.7.2/24`) or `dhcp`. Default: the
    /// persisted address.
    #[arg(long, value_name = "ADDR/PREFIX|dhcp")]
    pub ip: Option<String>,

    /// Give the simulator the board's wired e-stop input, closed at start: SIGUSR1 opens
    /// it (every STEP output stops at once; the controller latches in STOPPED), SIGUSR2
    /// closes it (ESTOP_RESET then clears the latch). Without it STATUS shows no input.
    #[arg(long)]
    pub estop_input: bool,

    /// Give the simulator the safety-door input (issue 32; the NUCLEO's PF4), closed at
    /// start: SIGRTMIN+1 opens it (a run holds along its path; RUNING and RESUME refused
    /// DOOR_OPEN), SIGRTMIN+2 closes it (RESUME goes on). Without it the door reads closed.
    #[arg(long)]
    pub door_input: bool,

    /// What a stop (STOPPED, the wired e-stop input) does to a servo PWM on the gripper
    /// timer: `hold` keeps its duty (the board's default: a limp servo gripper drops its
    /// part), `cut` stops it as PWM_STOP does. A counted burst is cut either way (issue 30;
    /// docs/PROTOCOL.md, PWM_START).
    #[arg(long, value_enum, default_value_t = ServoOnStopOption::Hold)]
    pub servo_on_stop: ServoOnStopOption,

    /// Give the step thread real-time priority (SCHED_FIFO; needs privileges).
    #[arg(long)]
    pub realtime: bool,

    /// No effect, kept so that old command lines still work: the step thread no longer
    /// has per-edge deadlines to spin for (it plays DMA buffers in simulated time).
    #[arg(long, default_value_t = 20, value_parser = clap::value_parser!(u64).range(0..=10_000))]
    pub spin_us: u64,
}

/// `--servo-on-stop`: arm-core's [`ServoOnStop`] on the command line.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum ServoOnStopOption {
    /// The servo PWM keeps its duty through a stop.
    #[default]
    Hold,
    /// A stop cuts the servo PWM too.
    Cut,
}

impl From<ServoOnStopOption> for ServoOnStop {
    fn from(option: ServoOnStopOption) -> ServoOnStop {
        match option {
            ServoOnStopOption::Hold => ServoOnStop::Hold,
            ServoOnStopOption::Cut => ServoOnStop::Cut,
        }
    }
}

impl SimOptions {
    /// The fault configuration.
    pub fn faults(&self) -> FaultConfig {
        FaultConfig {
            loss: self.loss,
            dup: self.dup,
            reorder: self.reorder,
            seed: self.seed,
        }
    }

    /// Default options, as with no argument.
    pub fn defaults() -> SimOptions {
        Cli::parse_from(["sim-host"]).sim
    }

    /// The settings file to use.
    pub fn settings_path(&self) -> PathBuf {
        if let Some(path) = &self.settings {
            return path.clone();
        }
        let state = std::env::var_os("XDG_STATE_HOME")
            .map(PathBuf::from)
            .or_else(|| std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".local/state")))
            .unwrap_or_else(std::env::temp_dir);
        state
            .join("sim-host")
            .join(format!("settings-{}.txt", self.bind.port()))
    }

    /// The joints' physical model and switches (issue 33).
    pub fn switch_model(&self) -> crate::switches::SwitchModel {
        crate::switches::model_of(&self.positions, &self.home_switches, &self.limit_switches)
    }

    /// Encoder offsets per joint.
    pub fn encoder_offset_array(&self) -> [i64; arm_step::MAX_JOINTS] {
        let mut offsets = [0; arm_step::MAX_JOINTS];
        for &(j, steps) in &self.encoder_offsets {
            if let Some(o) = offsets.get_mut(j) {
                *o = steps;
            }
        }
        offsets
    }
}

impl SimOptions {
    /// Encoder misbehaviour per joint.
    pub fn encoder_fault_array(&self) -> [EncoderFaultMode; arm_step::MAX_JOINTS] {
        let mut faults = [EncoderFaultMode::None; arm_step::MAX_JOINTS];
        for &(j, mode) in &self.encoder_faults {
            if let Some(f) = faults.get_mut(j) {
                *f = mode;
            }
        }
        faults
    }
}

/// Splits `J:VALUE` (`what` names VALUE in the message) into a joint number in
/// 0..MAX_JOINTS and the value's text.
fn parse_joint_value<'a>(s: &'a str, what: &str) -> Result<(usize, &'a str), String> {
    let (joint, value) = s
        .split_once(':')
        .ok_or_else(|| format!("expected J:{what}, got {s}"))?;
    let joint: usize = joint.parse().map_err(|_| format!("bad joint: {joint}"))?;
    if joint >= arm_step::MAX_JOINTS {
        return Err(format!(
            "joint {joint} is not 0..{}",
            arm_step::MAX_JOINTS - 1
        ));
    }
    Ok((joint, value))
}

fn parse_encoder_fault(s: &str) -> Result<(usize, EncoderFaultMode), String> {
    let (joint, kind) = parse_joint_value(s, "KIND")?;
    let mode = <EncoderFaultMode as clap::ValueEnum>::from_str(kind, true)
        .map_err(|_| format!("bad encoder fault {kind}: silent, crc or exception"))?;
    Ok((joint, mode))
}

fn parse_home_switch(s: &str) -> Result<(usize, i64, arm_core::switches::Side), String> {
    let (joint, rest) = parse_joint_value(s, "STEPS[:min|max]")?;
    let (steps, side) = match rest.split_once(':') {
        Some((steps, side)) => (steps, side),
        None => (rest, "min"),
    };
    let steps: i64 = steps.parse().map_err(|_| format!("bad steps: {steps}"))?;
    let side = match side {
        "min" => arm_core::switches::Side::Min,
        "max" => arm_core::switches::Side::Max,
        other => return Err(format!("bad side {other}: min or max")),
    };
    Ok((joint, steps, side))
}

fn parse_limit_switch(s: &str) -> Result<(usize, i64, i64), String> {
    let (joint, rest) = parse_joint_value(s, "MIN:MAX")?;
    let (min, max) = rest
        .split_once(':')
        .ok_or_else(|| format!("expected J:MIN:MAX, got {s}"))?;
    let min: i64 = min.parse().map_err(|_| format!("bad min: {min}"))?;
    let max: i64 = max.parse().map_err(|_| format!("bad max: {max}"))?;
    if min >= max {
        return Err(format!("min {min} is not below max {max}"));
    }
    Ok((joint, min, max))
}

fn parse_probability(s: &str) -> Result<f64, String> {
    let p: f64 = s.parse().map_err(|_| format!("not a number: {s}"))?;
    if (0.0..=1.0).contains(&p) {
        Ok(p)
    } else {
        Err(format!("{p} is not a probability in 0..1"))
    }
}

fn parse_time_scale(s: &str) -> Result<f64, String> {
    let scale: f64 = s.parse().map_err(|_| format!("not a number: {s}"))?;
    if (0.01..=1000.0).contains(&scale) {
        Ok(scale)
    } else {
        Err(format!("time scale {scale} is outside 0.01..1000"))
    }
}

fn parse_encoder_offset(s: &str) -> Result<(usize, i64), String> {
    let (joint, steps) = parse_joint_value(s, "STEPS")?;
    let steps: i64 = steps.parse().map_err(|_| format!("bad steps: {steps}"))?;
    if i32::try_from(steps).is_err() {
        return Err(format!("{steps} steps do not fit a position"));
    }
    Ok((joint, steps))
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::CommandFactory;

    #[test]
    fn cli_is_consistent() {
        Cli::command().debug_assert();
    }

    #[test]
    fn options_parse() {
        let cli = Cli::parse_from([
            "sim-host",
            "--bind",
            "127.0.0.1:0",
            "--encoder-offset",
            "2:-300",
            "--encoder-offset",
            "0:5",
            "--loss",
            "0.1",
            "--time-scale",
            "10",
        ]);
        assert_eq!(cli.sim.encoder_offset_array()[2], -300);
        assert_eq!(cli.sim.encoder_offset_array()[0], 5);
        assert_eq!(cli.sim.faults().loss, 0.1);
        assert_eq!(cli.sim.time_scale, 10.0);
        assert!(Cli::try_parse_from(["sim-host", "--loss", "2"]).is_err());
        let cli = Cli::parse_from([
            "sim-host",
            "--position",
            "1:-40",
            "--home-switch",
            "1:-100",
            "--home-switch",
            "2:30:max",
            "--limit-switch",
            "1:-500:400",
        ]);
        assert_eq!(cli.sim.positions, [(1, -40)]);
        assert_eq!(
            cli.sim.home_switches,
            [
                (1, -100, arm_core::switches::Side::Min),
                (2, 30, arm_core::switches::Side::Max)
            ]
        );
        assert_eq!(cli.sim.limit_switches, [(1, -500, 400)]);
        assert!(Cli::try_parse_from(["sim-host", "--limit-switch", "1:5:5"]).is_err());
        assert!(Cli::try_parse_from(["sim-host", "--home-switch", "1:5:up"]).is_err());
        assert!(Cli::try_parse_from(["sim-host", "--encoder-offset", "8:1"]).is_err());
        assert!(Cli::try_parse_from(["sim-host", "--joints", "9"]).is_err());
    }
}
