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
