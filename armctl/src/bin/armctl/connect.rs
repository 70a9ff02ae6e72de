//! The connection every command that talks to a controller shares.

use std::time::Duration;

use armctl::{Client, Options};

use crate::cli::{Cli, Cmd};

/// The client for `--controller` with the global options; checks that the controller
/// answers STATUS, except for `stop`.
pub fn connect(cli: &Cli) -> Result<Client, String> {
    let options = Options {
        ack_timeout: Duration::from_millis(cli.ack_timeout_ms.max(1)),
        attempts: cli.attempts.max(1),
        bind: cli.bind,
        key: match &cli.key_file {
            Some(path) => Some(crate::key::read(path)?),
            None => None,
        },
        ..Options::default()
    };
    let controller = Client::open(cli.controller.as_str(), options)
        .map_err(|e| format!("{}: {e}", cli.controller))?;
    if let Some(path) = &cli.pcap {
        let log = armctl::pcap::PcapLog::create(path)
            .map_err(|e| format!("--pcap {}: {e}", path.display()))?;
        controller.capture(std::sync::Arc::new(log));
    }
    match cli.command {
        // Anyone may stop the arm: no STATUS first, which another host's controller
        // would refuse (NOT_OWNER).
        Cmd::Stop => Ok(controller),
        // `status` asks itself, look-only: it never takes the controller (issue 23).
        Cmd::Status { .. } => Ok(controller),
        // So does `diag` (issue 34).
        Cmd::Diag { .. } => Ok(controller),
        // The pendant shows a controller that does not answer (yet), or another host's,
        // read-only.
        Cmd::Serve(_) => Ok(controller),
        // As Client::connect_with: check that the controller answers.
        _ => match controller.status() {
            Ok(_) => Ok(controller),
            Err(e) => Err(format!("{}: {e}", cli.controller)),
        },
    }
}
