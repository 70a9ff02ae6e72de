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
