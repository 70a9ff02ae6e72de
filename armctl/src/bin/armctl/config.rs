//! `armctl config get` and `armctl config set`: the limits on the controller (LIMITS_GET,
//! LIMITS_SET; docs/PROTOCOL.md, issue 23) and each joint's acceleration (ACCEL_SET,
//! issue 31), and what an INVALID_POINT broke; `armctl config init`: an arm description
//! (the joint config file armctl, Python and the bridge all read) from the drive's
//! figures.

use armctl::Client;
use clap::Subcommand;
use protocol::{JointLimits, LimitsReport, RefusalReason, Tag};

use crate::CliResult;

/// `armctl config ...`.
#[derive(Subcommand, Debug)]
pub enum ConfigCmd {
    /// LIMITS_GET: every joint's position range and step rate on the controller, and the
    /// last point it refused for one.
    Get {
        /// As JSON.
        #[arg(long)]
        json: bool,
        /// A joint config (the `run --config` file): joint names.
        #[arg(long, value_name = "FILE")]
        config: Option<std::path::PathBuf>,
    },
    /// Writes an arm description (a joint config: `run --config`, `config push`, the
    /// ROS 2 bridge) from the drive's figures, every joint alike (edit the file for joints
    /// that differ). Needs no controller.
    Init(InitArgs),
    /// LIMITS_SET for every joint of a joint config (the `run --config` file): its
    /// min_steps, max_steps and max_step_rate_hz, and ACCEL_SET for its
    /// max_accel_steps_s2 (none when absent), so that the controller enforces them
    /// whatever host drives it (only while STOPPED).
    Push {
        /// The joint config.
        file: std::path::PathBuf,
    },
    /// LIMITS_SET: one joint's position range and step rate, kept by the controller
    /// across power cycles and enforced on every point, RETURN and set-location (only
    /// while STOPPED). Options not given keep their value.
    Set {
        /// The joint, 0-7.
        #[arg(long, value_parser = clap::value_parser!(u8).range(0..=7))]
        joint: u8,
        /// Lowest position, steps.
        #[arg(long, allow_negative_numbers = true)]
        min: Option<i32>,
        /// Highest position, steps.
        #[arg(long, allow_negative_numbers = true)]
        max: Option<i32>,
        /// Most steps per second of this joint (0: the controller's own limit only).
        #[arg(long, value_name = "HZ")]
        max_rate: Option<u32>,
        /// Remove the joint's limits (the whole range, no rate of its own).
        #[arg(long, conflicts_with_all = ["min", "max", "max_rate"])]
        clear: bool,
    },
}

/// `armctl config init`'s figures.
#[derive(clap::Args, Debug)]
pub struct InitArgs {
    /// Joints, 1-8.
    #[arg(long, default_value_t = 6, value_parser = clap::value_parser!(u8).range(1..=8))]
    pub joints: u8,
    /// Motor full steps (pulses) per revolution.
    #[arg(long, default_value_t = 200.0)]
    pub pulses_per_rev: f64,
    /// Driver microsteps per full step.
    #[arg(long, default_value_t = 16.0)]
    pub microsteps: f64,
    /// Motor revolutions per joint revolution.
    #[arg(long, default_value_t = 1.0)]
    pub gear_ratio: f64,
    /// Lowest joint position, degrees.
    #[arg(long, default_value_t = -180.0, allow_negative_numbers = true)]
    pub min_deg: f64,
    /// Highest joint position, degrees.
    #[arg(long, default_value_t = 180.0, allow_negative_numbers = true)]
    pub max_deg: f64,
    /// Most joint speed, degrees per second.
    #[arg(long, default_value_t = 90.0)]
    pub max_rate_deg_s: f64,
    /// Most joint acceleration, degrees per second².
    #[arg(long, default_value_t = 360.0)]
    pub max_accel_deg_s2: f64,
    /// Joint names, comma-separated (default j0, j1, ...).
    #[arg(long, value_delimiter = ',')]
    pub names: Vec<String>,
    /// The units the tools show positions in: steps, deg or rad.
    #[arg(long, default_value = "deg")]
    pub units: String,
    /// Where to write it (default: standard output).
    #[arg(long, short, value_name = "FILE")]
    pub output: Option<std::path::PathBuf>,
}

/// `armctl config init`: the description as JSON, in the joint config's format.
pub fn init(args: &InitArgs) -> CliResult {
    let text = description(args)?;
    // Read back as every tool will read it: what is written loads.
    armctl::trajectory::ArmConfig::parse(&text, "config init").map_err(|e| e.to_string())?;
    match &args.output {
        Some(path) => {
            std::fs::write(path, &text).map_err(|e| format!("{}: {e}", path.display()))?;
            eprintln!("wrote {}", path.display());
        }
        None => print!("{text}"),
    }
    Ok(())
}

