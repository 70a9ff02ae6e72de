//! `armctl config get` and `armctl config set`: the limits on the controller (LIMITS_GET,
//! LIMITS_SET; docs/PROTOCOL.md, issue 23) and each joint's acceleration (ACCEL_SET,
//! issue 31), and what an INVALID_POINT broke; `armctl config init`: an arm description
//! (the joint config file armctl, Python and the bridge all read) from the drive's
//! figures.

use armctl::Client;
use armctl::motion::Units;
use armctl::push::{Pushed, PushedArm, describe_limits, scale_unit};
use armctl::trajectory::ArmConfig;
use clap::Subcommand;
use protocol::{JointLimits, LimitsReport, MAX_JOINTS, Point, Refusal, RefusalReason, Tag};

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
    /// whatever host drives it (only while STOPPED). FILE may also be what `config get
    /// --json` printed: the limits and accelerations it shows are put back.
    Push {
        /// The joint config, or a `config get --json` output.
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
            // Each joint's description (issue 31; none from an older controller).
            let descs = kept_descs(arm)?;
            // Named as the controller names them, when it names any.
            let names = names.or_else(|| {
                descs
                    .as_ref()
                    .filter(|d| d.iter().any(|d| !d.name().is_empty()))
                    .map(|d| {
                        d.iter()
                            .map(|d| match d.name() {
                                "" => "-".to_string(),
                                n => n.to_string(),
                            })
                            .collect()
                    })
            });
            if *json {
                let mut value = serde_json::to_value(report).map_err(|e| e.to_string())?;
                if let Some(object) = value.as_object_mut() {
                    object.insert("joint_desc".into(), desc_json(descs.as_deref()));
                }
                println!(
                    "{}",
                    serde_json::to_string_pretty(&value).map_err(|e| e.to_string())?
                );
            } else {
                print!("{}", limits_table(&report, names.as_deref()));
                if let Some(descs) = &descs {
                    print!("{}", desc_table(descs));
                }
            }
            Ok(())
        }
        ConfigCmd::Push { file } => {
            // One reading and one sending for every tool (armctl::push; Python's
            // Arm.push_config).
            let pushed = PushedArm::load(file)?;
            arm.push_arm(&pushed, |said| match said {
                Pushed::Kept(line) => println!("{line}"),
                Pushed::Warning(line) => eprintln!("warning: {line}"),
            })
            .map_err(|e| match e.command {
                Tag::LimitsSet => format!(
                    "joint {}: {}",
                    e.joint,
                    explain_old(e.error, Tag::LimitsSet)
                ),
                _ => e.to_string(),
            })?;
            println!(
                "OK: {} joints' limits kept on the controller",
                pushed.joints.len()
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
                describe_limits(&new)
            );
            Ok(())
        }
    }
}

/// Each joint's description the controller keeps (issue 31), joint 0 first; `None` from a
/// controller older than issue 31.
fn kept_descs(arm: &Client) -> Result<Option<Vec<protocol::JointDesc>>, String> {
    let mut descs = Vec::with_capacity(protocol::MAX_JOINTS);
    for j in 0..protocol::MAX_JOINTS as u8 {
        match arm.joint_desc(j) {
            Ok(d) => descs.push(d),
            Err(e) if e.status() == Some(protocol::StatusCode::UnknownTag) => return Ok(None),
            Err(e) => return Err(format!("joint {j}: JOINT_DESC_GET: {e}")),
        }
    }
    Ok(Some(descs))
}

/// `config get --json`'s `joint_desc`: one object per joint (null from an older
/// controller), as `config push` reads it back.
fn desc_json(descs: Option<&[protocol::JointDesc]>) -> serde_json::Value {
    match descs {
        None => serde_json::Value::Null,
        Some(descs) => descs
            .iter()
            .map(|d| {
                serde_json::json!({
                    "name": d.name(),
                    "unit": d.unit.name(),
                    "zero_offset_steps": d.zero_offset_steps,
                    "scale": d.scale(),
                })
            })
            .collect(),
    }
}

/// The descriptions as `config get` shows them, described joints only.
fn desc_table(descs: &[protocol::JointDesc]) -> String {
    let mut out = String::new();
    for (j, d) in descs.iter().enumerate().filter(|(_, d)| d.is_described()) {
        out.push_str(&format!(
            "joint {j} {}: {}, {} steps per {}, zero at {} steps\n",
            match d.name() {
                "" => "-",
                n => n,
            },
            d.unit,
            d.scale(),
            scale_unit(d.unit),
            d.zero_offset_steps
        ));
    }
    if out.is_empty() {
        out.push_str("no joint described (armctl config push FILE stores names and units)\n");
    }
    out
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
        out.push_str(&format!("{j:>5}{name}  {}{accel}\n", describe_limits(l)));
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

/// An upload as sent, to tell which of its points the controller refused.
pub struct Sent<'a> {
    /// Where the arm was when it began, steps.
    pub from: [i32; MAX_JOINTS],
    /// The points, in order.
    pub points: &'a [Point],
    /// The joints' names and calibration (without a config: unnamed, in steps).
    pub config: &'a ArmConfig,
    /// The units the user gave positions in.
    pub units: Units,
}

