//! `armctl`: the command-line tool that drives an arm controller. `armctl --help` lists
//! the commands.
//!
//! This file parses the command line and hands each subcommand to its module:
//! - `cli`: the global options and the list of subcommands (the syntax, with clap);
//! - `connect`: opening the client, and the check that the controller answers;
//! - one module per subcommand or family: `status`, `watch`, `run`, `single` (the
//!   commands that are one frame and an `OK`: stop, return, joints, set-location, enable,
//!   pin, upload-period, reports), `pwm`, `serial`, `net`, `discover`, and `frame` and
//!   `plot`, which need no controller; `serve`, the pendant in the browser.
//!
//! Every failure prints `error: ...` and exits with 1; clap exits with 2 on a usage error.
//! A closed stdout (`armctl status | head -n 1`) ends the tool quietly, killed by SIGPIPE,
//! once the command has finished (`out`).
//! SIGINT, SIGTERM or SIGHUP during a command that moves the arm (`run`, `return`) sends STOPPED,
//! prints `interrupted (SIGINT): STOPPED sent, ...` and exits 130 or 143 (`interrupt`).
//! Library diagnostics (an upload's ACKs, timeouts, go-back-N resends) go through the `log`
//! facade: `ARMCTL_TRACE=1` shows them all, `RUST_LOG` (e.g. `RUST_LOG=armctl=debug`)
//! chooses more finely.

// std's `print!`, `println!` and `eprintln!` panic when the stream is a closed pipe
// (`armctl status | head -n 1`, issue 31). These, defined before the modules and so used
// by all of them, write through `out` instead (stderr: errors ignored, nothing to tell).
macro_rules! print {
    ($($arg:tt)*) => { $crate::out::write(format_args!($($arg)*)) };
}
macro_rules! println {
    () => { $crate::out::write(format_args!("\n")) };
    ($($arg:tt)*) => { $crate::out::write(format_args!("{}\n", format_args!($($arg)*))) };
}
macro_rules! eprintln {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        let _ = writeln!(std::io::stderr(), $($arg)*);
    }};
}

mod cli;
mod config;
mod connect;
mod diag;
mod discover;
mod enable;
mod frame;
mod homing;
mod interrupt;
mod jog_keys;
mod key;
mod motion;
mod net;
mod out;
mod owner;
mod plot;
mod pwm;
mod run;
mod serial;
mod serve;
mod single;
mod status;
mod watch;

use std::process::ExitCode;

use armctl::trajectory::ArmConfig;
use clap::{CommandFactory, FromArgMatches};

use cli::{Cli, Cmd};

/// A failure with the message to print; exit code 1 (clap exits with 2 on a usage error).
type CliResult = Result<(), String>;

fn main() -> ExitCode {
    init_logging();
    // As Cli::parse(), keeping the matches for the name of the command run.
    let matches = Cli::command().get_matches();
    let mut cli = Cli::from_arg_matches(&matches).unwrap_or_else(|e| e.exit());
    let command = command_name(&matches);
    cli.controller = armctl::controller_address(&cli.controller);
    if let Some(warning) = cli::resend_warning(cli.ack_timeout_ms, cli.attempts) {
        eprintln!("warning: {warning}");
    }
    let result = execute(cli, &command);
    if let Some(code) = interrupt::exit_code() {
        // interrupt::finish said what was stopped.
        return ExitCode::from(code);
    }
    match result {
        // Killed by SIGPIPE when stdout's reader went away (crate::out).
        Ok(()) => out::success(),
        Err(message) => {
            eprintln!("error: {message}");
            ExitCode::FAILURE
        }
    }
}

/// The logger behind the library's `log` records: `RUST_LOG` as usual (warnings by
/// default), and every record of the armctl crate with `ARMCTL_TRACE` set.
fn init_logging() {
    armctl::logger("warn").init();
}

/// The command run as the user typed it: `move`, `config set` (subcommands two deep).
fn command_name(matches: &clap::ArgMatches) -> String {
    let mut words = Vec::new();
    let mut at = matches;
    while let Some((name, sub)) = at.subcommand() {
        words.push(name);
        if words.len() == 2 {
            break;
        }
        at = sub;
    }
    words.join(" ")
}

