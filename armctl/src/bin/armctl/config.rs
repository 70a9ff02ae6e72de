//! `armctl config get` and `armctl config set`: the limits on the controller (LIMITS_GET,
//! LIMITS_SET; docs/PROTOCOL.md, issue 23), and what an INVALID_POINT broke.

use armctl::Client;
use armctl::motion::Units;
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
    /// LIMITS_SET for every joint of a joint config (the `run --config` file): its
    /// min_steps, max_steps and max_step_rate_hz, so that the controller enforces them
    /// whatever host drives it (only while STOPPED). FILE may also be what `config get
    /// --json` printed: the limits it shows are put back.
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

/// Runs `config get` or `config set`.
pub fn execute(arm: &Client, command: &ConfigCmd) -> CliResult {
    match command {
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
            let report = arm.limits().map_err(|e| explain_old(e, Tag::LimitsGet))?;
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
            let joints = pushed_limits(file)?;
            for (j, (name, limits)) in joints.iter().enumerate().take(protocol::MAX_JOINTS) {
                let j = u8::try_from(j).unwrap_or(u8::MAX);
                arm.set_limits(j, *limits)
                    .map_err(|e| format!("joint {j}: {}", explain_old(e, Tag::LimitsSet)))?;
                println!("joint {j} {name}: {}", describe(limits));
            }
            println!("OK: {} joints' limits kept on the controller", joints.len());
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

/// What `config get --json` prints, as `config push` reads it back: the joints' limits
/// (the last refusal, also printed, is left alone).
#[derive(serde::Deserialize)]
struct KeptLimits {
    joints: Vec<JointLimits>,
}

/// The limits `config push FILE` sends, joint 0 first, each with the name it is shown
/// with: from a joint config (`min_steps`, `max_steps`, `max_step_rate_hz`), or from what
/// `config get --json` printed (`min`, `max`, `max_rate_hz`; issue 31: it was refused,
/// "missing field `max_step_rate_hz`").
fn pushed_limits(file: &std::path::Path) -> Result<Vec<(String, JointLimits)>, String> {
    let text = std::fs::read_to_string(file).map_err(|e| format!("{}: {e}", file.display()))?;
    let value: serde_json::Value = serde_json::from_str(&text)
        .map_err(|e| format!("{}: cannot parse: {e}", file.display()))?;
    let from_get = value
        .pointer("/joints/0")
        .is_some_and(|joint| joint.get("max_rate_hz").is_some());
    if !from_get {
        let config = armctl::trajectory::ArmConfig::parse(&text, &file.display().to_string())
            .map_err(|e| e.to_string())?;
        return Ok(config
            .joints
            .iter()
            .map(|joint| {
                (
                    joint.name.clone().unwrap_or_else(|| "-".into()),
                    JointLimits {
                        min: joint.min_steps,
                        max: joint.max_steps,
                        max_rate_hz: joint.max_step_rate_hz,
                    },
                )
            })
            .collect());
    }
    let kept: KeptLimits = serde_json::from_value(value)
        .map_err(|e| format!("{}: cannot parse: {e}", file.display()))?;
    if kept.joints.is_empty() || kept.joints.len() > protocol::MAX_JOINTS {
        return Err(format!(
            "{}: {} joints: 1 to {}",
            file.display(),
            kept.joints.len(),
            protocol::MAX_JOINTS
        ));
    }
    if let Some(j) = kept.joints.iter().position(|l| !l.is_valid()) {
        return Err(format!(
            "{}: joint {j}: min {} is above max {}",
            file.display(),
            kept.joints[j].min,
            kept.joints[j].max
        ));
    }
    Ok(kept.joints.into_iter().map(|l| ("-".into(), l)).collect())
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
        out.push_str(&format!("{j:>5}{name}  {}\n", describe(l)));
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
        RefusalReason::BelowMin | RefusalReason::AboveMax => {
            joint < MAX_JOINTS && sent.points[i].position[joint] == r.value
        }
        RefusalReason::JointRate | RefusalReason::BoardRate => {
            joint < MAX_JOINTS && over(steps(i, joint), i)
        }
        RefusalReason::StepBudget => over((0..MAX_JOINTS).map(|j| steps(i, j)).sum(), i),
        RefusalReason::Duration | RefusalReason::None => false,
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
        _ => format!(
            "{at}: all joints together: {} steps/s is above the controller's step_budget_hz \
             {} steps/s: it needs {} longer",
            r.value,
            r.limit,
            slower()
        ),
    })
}
