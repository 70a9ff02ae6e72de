//! The commands that are one frame and an `OK (state ...)` line: stop, return, joints,
//! set-location, enable, pin, upload-period, reports (and the `pwm` ones).

use std::time::Duration;

use armctl::Client;

use crate::CliResult;

/// Prints the ACK's state, or fails with the refusal's message.
pub fn done(ack: armctl::Result<protocol::Ack>) -> CliResult {
    let ack = ack.map_err(|e| e.to_string())?;
    println!("OK (state {})", ack.state.name());
    Ok(())
}

/// Runs `override`: OVERRIDE, and on OVERRIDE_REFUSED the joint and limit the MOTION
/// report names.
pub fn set_override(arm: &Client, percent: u8) -> CliResult {
    match arm.set_override(percent) {
        Err(armctl::Error::Refused {
            status: protocol::StatusCode::OverrideRefused,
            ..
        }) => {
            let why = match arm.motion() {
                Ok((_, Some(m)))
                    if m.refused_limit == Some(protocol::OverrideLimit::StepBudget) =>
                {
                    "the run's steps per second at that speed are more than the board can time \
                     under a speed change (its warp budget)"
                        .to_owned()
                }
                Ok((_, Some(m))) => format!(
                    "joint {} would go over its {} limit",
                    m.refused_joint,
                    match m.refused_limit {
                        Some(protocol::OverrideLimit::Accel) => "acceleration",
                        _ => "step rate",
                    }
                ),
                _ => "a joint would go over a limit".to_owned(),
            };
            Err(format!("OVERRIDE {percent} % refused: {why}"))
        }
        other => done(other),
    }
}

/// Runs `estop-category`: with a value, ESTOP_CATEGORY; without, the category MOTION
/// reports (a controller older than issue 32 has none: it stops at once, category 0).
pub fn estop_category(arm: &Client, category: Option<u8>) -> CliResult {
    if let Some(byte) = category {
        let category = protocol::EStopCategory::from_u8(byte)
            .ok_or_else(|| format!("e-stop category {byte}: give 0 or 1"))?;
        return done(arm.set_estop_category(category));
    }
    let (_, motion) = arm.motion().map_err(|e| e.to_string())?;
    println!("{}", estop_category_line(motion.map(|m| m.estop_category)));
    Ok(())
}

/// The line `estop-category` prints for MOTION's category (`None`: no MOTION report, an
/// older controller; `Some(None)`: a byte this armctl does not know).
pub fn estop_category_line(category: Option<Option<protocol::EStopCategory>>) -> String {
    match category {
        Some(Some(protocol::EStopCategory::Instant)) => {
            "e-stop category 0: the input stops every joint at once".to_owned()
        }
        Some(Some(protocol::EStopCategory::Controlled)) => "e-stop category 1: the input \
             decelerates the run along its path, then disables the drivers"
            .to_owned(),
        Some(None) => "e-stop category unknown (a newer controller)".to_owned(),
        None => "e-stop category 0: this controller predates ESTOP_CATEGORY (it stops at once)"
            .to_owned(),
    }
}

/// Runs `return`: RETURN, and with `wait` the wait for the move's end. SIGINT, SIGTERM or SIGHUP
/// from the RETURN on: STOPPED (crate::interrupt).
pub fn go_home(arm: &Client, wait: bool) -> CliResult {
    let cancel = crate::interrupt::watch()?;
    done(arm.go_home())?;
    if wait {
        let status = arm
            .wait_stopped_cancellable(Duration::from_secs(600), &cancel)
            .map_err(|e| e.to_string())?;
        println!("state {}", status.state.name());
    }
    Ok(())
}
