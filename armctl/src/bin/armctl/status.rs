//! `armctl status`: the controller's STATUS, as text or JSON.

use armctl::Client;
use armctl::motion::Units;
use protocol::{MoreFlags, StatusFlags, StatusReport};

use crate::CliResult;

/// Runs `status`: STATUS with a LOCATION, look-only (issue 23: from any host, never
/// taking the controller).
pub fn execute(arm: &Client, json: bool, config: Option<&std::path::Path>) -> CliResult {
    let config = config
        .map(armctl::trajectory::ArmConfig::load)
        .transpose()
        .map_err(|e| e.to_string())?;
    let glance = arm.glance(true).map_err(|e| e.to_string())?;
    let status = glance.status;
    // Without --config, the names and units the controller keeps (issue 31: `armctl
    // config push`), as move and run show them; steps when it keeps none, or cannot say.
    // The file's positions are in degrees as before; the controller's in its units.
    let (config, units) = match config {
        Some(config) => (Some(config), Units::Deg),
        None => match arm.described_names(usize::from(status.joints)) {
            Ok(Some(described)) => {
                let units = described.units;
                (Some(described), units)
            }
            _ => (None, Units::Steps),
        },
    };
    // What ended the last run and who sent the STOPPED (issue 31); `None` from an older
    // controller, or if the report was lost.
    let stop = arm.stop_report().ok().and_then(|(_, stop)| stop);
    // The override, a hold, the door and the e-stop category (issue 32's MOTION report);
    // `None` from an older controller, or if the report was lost.
    let motion = arm.motion().ok().and_then(|(_, motion)| motion);
    if json {
        // The STATUS fields as before, plus `positions` (null when none came) and
        // `read_only`.
        let mut value = serde_json::to_value(status).map_err(|e| e.to_string())?;
        if let Some(map) = value.as_object_mut() {
            let joints = usize::from(status.joints).min(protocol::MAX_JOINTS);
            map.insert(
                "positions".into(),
                glance
                    .location
                    .map_or(serde_json::Value::Null, |l| l.position[..joints].into()),
            );
            map.insert("read_only".into(), glance.read_only.into());
            // Issue 31: the cause's name (null from an older controller) and the
            // STOPPED's sender ("127.0.0.2:40001", null when none or not told).
            map.insert(
                "stop_cause".into(),
                status
                    .stop_cause()
                    .map_or(serde_json::Value::Null, |c| c.name().into()),
            );
            map.insert(
                "stopped_by".into(),
                armctl::stopped_by(stop.as_ref())
                    .map_or(serde_json::Value::Null, |a| a.to_string().into()),
            );
            map.insert(
                "motion".into(),
                serde_json::to_value(motion).map_err(|e| e.to_string())?,
            );
            if let Some(config) = &config {
                let names: Vec<serde_json::Value> = config
                    .joints
                    .iter()
                    .take(joints)
                    .map(|j| j.name.clone().map_or(serde_json::Value::Null, Into::into))
                    .collect();
                map.insert("joint_names".into(), names.into());
            }
        }
        println!(
            "{}",
            serde_json::to_string_pretty(&value).map_err(|e| e.to_string())?
        );
    } else {
        print_status(&status);
        println!("{}", stop_line(&status, stop.as_ref()));
        if let Some(m) = &motion {
            println!("{}", motion_line(m));
            println!(
                "{}",
                crate::single::estop_category_line(Some(m.estop_category))
            );
        }
        // Issue 33: the switches, when the controller has any or has homed (an older
        // controller refuses the request bit: nothing printed).
        if let Ok(Some(switches)) = arm.switches() {
            let names = config.as_ref().map(|c| {
                c.joints
                    .iter()
                    .map(|j| j.name.clone())
                    .collect::<Vec<Option<String>>>()
            });
            if let Some(line) = switches_line(&switches, names.as_deref()) {
                println!("{line}");
            }
        }
        println!(
            "{}",
            positions_block(&status, glance.location.as_ref(), config.as_ref(), units)
        );
        if glance.read_only {
            println!("(read-only: another host owns the controller, or nobody does)");
        }
    }
    Ok(())
}