/// The joint config text for `args`.
pub fn description(args: &InitArgs) -> Result<String, String> {
    let steps_per_rev = args.pulses_per_rev * args.microsteps * args.gear_ratio;
    if !(steps_per_rev.is_finite() && steps_per_rev != 0.0) {
        return Err(
            "pulses per revolution, microsteps and gear ratio must give a non-zero number of steps"
                .into(),
        );
    }
    if !["steps", "deg", "rad"].contains(&args.units.as_str()) {
        return Err(format!("--units {}: steps, deg or rad", args.units));
    }
    if args.min_deg > args.max_deg {
        return Err(format!(
            "--min-deg {} is above --max-deg {}",
            args.min_deg, args.max_deg
        ));
    }
    let steps_per_radian = steps_per_rev / std::f64::consts::TAU;
    let steps_per_deg = (steps_per_rev / 360.0).abs();
    let steps = |deg: f64| (deg * steps_per_rev / 360.0).round();
    let (min, max) = if steps_per_rev > 0.0 {
        (steps(args.min_deg), steps(args.max_deg))
    } else {
        (steps(args.max_deg), steps(args.min_deg))
    };
    if !(min >= f64::from(i32::MIN) && max <= f64::from(i32::MAX)) {
        return Err(format!("the range is {min}..{max} steps: beyond i32"));
    }
    let rate = (args.max_rate_deg_s * steps_per_deg).round();
    let accel = (args.max_accel_deg_s2 * steps_per_deg).round();
    if !(rate >= 1.0 && rate <= f64::from(u32::MAX) && accel >= 1.0 && accel <= f64::from(u32::MAX))
    {
        return Err(format!(
            "--max-rate-deg-s and --max-accel-deg-s2 give {rate} steps/s and {accel} steps/s²: at least 1, and within u32"
        ));
    }
    let joints: Vec<serde_json::Value> = (0..usize::from(args.joints))
        .map(|j| {
            let name = args
                .names
                .get(j)
                .cloned()
                .unwrap_or_else(|| format!("j{j}"));
            serde_json::json!({
                "name": name,
                "steps_per_radian": steps_per_radian,
                "zero_offset_steps": 0,
                "min_steps": min as i64,
                "max_steps": max as i64,
                "max_step_rate_hz": rate as u64,
                "max_accel_steps_s2": accel as u64,
            })
        })
        .collect();
    let value = serde_json::json!({ "units": args.units, "joints": joints });
    let mut text = serde_json::to_string_pretty(&value).map_err(|e| e.to_string())?;
    text.push('\n');
    Ok(text)
}

/// Runs `config get`, `push` or `set` (`init` needs no controller: [`init`]).
pub fn execute(arm: &Client, command: &ConfigCmd) -> CliResult {
    match command {
        ConfigCmd::Init(args) => init(args),
        ConfigCmd::Get { json, config } => {
            let names = config
                .as_deref()
                .map(armctl::trajectory::ArmConfig::load)
                .transpose()
                .map_err(|e| e.to_string())?
                .map(|c| {
                    c.joints
                        .iter()
                        .map(|j| j.name.clone().unwrap_or_else(|| "-".into()))
                        .collect::<Vec<_>>()
                });
            // With each joint's acceleration (issue 31; `max_accel` null from an older
            // controller): the JSON gains one field, the rest is as before.
            let report = arm
                .limits_with_accel()
                .map_err(|e| explain_old(e, Tag::LimitsGet))?;
            if *json {
                println!(
                    "{}",
                    serde_json::to_string_pretty(&report).map_err(|e| e.to_string())?
                );
            } else {
                print!("{}", limits_table(&report, names.as_deref()));
            }
            Ok(())
        }
        ConfigCmd::Push { file } => {
            let config = armctl::trajectory::ArmConfig::load(file).map_err(|e| e.to_string())?;
            for (j, joint) in config.joints.iter().enumerate().take(protocol::MAX_JOINTS) {
                let limits = JointLimits {
                    min: joint.min_steps,
                    max: joint.max_steps,
                    max_rate_hz: joint.max_step_rate_hz,
                };
                let j = u8::try_from(j).unwrap_or(u8::MAX);
                arm.set_limits(j, limits)
                    .map_err(|e| format!("joint {j}: {}", explain_old(e, Tag::LimitsSet)))?;
                let name = joint.name.as_deref().unwrap_or("-");
                println!("joint {j} {name}: {}", describe(&limits));
                // The acceleration (issue 31): the file's, or none.
                let accel = joint
                    .max_accel_steps_s2
                    .map_or(0, |a| a.round().clamp(1.0, f64::from(u32::MAX)) as u32);
                match arm.set_accel(j, accel) {
                    Ok(_) if accel > 0 => {
                        println!("joint {j} {name}: at most {accel} steps/s²")
                    }
                    Ok(_) => {}
                    // An older controller keeps no acceleration: say so when the file has one.
                    Err(e) if e.status() == Some(protocol::StatusCode::UnknownTag) => {
                        if accel > 0 {
                            eprintln!(
                                "warning: joint {j}: the controller keeps no acceleration (older than issue 31): max_accel_steps_s2 not enforced there"
                            );
                        }
                    }
                    Err(e) => return Err(format!("joint {j}: ACCEL_SET: {e}")),
                }
            }
            println!(
                "OK: {} joints' limits kept on the controller",
                config.joints.len()
            );
            Ok(())
        }
        ConfigCmd::Set {
            joint,
            min,
            max,
            max_rate,
            clear,
        } => {
            let current = arm.limits().map_err(|e| explain_old(e, Tag::LimitsGet))?;
            let old = current.joints[usize::from(*joint)];
            let new = if *clear {
                JointLimits::NONE
            } else {
                JointLimits {
                    min: min.unwrap_or(old.min),
                    max: max.unwrap_or(old.max),
                    max_rate_hz: max_rate.unwrap_or(old.max_rate_hz),
                }
            };
            if !new.is_valid() {
                return Err(format!(
                    "joint {joint}: min {} is above max {}",
                    new.min, new.max
                ));
            }
            let ack = arm
                .set_limits(*joint, new)
                .map_err(|e| explain_old(e, Tag::LimitsSet))?;
            println!(
                "OK (state {}): joint {joint} {}",
                ack.state.name(),
                describe(&new)
            );
            Ok(())
        }
    }
}