/// `message` with what the controller says it refused, when it is an INVALID_POINT and
/// the controller keeps limits (an older one answers LIMITS_GET with UNKNOWN_TAG: the
/// message stays as it is). With the upload `sent`, the refused point is found in it:
/// its time, the joint's config name, the values in the user's units and, for a rate,
/// how much slower it must go (issue 31).
pub fn explain_invalid_point(message: String, arm: &Client, sent: Option<&Sent<'_>>) -> String {
    const SAYS: &str = "the controller says: ";
    if !message.contains("INVALID_POINT") || message.contains(SAYS) {
        return message;
    }
    let Some(report) = arm.limits().ok() else {
        return message;
    };
    let line = sent
        .and_then(|sent| refused_point(&report.last_refusal, sent))
        .or_else(|| refusal_line(&report));
    match line {
        Some(line) => format!("{message}\n{SAYS}{line}"),
        None => message,
    }
}

/// The refused point of an upload `sent`, in words, when the refusal is of a PENDING and
/// a point of `sent` breaks its limit: the first such point (every point before it was
/// taken, under the same limits).
pub fn refused_point(r: &Refusal, sent: &Sent<'_>) -> Option<String> {
    if Tag::from_u8(r.tag) != Some(Tag::Pending) {
        return None;
    }
    let joint = usize::from(r.joint);
    let steps = |i: usize, j: usize| {
        let before = if i == 0 {
            sent.from[j]
        } else {
            sent.points[i - 1].position[j]
        };
        (i64::from(sent.points[i].position[j]) - i64::from(before)).unsigned_abs()
    };
    // steps / duration > limit, in integers.
    let over = |steps: u64, i: usize| {
        u128::from(steps) * 1_000_000
            > u128::from(r.limit.max(0).unsigned_abs())
                * u128::from(sent.points[i].duration.max(0).unsigned_abs())
    };
    let found = (0..sent.points.len()).find(|&i| match r.reason {
        RefusalReason::BelowMin | RefusalReason::AboveMax | RefusalReason::JointDisabled => {
            joint < MAX_JOINTS && sent.points[i].position[joint] == r.value
        }
        RefusalReason::JointRate | RefusalReason::BoardRate => {
            joint < MAX_JOINTS && over(steps(i, joint), i)
        }
        RefusalReason::StepBudget => over((0..MAX_JOINTS).map(|j| steps(i, j)).sum(), i),
        // The controller's acceleration is between segments' midpoints (PROTOCOL.md,
        // ACCEL_SET): the LIMITS report's own words are given for it.
        RefusalReason::Acceleration | RefusalReason::Duration | RefusalReason::None => false,
    })?;
    // The point's end: the time the arm is at its positions.
    let t: i64 = sent.points[..=found]
        .iter()
        .map(|p| i64::from(p.duration))
        .sum();
    let at = format!(
        "point {found} of the upload, ending at t = {:.6} s (PENDING seq {:#04x}, point {} of \
         the frame)",
        t as f64 / 1e6,
        r.seq,
        r.point
    );
    let calibration = sent.config.joints.get(joint);
    let name = match calibration.and_then(|c| c.name.as_deref()) {
        Some(name) => format!("joint {joint} ({name})"),
        None => format!("joint {joint}"),
    };
    let position = |steps: i32| match (sent.units, calibration) {
        (Units::Steps, _) | (_, None) => format!("{steps} steps"),
        (units, Some(c)) => format!("{steps} steps ({})", units.show(i64::from(steps), c)),
    };
    let rate = |hz: i32| match (sent.units, calibration) {
        (Units::Steps, _) | (_, None) => format!("{hz} steps/s"),
        (units, Some(c)) => format!(
            "{hz} steps/s ({:.2} {}/s)",
            units.distance_from_steps(f64::from(hz), c).abs(),
            units.name()
        ),
    };
    let slower = || armctl::trajectory::slow_down(f64::from(r.value), f64::from(r.limit));
    Some(match r.reason {
        RefusalReason::BelowMin => format!(
            "{at}: {name}: position {} is below its min {}",
            position(r.value),
            position(r.limit)
        ),
        RefusalReason::AboveMax => format!(
            "{at}: {name}: position {} is above its max {}",
            position(r.value),
            position(r.limit)
        ),
        RefusalReason::JointRate => format!(
            "{at}: {name}: {} is above its max rate {}: it needs {} longer",
            rate(r.value),
            rate(r.limit),
            slower()
        ),
        RefusalReason::BoardRate => format!(
            "{at}: {name}: {} is above the controller's max_step_rate_hz {}: it needs {} \
             longer",
            rate(r.value),
            rate(r.limit),
            slower()
        ),
        RefusalReason::JointDisabled => format!(
            "{at}: {name}: its driver is disabled (limp): moving it to {} would count steps \
             it does not make (`armctl enable {joint}` first)",
            position(r.value)
        ),
        _ => format!(
            "{at}: all joints together: {} steps/s is above the controller's step_budget_hz \
             {} steps/s: it needs {} longer",
            r.value,
            r.limit,
            slower()
        ),
    })
}
