//! `armctl status`: the controller's STATUS, as text or JSON.

use armctl::Client;
use protocol::{MoreFlags, StatusFlags, StatusReport};

use crate::CliResult;

/// Runs `status`.
pub fn execute(arm: &Client, json: bool) -> CliResult {
    let status = arm.status().map_err(|e| e.to_string())?;
    if json {
        println!(
            "{}",
            serde_json::to_string_pretty(&status).map_err(|e| e.to_string())?
        );
    } else {
        print_status(&status);
    }
    Ok(())
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
