//! `armctl watch`: live positions and state from LOCATION reports.

use std::io::{IsTerminal, Write};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use armctl::Client;
use armctl::motion::Units;
use armctl::record::{self, Recorder};
use armctl::trajectory::ArmConfig;
use protocol::Location;

use crate::CliResult;

/// How often a watch from a host that does not own the controller asks for a read-only
/// STATUS: 5 a second, half the controller's budget for such answers (10 a second after a
/// burst of 10, docs/PROTOCOL.md section 1), so that two such watchers fit.
const READ_ONLY_POLL: Duration = Duration::from_millis(200);

/// How `watch` shows positions: `j0 1234` in steps, or with a joint config its names and
/// units (`base 30.02 deg`).
pub struct Shown {
    pub config: ArmConfig,
    pub units: Units,
}

/// Without --config, the names and units the controller keeps (issue 31: `armctl config
/// push`; JOINT_DESC_GET, which any host may ask); `None` (steps) when it keeps none or
/// cannot say, as `status` shows them.
pub fn described(arm: &Client) -> Result<Option<Shown>, String> {
    let status = arm.status().map_err(|e| e.to_string())?;
    let described = arm
        .described_names(usize::from(status.joints))
        .ok()
        .flatten();
    Ok(described.map(|config| Shown {
        units: config.units,
        config,
    }))
}

/// The override and hold as `watch` shows them after the positions (issue 32): nothing at
/// 100 % with no hold (what older controllers show), else e.g. ` speed 50 %`, ` HELD`,
/// ` ramping`, ` UNDERRUN (slowing: ...)`, ` DOOR OPEN`.
pub fn motion_suffix(motion: Option<&protocol::MotionReport>) -> String {
    use protocol::MotionFlags;
    let Some(m) = motion else {
        return String::new();
    };
    let mut out = String::new();
    if m.factor_percent != 100 {
        out.push_str(&format!(" speed {} %", m.factor_percent));
    }
    if m.flags.has(MotionFlags::HELD) {
        out.push_str(if m.flags.has(MotionFlags::AT_REST) {
            " HELD"
        } else {
            " HOLDING"
        });
    } else if m.flags.has(MotionFlags::ESTOP_RAMP) {
        out.push_str(" E-STOP (category 1: decelerating)");
    } else if m.flags.has(MotionFlags::UNDERRUN_RAMP) {
        out.push_str(" UNDERRUN (slowing: the host is late)");
    } else if m.flags.has(MotionFlags::RAMPING) {
        out.push_str(" ramping");
    }
    if m.flags.has(MotionFlags::DOOR_OPEN) {
        out.push_str(" DOOR OPEN");
    }
    out
}

fn location_line(location: &Location, joints: usize, shown: Option<&Shown>) -> String {
    let mut line = format!("{:<8}", record::state_name(location.state));
    for (j, p) in location.position.iter().take(joints).enumerate() {
        match shown.and_then(|s| s.config.joints.get(j).map(|c| (s, c))) {
            Some((shown, joint)) => {
                let name = joint.name.clone().unwrap_or_else(|| format!("j{j}"));
                let value = shown.units.show(i64::from(*p), joint);
                line.push_str(&format!(" {name} {value:>13}"));
            }
            None => line.push_str(&format!(" j{j} {p:>9}")),
        }
    }
    line
}

