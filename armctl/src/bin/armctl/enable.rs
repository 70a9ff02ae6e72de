//! `armctl enable [JOINTS]` and `armctl disable [JOINTS]`: SET_ENABLE (docs/PROTOCOL.md,
//! issue 23), explicit per driver, then the drivers' state as STATUS reports it.

use armctl::Client;
use protocol::StatusCode;

use crate::CliResult;

/// The mask bit of the gripper's driver in the ENABLE masks.
pub const GRIPPER_BIT: u16 = 1 << 8;

/// Every driver: joints 0-7 and the gripper.
pub const ALL_DRIVERS: u16 = protocol::limits::ENABLE_MASK_BITS;

/// One driver of the command line as its mask bits: a joint number 0-7, `gripper` (or
/// `g`), or `all`.
pub fn parse_driver(text: &str) -> Result<u16, String> {
    let text = text.trim();
    match text.to_ascii_lowercase().as_str() {
        "all" => return Ok(ALL_DRIVERS),
        "gripper" | "g" => return Ok(GRIPPER_BIT),
        _ => {}
    }
    match text.parse::<u8>() {
        Ok(j) if usize::from(j) < protocol::MAX_JOINTS => Ok(1 << j),
        _ => Err(format!(
            "{text:?} is not a driver: give joint numbers 0-7, `gripper` or `all`"
        )),
    }
}

/// The mask of the drivers given (every driver when none is).
pub fn mask_of(drivers: &[u16]) -> u16 {
    if drivers.is_empty() {
        ALL_DRIVERS
    } else {
        drivers.iter().fold(0, |m, d| m | d)
    }
}

/// The drivers of `mask` in words: `joints 0, 1 and the gripper`.
pub fn describe(mask: u16) -> String {
    if mask == ALL_DRIVERS {
        return "every driver".to_string();
    }
    let joints: Vec<String> = (0..protocol::MAX_JOINTS)
        .filter(|j| mask & (1 << j) != 0)
        .map(|j| j.to_string())
        .collect();
    let mut text = match joints.len() {
        0 => String::new(),
        1 => format!("joint {}", joints[0]),
        _ => format!("joints {}", joints.join(", ")),
    };
    if mask & GRIPPER_BIT != 0 {
        if !text.is_empty() {
            text.push_str(" and ");
        }
        text.push_str("the gripper");
    }
    text
}

/// One line per driver state from STATUS: `enabled: 0 1 2 gripper  disabled: 3`, or what
/// an older controller tells (`flags` bit 1 only).
pub fn drivers_line(status: &protocol::StatusReport) -> String {
    let Some(enabled) = status.drivers_enabled() else {
        let any = status.flags.has(protocol::StatusFlags::DRIVERS_ENABLED);
        return format!(
            "drivers          {} enabled (this controller does not report each driver)",
            if any { "some" } else { "none" }
        );
    };
    let list = |on: bool| {
        let mut names: Vec<String> = (0..usize::from(status.joints).min(protocol::MAX_JOINTS))
            .filter(|j| (enabled & (1 << j) != 0) == on)
            .map(|j| j.to_string())
            .collect();
        if (enabled & GRIPPER_BIT != 0) == on {
            names.push("gripper".to_string());
        }
        if names.is_empty() {
            "-".to_string()
        } else {
            names.join(" ")
        }
    };
    format!(
        "drivers          enabled: {}  disabled: {}",
        list(true),
        list(false)
    )
}

/// Runs `enable` (`on`) or `disable` on `drivers`.
pub fn execute(arm: &Client, drivers: &[u16], on: bool) -> CliResult {
    let mask = mask_of(drivers);
    let ack = arm.set_enable(mask, on).map_err(|e| match e.status() {
        Some(StatusCode::UnknownTag) => format!(
            "{e}\nthis controller predates SET_ENABLE (0x18): `armctl toggle-enable --mask \
             {mask:#x}` flips those drivers instead (check `armctl status` first)"
        ),
        _ => e.to_string(),
    })?;
    println!(
        "OK (state {}): {} {}",
        ack.state.name(),
        describe(mask),
        if on { "enabled" } else { "disabled" }
    );
    if let Ok(status) = arm.status() {
        println!("{}", drivers_line(&status));
    }
    Ok(())
}