/// The commands that need no controller, then the others over one connection. `command`
/// (as the user typed it) names what was refused.
fn execute(cli: Cli, command: &str) -> CliResult {
    match &cli.command {
        Cmd::Frame(command) => frame::execute(command),
        Cmd::Plot(args) => plot::execute(args),
        Cmd::Discover {
            to,
            interface,
            wait_ms,
            rounds,
            json,
        } => discover::execute(&cli, *to, interface.as_deref(), *wait_ms, *rounds, *json),
        Cmd::Net(net::NetCmd::Show) => net::show(&cli),
        Cmd::Run(args) if args.dry_run => run::dry_run(args),
        Cmd::Check(args) => run::dry_run(args),
        Cmd::Config(config::ConfigCmd::Init(args)) => config::init(args),
        Cmd::Serve(args) => {
            let arm = connect::connect(&cli)?;
            serve::execute(arm, args)
        }
        Cmd::Key(cli::KeyCmd::New { output }) => key::new(output.as_deref()),
        _ => {
            let arm = connect::connect(&cli)
                .map_err(|e| owner::explain_not_owner(e, command, &cli.controller, cli.bind))?;
            let result = execute_online(&cli, &arm)
                .map_err(|e| owner::explain_not_owner(e, command, &cli.controller, cli.bind))
                .map_err(|e| config::explain_invalid_point(e, &arm, None));
            // After a signal: STOPPED (unless the command sent it) and the line saying so.
            interrupt::finish(&arm);
            result
        }
    }
}

/// The commands that talk to the controller at `--controller`.
fn execute_online(cli: &Cli, arm: &armctl::Client) -> CliResult {
    match &cli.command {
        Cmd::Status { json, config } => status::execute(arm, *json, config.as_deref()),
        Cmd::Diag { json } => diag::execute(arm, *json),
        Cmd::Watch {
            record,
            duration,
            config,
            units,
        } => {
            let shown = match config.as_deref() {
                Some(path) => {
                    let config = ArmConfig::load(path).map_err(|e| e.to_string())?;
                    let units = units.unwrap_or(config.units);
                    Some(watch::Shown { config, units })
                }
                None => watch::described(arm)?,
            };
            watch::execute(arm, record.as_deref(), *duration, shown.as_ref())
        }
        Cmd::Run(args) => run::execute(arm, args),
        Cmd::Stop => single::done(arm.stop()),
        Cmd::Release => owner::release(arm),
        Cmd::EstopReset => single::done(arm.estop_reset()),
        Cmd::EstopCategory { category } => single::estop_category(arm, *category),
        Cmd::Unlock => single::done(arm.unlock()),
        Cmd::Hold => single::done(arm.hold()),
        Cmd::Resume => single::done(arm.resume()),
        Cmd::Override { percent } => single::set_override(arm, *percent),
        Cmd::Homing(command) => homing::execute(arm, command),
        Cmd::Return { wait } => single::go_home(arm, *wait),
        Cmd::Move(args) => motion::execute_move(arm, args),
        Cmd::Jog(args) => motion::execute_jog(arm, args),
        Cmd::Home { config, units } => motion::execute_home(arm, config.as_ref(), *units),
        Cmd::Joints { n } => single::done(arm.set_joints(*n)),
        Cmd::SetLocation { positions } => single::done(arm.set_location(positions)),
        Cmd::Enable { joints } => enable::execute(arm, joints, true),
        Cmd::Disable { joints } => enable::execute(arm, joints, false),
        Cmd::ToggleEnable { mask } => single::done(arm.toggle_enable(*mask)),
        Cmd::Pin { pin, level } => single::done(arm.pin(*pin, *level == cli::OnOff::On)),
        Cmd::Pwm(command) => pwm::execute(arm, command),
        Cmd::Serial {
            baud,
            mode,
            keep_open,
        } => serial::execute(arm, *baud, mode.code(), *keep_open),
        Cmd::UploadPeriod { us } => single::done(arm.upload_period(*us)),
        Cmd::Reports { state } => single::done(arm.reports(*state == cli::OnOff::On)),
        Cmd::Net(net::NetCmd::Set { ip, gateway, dhcp }) => {
            net::set(arm, ip.as_deref(), *gateway, *dhcp)
        }
        Cmd::Key(cli::KeyCmd::Set { file }) => {
            let key = key::read(file)?;
            single::done(arm.set_key(Some(key)))
        }
        Cmd::Key(cli::KeyCmd::Clear) => single::done(arm.set_key(None)),
        Cmd::Config(command) => config::execute(arm, command),
        Cmd::Frame(_)
        | Cmd::Serve(_)
        | Cmd::Check(_)
        | Cmd::Plot { .. }
        | Cmd::Discover { .. }
        | Cmd::Net(net::NetCmd::Show)
        | Cmd::Key(cli::KeyCmd::New { .. }) => Ok(()),
    }
}

#[cfg(test)]
mod tests;
