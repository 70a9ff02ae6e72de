//! Who owns the controller: `armctl release` (RELEASE, docs/PROTOCOL.md section 4), and
//! the owner's address added to a NOT_OWNER message (from DISCOVER_REPLY's `owner_ip`,
//! which any host may ask for: section 12).

use std::net::{SocketAddr, SocketAddrV4, ToSocketAddrs};
use std::time::Duration;

use armctl::Client;
use protocol::OwnerState;

use crate::CliResult;

/// How long to wait for the DISCOVER_REPLY that names the owner.
const OWNER_QUERY_WAIT: Duration = Duration::from_millis(300);

/// Runs `release`.
pub fn release(arm: &Client) -> CliResult {
    let ack = arm.release().map_err(|e| e.to_string())?;
    println!(
        "OK (state {}): released; any host may take the controller now (this one too, \
         with its next command)",
        ack.state.name()
    );
    Ok(())
}

/// `message` with who owns the controller at `controller` appended, when it is a
/// NOT_OWNER refusal and the controller tells (an older one without DISCOVER does not).
/// The refusal names `command`, the command the user ran, not the frame refused (issue
/// 31: `move` said "UPLOAD_PERIOD refused", the first frame it sends that needs the
/// owner).
pub fn explain_not_owner(
    message: String,
    command: &str,
    controller: &str,
    bind: Option<SocketAddr>,
) -> String {
    if !message.contains("NOT_OWNER") {
        return message;
    }
    let message = name_the_command(&message, command);
    match owner_of(controller, bind) {
        Some(ip) => format!(
            "{message}\nthe controller is owned by {ip}: it passes to another host when \
             that one has been silent 5 s (not while running), or at once when it runs \
             `armctl release`; `armctl status` and `armctl stop` work from any host"
        ),
        None => message,
    }
}

/// `LIMITS_GET refused with NOT_OWNER: ...` as `move refused with NOT_OWNER: ...`: the
/// frame's name before the refusal replaced by `command`.
pub fn name_the_command(message: &str, command: &str) -> String {
    const REFUSED: &str = " refused with NOT_OWNER";
    let Some(at) = message.find(REFUSED) else {
        return message.to_string();
    };
    let start = message[..at]
        .rfind(|c: char| !(c.is_ascii_uppercase() || c == '_'))
        .map_or(0, |i| i + 1);
    if start == at || command.is_empty() {
        return message.to_string();
    }
    format!("{}{command}{}", &message[..start], &message[at..])
}

/// The owner's address as DISCOVER_REPLY gives it, if a controller answers and has one.
fn owner_of(controller: &str, bind: Option<SocketAddr>) -> Option<std::net::Ipv4Addr> {
    let target = controller.to_socket_addrs().ok()?.find_map(|a| match a {
        SocketAddr::V4(v4) => Some(v4),
        SocketAddr::V6(_) => None,
    })?;
    let bind = match bind {
        Some(SocketAddr::V4(b)) => Some(SocketAddrV4::new(*b.ip(), 0)),
        _ => None,
    };
    let found = armctl::discover::discover(&armctl::discover::DiscoverOptions {
        target,
        bind,
        wait: OWNER_QUERY_WAIT,
        rounds: 1,
    })
    .ok()?;
    let reply = found.into_iter().find_map(|f| f.reply)?;
    match reply.owner {
        OwnerState::Other => Some(reply.owner_ip.into()),
        OwnerState::Free | OwnerState::Asker => None,
    }
}