/// Runs `watch`: live positions on screen, optionally recorded, until the end of
/// `duration` or Ctrl-C.
pub fn execute(
    arm: &Client,
    record: Option<&std::path::Path>,
    duration: Option<f64>,
    shown: Option<&Shown>,
) -> CliResult {
    let status = arm.status().map_err(|e| e.to_string())?;
    let joints = usize::from(status.joints).clamp(1, 8);
    let locations = arm.locations();
    // LOCATION reports go to the tool that asked last: this one, from now on. Another
    // host owns the controller: poll a read-only STATUS with a LOCATION instead (issue
    // 23), within the controller's budget for such answers.
    let read_only = match arm.claim_locations() {
        Ok(()) => false,
        Err(e) if e.status() == Some(protocol::StatusCode::NotOwner) => {
            eprintln!(
                "read-only: another host owns the controller; polling STATUS every {} ms",
                READ_ONLY_POLL.as_millis()
            );
            true
        }
        Err(e) => return Err(e.to_string()),
    };
    let mut recorder = record
        .map(|path| {
            let names = shown.map_or(Vec::new(), |s| s.config.short_names());
            Recorder::create_named(path, joints, &names)
                .map_err(|e| format!("{}: {e}", path.display()))
        })
        .transpose()?;
    let started = Instant::now();
    let end = duration.map(|s| started + Duration::from_secs_f64(s.max(0.0)));
    let tty = std::io::stdout().is_terminal();
    let mut out = std::io::stdout().lock();
    let mut last_print = Instant::now() - Duration::from_secs(1);
    let mut last_status = Instant::now();
    let mut seen = 0u64;
    let mut last_state = None;
    // The last MOTION report (override, hold), asked with the owner's STATUS each second.
    let mut motion = None;
    loop {
        if end.is_some_and(|e| Instant::now() >= e) {
            break;
        }
        let next = if read_only {
            std::thread::sleep(READ_ONLY_POLL);
            match arm.glance(true) {
                Ok(armctl::Glance {
                    location: Some(location),
                    ..
                }) => Ok(location),
                _ => Err(mpsc::RecvTimeoutError::Timeout),
            }
        } else {
            locations.recv_timeout(Duration::from_millis(200))
        };
        match next {
            Ok(location) => {
                seen += 1;
                // A run just ended: say what ended it (issue 31), on a line of its own.
                let ended = location.state == protocol::State::Stopped as u8
                    && last_state == Some(protocol::State::Running as u8);
                last_state = Some(location.state);
                if ended {
                    let why = match arm.stop_report() {
                        Ok((status, stop)) => armctl::stop_cause_text(&status, stop.as_ref()),
                        Err(e) => format!("unknown ({e})"),
                    };
                    let line = location_line(&location, joints, shown);
                    let written = if tty {
                        write!(out, "\r{line}\nrun ended: {why}\n")
                    } else {
                        writeln!(out, "{line}\nrun ended: {why}")
                    }
                    .and_then(|()| out.flush());
                    if crate::out::closed(&written) {
                        return Ok(());
                    }
                    written.map_err(|e| format!("stdout: {e}"))?;
                }
                if let Some(r) = recorder.as_mut() {
                    r.record(&location)
                        .and_then(|()| r.flush())
                        .map_err(|e| e.to_string())?;
                }
                // At most 10 lines a second on screen, every state change included.
                if last_print.elapsed() >= Duration::from_millis(100) {
                    last_print = Instant::now();
                    let line =
                        location_line(&location, joints, shown) + &motion_suffix(motion.as_ref());
                    let written = if tty {
                        write!(out, "\r{line}").and_then(|()| out.flush())
                    } else {
                        writeln!(out, "{line}")
                    };
                    // The reader went away (`armctl watch | head`): done, quietly.
                    if crate::out::closed(&written) {
                        return Ok(());
                    }
                }
            }
            Err(mpsc::RecvTimeoutError::Timeout) => {}
            Err(mpsc::RecvTimeoutError::Disconnected) => break,
        }
        // STATUS now and then keeps this host the owner (reports go to the owner).
        if !read_only && last_status.elapsed() >= Duration::from_secs(1) {
            last_status = Instant::now();
            motion = arm.motion().map_err(|e| e.to_string())?.1;
        }
    }
    let written = if tty { writeln!(out) } else { Ok(()) }
        .and_then(|()| writeln!(out, "{seen} location reports"));
    // A closed pipe or a failed write: main ends the tool as it should (crate::out).
    crate::out::closed(&written);
    Ok(())
}