/// One line per joint in use: its position in steps and its driver; with a joint config,
/// its name and its position in `units` too (the steps column again for steps).
pub fn positions_block(
    s: &StatusReport,
    location: Option<&protocol::Location>,
    config: Option<&armctl::trajectory::ArmConfig>,
    units: Units,
) -> String {
    let Some(location) = location else {
        return "positions        unknown (no LOCATION came: an older controller?)".into();
    };
    let enabled = s.drivers_enabled();
    let joints = usize::from(s.joints).min(protocol::MAX_JOINTS);
    let mut lines = vec![match config {
        Some(_) => format!(
            "joint  name                  steps  {:>7}  driver",
            match units {
                Units::Deg => "degrees",
                Units::Rad => "radians",
                Units::Steps => "steps",
            }
        ),
        None => "joint  position (steps)  driver".to_string(),
    }];
    for (j, p) in location.position.iter().enumerate().take(joints) {
        let driver = match enabled {
            Some(mask) if mask & (1 << j) != 0 => "enabled",
            Some(_) => "disabled",
            None => "?",
        };
        let line = match config.map(|c| c.joints.get(j)) {
            Some(Some(joint)) => {
                let name = joint.name.as_deref().unwrap_or("-");
                let value = units.from_steps(i64::from(*p), joint);
                match units {
                    Units::Deg => format!("{j:>5}  {name:<16} {p:>10} {value:>8.1}  {driver}"),
                    Units::Rad => format!("{j:>5}  {name:<16} {p:>10} {value:>8.3}  {driver}"),
                    Units::Steps => format!("{j:>5}  {name:<16} {p:>10} {p:>8}  {driver}"),
                }
            }
            Some(None) => format!("{j:>5}  {:<16} {p:>10} {:>8}  {driver}", "-", "-"),
            None => format!("{j:>5}  {p:>16}  {driver}"),
        };
        lines.push(line);
    }
    lines.join("\n")
}

/// The limit switch latch and the homing cycle (issue 33, the SWITCHES report), `None`
/// when there is nothing to say (never homed, nothing pressed, not latched). `names`:
/// the joint config's names, to name the joint with.
pub fn switches_line(
    s: &protocol::SwitchesReport,
    names: Option<&[Option<String>]>,
) -> Option<String> {
    let name = |j: u8| {
        names
            .and_then(|n| n.get(usize::from(j)).cloned().flatten())
            .map_or(format!("joint {j}"), |n| format!("joint {j} ({n})"))
    };
    let mut parts = Vec::new();
    if let Some(l) = s.latched {
        let side = if l & 0x80 != 0 { "max" } else { "min" };
        parts.push(format!(
            "LATCHED on the {side} limit of {}: `armctl unlock`, then move away from it",
            name(l & 0x7f)
        ));
    }
    for (mask, what) in [(s.min_active, "min"), (s.max_active, "max")] {
        for j in (0..8u8).filter(|j| mask & (1 << j) != 0) {
            parts.push(format!("{what} limit of {} pressed", name(j)));
        }
    }
    match s.phase {
        protocol::HomingPhase::Never => {}
        protocol::HomingPhase::Homing => parts.push(format!("homing {}", name(s.joint))),
        protocol::HomingPhase::Homed => parts.push(format!("homed (joints {:#04x})", s.homed)),
        protocol::HomingPhase::Failed => parts.push(format!(
            "homing failed on {}: {}",
            name(s.joint),
            s.error.map_or("?", |e| e.text())
        )),
    }
    (!parts.is_empty()).then(|| format!("switches         {}", parts.join("; ")))
}

