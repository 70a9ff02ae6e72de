//! `armctl net show|set`: the controller's stored network settings.

use armctl::Client;
use clap::Subcommand;

use crate::CliResult;
use crate::cli::Cli;

/// `net` subcommands.
#[derive(Subcommand, Debug)]
pub enum NetCmd {
    /// Show the stored settings of --controller (asks with DISCOVER: any host may).
    Show,
    /// NET_SET: store a static address or DHCP (owner only, not while RUNNING); the
    /// controller uses it from its next reset.
    #[command(group(clap::ArgGroup::new("mode").required(true).args(["ip", "dhcp"])))]
    Set {
        /// Static address with its prefix length, e.g. 192.168.1.30/24.
        #[arg(long, value_name = "A.B.C.D/P")]
        ip: Option<String>,
        /// Default gateway (with --ip).
        #[arg(long, value_name = "A.B.C.D", requires = "ip")]
        gateway: Option<std::net::Ipv4Addr>,
        /// Take the address from DHCP.
        #[arg(long, conflicts_with_all = ["ip", "gateway"])]
        dhcp: bool,
    },
}

/// `net show`: DISCOVER to `--controller` alone (any host may ask).
pub fn show(cli: &Cli) -> CliResult {
    let to = match cli.controller.parse::<std::net::SocketAddr>() {
        Ok(std::net::SocketAddr::V4(to)) => to,
        _ => return Err(format!("{}: give an IPv4 address:port", cli.controller)),
    };
    crate::discover::execute(cli, Some(to), None, 300, 3, false)
}

/// `net set`: NET_SET with a static address or DHCP, checked before it is sent.
pub fn set(
    arm: &Client,
    ip: Option<&str>,
    gateway: Option<std::net::Ipv4Addr>,
    dhcp: bool,
) -> CliResult {
    let net = if dhcp {
        protocol::NetSettings::DHCP
    } else {
        let (ip, prefix) = armctl::discover::parse_cidr(ip.unwrap_or_default())?;
        protocol::NetSettings::fixed(ip, prefix, gateway.map(|g| g.octets()))
    };
    if !net.is_valid() {
        return Err(format!(
            "{}: not usable (a unicast address with a prefix of 1..32 and a gateway \
             inside its subnet, or --dhcp)",
            armctl::discover::net_string(&net)
        ));
    }
    let ack = arm.net_set(net).map_err(|e| e.to_string())?;
    println!(
        "stored {} (state {}): the controller uses it after its next reset",
        armctl::discover::net_string(&net),
        ack.state.name()
    );
    Ok(())
}