/// An older controller's UNKNOWN_TAG, explained.
fn explain_old(e: armctl::Error, tag: Tag) -> String {
    match e.status() {
        Some(protocol::StatusCode::UnknownTag) => format!(
            "{e}\nthis controller predates {} ({:#04x}): it keeps no limits (the host's \
             --config limits still apply to `armctl run`)",
            tag.name(),
            tag as u8
        ),
        _ => e.to_string(),
    }
}

/// A joint's limits in words.
pub fn describe(l: &JointLimits) -> String {
    let range = match (l.min, l.max) {
        (i32::MIN, i32::MAX) => "any position".to_string(),
        (i32::MIN, max) => format!("up to {max} steps"),
        (min, i32::MAX) => format!("from {min} steps"),
        (min, max) => format!("{min}..{max} steps"),
    };
    let rate = match l.max_rate_hz {
        0 => "the controller's max step rate".to_string(),
        hz => format!("at most {hz} steps/s"),
    };
    format!("{range}, {rate}")
}

/// One line per joint, then the last refusal. `names`: the joints' names from a config.
pub fn limits_table(report: &LimitsReport, names: Option<&[String]>) -> String {
    let mut out = String::from("joint  limits\n");
    for (j, l) in report.joints.iter().enumerate() {
        let name = names
            .and_then(|n| n.get(j))
            .map_or(String::new(), |n| format!(" {n}"));
        let accel = match report.max_accel.map(|a| a.get(j).copied().unwrap_or(0)) {
            Some(0) => ", no acceleration limit".to_string(),
            Some(a) => format!(", at most {a} steps/s²"),
            None => String::new(),
        };
        out.push_str(&format!("{j:>5}{name}  {}{accel}\n", describe(l)));
    }
    if let Some(line) = refusal_line(report) {
        out.push_str(&format!("{line}\n"));
    }
    out
}

/// The last refusal in words, if there was one.
pub fn refusal_line(report: &LimitsReport) -> Option<String> {
    let r = report.last_refusal;
    if r.reason == RefusalReason::None {
        return None;
    }
    let what = match Tag::from_u8(r.tag) {
        Some(Tag::Pending) => format!("PENDING seq {:#04x}, point {}", r.seq, r.point),
        Some(tag) => format!("{} seq {:#04x}", tag.name(), r.seq),
        None => format!("tag {:#04x} seq {:#04x}", r.tag, r.seq),
    };
    let joint = if r.joint == u8::MAX {
        "all joints".to_string()
    } else {
        format!("joint {}", r.joint)
    };
    Some(format!(
        "last refused: {what}: {joint}: {} ({} against {})",
        r.reason.describe(),
        r.value,
        r.limit
    ))
}

/// `message` with what the controller says it refused, when it is an INVALID_POINT and
/// the controller keeps limits (an older one answers LIMITS_GET with UNKNOWN_TAG: the
/// message stays as it is).
pub fn explain_invalid_point(message: String, arm: &Client) -> String {
    if !message.contains("INVALID_POINT") {
        return message;
    }
    match arm.limits().ok().as_ref().and_then(refusal_line) {
        Some(line) => format!("{message}\nthe controller says: {line}"),
        None => message,
    }
}