/// The speed override, a hold or ramp, the safety door, the last controlled stop and the
/// last OVERRIDE refused (issue 32's MOTION report), as one line.
pub fn motion_line(m: &protocol::MotionReport) -> String {
    use protocol::MotionFlags;
    let mut parts = vec![format!(
        "speed {} % (now {:.1} %)",
        m.factor_percent,
        f64::from(m.rate_permille) / 10.0
    )];
    let flag = |bit| m.flags.has(bit);
    if flag(MotionFlags::HELD) {
        parts.push(
            if flag(MotionFlags::AT_REST) {
                "HELD at rest: `armctl resume` goes on"
            } else {
                "HOLDING (decelerating)"
            }
            .to_owned(),
        );
    } else if flag(MotionFlags::ESTOP_RAMP) {
        parts.push("E-STOP category 1: decelerating, then the drivers off".to_owned());
    } else if flag(MotionFlags::UNDERRUN_RAMP) {
        parts.push("UNDERRUN: slowing, the host is late".to_owned());
    } else if flag(MotionFlags::RAMPING) {
        parts.push("ramping".to_owned());
    }
    if flag(MotionFlags::DOOR_OPEN) {
        parts.push("DOOR OPEN: runs hold, RUNING and RESUME refused".to_owned());
    }
    match m.last_stop {
        Some(protocol::ControlledStop::None) => {}
        Some(stop) => parts.push(format!("last controlled stop {}", stop.name())),
        None => parts.push("last controlled stop unknown (a newer controller)".to_owned()),
    }
    match (m.refused_limit, m.refused_joint) {
        (Some(protocol::OverrideLimit::StepBudget), _) => parts.push(
            "last OVERRIDE refused: the run's steps per second would pass the board's \
             budget for warped steps (STEP_BUDGET)"
                .to_owned(),
        ),
        (Some(limit), joint) => parts.push(format!(
            "last OVERRIDE refused: joint {joint} would pass its {} limit",
            limit.name()
        )),
        (None, 0xFF) => {}
        (None, joint) => parts.push(format!("last OVERRIDE refused: joint {joint} (limit ?)")),
    }
    format!("motion           {}", parts.join("; "))
}

/// What ended the last run (issue 31: STATUS `more_flags` bits 5-7 and the STOP_CAUSE
/// report; the older flags from an older controller).
pub fn stop_line(s: &StatusReport, stop: Option<&protocol::StopReport>) -> String {
    format!("last run ended   {}", armctl::stop_cause_text(s, stop))
}

/// The wired e-stop input and its latch (STATUS `more_flags` bits 1 and 2; both 0 from a
/// controller without the input).
pub fn estop_line(s: &StatusReport) -> String {
    let open = s.more_flags.has(MoreFlags::ESTOP_OPEN);
    let latched = s.more_flags.has(MoreFlags::ESTOP_LATCHED);
    let what = match (open, latched) {
        (false, false) => "closed, not latched",
        (false, true) => {
            "closed, LATCHED: RUNING and RETURN refused until `armctl estop-reset` clears it"
        }
        (true, _) => {
            "OPEN, LATCHED: RUNING and RETURN refused; close it, then `armctl estop-reset`"
        }
    };
    format!("e-stop input     {what}")
}

fn print_status(s: &StatusReport) {
    let flag = |bit| if s.flags.has(bit) { "yes" } else { "no" };
    println!(
        "version          {}.{}.{}",
        s.version[0], s.version[1], s.version[2]
    );
    println!("state            {}", s.state.name());
    println!("joints           {}", s.joints);
    println!(
        "buffer           {} of {} points ({} free)",
        s.buffered,
        s.capacity,
        s.capacity.saturating_sub(s.buffered)
    );
    println!(
        "trajectory       {} announced, {} received, {} executed",
        s.expected, s.received, s.executed
    );
    println!(
        "window           {} datagrams back to back{}",
        armctl::window_of(s),
        if s.window == 0 {
            " (not advertised: assumed)"
        } else {
            ""
        }
    );
    println!("report period    {} us", s.upload_period_us);
    println!("max step rate    {} steps/s", s.max_step_rate_hz);
    println!("pwm timer clock  {} Hz", s.pwm_timer_clock_hz);
    println!(
        "reports {}  drivers enabled {}  serial open {}  pin0 {}  pin1 {}  pwm {}",
        flag(StatusFlags::REPORTS_ON),
        flag(StatusFlags::DRIVERS_ENABLED),
        flag(StatusFlags::SERIAL_OPEN),
        flag(StatusFlags::PIN0_HIGH),
        flag(StatusFlags::PIN1_HIGH),
        flag(StatusFlags::PWM_ACTIVE)
    );
    // Kept as it was: scripts grep it (scripts/lookahead-soak.sh, step-load); the stop
    // cause line (issue 31) follows the block.
    println!(
        "last run ended by underrun {}  by STOPPED {}",
        flag(StatusFlags::UNDERRUN),
        flag(StatusFlags::STOPPED_BY_HOST)
    );
    println!("{}", crate::enable::drivers_line(s));
    println!("{}", estop_line(s));
    if s.more_flags.has(protocol::MoreFlags::UPLOAD_DROPPED) {
        println!("an unstarted upload was dropped when another host took the controller over");
    }
}
