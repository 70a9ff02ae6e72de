//! `armctl discover`: DISCOVER to a broadcast address or one controller, one line (or a
//! JSON entry) per controller that answered.

use std::time::Duration;

use crate::CliResult;
use crate::cli::Cli;

/// `discover` (and `net show`): one line per controller that answered.
pub fn execute(
    cli: &Cli,
    to: Option<std::net::SocketAddrV4>,
    interface: Option<&str>,
    wait_ms: u64,
    rounds: u32,
    json: bool,
) -> CliResult {
    use armctl::discover::{DiscoverOptions, mac_string, net_string};
    use std::net::SocketAddrV4;
    let interface = interface.map(armctl::discover::interface_v4).transpose()?;
    let bind = match cli.bind {
        Some(std::net::SocketAddr::V4(b)) => Some(b),
        Some(other) => return Err(format!("--bind {other}: DISCOVER is IPv4")),
        None => interface.map(|i| SocketAddrV4::new(i.address, 0)),
    };
    let to = to.unwrap_or_else(|| {
        SocketAddrV4::new(
            interface.map_or(std::net::Ipv4Addr::BROADCAST, |i| i.broadcast),
            protocol::PORT,
        )
    });
    let found = armctl::discover::discover(&DiscoverOptions {
        target: to,
        bind,
        wait: Duration::from_millis(wait_ms.max(1)),
        rounds,
    })
    .map_err(|e| armctl::discover::explain_send_error(&e, to))?;
    if json {
        let list: Vec<serde_json::Value> = found
            .iter()
            .map(|f| serde_json::json!({ "address": f.from.to_string(), "reply": f.reply }))
            .collect();
        println!(
            "{}",
            serde_json::to_string_pretty(&list).map_err(|e| e.to_string())?
        );
        return Ok(());
    }
    for f in &found {
        match &f.reply {
            Some(r) => {
                let owner = match r.owner {
                    protocol::OwnerState::Free => "free".to_string(),
                    protocol::OwnerState::Asker => "owned by this host".to_string(),
                    protocol::OwnerState::Other => {
                        let [a, b, c, d] = r.owner_ip;
                        format!("owned by {a}.{b}.{c}.{d}")
                    }
                };
                let pending = if r.pending_reset {
                    " (after reset)"
                } else {
                    ""
                };
                println!(
                    "{:<21} mac {}  version {}.{}.{}  {} joints  {:<8} {}  stored {}{pending}",
                    f.from.to_string(),
                    mac_string(&r.mac),
                    r.version[0],
                    r.version[1],
                    r.version[2],
                    r.joints,
                    r.state.name(),
                    owner,
                    net_string(&r.net)
                );
            }
            None => println!(
                "{:<21} a controller without DISCOVER (protocol 1.0): `armctl --controller {} status` tells more",
                f.from.to_string(),
                f.from
            ),
        }
    }
    println!("{} controller(s) answered DISCOVER to {to}", found.len());
    Ok(())
}
